"""The calibrated vehicle file: the input vehicle file with the fitted values written in
(comments, tables and sources kept), never over an existing file silently."""

from __future__ import annotations

import re
from pathlib import Path

from cevm.core.calibration import CalibrationResult
from cevm.errors import CevmError
from cevm.units import S_PER_H


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
