"""``cevm simulate``: the detailed time-step model over a cycle or a stored trip
(:mod:`cevm.core.detailed`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import numpy as np
import typer

from cevm.cli.common import (
    OutFile,
    SocStartOption,
    StoreOption,
    check_soc,
    fail,
    with_cycle_options,
)
from cevm.core import physical_inputs
from cevm.cli.output import OutputFormat, write_rows
from cevm.errors import CevmError
from cevm.text import printable
from cevm.units import J_PER_KWH


@with_cycle_options
def simulate(
    vehicle: Annotated[Path, typer.Option("--vehicle", "-v", metavar="FILE", help="Vehicle file with a [detailed] table (the drivetrain; a file without one is refused).")],
    cycle: Annotated[Optional[Path], typer.Option("--cycle", "-c", metavar="FILE", help="Cycle CSV.")] = None,
    trip: Annotated[Optional[str], typer.Option("--trip", "-t", metavar="ID", help="A stored trip id.")] = None,
    store: StoreOption = None,
    mass_kg: Annotated[Optional[float], typer.Option("--mass-kg", "-m", help="Gross mass [kg]. Default: the vehicle's.")] = None,
    payload_kg: Annotated[Optional[float], typer.Option("--payload-kg", "-p", help="Payload [kg] on the vehicle's kerb mass (instead of --mass-kg).")] = None,
    soc_start_pct: SocStartOption = 100.0,
    out: Annotated[Optional[Path], typer.Option("--out", "-o", metavar="FILE", help="Per-second output CSV.")] = None,
    plot: Annotated[Optional[Path], typer.Option(metavar="FILE.png", help="PNG: state of charge (EV, the paper's figure 4) or fuel and elevation (ICE, figure 6).")] = None,
    fmt: Annotated[OutputFormat, typer.Option("--format", "-f", help="Format of the summary.")] = OutputFormat.table,
    cycle_fmt=None,
) -> None:
    """Detailed time-step simulation of one vehicle over a trace (the baseline model).

    Motor map, regeneration limits and battery for an EV; gearbox and fuel map for a diesel.
    It takes no ambient temperature: an EV's auxiliaries are its [detailed] table's
    aux_base_power_kw + hvac_power_kw (the summary's aux_power_kw says what was used)."""
    from cevm.core.detailed import simulate as run_simulation
    from cevm.io.detailed import detailed_params
    from cevm.io.plots import plot_simulation
    from cevm.io import load_vehicle, read_cycle_csv

    if (cycle is None) == (trip is None):
        raise fail("give exactly one of --cycle or --trip")
    if mass_kg is not None and payload_kg is not None:
        raise fail("give --mass-kg or --payload-kg, not both")
    check_soc(soc_start_pct)
    try:
        veh = load_vehicle(vehicle)
        if "detailed" not in veh.extra:
            raise CevmError(_no_detailed_table(vehicle, veh.is_ev))
        mass_source, measured, foreign = "vehicle file", None, None
        if payload_kg is not None:
            mass_kg = (veh.kerb_mass_kg if veh.kerb_mass_kg is not None else veh.mass_kg) + float(
                physical_inputs.payloads_kg(payload_kg))
            mass_source = "--payload-kg"
        elif mass_kg is not None:
            mass_kg = float(physical_inputs.masses_for([veh], mass_kg))
            mass_source = "--mass-kg"
        if cycle is not None:
            c = read_cycle_csv(cycle, cycle_fmt)
            name, t, v, h = c.name, c.time_s, c.speed_mps, c.elevation_m
            if h is None:
                typer.echo(f"cevm: note: {printable(name)}: no elevation or grade: a flat road assumed", err=True)
        else:
            from cevm.store import TripStore, existing_store_path

            from cevm.store.masses import trip_masses
            from cevm.store.queries import row_measurement

            from cevm.store.sources import MAX_SOURCE_SAMPLES, too_long_trip

            with TripStore.open(existing_store_path(store), readonly=True) as st:
                listed = st.list_trips(trip_ids=[trip])
                if int(listed["n_samples"].iloc[0]) > MAX_SOURCE_SAMPLES:  # bounded as a cycle file is
                    raise CevmError(too_long_trip(trip, int(listed["n_samples"].iloc[0])))
                prof = st.load_profile(trip)
                own = trip_masses(st, listed)[trip]
            r = listed.iloc[0]
            measured = row_measurement(r["measured_kind"], r["measured_value"], r["measured_source"],
                                       r["measured_resolution"], r["measured_uncertainty"])
            if mass_kg is None:  # the trip's own mass: given to it, else logged (cevm.store.masses)
                mass_kg, mass_source = own.gross_kg(veh), own.origin
                from cevm.store.sources import foreign_mass

                foreign = foreign_mass(own, measured, veh)
                try:
                    mass_kg = float(physical_inputs.masses_for([veh], mass_kg))
                except CevmError as exc:
                    raise CevmError(f"trip {trip!r} ({own.describe()} mass): {exc}") from None
            name, t, v, h = trip, prof["time_s"], prof["speed_mps"], prof["elevation_m"]
        res = run_simulation(veh, t, v, h, mass_kg=mass_kg, soc_start=soc_start_pct / 100.0,
                             params=detailed_params(veh))
    except CevmError as exc:
        raise fail(exc) from None
    except ValueError as exc:  # inconsistent [detailed] parameters or trace
        raise fail(f"{vehicle}: {exc}") from None
    if out is not None:
        try:
            with OutFile(out) as fh:  # written whole or not at all (a full disk: one line, exit 3)
                for start in range(0, res.time_s.size, OUT_BLOCK_ROWS):  # in blocks: no frame of it all held
                    res.to_frame(rows=slice(start, start + OUT_BLOCK_ROWS)).to_csv(
                        fh, index=False, header=start == 0, float_format="%.6g")
        except CevmError as exc:
            raise fail(exc) from None
    if plot is not None:
        try:
            plot_simulation(_plot_columns(res), res, plot, f"{veh.name}: {name}")
        except CevmError as exc:  # a full disk: the plot's, exit 3 (cevm.io.plots leaves no half-written file)
            raise fail(exc) from None
    row = {"cycle": name, "vehicle": veh.name, "mass_kg": res.mass_kg, "mass_source": mass_source,
           "distance_km": res.distance_m / 1e3,
           "duration_s": res.duration_s, "wheel_energy_kwh": res.wheel_energy_j / J_PER_KWH,
           "friction_brake_kwh": res.friction_brake_energy_j / J_PER_KWH,
           "traction_deficit_kwh": res.traction_deficit_j / J_PER_KWH}
    aux_w = res.steps.get("aux_power_w")
    if aux_w is not None and res.duration_s > 0:  # what the battery fed besides the motor: an assumption
        row["aux_power_kw"] = float(np.sum(aux_w * res.steps["dt_s"]) / res.duration_s) / 1e3
    if veh.is_ev:
        row["energy_kwh"] = res.energy_j / J_PER_KWH
        row["soc_end_pct"] = float(res.samples["soc"][-1]) * 100.0
        row["soc_min_pct"] = float(np.min(res.samples["soc"])) * 100.0
    else:
        row["fuel_l"] = res.fuel_l
        row["fuel_l_per_100km"] = 100.0 * res.fuel_l / (res.distance_m / 1e3) if res.distance_m > 0 else None
    if measured is not None and measured.value > 0:  # a stored trip: what it measured beside the model
        fuel = measured.kind == "fuel_l"
        reference = measured.value if fuel else measured.value / J_PER_KWH
        row["measured_fuel_l" if fuel else "measured_energy_kwh"] = reference
        modelled = row.get("fuel_l" if fuel else "energy_kwh")  # None on a vehicle of the other powertrain
        own_mass = mass_source not in ("--mass-kg", "--payload-kg")
        row["error_pct"] = 100.0 * (modelled - reference) / reference if own_mass and modelled is not None else None
    if fmt == OutputFormat.table:
        write_rows([{"quantity": k, "value": v} for k, v in row.items()], fmt, title="cevm simulate (detailed model)")
    else:
        write_rows([row], fmt)
    if foreign:
        typer.echo(f"cevm: warning: {veh.label}: simulated at the own gross mass of trip {trip} ({own.describe()} "
                   f"{mass_kg:,.0f} kg), which another vehicle drove ({foreign}); give --mass-kg or --payload-kg for "
                   f"what {veh.label} would carry", err=True)
    if res.traction_deficit_j > 0.02 * max(res.wheel_energy_j, 1.0):
        typer.echo(f"cevm: warning: the vehicle could not follow the trace: {row['traction_deficit_kwh']:.2f} kWh "
                   "of wheel work beyond its powertrain's limits", err=True)


def _no_detailed_table(path: Path, is_ev: bool) -> str:
    """Why a vehicle file without a [detailed] table cannot be simulated, and what to do."""
    return (
        f"{path}: no [detailed] table: the detailed model needs the vehicle's drivetrain ("
        + ("motor, regeneration limits, battery, auxiliaries" if is_ev else "engine map, gearbox, "
           "auxiliaries") + "), and this file's CE figures (eta, " + ("aux_power_kw" if is_ev else
           "idle_fuel_lph") + ") do not give them. Add a [detailed] table (an empty one takes the "
        "defaults, which describe " + ("a 10 m electric bus with a 180 kW motor" if is_ev else
                                       "a 235 kW diesel tractor with a 12-speed gearbox")
        + "; configs/vehicles/*.toml show every key), or use 'cevm predict' (the CE model)")


#: Rows of ``--out`` made and written at a time: the per-second frame of a long trace is
#: never held whole beside the result (a million samples: 200 MB more).
OUT_BLOCK_ROWS = 100_000


def _plot_columns(res) -> dict[str, np.ndarray]:
    """The columns of :meth:`SimulationResult.to_frame` the figure draws (time, state of
    charge or fuel used, elevation), without the rest of the frame."""
    cols = {"time_s": res.time_s}
    if res.powertrain == "ev":
        cols["soc_pct"] = res.samples["soc"] * 100.0
    else:
        cols["fuel_cum_l"] = res.samples["fuel_cum_l"]
    if res.elevation_m is not None:
        cols["elevation_m"] = res.elevation_m
    return cols
