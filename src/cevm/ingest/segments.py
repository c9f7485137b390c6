"""Operations on the segments of one concatenated array at once: the trips of a batch,
each a slice ``bounds[i]:bounds[i + 1]`` of arrays that hold them end to end.

Ingest works on whole batches of trips (:mod:`cevm.ingest.cleaning.batch`,
:mod:`cevm.ingest.elevation_batch`): each step is a few numpy calls over the batch's
arrays, not a few hundred calls per trip. The results are those of the same numpy call
on each segment alone, bit for bit:

- :func:`segment_sums` is ``x[a:b].sum()`` of each segment: numpy's pairwise summation
  (blocks of at most 128 values summed with eight accumulators, longer runs split in
  halves at multiples of eight) done for all segments at once, the same additions in
  the same order; not ``np.add.reduceat``, which adds sequentially and differs in the
  last bits;
- :func:`segment_medians` is ``np.median`` of each group (a sort, then the middle value
  or the mean of the two middle values);
- :func:`segment_searchsorted` and :func:`segment_interp` are ``np.searchsorted`` and
  ``np.interp`` within each segment (whatever the values of the other segments);
- :func:`segment_cumsum` is ``np.cumsum`` of each segment (one call per segment: a
  cumulative sum is sequential, and one over the concatenation would carry the earlier
  segments' totals in its rounding).

Every function takes the segments as ``bounds`` (int, ``n + 1`` offsets from 0 to the
array's length, non-decreasing) or as ``starts`` and ``lengths``.
"""

from __future__ import annotations

import itertools
from typing import Literal

import numpy as np

__all__ = [
    "bounds_of",
    "ranges",
    "segment_cumsum",
    "segment_diffs",
    "segment_ids",
    "segment_interp",
    "segment_medians",
    "segment_searchsorted",
    "segment_sums",
]

#: numpy's pairwise summation: blocks of at most this many values are summed with
#: eight accumulators (``PW_BLOCKSIZE`` in numpy's loops).
_PW_BLOCK = 128

#: Segments up to which :func:`segment_sums` and :func:`segment_medians` call numpy once
#: per segment (the same values; fewer calls than their whole-batch steps).
_FEW = 24

#: Mean segment length from which :func:`segment_sums` calls numpy once per segment.
_LONG = 96

#: Elements gathered at a time by :func:`segment_sums` (bounded temporaries).
_GATHER_ELEMENTS = 1 << 20


def bounds_of(lengths) -> np.ndarray:
    """Offsets (``n + 1``, from 0) of consecutive segments of ``lengths``."""
    lengths = np.asarray(lengths, dtype=np.int64)
    out = np.zeros(lengths.size + 1, dtype=np.int64)
    np.cumsum(lengths, out=out[1:])
    return out


def ranges(starts, lengths) -> np.ndarray:
    """``np.arange(s, s + n)`` of each (start, length), end to end (int64)."""
    starts = np.asarray(starts, dtype=np.int64)
    lengths = np.asarray(lengths, dtype=np.int64)
    b = bounds_of(lengths)
    return np.repeat(starts - b[:-1], lengths) + np.arange(b[-1], dtype=np.int64)


def segment_ids(bounds: np.ndarray) -> np.ndarray:
    """The segment of each element (int64, length ``bounds[-1]``)."""
    bounds = np.asarray(bounds, dtype=np.int64)
    return np.repeat(np.arange(bounds.size - 1, dtype=np.int64), np.diff(bounds))


def _starts_lengths(bounds=None, starts=None, lengths=None) -> tuple[np.ndarray, np.ndarray]:
    if bounds is not None:
        b = np.asarray(bounds, dtype=np.int64)
        return b[:-1], np.diff(b)
    return np.asarray(starts, dtype=np.int64), np.asarray(lengths, dtype=np.int64)


def segment_sums(x: np.ndarray, bounds=None, *, starts=None, lengths=None) -> np.ndarray:
    """``x[s:s + n].sum()`` of each segment (float64 ``x``), bit for bit: numpy's
    pairwise summation for every segment at once (see the module docstring). An empty
    segment sums to 0.0."""
    x = np.ascontiguousarray(x, dtype=np.float64)
    s, n = _starts_lengths(bounds, starts, lengths)
    if s.size <= _FEW or (_FEW >= 0 and n.sum() >= _LONG * s.size):
        # numpy itself, segment by segment: a few segments, or long ones (the whole-batch
        # steps gather blocks of 128 values: more work per value than numpy's own loop)
        return np.array([x[a:a + k].sum() for a, k in zip(s.tolist(), n.tolist(), strict=True)], dtype=np.float64)
    return _pairwise(x, s, n)


def _pairwise(x: np.ndarray, s: np.ndarray, n: np.ndarray) -> np.ndarray:
    """numpy's pairwise sum of each x[s:s+n]: the segments over 128 values are split in
    halves as numpy's ``pairwise_sum`` splits them, all of them at once, level by level
    (at most log2(longest / 128) levels), and the halves' sums added."""
    out = np.empty(s.size)
    leaf = n <= _PW_BLOCK
    if leaf.all():
        return _leaf_sums(x, s, n)
    if leaf.any():
        out[leaf] = _leaf_sums(x, s[leaf], n[leaf])
    big = ~leaf
    sb, nb = s[big], n[big]
    n2 = nb // 2
    n2 -= n2 % 8
    halves = _pairwise(x, np.concatenate((sb, sb + n2)), np.concatenate((n2, nb - n2)))
    out[big] = halves[:sb.size] + halves[sb.size:]
    return out


def _leaf_sums(x: np.ndarray, s: np.ndarray, n: np.ndarray) -> np.ndarray:
    """numpy's sum of segments of at most 128 values: under 8 values, added in order to
    0.0; else eight accumulators over the whole blocks of eight, combined as
    ``((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))``, then the rest added in
    order. Padding is -0.0 (x + -0.0 == x for every x, signed zeros included)."""
    out = np.empty(s.size)
    step = max(1, _GATHER_ELEMENTS // _PW_BLOCK)
    for a in range(0, s.size, step):
        out[a:a + step] = _leaf_sums_part(x, s[a:a + step], n[a:a + step])
    return out


def _leaf_sums_part(x: np.ndarray, s: np.ndarray, n: np.ndarray) -> np.ndarray:
    m = s.size
    full = np.where(n >= 8, n - n % 8, 0)  # values in the accumulators' blocks
    width = int(full.max()) if m else 0
    if width:
        k = np.arange(width)
        idx = s[:, None] + k
        main = np.where(k < full[:, None], x[np.minimum(idx, x.size - 1)], -0.0).reshape(m, width // 8, 8)
        r = main[:, 0, :].copy()
        for blk in range(1, width // 8):
            r += main[:, blk, :]
        res = ((r[:, 0] + r[:, 1]) + (r[:, 2] + r[:, 3])) + ((r[:, 4] + r[:, 5]) + (r[:, 6] + r[:, 7]))
    else:
        res = np.full(m, -0.0)
    res[n < 8] = 0.0  # numpy starts a short sum at 0.0
    rest = n - full  # at most 7, added one at a time
    for j in range(int(rest.max()) if m else 0):
        has = rest > j
        pos = np.minimum(s + full + j, max(x.size - 1, 0))
        res = res + np.where(has, x[pos] if x.size else 0.0, -0.0)
    return res


def segment_diffs(x: np.ndarray, bounds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The within-segment differences ``np.diff(x[a:b])`` of every segment, end to end,
    and their bounds (a segment of ``k`` values has ``max(k - 1, 0)`` differences)."""
    bounds = np.asarray(bounds, dtype=np.int64)
    d = np.diff(x)
    lengths = np.maximum(np.diff(bounds) - 1, 0)
    if bounds.size <= 2:
        return (d if bounds.size == 2 and bounds[1] - bounds[0] > 1 else d[:0]), bounds_of(lengths)
    keep = np.ones(d.size, dtype=bool)
    inner = bounds[1:-1]
    inner = inner[(inner > 0) & (inner <= d.size)]
    keep[inner - 1] = False  # the step from one segment's last value to the next one's first
    return d[keep], bounds_of(lengths)


def segment_cumsum(x: np.ndarray, bounds: np.ndarray, *, start_zero: bool = False) -> np.ndarray:
    """``np.cumsum`` of each segment, end to end (one call per segment: a cumulative sum
    is sequential). ``start_zero``: each segment's sums start with 0.0 (one value more
    per segment: ``np.concatenate(([0.0], np.cumsum(seg)))``)."""
    bounds = np.asarray(bounds, dtype=np.int64)
    n = bounds.size - 1
    out = np.empty(x.size + (n if start_zero else 0))
    for i, (a, b) in enumerate(zip(bounds[:-1].tolist(), bounds[1:].tolist(), strict=True)):
        o = a + i if start_zero else a
        if start_zero:
            out[o] = 0.0
            o += 1
        np.cumsum(x[a:b], out=out[o:o + b - a])
    return out


def segment_medians(values: np.ndarray, group: np.ndarray, n_groups: int, *, finite_only: bool = False,
                    plain: bool = False) -> np.ndarray:
    """``np.median`` of the values of each group 0..n_groups-1, bit for bit (NaN for an
    empty group; a group holding a NaN has median NaN, as numpy's, unless
    ``finite_only``: then its finite values only). numpy takes the mean of the middle
    value or two, a sum from 0.0 (a median of -0.0 is 0.0); ``plain``: ``0.5 * (a + b)``
    of the middle two (``a`` twice for an odd count) instead, signed zeros kept."""
    values = np.asarray(values, dtype=np.float64)
    if finite_only:
        ok = np.isfinite(values)
        values, group = values[ok], group[ok]
    med = np.full(n_groups, np.nan)
    if not values.size:
        return med
    # The order among equal values matters only to the sign of a zero, and only to the
    # plain mean of the middle (numpy's sum from 0.0 makes -0.0 a 0.0): a stable sort
    # (np.lexsort's order, the cleaning's group median) only where that can arise.
    stable = plain and bool((values == 0).any())
    if n_groups <= _FEW and (group.size < 2 or bool((group[1:] >= group[:-1]).all())):  # contiguous groups
        cut = np.searchsorted(group, np.arange(n_groups + 1)).tolist()
        for i, (a, b) in enumerate(itertools.pairwise(cut)):
            if b > a:
                if not plain:
                    med[i] = np.median(values[a:b])
                    continue
                k = b - a
                v = np.sort(values[a:b], kind="stable") if stable else np.partition(values[a:b], ((k - 1) // 2, k // 2))
                med[i] = 0.5 * (v[(k - 1) // 2] + v[k // 2]) if not np.isnan(v).any() else np.nan
        return med
    # values sorted within each group: by value, then stably by group (numpy's radix sort
    # for 16-bit keys): np.lexsort's order (for ``stable``), at a fraction of its cost; NaN
    # last in a group
    order = np.argsort(values, kind="stable" if stable else "quicksort")
    small = group.astype(np.int16 if n_groups < 2**15 else np.int32)
    v = values[order[np.argsort(small[order], kind="stable")]]
    count = np.bincount(group, minlength=n_groups)
    start = np.zeros(n_groups, dtype=np.int64)
    np.cumsum(count[:-1], out=start[1:])
    has = count > 0
    lo = start[has] + (count[has] - 1) // 2
    hi = start[has] + count[has] // 2
    m = 0.5 * (v[lo] + v[hi]) if plain else ((0.0 + v[lo]) + v[hi]) * 0.5
    if not finite_only:
        nan_in = np.isnan(v[start[has] + count[has] - 1])  # the group's largest: NaN if it has one
        m[nan_in] = np.nan
    med[has] = m
    return med


def segment_searchsorted(a: np.ndarray, a_starts: np.ndarray, a_lengths: np.ndarray, v: np.ndarray,
                         v_seg: np.ndarray, side: Literal["left", "right"] = "left") -> np.ndarray:
    """``np.searchsorted(a[s:s + n], v, side)`` of each value of ``v`` in its segment
    (``v_seg``: the segment of each value; ``a`` sorted within each segment), as
    positions within the segment. The segments of ``a`` need not be sorted among
    themselves."""
    a_starts = np.asarray(a_starts, dtype=np.int64)
    a_lengths = np.asarray(a_lengths, dtype=np.int64)
    v = np.asarray(v, dtype=np.float64)
    out = np.empty(v.size, dtype=np.int64)
    if not v.size:
        return out
    if a.size and _segments_sorted(a, a_starts, a_lengths):
        pos = np.searchsorted(a, v, side=side)
        s, n = a_starts[v_seg], a_lengths[v_seg]
        return np.clip(pos - s, 0, n)
    # segments not in order among themselves: one search per segment
    for g in np.unique(v_seg).tolist():
        sel = np.flatnonzero(v_seg == g)
        s, n = int(a_starts[g]), int(a_lengths[g])
        out[sel] = np.searchsorted(a[s:s + n], v[sel], side=side)
    return out


def _segments_sorted(a: np.ndarray, starts: np.ndarray, lengths: np.ndarray) -> bool:
    """Whether the segments, in order, lie in ``a`` one after the other and the whole is
    non-decreasing (then one search over ``a``, clipped to the segment, is the search
    within each)."""
    if starts.size == 0:
        return True
    if not (np.all(starts[1:] == starts[:-1] + lengths[:-1])):
        return False
    s0, s1 = int(starts[0]), int(starts[-1] + lengths[-1])
    seg = a[s0:s1]
    return bool(seg.size < 2 or (seg[1:] >= seg[:-1]).all())


def segment_interp(x: np.ndarray, x_seg: np.ndarray, xp: np.ndarray, xp_starts: np.ndarray,
                   xp_lengths: np.ndarray, fp: np.ndarray) -> np.ndarray:
    """``np.interp(x, xp[s:s + n], fp[s:s + n])`` of each value of ``x`` in its segment
    (``x_seg``), bit for bit, for ``xp`` strictly increasing within each segment (and
    each segment holding at least one value): numpy's steps (the value itself at an
    exact sample, the end values held outside, else ``slope * (x - xp[j]) + fp[j]``
    with the slope ``(fp[j+1] - fp[j]) / (xp[j+1] - xp[j])``, and its fall-backs where
    that is NaN)."""
    x = np.asarray(x, dtype=np.float64)
    xp = np.asarray(xp, dtype=np.float64)
    fp = np.asarray(fp, dtype=np.float64)
    xp_starts = np.asarray(xp_starts, dtype=np.int64)
    xp_lengths = np.asarray(xp_lengths, dtype=np.int64)
    s, n = xp_starts[x_seg], xp_lengths[x_seg]
    first, last = s, s + n - 1
    if _strictly_increasing_within(xp, xp_starts, xp_lengths):
        # one numpy call over the segments end to end: its bracket of a value inside its
        # segment is the segment's own; the values outside take the end values (numpy's
        # per-segment left and right), those at the last sample its value
        a, b = int(xp_starts[0]), int(xp_starts[-1] + xp_lengths[-1])
        res = np.interp(x, xp[a:b], fp[a:b])
        res = np.where(x < xp[first], fp[first], res)
        res = np.where(x >= xp[last], fp[last], res)
        return np.where(n == 1, fp[first], res)
    j = segment_searchsorted(xp, xp_starts, xp_lengths, x, x_seg, "right") - 1  # xp[j] <= x < xp[j+1]
    g = s + np.clip(j, 0, np.maximum(n - 2, 0))  # the bracket's left sample (global)
    g1 = np.minimum(g + 1, last)
    x0, x1, y0, y1 = xp[g], xp[g1], fp[g], fp[g1]
    with np.errstate(invalid="ignore", divide="ignore"):
        slope = (y1 - y0) / (x1 - x0)
        res = slope * (x - x0) + y0
        bad = np.isnan(res)
        if bad.any():
            alt = slope * (x - x1) + y1
            alt = np.where(np.isnan(alt) & (y0 == y1), y0, alt)
            res = np.where(bad, alt, res)
    res = np.where(x == x0, y0, res)  # an exact sample: its value
    res = np.where(j < 0, fp[first], res)  # before the first sample: its value
    res = np.where((j >= n - 1), fp[last], res)  # at or after the last sample: its value
    return np.where(np.isnan(x) & (n > 1), x, res)  # NaN stays NaN (numpy: but for one sample)


def _strictly_increasing_within(xp: np.ndarray, starts: np.ndarray, lengths: np.ndarray) -> bool:
    """Whether the segments follow each other in ``xp``, each strictly increasing and
    none starting before the previous one ends (then one ``np.interp`` over them all
    brackets each value within its own segment)."""
    if starts.size == 0 or not bool(np.all(starts[1:] == starts[:-1] + lengths[:-1])) or (lengths < 1).any():
        return False
    a, b = int(starts[0]), int(starts[-1] + lengths[-1])
    d = np.diff(xp[a:b])
    inner = np.ones(d.size, dtype=bool)
    inner[(starts[1:] - a) - 1] = False
    return bool((d[inner] > 0).all() and (d[~inner] >= 0).all())
