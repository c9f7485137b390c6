"""The CE model's terms beyond the wheel, as data (pure): each term's vehicle field,
file key and unit, physical range, and what the data need to tell it.

Every term of :mod:`cevm.core.energy` is, for fixed CdA and Cr, linear in a
*coefficient* that multiplies a per-trip *feature* (the table in
:mod:`cevm.core.calibration.terms`); :mod:`cevm.core.uncertainty` puts priors and
posteriors on those coefficients, :mod:`cevm.core.calibration` fits them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from cevm.units import J_PER_KWH, S_PER_H


@dataclass(frozen=True)
class Term:
    """One fittable term: its names, units, bounds, and what the data need for it.

    ``bounds`` bound the coefficient in the fit; ``plausible`` is the range of the
    vehicle field's value (SI) outside which a fitted value is refused as physically
    implausible. ``display`` = (unit, factor from SI); ``file`` = (vehicle-file key,
    factor from SI).
    """

    name: str
    field: str
    powertrains: tuple[str, ...]
    label: str
    display: tuple[str, float]
    file: tuple[str, float]
    bounds: tuple[float, float]
    plausible: tuple[float, float]
    hint: str
    temperature: bool = False
    linear: bool = True


_INF = math.inf
#: The highest drive (and regeneration) efficiency of an EV from battery to wheel: see
#: the notes of the term list.
EV_ETA_MAX = 0.89


def _terms() -> dict[tuple[str, str], Term]:
    out: dict[tuple[str, str], Term] = {}
    for t in _TERM_LIST:
        for pt in t.powertrains:
            out[(pt, t.name)] = t
    return out


_TERM_LIST: tuple[Term, ...] = (
    # plausible efficiencies (the truncation of their priors, :mod:`cevm.core.uncertainty`):
    # battery to wheel, the best motor, inverter and gear together reach about 0.92 over a
    # cycle and the battery's discharge 0.97, so no EV exceeds 0.92 x 0.97 = 0.89 (and a
    # calibration above it has measured less than its wheels needed); regeneration runs
    # through the same chain backwards, so the same 0.89. Tank to wheel, the best truck
    # diesels reach 0.46 brake efficiency at their best point (0.5 with the Willans line's
    # marginal efficiency, idle and friction apart), times the driveline's ~0.95: 0.55.
    # The rates' upper bounds are the vehicle files' plausibility bounds
    # (:data:`cevm.core.vehicle.PLAUSIBLE`) in SI.
    Term("eta", "eta", ("ev",), "drive efficiency", ("", 1.0), ("eta", 1.0), (1.0, 20.0),
         (0.3, EV_ETA_MAX), "every trip informs it"),
    Term("eta", "eta", ("ice",), "drive efficiency", ("", 1.0), ("eta", 1.0), (1.0, 20.0),
         (0.1, 0.55), "every trip informs it"),
    Term("regen", "regen_eta", ("ev",), "regeneration efficiency", ("", 1.0), ("regen_eta", 1.0), (0.0, 1.0),
         (0.0, EV_ETA_MAX), "trips must differ in the share of braking and descent"),
    Term("aux", "aux_power_w", ("ev",), "auxiliary power", ("kW", 1e-3), ("aux_power_kw", 1e-3), (0.0, _INF),
         (0.0, 200e3), "trips must differ in average speed or mass (aux energy grows with duration)"),
    Term("heat", "aux_heating_w_per_k", ("ev",), "heating power per K", ("kW/K", 1e-3),
         ("aux_heating_kw_per_k", 1e-3), (0.0, _INF), (0.0, 10e3),
         "needs trips colder than the heating balance temperature, at several temperatures", temperature=True),
    Term("cool", "aux_cooling_w_per_k", ("ev",), "A/C power per K", ("kW/K", 1e-3), ("aux_cooling_kw_per_k", 1e-3),
         (0.0, _INF), (0.0, 10e3), "needs trips warmer than the cooling balance temperature, at several temperatures",
         temperature=True),
    Term("warm", "warmup_j_per_k", ("ev",), "warm-up energy per start per K", ("kWh/K", 1 / J_PER_KWH),
         ("warmup_kwh_per_k", 1 / J_PER_KWH), (0.0, _INF), (0.0, 10.0 * J_PER_KWH),
         "needs cold trips of different lengths", temperature=True),
    Term("kin", "kinetic_eta", ("ice",), "efficiency on kinetic energy", ("", 1.0), ("kinetic_eta", 1.0),
         (-_INF, _INF), (0.05, 0.8), "trips must differ in the kinetic share of their wheel energy (duty)"),
    Term("idle", "idle_fuel_lps", ("ice",), "idle fuel rate", ("l/h", S_PER_H), ("idle_fuel_lph", S_PER_H),
         (0.0, _INF), (0.0, 8.0 / S_PER_H), "trips must differ in their share of time at standstill"),
    Term("run", "running_fuel_lps", ("ice",), "running fuel rate", ("l/h", S_PER_H), ("running_fuel_lph", S_PER_H),
         (0.0, _INF), (0.0, 30.0 / S_PER_H), "trips must differ in average speed (engine time per wheel work)"),
    Term("heat", "heating_fuel_lps_per_k", ("ice",), "heating fuel per K", ("l/h/K", S_PER_H),
         ("heating_fuel_lph_per_k", S_PER_H), (0.0, _INF), (0.0, 5.0 / S_PER_H),
         "needs trips colder than the heating balance temperature, at several temperatures", temperature=True),
    Term("cool", "cooling_fuel_lps_per_k", ("ice",), "A/C fuel per K", ("l/h/K", S_PER_H),
         ("cooling_fuel_lph_per_k", S_PER_H), (0.0, _INF), (0.0, 5.0 / S_PER_H),
         "needs trips warmer than the cooling balance temperature, at several temperatures", temperature=True),
    Term("warm", "warmup_fuel_l_per_k", ("ice",), "cold-start fuel per K", ("l/K", 1.0), ("warmup_fuel_l_per_k", 1.0),
         (0.0, _INF), (0.0, 5.0), "needs cold trips of different lengths", temperature=True),
    Term("cda", "cda_m2", ("ev", "ice"), "drag area", ("m2", 1.0), ("cda_m2", 1.0), (1e-6, _INF), (0.05, 30.0),
         "trips must differ in speed (drag energy grows with v^2 per metre)", linear=False),
    Term("cr", "cr", ("ev", "ice"), "rolling coefficient", ("", 1.0), ("cr", 1.0), (0.0, 0.1), (0.001, 0.05),
         "trips must differ in mass and speed mix (rolling energy grows with m per metre)", linear=False),
)
#: (powertrain, term name) -> :class:`Term`.
TERMS_BY_POWERTRAIN = _terms()
#: The energy terms (not cda, cr) a calibration chooses among, per powertrain, in the
#: order of their physical priority; "eta" is always fitted.
EXTRA_TERMS = {"ev": ("regen", "aux", "heat", "cool", "warm"), "ice": ("idle", "run", "kin", "heat", "cool", "warm")}

#: The terms that change what the others mean, or describe an effect a vehicle may lack:
#: a calibration chooses them (:mod:`cevm.core.calibration.selection`). The others of
#: :data:`EXTRA_TERMS` (an EV's auxiliary power, heating and air conditioning; an ICE's
#: idle, heating and cooling fuel) every vehicle has: with a prior, they are always in its
#: model.
STRUCTURAL = {"ev": ("regen", "warm"), "ice": ("run", "kin", "warm")}
#: The terms every vehicle has (:data:`EXTRA_TERMS` less :data:`STRUCTURAL`): an EV's
#: auxiliary power, heating and A/C; an ICE's idle fuel, heating and cooling fuel. A vehicle
#: file that leaves one of them out has it at its class prior's central value, not at zero
#: (:func:`cevm.io.priors.with_prior_values`): a car with no heating key still heats in the
#: cold. The structural terms stay out where a file leaves them out: they change what eta
#: means (a running-fuel offset, a kinetic efficiency apart from eta, a regeneration apart
#: from it) or describe an effect a vehicle may lack (a warm-up per start).
PHYSICAL = {pt: tuple(n for n in names if n not in STRUCTURAL[pt]) for pt, names in EXTRA_TERMS.items()}

# Plausible rates: a heavy truck's diesel idles at 1.5-4 l/h (up to about 6 with the cab
# heated or cooled at idle), so 8 l/h is several times any idle; its engine friction and
# engine-driven auxiliaries at driving speeds burn a few l/h, 30 l/h is beyond any.

#: Names a user may type for a term (old parameter names and vehicle fields included).
ALIASES = {
    "aux_power": "aux", "aux_power_w": "aux", "idle_fuel": "idle", "idle_fuel_lps": "idle", "cda_m2": "cda",
    "regen_eta": "regen", "regeneration": "regen", "heating": "heat", "cooling": "cool", "warmup": "warm",
    "running": "run", "running_fuel": "run", "running_fuel_lps": "run", "kinetic": "kin", "kinetic_eta": "kin",
    "aux_heating_w_per_k": "heat", "aux_cooling_w_per_k": "cool", "warmup_j_per_k": "warm",
    "heating_fuel_lps_per_k": "heat", "cooling_fuel_lps_per_k": "cool", "warmup_fuel_l_per_k": "warm",
}
