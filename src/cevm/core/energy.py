"""What the battery or the tank gives for a trip: the CE model's terms beyond the wheel (pure).

The wheel energy of a trip comes from its drive-cycle vector (:mod:`cevm.core.model`,
the paper's eq. 22-30). Real vehicles also draw energy that the wheels never see, and
turn wheel energy into battery or fuel energy with an efficiency that depends on how the
vehicle is driven. Every term here is a per-trip sum computed once from the trip (its
vector's scalars) or a plain function of inputs known before a trip (mass, ambient
temperature), so predictions stay exact and take microseconds.

Electric vehicle, battery energy [J]::

    E = W(eta eta_r) / eta  +  D P_aux(T)  +  e_warm h(T)
      = P / eta  +  eta_r N  +  D P_aux(T)  +  e_warm h(T)

    P_aux(T) = p0 + p_heat h(T) + p_cool c(T)                  [W]
    h(T) = max(0, T_heat - T),  c(T) = max(0, T - T_cool)      [K]

P >= 0 is the positive wheel energy (E_DC1 plus the positive non-simplified steps), N <= 0
the negative non-simplified steps (what regeneration can recover), W(w) = P + w N the
wheel energy with weight w on the negative steps (:func:`cevm.core.model.wheel_energy_j`),
D the trip's duration [s], T its ambient temperature [degC]. ``eta_r`` (``regen_eta``) is
the share of the negative wheel energy that reaches the battery; by default it is eta
itself (the paper's eq. 29-31: weight eta^2 at the wheel, divided by eta). p0 is the
auxiliary load that does not depend on the weather (12 V loads, pumps, compressors),
p_heat and p_cool the cabin heating and air conditioning per kelvin beyond their balance
temperatures, e_warm the energy of warming up at each trip start per kelvin of cold.

Diesel (ICE) vehicle, fuel [l]::

    L = W(w) / (U eta)  +  K (1 / eta_k - 1 / eta) / U
        +  r_run D_t  +  r_idle I  +  D (r_heat h(T) + r_cool c(T))  +  l_warm h(T)

w is 1 for the paper's eq. (24) (braking credited) and 0 for "no-credit", U the fuel's
lower heating value [J/l], I the time at standstill [s], K = m k_pos the positive kinetic
energy of the trip [J] (``CycleVector.k_pos``, summed over every step), ``eta_k``
(``kinetic_eta``) the efficiency of the fuel spent on it (default eta: no term; a truck
accelerating in low gears at part load differs from one cruising). r_run is the fuel
burnt while driving beyond the wheel work (engine friction and engine-driven auxiliaries:
the offset of a Willans line) over the traction time D_t (``CycleVector.traction_s``: the
simplified steps, which need positive wheel work; coasting and braking run with the fuel
cut off), r_idle the idle rate at standstill, r_heat and r_cool
temperature-dependent fuel rates (heater, A/C compressor), l_warm the fuel of a cold
start per kelvin. With all of them zero this is the paper's eq. (26).

All functions broadcast their array arguments (one prediction per element).
"""

from __future__ import annotations

import math

import numpy as np

#: Balance temperature below which cabin heating draws power [degC] (default of
#: ``heating_below_c``). A vehicle cabin kept at about 20 degC gains heat from its
#: occupants, electronics and the sun; heating demand of buses and cars starts around
#: 15-18 degC outside (the UK's heating degree-days use 15.5 degC).
HEATING_BELOW_C_DEFAULT = 16.0
#: Balance temperature above which air conditioning draws power [degC] (default of
#: ``cooling_above_c``; Eurostat's cooling degree-days use 21 degC, climate control is
#: typically set to 20-22 degC).
COOLING_ABOVE_C_DEFAULT = 22.0
#: Ambient temperature assumed for a prediction when none is given and the vehicle file
#: has no ``reference_temp_c`` [degC]; only terms that depend on temperature use it,
#: and the CLI says when it was assumed.
AMBIENT_DEFAULT_C = 20.0
#: Ambient temperatures accepted as input [degC]: the coldest and hottest air
#: temperatures measured on Earth, with a margin. A value outside is a unit mistake
#: (kelvin, Fahrenheit) or a broken sensor.
AMBIENT_RANGE_C = (-60.0, 60.0)


def heating_k(ambient_c, below_c: float = HEATING_BELOW_C_DEFAULT) -> np.ndarray:
    """Kelvin of heating demand, max(0, below_c - T) [K]."""
    return np.maximum(0.0, below_c - np.asarray(ambient_c, dtype=np.float64))


def cooling_k(ambient_c, above_c: float = COOLING_ABOVE_C_DEFAULT) -> np.ndarray:
    """Kelvin of cooling demand, max(0, T - above_c) [K]."""
    return np.maximum(0.0, np.asarray(ambient_c, dtype=np.float64) - above_c)


def check_ambient_c(ambient_c, what: str = "ambient temperature") -> np.ndarray:
    """``ambient_c`` as a float array, or ValueError when not finite or outside
    :data:`AMBIENT_RANGE_C` (a value in kelvin or Fahrenheit, a broken sensor)."""
    t = np.asarray(ambient_c, dtype=np.float64)
    lo, hi = AMBIENT_RANGE_C
    bad = ~np.isfinite(t) | (t < lo) | (t > hi)
    if np.any(bad):
        first = float(t[bad].flat[0]) if t.ndim else float(t)
        raise ValueError(f"{what} {first:g} degC is outside {lo:g}..{hi:g} degC (a value in kelvin or "
                         "degrees Fahrenheit?)")
    return t


def uses_temperature(vehicle) -> bool:
    """Whether any of the vehicle's terms depends on the ambient temperature."""
    if vehicle.is_ev:
        return bool(vehicle.aux_heating_w_per_k or vehicle.aux_cooling_w_per_k or vehicle.warmup_j_per_k)
    return bool(vehicle.heating_fuel_lps_per_k or vehicle.cooling_fuel_lps_per_k or vehicle.warmup_fuel_l_per_k)


def ev_negative_weight(vehicle) -> float:
    """Weight of the negative non-simplified steps in an EV's wheel energy: eta eta_r
    (eta^2 by default, the paper's eq. 29), so that W / eta = P / eta + eta_r N."""
    regen = vehicle.eta if vehicle.regen_eta is None else vehicle.regen_eta
    return float(vehicle.eta * regen)


def ev_aux_power_w(vehicle, ambient_c) -> np.ndarray:
    """The EV's auxiliary power from the battery at ``ambient_c`` [W]:
    p0 + p_heat h(T) + p_cool c(T)."""
    p = np.asarray(vehicle.aux_power_w, dtype=np.float64)
    if vehicle.aux_heating_w_per_k:
        p = p + vehicle.aux_heating_w_per_k * heating_k(ambient_c, vehicle.heating_below_c)
    if vehicle.aux_cooling_w_per_k:
        p = p + vehicle.aux_cooling_w_per_k * cooling_k(ambient_c, vehicle.cooling_above_c)
    return np.asarray(p + 0.0 * np.asarray(ambient_c, dtype=np.float64))


def ev_start_energy_j(vehicle, ambient_c) -> np.ndarray:
    """Energy of one trip start (warming up) at ``ambient_c`` [J]: e_warm h(T)."""
    if not vehicle.warmup_j_per_k:
        return np.zeros(np.shape(ambient_c))
    return vehicle.warmup_j_per_k * heating_k(ambient_c, vehicle.heating_below_c)


def ice_time_fuel_lps(vehicle, ambient_c) -> np.ndarray:
    """The temperature-dependent fuel rate of an ICE at ``ambient_c`` [l/s]:
    r_heat h(T) + r_cool c(T) (over the whole trip)."""
    r = np.zeros(np.shape(ambient_c))
    if vehicle.heating_fuel_lps_per_k:
        r = r + vehicle.heating_fuel_lps_per_k * heating_k(ambient_c, vehicle.heating_below_c)
    if vehicle.cooling_fuel_lps_per_k:
        r = r + vehicle.cooling_fuel_lps_per_k * cooling_k(ambient_c, vehicle.cooling_above_c)
    return r


def ice_start_fuel_l(vehicle, ambient_c) -> np.ndarray:
    """Fuel of one cold start at ``ambient_c`` [l]: l_warm h(T)."""
    if not vehicle.warmup_fuel_l_per_k:
        return np.zeros(np.shape(ambient_c))
    return vehicle.warmup_fuel_l_per_k * heating_k(ambient_c, vehicle.heating_below_c)


def ice_kinetic_coefficient(vehicle) -> float:
    """Extra fuel energy per joule of positive kinetic energy, 1 / eta_k - 1 / eta [-]
    (0 when ``kinetic_eta`` is unset)."""
    if vehicle.kinetic_eta is None:
        return 0.0
    return 1.0 / vehicle.kinetic_eta - 1.0 / vehicle.eta


def ev_battery_energy_j(vehicle, wheel_j, *, duration_s, ambient_c, starts=1.0) -> np.ndarray:
    """Battery energy [J] of an EV for wheel energy ``wheel_j`` = W(eta eta_r) [J] (weight
    :func:`ev_negative_weight` on the negative steps): W / eta + D P_aux(T) + starts e_warm h(T).

    ``duration_s`` [s], ``ambient_c`` [degC] and ``starts`` (trip starts, 1 per trip)
    broadcast with ``wheel_j``.
    """
    return (np.asarray(wheel_j, dtype=np.float64) / vehicle.eta
            + ev_aux_power_w(vehicle, ambient_c) * np.asarray(duration_s, dtype=np.float64)
            + np.asarray(starts, dtype=np.float64) * ev_start_energy_j(vehicle, ambient_c))


def ice_fuel_l(vehicle, wheel_j, *, mass_kg, k_pos, traction_s, duration_s, idle_s, ambient_c,
               starts=1.0) -> np.ndarray:
    """Fuel [l] of an ICE for wheel energy ``wheel_j`` = W(w) [J] (w by braking mode).

    W / (U eta) + m k_pos (1/eta_k - 1/eta) / U + r_run D_t + r_idle I
    + D r_T(T) + starts l_warm h(T); ``mass_kg`` [kg], ``k_pos`` [J/kg] (the vector's
    positive kinetic sum), ``traction_s`` (D_t), ``duration_s`` and ``idle_s`` [s],
    ``ambient_c`` [degC].
    """
    lhv = vehicle.fuel_lhv_j_per_l
    d = np.asarray(duration_s, dtype=np.float64)
    idle = np.asarray(idle_s, dtype=np.float64)
    fuel = np.asarray(wheel_j, dtype=np.float64) / (lhv * vehicle.eta)
    c_kin = ice_kinetic_coefficient(vehicle)
    if c_kin:
        if not math.isfinite(float(np.max(k_pos))):
            raise ValueError("the cycle vector has no positive kinetic sum (k_pos; a vector stored before "
                             "cevm 0.2): recompute it to predict with kinetic_eta")
        fuel = fuel + c_kin * np.asarray(mass_kg, dtype=np.float64) * k_pos / lhv
    if vehicle.running_fuel_lps:
        if not math.isfinite(float(np.max(traction_s))):
            raise ValueError("the cycle vector has no traction time (traction_s; a vector stored before "
                             "cevm 0.2): recompute it to predict with running_fuel_lph")
        fuel = fuel + vehicle.running_fuel_lps * np.asarray(traction_s, dtype=np.float64)
    fuel = fuel + vehicle.idle_fuel_lps * idle
    fuel = fuel + ice_time_fuel_lps(vehicle, ambient_c) * d
    return fuel + np.asarray(starts, dtype=np.float64) * ice_start_fuel_l(vehicle, ambient_c)
