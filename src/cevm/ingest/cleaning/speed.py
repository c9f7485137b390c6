"""Step 4 of the cleaning: each row's speed from the best source it has (wheel speed, GPS
speed, positions), interpolated within limits."""

from __future__ import annotations

import numpy as np

from cevm.ingest.cleaning.arrays import _let_go, _nonzero
from cevm.ingest.cleaning.events import RepairEvents
from cevm.ingest.cleaning.gps import GpsFixes, _clean_gps
from cevm.ingest.cleaning.params import CleanParams
from cevm.ingest.cleaning.plausibility import _speed_rows
from cevm.ingest.consumption import chunks, interp_limited


def _interp_rows(t: np.ndarray, ok: np.ndarray | None, v: np.ndarray | None, max_fill_s: float,
                 at: np.ndarray | None = None) -> np.ndarray:
    """``interp_limited(t, t[ok], v[ok], max_fill_s)`` (all NaN for ``ok`` None) for a
    strictly increasing ``t``, at the rows ``at`` (None: every row): the rows' own
    values where ``ok``, interpolated between them elsewhere. Cheaper, as the sample
    positions in ``t`` are known: only the other rows are interpolated, a chunk of
    them at a time between the samples around the chunk."""
    if ok is None:
        return np.full(t.shape if at is None else at.shape, np.nan)
    assert v is not None  # a column's values come with its ok mask
    if at is None:
        if ok.all():  # every row is a sample: its own value (exact times)
            return v.copy()
        out = v.astype(np.float64, copy=True)
        fill = _nonzero(~ok)  # rows to interpolate, and their places in out
        where = fill
    else:
        out = v[at].astype(np.float64, copy=False)
        where = _nonzero(~ok[at])
        fill = at[where]
    if not fill.size:
        return out
    samples = _nonzero(ok)
    for a, b in chunks(fill.size):
        todo = fill[a:b]
        lo = max(int(np.searchsorted(samples, todo[0])) - 1, 0)  # the sample before the chunk ...
        hi = int(np.searchsorted(samples, todo[-1])) + 1  # ... to the one after it
        s = samples[lo:hi]
        out[where[a:b]] = interp_limited(t[todo], t[s], v[s], max_fill_s)
    return out


def _speed_from_positions(t: np.ndarray, fixes: GpsFixes, rows: np.ndarray, p: CleanParams) -> np.ndarray:
    """Speed [m/s] at the log rows ``rows`` from positions: the distance between
    consecutive fixes over their time step, at its midpoint time, for steps of at most
    ``max_fill_s`` and ``max_speed_mps``, interpolated over at most ``max_fill_s``."""
    m = fixes.rows.size - 1
    step_m = fixes.step_m
    assert step_m is not None  # set while the row speeds are made
    tm, vm = np.empty(m), np.empty(m)
    k = 0
    for a, b in chunks(m):
        ft = t[fixes.rows[a:b + 1]]
        dt = np.diff(ft)
        v = step_m[a:b] / dt
        ok = (dt <= p.max_fill_s) & (v <= p.max_speed_mps)
        j = k + int(ok.sum())
        tm[k:j] = (0.5 * (ft[1:] + ft[:-1]))[ok]
        vm[k:j] = v[ok]
        k = j
    return interp_limited(t[rows], tm[:k], vm[:k], p.max_fill_s)


def _row_speed(t, cols, p: CleanParams, ev: RepairEvents):
    """Per-row speed [m/s] and source code (int8: 0 wheel, 1 GPS speed, 2 positions, -1
    none), plus the cleaned GPS fixes. The speed columns and ``gps_hdop`` are removed
    from ``cols`` once used (nothing after needs them)."""
    ok_w = _speed_rows(t, cols, "wheel_speed_mps", p, ev)
    ok_g = _speed_rows(t, cols, "gps_speed_mps", p, ev)
    _let_go(t.size)
    v = _interp_rows(t, ok_w, cols.pop("wheel_speed_mps", None), p.max_fill_s)
    del ok_w
    _let_go(t.size)
    gps = cols.get("gps_speed_mps")
    moving = v > p.standstill_mps  # the wheel speed, else the GPS speed
    no_w = _nonzero(~np.isfinite(v))
    if no_w.size and gps is not None:
        moving[no_w] = _interp_rows(t, ok_g, gps, p.max_fill_s, at=no_w) > p.standstill_mps
    fixes, stale = _clean_gps(t, cols, moving, p, ev)
    del moving
    cols.pop("gps_hdop", None)
    _let_go(t.size)
    src = np.full(t.size, -1, dtype=np.int8)
    src[np.isfinite(v)] = 0
    if no_w.size and gps is not None:
        if (ok_g & stale).any():  # GPS speeds of stale fixes dropped too
            ok_g = ok_g & ~stale
        v_g = _interp_rows(t, ok_g, gps, p.max_fill_s, at=no_w)
        use = np.isfinite(v_g)
        v[no_w[use]] = v_g[use]
        src[no_w[use]] = 1
        del v_g, use
    del ok_g, stale, no_w, gps
    cols.pop("gps_speed_mps", None)
    _let_go(t.size)
    need = _nonzero(~np.isfinite(v))
    if need.size and fixes.rows.size > 1:
        v_p = _speed_from_positions(t, fixes, need, p)
        use = np.isfinite(v_p)
        v[need[use]] = v_p[use]
        src[need[use]] = 2
        del v_p, use
    fixes.step_m = None
    del need
    gps_based = src >= 1
    noisy = gps_based & (v < p.standstill_mps) & (v > 0)
    ev.add("gps_speed_zeroed", t[noisy])
    v[gps_based & (v < p.standstill_mps)] = 0.0
    return v, src, fixes
