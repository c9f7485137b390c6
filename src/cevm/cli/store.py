"""``cevm store check | info``: whether the trip store is sound, and what it holds
(:mod:`cevm.store.integrity`). Both only read: they work on a read-only store."""

from __future__ import annotations

import json
import sys

import typer

from cevm.cli.common import EXIT_OK, EXIT_STORE_DAMAGED, FormatOption, StoreOption, existing_store, fail
from cevm.cli.output import OutputFormat, write_rows
from cevm.errors import CevmError

app = typer.Typer(help="The trip store itself: check it for damage, say what it holds.", no_args_is_help=True)


@app.command("check")
def store_check(
    store: StoreOption = None,
    fmt: FormatOption = OutputFormat.table,
) -> None:
    """Check the store: SQLite's integrity check, then every trip's and route's blobs read
    back, checked against their checksums and decoded.

    Damaged trips and routes are listed by id. Exit 0 if the store is sound, 4 if anything
    is damaged (restore a backup, or re-ingest the damaged trips' log files with --force,
    or all logs into a new store), 3 if it could not be read."""
    from cevm.store import TripStore
    from cevm.store.integrity import check_store

    path = existing_store(store)
    progress = None
    if fmt == OutputFormat.table and sys.stderr.isatty():
        from rich.progress import Progress

        progress = Progress(transient=True)
    from cevm.store.failures import StoreDamagedError

    try:
        try:
            st = TripStore.open(path, readonly=True)
        except StoreDamagedError:  # too damaged to be migrated: SQLite's own check still says what it can
            st = TripStore(path, readonly=True, migrate=False)
        with st:
            if progress is None:
                report = check_store(st)
            else:
                with progress:
                    task = progress.add_task("checking trips", total=None)
                    report = check_store(st, lambda done, total: progress.update(task, completed=done, total=total))
    except CevmError as exc:
        raise fail(exc) from None
    if fmt == OutputFormat.json:
        typer.echo(json.dumps(report.as_dict(), indent=2))
    elif fmt == OutputFormat.csv:
        write_rows([{"kind": p.kind, "id": p.ident, "problem": p.problem} for p in report.problems], fmt,
                   columns=["kind", "id", "problem"])
    else:
        if report.problems:
            write_rows([{"kind": p.kind, "id": p.ident, "problem": p.problem} for p in report.problems], fmt,
                       title=f"cevm store check: {len(report.problems)} problem(s)", columns=["kind", "id", "problem"])
        damaged = len({p.ident for p in report.problems if p.kind == "trip"})
        verdict = "sound" if report.ok else "DAMAGED"
        typer.echo(f"cevm store check: {path}: {verdict}; SQLite integrity check: {report.integrity.splitlines()[0]}; "
                   f"{report.trips_checked} trips ({damaged} damaged) and {report.routes_checked} routes read back")
    raise typer.Exit(EXIT_OK if report.ok else EXIT_STORE_DAMAGED)


@app.command("info")
def store_info_cmd(
    store: StoreOption = None,
    fmt: FormatOption = OutputFormat.table,
) -> None:
    """What the store holds: schema version, files, trips, vehicles, routes, the last
    ingest run."""
    from cevm.store import TripStore, format_utc
    from cevm.store.integrity import store_info

    path = existing_store(store)
    try:
        with TripStore.open(path, readonly=True) as st:
            info = store_info(st)
    except CevmError as exc:
        raise fail(exc) from None
    if fmt == OutputFormat.json:
        typer.echo(json.dumps(info, indent=2))
        return
    if fmt == OutputFormat.csv:
        flat = {k: v for k, v in info.items() if k != "last_run"}
        flat.update({f"last_run_{k}": v for k, v in (info["last_run"] or {}).items() if k != "counts"})
        write_rows([flat], fmt)
        return
    last = info["last_run"]
    rows = [
        ("store", info["store"]),
        ("size", f"{info['size_bytes'] / 1e6:,.1f} MB"),
        ("schema version", str(info["schema_version"])),
        ("created", "-" if info["created_utc_s"] is None else
         f"{format_utc(info['created_utc_s'])} by cevm {info['created_by']}"),
        ("opened", f"{info['opened']}, journal {info['journal_mode']}"),
        ("files", f"{info['files_ok']} ok, {info['files_failed']} failed"),
        ("trips", f"{info['trips']} of {info['vehicles']} vehicles"),
        ("routes", str(info["routes"])),
        ("trip masses", f"{info['trip_masses']} given" + (f" ({info['trip_masses_of_trips_gone']} of trips no longer "
                                                          "stored)" if info["trip_masses_of_trips_gone"] else "")),
        ("last ingest", "-" if last is None else
         f"{format_utc(last['started_utc_s'])} on {last['host']}"
         + ("" if last["finished_utc_s"] is not None else " (unfinished: crashed or running)")),
    ]
    write_rows([{"item": k, "value": v} for k, v in rows], OutputFormat.table, title="cevm store info",
               columns=["item", "value"])
