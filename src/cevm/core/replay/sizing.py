"""The battery (or tank) and the charger power a duty needs, exact to a step (pure).

Whether a duty keeps its reserve is monotone in the capacity and in the charger power
(:mod:`cevm.core.replay.chain`), so the smallest sufficient value on a grid of ``step``
is found by bisection: about log2(range / step) runs of the duty's chain, all duties at
once (:func:`smallest_passing`), microseconds per duty. The fleet's size for a share of
its duties is then a quantile of the duties' sizes (:func:`size_for_share`); where the
level carries across duties (one chain per vehicle), the fleet's share is itself
monotone and is bisected directly.

A duty's needs are computed with the trips' in-trip excess known or bounded: ``excess``
gives the value used (the exact one where the step table was read, else the bound of
:mod:`cevm.core.replay.trip_energies`), so the size found is sufficient; where it could be
smaller with the exact excess (:func:`undecided_trips`), the caller reads those trips'
step tables and sizes again, until the bound no longer decides anything.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike

from cevm.core.replay.chain import Lanes, Stops, run_chains

#: Step of the battery sizing [kWh] and of the charger sizing [kW].
BATTERY_STEP_KWH = 1.0
CHARGER_STEP_KW = 1.0


def smallest_passing(passes: Callable[[np.ndarray], np.ndarray], lo: ArrayLike, hi: ArrayLike) -> np.ndarray:
    """Per row, the smallest integer k in [lo, hi] with ``passes(k)`` (k: an integer per
    row; True where the row passes), given that passing is monotone in k; hi + 1 where
    even hi does not pass."""
    lo = np.asarray(lo, dtype=np.int64)
    hi = np.asarray(hi, dtype=np.int64)
    ok = np.asarray(passes(hi), dtype=bool)
    b = np.where(ok, hi, hi + 1)
    a = lo - 1  # a virtual failure below the range
    active = ok & (b - a > 1)
    while active.any():
        mid = np.where(active, (a + b) // 2, b)
        p = np.asarray(passes(mid), dtype=bool)
        b = np.where(active & p, mid, b)
        a = np.where(active & ~p, mid, a)
        active = b - a > 1
    return np.asarray(b, dtype=np.int64)


def lane_lows(lanes: Lanes, energy: ArrayLike, excess: ArrayLike, stops: Stops, *, capacity: ArrayLike,
              start: ArrayLike, efficiency: float, power_w: ArrayLike | None = None) -> np.ndarray:
    """The lowest level of each lane (L, ...) (:func:`cevm.core.replay.chain.run_chains`)."""
    run = run_chains(lanes, energy, excess, stops, capacity=capacity, start=start, efficiency=efficiency,
                     power_w=power_w)
    return run.low.min(axis=0) if run.low.shape[0] else np.full(run.low.shape[1:], np.inf)


def battery_upper(lanes: Lanes, energy: ArrayLike, excess: ArrayLike, soc_start: float, reserve: float) -> np.ndarray:
    """A capacity per lane with which it surely keeps its reserve, without any charge
    [J or l]: its largest energy drawn counting only what trips take, (max_t sum_{u<t}
    max(E_u, 0) + max(E_t, 0) + x_t) / (s - r), s and r the start and the reserve as
    shares of the capacity."""
    e = np.maximum(lanes.take(energy), 0.0)
    drawn = np.cumsum(e, axis=0) + lanes.take(excess)
    return drawn.max(axis=0) / (soc_start - reserve) if drawn.shape[0] else np.zeros(lanes.shape[1])


def battery_needed(lanes: Lanes, energy: ArrayLike, excess: ArrayLike, stops: Stops, *, soc_start: float,
                   reserve: float, efficiency: float, step: float) -> np.ndarray:
    """The smallest capacity (a multiple of ``step``, [J or l]) with which each lane keeps
    its reserve, starting at ``soc_start`` of it and keeping ``reserve`` of it (shares in
    [0, 1], soc_start > reserve)."""
    if not soc_start > reserve:
        raise ValueError("a duty that starts at or below its reserve has no battery size")
    hi = np.maximum(np.ceil(battery_upper(lanes, energy, excess, soc_start, reserve) / step), 1).astype(np.int64)

    def passes(k: np.ndarray) -> np.ndarray:
        c = k * step
        return lane_lows(lanes, energy, excess, stops, capacity=c, start=soc_start * c,
                         efficiency=efficiency) >= reserve * c

    return smallest_passing(passes, np.ones_like(hi), hi) * step


def charger_upper(stops: Stops, capacity: float, efficiency: float) -> float:
    """A power [W] that fills the battery from empty in the shortest sizable stop: more
    changes nothing."""
    dwell = stops.dwell_s[stops.sizable & np.isfinite(stops.dwell_s) & (stops.dwell_s > 0)]
    return float(capacity / (efficiency * dwell.min())) if dwell.size else 0.0


def charger_needed(lanes: Lanes, energy: ArrayLike, excess: ArrayLike, stops: Stops, *, capacity: float, start: float,
                   reserve: float, efficiency: float, step: float) -> np.ndarray:
    """The smallest charger power (a multiple of ``step``, [W]) at the sizable stops with
    which each lane keeps its reserve; inf where none does."""
    top = int(np.ceil(charger_upper(stops, capacity, efficiency) / step))
    lanes_n = lanes.shape[1]
    slots = lanes.index
    trip_lane = np.zeros(stops.power_w.size, dtype=np.int64)
    trip_lane[slots[slots >= 0]] = np.broadcast_to(np.arange(lanes_n), slots.shape)[slots >= 0]

    def passes(k: np.ndarray) -> np.ndarray:
        power = np.where(stops.sizable, (k * step)[trip_lane], stops.power_w)
        return lane_lows(lanes, energy, excess, stops, capacity=capacity, start=start, efficiency=efficiency,
                         power_w=power) >= reserve

    k = smallest_passing(passes, np.zeros(lanes_n, dtype=np.int64), np.full(lanes_n, top, dtype=np.int64))
    return np.where(k > top, np.inf, k * step)


def size_for_share(needed: ArrayLike, share: float) -> float:
    """The smallest value of ``needed`` (one per duty; inf: none suffices) that covers at
    least ``share`` of the duties; inf if no value does, NaN without duties."""
    v = np.sort(np.asarray(needed, dtype=np.float64))
    if v.size == 0:
        return float("nan")
    i = max(0, int(np.ceil(share * v.size - 1e-9)) - 1)
    return float(v[i])


def undecided_trips(lanes: Lanes, bounds: np.ndarray, energy: ArrayLike, x_known: ArrayLike, x_bound: ArrayLike,
                    known: ArrayLike, stops: Stops, *, capacity: ArrayLike, start: ArrayLike, reserve: ArrayLike,
                    efficiency: float, power_w: ArrayLike | None = None) -> np.ndarray:
    """The trips (indices) whose unknown excess decides whether their duty (``bounds``
    over the trips) keeps its ``reserve`` (per duty, or one level) at ``capacity`` (per
    lane): the duty does with the known excess (0 where unknown, ``x_known``) but not with
    the bound (``x_bound``), and their lowest level with the bound is below the reserve.
    Reading their step tables narrows the size. (The levels at the trips' starts do not
    depend on the excess: one run serves both.)"""
    run = run_chains(lanes, energy, x_known, stops, capacity=capacity, start=start, efficiency=efficiency,
                     power_w=power_w)
    n = np.asarray(energy).shape[0]
    before = lanes.put(run.before, n)
    e = np.asarray(energy, dtype=np.float64)
    low_k = before - e - np.asarray(x_known, dtype=np.float64)
    low_b = before - e - np.asarray(x_bound, dtype=np.float64)
    first = bounds[:-1]
    if first.size == 0:
        return np.zeros(0, dtype=np.int64)
    res = np.broadcast_to(np.asarray(reserve, dtype=np.float64), first.shape)
    undecided = (np.minimum.reduceat(low_k, first) >= res) & (np.minimum.reduceat(low_b, first) < res)
    duty = np.repeat(np.arange(first.size), np.diff(bounds))
    pick = undecided[duty] & (low_b < res[duty]) & ~np.asarray(known, dtype=bool)
    return np.flatnonzero(pick)
