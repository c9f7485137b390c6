"""A scheduled trip's energy with its spread (pure): several drawn cycles of the trip
(:func:`~cevm.core.timetable.synthesis.synthesise_trip`, seeded), each reduced to its CE
vector with the road's elevation at each sample's distance, each predicted with the
vehicle's predictive distribution (:func:`cevm.core.predictive.predictive`, as ``cevm
predict`` does: the calibration's posterior, else the class prior) at the trip's mass and
ambient temperature.

The trip's energy is the mean of the draws' predicted means; its spread adds the
synthesis' to the model's predictive sd (the mean of the draws' sds) in quadrature: the
spread between the draws (their sample standard deviation: how much the energy depends
on the driving the timetable does not fix) and the synthesis' own error beyond it
(``params.synthesis_sd``, measured on the logs' own timetables, times the part of the
energy the wheel work makes: the mean less the same draws predicted without it).
Units: joules at the battery for an electric vehicle; for a
diesel, the fuel predict gives in litres times the vehicle's heating value (the fuel's
energy, ``fuel_lhv_j_per_l``): divide by it for litres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cevm.core import energy
from cevm.core.cycle import CR0_DEFAULT, CycleVector, drive_cycle_vector, step_terms
from cevm.core.predictive import Features, predictive
from cevm.core.predictive import mean as mean_of
from cevm.core.timetable.driving import DrivingParams
from cevm.core.timetable.synthesis import SynthCycle, synthesise_trips
from cevm.core.vehicle import Vehicle
from cevm.errors import CevmError


@dataclass(frozen=True, eq=False)
class ScheduledEnergy:
    """A scheduled trip's predicted energy (module notes): ``vector`` the representative
    draw's CE vector (the draw whose energy is nearest the mean); ``energy_j`` the mean
    over the draws [J: battery, or fuel energy for a diesel]; ``sd_model_j`` the model's
    predictive sd, ``sd_synthesis_j`` the synthesis' (the spread between draws and its
    own error: module notes), ``sd_j`` both; the representative draw's ``distance_m``,
    ``duration_s`` and ``ascent_m`` (climb summed
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


def draw_features(cycles: list[SynthCycle], elevations: list[np.ndarray | None], vehicle: Vehicle,
                  mass_kg: float, ambient_c: float) -> Features:
    """The :class:`~cevm.core.predictive.Features` of each drawn cycle in one pass over
    their step terms (:func:`cevm.core.cycle.step_terms` of the cycles end to end, the
    steps between two cycles left out): the wheel energy's parts P and N, the duration,
    standstill and traction times and the positive kinetic energy, as
    :meth:`Features.of` gets them from each cycle's vector (equal to rounding: the sums'
    order differs; the simplified steps are exactly the ones of positive wheel energy
    for every vehicle with Cr >= Cr0)."""
    n = len(cycles)
    t = np.concatenate([c.time_s for c in cycles])
    v = np.concatenate([c.speed_mps for c in cycles])
    h = None if all(e is None for e in elevations) else np.concatenate(
        [np.zeros(c.time_s.size) if e is None else e for c, e in zip(cycles, elevations, strict=True)])
    st = step_terms(t, v, h)
    sizes = np.array([c.time_s.size for c in cycles])
    draw = np.repeat(np.arange(n), sizes)[:-1]
    inside = np.ones(t.size - 1, dtype=bool)
    inside[np.cumsum(sizes)[:-1] - 1] = False  # the steps from one cycle to the next
    draw = draw[inside]
    k, a, r, e, dt = st.k[inside], st.a[inside], st.r[inside], st.e[inside], st.dt[inside]
    m = float(mass_kg)
    wheel = m * (k + e) + vehicle.cda_m2 * a + vehicle.cr * m * r
    P = np.bincount(draw, weights=np.maximum(wheel, 0.0), minlength=n)
    N = np.bincount(draw, weights=np.minimum(wheel, 0.0), minlength=n)
    dur = np.bincount(draw, weights=dt, minlength=n)
    idle = np.bincount(draw, weights=np.where(a > 0, 0.0, dt), minlength=n)
    trac = np.bincount(draw, weights=np.where(k + e + CR0_DEFAULT * r > 0, dt, 0.0), minlength=n)
    kin = m * np.bincount(draw, weights=np.maximum(k, 0.0), minlength=n)
    return Features(P, N, dur, idle, trac, kin, np.full(n, energy.check_ambient_c(float(ambient_c))))


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
    cycles = synthesise_trips(stop_dist_m, arrival_s, departure_s, params, rng, draws, speed_cap_mps=speed_cap_mps,
                              with_terminals=with_terminals)
    elev = [_elevation(c, pdist, pelev) for c in cycles]
    f = draw_features(cycles, elev, vehicle, mass_kg, ambient_c)
    p = predictive(vehicle, f)
    means = np.asarray(p.mean, dtype=np.float64).reshape(-1).copy()
    sds = np.asarray(p.sd, dtype=np.float64).reshape(-1).copy()
    # the part of the energy the driving moves: the mean less the same draws without wheel work
    still = Features(np.zeros(draws), np.zeros(draws), f.duration_s, f.idle_s, f.traction_s, np.zeros(draws),
                     f.ambient_c)
    wheel = means - np.asarray(mean_of(vehicle, still), dtype=np.float64).reshape(-1)
    scale = 1.0 if vehicle.is_ev else float(vehicle.fuel_lhv_j_per_l or math.nan)  # litres -> fuel energy [J]
    means, sds, wheel = means * scale, sds * scale, wheel * scale
    mean = float(means.mean())
    sd_model = float(sds.mean())
    own = params.synthesis_sd if math.isfinite(params.synthesis_sd) else 0.0
    sd_syn = math.hypot(float(means.std(ddof=1)) if draws > 1 else 0.0, own * max(float(wheel.mean()), 0.0))
    rep = int(np.argmin(np.abs(means - mean)))
    c = cycles[rep]
    e = elev[rep]
    vector = drive_cycle_vector(c.time_s, c.speed_mps, e, validate=False)
    Features.of(vector, vehicle, float(mass_kg), float(ambient_c))  # the model's checks (Cr >= the vector's Cr0)
    ascent = float(np.maximum(np.diff(e), 0.0).sum()) if e is not None else 0.0
    flat = "" if e is not None else "; flat road (no elevation profile)"
    return ScheduledEnergy(
        vector=vector, energy_j=mean, sd_model_j=sd_model, sd_synthesis_j=sd_syn,
        sd_j=math.hypot(sd_model, sd_syn), distance_m=float(c.distance_m[-1]),
        duration_s=float(c.time_s[-1] - c.time_s[0]), stops=int(np.size(stop_dist_m)), ascent_m=ascent,
        cycle_from=f"synthesised ({params.source}); {draws} draw{'s' if draws != 1 else ''}{flat}",
        late_s=float(max(cy.late_s for cy in cycles)),
        unscheduled_stops=float(np.mean([cy.unscheduled_stops for cy in cycles])),
        slowdowns=float(np.mean([cy.slowdowns for cy in cycles])), draws=draws)
