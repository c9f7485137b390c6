"""The ``cevm`` command line: a thin layer over the library.

Exit codes: 0 success; 1 some inputs of a batch failed (the rest was done);
2 bad usage or bad input (nothing was done). Errors caused by input are printed as one
line on stderr, without a traceback.
"""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Optional

import numpy as np
import typer

from cevm import __version__
from cevm.errors import CevmError
from cevm.io import read_cycle_csv
from cevm.core.model import ICE_BRAKING_MODES
from cevm.report import OutputFormat, write_rows
from cevm.units import J_PER_KWH

if TYPE_CHECKING:
    from cevm.core.calibration import CalibrationResult

EXIT_OK = 0
EXIT_PARTIAL = 1
EXIT_INPUT = 2

StoreOption = Annotated[
    Optional[Path],
    typer.Option("--store", envvar="CEVM_STORE", help="Trip store (SQLite). Default: $CEVM_STORE, else ~/.local/share/cevm/cevm.sqlite."),
]

app = typer.Typer(
    name="cevm",
    help="Vehicle energy and fuel from drive cycles, fast: the computationally efficient (CE) model.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def _fail(message: str, code: int = EXIT_INPUT) -> typer.Exit:
    typer.echo(f"cevm: error: {message}", err=True)
    return typer.Exit(code)


def _existing_store(store: Optional[Path], hint: Optional[str] = None) -> Path:
    """The store a reading command needs, or the usual one-line error (exit 2)."""
    from cevm.store import NO_STORE_HINT, existing_store_path

    try:
        return existing_store_path(store, hint or NO_STORE_HINT)
    except CevmError as exc:
        raise _fail(str(exc)) from None


def _version(value: bool) -> None:
    if value:
        typer.echo(f"cevm {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: Annotated[
        bool, typer.Option("--version", callback=_version, is_eager=True, help="Print the version and exit.")
    ] = False,
) -> None:
    """cevm: how much diesel or electricity a vehicle uses on a route."""


@app.command()
def ingest(
    paths: Annotated[list[str], typer.Argument(help="Log files, directories (recursive) or glob patterns; .csv and .csv.gz.")],
    store: StoreOption = None,
    dsm: Annotated[
        Optional[str], typer.Option(help="DSM for road elevation: a GeoTIFF, a directory of tiles, a VRT, or a GDAL URL.")
    ] = None,
    profile: Annotated[Optional[str], typer.Option(help="Force a logger profile by name (default: detect from the header).")] = None,
    profiles_dir: Annotated[Optional[Path], typer.Option(help="A directory of extra logger profiles (TOML).")] = None,
    force: Annotated[bool, typer.Option(help="Re-ingest files even when unchanged.")] = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar and no table: failures and one summary line only.")] = False,
    log_json: Annotated[bool, typer.Option(help="One JSON object per file on stdout, then a summary object (for cron and scripts).")] = False,
    workers: Annotated[
        Optional[int], typer.Option("--workers", "-w", min=1, help="Worker processes, one file per task (default: the machine's cores; 1: serial, in this process).")
    ] = None,
    scheduler: Annotated[
        Optional[str], typer.Option(help="Dask scheduler address (tcp://HOST:8786): run the per-file work on that cluster (pip install 'cevm[dask]'); the workers must read the log files at the same paths, and the DSM.")
    ] = None,
) -> None:
    """Read logger CSV exports into the trip store (clean trips, DSM elevation, vectors).

    Clean trips, DSM elevation, measured consumption and drive-cycle vectors.

    Files are processed in parallel (--workers, or a Dask cluster with --scheduler); this
    process alone writes the store, in input order, so the result is that of a serial run.
    Each failed file is reported on stderr (file, line, column, why) as it happens and
    skipped; the rest is stored. Exit 0 if every file was ingested or unchanged, 1 if any
    failed, 2 for bad options (unknown profile, unreadable DSM, unreachable scheduler)."""
    import json

    from cevm.ingest import IngestOptions
    from cevm.ingest import ingest as run_ingest
    from cevm.executors import make_executor
    from cevm.store import TripStore, resolve_store_path

    if workers is not None and scheduler is not None:
        raise _fail("give --workers (local processes) or --scheduler (a Dask cluster), not both")

    options = IngestOptions(dsm=dsm, profile=profile, profiles_dir=str(profiles_dir) if profiles_dir else None, force=force)
    store_path = resolve_store_path(store)
    progress = None
    if not quiet and not log_json and sys.stderr.isatty():
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        progress = Progress(TextColumn("ingest"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                            TextColumn("{task.description}"), transient=True)
    task = None

    def on_start(n: int) -> None:
        nonlocal task
        if progress is not None:
            progress.start()
            task = progress.add_task("", total=n)

    def on_file(fr) -> None:
        if log_json:
            typer.echo(json.dumps({"event": "file", **_file_dict(fr)}))
        elif fr.status == "failed":
            (progress.console.print if progress is not None else lambda m: typer.echo(m, err=True))(
                f"cevm: failed: {fr.error}"
            )
        if progress is not None and task is not None:  # inputs that matched nothing come before the bar
            progress.update(task, advance=1, description=Path(fr.path).name)

    try:
        with make_executor(workers, scheduler) as executor, TripStore.open(store_path) as st:
            report = run_ingest(paths, st, options, on_file=on_file, on_start=on_start, executor=executor)
    except CevmError as exc:
        raise _fail(str(exc)) from None
    finally:
        if progress is not None:
            progress.stop()
    summary = report.summary()
    if log_json:
        typer.echo(json.dumps({"event": "summary", "store": str(store_path), **summary}))
    elif quiet:
        typer.echo(_summary_line(summary, store_path))
    else:
        _print_ingest_table(report, summary, store_path)
    raise typer.Exit(EXIT_PARTIAL if report.failed else EXIT_OK)


def _file_dict(fr) -> dict:
    return {"path": fr.path, "status": fr.status, "trips": fr.trips, "samples": fr.samples,
            "km": round(fr.km, 3), "seconds": round(fr.seconds, 4), "profile": fr.profile,
            "error": fr.error, "duplicates": fr.duplicates, "repairs": list(fr.repairs)}


def _summary_line(s: dict, store_path: Path) -> str:
    return (f"cevm ingest: {s['files']} files ({s['ingested']} ingested, {s['unchanged']} unchanged, "
            f"{s['failed']} failed), {s['trips']} trips, {s['samples']} samples, {s['km']:.1f} km "
            f"in {s['seconds']:.2f} s -> {store_path}")


def _print_ingest_table(report, summary: dict, store_path: Path) -> None:
    rows = [
        {"file": Path(f.path).name, "status": f.status, "profile": f.profile or "-", "trips": f.trips,
         "samples": f.samples, "km": f.km, "s": f.seconds, "repairs": len(f.repairs)}
        for f in report.files
    ]
    if len(rows) <= 40:
        write_rows(rows, OutputFormat.table, title="cevm ingest", digits={"km": 1, "s": 2},
                   columns=["file", "status", "profile", "trips", "samples", "km", "s", "repairs"])
    typer.echo(_summary_line(summary, store_path))


@app.command()
def trips(
    store: StoreOption = None,
    vehicle_id: Annotated[Optional[str], typer.Option("--vehicle-id", help="Only this vehicle's trips.")] = None,
    fmt: Annotated[OutputFormat, typer.Option("--format", "-f", help="Output format.")] = OutputFormat.table,
) -> None:
    """List the stored trips."""
    from cevm.store import TripStore, format_trips

    path = _existing_store(store)
    try:
        with TripStore.open(path) as st:
            df = format_trips(st.list_trips(vehicle_id=vehicle_id))
    except CevmError as exc:
        raise _fail(str(exc)) from None
    rows = [{k: (None if isinstance(v, float) and v != v else v) for k, v in r.items()} for r in df.to_dict("records")]
    columns = ["trip_id", "vehicle_id", "start_utc", "distance_km", "duration_s", "measured_fuel_l",
               "measured_energy_kwh", "dsm_coverage_pct", "elevation_source"]
    if fmt == OutputFormat.table:
        columns = [c for c in columns if any(r.get(c) is not None for r in rows)] or columns[:5]
        write_rows(rows, fmt, columns=columns, title=f"cevm trips ({len(rows)})", headers=TRIPS_HEADERS,
                   digits={"duration_s": 0, "dsm_coverage_pct": 1, "distance_km": 2})
    else:
        write_rows(rows, fmt)


TRIPS_HEADERS = {"vehicle_id": "vehicle", "start_utc": "start (UTC)", "distance_km": "km", "duration_s": "s",
                 "measured_fuel_l": "fuel l", "measured_energy_kwh": "kWh", "dsm_coverage_pct": "DSM %",
                 "elevation_source": "elevation"}


@app.command()
def calibrate(
    vehicle: Annotated[Path, typer.Option("--vehicle", "-v", help="The vehicle file to start from.")],
    vehicle_id: Annotated[str, typer.Option("--vehicle-id", help="Whose stored trips to fit (see 'cevm trips').")],
    store: StoreOption = None,
    fit: Annotated[
        Optional[list[str]],
        typer.Option("--fit", help="Parameters to fit: eta (always), aux_power (EV), idle_fuel (ICE), cda, cr. Repeatable or comma-separated."),
    ] = None,
    out: Annotated[Optional[Path], typer.Option("--out", "-o", help="Write the calibrated vehicle file here.")] = None,
    force: Annotated[bool, typer.Option(help="Allow --out to overwrite an existing file.")] = False,
    cv_folds: Annotated[int, typer.Option(help="Cross-validation folds over days (leave-one-day-out below 10 days).")] = 5,
    max_rel_uncertainty: Annotated[float, typer.Option(help="Exclude trips measured worse than this (relative 1-sigma).")] = 0.10,
    plot: Annotated[Optional[Path], typer.Option(help="Write predicted-vs-measured and error-vs-distance plots (PNG).")] = None,
    ice_braking: Annotated[
        Optional[str],
        typer.Option(help="ICE: fit under this braking mode (no-credit or paper) and write it to --out. Default: the vehicle file's."),
    ] = None,
    fmt: Annotated[OutputFormat, typer.Option("--format", "-f", help="table, or json (figures plus per-trip rows).")] = OutputFormat.table,
) -> None:
    """Fit eta (and what the data supports) to a vehicle's measured trips.

    With in-sample and cross-validated errors: the paper's tables 1 and 2 for your fleet."""
    from cevm.io.calibrated import write_calibrated_vehicle
    from cevm.io.plots import plot_calibration
    from cevm.store.calibration import trips_for_calibration
    from cevm.core.calibration import fit as fit_vehicle
    from cevm.io import load_vehicle
    from cevm.store import TripStore

    params = ["eta"] + [p.strip() for f in (fit or []) for p in f.split(",") if p.strip() and p.strip() != "eta"]
    if cv_folds < 2:
        raise _fail("--cv-folds must be at least 2")
    path = _existing_store(store)
    if ice_braking is not None and ice_braking not in ICE_BRAKING_MODES:
        raise _fail(f"--ice-braking must be one of: {', '.join(ICE_BRAKING_MODES)}")
    try:
        veh = load_vehicle(vehicle)
        if ice_braking is not None:
            if veh.is_ev:
                raise CevmError(f"{vehicle}: --ice-braking applies to ICE vehicles only")
            veh = dataclasses.replace(veh, ice_braking=ice_braking)
        with TripStore.open(path) as st:
            sel = trips_for_calibration(st, vehicle_id, veh)
        result = fit_vehicle(veh, sel.trips, params, cv_folds=cv_folds, max_rel_uncertainty=max_rel_uncertainty)
        if out is not None:
            write_calibrated_vehicle(vehicle, out, result, force=force,
                                     note=f"calibrated by cevm calibrate on {len(result.rows)} trips of {vehicle_id} "
                                          f"(store {path})")
        if plot is not None:
            plot_calibration(result, plot, f"{veh.name} ({vehicle_id})")
    except CevmError as exc:
        raise _fail(str(exc)) from None
    report = result_json(result, vehicle_id, sel.notes)
    if fmt == OutputFormat.json:
        typer.echo(dumps(report))
    elif fmt == OutputFormat.csv:
        write_rows(report["trips"], fmt)
    else:
        _print_calibration(report, veh.is_ev)
    if out is not None and fmt == OutputFormat.table:
        typer.echo(f"calibrated vehicle written to {out}")


#: The paper's CE-model figures (tables 1 and 2), for comparison.
PAPER_CE = {True: ("electric bus, table 1", 0.4, 4.0, 19e-3, 2.6e-3), False: ("diesel HGV, table 2", 1.3, 3.7, 16.5e-3, 2.5e-3)}


def _print_calibration(r: dict, is_ev: bool) -> None:
    name, mu, sd, tmu, tsd = PAPER_CE[is_ev]
    ins, cv, t = r["in_sample"], r["cross_validated"], r["time_per_prediction_s"]

    def pct(x):
        return "-" if x is None else f"{x:+.2f} %" if x else "0.00 %"

    rows = [
        {"item": "mu(e)", "in-sample": pct(ins["mean_pct"]), "cross-validated": pct(cv and cv["mean_pct"]), f"paper ({name})": f"{mu:+.1f} %"},
        {"item": "sigma(e)", "in-sample": pct(ins["std_pct"]).lstrip("+"), "cross-validated": pct(cv and cv["std_pct"]).lstrip("+"), f"paper ({name})": f"{sd:.1f} %"},
        {"item": "mu(t_exe)", "in-sample": "-" if t is None else f"{t['mean'] * 1e6:.1f} us", "cross-validated": "", f"paper ({name})": f"{tmu * 1e3:.1f} ms"},
        {"item": "sigma(t_exe)", "in-sample": "-" if t is None else f"{t['std'] * 1e6:.1f} us", "cross-validated": "", f"paper ({name})": f"{tsd * 1e3:.1f} ms"},
        {"item": "trips", "in-sample": str(r["n_trips"]), "cross-validated": r["cv_scheme"], f"paper ({name})": "-"},
    ]
    write_rows(rows, OutputFormat.table, title=f"cevm calibrate: {r['vehicle_id']}, error e = (modelled - measured) / measured")
    fitted = []
    for k, v in r["fitted"].items():
        scale, unit = {"aux_power_w": (1e-3, "kW"), "idle_fuel_lps": (3600.0, "l/h")}.get(k, (1.0, ""))
        fitted.append({"parameter": k.replace("_w", "").replace("_lps", ""), "value": f"{v['value'] * scale:.4g} {unit}".strip(),
                       "std": f"{v['std'] * scale:.2g} {unit}".strip()})
    for k, why in r["refused"].items():
        fitted.append({"parameter": k, "value": "refused", "std": why})
    write_rows(fitted, OutputFormat.table, title="fitted parameters")
    for note in r["notes"]:
        typer.echo(f"note: {note}")
    if r["excluded"]:
        typer.echo(f"excluded {len(r['excluded'])} trips:")
        for tid, why in list(r["excluded"].items())[:20]:
            typer.echo(f"  {tid}: {why}")
        if len(r["excluded"]) > 20:
            typer.echo(f"  ... and {len(r['excluded']) - 20} more (see --format json)")


@app.command()
def simulate(
    vehicle: Annotated[Path, typer.Option("--vehicle", "-v", help="Vehicle file (with a [detailed] table).")],
    cycle: Annotated[Optional[Path], typer.Option("--cycle", "-c", help="Cycle CSV.")] = None,
    trip: Annotated[Optional[str], typer.Option("--trip", "-t", help="A stored trip id.")] = None,
    store: StoreOption = None,
    mass_kg: Annotated[Optional[float], typer.Option("--mass-kg", "-m", help="Gross mass [kg]. Default: the vehicle's.")] = None,
    soc_start_pct: Annotated[float, typer.Option("--soc-start", help="EV state of charge at the start [%].")] = 100.0,
    out: Annotated[Optional[Path], typer.Option("--out", "-o", help="Per-second output CSV.")] = None,
    plot: Annotated[Optional[Path], typer.Option(help="PNG: state of charge (EV, the paper's figure 4) or fuel and elevation (ICE, figure 6).")] = None,
    fmt: Annotated[OutputFormat, typer.Option("--format", "-f", help="Format of the summary.")] = OutputFormat.table,
) -> None:
    """Detailed time-step simulation of one vehicle over a trace (the baseline model).

    Motor map, regeneration limits and battery for an EV; gearbox and fuel map for a diesel."""
    from cevm.core.detailed import simulate as run_simulation
    from cevm.io import load_vehicle

    if (cycle is None) == (trip is None):
        raise _fail("give exactly one of --cycle or --trip")
    if not 0.0 < soc_start_pct <= 100.0:
        raise _fail("--soc-start must be in (0, 100]")
    try:
        veh = load_vehicle(vehicle)
        if cycle is not None:
            c = read_cycle_csv(cycle)
            name, t, v, h = c.name, c.time_s, c.speed_mps, c.elevation_m
        else:
            from cevm.store import TripStore, resolve_store_path

            with TripStore.open(resolve_store_path(store)) as st:
                prof = st.load_profile(trip)
            name, t, v, h = trip, prof["time_s"], prof["speed_mps"], prof["elevation_m"]
        res = run_simulation(veh, t, v, h, mass_kg=mass_kg, soc_start=soc_start_pct / 100.0)
    except CevmError as exc:
        raise _fail(str(exc)) from None
    except ValueError as exc:  # inconsistent [detailed] parameters or trace
        raise _fail(f"{vehicle}: {exc}") from None
    frame = res.to_frame()
    if out is not None:
        frame.to_csv(out, index=False, float_format="%.6g")
    if plot is not None:
        _plot_simulation(frame, res, plot, f"{veh.name}: {name}")
    row = {"cycle": name, "vehicle": veh.name, "mass_kg": res.mass_kg, "distance_km": res.distance_m / 1e3,
           "duration_s": res.duration_s, "wheel_energy_kwh": res.wheel_energy_j / J_PER_KWH,
           "friction_brake_kwh": res.friction_brake_energy_j / J_PER_KWH,
           "traction_deficit_kwh": res.traction_deficit_j / J_PER_KWH}
    if veh.is_ev:
        row["energy_kwh"] = res.energy_j / J_PER_KWH
        row["soc_end_pct"] = float(res.samples["soc"][-1]) * 100.0
        row["soc_min_pct"] = float(np.min(res.samples["soc"])) * 100.0
    else:
        row["fuel_l"] = res.fuel_l
        row["fuel_l_per_100km"] = 100.0 * res.fuel_l / (res.distance_m / 1e3) if res.distance_m > 0 else None
    if fmt == OutputFormat.table:
        write_rows([{"quantity": k, "value": v} for k, v in row.items()], fmt, title="cevm simulate (detailed model)")
    else:
        write_rows([row], fmt)
    if res.traction_deficit_j > 0.02 * max(res.wheel_energy_j, 1.0):
        typer.echo(f"cevm: warning: the vehicle could not follow the trace: {row['traction_deficit_kwh']:.2f} kWh "
                   "of wheel work beyond its powertrain's limits", err=True)


def _plot_simulation(frame, res, path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(10, 4.5))
    t_min = frame["time_s"] / 60.0
    if res.powertrain == "ev":
        ax.plot(t_min, frame["soc_pct"], label="state of charge")
        ax.set_ylabel("state of charge [%]")
    else:
        ax.plot(t_min, frame["fuel_cum_l"], label="fuel used")
        ax.set_ylabel("fuel used [l]")
    ax.set_xlabel("time [min]")
    ax.set_title(title)
    if "elevation_m" in frame:
        ax2 = ax.twinx()
        ax2.plot(t_min, frame["elevation_m"], color="0.6", lw=0.8, label="elevation")
        ax2.set_ylabel("elevation [m]")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


fleet_app = typer.Typer(help="Fleet assignment: which vehicle serves the shared stops (the paper's section 6).",
                        no_args_is_help=True)
app.add_typer(fleet_app, name="fleet")


@fleet_app.command("plan")
def fleet_plan(
    scenario: Annotated[Path, typer.Argument(help="Scenario TOML (see configs/fleet/paper-case-study.toml).")],
    day: Annotated[Optional[list[str]], typer.Option("--day", "-d", help="Day name or 0-based index. Repeatable. Default: every day.")] = None,
    method: Annotated[str, typer.Option(help="auto (enumerate when small, else MILP), enumerate, or milp.")] = "auto",
    store: StoreOption = None,
    fmt: Annotated[OutputFormat, typer.Option("--format", "-f", help="Output format.")] = OutputFormat.table,
) -> None:
    """The assignment of shared stops that minimises total fuel (or energy, or cost),
    within gross-weight limits and EV reserves: proven optimal (enumeration or MILP)."""
    import json

    from cevm.io.scenario import default_resolver, fleet_report
    from cevm.store.sources import store_resolver
    from cevm.store import TripStore, resolve_store_path

    if method not in ("auto", "enumerate", "milp"):
        raise _fail("--method must be auto, enumerate or milp")
    days = [int(d) if d.isdigit() else d for d in day] if day else None
    try:
        store_path = resolve_store_path(store)
        if store_path.exists():  # legs may be stored trips or routes
            with TripStore.open(store_path) as st:
                report = fleet_report(scenario, days, method=method, resolve_leg=store_resolver(st))
        else:
            report = fleet_report(scenario, days, method=method, resolve_leg=default_resolver)
    except CevmError as exc:
        raise _fail(str(exc)) from None
    if fmt == OutputFormat.json:
        typer.echo(json.dumps(report, indent=2))
        return
    unit = report["unit"]
    if fmt == OutputFormat.csv:
        rows = [{"day": p["day"], "vehicle": v["vehicle"], "stops": " ".join(v["stops"]), f"consumption_{unit}": v["value"]}
                for p in report["plans"] for v in p["vehicles"]]
        write_rows(rows, fmt)
        return
    day_cols = [k for k in report["table"][0] if k != "vehicle"] if report["table"] else []
    write_rows(report["table"], OutputFormat.table, columns=["vehicle", *day_cols],
               title=f"{report['scenario']}: stops per vehicle (the paper's table 4)")
    rows = []
    for p in report["plans"]:
        for v in p["vehicles"]:
            rows.append({"day": p["day"], "vehicle": v["vehicle"], unit: v["value"], "max gross kg": v["max_gross_used_kg"]})
    write_rows(rows, OutputFormat.table, title=f"consumption per vehicle [{unit}]", digits={unit: 2, "max gross kg": 0})
    summary = [{"day": s["day"], f"total {unit}": s["total"], f"default {unit}": s["default_total"],
                "saving %": s["saving_pct"], "method": s["method"], "status": s["status"],
                "solve ms": s["solve_time_s"] * 1e3} for s in report["summary"]]
    write_rows(summary, OutputFormat.table, title="optimum against the default assignment",
               digits={f"total {unit}": 2, f"default {unit}": 2, "saving %": 2, "solve ms": 2})


def result_json(result: CalibrationResult, vehicle_id: str, notes: tuple[str, ...]) -> dict:
    """The machine-readable form: figures of the table, fitted values, per-trip rows
    (each trip twice: its in-sample prediction, held_out false, and its cross-validated
    one, held_out true)."""
    from cevm.core.calibration import display_value
    from cevm.io.calibrated import fitted_keys

    unit = "kWh" if result.unit == "J" else "l"

    def stats(s):
        return None if s is None else {"n": s.n, "mean_pct": _f(s.mean_pct), "std_pct": _f(s.std_pct),
                                       "rms_pct": _f(s.rms_pct), "max_abs_pct": _f(s.max_abs_pct)}

    trips = []
    for r in result.rows:
        for held_out, pred, err in ((False, r.predicted_in_sample, r.error_pct_in_sample),
                                    (True, r.predicted_cv, r.error_pct_cv)):
            trips.append({"trip_id": r.trip_id, "measured": display_value(result, r.measured),
                          "predicted": _f(display_value(result, pred)), "error_pct": _f(err),
                          "held_out": held_out, "fold": r.fold if held_out else None, "unit": unit,
                          "distance_km": r.distance_m / 1e3, "mass_kg": r.mass_kg, "weight": r.weight,
                          "rel_uncertainty": r.rel_uncertainty})
    t = result.time_per_prediction_s
    return {
        "vehicle_id": vehicle_id,
        "eta": result.vehicle.eta,
        "fitted": {k: {"value": v, "std": s} for k, (v, s) in result.fitted.items()},
        "fitted_file_keys": fitted_keys(result),
        "refused": dict(result.refused),
        "excluded": dict(result.excluded),
        "n_trips": len(result.rows),
        "in_sample": stats(result.in_sample),
        "cross_validated": stats(result.cv),
        "cv_scheme": result.cv_scheme,
        "time_per_prediction_s": None if t is None else {"mean": t[0], "std": t[1]},
        "model_rel_sigma": result.model_rel_sigma,
        "unit": unit,
        "notes": list(notes) + list(result.warnings),
        "trips": trips,
    }


def _f(x: float) -> float | None:
    return float(x) if x is not None and np.isfinite(x) else None


def dumps(obj: dict) -> str:
    return json.dumps(obj, indent=2)


# predict, feasibility and route: defined in cevm.cli_predict on this app
from cevm import cli_predict  # noqa: E402,F401


def main() -> None:
    """Console entry point."""
    from cevm.runtime import tune_allocator

    tune_allocator()
    try:
        app()
    except CevmError as exc:  # a user's mistake that escaped a command: one line, no traceback
        typer.echo(f"cevm: error: {exc}", err=True)
        sys.exit(EXIT_INPUT)
