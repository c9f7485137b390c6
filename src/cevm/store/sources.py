"""Stored trips and routes as the inputs of the pure core: sweep sources
(:class:`cevm.core.sweep.Source`) for ``cevm predict`` and ``cevm feasibility``, and a
leg resolver (:func:`store_resolver`) for fleet scenarios whose legs are stored trips or
routes."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from contextlib import ExitStack
from pathlib import Path
from typing import Optional

from cevm.core.assignment import LegSource
from cevm.core.cycle import CycleVector
from cevm.core.sweep import LegProfile, Source
from cevm.errors import CevmError
from cevm.io.cycles import CycleFormat, read_cycle_files
from cevm.io.scenario import LegResolver, default_resolver
from cevm.store.failures import DamagedTripError
from cevm.store.location import existing_store_path
from cevm.store.routes import (
    check_route_profiles,
    load_route_legs,
    load_route_profiles,
    load_route_vector,
    resolve_route_patterns,
)
from cevm.store.trips import TripStore


def load_sources(stack: ExitStack, store: Optional[Path], cycles: Sequence[Path], trips: Sequence[str],
                 vehicle_ids: Sequence[str], routes: Sequence[str], cr0: float,
                 cycle_format: CycleFormat | None = None, *, need_profiles: bool = True,
                 on_damaged: Callable[[DamagedTripError], None] | None = None) -> list[Source]:
    """Sources in the order cycles (every cycle of each file, read with ``cycle_format``),
    trips, trips of vehicle ids, routes. A store is opened read-only (and kept open on
    ``stack``) only when a stored source is asked for; profiles are read from it when
    first needed. A stored trip's source carries its logged mean ambient temperature.

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
        if not got:
            raise CevmError(f"vehicle id {vid!r} has no usable stored trips (all are damaged); "
                            "'cevm store check' lists them")
        vectors.update((tid, vec) for tid, vec in got.items() if tid not in vectors)
    ambient = {}
    if vectors:
        rows = st.list_trips(trip_ids=list(vectors))
        ambient = dict(zip(rows["trip_id"], rows["ambient_temp_c"]))

    def trip_legs(tid: str):
        return lambda: (LegProfile.from_profile(st.load_profile(tid)),)

    for tid, vec in vectors.items():
        t_c = ambient.get(tid)
        sources.append(Source(name=tid, kind="trip", vector=vec, legs=trip_legs(tid),
                              ambient_c=None if t_c is None or not math.isfinite(t_c) else float(t_c)))

    def route_legs(name: str):
        return lambda: [LegProfile.from_profile(p) for p in load_route_profiles(st, name)]

    for name in resolve_route_patterns(st, list(routes)) if routes else []:
        legs = load_route_legs(st, name, profiles=False)
        if need_profiles:
            check_route_profiles(st, name)
        vec = legs[0].vector
        for leg in legs[1:]:
            vec = vec + leg.vector
        sources.append(Source(name=name, kind="route", vector=vec, legs=route_legs(name)))
    return sources


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
