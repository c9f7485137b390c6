"""Stored trips and routes as the inputs of the pure core: sweep sources
(:class:`cevm.core.sweep.Source`) for ``cevm predict`` and ``cevm feasibility``, and a
leg resolver (:func:`store_resolver`) for fleet scenarios whose legs are stored trips or
routes."""

from __future__ import annotations

from collections.abc import Sequence
from contextlib import ExitStack
from pathlib import Path
from typing import Optional

from cevm.core.assignment import LegSource
from cevm.core.cycle import CycleVector
from cevm.core.sweep import LegProfile, Source
from cevm.errors import CevmError
from cevm.io.cycles import CycleFormat, read_cycle_files
from cevm.io.scenario import LegResolver, default_resolver
from cevm.store.location import existing_store_path
from cevm.store.routes import load_route_legs, load_route_profiles, load_route_vector, resolve_route_patterns
from cevm.store.trips import TripStore


def load_sources(stack: ExitStack, store: Optional[Path], cycles: Sequence[Path], trips: Sequence[str],
                  vehicle_ids: Sequence[str], routes: Sequence[str], cr0: float,
                  cycle_format: CycleFormat | None = None) -> list[Source]:
    """Sources in the order cycles (every cycle of each file, read with ``cycle_format``),
    trips, trips of vehicle ids, routes. A store is opened (and kept open on ``stack``)
    only when a stored source is asked for; profiles are read from it when first needed."""
    sources = [Source.from_cycle(c, cr0=cr0) for c in read_cycle_files(cycles, cycle_format)]
    if not (trips or vehicle_ids or routes):
        return sources
    path = existing_store_path(store)
    st = stack.enter_context(TripStore.open(path))
    vectors: dict[str, bytes] = {}
    if trips:
        vectors.update(st.load_vectors(trip_ids=list(trips)))
    for vid in vehicle_ids:
        got = st.load_vectors(vehicle_id=vid)
        if not got:
            raise CevmError(f"vehicle id {vid!r} has no stored trips; see 'cevm trips'")
        vectors.update(got)

    def trip_legs(tid: str):
        return lambda: (LegProfile.from_profile(st.load_profile(tid)),)

    for tid, blob in vectors.items():
        sources.append(Source(name=tid, kind="trip", vector=CycleVector.from_bytes(blob), legs=trip_legs(tid)))

    def route_legs(name: str):
        return lambda: [LegProfile.from_profile(p) for p in load_route_profiles(st, name)]

    for name in resolve_route_patterns(st, list(routes)) if routes else []:
        legs = load_route_legs(st, name, profiles=False)
        vec = legs[0].vector
        for leg in legs[1:]:
            vec = vec + leg.vector
        sources.append(Source(name=name, kind="route", vector=vec, legs=route_legs(name)))
    return sources


def store_resolver(store) -> LegResolver:
    """A resolver that also reads ``trip`` (a stored trip id) and ``route`` (a stored
    route name) leg sources from an open :class:`cevm.store.TripStore`."""

    def resolve(source: LegSource, base_dir: Path) -> CycleVector:
        if source.kind == "trip":
            return CycleVector.from_bytes(store.load_vector_bytes(source.ref))
        if source.kind == "route":
            return load_route_vector(store, source.ref)
        return default_resolver(source, base_dir)

    return resolve
