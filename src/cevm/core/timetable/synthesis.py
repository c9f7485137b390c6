"""A scheduled trip's drive cycle, synthesised from its stop times and distances with the
driving of :class:`~cevm.core.timetable.driving.DrivingParams` (pure, vectorised), and a
logged trip turned back into a timetable (:func:`timetable_from_log`).

The speed of a run between two timed stops
------------------------------------------
Each run (departure at stop j to arrival at stop j+1, ``d`` metres in ``T`` seconds) is
drawn with a launch acceleration ``a`` and a braking deceleration ``b`` (log-normal: a
factor per drawn cycle, the trip's, and one per run), and within it unscheduled stops
(the logs' stops per km beyond the timetable's, spread by distance) and slowdowns (per
km), Poisson with a gamma factor per drawn cycle. Every event k (the stops at each end,
an unscheduled stop standing from ``s_k`` to ``e_k``, a slowdown at ``s_k = e_k`` to
speed ``u_k``) bounds the speed by a V: ``u_k + max(a (t - e_k), b (s_k - t))``, and so
does the cap; the speed at each sample of the 1 s grid is::

    v_i = min(c phi_i, h_i),   h_i = min(cap, max(0, min_k V_k(t_i)))

with one cruise speed ``c`` per run and the cruise's shape ``phi_i > 0``: its tilt (a
straight line over the run) times its wobble (``1 + A sin(2 pi t / P + theta)``, the
driving's amplitude A for the run's kind, slow or not, period P and phase theta drawn
per run) times, on runs of 3 minutes or more, its sway (``exp(s z - s^2 / 2)``, z
standard normal at knots a minute apart, linear between). As ``min(c phi, h) = phi
min(c, h / phi)``, the run's distance by the trapezoid rule (the CE model's,
:func:`cevm.core.cycle.trapezoid_distance_m`) is ``sum_i w_i phi_i min(c, h_i / phi_i)``
(``w_i`` half the steps either side of sample i): continuous, piecewise linear and
increasing in ``c``, so ``c`` is solved exactly by sorting the run's ``h_i / phi_i``
(the closed form of a trapezoid, on the grid: with no event and phi = 1, ``h_i = min(a
t_i, b (T - t_i))`` and ``c`` solves ``sum_i w_i min(c, h_i) = d``). The run then covers
exactly ``d`` in exactly ``T``, starts and ends at rest, and never exceeds its cap.
Slowdowns are placed where the run cruises (after a launch to about ``cruise_ratio``
times its mean speed, as long before its braking) and go to their drawn share of the
cruise there. All draws of a trip are built in one pass (:func:`synthesise_trips`).

Dwell: a stop whose arrival and departure differ keeps that dwell; one whose times are
equal (most GTFS feeds) stands for a drawn dwell (``params.stop_s``) centred on its time.
The first stop's departure and the last stop's arrival bound the cycle (``with_terminals``
adds the standing before the first departure and after the last arrival).

A schedule the driving cannot keep
----------------------------------
A run shorter than the least time a trapezoid with its drawn ``a``, ``b`` and cap needs
(plus :data:`GRID_MARGIN_S` for the 1 s grid) is first driven harder: both scaled by the
least factor that fits, up to the 99th percentile of the driving's distributions (a
driver late on a tight run launches and brakes harder). Beyond that it is not squeezed:
the bus leaves on time and
arrives late, and the lateness carries over to the next stops, shortened by their slack
(``x_i = max(s_i, x_{i-1} + m_i)`` over the schedule's times ``s_i`` and least gaps
``m_i``). :class:`SynthCycle` says how late (``late_s`` at the last stop, ``late_max_s``
at the worst); a schedule kept has both 0. Minute-rounded feeds with two stops at the
same minute are the common case. Unscheduled events are drawn only within a run's slack
(the time the unscheduled stops lose, their standing and ``c (1/a + 1/b) / 2`` each,
within half of it, then the time the slowdowns lose, ``(1/a + 1/b) (c - u)^2 / (2 c)``
each, within half of what is left) and dropped from a run they would still make
impossible.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cevm.core.timetable.driving import SHARE_LEVELS, STAND_MPS, STOP_MIN_S, SWAY_MIN_RUN_S, DrivingParams
from cevm.errors import CevmError

#: Extra seconds a run needs beyond the continuous least time, for the 1 s grid.
GRID_MARGIN_S = 0.5
#: Bounds on drawn accelerations and decelerations [m/s^2] (a log-normal's tails; no bus
#: launches slower or brakes harder in service).
ACCEL_BOUNDS = (0.15, 2.5)
DECEL_BOUNDS = (0.15, 3.5)
#: Bound on a run's drawn cruise tilt (its speed at the end at least half, at most 1.5
#: times, that at its start).
TILT_BOUND = 0.5
#: The cruise wobble's period [s], drawn per run (its amplitude is the driving's
#: ``wobble``, matched to the logs' kinetic energy): the slowdowns' window either side.
WOBBLE_PERIOD_S = (10.0, 30.0)
#: The knots of a long run's sway (its slow changes: traffic, roads) every so many
#: seconds [s] (its sd is the driving's ``sway``, matched to the logs' long runs).
SWAY_KNOT_S = 60.0
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


def _lognormal(rng: np.random.Generator, median: float, trip_sd: float, sd: float, shape: tuple[int, int],
               bounds: tuple[float, float] | None = None) -> np.ndarray:
    """Log-normal draws of ``shape`` (draws, n), each row sharing one trip factor (sds
    NaN count as 0)."""
    trip = _finite(trip_sd) * rng.standard_normal((shape[0], 1))
    x = median * np.exp(trip + _finite(sd) * rng.standard_normal(shape))
    return np.clip(x, *bounds) if bounds else x


def _gamma_factor(rng: np.random.Generator, cv: float, n: int) -> np.ndarray:
    """n mean-1 gamma factors of coefficient of variation ``cv`` (1 when cv is 0 or NaN)."""
    if not math.isfinite(cv) or cv <= 0:
        return np.ones(n)
    shape = 1.0 / (cv * cv)
    return rng.gamma(shape, 1.0 / shape, n)


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
    moving = h > 0  # standing samples add nothing to any run's distance at any c
    h, w, run = h[moving], w[moving], run[moving]
    if not h.size:
        return np.zeros(R), d <= 0
    # (run, h) order in one key: run * span + h, span a power of 2 above every h
    span = 2.0 ** math.ceil(math.log2(float(h.max(initial=0.0)) + 2.0))
    order = np.argsort(run * span + h, kind="stable")
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


@dataclass(frozen=True, eq=False)
class _Grid:
    """The draws' grids end to end: times ``t``, each sample's ``run`` (numbered across
    draws), ``key`` = draw * :data:`_DRAW_SHIFT_S` + t (increasing over all samples), the
    ``bounds`` of each draw's samples, each sample's trapezoid weight ``wgt``, and each
    run's first and past-last sample (``lo``, ``hi``)."""

    t: np.ndarray
    run: np.ndarray
    key: np.ndarray
    bounds: np.ndarray
    wgt: np.ndarray
    lo: np.ndarray
    hi: np.ndarray


#: Separates the draws' clocks in the grid's key [s] (2^20 s, 12 days: longer than any trip).
_DRAW_SHIFT_S = float(2 ** 20)


def _envelope(g: _Grid, dep: np.ndarray, arr: np.ndarray, a: np.ndarray, b: np.ndarray, cap: np.ndarray,
              ev_run: np.ndarray, ev_s: np.ndarray, ev_e: np.ndarray, ev_u: np.ndarray) -> np.ndarray:
    """h = min(cap, max(0, min over the events of each sample's run of u + max(a (t - e),
    b (s - t)))): the run's ends (its departure ``dep`` and arrival ``arr``) at every
    sample, each other event only over the samples where its V lies below the cap (its
    run's samples within (cap - u) / b before it and (cap - u) / a after it)."""
    run, t = g.run, g.t
    h = np.minimum(a[run] * (t - dep[run]), b[run] * (arr[run] - t))
    np.clip(h, 0.0, cap[run], out=h)
    if ev_run.size:
        ar, br, cr = a[ev_run], b[ev_run], cap[ev_run]
        runs_per_draw = dep.size // max(g.bounds.size - 1, 1)
        off = (ev_run // runs_per_draw) * _DRAW_SHIFT_S  # the event's draw's clock in the key
        i0 = np.maximum(np.searchsorted(g.key, off + ev_s - (cr - ev_u) / br, side="left"), g.lo[ev_run])
        i1 = np.minimum(np.searchsorted(g.key, off + ev_e + (cr - ev_u) / ar, side="right"), g.hi[ev_run])
        cnt = np.maximum(i1 - i0, 0)
        total = int(cnt.sum())
        if total:
            which = np.repeat(np.arange(ev_run.size), cnt)
            idx = np.repeat(i0, cnt) + (np.arange(total) - np.repeat(np.cumsum(cnt) - cnt, cnt))
            tt = t[idx]
            val = ev_u[which] + np.maximum(ar[which] * (tt - ev_e[which]), br[which] * (ev_s[which] - tt))
            np.minimum.at(h, idx, np.maximum(val, 0.0))
    return h


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
    return synthesise_trips(stop_dist_m, arrival_s, departure_s, params, rng, 1, speed_cap_mps=speed_cap_mps,
                            with_terminals=with_terminals)[0]


def synthesise_trips(stop_dist_m: np.ndarray, arrival_s: np.ndarray, departure_s: np.ndarray,
                     params: DrivingParams, rng: np.random.Generator, draws: int, *,
                     speed_cap_mps: float | np.ndarray | None = None, with_terminals: bool = False
                     ) -> list[SynthCycle]:
    """``draws`` independent cycles of one scheduled trip, in one vectorised pass (as
    :func:`synthesise_trip`, whose single draw is this one's first)."""
    d_stop = np.asarray(stop_dist_m, dtype=np.float64)
    arr = np.asarray(arrival_s, dtype=np.float64)
    dep = np.asarray(departure_s, dtype=np.float64)
    _check_schedule(d_stop, arr, dep)
    n, k = int(draws), d_stop.size
    R = k - 1
    origin = float(arr[0] if with_terminals else dep[0])
    arr, dep = arr - origin, dep - origin
    d = np.diff(d_stop)
    cap = _caps(speed_cap_mps, R, params)
    a = _lognormal(rng, params.accel_mps2, params.accel_trip_sd, params.accel_sd, (n, R), ACCEL_BOUNDS)
    b = _lognormal(rng, params.decel_mps2, params.decel_trip_sd, params.decel_sd, (n, R), DECEL_BOUNDS)
    # dwell windows [w0, w1] per stop: scheduled, or drawn and centred on the stop's time
    w0, w1 = np.tile(arr, (n, 1)), np.tile(dep, (n, 1))
    drawn = (dep <= arr)
    drawn[0] = drawn[-1] = False
    if drawn.any():
        dw = np.round(_lognormal(rng, params.stop_s, params.stop_trip_sd, params.stop_sd, (n, int(drawn.sum())),
                                 (0.0, STOP_MAX_S)))
        w0[:, drawn] = arr[drawn] - np.floor(0.5 * dw)
        w1[:, drawn] = w0[:, drawn] + dw
    if not with_terminals:
        w0[:, 0], w1[:, -1] = dep[0], arr[-1]
    # a run shorter than its drawn driving needs is driven harder, up to the 99th
    # percentile of the launches and brakings, before it is late
    a, b = _harder(d, w0[:, 1:] - w1[:, :-1], a, b, cap, params)
    ev = _draw_events(rng, params, d, n, k)
    least = np.where(d > 0, least_run_time_s(d, a, b, cap) + GRID_MARGIN_S, 0.0)
    for _ in range(8):  # a run the 1 s grid cannot fit (a few metres in under 2 s) gets a second more
        w0r, w1r, late = _retime(w0, w1, least)
        t, v, bounds, ok, n_st, n_dp = _drive(d, w0r, w1r, a.ravel(), b.ravel(), cap, ev, with_terminals, params,
                                              rng)
        if ok.all():
            break
        least = np.where(ok, least, np.maximum(least, w0r[:, 1:] - w1r[:, :-1]) + 1.0)
    else:
        j = int(np.flatnonzero(~ok.all(axis=0))[0])
        raise CevmError(f"stops {j + 1} to {j + 2}: {d[j]:.0f} m cannot be driven at up to {cap[j]:.1f} m/s")
    out = []
    for i in range(n):
        ti, vi = t[bounds[i]:bounds[i + 1]], v[bounds[i]:bounds[i + 1]]
        dist = np.concatenate(([0.0], np.cumsum(0.5 * (vi[:-1] + vi[1:]) * np.diff(ti))))
        out.append(SynthCycle(time_s=ti + origin, speed_mps=vi, distance_m=dist,
                              late_s=float(max(late[i, -2], 0.0)), late_max_s=float(max(late[i].max(), 0.0)),
                              unscheduled_stops=int(n_st[i]), slowdowns=int(n_dp[i])))
    return out


@dataclass(frozen=True, eq=False)
class _Events:
    """Drawn cycles' per-run tilts, their unscheduled stops (run, duration [s], position
    in the run's time as a share; runs numbered draw * (k - 1) + run) and each draw's
    factor on its slowdowns' rate (the slowdowns are drawn once the runs' slack is known)."""

    tilt: np.ndarray
    st_run: np.ndarray
    st_dur: np.ndarray
    st_pos: np.ndarray
    dip_gamma: np.ndarray  # per draw: the factor of its slowdowns' rate
    wob_period: np.ndarray  # per run: the wobble's period [s] and phase
    wob_phase: np.ndarray


def _draw_events(rng: np.random.Generator, params: DrivingParams, d: np.ndarray, n: int, k: int) -> _Events:
    """The tilts and unscheduled stops of n draws (module notes): the stops the logs' rate
    adds to the timetable's (k - 2 between its ends), spread over the runs by distance,
    with each draw's gamma factor; and the draws' factors on the slowdowns' rate."""
    R = k - 1
    total = max(float(d.sum()), 1e-9)
    extra = max(0.0, params.stops_per_km * total / 1000.0 - max(k - 2, 0)) \
        * _gamma_factor(rng, params.stops_trip_cv, n)
    n_stop = rng.poisson(extra[:, None] * d / total).ravel()
    ns = int(n_stop.sum())
    return _Events(
        tilt=np.clip(_finite(params.cruise_tilt) + _finite(params.cruise_tilt_sd) * rng.standard_normal(n * R),
                     -TILT_BOUND, TILT_BOUND),
        st_run=np.repeat(np.arange(n * R), n_stop),
        st_dur=np.round(_lognormal(rng, params.stop_s, params.stop_trip_sd, params.stop_sd, (1, ns),
                                   (STOP_MIN_S, STOP_MAX_S))[0]),
        st_pos=rng.random(ns),
        dip_gamma=_gamma_factor(rng, params.slowdowns_trip_cv, n),
        wob_period=rng.uniform(*WOBBLE_PERIOD_S, n * R), wob_phase=rng.uniform(0.0, 2.0 * np.pi, n * R))


def _retime(w0: np.ndarray, w1: np.ndarray, least: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per draw (row), the dwell windows [w0, w1] moved no earlier, and as little later as
    the runs' ``least`` times and the dwells need (x_i = max(s_i, x_{i-1} + m_i), module
    notes); and how late each time is (w0_0, w1_0, w0_1, ...)."""
    n, k = w0.shape
    s = np.stack((w0, w1), axis=2).reshape(n, 2 * k)
    gaps = np.stack((w1 - w0, np.concatenate((least, np.zeros((n, 1))), axis=1)), axis=2).reshape(n, 2 * k)
    M = np.concatenate((np.zeros((n, 1)), np.cumsum(gaps[:, :-1], axis=1)), axis=1)
    x = np.maximum.accumulate(s - M, axis=1) + M
    return x[:, 0::2], x[:, 1::2], x - s


def _grid(w0: np.ndarray, w1: np.ndarray, with_terminals: bool) -> _Grid:
    """Per draw the grid: whole seconds from its start, and every dwell window's ends (all
    draws in one sort, on their keys; no sort when they all fall on whole seconds, as a
    feed's times and the drawn dwells do)."""
    n, k = w0.shape
    R = k - 1
    t_end = w1[:, -1] if with_terminals else w0[:, -1]
    shift = np.arange(n)[:, None] * _DRAW_SHIFT_S
    ends = np.concatenate((w0, w1), axis=1)
    if np.all(ends == np.round(ends)):
        count = t_end.astype(np.int64) + 1  # 0, 1, ..., t_end
        draw = np.repeat(np.arange(n), count)
        t = (np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count)).astype(np.float64)
        key = t + draw * _DRAW_SHIFT_S
    else:
        whole = np.ceil(t_end).astype(np.int64)  # whole seconds below each end
        draw_of = np.repeat(np.arange(n), whole)
        sec = np.arange(int(whole.sum())) - np.repeat(np.cumsum(whole) - whole, whole)
        ends = np.where(ends <= t_end[:, None], ends, t_end[:, None]) + shift
        below = sec < t_end[draw_of]
        key = np.concatenate((sec[below] + draw_of[below] * _DRAW_SHIFT_S, ends.ravel()))
        key.sort()
        key = key[np.concatenate(([True], np.diff(key) > 1e-6))]
        draw = (key // _DRAW_SHIFT_S).astype(np.int64)
        t = key - draw * _DRAW_SHIFT_S
    dep_keys = (w1[:, :-1] + shift).ravel()
    run = np.searchsorted(dep_keys, key, side="right") - 1
    run = np.clip(run, draw * R, draw * R + R - 1)
    bounds = np.searchsorted(draw, np.arange(n + 1), side="left")
    dt = np.diff(t)
    dt[bounds[1:-1] - 1] = 0.0  # no step from one draw to the next
    wgt = 0.5 * (np.concatenate(([0.0], dt)) + np.concatenate((dt, [0.0])))
    every = np.arange(n * R)
    return _Grid(t=t, run=run, key=key, bounds=bounds, wgt=wgt,
                 lo=np.searchsorted(run, every, side="left"), hi=np.searchsorted(run, every, side="right"))


def _sway(rng: np.random.Generator, tau: np.ndarray, run: np.ndarray, T: np.ndarray, sd: float) -> np.ndarray:
    """The cruise's slow changes on the runs of :data:`SWAY_MIN_RUN_S` or more: exp(sd z -
    sd^2 / 2), z standard normal at knots every :data:`SWAY_KNOT_S` from the run's
    departure, linear between them; 1 on shorter runs and where sd is 0."""
    if sd <= 0 or not np.any(T >= SWAY_MIN_RUN_S):
        return np.ones(tau.size)
    knots = np.floor(np.maximum(T, 0.0) / SWAY_KNOT_S).astype(np.int64) + 2
    first = np.cumsum(knots) - knots
    z = rng.standard_normal(int(knots.sum()))
    z[np.repeat(T < SWAY_MIN_RUN_S, knots)] = 0.5 * sd  # exp(0) on the short runs
    x = np.maximum(tau, 0.0) / SWAY_KNOT_S
    j = np.minimum(np.floor(x).astype(np.int64), knots[run] - 2)
    f = x - j
    zi = z[first[run] + j] * (1.0 - f) + z[first[run] + j + 1] * f
    return np.exp(sd * zi - 0.5 * sd * sd)


def _running_sum(run: np.ndarray, x: np.ndarray, n_runs: int) -> np.ndarray:
    """Each event's ``x`` summed with those before it in its run (events in run order)."""
    by_run = np.bincount(run, weights=x, minlength=n_runs)
    return np.cumsum(x) - np.repeat(np.cumsum(by_run) - by_run, np.bincount(run, minlength=n_runs))


def _drive(d: np.ndarray, w0: np.ndarray, w1: np.ndarray, a: np.ndarray, b: np.ndarray, cap: np.ndarray,
           ev: _Events, with_terminals: bool, params: DrivingParams, rng: np.random.Generator
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The draws' grids end to end, the speeds on them, their bounds, which runs are
    feasible (draws x runs), and per draw the unscheduled stops and slowdowns kept
    (module notes): a run's stops while the time they lose fits in half its slack, then
    its slowdowns while theirs fits in half what is left, all its events dropped if they
    still make it impossible."""
    n, k = w0.shape
    NR = n * (k - 1)
    dd, cc = np.tile(d, n), np.tile(cap, n)
    dep_r, arr_r = w1[:, :-1].ravel(), w0[:, 1:].ravel()
    T = arr_r - dep_r
    slack = np.maximum(T - np.where(dd > 0, least_run_time_s(dd, a, b, cc), 0.0), 0.0)
    # an unscheduled stop loses its standing and the time of braking to it from about the
    # cruise speed and launching again, c (1/a + 1/b) / 2
    c0 = np.minimum((_finite(params.cruise_ratio) or 1.3) * dd / np.maximum(T, 1.0), cc)
    s_lost = ev.st_dur + 0.5 * c0[ev.st_run] * (1.0 / a[ev.st_run] + 1.0 / b[ev.st_run])
    fits = _running_sum(ev.st_run, s_lost, NR) <= 0.5 * slack[ev.st_run]
    st_run, st_dur = ev.st_run[fits], ev.st_dur[fits]
    standing = np.bincount(st_run, weights=st_dur, minlength=NR)
    lost_stops = np.bincount(st_run, weights=s_lost[fits], minlength=NR)
    st_start = dep_r[st_run] + ev.st_pos[fits] * np.maximum(T[st_run] - st_dur, 0.0)
    # slowdowns where the run cruises: after its launch to about its cruise speed (the
    # driving's peak-to-mean ratio times the mean) and a slowdown's window, and as long
    # before its braking; mid-run in a run without such room
    c_est = (_finite(params.cruise_ratio) or 1.3) * dd / np.maximum(T - standing, 1.0)
    lead = c_est / a
    room = T - lead - c_est / b
    # slowdowns at their rate per km, each to its share of the run's cruise speed there;
    # kept while the time they lose, (1/a + 1/b) (c - u)^2 / (2 c) each, fits in half the
    # slack the stops left
    left = np.maximum(slack - lost_stops, 0.0)
    n_dip = rng.poisson(_finite(params.slowdowns_per_km) * dd / 1000.0 * np.repeat(ev.dip_gamma, k - 1))
    r = np.repeat(np.arange(NR), n_dip)
    lead = np.where(room > 0, lead, 0.5 * T)
    dp_t = dep_r[r] + lead[r] + rng.random(r.size) * np.maximum(room[r], 0.0)
    share = np.interp(rng.random(r.size), SHARE_LEVELS, params.slowdown_quantiles)
    c_r = np.minimum(c_est, cc)
    phi_at = 1.0 - ev.tilt[r] * np.clip((dp_t - dep_r[r]) / np.maximum(T[r], 1e-9), 0.0, 1.0)
    dp_u = share * c_r[r] * phi_at
    lost = 0.5 * (1.0 / a[r] + 1.0 / b[r]) * (c_r[r] - dp_u) ** 2 / np.maximum(c_r[r], 1e-9)
    keep = _running_sum(r, lost, NR) <= 0.5 * left[r]
    r, dp_t, dp_u = r[keep], dp_t[keep], dp_u[keep]
    g = _grid(w0, w1, with_terminals)
    t, run, bounds, wgt = g.t, g.run, g.bounds, g.wgt
    slow = dd / np.maximum(T, 1.0) < params.wobble_split_mps  # False where the split is NaN
    amp = np.where(slow, _finite(params.wobble_slow), _finite(params.wobble))
    # the cruise's shape: its tilt, and its wobble (a sine of the driving's amplitude, the
    # run's period and phase); v = min(c phi, h) = phi min(c, h / phi), phi > 0
    tau = t - dep_r[run]
    phi = (1.0 - ev.tilt[run] * np.clip(tau / np.maximum(T[run], 1e-9), 0.0, 1.0)) \
        * (1.0 + amp[run] * np.sin(2.0 * np.pi * tau / ev.wob_period[run] + ev.wob_phase[run])) \
        * _sway(rng, tau, run, T, _finite(params.sway))

    def build(stops_on: np.ndarray, dips_on: np.ndarray, dp_u: np.ndarray) -> tuple[np.ndarray, np.ndarray,
                                                                                 np.ndarray]:
        ks, kd = stops_on[st_run], dips_on[r]
        ev_run = np.concatenate((st_run[ks], r[kd]))
        ev_s = np.concatenate((st_start[ks], dp_t[kd]))
        ev_e = np.concatenate((st_start[ks] + st_dur[ks], dp_t[kd]))
        ev_u = np.concatenate((np.zeros(int(ks.sum())), dp_u[kd]))
        h = _envelope(g, dep_r, arr_r, a, b, cc, ev_run, ev_s, ev_e, ev_u)
        c, ok = _solve_cruise(h / phi, wgt * phi, run, dd)
        return h, c, ok

    # the events of a run they make impossible (the 1 s grid, the estimates) dropped
    stops_on = np.ones(NR, dtype=bool)
    dips_on = np.ones(NR, dtype=bool)
    h, c, ok = build(stops_on, dips_on, dp_u)
    if not ok.all():
        stops_on &= ok
        dips_on &= ok
        h, c, ok = build(stops_on, dips_on, dp_u)
    v = np.minimum(c[run] * phi, h)
    v[v < 1e-9] = 0.0
    R = k - 1
    n_st = np.bincount(st_run[stops_on[st_run]] // R, minlength=n)
    n_dp = np.bincount(r[dips_on[r]] // R, minlength=n)
    return t, v, bounds, ok.reshape(n, R), n_st, n_dp


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
