"""The prediction set of a sweep (vehicles x masses, flat) and each row's terms beyond
the wheel energy (ambient temperature, auxiliary power, warm-up, an ICE's extra fuel).

A :class:`PredictionSet` is the flat list of (vehicle, mass) predictions of a sweep,
vehicle by vehicle, with each vehicle's parameters broadcast to its rows, so that a
million predictions are arrays, never a million Python objects. :func:`row_terms` gives,
per (prediction, source), the terms of :mod:`cevm.core.energy` that do not depend on the
sign of a step.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from cevm.core import energy, physical_inputs
from cevm.core.model import braking_weight
from cevm.core.sweep.sources import Source
from cevm.core.vehicle import Vehicle
from cevm.errors import CevmError

#: Where a prediction's ambient temperature comes from, in order: the run's (given for
#: every prediction), the source's own (a stored trip's logged mean), the vehicle file's
#: ``reference_temp_c``, or :data:`cevm.core.energy.AMBIENT_DEFAULT_C`.
AMBIENT_ORIGINS = ("given", "source", "vehicle reference_temp_c", f"default {energy.AMBIENT_DEFAULT_C:g} degC")


@dataclass(frozen=True, eq=False)
class PredictionSet:
    """The (vehicle, mass) predictions of a sweep, flat, vehicle by vehicle.

    Arrays (P,): ``vehicle_index``, ``mass_kg``, ``payload_kg`` (mass minus kerb mass;
    NaN without ``kerb_mass_kg``), ``over_max_gross``, and each vehicle's parameters
    broadcast to its rows: ``cda_m2``, ``cr``, ``eta``, ``negative_weight`` (eta eta_r
    for an EV, :func:`cevm.core.energy.ev_negative_weight`; 1 or 0 for an ICE by braking
    mode), ``aux_power_w`` (an EV's base auxiliary power p0 only: the terms that depend
    on the temperature and the trip are in :func:`row_terms`), ``battery_j`` (NaN for
    ICE), ``lhv_j_per_l`` (NaN for EV), ``idle_fuel_lps``, ``tank_l`` (NaN if unknown),
    ``is_ev``. ``braking`` holds each vehicle's ICE braking mode in force ("" for EV).
    ``ambient_c``: the ambient temperature of every prediction [degC], or None: each
    source's own, else each vehicle's default (:data:`AMBIENT_ORIGINS`).
    """

    vehicles: tuple[Vehicle, ...]
    vehicle_index: np.ndarray
    mass_kg: np.ndarray
    payload_kg: np.ndarray
    over_max_gross: np.ndarray
    cda_m2: np.ndarray
    cr: np.ndarray
    eta: np.ndarray
    negative_weight: np.ndarray
    aux_power_w: np.ndarray
    battery_j: np.ndarray
    lhv_j_per_l: np.ndarray
    idle_fuel_lps: np.ndarray
    tank_l: np.ndarray
    is_ev: np.ndarray
    braking: tuple[str, ...]
    ambient_c: float | None = None

    @property
    def n(self) -> int:
        return int(self.mass_kg.size)

    @classmethod
    def build(
        cls,
        vehicles: Sequence[Vehicle],
        *,
        mass_kg: Sequence[float] | np.ndarray | None = None,
        payload_kg: Sequence[float] | np.ndarray | None = None,
        ice_braking: str | None = None,
        ambient_c: float | None = None,
    ) -> PredictionSet:
        """Every vehicle at every mass: ``mass_kg`` (gross masses [kg], the same for all
        vehicles), or ``payload_kg`` (each vehicle's kerb mass + payload [kg]; needs
        ``kerb_mass_kg``), or neither (each vehicle's default ``mass_kg``).
        ``ice_braking`` overrides the ICE braking mode of every ICE vehicle; ``ambient_c``
        [degC] is the temperature of every prediction (None: see :data:`AMBIENT_ORIGINS`)."""
        if ambient_c is not None:
            try:
                ambient_c = float(energy.check_ambient_c(ambient_c))
            except ValueError as exc:
                raise CevmError(str(exc)) from None
        if mass_kg is not None and payload_kg is not None:
            raise CevmError("give gross masses or payloads, not both")
        vehicles = tuple(vehicles)
        if not vehicles:
            raise CevmError("no vehicles")
        masses: list[np.ndarray] = []
        if mass_kg is not None:
            m = physical_inputs.masses_for(vehicles, np.asarray(mass_kg, dtype=np.float64).ravel())
            if m.size == 0:
                raise CevmError("no gross masses given")
            masses = [m] * len(vehicles)
        elif payload_kg is not None:
            p = physical_inputs.payloads_kg(np.asarray(payload_kg, dtype=np.float64).ravel())
            if p.size == 0:
                raise CevmError("no payloads given")
            for v in vehicles:
                if v.kerb_mass_kg is None:
                    raise CevmError(f"vehicle {v.name!r} has no kerb_mass_kg, so a payload cannot be added; "
                                    "give gross masses (--mass-kg) instead")
                masses.append(v.kerb_mass_kg + p)
        else:
            masses = [np.array([v.mass_kg]) for v in vehicles]
        counts = np.array([m.size for m in masses])
        vi = np.repeat(np.arange(len(vehicles)), counts)
        mass = np.concatenate(masses)

        def per_vehicle(fn) -> np.ndarray:
            return np.array([fn(v) for v in vehicles], dtype=np.float64)[vi]

        braking = []
        for v in vehicles:
            if v.is_ev:
                braking.append("")
            else:
                mode = ice_braking or v.ice_braking
                braking_weight(mode)  # validates
                braking.append(mode)
        kerb = per_vehicle(lambda v: np.nan if v.kerb_mass_kg is None else v.kerb_mass_kg)
        max_gross = per_vehicle(lambda v: np.inf if v.max_gross_kg is None else v.max_gross_kg)
        is_ev = np.array([v.is_ev for v in vehicles], dtype=bool)[vi]
        eta = per_vehicle(lambda v: v.eta)
        w_ice = np.array([0.0 if v.is_ev else braking_weight(b) for v, b in zip(vehicles, braking, strict=True)])[vi]
        return cls(
            vehicles=vehicles,
            vehicle_index=vi,
            mass_kg=mass,
            payload_kg=mass - kerb,
            over_max_gross=mass > max_gross,
            cda_m2=per_vehicle(lambda v: v.cda_m2),
            cr=per_vehicle(lambda v: v.cr),
            eta=eta,
            negative_weight=np.where(is_ev, per_vehicle(lambda v: energy.ev_negative_weight(v) if v.is_ev else 0.0),
                                     w_ice),
            aux_power_w=per_vehicle(lambda v: v.aux_power_w if v.is_ev else 0.0),
            battery_j=per_vehicle(lambda v: v.battery_j if v.is_ev and v.battery_j else np.nan),
            lhv_j_per_l=per_vehicle(lambda v: np.nan if v.is_ev else v.fuel_lhv_j_per_l),
            idle_fuel_lps=per_vehicle(lambda v: 0.0 if v.is_ev else v.idle_fuel_lps),
            tank_l=per_vehicle(lambda v: np.nan if v.is_ev or v.tank_l is None else v.tank_l),
            is_ev=is_ev,
            braking=tuple(braking),
            ambient_c=ambient_c,
        )



@dataclass(frozen=True, eq=False)
class RowTerms:
    """The terms of :mod:`cevm.core.energy` that do not depend on the sign of a step, per
    (prediction, source): arrays (n, R).

    ``ambient_c`` the temperature used [degC] and ``ambient_from`` its origin (index into
    :data:`AMBIENT_ORIGINS`); EV rows: ``aux_w`` the auxiliary power P_aux(T) [W] and
    ``start_j`` the warm-up energy of the start [J]; ICE rows: ``fuel_extra_l`` the fuel
    beyond W / (U eta) (kinetic, running, idle, temperature and cold-start terms) [l].
    Zero where a row's powertrain has no such term.
    """

    ambient_c: np.ndarray
    ambient_from: np.ndarray
    aux_w: np.ndarray
    start_j: np.ndarray
    fuel_extra_l: np.ndarray


def row_terms(pset: PredictionSet, sources: Sequence[Source], rows: np.ndarray | None = None,
              mass_kg: np.ndarray | None = None) -> RowTerms:
    """:class:`RowTerms` of the predictions ``rows`` of ``pset`` (all by default; their
    masses ``mass_kg``, default the set's) on ``sources``."""
    rows = np.arange(pset.n) if rows is None else np.asarray(rows)
    mass = pset.mass_kg[rows] if mass_kg is None else np.asarray(mass_kg, dtype=np.float64)
    n, r = rows.size, len(sources)
    vecs = [src.vector for src in sources]
    dur = np.array([v.duration_s for v in vecs])
    idle = np.array([v.idle_s for v in vecs])
    kpos = np.array([v.k_pos for v in vecs])
    trac = np.array([v.traction_s for v in vecs])
    own = np.array([np.nan if src.ambient_c is None else float(src.ambient_c) for src in sources])
    t_all = np.empty((n, r))
    origin = np.empty((n, r), dtype=np.int8)
    aux = np.zeros((n, r))
    start = np.zeros((n, r))
    extra = np.zeros((n, r))
    vi = pset.vehicle_index[rows]
    for v in np.unique(vi):
        sel = vi == v
        veh = pset.vehicles[int(v)]
        if pset.ambient_c is not None:
            t, code = np.full(r, pset.ambient_c), np.zeros(r, dtype=np.int8)
        else:
            default = veh.reference_temp_c if veh.reference_temp_c is not None else energy.AMBIENT_DEFAULT_C
            code_default = 2 if veh.reference_temp_c is not None else 3
            t = np.where(np.isfinite(own), own, default)
            code = np.where(np.isfinite(own), 1, code_default).astype(np.int8)
        t_all[sel] = t
        origin[sel] = code
        if veh.is_ev:
            aux[sel] = energy.ev_aux_power_w(veh, t)
            start[sel] = energy.ev_start_energy_j(veh, t)
        else:
            try:
                extra[sel] = energy.ice_fuel_l(veh, 0.0, mass_kg=mass[sel][:, None], k_pos=kpos, traction_s=trac,
                                               duration_s=dur, idle_s=idle, ambient_c=t)
            except ValueError as exc:
                raise CevmError(f"vehicle {veh.name!r}: {exc}") from None
        for j, src in enumerate(sources):
            if src.leg_vectors is not None:
                temps = (np.full(len(src.leg_vectors), pset.ambient_c) if pset.ambient_c is not None
                         else np.asarray(src.leg_ambient_c, dtype=np.float64))
                a, s, x = _leg_terms(veh, src.leg_vectors, temps, mass[sel])
                aux[sel, j], start[sel, j], extra[sel, j] = a, s, x
    return RowTerms(t_all, origin, aux, start, extra)


def _leg_terms(veh, vectors, temps: np.ndarray, mass: np.ndarray) -> tuple[float, float, np.ndarray]:
    """A route's temperature terms leg by leg (:class:`Source` ``leg_vectors``): an EV's
    auxiliary power as the route's duration-weighted mean of each leg's at its own
    temperature and the sum of its legs' starts; an ICE's extra fuel summed over its legs
    (at the rows' masses ``mass``). The sum of the legs' own predictions, exactly."""
    dur = np.array([v.duration_s for v in vectors])
    if veh.is_ev:
        p = np.asarray(energy.ev_aux_power_w(veh, temps), dtype=np.float64)
        mean_w = float(np.sum(p * dur) / np.sum(dur)) if np.sum(dur) > 0 else float(p[0])
        return mean_w, float(np.sum(energy.ev_start_energy_j(veh, temps))), np.zeros(mass.size)
    try:
        fuel = energy.ice_fuel_l(veh, 0.0, mass_kg=mass[:, None], k_pos=np.array([v.k_pos for v in vectors]),
                                 traction_s=np.array([v.traction_s for v in vectors]), duration_s=dur,
                                 idle_s=np.array([v.idle_s for v in vectors]), ambient_c=temps)
    except ValueError as exc:
        raise CevmError(f"vehicle {veh.name!r}: {exc}") from None
    return 0.0, 0.0, np.asarray(fuel, dtype=np.float64).reshape(mass.size, -1).sum(axis=1)

