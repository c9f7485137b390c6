"""Vehicle parameters (pure): the frozen :class:`Vehicle` and its validation from a
mapping (a parsed TOML file; reading files is in :mod:`cevm.io`), and predictions of one
vehicle over a cycle vector.

Vehicle files (TOML), units in the key names::

    name = "Optare Metrocity electric bus"   # required
    id = "metrocity-paper"                    # optional: unique id in rows and legends
                                              #   (default: the file's stem)
    powertrain = "ev"                         # required: "ev" or "ice"
    kerb_mass_kg = 9000                       # mass_kg, or kerb_mass_kg (+ payload_kg)
    payload_kg = 825                          # default payload [kg] (0 if absent)
    max_gross_kg = 18000                      # optional gross-weight limit [kg]
    cda_m2 = 3.99                             # required: drag coefficient x frontal area
    cr = 0.0066                               # required: rolling-resistance coefficient
    eta = 0.78                                # required: average efficiency, (0, 1]
    battery_kwh = 124                         # EV, required: usable battery capacity
    aux_power_kw = 0.0                        # EV, optional: auxiliary load [kW]
    regen_eta = 0.7                           # EV, optional: battery share of negative wheel
                                              #   energy (default: eta, the paper's eq. 29-31)
    aux_heating_kw_per_k = 0.2                # EV, optional: heating per K below heating_below_c
    aux_cooling_kw_per_k = 0.1                # EV, optional: A/C per K above cooling_above_c
    warmup_kwh_per_k = 0.0                    # EV, optional: energy per trip start per K of cold
    fuel_lhv_mj_per_l = 35.8                  # ICE, required: fuel lower heating value
    idle_fuel_lph = 0.0                       # ICE, optional: idle fuel rate [l/h]
    running_fuel_lph = 0.0                    # ICE, optional: fuel rate while moving, beyond
                                              #   the wheel work (Willans-line offset) [l/h]
    kinetic_eta = 0.3                         # ICE, optional: efficiency of the fuel spent on
                                              #   positive kinetic energy (default: eta)
    heating_fuel_lph_per_k = 0.0              # ICE, optional: heater fuel per K below heating_below_c
    cooling_fuel_lph_per_k = 0.0              # ICE, optional: A/C fuel per K above cooling_above_c
    warmup_fuel_l_per_k = 0.0                 # ICE, optional: cold-start fuel per start per K
    ice_braking = "no-credit"                 # ICE, optional: "no-credit" (default) or "paper"
    tank_l = 400                              # ICE, optional: usable tank volume [l]
    heating_below_c = 16.0                    # optional: heating balance temperature [degC]
    cooling_above_c = 22.0                    # optional: cooling balance temperature [degC]
    reference_temp_c = 12.0                   # optional: ambient temperature of predictions
                                              #   that give none (default 20 degC)
    max_power_kw = 180                        # optional: rated power of the motor or engine
    max_speed_kmh = 90                        # optional: top speed; predict flags a cycle
                                              #   that needs more (see cevm.core.sweep)

    [sources]                                  # optional: where each number comes from
    cda_m2 = "paper, section 5.1"

    [calibration]                              # written by cevm calibrate: what the fit saw
    terms = ["eta", "aux", "heat"]             #   (see :class:`FitDomain`)

The model these parameters feed is :mod:`cevm.core.energy`.

Plausibility bounds
-------------------
Every number is also checked against :data:`PLAUSIBLE`, bounds no road vehicle leaves
(a value outside is a unit mistake or a typo, such as ``kerb_mass_kg = 1e20``): masses
20-200,000 kg, CdA 0.05-30 m^2, Cr 0.001-0.1, eta 0.05-1, battery 0.1-5,000 kWh, tank
1-5,000 l, fuel heating value 3-50 MJ/l, auxiliary power up to 200 kW, fuel rates up to
50-100 l/h, rated power 0.1-5,000 kW, top speed 5-400 km/h. The error names the file
and the key.
"""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import numpy as np

from cevm.core import energy
from cevm.core.cycle import CycleVector
from cevm.errors import InputError
from cevm.units import J_PER_KWH, J_PER_MJ, S_PER_H
from cevm.core.model import (
    ICE_BRAKING_DEFAULT,
    ICE_BRAKING_MODES,
    Prediction,
    braking_weight,
    wheel_energy_j,
)

Powertrain = Literal["ev", "ice"]


@dataclass(frozen=True)
class FitDomain:
    """What a calibration saw: the ``[calibration]`` table :func:`cevm.core.calibration`
    results write into a vehicle file, read back so that predictions outside it are
    warned about (:func:`domain_warnings`).

    Ranges are (low, high) over the trips the fit used, SI: ``ambient_c`` [degC, trip
    means], ``mean_speed_mps`` [m/s, distance / duration], ``mass_kg`` [kg],
    ``distance_m`` [m]; None where the trips did not say (no temperature logged).
    ``terms`` the model's terms, ``cv_mean_pct`` / ``cv_std_pct`` its cross-validated
    error [%], ``first_utc`` / ``last_utc`` the first and last trip start (ISO 8601).
    """

    terms: tuple[str, ...] = ()
    n_trips: int = 0
    vehicle_id: str | None = None
    first_utc: str | None = None
    last_utc: str | None = None
    ambient_c: tuple[float, float] | None = None
    mean_speed_mps: tuple[float, float] | None = None
    mass_kg: tuple[float, float] | None = None
    distance_m: tuple[float, float] | None = None
    cv_scheme: str | None = None
    cv_mean_pct: float | None = None
    cv_std_pct: float | None = None
    mass_sources: str | None = None


#: How far outside a calibration's range a prediction may go before it is warned about:
#: temperature [K] beyond the trips' coldest and warmest means, and relative margins on
#: mass and mean speed (a fit does not know what it did not see).
DOMAIN_MARGIN_K = 3.0
DOMAIN_MARGIN_MASS = 0.10
DOMAIN_MARGIN_SPEED = 0.25


def domain_warnings(vehicle: Vehicle, *, mass_kg=None, ambient_c=None, mean_speed_mps=None) -> list[str]:
    """Warnings for a prediction outside what the vehicle's calibration saw (none for a
    vehicle file that was not calibrated). Arguments are scalars or arrays (the extremes
    are checked); margins :data:`DOMAIN_MARGIN_K`, :data:`DOMAIN_MARGIN_MASS`,
    :data:`DOMAIN_MARGIN_SPEED`."""
    d = vehicle.calibration
    if d is None:
        return []
    out = []
    label = f"{vehicle.name!r} was calibrated on {d.n_trips} trips"
    if ambient_c is not None:
        t = np.asarray(ambient_c, dtype=np.float64)
        if d.ambient_c is None:
            if energy.uses_temperature(vehicle):
                out.append(f"{label} without a logged temperature; its temperature terms are not validated")
        else:
            lo, hi = d.ambient_c
            if t.size and (float(t.min()) < lo - DOMAIN_MARGIN_K or float(t.max()) > hi + DOMAIN_MARGIN_K):
                out.append(f"{label} at {lo:.1f} to {hi:.1f} degC; asked at {_span(t, 1)} degC: an extrapolation")
    if mass_kg is not None and d.mass_kg is not None:
        m = np.asarray(mass_kg, dtype=np.float64)
        lo, hi = d.mass_kg
        if m.size and (float(m.min()) < lo * (1 - DOMAIN_MARGIN_MASS) or float(m.max()) > hi * (1 + DOMAIN_MARGIN_MASS)):
            out.append(f"{label} at {lo:,.0f} to {hi:,.0f} kg; asked at {_span(m, 0)} kg: an extrapolation")
    if mean_speed_mps is not None and d.mean_speed_mps is not None:
        v = np.asarray(mean_speed_mps, dtype=np.float64)
        lo, hi = d.mean_speed_mps
        if v.size and (float(v.min()) < lo * (1 - DOMAIN_MARGIN_SPEED) or float(v.max()) > hi * (1 + DOMAIN_MARGIN_SPEED)):
            out.append(f"{label} at mean speeds of {3.6 * lo:.1f} to {3.6 * hi:.1f} km/h; asked at "
                       f"{_span(3.6 * v, 1)} km/h: a different duty")
    return out


def _span(x: np.ndarray, digits: int) -> str:
    lo, hi = f"{float(np.min(x)):,.{digits}f}", f"{float(np.max(x)):,.{digits}f}"
    return lo if lo == hi else f"{lo} to {hi}"  # equal as printed: one value


@dataclass(frozen=True)
class Vehicle:
    """A vehicle's CE-model parameters, SI inside.

    mass_kg is the default gross mass for predictions (kerb + default payload).
    """

    name: str
    powertrain: Powertrain
    mass_kg: float
    cda_m2: float
    cr: float
    eta: float
    id: str | None = None  # unique id in rows and legends (vehicle file: ``id``, else its stem)
    max_power_w: float | None = None  # rated power of the motor or engine [W]
    max_speed_mps: float | None = None  # top speed [m/s]
    kerb_mass_kg: float | None = None
    max_gross_kg: float | None = None
    battery_j: float | None = None  # EV: usable capacity [J]
    aux_power_w: float = 0.0  # EV: auxiliary load from the battery [W]
    fuel_lhv_j_per_l: float | None = None  # ICE: lower heating value [J/l]
    idle_fuel_lps: float = 0.0  # ICE: idle fuel rate [l/s]
    ice_braking: str = ICE_BRAKING_DEFAULT
    tank_l: float | None = None
    # terms beyond the paper (cevm.core.energy); zero / None: not in the model
    regen_eta: float | None = None  # EV: battery share of negative wheel energy; None: eta
    aux_heating_w_per_k: float = 0.0  # EV: heating power per K below heating_below_c [W/K]
    aux_cooling_w_per_k: float = 0.0  # EV: A/C power per K above cooling_above_c [W/K]
    warmup_j_per_k: float = 0.0  # EV: energy per trip start per K below heating_below_c [J/K]
    running_fuel_lps: float = 0.0  # ICE: fuel rate while moving, beyond the wheel work [l/s]
    kinetic_eta: float | None = None  # ICE: efficiency on positive kinetic energy; None: eta
    heating_fuel_lps_per_k: float = 0.0  # ICE: [l/s per K below heating_below_c]
    cooling_fuel_lps_per_k: float = 0.0  # ICE: [l/s per K above cooling_above_c]
    warmup_fuel_l_per_k: float = 0.0  # ICE: cold-start fuel per start per K [l/K]
    heating_below_c: float = energy.HEATING_BELOW_C_DEFAULT
    cooling_above_c: float = energy.COOLING_ABOVE_C_DEFAULT
    reference_temp_c: float | None = None  # ambient of predictions that give none [degC]
    calibration: FitDomain | None = field(default=None, compare=False)
    sources: dict = field(default_factory=dict, compare=False)
    extra: dict = field(default_factory=dict, compare=False)  # tables for other models

    @property
    def is_ev(self) -> bool:
        return self.powertrain == "ev"

    @property
    def label(self) -> str:
        """The vehicle's id, else its name: what rows and legends call it."""
        return self.id or self.name

    def with_payload(self, payload_kg: float) -> Vehicle:
        """This vehicle at kerb mass + ``payload_kg``."""
        if self.kerb_mass_kg is None:
            raise ValueError(f"vehicle {self.name!r} has no kerb_mass_kg, so a payload cannot be added")
        return replace(self, mass_kg=self.kerb_mass_kg + payload_kg)


_COMMON_KEYS = {
    "name",
    "id",
    "max_power_kw",
    "max_speed_kmh",
    "powertrain",
    "mass_kg",
    "kerb_mass_kg",
    "payload_kg",
    "max_gross_kg",
    "cda_m2",
    "cr",
    "eta",
    "sources",
    "notes",
    "heating_below_c",
    "cooling_above_c",
    "reference_temp_c",
    "calibration",
}
_EV_KEYS = {"battery_kwh", "aux_power_kw", "regen_eta", "aux_heating_kw_per_k", "aux_cooling_kw_per_k",
            "warmup_kwh_per_k"}
_ICE_KEYS = {"fuel_lhv_mj_per_l", "idle_fuel_lph", "ice_braking", "tank_l", "running_fuel_lph", "kinetic_eta",
             "heating_fuel_lph_per_k", "cooling_fuel_lph_per_k", "warmup_fuel_l_per_k"}
#: Tables other models may read (the detailed simulator's [detailed]; [[reference]],
#: published consumption ranges: cevm vehicle show, tests/test_shipped_vehicles.py);
#: kept, not validated here.
EXTRA_TABLES = {"detailed", "reference"}


#: Plausibility bounds of the vehicle-file keys, (low, high, unit): no road vehicle lies
#: outside them, so a value beyond is a unit mistake or a typo (``kerb_mass_kg = 1e20``).
#: From the lightest quadricycles and cargo bikes (tens of kg, CdA about 0.3 m^2) to road
#: trains (about 200 t, CdA up to about 15 m^2); see the module notes.
PLAUSIBLE: dict[str, tuple[float, float, str]] = {
    "mass_kg": (20.0, 200_000.0, "kg"),
    "kerb_mass_kg": (20.0, 200_000.0, "kg"),
    "payload_kg": (0.0, 200_000.0, "kg"),
    "max_gross_kg": (20.0, 200_000.0, "kg"),
    "cda_m2": (0.05, 30.0, "m^2"),
    "cr": (0.001, 0.1, ""),
    "eta": (0.05, 1.0, ""),
    "battery_kwh": (0.1, 5_000.0, "kWh"),
    "aux_power_kw": (0.0, 200.0, "kW"),
    "fuel_lhv_mj_per_l": (3.0, 50.0, "MJ/l"),
    "idle_fuel_lph": (0.0, 50.0, "l/h"),
    "running_fuel_lph": (0.0, 100.0, "l/h"),
    "tank_l": (1.0, 5_000.0, "l"),
    "aux_heating_kw_per_k": (0.0, 10.0, "kW/K"),
    "aux_cooling_kw_per_k": (0.0, 10.0, "kW/K"),
    "warmup_kwh_per_k": (0.0, 10.0, "kWh/K"),
    "heating_fuel_lph_per_k": (0.0, 5.0, "l/h per K"),
    "cooling_fuel_lph_per_k": (0.0, 5.0, "l/h per K"),
    "warmup_fuel_l_per_k": (0.0, 5.0, "l/K"),
    "max_power_kw": (0.1, 5_000.0, "kW"),
    "max_speed_kmh": (5.0, 400.0, "km/h"),
}

#: Longest vehicle id [characters].
ID_MAX_CHARS = 80


def check_vehicle_id(value: Any, source: str, what: str = "key 'id'") -> str:
    """A vehicle id: a non-empty string of at most :data:`ID_MAX_CHARS` printable
    characters (no control characters, no surrounding blanks), or InputError."""
    if not isinstance(value, str) or not value.strip():
        raise InputError(source, f"{what} must be a non-empty string, got {value!r}")
    if value != value.strip():
        raise InputError(source, f"{what} {value!r} must not start or end with blanks")
    if len(value) > ID_MAX_CHARS:
        raise InputError(source, f"{what} is {len(value)} characters long, more than {ID_MAX_CHARS}")
    if not value.isprintable():
        raise InputError(source, f"{what} {value!r} holds a control character")
    return value


def _number(data: dict, key: str, source: str, *, required: bool, lo: float | None = None,
            hi: float | None = None, lo_open: bool = False) -> float | None:
    if key not in data:
        if required:
            raise InputError(source, f"missing required key '{key}'", column=None)
        return None
    value = data[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InputError(source, f"key '{key}' must be a finite number, got {value!r}")
    value = float(value)
    if lo is not None and (value <= lo if lo_open else value < lo):
        raise InputError(source, f"key '{key}' = {value:g} must be {'>' if lo_open else '>='} {lo:g}")
    if hi is not None and value > hi:
        raise InputError(source, f"key '{key}' = {value:g} must be <= {hi:g}")
    if key in PLAUSIBLE:
        plo, phi, unit = PLAUSIBLE[key]
        if not plo <= value <= phi:
            unit = f" {unit}" if unit else ""
            raise InputError(source, f"key '{key}' = {value:g}{unit} is outside the plausible range "
                                     f"{plo:,g} to {phi:,g}{unit} of a road vehicle (a unit mistake?)")
    return value


def vehicle_from_mapping(data: dict[str, Any], source: str = "<vehicle>", *,
                         default_id: str | None = None) -> Vehicle:
    """Validate a parsed vehicle file and build a :class:`Vehicle`.

    The vehicle's ``id`` is the file's ``id`` key, else ``default_id`` (the file's stem,
    :func:`cevm.io.load_vehicle`), else None (rows then use the name).
    Raises :class:`~cevm.errors.InputError` naming ``source`` and the key for a missing,
    unknown, out-of-range or implausible key (:data:`PLAUSIBLE`).
    """
    pt = data.get("powertrain")
    if pt not in ("ev", "ice"):
        if pt is None:
            raise InputError(source, "missing required key 'powertrain' (\"ev\" or \"ice\")")
        raise InputError(source, f"key 'powertrain' must be \"ev\" or \"ice\", got {pt!r}")
    allowed = _COMMON_KEYS | (_EV_KEYS if pt == "ev" else _ICE_KEYS) | EXTRA_TABLES
    for key in data:
        if key not in allowed:
            other = _ICE_KEYS if pt == "ev" else _EV_KEYS
            if key in other:
                hint = f" (it belongs to {'an ICE' if pt == 'ev' else 'an EV'} vehicle)"
            else:
                close = difflib.get_close_matches(key, sorted(allowed), n=1)
                hint = f" (did you mean '{close[0]}'?)" if close else ""
            raise InputError(source, f"unknown key '{key}'{hint}")
    name = data.get("name")
    if not isinstance(name, str) or not name.strip():
        raise InputError(source, "missing required key 'name' (a non-empty string)")
    if not name.isprintable():
        raise InputError(source, f"key 'name' {name!r} holds a control character")

    kerb = _number(data, "kerb_mass_kg", source, required=False, lo=0.0, lo_open=True)
    payload = _number(data, "payload_kg", source, required=False, lo=0.0)
    mass = _number(data, "mass_kg", source, required=False, lo=0.0, lo_open=True)
    if mass is None and kerb is None:
        raise InputError(source, "missing required key 'mass_kg' (or 'kerb_mass_kg')")
    if mass is not None and payload is not None:
        raise InputError(source, "key 'payload_kg' goes with 'kerb_mass_kg', not with 'mass_kg'")
    if mass is None:
        mass = kerb + (payload or 0.0)
    max_gross = _number(data, "max_gross_kg", source, required=False, lo=0.0, lo_open=True)
    if max_gross is not None and mass > max_gross:
        raise InputError(source, f"default mass {mass:g} kg exceeds key 'max_gross_kg' = {max_gross:g}")
    if "id" in data:
        vid = check_vehicle_id(data["id"], source)
    else:
        vid = default_id
    max_power = _number(data, "max_power_kw", source, required=False, lo=0.0, lo_open=True)
    max_speed = _number(data, "max_speed_kmh", source, required=False, lo=0.0, lo_open=True)

    common = dict(
        name=name.strip(),
        id=vid,
        max_power_w=None if max_power is None else max_power * 1e3,
        max_speed_mps=None if max_speed is None else max_speed / 3.6,
        powertrain=pt,
        mass_kg=mass,
        kerb_mass_kg=kerb,
        max_gross_kg=max_gross,
        cda_m2=_number(data, "cda_m2", source, required=True, lo=0.0),
        cr=_number(data, "cr", source, required=True, lo=0.0, hi=0.1),
        eta=_number(data, "eta", source, required=True, lo=0.0, hi=1.0, lo_open=True),
        sources=dict(data.get("sources", {})),
        extra={k: data[k] for k in EXTRA_TABLES if k in data},
        **_temperature_keys(data, source),
    )
    if pt == "ev":
        battery = _number(data, "battery_kwh", source, required=True, lo=0.0, lo_open=True)
        aux = _number(data, "aux_power_kw", source, required=False, lo=0.0) or 0.0
        return Vehicle(
            **common, battery_j=battery * J_PER_KWH, aux_power_w=aux * 1e3,
            regen_eta=_number(data, "regen_eta", source, required=False, lo=0.0, hi=1.0),
            aux_heating_w_per_k=1e3 * (_number(data, "aux_heating_kw_per_k", source, required=False, lo=0.0) or 0.0),
            aux_cooling_w_per_k=1e3 * (_number(data, "aux_cooling_kw_per_k", source, required=False, lo=0.0) or 0.0),
            warmup_j_per_k=J_PER_KWH * (_number(data, "warmup_kwh_per_k", source, required=False, lo=0.0) or 0.0),
        )
    lhv = _number(data, "fuel_lhv_mj_per_l", source, required=True, lo=0.0, lo_open=True)
    idle = _number(data, "idle_fuel_lph", source, required=False, lo=0.0) or 0.0
    braking = data.get("ice_braking", ICE_BRAKING_DEFAULT)
    if braking not in ICE_BRAKING_MODES:
        raise InputError(source, f"key 'ice_braking' must be one of {', '.join(ICE_BRAKING_MODES)}; got {braking!r}")
    tank = _number(data, "tank_l", source, required=False, lo=0.0, lo_open=True)

    def per_h(key: str) -> float:
        return (_number(data, key, source, required=False, lo=0.0) or 0.0) / S_PER_H

    return Vehicle(
        **common,
        fuel_lhv_j_per_l=lhv * J_PER_MJ,
        idle_fuel_lps=idle / S_PER_H,
        ice_braking=braking,
        tank_l=tank,
        running_fuel_lps=per_h("running_fuel_lph"),
        kinetic_eta=_number(data, "kinetic_eta", source, required=False, lo=0.0, hi=1.0, lo_open=True),
        heating_fuel_lps_per_k=per_h("heating_fuel_lph_per_k"),
        cooling_fuel_lps_per_k=per_h("cooling_fuel_lph_per_k"),
        warmup_fuel_l_per_k=_number(data, "warmup_fuel_l_per_k", source, required=False, lo=0.0) or 0.0,
    )


def _temperature_keys(data: dict, source: str) -> dict:
    """heating_below_c, cooling_above_c, reference_temp_c and the [calibration] table."""
    lo, hi = energy.AMBIENT_RANGE_C
    below = _number(data, "heating_below_c", source, required=False, lo=lo, hi=hi)
    above = _number(data, "cooling_above_c", source, required=False, lo=lo, hi=hi)
    below = energy.HEATING_BELOW_C_DEFAULT if below is None else below
    above = energy.COOLING_ABOVE_C_DEFAULT if above is None else above
    if below > above:
        raise InputError(source, f"key 'heating_below_c' = {below:g} is above 'cooling_above_c' = {above:g}: "
                                 "a vehicle would heat and cool at once")
    return dict(heating_below_c=below, cooling_above_c=above,
                reference_temp_c=_number(data, "reference_temp_c", source, required=False, lo=lo, hi=hi),
                calibration=fit_domain_from_mapping(data.get("calibration"), source))


def _pair(table: dict, key: str, source: str, scale: float = 1.0) -> tuple[float, float] | None:
    v = table.get(key)
    if v is None:
        return None
    if (not isinstance(v, list) or len(v) != 2 or not all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                          and math.isfinite(x) for x in v) or v[0] > v[1]):
        raise InputError(source, f"key 'calibration.{key}' must be [low, high], got {v!r}")
    return (float(v[0]) * scale, float(v[1]) * scale)


def fit_domain_from_mapping(table: Any, source: str = "<vehicle>") -> FitDomain | None:
    """A :class:`FitDomain` from a vehicle file's ``[calibration]`` table (None if absent).
    File units: ``mean_speed_kmh``, ``distance_km``; the rest as :class:`FitDomain`."""
    if table is None:
        return None
    if not isinstance(table, dict):
        raise InputError(source, "key 'calibration' must be a table")

    def opt_str(key: str) -> str | None:
        v = table.get(key)
        return None if v is None else str(v)

    def opt_num(key: str) -> float | None:
        v = table.get(key)
        if v is None:
            return None
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise InputError(source, f"key 'calibration.{key}' must be a number, got {v!r}")
        return float(v)

    terms = table.get("terms", [])
    if not isinstance(terms, list) or not all(isinstance(t, str) for t in terms):
        raise InputError(source, "key 'calibration.terms' must be a list of term names")
    return FitDomain(
        terms=tuple(terms), n_trips=int(opt_num("n_trips") or 0), vehicle_id=opt_str("vehicle_id"),
        first_utc=opt_str("first_trip_utc"), last_utc=opt_str("last_trip_utc"),
        ambient_c=_pair(table, "ambient_c", source), mean_speed_mps=_pair(table, "mean_speed_kmh", source, 1 / 3.6),
        mass_kg=_pair(table, "mass_kg", source), distance_m=_pair(table, "distance_km", source, 1e3),
        cv_scheme=opt_str("cv_scheme"), cv_mean_pct=opt_num("cv_mean_pct"), cv_std_pct=opt_num("cv_std_pct"),
        mass_sources=opt_str("mass_sources"),
    )


def default_ambient_c(vehicle: Vehicle) -> tuple[float, str]:
    """The ambient temperature [degC] of a prediction that gives none, and where it
    comes from: the vehicle file's ``reference_temp_c``, else
    :data:`cevm.core.energy.AMBIENT_DEFAULT_C`."""
    if vehicle.reference_temp_c is not None:
        return float(vehicle.reference_temp_c), "vehicle reference_temp_c"
    return energy.AMBIENT_DEFAULT_C, f"default {energy.AMBIENT_DEFAULT_C:g} degC"


def predict(vector: CycleVector, vehicle: Vehicle, mass_kg=None, *, ambient_c=None,
            ice_braking: str | None = None) -> Prediction:
    """Predict one vehicle over one cycle vector for one or many masses (and ambient
    temperatures), with every term of the vehicle's model (:mod:`cevm.core.energy`).

    Parameters
    ----------
    vector : the cycle's vector
    vehicle : the vehicle
    mass_kg : gross mass(es) [kg]; default the vehicle's ``mass_kg``
    ambient_c : ambient temperature(s) [degC], broadcast with ``mass_kg``; default
        :func:`default_ambient_c` (used only by temperature-dependent terms)
    ice_braking : override the vehicle's ICE braking mode ("paper" or "no-credit")
    """
    m = vehicle.mass_kg if mass_kg is None else mass_kg
    # a scalar stays a Python float: the engine's scalar path is ~15x faster per call
    m = float(m) if np.ndim(m) == 0 else np.asarray(m, dtype=np.float64)
    t = default_ambient_c(vehicle)[0] if ambient_c is None else ambient_c
    t = energy.check_ambient_c(t)
    if vehicle.is_ev:
        e_wheel = wheel_energy_j(vector, m, vehicle.cda_m2, vehicle.cr, energy.ev_negative_weight(vehicle))
        e = energy.ev_battery_energy_j(vehicle, e_wheel, duration_s=vector.duration_s, ambient_c=t)
        return Prediction(mass_kg=np.asarray(m), wheel_energy_j=e_wheel, energy_j=e, fuel_l=None,
                          ambient_c=t)
    w = braking_weight(ice_braking or vehicle.ice_braking)
    e_wheel = wheel_energy_j(vector, m, vehicle.cda_m2, vehicle.cr, w)
    fuel = energy.ice_fuel_l(vehicle, e_wheel, mass_kg=m, k_pos=vector.k_pos, traction_s=vector.traction_s,
                             duration_s=vector.duration_s,
                             idle_s=vector.idle_s, ambient_c=t)
    return Prediction(mass_kg=np.asarray(m), wheel_energy_j=e_wheel, energy_j=None, fuel_l=fuel, ambient_c=t)
