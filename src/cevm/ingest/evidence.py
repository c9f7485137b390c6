"""Per-trip evidence from a clean trip's samples: ambient temperature and what the log
measured while the vehicle stood still (the :data:`cevm.core.trip.TRIP_EVIDENCE_FIELDS`).

These are evidence that a calibration checks its auxiliary and idle terms against
(issue 15), never model inputs: a prediction for a future trip would not have them.
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
  battery_current_a (:func:`cevm.ingest.consumption.source_samples`; readings beyond
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

from cevm.ingest.consumption import ConsumptionParams, _interp_limited, source_samples

__all__ = ["EVIDENCE_COLUMNS", "EvidenceParams", "trip_evidence"]

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


def trip_evidence(
    t_abs_s: np.ndarray,
    speed_mps: np.ndarray,
    row_t_s: np.ndarray,
    rows: Mapping[str, np.ndarray],
    standstill_mps: float,
    params: EvidenceParams = EvidenceParams(),
) -> tuple[dict[str, float | None], dict]:
    """The evidence fields of one trip and a JSON-serialisable quality dict.

    Parameters
    ----------
    t_abs_s : the trip's sample times [s, UTC epoch], strictly increasing.
    speed_mps : speed at those samples [m/s].
    row_t_s : the times of the log's cleaned rows around the trip [s, UTC epoch],
        strictly increasing.
    rows : canonical columns (any of :data:`EVIDENCE_COLUMNS`) aligned with ``row_t_s``,
        NaN where a row carries no value.
    standstill_mps : the speed at or below which the vehicle stands still [m/s].
    params : :class:`EvidenceParams`.

    Returns
    -------
    (fields, quality): ``fields`` maps every name of
    :data:`cevm.core.trip.TRIP_EVIDENCE_FIELDS` to a float or None; ``quality`` says
    where each came from and why a missing one is missing.
    """
    t = np.asarray(t_abs_s, dtype=np.float64)
    v = np.asarray(speed_mps, dtype=np.float64)
    row_t = np.asarray(row_t_s, dtype=np.float64)
    fields: dict[str, float | None] = {}
    quality: dict = {}
    fields.update(_ambient(t, row_t, rows.get("ambient_temp_c"), params, quality))
    still, ign_note = _standstill_steps(t, v, row_t, rows.get("ignition"), standstill_mps)
    dt = np.diff(t)
    standstill_s = float(dt[still].sum()) if t.size > 1 else 0.0
    fields["standstill_s"] = standstill_s
    quality["standstill"] = {"s": standstill_s, "ignition": ign_note}
    cp = params.consumption
    power = None
    if "battery_voltage_v" in rows and "battery_current_a" in rows:
        ts, p = source_samples(row_t, rows, "battery_power_w", cp.max_gap_s)
        ok = np.abs(p) <= cp.max_power_w
        power = _standstill_mean(t, still, ts[ok], p[ok], cp.max_gap_s)
        quality["standstill_power"] = _mean_quality(power, standstill_s, int((~ok).sum()), params)
    else:
        quality["standstill_power"] = {"why_none": "no battery_voltage_v and battery_current_a"}
    fields["standstill_power_w"] = _accepted(power, standstill_s, params)
    fuel = None
    fuel_q: dict = {"why_none": "no fuel rate column"}
    candidates = []
    for col in STANDSTILL_FUEL_COLUMNS:
        if col in rows:
            a = np.asarray(rows[col], dtype=np.float64)
            fin = np.isfinite(a)
            ok = fin & (a >= 0.0) & (a <= cp.max_fuel_lps)
            m = _standstill_mean(t, still, row_t[ok], a[ok], cp.max_gap_s)
            candidates.append((m, {"source": col, **_mean_quality(m, standstill_s, int((fin & ~ok).sum()), params)}))
    usable = [c for c in candidates if _accepted(c[0], standstill_s, params) is not None]
    if usable or candidates:
        fuel, fuel_q = (usable or candidates)[0]  # the first usable in order of preference
    fields["standstill_fuel_lps"] = _accepted(fuel, standstill_s, params)
    quality["standstill_fuel"] = fuel_q
    return fields, quality


def _ambient(t: np.ndarray, row_t: np.ndarray, temp, params: EvidenceParams, quality: dict) -> dict:
    none = {"ambient_temp_c": None, "ambient_temp_min_c": None, "ambient_temp_max_c": None}
    if temp is None:
        quality["ambient_temp"] = {"why_none": "no ambient_temp_c column"}
        return none
    a = np.asarray(temp, dtype=np.float64)
    fin = np.isfinite(a)
    lo, hi = params.ambient_range_c
    ok = fin & (a >= lo) & (a <= hi)
    t0, t1 = float(t[0]), float(t[-1])
    hold = params.ambient_max_hold_s
    sel = ok & (row_t >= t0 - hold) & (row_t <= t1 + hold)
    rt, rv = row_t[sel], a[sel]
    q: dict = {"readings": int(((rt >= t0) & (rt <= t1)).sum()), "rejected": int((fin & ~ok).sum())}
    quality["ambient_temp"] = q
    if rt.size == 0:
        q["why_none"] = "no plausible reading within the trip"
        return none
    far = _farthest_from_readings(t0, t1, rt)
    q["max_hold_s"] = far
    if far > hold:
        q["why_none"] = f"some instant of the trip is {far:.0f} s from a reading (over {hold:g} s)"
        return none
    inside = rt[(rt > t0) & (rt < t1)]
    pts = np.concatenate(([t0], inside, [t1]))
    vals = np.interp(pts, rt, rv)
    duration = t1 - t0
    mean = float(np.sum(0.5 * (vals[1:] + vals[:-1]) * np.diff(pts)) / duration) if duration > 0 else float(vals[0])
    return {"ambient_temp_c": mean, "ambient_temp_min_c": float(vals.min()), "ambient_temp_max_c": float(vals.max())}


def _farthest_from_readings(t0: float, t1: float, rt: np.ndarray) -> float:
    """max over t in [t0, t1] of the time to the nearest reading (``rt`` sorted)."""
    mid = np.clip(0.5 * (rt[1:] + rt[:-1]), t0, t1)
    cand = np.concatenate(([t0, t1], mid))
    k = np.searchsorted(rt, cand)
    before = np.abs(cand - rt[np.clip(k - 1, 0, rt.size - 1)])
    after = np.abs(rt[np.clip(k, 0, rt.size - 1)] - cand)
    return float(np.minimum(before, after).max())


def _standstill_steps(t, v, row_t, ignition, standstill_mps: float) -> tuple[np.ndarray, str]:
    """Steps (i to i+1) standing still with the ignition on at both ends."""
    still = (v[1:] <= standstill_mps) & (v[:-1] <= standstill_mps)
    if ignition is None:
        return still, "no ignition column: on (the trip)"
    ign = np.asarray(ignition, dtype=np.float64)
    ok = np.isfinite(ign)
    if not ok.any():
        return still, "no ignition reading: on (the trip)"
    it, iv = row_t[ok], ign[ok]
    j = np.searchsorted(it, t, side="right") - 1  # last reading at or before each sample
    on = ~((j >= 0) & (iv[np.maximum(j, 0)] < 0.5))
    return still & on[1:] & on[:-1], "from the ignition column"


def _standstill_mean(t, still, ts, vs, max_gap_s: float) -> tuple[float, float] | None:
    """(mean, covered time [s]) of a sampled rate over the standstill steps where it is
    known (trapezoid on the trip's samples), None if it is known on none."""
    if ts.size == 0 or not still.any():
        return None
    i = np.flatnonzero(still)  # the rate only at both ends of the standstill steps
    r0 = _interp_limited(t[i], ts, vs, max_gap_s)
    r1 = _interp_limited(t[i + 1], ts, vs, max_gap_s)
    known = np.isfinite(r0) & np.isfinite(r1)
    dt = t[i + 1][known] - t[i][known]
    covered = float(dt.sum())
    if covered <= 0:
        return None
    total = float(np.sum(0.5 * (r0[known] + r1[known]) * dt))
    return total / covered, covered


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
    """:func:`trip_evidence` of every trip of a batch at once, bit for bit: the trips'
    sample times [s, UTC epoch] and speeds end to end (``bounds``: each trip's), the
    log's row times ``row_t`` and evidence columns ``rows`` (whole), and each trip's
    rows ``row_window[i] = (a, b)``."""
    from cevm.ingest.measured import interp_limited_segments, window_samples
    from cevm.ingest.segments import bounds_of, segment_ids, segment_sums

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
        """_standstill_mean of each trip's samples (``tb``: their bounds)."""
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


def _kept(mask: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    cs = np.zeros(mask.size + 1, dtype=np.int64)
    np.cumsum(mask, out=cs[1:])
    return cs[bounds]


def _batch_ambient(t_abs, bounds, row_t, temp, lo, hi, params: EvidenceParams, out_f, out_q) -> None:
    """:func:`_ambient` of every trip (into ``out_f`` and ``out_q``)."""
    from cevm.ingest.segments import ranges, segment_interp, segment_searchsorted, segment_sums

    n = bounds.size - 1
    none = {"ambient_temp_c": None, "ambient_temp_min_c": None, "ambient_temp_max_c": None}
    if temp is None:
        for i in range(n):
            out_q[i]["ambient_temp"] = {"why_none": "no ambient_temp_c column"}
            out_f[i].update(none)
        return
    t0, t1 = t_abs[bounds[:-1]], t_abs[bounds[1:] - 1]
    rr = ranges(lo, hi - lo)
    wb = np.concatenate(([0], np.cumsum(hi - lo)))
    a = np.asarray(temp)[rr].astype(np.float64, copy=False)
    rt_all = row_t[rr]
    seg = np.repeat(np.arange(n), hi - lo)
    fin = np.isfinite(a)
    lo_c, hi_c = params.ambient_range_c
    ok = fin & (a >= lo_c) & (a <= hi_c)
    hold = params.ambient_max_hold_s
    sel = ok & (rt_all >= t0[seg] - hold) & (rt_all <= t1[seg] + hold)
    rejected = np.bincount(seg[fin & ~ok], minlength=n)
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
    # the farthest instant of each trip from a reading: candidates t0, t1 and the readings' midpoints
    starts, lens = rb[has], counts[has]
    mids_n = lens - 1
    mb = np.concatenate(([0], np.cumsum(mids_n + 2)))
    cand = np.empty(int(mb[-1]))
    cseg = np.repeat(np.arange(has.size), mids_n + 2)
    cand[mb[:-1]] = t0[has]
    cand[mb[:-1] + 1] = t1[has]
    mrows = ranges(starts, mids_n)
    mpos = ranges(mb[:-1] + 2, mids_n)
    cand[mpos] = np.clip(0.5 * (rt[mrows + 1] + rt[mrows]), t0[has][cseg[mpos]], t1[has][cseg[mpos]])
    k = segment_searchsorted(rt, starts, lens, cand, cseg, "left")
    ln = lens[cseg]
    before = np.abs(cand - rt[starts[cseg] + np.clip(k - 1, 0, ln - 1)])
    after = np.abs(rt[starts[cseg] + np.clip(k, 0, ln - 1)] - cand)
    far = np.maximum.reduceat(np.minimum(before, after), mb[:-1])
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
    pts[ranges(pb[:-1] + 1, n_in)] = grt[inside]
    pseg = np.repeat(np.arange(gi.size), n_in + 2)
    vals = segment_interp(pts, pseg, rt, g_starts, g_lens, rv)
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
    """:func:`_standstill_steps` of every trip: its steps (within trips, end to end)
    standing still with the ignition on at both ends, and each trip's ignition note."""
    from cevm.ingest.segments import ranges, segment_searchsorted

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
