"""Step 1 of the cleaning: time outliers, clock steps backwards and forwards (repaired in
file order), then the sort by time."""

from __future__ import annotations

import numpy as np

from cevm.ingest.cleaning.arrays import _let_go
from cevm.ingest.cleaning.events import RepairEvents
from cevm.ingest.cleaning.geodesy import local_distance_m
from cevm.ingest.cleaning.gps import _valid_fix
from cevm.ingest.cleaning.params import CleanParams
from cevm.ingest.cleaning.rows import LogRows
from cevm.ingest.consumption import chunks


def _repair_time(t, line, rows: LogRows, p: CleanParams, ev: RepairEvents):
    """File-order time repairs (step 1 of the module docstring). Returns (t, line,
    info) with rows still in file order, outlier rows removed (from ``rows`` too), times
    shifted at clock steps; an unordered file is returned as it is (it is simply sorted
    afterwards)."""
    n = t.size
    info: dict = {"file_order": "ordered", "clock_step_corrections_s": []}
    if n < 3:
        return t, line, info
    backward, forward = 0, 0
    for a, b in chunks(n - 1):
        dd = np.diff(t[a:b + 1])
        backward += int((dd < 0).sum())
        forward += int((dd > 0).sum())
    info["backward_steps_in_file"] = backward
    if backward > p.unordered_share * (n - 1):
        info["file_order"] = "unordered"
        return t, line, info
    nominal = _median_positive_step(t, forward)
    info["nominal_dt_s"] = nominal
    _let_go(n)
    d = np.diff(t)

    drop = _time_outlier_rows(t, d, nominal, p)
    outlier_at = np.empty(0, dtype=np.int64)  # kept row just before each dropped row
    if drop.any():
        keep = ~drop
        outlier_at = np.maximum(np.cumsum(keep)[np.flatnonzero(drop)] - 1, 0)
        t, line = t[keep], line[keep]
        rows.select(keep)
        n = t.size
        if n < 3:
            ev.add("time_outliers_dropped", t[outlier_at])
            return t, line, info
        d = np.diff(t)
    del drop

    back_step = _backward_clock_steps(t, d, p)
    fwd_step = _forward_clock_steps(t, d, rows, nominal, p)
    del d
    step = back_step | fwd_step
    info["clock_steps_backward"] = int(back_step.sum())
    info["clock_steps_forward"] = int(fwd_step.sum())
    if step.any():
        t, srows, corr = _shift_before_clock_steps(t, step, nominal)
        info["clock_step_corrections_s"] = [float(c) for c in corr[:20]]
        ev.add("clock_steps", t[srows])
    ev.add("time_outliers_dropped", t[outlier_at])
    return t, line, info


def _median_positive_step(t: np.ndarray, n_pos: int) -> float:
    """The median of the ``n_pos`` positive steps of ``t`` (1.0 without any), their array
    made a chunk at a time (not beside an array of every step)."""
    if not n_pos:
        return 1.0
    pos = np.empty(n_pos)
    k = 0
    for a, b in chunks(t.size - 1):
        dd = np.diff(t[a:b + 1])
        dd = dd[dd > 0]
        pos[k:k + dd.size] = dd
        k += dd.size
    return float(np.median(pos, overwrite_input=True))  # pos is ours: no copy


def _time_outlier_rows(t: np.ndarray, d: np.ndarray, nominal: float, p: CleanParams) -> np.ndarray:
    """Rows of junk timestamps: blocks of at most ``time_outlier_max_rows`` rows whose
    times lie far outside the bracket of their two neighbours, while the neighbours
    agree with each other (``d = diff(t)``, ``nominal`` the median positive step)."""
    n = t.size
    drop = np.zeros(n, dtype=bool)
    jumps = 1 + np.flatnonzero((d > p.clock_step_min_s) | (d < -p.clock_step_min_s))  # a block starts with a jump
    for k in range(1, p.time_outlier_max_rows + 1):
        if n < k + 2:
            break
        # block i .. i+k-1, neighbours i-1 and i+k
        i = jumps[jumps < n - k]
        prev, nxt = t[i - 1], t[i + k]
        width = nxt - prev
        agree = (width >= 0) & (width <= 2 * (k + 1) * nominal + p.clock_step_min_s)
        tol = np.maximum(p.clock_step_min_s, 2 * width)
        outside = np.ones(i.size, dtype=bool)
        for j in range(k):
            tj = t[i + j]
            outside &= (tj < prev - tol) | (tj > nxt + tol)
        hit = i[agree & outside]
        for j in range(k):
            drop[hit + j] = True
    return drop


def _backward_clock_steps(t: np.ndarray, d: np.ndarray, p: CleanParams) -> np.ndarray:
    """Steps (``d[i-1] = t[i] - t[i-1]``) where the clock was set back: a backward jump
    of more than ``clock_step_min_s`` and at most ``max_clock_step_s`` after which the
    next row is still before the previous one (the log overlaps itself)."""
    nxt_before_prev = np.concatenate((t[2:] < t[:-2], [True]))  # t[i+1] < t[i-1]
    return (d < -p.clock_step_min_s) & (d >= -p.max_clock_step_s) & nxt_before_prev


def _valid_near(ii: np.ndarray, n: int, valid_at) -> tuple[np.ndarray, np.ndarray]:
    """For each row ``ii`` (0 < ii < n): the last row of ii-4 .. ii-1 and the first of
    ii .. ii+3 where ``valid_at(rows)`` holds, -1 where there is none."""
    # the rows ii-1, ii-2, ii-3, ii-4 (before) and ii, ii+1, ii+2, ii+3 (after), in the
    # order they are looked at, all tested at once (valid_at is pure)
    offsets = np.array([-1, -2, -3, -4, 0, 1, 2, 3], dtype=np.int64)
    j = ii[:, None] + offsets
    inside = (j >= 0) & (j < n)
    hit = np.zeros(j.shape, dtype=bool)
    hit[inside] = valid_at(j[inside])
    out = []
    for cols in (slice(0, 4), slice(4, 8)):
        h = hit[:, cols]
        first = np.argmax(h, axis=1)
        found = h[np.arange(ii.size), first]
        out.append(np.where(found, j[:, cols][np.arange(ii.size), first], -1))
    return out[0], out[1]


def _forward_clock_steps(t: np.ndarray, d: np.ndarray, rows: LogRows, nominal: float, p: CleanParams) -> np.ndarray:
    """Steps where the clock jumped forward: a jump of at most ``max_clock_step_s``
    while the vehicle moves at >= ``clock_moving_mps`` on both sides and the positions
    (or the odometer) across the jump moved by about one tick, not by the jump. Only
    the rows within 3 of a candidate jump are looked at."""
    n = t.size
    fwd_cand = (d > max(p.clock_step_min_s, 3 * nominal)) & (d <= p.max_clock_step_s)
    fwd_step = np.zeros(n - 1, dtype=bool)
    if not fwd_cand.any():
        return fwd_step

    def speed_at(j):
        spd = np.full(j.size, np.nan)
        for name in ("gps_speed_mps", "wheel_speed_mps"):  # wheel overrides GPS
            if name in rows:
                v = rows.at(name, j)
                spd = np.where(np.isfinite(v), v, spd)
        return spd

    ii = np.flatnonzero(fwd_cand) + 1
    jb_s, ja_s = _valid_near(ii, n, lambda j: np.isfinite(speed_at(j)))
    has_v = (jb_s >= 0) & (ja_s >= 0)
    vb = np.where(has_v, speed_at(np.clip(jb_s, 0, n - 1)), np.nan)
    va = np.where(has_v, speed_at(np.clip(ja_s, 0, n - 1)), np.nan)
    moving = (np.minimum(vb, va) >= p.clock_moving_mps)
    disp = np.full(ii.size, np.nan)
    extra = np.full(ii.size, np.nan)  # time within the two sides [s]
    if "lat_deg" in rows and "lon_deg" in rows:
        hdop = "gps_hdop" in rows

        def fix_at(j):
            return _valid_fix(rows.at("lat_deg", j), rows.at("lon_deg", j), rows.at("gps_hdop", j) if hdop else None, p)

        jb, ja = _valid_near(ii, n, fix_at)
        ok = (jb >= 0) & (ja >= 0)
        jb, ja = np.clip(jb, 0, n - 1), np.clip(ja, 0, n - 1)
        dd = local_distance_m(rows.at("lat_deg", jb), rows.at("lon_deg", jb), rows.at("lat_deg", ja),
                              rows.at("lon_deg", ja))
        disp = np.where(ok, dd, disp)
        extra = np.where(ok, (t[ii - 1] - t[jb]) + (t[ja] - t[ii]), extra)
    if "odometer_m" in rows:
        jb, ja = _valid_near(ii, n, lambda j: np.isfinite(rows.at("odometer_m", j)))
        ok = (jb >= 0) & (ja >= 0) & ~np.isfinite(disp)
        jb, ja = np.clip(jb, 0, n - 1), np.clip(ja, 0, n - 1)
        disp = np.where(ok, np.abs(rows.at("odometer_m", ja) - rows.at("odometer_m", jb)), disp)
        extra = np.where(ok, (t[ii - 1] - t[jb]) + (t[ja] - t[ii]), extra)
    vmax, vmin = np.maximum(vb, va), np.minimum(vb, va)
    one_tick = disp <= 2 * vmax * (extra + nominal) + p.gps_jump_tolerance_m
    not_gap = disp < 0.5 * vmin * (extra + d[ii - 1])
    fwd_step[ii - 1] = moving & one_tick & not_gap
    return fwd_step


def _shift_before_clock_steps(t: np.ndarray, step: np.ndarray, nominal: float):
    """Correct clock steps (``step[i-1]``: between rows i-1 and i) keeping file order:
    every row before a step is shifted so that the step becomes one ``nominal`` tick
    (the clock after a correction is right; steps compose). Returns the shifted times,
    the rows after each step and each step's correction [s]."""
    n = t.size
    rows = np.flatnonzero(step) + 1
    corr = (t[rows] - nominal) - t[rows - 1]
    after = np.cumsum(corr[::-1])[::-1]  # per step: the sum of its and the later corrections
    # a row moves by the corrections of the steps after it: piecewise constant
    offset = np.repeat(np.append(after, 0.0), np.diff(np.concatenate(([0], rows, [n]))))
    return t + offset, rows, corr


def _sort_by_time(t, line, rows: LogRows):
    """Rows stably sorted by time (file order among equal times); nothing to do for a
    log in order."""
    if t.size > 1 and not (t[1:] >= t[:-1]).all():
        order = np.argsort(t, kind="stable")
        t, line = t[order], line[order]
        rows.select(order)
    return t, line
