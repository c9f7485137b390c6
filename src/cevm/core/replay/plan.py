"""One vehicle's logged duties run with the candidate: the levels trip by trip, the
duties' lowest points exact, where a failing duty crosses its reserve, what it would
need (pure; the step tables of the few trips that need one come through a callable).

:func:`plan_vehicle` does everything but the Monte Carlo, which needs no step table and
is the costly part (:meth:`VehiclePlan.draw_plan`: a task for a worker); it reads a
trip's step table only where the trip's in-trip excess could decide something
(:mod:`cevm.core.replay.trip_energies`): the duty's lowest point, whether the reserve is kept
within 4 standard deviations of the duty's energy (so the Monte Carlo is exact to its
own error), where it is crossed, and the sizes (:mod:`cevm.core.replay.sizing`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from cevm.core.cycle import CycleVector
from cevm.core.limits import Demand
from cevm.core.replay.chain import DutyLevels, Lanes, Stops, duty_levels, run_chains
from cevm.core.replay.duties import Duties, group_duties
from cevm.core.replay.follow import TripFollow, duty_reasons, trip_follow
from cevm.core.replay.montecarlo import DrawPlan
from cevm.core.replay.places import Depot, find_depot, rest_positions, stops_at
from cevm.core.replay.settings import ReplaySettings
from cevm.core.replay.sizing import battery_needed, charger_needed, undecided_trips
from cevm.core.replay.spread import TripSpread, energy_at_confidence, trip_spread
from cevm.core.replay.trip_energies import TripEnergies, trip_crossing, trip_energies, trips_excess
from cevm.core.sweep import StepTable
from cevm.core.vehicle import Vehicle
from cevm.errors import CevmError

#: Trips whose in-trip excess could move a duty's lowest point within this many
#: standard deviations of the duty's energy from its reserve get their step table read
#: (a draw beyond it has a probability below 3e-5).
RELEVANT_SD = 4.0


@dataclass(frozen=True, eq=False)
class LoggedTrips:
    """One logged vehicle's trips, sorted by start, as the store knows them (arrays (n,)):
    ``trip_ids``, ``start_s`` [s since the epoch], ``end_s``, ``distance_m``,
    ``vectors`` (their CE vectors), ``gross_kg`` (NaN: no mass of its own),
    ``payload_kg`` (a payload given to the trip, NaN: none), ``mass_source`` (per trip:
    :data:`cevm.store.masses.MASS_SOURCES`), ``ambient_c`` (NaN: not logged), start and
    end positions [deg] (NaN where unknown; None: not read), ``day`` (per trip, for the
    ``day`` rule), ``missing`` (damaged trips left out), ``elevation_source`` (per trip,
    how ingest made its road elevation: its power's tolerance, :mod:`cevm.core.limits`;
    None: unknown), ``own_sd`` (per trip, a spread of its energy beyond the model's,
    independent between trips, [J or l]: a timetable's synthesised cycles; None: none),
    ``energy_offset`` (per trip, added to the model's mean on its vector [J or l]: a
    synthesised cycle's mean over its draws less its representative draw's; None: none)."""

    vehicle_id: str
    trip_ids: tuple[str, ...]
    start_s: np.ndarray
    end_s: np.ndarray
    distance_m: np.ndarray
    vectors: tuple[CycleVector, ...]
    gross_kg: np.ndarray
    payload_kg: np.ndarray
    mass_source: tuple[str, ...]
    ambient_c: np.ndarray
    start_lat: np.ndarray | None = None
    start_lon: np.ndarray | None = None
    end_lat: np.ndarray | None = None
    end_lon: np.ndarray | None = None
    day: np.ndarray | None = None
    missing: int = 0
    elevation_source: tuple[str | None, ...] | None = None
    own_sd: np.ndarray | None = None
    energy_offset: np.ndarray | None = None

    @property
    def n(self) -> int:
        return len(self.trip_ids)


def candidate_masses(trips: LoggedTrips, vehicle: Vehicle, logged_kerb_kg: float | None) -> np.ndarray:
    """The candidate's gross mass on each trip [kg]: a payload given to the trip on its
    kerb mass; a trip's own gross mass as it is, or (``logged_kerb_kg``: the logged
    vehicles' kerb) its payload, gross less that kerb, on the candidate's; else the
    candidate's ``mass_kg``."""
    gross = np.asarray(trips.gross_kg, dtype=np.float64)
    payload = np.asarray(trips.payload_kg, dtype=np.float64)
    needs_kerb = np.isfinite(payload) | (np.isfinite(gross) & (logged_kerb_kg is not None))
    if needs_kerb.any() and vehicle.kerb_mass_kg is None:
        raise CevmError(f"vehicle {vehicle.name!r} has no kerb_mass_kg to carry the trips' payloads on: add it to the "
                        "vehicle file")
    kerb = vehicle.kerb_mass_kg if vehicle.kerb_mass_kg is not None else np.nan
    own = gross if logged_kerb_kg is None else kerb + np.maximum(gross - logged_kerb_kg, 0.0)
    return np.where(np.isfinite(payload), kerb + payload, np.where(np.isfinite(gross), own, vehicle.mass_kg))


@dataclass(eq=False)
class Excess:
    """The trips' in-trip excess as far as known: ``value`` (exact where ``known``, else
    0) and ``bound`` (exact where known, else the regeneration bound); ``unreadable``
    counts the trips whose step table could not be read (their bound stays), ``read`` the
    trips whose step table was asked for."""

    value: np.ndarray
    bound: np.ndarray
    known: np.ndarray
    unreadable: int = 0
    read: int = 0

    def learn(self, trips: np.ndarray, exact: Callable[[np.ndarray], np.ndarray]) -> None:
        """Learn the exact excess of ``trips`` (``exact(indices)``: NaN where unreadable)."""
        todo = np.asarray(trips, dtype=np.int64)
        todo = np.unique(todo[~self.known[todo]])
        if not todo.size:
            return
        x = np.asarray(exact(todo), dtype=np.float64)
        self.read += int(todo.size)
        self.known[todo] = True
        bad = ~np.isfinite(x)
        self.unreadable += int(bad.sum())
        self.value[todo] = np.where(bad, self.bound[todo], x)  # unreadable: the bound, both ways
        self.bound[todo] = self.value[todo]


@dataclass(frozen=True, eq=False)
class VehiclePlan:
    """One vehicle's duties run with the candidate (everything but the Monte Carlo).

    ``trips`` and ``energies`` per trip; ``duties``; ``stops``; ``levels`` per duty
    (:class:`~cevm.core.replay.chain.DutyLevels`) and per trip (``before``, ``low``,
    ``after``, ``gain``) [J or l]; ``capacity``, ``start``, ``reserve`` levels;
    ``excess`` (:class:`Excess`); ``spread``; per duty: ``energy_sd``, ``reserve_trip``
    and ``reserve_at_m`` (the first trip below the reserve and the distance into the
    duty where it is crossed; -1 / NaN if kept), ``empty_trip``, ``empty_at_m``,
    ``battery_needed`` [J or l] and ``charger_needed_w`` (NaN: not sized) at the mean
    energies, ``battery_needed_conf`` and ``charger_needed_w_conf`` with each duty's
    energy at ``settings.size_confidence`` (NaN: not sized; the mean's where the
    candidate has no predictive distribution); ``depot``
    (None: not asked or not found); ``unplaced`` stops long enough but with no known
    position (not charged); ``follow`` the candidate's limits on each trip
    (:mod:`cevm.core.replay.follow`), ``follows`` per duty (every trip followed) and
    ``cannot_follow`` per duty (why not, "" where it does)."""

    trips: LoggedTrips
    vehicle: Vehicle
    settings: ReplaySettings
    energies: TripEnergies
    duties: Duties
    stops: Stops
    before: np.ndarray
    low: np.ndarray
    after: np.ndarray
    gain: np.ndarray
    levels: DutyLevels
    capacity: float
    start: float
    reserve: float
    excess: Excess
    spread: TripSpread
    energy_sd: np.ndarray
    reserve_trip: np.ndarray
    reserve_at_m: np.ndarray
    empty_trip: np.ndarray
    empty_at_m: np.ndarray
    battery_needed: np.ndarray
    charger_needed_w: np.ndarray
    battery_needed_conf: np.ndarray
    charger_needed_w_conf: np.ndarray
    follow: TripFollow
    follows: np.ndarray
    cannot_follow: tuple[str, ...]
    depot: Depot | None = None
    unplaced: int = 0
    notes: tuple[str, ...] = field(default=())

    @property
    def completes(self) -> np.ndarray:
        """Per duty: it keeps the reserve all along at the mean energies and the candidate
        can follow every trip of it (:mod:`cevm.core.replay.follow`)."""
        return (self.levels.low >= self.reserve) & self.follows

    def judged(self, p: np.ndarray) -> np.ndarray:
        """The duties' probabilities of completing ``p`` (of the energy) with those the
        candidate cannot follow at 0."""
        return np.where(self.follows, np.asarray(p, dtype=np.float64), 0.0)

    @property
    def chained(self) -> bool:
        return self.settings.charging.chained

    def lanes(self) -> Lanes:
        """The chains of this vehicle: its duties, or all of them in one when the level
        carries across duties."""
        b = self.duties.bounds
        return Lanes.of([0], [b[-1]]) if self.chained else Lanes.of(b[:-1], b[1:])

    def draw_plan(self) -> DrawPlan:
        """What the Monte Carlo of this vehicle's duties needs (a small, picklable task)."""
        return DrawPlan(mean=self.energies.energy, excess=self.excess.bound, spread=self.spread, stops=self.stops,
                        bounds=self.duties.bounds, chained=self.chained, capacity=self.capacity, start=self.start,
                        reserve=self.reserve, efficiency=self.settings.charging.efficiency,
                        key=self.trips.vehicle_id, duty_start_s=self.trips.start_s[self.duties.first])


def capacity_of(vehicle: Vehicle) -> float:
    """The candidate's usable battery [J] or tank [l]."""
    cap = vehicle.battery_j if vehicle.is_ev else vehicle.tank_l
    if not cap:
        what = "battery_kwh" if vehicle.is_ev else "tank_l"
        raise CevmError(f"vehicle {vehicle.name!r} has no {what}: a replay needs the battery or tank it carries")
    return float(cap)


def make_stops(trips: LoggedTrips, duties: Duties, vehicle: Vehicle, settings: ReplaySettings
               ) -> tuple[Stops, Depot | None, int]:
    """The stops after each trip (:class:`~cevm.core.replay.chain.Stops`): inside a duty,
    a stop at least ``min_dwell_s`` long at an allowed place charges (EV: at the charger's
    power; ICE: refuelled to full where places are named); the rest after a duty charges
    at the overnight charger when levels carry across duties. Also the depot found, and
    how many long-enough stops had no known position."""
    ch = settings.charging
    n = trips.n
    dwell = duties.dwell_s
    end = duties.last_of_duty
    long_enough = ~end & np.isfinite(dwell) & (dwell >= ch.min_dwell_s)
    depot = None
    unplaced = 0
    if ch.anywhere:
        allowed = long_enough if vehicle.is_ev else np.zeros(n, dtype=bool)
    else:
        if trips.end_lat is None or trips.start_lat is None or trips.end_lon is None or trips.start_lon is None:
            raise CevmError("charging at named places or the depot needs the trips' positions")
        places = list(ch.places)
        if ch.depot:
            lat, lon = rest_positions(duties.first, duties.last, trips.start_lat, trips.start_lon, trips.end_lat,
                                      trips.end_lon)
            depot = find_depot(lat, lon, ch.depot_radius_m)
            if depot is not None:
                places.append(depot.place)
        nxt_lat = np.append(trips.start_lat[1:], np.nan)
        nxt_lon = np.append(trips.start_lon[1:], np.nan)
        at = stops_at(places, trips.end_lat, trips.end_lon, nxt_lat, nxt_lon)
        unknown = ~(np.isfinite(trips.end_lat) | np.isfinite(nxt_lat))
        unplaced = int(np.count_nonzero(long_enough & unknown))
        allowed = long_enough & at
    if vehicle.is_ev:
        power = np.where(allowed, ch.power_w, 0.0)
    else:
        power = np.where(allowed, np.inf, 0.0)
    if ch.overnight == "power":
        power = np.where(end, ch.overnight_w if vehicle.is_ev else np.inf, power)
    sizable = allowed & bool(vehicle.is_ev)
    return Stops(dwell_s=dwell, power_w=power, sizable=sizable, duty_end=end), depot, unplaced


def _levels(lanes: Lanes, n: int, energy: np.ndarray, excess: np.ndarray, stops: Stops, capacity: float,
            start: float, efficiency: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    run = run_chains(lanes, energy, excess, stops, capacity=capacity, start=start, efficiency=efficiency)
    return lanes.put(run.before, n), lanes.put(run.low, n), lanes.put(run.after, n), lanes.put(run.gain, n)


Exact = Callable[[np.ndarray], np.ndarray]


def _learn_lowest(plan_args: tuple, ex: Excess, exact: Exact, relevant: np.ndarray) -> None:
    """Read the excess of every trip that could hold its duty's lowest point, or could
    bring it within ``relevant`` (per duty, a level) of the reserve, until none is left."""
    lanes, n, energy, stops, cap, start, eff, bounds = plan_args
    duty = np.repeat(np.arange(bounds.size - 1), np.diff(bounds))
    while True:
        before, low, _, _ = _levels(lanes, n, energy, ex.value, stops, cap, start, eff)
        low_bound = before - energy - ex.bound
        lowest = np.minimum.reduceat(low, bounds[:-1]) if n else np.zeros(0)
        need = ~ex.known & ((low_bound < lowest[duty]) | (low_bound < relevant[duty]))
        if not need.any():
            return
        ex.learn(np.flatnonzero(need), exact)


def _no_table(i: int) -> None:
    return None


def _crossing_m(trips: LoggedTrips, energies: TripEnergies, bounds: np.ndarray, before: np.ndarray,
                first: np.ndarray, threshold: float, vehicle: Vehicle,
                step_table: Callable[[int], StepTable | None], ice_braking: str | None) -> np.ndarray:
    """Per duty, the distance from its start [m] where its level first falls below
    ``threshold`` (trip ``first[d]``, -1: never): the trips before it whole, then inside it
    from its step table, or where none is read, in proportion to the trip's energy."""
    out = np.full(first.size, np.nan)
    cum = np.concatenate([[0.0], np.cumsum(trips.distance_m)])
    for d in np.flatnonzero(first >= 0).tolist():
        i = int(first[d])
        st = step_table(i)
        e = energies.energy[i]
        share = (before[i] - threshold) / e if e > 0 else 1.0
        inside = trips.distance_m[i] * min(max(share, 0.0), 1.0)
        if st is not None:
            _, dist = trip_crossing(st, vehicle, float(energies.mass_kg[i]), float(energies.ambient_c[i]),
                                    float(before[i] - threshold), ice_braking=ice_braking)
            if np.isfinite(dist):
                inside = min(dist, trips.distance_m[i])
        out[d] = cum[i] - cum[bounds[d]] + inside
    return out


def _sized(lanes: Lanes, energy: np.ndarray, ex: Excess, exact: Exact, need: Callable[[np.ndarray], np.ndarray],
           undecided: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]) -> np.ndarray:
    """Sizes found with the excess bounded and with it at its known value, refined by
    reading the trips that decide between them until both agree (:mod:`cevm.core.replay.sizing`)."""
    while True:
        hi = need(ex.bound)
        lo = need(ex.value)
        differ = hi != lo
        if not differ.any():
            return hi
        trips = undecided(lo, differ, ex.known)
        if not trips.size:
            return hi  # no unknown trip decides: the bounded size stands
        ex.learn(trips, exact)


def plan_vehicle(trips: LoggedTrips, vehicle: Vehicle, settings: ReplaySettings,
                 step_table: Callable[[int], StepTable | None], *, size: bool = True,
                 demand: Callable[[int], Demand | None] | None = None) -> VehiclePlan:
    """Run ``trips``' duties with ``vehicle`` (module notes). ``step_table(i)`` reads trip
    i's step table (None: unreadable); ``size`` (with duties that do not carry their level
    across rests) adds each duty's battery and charger needs; ``demand(i)`` what trip i
    asks of a vehicle's power and speed (:mod:`cevm.core.replay.follow`; None: only the
    gross mass is checked)."""
    if trips.n == 0:
        raise CevmError(f"vehicle id {trips.vehicle_id!r} has no trips to replay")
    duties = group_duties(trips.start_s, trips.end_s, rule=settings.rule, gap_s=settings.gap_s, day=trips.day)
    mass = candidate_masses(trips, vehicle, settings.logged_kerb_kg)
    energies = trip_energies(trips.vectors, vehicle, mass, trips.ambient_c, ice_braking=settings.ice_braking)
    if trips.energy_offset is not None:
        energies = dataclasses.replace(energies, energy=energies.energy + trips.energy_offset)
    stops, depot, unplaced = make_stops(trips, duties, vehicle, settings)
    cap = capacity_of(vehicle)
    start, reserve = settings.soc_start_pct / 100.0 * cap, settings.reserve_pct / 100.0 * cap
    eff = settings.charging.efficiency
    spread = trip_spread(vehicle, energies, ice_braking=settings.ice_braking)
    if trips.own_sd is not None:
        spread = spread.with_own(trips.own_sd)
    energy = energies.energy
    bounds = duties.bounds
    energy_sd = spread.duty_sd(energy, bounds)
    bound = energies.regen_bound.copy() if settings.within_trips else np.zeros(trips.n)
    ex = Excess(value=np.zeros(trips.n), bound=bound, known=bound == 0.0)
    if not settings.within_trips:
        step_table = _no_table

    def exact(indices: np.ndarray) -> np.ndarray:
        return trips_excess([step_table(int(i)) for i in indices], vehicle, energies.mass_kg[indices],
                            energies.ambient_c[indices], ice_braking=settings.ice_braking)

    lanes = Lanes.of([0], [trips.n]) if settings.charging.chained else Lanes.of(bounds[:-1], bounds[1:])
    _learn_lowest((lanes, trips.n, energy, stops, cap, start, eff, bounds), ex, exact,
                  reserve + RELEVANT_SD * energy_sd)
    before, low, after, gain = _levels(lanes, trips.n, energy, ex.value, stops, cap, start, eff)
    lv = duty_levels(bounds, before, low, after, gain, reserve)
    empty_first = duty_levels(bounds, before, low, after, gain, 0.0).first_below
    cross = _crossing_m(trips, energies, bounds, before, lv.first_below, reserve, vehicle, step_table,
                        settings.ice_braking)
    empty = _crossing_m(trips, energies, bounds, before, empty_first, 0.0, vehicle, step_table, settings.ice_braking)
    nan = np.full(duties.n, np.nan)
    battery, charger = nan, nan.copy()
    battery_c, charger_c = nan.copy(), nan.copy()
    if size and not settings.charging.chained:
        battery, charger = _duty_sizes(lanes, bounds, energy, ex, exact, stops, settings, cap, vehicle)
        if settings.size_confidence is not None and np.any(energy_sd > 0.0):
            high = energy_at_confidence(energy, energy_sd, bounds, settings.size_confidence)
            battery_c, charger_c = _duty_sizes(lanes, bounds, high, ex, exact, stops, settings, cap, vehicle)
        elif settings.size_confidence is not None:  # no spread: the mean's sizes are the confidence's
            battery_c, charger_c = battery.copy(), charger.copy()
    follow = trip_follow(vehicle, energies.mass_kg, demand)
    reasons = duty_reasons(follow, duties.first, duties.last, trips.trip_ids, vehicle, energies.mass_kg)
    return VehiclePlan(trips=trips, vehicle=vehicle, settings=settings, energies=energies, duties=duties, stops=stops,
                       before=before, low=low, after=after, gain=gain, levels=lv, capacity=cap, start=start,
                       reserve=reserve, excess=ex, spread=spread, energy_sd=energy_sd,
                       reserve_trip=lv.first_below, reserve_at_m=cross, empty_trip=empty_first, empty_at_m=empty,
                       battery_needed=battery, charger_needed_w=charger, battery_needed_conf=battery_c,
                       charger_needed_w_conf=charger_c, follow=follow, follows=follow.duty_follows(duties.first),
                       cannot_follow=tuple(reasons), depot=depot, unplaced=unplaced)


def _duty_sizes(lanes: Lanes, bounds: np.ndarray, energy: np.ndarray, ex: Excess, exact: Exact, stops: Stops,
                settings: ReplaySettings,
                cap: float, vehicle: Vehicle) -> tuple[np.ndarray, np.ndarray]:
    """Each duty's battery need [J or l] (NaN when it starts at or below its reserve, or
    without a step) and, for an EV with stops that may charge, its charger need [W] at
    the candidate's battery (inf: no charger suffices)."""
    s, r = settings.soc_start_pct / 100.0, settings.reserve_pct / 100.0
    eff = settings.charging.efficiency
    d_count = lanes.shape[1]
    battery = np.full(d_count, np.nan)
    charger = np.full(d_count, np.nan)
    if s > r and settings.battery_step > 0:
        def need(x: np.ndarray) -> np.ndarray:
            return battery_needed(lanes, energy, x, stops, soc_start=s, reserve=r, efficiency=eff,
                                  step=settings.battery_step)

        def undecided(lo: np.ndarray, rows: np.ndarray, known: np.ndarray) -> np.ndarray:
            cap_lane = lo  # where the sizes agree both pass there: nothing undecided
            return undecided_trips(lanes, bounds, energy, ex.value, ex.bound, known, stops, capacity=cap_lane,
                                   start=s * cap_lane, reserve=r * cap_lane, efficiency=eff)

        battery = _sized(lanes, energy, ex, exact, need, undecided)
    if vehicle.is_ev and stops.sizable.any() and settings.charger_step_w > 0:
        def need_p(x: np.ndarray) -> np.ndarray:
            return charger_needed(lanes, energy, x, stops, capacity=cap, start=s * cap, reserve=r * cap,
                                  efficiency=eff, step=settings.charger_step_w)

        def undecided_p(lo: np.ndarray, rows: np.ndarray, known: np.ndarray) -> np.ndarray:
            slots = lanes.index
            trip_lane = np.zeros(stops.power_w.size, dtype=np.int64)
            trip_lane[slots[slots >= 0]] = np.broadcast_to(np.arange(d_count), slots.shape)[slots >= 0]
            p_lane = np.where(np.isfinite(lo), lo, 0.0)  # agreeing lanes decide nothing
            power = np.where(stops.sizable, p_lane[trip_lane], stops.power_w)
            return undecided_trips(lanes, bounds, energy, ex.value, ex.bound, known, stops, capacity=cap,
                                   start=s * cap, reserve=r * cap, efficiency=eff, power_w=power)

        charger = _sized(lanes, energy, ex, exact, need_p, undecided_p)
    return battery, charger
