"""What a trip consumes: the STAND-IN formula and the detailed model as a logger measures it."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from cevm_samplegen.common import G_MPS2, RHO_AIR_KG_M3



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

