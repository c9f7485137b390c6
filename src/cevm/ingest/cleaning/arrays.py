"""Array helpers of the cleaning steps: runs, group medians, forward fill, positions of
a mask a chunk at a time, memory handed back, JSON-safe values."""

from __future__ import annotations

import math

import numpy as np

from cevm.ingest.consumption import chunks
from cevm.runtime import MMAP_THRESHOLD_BYTES, release_free_memory


def _group_median(values: np.ndarray, group: np.ndarray, n_groups: int) -> np.ndarray:
    """Median of the finite values of each group 0..n_groups-1 (NaN for none)."""
    ok = np.isfinite(values)
    v, g = values[ok], group[ok]
    order = np.lexsort((v, g))
    v = v[order]
    count = np.bincount(g, minlength=n_groups)
    start = np.concatenate(([0], np.cumsum(count)[:-1]))
    med = np.full(n_groups, np.nan)
    has = count > 0
    lo = start[has] + (count[has] - 1) // 2
    hi = start[has] + count[has] // 2
    med[has] = 0.5 * (v[lo] + v[hi])
    return med


def _let_go(n_rows: int) -> None:
    """Return freed memory to the system (:func:`cevm.runtime.release_free_memory`) if
    the log's columns are large (``n_rows`` rows take at least the allocator's mapping
    threshold a column): glibc serves large arrays from the free memory in its heap and
    keeps what they free, so a step that makes and drops column after column would hold
    several times what it uses. A small log's arrays are left to the allocator."""
    if n_rows * 8 >= MMAP_THRESHOLD_BYTES:
        release_free_memory()


def _nonzero(mask: np.ndarray) -> np.ndarray:
    """``np.flatnonzero(mask)``, as int32 where the positions fit (half the memory of
    int64; made a chunk at a time, so no int64 array of them either)."""
    if mask.size >= 2**31:
        return np.flatnonzero(mask)
    out = np.empty(np.count_nonzero(mask), dtype=np.int32)
    k = 0
    for a, b in chunks(mask.size):
        nz = np.flatnonzero(mask[a:b])
        out[k:k + nz.size] = nz + a
        k += nz.size
    return out


def _last_valid_index(valid: np.ndarray) -> np.ndarray:
    """Index of the last True at or before each position, -1 if none."""
    idx = np.where(valid, np.arange(valid.size), -1)
    return np.maximum.accumulate(idx) if idx.size else idx


def _ffill(a: np.ndarray) -> np.ndarray:
    """Forward fill NaN (leading NaN stay NaN), a chunk at a time."""
    out = np.empty(a.size)
    last = np.nan  # the last finite value before the chunk
    for s, e in chunks(a.size):
        c = a[s:e]
        ok = np.isfinite(c)
        j = _last_valid_index(ok)
        out[s:e] = np.where(j >= 0, c[np.maximum(j, 0)], last)
        if ok.any():
            last = c[j[-1]]
    return out


def _runs(mask: np.ndarray, breaks: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """First and last index of each run of True in ``mask``; ``breaks[i]`` True also
    starts a new run at i."""
    m = mask.astype(bool)
    prev = np.concatenate(([False], m[:-1]))
    nxt = np.concatenate((m[1:], [False]))
    start = m & ~prev
    end = m & ~nxt
    if breaks is not None:
        start |= m & breaks
        end |= m & np.concatenate((breaks[1:], [False]))
    return np.flatnonzero(start), np.flatnonzero(end)


def _jsonable(x):
    t = type(x)
    if t is str or t is int or x is None or t is bool:
        return x
    if t is float:
        return x if math.isfinite(x) else None
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        x = float(x)
        return x if math.isfinite(x) else None
    return x
