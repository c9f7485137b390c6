"""Step 7 of the cleaning: a trip's distance from its speed, checked against the GPS track
and the odometer."""

from __future__ import annotations

import numpy as np

from cevm.ingest.cleaning.geodesy import geodesic_steps_m
from cevm.ingest.cleaning.gps import FixWindow
from cevm.ingest.cleaning.params import CleanParams
from cevm.ingest.cleaning.rows import CleanedLog


def _trapezoid_distance(grid_t: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Cumulative distance [m] from 0: the trapezoidal integral of speed (the CE
    model's r_i = (v_i + v_{i+1}) / 2 dt_i)."""
    return np.concatenate(([0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(grid_t))))


def _gps_distance_check(lat, lon, dist: np.ndarray, raw_still: np.ndarray, si: np.ndarray) -> dict:
    """The speed distance against the geodesic length of the GPS track, on the steps
    where both ends have a position; and the GPS path length that freezing removed."""
    gps_steps = geodesic_steps_m(lat, lon)
    okstep = np.isfinite(gps_steps)
    gps_dist = float(gps_steps[okstep].sum())
    speed_on_gps = float(np.diff(dist)[okstep].sum())
    return {
        "jitter_removed_m": float(np.nansum(raw_still - gps_steps[si])),
        "distance_gps_m": gps_dist,
        "distance_ratio_speed_vs_gps": speed_on_gps / gps_dist if gps_dist > 1.0 else None,
    }


def _gps_fix_stats(grid_t: np.ndarray, fixes: FixWindow, p: CleanParams) -> tuple[int, int]:
    """Fixes inside the trip's grid span (``fixes``: at least those), and the dropouts
    among them that were filled (steps over twice the nominal fix interval, up to
    ``gps_max_fill_s``)."""
    fix_in = (fixes.t >= grid_t[0]) & (fixes.t <= grid_t[-1])
    fdt = np.diff(fixes.t[fix_in])
    if not fdt.size:
        return int(fix_in.sum()), 0
    nominal_fix = float(np.median(fdt))
    return int(fix_in.sum()), int(((fdt > 2 * nominal_fix) & (fdt <= p.gps_max_fill_s)).sum())


def _odometer_ratio(log: CleanedLog, lo: int, hi: int, grid_t: np.ndarray, dist: np.ndarray) -> float | None:
    """Speed distance over odometer distance between the trip's first and last odometer
    readings inside the grid span (None without two readings or odometer progress)."""
    if "odometer_m" not in log.cols:
        return None
    odo_t = log.t[lo:hi]
    odo = log.cols["odometer_m"][lo:hi].astype(np.float64, copy=False)
    ok = np.isfinite(odo) & (odo_t >= grid_t[0]) & (odo_t <= grid_t[-1])
    if ok.sum() < 2:
        return None
    o_t, o_v = odo_t[ok], odo[ok]
    d_odo = float(o_v[-1] - o_v[0])
    d_spd = float(np.interp(o_t[-1], grid_t, dist) - np.interp(o_t[0], grid_t, dist))
    return d_spd / d_odo if d_odo > 0 else None
