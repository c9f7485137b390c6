"""Steps 6 to 9 for a batch of trips: from their speed rows to a
:class:`~cevm.ingest.cleaning.params.CleanBatch` of the kept trips (and the records of the
dropped segments), with each trip's quality and measured consumption.

Every step runs over the whole batch at once (:mod:`cevm.ingest.segments`); the values
are those of the same step on each trip alone, bit for bit (sums in numpy's pairwise
order, medians, interpolation and searches within each trip)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from cevm.ingest.cleaning.arrays import _jsonable
from cevm.ingest.cleaning.distance import gps_distance_check, gps_fix_stats, odometer_ratio, trapezoid_distance
from cevm.ingest.cleaning.gps import _fixes_between
from cevm.ingest.cleaning.grid import (
    BatchSpeedRows,
    batch_grid,
    grid_lengths,
    speed_holes_bridged,
    speed_on_grid,
    speed_source_share,
)
from cevm.ingest.cleaning.jitter import positions_on_grid
from cevm.ingest.cleaning.params import CleanBatch, CleanParams
from cevm.ingest.cleaning.rows import CleanedLog
from cevm.ingest.consumption import EnergySourceLike
from cevm.ingest.evidence import EVIDENCE_COLUMNS
from cevm.ingest.measured import measure_trips
from cevm.ingest.segments import bounds_of, ranges, segment_ids, segment_medians


def _dropped(start_s: float, duration_s: float, distance_m: float, lines: tuple[int, int], reason: str) -> dict:
    return _jsonable({
        "start_utc_s": start_s, "duration_s": duration_s, "distance_m": distance_m,
        "first_source_line": lines[0], "last_source_line": lines[1], "reason": reason,
    })


def _take(arrays: Sequence[np.ndarray], bounds: np.ndarray, which: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
    """The segments ``which`` of arrays that share ``bounds``, end to end, and their bounds."""
    lens = np.diff(bounds)[which]
    if which.size == bounds.size - 1:
        return list(arrays), bounds
    rows = ranges(bounds[which], lens)
    return [a[rows] for a in arrays], bounds_of(lens)


def clean_batch(log: CleanedLog, seg: BatchSpeedRows, sources: Sequence[EnergySourceLike],
                p: CleanParams) -> tuple[CleanBatch | None, list[tuple[int, dict]]]:
    """The trips of ``seg`` (steps 6-9 of the module docstring): the kept ones as a
    :class:`CleanBatch` (None if none is kept) and, for each dropped one (too short),
    its place among the batch's trips and its record."""
    b = seg.bounds
    n_rows = np.diff(b)
    t_first, t_last = seg.t[b[:-1]], seg.t[b[1:] - 1]
    glen = grid_lengths(t_first, t_last, n_rows, p.grid_s)
    dropped: list[tuple[int, dict]] = [
        (j, _dropped(float(t_first[j]), float(t_last[j] - t_first[j]), 0.0, seg.lines[j], "shorter than one grid step"))
        for j in np.flatnonzero(glen < 2).tolist()]
    gi = np.flatnonzero(glen >= 2)
    if not gi.size:
        return None, dropped
    gb = bounds_of(glen[gi])
    grid_t = batch_grid(seg, gi, glen[gi], p.grid_s)
    v, stand_holes = speed_on_grid(grid_t, gb, seg, gi, p)
    dist = trapezoid_distance(grid_t, v, gb)
    duration = grid_t[gb[1:] - 1] - grid_t[gb[:-1]]
    dist_end = dist[gb[1:] - 1]
    short = (duration < p.min_duration_s) | (dist_end < p.min_distance_m)
    dropped.extend((int(gi[k]), _dropped(float(grid_t[gb[k]]), float(duration[k]), float(dist_end[k]),
                                         seg.lines[gi[k]],
                                         f"shorter than {p.min_duration_s:g} s or {p.min_distance_m:g} m"))
                   for k in np.flatnonzero(short).tolist())
    dropped.sort(key=lambda d: d[0])
    keep = np.flatnonzero(~short)
    if not keep.size:
        return None, dropped
    trips = gi[keep]
    (grid_t, v, dist), gb = _take((grid_t, v, dist), gb, keep)
    stand_holes = stand_holes[keep]
    return _kept_batch(log, seg, trips, grid_t, gb, v, dist, stand_holes, sources, p), dropped


def _kept_batch(log: CleanedLog, seg: BatchSpeedRows, trips: np.ndarray, grid_t: np.ndarray, gb: np.ndarray,
                v: np.ndarray, dist: np.ndarray, stand_holes: np.ndarray, sources: Sequence[EnergySourceLike],
                p: CleanParams) -> CleanBatch:
    """The kept trips ``trips`` of ``seg`` (grids ``grid_t``, bounds ``gb``, speeds and
    distances made): positions, checks, consumption and quality."""
    m = trips.size
    first, last = gb[:-1], gb[1:] - 1
    g0, g1 = grid_t[first], grid_t[last]
    b = seg.bounds
    s_first, s_last = seg.t[b[trips]], seg.t[b[trips + 1] - 1]
    lo = np.searchsorted(log.t, s_first, side="left")
    hi = np.searchsorted(log.t, s_last, side="right")
    # the fixes the grid's positions may use (1 s more each side than the fill allows)
    fixes = _fixes_between(log.t, log.cols, log.fixes, float(g0[0]) - p.gps_max_fill_s - 1.0,
                           float(g1[-1]) + p.gps_max_fill_s + 1.0)
    pos = positions_on_grid(grid_t, gb, v, fixes, p)
    jitter, gps_m, speed_on_gps = gps_distance_check(pos.lat, pos.lon, dist, gb, pos)
    n_fixes, dropouts = gps_fix_stats(g0, g1, fixes, p)
    del fixes
    holes_bridged, hole_s = speed_holes_bridged(seg, trips, p)
    shares = speed_source_share(seg, trips)
    sid = segment_ids(gb)
    gps_cov = np.bincount(sid, weights=np.isfinite(pos.lat), minlength=m) / np.diff(gb)
    alt_cov = np.bincount(sid, weights=np.isfinite(pos.alt), minlength=m) / np.diff(gb)
    events = {k: (np.searchsorted(tv, s_last, "right") - np.searchsorted(tv, s_first, "left")).tolist()
              for k, tv in log.ev.times.items()}
    weights = _gross_weights(log, lo, hi)
    soc, soc_dt = _start_socs(log, g0, p.start_soc_window_s)
    odo = log.cols.get("odometer_m")
    w = p.consumption.max_gap_s
    consumption = measure_trips(log.t, log.cols, sources, g0, g1, p.consumption)
    qualities, measured = [], []
    for k, j in enumerate(trips.tolist()):
        gt, d = grid_t[first[k]:last[k] + 1], dist[first[k]:last[k] + 1]
        meas, mq = consumption[k]
        measured.append(meas)
        tq = {
            "rows": int(hi[k] - lo[k]),
            "samples": int(gt.size),
            "grid_s": p.grid_s,
            "split_before": seg.split_before[j],
            "split_after": seg.split_after[j],
            **{name: counts[k] for name, counts in events.items()},
            "speed_source": shares[k][0],
            "speed_source_share": shares[k][1],
            "speed_holes_filled": int(holes_bridged[k]),
            "speed_hole_s": float(hole_s[k]),
            "standstill_holes_filled": int(stand_holes[k]),
            "gps_fixes": int(n_fixes[k]),
            "gps_coverage": float(gps_cov[k]),
            "gps_dropouts_filled": int(dropouts[k]),
            "gps_alt_coverage": float(alt_cov[k]) if "gps_alt_m" in log.cols else 0.0,
            "jitter_frozen_samples": int(pos.frozen[k]),
            "jitter_removed_m": float(jitter[k]),
            "distance_speed_m": float(d[-1]),
            "distance_gps_m": float(gps_m[k]),
            "distance_ratio_speed_vs_gps": float(speed_on_gps[k]) / float(gps_m[k]) if gps_m[k] > 1.0 else None,
            "distance_ratio_speed_vs_odometer": None if odo is None else odometer_ratio(
                log.t, odo, int(lo[k]), int(hi[k]), gt, d),
            "consumption": mq,
        }
        if soc[k] is not None:
            tq["start_soc"] = {"pct": soc[k], "reading_offset_s": soc_dt[k]}
        jumps = log.ev.jumps_between(float(s_first[k]), float(s_last[k])) if log.ev.has_jumps else []
        if jumps:  # a splice the cleaning kept as logged: for calibrate to flag or down-weight the trip
            tq["speed_jumps"] = jumps
        qualities.append(_jsonable(tq))
    names = [c for c in EVIDENCE_COLUMNS if c in log.cols]
    window = np.stack((np.searchsorted(log.t, g0 - w, "left"), np.searchsorted(log.t, g1 + w, "right")), axis=1)
    return CleanBatch(
        bounds=gb, t_abs=grid_t, speed_mps=v, distance_m=dist, lat_deg=pos.lat, lon_deg=pos.lon,
        gps_alt_m=pos.alt, quality=qualities, measured=measured, gross_weight_kg=weights,
        source_lines=[seg.lines[j] for j in trips.tolist()], start_soc_pct=soc,
        row_t=log.t, rows={c: log.cols[c] for c in names}, row_window=window,
    )


def _gross_weights(log: CleanedLog, lo: np.ndarray, hi: np.ndarray) -> list[float | None]:
    """Per trip (its rows ``lo:hi`` of the log): the median of its positive gross-weight
    readings, or None."""
    col = log.cols.get("gross_weight_kg")
    if col is None:
        return [None] * lo.size
    lens = hi - lo
    w = col[ranges(lo, lens)].astype(np.float64, copy=False)
    ids = segment_ids(bounds_of(lens))
    ok = np.isfinite(w) & (w > 0)
    med = segment_medians(w[ok], ids[ok], lo.size)
    return [None if np.isnan(x) else x for x in med.tolist()]


def _start_socs(log: CleanedLog, t0: np.ndarray, window_s: float) -> tuple[list, list]:
    """Per trip starting at ``t0`` [s, UTC]: the state of charge [%] logged at its start
    (the reading at or last before it within ``window_s``, else the first within
    ``window_s`` after it) and the reading's time from ``t0`` [s]; None where the log has
    no reading there."""
    soc = log.cols.get("soc_pct")
    if soc is None:
        return [None] * t0.size, [None] * t0.size
    a = np.searchsorted(log.t, t0 - window_s, "left")
    b = np.searchsorted(log.t, t0 + window_s, "right")
    lo, hi = int(a.min()), int(b.max())
    f = np.flatnonzero(np.isfinite(soc[lo:hi])) + lo  # rows with a reading
    ft = log.t[f]
    k = np.searchsorted(ft, t0, side="right") - 1  # the last reading at or before t0
    before = (k >= 0) & (f[np.maximum(k, 0)] >= a) if f.size else np.zeros(t0.size, dtype=bool)
    after = ~before & (k + 1 < f.size) & (f[np.minimum(k + 1, max(f.size - 1, 0))] < b) if f.size \
        else np.zeros(t0.size, dtype=bool)
    pct: list[float | None] = []
    dt: list[float | None] = []
    for i in range(t0.size):
        r = int(f[k[i]]) if before[i] else (int(f[k[i] + 1]) if after[i] else None)
        if r is None:
            pct.append(None)
            dt.append(None)
        else:
            pct.append(float(np.float64(soc[r])))
            dt.append(float(log.t[r] - t0[i]))
    return pct, dt
