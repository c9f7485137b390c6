"""Step 3 of the cleaning: GPS fixes, invalid, stale and jumping ones rejected; the fixes
of a stretch of the log."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cevm.ingest.cleaning.arrays import _nonzero
from cevm.ingest.cleaning.events import RepairEvents
from cevm.ingest.cleaning.geodesy import local_distance_m
from cevm.ingest.cleaning.params import CleanParams
from cevm.ingest.cleaning.plausibility import _short_runs_between_jumps, _steps_over
from cevm.ingest.consumption import chunks


def _valid_fix(lat, lon, hdop, p: CleanParams) -> np.ndarray:
    ok = (
        np.isfinite(lat) & np.isfinite(lon)
        & (np.abs(lat) <= 90) & (np.abs(lon) <= 180)
        & (lat != 0) & (lon != 0)
    )
    if hdop is not None:
        ok &= ~(hdop > p.max_hdop)  # NaN HDOP = unknown = accepted
    return ok


@dataclass
class GpsFixes:
    """The cleaned GPS fixes: the log rows that hold one (``rows``, increasing) and
    which of them have a plausible altitude (``alt_ok``); their values are the log's
    ``lat_deg``, ``lon_deg`` and ``gps_alt_m`` columns (no copies). ``step_m``: the
    distance between consecutive fixes [m] (len - 1), while the row speeds are made."""

    rows: np.ndarray
    alt_ok: np.ndarray
    step_m: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class FixWindow:
    """The fixes of a stretch of the log: times [s], positions [deg], and the times and
    values [m] of those with an altitude."""

    t: np.ndarray
    lat: np.ndarray
    lon: np.ndarray
    alt_t: np.ndarray
    alt: np.ndarray


def _fixes_between(t: np.ndarray, cols: dict, fixes: GpsFixes, t0: float, t1: float) -> FixWindow:
    """The fixes from ``t0`` to ``t1`` [s] (``t`` the log's row times)."""
    r = np.array([np.searchsorted(t, t0, "left"), np.searchsorted(t, t1, "right")], dtype=fixes.rows.dtype)
    a, b = np.searchsorted(fixes.rows, r)  # r in the rows' own dtype: no copy of them to search
    f = fixes.rows[a:b]
    fa = f[fixes.alt_ok[a:b]]
    if not f.size:
        return FixWindow(*(np.empty(0) for _ in range(5)))
    alt = cols["gps_alt_m"][fa] if fa.size else np.empty(0)
    return FixWindow(t[f], cols["lat_deg"][f], cols["lon_deg"][f], t[fa], alt)


def _clean_gps(t, cols, moving, p: CleanParams, ev: RepairEvents) -> tuple[GpsFixes, np.ndarray]:
    """Clean GPS fixes (step 3 of the module docstring): invalid, then stale, then
    jumping fixes rejected. Returns the fixes and a per-row 'stale fix' mask."""
    n = t.size
    empty = np.empty(0, dtype=np.int64)
    stale_rows = np.zeros(n, dtype=bool)
    if "lat_deg" not in cols or "lon_deg" not in cols:
        return GpsFixes(empty, np.zeros(0, dtype=bool)), stale_rows
    lat, lon = cols["lat_deg"], cols["lon_deg"]
    valid = _valid_fix(lat, lon, cols.get("gps_hdop"), p)
    carried = np.isfinite(lat) | np.isfinite(lon)
    ev.add("gps_rejected_invalid", t[carried & ~valid])
    del carried
    f = _nonzero(valid)
    del valid
    if f.size > 1:
        f, stale = _drop_stale_fixes(f, lat, lon, moving)
        stale_rows[stale] = True
        ev.add("gps_rejected_stale", t[stale])
    step_m = np.empty(0)
    if f.size > 1:
        f, step_m = _drop_gps_jumps(f, t, lat, lon, p, ev)
    alt_ok = np.zeros(f.size, dtype=bool)
    if "gps_alt_m" in cols:
        for a, b in chunks(f.size):
            alt = cols["gps_alt_m"][f[a:b]]
            alt_ok[a:b] = np.isfinite(alt) & (alt > -500) & (alt < 9000)
    return GpsFixes(f, alt_ok, step_m), stale_rows


def _drop_stale_fixes(f: np.ndarray, lat, lon, moving) -> tuple[np.ndarray, np.ndarray]:
    """Fix rows ``f`` without the stale ones (exactly the previous fix repeated while
    the vehicle moves: a logger repeating its last value), and the stale rows."""
    rep = np.zeros(f.size - 1, dtype=bool)
    for a, b in chunks(f.size - 1):
        fa, fb = f[a:b], f[a + 1:b + 1]
        rep[a:b] = (lat[fb] == lat[fa]) & (lon[fb] == lon[fa]) & moving[fb]
    return f[np.concatenate(([True], ~rep))], f[1:][rep]


def _fix_steps_m(f: np.ndarray, lat, lon) -> np.ndarray:
    """Distance [m] between consecutive fixes ``f`` (rows of ``lat``, ``lon``)."""
    out = np.empty(f.size - 1)
    for a, b in chunks(f.size - 1):
        fa, fb = f[a:b], f[a + 1:b + 1]
        out[a:b] = local_distance_m(lat[fa], lon[fa], lat[fb], lon[fb])
    return out


def _drop_gps_jumps(f: np.ndarray, t, lat, lon, p: CleanParams, ev: RepairEvents) -> tuple[np.ndarray, np.ndarray]:
    """Fix rows ``f`` (at least two) without outliers, and the distance between
    consecutive kept fixes [m].

    Consecutive fixes farther apart than ``max_speed_mps * dt + gps_jump_tolerance_m``
    cut the fixes into runs; runs of at most ``gps_outlier_max_fixes`` are rejected
    (``gps_rejected_jump``) unless every run is that short; jumps left between kept
    fixes are counted (``gps_unresolved_jumps``)."""
    dist = _fix_steps_m(f, lat, lon)
    jump = _steps_over(f, t, dist, p.max_speed_mps, p.gps_jump_tolerance_m)
    if not jump.any():
        return f, dist
    bad = _short_runs_between_jumps(jump, p.gps_outlier_max_fixes)
    if bad is not None:
        ev.add("gps_rejected_jump", t[f[bad]])
        f = f[~bad]
        if f.size > 1:
            dist = _fix_steps_m(f, lat, lon)
            jump = _steps_over(f, t, dist, p.max_speed_mps, p.gps_jump_tolerance_m)
    if f.size > 1:
        ev.add("gps_unresolved_jumps", t[f[1:][jump]])
        return f, dist
    return f, np.empty(0)
