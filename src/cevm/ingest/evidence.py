"""Per-trip evidence from a clean trip's samples: ambient temperature and what the log
measured while the vehicle stood still (the :data:`cevm.core.trip.TRIP_EVIDENCE_FIELDS`).

These are evidence that a calibration checks its auxiliary and idle terms against
(what the vehicle drew standing still, at the logged temperature), never model inputs:
a prediction for a future trip would not have them.
Pure functions over a :class:`cevm.ingest.cleaning.CleanTrip`'s arrays; no I/O.

- **Ambient temperature** (``ambient_temp_c``, ``_min_c``, ``_max_c``): readings of the
  canonical ``ambient_temp_c`` inside ``ambient_range_c`` (FMS "not available" codes
  decode to far outside it), interpolated linearly in time and held at the trip's ends;
  the time-weighted mean over the trip (trapezoid rule, exact for that interpolant) and
  the interpolant's minimum and maximum. None without a reading, or when some instant
  of the trip is more than ``ambient_max_hold_s`` from the nearest reading (a
  temperature held that long is a guess, not a measurement).
- **Standstill** (``standstill_s``): the time of the grid steps whose two ends stand
  still (speed <= the cleaning's ``standstill_mps``) with the ignition on (the last
  ignition reading at or before each sample; unknown = on, as the trip split assumes).
- **Battery power at standstill** (``standstill_power_w``, EV): battery_voltage_v x
  battery_current_a (:func:`cevm.ingest.measured.window_samples`; readings beyond
  ``max_power_w`` rejected) interpolated onto the trip's samples over at most
  ``max_gap_s``, the trapezoid mean over the standstill steps where it is known. None
  without both columns, without standstill, or when it is known on less than
  ``min_standstill_coverage`` of the standstill time.
- **Fuel rate at standstill** (``standstill_fuel_lps``, ICE): the same mean of the
  flow meter's rate (``flowmeter_fuel_lps``) where it covers enough of the standstill
  time, else of the ECU's (``fuel_rate_lps``); readings outside [0, ``max_fuel_lps``]
  rejected. None without a rate.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from cevm.ingest.consumption import ConsumptionParams
from cevm.ingest.measured import interp_limited_segments, window_samples
from cevm.ingest.segments import bounds_of, ranges, segment_ids, segment_interp, segment_searchsorted, segment_sums

__all__ = ["EVIDENCE_COLUMNS", "EvidenceParams", "batch_evidence", "trip_evidence"]

#: Canonical columns whose readings a clean trip keeps for its evidence.
EVIDENCE_COLUMNS: tuple[str, ...] = (
    "ambient_temp_c", "battery_voltage_v", "battery_current_a", "flowmeter_fuel_lps", "fuel_rate_lps", "ignition",
)

#: Fuel-rate columns in order of preference at standstill (measured flow first).
STANDSTILL_FUEL_COLUMNS: tuple[str, ...] = ("flowmeter_fuel_lps", "fuel_rate_lps")


@dataclass(frozen=True)
class EvidenceParams:
    """Parameters of the per-trip evidence.

    - ``ambient_range_c = (-60, 60)``: plausible air temperatures at a road vehicle
      (the records of the inhabited world lie within them); FMS "not available"
      (0xFFFF x 0.03125 - 273 = 1775 degC) and error codes fall outside.
    - ``ambient_max_hold_s = 1800``: air temperature changes by a few degrees in half an
      hour at most (fronts, valleys), so a reading stands for that long either side.
    - ``min_standstill_coverage = 0.5``: a standstill mean from less than half of the
      standstill time is not reported (it would describe a few stops, not the trip).
    - ``consumption``: rate gaps and plausible bounds of battery power and fuel rate, as
      for the measured consumption (:class:`cevm.ingest.consumption.ConsumptionParams`).
    """

    ambient_range_c: tuple[float, float] = (-60.0, 60.0)
    ambient_max_hold_s: float = 1800.0
    min_standstill_coverage: float = 0.5
    consumption: ConsumptionParams = field(default_factory=ConsumptionParams)


def _accepted(m, standstill_s: float, params: EvidenceParams) -> float | None:
    if m is None or standstill_s <= 0:
        return None
    mean, covered = m
    if covered < params.min_standstill_coverage * standstill_s or not math.isfinite(mean):
        return None
    return float(mean)


def _mean_quality(m, standstill_s: float, rejected: int, params: EvidenceParams) -> dict:
    q: dict = {"rejected": rejected}
    if standstill_s <= 0:
        q["why_none"] = "no standstill in the trip"
        return q
    covered = 0.0 if m is None else m[1]
    q["coverage"] = covered / standstill_s
    if _accepted(m, standstill_s, params) is None:
        q["why_none"] = (f"known on {100 * covered / standstill_s:.0f} % of the standstill time "
                         f"(under {100 * params.min_standstill_coverage:.0f} %)")
    return q


def batch_evidence(t_abs: np.ndarray, speed_mps: np.ndarray, bounds: np.ndarray, row_t: np.ndarray,
                   rows: Mapping[str, np.ndarray], row_window: np.ndarray, standstill_mps: float,
                   params: EvidenceParams = EvidenceParams()) -> list[tuple[dict[str, float | None], dict]]:
    """The evidence fields and quality of every trip of a batch at once (the one
    implementation, for one trip as for a thousand; :func:`trip_evidence` is one trip's
    call of it).

    Parameters
    ----------
    t_abs : the trips' sample times [s, UTC epoch], end to end, strictly increasing
        within each trip; ``bounds``: each trip's (``n + 1`` offsets).
    speed_mps : speed at those samples [m/s].
    row_t : the times of the log's cleaned rows [s, UTC epoch], strictly increasing.
    rows : canonical columns (any of :data:`EVIDENCE_COLUMNS`) aligned with ``row_t``,
        NaN where a row carries no value.
    row_window : each trip's rows ``row_window[i] = (a, b)`` of ``row_t``.
    standstill_mps : the speed at or below which the vehicle stands still [m/s].

    Returns
    -------
    for each trip (fields, quality): ``fields`` maps every name of
    :data:`cevm.core.trip.TRIP_EVIDENCE_FIELDS` to a float or None; ``quality`` says
    where each came from and why a missing one is missing.
    """

    n = bounds.size - 1
    lo, hi = row_window[:, 0], row_window[:, 1]
    cols = {c: rows[c] for c in rows if c in EVIDENCE_COLUMNS}
    out_f: list[dict] = [{} for _ in range(n)]
    out_q: list[dict] = [{} for _ in range(n)]
    _batch_ambient(t_abs, bounds, row_t, cols.get("ambient_temp_c"), lo, hi, params, out_f, out_q)
    still, ign_note = _batch_standstill_steps(t_abs, speed_mps, bounds, row_t, cols.get("ignition"), lo, hi,
                                              standstill_mps)
    dt = np.diff(t_abs)
    sb = bounds_of(np.maximum(np.diff(bounds) - 1, 0))
    inner = np.ones(dt.size, dtype=bool)
    inner[bounds[1:-1] - 1] = False
    step_dt = dt[inner]
    standstill = segment_sums(step_dt[still], bounds_of(np.diff(_kept(still, sb)))).tolist()
    for i in range(n):
        out_f[i]["standstill_s"] = standstill[i]
        out_q[i]["standstill"] = {"s": standstill[i], "ignition": ign_note[i]}
    cp = params.consumption
    step_seg = segment_ids(sb)
    t_before = t_abs[:-1][inner]
    t_after = t_abs[1:][inner]

    def means(ts, vs, tb) -> list:
        """(mean, covered time [s]) of a sampled rate (``tb``: each trip's samples) over
        each trip's standstill steps where it is known (trapezoid on the trip's
        samples), None for a trip where it is known on none."""
        si = np.flatnonzero(still)
        seg = step_seg[si]
        r0, r1 = interp_limited_segments(np.concatenate((t_before[si], t_after[si])), np.concatenate((seg, seg)),
                                         ts, tb, vs, max_gap_s=cp.max_gap_s)[0].reshape(2, -1)
        known = np.isfinite(r0) & np.isfinite(r1)
        d = (t_after[si] - t_before[si])[known]
        kb = bounds_of(np.bincount(seg[known], minlength=n))
        covered = segment_sums(d, kb)
        total = segment_sums(0.5 * (r0[known] + r1[known]) * d, kb)
        has = np.diff(tb) > 0
        any_still = np.bincount(seg, minlength=n) > 0
        return [(float(total[i]) / float(covered[i]), float(covered[i]))
                if has[i] and any_still[i] and covered[i] > 0 else None for i in range(n)]

    if "battery_voltage_v" in cols and "battery_current_a" in cols:
        ts, p, tb = window_samples(row_t, cols, "battery_power_w", lo, hi, cp.max_gap_s)
        ok = np.abs(p) <= cp.max_power_w
        rejected = np.diff(_kept(~ok, tb)).tolist()
        power = means(ts[ok], p[ok], _kept(ok, tb))
        for i in range(n):
            out_q[i]["standstill_power"] = _mean_quality(power[i], standstill[i], rejected[i], params)
            out_f[i]["standstill_power_w"] = _accepted(power[i], standstill[i], params)
    else:
        for i in range(n):
            out_q[i]["standstill_power"] = {"why_none": "no battery_voltage_v and battery_current_a"}
            out_f[i]["standstill_power_w"] = None
    candidates: list[list] = [[] for _ in range(n)]
    for col in STANDSTILL_FUEL_COLUMNS:
        if col in cols:
            ts, a, tb = window_samples(row_t, {col: cols[col]}, col, lo, hi, cp.max_gap_s)  # the finite readings
            ok = (a >= 0.0) & (a <= cp.max_fuel_lps)
            rejected = np.diff(_kept(~ok, tb)).tolist()
            m = means(ts[ok], a[ok], _kept(ok, tb))
            for i in range(n):
                candidates[i].append((m[i], {"source": col, **_mean_quality(m[i], standstill[i], rejected[i], params)}))
    for i in range(n):
        fuel, fuel_q = None, {"why_none": "no fuel rate column"}
        usable = [c for c in candidates[i] if _accepted(c[0], standstill[i], params) is not None]
        if usable or candidates[i]:
            fuel, fuel_q = (usable or candidates[i])[0]
        out_f[i]["standstill_fuel_lps"] = _accepted(fuel, standstill[i], params)
        out_q[i]["standstill_fuel"] = fuel_q
    order = ("ambient_temp_c", "ambient_temp_min_c", "ambient_temp_max_c", "standstill_s", "standstill_power_w",
             "standstill_fuel_lps")
    return [({k: f[k] for k in order}, q) for f, q in zip(out_f, out_q, strict=True)]


def trip_evidence(t_abs_s: np.ndarray, speed_mps: np.ndarray, row_t_s: np.ndarray, rows: Mapping[str, np.ndarray],
                  standstill_mps: float, params: EvidenceParams = EvidenceParams()
                  ) -> tuple[dict[str, float | None], dict]:
    """:func:`batch_evidence` of one trip (its samples ``t_abs_s``, ``speed_mps``) with
    the log's rows ``row_t_s``, ``rows`` around it."""
    t = np.asarray(t_abs_s, dtype=np.float64)
    row_t = np.asarray(row_t_s, dtype=np.float64)
    return batch_evidence(t, np.asarray(speed_mps, dtype=np.float64), np.array([0, t.size]), row_t,
                          {c: np.asarray(x, dtype=np.float64) for c, x in rows.items()},
                          np.array([[0, row_t.size]]), standstill_mps, params)[0]


def _kept(mask: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    cs = np.zeros(mask.size + 1, dtype=np.int64)
    np.cumsum(mask, out=cs[1:])
    return cs[bounds]


def _batch_ambient(t_abs, bounds, row_t, temp, lo, hi, params: EvidenceParams, out_f, out_q) -> None:
    """The ambient temperature of every trip (into ``out_f`` and ``out_q``): readings
    within ``ambient_range_c`` and ``ambient_max_hold_s`` of the trip, the trapezoid
    mean of their interpolant over the trip, its minimum and maximum; none when some
    instant of the trip is farther than ``ambient_max_hold_s`` from a reading."""

    n = bounds.size - 1
    none = {"ambient_temp_c": None, "ambient_temp_min_c": None, "ambient_temp_max_c": None}
    if temp is None:
        for i in range(n):
            out_q[i]["ambient_temp"] = {"why_none": "no ambient_temp_c column"}
            out_f[i].update(none)
        return
    t0, t1 = t_abs[bounds[:-1]], t_abs[bounds[1:] - 1]
    # each trip's window of the rows that carry a reading (a temperature is logged far
    # less often than the rows: the windows' other rows are never gathered)
    temp = np.asarray(temp)
    r0, r1 = int(lo.min()), int(hi.max())  # the batch's rows (``row_t`` is the whole log's)
    fin_rows = np.flatnonzero(np.isfinite(temp[r0:r1])) + r0
    flo, fhi = np.searchsorted(fin_rows, lo), np.searchsorted(fin_rows, hi)
    rr = fin_rows[ranges(flo, fhi - flo)]
    wb = bounds_of(fhi - flo)
    a = temp[rr].astype(np.float64, copy=False)
    rt_all = row_t[rr]
    seg = np.repeat(np.arange(n), fhi - flo)
    lo_c, hi_c = params.ambient_range_c
    ok = (a >= lo_c) & (a <= hi_c)
    hold = params.ambient_max_hold_s
    sel = ok & (rt_all >= t0[seg] - hold) & (rt_all <= t1[seg] + hold)
    rejected = np.bincount(seg[~ok], minlength=n)
    rt, rv, rs = rt_all[sel], a[sel], seg[sel]
    rb = _kept(sel, wb)
    readings = np.bincount(rs[(rt >= t0[rs]) & (rt <= t1[rs])], minlength=n)
    counts = np.diff(rb)
    for i in range(n):
        out_q[i]["ambient_temp"] = {"readings": int(readings[i]), "rejected": int(rejected[i])}
    has = np.flatnonzero(counts > 0)
    for i in np.flatnonzero(counts == 0).tolist():
        out_q[i]["ambient_temp"]["why_none"] = "no plausible reading within the trip"
        out_f[i].update(none)
    if not has.size:
        return
    # the farthest instant of each trip from a reading: t0, t1, or a midpoint of two
    # consecutive readings inside [t0, t1] (one outside stands at t0 or t1: no farther)
    starts, lens = rb[has], counts[has]
    t0h, t1h = t0[has], t1[has]
    trip = np.arange(has.size)
    ends, eseg = np.concatenate((t0h, t1h)), np.concatenate((trip, trip))
    k = segment_searchsorted(rt, starts, lens, ends, eseg, "left")
    ln, first = lens[eseg], starts[eseg]
    before = np.abs(ends - rt[first + np.minimum(np.maximum(k - 1, 0), ln - 1)])
    after = np.abs(rt[first + np.minimum(np.maximum(k, 0), ln - 1)] - ends)
    near = np.minimum(before, after)
    far = np.maximum(near[:has.size], near[has.size:])
    mrows = ranges(starts, lens - 1)
    mseg = np.repeat(trip, lens - 1)
    mid = 0.5 * (rt[mrows + 1] + rt[mrows])
    within = (mid >= t0h[mseg]) & (mid <= t1h[mseg])  # its nearest readings: the two it lies between
    np.maximum.at(far, mseg[within], np.minimum(np.abs(mid - rt[mrows]), np.abs(rt[mrows + 1] - mid))[within])
    for g, i in enumerate(has.tolist()):
        out_q[i]["ambient_temp"]["max_hold_s"] = float(far[g])
    good = far <= hold
    for g in np.flatnonzero(~good).tolist():
        i = int(has[g])
        out_q[i]["ambient_temp"]["why_none"] = (f"some instant of the trip is {float(far[g]):.0f} s from a reading "
                                                f"(over {hold:g} s)")
        out_f[i].update(none)
    gi = has[good]
    if not gi.size:
        return
    g_starts, g_lens = rb[gi], counts[gi]
    gt0, gt1 = t0[gi], t1[gi]
    gseg = np.repeat(np.arange(gi.size), g_lens)
    grt = rt[ranges(g_starts, g_lens)]
    inside = (grt > gt0[gseg]) & (grt < gt1[gseg])
    n_in = np.bincount(gseg[inside], minlength=gi.size)
    pb = np.concatenate(([0], np.cumsum(n_in + 2)))
    pts = np.empty(int(pb[-1]))
    pts[pb[:-1]] = gt0
    pts[pb[1:] - 1] = gt1
    at_readings = ranges(pb[:-1] + 1, n_in)
    pts[at_readings] = grt[inside]
    # the interpolant: a reading's own value at its time (np.interp's exact match), so
    # only t0 and t1 of each trip are interpolated
    vals = np.empty(pts.size)
    vals[at_readings] = rv[ranges(g_starts, g_lens)][inside]
    ends = np.concatenate((pb[:-1], pb[1:] - 1))
    trip = np.arange(gi.size)
    vals[ends] = segment_interp(pts[ends], np.concatenate((trip, trip)), rt, g_starts, g_lens, rv)
    steps = np.ones(pts.size - 1, dtype=bool)
    steps[pb[1:-1] - 1] = False
    terms = (0.5 * (vals[1:] + vals[:-1]) * np.diff(pts))[steps]
    sums = segment_sums(terms, np.concatenate(([0], np.cumsum(n_in + 1))))
    vmin = np.minimum.reduceat(vals, pb[:-1])
    vmax = np.maximum.reduceat(vals, pb[:-1])
    duration = gt1 - gt0
    for g, i in enumerate(gi.tolist()):
        mean = float(sums[g] / duration[g]) if duration[g] > 0 else float(vals[pb[g]])
        out_f[i].update({"ambient_temp_c": mean, "ambient_temp_min_c": float(vmin[g]),
                         "ambient_temp_max_c": float(vmax[g])})


def _batch_standstill_steps(t_abs, v, bounds, row_t, ignition, lo, hi, standstill_mps: float
                            ) -> tuple[np.ndarray, list[str]]:
    """The steps of every trip (within trips, end to end) standing still with the
    ignition on at both ends (the last ignition reading at or before each sample;
    unknown = on), and each trip's ignition note."""

    n = bounds.size - 1
    inner = np.ones(max(v.size - 1, 0), dtype=bool)
    inner[bounds[1:-1] - 1] = False
    still = ((v[1:] <= standstill_mps) & (v[:-1] <= standstill_mps))[inner]
    if ignition is None:
        return still, ["no ignition column: on (the trip)"] * n
    rr = ranges(lo, hi - lo)
    ign = np.asarray(ignition)[rr].astype(np.float64, copy=False)
    ok = np.isfinite(ign)
    seg = np.repeat(np.arange(n), hi - lo)
    kb = _kept(ok, np.concatenate(([0], np.cumsum(hi - lo))))
    has = np.diff(kb) > 0
    notes = ["from the ignition column" if h else "no ignition reading: on (the trip)" for h in has.tolist()]
    if not has.any():
        return still, notes
    it, iv = row_t[rr][ok], ign[ok]
    sseg = np.repeat(np.arange(n), np.diff(bounds))
    j = segment_searchsorted(it, kb[:-1], np.diff(kb), t_abs, sseg, "right") - 1
    on = ~((j >= 0) & (iv[np.minimum(kb[:-1][sseg] + np.maximum(j, 0), max(iv.size - 1, 0))] < 0.5))
    on |= ~has[sseg]  # no reading: on
    del seg
    return still & on[1:][inner] & on[:-1][inner], notes
