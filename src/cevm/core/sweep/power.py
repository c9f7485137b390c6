"""Whether a vehicle can follow a source: the wheel power it asks over any
:data:`POWER_WINDOW_S` of driving against ``max_power_kw``, and its top speed against
``max_speed_kmh`` (:func:`follow_flags`)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from cevm.core.sweep.block import SweepBlock
from cevm.core.sweep.profiles import StepTable

#: Masses x windows of one chunk of :func:`peak_wheel_power_w` (8 MB of float64).
_POWER_CHUNK_CELLS = 1 << 20

#: The window over which the power a source asks is averaged [s] (:func:`follow_flags`):
#: a drivetrain delivers its rated power for seconds, and one-second steps of a logged
#: trace carry speed and elevation noise (1 m of elevation noise in 1 s is 430 kW at
#: 44 t); over 5 s the kinetic and potential energy of the noise cancel.
POWER_WINDOW_S = 5.0


def _window_coefficients(st: StepTable, window_s: float = POWER_WINDOW_S):
    """Per window of consecutive steps lasting at least ``window_s`` (one starting at
    each moving step): the sums of x, r, a over its moving steps and its duration, so
    that its mean wheel power at mass m is (m (sx + Cr sr) + CdA sa) / T. They depend
    on the source alone: made once per step table (every vehicle of a sweep asks)."""
    cache = st.__dict__.setdefault("_power_windows", {})  # goes with the table (Source.release)
    if window_s not in cache:
        cache[window_s] = _window_sums(st, window_s)
    return cache[window_s]


def _window_sums(st: StepTable, window_s: float):
    mv = st.moving
    x = np.where(mv, st.x, 0.0)  # standstill: the brakes hold the vehicle, no wheel work

    def csum(v: np.ndarray) -> np.ndarray:  # [0, cumsum...] without a second copy
        out = np.empty(v.size + 1)
        out[0] = 0.0
        np.cumsum(v, out=out[1:])
        return out

    cx, cr_, ca, ct = csum(x), csum(st.r), csum(st.a), csum(st.dt)
    starts = np.flatnonzero(mv)
    ends = np.searchsorted(ct, ct[starts] + window_s * (1.0 - 1e-12), side="left")
    ends = np.minimum(np.maximum(ends, starts + 1), st.n)
    dur = ct[ends] - ct[starts]
    return cx[ends] - cx[starts], cr_[ends] - cr_[starts], ca[ends] - ca[starts], dur


def peak_wheel_power_w(st: StepTable, mass_kg, cda_m2: float, cr: float, window_s: float = POWER_WINDOW_S
                       ) -> np.ndarray:
    """The largest mean wheel power [W] a source asks of a vehicle at each mass, over
    any ``window_s`` of driving (eq. 28 summed over the window, no rotating inertia);
    0 for a source that never moves."""
    m = np.atleast_1d(np.asarray(mass_kg, dtype=np.float64))
    if not st.moving.any():
        return np.zeros(m.shape)
    sx, sr, sa, dur = _window_coefficients(st, window_s)
    slope = (sx + cr * sr) / dur
    icpt = cda_m2 * sa / dur
    out = np.empty(m.shape)
    step = max(1, _POWER_CHUNK_CELLS // slope.size)
    for lo in range(0, m.size, step):
        out[lo:lo + step] = (m[lo:lo + step, None] * slope[None, :] + icpt[None, :]).max(axis=1)
    return out


def power_mass_window(st: StepTable, max_power_w: float, cda_m2: float, cr: float,
                      window_s: float = POWER_WINDOW_S) -> tuple[float, float]:
    """The masses [kg] at which a vehicle of rated power ``max_power_w`` [W] can follow
    the source: (low, high) with :func:`peak_wheel_power_w` <= ``max_power_w`` exactly
    between them (each window's power is affine in the mass, so the set is an
    interval); (nan, nan) when no mass can."""
    if not st.moving.any():
        return 0.0, math.inf
    sx, sr, sa, dur = _window_coefficients(st, window_s)
    slope = (sx + cr * sr) / dur
    icpt = cda_m2 * sa / dur
    if np.any((slope == 0) & (icpt > max_power_w)):
        return math.nan, math.nan
    with np.errstate(divide="ignore", invalid="ignore"):
        bound = (max_power_w - icpt) / slope
    hi = float(np.min(bound[slope > 0], initial=math.inf))
    lo = float(np.max(bound[slope < 0], initial=0.0))
    if lo > hi:
        return math.nan, math.nan
    return lo, hi


def follow_flags(block: SweepBlock) -> SweepBlock:
    """``block`` with ``over_power`` (the source asks more wheel power than the vehicle's
    ``max_power_kw`` at the row's mass; see :func:`power_mass_window`) and
    ``over_speed`` (the source is faster than its ``max_speed_kmh``): 1.0 / 0.0, NaN for
    rows of vehicles without the key. The power is the mean over any
    :data:`POWER_WINDOW_S` of driving, and rated power is at the motor or engine shaft,
    so the test is lenient: the drivetrain's losses and rotating parts ask more still."""
    ps = block.pset
    if all(v.max_power_w is None and v.max_speed_mps is None for v in ps.vehicles):
        return block
    over_p = np.full(ps.n, np.nan)
    over_v = np.full(ps.n, np.nan)
    for j, v in enumerate(ps.vehicles):
        if v.max_power_w is None and v.max_speed_mps is None:
            continue
        rows = np.flatnonzero(ps.vehicle_index == j)
        st = block.source.step_table
        if v.max_speed_mps is not None:
            over_v[rows] = float(st.v_max_mps > v.max_speed_mps * (1.0 + 1e-9))
        if v.max_power_w is not None:
            lo, hi = power_mass_window(st, v.max_power_w, v.cda_m2, v.cr)
            m = ps.mass_kg[rows]
            over_p[rows] = np.where(np.isnan(lo), 1.0, ((m < lo) | (m > hi)).astype(float))
    return replace(block, over_power=over_p, over_speed=over_v)
