"""Step 2 of the cleaning: exact duplicate rows dropped, rows of one tick merged."""

from __future__ import annotations

import numpy as np

from cevm.ingest.cleaning.arrays import _let_go, _nonzero
from cevm.ingest.cleaning.events import RepairEvents
from cevm.ingest.cleaning.rows import _ROW_SPEED_COLUMNS, LogRows
from cevm.ingest.consumption import chunks


def _dedupe(t, line, cols, ev: RepairEvents):
    """Sorted frame -> strictly increasing time (:func:`_merge_ticks` on columns given
    as a dict: every column kept). Returns (t, line, cols)."""
    rows = LogRows(dict(cols))
    t, line = _merge_ticks(t, line, rows, set(cols), ev, wide=set(cols))
    return t, line, rows.cols


def _merge_ticks(t, line, rows: LogRows, keep, ev: RepairEvents, wide=_ROW_SPEED_COLUMNS):
    """Time-sorted rows -> strictly increasing time: exact duplicates dropped, ticks
    with the same time merged (last non-NaN value per field); the columns in ``keep``
    made in the final row order (:meth:`LogRows.gather`; those in ``wide`` as float64),
    the others dropped.

    Rows equal in time and every field (NaN equal to NaN, -0.0 to 0.0) but the first are
    dropped (``duplicate_rows_dropped``); the remaining rows of one time are merged into
    one (``ticks_merged`` per merged tick): per field the last non-NaN value in file
    order, the lowest ``source_line``; a field with two or more distinct non-NaN values
    in one tick counts once in ``conflicting_values``. Numpy only, one field and a chunk
    of ticks at a time, over the rows in ticks of more than one row. Returns (t, line)."""
    same = t[1:] == t[:-1]
    if not same.any():
        rows.gather(keep, wide)
        return t, line
    cont = _nonzero(same) + 1  # the rows that continue the tick of the row before
    del same
    start = np.ones(t.size, dtype=bool)  # a tick's first row
    start[cont] = False
    multi = ~start
    multi[cont - 1] = True
    rows_m = _nonzero(multi)  # the rows in ticks of more than one row ...
    del multi
    g = np.empty(rows_m.size, dtype=rows_m.dtype)  # ... and their tick's place among the ticks
    for a, b in chunks(rows_m.size):
        g[a:b] = rows_m[a:b] - np.searchsorted(cont, rows_m[a:b], side="right")
    del cont
    names = list(rows.cols)
    dup = _exact_duplicates(g, rows_m, rows, names)
    if dup.any():
        ev.add("duplicate_rows_dropped", t[rows_m[dup]])
        keep_m = ~dup
        g, kept_rows = g[keep_m], rows_m[keep_m]
        del keep_m
    else:
        kept_rows = rows_m
    del dup, rows_m
    _let_go(t.size)
    # per tick: reduceat over runs of the same group id
    gstart = _nonzero(np.concatenate(([True], g[1:] != g[:-1])))
    ug = g[gstart]
    gend = np.concatenate((gstart[1:], np.array([g.size], dtype=gstart.dtype)))
    del g
    merged = (gend - gstart) > 1
    if merged.any():
        ev.add("ticks_merged", t[kept_rows[gstart[merged]]])
    n_ticks = gstart.size
    per_group = np.zeros(n_ticks, dtype=np.int32)  # conflicting fields per tick
    pos_first = rows.positions(start)
    out = {}
    for name in sorted(names, key=lambda c: c in keep):  # the dropped ones first: their memory is free sooner
        src = rows.cols.pop(name)
        last_val = np.empty(n_ticks) if name in keep else None
        for ga, gb in chunks(n_ticks):
            ra, rb = int(gstart[ga]), int(gend[gb - 1])  # the kept rows of these ticks
            vals = src[rows.positions(kept_rows[ra:rb])].astype(np.float64, copy=False)
            at = gstart[ga:gb] - ra
            if merged[ga:gb].any():
                with np.errstate(invalid="ignore"):
                    lo = np.fmin.reduceat(vals, at)
                    hi = np.fmax.reduceat(vals, at)
                per_group[ga:gb] += (lo != hi) & ~np.isnan(lo)
            if last_val is not None:
                # last non-NaN value of the field per tick (NaN if none)
                last = np.maximum.reduceat(np.where(np.isnan(vals), -1, np.arange(vals.size)), at)
                last_val[ga:gb] = np.where(last >= 0, vals[np.maximum(last, 0)], np.nan)
        if last_val is not None:
            a = src[pos_first]
            if name in wide:
                a = a.astype(np.float64, copy=False)
            a[ug] = last_val  # values of the column itself
            out[name] = a
        del src, last_val
        _let_go(t.size)
    if merged.any():
        ev.add("conflicting_values", np.repeat(t[kept_rows[gstart]], per_group))
    del per_group, merged
    rows.cols, rows.sel = {c: out[c] for c in names if c in out}, None
    t_out = t[start]  # made last: the columns above are made while only t and line are held twice
    line_out = line[start]
    line_out[ug] = np.minimum.reduceat(line[kept_rows], gstart)
    return t_out, line_out


def _exact_duplicates(g: np.ndarray, rows_m: np.ndarray, rows: LogRows, names: list[str]) -> np.ndarray:
    """Per row of ``rows_m`` (the current rows in ticks of more than one row, ``g`` their
    tick), whether an earlier one of its tick equals it in every field (NaN equal to NaN,
    -0.0 to 0.0). In a tick of two rows, the second is compared with the first, a field
    and a chunk at a time; in larger ticks, by :func:`_equal_classes`."""
    dup = np.zeros(g.size, dtype=bool)
    first = _nonzero(np.concatenate(([True], g[1:] != g[:-1])))  # each tick's first row in rows_m
    size = np.diff(np.append(first, g.size))
    pair = first[size == 2]
    if pair.size:
        same = np.ones(pair.size, dtype=bool)
        for name in names:
            for a, b in chunks(pair.size):
                r = rows_m[pair[a:b]]
                v0, v1 = rows.at(name, r), rows.at(name, r + 1)
                same[a:b] &= (v0 == v1) | (np.isnan(v0) & np.isnan(v1))
            if not same.any():
                break
        dup[pair[same] + 1] = True
    larger = size > 2
    if larger.any():
        idx = _nonzero(np.repeat(larger, size))
        dup[idx] = _later_of_equal(g[idx], rows_m[idx], rows, names)
    return dup


def _later_of_equal(g: np.ndarray, rows_m: np.ndarray, rows: LogRows, names: list[str]) -> np.ndarray:
    """Per row of ``rows_m`` (``g`` its tick), whether an earlier row of the tick equals it
    in every field: the rows' classes of equal values are refined one field at a time
    (sorted by class and value, a new class where either changes), so that one field of
    these rows is held at a time; the first row of each final class is kept."""
    cls = g
    n_cls = int(np.count_nonzero(g[1:] != g[:-1])) + 1
    for name in names:
        if n_cls == cls.size:  # every row alone in its class: no duplicates
            return np.zeros(cls.size, dtype=bool)
        v = rows.at(name, rows_m)
        order = np.lexsort((v, cls))
        new = np.empty(cls.size, dtype=bool)  # in sorted order: a class starts here
        new[0] = True
        for a, b in chunks(cls.size - 1):
            o0, o1 = order[a:b], order[a + 1:b + 1]
            v0, v1 = v[o0], v[o1]
            new[a + 1:b + 1] = (cls[o1] != cls[o0]) | ~((v1 == v0) | (np.isnan(v1) & np.isnan(v0)))
        del v
        sorted_cls = np.cumsum(new, dtype=g.dtype) - 1
        del new
        n_cls = int(sorted_cls[-1]) + 1
        cls = np.empty_like(sorted_cls)
        cls[order] = sorted_cls
        del order, sorted_cls
    if n_cls == cls.size:
        return np.zeros(cls.size, dtype=bool)
    dup = np.ones(cls.size, dtype=bool)
    dup[np.unique(cls, return_index=True)[1]] = False
    return dup
