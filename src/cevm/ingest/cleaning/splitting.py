"""Step 5 of the cleaning: the speed rows split into trips (ignition, gaps, holes in the
speed, long stops)."""

from __future__ import annotations

import numpy as np

from cevm.ingest.cleaning.arrays import _ffill, _nonzero, _runs
from cevm.ingest.cleaning.params import CleanParams

_SPLIT_REASONS = ("start", "ignition", "gap", "speed_gap", "long_stop")


def _segment(ts, vs, on, p: CleanParams):
    """Split the speed rows (times ts, speeds vs, ignition on) into trips (step 5 of
    the module docstring).

    Returns the kept row indices (into ts; None: every row), the position of each
    trip's first row among the kept rows, and the reason each trip started ('start',
    'ignition', 'gap', 'speed_gap', 'long_stop')."""
    if not ts.size:
        return np.empty(0, dtype=np.int64), np.zeros(0, dtype=np.int64), []
    keep = on.copy()
    keep[1:] |= on[:-1]  # the first "off" row ends the trip before it
    if keep.all():
        idx, t_kept, v_kept, on_kept = None, ts, vs, on
    else:
        idx = _nonzero(keep)
        if idx.size == 0:
            return idx, np.zeros(0, dtype=np.int64), []
        t_kept, v_kept, on_kept = ts[idx], vs[idx], on[idx]
    del keep
    reason = _split_points(t_kept, v_kept, on_kept, idx, p)
    idx, reason = _split_long_stops(t_kept, v_kept, idx, reason, p)
    starts = np.concatenate(([0], np.flatnonzero(reason > 0)))
    start_reasons = [_SPLIT_REASONS[int(reason[s])] if s > 0 else "start" for s in starts]
    return idx, starts, start_reasons


def _split_points(t_kept, v_kept, on_kept, idx, p: CleanParams) -> np.ndarray:
    """Per kept row, why a trip starts there (an index into :data:`_SPLIT_REASONS`, 0
    for none): the ignition turned on (or came back after dropped rows; ``idx`` the
    kept rows, None: all), no speed for more than ``gap_s``, or a hole over
    ``max_fill_s`` with the vehicle moving at either end (a hole between two standstill
    rows is a stop)."""
    k = t_kept.size
    reason = np.zeros(k, dtype=np.int8)
    dt = np.diff(t_kept)
    st = v_kept <= p.standstill_mps
    sgap = np.concatenate(([False], (dt > p.max_fill_s) & ~(st[1:] & st[:-1])))
    reason[sgap] = 3
    del sgap, st
    gap = np.concatenate(([False], dt > p.gap_s))
    reason[gap] = 2
    del gap, dt
    back = ~on_kept[:-1] if idx is None else ~on_kept[:-1] | (np.diff(idx) > 1)
    ign = np.concatenate(([False], on_kept[1:] & back))
    reason[ign] = 1
    return reason


def _split_long_stops(t_kept, v_kept, idx, reason, p: CleanParams):
    """Standstill runs (not crossing a split) lasting more than ``stop_s`` end their
    trip where the stop starts; the next starts where it ends, and the rows inside are
    dropped. Returns the kept ``idx`` (None: all rows) and ``reason``."""
    k = t_kept.size
    st = v_kept <= p.standstill_mps
    first, last = _runs(st, reason > 0)
    del st
    long_ = (t_kept[last] - t_kept[first]) > p.stop_s
    if not long_.any():
        return idx, reason
    f, la = first[long_], last[long_]
    diff = np.zeros(k + 1, dtype=np.int8)  # runs are disjoint: the sum is 0 or 1
    np.add.at(diff, f + 1, 1)
    np.add.at(diff, la, -1)
    sel = ~(np.cumsum(diff, dtype=np.int8)[:k] > 0)  # not inside a long stop
    reason[la[reason[la] == 0]] = 4
    return (_nonzero(sel) if idx is None else idx[sel]), reason[sel]


def _ignition_on(cols: dict, rows: np.ndarray | None, n: int) -> np.ndarray:
    """Ignition state of ``rows`` (None: all ``n``): the ignition column forward-filled
    (unknown before its first value = on); all on without the column."""
    if "ignition" in cols and np.isfinite(cols["ignition"]).any():
        ign = _ffill(cols["ignition"])
        return ~((ign if rows is None else ign[rows]) < 0.5)  # NaN before the first value = on
    return np.ones(n if rows is None else rows.size, dtype=bool)
