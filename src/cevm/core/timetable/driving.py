"""How buses drive between timed stops: the parameters a scheduled trip's drive cycle is
synthesised from (:mod:`cevm.core.timetable.synthesis`), measured on 1 Hz speed series
(pure, vectorised).

What is measured (:func:`measure_driving`, on each series' own samples; a sample is
*standing* at a speed below :data:`STAND_MPS`):

- **stops**: standstills of at least :data:`STOP_MIN_S` between two moving parts (not a
  trip's first or last standing); their rate per km moved and their durations (the time
  the CE vector counts as idle). Logs cannot tell a passenger stop from a red light: one
  distribution serves for the dwell at a stop the timetable gives no dwell for and for the
  stops between timed stops.
- **launches and brakings**: a launch's acceleration is the mean from standstill to the
  first sample at :data:`LAUNCH_SHARE` of the next moving part's peak speed; a braking's
  deceleration the mean from the last sample at that share of the previous part's peak to
  standstill (moving parts peaking under :data:`PART_MIN_PEAK_MPS` are left out). In a
  synthesised run (constant acceleration to its cruise) the same measure returns the
  acceleration used.
- **slowdowns**: local minima of speed, the lowest within :data:`DIP_WINDOW_S` either
  side, at least :data:`DIP_MIN_MPS` below the highest speed on each side within that
  window, and not inside a stop (a standstill shorter than :data:`STOP_MIN_S` is a
  slowdown to 0). Their rate per km, and their speed as a share of the lower of the
  highest speeds either side (the synthesis slows to that share of its cruise).
- **cruise**: its tilt, from the first sample at :data:`LAUNCH_SHARE` of the part's peak
  to the last: the least-squares slope of speed in time times the part's time, over its
  peak (negative: the speed still rises, as a bus's does once the launch's hard part is
  done); and each moving part's peak speed over its mean speed (reported; the synthesis
  solves the cruise speed from the schedule instead).
- **top speed**: the 99th percentile of moving speed, the default speed cap.

Three parameters are not read off the logs but matched
(:func:`~cevm.core.timetable.learning.match_kinetic`), so that the logs' own timetables
(:func:`~cevm.core.timetable.synthesis.timetable_from_log`), synthesised, drive as the logs
did where the energy sees it:

- the cruise's *wobbles*, a sine's amplitude as a share of the cruise speed (periods of
  10-30 s), one for the runs slower than the median run (mean speed, distance over
  scheduled time: congestion) and one for the others, each to the positive kinetic
  energy per km those runs of the logs gained (the CE vector's k_pos,
  behind the kinetic part of the energy: a speed trace's small changes, ignored by the
  measures above, add up to much of it; a flat cruise between trapezoids gained 26 % less
  than the sample buses' logs, 28 % less than the public bus cycles). A wobble costs no
  time; slowdowns would (a rate matched with them ran away in the public cycles' tight
  runs);
- the *sway* of runs of :data:`SWAY_MIN_RUN_S` or more (the sd of the cruise's log at
  knots a minute apart: a long run's slower changes, traffic and roads), to those runs'
  cubed speed per km (the aerodynamic term's): one cruise per long run lacked 15 % of the
  real Twizy logs', whose commutes stop every few km.

``kinetic_ratio`` and ``aero_ratio`` (the whole trips' cubed speed) say how close they
came: on the sample buses 0.99 and 0.96, on the public bus cycles 1.00 and 0.84, on the
truck cycles 1.00 and 0.85 (their short runs reach higher peaks than one cruise per run
does; the bus cycles' sway and slow wobble reach their bound, :data:`WOBBLE_MAX`, the
trucks' sway stays 0: it does not move their cubed speed); on the car's two cycles the
kinetic energy is 1.2 times theirs with no wobble at all. One wobble for all runs gave
the Twizy's congested city trips 0.7x their logs' kinetic energy and its commutes 2x.

The synthesis' own error (``synthesis_sd``): the logs' own timetables synthesised 4 times
each, the root mean square of the draws' mean wheel energy over the log's, less 1, beyond
what the draws' spread explains (the log as one more draw), for a proxy bus whose braking
counts half (:data:`PROXY_BUS`); scheduled trips add it, times their wheel energy's part,
to their spread. 0.016 on the sample buses (fit_driving on all their trips), 0.064 on the
real Twizy logs, 0.16 on the public bus and truck cycles (the class priors').

Spreads: accelerations, decelerations and stop durations are log-normal (median, and the
sd of their logarithm, split into a between-trip part, the sd of the trips' mean
logarithms beyond what the within-trip scatter explains, and the rest within trips); the
rates per km are Poisson with a between-trip factor (gamma, coefficient of variation
``*_trip_cv``: the trips' rates beyond Poisson scatter). The synthesis draws the trip
parts once per drawn cycle and the within parts per run, so the spread between draws of a
cycle is the spread between trips of the logs.

Learning with few trips (:func:`~cevm.core.timetable.learning.learn_driving`) shrinks each parameter towards the class
prior (:func:`driving_prior`), weighted by how much the logs saw: a parameter measured
on n observations (launches, brakings, stops, slowdowns; km for the rates, trips for the
between-trip spreads) gets ``n / (n + n0)`` of the logs' value and the rest of the
prior's (on the log scale for the log-normal medians), n0 from :data:`SHRINK_N0`: the
prior counts as much as 20 launches, 20 stops, 10 km or 5 trips (wobble and sway: 10 km). With
200 launches the logs' value weighs 91 %.

The class priors (:data:`PRIORS`) are these measurements on public drive cycles, the
ADVISOR cycle library (NREL; WVU, EPA, CARB and others, as ADVISOR states them; 1 Hz):

- ``bus``: CYC_MANHATTAN, CYC_NewYorkBus, CYC_OCC (Orange County), CYC_CBDBUS,
  CYC_UKBUS6 (London), CYC_NurembergR36;
- ``truck`` (and ``van``, for which the library has no cycle of its own): CYC_NYCTRUCK,
  CYC_CBDTRUCK, CYC_UDDSHDV, CYC_WVUCITY, CYC_WVUSUB, CYC_CSHVR_Vehicle;
- ``car`` and ``quadricycle``: CYC_ARTERIAL, CYC_COMMUTER (SAE J1376's business-arterial
  and commuter parts, the library's only light-duty urban cycles there).

The numbers are :func:`fit_driving` (the measures, wobble and sway matched) on the files of
the project's shared folder (``cycles/advisor``, km/h; tests/test_timetable_driving.py
measures them again when the folder is there), rounded to 3 significant digits. A cycle
is one "trip" in those counts. The two car cycles have no slowdown and a stop duration
without spread: their spreads are 0, not guessed.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

#: Below this speed a sample is standing [m/s] (ingest's cleaned speeds are exactly 0 at
#: standstill; public cycles too).
STAND_MPS = 0.1
#: A standstill of at least this long [s] is a stop (timetable_from_log's stops too);
#: shorter ones count as slowdowns to 0.
STOP_MIN_S = 5.0
#: A launch's acceleration is measured up to this share of the moving part's peak speed.
LAUNCH_SHARE = 0.7
#: Moving parts peaking below this speed [m/s] give no launch or braking (creeping in a
#: queue, manoeuvres).
PART_MIN_PEAK_MPS = 3.0
#: A slowdown's window [s] either side and its least depth [m/s] below the speeds on both
#: sides (7.2 km/h: a slowing for a junction, a bus ahead, a signal changing).
DIP_WINDOW_S = 10
DIP_MIN_MPS = 0.5
#: The least cruise (samples between a launch and a braking) whose tilt is measured.
TILT_MIN_SAMPLES = 5
#: The levels of the quantiles a slowdown's share is kept at (drawn by interpolating them).
SHARE_LEVELS = tuple(round(0.05 + 0.1 * i, 2) for i in range(10))
#: The cruise's wobble matched to the logs' kinetic energy (:func:`~cevm.core.timetable.learning.match_kinetic`): on at
#: most this many trips, and at most this amplitude (a share of the cruise speed).
KINETIC_MATCH_TRIPS = 60
#: Draws of each of the logs' own timetables for the synthesis' own error (_synthesis_sd).
SYNTH_SD_DRAWS = 4
WOBBLE_MAX = 0.4
#: Runs this long or longer [s] (departure to arrival) sway (:class:`DrivingParams`).
SWAY_MIN_RUN_S = 180.0
#: Shrinkage towards the prior (module notes): the prior's weight in observations.
SHRINK_N0 = {"launch": 20.0, "stop": 20.0, "dip": 20.0, "km": 10.0, "trips": 5.0}


@dataclass(frozen=True)
class DrivingParams:
    """How a fleet's (or a class's) vehicles drive between timed stops, SI. Log-normal
    quantities have a median and the sd of their logarithm, split into a part shared by a
    trip (``*_trip_sd``) and the rest (within a trip); rates per km have a between-trip
    coefficient of variation (``*_trip_cv``). ``source`` says where they come from,
    ``n_trips`` how many logged trips were learnt from (0 for a prior)."""

    source: str
    n_trips: int
    accel_mps2: float  # launch acceleration, median [m/s^2]
    accel_sd: float  # sd of its log, within trips
    accel_trip_sd: float  # ... between trips
    decel_mps2: float  # braking deceleration, median [m/s^2] (> 0)
    decel_sd: float
    decel_trip_sd: float
    stops_per_km: float  # standstills >= STOP_MIN_S between timed stops and at them
    stops_trip_cv: float
    stop_s: float  # a stop's duration (and a dwell the timetable does not give), median [s]
    stop_sd: float
    stop_trip_sd: float
    slowdowns_per_km: float
    slowdowns_trip_cv: float
    # a slowdown's lowest speed over the lower of the highest either side: quantiles at SHARE_LEVELS
    slowdown_quantiles: tuple[float, ...]
    cruise_tilt: float  # the cruise's fall in speed over a run, as a share of the peak (median)
    cruise_tilt_sd: float
    cruise_ratio: float  # a moving part's peak over its mean speed (median; reported)
    top_speed_mps: float  # the default speed cap: 99th percentile of moving speed
    # the cruise's wobble (a sine's amplitude as a share of the cruise speed, periods of
    # 10-30 s) and, on runs of SWAY_MIN_RUN_S or more, its sway (the sd of its log at
    # knots a minute apart), matched to the logs' positive kinetic energy per km and
    # their long runs' cubed speed per km (match_kinetic)
    wobble: float = 0.0
    sway: float = 0.0
    # ... the wobble of the runs whose mean speed (distance over scheduled time) is below
    # wobble_split_mps (the median of the logs' runs'; NaN: every run wobbles by ``wobble``)
    wobble_slow: float = 0.0
    wobble_split_mps: float = math.nan
    # the positive kinetic energy (kinetic_ratio) and the cubed speed (aero_ratio: the
    # aerodynamic term's) per km of the logs' own timetables synthesised, over the logs'
    # (NaN: not measured)
    kinetic_ratio: float = math.nan
    aero_ratio: float = math.nan
    # the synthesis' own error beyond its draws' spread, as a share of a trip's wheel
    # energy, on the logs' own timetables (NaN: not measured; scheduled_trip_energy adds it)
    synthesis_sd: float = math.nan
    km: float = 0.0  # km of logs (0 for a prior: see source)
    n_launches: int = 0
    n_stops: int = 0
    n_slowdowns: int = 0

    @property
    def slowdown_share(self) -> float:
        """The median slowdown's speed as a share of the speed around it."""
        return float(np.interp(0.5, SHARE_LEVELS, self.slowdown_quantiles))

    def describe(self) -> str:
        """One line for people: the medians and rates, the shape's amplitudes."""
        return (f"launch {self.accel_mps2:.2f} m/s2, braking {self.decel_mps2:.2f} m/s2, "
                f"{self.stops_per_km:.2f} stops/km of {self.stop_s:.0f} s, "
                f"{self.slowdowns_per_km:.2f} slowdowns/km to {100 * self.slowdown_share:.0f} % of the speed, "
                f"wobble {100 * self.wobble_slow:.0f} % below {3.6 * self.wobble_split_mps:.0f} km/h and "
                f"{100 * self.wobble:.0f} % above, sway {100 * self.sway:.0f} %, "
                f"top {3.6 * self.top_speed_mps:.0f} km/h ({self.source})")


@dataclass(frozen=True, eq=False)
class DrivingMeasures:
    """What :func:`measure_driving` found in a set of series: per observation arrays with
    the index of the series (trip) each came from, and per trip km moved."""

    km: np.ndarray  # (n_trips,) km moved
    accel: np.ndarray
    accel_trip: np.ndarray
    decel: np.ndarray
    decel_trip: np.ndarray
    stop_s: np.ndarray
    stop_trip: np.ndarray
    dip_share: np.ndarray
    dip_trip: np.ndarray
    tilt: np.ndarray
    cruise_ratio: np.ndarray
    top_speed_mps: float

    @property
    def n_trips(self) -> int:
        return int(self.km.size)


def _runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start and end (exclusive) indices of the runs of True in ``mask``."""
    d = np.diff(np.concatenate(([False], mask, [False])).astype(np.int8))
    return np.flatnonzero(d == 1), np.flatnonzero(d == -1)


def _tilt(t: np.ndarray, v: np.ndarray, part: np.ndarray, in_part: np.ndarray, first: np.ndarray,
          last: np.ndarray, peak: np.ndarray, span: np.ndarray, use: np.ndarray) -> np.ndarray:
    """Per moving part of ``use`` (launched from and braked to a standstill) with a cruise
    of at least :data:`TILT_MIN_SAMPLES` samples (from its launch's end to its braking's
    start): q = -beta T / peak, beta the least-squares slope of speed in time over the
    cruise, T the part's time from standstill to standstill."""
    n_parts = peak.size
    idx = np.arange(v.size)
    p = np.where(in_part, part, 0)
    cruise = in_part & (idx >= first[p]) & (idx <= last[p]) & use[p]
    pc = part[cruise]
    tc = t[cruise] - t[first[pc]]
    vc = v[cruise]
    n = np.bincount(pc, minlength=n_parts).astype(np.float64)
    st = np.bincount(pc, weights=tc, minlength=n_parts)
    sv = np.bincount(pc, weights=vc, minlength=n_parts)
    stt = np.bincount(pc, weights=tc * tc, minlength=n_parts)
    stv = np.bincount(pc, weights=tc * vc, minlength=n_parts)
    den = n * stt - st * st
    good = use & (n >= TILT_MIN_SAMPLES) & (den > 0)
    beta = (n[good] * stv[good] - st[good] * sv[good]) / den[good]
    return -beta * span[good] / peak[good]


def _one_series(t: np.ndarray, v: np.ndarray) -> dict[str, np.ndarray]:
    """The measures of one series (module notes)."""
    moving = v >= STAND_MPS
    ms, me = _runs(moving)  # moving parts [ms, me)
    ss, se = _runs(~moving)  # standstills [ss, se)
    out: dict[str, np.ndarray] = {}
    # distance moved (trapezoid, as the CE model's)
    dt = np.diff(t)
    out["km"] = np.array([float(np.sum((v[:-1] + v[1:]) * dt)) * 0.5e-3])
    # interior standstills: both neighbours moving
    inner = (ss > 0) & (se < v.size)
    dur = t[np.maximum(se - 1, 0)] - t[ss]
    is_stop = inner & (dur >= STOP_MIN_S)
    out["stop_s"] = dur[is_stop]
    # moving parts' peaks and means
    if ms.size:
        part = np.searchsorted(ms, np.arange(v.size), side="right") - 1
        in_part = moving & (part >= 0)
        peak = np.zeros(ms.size)
        np.maximum.at(peak, part[in_part], v[in_part])
        step = np.append(dt, 0.0)
        dist = np.bincount(part[in_part], weights=(v * step)[in_part], minlength=ms.size)
        dur_part = np.bincount(part[in_part], weights=step[in_part], minlength=ms.size)
        mean = dist / np.maximum(dur_part, 1e-9)
        ok = peak >= PART_MIN_PEAK_MPS
        out["cruise_ratio"] = (peak / np.maximum(mean, 1e-9))[ok & (ms > 0) & (me < v.size)]
        # launches: from the last standing sample before the part to the first at LAUNCH_SHARE * peak
        thr = LAUNCH_SHARE * peak
        above = in_part & (v >= thr[np.maximum(part, 0)])
        first = np.full(ms.size, -1)
        last = np.full(ms.size, -1)
        ai = np.flatnonzero(above)
        if ai.size:
            p = part[ai]
            uniq, first_pos = np.unique(p, return_index=True)
            first[uniq] = ai[first_pos]
            last_pos = np.r_[first_pos[1:] - 1, ai.size - 1]
            last[uniq] = ai[last_pos]
        launch = ok & (ms > 0) & (first >= 0)
        t0 = t[np.maximum(ms - 1, 0)]
        out["accel"] = v[first[launch]] / np.maximum(t[first[launch]] - t0[launch], 1e-9)
        brake = ok & (me < v.size) & (last >= 0)
        t1 = t[np.minimum(me, v.size - 1)]
        out["decel"] = v[last[brake]] / np.maximum(t1[brake] - t[last[brake]], 1e-9)
        out["tilt"] = _tilt(t, v, part, in_part, first, last, peak, t1 - t0, launch & brake)
    else:
        out["cruise_ratio"] = out["accel"] = out["decel"] = out["tilt"] = np.zeros(0)
        mean = np.zeros(0)
        part = np.full(v.size, -1)
    # slowdowns: window minima deep enough on both sides, outside stops
    w = DIP_WINDOW_S
    if v.size > 2 * w + 1 and ms.size:
        pad = np.concatenate((np.full(w, np.inf), v, np.full(w, np.inf)))
        win = np.lib.stride_tricks.sliding_window_view(pad, 2 * w + 1)
        lowest = win.min(axis=1)
        padm = np.concatenate((np.full(w, -np.inf), v, np.full(w, -np.inf)))
        winm = np.lib.stride_tricks.sliding_window_view(padm, w + 1)
        left = winm[:-w].max(axis=1)  # max over [i - w, i]
        right = winm[w:].max(axis=1)  # max over [i, i + w]
        cand = (v <= lowest) & (left - v >= DIP_MIN_MPS) & (right - v >= DIP_MIN_MPS)
        mark = np.zeros(v.size + 1, dtype=np.int64)
        np.add.at(mark, ss[is_stop], 1)
        np.add.at(mark, se[is_stop], -1)
        in_stop = np.cumsum(mark[:-1]) > 0
        cand &= ~in_stop
        cand[1:] &= ~cand[:-1]  # a plateau's first sample only
        di = np.flatnonzero(cand)
        out["dip_share"] = v[di] / np.maximum(np.minimum(left[di], right[di]), 1e-9)
    else:
        out["dip_share"] = np.zeros(0)
    out["moving_speed"] = v[moving]
    return out


def measure_driving(series: Sequence[tuple[np.ndarray, np.ndarray]]) -> DrivingMeasures:
    """The measures of the module notes on each (time_s, speed_mps) series (a trip, or a
    public cycle), pooled with the index of the series each observation came from."""
    parts: dict[str, list[np.ndarray]] = {}
    trips: dict[str, list[np.ndarray]] = {}
    speeds = []
    for i, (t, v) in enumerate(series):
        t = np.asarray(t, dtype=np.float64)
        v = np.asarray(v, dtype=np.float64)
        if t.size < 2:
            continue
        m = _one_series(t, v)
        speeds.append(m.pop("moving_speed"))
        for k, a in m.items():
            parts.setdefault(k, []).append(a)
            trips.setdefault(k, []).append(np.full(a.size, i, dtype=np.int64))

    def cat(k: str) -> np.ndarray:
        return np.concatenate(parts[k]) if parts.get(k) else np.zeros(0)

    def tri(k: str) -> np.ndarray:
        return np.concatenate(trips[k]) if trips.get(k) else np.zeros(0, dtype=np.int64)

    allv = np.concatenate(speeds) if speeds else np.zeros(0)
    return DrivingMeasures(
        km=cat("km"), accel=cat("accel"), accel_trip=tri("accel"), decel=cat("decel"), decel_trip=tri("decel"),
        stop_s=cat("stop_s"), stop_trip=tri("stop_s"), dip_share=cat("dip_share"), dip_trip=tri("dip_share"),
        tilt=cat("tilt"), cruise_ratio=cat("cruise_ratio"),
        top_speed_mps=float(np.percentile(allv, 99)) if allv.size else math.nan)


def _log_stats(x: np.ndarray, trip: np.ndarray) -> tuple[float, float, float]:
    """Median, within-trip and between-trip sd of log(x) (x > 0): the between part the
    variance of the trips' mean logs beyond what the within scatter explains."""
    x = np.asarray(x, dtype=np.float64)
    ok = np.isfinite(x) & (x > 0)
    x, trip = np.log(x[ok]), trip[ok]
    if x.size < 2:
        return (math.exp(float(x[0])) if x.size else math.nan), math.nan, math.nan
    med = math.exp(float(np.median(x)))
    _, codes, counts = np.unique(trip, return_inverse=True, return_counts=True)
    means = np.bincount(codes, weights=x) / counts
    resid = x - means[codes]
    dof = x.size - counts.size
    within = math.sqrt(float(resid @ resid) / dof) if dof > 0 else float(np.std(x))
    if counts.size >= 2:
        between_var = float(np.var(means, ddof=1)) - within ** 2 * float(np.mean(1.0 / counts))
        between = math.sqrt(max(between_var, 0.0))
    else:
        between = math.nan
    return med, within, between


def _rate_stats(count_trip: np.ndarray, km: np.ndarray) -> tuple[float, float]:
    """Rate per km (all trips pooled) and the between-trip coefficient of variation of
    the trips' rates beyond Poisson scatter (method of moments)."""
    n = np.bincount(count_trip, minlength=km.size).astype(np.float64) if km.size else np.zeros(0)
    total_km = float(km.sum())
    if total_km <= 0:
        return math.nan, math.nan
    rate = float(n.sum()) / total_km
    use = km > 0.2
    if use.sum() < 2 or rate <= 0:
        return rate, math.nan
    # Var(n_i) = mu_i + cv^2 mu_i^2, mu_i = rate km_i
    mu = rate * km[use]
    excess = float(np.sum((n[use] - mu) ** 2 - mu)) / float(np.sum(mu ** 2))
    return rate, math.sqrt(max(excess, 0.0))


def params_from_measures(m: DrivingMeasures, source: str) -> DrivingParams:
    """The parameters of measures ``m`` alone (no prior): NaN where nothing was seen, no
    wobble (:func:`~cevm.core.timetable.learning.match_kinetic` gives it)."""
    a = _log_stats(m.accel, m.accel_trip)
    b = _log_stats(m.decel, m.decel_trip)
    s = _log_stats(m.stop_s, m.stop_trip)
    stops, stops_cv = _rate_stats(m.stop_trip, m.km)
    dips, dips_cv = _rate_stats(m.dip_trip, m.km)
    share = m.dip_share[np.isfinite(m.dip_share)]
    return DrivingParams(
        source=source, n_trips=m.n_trips,
        accel_mps2=a[0], accel_sd=a[1], accel_trip_sd=a[2],
        decel_mps2=b[0], decel_sd=b[1], decel_trip_sd=b[2],
        stops_per_km=stops, stops_trip_cv=stops_cv,
        stop_s=s[0], stop_sd=s[1], stop_trip_sd=s[2],
        slowdowns_per_km=dips, slowdowns_trip_cv=dips_cv,
        slowdown_quantiles=tuple(float(q) for q in np.quantile(share, SHARE_LEVELS)) if share.size
        else (math.nan,) * len(SHARE_LEVELS),
        cruise_tilt=float(np.median(m.tilt)) if m.tilt.size else math.nan,
        cruise_tilt_sd=float(np.std(m.tilt, ddof=1)) if m.tilt.size > 1 else math.nan,
        cruise_ratio=float(np.median(m.cruise_ratio)) if m.cruise_ratio.size else math.nan,
        top_speed_mps=m.top_speed_mps, km=float(m.km.sum()), n_launches=int(m.accel.size),
        n_stops=int(m.stop_s.size), n_slowdowns=int(m.dip_share.size))


#: The class priors (module notes: measured on the ADVISOR cycles with
#: :func:`measure_driving`, rounded to the digits shown).
PRIORS: dict[str, DrivingParams] = {
    "bus": DrivingParams(
        source="class prior (bus: ADVISOR's Manhattan, New York bus, Orange County, CBD, UKBUS6 and "
               "Nuremberg 36 cycles)", n_trips=0,
        accel_mps2=0.764, accel_sd=0.298, accel_trip_sd=0.389, decel_mps2=0.939, decel_sd=0.483,
        decel_trip_sd=0.348, stops_per_km=3.59, stops_trip_cv=0.178, stop_s=12.0, stop_sd=0.274,
        stop_trip_sd=0.663, slowdowns_per_km=2.55, slowdowns_trip_cv=0.748, slowdown_quantiles=(0.0, 0.0,
        0.00718, 0.0105, 0.0184, 0.11, 0.225, 0.452, 0.64, 0.818), cruise_tilt=-0.115, cruise_tilt_sd=0.279,
        cruise_ratio=1.6, top_speed_mps=14.2, wobble=0.137, sway=0.4, wobble_slow=0.4, wobble_split_mps=4.92,
        kinetic_ratio=0.999, aero_ratio=0.842, synthesis_sd=0.164, km=34.5, n_launches=148, n_stops=124,
        n_slowdowns=88),
    "truck": DrivingParams(
        source="class prior (truck: ADVISOR's NYC truck, CBD truck, UDDS HDV, WVU city and suburban and "
               "CSHVR cycles)", n_trips=0,
        accel_mps2=0.32, accel_sd=0.455, accel_trip_sd=0.378, decel_mps2=0.585, decel_sd=0.646,
        decel_trip_sd=0.318, stops_per_km=1.48, stops_trip_cv=0.55, stop_s=20.0, stop_sd=0.744,
        stop_trip_sd=0.354, slowdowns_per_km=1.77, slowdowns_trip_cv=0.375, slowdown_quantiles=(0.0, 0.0864,
        0.156, 0.332, 0.457, 0.727, 0.788, 0.807, 0.924, 0.944), cruise_tilt=-0.28, cruise_tilt_sd=0.218,
        cruise_ratio=1.75, top_speed_mps=24.6, wobble=0.083, sway=0.0, wobble_slow=0.248,
        wobble_split_mps=5.02, kinetic_ratio=0.998, aero_ratio=0.85, synthesis_sd=0.165, km=44.0,
        n_launches=53, n_stops=65, n_slowdowns=78),
    # no slowdown in these two cycles: its shares 0 (never drawn: the rate is 0), its spreads
    # 0 where a cycle pair cannot give one
    "car": DrivingParams(
        source="class prior (car: ADVISOR's SAE J1376 arterial and commuter cycles)", n_trips=0,
        accel_mps2=0.752, accel_sd=0.0108, accel_trip_sd=0.165, decel_mps2=1.86, decel_sd=0.0337,
        decel_trip_sd=0.0416, stops_per_km=0.31, stops_trip_cv=1.0, stop_s=6.0, stop_sd=2.72e-16,
        stop_trip_sd=0.0, slowdowns_per_km=0.0, slowdowns_trip_cv=0.0, slowdown_quantiles=(0.0, 0.0, 0.0, 0.0,
        0.0, 0.0, 0.0, 0.0, 0.0, 0.0), cruise_tilt=-0.232, cruise_tilt_sd=0.058, cruise_ratio=1.35,
        top_speed_mps=24.6, wobble=0.0, sway=0.338, wobble_slow=0.0, wobble_split_mps=13.0, kinetic_ratio=1.2,
        aero_ratio=1.0, synthesis_sd=0.0, km=9.66, n_launches=5, n_stops=3, n_slowdowns=0),
}


def driving_prior(vehicle_class: str | None) -> DrivingParams:
    """The class prior of ``vehicle_class`` ("bus", "truck", "van", "car",
    "quadricycle"; None or another: the bus's, said in ``source``)."""
    cls = (vehicle_class or "bus").lower()
    key = {"van": "truck", "quadricycle": "car"}.get(cls, cls)
    p = PRIORS.get(key)
    if p is None:
        return replace(PRIORS["bus"], source=f"class prior (bus: no drive-cycle prior for class {cls!r})")
    if key != cls:
        return replace(p, source=f"class prior ({cls}: the {key} cycles)")
    return p if vehicle_class is not None else replace(p, source="class prior (bus: no class given)")
