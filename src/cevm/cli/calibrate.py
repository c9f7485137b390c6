"""``cevm calibrate``: fit eta (and what the data supports) to a vehicle's stored trips,
with cross-validated errors (:mod:`cevm.core.calibration`, :mod:`cevm.store.calibration`,
:mod:`cevm.io.calibrated`)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Optional

import numpy as np
import typer

from cevm.cli.common import StoreOption, existing_store, fail
from cevm.cli.output import OutputFormat, write_rows
from cevm.core.model import ICE_BRAKING_MODES
from cevm.errors import CevmError

if TYPE_CHECKING:
    from cevm.core.calibration import CalibrationResult


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
        raise fail("--cv-folds must be at least 2")
    path = existing_store(store)
    if ice_braking is not None and ice_braking not in ICE_BRAKING_MODES:
        raise fail(f"--ice-braking must be one of: {', '.join(ICE_BRAKING_MODES)}")
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
        raise fail(str(exc)) from None
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
