"""``cevm calibrate``: fit eta (and what the data supports) to a vehicle's stored trips,
with cross-validated errors (:mod:`cevm.core.calibration`, :mod:`cevm.store.calibration`,
:mod:`cevm.io.calibrated`)."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import numpy as np
import typer

from cevm.cli.common import (
    EXIT_PARTIAL,
    PNG,
    TOML,
    StoreOption,
    check_output_path,
    existing_store,
    fail,
    warn_damaged,
)
from cevm.cli.output import OutputFormat, write_lines, write_rows
from cevm.core.model import ICE_BRAKING_MODES
from cevm.errors import CevmError

if TYPE_CHECKING:
    from cevm.core.calibration import CalibrationResult


def calibrate(
    vehicle: Annotated[Path, typer.Option("--vehicle", "-v", metavar="FILE", help="The vehicle file to start from.")],
    vehicle_id: Annotated[str, typer.Option("--vehicle-id", help="Whose stored trips to fit (see 'cevm trips').")],
    store: StoreOption = None,
    fit: Annotated[
        list[str] | None,
        typer.Option("--fit", metavar="NAMES",
                     help="Force a term set instead of choosing one: eta (always) plus any of regen, aux, "
                          "heat, cool, warm (EV); idle, run, kin, heat, cool, warm (ICE); cda, cr. "
                          "Repeatable or comma-separated."),
    ] = None,
    terms: Annotated[
        list[str] | None,
        typer.Option("--terms", metavar="NAMES",
                     help="Choose only among these extra terms (default: all of the powertrain's). "
                          "Repeatable or comma-separated."),
    ] = None,
    nested: Annotated[bool, typer.Option("--nested/--no-nested", help="Also cross-validate the choice itself "
                                                                        "(nested cross-validation).")] = True,
    out: Annotated[Path | None,
                   typer.Option("--out", "-o", metavar="FILE", help="Write the calibrated vehicle file here.")] = None,
    force: Annotated[bool, typer.Option(help="Allow --out to overwrite an existing file.")] = False,
    cv_folds: Annotated[int,
                        typer.Option(help="Cross-validation folds over days; with fewer than 10 days, or no more days "
                                          "than folds, each day is its own fold (leave-one-day-out).")] = 5,
    max_rel_uncertainty: Annotated[
        float, typer.Option(help="Exclude trips measured worse than this (relative 1-sigma).")] = 0.10,
    plot: Annotated[Path | None,
                    typer.Option(metavar="FILE.png",
                                 help="Write predicted-vs-measured and error-vs-distance plots (PNG).")] = None,
    ice_braking: Annotated[
        str | None,
        typer.Option(help="ICE: fit under this braking mode (no-credit or paper) and write it to --out. Default: the "
                          "vehicle file's."),
    ] = None,
    fmt: Annotated[OutputFormat,
                   typer.Option("--format", "-f", help="table; csv (the per-trip rows); or json (figures plus "
                                                         "per-trip rows).")] = OutputFormat.table,
    interval: Annotated[float, typer.Option(
        metavar="LEVEL", help="Level of the per-trip intervals (predicted_low, predicted_high) and of the coverage "
                              "reported: the share of held-out trips inside their interval.")] = 0.9,
) -> None:
    """Fit the vehicle's model to its measured trips: a posterior from the vehicle class's
    priors, with every answer's range.

    The vehicle's physical terms (EV: auxiliary power, heating, A/C; diesel: idle,
    heating and cooling fuel) start from its class's priors (the file's 'class' and
    [prior], else inferred from its mass) and are always in the model: where the trips
    cannot tell one (a summer trial and heating) it keeps its prior. The structural
    terms (regeneration, warm-up; running fuel, kinetic efficiency) and the logs'
    standstill rates as observations are chosen by grouped cross-validation: the
    simplest set within one standard error of the best. Physically implausible values
    are refused, chosen or forced (--fit). Each trip is also predicted by a fit that
    never saw its day, with an interval (--interval), and the summary says how many of
    them it holds. In-sample and cross-validated errors: the paper's tables 1 and 2 for
    your fleet."""
    from cevm.core.calibration import Calibrator, term
    from cevm.io import load_vehicle
    from cevm.io.calibrated import calibration_table, write_calibrated_vehicle
    from cevm.io.plots import plot_calibration
    from cevm.store import TripStore
    from cevm.store.calibration import trips_for_calibration

    forced = [p.strip() for f in (fit or []) for p in f.split(",") if p.strip()]
    allowed = [p.strip() for f in (terms or []) for p in f.split(",") if p.strip() and p.strip() != "eta"]
    if forced and allowed:
        raise fail("give --fit (a forced term set) or --terms (the terms to choose among), not both")
    if cv_folds < 2:
        raise fail("--cv-folds must be at least 2")
    if not 0.0 < interval < 1.0:
        raise fail(f"--interval must be a level between 0 and 1 (0.9: 90 %), got {interval:g}")
    check_output_path(out, "--out", TOML)
    check_output_path(plot, "--plot", PNG)
    if out is not None and out.exists() and not force:  # said before the fit, not after it (onto -v: cevm.cli.paths)
        raise fail(f"--out {out}: would overwrite an existing file; give another --out or --force")
    path = existing_store(store)
    if ice_braking is not None and ice_braking not in ICE_BRAKING_MODES:
        raise fail(f"--ice-braking must be one of: {', '.join(ICE_BRAKING_MODES)}")
    try:
        veh = load_vehicle(vehicle)
        if ice_braking is not None:
            if veh.is_ev:
                raise CevmError(f"{vehicle}: --ice-braking applies to ICE vehicles only")
            veh = dataclasses.replace(veh, ice_braking=ice_braking)
        with TripStore.open(path, readonly=True) as st:
            sel = trips_for_calibration(st, vehicle_id, veh)
        cal = Calibrator(veh, fit_terms=["eta", *forced] if forced else None,
                         terms=[term(veh, t).name for t in allowed] if allowed else None, nested=nested,
                         cv_folds=cv_folds, max_rel_uncertainty=max_rel_uncertainty, vehicle_id=vehicle_id,
                         interval=interval).fit(sel.trips)
        result, selection = cal.result_, cal.selection_
        if out is not None:
            table = calibration_table(
                result, store=str(path), selected_from=None if selection is None else len(selection.candidates),
                compared=None if selection is None else selection.n_compared,
                nested_std_pct=None if selection is None or selection.nested_cv is None
                else selection.nested_cv.std_pct)
            write_calibrated_vehicle(vehicle, out, result, force=force, calibration=table,
                                     note=f"calibrated by cevm calibrate on {len(result.rows)} trips of {vehicle_id} "
                                          f"(store {path})")
        if plot is not None:
            plot_calibration(result, plot, f"{veh.name} ({vehicle_id}): {'+'.join(result.terms)}")
    except CevmError as exc:
        raise fail(exc) from None
    report = result_json(result, vehicle_id, sel.notes + (() if selection is None else selection.notes), selection)
    if fmt == OutputFormat.json:
        typer.echo(dumps(report))
    elif fmt == OutputFormat.csv:
        write_rows(report["trips"], fmt)
    else:
        _print_calibration(report, veh.is_ev, veh.vehicle_class)
    if out is not None and fmt == OutputFormat.table:
        typer.echo(f"calibrated vehicle written to {out}")
    for problem in sel.damaged:
        warn_damaged(problem)
    if sel.damaged:
        raise typer.Exit(EXIT_PARTIAL)


#: The paper's CE-model figures (tables 1 and 2), for comparison, by (is_ev, class): it
#: has a row for an electric bus (table 1) and a diesel HGV (table 2) only, so a car, a
#: van or an electric truck is compared with none.
PAPER_CE = {(True, "bus"): ("electric bus, table 1", 0.4, 4.0, 19e-3, 2.6e-3),
            (False, "truck"): ("diesel HGV, table 2", 1.3, 3.7, 16.5e-3, 2.5e-3)}


def _pct(x, sign=True) -> str:
    if x is None:
        return "-"
    return f"{x:+.2f} %" if sign else f"{x:.2f} %"


def _print_calibration(r: dict, is_ev: bool, vehicle_class: str | None = None) -> None:
    paper = PAPER_CE.get((is_ev, vehicle_class or ""))
    name, mu, sd, tmu, tsd = paper or ("", math.nan, math.nan, math.nan, math.nan)
    ins, cv, t, nested = r["in_sample"], r["cross_validated"], r["time_per_prediction_s"], r["nested_cross_validated"]
    rows = [
        {"item": "mu(e)", "in-sample": _pct(ins["mean_pct"]), "cross-validated": _pct(cv and cv["mean_pct"]),
         f"paper ({name})": f"{mu:+.1f} %"},
        {"item": "sigma(e)", "in-sample": _pct(ins["std_pct"], False),
         "cross-validated": _pct(cv and cv["std_pct"], False), f"paper ({name})": f"{sd:.1f} %"},
    ]
    if nested is not None:
        rows.append({"item": "sigma(e), choice included", "in-sample": "",
                     "cross-validated": _pct(nested["std_pct"], False) + " (nested)", f"paper ({name})": "-"})
    rows += [
        {"item": "mu(t_exe)", "in-sample": "-" if t is None else f"{t['mean'] * 1e6:.1f} us", "cross-validated": "",
         f"paper ({name})": f"{tmu * 1e3:.1f} ms"},
        {"item": "sigma(t_exe)", "in-sample": "-" if t is None else f"{t['std'] * 1e6:.1f} us", "cross-validated": "",
         f"paper ({name})": f"{tsd * 1e3:.1f} ms"},
        {"item": "trips", "in-sample": str(r["n_trips"]), "cross-validated": r["cv_scheme"], f"paper ({name})": "-"},
    ]
    iv = r["interval"]
    cov = r["coverage"]
    if cov.get("level") is not None and cov.get("inside") is not None:
        rows.insert(2 + (nested is not None), {
            "item": f"held-out trips inside their {100 * iv:g} % interval", "in-sample": "",
            "cross-validated": f"{cov['inside']} of {cov['trips']} ({100 * cov['share']:.0f} %)",
            f"paper ({name})": "-"})
        rows.insert(3 + (nested is not None), {
            "item": "mean interval width", "in-sample": "", "cross-validated": _pct(cov["mean_rel_width_pct"], False)
            + " of measured", f"paper ({name})": "-"})
    if paper is None:  # no row of the paper's to compare with: its column left out, and said
        for row in rows:
            row.pop(f"paper ({name})")
    write_rows(rows, OutputFormat.table, title=f"cevm calibrate: {r['vehicle_id']}, model {'+'.join(r['terms'])}, "
                                               "error e = (modelled - measured) / measured")
    if paper is None:
        kind = f"{'an electric' if is_ev else 'a diesel'} {vehicle_class or 'vehicle of no stated class'}"
        _say(f"the paper has CE-model errors for an electric bus (table 1) and a diesel HGV (table 2) only: "
             f"none to compare {kind} with")
    if r["candidates"]:
        _print_candidates(r["candidates"])
    fitted = [{"parameter": p["label"], "value": p["value_text"], "std": p["std_text"],
               "prior": p.get("prior_text") or "-"} for p in r["parameters"]]
    for k, why in r["refused"].items():
        fitted.append({"parameter": k, "value": "refused", "std": why, "prior": "-"})
    pri = r["priors"]
    write_rows(fitted, OutputFormat.table,
               title="fitted parameters (posterior mean, 1-sigma)" + (f"; priors of {pri['describe']}" if pri else ""))
    labels = {p["field"]: p["label"] for p in r["parameters"]}
    for k, why in r["prior_kept"].items():
        _say(f"prior kept: {labels.get(k, k)}: {why.removeprefix('kept its prior: ')}")
    sc = r["scatter"]
    if sc:
        _say(f"scatter of a trip around the model: {sc['aux_text']} x its duration, {100 * sc['share']:.1f} % "
             f"of its energy and {sc['trip_text']} a trip (from the held-out trips); within a day, correlation "
             f"{sc['day_correlation_note']}")
    if cov.get("by_level"):
        _say("held-out coverage at other levels: " + ", ".join(
            f"{100 * float(lv):g} %: {100 * sh:.0f} %" for lv, sh in cov["by_level"].items() if float(lv) != iv))
    if r["evidence"]:
        e = r["evidence"]
        _say(f"standing still: the model draws {e['fitted_text']}, the logs measured {e['measured_text']} "
                   f"({e['seconds'] / 60:.0f} min over {e['trips']} trips)")
    d = r["domain"]
    if d:
        parts = [f"{d['n_trips']} trips"]
        if d.get("first_trip_utc"):
            parts.append(f"{d['first_trip_utc'][:10]} to {d['last_trip_utc'][:10]}")
        if d.get("ambient_c"):
            parts.append("{:.1f} to {:.1f} degC".format(*d["ambient_c"]))
        else:
            parts.append("no temperature logged")
        if d.get("mean_speed_kmh"):
            parts.append("{:.0f} to {:.0f} km/h mean".format(*d["mean_speed_kmh"]))
        if d.get("mass_kg"):
            parts.append("{:,.0f} to {:,.0f} kg".format(*d["mass_kg"]))
        _say("fitted on: " + ", ".join(parts) + " (predictions outside are warned about)")
    for note in r["notes"]:
        _say(f"note: {note}")
    if r["excluded"]:
        _say(f"excluded {len(r['excluded'])} trips:")
        for tid, why in list(r["excluded"].items())[:20]:
            _say(f"  {tid}: {why}")
        if len(r["excluded"]) > 20:
            _say(f"  ... and {len(r['excluded']) - 20} more (see --format json)")


def _say(text: str) -> None:
    """A line of calibrate's report, wrapped between words on a terminal
    (:func:`cevm.cli.output.write_lines`)."""
    import sys

    write_lines([text], sys.stdout)


#: Candidates listed in the table at most (the rest: --format json).
CANDIDATE_ROWS = 12


def _print_candidates(cands: list[dict]) -> None:
    ok = [c for c in cands if c["status"] != "refused"]
    refused = [c for c in cands if c["status"] == "refused"]
    ok.sort(key=lambda c: (c["cv"]["rms_pct"] if c["cv"] else 1e9))
    shown = ok[:CANDIDATE_ROWS]
    if not any(c["terms"] == ["eta"] for c in shown):
        shown += [c for c in ok if c["terms"] == ["eta"]]
    rows = [{"terms": "+".join(c["terms"]) + (" (standstill)" if c.get("standstill") else ""),
             "CV mu": _pct(c["cv"]["mean_pct"]), "CV sigma": _pct(c["cv"]["std_pct"], False),
             "CV rms": _pct(c["cv"]["rms_pct"], False), "": "<- chosen" if c["status"] == "chosen" else "",
             "parameters": ", ".join(p["short"] for p in c["parameters"])} for c in shown]
    more = f"; the {len(shown)} best shown (all: --format json)" if len(shown) < len(ok) else ""
    write_rows(rows, OutputFormat.table, title=f"model selection: {len(cands)} candidates, {len(ok)} compared by "
                                               f"grouped cross-validation ({len(refused)} refused), the simplest "
                                               f"within 1 SE of the best chosen{more}")
    if refused:
        reasons: dict[str, int] = {}
        for c in refused:
            reasons[c["reason"]] = reasons.get(c["reason"], 0) + 1
        _say(f"refused: {len(refused)} candidates (a term the data cannot identify, or an implausible value):")
        for why, n in sorted(reasons.items(), key=lambda kv: -kv[1])[:8]:
            _say(f"  {n} x {why}")


def _parameters(fitted: dict, powertrain: str, priors=None) -> list[dict]:
    """Display forms of fitted values (field -> (value, std), SI), with their priors."""
    from cevm.core.calibration import TERMS_BY_POWERTRAIN

    by_field = {t.field: t for (pt, _), t in TERMS_BY_POWERTRAIN.items() if pt == powertrain}
    out = []
    for field, (value, std) in fitted.items():
        if field in ("heating_below_c", "cooling_above_c"):
            what = "heating below" if field == "heating_below_c" else "cooling above"
            out.append({"term": field, "field": field, "label": f"{what} (balance, on a 2 K grid)", "value": value,
                        "std": None, "value_text": f"{value:g} degC", "std_text": "-",
                        "short": f"{what.split()[0]} < {value:g} C" if field == "heating_below_c"
                        else f"cooling > {value:g} C"})
            continue
        t = by_field[field]
        unit, scale = t.display
        p = priors.get(t.name) if priors is not None else None
        prior_text = None if p is None else f"{p.low * scale:.3g} to {p.high * scale:.3g} {unit}".strip()
        out.append({"term": t.name, "field": field, "label": f"{t.label} ({t.name})", "value": value, "std": std,
                    "value_text": f"{value * scale:.4g} {unit}".strip(),
                    "std_text": f"{std * scale:.2g} {unit}".strip(),
                    "short": f"{t.name} {value * scale:.3g}{(' ' + unit) if unit else ''}",
                    "prior": None if p is None else [p.low, p.high], "prior_text": prior_text,
                    "prior_source": None if p is None else p.source})
    return out


def _coverage(result: CalibrationResult) -> dict:
    """The held-out trips inside their intervals: at the chosen level and the others."""
    inside = [r.inside for r in result.rows if r.inside is not None]
    return {"level": result.interval if inside else None, "inside": int(sum(inside)) if inside else None,
            "trips": len(inside), "share": (sum(inside) / len(inside)) if inside else None,
            "mean_rel_width_pct": _f(result.mean_rel_width_pct),
            "by_level": {f"{k:g}": v for k, v in result.coverage.items()}}


def _scatter(result: CalibrationResult) -> dict | None:
    sc = result.scatter
    if sc is None:
        return None
    ev = result.vehicle.is_ev
    aux_text = f"{sc.aux / 1e3:.2f} kW" if ev else f"{sc.aux * 3600:.2f} l/h"
    trip_text = f"{sc.trip / 3.6e6:.2f} kWh" if ev else f"{sc.trip:.2f} l"
    return {"aux": sc.aux, "aux_unit": "W" if ev else "l/s", "aux_text": aux_text, "share": sc.share,
            "trip": sc.trip, "trip_unit": "J" if ev else "l", "trip_text": trip_text,
            "day_correlation": sc.day_corr, "day_correlation_note": sc.day_corr_note, "standstill": sc.standstill,
            "meter_share": None if result.posterior is None else result.posterior.meter_share}


def result_json(result: CalibrationResult, vehicle_id: str, notes: tuple[str, ...], selection=None) -> dict:
    """The machine-readable form: figures of the table, fitted values, the compared
    candidates (with ``selection``), per-trip rows (each trip twice: its in-sample
    prediction, held_out false, and its cross-validated one, held_out true, each with
    its interval at the result's level: predicted_low, predicted_high, inside)."""
    from cevm.core.calibration import display_value
    from cevm.core.distribution import interval
    from cevm.io.calibrated import calibration_table, fitted_keys

    unit = "kWh" if result.unit == "J" else "l"
    pt = result.vehicle.powertrain

    def stats(s):
        return None if s is None else {"n": s.n, "mean_pct": _f(s.mean_pct), "std_pct": _f(s.std_pct),
                                       "rms_pct": _f(s.rms_pct), "max_abs_pct": _f(s.max_abs_pct)}

    trips = []
    for r in result.rows:
        for held_out, pred, err, low, high in (
                (False, r.predicted_in_sample, r.error_pct_in_sample,
                 *(float(x) for x in interval(r.predicted_in_sample, r.sd_in_sample, result.interval))),
                (True, r.predicted_cv, r.error_pct_cv, r.predicted_low, r.predicted_high)):
            lo, hi = _f(display_value(result, low)), _f(display_value(result, high))
            meas = display_value(result, r.measured)
            trips.append({"trip_id": r.trip_id, "measured": meas,
                          "predicted": _f(display_value(result, pred)), "predicted_low": lo, "predicted_high": hi,
                          "inside": None if lo is None or hi is None else bool(lo <= meas <= hi),
                          "error_pct": _f(err), "held_out": held_out, "fold": r.fold if held_out else None,
                          "unit": unit, "distance_km": r.distance_m / 1e3, "mass_kg": r.mass_kg,
                          "mass_source": r.mass_source, "ambient_c": _f(r.ambient_c), "weight": r.weight,
                          "rel_uncertainty": r.rel_uncertainty, "flags": "; ".join(r.flags) or None})
    candidates = []
    if selection is not None:
        for c in selection.candidates:
            refused = not c.ok
            candidates.append({
                "terms": list(c.terms), "standstill": c.standstill, "status": "refused" if refused else c.status,
                "reason": c.status.removeprefix("refused: ") if refused else None,
                "cv": stats(c.cv), "in_sample": stats(c.in_sample), "parameters": _parameters(c.fitted, pt),
            })
    t = result.time_per_prediction_s
    pri = result.priors
    return {
        "vehicle_id": vehicle_id,
        "terms": list(result.terms),
        "eta": result.vehicle.eta,
        "fitted": {k: {"value": v, "std": s} for k, (v, s) in result.fitted.items()},
        "parameters": _parameters(result.fitted, pt, pri),
        "fitted_file_keys": fitted_keys(result),
        "refused": dict(result.refused),
        "prior_kept": dict(result.prior_kept),
        "excluded": dict(result.excluded),
        "n_trips": len(result.rows),
        "in_sample": stats(result.in_sample),
        "cross_validated": stats(result.cv),
        "nested_cross_validated": None if selection is None else stats(selection.nested_cv),
        "cv_scheme": result.cv_scheme,
        "interval": result.interval,
        "coverage": _coverage(result),
        "scatter": _scatter(result),
        "posterior_source": None if result.posterior is None else result.posterior.source,
        "priors": None if pri is None else {"class": pri.vehicle_class, "class_from": pri.class_from,
                                            "describe": pri.describe()},
        "standstill_observations": result.standstill_used,
        "selection_rule": None if selection is None else selection.rule,
        "candidates_total": None if selection is None else len(selection.candidates),
        "candidates_compared": None if selection is None else selection.n_compared,
        "candidates": candidates,
        "evidence": result.evidence,
        "domain": calibration_table(result),
        "time_per_prediction_s": None if t is None else {"mean": t[0], "std": t[1]},
        "unit": unit,
        "notes": list(notes) + list(result.warnings),
        "trips": trips,
    }


def _f(x: float) -> float | None:
    return float(x) if x is not None and np.isfinite(x) else None


def dumps(obj: dict) -> str:
    return json.dumps(obj, indent=2)
