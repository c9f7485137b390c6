"""One candidate vehicle on many logged trips, each at its own mass and temperature
(pure): the trips' energies from their cached drive-cycle vectors, and from a trip's
step table what happens inside it (the most it draws before giving some back, where it
crosses a level).

:func:`trip_energies` is the CE model of :func:`cevm.core.vehicle.predict` (eq. 22-31
with every term of :mod:`cevm.core.energy`) evaluated for trip i at mass m_i and
temperature T_i only (the diagonal of a trips x masses sweep), vectorised over all trips
at once: the simplified steps' sums are dot products, the non-simplified steps of every
trip are concatenated and their positive parts summed per trip. Equal to
:func:`cevm.core.vehicle.predict` trip by trip to rounding (the sums' order differs).

Inside a trip the energy drawn E_j can peak before the end (a descent at the end gives
some back): the lowest state of charge on the way is at the start's level less
E_n + x, x = max_j E_j - E_n >= 0 the *excess*. An EV's excess is at most what it
regenerates, ``regen_bound`` = w / eta times the negative non-simplified wheel energy
(from the vector), so the step table is read only for the trips where that bound could
decide anything (:mod:`cevm.core.replay.chain`). An ICE's tank never fills on the way:
its excess is 0 (the paper's braking credit lowers the *estimate* of the total, not the
tank; :mod:`cevm.core.sweep.evaluate`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import cast

import numpy as np
from numpy.typing import ArrayLike

from cevm.core import energy
from cevm.core.cycle import CycleVector
from cevm.core.model import IceBraking, braking_weight
from cevm.core.predictive import SPEC_STEP, spec_spread
from cevm.core.sweep import AMBIENT_ORIGINS, PredictionSet, StepTable, crossings, step_coefficients
from cevm.core.sweep.stepenergy import StepCoefficients
from cevm.core.vehicle import Vehicle
from cevm.errors import CevmError

#: Where a trip's ambient temperature comes from: its own logged mean, else the vehicle
#: file's reference_temp_c, else the default (codes into
#: :data:`cevm.core.sweep.AMBIENT_ORIGINS`, whose first, "given", is not used here).
AMBIENT_SOURCE, AMBIENT_REFERENCE, AMBIENT_DEFAULT = 1, 2, 3


@dataclass(frozen=True, eq=False)
class TripEnergies:
    """The candidate on n trips, arrays (n,): ``energy`` battery energy [J] (EV) or fuel
    [l] (ICE); the wheel energy's parts ``positive_j`` (>= 0) and ``negative_j`` (<= 0)
    [J] (W = P + w N); ``regen_bound`` the most a trip can give back after its peak [J or
    l]; ``mass_kg``; ``ambient_c`` [degC] and ``ambient_from`` (codes into
    :data:`cevm.core.sweep.AMBIENT_ORIGINS`); and what the uncertainty model needs of each
    trip: ``duration_s``, ``idle_s``, ``traction_s``, ``kinetic_j`` (m k_pos [J]), and
    ``spec`` the derivatives of (P, N) in ln CdA and ln Cr for a candidate never calibrated
    (:class:`cevm.core.predictive.Features` ``spec``), else None."""

    energy: np.ndarray
    positive_j: np.ndarray
    negative_j: np.ndarray
    regen_bound: np.ndarray
    mass_kg: np.ndarray
    ambient_c: np.ndarray
    ambient_from: np.ndarray
    duration_s: np.ndarray
    idle_s: np.ndarray
    traction_s: np.ndarray
    kinetic_j: np.ndarray
    spec: tuple | None = None

    @property
    def n(self) -> int:
        return int(self.energy.size)

    def ambient_origins(self) -> list[str]:
        """The distinct origins of the trips' temperatures, in :data:`AMBIENT_ORIGINS` order."""
        return [AMBIENT_ORIGINS[c] for c in sorted(set(self.ambient_from.tolist()))]


def _positive_parts(vectors: Sequence[CycleVector], mass_kg: np.ndarray, cda: float, cr: float) -> np.ndarray:
    """Per trip, the sum of max(Delta_i, 0) over its non-simplified moving steps [J], with
    Delta_i = m (x_i + Cr r_i) + CdA a_i at the trip's own mass."""
    sizes = np.array([v.ns_x.size for v in vectors], dtype=np.int64)
    out = np.zeros(len(vectors))
    if not sizes.sum():
        return out
    x = np.concatenate([v.ns_x for v in vectors])
    a = np.concatenate([v.ns_a for v in vectors])
    r = np.concatenate([v.ns_r for v in vectors])
    delta = np.repeat(mass_kg, sizes) * (x + cr * r) + cda * a
    np.maximum(delta, 0.0, out=delta)
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    nonempty = sizes > 0
    out[nonempty] = np.add.reduceat(delta, starts[nonempty])
    return out


def trip_ambient_c(vehicle: Vehicle, own_c: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Each trip's ambient temperature [degC] and its origin code: its own logged mean
    (``own_c``, NaN where not logged), else the vehicle's ``reference_temp_c``, else
    :data:`cevm.core.energy.AMBIENT_DEFAULT_C` (as a sweep does)."""
    own = np.asarray(own_c, dtype=np.float64)
    if vehicle.reference_temp_c is not None:
        default, code = float(vehicle.reference_temp_c), AMBIENT_REFERENCE
    else:
        default, code = energy.AMBIENT_DEFAULT_C, AMBIENT_DEFAULT
    has = np.isfinite(own)
    return np.where(has, own, default), np.where(has, AMBIENT_SOURCE, code).astype(np.int8)


def trip_energies(vectors: Sequence[CycleVector], vehicle: Vehicle, mass_kg: ArrayLike, ambient_c: ArrayLike, *,
                  ice_braking: str | None = None) -> TripEnergies:
    """``vehicle`` on each of ``vectors``, trip i at ``mass_kg[i]`` [kg] and its own
    temperature ``ambient_c[i]`` [degC] (NaN: the vehicle's default; see
    :func:`trip_ambient_c`); ``ice_braking`` overrides an ICE's braking mode (module
    notes)."""
    n = len(vectors)
    m = np.broadcast_to(np.asarray(mass_kg, dtype=np.float64), (n,)).copy()
    if n and not np.all(m > 0):
        raise CevmError("every trip's mass must be > 0 kg")
    t, origin = trip_ambient_c(vehicle, np.broadcast_to(np.asarray(ambient_c, dtype=np.float64), (n,)))
    try:
        t = energy.check_ambient_c(t)
    except ValueError as exc:
        raise CevmError(str(exc)) from None
    for v in vectors:
        if vehicle.cr < v.cr0:
            raise CevmError(f"vehicle {vehicle.name!r}: cr {vehicle.cr:g} is below a trip's Cr0 {v.cr0:g}; the CE "
                            "split is only exact for Cr >= Cr0")

    def field(name: str) -> np.ndarray:
        return np.array([getattr(v, name) for v in vectors], dtype=np.float64)

    sums = np.array([v.ns_sums for v in vectors], dtype=np.float64).reshape(n, 3)

    def parts(cda: float, cr: float) -> tuple[np.ndarray, np.ndarray]:
        """(P, N): E_DC1 plus the positive non-simplified steps, and the negative ones
        (<= 0, standstill included)."""
        e1 = m * field("s_me") + cda * field("s_a") + cr * m * field("s_r")
        net = m * (sums[:, 0] + cr * sums[:, 2]) + cda * sums[:, 1]
        pos = _positive_parts(vectors, m, cda, cr)
        return e1 + pos, net - pos

    cda, cr = vehicle.cda_m2, vehicle.cr
    p_all, neg = parts(cda, cr)
    spec = None
    if spec_spread(vehicle):  # as Features.of: forward differences within the linear piece
        d = [parts(cda * (1 + SPEC_STEP), cr), parts(cda, cr * (1 + SPEC_STEP))]
        spec = tuple(((a - p_all) / SPEC_STEP, (b - neg) / SPEC_STEP) for a, b in d)
    duration, idle = field("duration_s"), field("idle_s")
    k_pos, traction = field("k_pos"), field("traction_s")
    if vehicle.is_ev:
        w = energy.ev_negative_weight(vehicle)
        e = energy.ev_battery_energy_j(vehicle, p_all + w * neg, duration_s=duration, ambient_c=t)
        bound = -w * neg / vehicle.eta
    else:
        w = braking_weight(cast(IceBraking, ice_braking or vehicle.ice_braking))
        try:
            e = energy.ice_fuel_l(vehicle, p_all + w * neg, mass_kg=m, k_pos=k_pos, traction_s=traction,
                                  duration_s=duration, idle_s=idle, ambient_c=t)
        except ValueError as exc:
            raise CevmError(f"vehicle {vehicle.name!r}: {exc}") from None
        bound = np.zeros(n)
    kin = np.where(np.isfinite(k_pos), m * k_pos, 0.0)
    return TripEnergies(energy=np.asarray(e, dtype=np.float64), positive_j=p_all, negative_j=neg,
                        regen_bound=np.maximum(bound, 0.0), mass_kg=m, ambient_c=np.asarray(t, dtype=np.float64),
                        ambient_from=origin, duration_s=duration, idle_s=idle,
                        traction_s=np.where(np.isfinite(traction), traction, 0.0), kinetic_j=kin, spec=spec)


# ------------------------------------------------------------------ inside one trip


def _coefficients(vehicle: Vehicle, mass_kg: float, ambient_c: float, ice_braking: str | None) -> StepCoefficients:
    pset = PredictionSet.build([vehicle], mass_kg=[mass_kg], ice_braking=ice_braking)
    return step_coefficients(pset, np.array([ambient_c]))


#: Steps summed together by :func:`trips_excess` (8 MB per work array).
EXCESS_CHUNK_STEPS = 1 << 20


def trips_excess(tables: Sequence[StepTable | None], vehicle: Vehicle, mass_kg: ArrayLike, ambient_c: ArrayLike, *,
                 ice_braking: str | None = None) -> np.ndarray:
    """For each trip of step table ``tables[i]`` at ``mass_kg[i]`` and ``ambient_c[i]``:
    the most ``vehicle`` draws inside it beyond what it has drawn at its end,
    x = max_j E_j - E_n >= 0 [J or l] (module notes), step by step with every term of
    :mod:`cevm.core.energy` (:func:`cevm.core.sweep.step_coefficients`); NaN where the
    table is None (unreadable). All trips at once, in chunks of
    :data:`EXCESS_CHUNK_STEPS` steps."""
    n = len(tables)
    out = np.full(n, np.nan)
    present = [t for t in tables if t is not None]
    ok = [i for i, t in enumerate(tables) if t is not None]
    if not vehicle.is_ev:
        out[ok] = 0.0
        return out
    mass = np.asarray(mass_kg, dtype=np.float64)
    temp = np.asarray(ambient_c, dtype=np.float64)
    k = 0
    while k < len(ok):
        chunk: list[int] = []
        steps = 0
        first = k
        while k < len(ok) and (not chunk or steps + present[k].n <= EXCESS_CHUNK_STEPS):
            chunk.append(ok[k])
            steps += present[k].n
            k += 1
        out[chunk] = _excess_chunk(present[first:k], vehicle, mass[chunk], temp[chunk], ice_braking)
    return out


def _excess_chunk(tables: list[StepTable], vehicle: Vehicle, mass: np.ndarray, temp: np.ndarray,
                  ice_braking: str | None) -> np.ndarray:
    sizes = np.array([t.n for t in tables], dtype=np.int64)
    out = np.zeros(len(tables))
    has = sizes > 0
    if not has.any():
        return out
    c = step_coefficients(PredictionSet.build([vehicle], mass_kg=mass, ice_braking=ice_braking), temp)
    seg = np.repeat(np.arange(len(tables)), sizes)

    def cat(name: str) -> np.ndarray:
        return np.concatenate([getattr(t, name) for t in tables])

    g = c.kx[seg] * cat("x") + c.kr[seg] * cat("r") + c.ka[seg] * cat("a")
    neg = ~cat("simplified") & (g < 0)
    g[neg] *= c.w[seg][neg]  # a negative non-simplified step: regenerated at w
    g += c.aux[seg] * cat("dt")
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])[has]
    cum = np.cumsum(g)
    before = np.concatenate([[0.0], cum])[starts]
    ends = (starts + sizes[has] - 1)
    run = cum - np.repeat(before, sizes[has])
    out[has] = np.maximum(np.maximum.reduceat(run, starts), 0.0) - run[ends]
    return np.maximum(out, 0.0)


def trip_crossing(st: StepTable, vehicle: Vehicle, mass_kg: float, ambient_c: float, level: float, *,
                  ice_braking: str | None = None) -> tuple[float, float]:
    """Where the energy drawn inside the trip first reaches ``level`` [J or l] (the start's
    warm-up included), as (time [s], distance [m]) from the trip's start, interpolated
    inside the step; (NaN, NaN) if it never does
    (:func:`cevm.core.sweep.crossings`)."""
    c = _coefficients(vehicle, mass_kg, ambient_c, ice_braking)
    t, d, within = crossings(st, c, np.array([[level]]), repeat=False)
    if not within[0, 0]:
        return float("nan"), float("nan")
    return float(t[0, 0]), float(d[0, 0])
