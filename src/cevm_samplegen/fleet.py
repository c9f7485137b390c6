"""The fleet: duties, vehicles, day plans, and the truth trips they drive."""

from __future__ import annotations

import dataclasses
import inspect
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime

import numpy as np

from cevm.units import M_PER_MILE, MPS_TO_KMH, S_PER_H
from cevm_samplegen.common import DEFAULT_SEED, seeded_rng
from cevm_samplegen.consumption import (
    DRIVER_MAX_WHEEL_POWER_W,
    STANDIN,
    Consumption,
    StandInParams,
    TripConditions,
    standin_consumption,
)
from cevm_samplegen.cycles import MicroTripSpec, micro_trip_cycle
from cevm_samplegen.weather import DayWeather, ForcedDay, day_weather
from cevm_samplegen.world import DsmSpec, World, build_world

#: ``consumption_fn(kind, time_s, speed_mps, elevation_m, mass_kg, *, conditions) ->
#: Consumption | cumulative array`` (see :mod:`cevm_samplegen.consumption`).
ConsumptionFn = Callable[..., "Consumption | np.ndarray"]


def power_limited_trace(v_target: np.ndarray, h_of_s: Callable[[np.ndarray], np.ndarray], mass_kg: float,
                        p: StandInParams, max_wheel_power_w: float, dt_s: float = 1.0) -> np.ndarray:
    """A driver who follows ``v_target`` [m/s] but never asks the wheels for more than
    ``max_wheel_power_w``: v_{i+1} = max(0, min(v_target_{i+1}, v_i + a_max dt)) with
    a_max = (P_max / max(v_i, 1 m/s) - F_roll - F_aero - F_grade) / (m x rot_factor), the
    grade taken 10 m ahead on the road ``h_of_s`` (elevation [m] at distance [m]). A
    loaded truck thus accelerates slower and crawls up steep hills, as a real one does.

    A sequential recurrence (each speed depends on the last), so a plain loop: this runs
    once per generated trip, not in any hot path.
    """
    n = v_target.size
    dist_max = float(np.sum(0.5 * (v_target[1:] + v_target[:-1])) * dt_s) + 50.0
    step = 2.0
    grid = np.arange(0.0, dist_max + 2 * step, step)
    h = np.asarray(h_of_s(grid), dtype=float)
    grade = np.append((h[5:] - h[:-5]) / (5 * step), np.zeros(5)).tolist()
    m_eff = mass_kg * p.rot_factor
    g, rho = 9.81, 1.225
    vt = v_target.tolist()
    v = [vt[0]] * n
    s = 0.0
    for i in range(n - 1):
        vi = v[i]
        k = min(int(s / step), len(grade) - 1)
        f_res = mass_kg * g * (p.cr + grade[k]) + 0.5 * rho * p.cda_m2 * vi * vi
        a_max = (max_wheel_power_w / max(vi, 1.0) - f_res) / m_eff
        vn = min(vt[i + 1], vi + a_max * dt_s)
        vn = vn if vn > 0.0 else 0.0
        v[i + 1] = vn
        s += 0.5 * (vi + vn) * dt_s
    return np.asarray(v)


@dataclass(frozen=True)
class DutySpec:
    """How a vehicle works a day.

    A trip's speed trace is the concatenation of micro-trip blocks ``segments``: (spec,
    (min, max) micro-trips). ``trips_per_day`` (min, max); ``layover_s`` (min, max)
    ignition-off pause between trips; ``first_start_utc_h`` (min, max) start of the first
    trip in hours after midnight UTC of the day (negative = the evening before);
    ``max_speed_kmh`` caps the trace (HGV limiter 90 km/h); ``load`` the load model:
    ``"passengers"`` (0-60 x 75 kg per trip), ``"drops"`` (a payload drawn in
    ``payload_kg`` falls by ``drop_kg`` after each trip), ``"out_back"`` (heavy out, in
    ``payload_kg``, light back, in ``return_kg``).
    """

    segments: tuple[tuple[MicroTripSpec, tuple[int, int]], ...]
    trips_per_day: tuple[int, int]
    layover_s: tuple[float, float]
    first_start_utc_h: tuple[float, float]
    max_speed_kmh: float
    load: str
    payload_kg: tuple[float, float] = (14000.0, 26000.0)
    drop_kg: tuple[float, float] = (3000.0, 8000.0)
    return_kg: tuple[float, float] = (0.0, 9000.0)


URBAN_BUS = MicroTripSpec(cruise_kmh=(20.0, 48.0), cruise_s=(10.0, 60.0), dwell_s=(8.0, 40.0),
                          accel_mps2=(0.6, 1.1), decel_mps2=(0.8, 1.4), fluctuation_kmh=2.0)
#: Town deliveries: short runs between junctions and drops, engine idling at each.
URBAN_TRUCK = MicroTripSpec(cruise_kmh=(18.0, 48.0), cruise_s=(8.0, 50.0), dwell_s=(5.0, 90.0),
                            accel_mps2=(0.3, 0.6), decel_mps2=(0.5, 1.0), fluctuation_kmh=2.0)
TOWN_TRUCK = MicroTripSpec(cruise_kmh=(30.0, 64.0), cruise_s=(20.0, 120.0), dwell_s=(3.0, 30.0),
                           accel_mps2=(0.3, 0.6), decel_mps2=(0.5, 0.9), fluctuation_kmh=2.0)
RURAL_TRUCK = MicroTripSpec(cruise_kmh=(50.0, 88.0), cruise_s=(60.0, 300.0), dwell_s=(3.0, 25.0),
                            accel_mps2=(0.25, 0.5), decel_mps2=(0.5, 0.9), fluctuation_kmh=2.5)
MOTORWAY = MicroTripSpec(cruise_kmh=(80.0, 89.0), cruise_s=(500.0, 1300.0), dwell_s=(2.0, 15.0),
                         accel_mps2=(0.15, 0.35), decel_mps2=(0.3, 0.6), fluctuation_kmh=1.5)

_REGIONAL = ((TOWN_TRUCK, (2, 4)), (RURAL_TRUCK, (3, 5)), (TOWN_TRUCK, (1, 3)))
_LONGHAUL = ((TOWN_TRUCK, (2, 3)), (MOTORWAY, (2, 3)), (TOWN_TRUCK, (1, 2)))

DUTIES: dict[str, DutySpec] = {
    "bus": DutySpec(((URBAN_BUS, (14, 20)),), (3, 3), (720.0, 1500.0), (5.0, 5.6), 50.0, "passengers"),
    # The sample fleet's logged days: 4-5 trips of the day's duty, the first at a random
    # hour of the morning (so the logs see different parts of the day's temperature cycle).
    "bus-logged": DutySpec(((URBAN_BUS, (14, 20)),), (4, 5), (720.0, 1500.0), (5.5, 11.0), 50.0, "passengers"),
    "regional": DutySpec(_REGIONAL, (3, 3), (900.0, 1800.0), (5.5, 10.0), 89.5, "drops"),
    # Urban multi-drop: 4 rounds in town from the depot, 4-12 t falling 1-2.5 t a round.
    "urban": DutySpec(((URBAN_TRUCK, (16, 22)),), (4, 4), (900.0, 1800.0), (5.0, 10.0), 50.0, "drops",
                      payload_kg=(6000.0, 12000.0), drop_kg=(1000.0, 2500.0)),
    "longhaul": DutySpec(_LONGHAUL, (2, 2), (1800.0, 2700.0), (4.0, 10.0), 89.5, "out_back",
                         payload_kg=(15000.0, 26000.0)),
    # Night trunk for the portal: first trip starts 23:40-23:50 UTC the evening before.
    "night": DutySpec(((TOWN_TRUCK, (2, 3)), (MOTORWAY, (2, 2)), (TOWN_TRUCK, (1, 2))), (2, 2), (1200.0, 1800.0),
                      (-0.33, -0.17), 89.5, "out_back", payload_kg=(15000.0, 26000.0)),
    # Full working days (benchmark fleets): the same duties, 4-6 h of driving.
    "bus-day": DutySpec(((URBAN_BUS, (14, 20)),), (12, 12), (720.0, 1500.0), (5.0, 5.6), 50.0, "passengers"),
    "regional-day": DutySpec(_REGIONAL, (9, 9), (900.0, 1800.0), (5.5, 6.5), 89.5, "drops"),
    "longhaul-day": DutySpec(_LONGHAUL, (6, 6), (1800.0, 2700.0), (4.0, 4.5), 89.5, "out_back",
                             payload_kg=(15000.0, 26000.0)),
    # --small duties: a few minutes of driving.
    "bus-short": DutySpec(((URBAN_BUS, (3, 4)),), (2, 2), (700.0, 800.0), (7.0, 7.1), 50.0, "passengers"),
    "truck-short": DutySpec(((TOWN_TRUCK, (2, 3)),), (2, 2), (700.0, 800.0), (6.0, 6.1), 89.5, "drops"),
    "urban-short": DutySpec(((URBAN_TRUCK, (5, 6)),), (2, 2), (700.0, 800.0), (12.0, 12.1), 50.0, "drops",
                            payload_kg=(6000.0, 12000.0), drop_kg=(1000.0, 2500.0)),
    # Starts 00:55-00:56 UTC on the DST day: the trip crosses 01:00 UTC.
    "night-short": DutySpec(((TOWN_TRUCK, (3, 3)),), (1, 1), (700.0, 800.0), (0.92, 0.93), 89.5, "out_back",
                            payload_kg=(15000.0, 26000.0)),
}

#: Ignition-off time before the first trip of a logging day [s]: parked overnight.
OVERNIGHT_SOAK_S = 12.0 * S_PER_H


@dataclass(frozen=True)
class VehicleSpec:
    """One vehicle: id (srf ``vehicle_id`` or portal ``Registration``), type (the
    ``kind`` passed to the consumption function), duty and route (or a ``schedule`` of
    (duty, route) per logging day, repeated if shorter), kerb mass [kg], and its
    sensors' quirks: flow meter fitted, counter start values, ECU fuel bias (factor on
    the ECU's fuel counter and rate), wheel-speed calibration factor, the ambient air
    temperature sensor's bias [K]."""

    vehicle_id: str
    vehicle_type: str
    duty: str
    route: str
    kerb_mass_kg: float
    flowmeter: bool = False
    fuel_counter_start_l: float = 0.0
    energy_counter_start_kwh: float = 0.0
    odometer_start_m: float = 0.0
    ecu_fuel_bias: float = 1.0
    wheel_speed_scale: float = 1.0
    ambient_bias_k: float = 0.0
    schedule: tuple[tuple[str, str], ...] = ()

    def duty_on(self, day_index: int) -> tuple[str, str]:
        """(duty, route) of the vehicle's ``day_index``-th logging day."""
        return self.schedule[day_index % len(self.schedule)] if self.schedule else (self.duty, self.route)

    @property
    def routes(self) -> set[str]:
        return {self.route} | {r for _, r in self.schedule}


@dataclass(frozen=True)
class FleetSpec:
    """What to generate: srf vehicles and their logging days (ISO dates), portal vehicles
    and days, the DSM, days of given weather (``forced_weather``; the others are drawn
    from the climate), and the deliberate faults: ``clock_step`` (vehicle, day index,
    trip index, seconds the clock ran ahead before a mid-trip correction), ``fuel_reset``
    (vehicle, day index, trip index, new counter value [l]), ``gzip_files`` (vehicle, day
    index) written as .csv.gz."""

    srf_vehicles: tuple[VehicleSpec, ...]
    srf_dates: tuple[str, ...]
    portal_vehicles: tuple[VehicleSpec, ...]
    portal_dates: dict[str, tuple[str, ...]]
    dsm: DsmSpec = dataclasses.field(default_factory=DsmSpec)
    clock_step: tuple[str, int, int, float] | None = None
    fuel_reset: tuple[str, int, int, float] | None = None
    gzip_files: tuple[tuple[str, int], ...] = ()
    forced_weather: tuple[ForcedDay, ...] = ()

    def weather(self, date: str, seed: int) -> DayWeather:
        """The weather of ``date``: forced, or drawn from the climate."""
        forced = next((f for f in self.forced_weather if f.date == date), None)
        return day_weather(date, seed, forced)


BUS_KERB_KG = 9000.0
HGV_KERB_KG = 18000.0

#: The cold snap at the end of January 2019 (frost, clear) and the heat of late July and
#: late August 2019: the days that make the heating and the air conditioning work.
SAMPLE_WEATHER = (
    ForcedDay("2019-01-31", -5.5, 1.0, 0.15),
    ForcedDay("2019-02-01", -4.0, 2.5, 0.35),
    ForcedDay("2019-07-25", 18.0, 31.0, 0.10),
    ForcedDay("2019-08-27", 15.5, 29.0, 0.15),
)

SAMPLE_FLEET = FleetSpec(
    srf_vehicles=(
        VehicleSpec("EB-01", "electric-bus", "bus-logged", "bus-1", BUS_KERB_KG, energy_counter_start_kwh=48213.7,
                    ambient_bias_k=0.4),
        VehicleSpec("EB-02", "electric-bus", "bus-logged", "bus-2", BUS_KERB_KG, energy_counter_start_kwh=51977.2,
                    ambient_bias_k=-0.3),
        VehicleSpec("HGV-11", "diesel-hgv", "regional", "regional", HGV_KERB_KG, flowmeter=True,
                    fuel_counter_start_l=96310.5, ecu_fuel_bias=1.03, wheel_speed_scale=1.015, ambient_bias_k=0.7,
                    schedule=(("regional", "regional"), ("urban", "bus-2"), ("regional", "regional"),
                              ("urban", "bus-1"), ("regional", "regional"), ("urban", "bus-2"))),
        VehicleSpec("HGV-21", "diesel-hgv", "longhaul", "trunk", HGV_KERB_KG, fuel_counter_start_l=1843210.5,
                    ambient_bias_k=-0.2,
                    schedule=(("longhaul", "trunk"), ("regional", "regional"), ("longhaul", "trunk"),
                              ("longhaul", "trunk"), ("regional", "regional"), ("longhaul", "trunk"))),
    ),
    srf_dates=("2019-01-31", "2019-02-01", "2019-04-10", "2019-05-15", "2019-07-25", "2019-08-27"),
    portal_vehicles=(
        VehicleSpec("KX19 LMR", "diesel-hgv", "regional", "regional", HGV_KERB_KG, fuel_counter_start_l=212344.0,
                    odometer_start_m=287041.3 * M_PER_MILE),
        VehicleSpec("KX19 LMT", "diesel-hgv", "night", "trunk", HGV_KERB_KG, fuel_counter_start_l=418870.5,
                    odometer_start_m=402118.8 * M_PER_MILE),
    ),
    portal_dates={"KX19 LMR": ("2019-10-25", "2019-10-26", "2019-10-28"),
                  "KX19 LMT": ("2019-10-26", "2019-10-27", "2019-10-28")},
    clock_step=("EB-02", 1, 1, 4.25),
    fuel_reset=("HGV-21", 1, 1, 12.5),
    gzip_files=tuple((v, d) for v in ("EB-01", "EB-02", "HGV-11", "HGV-21") for d in range(1, 6)),
    forced_weather=SAMPLE_WEATHER,
)

SMALL_FLEET = FleetSpec(
    srf_vehicles=(
        VehicleSpec("EB-01", "electric-bus", "bus-short", "bus-1", BUS_KERB_KG, energy_counter_start_kwh=48213.7,
                    ambient_bias_k=0.4),
        VehicleSpec("HGV-11", "diesel-hgv", "truck-short", "regional", HGV_KERB_KG, flowmeter=True,
                    fuel_counter_start_l=1843210.5, ecu_fuel_bias=1.03, wheel_speed_scale=1.015, ambient_bias_k=0.7,
                    schedule=(("truck-short", "regional"), ("urban-short", "bus-1"))),
    ),
    srf_dates=("2019-01-31", "2019-07-25"),
    portal_vehicles=(
        VehicleSpec("KX19 LMR", "diesel-hgv", "truck-short", "regional", HGV_KERB_KG, fuel_counter_start_l=212344.0,
                    odometer_start_m=287041.3 * M_PER_MILE),
        VehicleSpec("KX19 LMT", "diesel-hgv", "night-short", "regional", HGV_KERB_KG, fuel_counter_start_l=418870.5,
                    odometer_start_m=402118.8 * M_PER_MILE),
    ),
    portal_dates={"KX19 LMR": ("2019-10-26",), "KX19 LMT": ("2019-10-27",)},
    dsm=DsmSpec(resolution_m=5.0, survey_box=(483000.0, 235000.0, 489000.0, 238000.0),
                omitted_cells=((485000.0, 237000.0),)),
    clock_step=("EB-01", 0, 1, 4.25),
    fuel_reset=("HGV-11", 0, 1, 12.5),
    gzip_files=(("HGV-11", 0),),
    forced_weather=SAMPLE_WEATHER,
)


@dataclass(frozen=True, eq=False)
class TruthTrip:
    """One trip as it really happened, on a 1 s grid from ``time_s[0] = 0``.

    ``distance_m`` is the trapezoidal integral of ``speed_mps``; the vehicle is at
    ``route.xy(route_from_m + distance_m)`` on the route named ``route``; ``elevation_m``
    is the road surface there; ``consumption`` the cumulative output of the consumption
    function (l or J), ``parts`` what it said of its parts; ``mass_kg`` the gross mass,
    ``load`` passengers (bus) or payload [kg] (truck); ``conditions`` the weather along
    the trip, the ignition-off time before it and the people on board; ``weather`` the
    day's.
    """

    vehicle: VehicleSpec
    day_index: int
    trip_index: int  # within the vehicle's day
    duty: str
    route: str
    start_utc_s: float
    time_s: np.ndarray
    speed_mps: np.ndarray
    distance_m: np.ndarray
    route_from_m: float
    x_m: np.ndarray
    y_m: np.ndarray
    elevation_m: np.ndarray
    mass_kg: float
    load: float
    consumption: np.ndarray
    conditions: TripConditions
    weather: DayWeather
    parts: dict

    @property
    def end_utc_s(self) -> float:
        return self.start_utc_s + float(self.time_s[-1])

    def at(self, t_s: np.ndarray, world: World) -> dict[str, np.ndarray]:
        """Truth at arbitrary times ``t_s`` [s from trip start] inside the trip: speed
        (linear), distance (exact integral of the linear speed), position, road elevation,
        cumulative consumption and air temperature (linear), and the step index of the
        1 s grid."""
        t = self.time_s
        k = np.clip(np.searchsorted(t, t_s, side="right") - 1, 0, t.size - 2)
        tau = t_s - t[k]
        dt = t[k + 1] - t[k]
        v0, v1 = self.speed_mps[k], self.speed_mps[k + 1]
        v = v0 + (v1 - v0) * tau / dt
        d = self.distance_m[k] + v0 * tau + (v1 - v0) * tau * tau / (2 * dt)
        x, y = world.routes[self.route].xy(self.route_from_m + d)
        c = self.consumption[k] + (self.consumption[k + 1] - self.consumption[k]) * tau / dt
        amb = self.conditions.ambient_c
        a = amb[k] + (amb[k + 1] - amb[k]) * tau / dt
        return {"k": k, "speed": v, "distance": d, "x": x, "y": y, "elev": world.terrain.elevation_m(x, y), "cons": c,
                "ambient": a}


def _speed_trace(duty: DutySpec, rng: np.random.Generator) -> np.ndarray:
    """Speed [m/s] at 1 s steps: the duty's micro-trip blocks, concatenated and capped."""
    parts = []
    for spec, (lo, hi) in duty.segments:
        n = int(rng.integers(lo, hi + 1))
        cyc = micro_trip_cycle(dataclasses.replace(spec, n_trips=n), int(rng.integers(0, 2**31 - 1)))
        parts.append(cyc.speed_mps)
    v = np.minimum(np.concatenate(parts), duty.max_speed_kmh / MPS_TO_KMH)
    v[0] = v[-1] = 0.0
    return v


def _trapz_m(v: np.ndarray) -> float:
    return float(np.sum(0.5 * (v[1:] + v[:-1])))


def _return_trace(duty: DutySpec, rng: np.random.Generator, target_m: float, tries: int = 30) -> np.ndarray:
    """A speed trace whose distance is ``target_m`` to within one second of driving, so
    that the return leg of an out-and-back duty ends back at the depot: the first of
    ``tries`` drawn traces within 15 % of the target (else the closest), then samples
    inserted at its top speed or removed from its fast cruise (speeds >= 95 % of the top
    speed: the speed jumps this leaves are a fraction of a m/s)."""
    best = None
    for _ in range(tries):
        v = _speed_trace(duty, rng)
        if best is None or abs(_trapz_m(v) - target_m) < abs(_trapz_m(best) - target_m):
            best = v
        if abs(_trapz_m(best) - target_m) <= 0.15 * target_m:
            break
    assert best is not None  # tries >= 1
    v = best
    for _ in range(4):
        excess = _trapz_m(v) - target_m
        vmax = float(v.max())
        if abs(excess) < vmax:
            break
        n = int(round(abs(excess) / vmax))
        if excess < 0:
            i = int(np.argmax(v))
            v = np.concatenate((v[:i], np.full(n, v[i]), v[i:]))
        else:
            cand = np.flatnonzero(v >= 0.95 * vmax)
            cand = cand[(cand > 0) & (cand < v.size - 1)]
            n = min(n, cand.size)
            drop = np.unique(cand[np.round(np.linspace(0, cand.size - 1, n)).astype(int)]) if n else cand[:0]
            v = np.delete(v, drop)
    return v


def _utc_midnight_s(date: str) -> float:
    return datetime.fromisoformat(date).replace(tzinfo=UTC).timestamp()


def _day_loads(duty: DutySpec, n_trips: int, rng: np.random.Generator) -> list[float]:
    """Load per trip: passengers (bus) or payload [kg] (truck)."""
    if duty.load == "passengers":
        return [float(rng.integers(0, 61)) for _ in range(n_trips)]
    if duty.load == "drops":
        p = float(np.round(rng.uniform(*duty.payload_kg), -1))
        out = []
        for _ in range(n_trips):
            out.append(p)
            p = max(0.0, float(np.round(p - rng.uniform(*duty.drop_kg), -1)))
        return out
    return [float(np.round(rng.uniform(*(duty.payload_kg if i % 2 == 0 else duty.return_kg)), -1))
            for i in range(n_trips)]


def check_consumption_fn(fn: ConsumptionFn) -> None:
    """TypeError unless ``fn`` takes the keyword ``conditions`` (the interface of
    :mod:`cevm_samplegen.consumption`; a function written for the interface without the
    weather must say what it does with it)."""
    try:
        params = inspect.signature(fn).parameters
    except (TypeError, ValueError):
        return  # a builtin or C function: let the call speak
    if "conditions" in params or any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        return
    name = getattr(fn, "__qualname__", repr(fn))
    raise TypeError(f"consumption function {name} must take the keyword argument 'conditions' (a "
                    "cevm_samplegen.TripConditions: air temperature and sunshine per sample, soak time, "
                    "occupants): add '*, conditions' to its signature")


def _consumption(fn: ConsumptionFn, kind: str, t, v, h, mass: float, conditions: TripConditions):
    """(cumulative from 0, parts) of a consumption function's result, checked."""
    out = fn(kind, t, v, h, mass, conditions=conditions)
    parts = dict(out.parts) if isinstance(out, Consumption) else {}
    c = np.asarray(out.cumulative if isinstance(out, Consumption) else out, dtype=float)
    if c.shape != t.shape or not np.all(np.isfinite(c)):
        raise ValueError(f"consumption_fn returned shape {c.shape} or non-finite values for a trip of {t.size} samples")
    return c - c[0], {k: float(x) for k, x in parts.items()}


def simulate_day(world: World, veh: VehicleSpec, day_index: int, date: str, consumption_fn: ConsumptionFn, seed: int,
                 weather: DayWeather) -> list[TruthTrip]:
    """The truth trips of one vehicle-day (each day starts at the route's s = 0)."""
    duty_name, route_name = veh.duty_on(day_index)
    duty = DUTIES[duty_name]
    rng = seeded_rng(seed, "day", veh.vehicle_id, date)
    n_trips = int(rng.integers(duty.trips_per_day[0], duty.trips_per_day[1] + 1))
    loads = _day_loads(duty, n_trips, rng)
    start = _utc_midnight_s(date) + round(rng.uniform(*duty.first_start_utc_h) * S_PER_H)
    layovers = [OVERNIGHT_SOAK_S] + [float(round(rng.uniform(*duty.layover_s))) for _ in range(n_trips - 1)]
    route = world.routes[route_name]
    route_d = 0.0
    trips: list[TruthTrip] = []
    for j in range(n_trips):
        if duty.load == "out_back" and j % 2 == 1 and not route.closed:
            # the return leg: turn round (the mirror position on the way back, see
            # Route.along_m) and drive the outbound distance back to the depot
            v = _return_trace(duty, rng, float(trips[-1].distance_m[-1]))
            route_d = 2.0 * route.length_m - route_d
        else:
            v = _speed_trace(duty, rng)
        passengers = duty.load == "passengers"
        mass = veh.kerb_mass_kg + (loads[j] * 75.0 if passengers else loads[j])

        def elevation_at(s_m, d0=route_d):
            return world.terrain.elevation_m(*route.xy(d0 + s_m))

        v = power_limited_trace(
            v, elevation_at, mass,
            STANDIN[veh.vehicle_type], DRIVER_MAX_WHEEL_POWER_W[veh.vehicle_type],
        )
        t = np.arange(v.size, dtype=float)
        d = np.concatenate(([0.0], np.cumsum(0.5 * (v[1:] + v[:-1]))))
        x, y = route.xy(route_d + d)
        h = world.terrain.elevation_m(x, y)
        if j:
            start = trips[-1].end_utc_s + layovers[j]
        cond = TripConditions(weather.ambient_c(start + t), weather.solar_w_m2(start + t), layovers[j],
                              1.0 + (loads[j] if passengers else 0.0))
        c, parts = _consumption(consumption_fn, veh.vehicle_type, t, v, h, mass, cond)
        trips.append(TruthTrip(veh, day_index, j, duty_name, route_name, float(start), t, v, d, route_d, x, y, h,
                               float(mass), loads[j], c, cond, weather, parts))
        route_d += float(d[-1])
    return trips


def simulate_fleet(fleet: FleetSpec = SAMPLE_FLEET, consumption_fn: ConsumptionFn = standin_consumption,
                   seed: int = DEFAULT_SEED, world: World | None = None,
                   ) -> tuple[World, dict[str, list[list[TruthTrip]]]]:
    """The world and, per vehicle id, per day, the truth trips of ``fleet`` (srf vehicles
    on ``fleet.srf_dates``, portal vehicles on their ``portal_dates``)."""
    check_consumption_fn(consumption_fn)
    if world is None:
        names = set().union(*(v.routes for v in fleet.srf_vehicles + fleet.portal_vehicles))
        world = build_world(seed, fleet.dsm, sorted(names))
    weather: dict[str, DayWeather] = {}

    def day(veh, i, date):
        if date not in weather:
            weather[date] = fleet.weather(date, seed)
        return simulate_day(world, veh, i, date, consumption_fn, seed, weather[date])

    out: dict[str, list[list[TruthTrip]]] = {}
    for veh in fleet.srf_vehicles:
        out[veh.vehicle_id] = [day(veh, i, d) for i, d in enumerate(fleet.srf_dates)]
    for veh in fleet.portal_vehicles:
        out[veh.vehicle_id] = [day(veh, i, d) for i, d in enumerate(fleet.portal_dates[veh.vehicle_id])]
    return world, out
