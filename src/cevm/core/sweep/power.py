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
from cevm.core.sweep.steptable import StepTable, edges


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
    ct = st.t_edges
    starts = np.flatnonzero(mv)
    n = st.n
    span = window_s * (1.0 - 1e-12)
    # Each window ends at the first step edge at least span after its start (searchsorted
    # on the time edges). On a uniform time grid that is w steps on from every start: so
    # the sums are differences of slices, and the guess is checked exactly (the edge w
    # on reaches the span, the one before does not); searchsorted where it fails. One
    # running sum at a time (each 8 bytes a step): the peak memory of a long cycle.
    w = max(1, math.ceil(span / st.dt[starts[0]])) if starts.size else 1
    m = n + 1 - w  # the starts i <= n - w whose guess stays within the source
    good = np.zeros(starts.size, dtype=bool)
    if m > 0:
        goal = ct[:m] + span  # where each window must end
        ok = np.less_equal(goal, ct[w:])
        ok &= ct[w - 1 : n] < goal
        del goal
        good = np.take(ok, starts, mode="clip") & (starts < m)
        del ok
    searched = None if good.all() else starts[~good]
    if searched is not None:
        ends = np.searchsorted(ct, ct[searched] + span, side="left")
        ends = np.minimum(np.maximum(ends, searched + 1), n)
    out = []
    for values in (lambda: np.where(mv, st.x, 0.0), lambda: st.r, lambda: st.a, None):
        # x counts on moving steps only (standstill: the brakes hold the vehicle, no wheel work)
        c = ct if values is None else edges(values())
        if searched is None:
            res = np.subtract(c[w:], c[:m]).take(starts)
        else:
            res = np.empty(starts.size)
            sel = starts[good]
            res[good] = c[sel + w] - c[sel]
            res[~good] = c[ends] - c[searched]
        out.append(res)
        del c
    return tuple(out)


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
