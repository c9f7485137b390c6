"""Vehicle parameters (pure): the frozen :class:`Vehicle` and its validation from a
mapping (a parsed TOML file; reading files is in :mod:`cevm.io`), and predictions of one
vehicle over a cycle vector.

Vehicle files (TOML), units in the key names::

    name = "Optare Metrocity electric bus"   # required
    powertrain = "ev"                         # required: "ev" or "ice"
    kerb_mass_kg = 9000                       # mass_kg, or kerb_mass_kg (+ payload_kg)
    payload_kg = 825                          # default payload [kg] (0 if absent)
    max_gross_kg = 18000                      # optional gross-weight limit [kg]
    cda_m2 = 3.99                             # required: drag coefficient x frontal area
    cr = 0.0066                               # required: rolling-resistance coefficient
    eta = 0.78                                # required: average efficiency, (0, 1]
    battery_kwh = 124                         # EV, required: usable battery capacity
    aux_power_kw = 0.0                        # EV, optional: auxiliary load [kW]
    fuel_lhv_mj_per_l = 35.8                  # ICE, required: fuel lower heating value
    idle_fuel_lph = 0.0                       # ICE, optional: idle fuel rate [l/h]
    ice_braking = "no-credit"                 # ICE, optional: "no-credit" (default) or "paper"
    tank_l = 400                              # ICE, optional: usable tank volume [l]

    [sources]                                  # optional: where each number comes from
    cda_m2 = "paper, section 5.1"
"""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import numpy as np

from cevm.core.cycle import CycleVector
from cevm.errors import InputError
from cevm.units import J_PER_KWH, J_PER_MJ, S_PER_H
from cevm.core.model import (
    ICE_BRAKING_DEFAULT,
    ICE_BRAKING_MODES,
    Prediction,
    battery_energy_from_wheel_j,
    braking_weight,
    fuel_from_wheel_energy_l,
    wheel_energy_j,
)

Powertrain = Literal["ev", "ice"]


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
    kerb_mass_kg: float | None = None
    max_gross_kg: float | None = None
    battery_j: float | None = None  # EV: usable capacity [J]
    aux_power_w: float = 0.0  # EV: auxiliary load from the battery [W]
    fuel_lhv_j_per_l: float | None = None  # ICE: lower heating value [J/l]
    idle_fuel_lps: float = 0.0  # ICE: idle fuel rate [l/s]
    ice_braking: str = ICE_BRAKING_DEFAULT
    tank_l: float | None = None
    sources: dict = field(default_factory=dict, compare=False)
    extra: dict = field(default_factory=dict, compare=False)  # tables for other models

    @property
    def is_ev(self) -> bool:
        return self.powertrain == "ev"

    def with_payload(self, payload_kg: float) -> Vehicle:
        """This vehicle at kerb mass + ``payload_kg``."""
        if self.kerb_mass_kg is None:
            raise ValueError(f"vehicle {self.name!r} has no kerb_mass_kg, so a payload cannot be added")
        return replace(self, mass_kg=self.kerb_mass_kg + payload_kg)


_COMMON_KEYS = {
    "name",
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
}
_EV_KEYS = {"battery_kwh", "aux_power_kw"}
_ICE_KEYS = {"fuel_lhv_mj_per_l", "idle_fuel_lph", "ice_braking", "tank_l"}
#: Tables other models may read (e.g. the detailed simulator); kept, not validated here.
EXTRA_TABLES = {"detailed"}


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
    return value


def vehicle_from_mapping(data: dict[str, Any], source: str = "<vehicle>") -> Vehicle:
    """Validate a parsed vehicle file and build a :class:`Vehicle`.

    Raises :class:`~cevm.errors.InputError` naming ``source`` and the key for a missing,
    unknown or out-of-range key.
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

    common = dict(
        name=name.strip(),
        powertrain=pt,
        mass_kg=mass,
        kerb_mass_kg=kerb,
        max_gross_kg=max_gross,
        cda_m2=_number(data, "cda_m2", source, required=True, lo=0.0),
        cr=_number(data, "cr", source, required=True, lo=0.0, hi=0.1),
        eta=_number(data, "eta", source, required=True, lo=0.0, hi=1.0, lo_open=True),
        sources=dict(data.get("sources", {})),
        extra={k: data[k] for k in EXTRA_TABLES if k in data},
    )
    if pt == "ev":
        battery = _number(data, "battery_kwh", source, required=True, lo=0.0, lo_open=True)
        aux = _number(data, "aux_power_kw", source, required=False, lo=0.0) or 0.0
        return Vehicle(**common, battery_j=battery * J_PER_KWH, aux_power_w=aux * 1e3)
    lhv = _number(data, "fuel_lhv_mj_per_l", source, required=True, lo=0.0, lo_open=True)
    idle = _number(data, "idle_fuel_lph", source, required=False, lo=0.0) or 0.0
    braking = data.get("ice_braking", ICE_BRAKING_DEFAULT)
    if braking not in ICE_BRAKING_MODES:
        raise InputError(source, f"key 'ice_braking' must be one of {', '.join(ICE_BRAKING_MODES)}; got {braking!r}")
    tank = _number(data, "tank_l", source, required=False, lo=0.0, lo_open=True)
    return Vehicle(
        **common,
        fuel_lhv_j_per_l=lhv * J_PER_MJ,
        idle_fuel_lps=idle / S_PER_H,
        ice_braking=braking,
        tank_l=tank,
    )


def predict(vector: CycleVector, vehicle: Vehicle, mass_kg=None, *, ice_braking: str | None = None) -> Prediction:
    """Predict one vehicle over one cycle vector for one or many masses.

    Parameters
    ----------
    vector : the cycle's vector
    vehicle : the vehicle
    mass_kg : gross mass(es) [kg]; default the vehicle's ``mass_kg``
    ice_braking : override the vehicle's ICE braking mode ("paper" or "no-credit")
    """
    m = vehicle.mass_kg if mass_kg is None else mass_kg
    # a scalar stays a Python float: the engine's scalar path is ~15x faster per call
    m = float(m) if np.ndim(m) == 0 else np.asarray(m, dtype=np.float64)
    if vehicle.is_ev:
        e_wheel = wheel_energy_j(vector, m, vehicle.cda_m2, vehicle.cr, vehicle.eta * vehicle.eta)
        energy = battery_energy_from_wheel_j(e_wheel, vehicle.eta, vehicle.aux_power_w, vector.duration_s)
        return Prediction(mass_kg=np.asarray(m), wheel_energy_j=e_wheel, energy_j=energy, fuel_l=None)
    w = braking_weight(ice_braking or vehicle.ice_braking)
    e_wheel = wheel_energy_j(vector, m, vehicle.cda_m2, vehicle.cr, w)
    fuel = fuel_from_wheel_energy_l(
        e_wheel, vehicle.eta, vehicle.fuel_lhv_j_per_l, vehicle.idle_fuel_lps, vector.idle_s
    )
    return Prediction(mass_kg=np.asarray(m), wheel_energy_j=e_wheel, energy_j=None, fuel_l=fuel)
