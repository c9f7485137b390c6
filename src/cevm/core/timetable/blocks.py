"""A service day's trips grouped into blocks (one vehicle's day), and the empty running a
block needs between them (pure).

A feed's ``block_id`` says which trips one vehicle runs (``block_from = "feed"``). Where a
trip has none, it is chained (:func:`infer_blocks`, ``block_from = "inferred"``): trips in
order of departure, each taken by the block that ended at its first stop (the same stop, or
within :data:`CHAIN_RADIUS_M`) at least ``min_layover_s`` before, the one free latest (the
least idle time; first-fit by the latest end is the usual greedy vehicle-chaining rule), a
new block otherwise. An inferred block is named after its first trip
(``inferred:TRIPID``), so the same schedule on two dates gives the same names.

Between two trips of a block that end and begin apart a *deadhead* runs empty: the
straight-line distance times a detour factor, at a speed (:class:`DeadheadRule`); from a
depot (when one is given) a pull-out before the first trip and a pull-in after the last.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Trips chained into a block end and begin within this distance [m] when their stops
#: differ: the two sides of a terminus, its bays.
CHAIN_RADIUS_M = 150.0
#: Default shortest layover between chained trips [s]: US transit scheduling keeps at
#: least 5 minutes of recovery at a terminus (TCRP Report 135 / Transit Capacity and
#: Quality of Service Manual: layover 5-10 min or 10-15 % of the running time).
DEFAULT_MIN_LAYOVER_S = 300.0
#: Default detour factor of a deadhead (road distance over the straight line): 1.3, the
#: middle of the circuity factors measured on road networks (Ballou, Rahardja and Sakai
#: 2002: 1.17-1.42 between city pairs; about 1.2-1.4 inside cities).
DEFAULT_DETOUR = 1.3
#: Default deadhead speed [m/s]: 30 km/h, an urban bus running empty without stops
#: (service runs 15-20 km/h with its stops; urban car traffic averages 25-35 km/h).
DEFAULT_DEADHEAD_SPEED_MPS = 30.0 / 3.6
#: Ends closer than this [m] need no deadhead (the same terminus).
DEADHEAD_MIN_M = CHAIN_RADIUS_M


@dataclass(frozen=True)
class DeadheadRule:
    """How empty running is estimated: ``detour`` (road over straight line, >= 1),
    ``speed_mps``, the ``depot`` (lat, lon) [deg] or None (no pull-out, pull-in)."""

    detour: float = DEFAULT_DETOUR
    speed_mps: float = DEFAULT_DEADHEAD_SPEED_MPS
    depot: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if not 1.0 <= self.detour <= 5.0:
            raise ValueError(f"deadhead detour {self.detour!r} must be in [1, 5]")
        if not 0.5 <= self.speed_mps <= 40.0:
            raise ValueError(f"deadhead speed {self.speed_mps * 3.6!r} km/h must be in [1.8, 144]")


@dataclass(frozen=True, eq=False)
class Blocks:
    """Blocks of one service day: ``names`` (B,), ``source`` (B,) "feed" or "inferred",
    ``trips`` (list of B index arrays into the day's trips, in order of departure)."""

    names: tuple[str, ...]
    source: tuple[str, ...]
    trips: tuple[np.ndarray, ...]

    @property
    def n(self) -> int:
        return len(self.names)


def infer_blocks(start_s: np.ndarray, end_s: np.ndarray, first_stop: np.ndarray, last_stop: np.ndarray,
                 start_xy: tuple[np.ndarray, np.ndarray], end_xy: tuple[np.ndarray, np.ndarray], *,
                 min_layover_s: float = DEFAULT_MIN_LAYOVER_S, radius_m: float = CHAIN_RADIUS_M
                 ) -> list[list[int]]:
    """Trips chained into blocks (module notes): lists of trip indices. ``start_xy`` and
    ``end_xy`` are the first and last stops' positions in a local plane [m] (the same
    plane for all trips)."""
    order = np.lexsort((end_s, start_s))
    chains: list[list[int]] = []
    free_at = np.zeros(0)
    at_stop = np.zeros(0, dtype=np.int64)
    at_x, at_y = np.zeros(0), np.zeros(0)
    for i in order.tolist():  # a day's trips (thousands), one vectorised test over the open blocks each
        if chains:
            near = (at_stop == first_stop[i]) | (np.hypot(at_x - start_xy[0][i], at_y - start_xy[1][i]) <= radius_m)
            ok = near & (free_at + min_layover_s <= start_s[i])
        else:
            ok = np.zeros(0, dtype=bool)
        if ok.any():
            cand = np.flatnonzero(ok)
            k = int(cand[np.argmax(free_at[cand])])
            chains[k].append(i)
        else:
            chains.append([i])
            k = len(chains) - 1
            free_at = np.append(free_at, 0.0)
            at_stop = np.append(at_stop, 0)
            at_x, at_y = np.append(at_x, 0.0), np.append(at_y, 0.0)
        free_at[k] = end_s[i]
        at_stop[k] = last_stop[i]
        at_x[k], at_y[k] = end_xy[0][i], end_xy[1][i]
    return chains


def day_blocks(trip_id: np.ndarray, block_id: np.ndarray, start_s: np.ndarray, end_s: np.ndarray,
               first_stop: np.ndarray, last_stop: np.ndarray, start_xy: tuple[np.ndarray, np.ndarray],
               end_xy: tuple[np.ndarray, np.ndarray], *, min_layover_s: float = DEFAULT_MIN_LAYOVER_S) -> Blocks:
    """One service day's trips (arrays over them) into blocks: by ``block_id`` ("" none),
    the rest inferred (module notes). Blocks are ordered by their first departure."""
    names: list[str] = []
    source: list[str] = []
    trips: list[np.ndarray] = []
    has = block_id != ""
    if has.any():
        ids, inv = np.unique(block_id[has], return_inverse=True)
        rows = np.flatnonzero(has)
        for b, name in enumerate(ids.tolist()):
            r = rows[inv == b]
            r = r[np.lexsort((end_s[r], start_s[r]))]
            names.append(str(name))
            source.append("feed")
            trips.append(r)
    rest = np.flatnonzero(~has)
    if rest.size:
        sub = (start_xy[0][rest], start_xy[1][rest]), (end_xy[0][rest], end_xy[1][rest])
        for chain in infer_blocks(start_s[rest], end_s[rest], first_stop[rest], last_stop[rest], sub[0], sub[1],
                                  min_layover_s=min_layover_s):
            r = rest[np.asarray(chain, dtype=np.int64)]
            names.append(f"inferred:{trip_id[r[0]]}")
            source.append("inferred")
            trips.append(r)
    first = np.array([start_s[t[0]] for t in trips]) if trips else np.zeros(0)
    order = np.lexsort((np.array(names, dtype=object).astype(str), first)) if trips else np.zeros(0, np.int64)
    return Blocks(tuple(names[k] for k in order), tuple(source[k] for k in order), tuple(trips[k] for k in order))


@dataclass(frozen=True, eq=False)
class Legs:
    """A block's legs in order, revenue trips and empty running (arrays over the legs):
    ``trip`` (the trip's index, -1 for empty running), ``kind`` ("trip", "deadhead",
    "pull-out", "pull-in"), ``start_s``, ``end_s``, ``distance_m`` (empty running: its
    road estimate), start and end positions [deg]; ``late_s`` how much later than the next
    trip's departure empty running would arrive (0: in time; it is run anyway, the next
    trip starting late is not modelled)."""

    trip: np.ndarray
    kind: tuple[str, ...]
    start_s: np.ndarray
    end_s: np.ndarray
    distance_m: np.ndarray
    start_lat: np.ndarray
    start_lon: np.ndarray
    end_lat: np.ndarray
    end_lon: np.ndarray
    late_s: np.ndarray

    @property
    def n(self) -> int:
        return int(self.trip.size)


def block_legs(trips: np.ndarray, start_s: np.ndarray, end_s: np.ndarray, distance_m: np.ndarray,
               start_ll: tuple[np.ndarray, np.ndarray], end_ll: tuple[np.ndarray, np.ndarray],
               straight_m, rule: DeadheadRule) -> Legs:
    """A block's legs (:class:`Legs`): its ``trips`` (indices into the day's arrays) with
    empty running where a trip ends away from the next one's start (more than
    :data:`DEADHEAD_MIN_M`), and a pull-out and pull-in from ``rule.depot``.
    ``straight_m(lat1, lon1, lat2, lon2)`` gives straight-line distances [m] (arrays)."""
    t = np.asarray(trips, dtype=np.int64)
    rows: list[tuple] = []  # (trip, kind, start, end, dist, slat, slon, elat, elon, late)

    def empty(kind: str, lat1: float, lon1: float, lat2: float, lon2: float, at_s: float, by_s: float | None,
              before: bool) -> None:
        d = float(straight_m(np.array([lat1]), np.array([lon1]), np.array([lat2]), np.array([lon2]))[0])
        if d <= DEADHEAD_MIN_M:
            return
        road = d * rule.detour
        dur = road / rule.speed_mps
        start = at_s - dur if before else at_s
        late = max(start + dur - by_s, 0.0) if by_s is not None and not before else 0.0
        rows.append((-1, kind, start, start + dur, road, lat1, lon1, lat2, lon2, late))

    if rule.depot is not None:
        i = int(t[0])
        empty("pull-out", rule.depot[0], rule.depot[1], start_ll[0][i], start_ll[1][i], float(start_s[i]), None, True)
    for k, i in enumerate(t.tolist()):
        rows.append((i, "trip", float(start_s[i]), float(end_s[i]), float(distance_m[i]), start_ll[0][i],
                     start_ll[1][i], end_ll[0][i], end_ll[1][i], 0.0))
        if k + 1 < t.size:
            j = int(t[k + 1])
            empty("deadhead", end_ll[0][i], end_ll[1][i], start_ll[0][j], start_ll[1][j], float(end_s[i]),
                  float(start_s[j]), False)
    if rule.depot is not None:
        i = int(t[-1])
        empty("pull-in", end_ll[0][i], end_ll[1][i], rule.depot[0], rule.depot[1], float(end_s[i]), None, False)
    cols = list(zip(*rows, strict=True))
    f = np.asarray
    return Legs(trip=f(cols[0], dtype=np.int64), kind=tuple(cols[1]), start_s=f(cols[2], dtype=np.float64),
                end_s=f(cols[3], dtype=np.float64), distance_m=f(cols[4], dtype=np.float64),
                start_lat=f(cols[5], dtype=np.float64), start_lon=f(cols[6], dtype=np.float64),
                end_lat=f(cols[7], dtype=np.float64), end_lon=f(cols[8], dtype=np.float64),
                late_s=f(cols[9], dtype=np.float64))
