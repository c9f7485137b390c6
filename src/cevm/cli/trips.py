"""``cevm trips`` (what is stored, with each trip's mass and where it comes from) and
``cevm trips set-mass`` (give trips their masses: by hand, or from a manifest;
:mod:`cevm.store.masses`, :mod:`cevm.io.manifest`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from cevm.cli.common import EXIT_OK, EXIT_PARTIAL, StoreOption, apply_manifest, existing_store, fail
from cevm.cli.output import OutputFormat, write_rows
from cevm.errors import CevmError

app = typer.Typer(help="The stored trips: list them (with their masses), give them their masses.")
_PANEL = "Manifest columns and format (detected when not given)"


@app.callback(invoke_without_command=True)
def trips(
    ctx: typer.Context,
    store: StoreOption = None,
    vehicle_id: Annotated[str | None, typer.Option("--vehicle-id", help="Only this vehicle's trips.")] = None,
    fmt: Annotated[OutputFormat, typer.Option("--format", "-f", help="Output format.")] = OutputFormat.table,
) -> None:
    """List the stored trips, each with its mass and where it comes from (a manifest, by
    hand, the logger, or none: the vehicle file's), the state of charge logged at its
    start (EV logs) and the time the vehicle stood since its previous stored trip (none
    for its first). 'cevm trips set-mass' gives trips their masses."""
    if ctx.invoked_subcommand is not None:
        return
    from cevm.store import TripStore, format_trips
    from cevm.store.masses import trip_masses

    path = existing_store(store)
    try:
        with TripStore.open(path, readonly=True) as st:
            listed = st.list_trips(vehicle_id=vehicle_id)
            df = format_trips(listed, trip_masses(st, listed))
    except CevmError as exc:
        raise fail(exc) from None
    rows = [{k: (None if isinstance(v, float) and v != v else v) for k, v in r.items()} for r in df.to_dict("records")]
    columns = ["trip_id", "vehicle_id", "start_utc", "distance_km", "duration_s", "start_soc_pct",
               "standstill_before_s", "mass_kg", "payload_kg", "mass_source", "measured_fuel_l", "measured_energy_kwh",
               "dsm_coverage_pct", "elevation_source"]
    if fmt == OutputFormat.table:
        columns = [c for c in columns if any(r.get(c) is not None for r in rows)] or columns[:5]
        write_rows(rows, fmt, columns=columns, title=f"cevm trips ({len(rows)})", headers=TRIPS_HEADERS,
                   digits={"duration_s": 0, "dsm_coverage_pct": 1, "distance_km": 2, "mass_kg": 0, "payload_kg": 0,
                           "start_soc_pct": 1, "standstill_before_s": 0})
        off = [r for r in rows if r["mass_vs_logged_pct"] is not None and abs(r["mass_vs_logged_pct"]) > 5.0]
        if off:
            typer.echo(f"cevm: note: {len(off)} trip(s) have a given mass more than 5 % from their logged gross "
                       "weight (the given one is used; columns logged_gross_kg, mass_vs_logged_pct in --format csv)",
                       err=True)
    else:
        write_rows(rows, fmt)


TRIPS_HEADERS = {"vehicle_id": "vehicle", "start_utc": "start (UTC)", "distance_km": "km", "duration_s": "s",
                 "measured_fuel_l": "fuel l", "measured_energy_kwh": "kWh", "dsm_coverage_pct": "DSM %",
                 "elevation_source": "elevation", "mass_kg": "mass kg", "payload_kg": "payload kg",
                 "mass_source": "mass from", "start_soc_pct": "SoC start %", "standstill_before_s": "stood s"}


@app.command("set-mass")
def set_mass(
    trip_ids: Annotated[list[str] | None, typer.Argument(help="Stored trip ids (see 'cevm trips').",
                                                            show_default=False)] = None,
    gross_kg: Annotated[float | None, typer.Option("--gross-kg", help="The trips' gross mass [kg].")] = None,
    payload_kg: Annotated[float | None, typer.Option(
        "--payload-kg", help="The trips' payload [kg]: added to the kerb_mass_kg of the vehicle file each command is "
                             "given.")] = None,
    clear: Annotated[bool, typer.Option("--clear", help="Forget the masses given to the trips (they fall back to "
                                                        "the logged gross weight, else the vehicle file's).")] = False,
    manifest: Annotated[Path | None, typer.Option(
        "--manifest", metavar="FILE",
        help="A manifest CSV (a transport management system's export): vehicle, and trip id or a "
             "start/end window, and gross or payload kg per row.")] = None,
    dry_run: Annotated[bool, typer.Option("--dry-run", help="Say what a manifest would give, store nothing.")] = False,
    store: StoreOption = None,
    vehicle_col: Annotated[str | None, typer.Option(help="Manifest: the vehicle id column.",
                                                       rich_help_panel=_PANEL)] = None,
    trip_col: Annotated[str | None, typer.Option(help="Manifest: the trip id column.", rich_help_panel=_PANEL)] = None,
    start_col: Annotated[str | None, typer.Option(help="Manifest: the window's start column (ISO 8601).",
                                                     rich_help_panel=_PANEL)] = None,
    end_col: Annotated[str | None, typer.Option(help="Manifest: the window's end column (ISO 8601).",
                                                   rich_help_panel=_PANEL)] = None,
    gross_col: Annotated[str | None, typer.Option(help="Manifest: the gross mass column.",
                                                     rich_help_panel=_PANEL)] = None,
    payload_col: Annotated[str | None, typer.Option(help="Manifest: the payload column.",
                                                       rich_help_panel=_PANEL)] = None,
    sep: Annotated[str | None, typer.Option(help="Manifest: the separator, one of , ; tab | (default: detected).",
                                               rich_help_panel=_PANEL)] = None,
    decimal: Annotated[str | None, typer.Option(help="Manifest: the decimal mark, . or , (default: , in a "
                                                        "';' file, else .).", rich_help_panel=_PANEL)] = None,
    mass_unit: Annotated[str | None, typer.Option(help="Manifest: kg or t (default: from the column name, else "
                                                          "kg).", rich_help_panel=_PANEL)] = None,
    tz: Annotated[str | None, typer.Option(help="Manifest: the zone of times without one: an IANA name "
                                                   "(Europe/London), UTC or +01:00. Without it such times are "
                                                   "refused.", rich_help_panel=_PANEL)] = None,
) -> None:
    """Give stored trips their gross mass or payload: by hand (TRIP_ID... --gross-kg KG),
    or from a manifest (--manifest FILE).

    A later value for a trip replaces the earlier; --clear forgets it. Each value is stored
    with where it came from (the manifest's file and line, or by hand) and when. A
    manifest row that matches no stored trip, or several, is reported with its line and
    not applied (exit 1); a mass more than 5 % from the trip's logged gross weight is
    reported. Predictions and calibrations then use, for each trip: the mass given here,
    else the logged gross weight, else the vehicle file's mass."""
    from cevm.io.manifest import GROSS_RANGE_KG, PAYLOAD_RANGE_KG, ManifestFormat, open_manifest
    from cevm.store import TripStore
    from cevm.store.masses import AssignedMass, clear_masses, set_masses, trip_masses

    given = [x for x in (gross_kg is not None, payload_kg is not None, clear, manifest is not None) if x]
    if len(given) != 1:
        raise fail("give one of --gross-kg, --payload-kg, --clear (with trip ids) or --manifest FILE")
    if manifest is not None and trip_ids:
        raise fail("--manifest names its trips itself: give no trip ids with it")
    if manifest is None and not trip_ids:
        raise fail("give the trip ids (see 'cevm trips'), or --manifest FILE")
    if dry_run and manifest is None:
        raise fail("--dry-run goes with --manifest")
    for value, (lo, hi), what in ((gross_kg, GROSS_RANGE_KG, "--gross-kg"), (payload_kg, PAYLOAD_RANGE_KG,
                                                                           "--payload-kg")):
        if value is not None and not lo <= value <= hi:
            raise fail(f"{what} {value:g}: a mass in kg from {lo:,.0f} to {hi:,.0f}")
    path = existing_store(store)
    try:
        fmt = ManifestFormat(sep=sep, decimal=decimal, vehicle_col=vehicle_col, trip_col=trip_col,
                             start_col=start_col, end_col=end_col, gross_col=gross_col, payload_col=payload_col,
                             mass_unit=mass_unit, tz=tz)
        with TripStore.open(path) as st:
            if manifest is not None:  # streamed: its rows are matched one at a time, never all held
                with open_manifest(manifest, fmt) as reader:
                    _applied, problems = apply_manifest(st, manifest, reader, dry_run=dry_run)
                raise typer.Exit(EXIT_PARTIAL if problems else EXIT_OK)
            ids = list(dict.fromkeys(trip_ids or []))  # given (checked above)
            if clear:
                n = clear_masses(st, ids)
                typer.echo(f"cevm trips set-mass: cleared the given masses of {n} of {len(ids)} trip(s) in {path}")
                return
            kind, value = ("gross", gross_kg) if gross_kg is not None else ("payload", payload_kg)
            assert value is not None  # exactly one of the options (checked above)
            new, replaced = set_masses(st, [AssignedMass(t, kind, float(value), "hand") for t in ids])
            typer.echo(f"cevm trips set-mass: {len(ids)} trip(s) given a {kind} mass of {value:,.0f} kg by hand "
                       f"({new} new, {replaced} replaced) in {path}")
            listed = st.list_trips(trip_ids=ids)
            for m in trip_masses(st, listed).values():
                text = m.disagreement()
                if text:
                    typer.echo(f"cevm: note: {text}", err=True)
    except CevmError as exc:
        raise fail(exc) from None
