"""Energy predictions from a cached drive-cycle vector (paper eq. 22-31).

Every function here is pure and vectorised: vehicle parameters and masses are numpy
arrays (or scalars) that broadcast together, one prediction per broadcast element.
Results equal the paper's per-step sums to floating-point rounding (see the tests, which
compare with a plain per-step loop).

Wheel energy over a cycle, for weight w on the negative non-simplified steps,

    E_DC = E_DC1 + sum_{i in NS, Delta_i > 0} Delta_i + w * sum_{i in NS, Delta_i <= 0} Delta_i

with E_DC1 = Delta . V (eq. 22). The three modes of the paper and cevm:

- ICE as printed in the paper (eq. 24), ``braking="paper"``: w = 1, braking energy is
  credited; E_DC is then affine in m and CdA.
- ICE with no credit for braking, ``braking="no-credit"``: w = 0 (an engine does not
  recover braking energy; the brakes dissipate it).
- EV (eq. 27-29): w = eta^2 (regeneration through the powertrain twice).

Then ICE fuel L_f = E_DC / (U_f eta) (26) and EV battery energy E_e = E_DC / eta (31).
Two optional terms beyond the paper, zero by default: an EV's auxiliary power drawn from
the battery for the whole cycle (heating, air conditioning), and an ICE's idle fuel rate
for the time at standstill.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from cevm.core.cycle import CycleVector

IceBraking = Literal["paper", "no-credit"]
ICE_BRAKING_MODES: tuple[str, ...] = ("paper", "no-credit")
#: The ICE braking mode when none is given: "no-credit", chosen by measured fit. Against
#: the detailed model (the sample logs, and the public cycles in benchmarks/TABLES.md) it
#: predicts fuel with a smaller error across cycles and gives physically plausible
#: efficiencies, while eq. (24)'s credit for braking energy makes the fitted eta swing
#: with the share of stop-and-go. The paper's mode stays one keyword away.
ICE_BRAKING_DEFAULT: IceBraking = "no-credit"

# Direct evaluation touches n_steps values per prediction; the sorted table costs about
# n_steps * log2(n_steps) once per (cycle, Cr), then log2(n_steps) per prediction. A Cr
# met in small groups is summed directly until it has been asked for this many times
# (an optimisation loop predicting one vehicle at a time), then it gets its table.
_DIRECT_CHUNK_ELEMENTS = 1 << 20
_TABLE_AFTER_DIRECT_USES = 3


def _check_cr(vector: CycleVector, cr: np.ndarray) -> None:
    if np.any(cr < vector.cr0):
        bad = float(np.min(cr))
        raise ValueError(
            f"rolling coefficient Cr={bad:g} is below the cycle vector's Cr0={vector.cr0:g}: "
            "the simplified split is only exact for Cr >= Cr0; recompute the vector with a lower cr0"
        )


def nonsimplified_positive_j(
    vector: CycleVector, mass_kg, cda_m2, cr
) -> np.ndarray:
    """Sum of the positive Delta_i over the non-simplified steps [J], exact.

    Parameters broadcast together: mass_kg [kg] (> 0), cda_m2 [m^2] (>= 0), cr [-].
    Uses the per-Cr sorted threshold table (one binary search per prediction) for groups
    of predictions sharing a Cr, and a direct sum for isolated Cr values.
    """
    m, cda, crs = np.broadcast_arrays(
        np.asarray(mass_kg, dtype=np.float64),
        np.asarray(cda_m2, dtype=np.float64),
        np.asarray(cr, dtype=np.float64),
    )
    shape = m.shape
    m = m.ravel()
    cda = cda.ravel()
    crs = crs.ravel()
    out = np.empty(m.size)
    n = vector.n_nonsimplified
    if n == 0 or m.size == 0:
        out[:] = 0.0
        return out.reshape(shape)
    unique_cr, inverse = np.unique(crs, return_inverse=True)
    direct_below = 2.0 * np.log2(n + 1.0) + 4.0
    for j, crv in enumerate(unique_cr):
        sel = inverse == j if unique_cr.size > 1 else slice(None)
        mg = m[sel]
        cg = cda[sel]
        if _use_table(vector, float(crv), mg.size, direct_below):
            t = vector.threshold_table(float(crv))
            idx = np.searchsorted(t.threshold, cg / mg, side="left")
            out[sel] = mg * (t.x_cum[idx] + crv * t.r_cum[idx]) + cg * t.a_cum[idx]
        else:
            out[sel] = _positive_direct(vector, mg, cg, float(crv))
    return out.reshape(shape)


def _use_table(vector: CycleVector, cr: float, n_predictions: int, direct_below: float) -> bool:
    if n_predictions >= direct_below or cr in vector._tables:
        return True
    uses = vector._direct_uses.get(cr, 0) + 1
    if len(vector._direct_uses) >= 1024:  # many distinct Cr (a fit over Cr): stay bounded
        vector._direct_uses.clear()
    vector._direct_uses[cr] = uses
    return uses > _TABLE_AFTER_DIRECT_USES


def _positive_scalar(vector: CycleVector, m: float, cda: float, cr: float) -> float:
    if vector.n_nonsimplified == 0:
        return 0.0
    if not _use_table(vector, cr, 1, 2.0 * np.log2(vector.n_nonsimplified + 1.0) + 4.0):
        return float(_positive_direct(vector, np.array([m]), np.array([cda]), cr)[0])
    t = vector.threshold_table(cr)
    i = int(t.threshold.searchsorted(cda / m, side="left"))
    return m * (float(t.x_cum[i]) + cr * float(t.r_cum[i])) + cda * float(t.a_cum[i])


def _positive_direct(vector: CycleVector, m: np.ndarray, cda: np.ndarray, cr: float) -> np.ndarray:
    xr = vector.ns_x + cr * vector.ns_r
    a = vector.ns_a
    res = np.empty(m.size)
    step = max(1, _DIRECT_CHUNK_ELEMENTS // max(1, xr.size))
    for s in range(0, m.size, step):
        d = m[s : s + step, None] * xr[None, :] + cda[s : s + step, None] * a[None, :]
        res[s : s + step] = np.maximum(d, 0.0).sum(axis=1)
    return res


def wheel_energy_j(
    vector: CycleVector,
    mass_kg,
    cda_m2,
    cr,
    negative_weight=1.0,
) -> np.ndarray | np.float64:  # np.float64 for Python scalar arguments (the fast path)
    """Wheel energy E_DC = E_DC1 + E_DC2 over the cycle [J] (eq. 22, 24/27, 25/30).

    The parameters: broadcast together.

    Parameters
    ----------
    vector
        the cycle's :class:`~cevm.core.cycle.CycleVector`
    mass_kg
        vehicle mass m [kg], > 0
    cda_m2
        drag area CdA [m^2], >= 0
    cr
        rolling-resistance coefficient [-], >= vector.cr0
    negative_weight
        w applied to negative non-simplified steps: 1 for the paper's ICE
        (eq. 24), 0 for an ICE with no braking credit, eta^2 for an EV (eq. 29)
    """
    if all(isinstance(x, (float, int)) for x in (mass_kg, cda_m2, cr, negative_weight)):
        return _wheel_energy_scalar(vector, float(mass_kg), float(cda_m2), float(cr), float(negative_weight))
    m = np.asarray(mass_kg, dtype=np.float64)
    cda = np.asarray(cda_m2, dtype=np.float64)
    crs = np.asarray(cr, dtype=np.float64)
    w = np.asarray(negative_weight, dtype=np.float64)
    e1, net = _simplified_and_net_j(vector, m, cda, crs)
    if np.all(w == 1.0):
        return np.asarray(e1 + net + 0.0 * w)
    pos = nonsimplified_positive_j(vector, m, cda, crs)
    return np.asarray(e1 + pos + w * (net - pos))


def wheel_energy_parts_j(vector: CycleVector, mass_kg, cda_m2, cr) -> tuple[np.ndarray, np.ndarray]:
    """The two parts of the wheel energy [J]: P, E_DC1 plus the positive non-simplified
    steps, and N <= 0, the negative non-simplified steps; E_DC = P + w N for any weight
    w (:func:`wheel_energy_j`, same broadcasting and checks, one pass for both)."""
    m, cda, crs = np.broadcast_arrays(np.asarray(mass_kg, dtype=np.float64), np.asarray(cda_m2, dtype=np.float64),
                                      np.asarray(cr, dtype=np.float64))
    e1, net = _simplified_and_net_j(vector, m, cda, crs)
    pos = nonsimplified_positive_j(vector, m, cda, crs)
    return e1 + pos, net - pos


def _simplified_and_net_j(vector: CycleVector, m: np.ndarray, cda: np.ndarray,
                          crs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """E_DC1 and the net sum of the non-simplified steps [J] (eq. 22, 25) of the arrays
    given, after the checks of every caller (mass > 0, CdA >= 0, Cr within the vector's)."""
    if np.any(m <= 0):
        raise ValueError("mass_kg must be > 0")
    if np.any(cda < 0):
        raise ValueError("cda_m2 must be >= 0")
    _check_cr(vector, crs)
    e1 = m * vector.s_me + cda * vector.s_a + crs * m * vector.s_r
    sx, sa, sr = vector.ns_sums
    return e1, m * (sx + crs * sr) + cda * sa


def _wheel_energy_scalar(vector: CycleVector, m: float, cda: float, cr: float, w: float) -> np.float64:
    """:func:`wheel_energy_j` for plain Python numbers: same result, less overhead."""
    if not m > 0:
        raise ValueError("mass_kg must be > 0")
    if not cda >= 0:
        raise ValueError("cda_m2 must be >= 0")
    if not cr >= vector.cr0:
        _check_cr(vector, np.asarray(cr))
    e1 = m * vector.s_me + cda * vector.s_a + cr * m * vector.s_r
    sx, sa, sr = vector.ns_sums
    net = m * (sx + cr * sr) + cda * sa
    if w == 1.0:
        return np.float64(e1 + net)
    pos = _positive_scalar(vector, m, cda, cr)
    return np.float64(e1 + pos + w * (net - pos))


def ice_fuel_l(
    vector: CycleVector,
    mass_kg,
    cda_m2,
    cr,
    eta,
    lhv_j_per_l,
    *,
    braking: IceBraking = ICE_BRAKING_DEFAULT,
    idle_fuel_lps=0.0,
) -> np.ndarray:
    """ICE fuel over the cycle [l]: L_f = E_DC / (U_f eta) (eq. 26), plus idle fuel.

    ``braking`` defaults to :data:`ICE_BRAKING_DEFAULT` ("no-credit"). ``"paper"`` credits braking energy
    as eq. (24) does; ``"no-credit"`` counts
    only the positive non-simplified steps. ``idle_fuel_lps`` [l/s] is burnt during the
    cycle's time at standstill (0 by default, as in the paper). E_DC < 0 (a long
    descent, paper mode) gives negative fuel from the traction term: the model, not
    cevm, says so; no clipping is applied.
    """
    e = wheel_energy_j(vector, mass_kg, cda_m2, cr, braking_weight(braking))
    return fuel_from_wheel_energy_l(e, eta, lhv_j_per_l, idle_fuel_lps, vector.idle_s)


def ev_energy_j(
    vector: CycleVector,
    mass_kg,
    cda_m2,
    cr,
    eta,
    *,
    aux_power_w=0.0,
) -> np.ndarray:
    """EV electric energy from the battery over the cycle [J]: E_e = E_DC / eta (eq. 31),
    with regeneration weighted by eta^2 (eq. 29), plus auxiliary power [W] times the
    cycle's duration (0 by default, as in the paper)."""
    eta = _check_eta(eta)
    e = wheel_energy_j(vector, mass_kg, cda_m2, cr, eta * eta)
    return battery_energy_from_wheel_j(e, eta, aux_power_w, vector.duration_s)


def braking_weight(braking: str) -> float:
    """Weight w of negative non-simplified steps for an ICE braking mode (one of
    :data:`ICE_BRAKING_MODES`, else ValueError)."""
    if braking not in ICE_BRAKING_MODES:
        raise ValueError(f"braking must be one of {ICE_BRAKING_MODES}, not {braking!r}")
    return 1.0 if braking == "paper" else 0.0


def _check_eta(eta) -> np.ndarray:
    eta = np.asarray(eta, dtype=np.float64)
    if np.any((eta <= 0) | (eta > 1)):
        raise ValueError("eta must be in (0, 1]")
    return eta


def fuel_from_wheel_energy_l(wheel_energy_j, eta, lhv_j_per_l, idle_fuel_lps=0.0, idle_s=0.0) -> np.ndarray:
    """Fuel [l] = E_DC / (U_f eta) (eq. 26) + idle fuel rate [l/s] x idle time [s]."""
    eta = _check_eta(eta)
    return np.asarray(wheel_energy_j) / (np.asarray(lhv_j_per_l) * eta) + np.asarray(idle_fuel_lps) * idle_s


def battery_energy_from_wheel_j(wheel_energy_j, eta, aux_power_w=0.0, duration_s=0.0) -> np.ndarray:
    """Battery energy [J] = E_DC / eta (eq. 31) + auxiliary power [W] x duration [s]."""
    eta = _check_eta(eta)
    return np.asarray(wheel_energy_j) / eta + np.asarray(aux_power_w) * duration_s


@dataclass(frozen=True)
class Prediction:
    """Arrays (broadcast shape of the inputs) of one vehicle model's predictions."""

    mass_kg: np.ndarray
    wheel_energy_j: np.ndarray | np.float64  # np.float64 for scalar arguments
    energy_j: np.ndarray | None  # EV: at the battery
    fuel_l: np.ndarray | None  # ICE
    ambient_c: np.ndarray | None = None  # the ambient temperature used [degC]
