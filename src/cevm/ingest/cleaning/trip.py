"""Steps 6 to 9 for one trip: from its speed rows to a :class:`~cevm.ingest.cleaning.CleanTrip`
(or the record of a dropped segment), with its quality and measured consumption."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from cevm.ingest.cleaning.arrays import _jsonable
from cevm.ingest.cleaning.distance import (
    _gps_distance_check,
    _gps_fix_stats,
    _odometer_ratio,
    _trapezoid_distance,
)
from cevm.ingest.cleaning.gps import _fixes_between
from cevm.ingest.cleaning.grid import (
    TripSpeedRows,
    _grid,
    _speed_holes_bridged,
    _speed_on_grid,
    _speed_source_share,
)
from cevm.ingest.cleaning.jitter import _positions_on_grid
from cevm.ingest.cleaning.params import CleanParams, CleanTrip
from cevm.ingest.cleaning.rows import CleanedLog
from cevm.ingest.consumption import EnergySourceLike, measure_trip
from cevm.ingest.evidence import EVIDENCE_COLUMNS


def _dropped(start_s: float, duration_s: float, distance_m: float, lines: tuple[int, int], reason: str) -> dict:
    return _jsonable({
        "start_utc_s": start_s, "duration_s": duration_s, "distance_m": distance_m,
        "first_source_line": lines[0], "last_source_line": lines[1], "reason": reason,
    })


def _gross_weight(log: CleanedLog, lo: int, hi: int) -> float | None:
    """Median of the trip's positive gross-weight readings, or None."""
    if "gross_weight_kg" not in log.cols:
        return None
    w = log.cols["gross_weight_kg"][lo:hi].astype(np.float64, copy=False)
    w = w[np.isfinite(w) & (w > 0)]
    return float(np.median(w)) if w.size else None


def _clean_trip(log: CleanedLog, seg: TripSpeedRows, sources: Sequence[EnergySourceLike], p: CleanParams) -> CleanTrip | dict:
    """One trip from its speed rows (steps 6-9 of the module docstring): a
    :class:`CleanTrip`, or the dict of a dropped segment (too short)."""
    lo = int(np.searchsorted(log.t, seg.t[0], "left"))
    hi = int(np.searchsorted(log.t, seg.t[-1], "right"))
    lines = seg.lines
    grid_t = _grid(seg.t, p.grid_s) if seg.t.size > 1 else np.empty(0)
    if grid_t.size < 2:
        return _dropped(float(seg.t[0]), float(seg.t[-1] - seg.t[0]), 0.0, lines, "shorter than one grid step")
    v, standstill_holes = _speed_on_grid(grid_t, seg, p)
    dist = _trapezoid_distance(grid_t, v)
    duration = float(grid_t[-1] - grid_t[0])
    if duration < p.min_duration_s or dist[-1] < p.min_distance_m:
        return _dropped(float(grid_t[0]), duration, float(dist[-1]), lines,
                        f"shorter than {p.min_duration_s:g} s or {p.min_distance_m:g} m")
    # the fixes the grid's positions may use (1 s more each side than the fill allows)
    fixes = _fixes_between(log.t, log.cols, log.fixes, float(grid_t[0]) - p.gps_max_fill_s - 1.0,
                           float(grid_t[-1]) + p.gps_max_fill_s + 1.0)
    lat, lon, alt, frozen, raw_still, si = _positions_on_grid(grid_t, v, fixes, p)
    gps_check = _gps_distance_check(lat, lon, dist, raw_still, si)
    n_fixes, dropouts = _gps_fix_stats(grid_t, fixes, p)
    del fixes
    holes_bridged, hole_s = _speed_holes_bridged(seg, p)
    speed_source, share = _speed_source_share(seg)
    measured, mq = measure_trip(log.t, log.cols, sources, float(grid_t[0]), float(grid_t[-1]), p.consumption)
    rows_t, rows = _evidence_rows(log, float(grid_t[0]), float(grid_t[-1]), p)
    tq = {
        "rows": int(hi - lo),
        "samples": int(grid_t.size),
        "grid_s": p.grid_s,
        "split_before": seg.split_before,
        "split_after": seg.split_after,
        **log.ev.between(float(seg.t[0]), float(seg.t[-1])),
        "speed_source": speed_source,
        "speed_source_share": share,
        "speed_holes_filled": holes_bridged,
        "speed_hole_s": hole_s,
        "standstill_holes_filled": standstill_holes,
        "gps_fixes": n_fixes,
        "gps_coverage": float(np.mean(np.isfinite(lat))),
        "gps_dropouts_filled": dropouts,
        "gps_alt_coverage": float(np.mean(np.isfinite(alt))) if "gps_alt_m" in log.cols else 0.0,
        "jitter_frozen_samples": frozen,
        "jitter_removed_m": gps_check["jitter_removed_m"],
        "distance_speed_m": float(dist[-1]),
        "distance_gps_m": gps_check["distance_gps_m"],
        "distance_ratio_speed_vs_gps": gps_check["distance_ratio_speed_vs_gps"],
        "distance_ratio_speed_vs_odometer": _odometer_ratio(log, lo, hi, grid_t, dist),
        "consumption": mq,
    }
    start_soc, soc_offset_s = _start_soc(log, float(grid_t[0]), p.start_soc_window_s)
    if start_soc is not None:
        tq["start_soc"] = {"pct": start_soc, "reading_offset_s": soc_offset_s}
    jumps = log.ev.jumps_between(float(seg.t[0]), float(seg.t[-1]))
    if jumps:  # a splice the cleaning kept as logged: for calibrate to flag or down-weight the trip
        tq["speed_jumps"] = jumps
    return CleanTrip(
        start_utc_s=float(grid_t[0]),
        time_s=grid_t - grid_t[0],
        speed_mps=v,
        distance_m=dist,
        lat_deg=lat,
        lon_deg=lon,
        gps_alt_m=alt,
        gross_weight_kg=_gross_weight(log, lo, hi),
        measured=measured,
        quality=_jsonable(tq),
        first_source_line=lines[0],
        last_source_line=lines[1],
        rows_t_s=rows_t,
        rows=rows,
        start_soc_pct=start_soc,
    )


def _evidence_rows(log: CleanedLog, t0: float, t1: float, p: CleanParams) -> tuple[np.ndarray, dict]:
    """The log's rows from ``consumption.max_gap_s`` before ``t0`` to as long after
    ``t1``: their times and the evidence columns the log has (views of the log's
    arrays, which nothing writes to; float64 copies of its float32 ones)."""
    names = [c for c in EVIDENCE_COLUMNS if c in log.cols]
    if not names:
        return np.empty(0), {}
    w = p.consumption.max_gap_s
    a = int(np.searchsorted(log.t, t0 - w, "left"))
    b = int(np.searchsorted(log.t, t1 + w, "right"))
    return log.t[a:b], {c: log.cols[c][a:b].astype(np.float64, copy=False) for c in names}


def _start_soc(log: CleanedLog, t0: float, window_s: float) -> tuple[float | None, float | None]:
    """The state of charge [%] logged at ``t0`` [s, UTC]: the reading at or last before it
    within ``window_s``, else the first within ``window_s`` after it; and the reading's
    time from ``t0`` [s]. (None, None) where the log has no reading there."""
    soc = log.cols.get("soc_pct")
    if soc is None:
        return None, None
    a = int(np.searchsorted(log.t, t0 - window_s, "left"))
    b = int(np.searchsorted(log.t, t0 + window_s, "right"))
    t, x = log.t[a:b], soc[a:b].astype(np.float64, copy=False)
    ok = np.isfinite(x)
    before = np.flatnonzero(ok & (t <= t0))
    i = before[-1] if before.size else next(iter(np.flatnonzero(ok & (t > t0))), None)
    if i is None:
        return None, None
    return float(x[i]), float(t[i] - t0)
