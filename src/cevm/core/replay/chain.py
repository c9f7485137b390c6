"""The state of charge (or the fuel in the tank) carried from trip to trip, with charging
in the stops (pure, vectorised over chains and draws).

Levels are energies in the battery [J] (EV) or fuel in the tank [l] (ICE), from 0
(empty) to the capacity C (the usable battery, the tank). Trip by trip, in time order,
with L the level at the trip's start, E the trip's energy and x its excess (the most it
draws inside the trip beyond E, :mod:`cevm.core.replay.trip_energies`):

- the lowest level inside the trip is L - E - x;
- after the trip the level is min(L - E, C): a full battery takes no regenerated energy;
- in the stop after it the vehicle gains min(eta_c P dt, C - level): a charger of power
  P [W] (0 where the stop does not charge; infinite for refuelling to full) for the
  stop's whole dwell dt [s] at charging efficiency eta_c, never beyond full;
- at the end of a duty whose level fell below empty the level is taken as empty (the
  duty failed; the next starts from what the rest between them gives).

A *chain* is a run of trips whose level carries over: one duty when every duty starts
from the same level (the default: a full depot charge overnight), or all of a vehicle's
duties when the level carries across the rests. Chains are laid side by side in
:class:`Lanes` (slot t of lane l is the chain's t-th trip, padded with nothing), so that
one loop over slots serves every chain, and a last axis of draws (the Monte Carlo of
:mod:`cevm.core.replay.montecarlo`) or of trial capacities (:mod:`cevm.core.replay.sizing`)
costs no Python loop.

Every operation above is non-decreasing in L, C and P: a bigger battery or a stronger
charger never lowers a level, so whether a duty keeps its reserve (its lowest level at or
above a share r of C, starting from a share s of C with s > r) is monotone in both (the
sizing relies on it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike


@dataclass(frozen=True, eq=False)
class Lanes:
    """Chains side by side: ``index`` (T, L) the trip at slot t of lane l (-1: past the
    chain's end). Chains are runs of consecutive trips of one trip array."""

    index: np.ndarray

    @classmethod
    def of(cls, starts: ArrayLike, stops: ArrayLike) -> Lanes:
        """Lanes of the chains ``starts[l]:stops[l]`` (trip indices)."""
        starts = np.asarray(starts, dtype=np.int64)
        sizes = np.asarray(stops, dtype=np.int64) - starts
        t = int(sizes.max()) if sizes.size else 0
        slot = np.arange(t)[:, None]
        index = np.where(slot < sizes[None, :], starts[None, :] + slot, -1)
        return cls(index)

    @property
    def shape(self) -> tuple[int, int]:
        t, lanes = self.index.shape
        return int(t), int(lanes)

    @property
    def valid(self) -> np.ndarray:
        return self.index >= 0

    def take(self, values: ArrayLike, fill: float | bool = 0.0) -> np.ndarray:
        """Per-trip ``values`` (n, ...) at each slot (T, L, ...); ``fill`` where none."""
        v = np.asarray(values)
        out = v[np.maximum(self.index, 0)]
        if self.index.size and not self.valid.all():
            mask = ~self.valid
            out = out.copy()
            out[mask] = fill
        return np.asarray(out)

    def put(self, slots: np.ndarray, n: int) -> np.ndarray:
        """Slot values (T, L, ...) back to one per trip (n, ...)."""
        out = np.zeros((n,) + slots.shape[2:], dtype=slots.dtype)
        ok = self.valid
        out[self.index[ok]] = slots[ok]
        return out


@dataclass(frozen=True, eq=False)
class Stops:
    """The stop after each trip (n,): ``dwell_s`` [s] (NaN after the last), ``power_w``
    the charger there [W] (0: no charging; inf: refuelled to full), ``sizable`` whether a
    charger sizing sets its power (the stops of a duty that charge; not the rests
    between duties), ``duty_end`` whether the trip ends a duty."""

    dwell_s: np.ndarray
    power_w: np.ndarray
    sizable: np.ndarray
    duty_end: np.ndarray

    def with_power(self, power_w: ArrayLike) -> np.ndarray:
        """The stops' powers with the sizable ones at ``power_w`` (broadcast over a last
        axis of trial powers: (n, K))."""
        p = np.asarray(power_w, dtype=np.float64)
        base = self.power_w if p.ndim == 0 else self.power_w[:, None]
        return np.where((self.sizable if p.ndim == 0 else self.sizable[:, None]), p, base)


def stop_gain(level: ArrayLike, capacity: ArrayLike, power_w: ArrayLike, dwell_s: ArrayLike,
              efficiency: float) -> np.ndarray:
    """What a stop adds [J or l]: min(eta_c P dt, C - level), all of C - level for an
    infinite P (refuelling), nothing for P = 0 or a NaN dwell."""
    room = np.maximum(np.asarray(capacity, dtype=np.float64) - np.asarray(level, dtype=np.float64), 0.0)
    return np.asarray(np.minimum(stop_potential(power_w, dwell_s, efficiency), room), dtype=np.float64)


def stop_potential(power_w: ArrayLike, dwell_s: ArrayLike, efficiency: float) -> np.ndarray:
    """What a stop could add to an empty battery or tank: eta_c P dt (inf for an infinite P,
    0 for P = 0 or a NaN dwell)."""
    p = np.asarray(power_w, dtype=np.float64)
    dwell = np.nan_to_num(np.asarray(dwell_s, dtype=np.float64), nan=0.0)
    with np.errstate(invalid="ignore"):
        raw = np.where(np.isinf(p), np.inf, efficiency * p * dwell)
    return np.where(p > 0, raw, 0.0)


@dataclass(frozen=True, eq=False)
class ChainRun:
    """Per slot (T, L, ...): ``before`` the level at the trip's start, ``low`` the lowest
    inside it (+inf past a lane's end), ``after`` the level after it (capped at full),
    ``gain`` what the stop after it added."""

    before: np.ndarray
    low: np.ndarray
    after: np.ndarray
    gain: np.ndarray


class _Slots:
    """What one loop over a lanes' slots reads: energies, excess, stop potentials and
    duty ends laid out (T, L, ...), the capacity and the start level per lane."""

    def __init__(self, lanes: Lanes, energy: ArrayLike, excess: ArrayLike, stops: Stops, capacity: ArrayLike,
                 start: ArrayLike, efficiency: float, power_w: ArrayLike | None):
        self.e = lanes.take(energy)
        self.x = lanes.take(excess)
        power = stops.power_w if power_w is None else power_w
        self.pot = lanes.take(stop_potential(power, stops.dwell_s if np.ndim(power) == 1 else stops.dwell_s[:, None],
                                             efficiency))
        self.end = lanes.take(stops.duty_end, fill=False)
        self.valid = lanes.valid
        t_count, l_count = lanes.shape
        extra = np.broadcast_shapes(self.e.shape[2:], self.x.shape[2:], self.pot.shape[2:], np.shape(capacity)[1:],
                                    np.shape(start)[1:])
        self.shape = (l_count,) + extra
        self.t_count = t_count
        self.cap = np.broadcast_to(np.asarray(capacity, dtype=np.float64).reshape(_lane_shape(capacity, extra)),
                                   self.shape)
        self.start = np.broadcast_to(np.asarray(start, dtype=np.float64).reshape(_lane_shape(start, extra)),
                                     self.shape).copy()
        self.pad = (slice(None),) + (None,) * (len(self.shape) - 1)

    def step(self, t: int, level: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Slot t from ``level``: (low, after, gain, the next level)."""
        et = _lane_slot(self.e[t], self.shape)
        low = level - et - _lane_slot(self.x[t], self.shape)
        low = np.where(self.valid[t][self.pad], low, np.inf)
        after = np.minimum(level - et, self.cap)
        level = np.where(self.end[t][self.pad], np.maximum(after, 0.0), after) if self.end[t].any() else after
        gain = np.minimum(_lane_slot(self.pot[t], self.shape), np.maximum(self.cap - level, 0.0))
        return low, after, gain, level + gain


def run_chains(lanes: Lanes, energy: ArrayLike, excess: ArrayLike, stops: Stops, *, capacity: ArrayLike,
               start: ArrayLike, efficiency: float, power_w: ArrayLike | None = None) -> ChainRun:
    """The levels along each lane (module notes). ``energy`` and ``excess`` per trip (n,)
    or (n, K) (K draws or trials along a last axis); ``capacity`` and ``start`` per lane
    (L,) or (L, K), or scalars; ``power_w`` per trip (n,) or (n, K) (default the stops')."""
    sl = _Slots(lanes, energy, excess, stops, capacity, start, efficiency, power_w)
    before = np.empty((sl.t_count,) + sl.shape)
    low, after, gain = np.empty_like(before), np.empty_like(before), np.empty_like(before)
    level = sl.start
    for t in range(sl.t_count):
        before[t] = level
        low[t], after[t], gain[t], level = sl.step(t, level)
    return ChainRun(before, low, after, gain)


def duty_minima(lanes: Lanes, duty_of_slot: np.ndarray, last_of_duty: np.ndarray, n_duties: int, energy: ArrayLike,
                excess: ArrayLike, stops: Stops, *, capacity: ArrayLike, start: ArrayLike,
                efficiency: float) -> np.ndarray:
    """Each duty's lowest level (D, ...) along the lanes, without keeping every slot:
    ``duty_of_slot`` (T, L) the duty of each slot, ``last_of_duty`` (T, L) whether the
    slot's trip is its duty's last (:func:`run_chains` otherwise)."""
    sl = _Slots(lanes, energy, excess, stops, capacity, start, efficiency, None)
    out = np.empty((n_duties,) + sl.shape[1:])
    running = np.full(sl.shape, np.inf)
    level = sl.start
    for t in range(sl.t_count):
        low, _, _, level = sl.step(t, level)
        np.minimum(running, low, out=running)
        ends = last_of_duty[t] & sl.valid[t]
        if ends.any():
            out[duty_of_slot[t, ends]] = running[ends]
            running[ends] = np.inf
    return out


def _lane_shape(value: ArrayLike, extra: tuple[int, ...]) -> tuple[int, ...]:
    """A per-lane value's shape for broadcasting against (L, *extra)."""
    s = tuple(int(x) for x in np.shape(value))
    if not s:
        return (1,) * (1 + len(extra))
    return s + (1,) * (1 + len(extra) - len(s))


def _lane_slot(v: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """One slot's per-lane values (L,) or (L, K) against the state's ``shape``."""
    return v.reshape(v.shape + (1,) * (len(shape) - v.ndim))


# ----------------------------------------------------------------------- per duty


@dataclass(frozen=True, eq=False)
class DutyLevels:
    """Per duty (D,) [J or l]: the level at its start (``start``), its lowest inside any of
    its trips (``low``), at its end (``end``, after its last trip), what its stops added
    (``gained``: the stops between its trips, not the rest after it), how many stops
    charged (``charges``); ``first_below`` the first trip (global index) whose lowest
    level is below the duty's ``threshold`` (-1: none)."""

    start: np.ndarray
    low: np.ndarray
    end: np.ndarray
    gained: np.ndarray
    charges: np.ndarray
    first_below: np.ndarray


def duty_levels(bounds: np.ndarray, before: np.ndarray, low: np.ndarray, after: np.ndarray, gain: np.ndarray,
                threshold: ArrayLike) -> DutyLevels:
    """:class:`DutyLevels` from per-trip levels (n,) (:meth:`Lanes.put` of a
    :class:`ChainRun`), duties ``bounds`` (D+1) over the trips; ``threshold`` (D,) or a
    scalar: the level (the reserve) whose first crossing is looked for."""
    first, last = bounds[:-1], bounds[1:] - 1
    n = before.size
    if first.size == 0:
        z = np.zeros(0)
        return DutyLevels(z, z, z, z, z.astype(np.int64), z.astype(np.int64))
    inner = np.ones(n, dtype=bool)
    inner[last] = False  # the stop after a duty's last trip is the rest between duties
    duty = np.repeat(np.arange(first.size), np.diff(bounds))
    thr = np.broadcast_to(np.asarray(threshold, dtype=np.float64), first.shape)[duty]
    below = np.where(low < thr, np.arange(n), n)
    fb = np.minimum.reduceat(below, first)
    return DutyLevels(start=before[first], low=np.minimum.reduceat(low, first), end=after[last],
                      gained=np.add.reduceat(np.where(inner, gain, 0.0), first),
                      charges=np.add.reduceat((inner & (gain > 0)).astype(np.int64), first),
                      first_below=np.where(fb < n, fb, -1))
