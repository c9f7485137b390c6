"""Where a vehicle stood: named charging (or refuelling) places, and a depot found from
where it stands overnight (pure).

A stop is *at* a place when the position where the trip before it ended and the
position where the trip after it started (the ones known: a logger may have no fix at
key-off) both lie within the place's radius, and at least one is known; a stop whose
two positions are both unknown is at no place (it is not charged: the row's notes
count such stops).

The depot (:func:`find_depot`) is the position where the vehicle most often stands
between duties: each rest between two duties gives the positions where the duty before
ended and the next began; the depot is the mean of the largest group of those positions
that lie within ``radius_m`` of one of them (the one with the most such neighbours,
the earliest on a tie). It is refused (None) when fewer than :data:`DEPOT_MIN_SHARE`
of the rests with a known position are there: a vehicle without a home base has no
depot to charge at.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

#: Mean Earth radius [m] (IUGG): distances of a few hundred metres to 0.5 %.
EARTH_RADIUS_M = 6_371_008.8

#: Default radius of a place [m]: a stop within it is at the place. A logistics yard
#: spans a few hundred metres, a GPS fix at key-off is within tens of metres; 500 m
#: keeps a vehicle that parked at the far end of its yard at its depot and a customer's
#: site one road further off.
DEFAULT_PLACE_RADIUS_M = 500.0

#: A depot must hold at least this share of a vehicle's rests between duties (with a
#: known position).
DEPOT_MIN_SHARE = 0.5


@dataclass(frozen=True)
class Place:
    """A charging or refuelling place: centre [deg, WGS84] and radius [m], and what it is
    (``name``: "given" or "depot", for the rows)."""

    lat_deg: float
    lon_deg: float
    radius_m: float = DEFAULT_PLACE_RADIUS_M
    name: str = "given"

    def __post_init__(self) -> None:
        if not -90.0 <= self.lat_deg <= 90.0:
            raise ValueError(f"latitude {self.lat_deg:g} is not in [-90, 90] degrees")
        if not -180.0 <= self.lon_deg <= 180.0:
            raise ValueError(f"longitude {self.lon_deg:g} is not in [-180, 180] degrees")
        if not self.radius_m > 0:
            raise ValueError(f"radius {self.radius_m:g} m must be > 0")

    def describe(self) -> str:
        return f"{self.name} {self.lat_deg:.5f},{self.lon_deg:.5f} r {self.radius_m:g} m"


def distance_m(lat1: ArrayLike, lon1: ArrayLike, lat2: ArrayLike, lon2: ArrayLike) -> np.ndarray:
    """Great-circle distance [m] between points [deg] (haversine; arrays broadcast; NaN
    where a position is unknown)."""
    p1, p2 = np.radians(lat1), np.radians(lat2)
    dl = np.radians(np.asarray(lon2, dtype=np.float64) - np.asarray(lon1, dtype=np.float64))
    h = np.sin(0.5 * (p2 - p1)) ** 2 + np.cos(p1) * np.cos(p2) * np.sin(0.5 * dl) ** 2
    return np.asarray(2.0 * EARTH_RADIUS_M * np.arcsin(np.sqrt(np.clip(h, 0.0, 1.0))), dtype=np.float64)


def stops_at(places: Sequence[Place], end_lat: ArrayLike, end_lon: ArrayLike, next_lat: ArrayLike,
             next_lon: ArrayLike) -> np.ndarray:
    """Whether each stop is at one of ``places`` (module notes): the trip before it ended
    at (``end_lat``, ``end_lon``), the trip after it started at (``next_lat``,
    ``next_lon``) [deg], NaN where unknown. Arrays of one length."""
    e_lat, e_lon, n_lat, n_lon = (np.asarray(a, dtype=np.float64) for a in (end_lat, end_lon, next_lat, next_lon))
    known_e = np.isfinite(e_lat) & np.isfinite(e_lon)
    known_n = np.isfinite(n_lat) & np.isfinite(n_lon)
    out = np.zeros(e_lat.shape, dtype=bool)
    for p in places:
        with np.errstate(invalid="ignore"):
            near_e = distance_m(e_lat, e_lon, p.lat_deg, p.lon_deg) <= p.radius_m
            near_n = distance_m(n_lat, n_lon, p.lat_deg, p.lon_deg) <= p.radius_m
        out |= (known_e | known_n) & (near_e | ~known_e) & (near_n | ~known_n)
    return out


@dataclass(frozen=True)
class Depot:
    """A depot found by :func:`find_depot`: the place, how many rests were there and how
    many rests had a known position."""

    place: Place
    rests_there: int
    rests_known: int

    def describe(self) -> str:
        return (f"depot {self.place.lat_deg:.5f},{self.place.lon_deg:.5f} r {self.place.radius_m:g} m "
                f"({self.rests_there} of {self.rests_known} rests)")


def find_depot(lat_deg: ArrayLike, lon_deg: ArrayLike, radius_m: float = DEFAULT_PLACE_RADIUS_M, *,
               min_share: float = DEPOT_MIN_SHARE) -> Depot | None:
    """The depot among the positions [deg] where a vehicle stood between duties (module
    notes), or None: no known position, or its largest group holds less than
    ``min_share`` of them."""
    lat = np.asarray(lat_deg, dtype=np.float64)
    lon = np.asarray(lon_deg, dtype=np.float64)
    known = np.isfinite(lat) & np.isfinite(lon)
    lat, lon = lat[known], lon[known]
    n = lat.size
    if n == 0:
        return None
    counts = np.empty(n, dtype=np.int64)
    step = max(1, (1 << 20) // n)
    for lo in range(0, n, step):  # n x n distances in bounded chunks
        d = distance_m(lat[lo:lo + step, None], lon[lo:lo + step, None], lat[None, :], lon[None, :])
        counts[lo:lo + step] = np.count_nonzero(d <= radius_m, axis=1)
    best = int(np.argmax(counts))
    near = distance_m(lat[best], lon[best], lat, lon) <= radius_m
    there = int(np.count_nonzero(near))
    if there < min_share * n:
        return None
    return Depot(Place(float(lat[near].mean()), float(lon[near].mean()), radius_m, "depot"), there, n)


def rest_positions(first: ArrayLike, last: ArrayLike, start_lat: ArrayLike, start_lon: ArrayLike, end_lat: ArrayLike,
                   end_lon: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """One position [deg] per rest of a vehicle between its duties (``first``, ``last``:
    each duty's first and last trip, as :class:`~cevm.core.replay.duties.Duties` gives
    them; trip start and end positions, NaN where unknown): where it stood before its
    first duty, between each two duties (where the duty before ended, else where the next
    began), and after its last duty."""
    s_lat, s_lon, e_lat, e_lon = (np.asarray(a, dtype=np.float64) for a in (start_lat, start_lon, end_lat, end_lon))
    first, last = np.asarray(first), np.asarray(last)
    if first.size == 0:
        return np.zeros(0), np.zeros(0)
    end_lat_d, end_lon_d = e_lat[last], e_lon[last]
    next_lat, next_lon = np.append(s_lat[first[1:]], np.nan), np.append(s_lon[first[1:]], np.nan)
    known = np.isfinite(end_lat_d) & np.isfinite(end_lon_d)
    lat = np.concatenate([s_lat[first[:1]], np.where(known, end_lat_d, next_lat)])
    lon = np.concatenate([s_lon[first[:1]], np.where(known, end_lon_d, next_lon)])
    return lat, lon
