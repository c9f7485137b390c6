"""``cevm vehicle show``: a vehicle file's parameters with their sources, and what they
give (consumption per km on the shipped cycles at kerb and at max gross, the published
ranges the file states), its terms beyond the paper and its calibration."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Annotated, Any

import typer

from cevm.cli.common import FormatOption, fail
from cevm.cli.output import OutputFormat, write_rows
from cevm.errors import CevmError
from cevm.text import printable
from cevm.units import J_PER_KWH

app = typer.Typer(help="Vehicle files: what they hold and what they give.", no_args_is_help=True,
                  rich_markup_mode=None)

#: The terms beyond the paper's model (cevm.core.energy), by file key: what each adds.
TERM_KEYS = {
    "aux_power_kw": "EV: auxiliary power from the battery all the time [kW]",
    "regen_eta": "EV: share of the negative wheel energy that reaches the battery",
    "aux_heating_kw_per_k": "EV: heating power per K below heating_below_c [kW/K]",
    "aux_cooling_kw_per_k": "EV: air conditioning per K above cooling_above_c [kW/K]",
    "warmup_kwh_per_k": "EV: warm-up energy per trip start per K of cold [kWh/K]",
    "idle_fuel_lph": "ICE: fuel at standstill [l/h]",
    "running_fuel_lph": "ICE: fuel while driving, beyond the wheel work (Willans offset) [l/h]",
    "kinetic_eta": "ICE: efficiency of the fuel spent on positive kinetic energy",
    "heating_fuel_lph_per_k": "ICE: heater fuel per K below heating_below_c [l/h per K]",
    "cooling_fuel_lph_per_k": "ICE: A/C fuel per K above cooling_above_c [l/h per K]",
    "warmup_fuel_l_per_k": "ICE: cold-start fuel per start per K [l/K]",
}
_MASS_KEYS = {"mass_kg", "kerb_mass_kg", "payload_kg", "max_gross_kg"}


def _shipped_cycles() -> list[Path]:
    from cevm.configs_dir import shipped_configs_dir

    return sorted((shipped_configs_dir() / "cycles").glob("*.csv"))


def _parameters(data: dict, sources: dict) -> list[dict]:
    rows = []
    for key, value in data.items():
        if isinstance(value, dict) or (isinstance(value, list) and value and isinstance(value[0], dict)):
            continue  # tables: [sources], [detailed], [calibration], [[reference]]
        src = sources.get(key)
        if src is None and key in _MASS_KEYS:
            src = sources.get("mass")
        rows.append({"parameter": key, "value": value if isinstance(value, str) else json.dumps(value),
                     "basis": src or "-"})
    return rows


def _figures(vehicle, cycles: list[Path]) -> list[dict]:
    """Consumption per km of ``vehicle`` on each cycle at kerb and at max gross (else its
    default mass), with where it cannot follow the cycle."""
    from cevm.core.sweep import PredictionSet, Source, predict_source
    from cevm.io import read_cycle_csv

    kerb = vehicle.kerb_mass_kg if vehicle.kerb_mass_kg is not None else vehicle.mass_kg
    loads = [("kerb", kerb)]
    loads.append(("max gross", vehicle.max_gross_kg) if vehicle.max_gross_kg is not None
                 else ("default", vehicle.mass_kg))
    rows = []
    for path in cycles:
        src = Source.from_cycle(read_cycle_csv(path))
        ps = PredictionSet.build([vehicle], mass_kg=[m for _, m in loads])
        b = predict_source(src, ps, ranges=True)
        km = src.distance_m / 1e3
        for i, (label, m) in enumerate(loads):
            cannot = [w for w, a in (("power", b.over_power), ("speed", b.over_speed)) if a is not None and a[i] == 1.0]
            row = {"cycle": src.name, "load": label, "mass_kg": float(m), "distance_km": km}
            if vehicle.is_ev:
                row["energy_kwh_per_km"] = float(b.energy_j[i] / J_PER_KWH / km)
            else:
                assert b.fuel_l is not None  # an ICE block's
                row["fuel_l_per_100km"] = float(100.0 * b.fuel_l[i] / km)
            assert b.range_m is not None  # asked for (ranges=True)
            rng = float(b.range_m[i])
            row["range_km"] = None if not math.isfinite(rng) else rng / 1e3
            row["cannot_follow"] = ", ".join(cannot) or None
            rows.append(row)
    return rows


def _references(vehicle, cycles: list[Path]) -> list[dict]:
    """The file's [[reference]] cases: the published range and what cevm gives."""
    from cevm.core.sweep import PredictionSet, Source, predict_source
    from cevm.io import read_cycle_csv

    by_name = {p.stem: p for p in cycles}
    rows = []
    for case in vehicle.extra.get("reference", []) or []:
        if not isinstance(case, dict):
            continue
        path = by_name.get(str(case.get("cycle")))
        value = None
        if path is not None and isinstance(case.get("mass_kg"), (int, float)):
            src = Source.from_cycle(read_cycle_csv(path))
            b = predict_source(src, PredictionSet.build([vehicle], mass_kg=[float(case["mass_kg"])]))
            km = src.distance_m / 1e3
            value = (float(b.energy_j[0] / J_PER_KWH / km) if case.get("unit") == "kWh/km"
                     else float(100.0 * b.fuel_l[0] / km))
        lo, hi = (case.get("range") or [None, None])[:2]
        rows.append({"cycle": case.get("cycle"), "mass_kg": case.get("mass_kg"), "unit": case.get("unit"),
                     "published": f"{lo:g}-{hi:g}" if lo is not None and hi is not None else "-",
                     "cevm": value, "within": None if value is None or lo is None else bool(lo <= value <= hi),
                     "basis": case.get("source")})
    return rows


@app.command("show")
def vehicle_show(
    file: Annotated[Path, typer.Argument(metavar="FILE", help="A vehicle file (TOML).")],
    fmt: FormatOption = OutputFormat.table,
) -> None:
    """A vehicle file's parameters with their sources, and what they give.

    Consumption per km on the shipped cycles (configs/cycles) at kerb mass and at
    max_gross_kg (else the default mass), with the range and what the vehicle cannot
    follow (max_power_kw, max_speed_kmh); the published ranges the file states
    ([[reference]]); the terms beyond the paper's model (cevm.core.energy) when the file
    sets them; the [calibration] table when the file has one; where its intervals come
    from (its calibration's posterior, or its class's priors)."""
    from cevm.core.predictive import posterior_of
    from cevm.io import load_vehicle, read_toml
    from cevm.io.priors import prior_values_note

    try:
        data = read_toml(file, "vehicle file")
        vehicle = load_vehicle(file)
        cycles = _shipped_cycles()
        params = _parameters(data, dict(data.get("sources", {}) or {}))
        figures = _figures(vehicle, cycles)
        references = _references(vehicle, cycles)
    except CevmError as exc:
        raise fail(exc) from None
    terms = [{"term": k, "value": data[k], "what": TERM_KEYS[k]} for k in TERM_KEYS
             if k in data and data[k] not in (0, 0.0, None)]
    calibration = data.get("calibration") if isinstance(data.get("calibration"), dict) else None
    post = posterior_of(vehicle)
    uncertainty = {"interval_from": "none" if post is None else post.label,
                   "source": "no priors: no interval" if post is None else post.source,
                   "priors": None if vehicle.priors is None else vehicle.priors.describe(),
                   "from_prior": list(vehicle.from_prior), "prior_note": prior_values_note(vehicle)}
    report: dict[str, Any] = {
        "file": str(file), "id": vehicle.id, "name": vehicle.name, "powertrain": vehicle.powertrain,
        "parameters": params, "consumption": figures, "reference": references, "terms": terms,
        "calibration": calibration, "uncertainty": uncertainty, "detailed": "detailed" in vehicle.extra,
    }
    if fmt == OutputFormat.json:
        typer.echo(json.dumps(report, indent=2, default=str))
        return
    if fmt == OutputFormat.csv:
        write_rows(figures, fmt)
        return
    typer.echo(printable(f"{vehicle.id}: {vehicle.name} ({vehicle.powertrain}), {file}"))
    typer.echo(printable(f"intervals from: {uncertainty['interval_from']} ({uncertainty['source']})"
                         + (f"; priors of {uncertainty['priors']}" if uncertainty["priors"] else "")))
    if uncertainty["prior_note"]:
        typer.echo(printable(f"from its priors: {uncertainty['prior_note']}"))
    write_rows(params, OutputFormat.table, title="parameters", columns=["parameter", "value", "basis"],
               headers={"basis": "source"})
    unit = "energy_kwh_per_km" if vehicle.is_ev else "fuel_l_per_100km"
    write_rows(figures, OutputFormat.table, title="on the shipped cycles (cevm predict, the CE model)",
               columns=["cycle", "load", "mass_kg", "distance_km", unit, "range_km", "cannot_follow"],
               headers={"mass_kg": "mass kg", "distance_km": "km", "energy_kwh_per_km": "kWh/km",
                        "fuel_l_per_100km": "l/100km", "range_km": "range km", "cannot_follow": "cannot follow"},
               digits={"mass_kg": 0, "distance_km": 1, "energy_kwh_per_km": 3, "fuel_l_per_100km": 1, "range_km": 0})
    if references:
        write_rows(references, OutputFormat.table, title="published real-world ranges ([[reference]])",
                   columns=["cycle", "mass_kg", "unit", "published", "cevm", "within", "basis"],
                   headers={"mass_kg": "mass kg", "basis": "source"}, digits={"mass_kg": 0, "cevm": 3})
    if terms:
        write_rows(terms, OutputFormat.table, title="terms beyond the paper (cevm.core.energy)",
                   columns=["term", "value", "what"])
    else:
        typer.echo("terms beyond the paper: none (the paper's CE model)")
    if calibration:
        rows = [{"item": k, "value": v if isinstance(v, (int, float, str)) else json.dumps(v)}
                for k, v in calibration.items()]
        write_rows(rows, OutputFormat.table, title="[calibration]: what the fit saw", columns=["item", "value"])
    if not vehicle.extra.get("detailed"):
        typer.echo("no [detailed] table: 'cevm simulate' refuses this file")
