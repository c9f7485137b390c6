"""A vehicle file's ``[detailed]`` table read into the detailed model's parameters
(:class:`~cevm.core.detailed.EvParams`, :class:`~cevm.core.detailed.DieselParams`).

The table speaks the file's units (kW, rpm, km/h, litres, bar); the parameters are SI.
Every key is checked here, and a problem is reported in the file's terms, naming the
key (:class:`~cevm.errors.InputError`); the parameters' own limits are the core's
(:data:`cevm.core.detailed.EV_LIMITS`, :data:`~cevm.core.detailed.DIESEL_LIMITS`).
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Mapping
from typing import Any

from cevm.core.detailed import DieselParams, EvParams
from cevm.core.detailed.params import SEQ, limits_of, param_problem, range_problem
from cevm.errors import InputError
from cevm.units import KMH_TO_MPS, M3_PER_L, PA_PER_BAR, RAD_S_PER_RPM, W_PER_KW

EV_KEYS: dict[str, tuple[str, float]] = {
    "wheel_radius_m": ("wheel_radius_m", 1.0),
    "gear_ratio": ("gear_ratio", 1.0),
    "final_drive_ratio": ("final_drive_ratio", 1.0),
    "transmission_efficiency": ("transmission_efficiency", 1.0),
    "motor_peak_power_kw": ("motor_peak_power_w", W_PER_KW),
    "motor_peak_torque_nm": ("motor_peak_torque_nm", 1.0),
    "motor_max_speed_rpm": ("motor_max_speed_rad_s", RAD_S_PER_RPM),
    "copper_loss_frac": ("copper_loss_frac", 1.0),
    "iron_loss_frac": ("iron_loss_frac", 1.0),
    "windage_loss_frac": ("windage_loss_frac", 1.0),
    "constant_loss_frac": ("constant_loss_frac", 1.0),
    "regen_max_power_kw": ("regen_max_power_w", W_PER_KW),
    "regen_max_torque_nm": ("regen_max_torque_nm", 1.0),
    "regen_fade_low_kmh": ("regen_fade_low_mps", KMH_TO_MPS),
    "regen_fade_high_kmh": ("regen_fade_high_mps", KMH_TO_MPS),
    "cells_in_series": ("cells_in_series", 1.0),
    "ocv_soc": ("ocv_soc", 1.0),
    "ocv_cell_v": ("ocv_cell_v", 1.0),
    "internal_resistance_ohm": ("internal_resistance_ohm", 1.0),
    "aux_base_power_kw": ("aux_base_power_w", W_PER_KW),
    "hvac_power_kw": ("hvac_power_w", W_PER_KW),
    "wheel_inertia_kgm2": ("wheel_inertia_kgm2", 1.0),
    "motor_inertia_kgm2": ("motor_inertia_kgm2", 1.0),
}
"""Keys of an EV's ``[detailed]`` table: key -> (:class:`EvParams` field, factor to SI;
for a list, of each element)."""

DIESEL_KEYS: dict[str, tuple[str, float]] = {
    "wheel_radius_m": ("wheel_radius_m", 1.0),
    "gear_ratios": ("gear_ratios", 1.0),
    "axle_ratio": ("axle_ratio", 1.0),
    "gear_efficiencies": ("gear_efficiencies", 1.0),
    "axle_efficiency": ("axle_efficiency", 1.0),
    "displacement_l": ("displacement_m3", M3_PER_L),
    "idle_speed_rpm": ("idle_speed_rad_s", RAD_S_PER_RPM),
    "max_speed_rpm": ("max_speed_rad_s", RAD_S_PER_RPM),
    "full_load_speed_rpm": ("full_load_speed_rad_s", RAD_S_PER_RPM),
    "full_load_torque_nm": ("full_load_torque_nm", 1.0),
    "fmep0_bar": ("fmep0_pa", PA_PER_BAR),
    "fmep1_bar": ("fmep1_pa", PA_PER_BAR),
    "fmep2_bar": ("fmep2_pa", PA_PER_BAR),
    "indicated_efficiency_max": ("indicated_efficiency_max", 1.0),
    "indicated_efficiency_speed_drop": ("indicated_efficiency_speed_drop", 1.0),
    "best_efficiency_speed_rpm": ("best_efficiency_speed_rad_s", RAD_S_PER_RPM),
    "indicated_efficiency_load_drop": ("indicated_efficiency_load_drop", 1.0),
    "aux_power_kw": ("aux_power_w", W_PER_KW),
    "shift_low_rpm": ("shift_low_speed_rad_s", RAD_S_PER_RPM),
    "shift_high_rpm": ("shift_high_speed_rad_s", RAD_S_PER_RPM),
    "wheel_inertia_kgm2": ("wheel_inertia_kgm2", 1.0),
    "engine_inertia_kgm2": ("engine_inertia_kgm2", 1.0),
}
"""Keys of a diesel's ``[detailed]`` table: key -> (:class:`DieselParams` field, factor
to SI; for a list, of each element)."""


def _value(key: str, value: Any, scale: float, limits, source: str):
    """One key's value in SI: a number within the field's limits, or a list of numbers."""
    if limits == SEQ:
        if not isinstance(value, (list, tuple)) or any(
            isinstance(x, bool) or not isinstance(x, (int, float)) for x in value
        ):
            raise InputError(source, f"[detailed] key '{key}' must be a list of numbers, got {value!r}")
        return tuple(float(x) * scale for x in value)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InputError(source, f"[detailed] key '{key}' must be a finite number, got {value!r}")
    problem = range_problem(float(value), *limits)
    if problem:
        raise InputError(source, f"[detailed] key '{key}' = {value!r} {problem}")
    return float(value) * scale


def _unchecked(cls, kwargs: dict):
    """An instance of a parameter dataclass built without running its checks."""
    obj = object.__new__(cls)
    for f in cls.__dataclass_fields__.values():
        object.__setattr__(obj, f.name, kwargs.get(f.name, f.default))
    return obj


def params_from_table(cls, keys: dict, table: Any, source: str):
    """``cls`` (:class:`EvParams` or :class:`DieselParams`) from a ``[detailed]`` table
    whose keys are ``keys`` (:data:`EV_KEYS` or :data:`DIESEL_KEYS`); the defaults for
    an absent table (None) and for absent keys. InputError naming ``source`` and the
    key for an unknown key or a bad value."""
    if table is None:
        return cls()
    if not isinstance(table, Mapping):
        raise InputError(source, "[detailed] must be a table of keys")
    limits = limits_of(cls)
    kwargs: dict[str, Any] = {}
    for key, value in table.items():
        if key not in keys:
            close = difflib.get_close_matches(key, sorted(keys), n=1)
            hint = f" (did you mean '{close[0]}'?)" if close else ""
            raise InputError(source, f"unknown key '{key}' in [detailed]{hint}")
        name, scale = keys[key]
        kwargs[name] = _value(key, value, scale, limits[name], source)
    found = param_problem(_unchecked(cls, kwargs))
    if found:
        # Speak the file's language: TOML keys, not dataclass fields.
        to_key = {spec[0]: k for k, spec in keys.items()}
        field_name, message = found
        for f in sorted(to_key, key=len, reverse=True):
            message = message.replace(f, to_key[f])
        raise InputError(source, f"[detailed] key '{to_key.get(field_name, field_name)}' {message}")
    return cls(**kwargs)


def ev_params_from_vehicle(vehicle, source: str | None = None) -> EvParams:
    """:class:`EvParams` from an EV's ``[detailed]`` table (defaults for absent keys).

    Raises :class:`~cevm.errors.InputError` naming ``source`` (default: the vehicle's
    name) and the key for an unknown key or a bad value.
    """
    if not vehicle.is_ev:
        raise ValueError(f"vehicle {vehicle.name!r} is not an EV")
    return params_from_table(EvParams, EV_KEYS, vehicle.extra.get("detailed"), source or vehicle.name)


def diesel_params_from_vehicle(vehicle, source: str | None = None) -> DieselParams:
    """:class:`DieselParams` from an ICE vehicle's ``[detailed]`` table (see
    :func:`ev_params_from_vehicle`)."""
    if vehicle.is_ev:
        raise ValueError(f"vehicle {vehicle.name!r} is not an ICE vehicle")
    return params_from_table(DieselParams, DIESEL_KEYS, vehicle.extra.get("detailed"), source or vehicle.name)


def detailed_params(vehicle, source: str | None = None) -> EvParams | DieselParams:
    """The powertrain of ``vehicle`` for :func:`cevm.core.detailed.simulate`: its
    ``[detailed]`` table read by :func:`ev_params_from_vehicle` or
    :func:`diesel_params_from_vehicle`, as its powertrain is."""
    if vehicle.is_ev:
        return ev_params_from_vehicle(vehicle, source)
    return diesel_params_from_vehicle(vehicle, source)
