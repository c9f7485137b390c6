"""What a trip consumes: the STAND-IN formula and the detailed model as a logger measures it.

The interface of a consumption function (``--consumption MODULE:FUNC``)::

    consumption_fn(kind, time_s, speed_mps, elevation_m, mass_kg, *, conditions)
        -> Consumption | cumulative array

``kind`` is the vehicle type, the stem of a ``configs/vehicles`` file: ``"electric-bus"``
(joules at the battery, net of regeneration) or ``"diesel-hgv"`` (litres of diesel).
Arrays are the 1 Hz truth samples of one trip (time from 0 s), ``mass_kg`` the trip's
constant gross mass, ``conditions`` a :class:`TripConditions` (the air temperature and
sunshine along the trip, how long the vehicle stood before it, the people on board).
The result has one value per sample, starting at 0; a :class:`Consumption` adds the
parts of it that ``truth.json`` records (heating and A/C energy, warm-up, cold start).

Both functions here take the weather's loads from :mod:`cevm_samplegen.auxiliaries`
(the cabin's HVAC, a diesel's cold start), so the stand-in and the detailed model see
the same heating, A/C and warm-up; neither is the CE model.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from cevm.units import J_PER_KWH
from cevm_samplegen.auxiliaries import BUS_CABIN, DIESEL_WARMUP, TRUCK_CAB, CabinLoad, cabin_load
from cevm_samplegen.common import G_MPS2, RHO_AIR_KG_M3


@dataclass(frozen=True)
class StandInParams:
    """Parameters of the stand-in consumption formula and of the plausible FMS signals.

    Body: ``cda_m2``, ``cr`` (rolling, plus ``cr_speed_per_mps`` x v), ``rot_factor``
    (rotating-mass factor on the kinetic term), ``wheel_radius_m``. Electric:
    ``drive_eff`` (battery -> wheel, marginal), ``drive_loss_w`` (constant loss while
    driving), ``regen_eff`` (wheel -> battery), ``regen_max_w`` (regenerative braking
    limit at the wheel; friction brakes do the rest), ``aux_w`` (air compressor,
    steering, 24 V: always on; heating and A/C come from the cabin model). Diesel:
    ``idle_fuel_w`` (fuel power at idle, about 2.5 l/h for a 13 l engine), ``marginal_eff``
    (Willans slope: wheel power per fuel power above idle, transmission included),
    ``fuel_lhv_j_per_l`` (EN 590 diesel), ``aux_w`` (alternator, compressor).
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
        aux_w=4000.0, drive_eff=0.86, drive_loss_w=2500.0, regen_eff=0.62, regen_max_w=90e3,
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

#: What a vehicle type's consumption is measured in (cevm.core.trip.MeasurementKind).
MEASUREMENT_KIND = {"electric-bus": "energy_j", "diesel-hgv": "fuel_l"}


def wheel_power_w(p: StandInParams, dt_s, v0, v1, dh_m, mass_kg) -> np.ndarray:
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


@dataclass(frozen=True, eq=False)
class TripConditions:
    """What a trip's consumption depends on besides its trace and mass.

    ``ambient_c`` (N,) air temperature [degC] and ``solar_w_m2`` (N,) global horizontal
    irradiance [W/m^2] at the trip's samples; ``soak_s`` how long the vehicle stood with
    the ignition off before the trip [s] (a layover, or the night); ``occupants`` the
    people on board, driver included.
    """

    ambient_c: np.ndarray
    solar_w_m2: np.ndarray
    soak_s: float
    occupants: float

    def __post_init__(self) -> None:
        a, s = np.asarray(self.ambient_c), np.asarray(self.solar_w_m2)
        if a.ndim != 1 or a.shape != s.shape or not (np.all(np.isfinite(a)) and np.all(np.isfinite(s))):
            raise ValueError("TripConditions: ambient_c and solar_w_m2 must be finite arrays of one shape (N,)")
        if not (self.soak_s >= 0.0 and self.occupants >= 0.0):
            raise ValueError("TripConditions: soak_s and occupants must be >= 0")


@dataclass(frozen=True, eq=False)
class Consumption:
    """A consumption function's result: the cumulative consumption per sample (J or l,
    from 0) and named parts of it or facts about the trip for ``truth.json`` (floats)."""

    cumulative: np.ndarray
    parts: Mapping[str, float] = field(default_factory=dict)


#: Electric power from the engine through belt and alternator: mechanical power per
#: electric power is 1 / 0.55 (alternators reach 0.6-0.7 at best, less at part load).
ALTERNATOR_EFFICIENCY = 0.55
#: Cabins of the vehicle types (:mod:`cevm_samplegen.auxiliaries`).
CABINS = {"electric-bus": BUS_CABIN, "diesel-hgv": TRUCK_CAB}


def _check_kind(kind: str, trace_n: int, conditions: TripConditions) -> None:
    if kind not in STANDIN:
        raise ValueError(f"unknown vehicle type {kind!r} (known: {', '.join(sorted(STANDIN))})")
    if np.shape(conditions.ambient_c) != (trace_n,):
        raise ValueError(f"conditions have {np.size(conditions.ambient_c)} samples, the trace {trace_n}")


def _cabin(kind: str, t, v, conditions: TripConditions) -> CabinLoad:
    return cabin_load(CABINS[kind], t, v, conditions.ambient_c, conditions.solar_w_m2,
                      occupants=conditions.occupants, soak_s=conditions.soak_s)


def _trapz(x, t) -> float:
    x = np.asarray(x, dtype=np.float64)
    return float(np.sum(0.5 * (x[1:] + x[:-1]) * np.diff(t)))


def _step(x) -> np.ndarray:
    return 0.5 * (x[1:] + x[:-1])


def cab_mechanical_w(cab: CabinLoad) -> np.ndarray:
    """A truck cab's HVAC as mechanical power at the engine [W] per sample: the belt
    compressor plus the electric fans through the alternator."""
    return cab.compressor_w + cab.electric_w / ALTERNATOR_EFFICIENCY


def _bus_parts(cab: CabinLoad, t) -> dict[str, float]:
    return {"hvac_energy_j": _trapz(cab.electric_w, t), "warmup_energy_j": _trapz(cab.warmup_electric_w, t),
            "cabin_start_c": cab.start_c}


def standin_consumption(kind: str, time_s, speed_mps, elevation_m, mass_kg: float, *,
                        conditions: TripConditions) -> Consumption:
    """STAND-IN consumption for tests and trial runs: cumulative per sample, from 0.

    Per step, wheel power P_w [W] from longitudinal dynamics (:func:`wheel_power_w`).
    ``"electric-bus"`` -> joules at the battery: P_b = P_w / drive_eff + drive_loss_w when
    P_w > 0, else max(P_w, -regen_max_w) * regen_eff; plus aux_w and the cabin's HVAC.
    So the efficiency varies with load (low at light load) and regeneration is partial.
    ``"diesel-hgv"`` -> litres: fuel power = idle_fuel_w + P_e / marginal_eff when
    P_e = P_w + aux_w + cab HVAC (mechanical) > 0 (a Willans line), 0 on overrun above
    2 m/s (fuel cut-off), idle otherwise; a cold engine adds (s - 1) idle_fuel_w while
    fuel is injected, s the friction scale of :data:`~cevm_samplegen.auxiliaries.DIESEL_WARMUP`.
    Parameters: :data:`STANDIN`. This is deliberately not the CE model.
    """
    t = np.asarray(time_s, dtype=float)
    v = np.asarray(speed_mps, dtype=float)
    h = np.asarray(elevation_m, dtype=float)
    _check_kind(kind, t.size, conditions)
    p = STANDIN[kind]
    dt = np.diff(t)
    pw = wheel_power_w(p, dt, v[:-1], v[1:], np.diff(h), float(mass_kg))
    cab = _cabin(kind, t, v, conditions)
    if kind == "electric-bus":
        pb = np.where(pw > 0, pw / p.drive_eff + p.drive_loss_w, np.maximum(pw, -p.regen_max_w) * p.regen_eff)
        step = (pb + p.aux_w + _step(cab.electric_w)) * dt
        return Consumption(np.concatenate(([0.0], np.cumsum(step))), _bus_parts(cab, t))
    vm = 0.5 * (v[:-1] + v[1:])

    def fuel_w(extra_aux_w):
        pe = pw + p.aux_w + extra_aux_w
        return np.where(pe > 0, p.idle_fuel_w + pe / p.marginal_eff, np.where(vm > 2.0, 0.0, p.idle_fuel_w))

    hot = fuel_w(_step(cab_mechanical_w(cab)))
    warm = DIESEL_WARMUP
    engine0 = warm.start_c(float(conditions.ambient_c[0]), conditions.soak_s)
    engine = warm.temperature_c(t, hot, engine0, cab.heating_w)
    cold_extra = np.where(hot > 0, (_step(warm.friction_scale(engine)) - 1.0) * p.idle_fuel_w, 0.0)
    step = (hot + cold_extra) * dt / p.fuel_lhv_j_per_l
    parts = {"hvac_fuel_l": float(np.sum((hot - fuel_w(0.0)) * dt) / p.fuel_lhv_j_per_l),
             "cold_start_fuel_l": float(np.sum(cold_extra * dt) / p.fuel_lhv_j_per_l),
             "engine_start_c": engine0, "cabin_start_c": cab.start_c}
    return Consumption(np.concatenate(([0.0], np.cumsum(step))), parts)


#: Deficits above this share of the wheel work are reported by
#: :func:`logged_consumption`: the trace asks more than the vehicle can do.
MAX_DEFICIT_SHARE = 0.02


@lru_cache(maxsize=8)
def _project_vehicle(kind: str):
    from cevm.configs_dir import shipped_configs_dir
    from cevm.io import load_vehicle

    path = shipped_configs_dir() / "vehicles" / f"{kind}.toml"
    return load_vehicle(path)


def logged_consumption(kind: str, time_s, speed_mps, elevation_m, mass_kg: float, *,
                       conditions: TripConditions) -> Consumption:
    """Cumulative consumption per sample, as a logger would measure it: the detailed
    model (:func:`cevm.core.detailed.simulate`) of the project's vehicle
    ``configs/vehicles/<kind>.toml`` over a true trace, with the weather's loads.

    Joules at the battery (EV, net of regeneration, auxiliaries included) or litres of
    fuel (diesel), from 0 at the first sample. The EV's heating, ventilation and A/C
    (:data:`~cevm_samplegen.auxiliaries.BUS_CABIN`) draw from the battery beside the
    vehicle file's base auxiliaries (``aux_power_w``); the truck's cab HVAC
    (:data:`~cevm_samplegen.auxiliaries.TRUCK_CAB`) loads the engine, and a cold engine's
    friction (:data:`~cevm_samplegen.auxiliaries.DIESEL_WARMUP`, ``friction_scale``) is
    taken from its temperature, warmed by the hot engine's fuel power along the same
    trace. The parts (HVAC energy or fuel, warm-up energy, cold-start fuel) are the
    differences between runs with and without each load. The consumption function of
    the shipped sample logs (``--consumption cevm_samplegen:logged_consumption``).

    Raises ValueError if the vehicle could not follow the trace (traction deficit above
    :data:`MAX_DEFICIT_SHARE` of the wheel work). It lives here, not in the detailed
    model's module, because it reads the project's vehicle files.
    """
    from cevm.core.detailed import simulate
    from cevm.io.detailed import detailed_params

    t = np.asarray(time_s, dtype=float)
    _check_kind(kind, t.size, conditions)
    vehicle = _project_vehicle(kind)
    params = detailed_params(vehicle)
    cab = _cabin(kind, t, speed_mps, conditions)

    def run(**series):
        return simulate(vehicle, t, speed_mps, elevation_m, mass_kg=mass_kg, time_step_s=None, params=params,
                        **series)

    if vehicle.is_ev:
        res = run(aux_power_w=cab.electric_w)
        parts = _bus_parts(cab, t)
    else:
        mech = cab_mechanical_w(cab)
        base = run()
        res = run(aux_power_w=mech)
        hot_fuel_l = res.fuel_l
        warm = DIESEL_WARMUP
        engine0 = warm.start_c(float(conditions.ambient_c[0]), conditions.soak_s)
        if engine0 < warm.hot_c - 0.01:
            engine = warm.temperature_c(t, res.steps["fuel_power_w"], engine0, cab.heating_w)
            res = run(aux_power_w=mech, friction_scale=warm.friction_scale(engine))
        parts = {"hvac_fuel_l": hot_fuel_l - base.fuel_l, "cold_start_fuel_l": res.fuel_l - hot_fuel_l,
                 "engine_start_c": engine0, "cabin_start_c": cab.start_c}
    positive = float(np.sum(np.maximum(res.steps["wheel_power_w"] * res.steps["dt_s"], 0.0)))
    if res.traction_deficit_j > MAX_DEFICIT_SHARE * max(positive, 1.0):
        raise ValueError(
            f"{kind} at {mass_kg:.0f} kg cannot follow the trace: {res.traction_deficit_j / J_PER_KWH:.2f} kWh "
            f"beyond its powertrain ({100 * res.traction_deficit_j / positive:.1f} % of the wheel work)"
        )
    key = "energy_cum_j" if vehicle.is_ev else "fuel_cum_l"
    return Consumption(np.asarray(res.samples[key], dtype=np.float64), parts)
