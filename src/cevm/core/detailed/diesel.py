"""The diesel powertrain of the detailed model: gearbox and shift rule, full-load
curve and the Willans-line fuel model."""

from __future__ import annotations

import numpy as np

from cevm.core.cycle import PAPER_PHYSICS, Physics
from cevm.core.detailed.params import DieselParams
from cevm.core.detailed.results import SimulationResult, make_result
from cevm.core.detailed.road import road_loads, step_mean

_GEAR_CHUNK = 2048


def _choose_gears(p: DieselParams, ratios, eta_gears, inertia_coef, w_wheel, power, k_per_dt, w_req, aux_w):
    """Gear choice for a chunk of steps, all gears at once.

    Returns (gear index, any gear satisfies the shift rule, any gear engageable): the
    index is the highest gear meeting the rule, or else the one with the most power
    among the gears the engine can turn at.
    """
    w_e = np.multiply.outer(ratios, w_wheel)  # (G, m) engine speed [rad/s]
    p_eng = np.multiply.outer(1.0 / eta_gears, np.maximum(power, 0.0))
    p_eng += np.multiply.outer(eta_gears, np.minimum(power, 0.0))
    p_eng += np.multiply.outer(inertia_coef, k_per_dt)
    p_eng += aux_w
    p_avail = p.full_load_torque(w_e)
    p_avail *= w_e
    below_max = w_e <= p.max_speed_rad_s
    ok = below_max & (w_e >= w_req) & (p_eng <= p_avail)
    any_ok = ok.any(axis=0)
    highest_ok = ok.shape[0] - 1 - np.argmax(ok[::-1], axis=0)
    engageable = below_max & (w_e >= p.idle_speed_rad_s)
    p_avail[~engageable] = -1.0
    best_power = np.argmax(p_avail, axis=0)
    return np.where(any_ok, highest_ok, best_power), any_ok, engageable.any(axis=0)


def simulate_diesel(params: DieselParams, time_s, speed_mps, elevation_m, *, mass_kg: float, cda_m2: float,
                    cr: float, fuel_lhv_j_per_l: float, physics: Physics = PAPER_PHYSICS, aux_power_w=None,
                    friction_scale=None) -> SimulationResult:
    """Backward simulation of a diesel vehicle (see the module docstring).

    Parameters
    ----------
    params : powertrain parameters
    time_s, speed_mps, elevation_m : (N,) trace [s], [m/s], [m] (elevation None = flat)
    mass_kg, cda_m2, cr : road-load parameters (eq. 1-4)
    fuel_lhv_j_per_l : fuel lower heating value [J/l]
    aux_power_w : (N,) mechanical auxiliary power at the engine beyond the parameters' [W]
        per sample (an air-conditioning compressor, say); a step takes the mean of its
        two samples. None: none.
    friction_scale : (N,) factor on the engine friction per sample (> 1 while a cold
        engine warms up), the step's the mean of its two samples. None: 1.
    """
    t = np.asarray(time_s, dtype=np.float64)
    p = params
    road = road_loads(t, speed_mps, elevation_m, mass_kg, cda_m2, cr, p.rotating_mass_kg(), physics)
    n = road.dt.size
    aux = p.aux_power_w if aux_power_w is None else p.aux_power_w + step_mean(aux_power_w)
    fscale = 1.0 if friction_scale is None else step_mean(friction_scale)
    r = p.wheel_radius_m
    ratios = np.asarray(p.gear_ratios, dtype=np.float64) * p.axle_ratio  # (G,) engine/wheel
    eta_gears = p.gear_efficiency_array()  # (G,)
    w_wheel = road.v / r
    rated = p.rated_power_w()
    demand = np.clip(road.power / (eta_gears[-1] * rated), 0.0, 1.0)
    w_req = p.shift_low_speed_rad_s + (p.shift_high_speed_rad_s - p.shift_low_speed_rad_s) * demand  # (n,)
    inertia_coef = p.engine_inertia_kgm2 * (ratios / r) ** 2  # (G,) [kg]
    gear_idx = np.empty(n, dtype=np.intp)
    any_ok = np.empty(n, dtype=bool)
    any_engageable = np.empty(n, dtype=bool)
    # All gears at once, (G, chunk) arrays; chunks keep the temporaries in cache.
    for lo in range(0, n, _GEAR_CHUNK):
        sl = slice(lo, min(n, lo + _GEAR_CHUNK))
        gear_idx[sl], any_ok[sl], any_engageable[sl] = _choose_gears(
            p, ratios, eta_gears, inertia_coef, w_wheel[sl], road.power[sl], road.k_per_dt[sl], w_req[sl],
            aux[sl] if isinstance(aux, np.ndarray) and aux.ndim else aux,
        )
    # No gear at the preferred speeds with enough torque. Driving slower than first gear
    # turns at the preferred speed: launch, clutch slipping, engine at that speed.
    # Otherwise the gear with the most power among those the engine can turn at (trace
    # missed, deficit reported). Not driving: clutch open, engine idling.
    driving = road.moving & (road.power > 0)
    slipping = driving & ~any_ok & (ratios[0] * w_wheel < w_req)
    fallback = driving & ~any_ok & ~slipping & any_engageable
    engaged = road.moving & (any_ok | fallback)
    gi = np.where(engaged, gear_idx, 0)
    eta_sel = eta_gears[gi]
    w_eng = ratios[gi] * w_wheel
    p_inertia_sel = np.where(engaged, inertia_coef[gi] * road.k_per_dt, 0.0)
    pe = np.where(road.power > 0, road.power / eta_sel, road.power * eta_sel) + p_inertia_sel + aux
    # Clutch slipping: the clutch passes the torque the wheels need.
    w_slip = np.maximum(w_req, p.idle_speed_rad_s)
    t_slip = road.force * r / (ratios[0] * eta_gears[0]) + aux / w_slip
    w_eng = np.where(slipping, w_slip, w_eng)
    pe = np.where(slipping, t_slip * w_slip, pe)
    idle = ~(engaged | slipping)
    w_eng = np.where(idle, p.idle_speed_rad_s, w_eng)
    pe = np.where(idle, aux, pe)
    avail = p.full_load_torque(w_eng) * w_eng
    pe_act = np.minimum(pe, avail)
    # Wheel power delivered while driving: engaged, through the gear (engine inertia and
    # auxiliaries served first); slipping, the clutch torque at the wheels' speed.
    delivered = np.where(
        slipping,
        (pe_act - aux) / w_eng * (ratios[0] * eta_gears[0]) * w_wheel,
        np.where(engaged, (pe_act - aux - p_inertia_sel) * eta_sel, 0.0),
    )
    deficit = np.where(driving, np.maximum(road.power - delivered, 0.0), 0.0)
    torque = pe_act / w_eng
    fuel_power = p.fuel_power_w(w_eng, pe_act, fscale)
    fuel_rate = fuel_power / fuel_lhv_j_per_l
    # Braking: what neither the engine's friction (fuel cut) nor the driveline takes.
    fric = p.friction_power_w(w_eng) * fscale
    brake_engaged = np.maximum(-(pe_act + fric), 0.0) / eta_sel
    brake = np.where(road.power < 0, np.where(idle, -road.power, np.minimum(brake_engaged, -road.power)), 0.0)
    gear = np.where(engaged | slipping, gi + 1, 0)
    fuel_cum = np.concatenate([[0.0], np.cumsum(fuel_rate * road.dt)])
    steps = {
        "dt_s": road.dt,
        "speed_mean_mps": road.v,
        "accel_mps2": road.accel,
        "wheel_force_n": road.force,
        "wheel_power_w": road.power,
        "gear": gear,
        "engine_speed_rad_s": w_eng,
        "engine_torque_nm": torque,
        "engine_power_w": pe_act,
        "fuel_power_w": fuel_power,
        "fuel_rate_lps": fuel_rate,
        "friction_brake_power_w": brake,
        "traction_deficit_w": deficit,
    }
    return make_result("ice", mass_kg, t, speed_mps, elevation_m, steps, {"fuel_cum_l": fuel_cum},
                   fuel_l=float(fuel_cum[-1]))
