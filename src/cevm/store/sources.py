"""Stored trips and routes as the inputs of the pure core: sweep sources
(:class:`cevm.core.sweep.Source`) for ``cevm predict`` and ``cevm feasibility``, and a
leg resolver (:func:`store_resolver`) for fleet scenarios whose legs are stored trips or
routes."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path

from cevm.core.assignment import LegSource
from cevm.core.cycle import CycleVector
from cevm.core.limits import elevation_sd_m
from cevm.core.sweep import LegProfile, PredictionSet, Source
from cevm.core.trip import Measurement
from cevm.errors import CevmError
from cevm.io.cycles import MAX_CYCLE_SAMPLES, CycleFormat, read_cycle_files
from cevm.io.scenario import LegResolver, default_resolver
from cevm.store.codec import MAX_PROFILE_SAMPLES
from cevm.store.failures import DAMAGED_HINT, DamagedTripError, StoreDamagedError
from cevm.store.location import existing_store_path
from cevm.store.masses import TripMass, trip_masses
from cevm.store.queries import row_measurement
from cevm.store.routes import (
    check_route_profiles,
    load_route_legs,
    load_route_profiles,
    load_route_vector,
    resolve_route_patterns,
)
from cevm.store.trips import TripStore


@dataclass(frozen=True, eq=False)
class StoredTrip(Source):
    """A stored trip as a sweep source, with what the store knows of it beyond its cycle:
    its mass (:class:`~cevm.store.masses.TripMass`: given, logged) and its measured
    consumption (None if unmeasured), to predict it at its own mass and show the
    measurement beside the model; and its start: the state of charge its log holds there
    [%] and the time its vehicle stood since its previous stored trip [s] (None where not
    known), inputs known before a trip in operations."""

    mass: TripMass | None = None
    measured: Measurement | None = None
    elevation_source: str | None = None  # cevm.ingest.elevation: "dsm", "gps", "flat", ...
    start_soc_pct: float | None = None
    standstill_before_s: float | None = None


#: Without a max_gross_kg, a trip's gross mass above this multiple of a vehicle's kerb
#: mass is taken for another vehicle's (a loaded articulated truck weighs about 2.5 times
#: its empty weight; a bus or van far less).
FOREIGN_MASS_KERB_RATIO = 3.0


def foreign_mass(mass: TripMass | None, measured: Measurement | None, vehicle) -> str | None:
    """Why a stored trip's own gross mass (``mass``: logged, or given as a gross) looks
    like another vehicle's than ``vehicle``'s, or None (``measured``: what the trip
    measured): the trip measured the other powertrain's
    energy (fuel for an EV, electricity for an ICE), or the mass is over
    :data:`FOREIGN_MASS_KERB_RATIO` times the vehicle's kerb mass where it has no
    max_gross_kg (above a max_gross_kg a row is flagged ``over_max_gross``). A payload
    given to a trip is the goods it carried, and goes with any vehicle."""
    key = None if mass is None else mass.sweep_key()
    if key is None or key[0] != "gross":
        return None
    if measured is not None and (measured.kind == "fuel_l") == vehicle.is_ev:
        return f"it measured {'fuel' if vehicle.is_ev else 'electric energy'}, so another powertrain drove it"
    if (vehicle.max_gross_kg is None and vehicle.kerb_mass_kg
            and key[1] > FOREIGN_MASS_KERB_RATIO * vehicle.kerb_mass_kg):
        return f"over {FOREIGN_MASS_KERB_RATIO:g} times this vehicle's kerb mass of {vehicle.kerb_mass_kg:,.0f} kg"
    return None


def foreign_mass_warnings(sources: Sequence[Source], vehicles: Sequence) -> list[str]:
    """One warning per vehicle predicted at stored trips' own gross masses that look like
    another vehicle's (:func:`foreign_mass`), with the first such trip as an example."""
    out = []
    for v in vehicles:
        hits = [(src, why) for src in sources
                if isinstance(src, StoredTrip) and (why := foreign_mass(src.mass, src.measured, v))]
        if hits:
            src, why = hits[0]
            mass = src.mass
            key = None if mass is None else mass.sweep_key()
            assert mass is not None and key is not None  # foreign_mass() found its gross mass
            out.append(f"{v.label}: predicted at the own gross mass of {len(hits)} stored trip(s) another vehicle "
                       f"drove (e.g. {src.name}: {mass.describe()} {key[1]:,.0f} kg; {why}); "
                       f"give --mass-kg or --payload-kg for what {v.label} would carry")
    return out


def mass_runs(sources: Sequence[Source], build: Callable[..., PredictionSet]
              ) -> Iterator[tuple[Sequence[Source], PredictionSet, str]]:
    """The sources in consecutive runs that share a prediction set, each with its
    ``mass_source`` (:data:`~cevm.store.masses.MASS_SOURCES`): a stored trip at its own
    mass (:mod:`cevm.store.masses`: given, else logged), anything else at each vehicle's
    ``mass_kg``. ``build(mass_kg=..., payload_kg=...)`` makes a set (the caller's vehicles
    and options); one set per distinct mass, made once."""
    made: dict = {}

    def pset(src: Source) -> tuple[PredictionSet, str]:
        mass = src.mass if isinstance(src, StoredTrip) else None
        key = None if mass is None else mass.sweep_key()
        label = "vehicle file" if mass is None else mass.origin
        if key not in made:
            try:
                made[key] = (build() if key is None else build(mass_kg=[key[1]]) if key[0] == "gross"
                             else build(payload_kg=[key[1]]))
            except CevmError as exc:  # a payload on a vehicle without a kerb mass, a mass below it
                if mass is None:  # the vehicle file's own mass: its message as it is
                    raise
                raise CevmError(f"trip {src.name!r} ({mass.describe()} mass): {exc}") from None
        return made[key], label

    run: list[Source] = []
    current = None
    for src in sources:
        ps, label = pset(src)
        if current is not None and (ps, label) != current:
            yield run, current[0], current[1]
            run = []
        run.append(src)
        current = (ps, label)
    if run and current is not None:
        yield run, current[0], current[1]


def load_sources(stack: ExitStack, store: Path | None, cycles: Sequence[Path], trips: Sequence[str],
                 vehicle_ids: Sequence[str], routes: Sequence[str], cr0: float,
                 cycle_format: CycleFormat | None = None, *, need_profiles: bool = True,
                 on_damaged: Callable[[CevmError], None] | None = None) -> list[Source]:
    """Sources in the order cycles (every cycle of each file, read with ``cycle_format``),
    trips, trips of vehicle ids, routes. A store is opened read-only (and kept open on
    ``stack``) only when a stored source is asked for; profiles are read from it when
    first needed. A stored trip's source carries its logged mean ambient temperature, a
    route the duration-weighted mean of its trip legs' (:func:`route_ambient_c`).

    Damaged blobs: a trip asked for by id (``trips``) or a route with a damaged leg raises
    :class:`DamagedTripError` / :class:`~cevm.store.failures.DamagedRouteError`; the
    trips of ``vehicle_ids`` that are damaged are passed to ``on_damaged`` and left out
    (without it they raise too). ``need_profiles`` (default True: a sweep with EVs reads
    them for the state of charge) also checks the profiles' checksums now, so that a
    damaged one is found before the first row is written, not half-way."""
    sources = [Source.from_cycle(c, cr0=cr0) for c in read_cycle_files(cycles, cycle_format)]
    if not (trips or vehicle_ids or routes):
        return sources
    path = existing_store_path(store)
    st = stack.enter_context(TripStore.open(path, readonly=True))
    vectors: dict[str, CycleVector] = {}
    if trips:
        vectors.update(st.load_cycle_vectors(trip_ids=list(trips)))
        if need_profiles:
            for exc in st.damaged_profiles(list(trips)):
                raise exc
    for vid in vehicle_ids:
        got = st.load_cycle_vectors(vehicle_id=vid, on_damaged=on_damaged)
        if need_profiles and got:
            for exc in st.damaged_profiles(list(got)):
                if on_damaged is None:
                    raise exc
                on_damaged(exc)
                del got[exc.trip_id]
        if not got:  # the store's damage (exit 4), not the user's mistake
            raise StoreDamagedError(f"{path}: vehicle id {vid!r} has no usable stored trips (all are damaged); "
                                    "'cevm store check' lists them")
        vectors.update((tid, vec) for tid, vec in got.items() if tid not in vectors)
    facts: dict[str, tuple] = {}
    if vectors:
        try:
            rows = st.list_trips(trip_ids=list(vectors))
        except CevmError as exc:  # trips just read by id or vehicle that the store cannot find again: a damaged index
            if type(exc) is not CevmError:
                raise
            raise StoreDamagedError(f"{path}: the store is damaged: trips it listed cannot be found again ({exc}); "
                                    f"{DAMAGED_HINT}") from None
        for tid, n in zip(rows["trip_id"], rows["n_samples"], strict=True):
            if n > MAX_SOURCE_SAMPLES:  # bounded as a cycle file is: one source's samples are held together
                # a count no stored profile can hold (cevm.store.codec) is the row's damage, not a long trip
                bad: DamagedTripError | TripTooLong = (
                    DamagedTripError(tid, "row", f"its row says {int(n):,} samples, more than the "
                                                 f"{MAX_PROFILE_SAMPLES:,} any stored trip holds")
                    if n > MAX_PROFILE_SAMPLES else TripTooLong(too_long_trip(tid, int(n))))
                if tid in trips or on_damaged is None:
                    raise bad
                on_damaged(bad)  # a vehicle's trips: left out and named, as a damaged one is
                del vectors[tid]
        rows = rows[rows["trip_id"].isin(list(vectors))]
        masses = trip_masses(st, rows)
        for r in rows.itertuples(index=False):
            t_c = r.ambient_temp_c
            facts[r.trip_id] = (None if not math.isfinite(t_c) else float(t_c), masses[r.trip_id],
                                row_measurement(r.measured_kind, r.measured_value, r.measured_source,
                                                r.measured_resolution, r.measured_uncertainty),
                                r.elevation_source, _finite(r.start_soc_pct), _finite(r.standstill_before_s))

    def trip_legs(tid: str):
        return lambda: (LegProfile.from_profile(st.load_profile(tid)),)

    for tid, vec in vectors.items():
        ambient, mass, measured, elevation, soc, stood = facts[tid]
        sources.append(StoredTrip(name=tid, kind="trip", vector=vec, legs=trip_legs(tid), ambient_c=ambient,
                                  mass=mass, measured=measured, elevation_source=elevation, start_soc_pct=soc,
                                  standstill_before_s=stood, logged=True, elevation_sd_m=elevation_sd_m(elevation)))

    def route_legs(name: str):
        return lambda: [LegProfile.from_profile(p) for p in load_route_profiles(st, name)]

    for name in resolve_route_patterns(st, list(routes)) if routes else []:
        legs = load_route_legs(st, name, profiles=False)
        if need_profiles:
            check_route_profiles(st, name)
        vec = legs[0].vector
        for leg in legs[1:]:
            vec = vec + leg.vector
        logged = all(leg.info.kind == "trip" for leg in legs)  # else: a cycle leg, a target held exactly
        sources.append(Source(name=name, kind="route", vector=vec, legs=route_legs(name),
                              ambient_c=route_ambient_c(st, legs), logged=logged,
                              elevation_sd_m=elevation_sd_m(None) if logged else 0.0))
    return sources


#: Most samples of one stored trip a command predicts or simulates: a source is held whole
#: while it is swept, so it is bounded as one cycle file is
#: (:data:`cevm.io.cycles.MAX_CYCLE_SAMPLES`: 11.6 days at 1 Hz; no vehicle drives that long
#: without the 30-minute stop that ends a trip). At 2.5 million samples (what a log within
#: ingest's default limits could make of one endless trip) ``predict`` peaked at 627 MB,
#: ``simulate`` at 834 MB.
MAX_SOURCE_SAMPLES = MAX_CYCLE_SAMPLES


class TripTooLong(CevmError):
    """A stored trip of more than :data:`MAX_SOURCE_SAMPLES` samples."""


def too_long_trip(trip_id: str, n_samples: int) -> str:
    """The sentence that refuses a stored trip of ``n_samples`` samples."""
    return (f"trip {trip_id!r} holds {n_samples:,} samples, more than the {MAX_SOURCE_SAMPLES:,} one source may "
            "(11.6 days at 1 Hz without the 30-minute stop that ends a trip: not a trip a vehicle drives)")


def _finite(x: float) -> float | None:
    """A stored REAL as the list's NaN-for-NULL gives it: a float, or None for NaN."""
    return float(x) if math.isfinite(x) else None


def route_ambient_c(st: TripStore, legs: Sequence) -> float | None:
    """A route's ambient temperature [degC]: the duration-weighted mean of its legs'
    logged temperatures when every leg is a stored trip that logged one; None otherwise
    (a cycle leg has no temperature, and a mean over some legs only would pass for the
    whole route's), so that the prediction falls back to the vehicle's reference and says
    so."""
    if not legs or any(leg.info.kind != "trip" for leg in legs):
        return None
    rows = st.list_trips(trip_ids=[leg.info.ref for leg in legs]).set_index("trip_id")
    temps = [rows.at[leg.info.ref, "ambient_temp_c"] if leg.info.ref in rows.index else math.nan for leg in legs]
    weights = [leg.vector.duration_s for leg in legs]
    if not all(math.isfinite(t) for t in temps) or sum(weights) <= 0:
        return None
    return float(sum(t * w for t, w in zip(temps, weights, strict=True)) / sum(weights))


def store_resolver(store: TripStore | Callable[[], TripStore]) -> LegResolver:
    """A resolver that also reads ``trip`` (a stored trip id) and ``route`` (a stored
    route name) leg sources from an open :class:`cevm.store.TripStore`, or from the one a
    callable opens when the first such leg comes (so that a scenario of cycle files never
    touches the store)."""
    opened: list[TripStore] = []

    def st() -> TripStore:
        if not opened:
            opened.append(store() if callable(store) else store)
        return opened[0]

    def resolve(source: LegSource, base_dir: Path) -> CycleVector:
        if source.kind == "trip":
            return st().load_cycle_vectors(trip_ids=[source.ref])[source.ref]
        if source.kind == "route":
            return load_route_vector(st(), source.ref)
        return default_resolver(source, base_dir)

    return resolve


def store_leg_demand(store: TripStore | Callable[[], TripStore], base_dir: Path):
    """What each leg of a fleet scenario asks of a vehicle
    (:class:`cevm.core.limits.Demand`): stored trip and route legs from the store (opened
    by the callable when the first comes; logged traces, held with their measurement's
    tolerance), cycle files as :func:`cevm.io.scenario.cycle_leg_demand`."""
    from cevm.core.limits import elevation_sd_m as sd_of
    from cevm.io.scenario import cycle_leg_demand

    cycles = cycle_leg_demand(base_dir)
    opened: list[TripStore] = []
    cache: dict[tuple[str, str], object] = {}

    def st() -> TripStore:
        if not opened:
            opened.append(store() if callable(store) else store)
        return opened[0]

    def demand(leg):
        src = leg.source
        if src is None or src.kind not in ("trip", "route"):
            return cycles(leg)
        key = (src.kind, src.ref)
        if key not in cache:
            if src.kind == "trip":
                row = st().list_trips(trip_ids=[src.ref])
                elevation = row["elevation_source"].iloc[0] if len(row) else None
                legs: tuple[LegProfile, ...] = (LegProfile.from_profile(st().load_profile(src.ref)),)
                sd = sd_of(elevation)
            else:
                legs = tuple(LegProfile.from_profile(p) for p in load_route_profiles(st(), src.ref))
                sd = sd_of(None)
            cache[key] = Source(src.ref, src.kind, load_route_vector(st(), src.ref) if src.kind == "route" else
                                st().load_cycle_vectors(trip_ids=[src.ref])[src.ref], legs=legs, logged=True,
                                elevation_sd_m=sd).demand
        return cache[key]

    return demand
