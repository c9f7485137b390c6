"""Where a scheduled trip runs (pure): its shape resampled along the geodesic, its stops
placed along it, the unit of the feed's ``shape_dist_traveled`` found, straight lines
between stops where the feed has no shape, and the times the feed leaves out between timed
stops.

Distances are geodesic on the WGS84 ellipsoid (pyproj ``Geod``). GTFS leaves the unit of
``shape_dist_traveled`` to the publisher (metres, kilometres, feet, miles are all in use);
:func:`detect_unit` takes the one that makes the shape's own distances closest to its
geodesic length, and refuses to guess when none is within :data:`UNIT_TOLERANCE` (a
feed's distances are along its own polyline, so they agree with the geodesic to a few per
cent). A stop is placed by its ``shape_dist_traveled`` mapped through the shape's (its
distances against the geodesic ones at its points), else projected onto the shape in the
stops' order (:func:`project_in_order`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pyproj import Geod

_GEOD = Geod(ellps="WGS84")

#: The units of shape_dist_traveled in use, metres per unit.
UNITS = {"m": 1.0, "km": 1000.0, "ft": 0.3048, "mi": 1609.344}
#: A unit is taken when the shape's distances in it are within this share of the
#: shape's geodesic length (a polyline's own length and a publisher's road distances
#: differ by a few per cent; the units differ by factors of 3.28 and more).
UNIT_TOLERANCE = 0.15
#: Step of a resampled shape [m]: the DSM's road profile is built on a 5 m grid (ingest's
#: ``grid_step_m``); 10 m samples it finely enough for its 40 m median window.
RESAMPLE_STEP_M = 10.0
#: Earth's mean radius [m], for the local plane a stop is projected in.
_R = 6371008.8


def segment_lengths_m(lat: np.ndarray, lon: np.ndarray) -> np.ndarray:
    """The geodesic length of each step of a polyline [m], len - 1."""
    lat = np.asarray(lat, dtype=np.float64)
    lon = np.asarray(lon, dtype=np.float64)
    if lat.size < 2:
        return np.zeros(0)
    _, _, d = _GEOD.inv(lon[:-1], lat[:-1], lon[1:], lat[1:])
    return np.asarray(d, dtype=np.float64)


def cumulative_m(lat: np.ndarray, lon: np.ndarray) -> np.ndarray:
    """Cumulative geodesic distance along a polyline from its first point [m]."""
    return np.concatenate([[0.0], np.cumsum(segment_lengths_m(lat, lon))])


def geodesic_m(lat1, lon1, lat2, lon2) -> np.ndarray:
    """Geodesic distance between points [m] (arrays broadcast)."""
    a, b, c, d = np.broadcast_arrays(*(np.asarray(x, dtype=np.float64) for x in (lat1, lon1, lat2, lon2)))
    _, _, dist = _GEOD.inv(b, a, d, c)
    return np.asarray(dist, dtype=np.float64)


def detect_unit(feed_length: float, geodesic_length_m: float) -> tuple[str, float] | None:
    """The unit of a feed distance ``feed_length`` covering a geodesic ``geodesic_length_m``
    (:data:`UNITS`: name and metres per unit), or None when none is within
    :data:`UNIT_TOLERANCE` (or the lengths are too short to tell)."""
    if not (feed_length > 0 and geodesic_length_m > 50.0):
        return None
    name, f = min(UNITS.items(), key=lambda kv: abs(np.log(feed_length * kv[1] / geodesic_length_m)))
    if abs(feed_length * f / geodesic_length_m - 1.0) > UNIT_TOLERANCE:
        return None
    return name, f


@dataclass(frozen=True, eq=False)
class Shape:
    """A polyline resampled every ``step_m`` along its geodesic: ``dist_m`` (from its first
    point), ``lat``, ``lon``; ``point_m`` the geodesic distance of the feed's own points
    and ``feed_dist`` their shape_dist_traveled (NaN: none); ``unit`` (name, metres per
    unit) of the feed's distances, None when not found; ``source`` what the geometry is
    ("shape" or "straight lines between stops")."""

    dist_m: np.ndarray
    lat: np.ndarray
    lon: np.ndarray
    point_m: np.ndarray
    point_lat: np.ndarray
    point_lon: np.ndarray
    feed_dist: np.ndarray
    unit: tuple[str, float] | None
    source: str = "shape"

    @property
    def length_m(self) -> float:
        return float(self.dist_m[-1]) if self.dist_m.size else 0.0


def resample(lat: np.ndarray, lon: np.ndarray, feed_dist: np.ndarray | None = None, *,
             step_m: float = RESAMPLE_STEP_M, source: str = "shape") -> Shape:
    """A shape's points (in sequence order) resampled every ``step_m`` along the geodesic
    (the points themselves kept), its distance unit detected from ``feed_dist``."""
    lat = np.asarray(lat, dtype=np.float64)
    lon = np.asarray(lon, dtype=np.float64)
    pm = cumulative_m(lat, lon)
    fd = np.full(lat.size, np.nan) if feed_dist is None else np.asarray(feed_dist, dtype=np.float64)
    length = float(pm[-1]) if pm.size else 0.0
    grid = np.union1d(np.arange(0.0, length, step_m), pm) if length > 0 else pm.copy()
    # a point's latitude and longitude linear in distance between the feed's points (a
    # step of at most a few hundred metres: the chord and the geodesic agree to a millimetre)
    glat = np.interp(grid, pm, lat) if pm.size else grid
    glon = np.interp(grid, pm, lon) if pm.size else grid
    finite = np.isfinite(fd)
    unit = None
    if finite.sum() >= 2:
        unit = detect_unit(float(fd[finite].max() - fd[finite].min()), float(pm[finite].max() - pm[finite].min()))
    return Shape(grid, glat, glon, pm, lat, lon, fd, unit, source)


def _local_xy(lat: np.ndarray, lon: np.ndarray, lat0: float, lon0: float) -> tuple[np.ndarray, np.ndarray]:
    k = np.cos(np.radians(lat0))
    return np.radians(lon - lon0) * k * _R, np.radians(lat - lat0) * _R


#: A stop is projected on the first part of the shape (after the stop before it) that
#: comes within this much of the nearest part [m]: a loop passing the stop twice takes the
#: pass in the stops' order, not the nearest.
PROJECTION_SLACK_M = 25.0


def project_in_order(shape: Shape, stop_lat: np.ndarray, stop_lon: np.ndarray) -> np.ndarray:
    """Each stop's distance along ``shape`` [m], projected in the stops' order: the stop's
    foot on the shape at or after the previous stop's, on the first stretch within
    :data:`PROJECTION_SLACK_M` of the nearest (a loop is followed in order)."""
    lat, lon = shape.point_lat, shape.point_lon
    if lat.size < 2:
        return np.zeros(np.size(stop_lat))
    lat0, lon0 = float(lat.mean()), float(lon.mean())
    x, y = _local_xy(lat, lon, lat0, lon0)
    sx, sy = _local_xy(np.asarray(stop_lat, dtype=np.float64), np.asarray(stop_lon, dtype=np.float64), lat0, lon0)
    ax, ay, bx, by = x[:-1], y[:-1], x[1:], y[1:]
    dx, dy = bx - ax, by - ay
    seg2 = np.maximum(dx * dx + dy * dy, 1e-12)
    planar = np.sqrt(seg2)
    scale = np.where(planar > 1e-6, np.diff(shape.point_m) / planar, 1.0)  # plane to geodesic, per step
    out = np.empty(sx.size)
    prev = 0.0
    for k in range(sx.size):  # a trip's stops (tens), one vectorised pass over the shape each
        t = np.clip(((sx[k] - ax) * dx + (sy[k] - ay) * dy) / seg2, 0.0, 1.0)
        px, py = ax + t * dx, ay + t * dy
        dist = np.hypot(px - sx[k], py - sy[k])
        along = shape.point_m[:-1] + t * planar * scale
        ahead = along >= prev - 1.0
        if not ahead.any():
            out[k] = prev
            continue
        best = dist[ahead].min()
        first = np.flatnonzero(ahead & (dist <= best + PROJECTION_SLACK_M))[0]
        out[k] = max(float(along[first]), prev)
        prev = out[k]
    return out


def place_stops(shape: Shape, stop_lat: np.ndarray, stop_lon: np.ndarray,
                stop_feed_dist: np.ndarray) -> tuple[np.ndarray, str]:
    """The stops' distances along ``shape`` [m] and how they were placed: by their
    shape_dist_traveled (through the shape's own distances where it has them, else in the
    unit detected from the stops' span), else projected in order."""
    fd = np.asarray(stop_feed_dist, dtype=np.float64)
    if shape.source != "shape":
        return cumulative_m(stop_lat, stop_lon), "straight lines between stops (no shape)"
    if np.all(np.isfinite(fd)) and np.all(np.diff(fd) >= 0):
        pf = shape.feed_dist
        ok = np.isfinite(pf)
        if ok.sum() >= 2 and shape.unit is not None and np.all(np.diff(pf[ok]) >= 0):
            d = np.interp(fd, pf[ok], shape.point_m[ok])
            return d, f"shape_dist_traveled ({shape.unit[0]})"
        span_geo = project_in_order(shape, stop_lat[[0, -1]], stop_lon[[0, -1]])
        unit = detect_unit(float(fd[-1] - fd[0]), float(span_geo[-1] - span_geo[0]))
        if unit is not None:
            d = span_geo[0] + (fd - fd[0]) * unit[1]
            return np.clip(d, 0.0, shape.length_m), f"shape_dist_traveled ({unit[0]})"
    return project_in_order(shape, stop_lat, stop_lon), "projected onto the shape"


def straight_shape(stop_lat: np.ndarray, stop_lon: np.ndarray, *, step_m: float = RESAMPLE_STEP_M) -> Shape:
    """Straight lines between the stops, as a shape (a feed without shapes)."""
    return resample(stop_lat, stop_lon, None, step_m=step_m, source="straight lines between stops")


def fill_times(stop_dist_m: np.ndarray, arrival_s: np.ndarray, departure_s: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
    """Arrival and departure at every stop [s]: an untimed stop (NaN) interpolated
    linearly in distance between the timed stops around it (GTFS's rule for stops
    without times); the first and last must be timed."""
    arr = np.asarray(arrival_s, dtype=np.float64).copy()
    dep = np.asarray(departure_s, dtype=np.float64).copy()
    timed = np.isfinite(arr)
    if timed.all():
        return arr, dep
    d = np.asarray(stop_dist_m, dtype=np.float64)
    # between two timed stops, from the earlier's departure to the later's arrival
    t_dep, t_arr = dep[timed], arr[timed]
    d_t = d[timed]
    k = np.clip(np.searchsorted(d_t, d, side="right") - 1, 0, d_t.size - 2)
    span = np.maximum(d_t[k + 1] - d_t[k], 1e-9)
    share = np.clip((d - d_t[k]) / span, 0.0, 1.0)
    t = t_dep[k] + share * (t_arr[k + 1] - t_dep[k])
    arr[~timed] = t[~timed]
    dep[~timed] = t[~timed]
    return arr, dep


def profile_between(dist_m: np.ndarray, elev_m: np.ndarray, start_m: float, end_m: float
                    ) -> tuple[np.ndarray, np.ndarray]:
    """A shape's elevation profile from ``start_m`` to ``end_m`` along it, its distance
    counted from ``start_m`` (the trip's first stop)."""
    inside = (dist_m > start_m) & (dist_m < end_m)
    d = np.concatenate([[start_m], dist_m[inside], [end_m]])
    z = np.interp(d, dist_m, elev_m)
    return d - start_m, z


def ascent_m(elev_m: np.ndarray) -> float:
    """The sum of the rises of a profile [m]."""
    return float(np.clip(np.diff(np.asarray(elev_m, dtype=np.float64)), 0.0, None).sum()) if np.size(elev_m) else 0.0
