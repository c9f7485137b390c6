"""cevm.ingest.segments: each operation over many segments at once equals the numpy call
on each segment alone, bit for bit (numpy is the reference)."""

from __future__ import annotations

import itertools
from contextlib import contextmanager

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cevm.ingest import segments
from cevm.ingest.cleaning.arrays import _group_median
from cevm.ingest.segments import (
    bounds_of,
    segment_cumsum,
    segment_diffs,
    segment_ids,
    segment_interp,
    segment_medians,
    segment_searchsorted,
    segment_sums,
)

lengths = st.lists(st.integers(0, 700), min_size=1, max_size=12)


@contextmanager
def whole_batch(on: bool):
    """With ``on``, the whole-batch steps even for a few segments (else numpy segment by
    segment, as for up to ``segments._FEW``): both are checked."""
    few = segments._FEW
    segments._FEW = -1 if on else few
    try:
        yield
    finally:
        segments._FEW = few


def _values(rng, n, kind):
    if kind == 0:
        return rng.standard_normal(n) * 10.0 ** rng.integers(-3, 6)
    if kind == 1:  # signed zeros and repeats
        return rng.choice(np.array([0.0, -0.0, 1.5, -2.25, 1e16, -1e16]), n)
    return np.abs(rng.standard_normal(n)).cumsum()


@pytest.mark.slow
@settings(max_examples=200, deadline=None)
@given(lengths, st.integers(0, 2**32 - 1), st.integers(0, 2), st.booleans())
def test_segment_sums_equal_numpy_sum(lens, seed, kind, batch):
    rng = np.random.default_rng(seed)
    b = bounds_of(lens)
    x = _values(rng, int(b[-1]), kind)
    with whole_batch(batch):
        got = segment_sums(x, b)
    want = np.array([x[a:c].sum() for a, c in itertools.pairwise(b)])
    assert got.tobytes() == want.tobytes()  # signed zeros too


def test_segment_sums_long_segments():
    rng = np.random.default_rng(3)
    lens = [1, 129, 1000, 8191, 8192, 8193, 70001, 7]
    b = bounds_of(lens)
    x = rng.standard_normal(int(b[-1])) * 1e3
    want = np.array([x[a:c].sum() for a, c in itertools.pairwise(b)])
    starts, n = b[:-1][::-1].copy(), np.diff(b)[::-1].copy()  # any order, as starts and lengths
    for batch in (False, True):
        with whole_batch(batch):
            assert segment_sums(x, b).tobytes() == want.tobytes()
            assert segment_sums(x, starts=starts, lengths=n).tobytes() == want[::-1].tobytes()


@settings(max_examples=100, deadline=None)
@given(lengths, st.integers(0, 2**32 - 1))
def test_segment_cumsum_and_diffs(lens, seed):
    rng = np.random.default_rng(seed)
    b = bounds_of(lens)
    x = rng.standard_normal(int(b[-1]))
    segs = [x[a:c] for a, c in itertools.pairwise(b)]
    assert segment_cumsum(x, b).tobytes() == np.concatenate([np.cumsum(s) for s in segs]).tobytes()
    z = segment_cumsum(x, b, start_zero=True)
    assert z.tobytes() == np.concatenate([np.concatenate(([0.0], np.cumsum(s))) for s in segs]).tobytes()
    d, db = segment_diffs(x, b)
    assert d.tobytes() == np.concatenate([np.diff(s) for s in segs] + [np.empty(0)]).tobytes()
    assert np.array_equal(np.diff(db), [max(len(s) - 1, 0) for s in segs])


@settings(max_examples=100, deadline=None)
@given(lengths, st.integers(0, 2**32 - 1), st.booleans(), st.booleans())
def test_segment_medians_equal_numpy_median(lens, seed, with_nan, batch):
    rng = np.random.default_rng(seed)
    b = bounds_of(lens)
    x = rng.integers(-5, 5, int(b[-1])).astype(float) * 0.7
    if with_nan and x.size:
        x[rng.integers(0, x.size, 3)] = np.nan
    g = segment_ids(b)
    x[x == 0] = rng.choice([0.0, -0.0], int((x == 0).sum()))  # signed zeros: numpy's median of -0.0 is 0.0
    with whole_batch(batch):
        got = segment_medians(x, g, len(lens))
        fins = segment_medians(x, g, len(lens), finite_only=True)
        plain = segment_medians(x, g, len(lens), finite_only=True, plain=True)
    for i, (a, c) in enumerate(itertools.pairwise(b)):
        want = np.median(x[a:c]) if c > a else np.nan
        assert (np.isnan(want) and np.isnan(got[i])) or want.tobytes() == got[i].tobytes()
        fin = x[a:c][np.isfinite(x[a:c])]
        f = fins[i]
        assert (fin.size == 0 and np.isnan(f)) or f.tobytes() == np.median(fin).tobytes()
    want_plain = _group_median(x, g, len(lens))  # the cleaning's own group median (np.lexsort)
    assert want_plain.tobytes() == plain.tobytes()


@pytest.mark.slow
@settings(max_examples=150, deadline=None)
@given(st.lists(st.integers(1, 60), min_size=1, max_size=8), st.integers(0, 2**32 - 1), st.booleans(),
       st.sampled_from(["left", "right"]))
def test_segment_searchsorted_and_interp_equal_numpy(lens, seed, global_order, side):
    """Within each segment as numpy on that segment alone: segments that follow each
    other in the values (trip times) or each starting again from 0 (trip distances),
    queries inside, outside, on and between the samples, NaN."""
    rng = np.random.default_rng(seed)
    b = bounds_of(lens)
    segs, fps = [], []
    t0 = 0.0
    for n in lens:
        s = np.cumsum(rng.choice([0.25, 1.0, 3.0, 1e-9], n)) + (t0 if global_order else 0.0)
        if global_order:
            t0 = s[-1] + rng.choice([0.0, 1e-9, 5.0])
            s = s + 1e-12  # strictly after the previous segment
        segs.append(s)
        fps.append(rng.choice([0.0, -0.0, 1.0, np.inf, 2.5, -3.0], n) if seed % 5 == 0 else rng.standard_normal(n))
    xp, fp = np.concatenate(segs), np.concatenate(fps)
    qs, qseg = [], []
    for i, s in enumerate(segs):
        q = np.concatenate((s, s - 1e-9, s + 0.5, [s[0] - 10, s[-1] + 10, np.nan]))
        qs.append(q)
        qseg.append(np.full(q.size, i))
    q, qseg = np.concatenate(qs), np.concatenate(qseg)
    pos = segment_searchsorted(xp, b[:-1], np.diff(b), q, qseg, side)
    want_pos = np.concatenate([np.searchsorted(s, qq, side) for s, qq in zip(segs, qs, strict=True)])
    assert np.array_equal(pos, want_pos)
    with np.errstate(invalid="ignore"):
        got = segment_interp(q, qseg, xp, b[:-1], np.diff(b), fp)
        want = np.concatenate([np.interp(qq, s, f) for s, f, qq in zip(segs, fps, qs, strict=True)])
    assert got.tobytes() == want.tobytes()


@settings(max_examples=40, deadline=None)
@given(st.lists(st.integers(0, 300), min_size=1, max_size=6), st.integers(0, 2**32 - 1))
def test_encode_profiles_equal_encode_profile_of_each(lens, seed):
    """The stored profiles of a batch's trips, made at once, are each trip's own
    encode_profile bytes (NaN, infinities, float32 overflow and empty trips too)."""
    from cevm.store.codec import PROFILE_DTYPES, encode_profile, encode_profiles

    rng = np.random.default_rng(seed)
    b = bounds_of(lens)
    n = int(b[-1])
    arrays = {name: np.cumsum(rng.standard_normal(n)) * 10.0 ** rng.integers(-3, 6) for name in PROFILE_DTYPES}
    if n:
        arrays["elevation_m"][rng.integers(0, n)] = 1e39  # beyond float32: inf
        arrays["lat_deg"][rng.integers(0, n)] = np.nan
    got = encode_profiles(arrays, b)
    assert got == [encode_profile({k: v[x:y] for k, v in arrays.items()}) for x, y in itertools.pairwise(b)]
    for blob, x, y in zip(got, b[:-1], b[1:], strict=True):
        assert blob == _format_2({k: v[x:y] for k, v in arrays.items()})


def _format_2(arrays) -> bytes:
    """Profile format 2 as documented (cevm.store.codec.encode_profile), one trip: each
    array cast, its bit patterns differenced from 0, byte-shuffled, zstd level 1."""
    import json
    import struct

    import pyarrow as pa

    from cevm.store.codec import PROFILE_DTYPES

    zstd = pa.Codec("zstd", compression_level=1)
    entries, payloads = [], []
    for name, dtype in PROFILE_DTYPES.items():
        with np.errstate(over="ignore"):
            a = np.ascontiguousarray(arrays[name], dtype=dtype)
        bits = a.view(np.uint64 if a.itemsize == 8 else np.uint32)
        delta = np.diff(bits, prepend=bits.dtype.type(0))
        payload = zstd.compress(delta.view(np.uint8).reshape(a.size, a.itemsize).T.tobytes(), asbytes=True)
        entries.append([name, dtype, len(payload)])
        payloads.append(payload)
    header = json.dumps({"n": int(a.size), "codec": "delta+shuffle+zstd", "arrays": entries}).encode()
    return b"".join([b"CEVMPRF2", struct.pack("<I", len(header)), header, *payloads])
