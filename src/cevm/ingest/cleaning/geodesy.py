"""Distances on the WGS84 ellipsoid: a fast local formula for short steps, pyproj's
geodesic for long ones."""

from __future__ import annotations

import math

import numpy as np
from pyproj import Geod

from cevm.ingest import consumption
from cevm.ingest.consumption import chunks

_GEOD = Geod(ellps="WGS84")


_WGS84_A_M = 6378137.0


_WGS84_F = 1.0 / 298.257223563


_WGS84_E2 = _WGS84_F * (2.0 - _WGS84_F)


_RAD = math.pi / 180.0


def local_distance_m(lat1, lon1, lat2, lon2) -> np.ndarray:
    """Distance [m] between points [deg] by the local ellipsoidal (WGS84) approximation.

    sqrt((M dphi)^2 + (N cos(phi) dlambda)^2) with M, N the meridian and prime-vertical
    radii of curvature at the mid latitude: within 4e-8 of the geodesic under 1 km,
    fast (pure numpy). Longitude differences are wrapped to [-180, 180). Long 1-D
    arrays are done :data:`~cevm.ingest.consumption.CHUNK_ROWS` at a time (bounded
    temporaries).
    """
    lat1, lon1, lat2, lon2 = (np.asarray(a, dtype=float) for a in (lat1, lon1, lat2, lon2))
    n = lat1.size
    if lat1.ndim == 1 and n > consumption.CHUNK_ROWS and all(a.shape == lat1.shape for a in (lon1, lat2, lon2)):
        out = np.empty(n)
        for a, b in chunks(n):
            out[a:b] = _local_distance_m(lat1[a:b], lon1[a:b], lat2[a:b], lon2[a:b])
        return out
    return _local_distance_m(lat1, lon1, lat2, lon2)


def _local_distance_m(lat1, lon1, lat2, lon2) -> np.ndarray:
    s = np.sin((0.5 * _RAD) * (lat1 + lat2))
    s2 = s * s
    w2 = 1.0 - _WGS84_E2 * s2
    n_m = _WGS84_A_M / np.sqrt(w2)
    m_m = n_m * (1.0 - _WGS84_E2) / w2
    dlon = lon2 - lon1
    wrap = np.abs(dlon) > 180.0  # across the antimeridian (rare: wrapped only there)
    if wrap.any():
        dlon = np.where(wrap, (dlon + 180.0) % 360.0 - 180.0, dlon)
    east = n_m * np.sqrt(1.0 - s2) * (_RAD * dlon)  # cos(phi) >= 0 for |phi| <= 90 deg
    north = m_m * (_RAD * (lat2 - lat1))
    return np.sqrt(north * north + east * east)


#: Steps at least this long [m] are measured with pyproj's geodesic; shorter ones with
#: :func:`local_distance_m`, which agrees with it within 4e-8 (relative) below 1 km and
#: costs a tenth of a pyproj call (0.35 us per step, a third of the ingest budget).
GEODESIC_MIN_STEP_M = 1000.0


def geodesic_steps_m(lat_deg: np.ndarray, lon_deg: np.ndarray) -> np.ndarray:
    """Geodesic length [m] of each step of a track on the WGS84 ellipsoid, len - 1.

    pyproj ``Geod(ellps="WGS84").inv`` for steps of :data:`GEODESIC_MIN_STEP_M` or more,
    the local ellipsoidal formula (same result within 4e-8) below. Steps with an unknown
    end are NaN; steps that do not move are exactly 0.
    """
    lat = np.asarray(lat_deg, dtype=float)
    lon = np.asarray(lon_deg, dtype=float)
    if lat.size < 2:
        return np.empty(0)
    out = local_distance_m(lat[:-1], lon[:-1], lat[1:], lon[1:])
    moved = (lat[1:] != lat[:-1]) | (lon[1:] != lon[:-1])
    out[~moved] = 0.0
    out[~(np.isfinite(out))] = np.nan
    long_ = np.flatnonzero(out >= GEODESIC_MIN_STEP_M)
    if long_.size:
        _, _, d = _GEOD.inv(lon[long_], lat[long_], lon[long_ + 1], lat[long_ + 1])
        out[long_] = d
    return out
