"""``cevm ingest``: logger CSV exports into the trip store (:mod:`cevm.ingest`)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from cevm.cli.common import EXIT_OK, EXIT_PARTIAL, StoreOption, apply_manifest, check_workers, fail
from cevm.cli.output import OutputFormat, write_lines, write_rows
from cevm.errors import CevmError
from cevm.ingest.textfile import MAX_SAMPLES, ReadLimits
from cevm.text import one_line, printable

if TYPE_CHECKING:
    from rich.progress import TaskID

#: The defaults of the per-file limits (the flags show them in --help).
_LIMITS = ReadLimits()


def ingest(
    paths: Annotated[list[str],
                     typer.Argument(metavar="PATH",
                                    help="Log files, directories (recursive) or glob patterns; .csv and .csv.gz.")],
    store: StoreOption = None,
    dsm: Annotated[
        str | None, typer.Option(help="DSM for road elevation: a GeoTIFF, a directory of tiles, a VRT, or a GDAL URL.")
    ] = None,
    allow_remote_dsm: Annotated[
        bool,
        typer.Option(help="Allow a DSM (or VRT sources) that GDAL fetches over a network: URLs, /vsicurl/, /vsis3/ ... "
                          "(also: CEVM_ALLOW_REMOTE_DSM=1). Off: local GeoTIFFs and VRTs only.")
    ] = False,
    profile: Annotated[str | None,
                       typer.Option(help="Force a logger profile by name (default: detect from the header).")] = None,
    profiles_dir: Annotated[Path | None,
                            typer.Option(metavar="DIR", help="A directory of extra logger profiles (TOML).")] = None,
    force: Annotated[bool, typer.Option(help="Re-ingest files even when unchanged.")] = False,
    quiet: Annotated[bool,
                     typer.Option("--quiet", "-q",
                                  help="No progress bar and no table: failures and one summary line only.")] = False,
    log_json: Annotated[bool,
                        typer.Option(help="One JSON object per file on stdout, then a summary object (for cron and "
                                          "scripts).")] = False,
    workers: Annotated[
        int | None,
        typer.Option("--workers", "-w", min=1, metavar="N",
                     help="Worker processes (default: as many of the machine's cores as the batch's work pays for, "
                          "none for a small batch; 1: serial, in this process).")
    ] = None,
    scheduler: Annotated[
        str | None,
        typer.Option(help="Dask scheduler address (tcp://HOST:8786): run the per-file work on that cluster (pip "
                          "install 'cevm[dask]'); the workers must read the log files at the same paths, and the DSM.")
    ] = None,
    max_rows: Annotated[
        int | None,
        typer.Option(min=1, metavar="ROWS",
                     help="Refuse a file of more data rows than this. Default: 2,500,000, and at most 36 million "
                          "values (rows x columns read), which keeps a worker under 500 MB; given, the rows alone "
                          "bound a file (memory grows with rows and columns; see docs/guide/ingest.md).")
    ] = None,
    max_samples: Annotated[
        int,
        typer.Option(min=1, metavar="SAMPLES",
                     help="Refuse a file whose trips would hold more samples than this on the 1 s grid (a log every 5 "
                          "s gives 5 a row): the stored trips are held until written, so this keeps a worker under 500 "
                          "MB.")
    ] = MAX_SAMPLES,
    max_file_mb: Annotated[
        float,
        typer.Option(min=0.001, max=1e9, metavar="MB",  # a finite bound: inf is no size in bytes
                     help="Refuse a file of more text than this [MB], after decompression.")
    ] = _LIMITS.max_file_mb,
    max_expansion: Annotated[
        float, typer.Option(min=1.0, metavar="RATIO",
                            help="Refuse a gzip file that expands more than this many times (a zip bomb).")
    ] = _LIMITS.max_expansion,
    manifest: Annotated[
        Path | None,
        typer.Option(metavar="FILE",
                     help="A manifest CSV of trip masses, applied after the logs (its columns detected; for other "
                          "layouts: 'cevm trips set-mass --manifest' with column options).")
    ] = None,
    manifest_tz: Annotated[
        str | None, typer.Option(help="The manifest's zone for times without one (Europe/London, UTC, +01:00).")
    ] = None,
) -> None:
    """Read logger CSV exports into the trip store (clean trips, DSM elevation, vectors).

    Clean trips, DSM elevation, measured consumption and drive-cycle vectors.

    Files are processed in parallel (--workers, or a Dask cluster with --scheduler); this
    process alone writes the store, in input order, so the result is that of a serial run.
    Each failed file is reported on stderr (file, line, column, why) as it happens and
    skipped; the rest is stored. Exit 0 if every file was ingested or unchanged, 1 if any
    failed, 2 for bad options (no input holds a log file: then no store is created;
    unknown profile, unreadable DSM, unreachable scheduler).
    SIGINT (Ctrl-C) or SIGTERM stops the run: the file being written is finished, the
    rest left as it was, one line says which; exit 130 (SIGINT) or 143 (SIGTERM).

    --manifest gives the trips their masses once the logs are stored (as 'cevm trips
    set-mass --manifest' does); its rows that match no stored trip, or several, are
    reported with their line (exit 1)."""
    import json

    from cevm.cli import interrupts
    from cevm.executors import make_executor
    from cevm.ingest import IngestOptions
    from cevm.ingest import ingest as run_ingest
    from cevm.ingest.pipeline import discover
    from cevm.runtime import signals_deferred
    from cevm.store import TripStore, resolve_store_path
    from cevm.store.failures import StoreAccessError

    if workers is not None and scheduler is not None:
        raise fail("give --workers (local processes) or --scheduler (a Dask cluster), not both")
    check_workers(workers)

    limits = (ReadLimits(max_file_mb=max_file_mb, max_expansion=max_expansion, max_samples=max_samples)
              if max_rows is None else
              ReadLimits(max_file_mb=max_file_mb, max_expansion=max_expansion, max_rows=max_rows, max_values=None,
                         max_samples=max_samples))
    options = IngestOptions(dsm=dsm, profile=profile, profiles_dir=str(profiles_dir) if profiles_dir else None,
                            force=force, limits=limits, allow_remote_dsm=True if allow_remote_dsm else None)
    store_path = resolve_store_path(store)
    files, missing = discover(paths)
    if not files:  # nothing to ingest: bad usage, and no store is created for it
        for m in missing[:-1]:
            typer.echo(f"cevm: error: {printable(m)}", err=True)
        raise fail(missing[-1] + ("" if len(missing) == 1
                                  else f" (none of the {len(missing)} inputs holds a log file)"))
    files_seen = _FileEvents(quiet, log_json)  # the progress bar and the per-file lines
    progress, n_files, done = files_seen.progress, files_seen.n_files, files_seen.done
    on_start, on_file = files_seen.on_start, files_seen.on_file

    masses = _checked_manifest(manifest, manifest_tz)
    not_applied = 0
    manifest_applied = False  # said in the line of an interrupted run: the masses wait for the next one
    new_store = not store_path.exists()
    try:
        with make_executor(workers, scheduler) as executor, TripStore.open(store_path) as st:
            st.require_intact()  # never write into a damaged database
            report = run_ingest(paths, st, options, on_file=on_file, on_start=on_start, executor=executor)
            if masses is not None and manifest is not None:
                from cevm.io.manifest import open_manifest

                with signals_deferred(), open_manifest(manifest, masses) as reader:  # streamed: rows never all held
                    _, not_applied = apply_manifest(st, manifest, reader)
                    manifest_applied = True
    except StoreAccessError as exc:
        stop = fail(exc)
        if done:  # not for a store that could not even be opened or created
            typer.echo("cevm: note: the files written before the failure are stored, the one being written was "
                       "rolled back; run the same command again once it is fixed (stored files are skipped)", err=True)
        raise stop from None
    except CevmError as exc:  # bad options found once the store was open (profile, DSM): no store made for them
        if new_store and not done:
            _remove_store_files(store_path)
        raise fail(exc) from None
    except KeyboardInterrupt as exc:  # SIGINT, or SIGTERM under cevm.cli.main: what is stored, what is not
        if progress is not None:
            progress.stop()
        pending = manifest if masses is not None and not manifest_applied else None
        typer.echo(_interrupted_line(exc, done, n_files, store_path, pending), err=True)
        if log_json:
            typer.echo(json.dumps(_interrupted_event(exc, done, n_files, store_path,
                                                     None if masses is None else manifest_applied)))
        raise typer.Exit(interrupts.exit_code(exc)) from None
    finally:
        if progress is not None:
            progress.stop()
    # The run is finished and stored: a stop signal from here on stops nothing, and turns
    # neither the summary nor the exit code into an interrupted run's; it is said in a line.
    with interrupts.late_signals_noted() as late:
        summary = report.summary()
        if log_json:
            typer.echo(json.dumps({"event": "summary", "store": str(store_path), **summary}))
        elif quiet:
            typer.echo(_summary_line(summary, store_path))
        else:
            _print_ingest_table(report, summary, store_path)
        if late:
            typer.echo(f"cevm ingest: {interrupts.signal_name(interrupts.Interrupted(late[0]))} arrived after the "
                       "run had finished: it stopped nothing, the summary above stands", err=True)
    raise typer.Exit(EXIT_PARTIAL if report.failed or not_applied else EXIT_OK)


class _FileEvents:
    """What ``cevm ingest`` shows as files are done: a progress bar on a terminal (unless
    quiet or --log-json), a JSON event or a failure line per file. ``n_files``: the number
    the run found (once it starts); ``done``: the reports of the files written (or found
    unchanged, or failed), in order."""

    def __init__(self, quiet: bool, log_json: bool) -> None:
        self.log_json = log_json
        self.progress = None
        if not quiet and not log_json and sys.stderr.isatty():
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

            self.progress = Progress(TextColumn("ingest"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                                     TextColumn("{task.description}"), transient=True)
        self.task: TaskID | None = None
        self.n_files: list[int] = []
        self.done: list = []

    def on_start(self, n: int) -> None:
        self.n_files.append(n)
        if self.progress is not None:
            self.progress.start()
            self.task = self.progress.add_task("", total=n)

    def on_file(self, fr) -> None:
        import json

        progress = self.progress
        if self.n_files:  # not an input that matched nothing (those come before on_start)
            self.done.append(fr)
        if self.log_json:
            typer.echo(json.dumps({"event": "file", **_file_dict(fr)}))
        elif fr.status == "failed":
            message = f"cevm: failed: {one_line(str(fr.error))}"
            if progress is not None:
                progress.console.print(message, markup=False, highlight=False)
            else:
                typer.echo(message, err=True)
        if progress is not None and self.task is not None:  # inputs that matched nothing come before the bar
            progress.update(self.task, advance=1, description=Path(fr.path).name)


def _checked_manifest(manifest: Path | None, manifest_tz: str | None):
    """The ManifestFormat of ``--manifest`` (None without one), the file read through once
    (every line readable, within its bounds, holding no row): a manifest cevm cannot read
    stops the run before any work."""
    if manifest is None:
        return None
    from cevm.io.manifest import ManifestFormat, open_manifest

    masses = ManifestFormat(tz=manifest_tz)
    try:
        with open_manifest(manifest, masses) as reader:
            for _ in reader.items():
                pass
    except CevmError as exc:
        raise fail(exc) from None
    return masses


def _interrupted_event(exc: BaseException, done: list, n_files: list[int], store_path: Path,
                       manifest_applied: bool | None) -> dict:
    """The --log-json event of an interrupted run (``manifest_applied`` None: no --manifest)."""
    from cevm.cli import interrupts

    event = {"event": "interrupted", "signal": interrupts.signal_name(exc), "store": str(store_path),
             "files": n_files[0] if n_files else None, "done": len(done),
             "not_done": n_files[0] - len(done) if n_files else None}
    if manifest_applied is not None:
        event["manifest"] = "applied" if manifest_applied else "not applied"
    return event


def _remove_store_files(store_path: Path) -> None:
    """Remove a store this run created and wrote no file into (and SQLite's side files)."""
    for p in (store_path, *(store_path.with_name(store_path.name + s) for s in ("-wal", "-shm", "-journal"))):
        p.unlink(missing_ok=True)


def _file_dict(fr) -> dict:
    return {"path": fr.path, "status": fr.status, "trips": fr.trips, "samples": fr.samples,
            "km": round(fr.km, 3), "seconds": round(fr.seconds, 4), "profile": fr.profile,
            "error": fr.error, "duplicates": fr.duplicates, "repairs": list(fr.repairs)}


def _summary_line(s: dict, store_path: Path) -> str:
    return (f"cevm ingest: {s['files']} files ({s['ingested']} ingested, {s['unchanged']} unchanged, "
            f"{s['failed']} failed), {s['trips']} trips, {s['samples']} samples, {s['km']:.1f} km "
            f"in {s['seconds']:.2f} s -> {store_path}")


def _interrupted_line(exc: BaseException, done: list, n_files: list[int], store_path: Path,
                      manifest_pending: Path | None = None) -> str:
    """One line after an interrupt: the files done (each stored as reported), the files
    not done (left as the store had them), and a manifest whose masses were not applied."""
    from cevm.cli.interrupts import signal_name

    head = f"cevm ingest: interrupted by {signal_name(exc)}"
    masses = ""
    if manifest_pending is not None:
        masses = (f"; the manifest {printable(str(manifest_pending))} was not applied: no trip has its mass from it "
                  "(run again: the stored files are skipped, then the manifest is applied)")
    if not n_files:
        return f"{head} before any file was read; nothing stored{masses} -> {store_path}"
    counts = {k: sum(1 for f in done if f.status == k) for k in ("ingested", "unchanged", "failed")}
    return (f"{head}: {len(done)} of {n_files[0]} files done ({counts['ingested']} ingested, "
            f"{counts['unchanged']} unchanged, {counts['failed']} failed) and stored as reported; "
            f"{n_files[0] - len(done)} not done, left as they were (run again to ingest them){masses} -> {store_path}")


def _print_ingest_table(report, summary: dict, store_path: Path) -> None:
    rows = [
        {"file": Path(f.path).name, "status": f.status, "profile": f.profile or "-", "trips": f.trips,
         "samples": f.samples, "km": f.km, "s": f.seconds, "repairs": len(f.repairs)}
        for f in report.files
    ]
    if len(rows) <= 40:
        write_rows(rows, OutputFormat.table, title="cevm ingest", digits={"km": 1, "s": 2},
                   columns=["file", "status", "profile", "trips", "samples", "km", "s", "repairs"],
                   keep=("file", "status", "trips"), drop_order=("s", "profile", "samples"))
    write_lines([_summary_line(summary, store_path)], sys.stdout)  # wrapped on a terminal, whole in a log
