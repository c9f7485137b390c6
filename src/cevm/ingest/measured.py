"""The measured consumption of the trips of one log, all at once: :func:`measure_trips`
(the one implementation, for one trip as for a thousand; :func:`measure_trip` is one
trip's call of it). What is measured, and how a source is chosen, is in
:mod:`cevm.ingest.consumption`.

Each source's samples are taken from every trip's window of the log (``max_gap_s``
either side of it: overlapping windows of consecutive trips give each trip its own
samples), end to end, and the estimators (integrated rate, counter increase, state of
charge) run over all the trips' samples at once (:mod:`cevm.ingest.segments`: sums in
numpy's pairwise order, medians, interpolation within each trip); the choice among a
trip's sources and the quality it reports are those of
:func:`~cevm.ingest.consumption.choose_measurement`. ``tests/test_measured.py`` checks
on random logs that a trip measured among many is measured as when it is alone, and
``tests/test_consumption.py`` each estimator against hand computations.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from cevm.core.trip import Measurement
from cevm.ingest.consumption import (
    NO_CAPACITY,
    ConsumptionParams,
    EnergySourceLike,
    RawEstimate,
    SourceEstimate,
    choose_measurement,
    finish_estimate,
    invalid_estimate,
    product_factors,
)
from cevm.ingest.segments import (
    bounds_of,
    ranges,
    segment_diffs,
    segment_ids,
    segment_interp,
    segment_medians,
    segment_searchsorted,
    segment_sums,
)

__all__ = ["counter_increases", "integrate_rates", "interp_limited_segments", "measure_trip", "measure_trips",
           "soc_energies", "window_samples"]


def measure_trips(time_s: np.ndarray, columns: Mapping[str, np.ndarray], sources: Sequence[EnergySourceLike],
                  t0: np.ndarray, t1: np.ndarray, params: ConsumptionParams = ConsumptionParams()
                  ) -> list[tuple[Measurement | None, dict]]:
    """The measured consumption of each trip ``[t0[i], t1[i]]`` [s] of one log
    (``time_s`` strictly increasing, ``columns`` aligned with it): for each, the
    chosen measurement or None and its quality
    (:func:`~cevm.ingest.consumption.choose_measurement`)."""
    t0 = np.asarray(t0, dtype=np.float64)
    t1 = np.asarray(t1, dtype=np.float64)
    per_source = [_estimates(time_s, columns, s, t0, t1, params) for s in sources]
    return [choose_measurement([est[i] for est in per_source], params) for i in range(t0.size)]


def measure_trip(time_s: np.ndarray, columns: Mapping[str, np.ndarray], sources: Sequence[EnergySourceLike],
                 t0: float, t1: float, params: ConsumptionParams = ConsumptionParams()
                 ) -> tuple[Measurement | None, dict]:
    """:func:`measure_trips` of the one trip ``[t0, t1]`` [s]."""
    return measure_trips(time_s, columns, sources, np.array([t0], dtype=np.float64),
                         np.array([t1], dtype=np.float64), params)[0]


def estimate_sources(time_s: np.ndarray, columns: Mapping[str, np.ndarray], source: EnergySourceLike,
                     t0: np.ndarray, t1: np.ndarray, params: ConsumptionParams = ConsumptionParams()
                     ) -> list[SourceEstimate]:
    """One source's estimate for each trip ``[t0[i], t1[i]]`` [s] (valid or not, and
    why): what :func:`measure_trips` chooses among."""
    return _estimates(time_s, columns, source, np.asarray(t0, dtype=np.float64),
                      np.asarray(t1, dtype=np.float64), params)


def _estimates(time_s: np.ndarray, columns: Mapping[str, np.ndarray], source: EnergySourceLike, t0: np.ndarray,
               t1: np.ndarray, params: ConsumptionParams) -> list[SourceEstimate]:
    """One source's estimate for each trip (:func:`estimate_sources`)."""
    n = t0.size
    kind, quantity = str(source.kind), str(source.quantity)
    res = float(source.resolution)
    if quantity not in ("fuel_l", "energy_j"):
        return [invalid_estimate(source, f"unknown quantity {quantity!r}")] * n
    max_rate = params.max_fuel_lps if quantity == "fuel_l" else params.max_power_w
    lo = np.searchsorted(time_s, t0 - params.max_gap_s, side="left")
    hi = np.searchsorted(time_s, t1 + params.max_gap_s, side="right")
    try:
        ts, vs, sb = window_samples(time_s, columns, str(source.column), lo, hi, params.max_gap_s)
    except KeyError:
        return [invalid_estimate(source, "column not in the log")] * n
    if kind == "rate":
        # negative fuel flow is impossible; power may be negative (regeneration)
        lim_lo = 0.0 if quantity == "fuel_l" else -max_rate
        ok = (vs >= lim_lo - 2 * abs(res)) & (vs <= max_rate)
        rejected = np.diff(_kept_bounds(~ok, sb)).tolist()
        raws = integrate_rates(ts[ok], vs[ok], _kept_bounds(ok, sb), t0, t1, max_gap_s=params.max_gap_s,
                               resolution=res)
        for raw, k in zip(raws, rejected, strict=True):
            raw.counts["rate_values_rejected"] = k
        resolution = 0.0
    elif kind == "counter":
        raws = counter_increases(ts, vs, sb, t0, t1, resolution=res, max_rate=max_rate,
                                 max_rate_neg=0.0 if quantity == "fuel_l" else max_rate,
                                 modulus=getattr(source, "modulus", None), reset_fraction=params.reset_fraction)
        resolution = abs(res)
    elif kind == "soc":
        cap = getattr(source, "capacity_j", None)
        ok = (vs >= 0) & (vs <= 100)
        if quantity != "energy_j" or cap is None or not cap > 0:
            readings = np.diff(_kept_bounds(ok, sb))  # a trip with readings says why they measured nothing
            return [invalid_estimate(source, NO_CAPACITY if k >= 2 else
                                     "SoC source needs quantity 'energy_j' and a capacity_j > 0")
                    for k in readings.tolist()]
        raws = soc_energies(ts[ok], vs[ok], _kept_bounds(ok, sb), t0, t1, resolution_pct=res, capacity_j=float(cap))
        resolution = abs(res) / 100.0 * float(cap)
    else:
        return [invalid_estimate(source, f"unknown kind {kind!r}")] * n
    return [finish_estimate(source, raw, resolution, params) for raw in raws]


def _kept_bounds(mask: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    """The bounds of the segments of ``bounds`` after keeping the elements ``mask``."""
    cs = np.zeros(mask.size + 1, dtype=np.int64)
    np.cumsum(mask, out=cs[1:])
    return cs[bounds]


def window_samples(time_s: np.ndarray, columns: Mapping[str, np.ndarray], column: str, lo: np.ndarray,
                   hi: np.ndarray, max_gap_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The valid samples (times [s], values) of a source column in each window
    ``lo[i]:hi[i]`` of the log, every window's end to end, and their bounds. A product
    column ``"a*b"`` or ``"battery_power_w"`` is evaluated at the times where either
    factor has a value, each factor interpolated linearly within its window over at
    most ``max_gap_s`` [s]. Raises KeyError when a needed column is missing."""
    lens = hi - lo
    rows = ranges(lo, lens)
    wb = bounds_of(lens)
    tw = time_s[rows]
    if column in columns:
        v = np.asarray(columns[column])[rows].astype(np.float64, copy=False)
        ok = np.isfinite(v)
        return tw[ok], v[ok], _kept_bounds(ok, wb)
    arrays = [np.asarray(columns[f])[rows].astype(np.float64, copy=False)
              for f in product_factors(column)]  # KeyError if absent
    oks = [np.isfinite(a) for a in arrays]
    any_ok = np.logical_or.reduce(oks)
    q, qb = tw[any_ok], _kept_bounds(any_ok, wb)
    own = [np.array_equal(ok, any_ok) for ok in oks]  # sampled at every q: its own values
    qseg = segment_ids(qb) if not all(own) else np.zeros(0, dtype=np.int64)
    prod = np.ones(q.shape)
    for a, ok, at_q in zip(arrays, oks, own, strict=True):
        if at_q:  # what interpolating at its own sample times gives, without the search
            prod *= a[ok]
        else:  # a factor sampled at a time of q gives its own value there (exact interpolation)
            prod *= interp_limited_segments(q, qseg, tw[ok], _kept_bounds(ok, wb), a[ok], max_gap_s=max_gap_s)[0]
    ok = np.isfinite(prod)
    return q[ok], prod[ok], _kept_bounds(ok, qb)


def interp_limited_segments(q: np.ndarray, qseg: np.ndarray, ts: np.ndarray, sb: np.ndarray, *values: np.ndarray,
                            max_gap_s: float) -> list[np.ndarray]:
    """:func:`~cevm.ingest.consumption.interp_limited` of the samples of each segment
    (``ts`` strictly increasing within each, bounds ``sb``; ``values`` sharing them) at
    the times ``q`` of that segment (``qseg``): linear, NaN outside a segment's samples
    or between two samples more than ``max_gap_s`` apart (exact sample times always get
    their value)."""
    starts, lens = sb[:-1], np.diff(sb)
    n = lens[qseg]
    s = starts[qseg]
    right = segment_searchsorted(ts, starts, lens, q, qseg, "left")
    has = n > 0
    rc = s + np.where(has, np.minimum(right, n - 1), 0)
    lc = s + np.where(has, np.maximum(right - 1, 0), 0)
    if ts.size:
        rc, lc = np.minimum(rc, ts.size - 1), np.minimum(lc, ts.size - 1)
        trc, tlc = ts[rc], ts[lc]
    else:
        trc = tlc = np.full(q.size, np.nan)
    exact = has & (trc == q)
    span = trc - tlc
    ok = has & (right > 0) & (right < n) & (span <= max_gap_s) & (span > 0)
    w = (q - tlc) / np.where(ok, span, 1.0)
    miss = ~(ok | exact)
    out = []
    for a in values:
        if a.size:
            ar, al = a[rc], a[lc]
            val = np.where(exact, ar, al + w * (ar - al))
        else:
            val = np.full(q.size, np.nan)
        val[miss] = np.nan
        out.append(val)
    return out


def integrate_rates(ts: np.ndarray, rate: np.ndarray, sb: np.ndarray, t0: np.ndarray, t1: np.ndarray, *,
                    max_gap_s: float = 15.0, resolution: float = 0.0) -> list[RawEstimate]:
    """Integral of each trip's sampled rate [unit/s] (``ts`` strictly increasing within
    each trip, ``sb``: the trips' bounds) over ``[t0[i], t1[i]]`` [s] -> [unit].

    Trapezoid rule on the piecewise-linear interpolant through the samples (values
    outside the samples held at the edge value), evaluated at ``t0``, every sample
    strictly inside, and ``t1``. Steps longer than ``max_gap_s`` count as gaps.
    Uncertainty: see :mod:`cevm.ingest.consumption`."""
    n = t0.size
    duration = t1 - t0
    ok = np.isfinite(ts) & np.isfinite(rate)
    if not ok.all():
        ts, rate, sb = ts[ok], rate[ok], _kept_bounds(ok, sb)
    lens = np.diff(sb)
    out: list[RawEstimate | None] = [None] * n
    todo = []
    for i in range(n):
        if lens[i] == 0 or duration[i] < 0:
            out[i] = RawEstimate(math.nan, math.nan, 0.0, 1.0, {}, "no samples")
        elif duration[i] == 0:
            out[i] = RawEstimate(0.0, 0.0, 1.0, 0.0, {"rate_gaps": 0})
        else:
            todo.append(i)
    if not todo:
        return out  # type: ignore[return-value]
    tk = np.asarray(todo, dtype=np.int64)
    rows = ranges(sb[tk], lens[tk])
    ts, rate, sb = ts[rows], rate[rows], bounds_of(lens[tk])
    a, b = t0[tk], t1[tk]
    seg = segment_ids(sb)
    inside = (ts > a[seg]) & (ts < b[seg])
    n_in = np.diff(_kept_bounds(inside, sb))
    pb = bounds_of(n_in + 2)  # t0, the samples strictly inside, t1
    pts = np.empty(int(pb[-1]))
    pts[pb[:-1]] = a
    pts[pb[1:] - 1] = b
    at_samples = ranges(pb[:-1] + 1, n_in)
    pts[at_samples] = ts[inside]
    # the interpolant's values: a sample's own value at its time (np.interp's exact
    # match), so only t0 and t1 of each trip are interpolated
    vals = np.empty(pts.size)
    vals[at_samples] = rate[inside]
    ends = np.concatenate((pb[:-1], pb[1:] - 1))
    trip = np.arange(tk.size)
    vals[ends] = segment_interp(pts[ends], np.concatenate((trip, trip)), ts, sb[:-1], np.diff(sb), rate)
    dts, db = segment_diffs(pts, pb)
    inner = _inner_steps(pb)
    value = segment_sums((0.5 * (vals[1:] + vals[:-1]) * np.diff(pts))[inner], db)
    gap = dts > max_gap_s
    gb = _kept_bounds(gap, db)
    gap_s = segment_sums(dts[gap], gb)
    gap_share = gap_s / (b - a)
    half = 0.5 * dts
    w = np.zeros(pts.size)  # each point's trapezoid weight: its step after, then its step before
    first, last = pb[:-1], pb[1:] - 1
    not_last = np.ones(pts.size, dtype=bool)
    not_last[last] = False
    not_first = np.ones(pts.size, dtype=bool)
    not_first[first] = False
    w[not_last] += half
    w[not_first] += half
    var = (resolution**2 / 12.0) * segment_sums(w * w, pb)
    n_gaps = np.diff(gb)
    if n_gaps.any():
        g = np.flatnonzero(n_gaps > 0)
        sd = _stds(vals, pb, g)
        sq = segment_sums(dts[gap] ** 2, gb)
        for k, i in enumerate(g.tolist()):
            var[i] = float(var[i]) + float(sd[k]) ** 2 * float(sq[i])
    for k, i in enumerate(todo):
        gs = float(gap_share[k])
        out[i] = RawEstimate(float(value[k]), math.sqrt(float(var[k])), 1.0 - gs, gs, {"rate_gaps": int(n_gaps[k])})
    return out  # type: ignore[return-value]


def _inner_steps(bounds: np.ndarray) -> np.ndarray:
    """Which steps (i to i + 1) of the concatenated segments lie within one segment."""
    inner = np.ones(max(int(bounds[-1]) - 1, 0), dtype=bool)
    inner[bounds[1:-1] - 1] = False
    return inner


def _stds(x: np.ndarray, bounds: np.ndarray, which: np.ndarray) -> np.ndarray:
    """``np.std`` of the segments ``which`` of ``x``: the mean (pairwise sum over the
    count), then the pairwise sum of the squared deviations over the count, its root."""
    lens = np.diff(bounds)[which]
    rows = ranges(bounds[which], lens)
    sub, sb = x[rows], bounds_of(lens)
    mean = segment_sums(sub, sb) / lens
    dev = sub - np.repeat(mean, lens)
    return np.sqrt(segment_sums(dev * dev, sb) / lens)


def _trip_readings(ts: np.ndarray, vs: np.ndarray, sb: np.ndarray, t0: np.ndarray, t1: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each trip's finite readings inside ``[t0, t1]``, end to end, and their bounds."""
    seg = segment_ids(sb)
    sel = (ts >= t0[seg]) & (ts <= t1[seg]) & np.isfinite(vs)
    return ts[sel], vs[sel], _kept_bounds(sel, sb)


def counter_increases(ts: np.ndarray, counter: np.ndarray, sb: np.ndarray, t0: np.ndarray, t1: np.ndarray, *,
                      resolution: float, max_rate: float, max_rate_neg: float = 0.0, modulus: float | None = None,
                      reset_fraction: float = 0.01) -> list[RawEstimate]:
    """Increase of each trip's cumulative counter [unit] (samples ``sb``: their bounds)
    between its first and last reading in ``[t0[i], t1[i]]`` [s], with wraps, resets
    and jumps handled as in :mod:`cevm.ingest.consumption`. ``max_rate`` /
    ``max_rate_neg`` [unit/s] bound plausible forward / backward steps; a reset is a
    drop to near zero relative to the counter's level (the previous reading, or the
    trip's median reading if smaller, so that coming down from a glitch is not one)."""
    n = t0.size
    duration = t1 - t0
    t, c, cb = _trip_readings(ts, counter, sb, t0, t1)
    lens = np.diff(cb)
    good = (lens >= 2) & (duration > 0)
    out: list[RawEstimate] = [RawEstimate(math.nan, math.nan, 0.0, 1.0, {}, "fewer than 2 readings")] * n
    if not good.any():
        return out
    out = list(out)
    gi = np.flatnonzero(good)
    if not good.all():
        rows = ranges(cb[gi], lens[gi])
        t, c, cb, lens = t[rows], c[rows], bounds_of(lens[gi]), lens[gi]
    d, db = segment_diffs(c, cb)
    dt, _ = segment_diffs(t, cb)
    q = abs(resolution)
    wraps = np.zeros(d.shape, dtype=bool)
    if modulus is not None and modulus > 0:
        wraps = d < -0.5 * modulus
        d = np.where(wraps, d + modulus, d)
    plausible = (d >= -max_rate_neg * dt - 2 * q) & (d <= max_rate * dt + 2 * q)
    med = np.abs(segment_medians(c, segment_ids(cb), gi.size))
    not_last = np.ones(c.size, dtype=bool)
    not_last[cb[1:] - 1] = False
    not_first = np.ones(c.size, dtype=bool)
    not_first[cb[:-1]] = False
    step_trip = segment_ids(db)
    level = np.minimum(np.abs(c[not_last]), med[step_trip])
    resets = ~plausible & (d < 0) & (c[not_first] <= reset_fraction * level + 2 * q)
    jumps = ~plausible & ~resets
    lost = resets | jumps
    d = np.where(lost, 0.0, d)
    value = segment_sums(d, db)
    covered = t[cb[1:] - 1] - t[cb[:-1]]
    lb = _kept_bounds(lost, db)
    lost_trip = segment_ids(lb)
    k_wraps = np.diff(_kept_bounds(wraps, db))
    k_resets = np.diff(_kept_bounds(resets, db))
    k_jumps = np.diff(_kept_bounds(jumps, db))
    mean_rate = np.where(covered > 0, value / np.where(covered > 0, covered, 1.0), 0.0)
    lost_sq = segment_sums((mean_rate[lost_trip] * dt[lost]) ** 2, lb)
    for k, i in enumerate(gi.tolist()):
        dur, cov, mr = float(duration[i]), float(covered[k]), float(mean_rate[k])
        var = q * q / 6.0
        var += float(lost_sq[k])
        var += (mr * (dur - cov)) ** 2
        counts = {"counter_wraps": int(k_wraps[k]), "counter_resets": int(k_resets[k]),
                  "counter_jumps": int(k_jumps[k])}
        out[i] = RawEstimate(float(value[k]), math.sqrt(var), cov / dur, 1.0 - cov / dur, counts)
    return out


def soc_energies(ts: np.ndarray, soc_pct: np.ndarray, sb: np.ndarray, t0: np.ndarray, t1: np.ndarray, *,
                 resolution_pct: float, capacity_j: float) -> list[RawEstimate]:
    """Battery energy [J] each trip used over ``[t0[i], t1[i]]`` [s] from the first and
    last state-of-charge readings [%] in the span (samples ``sb``: their bounds):
    (soc_first - soc_last) / 100 * capacity_j."""
    duration = t1 - t0
    t, s, cb = _trip_readings(ts, soc_pct, sb, t0, t1)
    lens = np.diff(cb)
    q_j = abs(resolution_pct) / 100.0 * capacity_j
    out = []
    for i in range(t0.size):
        dur = float(duration[i])
        if lens[i] < 2 or dur <= 0:
            out.append(RawEstimate(math.nan, math.nan, 0.0, 1.0, {}, "fewer than 2 readings"))
            continue
        a, b = int(cb[i]), int(cb[i + 1]) - 1
        value = float((s[a] - s[b]) / 100.0 * capacity_j)
        covered = float(t[b] - t[a])
        coverage = covered / dur
        mean_rate = value / covered if covered > 0 else 0.0
        var = q_j * q_j / 6.0 + (mean_rate * (dur - covered)) ** 2
        out.append(RawEstimate(value, math.sqrt(var), coverage, 1.0 - coverage, {}))
    return out
