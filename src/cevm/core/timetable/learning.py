"""How buses drive, learnt: a fleet's stored trips' driving measured
(:func:`cevm.core.timetable.driving.measure_driving`) and shrunk towards the class prior
(:func:`learn_driving`), the cruise's wobbles and sway matched so that the logs' own
timetables, synthesised, drive as the logs did where the energy sees it
(:func:`match_kinetic`), and the synthesis' own error measured on them (pure). Apart from
:mod:`cevm.core.timetable.driving` because it synthesises
(:mod:`cevm.core.timetable.synthesis`), which needs the parameters' type: the two would
import each other."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from cevm.core.timetable.driving import (
    KINETIC_MATCH_TRIPS,
    SHRINK_N0,
    STAND_MPS,
    SWAY_MIN_RUN_S,
    SYNTH_SD_DRAWS,
    WOBBLE_MAX,
    DrivingParams,
    measure_driving,
    params_from_measures,
)
from cevm.core.timetable.synthesis import synthesise_trip, synthesise_trips, timetable_from_log


def fit_driving(series: Sequence[tuple[np.ndarray, np.ndarray]], source: str) -> DrivingParams:
    """The parameters of ``series`` alone, no prior (how the class priors were made):
    :func:`params_from_measures` with the slowdowns' rate matched (:func:`match_kinetic`)."""
    return match_kinetic(series, params_from_measures(measure_driving(series), source))


def _shrink(x: float, n: float, prior: float, n0: float, *, log: bool = False) -> float:
    """n / (n + n0) of ``x`` and the rest of ``prior`` (on the log scale with ``log``);
    the prior alone where ``x`` is not finite."""
    if not math.isfinite(x) or n <= 0:
        return prior
    w = n / (n + n0)
    if log and x > 0 and prior > 0:
        return math.exp(w * math.log(x) + (1 - w) * math.log(prior))
    return w * x + (1 - w) * prior


def learn_driving(series: Sequence[tuple[np.ndarray, np.ndarray]], *, prior: DrivingParams,
                  label: str = "") -> DrivingParams:
    """The driving of ``series`` (per stored trip (time_s, speed_mps) on its 1 s grid),
    each parameter shrunk towards ``prior`` by how much the logs saw (module notes); the
    cruise's wobbles and sway matched (:func:`match_kinetic`) with the others shrunk, then
    shrunk by the km the logs drove (``kinetic_ratio`` and ``aero_ratio`` are the match's,
    before that). ``label`` names the trips' vehicles in ``source`` (e.g. "EB-01, EB-02")."""
    m = measure_driving(series)
    if m.n_trips == 0 or float(m.km.sum()) <= 0:
        return prior
    x = params_from_measures(m, "")
    n0 = SHRINK_N0
    nt = float(m.n_trips)
    na, nb, ns, nd, nn = (float(np.isfinite(a).sum()) for a in (m.accel, m.decel, m.stop_s, m.dip_share, m.tilt))
    km = float(m.km.sum())
    who = f" of {label}" if label else ""
    shrunk = DrivingParams(
        source=f"learnt from {m.n_trips} trip{'s' if m.n_trips != 1 else ''}{who} ({km:.0f} km), "
               f"shrunk towards the {prior.source}",
        n_trips=m.n_trips,
        accel_mps2=_shrink(x.accel_mps2, na, prior.accel_mps2, n0["launch"], log=True),
        accel_sd=_shrink(x.accel_sd, na, prior.accel_sd, n0["launch"]),
        accel_trip_sd=_shrink(x.accel_trip_sd, nt, prior.accel_trip_sd, n0["trips"]),
        decel_mps2=_shrink(x.decel_mps2, nb, prior.decel_mps2, n0["launch"], log=True),
        decel_sd=_shrink(x.decel_sd, nb, prior.decel_sd, n0["launch"]),
        decel_trip_sd=_shrink(x.decel_trip_sd, nt, prior.decel_trip_sd, n0["trips"]),
        stops_per_km=_shrink(x.stops_per_km, km, prior.stops_per_km, n0["km"]),
        stops_trip_cv=_shrink(x.stops_trip_cv, nt, prior.stops_trip_cv, n0["trips"]),
        stop_s=_shrink(x.stop_s, ns, prior.stop_s, n0["stop"], log=True),
        stop_sd=_shrink(x.stop_sd, ns, prior.stop_sd, n0["stop"]),
        stop_trip_sd=_shrink(x.stop_trip_sd, nt, prior.stop_trip_sd, n0["trips"]),
        slowdowns_per_km=_shrink(x.slowdowns_per_km, km, prior.slowdowns_per_km, n0["km"]),
        slowdowns_trip_cv=_shrink(x.slowdowns_trip_cv, nt, prior.slowdowns_trip_cv, n0["trips"]),
        wobble=prior.wobble, sway=prior.sway, wobble_slow=prior.wobble_slow,
        wobble_split_mps=prior.wobble_split_mps,
        slowdown_quantiles=tuple(_shrink(q, nd, q0, n0["dip"]) for q, q0 in
                                 zip(x.slowdown_quantiles, prior.slowdown_quantiles, strict=True)),
        cruise_tilt=_shrink(x.cruise_tilt, nn, prior.cruise_tilt, n0["launch"]),
        cruise_tilt_sd=_shrink(x.cruise_tilt_sd, nn, prior.cruise_tilt_sd, n0["launch"]),
        cruise_ratio=_shrink(x.cruise_ratio, na, prior.cruise_ratio, n0["launch"]),
        top_speed_mps=_shrink(x.top_speed_mps, km, prior.top_speed_mps, n0["km"]),
        km=km, n_launches=int(na), n_stops=int(ns), n_slowdowns=int(nd))
    matched = match_kinetic(series, shrunk)
    return replace(matched, synthesis_sd=_shrink(matched.synthesis_sd, nt, prior.synthesis_sd, n0["trips"]),
                   wobble=_shrink(matched.wobble, km, prior.wobble, n0["km"]),
                   sway=_shrink(matched.sway, km, prior.sway, n0["km"]),
                   wobble_slow=_shrink(matched.wobble_slow, km, prior.wobble_slow, n0["km"]),
                   wobble_split_mps=_shrink(matched.wobble_split_mps, km, prior.wobble_split_mps, n0["km"]))


def _run_class(d: np.ndarray, arr: np.ndarray, dep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each run's mean speed [m/s] (distance over departure-to-arrival time) and time [s]."""
    T = arr[1:] - dep[:-1]
    return np.diff(d) / np.maximum(T, 1.0), T


def _moments(t: np.ndarray, v: np.ndarray, d: np.ndarray, arr: np.ndarray, dep: np.ndarray,
             split: float) -> np.ndarray:
    """Sums over a speed trace's steps, by the runs of its timetable (``d``, ``arr``,
    ``dep``): the positive kinetic energy per kg [J/kg] (the CE vector's k_pos), the cubed
    speeds [m^3/s^2] (the aerodynamic term's, per unit of 0.5 rho) and the distance [m]
    (trapezoids) of the whole trace; the kinetic energy and distance of its slow runs (mean
    speed below ``split``) and of the others; the cubed speeds and distance of its long
    runs (:data:`SWAY_MIN_RUN_S` or more)."""
    dt = np.diff(t)
    v0, v1 = v[:-1], v[1:]
    kin = np.maximum(0.5 * (v1 * v1 - v0 * v0), 0.0)
    cube = 0.5 * (v0 ** 3 + v1 ** 3) * dt
    dist = 0.5 * (v0 + v1) * dt
    mean, T = _run_class(d, arr, dep)
    j = np.searchsorted(dep[:-1], t[:-1], side="right") - 1
    inrun = j >= 0
    inrun[inrun] = t[:-1][inrun] < arr[1:][j[inrun]]
    jj = np.where(inrun, j, 0)
    slow = inrun & (mean[jj] < split)
    fast = inrun & ~(mean[jj] < split)
    long = inrun & (T[jj] >= SWAY_MIN_RUN_S)
    return np.array([kin.sum(), cube.sum(), dist.sum(), kin[slow].sum(), dist[slow].sum(), kin[fast].sum(),
                     dist[fast].sum(), cube[long].sum(), dist[long].sum()], dtype=np.float64)


def match_kinetic(series: Sequence[tuple[np.ndarray, np.ndarray]], params: DrivingParams, *,
                  trips: int = KINETIC_MATCH_TRIPS) -> DrivingParams:
    """``params`` with the cruise's wobbles and sway that make the series' own timetables
    (:func:`~cevm.core.timetable.synthesis.timetable_from_log`, up to ``trips`` of them
    spread over the series), synthesised, gain the series' positive kinetic energy per km
    on their slow runs (``wobble_slow``: mean speed below ``wobble_split_mps``, the median
    of the runs') and on the others (``wobble``), and have their long runs' cubed speed per
    km (``sway``): secant steps on one amplitude at a time (the wobbles, the sway, the
    wobbles again), each in [0, :data:`WOBBLE_MAX`], with the same random draws at each
    step; ``kinetic_ratio`` and ``aero_ratio`` (the whole trips') say how close they came.
    An amplitude without runs of its kind stays the one given (params unchanged where no
    series moves)."""
    usable = [(np.asarray(t, dtype=np.float64), np.asarray(v, dtype=np.float64)) for t, v in series
              if np.size(t) > 2 and np.any(np.asarray(v) >= STAND_MPS)]
    if not usable:
        return params
    pick = np.unique(np.linspace(0, len(usable) - 1, min(trips, len(usable))).round().astype(np.int64))
    chosen = [usable[i] for i in pick.tolist()]
    tables = [timetable_from_log(t, v) for t, v in chosen]
    means = np.concatenate([_run_class(d, arr, dep)[0] for d, arr, dep in tables])
    split = float(np.median(means[means > 0])) if np.any(means > 0) else math.nan
    params = replace(params, wobble_split_mps=split)

    def per_m(m: np.ndarray) -> np.ndarray:  # all: kinetic, cubed speed; slow, fast: kinetic; long: cubed
        def ratio(x: float, y: float) -> float:
            return x / y if y > 0 else math.nan
        return np.array([ratio(m[0], m[2]), ratio(m[1], m[2]), ratio(m[3], m[4]), ratio(m[5], m[6]),
                         ratio(m[7], m[8])])

    target = per_m(np.sum([_moments(t, v, d, arr, dep, split)
                           for (t, v), (d, arr, dep) in zip(chosen, tables, strict=True)], axis=0))

    def synth(p: DrivingParams) -> np.ndarray:
        rng = np.random.default_rng(0)
        m = np.zeros(9)
        for d, arr, dep in tables:
            c = synthesise_trip(d, arr, dep, p, rng, with_terminals=True)
            m += _moments(c.time_s, c.speed_mps, d, arr, dep, split)
        return per_m(m)

    def secant(p: DrivingParams, field: str, which: int) -> tuple[DrivingParams, np.ndarray | None]:
        if not math.isfinite(target[which]):
            return p, None
        x0, x1 = 0.0, 0.1
        y0, y1 = synth(replace(p, **{field: x0})), synth(replace(p, **{field: x1}))  # type: ignore[arg-type]
        for _ in range(3):
            if not y1[which] > y0[which]:
                break
            x2 = float(np.clip(x1 + (target[which] - y1[which]) * (x1 - x0) / (y1[which] - y0[which]), 0.0,
                               WOBBLE_MAX))
            if x2 == x1:
                break
            x0, y0, x1, y1 = x1, y1, x2, synth(replace(p, **{field: x2}))  # type: ignore[arg-type]
        x, y = (x1, y1) if abs(y1[which] - target[which]) <= abs(y0[which] - target[which]) else (x0, y0)
        return replace(p, **{field: x}), y  # type: ignore[arg-type]

    p = replace(params, wobble=0.0, wobble_slow=0.0)
    p, _ = secant(p, "wobble_slow", 2)
    p, _ = secant(p, "wobble", 3)
    p, _ = secant(p, "sway", 4)
    p, _ = secant(p, "wobble_slow", 2)
    p, got = secant(p, "wobble", 3)
    got = synth(p) if got is None else got
    return replace(p, kinetic_ratio=float(got[0] / target[0]) if target[0] > 0 else math.nan,
                   aero_ratio=float(got[1] / target[1]) if target[1] > 0 else math.nan,
                   synthesis_sd=_synthesis_sd(chosen, tables, p))


#: The proxy vehicle of :func:`_synthesis_sd`: a 12 t city bus, CdA 5.5 m^2, Cr 0.007,
#: its braking credited at half (a diesel credits none, an electric bus about eta^2, 0.6).
PROXY_BUS = (12_000.0, 5.5, 0.007)
PROXY_BRAKING_WEIGHT = 0.5


def _proxy_j(t: np.ndarray, v: np.ndarray) -> float:
    """A speed trace's wheel energy on a flat road for :data:`PROXY_BUS`, its braking
    credited at :data:`PROXY_BRAKING_WEIGHT` (between a diesel's nothing and an electric
    bus's eta^2) [J]: P + w N of the steps' m k + CdA a + Cr m r (eq. 28)."""
    m, cda, cr = PROXY_BUS
    dt = np.diff(t)
    v0, v1 = v[:-1], v[1:]
    step = m * 0.5 * (v1 * v1 - v0 * v0) + cda * 0.25 * 1.225 * (v0 ** 3 + v1 ** 3) * dt \
        + cr * m * 0.5 * 9.81 * (v0 + v1) * dt
    return float(np.maximum(step, 0.0).sum() + PROXY_BRAKING_WEIGHT * np.minimum(step, 0.0).sum())


def _synthesis_sd(chosen: list[tuple[np.ndarray, np.ndarray]], tables: list, p: DrivingParams) -> float:
    """The synthesis' own error beyond its draws' spread, relative to a trip's wheel
    energy: on the logs' own timetables, each synthesised :data:`SYNTH_SD_DRAWS` times,
    the root mean square of (the draws' mean proxy energy / the log's - 1) less what the
    draws' spread explains (the log as one more draw); NaN with fewer than 3 trips."""
    if len(chosen) < 3:
        return math.nan
    rng = np.random.default_rng(1)
    err, spread = [], []
    for (t, v), (d, arr, dep) in zip(chosen, tables, strict=True):
        e_log = _proxy_j(t, v)
        if e_log <= 0:
            continue
        x = np.array([_proxy_j(c.time_s, c.speed_mps) for c in
                      synthesise_trips(d, arr, dep, p, rng, SYNTH_SD_DRAWS, with_terminals=True)]) / e_log
        err.append(float(x.mean()) - 1.0)
        spread.append(float(x.var(ddof=1)))
    if len(err) < 3:
        return math.nan
    excess = float(np.mean(np.square(err))) - float(np.mean(spread)) * (1.0 + 1.0 / SYNTH_SD_DRAWS)
    return math.sqrt(max(excess, 0.0))


def _finite(x: float) -> float:
    return x if math.isfinite(x) else 0.0
