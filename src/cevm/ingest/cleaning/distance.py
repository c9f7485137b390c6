"""Step 7 of the cleaning for a batch of trips: each trip's distance from its speed,
checked against the GPS track and the odometer."""

from __future__ import annotations

import numpy as np

from cevm.ingest.cleaning.geodesy import geodesic_steps_m
from cevm.ingest.cleaning.gps import FixWindow
from cevm.ingest.cleaning.jitter import Positions
from cevm.ingest.cleaning.params import CleanParams
from cevm.ingest.segments import bounds_of, ranges, segment_cumsum, segment_ids, segment_medians, segment_sums


def inner_steps(gb: np.ndarray) -> np.ndarray:
    """Which steps (sample i to i + 1) of a batch's samples lie within one trip (not
    from one trip's last sample to the next one's first)."""
    inner = np.ones(max(int(gb[-1]) - 1, 0), dtype=bool)
    inner[gb[1:-1] - 1] = False
    return inner


def trapezoid_distance(grid_t: np.ndarray, v: np.ndarray, gb: np.ndarray) -> np.ndarray:
    """Each trip's cumulative distance [m] from 0: the trapezoidal integral of speed
    (the CE model's r_i = (v_i + v_{i+1}) / 2 dt_i)."""
    inc = (0.5 * (v[1:] + v[:-1]) * np.diff(grid_t))[inner_steps(gb)]
    return segment_cumsum(inc, bounds_of(np.diff(gb) - 1), start_zero=True)


def gps_distance_check(lat: np.ndarray, lon: np.ndarray, dist: np.ndarray, gb: np.ndarray,
                       pos: Positions) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per trip: the GPS path length that freezing removed [m], the geodesic length of
    the GPS track on the steps where both ends have a position [m], and the speed
    distance over those steps [m]."""
    n = gb.size - 1
    gs = geodesic_steps_m(lat, lon)
    inner = inner_steps(gb)
    sid = segment_ids(bounds_of(np.diff(gb) - 1))
    gs_in = gs[inner]
    ok = np.isfinite(gs_in)
    ob = bounds_of(np.bincount(sid[ok], minlength=n))
    gps_m = segment_sums(gs_in[ok], ob)
    speed_on_gps = segment_sums(np.diff(dist)[inner][ok], ob)
    removed = pos.raw_still - gs[pos.still_at]
    removed[np.isnan(removed)] = 0.0  # np.nansum's
    trip_of = np.searchsorted(gb, pos.still_at, side="right") - 1
    jitter = segment_sums(removed, bounds_of(np.bincount(trip_of, minlength=n)))
    return jitter, gps_m, speed_on_gps


def gps_fix_stats(grid_first: np.ndarray, grid_last: np.ndarray, fixes: FixWindow,
                  p: CleanParams) -> tuple[np.ndarray, np.ndarray]:
    """Per trip: the fixes inside its grid span (``fixes``: at least those), and the
    dropouts among them that were filled (steps over twice the trip's median fix
    interval, up to ``gps_max_fill_s``)."""
    i0 = np.searchsorted(fixes.t, grid_first, side="left")
    i1 = np.searchsorted(fixes.t, grid_last, side="right")
    count = i1 - i0
    steps = np.diff(fixes.t)
    lens = np.maximum(count - 1, 0)
    fdt = steps[ranges(i0, lens)]
    ids = segment_ids(bounds_of(lens))
    nominal = segment_medians(fdt, ids, count.size)
    drop = (fdt > 2 * nominal[ids]) & (fdt <= p.gps_max_fill_s)
    return count, np.bincount(ids[drop], minlength=count.size)


def odometer_ratio(t: np.ndarray, odometer: np.ndarray, lo: int, hi: int, grid_t: np.ndarray,
                   dist: np.ndarray) -> float | None:
    """Speed distance over odometer distance between a trip's first and last odometer
    readings inside its grid span (None without two readings or odometer progress);
    ``lo:hi`` the trip's rows of the log (times ``t``)."""
    odo_t = t[lo:hi]
    odo = odometer[lo:hi].astype(np.float64, copy=False)
    ok = np.isfinite(odo) & (odo_t >= grid_t[0]) & (odo_t <= grid_t[-1])
    if ok.sum() < 2:
        return None
    o_t, o_v = odo_t[ok], odo[ok]
    d_odo = float(o_v[-1] - o_v[0])
    d_spd = float(np.interp(o_t[-1], grid_t, dist) - np.interp(o_t[0], grid_t, dist))
    return d_spd / d_odo if d_odo > 0 else None
