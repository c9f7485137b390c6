"""Whether a vehicle can follow a source: the wheel power it asks over any
:data:`POWER_WINDOW_S` of driving against ``max_power_kw``, and its top speed against
``max_speed_kmh`` (:func:`follow_flags`)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from cevm.core import limits
from cevm.core.limits import POWER_WINDOW_S
from cevm.core.sweep.block import SweepBlock
from cevm.core.sweep.profiles import StepTable


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
    if not st.moving.any():
        return np.zeros(np.shape(np.atleast_1d(mass_kg)))
    sx, sr, sa, dur = _window_coefficients(st, window_s)
    return limits.affine_peak((sx + cr * sr) / dur, cda_m2 * sa / dur, mass_kg)


def power_mass_window(st: StepTable, max_power_w: float, cda_m2: float, cr: float,
                      window_s: float = POWER_WINDOW_S) -> tuple[float, float]:
    """The masses [kg] at which a vehicle of rated power ``max_power_w`` [W] can follow
    the source: (low, high) with :func:`peak_wheel_power_w` <= ``max_power_w`` exactly
    between them (each window's power is affine in the mass, so the set is an
    interval); (nan, nan) when no mass can."""
    if not st.moving.any():
        return 0.0, math.inf
    sx, sr, sa, dur = _window_coefficients(st, window_s)
    return limits.affine_mass_window((sx + cr * sr) / dur, cda_m2 * sa / dur, max_power_w)


def follow_flags(block: SweepBlock) -> SweepBlock:
    """``block`` with ``over_power``, ``over_speed`` (:func:`cevm.core.limits.follow_flags`:
    the source's power over any :data:`POWER_WINDOW_S` against the vehicle's
    ``max_power_kw`` at the row's mass, its held top speed against ``max_speed_kmh``,
    with a logged trace's measurement tolerance; 1.0 / 0.0, NaN for rows of vehicles
    without the key) and ``power_demand_w`` (the power the source asks at the row's
    mass), for vehicles with either key. Rated power is at the motor or engine shaft, so
    the test is lenient: the drivetrain's losses and rotating parts ask more still."""
    ps = block.pset
    if all(v.max_power_w is None and v.max_speed_mps is None for v in ps.vehicles):
        return block
    over_p = np.full(ps.n, np.nan)
    over_v = np.full(ps.n, np.nan)
    demand_w = np.full(ps.n, np.nan)
    demand = block.source.demand
    for j, v in enumerate(ps.vehicles):
        if v.max_power_w is None and v.max_speed_mps is None:
            continue
        rows = np.flatnonzero(ps.vehicle_index == j)
        over_p[rows], over_v[rows], demand_w[rows] = limits.follow_flags(demand, v, ps.mass_kg[rows])
    return replace(block, over_power=over_p, over_speed=over_v, power_demand_w=demand_w)
