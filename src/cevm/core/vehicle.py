"""Vehicle parameters (pure): the frozen :class:`Vehicle`, what a calibration saw
(:class:`FitDomain`), the plausibility bounds of its numbers (:data:`PLAUSIBLE`), and
predictions of one vehicle over a cycle vector.

Vehicle files (TOML) are read and validated by :mod:`cevm.io.vehicles`, whose
docstring lists their keys; the model these parameters feed is :mod:`cevm.core.energy`.

Plausibility bounds
-------------------
Every number of a vehicle file is checked against :data:`PLAUSIBLE`, bounds no road
vehicle leaves (a value outside is a unit mistake or a typo, such as
``kerb_mass_kg = 1e20``): masses 20-200,000 kg, CdA 0.05-30 m^2, Cr 0.001-0.1, eta
0.05-1, battery 0.1-5,000 kWh, tank 1-5,000 l, fuel heating value 3-50 MJ/l, auxiliary
power up to 200 kW, fuel rates up to 50-100 l/h, rated power 0.1-5,000 kW, top speed
5-400 km/h.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np

from cevm.core import energy
from cevm.core.cycle import CycleVector
from cevm.core.model import (
    ICE_BRAKING_DEFAULT,
    Prediction,
    braking_weight,
    wheel_energy_j,
)
from cevm.core.terms import TERMS_BY_POWERTRAIN
from cevm.core.uncertainty import Posterior, Priors

Powertrain = Literal["ev", "ice"]


@dataclass(frozen=True)
class FitDomain:
    """What a calibration saw: the ``[calibration]`` table :func:`cevm.core.calibration`
    results write into a vehicle file, read back so that predictions outside it are
    warned about (:func:`domain_warnings`).

    Ranges are (low, high) over the trips the fit used, SI: ``ambient_c`` [degC, trip
    means], ``mean_speed_mps`` [m/s, distance / duration], ``mass_kg`` [kg],
    ``distance_m`` [m]; None where the trips did not say (no temperature logged).
    ``idle_share`` [-] the trips' time at standstill over their duration (their duty);
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
    idle_share: tuple[float, float] | None = None


#: How far outside a calibration's range a prediction may go before it is warned about:
#: temperature [K] beyond the trips' coldest and warmest means, and relative margins on
#: mass and mean speed (a fit does not know what it did not see).
DOMAIN_MARGIN_K = 3.0
DOMAIN_MARGIN_MASS = 0.10
DOMAIN_MARGIN_SPEED = 0.25
#: ... and an absolute margin on the share of time at standstill (a duty with many more
#: stops, or none, than the trips had).
DOMAIN_MARGIN_IDLE_SHARE = 0.10

#: What a prediction can lie outside of (:func:`extrapolation_mask`), in column order.
EXTRAPOLATION_AXES = ("temperature", "mass", "speed", "duty")


def extrapolation_mask(domain: FitDomain | None, *, mass_kg=None, ambient_c=None, mean_speed_mps=None,
                       idle_share=None) -> np.ndarray:
    """Per prediction, a bit per axis of :data:`EXTRAPOLATION_AXES` set where it lies
    outside what the calibration ``domain`` saw (with the margins of
    :func:`domain_warnings`); 0 everywhere without a domain. Arguments broadcast."""
    args = [np.asarray(x, dtype=np.float64) for x in (mass_kg, ambient_c, mean_speed_mps, idle_share)
            if x is not None]
    shape = np.broadcast(*args).shape if args else ()
    out = np.zeros(shape, dtype=np.int64)
    if domain is None:
        return out
    if ambient_c is not None and domain.ambient_c is not None:
        lo, hi = domain.ambient_c
        t = np.asarray(ambient_c, dtype=np.float64)
        out |= np.broadcast_to(((t < lo - DOMAIN_MARGIN_K) | (t > hi + DOMAIN_MARGIN_K)), shape).astype(np.int64)
    if mass_kg is not None and domain.mass_kg is not None:
        lo, hi = domain.mass_kg
        m = np.asarray(mass_kg, dtype=np.float64)
        bad = (m < lo * (1 - DOMAIN_MARGIN_MASS)) | (m > hi * (1 + DOMAIN_MARGIN_MASS))
        out |= np.broadcast_to(bad, shape).astype(np.int64) << 1
    if mean_speed_mps is not None and domain.mean_speed_mps is not None:
        lo, hi = domain.mean_speed_mps
        v = np.asarray(mean_speed_mps, dtype=np.float64)
        bad = (v < lo * (1 - DOMAIN_MARGIN_SPEED)) | (v > hi * (1 + DOMAIN_MARGIN_SPEED))
        out |= np.broadcast_to(bad, shape).astype(np.int64) << 2
    if idle_share is not None and domain.idle_share is not None:
        lo, hi = domain.idle_share
        x = np.asarray(idle_share, dtype=np.float64)
        bad = (x < lo - DOMAIN_MARGIN_IDLE_SHARE) | (x > hi + DOMAIN_MARGIN_IDLE_SHARE)
        out |= np.broadcast_to(bad, shape).astype(np.int64) << 3
    return out


def extrapolation_text(mask: int) -> str:
    """"none", or the axes of :data:`EXTRAPOLATION_AXES` a mask sets, joined by "+"."""
    names = [a for i, a in enumerate(EXTRAPOLATION_AXES) if int(mask) >> i & 1]
    return "+".join(names) if names else "none"


def domain_warnings(vehicle: Vehicle, *, mass_kg=None, ambient_c=None, mean_speed_mps=None,
                    idle_share=None) -> list[str]:
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
        if m.size and (float(m.min()) < lo * (1 - DOMAIN_MARGIN_MASS)
                       or float(m.max()) > hi * (1 + DOMAIN_MARGIN_MASS)):
            out.append(f"{label} at {lo:,.0f} to {hi:,.0f} kg; asked at {_span(m, 0)} kg: an extrapolation")
    if mean_speed_mps is not None and d.mean_speed_mps is not None:
        v = np.asarray(mean_speed_mps, dtype=np.float64)
        lo, hi = d.mean_speed_mps
        if v.size and (float(v.min()) < lo * (1 - DOMAIN_MARGIN_SPEED)
                       or float(v.max()) > hi * (1 + DOMAIN_MARGIN_SPEED)):
            out.append(f"{label} at mean speeds of {3.6 * lo:.1f} to {3.6 * hi:.1f} km/h; asked at "
                       f"{_span(3.6 * v, 1)} km/h: a different duty")
    if idle_share is not None and d.idle_share is not None:
        x = np.asarray(idle_share, dtype=np.float64)
        lo, hi = d.idle_share
        if x.size and (float(x.min()) < lo - DOMAIN_MARGIN_IDLE_SHARE
                       or float(x.max()) > hi + DOMAIN_MARGIN_IDLE_SHARE):
            out.append(f"{label} standing still {100 * lo:.0f} to {100 * hi:.0f} % of the time; asked at "
                       f"{_span(100 * x, 0)} %: a different duty")
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
    vehicle_class: str | None = None  # "bus", "truck", "van", "car", "quadricycle" (priors)
    priors: Priors | None = field(default=None, compare=False)  # the class defaults and the file's [prior]
    posterior: Posterior | None = field(default=None, compare=False)  # what a calibration learnt
    # the terms (cevm.core.terms names) its file leaves out, at their class prior's central value
    from_prior: tuple[str, ...] = ()
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

def coefficient(vehicle: Vehicle, term: str) -> float:
    """The coefficient of ``term`` at the vehicle's values (the model is linear in its
    coefficients, :mod:`cevm.core.uncertainty`): 1/eta for eta, 1/eta_k - 1/eta for the
    kinetic term, the field's own value for the others; NaN for an EV's regeneration
    tied to eta."""
    if term == "eta":
        return 1.0 / float(vehicle.eta)
    if term == "kin":
        return 0.0 if vehicle.kinetic_eta is None else 1.0 / vehicle.kinetic_eta - 1.0 / vehicle.eta
    if term == "regen":
        return math.nan if vehicle.regen_eta is None else float(vehicle.regen_eta)
    return float(getattr(vehicle, TERMS_BY_POWERTRAIN[(vehicle.powertrain, term)].field))


def coefficients(vehicle: Vehicle, terms: Sequence[str]) -> np.ndarray:
    """:func:`coefficient` of each of ``terms``."""
    return np.array([coefficient(vehicle, t) for t in terms], dtype=np.float64)


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
