"""A vehicle's consumption over one leg as an exact convex piecewise-affine function of
its gross mass (:func:`leg_curve`; the package docstring says why it is exact)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cevm.core import energy
from cevm.core.cycle import CycleVector
from cevm.core.model import braking_weight
from cevm.core.vehicle import Vehicle, default_ambient_c, predict

#: Relative tolerance of the check of leg pieces against the CE model.
_CURVE_RTOL = 1e-9


@dataclass(frozen=True, eq=False)
class LegCurve:
    """A vehicle's consumption over one leg as a convex piecewise-affine function of its
    gross mass m [kg] on ``[m_lo_kg, m_hi_kg]``: ``q(m) = max_k (alpha[k] + beta[k] m)``
    in litres (ICE) or joules at the battery (EV). ``affine`` when one piece remains."""

    alpha: np.ndarray
    beta: np.ndarray
    m_lo_kg: float
    m_hi_kg: float

    @property
    def affine(self) -> bool:
        return self.alpha.size == 1

    def __call__(self, mass_kg) -> np.ndarray:
        m = np.asarray(mass_kg, dtype=np.float64)
        return np.max(self.alpha[:, None] + self.beta[:, None] * m.ravel()[None, :], axis=0).reshape(m.shape)


def _negative_weight(vehicle: Vehicle) -> float:
    return energy.ev_negative_weight(vehicle) if vehicle.is_ev else braking_weight(vehicle.ice_braking)


def _to_quantity(vehicle: Vehicle, vector: CycleVector, ambient_c: float) -> tuple[float, float, float]:
    """Gain and offset of the map wheel energy [J] -> litres or battery joules, and the
    slope in mass [per kg] of the terms beyond the wheel (an ICE's kinetic term), read
    from cevm.core.energy's own functions at ``ambient_c``."""
    if vehicle.is_ev:
        def conv(e, m):
            return float(energy.ev_battery_energy_j(vehicle, e, duration_s=vector.duration_s, ambient_c=ambient_c))
    else:
        def conv(e, m):
            return float(energy.ice_fuel_l(vehicle, e, mass_kg=m, k_pos=vector.k_pos, traction_s=vector.traction_s,
                                           duration_s=vector.duration_s, idle_s=vector.idle_s, ambient_c=ambient_c))
    q0 = conv(0.0, 0.0)
    return conv(1.0, 0.0) - q0, q0, conv(0.0, 1.0) - q0


def leg_curve(vector: CycleVector, vehicle: Vehicle, m_lo_kg: float, m_hi_kg: float, *, check: bool = True,
              ambient_c: float | None = None) -> LegCurve:
    """The exact pieces of ``predict(vector, vehicle, m)`` for m in [m_lo_kg, m_hi_kg].

    Wheel energy is ``m B0 + A0 + (1 - w) P(m)`` with P the sum of the positive
    non-simplified Delta_i; on the c = CdA/m interval where the first i steps of the
    cycle's sorted threshold table are positive, P(m) = m (X_i + Cr R_i) + CdA A_i with
    the table's prefix sums. One piece per threshold inside the range, duplicates
    removed (w = 1 leaves one: affine). The terms beyond the wheel (:mod:`cevm.core.energy`,
    at ``ambient_c``, default the vehicle's) add a constant and, an ICE's kinetic term,
    a slope in m. With ``check`` (default), the pieces are compared
    with :func:`cevm.core.vehicle.predict` at every breakpoint in the range, every midpoint and
    both ends; a mismatch beyond 1e-9 relative raises RuntimeError (a bug, not input).
    """
    if not (0 < m_lo_kg <= m_hi_kg):
        raise ValueError("need 0 < m_lo_kg <= m_hi_kg")
    cda, cr = float(vehicle.cda_m2), float(vehicle.cr)
    w = _negative_weight(vehicle)
    sx, sa, sr = vector.ns_sums
    b0 = vector.s_me + cr * vector.s_r + w * (sx + cr * sr)
    a0 = cda * vector.s_a + w * cda * sa
    if vector.n_nonsimplified == 0 or w == 1.0:
        B = np.array([b0])
        A = np.array([a0])
        thr = np.empty(0)
    else:
        table = vector.threshold_table(cr)
        i_lo = int(np.searchsorted(table.threshold, cda / m_hi_kg, side="left"))
        i_hi = int(np.searchsorted(table.threshold, cda / m_lo_kg, side="left"))
        idx = np.arange(i_lo, i_hi + 1)
        B = b0 + (1.0 - w) * (table.x_cum[idx] + cr * table.r_cum[idx])
        A = a0 + (1.0 - w) * cda * table.a_cum[idx]
        thr = table.threshold[i_lo:i_hi]
    t_c = default_ambient_c(vehicle)[0] if ambient_c is None else float(ambient_c)
    gain, offset, slope = _to_quantity(vehicle, vector, t_c)
    alpha = gain * A + offset
    beta = gain * B + slope
    if alpha.size > 1:
        keep = np.ones(alpha.size, dtype=bool)
        keep[1:] = (alpha[1:] != alpha[:-1]) | (beta[1:] != beta[:-1])
        alpha, beta = alpha[keep], beta[keep]
    curve = LegCurve(alpha=alpha, beta=beta, m_lo_kg=float(m_lo_kg), m_hi_kg=float(m_hi_kg))
    if check:
        bps = np.sort(cda / thr[thr > 0]) if thr.size else np.empty(0)
        pts = np.concatenate([[m_lo_kg], bps, [m_hi_kg]])
        grid = np.concatenate([pts, 0.5 * (pts[1:] + pts[:-1])])
        grid = grid[(grid >= m_lo_kg) & (grid <= m_hi_kg)]
        truth = quantity(predict(vector, vehicle, grid, ambient_c=t_c), vehicle)
        err = np.max(np.abs(curve(grid) - truth))
        scale = float(np.max(np.abs(truth))) + abs(offset) + 1e-300
        if err > _CURVE_RTOL * scale:
            raise RuntimeError(f"leg pieces disagree with the CE model by {err:g} (scale {scale:g}): a bug in cevm")
    return curve


def quantity(pred, vehicle: Vehicle) -> np.ndarray:
    return pred.energy_j if vehicle.is_ev else pred.fuel_l
