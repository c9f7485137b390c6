"""The detailed (baseline) vehicle model: a backward-facing time-step simulation.

This is cevm's stand-in for the paper's Simulink baseline models (section 4): it turns a
speed and elevation trace into per-step operating points of the powertrain and, from
efficiency maps, limits and a battery or fuel model, into electric energy or fuel. It is
*not* the CE model: its efficiencies vary with the operating point, regeneration is
limited, auxiliaries draw power all the time and a diesel burns fuel at idle, so the CE
model's single eta matches it only on average (the spread is the CE model's error).

Backward-facing means the trace is followed exactly: the model asks what force the wheels
need for the measured speed change, and what the powertrain must do to supply it. Where a
limit binds (motor or engine torque), the unmet part is reported (``traction_deficit_j``)
instead of slowing the vehicle down.

Step convention (as in :mod:`cevm.core.cycle` and PAPER-NOTES.md): step i joins sample i to
i+1, dt_i = T_{i+1} - T_i, mean speed v_i = (v_i + v_{i+1}) / 2, acceleration
(v_{i+1} - v_i) / dt_i. The road load of a step is the paper's eq. (28),

    Delta_i = m (k_i + e_i) + CdA a_i + Cr m r_i          [J]

(eq. 1-4 integrated over the step, rho_air = 1.225 kg/m^3, g = 9.81 m/s^2), plus the
kinetic energy of the rotating parts m_rot k_i (wheels, motor or engine). The wheel
power of the step is that energy over dt_i and the wheel force that energy over the
step's distance v_i dt_i. Steps at standstill (v_i = 0) need no wheel work: the brakes
hold the vehicle, so elevation noise at standstill costs nothing.

Electric vehicle (:class:`EvParams`)
    wheel -> fixed reduction x final drive (one efficiency) -> motor+inverter (loss map)
    -> battery (open-circuit voltage curve, internal resistance, coulomb counting).
    Motor and inverter losses, the standard loss model used to generate scalable maps::

        P_loss(T, w) = k_c T^2 + k_i w + k_w w^3 + C        [W]

    (copper, iron, windage and friction, constant inverter/control losses), with the
    coefficients given as fractions of the peak power so the map scales with the motor.
    Drive is limited by the peak torque below base speed and the peak power above it;
    regeneration by its own torque and power limits and a fade-out at low speed; what
    regeneration cannot take goes to the friction brakes. A regenerating step whose
    losses exceed the recovered power is left to the friction brakes (no battery drain).
    Above the maximum motor speed there is no drive torque. Battery terminal power =
    motor electric power + auxiliaries (always on, standstill included).

Diesel vehicle (:class:`DieselParams`)
    wheel -> axle -> N-speed gearbox (per-gear efficiency) -> engine with a full-load
    torque curve and a Willans-line fuel model. Gear choice, vectorised over all gears
    at once (arrays of shape (n_gears, n_steps)): the highest gear whose engine speed is
    at least a minimum that rises with the power demand (from 950 rpm at no load to
    1,350 rpm at rated power by default), at most the maximum speed, and whose
    full-load torque covers the demand. Fuel power::

        P_fuel = (P_eng + P_fric(w)) / e_ind(w, T)      if P_eng + P_fric > 0, else 0

    P_eng the brake power (traction + engine inertia + auxiliaries), P_fric the friction
    power from a friction mean effective pressure quadratic in speed, e_ind the indicated
    efficiency, mildly dependent on speed and load. Fuel cut: when the indicated power
    needed is negative (the wheels drive the engine harder than its friction brakes it)
    no fuel is injected, and the service brakes take the rest; a brake torque between
    zero and the friction torque needs some fuel (the driver holds a little throttle).
    Launch (slower than first gear at the preferred engine speed): the clutch slips, the
    engine turns at the preferred speed and passes the wheels' torque. At standstill,
    and when the vehicle is too slow for first gear while not driving, the clutch is
    open and the engine idles: idle fuel = (P_aux + P_fric(idle)) / e_ind(idle).

Time step: :func:`simulate` decimates traces sampled faster than 1 s to about 1 s
(``time_step_s``), as quantisation noise of fast logs otherwise makes spurious power
spikes; any strictly increasing time is accepted.

Default parameters are plausible values for the paper's vehicles (Optare Metrocity EV,
Scania P320 with a 9.3 l DC09 engine), from public data-sheet figures and textbook
values, not from measurements. A vehicle file can override any of them in its
``[detailed]`` table (keys in :data:`EV_KEYS` / :data:`DIESEL_KEYS`).

Battery SoC: SoC_{i+1} = SoC_i - I_i dt_i / Q, and I_i depends on V_oc(SoC_i). This is
solved vectorised by fixed-point passes: each pass evaluates V_oc at the previous pass's
SoC, solves P = V_oc I - R I^2 for every step and integrates with one cumulative sum;
passes repeat until the SoC changes by less than 1e-12. The error shrinks like
(L x SoC drop)^k / k!: for a 1 h bus cycle (6 % SoC) 4-5 passes reach 1e-11, a full
discharge 10 passes reach 1e-14 (measured against a plain per-step loop; the tests do
the same). SoC is not clipped: below 0 the trace needs more than the usable capacity
(the OCV curve is held at its end values).
"""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any, Mapping

import numpy as np

from cevm.core.cycle import PAPER_PHYSICS, Physics, step_terms, trapezoid_distance_m, validate_cycle
from cevm.errors import InputError
from cevm.units import J_PER_KWH

RPM = 2.0 * math.pi / 60.0  # rad/s per rpm


# --------------------------------------------------------------------------------------
# Parameters
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class EvParams:
    """Electric powertrain parameters, SI units (plausible values, not measured).

    Defaults describe a 10 m single-deck electric bus of the Optare Metrocity EV class
    (9.8 t, central permanent-magnet motor, fixed reduction):

    - ``wheel_radius_m`` = 0.466: dynamic rolling radius of a 275/70 R22.5 city-bus tyre
      (static diameter 0.957 m, about 3 % deflection).
    - ``gear_ratio`` = 1.40 (single-stage reduction box) and ``final_drive_ratio`` = 5.74
      (bus drive axle), 8.04 in all: 4,500 rpm at 98 km/h.
    - ``transmission_efficiency`` = 0.95: reduction gear and hypoid axle together, both
      ways (typical 0.97 x 0.98).
    - ``motor_peak_power_w`` = 180 kW, ``motor_peak_torque_nm`` = 1,100 N m (base speed
      1,560 rpm, 34 km/h), ``motor_max_speed_rad_s`` = 4,500 rpm: a typical 150-250 kW
      e-bus traction motor, able to start the bus at about 1.8 m/s^2.
    - Loss map fractions of the peak power: ``copper_loss_frac`` = 0.06 at peak torque
      (k_c = 0.06 P_peak / T_peak^2), ``iron_loss_frac`` = 0.015 at maximum speed
      (k_i = 0.015 P_peak / w_max), ``windage_loss_frac`` = 0.005 at maximum speed
      (k_w = 0.005 P_peak / w_max^3), ``constant_loss_frac`` = 0.003 (inverter and
      control). Motor+inverter efficiency: about 0.92-0.93 at best, 0.88 at light cruise
      load, lower at low speed and low torque: the usual shape of PMSM maps.
    - ``regen_max_power_w`` = 120 kW at the motor shaft (charge acceptance of a ~140 kWh
      pack at about 1C); ``regen_max_torque_nm`` = None means the peak torque;
      regeneration fades linearly from full at ``regen_fade_high_mps`` = 10 km/h to
      none at ``regen_fade_low_mps`` = 4 km/h (the friction brakes stop the bus).
    - Battery: ``cells_in_series`` = 180 NMC cells, pack open-circuit voltage
      180 x ``ocv_cell_v`` (a monotone NMC curve, 3.40-4.10 V, about 670 V nominal) over
      ``ocv_soc``; ``internal_resistance_ohm`` = 0.08 (pack, about 0.45 mOhm per cell
      equivalent); the capacity comes from the vehicle's ``battery_kwh`` (usable), SoC
      0..1 spanning that usable window.
    - ``aux_base_power_w`` = 4 kW: always-on auxiliaries from the battery, heating and
      air conditioning excluded (air compressor for brakes, doors and suspension about
      1.5 kW on average, power steering 0.5-1 kW, 24 V DC/DC for lights, displays and
      ticketing 1-1.5 kW, battery and motor cooling 0.5-1 kW).
    - ``hvac_power_w`` = 0: heating / air conditioning, a user setting (10-20 kW for an
      electrically heated bus in winter). Both are the detailed model's own: the
      vehicle's ``aux_power_kw`` belongs to the CE model and is not read here.
    - Rotating inertia: ``wheel_inertia_kgm2`` = 72 (six 22.5" wheels with tyres, about
      12 kg m^2 each), ``motor_inertia_kgm2`` = 0.5 (rotor): about 480 kg equivalent
      mass, 5 % of the bus.
    """

    wheel_radius_m: float = 0.466
    gear_ratio: float = 1.40
    final_drive_ratio: float = 5.74
    transmission_efficiency: float = 0.95
    motor_peak_power_w: float = 180e3
    motor_peak_torque_nm: float = 1100.0
    motor_max_speed_rad_s: float = 4500.0 * RPM
    copper_loss_frac: float = 0.06
    iron_loss_frac: float = 0.015
    windage_loss_frac: float = 0.005
    constant_loss_frac: float = 0.003
    regen_max_power_w: float = 120e3
    regen_max_torque_nm: float | None = None
    regen_fade_low_mps: float = 4.0 / 3.6
    regen_fade_high_mps: float = 10.0 / 3.6
    cells_in_series: float = 180.0
    ocv_soc: tuple[float, ...] = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0)
    ocv_cell_v: tuple[float, ...] = (3.40, 3.55, 3.61, 3.65, 3.69, 3.74, 3.80, 3.87, 3.94, 4.02, 4.10)
    internal_resistance_ohm: float = 0.08
    aux_base_power_w: float = 4.0e3
    hvac_power_w: float = 0.0
    wheel_inertia_kgm2: float = 72.0
    motor_inertia_kgm2: float = 0.5

    def __post_init__(self) -> None:
        _check_params(self, EV_KEYS)

    @property
    def total_ratio(self) -> float:
        """Motor speed / wheel speed [-]."""
        return self.gear_ratio * self.final_drive_ratio

    @property
    def loss_coefficients(self) -> tuple[float, float, float, float]:
        """(k_c [W/(N m)^2], k_i [W s/rad], k_w [W s^3/rad^3], C [W]) of the loss map."""
        p = self.motor_peak_power_w
        w = self.motor_max_speed_rad_s
        return (
            self.copper_loss_frac * p / self.motor_peak_torque_nm**2,
            self.iron_loss_frac * p / w,
            self.windage_loss_frac * p / w**3,
            self.constant_loss_frac * p,
        )

    def motor_loss_w(self, torque_nm, speed_rad_s) -> np.ndarray:
        """Motor + inverter loss [W] at torque [N m] and speed [rad/s] (loss map)."""
        kc, ki, kw, c = self.loss_coefficients
        t = np.asarray(torque_nm, dtype=np.float64)
        w = np.asarray(speed_rad_s, dtype=np.float64)
        return kc * t * t + ki * w + kw * w * w * w + c

    def pack_ocv_v(self, soc) -> np.ndarray:
        """Pack open-circuit voltage [V] at state of charge ``soc`` [0..1] (clamped)."""
        return self.cells_in_series * np.interp(soc, self.ocv_soc, self.ocv_cell_v)

    def mean_pack_ocv_v(self) -> float:
        """Mean pack open-circuit voltage over SoC 0..1 [V] (trapezoidal integral)."""
        s = np.asarray(self.ocv_soc)
        v = np.asarray(self.ocv_cell_v)
        return float(self.cells_in_series * np.sum(0.5 * (v[1:] + v[:-1]) * np.diff(s)) / (s[-1] - s[0]))

    def rotating_mass_kg(self) -> float:
        """Equivalent translating mass of the wheels and motor rotor [kg]."""
        r = self.wheel_radius_m
        return (self.wheel_inertia_kgm2 + self.motor_inertia_kgm2 * self.total_ratio**2) / (r * r)


#: Gear ratios of a 12-speed direct-drive automated gearbox of the Scania GRS895 /
#: ZF 12AS class (spread about 16:1, top gear direct); plausible, not a data sheet.
GEAR_RATIOS_12 = (15.86, 12.33, 9.57, 7.44, 5.87, 4.57, 3.47, 2.70, 2.10, 1.63, 1.29, 1.00)


@dataclass(frozen=True)
class DieselParams:
    """Diesel powertrain parameters, SI units (plausible values, not measured).

    Defaults describe a Scania P320 4x2 tractor with the DC09 5-cylinder 9.3 l engine,
    320 hp (235 kW) at 1,900 rpm, 1,600 N m at 1,100-1,350 rpm (Scania's published
    rating for this engine), towing a tri-axle trailer:

    - ``wheel_radius_m`` = 0.49: dynamic radius of a 315/70 R22.5 truck tyre.
    - ``gear_ratios`` = :data:`GEAR_RATIOS_12` (12 gears, 15.86 to 1.00),
      ``axle_ratio`` = 2.71 (a common Scania long-haul rear-axle ratio: 1,230 rpm at
      85 km/h in top gear).
    - ``gear_efficiencies``: None means 0.97 for indirect gears and 0.985 for a direct
      gear (ratio 1.0); ``axle_efficiency`` = 0.965 (hypoid axle).
    - Engine: ``displacement_m3`` = 9.29e-3, ``idle_speed_rad_s`` = 600 rpm,
      ``max_speed_rad_s`` = 2,100 rpm (upshift limit; governed above), full-load torque
      ``full_load_torque_nm`` over ``full_load_speed_rad_s`` (800 N m at idle rising to
      1,600 N m at 1,100-1,350 rpm, constant 235 kW from 1,600 to 1,900 rpm, falling to
      950 N m at 2,100 rpm).
    - Willans line: friction mean effective pressure
      FMEP = fmep0 + fmep1 (n/1000 rpm) + fmep2 (n/1000 rpm)^2 with 0.97, 0.15, 0.05 bar
      (1.1 bar at idle, 1.45 bar at rated speed: textbook heavy-duty diesel values), so
      P_fric = FMEP V_d w / (4 pi); indicated efficiency
      e_ind = ``indicated_efficiency_max`` (0.47) - ``indicated_efficiency_speed_drop``
      (0.04) ((n - ``best_efficiency_speed_rad_s`` (1,250 rpm)) / 1000 rpm)^2, times
      (1 - ``indicated_efficiency_load_drop`` (0.04) (T / T_max(n))^2) (richer mixture and
      retarded injection near full load). Result: about 195 g/kWh at peak torque,
      205 g/kWh at rated power, 225-260 g/kWh at light load: the usual shape of a modern
      heavy-duty diesel map.
    - ``aux_power_w`` = 3 kW mechanical (alternator, air compressor, cooling fan and
      steering pump on average). With the engine friction this gives an idle fuel rate
      of about 1.8 l/h.
    - Shift rule: the highest gear whose engine speed is at least
      ``shift_low_speed_rad_s`` = 950 rpm at zero load, rising linearly to
      ``shift_high_speed_rad_s`` = 1,350 rpm at rated power (an economy AMT strategy:
      low speeds at light load, the peak-torque plateau when power is asked), at most
      the maximum speed, with enough full-load torque.
    - Rotating inertia: ``wheel_inertia_kgm2`` = 170 (12 wheels of tractor and trailer,
      about 14 kg m^2 each), ``engine_inertia_kgm2`` = 3.0 (crankshaft, flywheel,
      clutch), the latter multiplied by the square of the engaged total ratio.
    """

    wheel_radius_m: float = 0.49
    gear_ratios: tuple[float, ...] = GEAR_RATIOS_12
    axle_ratio: float = 2.71
    gear_efficiencies: tuple[float, ...] | None = None
    axle_efficiency: float = 0.965
    displacement_m3: float = 9.29e-3
    idle_speed_rad_s: float = 600.0 * RPM
    max_speed_rad_s: float = 2100.0 * RPM
    full_load_speed_rad_s: tuple[float, ...] = tuple(
        n * RPM for n in (600.0, 800.0, 1000.0, 1100.0, 1350.0, 1600.0, 1900.0, 2100.0)
    )
    full_load_torque_nm: tuple[float, ...] = (800.0, 1150.0, 1450.0, 1600.0, 1600.0, 1403.0, 1181.0, 950.0)
    fmep0_pa: float = 0.97e5
    fmep1_pa: float = 0.15e5
    fmep2_pa: float = 0.05e5
    indicated_efficiency_max: float = 0.47
    indicated_efficiency_speed_drop: float = 0.04
    best_efficiency_speed_rad_s: float = 1250.0 * RPM
    indicated_efficiency_load_drop: float = 0.04
    aux_power_w: float = 3.0e3
    shift_low_speed_rad_s: float = 950.0 * RPM
    shift_high_speed_rad_s: float = 1350.0 * RPM
    wheel_inertia_kgm2: float = 170.0
    engine_inertia_kgm2: float = 3.0

    def __post_init__(self) -> None:
        _check_params(self, DIESEL_KEYS)

    @property
    def n_gears(self) -> int:
        return len(self.gear_ratios)

    def gear_efficiency_array(self) -> np.ndarray:
        """Efficiency of each gear, gearbox times axle [-]."""
        if self.gear_efficiencies is not None:
            g = np.asarray(self.gear_efficiencies, dtype=np.float64)
        else:
            g = np.where(np.asarray(self.gear_ratios) == 1.0, 0.985, 0.97)
        return g * self.axle_efficiency

    def full_load_torque(self, speed_rad_s) -> np.ndarray:
        """Full-load engine torque [N m] at engine speed [rad/s] (0 outside the curve)."""
        return np.interp(speed_rad_s, self.full_load_speed_rad_s, self.full_load_torque_nm, left=0.0, right=0.0)

    def rated_power_w(self) -> float:
        """Maximum of full-load torque x speed [W]."""
        w = np.linspace(self.full_load_speed_rad_s[0], self.full_load_speed_rad_s[-1], 401)
        w = np.union1d(w, self.full_load_speed_rad_s)
        return float(np.max(self.full_load_torque(w) * w))

    def friction_power_w(self, speed_rad_s) -> np.ndarray:
        """Engine friction power [W] at engine speed [rad/s] (Willans intercept)."""
        w = np.asarray(speed_rad_s, dtype=np.float64)
        n_k = w / (1000.0 * RPM)
        fmep = self.fmep0_pa + (self.fmep1_pa + self.fmep2_pa * n_k) * n_k
        return fmep * self.displacement_m3 * w / (4.0 * math.pi)

    def indicated_efficiency(self, speed_rad_s, torque_nm=0.0) -> np.ndarray:
        """Indicated efficiency [-] at engine speed [rad/s] and brake torque [N m]."""
        w = np.asarray(speed_rad_s, dtype=np.float64)
        d = (w - self.best_efficiency_speed_rad_s) / (1000.0 * RPM)
        e = self.indicated_efficiency_max - self.indicated_efficiency_speed_drop * d * d
        tmax = self.full_load_torque(w)
        load = np.where(tmax > 0, np.clip(np.asarray(torque_nm, dtype=np.float64), 0.0, None) / np.where(tmax > 0, tmax, 1.0), 0.0)
        return e * (1.0 - self.indicated_efficiency_load_drop * np.minimum(load, 1.0) ** 2)

    def fuel_power_w(self, speed_rad_s, brake_power_w, friction_scale=1.0) -> np.ndarray:
        """Fuel power [W] for brake power [W] (traction + auxiliaries) at engine speed
        [rad/s]: (P + s P_fric) / e_ind, zero when P + s P_fric <= 0 (fuel cut);
        ``friction_scale`` s multiplies the friction (a cold engine: s > 1)."""
        w = np.asarray(speed_rad_s, dtype=np.float64)
        p = np.asarray(brake_power_w, dtype=np.float64)
        ind = p + self.friction_power_w(w) * friction_scale
        torque = np.divide(p, w, out=np.zeros(np.broadcast(p, w).shape), where=w > 0)
        return np.where(ind > 0, ind / self.indicated_efficiency(w, torque), 0.0)

    def rotating_mass_kg(self) -> float:
        """Equivalent translating mass of the wheels [kg] (engine inertia: per gear)."""
        return self.wheel_inertia_kgm2 / self.wheel_radius_m**2


# --- parameter keys of the [detailed] table: toml key -> (field, scale to SI, lo, hi) -----
# lo is exclusive when given as ("gt", x); hi inclusive. Sequence keys are marked "seq".

_POS = ("gt", 0.0)
_NONNEG = ("ge", 0.0)

EV_KEYS: dict[str, tuple] = {
    "wheel_radius_m": ("wheel_radius_m", 1.0, _POS, None),
    "gear_ratio": ("gear_ratio", 1.0, _POS, None),
    "final_drive_ratio": ("final_drive_ratio", 1.0, _POS, None),
    "transmission_efficiency": ("transmission_efficiency", 1.0, _POS, 1.0),
    "motor_peak_power_kw": ("motor_peak_power_w", 1e3, _POS, None),
    "motor_peak_torque_nm": ("motor_peak_torque_nm", 1.0, _POS, None),
    "motor_max_speed_rpm": ("motor_max_speed_rad_s", RPM, _POS, None),
    "copper_loss_frac": ("copper_loss_frac", 1.0, _NONNEG, 0.5),
    "iron_loss_frac": ("iron_loss_frac", 1.0, _NONNEG, 0.5),
    "windage_loss_frac": ("windage_loss_frac", 1.0, _NONNEG, 0.5),
    "constant_loss_frac": ("constant_loss_frac", 1.0, _NONNEG, 0.5),
    "regen_max_power_kw": ("regen_max_power_w", 1e3, _NONNEG, None),
    "regen_max_torque_nm": ("regen_max_torque_nm", 1.0, _NONNEG, None),
    "regen_fade_low_kmh": ("regen_fade_low_mps", 1 / 3.6, _NONNEG, None),
    "regen_fade_high_kmh": ("regen_fade_high_mps", 1 / 3.6, _NONNEG, None),
    "cells_in_series": ("cells_in_series", 1.0, _POS, None),
    "ocv_soc": ("ocv_soc", "seq", None, None),
    "ocv_cell_v": ("ocv_cell_v", "seq", None, None),
    "internal_resistance_ohm": ("internal_resistance_ohm", 1.0, _NONNEG, None),
    "aux_base_power_kw": ("aux_base_power_w", 1e3, _NONNEG, None),
    "hvac_power_kw": ("hvac_power_w", 1e3, _NONNEG, None),
    "wheel_inertia_kgm2": ("wheel_inertia_kgm2", 1.0, _NONNEG, None),
    "motor_inertia_kgm2": ("motor_inertia_kgm2", 1.0, _NONNEG, None),
}

DIESEL_KEYS: dict[str, tuple] = {
    "wheel_radius_m": ("wheel_radius_m", 1.0, _POS, None),
    "gear_ratios": ("gear_ratios", "seq", None, None),
    "axle_ratio": ("axle_ratio", 1.0, _POS, None),
    "gear_efficiencies": ("gear_efficiencies", "seq", None, None),
    "axle_efficiency": ("axle_efficiency", 1.0, _POS, 1.0),
    "displacement_l": ("displacement_m3", 1e-3, _POS, None),
    "idle_speed_rpm": ("idle_speed_rad_s", RPM, _POS, None),
    "max_speed_rpm": ("max_speed_rad_s", RPM, _POS, None),
    "full_load_speed_rpm": ("full_load_speed_rad_s", "seq", None, None),
    "full_load_torque_nm": ("full_load_torque_nm", "seq", None, None),
    "fmep0_bar": ("fmep0_pa", 1e5, _NONNEG, None),
    "fmep1_bar": ("fmep1_pa", 1e5, None, None),
    "fmep2_bar": ("fmep2_pa", 1e5, None, None),
    "indicated_efficiency_max": ("indicated_efficiency_max", 1.0, _POS, 1.0),
    "indicated_efficiency_speed_drop": ("indicated_efficiency_speed_drop", 1.0, _NONNEG, 1.0),
    "best_efficiency_speed_rpm": ("best_efficiency_speed_rad_s", RPM, _POS, None),
    "indicated_efficiency_load_drop": ("indicated_efficiency_load_drop", 1.0, _NONNEG, 0.5),
    "aux_power_kw": ("aux_power_w", 1e3, _NONNEG, None),
    "shift_low_rpm": ("shift_low_speed_rad_s", RPM, _POS, None),
    "shift_high_rpm": ("shift_high_speed_rad_s", RPM, _POS, None),
    "wheel_inertia_kgm2": ("wheel_inertia_kgm2", 1.0, _NONNEG, None),
    "engine_inertia_kgm2": ("engine_inertia_kgm2", 1.0, _NONNEG, None),
}

# Sequence keys: SI scale per element (rpm lists are converted element-wise).
_SEQ_SCALE = {"full_load_speed_rpm": RPM}


def _range_problem(value: float, lo, hi) -> str | None:
    if lo is not None:
        kind, bound = lo
        if kind == "gt" and not value > bound:
            return f"must be > {bound:g}"
        if kind == "ge" and not value >= bound:
            return f"must be >= {bound:g}"
    if hi is not None and value > hi:
        return f"must be <= {hi:g}"
    return None


def _seq_problem(name: str, values: tuple, params) -> str | None:
    """Checks of the sequence parameters (names are dataclass fields)."""
    a = np.asarray(values, dtype=np.float64)
    if a.ndim != 1 or a.size == 0 or not np.all(np.isfinite(a)):
        return "must be a non-empty list of finite numbers"
    if name in ("ocv_soc", "full_load_speed_rad_s"):
        if a.size < 2 or np.any(np.diff(a) <= 0):
            return "must be strictly increasing, at least 2 values"
    if name == "ocv_soc" and (a[0] > 0.0 or a[-1] < 1.0):
        return "must span 0 to 1 (first value <= 0, last >= 1)"
    if name in ("ocv_cell_v", "full_load_torque_nm", "gear_ratios") and np.any(a <= 0):
        return "values must be > 0"
    if name == "ocv_cell_v" and np.any(np.diff(a) < 0):
        return "must not decrease with SoC"
    if name == "gear_efficiencies" and np.any((a <= 0) | (a > 1)):
        return "values must be in (0, 1]"
    if name == "gear_ratios" and np.any(np.diff(a) >= 0):
        return "must be strictly decreasing (first gear first)"
    pairs = {"ocv_cell_v": "ocv_soc", "full_load_torque_nm": "full_load_speed_rad_s"}
    if name in pairs and len(getattr(params, pairs[name])) != a.size:
        return f"must have as many values as {pairs[name]}"
    return None


def _param_problem(params, keys: dict) -> tuple[str, str] | None:
    """(field, message) of the first invalid field of a parameter dataclass, or None."""
    for name, scale, lo, hi in keys.values():
        value = getattr(params, name)
        if value is None:
            continue
        if scale == "seq":
            problem = _seq_problem(name, value, params)
        elif isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            problem = f"must be a finite number, got {value!r}"
        else:
            problem = _range_problem(float(value), lo, hi)
        if problem:
            return name, problem
    if isinstance(params, EvParams) and params.regen_fade_high_mps < params.regen_fade_low_mps:
        return "regen_fade_high_mps", "must be >= regen_fade_low_mps"
    if isinstance(params, DieselParams):
        if params.max_speed_rad_s <= params.idle_speed_rad_s:
            return "max_speed_rad_s", "must be > idle_speed_rad_s"
        if params.shift_high_speed_rad_s < params.shift_low_speed_rad_s:
            return "shift_high_speed_rad_s", "must be >= shift_low_speed_rad_s"
        if params.gear_efficiencies is not None and len(params.gear_efficiencies) != len(params.gear_ratios):
            return "gear_efficiencies", "must have one value per gear ratio (gear_ratios)"
    return None


def _check_params(params, keys: dict) -> None:
    """Raise ValueError naming the first invalid field of a parameter dataclass."""
    found = _param_problem(params, keys)
    if found:
        raise ValueError(f"{found[0]} {found[1]}")


def _params_from_table(cls, keys: dict, table: Any, source: str):
    if table is None:
        return cls()
    if not isinstance(table, Mapping):
        raise InputError(source, "[detailed] must be a table of keys")
    kwargs: dict[str, Any] = {}
    for key, value in table.items():
        if key not in keys:
            close = difflib.get_close_matches(key, sorted(keys), n=1)
            hint = f" (did you mean '{close[0]}'?)" if close else ""
            raise InputError(source, f"unknown key '{key}' in [detailed]{hint}")
        name, scale, lo, hi = keys[key]
        if scale == "seq":
            if not isinstance(value, (list, tuple)) or any(
                isinstance(x, bool) or not isinstance(x, (int, float)) for x in value
            ):
                raise InputError(source, f"[detailed] key '{key}' must be a list of numbers, got {value!r}")
            s = _SEQ_SCALE.get(key, 1.0)
            kwargs[name] = tuple(float(x) * s for x in value)
        else:
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise InputError(source, f"[detailed] key '{key}' must be a finite number, got {value!r}")
            problem = _range_problem(float(value), lo, hi)
            if problem:
                raise InputError(source, f"[detailed] key '{key}' = {value!r} {problem}")
            kwargs[name] = float(value) * scale
    found = _param_problem(_unchecked(cls, kwargs), keys)
    if found:
        # Speak the file's language: TOML keys, not dataclass fields.
        to_key = {spec[0]: k for k, spec in keys.items()}
        field_name, message = found
        for f in sorted(to_key, key=len, reverse=True):
            message = message.replace(f, to_key[f])
        raise InputError(source, f"[detailed] key '{to_key.get(field_name, field_name)}' {message}")
    return cls(**kwargs)


def _unchecked(cls, kwargs: dict):
    """An instance of a parameter dataclass built without running its checks."""
    obj = object.__new__(cls)
    for f in cls.__dataclass_fields__.values():
        object.__setattr__(obj, f.name, kwargs.get(f.name, f.default))
    return obj


def ev_params_from_vehicle(vehicle, source: str | None = None) -> EvParams:
    """:class:`EvParams` from an EV's ``[detailed]`` table (defaults for absent keys).

    Raises :class:`~cevm.errors.InputError` naming ``source`` (default: the vehicle's
    name) and the key for an unknown key or a bad value.
    """
    if not vehicle.is_ev:
        raise ValueError(f"vehicle {vehicle.name!r} is not an EV")
    return _params_from_table(EvParams, EV_KEYS, vehicle.extra.get("detailed"), source or vehicle.name)


def diesel_params_from_vehicle(vehicle, source: str | None = None) -> DieselParams:
    """:class:`DieselParams` from an ICE vehicle's ``[detailed]`` table (see
    :func:`ev_params_from_vehicle`)."""
    if vehicle.is_ev:
        raise ValueError(f"vehicle {vehicle.name!r} is not an ICE vehicle")
    return _params_from_table(DieselParams, DIESEL_KEYS, vehicle.extra.get("detailed"), source or vehicle.name)


# --------------------------------------------------------------------------------------
# Results
# --------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class SimulationResult:
    """Per-step and per-sample output of :func:`simulate`, and totals.

    ``steps`` maps channel names (SI, unit in the name) to arrays of the N-1 steps;
    ``samples`` maps names to arrays of the N samples. EV step channels: ``dt_s``,
    ``speed_mean_mps``, ``accel_mps2``, ``wheel_force_n``, ``wheel_power_w``,
    ``motor_speed_rad_s``, ``motor_torque_nm``, ``motor_power_w`` (shaft),
    ``motor_loss_w``, ``motor_electric_power_w``, ``aux_power_w``, ``battery_power_w``
    (terminals, + = discharge), ``battery_ocv_v``, ``battery_current_a``,
    ``friction_brake_power_w``, ``traction_deficit_w``; samples ``soc``,
    ``energy_cum_j``. Diesel step channels: the common ones, ``gear`` (0 = clutch open,
    engine idling), ``engine_speed_rad_s``, ``engine_torque_nm``, ``engine_power_w``
    (brake, auxiliaries included), ``fuel_power_w``, ``fuel_rate_lps``,
    ``friction_brake_power_w``, ``traction_deficit_w``; samples ``fuel_cum_l``.

    Totals: ``wheel_energy_j`` (sum of wheel work, braking negative),
    ``energy_j`` (EV: net electric energy at the battery terminals, regeneration
    subtracted, auxiliaries included), ``fuel_l`` (diesel), ``friction_brake_energy_j``,
    ``traction_deficit_j`` (wheel work the powertrain could not deliver: > 0 means the
    trace asks more than the vehicle can do).
    """

    powertrain: str
    mass_kg: float
    time_s: np.ndarray
    speed_mps: np.ndarray
    elevation_m: np.ndarray | None
    steps: Mapping[str, np.ndarray]
    samples: Mapping[str, np.ndarray]
    wheel_energy_j: float
    friction_brake_energy_j: float
    traction_deficit_j: float
    energy_j: float | None = None
    fuel_l: float | None = None

    @property
    def duration_s(self) -> float:
        return float(self.time_s[-1] - self.time_s[0])

    @property
    def distance_m(self) -> float:
        """Trapezoidal distance [m]."""
        return trapezoid_distance_m(self.time_s, self.speed_mps)

    @property
    def soc(self) -> np.ndarray | None:
        """EV state of charge per sample [0..1], None for a diesel."""
        return self.samples.get("soc")

    @property
    def fuel_cum_l(self) -> np.ndarray | None:
        """Diesel cumulative fuel per sample [l], None for an EV."""
        return self.samples.get("fuel_cum_l")

    def to_frame(self):
        """A pandas DataFrame, one row per sample, user units in the column names.

        Step quantities are on the row of the step's first sample (the last row has
        none: NaN); cumulative quantities and SoC are at the sample.
        """
        import pandas as pd

        n = self.time_s.size

        def per_sample(x, scale=1.0):
            out = np.full(n, np.nan)
            out[:-1] = x * scale
            return out

        cols: dict[str, Any] = {
            "time_s": self.time_s,
            "speed_kmh": self.speed_mps * 3.6,
        }
        if self.elevation_m is not None:
            cols["elevation_m"] = self.elevation_m
        s = self.steps
        cols["accel_mps2"] = per_sample(s["accel_mps2"])
        cols["wheel_force_kn"] = per_sample(s["wheel_force_n"], 1e-3)
        cols["wheel_power_kw"] = per_sample(s["wheel_power_w"], 1e-3)
        if self.powertrain == "ev":
            cols["motor_speed_rpm"] = per_sample(s["motor_speed_rad_s"], 1 / RPM)
            cols["motor_torque_nm"] = per_sample(s["motor_torque_nm"])
            cols["motor_power_kw"] = per_sample(s["motor_power_w"], 1e-3)
            cols["motor_electric_power_kw"] = per_sample(s["motor_electric_power_w"], 1e-3)
            cols["aux_power_kw"] = per_sample(s["aux_power_w"], 1e-3)
            cols["battery_power_kw"] = per_sample(s["battery_power_w"], 1e-3)
            cols["battery_current_a"] = per_sample(s["battery_current_a"])
            cols["battery_ocv_v"] = per_sample(s["battery_ocv_v"])
            cols["friction_brake_power_kw"] = per_sample(s["friction_brake_power_w"], 1e-3)
            cols["soc_pct"] = self.samples["soc"] * 100.0
            cols["energy_cum_kwh"] = self.samples["energy_cum_j"] / J_PER_KWH
        else:
            gear = pd.array(np.zeros(n, dtype=np.int64), dtype="Int64")
            gear[:-1] = s["gear"]
            gear[-1] = pd.NA
            cols["gear"] = gear
            cols["engine_speed_rpm"] = per_sample(s["engine_speed_rad_s"], 1 / RPM)
            cols["engine_torque_nm"] = per_sample(s["engine_torque_nm"])
            cols["engine_power_kw"] = per_sample(s["engine_power_w"], 1e-3)
            cols["fuel_rate_lph"] = per_sample(s["fuel_rate_lps"], 3600.0)
            cols["friction_brake_power_kw"] = per_sample(s["friction_brake_power_w"], 1e-3)
            cols["fuel_cum_l"] = self.samples["fuel_cum_l"]
        cols["traction_deficit_kw"] = per_sample(s["traction_deficit_w"], 1e-3)
        return pd.DataFrame(cols)


# --------------------------------------------------------------------------------------
# Simulation
# --------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class _Road:
    dt: np.ndarray  # s
    v: np.ndarray  # mean speed, m/s
    accel: np.ndarray  # m/s^2
    k_per_dt: np.ndarray  # (v1^2 - v0^2) / (2 dt) = v * accel, W/kg
    moving: np.ndarray  # bool
    force: np.ndarray  # N, wheel force incl. rotating inertia (0 at standstill)
    power: np.ndarray  # W, wheel power (0 at standstill)


def _road(time_s, speed_mps, elevation_m, mass_kg, cda_m2, cr, rot_mass_kg, physics) -> _Road:
    """Wheel force and power per step: the paper's eq. (28) plus rotating inertia."""
    st = step_terms(time_s, speed_mps, elevation_m, physics)
    v = np.asarray(speed_mps, dtype=np.float64)
    dt = st.dt
    vm = 0.5 * (v[:-1] + v[1:])
    moving = vm > 0.0
    energy = mass_kg * (st.k + st.e) + cda_m2 * st.a + (cr * mass_kg) * st.r + rot_mass_kg * st.k
    energy = np.where(moving, energy, 0.0)
    ds = vm * dt
    force = np.divide(energy, ds, out=np.zeros_like(energy), where=moving)
    return _Road(
        dt=dt,
        v=vm,
        accel=(v[1:] - v[:-1]) / dt,
        k_per_dt=st.k / dt,
        moving=moving,
        force=force,
        power=energy / dt,
    )


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
    road = _road(t, speed_mps, elevation_m, mass_kg, cda_m2, cr, params.rotating_mass_kg(), physics)
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
        aux += _step_mean(aux_power_w)
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
    return _result("ev", mass_kg, t, speed_mps, elevation_m, steps, {"soc": soc, "energy_cum_j": e_cum},
                   energy_j=float(e_cum[-1]))


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
    road = _road(t, speed_mps, elevation_m, mass_kg, cda_m2, cr, p.rotating_mass_kg(), physics)
    n = road.dt.size
    aux = p.aux_power_w if aux_power_w is None else p.aux_power_w + _step_mean(aux_power_w)
    fscale = 1.0 if friction_scale is None else _step_mean(friction_scale)
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
            aux if np.ndim(aux) == 0 else aux[sl],
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
    return _result("ice", mass_kg, t, speed_mps, elevation_m, steps, {"fuel_cum_l": fuel_cum},
                   fuel_l=float(fuel_cum[-1]))


def _step_mean(per_sample) -> np.ndarray:
    """Per-step values from a per-sample series: the mean of each step's two samples."""
    x = np.asarray(per_sample, dtype=np.float64)
    return 0.5 * (x[:-1] + x[1:])


def _check_series(name: str, values, n: int, low: float, low_open: bool) -> np.ndarray:
    """A per-sample series as a float array of ``n`` finite values above ``low``, or
    ValueError naming it."""
    x = np.asarray(values, dtype=np.float64)
    if x.shape != (n,):
        raise ValueError(f"{name} must have one value per sample ({n}), got shape {x.shape}")
    bad = ~np.isfinite(x) | ((x <= low) if low_open else (x < low))
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"{name} must be finite and {'>' if low_open else '>='} {low:g}; sample {i} is {x[i]!r}")
    return x


def decimate_indices(time_s, time_step_s: float) -> np.ndarray:
    """Indices of the samples kept on a grid of at least ``time_step_s`` [s]: the first
    sample in each interval [t0 + k step, t0 + (k+1) step), and the last sample.

    A trace sampled at ``time_step_s`` or slower keeps every sample.
    """
    t = np.asarray(time_s, dtype=np.float64)
    if t.size <= 2:
        return np.arange(t.size)
    b = np.floor((t - t[0]) / time_step_s + 1e-9)
    keep = np.empty(t.size, dtype=bool)
    keep[0] = True
    keep[1:] = b[1:] != b[:-1]
    keep[-1] = True
    return np.flatnonzero(keep)


def _result(powertrain: str, mass_kg, t, speed_mps, elevation_m, steps: dict, samples: dict,
            **totals) -> SimulationResult:
    """A :class:`SimulationResult` from the step channels (``wheel_power_w``, ``dt_s``,
    ``friction_brake_power_w``, ``traction_deficit_w`` among them) and the sample ones."""
    dt = steps["dt_s"]
    return SimulationResult(
        powertrain=powertrain,
        mass_kg=float(mass_kg),
        time_s=t,
        speed_mps=np.asarray(speed_mps, dtype=np.float64),
        elevation_m=None if elevation_m is None else np.asarray(elevation_m, dtype=np.float64),
        steps=MappingProxyType(steps),
        samples=MappingProxyType(samples),
        wheel_energy_j=float(np.dot(steps["wheel_power_w"], dt)),
        friction_brake_energy_j=float(np.dot(steps["friction_brake_power_w"], dt)),
        traction_deficit_j=float(np.dot(steps["traction_deficit_w"], dt)),
        **totals,
    )


def simulate(vehicle, time_s, speed_mps, elevation_m=None, mass_kg: float | None = None,
             soc_start: float = 1.0, *, params: EvParams | DieselParams | None = None,
             time_step_s: float | None = 1.0, physics: Physics = PAPER_PHYSICS, aux_power_w=None,
             friction_scale=None) -> SimulationResult:
    """Simulate ``vehicle`` (a :class:`~cevm.core.vehicle.Vehicle`) over a trace.

    Parameters
    ----------
    vehicle : road-load parameters (mass, CdA, Cr), battery capacity (EV) or fuel
        heating value (ICE); powertrain details (auxiliaries included) from its
        ``[detailed]`` table unless ``params`` is given. The CE-model terms ``eta``,
        ``aux_power_kw`` and ``idle_fuel_lph`` are not used.
    time_s : (N,) time [s], strictly increasing (any step)
    speed_mps : (N,) speed [m/s], >= 0
    elevation_m : (N,) road elevation [m], or None for a flat road
    mass_kg : gross mass [kg]; default the vehicle's ``mass_kg``
    soc_start : EV state of charge at the first sample [0..1], default 1.0 (full)
    params : :class:`EvParams` / :class:`DieselParams` overriding the vehicle's table
    time_step_s : simulation step [s], default 1.0: a trace sampled faster is decimated
        to one sample per ``time_step_s`` (:func:`decimate_indices`) before simulating,
        as backward models usually run at 1 s. Speed logged at 10 Hz with 0.1 mph
        resolution gives +-0.45 m/s^2 acceleration spikes from quantisation alone, which
        no powertrain follows (a forward model's driver and the vehicle's inertia filter
        them). Kinetic and potential energy telescope, so the decimated trace needs the
        same net energy. None: simulate every sample. The result's arrays are on the
        simulated samples.
    physics : air density and gravity (the paper's by default)
    aux_power_w : (N,) auxiliary power [W] per sample beyond the ``[detailed]`` table's
        (>= 0): EV, from the battery (heating and air conditioning that follow the
        weather); diesel, mechanical at the engine (an A/C compressor). None: none.
    friction_scale : (N,) diesel only: factor (> 0) on the engine friction per sample,
        e.g. above 1 while a cold engine warms up. None: 1.

    Raises ValueError for an invalid trace (see :func:`cevm.core.cycle.validate_cycle`)
    or series.
    """
    validate_cycle(time_s, speed_mps, elevation_m)
    n_samples = np.size(time_s)
    if aux_power_w is not None:
        aux_power_w = _check_series("aux_power_w", aux_power_w, n_samples, 0.0, False)
    if friction_scale is not None:
        if vehicle.is_ev:
            raise ValueError("friction_scale applies to a diesel engine, not to an EV")
        friction_scale = _check_series("friction_scale", friction_scale, n_samples, 0.0, True)
    if time_step_s is not None:
        if not time_step_s > 0:
            raise ValueError("time_step_s must be > 0")
        idx = decimate_indices(time_s, time_step_s)
        if idx.size < np.size(time_s):
            time_s = np.asarray(time_s, dtype=np.float64)[idx]
            speed_mps = np.asarray(speed_mps, dtype=np.float64)[idx]
            if elevation_m is not None:
                elevation_m = np.asarray(elevation_m, dtype=np.float64)[idx]
            aux_power_w = None if aux_power_w is None else aux_power_w[idx]
            friction_scale = None if friction_scale is None else friction_scale[idx]
    m = float(vehicle.mass_kg if mass_kg is None else mass_kg)
    if not m > 0:
        raise ValueError("mass_kg must be > 0")
    if not 0.0 <= soc_start <= 1.0:
        raise ValueError("soc_start must be in [0, 1]")
    if vehicle.is_ev:
        ev = params if params is not None else ev_params_from_vehicle(vehicle)
        if not isinstance(ev, EvParams):
            raise TypeError("an EV needs EvParams")
        return simulate_ev(ev, time_s, speed_mps, elevation_m, mass_kg=m, cda_m2=vehicle.cda_m2, cr=vehicle.cr,
                           battery_j=vehicle.battery_j, soc_start=soc_start,
                           physics=physics, aux_power_w=aux_power_w)
    ice = params if params is not None else diesel_params_from_vehicle(vehicle)
    if not isinstance(ice, DieselParams):
        raise TypeError("an ICE vehicle needs DieselParams")
    return simulate_diesel(ice, time_s, speed_mps, elevation_m, mass_kg=m, cda_m2=vehicle.cda_m2, cr=vehicle.cr,
                           fuel_lhv_j_per_l=vehicle.fuel_lhv_j_per_l, physics=physics,
                           aux_power_w=aux_power_w, friction_scale=friction_scale)
