"""A vehicle's logged trips grouped into duties, and the stops between them (pure).

A *duty* is what one vehicle did between two long rests: its trips in time order and
the stops between them. Two rules (:data:`DUTY_RULES`):

- ``gap`` (the default): a new duty starts after a stop of at least ``gap_s``
  (:data:`DEFAULT_DUTY_GAP_H` hours). A night trunk that leaves at 23:45 and is back
  at 02:00 is one duty, not two halves of two calendar days.
- ``day``: a new duty starts with each calendar day of the trips' starts (a day number
  per trip, computed in the user's time zone at the edge: the core takes integers).
- ``given``: the caller says each trip's duty (an integer per trip, the same for a duty's
  trips, which lie together, sorted by start within it): a timetable's blocks, which run
  at the same time on different vehicles, as the duties of one run. The stop after a
  duty's last trip is NaN (the next duty is another vehicle's).

Trips are taken sorted by their start. A stop's *dwell* is the time from a trip's end
to the next trip's start (0 where logged trips overlap: a clock step, a split log);
the trip that ended latest decides, so that a short trip inside a long one does not
open a long false stop.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

#: The rules of :func:`group_duties`.
DUTY_RULES = ("gap", "day", "given")

#: Default stop [h] that ends a duty. Longer than any break inside a working day: the
#: EU drivers' hours rules (Regulation (EC) 561/2006) ask a 45-minute break after 4.5 h
#: of driving, and bus split shifts pause 2-4 h; shorter than the shortest daily rest
#: the same rules allow (9 h reduced, 11 h regular), so that every night's rest ends a
#: duty. Trips of a night shift that crosses midnight stay one duty (a calendar day
#: would cut it in two).
DEFAULT_DUTY_GAP_H = 6.0


@dataclass(frozen=True, eq=False)
class Duties:
    """Trips (sorted by start) grouped into D duties.

    ``bounds`` (D+1,): duty d holds trips ``bounds[d]:bounds[d+1]``; ``dwell_s`` (n,):
    the stop after each trip [s] until the next trip (of the same duty, or the next
    duty's first for a duty's last trip: the rest between duties); NaN after the very
    last trip."""

    bounds: np.ndarray
    dwell_s: np.ndarray

    @property
    def n(self) -> int:
        """Number of duties."""
        return int(self.bounds.size - 1)

    @property
    def n_trips(self) -> int:
        return int(self.bounds[-1])

    @property
    def sizes(self) -> np.ndarray:
        """Trips per duty (D,)."""
        return np.diff(self.bounds)

    @property
    def duty_of_trip(self) -> np.ndarray:
        """The duty of each trip (n,)."""
        return np.repeat(np.arange(self.n), self.sizes)

    @property
    def first(self) -> np.ndarray:
        """Each duty's first trip (D,)."""
        return self.bounds[:-1]

    @property
    def last(self) -> np.ndarray:
        """Each duty's last trip (D,)."""
        return self.bounds[1:] - 1

    @property
    def last_of_duty(self) -> np.ndarray:
        """Whether each trip is its duty's last (n,): the stop after it is a rest between
        duties."""
        out = np.zeros(self.n_trips, dtype=bool)
        out[self.last] = True
        return out


#: A trip lying more than this share of its duration inside earlier trips of its vehicle
#: is the same driving logged twice (two loggers on one vehicle, one log under two names):
#: a vehicle drives one trip at a time, while a clock step or a split log overlaps its
#: neighbour by seconds.
DUPLICATE_OVERLAP_SHARE = 0.5


def logged_twice(start_s: ArrayLike, end_s: ArrayLike, share: float = DUPLICATE_OVERLAP_SHARE) -> np.ndarray:
    """Which trips (sorted by start) lie more than ``share`` of their duration inside the
    trips before them (the latest end so far): the same driving logged again, to be
    counted once. A trip of no duration is never one."""
    start = np.asarray(start_s, dtype=np.float64)
    end = np.asarray(end_s, dtype=np.float64)
    out = np.zeros(start.size, dtype=bool)
    if start.size > 1:
        before = np.maximum.accumulate(end)[:-1]
        inside = np.minimum(end[1:], before) - start[1:]
        dur = end[1:] - start[1:]
        out[1:] = (dur > 0) & (inside > share * dur)
    return out


def stop_dwell_s(start_s: ArrayLike, end_s: ArrayLike) -> np.ndarray:
    """The stop after each trip [s] (trips sorted by start): the next trip's start less
    the latest end so far, never negative; NaN after the last trip."""
    start = np.asarray(start_s, dtype=np.float64)
    end = np.maximum.accumulate(np.asarray(end_s, dtype=np.float64)) if start.size else np.zeros(0)
    dwell = np.full(start.size, np.nan)
    if start.size > 1:
        dwell[:-1] = np.maximum(start[1:] - end[:-1], 0.0)
    return dwell


def group_duties(start_s: ArrayLike, end_s: ArrayLike, *, rule: str = "gap", gap_s: float = DEFAULT_DUTY_GAP_H * 3600.0,
                 day: ArrayLike | None = None) -> Duties:
    """Group trips sorted by ``start_s`` [s] (ending at ``end_s``) into duties by
    ``rule`` (:data:`DUTY_RULES`): ``"gap"``, a new duty after a stop of at least
    ``gap_s`` [s]; ``"day"``, a new duty at each change of ``day`` (an integer per
    trip, non-decreasing: the calendar day of the trip's start in the chosen zone);
    ``"given"``, ``day`` is each trip's duty (module notes)."""
    start = np.asarray(start_s, dtype=np.float64)
    if rule == "given":
        return _given_duties(start, np.asarray(end_s, dtype=np.float64), day)
    if start.size and np.any(np.diff(start) < 0):
        raise ValueError("trips must be sorted by their start")
    dwell = stop_dwell_s(start, end_s)
    n = start.size
    if rule == "gap":
        if not gap_s > 0:
            raise ValueError(f"the duty gap must be > 0 s, got {gap_s!r}")
        cut = dwell[:-1] >= gap_s if n else np.zeros(0, dtype=bool)
    elif rule == "day":
        if day is None:
            raise ValueError("rule 'day' needs each trip's day")
        d = np.asarray(day)
        if d.shape != start.shape:
            raise ValueError("one day per trip")
        cut = d[1:] != d[:-1] if n else np.zeros(0, dtype=bool)
    else:
        raise ValueError(f"duty rule must be one of {DUTY_RULES}, not {rule!r}")
    bounds = np.concatenate([[0], np.flatnonzero(cut) + 1, [n]]) if n else np.zeros(1, dtype=np.int64)
    return Duties(bounds=bounds.astype(np.int64), dwell_s=dwell)


def _given_duties(start: np.ndarray, end: np.ndarray, duty: ArrayLike | None) -> Duties:
    """Duties as the caller gives them (rule ``given``): a new duty at each change of
    ``duty``; the stops inside each duty as :func:`stop_dwell_s` finds them, NaN after a
    duty's last trip."""
    if duty is None:
        raise ValueError("rule 'given' needs each trip's duty")
    d = np.asarray(duty)
    if d.shape != start.shape:
        raise ValueError("one duty per trip")
    n = start.size
    cut = np.flatnonzero(d[1:] != d[:-1]) + 1 if n else np.zeros(0, dtype=np.int64)
    bounds = np.concatenate([[0], cut, [n]]).astype(np.int64) if n else np.zeros(1, dtype=np.int64)
    if np.unique(d[bounds[:-1]]).size != bounds.size - 1:
        raise ValueError("a duty's trips must lie together")
    dwell = np.full(n, np.nan)
    for a, b in zip(bounds[:-1].tolist(), bounds[1:].tolist(), strict=True):  # duties (hundreds), vectorised inside
        if np.any(np.diff(start[a:b]) < 0):
            raise ValueError("trips must be sorted by their start within a duty")
        dwell[a:b] = stop_dwell_s(start[a:b], end[a:b])
    return Duties(bounds=bounds, dwell_s=dwell)
