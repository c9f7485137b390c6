"""``cevm route add | list | remove``: named routes in the store (:mod:`cevm.store.routes`)."""

from __future__ import annotations

from typing import Annotated, Any

import typer

from cevm.cli.common import (
    CycleOption,
    FormatOption,
    StoreOption,
    TripOption,
    cr0_check,
    existing_store,
    fail,
    with_cycle_options,
)
from cevm.cli.output import OutputFormat, write_rows
from cevm.core.cycle import CR0_DEFAULT
from cevm.errors import CevmError

app = typer.Typer(help="Named routes (a bus block, a delivery round): sequences of stored trips or cycle files.",
                  no_args_is_help=True, rich_markup_mode=None)


@app.command("add")
@with_cycle_options
def route_add(
    name: Annotated[str, typer.Argument(help="Route name: letters, digits, '.', '_', '-'.")],
    trip: TripOption = None,
    cycle: CycleOption = None,
    leg: Annotated[
        list[str] | None,
        typer.Option("--leg", metavar="trip:ID|cycle:PATH",
                     help="A leg as trip:ID or cycle:PATH, in order (to mix trips and cycles). Repeatable."),
    ] = None,
    store: StoreOption = None,
    replace: Annotated[bool, typer.Option(help="Overwrite an existing route of this name.")] = False,
    note: Annotated[str | None, typer.Option(help="A note kept with the route.")] = None,
    cr0: Annotated[float, typer.Option(help="Cr0 for the cycle legs' vectors (trips keep theirs).",
                                       callback=cr0_check)] = CR0_DEFAULT,
    cycle_fmt=None,
) -> None:
    """Store a named route: stored trips (--trip) or cycle files (--cycle) in the order
    given, or a mix with --leg trip:ID --leg cycle:PATH. Cycle legs are copied into the
    store (vector and profile), so the route does not depend on the files afterwards; a
    file with several selected speed columns (--speed-col) gives one leg per column."""
    from cevm.store import TripStore, resolve_store_path
    from cevm.store.routes import add_route

    given = sum(bool(x) for x in (trip, cycle, leg))
    if given == 0:
        raise fail("give the legs: --trip ID ..., --cycle PATH ..., or --leg trip:ID|cycle:PATH ...")
    if given > 1:
        raise fail("--trip, --cycle and --leg cannot be combined (their order would be lost); "
                    "to mix trips and cycles use --leg trip:ID --leg cycle:PATH in order")
    specs: list[tuple[str, str]] = [("trip", t) for t in trip or []] + [("cycle", str(c)) for c in cycle or []]
    for s in leg or []:
        kind, sep, ref = s.partition(":")
        if not sep or kind not in ("trip", "cycle") or not ref:
            raise fail(f"--leg {s!r}: expected trip:ID or cycle:PATH")
        specs.append((kind, ref))
    path = resolve_store_path(store)
    if any(k == "trip" for k, _ in specs) and not path.exists():
        raise fail(f"{path}: no trip store here; run 'cevm ingest' first or give --store")
    try:
        legs = _legs(specs, cycle_fmt)
        with TripStore.open(path) as st:
            info = add_route(st, name, legs, replace=replace, cr0=cr0, note=note)
    except CevmError as exc:
        raise fail(exc) from None
    n_trip = sum(1 for x in info.legs if x.kind == "trip")
    n_cycle = len(info.legs) - n_trip
    msg = f"route {info.name!r}: {len(info.legs)} legs ({n_trip} trips, {n_cycle} cycles) stored in {path}"
    if n_cycle:
        msg += "; cycle legs are copied into the store (vector and profile), the files are no longer needed"
    typer.echo(msg)


@app.command("list")
def route_list(
    store: StoreOption = None,
    fmt: FormatOption = OutputFormat.table,
) -> None:
    """List the stored routes: legs, distance, duration."""
    from cevm.store import TripStore, format_utc
    from cevm.store.routes import check_route_profiles, list_routes, load_route_legs

    path = existing_store(store, "run 'cevm ingest' or 'cevm route add' first, or give --store")
    rows: list[dict[str, Any]] = []
    try:
        with TripStore.open(path, readonly=True) as st:
            for info in list_routes(st):
                row = {"route": info.name, "legs": len(info.legs),
                       "trips": sum(1 for x in info.legs if x.kind == "trip"),
                       "cycles": sum(1 for x in info.legs if x.kind == "cycle"),
                       "distance_km": None, "duration_s": None, "created_utc": format_utc(info.created_utc_s),
                       "status": "ok", "sources": " ".join(f"{x.kind}:{x.label}" for x in info.legs),
                       "note": info.note}
                try:
                    legs = load_route_legs(st, info.name, profiles=False)
                    check_route_profiles(st, info.name)
                    row["distance_km"] = sum(x.vector.distance_m for x in legs) / 1000.0
                    row["duration_s"] = sum(x.vector.duration_s for x in legs)
                except CevmError as exc:
                    row["status"] = f"broken: {exc}"
                rows.append(row)
    except CevmError as exc:
        raise fail(exc) from None
    if fmt == OutputFormat.table:
        for r in rows:
            r["sources"] = _short_legs(r["sources"])
        write_rows(rows, fmt, title=f"cevm routes ({len(rows)})", digits={"distance_km": 2, "duration_s": 0},
                   columns=["route", "legs", "distance_km", "duration_s", "created_utc", "status", "sources"],
                   headers={"distance_km": "km", "duration_s": "s", "created_utc": "added (UTC)"})
    else:
        write_rows(rows, fmt)


def _short_legs(sources: str, width: int = 48) -> str:
    """'a a a b' -> 'a x3 b', cut to ``width`` characters (for the table)."""
    out: list[list] = []
    for item in sources.split():
        if out and out[-1][0] == item:
            out[-1][1] += 1
        else:
            out.append([item, 1])
    text = " ".join(f"{item} x{n}" if n > 1 else item for item, n in out)
    return text if len(text) <= width else text[: width - 3] + "..."


@app.command("remove")
def route_remove(
    name: Annotated[str, typer.Argument(help="The route to delete.")],
    store: StoreOption = None,
) -> None:
    """Delete a stored route (its trips stay in the store)."""
    from cevm.store import TripStore
    from cevm.store.routes import remove_route

    path = existing_store(store, "give --store")
    try:
        with TripStore.open(path) as st:
            gone = remove_route(st, name)
    except CevmError as exc:
        raise fail(exc) from None
    if not gone:
        raise fail(f"no route {name!r} in {path}; 'cevm route list' shows them")
    typer.echo(f"route {name!r} removed from {path}")


def _legs(specs: list[tuple[str, str]], cycle_fmt) -> list:
    """The legs of ``specs`` (kind, ref), cycle files read in order within the samples the
    files before left (:data:`cevm.store.routes.MAX_ROUTE_SAMPLES` over them all: a
    large file is refused at its line past the bound, before the rest is read)."""
    from cevm.io.cycles import MAX_CYCLE_SAMPLES, CycleTooLong
    from cevm.store.routes import MAX_ROUTE_SAMPLES, CycleLeg, TripLeg

    legs: list = []
    left = MAX_ROUTE_SAMPLES
    for kind, ref in specs:
        if kind == "trip":
            legs.append(TripLeg(ref))
            continue
        if left < 2:
            raise CevmError(f"{ref}: a route holds at most {MAX_ROUTE_SAMPLES:,} samples, and its cycle legs before "
                            "this one hold them all: split it into routes")
        try:
            read = CycleLeg.all_from_file(ref, cycle_fmt, max_samples=left)
        except CycleTooLong as exc:
            if exc.max_samples >= MAX_CYCLE_SAMPLES:  # the file's own bound
                raise
            raise CevmError(f"{exc.path}:{exc.line}: more than the {left:,} samples left: a route holds at most "
                            f"{MAX_ROUTE_SAMPLES:,} samples, and its cycle legs before this one "
                            f"{MAX_ROUTE_SAMPLES - left:,}: split it into routes") from None
        left -= sum(leg.cycle.time_s.size for leg in read)
        legs += read
    return legs
