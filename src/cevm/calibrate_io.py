"""The edges of calibration: stored trips in, a calibrated vehicle file and a plot out.

The fitting itself is pure (:mod:`cevm.core.calibration`); this module reads the store,
decides each trip's mass, quality factor and group, writes the calibrated vehicle file
(never over its input silently) and draws the paper's figures 5 and 7.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cevm.core.calibration import CalibrationResult, TripData
from cevm.core.cycle import CycleVector
from cevm.errors import CevmError
from cevm.store import TripStore
from cevm.core.trip import Measurement
from cevm.units import J_PER_KWH, S_PER_H
from cevm.core.vehicle import Vehicle


@dataclass(frozen=True)
class TripSelection:
    trips: tuple[TripData, ...]
    notes: tuple[str, ...]


def elevation_quality(elevation_source: str | None, dsm_coverage_pct: float | None) -> float:
    """Quality factor q in (0, 1] of a trip's road profile, for the calibration weights.

    q = 0.5 + 0.5 x DSM coverage for DSM-based profiles; 0.5 for GPS altitude or a flat
    road (a climb the model cannot see is an error the measurement cannot show). Equal
    factors cancel: only differences between trips move the fit.
    """
    cov = 0.0 if dsm_coverage_pct is None or not np.isfinite(dsm_coverage_pct) else float(dsm_coverage_pct)
    if elevation_source and elevation_source.startswith("dsm"):
        return 0.5 + 0.5 * min(max(cov, 0.0), 100.0) / 100.0
    return 0.5


def trips_for_calibration(store: TripStore, vehicle_id: str, vehicle: Vehicle) -> TripSelection:
    """The stored trips of ``vehicle_id`` as :class:`TripData`.

    Mass: the trip's measured gross weight where the logger reported one, else the
    vehicle file's mass. Group: the trip's UTC day, so trips of one day (one driver, one
    load, one weather) are held out together in cross-validation.
    """
    df = store.list_trips(vehicle_id=vehicle_id)
    if df.empty:
        known = ", ".join(store.vehicle_ids()[:10]) or "none"
        raise CevmError(f"vehicle id {vehicle_id!r} has no stored trips (stored vehicle ids: {known}); see 'cevm trips'")
    vectors = store.load_vectors(vehicle_id=vehicle_id)
    out: list[TripData] = []
    n_weight = 0
    for r in df.itertuples(index=False):
        meas = None
        if isinstance(r.measured_kind, str) and np.isfinite(r.measured_value):
            meas = Measurement(r.measured_kind, float(r.measured_value), str(r.measured_source),
                               float(r.measured_resolution), float(r.measured_uncertainty))
        gw = r.gross_weight_kg
        has_weight = gw is not None and np.isfinite(gw) and gw > 0
        n_weight += has_weight
        day = np.datetime_as_string(np.datetime64(int(r.start_utc_s), "s"), unit="D")
        out.append(TripData.from_measurement(
            r.trip_id, CycleVector.from_bytes(vectors[r.trip_id]), meas,
            mass_kg=float(gw) if has_weight else vehicle.mass_kg,
            quality=elevation_quality(r.elevation_source, r.dsm_coverage_pct),
            group=day,
        ))
    if n_weight == len(out):
        notes = [f"mass: the measured gross weight of each of the {len(out)} trips"]
    else:
        notes = [f"mass: measured gross weight on {n_weight} of {len(out)} trips, the vehicle file's "
                 f"{vehicle.mass_kg:,.0f} kg on the other {len(out) - n_weight} (give trips a gross weight for a better fit)"]
    return TripSelection(tuple(out), tuple(notes))


_TOP_KEY = re.compile(r"^(?P<key>[A-Za-z0-9_]+)\s*=\s*(?P<value>[^#\n]*?)(?P<rest>\s*(#.*)?)$")


def fitted_keys(result: CalibrationResult) -> dict[str, float | str]:
    """The vehicle-file keys (file units) of the fitted parameters, and for an ICE the
    braking mode the fit was made under (eta means something else in each)."""
    v = result.vehicle
    keys: dict[str, float | str] = {}
    if not v.is_ev:
        keys["ice_braking"] = v.ice_braking
    for name in result.fitted:
        if name == "eta":
            keys["eta"] = v.eta
        elif name == "aux_power_w":
            keys["aux_power_kw"] = v.aux_power_w / 1e3
        elif name == "idle_fuel_lps":
            keys["idle_fuel_lph"] = v.idle_fuel_lps * S_PER_H
        elif name in ("cda_m2", "cr"):
            keys[name] = getattr(v, name)
    return keys


def _toml_value(value: float | str) -> str:
    return f'"{value}"' if isinstance(value, str) else f"{value:.6g}"


def calibrated_toml(text: str, values: dict[str, float | str], header: str) -> str:
    """``text`` (a vehicle TOML file) with top-level ``values`` replaced or added, and a
    comment header; everything else (comments, tables, sources) is kept as it was."""
    lines = text.splitlines()
    first_table = next((i for i, line in enumerate(lines) if line.lstrip().startswith("[")), len(lines))
    todo = dict(values)
    for i in range(first_table):
        m = _TOP_KEY.match(lines[i])
        if m and m.group("key") in todo:
            key = m.group("key")
            old = m.group("value").strip()
            lines[i] = f"{key} = {_toml_value(todo.pop(key))}  # cevm calibrate (was {old})"
    added = [f"{k} = {_toml_value(v)}  # added by cevm calibrate" for k, v in todo.items()]
    lines[first_table:first_table] = added + ([""] if added and first_table < len(lines) else [])
    head = [f"# {h}" for h in header.splitlines()]
    return "\n".join(head + lines) + "\n"


def write_calibrated_vehicle(source: Path, out: Path, result: CalibrationResult, *, force: bool, note: str) -> None:
    """Write the calibrated vehicle file; refuse to overwrite anything unless ``force``."""
    if out.exists() and not force:
        what = "the input vehicle file" if out.resolve() == source.resolve() else "an existing file"
        raise CevmError(f"{out}: would overwrite {what}; give another --out or --force")
    fitted = ", ".join(f"{k} = {_toml_value(v)}" for k, v in fitted_keys(result).items())
    text = calibrated_toml(source.read_text(encoding="utf-8"), fitted_keys(result), f"{note}\nfitted: {fitted}")
    tmp = out.with_name(out.name + ".tmp")
    tmp.write_text(text, encoding="utf-8")
    tmp.replace(out)  # atomic: never a half-written vehicle file


def display_value(result: CalibrationResult, value: float) -> float:
    """Consumption in display units: litres, or kWh for joules."""
    return value / J_PER_KWH if result.unit == "J" else value


def plot_calibration(result: CalibrationResult, path: Path, title: str) -> None:
    """Predicted against measured with the 1:1 line (the paper's figures 5 and 7), and the
    percent error against trip distance, in-sample and cross-validated."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    unit = "kWh" if result.unit == "J" else "l"
    meas = np.array([display_value(result, r.measured) for r in result.rows])
    ins = np.array([display_value(result, r.predicted_in_sample) for r in result.rows])
    cv = np.array([display_value(result, r.predicted_cv) for r in result.rows])
    dist = np.array([r.distance_m for r in result.rows]) / 1e3
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.8))
    lim = [0, max(meas.max(), np.nanmax(cv) if np.isfinite(cv).any() else 0, ins.max()) * 1.05]
    a1.plot(lim, lim, "k-", lw=1, label="1:1")
    a1.scatter(meas, ins, s=18, label="CE model, in-sample")
    if np.isfinite(cv).any():
        a1.scatter(meas, cv, s=18, marker="x", label="CE model, cross-validated")
    a1.set(xlim=lim, ylim=lim, xlabel=f"measured [{unit}]", ylabel=f"modelled [{unit}]", title=title)
    a1.legend()
    a2.axhline(0, color="k", lw=1)
    a2.scatter(dist, [r.error_pct_in_sample for r in result.rows], s=18, label="in-sample")
    if np.isfinite(cv).any():
        a2.scatter(dist, [r.error_pct_cv for r in result.rows], s=18, marker="x", label="cross-validated")
    a2.set(xlabel="trip distance [km]", ylabel="error (modelled - measured) / measured [%]")
    a2.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def result_json(result: CalibrationResult, vehicle_id: str, notes: tuple[str, ...]) -> dict:
    """The machine-readable form: figures of the table, fitted values, per-trip rows
    (each trip twice: its in-sample prediction, held_out false, and its cross-validated
    one, held_out true)."""
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
