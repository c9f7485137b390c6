"""Step 8 of the cleaning: positions on the grid, each stop frozen at one position (GPS
jitter at standstill makes no distance or elevation wiggle)."""

from __future__ import annotations

import numpy as np

from cevm.ingest.cleaning.arrays import _group_median, _runs
from cevm.ingest.cleaning.geodesy import local_distance_m
from cevm.ingest.cleaning.gps import FixWindow
from cevm.ingest.cleaning.params import CleanParams
from cevm.ingest.consumption import _interp_limited


def _freeze_standstill(v, arrays, p: CleanParams):
    """Hold one position per stop: every sample of a standstill run (speed <=
    ``standstill_mps``) gets the median of the run's known values."""
    st = v <= p.standstill_mps
    first, _ = _runs(st)
    if first.size == 0:
        return arrays, 0
    starts = np.zeros(v.size, dtype=np.int64)
    starts[first] = 1
    run = (np.cumsum(starts) - 1)[st]
    out = []
    for a in arrays:
        b = a.copy()
        b[st] = _group_median(a[st], run, first.size)[run]
        out.append(b)
    return out, int(st.sum())


def _positions_on_grid(grid_t: np.ndarray, v: np.ndarray, fixes: FixWindow, p: CleanParams):
    """Positions and GPS altitude at the grid times: fixes interpolated over at most
    ``gps_max_fill_s`` (dropouts filled), NaN beyond; each stop frozen at the median of
    its samples. ``fixes``: the fixes from at least ``gps_max_fill_s`` before the grid
    to as long after it (the only ones the interpolation may use). Returns (lat, lon,
    alt, frozen samples, the raw GPS steps [m] at standstill before freezing, and their
    step indices)."""
    lat, lon = _interp_limited(grid_t, fixes.t, fixes.lat, p.gps_max_fill_s, fixes.lon)
    alt = _interp_limited(grid_t, fixes.alt_t, fixes.alt, p.gps_max_fill_s)
    still = (v[1:] <= p.standstill_mps) & (v[:-1] <= p.standstill_mps)
    si = np.flatnonzero(still)
    raw_still = local_distance_m(lat[si], lon[si], lat[si + 1], lon[si + 1])
    (lat, lon, alt), frozen = _freeze_standstill(v, [lat, lon, alt], p)
    return lat, lon, alt, frozen, raw_still, si
