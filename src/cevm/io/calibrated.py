"""The calibrated vehicle file: the input vehicle file with the fitted values written in
(its comments, order, tables and other sources kept: edited with tomlkit), the terms the
model leaves out set to zero or removed, ``[sources]`` texts for every value calibrate
changed, and the tables that record what the fit saw (``[calibration]``), the priors it
started from (``[prior]``) and what it learnt (``[posterior]``: the coefficients'
standard deviations and correlations, the trips' scatter, :mod:`cevm.io.priors`); never
over an existing file silently."""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import tomlkit

from cevm import __version__
from cevm.core.calibration import TERMS_BY_POWERTRAIN, CalibrationResult
from cevm.core.calibration.terms import EXTRA_TERMS
from cevm.errors import CevmError
from cevm.io.outputs import write_text
from cevm.io.priors import posterior_table, prior_table
from cevm.io.vehicles import stem_id

#: Leading comment lines an earlier calibrate wrote (dropped before the new header).
_OLD_HEADER = re.compile(r"^# (calibrated by cevm calibrate|fitted: |removed by cevm calibrate: )")


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
    temps = np.array([r.ambient_c for r in result.rows])
    temps = temps[np.isfinite(temps)]
    if any(fields[n].temperature for n in result.fitted if n in fields) and temps.size:
        keys["reference_temp_c"] = round(float(np.median(temps)), 1)
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


def _round(value):
    """Floats to 6 significant digits (what the text form carries); others as they are."""
    if isinstance(value, float) and math.isfinite(value):
        return float(f"{value:.6g}")
    if isinstance(value, (list, tuple)):
        return [_round(x) for x in value]
    if isinstance(value, dict):
        return {k: _round(x) for k, x in value.items()}
    return value


def _table(mapping: dict, comment: str | None = None):
    t = tomlkit.table()
    if comment:
        t.add(tomlkit.comment(comment))
    for k, v in mapping.items():
        if v is None:
            continue
        if isinstance(v, dict):
            t.add(k, _table(v))
        else:
            t.add(k, _round(v))
    return t


def calibrated_toml(text: str, values: dict[str, float | str], header: str,
                    neutral: dict[str, float | None] | None = None, calibration: dict | None = None, *,
                    sources: dict[str, str] | None = None, prior: dict | None = None,
                    posterior: dict | None = None) -> str:
    """``text`` (a vehicle TOML file) with top-level ``values`` replaced or added (each
    with a comment saying what it was), the keys of ``neutral`` replaced (or, for None,
    removed: the header says so) where present, ``sources`` set in ``[sources]``, the
    ``[calibration]``, ``[prior]`` and ``[posterior]`` tables replaced by the given
    ones, and a comment header; everything else (comments, order, tables, other
    sources) is kept as it was."""
    lines = text.splitlines()
    while lines and _OLD_HEADER.match(lines[0]):
        lines.pop(0)
    doc = tomlkit.parse("\n".join(lines) + "\n")
    removed: list[str] = []
    for key, value in values.items():
        value = _round(value)
        if key in doc and not isinstance(doc[key], dict):
            old = doc[key]
            old_text = old.as_string().strip() if hasattr(old, "as_string") else repr(old)
            if key == "class" or old_text == tomlkit.item(value).as_string().strip():
                doc[key] = value
                continue
            doc[key] = value
            doc[key].comment(f"cevm calibrate (was {old_text})")
        else:
            item = tomlkit.item(value)
            item.comment("added by cevm calibrate")
            doc.add(key, item)
    for key, neutral_value in (neutral or {}).items():
        if key not in doc:
            continue
        old_text = doc[key].as_string().strip()
        if neutral_value is None:
            doc.remove(key)
            removed.append(f"{key} = {old_text}")
        else:
            doc[key] = _round(neutral_value)
            doc[key].comment(f"cevm calibrate: not in the calibrated model (was {old_text})")
    if sources:
        if "sources" not in doc:
            doc.add("sources", tomlkit.table())
        _set_keeping_trailing_comments(doc["sources"], sources)
    for name, table, comment in (
            ("calibration", calibration, "What the calibration saw (cevm calibrate): predictions outside it are "
                                         "warned about."),
            ("prior", prior, "The priors the calibration started from (cevm calibrate; ranges hold the value with "
                             "about 95 %); a new calibration starts from them again."),
            ("posterior", posterior, "What the calibration learnt (cevm calibrate): the fitted values' standard "
                                     "deviations (each key's unit) and correlations, and the trips' scatter.")):
        if table is None:
            continue
        if name in doc:
            doc.remove(name)
        doc.add(name, _table(table, comment))
    head = [f"# {h}" for h in header.splitlines()]
    if removed:
        head.append(f"# removed by cevm calibrate: {', '.join(removed)} (not in the calibrated model: regeneration "
                    "and kinetic efficiency follow eta)")
    return "\n".join(head) + "\n" + tomlkit.dumps(doc).rstrip("\n") + "\n"


def calibration_table(result: CalibrationResult, *, store: str | None = None, selected_from: int | None = None,
                      nested_std_pct: float | None = None, compared: int | None = None) -> dict:
    """The ``[calibration]`` table of the calibrated file, in file units (see
    :class:`cevm.core.vehicle.FitDomain`, which reads it back)."""
    d = result.domain
    if d is None:
        raise ValueError("a calibration result without its fit domain")

    def pair(x, f=1.0, nd=3):
        return None if x is None else [round(x[0] * f, nd), round(x[1] * f, nd)]

    def num(x, nd=3):
        return None if x is None or not math.isfinite(x) else round(float(x), nd)

    cov = result.coverage.get(result.interval) if result.coverage else None
    return {
        "by": f"cevm {__version__}",
        "vehicle_id": d.vehicle_id, "store": store, "terms": list(d.terms), "n_trips": d.n_trips,
        "first_trip_utc": d.first_utc, "last_trip_utc": d.last_utc,
        "ambient_c": pair(d.ambient_c, 1.0, 1), "mean_speed_kmh": pair(d.mean_speed_mps, 3.6, 2),
        "mass_kg": pair(d.mass_kg, 1.0, 0), "distance_km": pair(d.distance_m, 1e-3, 2),
        "idle_share": pair(d.idle_share, 1.0, 3),
        "mass_sources": d.mass_sources, "cv_scheme": d.cv_scheme, "cv_mean_pct": num(d.cv_mean_pct),
        "cv_std_pct": num(d.cv_std_pct), "nested_cv_std_pct": num(nested_std_pct),
        "candidates": selected_from, "candidates_compared": compared,
        "interval": num(result.interval, 3), "cv_coverage": num(cov, 3),
        "cv_mean_rel_width_pct": num(result.mean_rel_width_pct, 2),
    }


def _set_keeping_trailing_comments(table: Any, values: dict[str, str]) -> None:
    """Set ``values`` in a tomlkit table, new keys after its last key: the comments
    that end the table (in TOML they introduce the next one) stay at its end."""
    body = table.value.body
    last = max((i for i, (k, _) in enumerate(body) if k is not None), default=-1)
    trailing = body[last + 1:]
    del body[last + 1:]
    for key, why in values.items():
        table[key] = why
    for _, item in trailing:
        table.value.append(None, item)


def changed_sources(result: CalibrationResult, vehicle_id: str | None) -> dict[str, str]:
    """[sources] texts for every key calibrate writes: the fitted values (their posterior
    mean and standard deviation, the trips, the prior), the terms left out, the balance
    and reference temperatures."""
    v = result.vehicle
    pt = v.powertrain
    post = result.posterior
    base = post.source if post is not None else f"cevm calibrate on {len(result.rows)} trips"
    out: dict[str, str] = {}
    by_field = {t.field: t for (p, _), t in TERMS_BY_POWERTRAIN.items() if p == pt}
    priors = result.priors
    for field, (value, sd) in result.fitted.items():
        t = by_field.get(field)
        if t is None:
            continue
        key, f = t.file
        unit = t.display[0] if t.display[1] == f else ""
        u = f" {unit}" if unit else ""
        text = f"cevm calibrate, {base}: {value * f:.4g} +- {sd * f:.2g}{u} (posterior)"
        p = priors.get(t.name) if priors is not None else None
        if p is not None:
            kept = result.prior_kept.get(field)
            text += (f"; prior {p.low * f:.4g} to {p.high * f:.4g}{u} ({p.source})" + (f"; {kept}" if kept else ""))
        out[key] = text
    for key in neutral_keys(result):
        out[key] = f"cevm calibrate, {base}: not in the calibrated model"
    if "heating_below_c" in result.fitted or "cooling_above_c" in result.fitted:
        out["heating_below_c"] = f"cevm calibrate, {base}: balance temperature chosen on a grid by the evidence"
        out["cooling_above_c"] = out["heating_below_c"]
        out["reference_temp_c"] = f"cevm calibrate, {base}: the median of the trips' temperatures"
    if not v.is_ev:
        out["ice_braking"] = f"cevm calibrate, {base}: the braking mode the fit was made under"
    return out


def write_calibrated_vehicle(source: Path, out: Path, result: CalibrationResult, *, force: bool, note: str,
                             calibration: dict | None = None) -> None:
    """Write the calibrated vehicle file; refuse to overwrite anything unless ``force``."""
    if out.exists() and not force:
        what = "the input vehicle file" if out.resolve() == source.resolve() else "an existing file"
        raise CevmError(f"{out}: would overwrite {what}; give another --out or --force")
    fitted = ", ".join(f"{k} = {_round(v)}" for k, v in fitted_keys(result).items())
    v = result.vehicle
    # the calibrated vehicle's id is its own file's stem: never the input file's 'id' key,
    # so the two can be predicted side by side (cevm.io.vehicles)
    values = {**fitted_keys(result), "id": stem_id(out)}
    if v.vehicle_class is not None:
        values["class"] = v.vehicle_class
    prior = None if result.priors is None else prior_table(result.priors, v.powertrain)
    posterior = None if result.posterior is None else posterior_table(result.posterior, v)
    text = calibrated_toml(source.read_text(encoding="utf-8"), values, f"{note}\nfitted: {fitted}",
                           neutral=neutral_keys(result), calibration=calibration,
                           sources=changed_sources(result, v.id), prior=prior, posterior=posterior)
    # whole or not at all, a device (--out /dev/stdout) written rather than replaced by a
    # rename; a full disk is an OutputError naming the file (exit 3)
    write_text(out, text)
