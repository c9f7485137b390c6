"""A scheduled trip's drive cycle, synthesised from its stop times and distances with the
driving of :class:`~cevm.core.timetable.driving.DrivingParams` (pure, vectorised), and a
logged trip turned back into a timetable (:func:`timetable_from_log`).

The speed of a run between two timed stops
------------------------------------------
Each run (departure at stop j to arrival at stop j+1, ``d`` metres in ``T`` seconds) is
drawn with a launch acceleration ``a`` and a braking deceleration ``b`` (log-normal: a
factor per drawn cycle, the trip's, and one per run), and within it unscheduled stops
and slowdowns (Poisson per km, with a gamma factor per drawn cycle; their times uniform
in the run). Every event k (the stops at each end, an unscheduled stop standing from
``s_k`` to ``e_k``, a slowdown at ``s_k = e_k`` to speed ``u_k``) bounds the speed by a
V: ``u_k + max(a (t - e_k), b (s_k - t))``, and so does the cap; the speed at each sample
of the 1 s grid is::

    v_i = min(c, h_i),   h_i = min(cap, max(0, min_k V_k(t_i)))

with one cruise speed ``c`` per run. The run's distance by the trapezoid rule (the CE
model's, :func:`cevm.core.cycle.trapezoid_distance_m`) is ``sum_i w_i min(c, h_i)``
(``w_i`` half the steps either side of sample i): continuous, piecewise linear and
increasing in ``c``, so ``c`` is solved exactly by sorting the h_i of the run (the closed
form of a trapezoid, on the grid: with no event ``h_i = min(a t_i, b (T - t_i))`` and
``c`` solves ``sum_i w_i min(c, h_i) = d``). The run then covers exactly ``d`` in exactly
``T``, starts and ends at rest, never exceeds its cap, and changes speed by at most ``a``
(``b``) per second.

Dwell: a stop whose arrival and departure differ keeps that dwell; one whose times are
equal (most GTFS feeds) stands for a drawn dwell (``params.stop_s``) centred on its time.
The first stop's departure and the last stop's arrival bound the cycle (``with_terminals``
adds the standing before the first departure and after the last arrival).

A schedule the driving cannot keep
----------------------------------
A run shorter than the least time a trapezoid with its ``a``, ``b`` and cap needs (plus
:data:`GRID_MARGIN_S` for the 1 s grid) is not squeezed: the bus leaves on time and
arrives late, and the lateness carries over to the next stops, shortened by their slack
(``x_i = max(s_i, x_{i-1} + m_i)`` over the schedule's times ``s_i`` and least gaps
``m_i``). :class:`SynthCycle` says how late (``late_s`` at the last stop, ``late_max_s``
at the worst); a schedule kept has both 0. Minute-rounded feeds with two stops at the
same minute are the common case. Unscheduled events are drawn only within a run's slack
(their standing within half of it) and dropped from a run they would make impossible.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cevm.core.timetable.driving import STAND_MPS, STOP_MIN_S, DrivingParams
from cevm.errors import CevmError

#: Extra seconds a run needs beyond the continuous least time, for the 1 s grid.
GRID_MARGIN_S = 0.5
#: Bounds on drawn accelerations and decelerations [m/s^2] (a log-normal's tails; no bus
#: launches slower or brakes harder in service).
ACCEL_BOUNDS = (0.15, 2.5)
DECEL_BOUNDS = (0.15, 3.5)
#: Longest drawn dwell or unscheduled stop [s].
STOP_MAX_S = 600.0


@dataclass(frozen=True, eq=False)
class SynthCycle:
    """A synthesised drive cycle: ``time_s`` (the schedule's clock; 1 s steps but where a
    stop's time falls between seconds), ``speed_mps``, ``distance_m`` (cumulative
    trapezoid from the first stop, ending at the trip's length); ``late_s`` /
    ``late_max_s`` how much later than the schedule it reaches the last stop / its worst
    stop (module notes; 0 when the schedule is kept); ``unscheduled_stops`` and
    ``slowdowns`` drawn."""

    time_s: np.ndarray
    speed_mps: np.ndarray
    distance_m: np.ndarray
    late_s: float = 0.0
    late_max_s: float = 0.0
    unscheduled_stops: int = 0
    slowdowns: int = 0


def _check_schedule(d: np.ndarray, arr: np.ndarray, dep: np.ndarray) -> None:
    """One clear line for a schedule that cannot be a trip (stop numbers 1-based)."""
    if d.ndim != 1 or arr.shape != d.shape or dep.shape != d.shape:
        raise CevmError("a trip's stop distances, arrivals and departures must be 1-D arrays of one length")
    if d.size < 2:
        raise CevmError(f"a trip needs at least 2 stops, got {d.size}")
    for name, a in (("distance", d), ("arrival", arr), ("departure", dep)):
        bad = np.flatnonzero(~np.isfinite(a))
        if bad.size:
            raise CevmError(f"stop {bad[0] + 1}: its {name} is not a number")
    bad = np.flatnonzero(np.diff(d) < 0)
    if bad.size:
        raise CevmError(f"stops {bad[0] + 1} to {bad[0] + 2}: the distance goes back "
                        f"({d[bad[0]]:.1f} m to {d[bad[0] + 1]:.1f} m)")
    bad = np.flatnonzero(dep < arr)
    if bad.size:
        raise CevmError(f"stop {bad[0] + 1}: departs before it arrives")
    bad = np.flatnonzero(arr[1:] < dep[:-1])
    if bad.size:
        raise CevmError(f"stops {bad[0] + 1} to {bad[0] + 2}: arrives before the previous departure")


def least_run_time_s(d_m: np.ndarray, a: np.ndarray, b: np.ndarray, cap: np.ndarray) -> np.ndarray:
    """The least time [s] to cover ``d_m`` from rest to rest with acceleration ``a``,
    deceleration ``b`` and top speed ``cap`` (continuous: a triangle, or a trapezoid
    once the cap is reached)."""
    k = 0.5 * (1.0 / a + 1.0 / b)
    d_cap = cap * cap * k  # distance of the triangle that just reaches the cap
    tri = np.sqrt(4.0 * d_m * k)
    trap = d_m / cap + cap * k
    return np.where(d_m >= d_cap, trap, tri)


def _lognormal(rng: np.random.Generator, median: float, trip_sd: float, sd: float, n: int,
               bounds: tuple[float, float] | None = None) -> np.ndarray:
    """n log-normal draws sharing one trip factor (sds NaN count as 0)."""
    ts = 0.0 if not math.isfinite(trip_sd) else trip_sd
    ws = 0.0 if not math.isfinite(sd) else sd
    x = median * np.exp(ts * rng.standard_normal() + ws * rng.standard_normal(n))
    return np.clip(x, *bounds) if bounds else x


def _gamma_factor(rng: np.random.Generator, cv: float) -> float:
    """A mean-1 gamma factor of coefficient of variation ``cv`` (1 when cv is 0 or NaN)."""
    if not math.isfinite(cv) or cv <= 0:
        return 1.0
    shape = 1.0 / (cv * cv)
    return float(rng.gamma(shape, 1.0 / shape))


def _caps(speed_cap_mps, runs: int, params: DrivingParams) -> np.ndarray:
    """One cap per run: ``speed_cap_mps`` (one, or one per run), else the driving's top speed."""
    if speed_cap_mps is None:
        cap = np.full(runs, float(params.top_speed_mps))
    elif np.ndim(speed_cap_mps) == 0 or np.size(speed_cap_mps) == runs:
        cap = np.broadcast_to(np.asarray(speed_cap_mps, dtype=np.float64).reshape(-1), (runs,)).copy()
    else:
        raise CevmError(f"speed_cap_mps: one cap, or one per run ({runs}), not {np.size(speed_cap_mps)}")
    if not np.all(np.isfinite(cap) & (cap > 0)):
        raise CevmError("speed caps must be positive numbers [m/s]")
    return cap


def _solve_cruise(h: np.ndarray, w: np.ndarray, run: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per run r the cruise c_r with sum_{i in r} w_i min(c_r, h_i) = d_r (module notes),
    and whether each run is feasible (sum w_i h_i >= d_r). Infeasible runs get their
    largest h."""
    R = d.size
    order = np.lexsort((h, run))
    hs, ws, rs = h[order], w[order], run[order]
    cw = np.cumsum(ws)
    cwh = np.cumsum(ws * hs)
    W = np.bincount(rs, weights=ws, minlength=R)
    start = np.searchsorted(rs, np.arange(R), side="left")
    base_w = np.where(start > 0, cw[np.maximum(start - 1, 0)], 0.0)
    base_wh = np.where(start > 0, cwh[np.maximum(start - 1, 0)], 0.0)
    before_w = cw - ws - base_w[rs]  # weight of the run's samples sorted before this one
    before_wh = cwh - ws * hs - base_wh[rs]
    reach = before_wh + hs * (W[rs] - before_w)  # distance with c = hs
    ok = reach >= d[rs]
    first = np.full(R, -1)
    hit = np.flatnonzero(ok)
    if hit.size:
        rr, pos = np.unique(rs[hit], return_index=True)
        first[rr] = hit[pos]
    feasible = (first >= 0) | (d <= 0)
    c = np.zeros(R)
    f = first >= 0
    p = first[f]
    denom = W[f] - before_w[p]
    c[f] = np.where(denom > 0, (d[f] - before_wh[p]) / np.where(denom > 0, denom, 1.0), hs[p])
    c[d <= 0] = 0.0
    top = np.zeros(R)
    np.maximum.at(top, rs, hs)
    c[~feasible] = top[~feasible]
    return c, feasible


def _envelope(t: np.ndarray, run: np.ndarray, ev_run: np.ndarray, ev_s: np.ndarray, ev_e: np.ndarray,
              ev_u: np.ndarray, a: np.ndarray, b: np.ndarray, R: int) -> np.ndarray:
    """max(0, min over the events of each sample's run of u + max(a (t - e), b (s - t)))."""
    order = np.argsort(ev_run, kind="stable")
    er, es, ee, eu = ev_run[order], ev_s[order], ev_e[order], ev_u[order]
    counts = np.bincount(er, minlength=R)
    E = int(counts.max()) if counts.size else 0
    slot = np.arange(er.size) - np.repeat(np.cumsum(counts) - counts, counts)
    S = np.full((R, E), np.nan)
    Ee = np.full((R, E), np.nan)
    U = np.full((R, E), np.inf)
    S[er, slot], Ee[er, slot], U[er, slot] = es, ee, eu
    ar, br = a[run][:, None], b[run][:, None]
    tt = t[:, None]
    f = U[run] + np.maximum(ar * (tt - Ee[run]), br * (S[run] - tt))
    g = np.nanmin(np.where(np.isnan(f), np.inf, f), axis=1)
    return np.maximum(g, 0.0)


def _harder(d: np.ndarray, T: np.ndarray, a: np.ndarray, b: np.ndarray, cap: np.ndarray,
            params: DrivingParams) -> tuple[np.ndarray, np.ndarray]:
    """``a`` and ``b`` scaled by the least factor f >= 1 that fits each run in its time
    ``T`` (less :data:`GRID_MARGIN_S`), at most to the 99th percentile of the drawn
    distributions (or their bounds); runs that fit keep theirs."""
    Tm = np.maximum(T - GRID_MARGIN_S, 1e-9)
    k = 0.5 * (1.0 / a + 1.0 / b)
    with np.errstate(divide="ignore", invalid="ignore"):
        f_tri = 4.0 * d * k / (Tm * Tm)  # a triangle in Tm
        peak = np.sqrt(d * f_tri / np.maximum(k, 1e-12))
        rest = Tm - d / cap
        f_cap = np.where(rest > 0, cap * k / rest, np.inf)  # a trapezoid at the cap
    f = np.where(peak <= cap, f_tri, f_cap)
    z99 = 2.326
    sd_a = math.hypot(_finite(params.accel_sd), _finite(params.accel_trip_sd))
    sd_b = math.hypot(_finite(params.decel_sd), _finite(params.decel_trip_sd))
    a99 = min(params.accel_mps2 * math.exp(z99 * sd_a), ACCEL_BOUNDS[1])
    b99 = min(params.decel_mps2 * math.exp(z99 * sd_b), DECEL_BOUNDS[1])
    f_max = np.maximum(np.minimum(a99 / a, b99 / b), 1.0)
    f = np.clip(np.where(np.isfinite(f), f, f_max), 1.0, f_max)
    return a * f, b * f


def _finite(x: float) -> float:
    return x if math.isfinite(x) else 0.0


def synthesise_trip(stop_dist_m: np.ndarray, arrival_s: np.ndarray, departure_s: np.ndarray,
                    params: DrivingParams, rng: np.random.Generator, *,
                    speed_cap_mps: float | np.ndarray | None = None, with_terminals: bool = False) -> SynthCycle:
    """One drawn drive cycle of a scheduled trip (module notes): ``stop_dist_m`` (k,) the
    stops' distances along the trip [m], non-decreasing; ``arrival_s`` / ``departure_s``
    (k,) their times [s, any origin]; ``speed_cap_mps`` one cap or one per run (k - 1)
    [m/s], default ``params.top_speed_mps``. ``with_terminals``: the cycle also stands
    from the first stop's arrival and until the last stop's departure. An impossible
    schedule (times going back, distances going back) raises :class:`CevmError` naming
    the stop."""
    d_stop = np.asarray(stop_dist_m, dtype=np.float64)
    arr = np.asarray(arrival_s, dtype=np.float64)
    dep = np.asarray(departure_s, dtype=np.float64)
    _check_schedule(d_stop, arr, dep)
    k = d_stop.size
    R = k - 1
    origin = float(arr[0] if with_terminals else dep[0])
    arr, dep = arr - origin, dep - origin
    d = np.diff(d_stop)
    cap = _caps(speed_cap_mps, R, params)
    a = _lognormal(rng, params.accel_mps2, params.accel_trip_sd, params.accel_sd, R, ACCEL_BOUNDS)
    b = _lognormal(rng, params.decel_mps2, params.decel_trip_sd, params.decel_sd, R, DECEL_BOUNDS)
    # dwell windows [w0, w1] per stop: scheduled, or drawn and centred on the stop's time
    w0, w1 = arr.copy(), dep.copy()
    drawn = (dep <= arr)
    drawn[0] = drawn[-1] = False
    if drawn.any():
        dw = np.round(_lognormal(rng, params.stop_s, params.stop_trip_sd, params.stop_sd, int(drawn.sum()),
                                 (0.0, STOP_MAX_S)))
        w0[drawn] = arr[drawn] - np.floor(0.5 * dw)
        w1[drawn] = w0[drawn] + dw
    if not with_terminals:
        w0[0], w1[-1] = dep[0], arr[-1]
    # a run shorter than its drawn driving needs is driven harder, up to the 99th
    # percentile of the launches and brakings, before it is late
    a, b = _harder(d, w0[1:] - w1[:-1], a, b, cap, params)
    # unscheduled stops and slowdowns: counts, durations, shares; placed once the runs' times are known
    total_km = float(d.sum()) / 1000.0
    extra = max(0.0, params.stops_per_km * total_km - max(k - 2, 0)) * _gamma_factor(rng, params.stops_trip_cv)
    n_stop = rng.poisson(extra * d / max(float(d.sum()), 1e-9))
    n_dip = rng.poisson(params.slowdowns_per_km * d / 1000.0 * _gamma_factor(rng, params.slowdowns_trip_cv))
    ev = _Events(
        st_run=np.repeat(np.arange(R), n_stop),
        st_dur=np.round(_lognormal(rng, params.stop_s, params.stop_trip_sd, params.stop_sd, int(n_stop.sum()),
                                   (STOP_MIN_S, STOP_MAX_S))),
        st_pos=rng.random(int(n_stop.sum())),
        dp_run=np.repeat(np.arange(R), n_dip),
        dp_share=np.clip(params.slowdown_share + _finite(params.slowdown_sd) * rng.standard_normal(int(n_dip.sum())),
                         0.0, 0.95),
        dp_pos=rng.random(int(n_dip.sum())))
    least = np.where(d > 0, least_run_time_s(d, a, b, cap) + GRID_MARGIN_S, 0.0)
    for _ in range(8):  # a run the 1 s grid cannot fit (a few metres in under 2 s) gets a second more
        w0r, w1r, late = _retime(w0, w1, least)
        t, v, ok, n_st, n_dp = _drive(d, w0r, w1r, a, b, cap, ev, with_terminals)
        if ok.all():
            break
        least = np.where(ok, least, np.maximum(least, w0r[1:] - w1r[:-1]) + 1.0)
    else:
        j = int(np.flatnonzero(~ok)[0])
        raise CevmError(f"stops {j + 1} to {j + 2}: {d[j]:.0f} m cannot be driven at up to {cap[j]:.1f} m/s")
    dist = np.concatenate(([0.0], np.cumsum(0.5 * (v[:-1] + v[1:]) * np.diff(t))))
    return SynthCycle(time_s=t + origin, speed_mps=v, distance_m=dist, late_s=float(max(late[-2], 0.0)),
                      late_max_s=float(max(late.max(), 0.0)), unscheduled_stops=n_st, slowdowns=n_dp)


@dataclass(frozen=True, eq=False)
class _Events:
    """A drawn cycle's unscheduled stops (run, duration [s], position in the run's time
    as a share) and slowdowns (run, speed as a share of the run's mean, position)."""

    st_run: np.ndarray
    st_dur: np.ndarray
    st_pos: np.ndarray
    dp_run: np.ndarray
    dp_share: np.ndarray
    dp_pos: np.ndarray


def _retime(w0: np.ndarray, w1: np.ndarray, least: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The dwell windows [w0, w1] moved no earlier, and as little later as the runs'
    ``least`` times and the dwells need (x_i = max(s_i, x_{i-1} + m_i), module notes);
    and how late each time is (w0_0, w1_0, w0_1, ...)."""
    s = np.column_stack((w0, w1)).ravel()
    gaps = np.column_stack((w1 - w0, np.append(least, 0.0))).ravel()[:-1]
    M = np.concatenate(([0.0], np.cumsum(gaps)))
    x = np.maximum.accumulate(s - M) + M
    return x[0::2], x[1::2], x - s


def _drive(d: np.ndarray, w0: np.ndarray, w1: np.ndarray, a: np.ndarray, b: np.ndarray, cap: np.ndarray,
           ev: _Events, with_terminals: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, int]:
    """The grid, the speeds on it, which runs are feasible, and the unscheduled stops and
    slowdowns kept (module notes): a run's stops while their standing fits in half its
    slack, all its events dropped if they make it impossible."""
    R = d.size
    T = w0[1:] - w1[:-1]
    least = np.where(d > 0, least_run_time_s(d, a, b, cap), 0.0)
    slack = np.maximum(T - least, 0.0)
    by_run = np.bincount(ev.st_run, weights=ev.st_dur, minlength=R)
    cum = np.cumsum(ev.st_dur) - np.repeat(np.cumsum(by_run) - by_run, np.bincount(ev.st_run, minlength=R))
    fits = cum <= 0.5 * slack[ev.st_run]
    st_run, st_dur = ev.st_run[fits], ev.st_dur[fits]
    standing = np.bincount(st_run, weights=st_dur, minlength=R)
    st_start = w1[:-1][st_run] + ev.st_pos[fits] * np.maximum(T[st_run] - st_dur, 0.0)
    mean_v = d / np.maximum(T - standing, 1.0)
    dp_t = w1[:-1][ev.dp_run] + ev.dp_pos * T[ev.dp_run]
    dp_u = ev.dp_share * mean_v[ev.dp_run]
    # the grid: whole seconds from the start, and every dwell window's ends
    t_end = float(w1[-1] if with_terminals else w0[-1])
    t = np.union1d(np.arange(0.0, t_end, 1.0), np.concatenate((w0, w1)))
    t = t[(t >= 0) & (t <= t_end)]
    t = t[np.concatenate(([True], np.diff(t) > 1e-6))]
    run = np.clip(np.searchsorted(w1[:-1], t, side="right") - 1, 0, R - 1)
    dt = np.diff(t)
    wgt = 0.5 * (np.concatenate(([0.0], dt)) + np.concatenate((dt, [0.0])))

    def build(with_events: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        ks, kd = with_events[st_run], with_events[ev.dp_run]
        ev_run = np.concatenate((np.arange(R), np.arange(R), st_run[ks], ev.dp_run[kd]))
        ev_s = np.concatenate((w0[:-1], w0[1:], st_start[ks], dp_t[kd]))
        ev_e = np.concatenate((w1[:-1], w1[1:], st_start[ks] + st_dur[ks], dp_t[kd]))
        ev_u = np.concatenate((np.zeros(2 * R), np.zeros(int(ks.sum())), dp_u[kd]))
        h = np.minimum(_envelope(t, run, ev_run, ev_s, ev_e, ev_u, a, b, R), cap[run])
        c, ok = _solve_cruise(h, wgt, run, d)
        return h, c, ok

    events = np.ones(R, dtype=bool)
    h, c, ok = build(events)
    if not ok.all():  # drop the events of the runs they make impossible
        events &= ok
        h, c, ok = build(events)
    v = np.minimum(c[run], h)
    v[v < 1e-9] = 0.0
    return t, v, ok, int(events[st_run].sum()), int(events[ev.dp_run].sum())


def timetable_from_log(t_s: np.ndarray, speed_mps: np.ndarray, *, stop_min_s: float = STOP_MIN_S
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A logged trip as a timetable: ``(stop_dist_m, arrival_s, departure_s)`` of its
    stops, the standstills of at least ``stop_min_s`` (the driving's stops,
    :data:`~cevm.core.timetable.driving.STOP_MIN_S`), with the trip's start (arrival at
    its first sample, departure when it first moves) and end (arrival when it last
    stops, departure at its last sample) as first and last stops. Distances are the
    trapezoid's, from the first sample; times those of the samples where the standing
    begins and ends. No speed, no energy: what a timetable would say."""
    t = np.asarray(t_s, dtype=np.float64)
    v = np.asarray(speed_mps, dtype=np.float64)
    dist = np.concatenate(([0.0], np.cumsum(0.5 * (v[:-1] + v[1:]) * np.diff(t))))
    moving = v >= STAND_MPS
    if not moving.any():
        raise CevmError("the trip never moves: no timetable")
    # standing = not moving; a step counts as standing where both its ends do
    idx = np.flatnonzero(moving)
    first_move, last_move = int(idx[0]), int(idx[-1])
    dep0 = t[max(first_move - 1, 0)]
    arr_end = t[min(last_move + 1, t.size - 1)]
    st = ~moving
    d_ = np.diff(np.concatenate(([False], st, [False])).astype(np.int8))
    ss, se = np.flatnonzero(d_ == 1), np.flatnonzero(d_ == -1)
    inner = (ss > first_move) & (se <= last_move)
    ss, se = ss[inner], se[inner]
    dur = t[se - 1] - t[ss]
    keep = dur >= stop_min_s
    ss, se = ss[keep], se[keep]
    stop_d = np.concatenate(([dist[max(first_move - 1, 0)]], dist[ss], [dist[min(last_move + 1, t.size - 1)]]))
    arr = np.concatenate(([t[0]], t[ss], [arr_end]))
    dep = np.concatenate(([dep0], t[se - 1], [t[-1]]))
    return stop_d - stop_d[0], arr, dep
