"""One verdict for every command (pure): what a vehicle's limits say of a source, and
whether it runs the source.

Every command that answers "can this vehicle do this?" (``cevm predict``,
``feasibility``, ``fleet plan``, ``simulate``, ``replay``) computes the same flags the
same way, here:

- ``over_max_gross``: the gross mass is above the vehicle's ``max_gross_kg``;
- ``over_power``: the source asks more wheel power than ``max_power_kw`` (the mean over
  any :data:`POWER_WINDOW_S`, at the row's mass);
- ``over_speed``: the source is faster than ``max_speed_kmh`` (held for
  :data:`SPEED_HOLD_S`);
- ``reserve_ok`` (EV): the lowest state of charge keeps the reserve; ``tank_ok`` (ICE):
  the fuel fits ``tank_l``;
- ``feasible``: all of these pass (:func:`verdict`).

A flag is 1.0 or 0.0, NaN where the vehicle file lacks the limit (it is then not
checked, and ``feasible`` says so: :func:`verdict`).

What a source asks (:class:`Demand`, once per source, for any vehicle):

- its top speed is the highest speed it *holds* for :data:`SPEED_HOLD_S`, so one sample's
  spike (a GPS speed jump) is not a top speed;
- its power is the wheel power of eq. 28 (no rotating inertia) averaged over any
  :data:`POWER_WINDOW_S` of driving, from per-step kinetic and potential energies that
  are first de-spiked (each the median of itself and its two neighbours): a logger's
  one-second jump (a speed held stale and then caught up, an elevation step at a DSM
  tile's edge) puts a whole window's energy into one step, which no drivetrain delivers.

**Logged traces** (stored trips and routes: a vehicle drove them, and a logger measured
them) are held to the vehicle's limits with the tolerance of the measurement, so that a
vehicle's own logs are not flagged for their noise (predict once flagged over_power where feasibility said feasible):

- a logged speed may read high: a speedometer or wheel-speed signal by up to
  :data:`SPEED_READING_HIGH_FRACTION` + :data:`SPEED_READING_HIGH_KMH` (UN ECE
  Regulation 39, the legal bound on a vehicle's indicated speed over its true speed), so
  a log is over the speed limit only beyond that;
- its power is then over the limit only when the least power the log can mean is: its
  speeds up to that much lower (kinetic energy over the square of the reading's factor,
  rolling over the factor, aerodynamic over its cube) and its elevation uncertain by
  :func:`elevation_sd_m` at each end of a window (two standard deviations of the
  difference of two ends).

A cycle file (a target trace, not a measurement) is held to the limits exactly. Every
row also says how far the source goes against each limit (``power_demand_kw``,
``top_speed_kmh``), so a log within its tolerance but over the file's figure is visible.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from cevm.units import KMH_TO_MPS

if TYPE_CHECKING:  # the sweep imports this module: no import back at run time
    from cevm.core.sweep.steptable import LegProfile, StepTable
    from cevm.core.vehicle import Vehicle

#: The window over which the power a source asks is averaged [s]: a drivetrain delivers
#: its rated power for seconds, and one-second steps of a logged trace carry speed and
#: elevation noise (1 m of elevation noise in 1 s is 430 kW at 44 t); over 5 s the
#: kinetic and potential energy of the noise cancel.
POWER_WINDOW_S = 5.0

#: How long a speed must be held to count as a source's top speed [s]: a speed limiter
#: holds the vehicle's top speed, a logger's spike lasts one sample.
SPEED_HOLD_S = 3.0
#: How far a logged speed may read above the true speed: UN ECE Regulation 39 (and EU
#: Directive 75/443/EEC) requires 0 <= indicated - true <= 0.1 true + 4 km/h.
SPEED_READING_HIGH_FRACTION = 0.10
#: The constant part of that bound [km/h].
SPEED_READING_HIGH_KMH = 4.0
#: Standard deviation [m] of a logged road elevation at a point, by how ingest made it
#: (:mod:`cevm.ingest.elevation`): a DSM road profile (DSM noise on tarmac 0.1-0.3 m, a
#: running median's error on vertical curves a few tenths of a metre: 0.3 m); GPS
#: altitude low-passed over 300 m (a 10-30 m error correlated over minutes, so that it
#: moves by about a metre over a window of seconds: 1 m, an assumption); a flat road (no
#: elevation: the power is the flat road's and says nothing of grades: 0).
ELEVATION_SD_M = {"dsm": 0.3, "gps": 1.0, "flat": 0.0}
#: Standard deviations of a window's end-to-end difference the power tolerance allows.
ELEVATION_SIGMAS = 2.0
#: The flags of a verdict, in output order.
FLAGS = ("over_max_gross", "over_power", "over_speed", "reserve_ok", "tank_ok", "feasible")


def elevation_sd_m(elevation_source: str | None) -> float:
    """The elevation uncertainty [m] of a logged trace whose elevation ingest made from
    ``elevation_source`` (``"dsm"``, ``"dsm+gps"``, ``"gps"``, ``"flat"``...: the
    largest of its parts'); :data:`ELEVATION_SD_M` ``["dsm"]`` when unknown."""
    if not elevation_source:
        return ELEVATION_SD_M["dsm"]
    parts = [ELEVATION_SD_M.get(p) for p in elevation_source.split("+")]
    known = [p for p in parts if p is not None]
    return max(known) if known else ELEVATION_SD_M["dsm"]


def speed_reading_low_mps(speed_mps: float) -> float:
    """The least true speed [m/s] a logged speed reading may mean (UN ECE R39)."""
    return max(0.0, (speed_mps - SPEED_READING_HIGH_KMH * KMH_TO_MPS) / (1.0 + SPEED_READING_HIGH_FRACTION))


# ------------------------------------------------------------------------------ demand


def held_top_speed_mps(legs: Sequence[LegProfile], hold_s: float = SPEED_HOLD_S) -> float:
    """The highest speed [m/s] a source holds for ``hold_s``: the largest over every
    stretch of samples lasting at least ``hold_s`` of its lowest speed (a leg shorter
    than that: its lowest speed)."""
    best = 0.0
    for leg in legs:
        t, v = leg.time_s, leg.speed_mps
        if v.size == 0:
            continue
        k = min(max(_longest_reach(t, hold_s * (1.0 - 1e-12)) + 1, 1), v.size)
        # the minimum over each run of k samples (k covers hold_s on the leg's widest
        # sampling; on a uniform grid, exactly the samples of hold_s): k - 1 passes
        low = v[: v.size - k + 1].copy()
        for j in range(1, k):
            np.minimum(low, v[j: v.size - k + 1 + j], out=low)
        best = max(best, float(low.max()))
    return best


def _longest_reach(t: np.ndarray, span: float) -> int:
    """The most samples ahead of any sample ``i`` that the first sample at or after
    ``t[i] + span`` lies (the end of the series where there is none): the largest
    ``searchsorted(t, t + span) - arange``. The first sample's reach ``m``, checked for
    every sample by one comparison (each reaches at most ``m`` ahead when ``t[i + m] >=
    t[i] + span``): on a regular grid, one pass instead of a binary search per sample;
    searched for every sample where the check fails."""
    n = t.size
    s = t + span
    m = int(np.searchsorted(t, s[0], side="left"))
    if 0 < m < n and bool(np.all(t[m:] >= s[: n - m])):
        return m  # the samples from n - m on reach at most the end, n - i <= m ahead
    return int(np.max(np.searchsorted(t, s, side="left") - np.arange(n)))


def _median3(x: np.ndarray) -> np.ndarray:
    """Each element replaced by the median of itself and its two neighbours (the ends
    kept): one-sample spikes go, steps and ramps stay. A new array, with one temporary
    one (a long source's memory)."""
    out = x.copy()
    if x.size < 3:
        return out
    a, b, c = x[:-2], x[1:-1], x[2:]
    mid = out[1:-1]
    hi = np.maximum(a, b)
    np.minimum(hi, c, out=hi)
    np.minimum(a, b, out=mid)
    np.maximum(mid, hi, out=mid)
    return out


#: Masses x windows of one chunk of :func:`affine_peak` (8 MB of float64).
_PEAK_CHUNK_CELLS = 1 << 20


def affine_peak(slope: np.ndarray, icpt: np.ndarray, mass_kg: float | np.ndarray) -> np.ndarray:
    """The largest over windows of ``mass * slope + icpt`` at each mass (a window's mean
    wheel power is affine in the mass), a chunk of masses at a time."""
    m = np.atleast_1d(np.asarray(mass_kg, dtype=np.float64))
    out = np.empty(m.shape)
    step = max(1, _PEAK_CHUNK_CELLS // max(slope.size, 1))
    for lo in range(0, m.size, step):
        out[lo:lo + step] = (m[lo:lo + step, None] * slope[None, :] + icpt[None, :]).max(axis=1)
    return out


def affine_mass_window(slope: np.ndarray, icpt: np.ndarray, limit: float) -> tuple[float, float]:
    """The masses (low, high) between which every window's ``mass * slope + icpt`` stays
    within ``limit`` (each is affine in the mass, so the set is an interval); (nan, nan)
    when no mass does."""
    if np.any((slope == 0) & (icpt > limit)):
        return math.nan, math.nan
    with np.errstate(divide="ignore", invalid="ignore"):
        bound = (limit - icpt) / slope
    hi = float(np.min(bound[slope > 0], initial=math.inf))
    lo = float(np.max(bound[slope < 0], initial=0.0))
    return (math.nan, math.nan) if lo > hi else (lo, hi)


@dataclass(frozen=True, eq=False)
class Demand:
    """What a source asks of a vehicle, for any vehicle: its held top speed and, per
    window of :data:`POWER_WINDOW_S` starting at each moving step (the windows that fit
    in the source; a source shorter than a window is one), the sums over its moving
    steps of the (de-spiked) kinetic and potential energy per kg ``sx`` [J/kg], of the
    rolling term ``sr`` [J/kg per unit Cr] and the aerodynamic term ``sa`` [J/m^2], and
    its duration ``dur`` [s]: the window's mean wheel power at mass m is
    (m (sx + Cr sr) + CdA sa) / dur. ``logged``: a measured trace, held to the limits
    with the tolerance of its measurement (module notes), ``elevation_sd_m`` its
    elevation's uncertainty, and ``sk`` the kinetic part of ``sx`` (a logged trace only:
    its speed reading's tolerance scales it; None for a cycle, to spare the memory)."""

    top_speed_mps: float
    sx: np.ndarray
    sr: np.ndarray
    sa: np.ndarray
    dur: np.ndarray
    logged: bool = False
    elevation_sd_m: float = 0.0
    sk: np.ndarray | None = None

    def coefficients(self, cda_m2: float, cr: float, least: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """(slope [W/kg], intercept [W]) of each window's mean wheel power, affine in the
        mass. ``least``: the least power a logged trace can mean (its speeds read up to
        :data:`SPEED_READING_HIGH_FRACTION` high, its elevation uncertain); a cycle's
        exact power otherwise."""
        if not (least and self.logged and self.sk is not None):
            return (self.sx + cr * self.sr) / self.dur, cda_m2 * self.sa / self.dur
        s = 1.0 + SPEED_READING_HIGH_FRACTION
        sk = self.sk
        se = self.sx - sk - ELEVATION_SIGMAS * math.sqrt(2.0) * 9.81 * self.elevation_sd_m
        return (np.where(sk > 0, sk / s**2, sk) + se + cr * self.sr / s) / self.dur, cda_m2 * self.sa / s**3 / self.dur

    def peak_power_w(self, mass_kg: float | np.ndarray, cda_m2: float, cr: float, least: bool = False
                     ) -> np.ndarray:
        """The largest mean wheel power [W] over any window at each mass (0 for a source
        that never moves)."""
        if self.dur.size == 0:
            return np.zeros(np.shape(np.atleast_1d(mass_kg)))
        return affine_peak(*self.coefficients(cda_m2, cr, least), mass_kg)

    def power_mass_window(self, max_power_w: float, cda_m2: float, cr: float) -> tuple[float, float]:
        """The masses [kg] (low, high) between which the vehicle's ``max_power_w`` is not
        exceeded (the least power for a logged trace); (nan, nan) when no mass is."""
        if self.dur.size == 0:
            return 0.0, math.inf
        return affine_mass_window(*self.coefficients(cda_m2, cr, least=True), max_power_w)

    def over_speed(self, max_speed_mps: float) -> bool:
        """Whether the source is faster than ``max_speed_mps`` (beyond a logged speed's
        reading tolerance)."""
        top = speed_reading_low_mps(self.top_speed_mps) if self.logged else self.top_speed_mps
        return top > max_speed_mps * (1.0 + 1e-9)


def source_demand(st: StepTable, legs: Sequence[LegProfile], *, logged: bool = False,
                  elevation_sd: float = 0.0, window_s: float = POWER_WINDOW_S) -> Demand:
    """The :class:`Demand` of a source from its step table ``st`` and its legs."""
    top = held_top_speed_mps(legs)
    mv = st.moving
    if not mv.any():
        z = np.zeros(0)
        return Demand(top, z, z, z, z, logged, elevation_sd)
    ct = st.t_edges  # the table's own, kept with it
    starts = np.flatnonzero(mv)
    span = window_s * (1.0 - 1e-12)
    dt0 = float(st.dt[0])
    w = max(1, math.ceil(span / dt0)) if dt0 > 0 else 1
    uniform = bool(np.all(st.dt == dt0)) and (w - 1) * dt0 < span
    if uniform:  # a uniform grid: each window is w steps
        ends = starts + w
    else:
        ends = np.searchsorted(ct, ct[starts] + span, side="left")
    full = ends <= st.n  # windows that last window_s within the source
    if full.any():
        starts, ends = starts[full], ends[full]
    else:  # a source shorter than a window: itself, whole
        uniform = False
        starts, ends = starts[:1], np.array([st.n])
    c = np.empty(st.n + 1)  # one running sum at a time, in one buffer: a long source's peak memory
    c[0] = 0.0

    def differences(c: np.ndarray) -> np.ndarray:
        """c[ends] - c[starts]; on a uniform grid the same differences as slices w
        apart, then the moving steps' (one gather instead of two)."""
        if uniform:
            return np.asarray(np.subtract(c[w:], c[:-w])[starts])
        return np.asarray(c[ends] - c[starts])

    def window_sums(values: np.ndarray) -> np.ndarray:
        np.cumsum(values, out=c[1:])
        return differences(c)

    # de-spiked kinetic and potential energies; standstill: the brakes hold the vehicle
    still = ~mv
    k = _median3(st.k)
    k[still] = 0.0
    sk = window_sums(k) if logged else None
    e = st.x - st.k
    x = _median3(e)
    del e
    x[still] = 0.0
    x += k
    del k
    sx = window_sums(x)
    del x
    return Demand(top, sx, window_sums(st.r), window_sums(st.a), differences(ct), logged=logged,
                  elevation_sd_m=elevation_sd, sk=sk)


# ----------------------------------------------------------------------------- flags


def follow_flags(demand: Demand, vehicle: Vehicle, mass_kg: float | np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(over_power, over_speed, power_demand_w) of one vehicle at each gross mass
    ``mass_kg`` on the source of ``demand``: flags 1.0 / 0.0, NaN where the vehicle has
    no ``max_power_kw`` / ``max_speed_kmh``; the power the source asks [W] (its peak
    5-s wheel power at each mass)."""
    m = np.atleast_1d(np.asarray(mass_kg, dtype=np.float64))
    over_p = np.full(m.shape, np.nan)
    over_v = np.full(m.shape, np.nan)
    if vehicle.max_speed_mps is not None:
        over_v[:] = float(demand.over_speed(vehicle.max_speed_mps))
    if vehicle.max_power_w is not None:
        lo, hi = demand.power_mass_window(vehicle.max_power_w, vehicle.cda_m2, vehicle.cr)
        over_p[:] = 1.0 if math.isnan(lo) else ((m < lo) | (m > hi)).astype(float)
    return over_p, over_v, demand.peak_power_w(m, vehicle.cda_m2, vehicle.cr)


def reserve_ok(soc_min_pct: float | np.ndarray, reserve_pct: float) -> np.ndarray:
    """1.0 where the lowest state of charge [%] keeps the reserve [%], 0.0 where not,
    NaN where the lowest state of charge is unknown (NaN)."""
    soc = np.asarray(soc_min_pct, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        return np.where(np.isfinite(soc), (soc >= reserve_pct).astype(float), np.nan)


def tank_ok(fuel_l: float | np.ndarray, tank_l: float | np.ndarray, is_ice: bool | np.ndarray = True
            ) -> np.ndarray:
    """1.0 where the fuel [l] fits the tank [l], 0.0 where not, NaN for rows that are not
    ``is_ice`` and where the tank (a vehicle without ``tank_l``) or the fuel is unknown.
    Fuel burnt never falls along a route, so the total is what the tank must hold."""
    fuel = np.asarray(fuel_l, dtype=np.float64)
    tank = np.asarray(tank_l, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        return np.where(np.asarray(is_ice) & np.isfinite(tank), (fuel <= tank).astype(float), np.nan)


def verdict(*, is_ev: bool | np.ndarray, over_max_gross: float | np.ndarray, over_power: float | np.ndarray,
            over_speed: float | np.ndarray, soc_min_pct: float | np.ndarray | None = None, reserve_pct: float = 0.0,
            fuel_l: float | np.ndarray | None = None, tank_l: float | np.ndarray | None = None,
            energy_ok: float | np.ndarray | None = None) -> dict[str, np.ndarray]:
    """The flags of :data:`FLAGS` of rows (arrays broadcast): ``over_max_gross``,
    ``over_power``, ``over_speed`` as given (1.0 / 0.0, NaN: not checked);
    ``reserve_ok`` for EV rows (lowest SoC ``soc_min_pct`` >= ``reserve_pct``; NaN where
    unknown), ``tank_ok`` for ICE rows (``fuel_l`` <= ``tank_l``; NaN without a tank);
    ``feasible``: 0.0 when any flag fails, else 1.0 when the energy is known to suffice
    (reserve or tank), else NaN (an ICE vehicle without ``tank_l``). A limit the vehicle
    file lacks (max_power_kw, max_speed_kmh, max_gross_kg) is not checked and does not
    make ``feasible`` unknown; the row's flags say which were (NaN). ``energy_ok``
    (1.0 / 0.0 / NaN) instead of the state of charge or the fuel: the reserve or the tank
    judged elsewhere (a fleet plan's day against its energy budget)."""
    ev = np.asarray(is_ev, dtype=bool)
    gross = np.asarray(over_max_gross, dtype=np.float64)
    shape = np.broadcast_shapes(ev.shape, gross.shape, np.shape(over_power), np.shape(over_speed))
    nan = np.full(shape, np.nan)
    if energy_ok is not None:
        given = np.broadcast_to(np.asarray(energy_ok, dtype=np.float64), shape)
        reserve, tank = np.where(ev, given, np.nan), np.where(ev, np.nan, given)
    else:
        reserve = nan if soc_min_pct is None else np.where(ev, reserve_ok(soc_min_pct, reserve_pct), np.nan)
        tank = nan if fuel_l is None or tank_l is None else tank_ok(fuel_l, tank_l, ~ev)
    energy_ok = np.where(ev, reserve, tank)
    fails = np.zeros(shape, dtype=bool)
    for flag in (gross, over_power, over_speed):
        fails |= np.asarray(flag) == 1.0
    fails |= energy_ok == 0.0
    feasible = np.where(fails, 0.0, np.where(energy_ok == 1.0, 1.0, np.nan))
    return {"over_max_gross": np.broadcast_to(gross, shape).astype(float),
            "over_power": np.broadcast_to(np.asarray(over_power, dtype=float), shape).copy(),
            "over_speed": np.broadcast_to(np.asarray(over_speed, dtype=float), shape).copy(),
            "reserve_ok": reserve, "tank_ok": tank, "feasible": feasible}



def first_below(time_s: np.ndarray, distance_m: np.ndarray, values: np.ndarray, level: float
                ) -> tuple[float, float]:
    """(time [s], distance [m]) at which a per-sample series (a state of charge, a tank's
    remaining fuel) first falls below ``level``, linearly interpolated between the
    samples on either side; (nan, nan) if it never does (a series starting below:
    its first sample)."""
    below = np.flatnonzero(values < level)
    if below.size == 0:
        return math.nan, math.nan
    j = int(below[0])
    if j == 0:
        return float(time_s[0]), float(distance_m[0])
    a, b = float(values[j - 1]), float(values[j])
    f = (a - level) / (a - b) if a != b else 1.0
    return (float(time_s[j - 1] + f * (time_s[j] - time_s[j - 1])),
            float(distance_m[j - 1] + f * (distance_m[j] - distance_m[j - 1])))
