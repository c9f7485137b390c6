"""The calibrated vehicle file: the input vehicle file with the fitted values written in
(comments, tables and sources kept), the terms the model leaves out set to zero, and a
``[calibration]`` table that records what the fit saw; never over an existing file
silently."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from cevm.core.calibration import TERMS_BY_POWERTRAIN, CalibrationResult
from cevm.core.calibration.terms import EXTRA_TERMS
from cevm.errors import CevmError
from cevm.io.vehicles import stem_id


_TOP_KEY = re.compile(r"^(?P<key>[A-Za-z0-9_]+)\s*=\s*(?P<value>[^#\n]*?)(?P<rest>\s*(#.*)?)$")


def fitted_keys(result: CalibrationResult) -> dict[str, float | str]:
    """The vehicle-file keys (file units) of the fitted parameters, for an ICE the braking
    mode the fit was made under (eta means something else in each), and the reference
    temperature of a model with temperature terms (the median of the trips' means)."""
    v = result.vehicle
    keys: dict[str, float | str] = {}
    if not v.is_ev:
        keys["ice_braking"] = v.ice_braking
    fields = {t.field: t for (pt, _), t in TERMS_BY_POWERTRAIN.items() if pt == v.powertrain}
    for name in result.fitted:
        t = fields.get(name)
        if t is None:  # the balance temperatures, below
            continue
        key, factor = t.file
        keys[key] = getattr(v, name) * factor
    if any(fields[n].temperature for n in result.fitted if n in fields) and result.rows:
        temps = np.array([r.ambient_c for r in result.rows])
        keys["reference_temp_c"] = round(float(np.median(temps[np.isfinite(temps)])), 1)
        keys["heating_below_c"] = v.heating_below_c
        keys["cooling_above_c"] = v.cooling_above_c
    return keys


def neutral_keys(result: CalibrationResult) -> dict[str, float | None]:
    """Keys of the energy terms the calibrated model leaves out (zero, or None for a key
    to remove: regeneration and kinetic efficiency then follow eta): replaced where the
    input file has them, so its old values do not linger in the new model."""
    v = result.vehicle
    out: dict[str, float | None] = {}
    for name in EXTRA_TERMS[v.powertrain]:
        t = TERMS_BY_POWERTRAIN[(v.powertrain, name)]
        if t.field in result.fitted:
            continue
        value = getattr(v, t.field)
        if value is None:
            out[t.file[0]] = None
        elif value == 0.0:
            out[t.file[0]] = 0.0
    return out


def _toml_value(value) -> str:
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in value) + "]"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    return f"{value:.6g}"


def calibrated_toml(text: str, values: dict[str, float | str], header: str,
                    neutral: dict[str, float | None] | None = None,
                    calibration: dict | None = None) -> str:
    """``text`` (a vehicle TOML file) with top-level ``values`` replaced or added, the
    keys of ``neutral`` replaced (or, for None, commented out) where present, the
    ``[calibration]`` table replaced by ``calibration`` (when given), and a comment
    header; everything else (comments, tables, sources) is kept as it was."""
    lines = text.splitlines()
    if calibration is not None:
        lines = _without_table(lines, "calibration")
    first_table = next((i for i, line in enumerate(lines) if line.lstrip().startswith("[")), len(lines))
    todo = dict(values)
    neutral = dict(neutral or {})
    for i in range(first_table):
        m = _TOP_KEY.match(lines[i])
        if not m:
            continue
        key = m.group("key")
        old = m.group("value").strip()
        if key in todo:
            lines[i] = f"{key} = {_toml_value(todo.pop(key))}  # cevm calibrate (was {old})"
        elif key in neutral:
            value = neutral.pop(key)
            lines[i] = (f"# {key} = {old}  # removed by cevm calibrate: not in the calibrated model" if value is None
                        else f"{key} = {_toml_value(value)}  # cevm calibrate: not in the calibrated model (was {old})")
    added = [f"{k} = {_toml_value(v)}  # added by cevm calibrate" for k, v in todo.items()]
    lines[first_table:first_table] = added + ([""] if added and first_table < len(lines) else [])
    if calibration is not None:
        while lines and not lines[-1].strip():
            lines.pop()
        lines += ["", "# What the calibration saw (cevm calibrate): predictions outside it are warned about.",
                  "[calibration]"]
        lines += [f"{k} = {_toml_value(v)}" for k, v in calibration.items() if v is not None]
    head = [f"# {h}" for h in header.splitlines()]
    return "\n".join(head + lines) + "\n"


def _without_table(lines: list[str], name: str) -> list[str]:
    """``lines`` without the table ``[name]`` (its header to the next table header)."""
    out, skip = [], False
    for line in lines:
        stripped = line.strip()
        if stripped.startswith("["):
            skip = stripped.strip("[] ").split("#")[0].strip() == name and not stripped.startswith("[[")
            if skip:
                while out and out[-1].lstrip().startswith("#") and "cevm calibrate" in out[-1]:
                    out.pop()
                continue
        if not skip:
            out.append(line)
    return out


def calibration_table(result: CalibrationResult, *, store: str | None = None, selected_from: int | None = None,
                      nested_std_pct: float | None = None) -> dict:
    """The ``[calibration]`` table of the calibrated file, in file units (see
    :class:`cevm.core.vehicle.FitDomain`, which reads it back)."""
    from cevm import __version__

    d = result.domain

    def pair(x, f=1.0, nd=3):
        return None if x is None else [round(x[0] * f, nd), round(x[1] * f, nd)]

    def num(x, nd=3):
        return None if x is None or not math.isfinite(x) else round(float(x), nd)

    return {
        "by": f"cevm {__version__}",
        "vehicle_id": d.vehicle_id, "store": store, "terms": list(d.terms), "n_trips": d.n_trips,
        "first_trip_utc": d.first_utc, "last_trip_utc": d.last_utc,
        "ambient_c": pair(d.ambient_c, 1.0, 1), "mean_speed_kmh": pair(d.mean_speed_mps, 3.6, 2),
        "mass_kg": pair(d.mass_kg, 1.0, 0), "distance_km": pair(d.distance_m, 1e-3, 2),
        "mass_sources": d.mass_sources, "cv_scheme": d.cv_scheme, "cv_mean_pct": num(d.cv_mean_pct),
        "cv_std_pct": num(d.cv_std_pct), "nested_cv_std_pct": num(nested_std_pct),
        "candidates_compared": selected_from,
    }


def write_calibrated_vehicle(source: Path, out: Path, result: CalibrationResult, *, force: bool, note: str,
                             calibration: dict | None = None) -> None:
    """Write the calibrated vehicle file; refuse to overwrite anything unless ``force``."""
    if out.exists() and not force:
        what = "the input vehicle file" if out.resolve() == source.resolve() else "an existing file"
        raise CevmError(f"{out}: would overwrite {what}; give another --out or --force")
    fitted = ", ".join(f"{k} = {_toml_value(v)}" for k, v in fitted_keys(result).items())
    # the calibrated vehicle's id is its own file's stem: never the input file's 'id' key,
    # so the two can be predicted side by side (cevm.io.vehicles)
    values = {**fitted_keys(result), "id": stem_id(out)}
    text = calibrated_toml(source.read_text(encoding="utf-8"), values, f"{note}\nfitted: {fitted}",
                           neutral=neutral_keys(result), calibration=calibration)
    tmp = out.with_name(out.name + ".tmp")
    tmp.write_text(text, encoding="utf-8")
    tmp.replace(out)  # atomic: never a half-written vehicle file
