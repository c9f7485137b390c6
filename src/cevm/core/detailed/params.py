"""The detailed model's powertrain parameters (:class:`EvParams`, :class:`DieselParams`:
frozen, SI units, checked when made) and their limits.

A vehicle file's ``[detailed]`` table (keys in user units, kW, rpm, km/h) is read into
these by :mod:`cevm.io.detailed`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cevm.units import MPS_TO_KMH, RAD_S_PER_RPM

RPM = RAD_S_PER_RPM  # rad/s per rpm


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
    regen_fade_low_mps: float = 4.0 / MPS_TO_KMH
    regen_fade_high_mps: float = 10.0 / MPS_TO_KMH
    cells_in_series: float = 180.0
    ocv_soc: tuple[float, ...] = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0)
    ocv_cell_v: tuple[float, ...] = (3.40, 3.55, 3.61, 3.65, 3.69, 3.74, 3.80, 3.87, 3.94, 4.02, 4.10)
    internal_resistance_ohm: float = 0.08
    aux_base_power_w: float = 4.0e3
    hvac_power_w: float = 0.0
    wheel_inertia_kgm2: float = 72.0
    motor_inertia_kgm2: float = 0.5

    def __post_init__(self) -> None:
        _check_params(self)

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
        _check_params(self)

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
        brake = np.clip(np.asarray(torque_nm, dtype=np.float64), 0.0, None)
        load = np.where(tmax > 0, brake / np.where(tmax > 0, tmax, 1.0), 0.0)
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


# --- limits of each field: (lower bound, upper bound), or SEQ for a sequence ---------------
# A lower bound is ("gt", x) (exclusive) or ("ge", x); an upper bound is inclusive.

SEQ = "seq"
_POS = ("gt", 0.0)
_NONNEG = ("ge", 0.0)

EV_LIMITS: dict[str, tuple | str] = {
    "wheel_radius_m": (_POS, None),
    "gear_ratio": (_POS, None),
    "final_drive_ratio": (_POS, None),
    "transmission_efficiency": (_POS, 1.0),
    "motor_peak_power_w": (_POS, None),
    "motor_peak_torque_nm": (_POS, None),
    "motor_max_speed_rad_s": (_POS, None),
    "copper_loss_frac": (_NONNEG, 0.5),
    "iron_loss_frac": (_NONNEG, 0.5),
    "windage_loss_frac": (_NONNEG, 0.5),
    "constant_loss_frac": (_NONNEG, 0.5),
    "regen_max_power_w": (_NONNEG, None),
    "regen_max_torque_nm": (_NONNEG, None),
    "regen_fade_low_mps": (_NONNEG, None),
    "regen_fade_high_mps": (_NONNEG, None),
    "cells_in_series": (_POS, None),
    "ocv_soc": SEQ,
    "ocv_cell_v": SEQ,
    "internal_resistance_ohm": (_NONNEG, None),
    "aux_base_power_w": (_NONNEG, None),
    "hvac_power_w": (_NONNEG, None),
    "wheel_inertia_kgm2": (_NONNEG, None),
    "motor_inertia_kgm2": (_NONNEG, None),
}
"""Limits of the :class:`EvParams` fields, in the order they are checked."""

DIESEL_LIMITS: dict[str, tuple | str] = {
    "wheel_radius_m": (_POS, None),
    "gear_ratios": SEQ,
    "axle_ratio": (_POS, None),
    "gear_efficiencies": SEQ,
    "axle_efficiency": (_POS, 1.0),
    "displacement_m3": (_POS, None),
    "idle_speed_rad_s": (_POS, None),
    "max_speed_rad_s": (_POS, None),
    "full_load_speed_rad_s": SEQ,
    "full_load_torque_nm": SEQ,
    "fmep0_pa": (_NONNEG, None),
    "fmep1_pa": (None, None),
    "fmep2_pa": (None, None),
    "indicated_efficiency_max": (_POS, 1.0),
    "indicated_efficiency_speed_drop": (_NONNEG, 1.0),
    "best_efficiency_speed_rad_s": (_POS, None),
    "indicated_efficiency_load_drop": (_NONNEG, 0.5),
    "aux_power_w": (_NONNEG, None),
    "shift_low_speed_rad_s": (_POS, None),
    "shift_high_speed_rad_s": (_POS, None),
    "wheel_inertia_kgm2": (_NONNEG, None),
    "engine_inertia_kgm2": (_NONNEG, None),
}
"""Limits of the :class:`DieselParams` fields, in the order they are checked."""


def limits_of(params_or_cls) -> dict[str, tuple | str]:
    """:data:`EV_LIMITS` or :data:`DIESEL_LIMITS`, for a parameter dataclass or an
    instance of one."""
    cls = params_or_cls if isinstance(params_or_cls, type) else type(params_or_cls)
    return EV_LIMITS if issubclass(cls, EvParams) else DIESEL_LIMITS


def range_problem(value: float, lo, hi) -> str | None:
    """What is wrong with ``value`` between the bounds ``lo`` and ``hi``, or None."""
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
    if name in ("ocv_soc", "full_load_speed_rad_s") and (a.size < 2 or np.any(np.diff(a) <= 0)):
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


def param_problem(params) -> tuple[str, str] | None:
    """(field, message) of the first invalid field of a parameter dataclass, or None."""
    for name, limits in limits_of(params).items():
        value = getattr(params, name)
        if value is None:
            continue
        if limits == SEQ:
            problem = _seq_problem(name, value, params)
        elif isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            problem = f"must be a finite number, got {value!r}"
        else:
            problem = range_problem(float(value), *limits)
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


def _check_params(params) -> None:
    """Raise ValueError naming the first invalid field of a parameter dataclass."""
    found = param_problem(params)
    if found:
        raise ValueError(f"{found[0]} {found[1]}")
