"""The ``cevm`` command line: a thin layer over the library.

Exit codes: 0 success; 1 some inputs of a batch failed (the rest was done);
2 bad usage or bad input (nothing was done). Errors caused by input are printed as one
line on stderr, without a traceback.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated, Optional

import numpy as np
import typer

from cevm import __version__
from cevm.cycle import CR0_DEFAULT, cycle_vector
from cevm.errors import CevmError
from cevm.io import load_vehicles, read_cycle_csv
from cevm.model import ICE_BRAKING_MODES
from cevm.report import OutputFormat, write_rows
from cevm.vehicle import J_PER_KWH, predict

EXIT_OK = 0
EXIT_PARTIAL = 1
EXIT_INPUT = 2

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


@app.command("predict")
def predict_cmd(
    vehicle: Annotated[
        list[Path], typer.Option("--vehicle", "-v", help="Vehicle TOML file, or a directory of them. Repeatable.")
    ],
    cycle: Annotated[
        list[Path], typer.Option("--cycle", "-c", help="Cycle CSV (time_s, speed_kmh|speed_mps[, elevation_m]). Repeatable.")
    ],
    mass_kg: Annotated[
        Optional[list[float]],
        typer.Option("--mass-kg", "-m", help="Gross mass [kg]. Repeatable. Default: each vehicle's mass_kg."),
    ] = None,
    fmt: Annotated[OutputFormat, typer.Option("--format", "-f", help="Output format.")] = OutputFormat.table,
    ice_braking: Annotated[
        Optional[str],
        typer.Option(help=f"Override ICE braking mode: {' or '.join(ICE_BRAKING_MODES)}. Default: the vehicle file's."),
    ] = None,
    cr0: Annotated[float, typer.Option(help="Conservative rolling coefficient Cr0 of the simplification criterion.")] = CR0_DEFAULT,
) -> None:
    """Predict energy (EV) or fuel (ICE) for every (cycle, vehicle, mass)."""
    if ice_braking is not None and ice_braking not in ICE_BRAKING_MODES:
        raise _fail(f"--ice-braking must be one of: {', '.join(ICE_BRAKING_MODES)}")
    if mass_kg and any(not np.isfinite(m) or m <= 0 for m in mass_kg):
        raise _fail("--mass-kg values must be positive")
    try:
        vehicles = load_vehicles(vehicle)
        cycles = [read_cycle_csv(c) for c in cycle]
    except CevmError as exc:
        raise _fail(str(exc)) from None
    rows = []
    for path, cyc in zip(cycle, cycles):
        vec = cycle_vector(cyc, cr0=cr0)
        for veh in vehicles:
            if veh.cr < cr0:
                raise _fail(f"vehicle {veh.name!r}: cr {veh.cr:g} is below --cr0 {cr0:g}")
            masses = np.asarray(mass_kg if mass_kg else [veh.mass_kg], dtype=np.float64)
            pred = predict(vec, veh, masses, ice_braking=ice_braking)
            dist_km = vec.distance_m / 1000.0
            for i, m in enumerate(masses):
                row = {
                    "cycle": cyc.name or str(path),
                    "vehicle": veh.name,
                    "powertrain": veh.powertrain,
                    "mass_kg": float(m),
                    "distance_km": dist_km,
                    "duration_s": vec.duration_s,
                    "wheel_energy_kwh": float(pred.wheel_energy_j[i]) / J_PER_KWH,
                }
                if veh.is_ev:
                    e_kwh = float(pred.energy_j[i]) / J_PER_KWH
                    row["energy_kwh"] = e_kwh
                    row["energy_kwh_per_km"] = e_kwh / dist_km if dist_km > 0 else None
                else:
                    fuel = float(pred.fuel_l[i])
                    row["fuel_l"] = fuel
                    row["fuel_l_per_100km"] = 100.0 * fuel / dist_km if dist_km > 0 else None
                    row["ice_braking"] = ice_braking or veh.ice_braking
                if veh.max_gross_kg is not None and m > veh.max_gross_kg:
                    typer.echo(
                        f"cevm: warning: {veh.name}: mass {m:g} kg exceeds max_gross_kg {veh.max_gross_kg:g}",
                        err=True,
                    )
                rows.append(row)
    columns = [
        "cycle", "vehicle", "mass_kg", "distance_km", "duration_s", "wheel_energy_kwh",
        "energy_kwh", "energy_kwh_per_km", "fuel_l", "fuel_l_per_100km",
    ]
    if fmt == OutputFormat.table:
        columns = [c for c in columns if any(c in r for r in rows)]
    write_rows(rows, fmt, columns=columns, title="cevm predict", digits=PREDICT_DIGITS, headers=PREDICT_HEADERS)


PREDICT_HEADERS = {
    "mass_kg": "mass kg",
    "distance_km": "km",
    "duration_s": "s",
    "wheel_energy_kwh": "wheel kWh",
    "energy_kwh": "battery kWh",
    "energy_kwh_per_km": "kWh/km",
    "fuel_l": "fuel l",
    "fuel_l_per_100km": "l/100km",
}
PREDICT_DIGITS = {"mass_kg": 0, "duration_s": 0, "distance_km": 2, "wheel_energy_kwh": 2, "energy_kwh": 2, "fuel_l": 2, "fuel_l_per_100km": 1}


def _not_yet(name: str, issue: str) -> None:
    raise _fail(f"'cevm {name}' is not yet available ({issue}).", EXIT_INPUT)


@app.command()
def ingest() -> None:
    """Read logger CSV exports into the trip store (not yet available)."""
    _not_yet("ingest", "the ingest capability is being built")


@app.command()
def calibrate() -> None:
    """Fit a vehicle's efficiency to measured trips (not yet available)."""
    _not_yet("calibrate", "the calibration capability is being built")


def main() -> None:
    """Console entry point."""
    try:
        app()
    except CevmError as exc:  # a user's mistake that escaped a command: one line, no traceback
        typer.echo(f"cevm: error: {exc}", err=True)
        sys.exit(EXIT_INPUT)
