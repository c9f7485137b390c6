"""Reading vehicle files (TOML): validation of their keys into a
:class:`cevm.core.vehicle.Vehicle` (configuration parsing stays out of the pure core),
and loading one or many files.

A vehicle's id (what rows and legends call it) is the file's ``id`` key, else the
file's stem (``configs/vehicles/diesel-hgv.toml`` -> ``diesel-hgv``). Vehicles loaded
together must have different ids: two calibrations of one vehicle are told apart by them.

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
    aux_power_kw = 0.0                        # EV, optional: auxiliary load [kW]; left out:
                                              #   its class prior's central value (below)
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

    class = "bus"                              # optional: bus, truck, van, car, quadricycle:
                                               #   whose priors the terms start from (default:
                                               #   inferred from the mass, and said so)
    [prior]                                    # optional: ranges [low, high] that override
    eta = [0.75, 0.85]                         #   the class's (:mod:`cevm.io.priors`)

    A term every vehicle has (:data:`cevm.core.terms.PHYSICAL`: an EV's aux_power_kw,
    aux_heating_kw_per_k, aux_cooling_kw_per_k; an ICE's idle_fuel_lph,
    heating_fuel_lph_per_k, cooling_fuel_lph_per_k) that the file leaves out is not zero:
    it takes the middle of its class's prior range (or of the file's [prior] range), and
    its spread widens the intervals; rows list such terms (column from_prior). A stated
    value, zero included, is the file's. The other optional terms are off where left out.

    [calibration]                              # written by cevm calibrate: what the fit saw
    terms = ["eta", "aux", "heat"]             #   (see :class:`FitDomain`)
    [posterior]                                # written by cevm calibrate: what it learnt
    terms = ["eta", "aux", "heat"]             #   (standard deviations, correlations, the
                                               #   trips' scatter: :mod:`cevm.io.priors`)

Every number is checked against :data:`cevm.core.vehicle.PLAUSIBLE` (bounds no road
vehicle leaves); the error names the file and the key.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any, Literal, overload

from cevm.core import energy
from cevm.core.model import ICE_BRAKING_DEFAULT, ICE_BRAKING_MODES
from cevm.core.vehicle import PLAUSIBLE, FitDomain, Vehicle
from cevm.errors import InputError
from cevm.io.priors import posterior_from_mapping, priors_from_mapping, with_prior_values
from cevm.io.toml import read_toml
from cevm.text import printable
from cevm.units import J_PER_KWH, J_PER_MJ, S_PER_H

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
    "class",
    "prior",
    "posterior",
}
_EV_KEYS = {"battery_kwh", "aux_power_kw", "regen_eta", "aux_heating_kw_per_k", "aux_cooling_kw_per_k",
            "warmup_kwh_per_k"}
_ICE_KEYS = {"fuel_lhv_mj_per_l", "idle_fuel_lph", "ice_braking", "tank_l", "running_fuel_lph", "kinetic_eta",
             "heating_fuel_lph_per_k", "cooling_fuel_lph_per_k", "warmup_fuel_l_per_k"}
#: Tables other models may read (the detailed simulator's [detailed]; [[reference]],
#: published consumption ranges: cevm vehicle show, tests/test_shipped_vehicles.py);
#: kept, not validated here.
EXTRA_TABLES = {"detailed", "reference"}

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


@overload
def _number(data: dict, key: str, source: str, *, required: Literal[True], lo: float | None = None,
            hi: float | None = None, lo_open: bool = False) -> float: ...
@overload
def _number(data: dict, key: str, source: str, *, required: bool, lo: float | None = None,
            hi: float | None = None, lo_open: bool = False) -> float | None: ...
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
    """Validate a parsed vehicle file and build a :class:`Vehicle`, with its priors (its
    class's defaults and its ``[prior]`` table), the terms every vehicle has that the
    file leaves out at their prior's central value (:func:`cevm.io.priors.
    with_prior_values`; a stated value, zero too, is kept) and, for a calibrated file, its
    posterior (:mod:`cevm.io.priors`).

    The vehicle's ``id`` is the file's ``id`` key, else ``default_id`` (the file's stem,
    :func:`load_vehicle`), else None (rows then use the name). Raises
    :class:`~cevm.errors.InputError` naming ``source`` and the key for a missing,
    unknown, out-of-range or implausible key (:data:`cevm.core.vehicle.PLAUSIBLE`).
    """

    v = _vehicle_values(data, source, default_id=default_id)
    if "detailed" in data:  # one rule in every command: what simulate refuses, predict does not take
        from cevm.io.detailed import detailed_params

        detailed_params(v, source)
    priors = priors_from_mapping(data, v.powertrain, v.mass_kg, source)
    v = with_prior_values(replace(v, vehicle_class=priors.vehicle_class, priors=priors), data)
    return replace(v, posterior=posterior_from_mapping(data.get("posterior"), v, priors, source))


def _vehicle_values(data: dict[str, Any], source: str = "<vehicle>", *,
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
    if mass is not None and payload is not None:
        raise InputError(source, "key 'payload_kg' goes with 'kerb_mass_kg', not with 'mass_kg'")
    if mass is None:
        if kerb is None:
            raise InputError(source, "missing required key 'mass_kg' (or 'kerb_mass_kg')")
        mass = kerb + (payload or 0.0)
    max_gross = _number(data, "max_gross_kg", source, required=False, lo=0.0, lo_open=True)
    if max_gross is not None and mass > max_gross:
        raise InputError(source, f"default mass {mass:g} kg exceeds key 'max_gross_kg' = {max_gross:g}")
    vid: str | None
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
        mass_sources=opt_str("mass_sources"), idle_share=_pair(table, "idle_share", source),
    )


def stem_id(path: str | Path) -> str:
    """The id a vehicle file without an ``id`` key gets: its stem, with any control
    character escaped (a file name cannot forge output)."""
    return printable(Path(path).stem)


def load_vehicle(path: str | Path) -> Vehicle:
    """Read and validate a vehicle TOML file (keys: see the module docstring)."""
    return vehicle_from_mapping(read_toml(path, "vehicle file"), str(path), default_id=stem_id(path))


def load_vehicles(paths: Sequence[str | Path]) -> list[Vehicle]:
    """Load vehicle files; a directory contributes its ``*.toml`` files, sorted. Raises
    :class:`InputError` when two of them have the same id."""
    out: list[Vehicle] = []
    where: dict[str | None, Path] = {}
    for p in paths:
        p = Path(p)
        if p.is_dir():
            files = sorted(p.glob("*.toml"))
            if not files:
                raise InputError(p, "directory holds no vehicle files (*.toml)")
        else:
            files = [p]
        for f in files:
            v = load_vehicle(f)
            if v.id in where:
                raise InputError(f, f"vehicle id {v.id!r} is also the id of {where[v.id]}: give one of them "
                                    "another 'id' key (rows and legends tell vehicles apart by it)")
            where[v.id] = f
            out.append(v)
    return out
