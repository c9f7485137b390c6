"""The electric powertrain of the detailed model: motor map, regeneration limits and
the battery (open-circuit voltage, internal resistance, coulomb counting)."""

from __future__ import annotations

import numpy as np

from cevm.core.cycle import PAPER_PHYSICS, Physics
from cevm.core.detailed.params import EvParams
from cevm.core.detailed.results import SimulationResult, make_result
from cevm.core.detailed.road import road_loads, step_mean


def battery_current_a(power_w, ocv_v, resistance_ohm) -> np.ndarray:
    """Battery current [A] (+ = discharge) delivering terminal power ``power_w`` [W]:
    the smaller root of P = V_oc I - R I^2, written I = 2P / (V_oc + sqrt(V_oc^2 - 4RP))
    so that R = 0 and charging (P < 0) need no special case. Power beyond the pack's
    maximum V_oc^2 / 4R is capped there (I = V_oc / 2R)."""
    p = np.asarray(power_w, dtype=np.float64)
    v = np.asarray(ocv_v, dtype=np.float64)
    disc = np.maximum(v * v - 4.0 * resistance_ohm * p, 0.0)
    p_capped = np.minimum(p, v * v / (4.0 * resistance_ohm)) if resistance_ohm > 0 else p
    return 2.0 * p_capped / (v + np.sqrt(disc))


def integrate_soc(power_w, dt_s, params: EvParams, capacity_c: float, soc_start: float,
                  max_passes: int = 50, tol: float = 1e-12):
    """SoC per sample [0..1], current [A] and V_oc [V] per step for terminal power
    ``power_w`` [W] over steps ``dt_s`` [s] and a capacity of ``capacity_c`` [C].

    Coulomb counting SoC_{i+1} = SoC_i - I_i dt_i / Q with I_i from V_oc(SoC_i): solved
    by fixed-point passes (V_oc at the previous pass's SoC, one cumulative sum per pass)
    until the SoC changes by less than ``tol``, at most ``max_passes`` passes.
    """
    n = power_w.size
    soc = np.full(n + 1, float(soc_start))
    r = params.internal_resistance_ohm
    for _ in range(max_passes):
        ocv = params.pack_ocv_v(soc[:-1])
        current = battery_current_a(power_w, ocv, r)
        new = np.empty(n + 1)
        new[0] = soc_start
        np.cumsum(current * dt_s, out=new[1:])
        new[1:] = soc_start - new[1:] / capacity_c
        done = np.max(np.abs(new - soc)) < tol
        soc = new
        if done:
            break
    return soc, current, ocv


def simulate_ev(params: EvParams, time_s, speed_mps, elevation_m, *, mass_kg: float, cda_m2: float,
                cr: float, battery_j: float, soc_start: float = 1.0,
                physics: Physics = PAPER_PHYSICS, aux_power_w=None) -> SimulationResult:
    """Backward simulation of an electric vehicle (see the module docstring).

    Parameters
    ----------
    params : powertrain parameters
    time_s, speed_mps, elevation_m : (N,) trace [s], [m/s], [m] (elevation None = flat)
    mass_kg, cda_m2, cr : road-load parameters (eq. 1-4)
    battery_j : usable battery capacity [J]; SoC 1 -> 0 spans it
    soc_start : state of charge at the first sample [0..1]
    aux_power_w : (N,) auxiliary power beyond the parameters' [W] per sample (heating and
        air conditioning that follow the weather, say), from the battery; a step draws
        the mean of its two samples. None: none.
    """
    t = np.asarray(time_s, dtype=np.float64)
    road = road_loads(t, speed_mps, elevation_m, mass_kg, cda_m2, cr, params.rotating_mass_kg(), physics)
    p = params
    ratio = p.total_ratio
    r = p.wheel_radius_m
    eta = p.transmission_efficiency
    w_m = road.v * (ratio / r)
    t_wheel = road.force * r
    t_dem = np.where(t_wheel > 0, t_wheel / (ratio * eta), t_wheel * (eta / ratio))
    w_safe = np.where(w_m > 0, w_m, 1.0)
    t_drive_max = np.minimum(p.motor_peak_torque_nm, p.motor_peak_power_w / w_safe)
    t_drive_max = np.where(w_m > p.motor_max_speed_rad_s, 0.0, t_drive_max)  # over-speed: no drive
    t_regen_peak = p.motor_peak_torque_nm if p.regen_max_torque_nm is None else p.regen_max_torque_nm
    span = p.regen_fade_high_mps - p.regen_fade_low_mps
    if span > 0:
        fade = np.clip((road.v - p.regen_fade_low_mps) / span, 0.0, 1.0)
    else:
        fade = (road.v >= p.regen_fade_low_mps).astype(np.float64)
    t_regen_max = np.minimum(t_regen_peak, p.regen_max_power_w / w_safe) * fade
    torque = np.clip(t_dem, -t_regen_max, t_drive_max)
    torque = np.where(road.moving, torque, 0.0)
    p_mech = torque * w_m
    loss = np.where(torque != 0.0, p.motor_loss_w(torque, w_m), 0.0)
    p_el = p_mech + loss
    unprofitable = (torque < 0) & (p_el > 0)
    if unprofitable.any():
        torque = np.where(unprofitable, 0.0, torque)
        p_mech = np.where(unprofitable, 0.0, p_mech)
        loss = np.where(unprofitable, 0.0, loss)
        p_el = np.where(unprofitable, 0.0, p_el)
    # Wheel-side power the motor takes or gives, the brakes' share and the shortfall.
    p_wheel_motor = np.where(p_mech > 0, p_mech * eta, p_mech / eta)
    brake = np.where(road.power < 0, np.maximum(p_wheel_motor - road.power, 0.0), 0.0)
    deficit = np.where(road.power > 0, np.maximum(road.power - p_wheel_motor, 0.0), 0.0)
    aux = np.full(road.dt.size, p.aux_base_power_w + p.hvac_power_w)
    if aux_power_w is not None:
        aux += step_mean(aux_power_w)
    p_batt = p_el + aux
    capacity_c = battery_j / p.mean_pack_ocv_v()
    soc, current, ocv = integrate_soc(p_batt, road.dt, p, capacity_c, soc_start)
    e_step = p_batt * road.dt
    e_cum = np.concatenate([[0.0], np.cumsum(e_step)])
    steps = {
        "dt_s": road.dt,
        "speed_mean_mps": road.v,
        "accel_mps2": road.accel,
        "wheel_force_n": road.force,
        "wheel_power_w": road.power,
        "motor_speed_rad_s": w_m,
        "motor_torque_nm": torque,
        "motor_power_w": p_mech,
        "motor_loss_w": loss,
        "motor_electric_power_w": p_el,
        "aux_power_w": aux,
        "battery_power_w": p_batt,
        "battery_ocv_v": ocv,
        "battery_current_a": current,
        "friction_brake_power_w": brake,
        "traction_deficit_w": deficit,
    }
    return make_result("ev", mass_kg, t, speed_mps, elevation_m, steps, {"soc": soc, "energy_cum_j": e_cum},
                   energy_j=float(e_cum[-1]))
