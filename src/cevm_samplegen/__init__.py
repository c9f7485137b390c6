"""Deterministic synthetic logger exports and DSM tiles: the project's ``sample_logs/``.

``python -m cevm_samplegen OUTDIR [--small] [--seed N] [--consumption MODULE:FUNC]``
writes, from a seed alone (no wall clock, no network; same bytes on every run)::

    OUTDIR/srf/<vehicle>_<yyyy-mm-dd>.csv[.gz]   one file per vehicle and logging day
    OUTDIR/portal/portal_export_<first>_<last>.csv  two vehicles, several days, one DST jump
    OUTDIR/dsm/<OS tile>_DSM_<r>M.tif              DSM tiles, EPSG:27700
    OUTDIR/truth.json                              what really happened (see below)

**Truth first, then sensors.** For every trip the generator draws a speed trace (the
micro-trip generator of :mod:`cevm_samplegen.cycles`: stop-to-stop runs; long haul adds motorway
cruise blocks), lays it along a smooth road polyline in British National Grid (BNG,
EPSG:27700) around Milton Keynes (position = the route point at the cumulative distance),
takes the TRUE road elevation from a smooth terrain function (the road surface: no
buildings), and gets the consumption from an injected function::

    consumption_fn(kind, time_s, speed_mps, elevation_m, mass_kg) -> cumulative array

``kind`` is the vehicle type, the stem of a ``configs/vehicles`` file: ``"electric-bus"``
(result in joules at the battery, net of regeneration) or ``"diesel-hgv"`` (litres of
diesel). Arrays are the 1 Hz truth samples of one trip (time from 0 s), ``mass_kg`` the
trip's constant gross mass; the result has one value per sample, starting at 0. The
default, :func:`standin_consumption`, is a STAND-IN (a longitudinal-dynamics formula with
load-dependent efficiency, written here) for tests and trial runs; the project's sample
logs are meant to be generated with the detailed simulator. The CE model
(:mod:`cevm.core.model`) is never used for measured values.

Sensors are then derived from the truth:

* ``srf`` (LOGGERS.md dialect 1): ~1 Hz ticks with a random phase, +-12 ms jitter, 1 %
  missed ticks (plus short bursts), 0.3 % repeated ticks (identical duplicate lines); no
  rows while the ignition is off between trips (the FMS dongle is unpowered and the app
  pauses: layovers are gaps of 12-45 min). GPS: correlated position noise (AR(1),
  tau 40 s, about 2.5 m x HDOP/0.9, plus 0.7 m white; it keeps wandering at standstill),
  HDOP, cold start (8-25 s without fix) and re-acquisition (2-6 s) after each layover,
  dropouts of 10-45 s, 2 % single missing fixes, GPS altitude = road + geoid undulation
  47 m (ellipsoidal heights near Milton Keynes) + session bias + drift of about 12 m.
  FMS fields arrive asynchronously (a field is empty in a tick that got no new value):
  wheel speed (per-vehicle calibration factor, 1/256 km/h steps), pedal (0.4 %), brake
  switch, engine/motor speed (0.125 rpm) and torque (1 %, from a plausible gear model),
  every tick but 0.5 %; fuel counter (0.5 l, floor, every 5-10 s; per-vehicle ECU bias),
  fuel rate (0.05 l/h, 2 % noise, same ECU bias), flow meter (mean rate over each 2 s
  interval, 1.5 % noise: the trusted truck source), gross weight (10 kg, every ~10 s once
  the vehicle has moved for 30 s); bus: total energy (0.1 kWh floor, net of regeneration,
  every 4-6 s: the trusted bus source), SoC (0.4 %), pack voltage and current from an
  open-circuit-voltage + resistance model, consistent with the energy (V I = battery
  power). Comment metadata ``# vehicle_id=``, ``# logger=``, ``# started=``.
* ``portal`` (dialect 2): ``;``, decimal comma, cp1252 (``£``, ``é``, an en dash in
  Event texts), CRLF, Europe/London local time ``dd/mm/yyyy HH:MM:SS`` (the autumn DST
  jump makes one hour repeat), rows every 1-10 s while moving, every 30-120 s when
  stopped with the ignition on, a row where the vehicle comes to rest and where it moves
  off, ``Ignition`` On/Off rows at trip ends, heartbeats every 15-30 min while off; GPS
  speed in mph, CAN odometer in miles (0.1 mi, floor), fuel used (0.5 l, floor), rare
  no-fix rows written as 0;0; Events: harsh braking etc., a depot exit on each day's
  first row and a fuel-card purchase on its last. Rows grouped by ``Registration``.

**Fleet** (:data:`SAMPLE_FLEET`): srf, 14-16 May 2019: electric buses EB-01 and EB-02
on two urban loops (3 trips a day, 0-60 passengers x 75 kg per trip), diesel HGV-11 on
a regional delivery loop (3 trips a day, payload falling at each drop) and HGV-21 on a
trunk road (out and back: the return leg is drawn to end at the depot; heavy out,
light back); payloads 0-26,000 kg on an 18,000 kg tractor. Portal, 25-28 October 2019:
KX19 LMR on the regional loop by day, KX19 LMT on the trunk road by night (its night of
26-27 October spans 01:00 UTC, when the clocks went back). :func:`fleet_for_benchmark`
writes a larger srf fleet on the same routes.

**File-level faults** (all listed in ``truth.json``): a backward clock correction of
4.25 s in one srf file (EB-02, day 2, mid trip 2: the phone clock ran ahead), a
fuel-counter reset in one file (HGV-21, day 2, mid trip 2: the new counter starts at
12.5 l), HGV-21's counter starting near 1.84 million litres, one gzipped file
(HGV-21, day 3, ``.csv.gz``), HGV-11's wheel speed reading 1.5 % high and its ECU fuel
figures 3 % high (its flow meter shows the truth).

**DSM.** Float32 GeoTIFFs, 1 km tiles named by OS grid reference (``SP8538_DSM_2M.tif``),
2 m pixels (5 m in ``--small``), deflate + floating-point predictor, values rounded to
1/128 m (exact in binary, half the size of 0.01 m rounding), nodata -9999. Surface =
terrain + flat-roofed buildings beside the roads (at least 8 m clear of every road
centreline) + trees (dome canopies) beside the roads and a few over them + bridge decks
across the roads + nodata holes (LIDAR voids, some on the roads). Tiles exist only for
the 1 km cells the routes touch inside a survey box (E 480-492 km, N 233-245 km), so
these route sections lie outside every tile ON PURPOSE: (1) the trunk road north of
N 245 km, i.e. all but the first ~5 km of each long-haul trip; (2) the cell SP8139 on the
west side of the regional loop (a survey hole, about 1 km of road). Exact intervals:
``truth.json`` -> ``routes.<name>.dsm_gaps_m``; the road intervals with trees, bridges or
holes over them: ``routes.<name>.surface_objects``.

**truth.json**: per trip the vehicle, file, first and last file line, true UTC start and
end (first and last logged tick, true clock), true distance, gross mass and load, true
consumption (``consumption`` in ``consumption_unit``), the route and where on it the
trip starts (``route_from_m``: the true positions are ``Route.xy(route_from_m +
distance)``), the share inside DSM tiles; per file its faults; per vehicle the sensor
biases; the consumption function's qualified name.

**Not simulated**: lane offsets (all traffic drives on the centreline), traffic and
signals as such (stops are random micro-trip dwells), load changes within a trip,
charging, wrap-around of counters, OSTN15-grade datum detail (pyproj's default
BNG->WGS84 transformation is used both ways), DSM noise on the road surface (the road is
the terrain, to 1/128 m), embankments, cuttings and bridge ramps, vehicles in the DSM.

Public API: :func:`generate_sample_logs`, :func:`fleet_for_benchmark`,
:func:`simulate_fleet`, :func:`build_world`, :func:`standin_consumption`,
:func:`logged_consumption`, :class:`FleetSpec`, :data:`SAMPLE_FLEET`, :data:`SMALL_FLEET`.

This package is the project's developer tool, apart from the runtime package ``cevm``:
``cevm`` never imports it. Demo cycles: ``python -m cevm_samplegen demo-cycles OUTDIR``; the
fleet case study's stand-in cycles: ``python -m cevm_samplegen standin-cycles OUTDIR``.
"""

from __future__ import annotations

import dataclasses
import gzip
import hashlib
import importlib
import json
import math
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import datetime, timezone
from functools import lru_cache
from pathlib import Path

import numpy as np

from cevm_samplegen.cycles import MicroTripSpec, micro_trip_cycle

__all__ = [
    "ConsumptionFn",
    "DsmSpec",
    "DutySpec",
    "FleetSpec",
    "Route",
    "SAMPLE_FLEET",
    "SMALL_FLEET",
    "StandInParams",
    "Terrain",
    "TruthTrip",
    "VehicleSpec",
    "World",
    "build_world",
    "dsm_tile",
    "fleet_for_benchmark",
    "generate_sample_logs",
    "logged_consumption",
    "main",
    "simulate_fleet",
    "standin_consumption",
]

#: ``consumption_fn(kind, time_s, speed_mps, elevation_m, mass_kg) -> cumulative array``.
ConsumptionFn = Callable[[str, np.ndarray, np.ndarray, np.ndarray, float], np.ndarray]

DEFAULT_SEED = 7
G_MPS2 = 9.81
RHO_AIR_KG_M3 = 1.225
#: Geoid undulation near Milton Keynes [m]: GPS reports heights above the WGS84
#: ellipsoid, about 47 m above mean sea level there (OSGM15).
GEOID_UNDULATION_M = 47.0
#: Origin of the terrain phases (BNG, m): keeps the cosine arguments small.
WORLD_ORIGIN_EN = (485000.0, 238000.0)
BNG = "EPSG:27700"
WGS84 = "EPSG:4326"


def _rng(seed: int, *keys: object) -> np.random.Generator:
    """An independent, reproducible generator for ``(seed, *keys)`` (strings hashed with
    CRC-32, never Python's salted ``hash``)."""
    ints = [int(seed)] + [k if isinstance(k, int) else zlib.crc32(str(k).encode()) for k in keys]
    return np.random.default_rng(np.random.SeedSequence(ints))


# ======================================================================================
# Stand-in consumption (NOT the detailed simulator, NOT the CE model)
# ======================================================================================


@dataclass(frozen=True)
class StandInParams:
    """Parameters of the stand-in consumption formula and of the plausible FMS signals.

    Body: ``cda_m2``, ``cr`` (rolling, plus ``cr_speed_per_mps`` x v), ``rot_factor``
    (rotating-mass factor on the kinetic term), ``wheel_radius_m``. Electric:
    ``drive_eff`` (battery -> wheel, marginal), ``drive_loss_w`` (constant loss while
    driving), ``regen_eff`` (wheel -> battery), ``regen_max_w`` (regenerative braking
    limit at the wheel; friction brakes do the rest), ``aux_w`` (HVAC, air, 24 V: always
    on). Diesel: ``idle_fuel_w`` (fuel power at idle, about 2.5 l/h for a 13 l engine),
    ``marginal_eff`` (Willans slope: wheel power per fuel power above idle, transmission
    included), ``fuel_lhv_j_per_l`` (EN 590 diesel), ``aux_w`` (alternator, compressor).
    Values are plausible for the paper's vehicles, not calibrated.
    """

    cda_m2: float
    cr: float
    cr_speed_per_mps: float
    rot_factor: float
    wheel_radius_m: float
    aux_w: float
    drive_eff: float = 0.0
    drive_loss_w: float = 0.0
    regen_eff: float = 0.0
    regen_max_w: float = 0.0
    idle_fuel_w: float = 0.0
    marginal_eff: float = 0.0
    fuel_lhv_j_per_l: float = 35.8e6
    max_power_w: float = 250e3
    motor_ratio: float = 10.0  # electric: motor revolutions per wheel revolution
    ref_torque_nm: float = 1500.0


STANDIN: dict[str, StandInParams] = {
    "electric-bus": StandInParams(
        cda_m2=4.1, cr=0.0068, cr_speed_per_mps=0.00005, rot_factor=1.06, wheel_radius_m=0.48,
        aux_w=5000.0, drive_eff=0.86, drive_loss_w=2500.0, regen_eff=0.62, regen_max_w=90e3,
        max_power_w=240e3, motor_ratio=10.0, ref_torque_nm=1500.0,
    ),
    "diesel-hgv": StandInParams(
        cda_m2=6.5, cr=0.0064, cr_speed_per_mps=0.00004, rot_factor=1.04, wheel_radius_m=0.5,
        aux_w=3000.0, idle_fuel_w=24.9e3, marginal_eff=0.38, max_power_w=235e3,
        ref_torque_nm=1600.0,
    ),
}

#: Wheel power the generated drivers never ask for more than [W]: 85 % of what the
#: vehicle files' [detailed] powertrains deliver at the wheels (bus: 180 kW motor peak x
#: 0.92 motor and gear efficiency; truck: 235 kW engine less 3 kW auxiliaries x 0.95
#: driveline), so that the detailed model can follow every generated trace, loaded.
DRIVER_MAX_WHEEL_POWER_W: dict[str, float] = {
    "electric-bus": 0.85 * 180e3 * 0.92,
    "diesel-hgv": 0.85 * (235e3 - 3e3) * 0.95,
}


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


#: What a vehicle type's consumption is measured in (cevm.core.trip.MeasurementKind).
MEASUREMENT_KIND = {"electric-bus": "energy_j", "diesel-hgv": "fuel_l"}


def _wheel_power_w(p: StandInParams, dt_s, v0, v1, dh_m, mass_kg) -> np.ndarray:
    """Mean wheel power [W] over steps: kinetic (with rotating mass), potential, rolling
    and aerodynamic work divided by the step duration."""
    vm = 0.5 * (v0 + v1)
    ds = vm * dt_s
    cr = p.cr + p.cr_speed_per_mps * vm
    work = (
        mass_kg * p.rot_factor * 0.5 * (v1 * v1 - v0 * v0)
        + mass_kg * G_MPS2 * dh_m
        + cr * mass_kg * G_MPS2 * ds
        + 0.5 * RHO_AIR_KG_M3 * p.cda_m2 * 0.5 * (v0**3 + v1**3) * dt_s
    )
    return work / dt_s


def standin_consumption(kind: str, time_s, speed_mps, elevation_m, mass_kg: float) -> np.ndarray:
    """STAND-IN consumption for tests and trial runs: cumulative per sample, from 0.

    Per step, wheel power P_w [W] from longitudinal dynamics (:func:`_wheel_power_w`).
    ``"electric-bus"`` -> joules at the battery: P_b = P_w / drive_eff + drive_loss_w when
    P_w > 0, else max(P_w, -regen_max_w) * regen_eff; plus aux_w. So the efficiency varies
    with load (low at light load) and regeneration is partial. ``"diesel-hgv"`` -> litres:
    fuel power = idle_fuel_w + P_w / marginal_eff when P_w > 0 (a Willans line), 0 on
    overrun above 2 m/s (fuel cut-off), idle otherwise; aux_w is added to P_w.
    Parameters: :data:`STANDIN`. This is deliberately not the CE model.
    """
    if kind not in STANDIN:
        raise ValueError(f"unknown vehicle type {kind!r} (known: {', '.join(sorted(STANDIN))})")
    p = STANDIN[kind]
    t = np.asarray(time_s, dtype=float)
    v = np.asarray(speed_mps, dtype=float)
    h = np.asarray(elevation_m, dtype=float)
    dt = np.diff(t)
    pw = _wheel_power_w(p, dt, v[:-1], v[1:], np.diff(h), float(mass_kg))
    if kind == "electric-bus":
        pb = np.where(pw > 0, pw / p.drive_eff + p.drive_loss_w, np.maximum(pw, -p.regen_max_w) * p.regen_eff)
        step = (pb + p.aux_w) * dt
    else:
        pe = pw + p.aux_w
        vm = 0.5 * (v[:-1] + v[1:])
        fuel_w = np.where(pe > 0, p.idle_fuel_w + pe / p.marginal_eff, np.where(vm > 2.0, 0.0, p.idle_fuel_w))
        step = fuel_w * dt / p.fuel_lhv_j_per_l
    return np.concatenate(([0.0], np.cumsum(step)))


#: Deficits above this share of the wheel work are reported by
#: :func:`logged_consumption`: the trace asks more than the vehicle can do.
MAX_DEFICIT_SHARE = 0.02


@lru_cache(maxsize=8)
def _project_vehicle(kind: str):
    from cevm.io import load_vehicle

    from cevm.configs_dir import shipped_configs_dir

    path = shipped_configs_dir() / "vehicles" / f"{kind}.toml"
    return load_vehicle(path)


def logged_consumption(kind: str, time_s, speed_mps, elevation_m, mass_kg: float) -> np.ndarray:
    """Cumulative consumption per sample, as a logger would measure it: the detailed
    model (:func:`cevm.core.detailed.simulate`) of the project's vehicle
    ``configs/vehicles/<kind>.toml`` over a true trace.

    Joules at the battery (EV, net of regeneration, auxiliaries included) or litres of
    fuel (diesel), from 0 at the first sample. The consumption function of the shipped
    sample logs (``--consumption cevm_samplegen:logged_consumption``). Raises ValueError
    if the vehicle could not follow the trace (traction deficit above
    :data:`MAX_DEFICIT_SHARE` of the wheel work). It lives here, not in the detailed
    model's module, because it reads the project's vehicle files.
    """
    from cevm.core.detailed import simulate

    vehicle = _project_vehicle(kind)
    res = simulate(vehicle, time_s, speed_mps, elevation_m, mass_kg=mass_kg, time_step_s=None)
    positive = float(np.sum(np.maximum(res.steps["wheel_power_w"] * res.steps["dt_s"], 0.0)))
    if res.traction_deficit_j > MAX_DEFICIT_SHARE * max(positive, 1.0):
        raise ValueError(
            f"{kind} at {mass_kg:.0f} kg cannot follow the trace: {res.traction_deficit_j / 3.6e6:.2f} kWh "
            f"beyond its powertrain ({100 * res.traction_deficit_j / positive:.1f} % of the wheel work)"
        )
    key = "energy_cum_j" if vehicle.is_ev else "fuel_cum_l"
    return np.asarray(res.samples[key], dtype=np.float64)


# ======================================================================================
# World: terrain, roads, surface objects, DSM tiles
# ======================================================================================


@dataclass(frozen=True, eq=False)
class Terrain:
    """Smooth hills: ``base_m + sum_i amp_i cos(kx_i (x - x0) + ky_i (y - y0) + phase_i)``
    in BNG metres. Each wave's maximum grade is 0.4-1.2 %; roads follow it (the road
    surface IS the terrain)."""

    base_m: float
    kx: np.ndarray
    ky: np.ndarray
    amp_m: np.ndarray
    phase: np.ndarray

    def elevation_m(self, x, y) -> np.ndarray:
        """Terrain height [m above mean sea level] at BNG easting ``x``, northing ``y`` [m]."""
        x = np.asarray(x, dtype=float) - WORLD_ORIGIN_EN[0]
        y = np.asarray(y, dtype=float) - WORLD_ORIGIN_EN[1]
        out = np.full(np.broadcast(x, y).shape, self.base_m)
        for kx, ky, a, ph in zip(self.kx, self.ky, self.amp_m, self.phase):
            out += a * np.cos(kx * x + ky * y + ph)
        return out


def make_terrain(seed: int) -> Terrain:
    """Eight waves, wavelengths log-uniform in 0.7-16 km, random directions, amplitude =
    grade x wavelength / 2 pi with grade uniform in 0.4-1.2 %; base 95 m (Milton Keynes
    lies at 60-150 m)."""
    rng = _rng(seed, "terrain")
    n = 8
    lam = np.exp(rng.uniform(np.log(700.0), np.log(16000.0), n))
    theta = rng.uniform(0.0, np.pi, n)
    grade = rng.uniform(0.004, 0.012, n)
    k = 2 * np.pi / lam
    return Terrain(
        base_m=95.0, kx=k * np.cos(theta), ky=k * np.sin(theta), amp_m=grade * lam / (2 * np.pi),
        phase=rng.uniform(0, 2 * np.pi, n),
    )


@dataclass(frozen=True, eq=False)
class Route:
    """A road polyline in BNG, resampled every metre along its length.

    ``closed`` routes are loops (distance wraps modulo the length); open routes are
    driven out and back (distance reflects at each end: a U-turn at a junction).
    """

    name: str
    closed: bool
    s_m: np.ndarray  # along-route position of the points [m], 0 .. length
    x_m: np.ndarray
    y_m: np.ndarray

    @property
    def length_m(self) -> float:
        return float(self.s_m[-1])

    def along_m(self, distance_m) -> np.ndarray:
        """Position along the centreline [m] after driving ``distance_m`` from s = 0."""
        d = np.asarray(distance_m, dtype=float)
        L = self.length_m
        if self.closed:
            return np.mod(d, L)
        s = np.mod(d, 2 * L)
        return np.where(s > L, 2 * L - s, s)

    def xy(self, distance_m) -> tuple[np.ndarray, np.ndarray]:
        """BNG easting, northing [m] after driving ``distance_m`` from s = 0."""
        s = self.along_m(distance_m)
        return np.interp(s, self.s_m, self.x_m), np.interp(s, self.s_m, self.y_m)


#: Road control points in BNG metres around Milton Keynes: (closed, points). Smoothed by
#: a cubic spline through the points (periodic for loops).
ROUTE_POINTS: dict[str, tuple[bool, tuple[tuple[float, float], ...]]] = {
    # Urban bus loops (about 9 km and 8 km), through central Milton Keynes.
    "bus-1": (True, ((484200, 237400), (485300, 237050), (486400, 237500), (486950, 238550),
                     (486300, 239700), (485100, 240150), (484000, 239650), (483550, 238500))),
    "bus-2": (True, ((485600, 236200), (486500, 235750), (487300, 236000), (488300, 236900),
                     (488150, 238250), (487050, 238950), (486050, 238450), (485350, 237350))),
    # Regional delivery loop (about 27 km) through the surrounding villages.
    "regional": (True, ((487500, 235100), (490000, 236000), (490900, 238500), (489800, 241500),
                        (487000, 242700), (484000, 242300), (481900, 240600), (481500, 237600),
                        (483200, 235200), (485500, 234500))),
    # Trunk road north-west towards the East Midlands (about 110 km), driven out and back.
    "trunk": (False, ((488900, 240800), (489600, 243000), (487600, 246000), (484000, 250500),
                      (479000, 257000), (474000, 265000), (470000, 273000), (466500, 281000),
                      (462000, 289000), (458500, 297000), (452000, 312000), (446000, 323000),
                      (440000, 333000))),
}


def make_route(name: str, step_m: float = 1.0) -> Route:
    """Smooth :data:`ROUTE_POINTS` ``name`` with a cubic spline through the points
    (parameterised by chord length) and resample it every ``step_m`` metres of arc."""
    from scipy.interpolate import CubicSpline

    closed, pts = ROUTE_POINTS[name]
    p = np.asarray(pts, dtype=float)
    if closed:
        p = np.vstack([p, p[:1]])
    chord = np.concatenate(([0.0], np.cumsum(np.hypot(*np.diff(p, axis=0).T))))
    cs = CubicSpline(chord, p, bc_type="periodic" if closed else "natural")
    u = np.linspace(0.0, chord[-1], int(chord[-1] / (step_m / 4.0)) + 2)
    xy = cs(u)
    s = np.concatenate(([0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))))
    s_new = np.concatenate((np.arange(0.0, s[-1], step_m), [s[-1]]))
    return Route(name, closed, s_new, np.interp(s_new, s, xy[:, 0]), np.interp(s_new, s, xy[:, 1]))


@dataclass(frozen=True)
class DsmSpec:
    """Where and how the DSM tiles are made.

    ``tile_m = 1000``: 1 km tiles, the Ordnance Survey grid the UK's LIDAR products use.
    ``resolution_m = 2.0``: the Environment Agency's 2 m composite DSM. ``quantum_m =
    1/128``: rounding step of the stored heights, exact in binary floating point (half
    the compressed size of 0.01 m). ``survey_box`` (E0, N0, E1, N1): tiles exist only
    inside it. ``omitted_cells``: SW corners of 1 km cells left out on purpose.
    """

    tile_m: float = 1000.0
    resolution_m: float = 2.0
    quantum_m: float = 1.0 / 128.0
    survey_box: tuple[float, float, float, float] = (480000.0, 233000.0, 492000.0, 245000.0)
    omitted_cells: tuple[tuple[float, float], ...] = ((481000.0, 239000.0),)
    nodata: float = -9999.0


@dataclass(frozen=True, eq=False)
class SurfaceObjects:
    """Objects standing on the terrain (or holes in the survey), as flat arrays.

    Rectangles (buildings, bridge decks): centre, unit vector (ux, uy) of the half-length
    axis, half-length, half-width, absolute top height [m]. Discs (tree canopies):
    centre, radius, ground height, canopy height above ground. Holes: centre, radius.
    """

    rect_kind: np.ndarray  # "building" | "bridge"
    rect_cx: np.ndarray
    rect_cy: np.ndarray
    rect_ux: np.ndarray
    rect_uy: np.ndarray
    rect_hl: np.ndarray
    rect_hw: np.ndarray
    rect_top: np.ndarray
    tree_cx: np.ndarray
    tree_cy: np.ndarray
    tree_r: np.ndarray
    tree_ground: np.ndarray
    tree_h: np.ndarray
    hole_cx: np.ndarray
    hole_cy: np.ndarray
    hole_r: np.ndarray


@dataclass(frozen=True, eq=False)
class World:
    """Terrain, routes, surface objects and the DSM tile set of one seed."""

    seed: int
    terrain: Terrain
    routes: dict[str, Route]
    objects: SurfaceObjects
    dsm: DsmSpec
    tiles: tuple[tuple[float, float], ...]  # SW corners of the tiles, sorted

    def in_tiles(self, x, y) -> np.ndarray:
        """True where BNG points (x, y) lie inside a DSM tile."""
        t = self.dsm.tile_m
        cells = {(float(a), float(b)) for a, b in self.tiles}
        cx, cy = _cell_of(x, y, t)
        keys = np.round(cx).astype(np.int64) * 10_000_000 + np.round(cy).astype(np.int64)
        have = np.array([int(a) * 10_000_000 + int(b) for a, b in cells], dtype=np.int64)
        return np.isin(keys, have)


def _cell_of(x, y, tile_m: float) -> tuple[np.ndarray, np.ndarray]:
    """SW corner of the tile cell holding each point, with the raster convention of
    :class:`cevm.ingest.dsm.DsmSampler`: x in [x0, x0 + t), y in (y0, y0 + t]."""
    cx = np.floor(np.asarray(x, dtype=float) / tile_m) * tile_m
    cy = (np.ceil(np.asarray(y, dtype=float) / tile_m) - 1.0) * tile_m
    return cx, cy


def _in_box(x, y, box, margin=0.0):
    return (x >= box[0] - margin) & (x <= box[2] + margin) & (y >= box[1] - margin) & (y <= box[3] + margin)


#: Object densities per route: (building spacing range [m] per side, off-road tree
#: spacing range [m] per side, trees over the road per km, bridges on the route).
_DENSITY = {
    "bus-1": ((12.0, 30.0), (30.0, 80.0), 0.6, 1),
    "bus-2": ((12.0, 30.0), (30.0, 80.0), 0.6, 1),
    "regional": ((40.0, 160.0), (20.0, 60.0), 0.5, 2),
    "trunk": ((150.0, 400.0), (40.0, 120.0), 0.4, 1),
}


def _place_objects(seed: int, terrain: Terrain, routes: dict[str, Route], dsm: DsmSpec) -> SurfaceObjects:
    """Draw buildings, trees, bridges and holes beside and over the routes, inside the
    survey box. Buildings and off-road trees keep clear of every road centreline (8 m and
    6 m plus their own extent); trees over the road, bridges and some holes sit on it."""
    from scipy.spatial import cKDTree

    pts = np.concatenate([np.column_stack([r.x_m[::2], r.y_m[::2]]) for r in routes.values()])
    tree = cKDTree(pts)
    box = dsm.survey_box
    R: dict[str, list[np.ndarray]] = {k: [] for k in ("kind", "cx", "cy", "ux", "uy", "hl", "hw", "top")}
    T: dict[str, list[np.ndarray]] = {k: [] for k in ("cx", "cy", "r", "ground", "h")}
    H: dict[str, list[np.ndarray]] = {k: [] for k in ("cx", "cy", "r")}

    def frame(route: Route, s):
        x = np.interp(s, route.s_m, route.x_m)
        y = np.interp(s, route.s_m, route.y_m)
        ds = 1.0
        dx = np.interp(s + ds, route.s_m, route.x_m) - np.interp(s - ds, route.s_m, route.x_m)
        dy = np.interp(s + ds, route.s_m, route.y_m) - np.interp(s - ds, route.s_m, route.y_m)
        n = np.hypot(dx, dy)
        return x, y, dx / n, dy / n

    def clear_of_roads(cx, cy, extent, clearance):
        d, _ = tree.query(np.column_stack([cx, cy]))
        return d > extent + clearance

    for name in sorted(routes):
        route = routes[name]
        rng = _rng(seed, "objects", name)
        bsp, tsp, trees_per_km, n_bridges = _DENSITY.get(name, _DENSITY["regional"])
        inside = _in_box(route.x_m, route.y_m, box, 200.0)
        if not inside.any():
            continue
        s_lo, s_hi = float(route.s_m[inside].min()), float(route.s_m[inside].max())
        span = s_hi - s_lo
        # Buildings, both sides.
        for side in (-1.0, 1.0):
            n = int(span / bsp[0]) + 2
            s = s_lo + np.cumsum(rng.uniform(*bsp, n))
            s = s[s < s_hi]
            m = s.size
            x, y, ux, uy = frame(route, s)
            hl, hw = rng.uniform(4.0, 12.0, m), rng.uniform(3.0, 7.0, m)
            off = rng.uniform(12.0, 35.0, m)
            cx, cy = x - side * uy * off, y + side * ux * off
            height = rng.uniform(4.0, 14.0, m)
            ok = clear_of_roads(cx, cy, np.hypot(hl, hw), 8.0) & _in_box(cx, cy, box, 50.0)
            R["kind"].append(np.full(int(ok.sum()), "building"))
            for k, v in (("cx", cx), ("cy", cy), ("ux", ux), ("uy", uy), ("hl", hl), ("hw", hw)):
                R[k].append(v[ok])
            R["top"].append(terrain.elevation_m(cx[ok], cy[ok]) + height[ok])
            # Off-road trees.
            n = int(span / tsp[0]) + 2
            s = s_lo + np.cumsum(rng.uniform(*tsp, n))
            s = s[s < s_hi]
            m = s.size
            x, y, ux, uy = frame(route, s)
            r = rng.uniform(2.0, 5.0, m)
            off = rng.uniform(7.0, 30.0, m)
            cx, cy = x - side * uy * off, y + side * ux * off
            ok = clear_of_roads(cx, cy, r, 6.0) & _in_box(cx, cy, box, 50.0)
            T["cx"].append(cx[ok]), T["cy"].append(cy[ok]), T["r"].append(r[ok])
            T["ground"].append(terrain.elevation_m(cx[ok], cy[ok]))
            T["h"].append(rng.uniform(5.0, 14.0, m)[ok])
        # Trees over the road.
        m = max(1, int(round(span / 1000.0 * trees_per_km)))
        s = rng.uniform(s_lo, s_hi, m)
        x, y, ux, uy = frame(route, s)
        lat = rng.uniform(-2.0, 2.0, m)
        cx, cy = x - uy * lat, y + ux * lat
        T["cx"].append(cx), T["cy"].append(cy), T["r"].append(rng.uniform(3.0, 5.0, m))
        T["ground"].append(terrain.elevation_m(cx, cy)), T["h"].append(rng.uniform(7.0, 12.0, m))
        # Bridges: a deck across the road, 6.5-7.5 m above it.
        s = rng.uniform(s_lo + 0.1 * span, s_hi - 0.1 * span, n_bridges)
        x, y, ux, uy = frame(route, s)
        R["kind"].append(np.full(n_bridges, "bridge"))
        R["cx"].append(x), R["cy"].append(y), R["ux"].append(-uy), R["uy"].append(ux)
        R["hl"].append(np.full(n_bridges, 25.0)), R["hw"].append(rng.uniform(5.0, 7.5, n_bridges))
        R["top"].append(terrain.elevation_m(x, y) + rng.uniform(6.5, 7.5, n_bridges))
        # Holes on the road (a LIDAR void over wet tarmac, say).
        m = 2
        s = rng.uniform(s_lo, s_hi, m)
        x, y, _, _ = frame(route, s)
        H["cx"].append(x), H["cy"].append(y), H["r"].append(rng.uniform(3.0, 8.0, m))
    # Off-road holes (water, voids): about one per km^2 of the survey box.
    rng = _rng(seed, "holes")
    area_km2 = (box[2] - box[0]) * (box[3] - box[1]) / 1e6
    m = max(1, int(round(area_km2)))
    H["cx"].append(rng.uniform(box[0], box[2], m)), H["cy"].append(rng.uniform(box[1], box[3], m))
    H["r"].append(rng.uniform(5.0, 25.0, m))

    def cat(d, k, dtype=float):
        return np.concatenate(d[k]).astype(dtype) if d[k] else np.zeros(0, dtype=dtype)

    return SurfaceObjects(
        rect_kind=cat(R, "kind", object), rect_cx=cat(R, "cx"), rect_cy=cat(R, "cy"),
        rect_ux=cat(R, "ux"), rect_uy=cat(R, "uy"), rect_hl=cat(R, "hl"), rect_hw=cat(R, "hw"),
        rect_top=cat(R, "top"), tree_cx=cat(T, "cx"), tree_cy=cat(T, "cy"), tree_r=cat(T, "r"),
        tree_ground=cat(T, "ground"), tree_h=cat(T, "h"), hole_cx=cat(H, "cx"), hole_cy=cat(H, "cy"),
        hole_r=cat(H, "r"),
    )


def _tile_set(routes: dict[str, Route], dsm: DsmSpec) -> tuple[tuple[float, float], ...]:
    """SW corners of the tiles: cells any route touches, inside the survey box, minus the
    omitted cells; sorted."""
    t = dsm.tile_m
    box = dsm.survey_box
    cells: set[tuple[float, float]] = set()
    for r in routes.values():
        cx, cy = _cell_of(r.x_m, r.y_m, t)
        ok = (cx >= box[0]) & (cx + t <= box[2]) & (cy >= box[1]) & (cy + t <= box[3])
        cells.update(zip(cx[ok].tolist(), cy[ok].tolist()))
    cells -= {(float(a), float(b)) for a, b in dsm.omitted_cells}
    return tuple(sorted(cells))


def build_world(seed: int = DEFAULT_SEED, dsm: DsmSpec = DsmSpec(), route_names: Sequence[str] | None = None) -> World:
    """Terrain, routes (all of :data:`ROUTE_POINTS` unless ``route_names``), surface
    objects and DSM tile set for ``seed``. Pure and deterministic."""
    names = sorted(route_names) if route_names is not None else sorted(ROUTE_POINTS)
    terrain = make_terrain(seed)
    routes = {n: make_route(n) for n in names}
    objects = _place_objects(seed, terrain, routes, dsm)
    return World(seed, terrain, routes, objects, dsm, _tile_set(routes, dsm))


def dsm_tile(world: World, e0: float, n0: float) -> np.ndarray:
    """The DSM of the tile with SW corner (e0, n0) [m]: float32 rows north to south,
    pixel centres at e0 + (col + 0.5) r, n0 + tile - (row + 0.5) r; heights rounded to
    ``quantum_m``; ``nodata`` in holes."""
    spec = world.dsm
    res = spec.resolution_m
    n = int(round(spec.tile_m / res))
    xs = e0 + (np.arange(n) + 0.5) * res
    ys = n0 + spec.tile_m - (np.arange(n) + 0.5) * res
    z = world.terrain.elevation_m(xs[None, :], ys[:, None])
    o = world.objects

    def window(cx, cy, rad):
        c0 = max(0, int(np.floor((cx - rad - e0) / res)))
        c1 = min(n, int(np.ceil((cx + rad - e0) / res)) + 1)
        r0 = max(0, int(np.floor((n0 + spec.tile_m - (cy + rad)) / res)))
        r1 = min(n, int(np.ceil((n0 + spec.tile_m - (cy - rad)) / res)) + 1)
        return r0, r1, c0, c1

    def near(cx, cy, rad):
        return np.flatnonzero((cx + rad >= e0) & (cx - rad <= e0 + spec.tile_m) & (cy + rad >= n0) & (cy - rad <= n0 + spec.tile_m))

    rad = np.hypot(o.rect_hl, o.rect_hw)
    for i in near(o.rect_cx, o.rect_cy, rad):
        r0, r1, c0, c1 = window(o.rect_cx[i], o.rect_cy[i], rad[i])
        if r0 >= r1 or c0 >= c1:
            continue
        dx = xs[None, c0:c1] - o.rect_cx[i]
        dy = ys[r0:r1, None] - o.rect_cy[i]
        du = dx * o.rect_ux[i] + dy * o.rect_uy[i]
        dv = -dx * o.rect_uy[i] + dy * o.rect_ux[i]
        inside = (np.abs(du) <= o.rect_hl[i]) & (np.abs(dv) <= o.rect_hw[i])
        sub = z[r0:r1, c0:c1]
        sub[inside] = np.maximum(sub[inside], o.rect_top[i])
    for i in near(o.tree_cx, o.tree_cy, o.tree_r):
        r0, r1, c0, c1 = window(o.tree_cx[i], o.tree_cy[i], o.tree_r[i])
        if r0 >= r1 or c0 >= c1:
            continue
        q = ((xs[None, c0:c1] - o.tree_cx[i]) ** 2 + (ys[r0:r1, None] - o.tree_cy[i]) ** 2) / o.tree_r[i] ** 2
        canopy = o.tree_ground[i] + o.tree_h[i] * np.sqrt(np.clip(1.0 - q, 0.0, None))
        sub = z[r0:r1, c0:c1]
        np.maximum(sub, np.where(q < 1.0, canopy, -np.inf), out=sub)
    z = np.round(z / spec.quantum_m) * spec.quantum_m
    for i in near(o.hole_cx, o.hole_cy, o.hole_r):
        r0, r1, c0, c1 = window(o.hole_cx[i], o.hole_cy[i], o.hole_r[i])
        if r0 >= r1 or c0 >= c1:
            continue
        q = (xs[None, c0:c1] - o.hole_cx[i]) ** 2 + (ys[r0:r1, None] - o.hole_cy[i]) ** 2
        z[r0:r1, c0:c1][q <= o.hole_r[i] ** 2] = spec.nodata
    return z.astype(np.float32)


def os_tile_name(e0: float, n0: float) -> str:
    """Ordnance Survey grid reference of the 1 km cell with SW corner (e0, n0), e.g.
    ``SP8538`` for (485000, 238000)."""
    e, n = int(e0), int(n0)
    e100, n100 = e // 100000, n // 100000
    l1 = (19 - n100) - (19 - n100) % 5 + (e100 + 10) // 5
    l2 = (19 - n100) * 5 % 25 + e100 % 5
    letters = "ABCDEFGHJKLMNOPQRSTUVWXYZ"  # no I
    return f"{letters[l1]}{letters[l2]}{(e % 100000) // 1000:02d}{(n % 100000) // 1000:02d}"


def tile_filename(world: World, e0: float, n0: float) -> str:
    r = world.dsm.resolution_m
    rs = f"{r:g}".replace(".", "P")
    return f"{os_tile_name(e0, n0)}_DSM_{rs}M.tif"


def write_dsm_tiles(world: World, outdir: Path) -> list[Path]:
    """Write every tile of ``world`` as a tiled, deflate-compressed (floating-point
    predictor) float32 GeoTIFF in EPSG:27700; returns the paths, sorted."""
    import rasterio
    from affine import Affine

    outdir.mkdir(parents=True, exist_ok=True)
    spec = world.dsm
    n = int(round(spec.tile_m / spec.resolution_m))
    paths = []
    for e0, n0 in world.tiles:
        z = dsm_tile(world, e0, n0)
        path = outdir / tile_filename(world, e0, n0)
        profile = dict(
            driver="GTiff", width=n, height=n, count=1, dtype="float32", crs=BNG,
            transform=Affine(spec.resolution_m, 0.0, e0, 0.0, -spec.resolution_m, n0 + spec.tile_m),
            nodata=spec.nodata, compress="deflate", predictor=3, zlevel=6, tiled=True,
            blockxsize=256, blockysize=256,
        )
        with rasterio.open(path, "w", **profile) as ds:
            ds.write(z, 1)
        paths.append(path)
    return sorted(paths)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Index ranges [i0, i1] (inclusive) of the True runs of ``mask``."""
    m = np.concatenate(([False], mask, [False])).astype(np.int8)
    d = np.diff(m)
    return list(zip(np.flatnonzero(d == 1).tolist(), (np.flatnonzero(d == -1) - 1).tolist()))


def route_dsm_summary(world: World, route: Route) -> dict:
    """Intervals of ``route`` [m along it] outside every DSM tile, and intervals where a
    surface object (tree, bridge, building, hole) lies within 1.5 pixels + 0.5 m of the
    centreline (the raw DSM road profile there is spiky or missing)."""
    from scipy.spatial import cKDTree

    s, x, y = route.s_m, route.x_m, route.y_m
    gaps = [[round(float(s[a]), 1), round(float(s[b]), 1)] for a, b in _runs(~world.in_tiles(x, y))]
    o = world.objects
    margin = 1.5 * world.dsm.resolution_m + 0.5
    tree = cKDTree(np.column_stack([x, y]))
    hit: dict[str, np.ndarray] = {k: np.zeros(s.size, bool) for k in ("bridge", "building", "hole", "tree")}
    rad = np.hypot(o.rect_hl, o.rect_hw) + margin
    for i, idx in enumerate(tree.query_ball_point(np.column_stack([o.rect_cx, o.rect_cy]), rad) if o.rect_cx.size else []):
        if not idx:
            continue
        idx = np.asarray(idx)
        dx, dy = x[idx] - o.rect_cx[i], y[idx] - o.rect_cy[i]
        du = dx * o.rect_ux[i] + dy * o.rect_uy[i]
        dv = -dx * o.rect_uy[i] + dy * o.rect_ux[i]
        hit[o.rect_kind[i]][idx[(np.abs(du) <= o.rect_hl[i] + margin) & (np.abs(dv) <= o.rect_hw[i] + margin)]] = True
    for kind, cx, cy, r in (("tree", o.tree_cx, o.tree_cy, o.tree_r), ("hole", o.hole_cx, o.hole_cy, o.hole_r)):
        if not cx.size:
            continue
        for i, idx in enumerate(tree.query_ball_point(np.column_stack([cx, cy]), r + margin)):
            if idx:
                hit[kind][np.asarray(idx)] = True
    objects = []
    for kind in sorted(hit):
        for a, b in _runs(hit[kind]):
            objects.append({"kind": kind, "from_m": round(float(s[a]), 1), "to_m": round(float(s[b]), 1)})
    objects.sort(key=lambda d: (d["from_m"], d["kind"]))
    return {"closed": route.closed, "length_m": round(route.length_m, 1), "dsm_gaps_m": gaps, "surface_objects": objects}


# ======================================================================================
# Fleet: duties, vehicles, day plans, truth trips
# ======================================================================================


@dataclass(frozen=True)
class DutySpec:
    """How a vehicle works a day.

    A trip's speed trace is the concatenation of micro-trip blocks ``segments``: (spec,
    (min, max) micro-trips). ``trips_per_day`` (min, max); ``layover_s`` (min, max)
    ignition-off pause between trips; ``first_start_utc_h`` (min, max) start of the first
    trip in hours after midnight UTC of the day (negative = the evening before);
    ``max_speed_kmh`` caps the trace (HGV limiter 90 km/h); ``load`` the load model:
    ``"passengers"`` (0-60 x 75 kg per trip), ``"drops"`` (payload falls at each drop),
    ``"out_back"`` (heavy out, light back).
    """

    segments: tuple[tuple[MicroTripSpec, tuple[int, int]], ...]
    trips_per_day: tuple[int, int]
    layover_s: tuple[float, float]
    first_start_utc_h: tuple[float, float]
    max_speed_kmh: float
    load: str


URBAN_BUS = MicroTripSpec(cruise_kmh=(20.0, 48.0), cruise_s=(10.0, 60.0), dwell_s=(8.0, 40.0), accel_mps2=(0.6, 1.1), decel_mps2=(0.8, 1.4), fluctuation_kmh=2.0)
TOWN_TRUCK = MicroTripSpec(cruise_kmh=(30.0, 64.0), cruise_s=(20.0, 120.0), dwell_s=(3.0, 30.0), accel_mps2=(0.3, 0.6), decel_mps2=(0.5, 0.9), fluctuation_kmh=2.0)
RURAL_TRUCK = MicroTripSpec(cruise_kmh=(50.0, 88.0), cruise_s=(60.0, 300.0), dwell_s=(3.0, 25.0), accel_mps2=(0.25, 0.5), decel_mps2=(0.5, 0.9), fluctuation_kmh=2.5)
MOTORWAY = MicroTripSpec(cruise_kmh=(80.0, 89.0), cruise_s=(500.0, 1300.0), dwell_s=(2.0, 15.0), accel_mps2=(0.15, 0.35), decel_mps2=(0.3, 0.6), fluctuation_kmh=1.5)

DUTIES: dict[str, DutySpec] = {
    "bus": DutySpec(((URBAN_BUS, (14, 20)),), (3, 3), (720.0, 1500.0), (5.0, 5.6), 50.0, "passengers"),
    "regional": DutySpec(((TOWN_TRUCK, (2, 4)), (RURAL_TRUCK, (3, 5)), (TOWN_TRUCK, (1, 3))), (3, 3), (900.0, 1800.0), (5.5, 6.5), 89.5, "drops"),
    "longhaul": DutySpec(((TOWN_TRUCK, (2, 3)), (MOTORWAY, (2, 3)), (TOWN_TRUCK, (1, 2))), (2, 2), (1800.0, 2700.0), (4.0, 4.5), 89.5, "out_back"),
    # Night trunk for the portal: first trip starts 23:40-23:50 UTC the evening before.
    "night": DutySpec(((TOWN_TRUCK, (2, 3)), (MOTORWAY, (2, 2)), (TOWN_TRUCK, (1, 2))), (2, 2), (1200.0, 1800.0), (-0.33, -0.17), 89.5, "out_back"),
    # Full working days (benchmark fleets): the same duties, 4-6 h of driving.
    "bus-day": DutySpec(((URBAN_BUS, (14, 20)),), (12, 12), (720.0, 1500.0), (5.0, 5.6), 50.0, "passengers"),
    "regional-day": DutySpec(((TOWN_TRUCK, (2, 4)), (RURAL_TRUCK, (3, 5)), (TOWN_TRUCK, (1, 3))), (9, 9), (900.0, 1800.0), (5.5, 6.5), 89.5, "drops"),
    "longhaul-day": DutySpec(((TOWN_TRUCK, (2, 3)), (MOTORWAY, (2, 3)), (TOWN_TRUCK, (1, 2))), (6, 6), (1800.0, 2700.0), (4.0, 4.5), 89.5, "out_back"),
    # --small duties: a few minutes of driving.
    "bus-short": DutySpec(((URBAN_BUS, (3, 4)),), (2, 2), (700.0, 800.0), (5.0, 5.1), 50.0, "passengers"),
    "truck-short": DutySpec(((TOWN_TRUCK, (2, 3)),), (2, 2), (700.0, 800.0), (6.0, 6.1), 89.5, "drops"),
    # Starts 00:55-00:56 UTC on the DST day: the trip crosses 01:00 UTC.
    "night-short": DutySpec(((TOWN_TRUCK, (3, 3)),), (1, 1), (700.0, 800.0), (0.92, 0.93), 89.5, "out_back"),
}


@dataclass(frozen=True)
class VehicleSpec:
    """One vehicle: id (srf ``vehicle_id`` or portal ``Registration``), type (the
    ``kind`` passed to the consumption function), duty, route, kerb mass [kg], and its
    sensors' quirks: flow meter fitted, counter start values, ECU fuel bias (factor on
    the ECU's fuel counter and rate), wheel-speed calibration factor."""

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


@dataclass(frozen=True)
class FleetSpec:
    """What to generate: srf vehicles and their logging days (ISO dates), portal vehicles
    and days, the DSM, and the deliberate faults: ``clock_step`` (vehicle, day index,
    trip index, seconds the clock ran ahead before a mid-trip correction), ``fuel_reset``
    (vehicle, day index, trip index, new counter value [l]), ``gzip_files`` (vehicle, day
    index) written as .csv.gz."""

    srf_vehicles: tuple[VehicleSpec, ...]
    srf_dates: tuple[str, ...]
    portal_vehicles: tuple[VehicleSpec, ...]
    portal_dates: dict[str, tuple[str, ...]]
    dsm: DsmSpec = DsmSpec()
    clock_step: tuple[str, int, int, float] | None = None
    fuel_reset: tuple[str, int, int, float] | None = None
    gzip_files: tuple[tuple[str, int], ...] = ()


_BUS_KERB = 9000.0
_HGV_KERB = 18000.0

SAMPLE_FLEET = FleetSpec(
    srf_vehicles=(
        VehicleSpec("EB-01", "electric-bus", "bus", "bus-1", _BUS_KERB, energy_counter_start_kwh=48213.7),
        VehicleSpec("EB-02", "electric-bus", "bus", "bus-2", _BUS_KERB, energy_counter_start_kwh=51977.2),
        VehicleSpec("HGV-11", "diesel-hgv", "regional", "regional", _HGV_KERB, flowmeter=True,
                    fuel_counter_start_l=96310.5, ecu_fuel_bias=1.03, wheel_speed_scale=1.015),
        VehicleSpec("HGV-21", "diesel-hgv", "longhaul", "trunk", _HGV_KERB, fuel_counter_start_l=1843210.5),
    ),
    srf_dates=("2019-05-14", "2019-05-15", "2019-05-16"),
    portal_vehicles=(
        VehicleSpec("KX19 LMR", "diesel-hgv", "regional", "regional", _HGV_KERB, fuel_counter_start_l=212344.0, odometer_start_m=287041.3 * 1609.344),
        VehicleSpec("KX19 LMT", "diesel-hgv", "night", "trunk", _HGV_KERB, fuel_counter_start_l=418870.5, odometer_start_m=402118.8 * 1609.344),
    ),
    portal_dates={"KX19 LMR": ("2019-10-25", "2019-10-26", "2019-10-28"), "KX19 LMT": ("2019-10-26", "2019-10-27", "2019-10-28")},
    clock_step=("EB-02", 1, 1, 4.25),
    fuel_reset=("HGV-21", 1, 1, 12.5),
    gzip_files=(("HGV-21", 2),),
)

SMALL_FLEET = FleetSpec(
    srf_vehicles=(
        VehicleSpec("EB-01", "electric-bus", "bus-short", "bus-1", _BUS_KERB, energy_counter_start_kwh=48213.7),
        VehicleSpec("HGV-11", "diesel-hgv", "truck-short", "regional", _HGV_KERB, flowmeter=True,
                    fuel_counter_start_l=1843210.5, ecu_fuel_bias=1.03, wheel_speed_scale=1.015),
    ),
    srf_dates=("2019-05-14",),
    portal_vehicles=(
        VehicleSpec("KX19 LMR", "diesel-hgv", "truck-short", "regional", _HGV_KERB, fuel_counter_start_l=212344.0, odometer_start_m=287041.3 * 1609.344),
        VehicleSpec("KX19 LMT", "diesel-hgv", "night-short", "regional", _HGV_KERB, fuel_counter_start_l=418870.5, odometer_start_m=402118.8 * 1609.344),
    ),
    portal_dates={"KX19 LMR": ("2019-10-26",), "KX19 LMT": ("2019-10-27",)},
    dsm=DsmSpec(resolution_m=5.0, survey_box=(483000.0, 235000.0, 489000.0, 238000.0), omitted_cells=((485000.0, 237000.0),)),
    clock_step=("EB-01", 0, 1, 4.25),
    fuel_reset=("HGV-11", 0, 1, 12.5),
    gzip_files=(("HGV-11", 0),),
)


@dataclass(frozen=True, eq=False)
class TruthTrip:
    """One trip as it really happened, on a 1 s grid from ``time_s[0] = 0``.

    ``distance_m`` is the trapezoidal integral of ``speed_mps``; the vehicle is at
    ``route.xy(route_from_m + distance_m)``; ``elevation_m`` is the road surface there;
    ``consumption`` the cumulative output of the consumption function (l or J);
    ``mass_kg`` the gross mass, ``load`` passengers (bus) or payload [kg] (truck).
    """

    vehicle: VehicleSpec
    day_index: int
    trip_index: int  # within the vehicle's day
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

    @property
    def end_utc_s(self) -> float:
        return self.start_utc_s + float(self.time_s[-1])

    def at(self, t_s: np.ndarray, world: World) -> dict[str, np.ndarray]:
        """Truth at arbitrary times ``t_s`` [s from trip start] inside the trip: speed
        (linear), distance (exact integral of the linear speed), position, road elevation,
        cumulative consumption (linear), and the step index of the 1 s grid."""
        t = self.time_s
        k = np.clip(np.searchsorted(t, t_s, side="right") - 1, 0, t.size - 2)
        tau = t_s - t[k]
        dt = t[k + 1] - t[k]
        v0, v1 = self.speed_mps[k], self.speed_mps[k + 1]
        v = v0 + (v1 - v0) * tau / dt
        d = self.distance_m[k] + v0 * tau + (v1 - v0) * tau * tau / (2 * dt)
        x, y = world.routes[self.vehicle.route].xy(self.route_from_m + d)
        c = self.consumption[k] + (self.consumption[k + 1] - self.consumption[k]) * tau / dt
        return {"k": k, "speed": v, "distance": d, "x": x, "y": y, "elev": world.terrain.elevation_m(x, y), "cons": c}


def _speed_trace(duty: DutySpec, rng: np.random.Generator) -> np.ndarray:
    """Speed [m/s] at 1 s steps: the duty's micro-trip blocks, concatenated and capped."""
    parts = []
    for spec, (lo, hi) in duty.segments:
        n = int(rng.integers(lo, hi + 1))
        cyc = micro_trip_cycle(dataclasses.replace(spec, n_trips=n), int(rng.integers(0, 2**31 - 1)))
        parts.append(cyc.speed_mps)
    v = np.minimum(np.concatenate(parts), duty.max_speed_kmh / 3.6)
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
    return datetime.fromisoformat(date).replace(tzinfo=timezone.utc).timestamp()


def _day_loads(veh: VehicleSpec, duty: DutySpec, n_trips: int, rng: np.random.Generator) -> list[float]:
    """Load per trip: passengers (bus) or payload [kg] (truck, 0-26,000 kg)."""
    if duty.load == "passengers":
        return [float(rng.integers(0, 61)) for _ in range(n_trips)]
    if duty.load == "drops":
        p = float(np.round(rng.uniform(14000.0, 26000.0), -1))
        out = []
        for _ in range(n_trips):
            out.append(p)
            p = max(0.0, float(np.round(p - rng.uniform(3000.0, 8000.0), -1)))
        return out
    return [float(np.round(rng.uniform(15000.0, 26000.0), -1)) if i % 2 == 0 else float(np.round(rng.uniform(0.0, 9000.0), -1)) for i in range(n_trips)]


def simulate_day(world: World, veh: VehicleSpec, day_index: int, date: str, consumption_fn: ConsumptionFn, seed: int) -> list[TruthTrip]:
    """The truth trips of one vehicle-day (each day starts at the route's s = 0)."""
    duty = DUTIES[veh.duty]
    rng = _rng(seed, "day", veh.vehicle_id, date)
    n_trips = int(rng.integers(duty.trips_per_day[0], duty.trips_per_day[1] + 1))
    loads = _day_loads(veh, duty, n_trips, rng)
    start = _utc_midnight_s(date) + round(rng.uniform(*duty.first_start_utc_h) * 3600.0)
    route = world.routes[veh.route]
    route_d = 0.0
    trips = []
    for j in range(n_trips):
        if duty.load == "out_back" and j % 2 == 1 and not route.closed:
            # the return leg: turn round (the mirror position on the way back, see
            # Route.along_m) and drive the outbound distance back to the depot
            v = _return_trace(duty, rng, float(trips[-1].distance_m[-1]))
            route_d = 2.0 * route.length_m - route_d
        else:
            v = _speed_trace(duty, rng)
        mass = veh.kerb_mass_kg + (loads[j] * 75.0 if duty.load == "passengers" else loads[j])
        v = power_limited_trace(
            v, lambda s_m, d0=route_d: world.terrain.elevation_m(*route.xy(d0 + s_m)), mass,
            STANDIN[veh.vehicle_type], DRIVER_MAX_WHEEL_POWER_W[veh.vehicle_type],
        )
        t = np.arange(v.size, dtype=float)
        d = np.concatenate(([0.0], np.cumsum(0.5 * (v[1:] + v[:-1]))))
        x, y = route.xy(route_d + d)
        h = world.terrain.elevation_m(x, y)
        c = np.asarray(consumption_fn(veh.vehicle_type, t, v, h, mass), dtype=float)
        if c.shape != t.shape or not np.all(np.isfinite(c)):
            raise ValueError(f"consumption_fn returned shape {c.shape} or non-finite values for a trip of {t.size} samples")
        c = c - c[0]
        trips.append(TruthTrip(veh, day_index, j, float(start), t, v, d, route_d, x, y, h, float(mass), loads[j], c))
        route_d += float(d[-1])
        start += float(t[-1]) + round(rng.uniform(*duty.layover_s))
    return trips


def simulate_fleet(fleet: FleetSpec = SAMPLE_FLEET, consumption_fn: ConsumptionFn = standin_consumption, seed: int = DEFAULT_SEED, world: World | None = None) -> tuple[World, dict[str, list[list[TruthTrip]]]]:
    """The world and, per vehicle id, per day, the truth trips of ``fleet`` (srf vehicles
    on ``fleet.srf_dates``, portal vehicles on their ``portal_dates``)."""
    if world is None:
        names = {v.route for v in fleet.srf_vehicles + fleet.portal_vehicles}
        world = build_world(seed, fleet.dsm, sorted(names))
    out: dict[str, list[list[TruthTrip]]] = {}
    for veh in fleet.srf_vehicles:
        out[veh.vehicle_id] = [simulate_day(world, veh, i, d, consumption_fn, seed) for i, d in enumerate(fleet.srf_dates)]
    for veh in fleet.portal_vehicles:
        out[veh.vehicle_id] = [simulate_day(world, veh, i, d, consumption_fn, seed) for i, d in enumerate(fleet.portal_dates[veh.vehicle_id])]
    return world, out


# ======================================================================================
# Fast, deterministic CSV formatting (no per-value Python)
# ======================================================================================


def _num_field(x, decimals: int, *, strip: bool = False, dec: bytes = b".") -> tuple[np.ndarray, np.ndarray]:
    """Characters (N x W uint8) and keep-mask of numbers printed with ``decimals``
    decimals (``strip``: trailing fractional zeros dropped); NaN -> empty field."""
    x = np.asarray(x, dtype=float)
    nrow = x.size
    valid = np.isfinite(x)
    n = np.rint(np.where(valid, x, 0.0) * 10.0**decimals).astype(np.int64)
    neg = n < 0
    a = np.abs(n)
    amax = int(a.max()) if nrow else 0
    nd = max(len(str(amax)), decimals + 1)
    pw = 10 ** np.arange(nd - 1, -1, -1, dtype=np.int64)
    digits = ((a[:, None] // pw[None, :]) % 10).astype(np.uint8)
    ni = nd - decimals
    keep_i = np.logical_or.accumulate(digits[:, :ni] != 0, axis=1)
    keep_i[:, -1] = True
    if decimals:
        if strip:
            keep_f = np.logical_or.accumulate((digits[:, ni:] != 0)[:, ::-1], axis=1)[:, ::-1]
            dot = keep_f.any(axis=1)
        else:
            keep_f = np.ones((nrow, decimals), bool)
            dot = np.ones(nrow, bool)
        chars = np.concatenate([np.full((nrow, 1), ord("-"), np.uint8), digits[:, :ni] + 48, np.full((nrow, 1), dec[0], np.uint8), digits[:, ni:] + 48], axis=1)
        keep = np.concatenate([neg[:, None], keep_i, dot[:, None], keep_f], axis=1)
    else:
        chars = np.concatenate([np.full((nrow, 1), ord("-"), np.uint8), digits + 48], axis=1)
        keep = np.concatenate([neg[:, None], keep_i], axis=1)
    return chars, keep & valid[:, None]


def _text_field(values) -> tuple[np.ndarray, np.ndarray]:
    """Characters and keep-mask of byte strings (empty string -> empty field)."""
    arr = np.asarray(values, dtype=bytes)
    if arr.dtype.itemsize == 0:
        arr = arr.astype("S1")
    chars = arr.view(np.uint8).reshape(arr.size, arr.dtype.itemsize)
    return chars, chars != 0


def _assemble(fields: list[tuple[np.ndarray, np.ndarray]], sep: bytes, eol: bytes) -> bytes:
    """Rows of ``fields`` joined by ``sep`` and ended by ``eol``, as bytes."""
    nrow = fields[0][0].shape[0]
    parts, keeps = [], []
    for i, (c, k) in enumerate(fields):
        if i:
            parts.append(np.full((nrow, len(sep)), np.frombuffer(sep, np.uint8), np.uint8))
            keeps.append(np.ones((nrow, len(sep)), bool))
        parts.append(c)
        keeps.append(k)
    parts.append(np.tile(np.frombuffer(eol, np.uint8), (nrow, 1)))
    keeps.append(np.ones((nrow, len(eol)), bool))
    return np.concatenate(parts, axis=1)[np.concatenate(keeps, axis=1)].tobytes()


def _iso_utc_ms(epoch_ms: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``YYYY-MM-DDTHH:MM:SS.mmmZ`` characters of integer epoch milliseconds."""
    s = np.datetime_as_string(epoch_ms.astype("datetime64[ms]"), unit="ms").astype("S23")
    c = np.concatenate([s.view(np.uint8).reshape(-1, 23), np.full((s.size, 1), ord("Z"), np.uint8)], axis=1)
    return c, np.ones(c.shape, bool)


def _uk_local(epoch_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``dd/mm/yyyy HH:MM:SS`` characters of UTC epoch seconds in Europe/London time."""
    import pandas as pd

    idx = pd.DatetimeIndex(np.asarray(epoch_s, dtype=np.int64).astype("datetime64[s]"), tz="UTC")
    local = idx.tz_convert("Europe/London").tz_localize(None).values.astype("datetime64[s]")
    s = np.datetime_as_string(local, unit="s").astype("S19").view(np.uint8).reshape(-1, 19)
    order = [8, 9, 7, 5, 6, 4, 0, 1, 2, 3, 10, 11, 12, 13, 14, 15, 16, 17, 18]
    c = s[:, order].copy()
    c[:, 2] = c[:, 5] = ord("/")
    c[:, 10] = ord(" ")
    return c, np.ones(c.shape, bool)


# ======================================================================================
# Sensors: srf
# ======================================================================================

SRF_BUS_COLUMNS = (
    "timestamp_utc", "gps_lat_deg", "gps_lon_deg", "gps_alt_m", "gps_speed_kmh", "gps_hdop",
    "fms_wheel_speed_kmh", "fms_accel_pedal_pct", "fms_brake_switch", "fms_engine_speed_rpm",
    "fms_engine_torque_pct", "fms_battery_soc_pct", "fms_battery_voltage_v", "fms_battery_current_a",
    "fms_total_energy_used_kwh",
)
SRF_TRUCK_COLUMNS = (
    "timestamp_utc", "gps_lat_deg", "gps_lon_deg", "gps_alt_m", "gps_speed_kmh", "gps_hdop",
    "fms_wheel_speed_kmh", "fms_accel_pedal_pct", "fms_brake_switch", "fms_engine_speed_rpm",
    "fms_engine_torque_pct", "fms_total_fuel_used_l", "fms_fuel_rate_lph", "flowmeter_fuel_lph",
    "fms_gross_weight_kg",
)
#: (decimals, strip trailing zeros) per srf column.
SRF_FORMAT = {
    "gps_lat_deg": (6, False), "gps_lon_deg": (6, False), "gps_alt_m": (1, False), "gps_speed_kmh": (1, False),
    "gps_hdop": (1, False), "fms_wheel_speed_kmh": (8, True), "fms_accel_pedal_pct": (1, False),
    "fms_brake_switch": (0, False), "fms_engine_speed_rpm": (3, True), "fms_engine_torque_pct": (0, False),
    "fms_battery_soc_pct": (1, False), "fms_battery_voltage_v": (1, False), "fms_battery_current_a": (1, False),
    "fms_total_energy_used_kwh": (1, False), "fms_total_fuel_used_l": (1, False), "fms_fuel_rate_lph": (2, False),
    "flowmeter_fuel_lph": (2, False), "fms_gross_weight_kg": (0, False),
}
#: Truck gearbox (12-speed AMT) and axle ratio of the plausible engine-speed model.
_GEARS = np.array([14.9, 11.7, 9.0, 7.1, 5.6, 4.4, 3.5, 2.7, 2.1, 1.7, 1.3, 1.0])
_AXLE = 2.8
_EV_USABLE_J = 124.0 * 3.6e6  # configs/vehicles/electric-bus.toml battery_kwh


def _arrivals(tk: np.ndarray, period_s: tuple[float, float], rng: np.random.Generator) -> np.ndarray:
    """Mask of ticks that received a new value of a field broadcast at random intervals
    in ``period_s``: a tick shows a value if an arrival fell after the previous tick."""
    if tk.size == 0:
        return np.zeros(0, bool)
    span = tk[-1] - tk[0] + 2.0
    n = int(span / period_s[0]) + 2
    arr = tk[0] - rng.uniform(0.0, period_s[1]) + np.cumsum(rng.uniform(*period_s, n))
    idx = np.searchsorted(tk, arr, side="left")
    idx = idx[(idx < tk.size) & (arr >= tk[0] - 1.0)]
    m = np.zeros(tk.size, bool)
    m[idx] = True
    return m


def _ar1(n: int, tau_ticks: float, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """Stationary AR(1) noise with correlation time ``tau_ticks`` and std ``sigma``."""
    from scipy.signal import lfilter

    if n == 0:
        return np.zeros(0)
    a = math.exp(-1.0 / tau_ticks)
    w = rng.normal(0.0, sigma * math.sqrt(1 - a * a), n)
    w[0] = rng.normal(0.0, sigma)
    return lfilter([1.0], [1.0, -a], w)


def _floor_q(x, q):
    """Counter reading: ``x`` floored to the resolution ``q`` (with a 1e-9 guard)."""
    return np.floor(np.asarray(x) / q + 1e-9) * q


def _round_q(x, q):
    return np.round(np.asarray(x) / q) * q


def _transformer():
    import pyproj

    return pyproj.Transformer.from_crs(BNG, WGS84, always_xy=True)


def _fms_common(veh: VehicleSpec, tr: TruthTrip, at: dict, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Wheel speed, pedal, brake switch, engine/motor speed and torque at the ticks."""
    p = STANDIN[veh.vehicle_type]
    k = at["k"]
    v0, v1 = tr.speed_mps[k], tr.speed_mps[k + 1]
    acc = v1 - v0  # the grid step is 1 s
    dh = tr.elevation_m[k + 1] - tr.elevation_m[k]
    pw = _wheel_power_w(p, 1.0, v0, v1, dh, tr.mass_kg)
    v = at["speed"]
    n = v.size
    out = {}
    out["fms_wheel_speed_kmh"] = np.round(v * veh.wheel_speed_scale * 3.6 * 256.0) / 256.0
    out["fms_accel_pedal_pct"] = _round_q(np.clip(100.0 * pw / p.max_power_w, 0.0, 100.0) * (pw > 0), 0.4)
    out["fms_brake_switch"] = ((acc < -0.3) | (v < 0.05)).astype(float)
    omega_w = v / p.wheel_radius_m  # wheel rad/s
    if veh.vehicle_type == "electric-bus":
        omega = omega_w * p.motor_ratio
        pm = np.where(pw > 0, pw / 0.95, np.maximum(pw, -p.regen_max_w) * 0.95)
        torque = pm / np.maximum(omega, 5.0)
        rpm = omega * 60.0 / (2 * np.pi)
    else:
        rpm_all = omega_w[:, None] * _AXLE * _GEARS[None, :] * 60.0 / (2 * np.pi)
        gear = np.maximum((rpm_all >= 1000.0).sum(axis=1) - 1, 0)
        rpm = np.clip(rpm_all[np.arange(n), gear], 600.0, 1900.0) + rng.normal(0.0, 4.0, n)
        pe = pw + p.aux_w
        torque = np.where(pe > 0, pe / (rpm * 2 * np.pi / 60.0), -0.08 * p.ref_torque_nm)
        torque = np.where(v < 0.1, 0.05 * p.ref_torque_nm, torque)
    out["fms_engine_speed_rpm"] = _round_q(np.maximum(rpm, 0.0), 0.125)
    out["fms_engine_torque_pct"] = np.clip(np.round(100.0 * torque / p.ref_torque_nm), -125, 125)
    return out


@dataclass
class _Counters:
    """Running state of one vehicle across its days: cumulative true consumption."""

    consumption: float = 0.0
    odometer_m: float = 0.0
    reset_offset: float | None = None  # ECU counter after a reset = offset + bias x consumption


def _srf_file(world: World, veh: VehicleSpec, trips: list[TruthTrip], date: str, state: _Counters, fleet: FleetSpec, seed: int, transformer) -> tuple[bytes, list[dict], dict]:
    """One srf session file: (bytes, truth records of its trips, file record)."""
    rng = _rng(seed, "srf", veh.vehicle_id, date)
    is_bus = veh.vehicle_type == "electric-bus"
    cols = SRF_BUS_COLUMNS if is_bus else SRF_TRUCK_COLUMNS
    if not is_bus and not veh.flowmeter:
        cols = tuple(c for c in cols if c != "flowmeter_fuel_lph")
    day_index = trips[0].day_index
    faults: list[dict] = []
    blocks: list[dict[str, np.ndarray]] = []
    records: list[dict] = []
    soc0 = float(rng.uniform(92.0, 100.0))
    day_energy0 = state.consumption
    alt_bias = float(rng.uniform(-10.0, 10.0))
    for tr in trips:
        T = float(tr.time_s[-1])
        n0 = int(T) + 1
        tk = np.arange(n0) + rng.uniform(0.0, 1.0) + rng.normal(0.0, 0.012, n0)
        tk = tk[(tk >= 0.0) & (tk <= T)]
        keep = rng.random(tk.size) > 0.01
        for _ in range(int(rng.integers(0, 3))):  # short bursts of missed ticks
            i0 = int(rng.integers(1, max(2, tk.size - 5)))
            keep[i0 : i0 + int(rng.integers(2, 5))] = False
        keep[0] = keep[-1] = True
        tk = tk[keep]
        n = tk.size
        at = tr.at(tk, world)
        cols_v: dict[str, np.ndarray] = {}
        # ---- GPS
        fix = rng.random(n) > 0.02
        cold = int(rng.integers(8, 26)) if tr.trip_index == 0 else int(rng.integers(2, 7))
        fix[:cold] = False
        hdop = 0.9 + np.abs(_ar1(n, 60.0, 0.25, rng))
        for _ in range(int(rng.poisson(T / 1800.0))):
            i0 = int(rng.integers(0, n))
            L = int(rng.integers(10, 46))
            fix[i0 : i0 + L] = False
            hdop[max(0, i0 - 5) : i0] += np.linspace(0.5, 2.5, len(hdop[max(0, i0 - 5) : i0]))
            hdop[i0 + L : i0 + L + 8] += np.linspace(2.5, 0.3, len(hdop[i0 + L : i0 + L + 8]))
        scale = hdop / 0.9
        ex = _ar1(n, 40.0, 2.5, rng) * scale + rng.normal(0.0, 0.7, n)
        ny = _ar1(n, 40.0, 2.5, rng) * scale + rng.normal(0.0, 0.7, n)
        lon, lat = transformer.transform(at["x"] + ex, at["y"] + ny)
        alt = at["elev"] + GEOID_UNDULATION_M + alt_bias + _ar1(n, 200.0, 12.0, rng) + rng.normal(0.0, 2.0, n)
        gspeed = np.abs(at["speed"] + rng.normal(0.0, 0.15, n)) * 3.6
        nan = np.where(fix, 1.0, np.nan)
        cols_v["gps_lat_deg"], cols_v["gps_lon_deg"] = lat * nan, lon * nan
        cols_v["gps_alt_m"], cols_v["gps_speed_kmh"], cols_v["gps_hdop"] = alt * nan, gspeed * nan, _round_q(hdop, 0.1) * nan
        # ---- FMS common (three broadcast groups, each missing in 0.5 % of ticks)
        fms = _fms_common(veh, tr, at, rng)
        groups = (("fms_wheel_speed_kmh", "fms_brake_switch"), ("fms_accel_pedal_pct",), ("fms_engine_speed_rpm", "fms_engine_torque_pct"))
        for g in groups:
            m = np.where(rng.random(n) > 0.005, 1.0, np.nan)
            for c in g:
                cols_v[c] = fms[c] * m
        cons = state.consumption + at["cons"]
        rate = np.diff(tr.consumption)[at["k"]]  # per 1 s step: l/s or W
        if is_bus:
            e_day = cons - day_energy0
            soc_true = soc0 - 100.0 * e_day / _EV_USABLE_J
            voc = 560.0 + 1.3 * soc_true
            r_ohm = 0.1
            cur = (voc - np.sqrt(voc * voc - 4.0 * r_ohm * rate)) / (2.0 * r_ohm)
            volt = voc - r_ohm * cur
            m = np.where(rng.random(n) > 0.01, 1.0, np.nan)
            cols_v["fms_battery_voltage_v"] = _round_q(volt, 0.1) * m
            cols_v["fms_battery_current_a"] = _round_q(cur, 0.1) * m
            cols_v["fms_battery_soc_pct"] = np.where(_arrivals(tk, (9.0, 11.0), rng), _round_q(soc_true, 0.4), np.nan)
            kwh = veh.energy_counter_start_kwh + cons / 3.6e6
            cols_v["fms_total_energy_used_kwh"] = np.where(_arrivals(tk, (4.0, 6.0), rng), _floor_q(kwh, 0.1), np.nan)
        else:
            ecu = veh.fuel_counter_start_l + veh.ecu_fuel_bias * cons
            if fleet.fuel_reset and fleet.fuel_reset[:3] == (veh.vehicle_id, day_index, tr.trip_index):
                i_reset = n // 2
                state.reset_offset = fleet.fuel_reset[3] - veh.ecu_fuel_bias * cons[i_reset]
                faults.append({"kind": "fuel_counter_reset", "trip_index": tr.trip_index, "tick": sum(b["n"] for b in blocks) + i_reset,
                               "from_l": float(_floor_q(ecu[i_reset - 1], 0.5)), "to_l": fleet.fuel_reset[3]})
                ecu = np.where(np.arange(n) >= i_reset, state.reset_offset + veh.ecu_fuel_bias * cons, ecu)
            elif state.reset_offset is not None:
                ecu = state.reset_offset + veh.ecu_fuel_bias * cons
            cols_v["fms_total_fuel_used_l"] = np.where(_arrivals(tk, (5.0, 10.0), rng), _floor_q(ecu, 0.5), np.nan)
            lph = np.maximum(0.0, veh.ecu_fuel_bias * rate * 3600.0 * (1.0 + rng.normal(0.0, 0.02, n)))
            cols_v["fms_fuel_rate_lph"] = np.where(rng.random(n) > 0.03, _round_q(lph, 0.05), np.nan)
            if veh.flowmeter:
                m = _arrivals(tk, (1.8, 2.2), rng)
                idx = np.flatnonzero(m)
                c_at = at["cons"][idx]
                prev_t = np.concatenate(([tk[idx[0]] - 2.0], tk[idx[:-1]])) if idx.size else idx
                prev_c = np.interp(prev_t, tr.time_s, tr.consumption) if idx.size else idx
                mean_lph = (c_at - prev_c) / np.maximum(tk[idx] - prev_t, 1e-3) * 3600.0
                flow = np.full(n, np.nan)
                flow[idx] = _round_q(np.maximum(0.0, mean_lph * (1.0 + rng.normal(0.0, 0.015, idx.size))), 0.01)
                cols_v["flowmeter_fuel_lph"] = flow
            moved = np.cumsum(np.concatenate(([0.0], np.diff(tk))) * (at["speed"] > 0.5)) > 30.0
            cols_v["fms_gross_weight_kg"] = np.where(_arrivals(tk, (9.0, 11.0), rng) & moved, _round_q(tr.mass_kg, 10.0), np.nan)
        # ---- clock: the phone clock ran ahead until a mid-trip correction
        clock = np.zeros(n)
        cs = fleet.clock_step
        if cs and cs[0] == veh.vehicle_id and cs[1] == day_index:
            if tr.trip_index < cs[2]:
                clock[:] = cs[3]
            elif tr.trip_index == cs[2]:
                i_step = n // 2
                clock[:i_step] = cs[3]
                faults.append({"kind": "clock_step_backwards", "trip_index": tr.trip_index, "tick": sum(b["n"] for b in blocks) + i_step, "seconds": cs[3]})
        true_ms = np.round((tr.start_utc_s + tk) * 1000.0).astype(np.int64)
        cols_v["timestamp_ms"] = true_ms + np.round(clock * 1000.0).astype(np.int64)
        blocks.append({"n": n, "cols": cols_v})
        t_first, t_last = tk[0], tk[-1]
        c_first, c_last = at["cons"][0], at["cons"][-1]
        records.append({
            "vehicle_id": veh.vehicle_id, "vehicle_type": veh.vehicle_type, "dialect": "srf", "day_index": day_index,
            "trip_index": tr.trip_index, "start_utc_s": round(tr.start_utc_s + t_first, 3), "end_utc_s": round(tr.start_utc_s + t_last, 3),
            "duration_s": round(t_last - t_first, 3), "distance_m": round(float(at["distance"][-1] - at["distance"][0]), 2),
            "mass_kg": tr.mass_kg, "consumption": float(c_last - c_first), "route": veh.route,
            "route_from_m": round(tr.route_from_m + float(at["distance"][0]), 2),
            "load": tr.load, "dsm_covered_share": round(float(world.in_tiles(tr.x_m, tr.y_m).mean()), 4),
            "_rows": n,
        })
        state.consumption += float(tr.consumption[-1])
    # ---- assemble rows, repeated ticks (identical duplicate lines)
    allc = {c: np.concatenate([b["cols"][c] for b in blocks]) for c in blocks[0]["cols"]}
    ntot = allc["timestamp_ms"].size
    rep = rng.random(ntot) < 0.003
    order = np.repeat(np.arange(ntot), 1 + rep.astype(int))
    first_row = np.concatenate(([0], np.cumsum([b["n"] for b in blocks])))
    # line of row i of the original = header lines + position in `order`
    started = datetime.fromtimestamp(int(allc["timestamp_ms"][0] // 1000) - int(rng.integers(2, 9)), timezone.utc)
    header = (
        f"# vehicle_id={veh.vehicle_id}\n# logger=SRF Logger 2.4.1\n# started={started.strftime('%Y-%m-%dT%H:%M:%SZ')}\n"
        f"# fms_dongle=FMS-BT 1.7\n{','.join(cols)}\n"
    ).encode()
    n_head = header.count(b"\n")
    pos_first = np.searchsorted(order, np.arange(ntot), side="left")  # first output row of each tick
    pos_last = np.searchsorted(order, np.arange(ntot), side="right") - 1
    for j, rec in enumerate(records):
        rec["first_line"] = int(n_head + 1 + pos_first[first_row[j]])
        rec["last_line"] = int(n_head + 1 + pos_last[first_row[j + 1] - 1])
        del rec["_rows"]
    for f in faults:
        f["line"] = int(n_head + 1 + pos_first[f.pop("tick")])
    fields = [_iso_utc_ms(allc["timestamp_ms"][order])]
    for c in cols[1:]:
        dec, strip = SRF_FORMAT[c]
        fields.append(_num_field(allc[c][order], dec, strip=strip))
    data = header + _assemble(fields, b",", b"\n")
    info = {"vehicle_id": veh.vehicle_id, "dialect": "srf", "rows": int(order.size), "repeated_ticks": int(rep.sum()), "faults": faults}
    return data, records, info


# ======================================================================================
# Sensors: portal
# ======================================================================================

PORTAL_COLUMNS = ("Registration", "Date/Time", "Latitude", "Longitude", "Speed (mph)", "Odometer (mi)", "Fuel Used (l)", "Ignition", "Event")
MPH = 0.44704
MILE_M = 1609.344


def _portal_vehicle(world: World, veh: VehicleSpec, days: list[list[TruthTrip]], state: _Counters, seed: int, transformer) -> tuple[dict[str, np.ndarray], list[dict]]:
    """Rows of one vehicle (time order) and truth records of its trips."""
    rng = _rng(seed, "portal", veh.vehicle_id)
    rows: dict[str, list[np.ndarray]] = {k: [] for k in ("t", "x", "y", "speed_mph", "odo", "fuel", "ign", "event")}
    records = []
    trips = [tr for day in days for tr in day]
    events_pool = np.array(["", "Harsh braking", "Speeding", "Harsh acceleration"], dtype=object)
    for j, tr in enumerate(trips):
        T = int(tr.time_s[-1])
        v = tr.speed_mps
        moving = v > 0.3
        rate = np.where(moving, 1.0 / 5.0, 1.0 / 75.0) * rng.uniform(0.5, 1.5, v.size)
        cum = np.cumsum(rate)
        sel = np.flatnonzero(np.diff(np.floor(cum), prepend=0.0) > 0)
        # journey events: a row when the vehicle comes to rest and when it moves off
        change = np.flatnonzero(moving[1:] != moving[:-1])
        sel = np.unique(np.concatenate(([0], sel, change, change + 1, [T])))
        ts = sel.astype(float)
        at = tr.at(ts, world)
        n = ts.size
        ex = _ar1(n, 8.0, 3.0, rng)
        ny = _ar1(n, 8.0, 3.0, rng)
        rows["t"].append(tr.start_utc_s + ts)
        rows["x"].append(at["x"] + ex), rows["y"].append(at["y"] + ny)
        rows["speed_mph"].append(np.abs(at["speed"] + rng.normal(0.0, 0.2, n) * (at["speed"] > 0.3)) / MPH)
        rows["odo"].append(state.odometer_m + at["distance"])
        rows["fuel"].append(veh.fuel_counter_start_l + state.consumption + at["cons"])
        ign = np.ones(n)
        ign[-1] = 0.0
        rows["ign"].append(ign)
        ev = np.full(n, "", dtype=object)
        # Harsh events on a few rows with the strongest deceleration / while fast.
        acc = np.diff(v, append=0.0)[sel]
        if n > 10:
            ev[int(np.argmin(acc))] = "Harsh braking"
            if rng.random() < 0.5:
                ev[int(rng.integers(1, n - 1))] = str(events_pool[int(rng.integers(1, 4))])
        if j == 0 or trips[j - 1].day_index != tr.day_index:
            ev[0] = "Départ dépôt – Café Rouge Distribution, Wolverton"
        if j + 1 == len(trips) or trips[j + 1].day_index != tr.day_index:
            ev[-1] = "Fuel card: £152,40 at Shell Newport Pagnell"
        rows["event"].append(ev)
        records.append({
            "vehicle_id": veh.vehicle_id, "vehicle_type": veh.vehicle_type, "dialect": "portal", "day_index": tr.day_index,
            "trip_index": j, "start_utc_s": float(tr.start_utc_s), "end_utc_s": float(tr.start_utc_s + T), "duration_s": float(T),
            "distance_m": round(float(tr.distance_m[-1]), 2), "mass_kg": tr.mass_kg, "consumption": float(tr.consumption[-1]),
            "route": veh.route, "route_from_m": round(tr.route_from_m, 2), "load": tr.load,
            "dsm_covered_share": round(float(world.in_tiles(tr.x_m, tr.y_m).mean()), 4),
        })
        state.odometer_m += float(tr.distance_m[-1])
        state.consumption += float(tr.consumption[-1])
        # Heartbeats while parked with the ignition off, until the next trip.
        if j + 1 < len(trips):
            nxt = trips[j + 1].start_utc_s
            hb = tr.start_utc_s + T + np.cumsum(rng.uniform(900.0, 1800.0, 40))
            hb = np.round(hb[hb < nxt - 30.0])
            m = hb.size
            if m:
                rows["t"].append(hb)
                rows["x"].append(np.full(m, at["x"][-1]) + rng.normal(0, 2.0, m)), rows["y"].append(np.full(m, at["y"][-1]) + rng.normal(0, 2.0, m))
                rows["speed_mph"].append(np.zeros(m)), rows["odo"].append(np.full(m, state.odometer_m))
                rows["fuel"].append(np.full(m, veh.fuel_counter_start_l + state.consumption)), rows["ign"].append(np.zeros(m))
                rows["event"].append(np.full(m, "", dtype=object))
    out = {k: np.concatenate(vv) for k, vv in rows.items()}
    o = np.argsort(out["t"], kind="stable")
    out = {k: vv[o] for k, vv in out.items()}
    lon, lat = transformer.transform(out["x"], out["y"])
    nofix = rng.random(lon.size) < 0.002
    out["lat"], out["lon"] = np.where(nofix, 0.0, lat), np.where(nofix, 0.0, lon)
    return out, records


def _portal_file(world: World, fleet: FleetSpec, truth: dict[str, list[list[TruthTrip]]], seed: int, transformer) -> tuple[bytes, list[dict], dict]:
    """The portal export of all portal vehicles: (cp1252 bytes, truth records, file record)."""
    per = []
    records = []
    for veh in sorted(fleet.portal_vehicles, key=lambda v: v.vehicle_id):
        rows, recs = _portal_vehicle(world, veh, truth[veh.vehicle_id], _Counters(odometer_m=veh.odometer_start_m), seed, transformer)
        per.append((veh, rows))
        records.extend(recs)
    reg = np.concatenate([np.full(r["t"].size, v.vehicle_id.encode("cp1252")) for v, r in per])
    allr = {k: np.concatenate([r[k] for _, r in per]) for k in per[0][1]}
    t = np.round(allr["t"]).astype(np.int64)
    texts, inverse = np.unique(allr["event"].astype(str), return_inverse=True)
    events = np.array([x.encode("cp1252") for x in texts], dtype=object)[inverse]
    fields = [
        _text_field(reg), _uk_local(t),
        _num_field(allr["lat"], 5, dec=b","), _num_field(allr["lon"], 5, dec=b","),
        _num_field(allr["speed_mph"], 1, dec=b","), _num_field(_floor_q(allr["odo"] / MILE_M, 0.1), 1, dec=b","),
        _num_field(_floor_q(allr["fuel"], 0.5), 1, dec=b","),
        _text_field(np.where(allr["ign"] > 0, b"On", b"Off")),
        _text_field(events),
    ]
    header = (";".join(PORTAL_COLUMNS) + "\r\n").encode("cp1252")
    data = header + _assemble(fields, b";", b"\r\n")
    # lines: header is line 1; rows in (vehicle, time) order; trips start/end at exact rows
    lines = {}
    offset = 0
    for v, r in per:
        lines[v.vehicle_id] = (offset, np.round(r["t"]).astype(np.int64))
        offset += r["t"].size
    for rec in records:
        off, tt = lines[rec["vehicle_id"]]
        rec["first_line"] = int(2 + off + np.searchsorted(tt, round(rec["start_utc_s"]), side="left"))
        rec["last_line"] = int(2 + off + np.searchsorted(tt, round(rec["end_utc_s"]), side="left"))
    info = {"dialect": "portal", "rows": int(t.size), "vehicles": [v.vehicle_id for v, _ in per], "faults": []}
    return data, records, info


# ======================================================================================
# Orchestration
# ======================================================================================


def _qualname(fn: Callable) -> str:
    return f"{getattr(fn, '__module__', '?')}:{getattr(fn, '__qualname__', repr(fn))}"


def _iso(t: float) -> str:
    ms = int(round(t * 1000.0))
    return datetime.fromtimestamp(ms // 1000, timezone.utc).strftime("%Y-%m-%dT%H:%M:%S") + f".{ms % 1000:03d}Z"


def _finish_records(records: list[dict]) -> None:
    for r in records:
        kind = MEASUREMENT_KIND[r["vehicle_type"]]
        r["consumption_unit"] = "J" if kind == "energy_j" else "l"
        r["consumption"] = round(r["consumption"], 1 if kind == "energy_j" else 5)
        r["load_unit"] = "passengers" if r["vehicle_type"] == "electric-bus" else "kg payload"
        r["start_utc"], r["end_utc"] = _iso(r["start_utc_s"]), _iso(r["end_utc_s"])


def _write(path: Path, data: bytes, gz: bool) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    if gz:
        path = path.with_name(path.name + ".gz")
        data = gzip.compress(data, compresslevel=9, mtime=0)
    path.write_bytes(data)
    return path


def _write_srf(outdir: Path, world: World, fleet: FleetSpec, truth, seed: int) -> tuple[list[dict], list[dict]]:
    transformer = _transformer()
    files, records = [], []
    for veh in fleet.srf_vehicles:
        state = _Counters()
        for day_index, date in enumerate(fleet.srf_dates):
            trips = truth[veh.vehicle_id][day_index]
            data, recs, info = _srf_file(world, veh, trips, date, state, fleet, seed, transformer)
            gz = (veh.vehicle_id, day_index) in fleet.gzip_files
            path = _write(outdir / "srf" / f"{veh.vehicle_id}_{date}.csv", data, gz)
            rel = path.relative_to(outdir).as_posix()
            info = {"path": rel, "sha256": hashlib.sha256(path.read_bytes()).hexdigest(), "bytes": path.stat().st_size, **info}
            for r in recs:
                r["file"] = rel
            files.append(info)
            records.extend(recs)
    return files, records


def _vehicles_json(vehicles: Sequence[VehicleSpec]) -> dict:
    return {v.vehicle_id: {k: (round(x, 3) if isinstance(x, float) else x) for k, x in sorted(dataclasses.asdict(v).items()) if k != "vehicle_id"} for v in vehicles}


def _dump_json(obj, path: Path) -> None:
    path.write_text(json.dumps(obj, indent=1, sort_keys=True, ensure_ascii=False) + "\n", encoding="utf-8")


def generate_sample_logs(outdir: str | Path, consumption_fn: ConsumptionFn = standin_consumption, *, seed: int = DEFAULT_SEED, small: bool = False, fleet: FleetSpec | None = None, write_dsm: bool = True) -> dict:
    """Generate the sample logs, DSM tiles and ``truth.json`` into ``outdir``.

    ``small=True`` uses :data:`SMALL_FLEET` (a few minutes of driving, four 5 m tiles:
    well under a second); ``fleet`` overrides both. Returns the truth dictionary written
    to ``outdir/truth.json``. Same arguments -> same bytes.
    """
    outdir = Path(outdir)
    fleet = fleet if fleet is not None else (SMALL_FLEET if small else SAMPLE_FLEET)
    world, truth = simulate_fleet(fleet, consumption_fn, seed)
    files, records = _write_srf(outdir, world, fleet, truth, seed)
    if fleet.portal_vehicles:
        data, precs, pinfo = _portal_file(world, fleet, truth, seed, _transformer())
        dates = sorted({d for ds in fleet.portal_dates.values() for d in ds})
        # the night duty's first trip starts the evening before its first date
        first = min(datetime.fromtimestamp(r["start_utc_s"], timezone.utc).date().isoformat() for r in precs)
        path = _write(outdir / "portal" / f"portal_export_{first}_{dates[-1]}.csv", data, False)
        rel = path.relative_to(outdir).as_posix()
        for r in precs:
            r["file"] = rel
        files.append({"path": rel, "sha256": hashlib.sha256(data).hexdigest(), "bytes": len(data), **pinfo})
        records.extend(precs)
    _finish_records(records)
    tiles = []
    if write_dsm:
        tiles = [p.relative_to(outdir).as_posix() for p in write_dsm_tiles(world, outdir / "dsm")]
    doc = {
        "generator": "cevm_samplegen",
        "format_version": 1,
        "seed": seed,
        "small": bool(small),
        "consumption_fn": _qualname(consumption_fn),
        "consumption_units": {"electric-bus": "J at the battery, net of regeneration", "diesel-hgv": "l of diesel"},
        "notes": "Times are the true UTC of the first and last logged tick of each trip; distance and consumption are the truth between them.",
        "vehicles": _vehicles_json(fleet.srf_vehicles + fleet.portal_vehicles),
        "files": files,
        "trips": records,
        "routes": {name: route_dsm_summary(world, r) for name, r in sorted(world.routes.items())},
        "dsm": {
            "crs": BNG, "tile_m": fleet.dsm.tile_m, "resolution_m": fleet.dsm.resolution_m, "quantum_m": fleet.dsm.quantum_m,
            "nodata": fleet.dsm.nodata, "survey_box": list(fleet.dsm.survey_box),
            "omitted_tiles": [os_tile_name(*c) for c in fleet.dsm.omitted_cells], "tiles": tiles,
            "geoid_undulation_m": GEOID_UNDULATION_M,
        },
    }
    outdir.mkdir(parents=True, exist_ok=True)
    _dump_json(doc, outdir / "truth.json")
    return doc


_BENCH_TEMPLATES = (
    ("electric-bus", "bus", "bus-1"),
    ("electric-bus", "bus", "bus-2"),
    ("diesel-hgv", "regional", "regional"),
    ("diesel-hgv", "longhaul", "trunk"),
)


def fleet_for_benchmark(n_vehicles: int, n_days: int, outdir: str | Path, *, seed: int = DEFAULT_SEED, consumption_fn: ConsumptionFn = standin_consumption, first_date: str = "2019-05-13", dsm_dir: str | Path | None = None, full_days: bool = False) -> dict:
    """A larger srf fleet for the ingest benchmark: ``n_vehicles`` (cycling through two
    buses, a regional and a long-haul truck, ids ``BM-001``...) x ``n_days`` consecutive
    days from ``first_date``, on the same routes as the sample logs (so the sample's DSM
    tiles cover them; pass ``dsm_dir`` to write the tiles too). A vehicle-day has the
    sample fleet's 2-3 trips (~1.4 h of driving, ~5,000 samples), or with
    ``full_days`` a working day of 6-12 trips (4-6 h, 15,000-22,000 samples). Writes
    ``outdir/srf/*.csv`` and ``outdir/truth.json``; returns the truth dictionary (with
    ``rows`` and ``bytes`` totals)."""
    outdir = Path(outdir)
    vehicles = []
    for i in range(n_vehicles):
        vt, duty, route = _BENCH_TEMPLATES[i % len(_BENCH_TEMPLATES)]
        if full_days:
            duty = f"{duty}-day"
        vid = f"BM-{i + 1:03d}"
        vehicles.append(VehicleSpec(vid, vt, duty, route, _BUS_KERB if vt == "electric-bus" else _HGV_KERB,
                                    flowmeter=(i % 8 == 2), fuel_counter_start_l=1000.0 * (i + 1), energy_counter_start_kwh=500.0 * (i + 1)))
    d0 = datetime.fromisoformat(first_date)
    dates = tuple((d0.fromordinal(d0.toordinal() + k)).date().isoformat() for k in range(n_days))
    fleet = FleetSpec(tuple(vehicles), dates, (), {})
    world, truth = simulate_fleet(fleet, consumption_fn, seed, world=build_world(seed, SAMPLE_FLEET.dsm))
    files, records = _write_srf(outdir, world, fleet, truth, seed)
    _finish_records(records)
    tiles = []
    if dsm_dir is not None:
        tiles = [p.as_posix() for p in write_dsm_tiles(world, Path(dsm_dir))]
    doc = {
        "generator": "cevm_samplegen.fleet_for_benchmark", "format_version": 1, "seed": seed,
        "consumption_fn": _qualname(consumption_fn), "vehicles": _vehicles_json(fleet.srf_vehicles),
        "files": files, "trips": records, "rows": int(sum(f["rows"] for f in files)),
        "bytes": int(sum(f["bytes"] for f in files)), "dsm_tiles": tiles,
    }
    _dump_json(doc, outdir / "truth.json")
    return doc


def _load_fn(spec: str) -> ConsumptionFn:
    mod, _, name = spec.partition(":")
    if not name:
        raise SystemExit(f"--consumption expects MODULE:FUNCTION, got {spec!r}")
    fn = importlib.import_module(mod)
    for part in name.split("."):
        fn = getattr(fn, part)
    return fn  # type: ignore[return-value]


def main(argv: list[str] | None = None) -> int:
    """``python -m cevm_samplegen OUTDIR [--small] [--seed N] [--consumption MODULE:FUNC]
    [--benchmark N_VEHICLES N_DAYS]``."""
    import argparse

    ap = argparse.ArgumentParser(prog="python -m cevm_samplegen", description="Generate synthetic logger exports, DSM tiles and truth.json.")
    ap.add_argument("outdir", type=Path)
    ap.add_argument("--small", action="store_true", help="tiny fleet for tests (well under a second)")
    ap.add_argument("--seed", type=int, default=DEFAULT_SEED)
    ap.add_argument("--consumption", default="cevm_samplegen:standin_consumption", help="MODULE:FUNCTION giving the measured consumption (default: the stand-in)")
    ap.add_argument("--benchmark", nargs=2, type=int, metavar=("N_VEHICLES", "N_DAYS"), help="write a benchmark srf fleet instead")
    a = ap.parse_args(argv)
    fn = _load_fn(a.consumption)
    if a.benchmark:
        doc = fleet_for_benchmark(a.benchmark[0], a.benchmark[1], a.outdir, seed=a.seed, consumption_fn=fn)
        print(f"{len(doc['files'])} files, {doc['rows']} rows, {doc['bytes']} bytes in {a.outdir}")
        return 0
    doc = generate_sample_logs(a.outdir, fn, seed=a.seed, small=a.small)
    print(f"{len(doc['files'])} log files, {len(doc['trips'])} trips, {len(doc['dsm']['tiles'])} DSM tiles in {a.outdir}")
    return 0

