"""A scheduled trip's energy with its spread (pure): several drawn cycles of the trip
(:func:`~cevm.core.timetable.synthesis.synthesise_trip`, seeded), each reduced to its CE
vector with the road's elevation at each sample's distance, each predicted with the
vehicle's predictive distribution (:func:`cevm.core.predictive.predictive`, as ``cevm
predict`` does: the calibration's posterior, else the class prior) at the trip's mass and
ambient temperature.

The trip's energy is the mean of the draws' predicted means; its spread adds the spread
between the draws (their sample standard deviation: how much the energy depends on the
driving the timetable does not fix) to the model's predictive sd (the mean of the
draws' sds) in quadrature. Units: joules at the battery for an electric vehicle; for a
diesel, the fuel predict gives in litres times the vehicle's heating value (the fuel's
energy, ``fuel_lhv_j_per_l``): divide by it for litres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cevm.core.cycle import CycleVector, drive_cycle_vector
from cevm.core.predictive import Features, predictive
from cevm.core.timetable.driving import DrivingParams
from cevm.core.timetable.synthesis import SynthCycle, synthesise_trip
from cevm.core.vehicle import Vehicle
from cevm.errors import CevmError


@dataclass(frozen=True, eq=False)
class ScheduledEnergy:
    """A scheduled trip's predicted energy (module notes): ``vector`` the representative
    draw's CE vector (the draw whose energy is nearest the mean); ``energy_j`` the mean
    over the draws [J: battery, or fuel energy for a diesel]; ``sd_model_j`` the model's
    predictive sd, ``sd_synthesis_j`` the spread between draws, ``sd_j`` both; the
    representative draw's ``distance_m``, ``duration_s`` and ``ascent_m`` (climb summed
    along it), ``stops`` the timetable's; ``cycle_from`` where the cycle came from;
    ``late_s`` the most any draw reached the last stop after the timetable (0: kept);
    ``unscheduled_stops`` and ``slowdowns`` the mean drawn."""

    vector: CycleVector
    energy_j: float
    sd_model_j: float
    sd_synthesis_j: float
    sd_j: float
    distance_m: float
    duration_s: float
    stops: int
    ascent_m: float
    cycle_from: str
    late_s: float = 0.0
    unscheduled_stops: float = 0.0
    slowdowns: float = 0.0
    draws: int = 0


def _elevation(c: SynthCycle, profile_dist_m: np.ndarray | None, profile_elev_m: np.ndarray | None
               ) -> np.ndarray | None:
    if profile_dist_m is None or profile_elev_m is None:
        return None
    return np.interp(c.distance_m, profile_dist_m, profile_elev_m)


def _check_profile(profile_dist_m, profile_elev_m) -> tuple[np.ndarray | None, np.ndarray | None]:
    if profile_dist_m is None or profile_elev_m is None:
        return None, None
    pd_ = np.asarray(profile_dist_m, dtype=np.float64)
    pe = np.asarray(profile_elev_m, dtype=np.float64)
    if pd_.ndim != 1 or pe.shape != pd_.shape or pd_.size < 1:
        raise CevmError("an elevation profile needs distances and elevations of one length")
    if not (np.all(np.isfinite(pd_)) and np.all(np.isfinite(pe))):
        raise CevmError("an elevation profile must be finite")
    if np.any(np.diff(pd_) < 0):
        raise CevmError("an elevation profile's distances must not go back")
    return pd_, pe


def scheduled_trip_energy(vehicle: Vehicle, stop_dist_m, arrival_s, departure_s, *,
                          profile_dist_m: np.ndarray | None, profile_elev_m: np.ndarray | None,
                          mass_kg: float, ambient_c: float, params: DrivingParams,
                          draws: int = 8, seed: int = 0, speed_cap_mps: float | np.ndarray | None = None,
                          with_terminals: bool = False) -> ScheduledEnergy:
    """The energy of one scheduled trip (module notes). ``profile_dist_m`` /
    ``profile_elev_m``: the road's elevation along the trip (distance from the first
    stop [m], elevation [m]); None: flat, said in ``cycle_from``. Deterministic for a
    given ``seed``. ``speed_cap_mps`` and ``with_terminals`` as
    :func:`~cevm.core.timetable.synthesis.synthesise_trip`."""
    if draws < 1:
        raise CevmError(f"draws must be at least 1, got {draws}")
    pdist, pelev = _check_profile(profile_dist_m, profile_elev_m)
    rng = np.random.default_rng(seed)
    cycles = [synthesise_trip(stop_dist_m, arrival_s, departure_s, params, rng, speed_cap_mps=speed_cap_mps,
                              with_terminals=with_terminals) for _ in range(draws)]
    elev = [_elevation(c, pdist, pelev) for c in cycles]
    vectors = [drive_cycle_vector(c.time_s, c.speed_mps, e, validate=False) for c, e in zip(cycles, elev, strict=True)]
    means = np.empty(draws)
    sds = np.empty(draws)
    for i, vec in enumerate(vectors):
        p = predictive(vehicle, Features.of(vec, vehicle, float(mass_kg), float(ambient_c)))
        means[i] = float(np.asarray(p.mean).reshape(-1)[0])
        sds[i] = float(np.asarray(p.sd).reshape(-1)[0])
    if not vehicle.is_ev:  # litres -> the fuel's energy [J]
        lhv = float(vehicle.fuel_lhv_j_per_l or math.nan)
        means, sds = means * lhv, sds * lhv
    mean = float(means.mean())
    sd_model = float(sds.mean())
    sd_syn = float(means.std(ddof=1)) if draws > 1 else 0.0
    rep = int(np.argmin(np.abs(means - mean)))
    c = cycles[rep]
    e = elev[rep]
    ascent = float(np.maximum(np.diff(e), 0.0).sum()) if e is not None else 0.0
    flat = "" if e is not None else "; flat road (no elevation profile)"
    return ScheduledEnergy(
        vector=vectors[rep], energy_j=mean, sd_model_j=sd_model, sd_synthesis_j=sd_syn,
        sd_j=math.hypot(sd_model, sd_syn), distance_m=float(c.distance_m[-1]),
        duration_s=float(c.time_s[-1] - c.time_s[0]), stops=int(np.size(stop_dist_m)), ascent_m=ascent,
        cycle_from=f"synthesised ({params.source}); {draws} draw{'s' if draws != 1 else ''}{flat}",
        late_s=float(max(cy.late_s for cy in cycles)),
        unscheduled_stops=float(np.mean([cy.unscheduled_stops for cy in cycles])),
        slowdowns=float(np.mean([cy.slowdowns for cy in cycles])), draws=draws)
