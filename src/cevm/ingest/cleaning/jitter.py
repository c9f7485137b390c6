"""Step 8 of the cleaning for a batch of trips: positions on the grid, each stop frozen
at one position (GPS jitter at standstill makes no distance or elevation wiggle)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cevm.ingest.cleaning.arrays import _runs
from cevm.ingest.cleaning.geodesy import local_distance_m
from cevm.ingest.cleaning.gps import FixWindow
from cevm.ingest.cleaning.params import CleanParams
from cevm.ingest.consumption import interp_limited
from cevm.ingest.segments import segment_ids, segment_medians


@dataclass(frozen=True, eq=False)
class Positions:
    """The positions of a batch's trips on their grids (frozen at stops), end to end,
    and per trip the samples frozen; the raw GPS steps [m] at standstill before
    freezing, with the step (its first sample) of each."""

    lat: np.ndarray
    lon: np.ndarray
    alt: np.ndarray
    frozen: np.ndarray
    raw_still: np.ndarray
    still_at: np.ndarray


def positions_on_grid(grid_t: np.ndarray, gb: np.ndarray, v: np.ndarray, fixes: FixWindow,
                      p: CleanParams) -> Positions:
    """Positions and GPS altitude at the grid times of a batch's trips (grid bounds
    ``gb``): fixes interpolated over at most ``gps_max_fill_s`` (dropouts filled), NaN
    beyond; each stop frozen at the median of its samples. ``fixes``: the fixes from at
    least ``gps_max_fill_s`` before the batch's first grid time to as long after its last
    (the interpolation at a grid time uses two fixes at most ``gps_max_fill_s`` apart,
    both within that reach: the same values as with each trip's own fixes)."""
    lat, lon = interp_limited(grid_t, fixes.t, fixes.lat, p.gps_max_fill_s, fixes.lon)
    alt = interp_limited(grid_t, fixes.alt_t, fixes.alt, p.gps_max_fill_s)
    st = v <= p.standstill_mps
    inner = np.ones(max(v.size - 1, 0), dtype=bool)  # steps within a trip
    inner[gb[1:-1] - 1] = False
    still = st[1:] & st[:-1] & inner
    si = np.flatnonzero(still)
    raw_still = local_distance_m(lat[si], lon[si], lat[si + 1], lon[si + 1])
    breaks = np.zeros(v.size, dtype=bool)
    breaks[gb[:-1][gb[:-1] < v.size]] = True  # a stop does not run over into the next trip
    first, _ = _runs(st, breaks)
    frozen = np.zeros(gb.size - 1, dtype=np.int64)
    if first.size:
        starts = np.zeros(v.size, dtype=np.int64)
        starts[first] = 1
        run = (np.cumsum(starts) - 1)[st]
        for a in (lat, lon, alt):
            a[st] = segment_medians(a[st], run, first.size, finite_only=True, plain=True)[run]
        frozen = np.bincount(segment_ids(gb)[st], minlength=gb.size - 1)
    return Positions(lat, lon, alt, frozen, raw_still, si)
