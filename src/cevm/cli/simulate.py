"""``cevm simulate``: the detailed time-step model over a cycle or a stored trip
(:mod:`cevm.core.detailed`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer

from cevm.cli.common import (
    PNG,
    OutFile,
    ReserveOption,
    SocStartOption,
    StoreOption,
    check_output_path,
    check_soc,
    fail,
    start_soc,
    with_cycle_options,
)
from cevm.cli.output import OutputFormat, write_rows
from cevm.core import physical_inputs
from cevm.core.sweep import DEFAULT_RESERVE_PCT
from cevm.errors import CevmError
from cevm.text import printable
from cevm.units import J_PER_KWH


@with_cycle_options
def simulate(
    vehicle: Annotated[Path,
                       typer.Option("--vehicle", "-v", metavar="FILE",
                                    help="Vehicle file with a [detailed] table (the drivetrain; a file without one is "
                                         "refused).")],
    cycle: Annotated[Path | None, typer.Option("--cycle", "-c", metavar="FILE", help="Cycle CSV.")] = None,
    trip: Annotated[str | None, typer.Option("--trip", "-t", metavar="ID", help="A stored trip id.")] = None,
    store: StoreOption = None,
    mass_kg: Annotated[float | None,
                       typer.Option("--mass-kg", "-m", help="Gross mass [kg]. Default: the vehicle's.")] = None,
    payload_kg: Annotated[float | None,
                          typer.Option("--payload-kg", "-p",
                                       help="Payload [kg] on the vehicle's kerb mass (instead of --mass-kg).")] = None,
    soc_start_pct: SocStartOption = None,
    reserve_pct: ReserveOption = DEFAULT_RESERVE_PCT,
    out: Annotated[Path | None, typer.Option("--out", "-o", metavar="FILE", help="Per-second output CSV.")] = None,
    plot: Annotated[Path | None,
                    typer.Option(metavar="FILE.png",
                                 help="PNG: state of charge (EV, the paper's figure 4) or fuel and elevation (ICE, "
                                      "figure 6).")] = None,
    fmt: Annotated[OutputFormat, typer.Option("--format", "-f", help="Format of the summary.")] = OutputFormat.table,
    cycle_fmt=None,
) -> None:
    """Detailed time-step simulation of one vehicle over a trace (the baseline model).

    Motor map, regeneration limits and battery for an EV; gearbox and fuel map for a diesel.
    It takes no ambient temperature: an EV's auxiliaries are its [detailed] table's
    aux_base_power_kw + hvac_power_kw (the summary's aux_power_kw says what was used)."""
    from cevm.core.detailed import simulate as run_simulation
    from cevm.io import load_vehicle, read_cycle_csv
    from cevm.io.detailed import detailed_params
    from cevm.io.plots import plot_simulation

    if (cycle is None) == (trip is None):
        raise fail("give exactly one of --cycle or --trip")
    if mass_kg is not None and payload_kg is not None:
        raise fail("give --mass-kg or --payload-kg, not both")
    check_soc(soc_start_pct, reserve_pct)
    check_output_path(out, "--out")
    check_output_path(plot, "--plot", PNG)
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
        soc0, soc_from, elevation = start_soc(None, soc_start_pct) + (None,)
        if cycle is not None:
            c = read_cycle_csv(cycle, cycle_fmt)
            name, t, v, h = c.name, c.time_s, c.speed_mps, c.elevation_m
            if h is None:
                typer.echo(f"cevm: note: {printable(name)}: no elevation or grade: a flat road assumed", err=True)
        else:
            assert trip is not None  # exactly one of --cycle, --trip (checked above)
            (name, t, v, h), (mass_kg, mass_source, measured, foreign, own), (soc0, soc_from), elevation = (
                _stored_trip(store, trip, veh, mass_kg, mass_source, soc_start_pct))
        res = run_simulation(veh, t, v, h, mass_kg=mass_kg, soc_start=soc0 / 100.0,
                             params=detailed_params(veh))
    except CevmError as exc:
        raise fail(exc) from None
    except ValueError as exc:  # inconsistent [detailed] parameters or trace
        raise fail(f"{vehicle}: {exc}") from None
    verdict = simulation_verdict(veh, res, mass_kg=res.mass_kg, soc_start_pct=soc0, reserve_pct=reserve_pct,
                                 logged=trip is not None, elevation_source=elevation)
    # no charge below 0: the series ends where it runs empty
    empty_at_s = verdict["empty_at_s"] if veh.is_ev else None
    if out is not None:
        try:
            with OutFile(out) as fh:  # written whole or not at all (a full disk: one line, exit 3)
                for start in range(0, res.time_s.size, OUT_BLOCK_ROWS):  # in blocks: no frame of it all held
                    block = res.to_frame(rows=slice(start, start + OUT_BLOCK_ROWS))
                    if empty_at_s is not None:
                        block["soc_pct"] = _soc_until_empty(block["time_s"].to_numpy(), block["soc_pct"].to_numpy(),
                                                            empty_at_s)
                    block.to_csv(fh, index=False, header=start == 0, float_format="%.6g")
        except CevmError as exc:
            raise fail(exc) from None
    if plot is not None:
        try:
            plot_simulation(_plot_columns(res, empty_at_s), res, plot, f"{veh.name}: {name}")
        except CevmError as exc:  # a full disk: the plot's, exit 3 (cevm.io.plots leaves no half-written file)
            raise fail(exc) from None
    row: dict[str, Any] = {"cycle": name, "vehicle": veh.name, "mass_kg": res.mass_kg, "mass_source": mass_source,
           "distance_km": res.distance_m / 1e3,
           "duration_s": res.duration_s, "wheel_work_net_kwh": res.wheel_energy_j / J_PER_KWH,
           "friction_brake_kwh": res.friction_brake_energy_j / J_PER_KWH,
           "traction_deficit_kwh": res.traction_deficit_j / J_PER_KWH}
    aux_w = res.steps.get("aux_power_w")
    if aux_w is not None and res.duration_s > 0:  # what the battery fed besides the motor: an assumption
        row["aux_power_kw"] = float(np.sum(aux_w * res.steps["dt_s"]) / res.duration_s) / 1e3
    if veh.is_ev:
        assert res.energy_j is not None  # an EV's result
        row["energy_kwh"] = res.energy_j / J_PER_KWH
        row["soc_start_pct"], row["soc_start_from"] = soc0, soc_from
        row["soc_end_pct"], row["soc_min_pct"] = verdict.pop("soc_end_pct"), verdict.pop("soc_min_pct")
        row["reserve_pct"] = reserve_pct
    else:
        assert res.fuel_l is not None  # an ICE's result
        row["fuel_l"] = res.fuel_l
        row["fuel_l_per_100km"] = 100.0 * res.fuel_l / (res.distance_m / 1e3) if res.distance_m > 0 else None
    if measured is not None and measured.value > 0:  # a stored trip: what it measured beside the model
        fuel = measured.kind == "fuel_l"
        reference = measured.value if fuel else measured.value / J_PER_KWH
        row["measured_fuel_l" if fuel else "measured_energy_kwh"] = reference
        modelled = row.get("fuel_l" if fuel else "energy_kwh")  # None on a vehicle of the other powertrain
        own_mass = mass_source not in ("--mass-kg", "--payload-kg")
        row["error_pct"] = 100.0 * (modelled - reference) / reference if own_mass and modelled is not None else None
    row.update(verdict)
    row["road"] = "flat" if h is None else (elevation or "elevation")
    notes = _beside_ce(row, veh, res, detailed_params(veh))
    if fmt == OutputFormat.table:
        write_rows(table_rows(row), fmt, title="cevm simulate (detailed model)")
    else:
        write_rows([row], fmt)
    if foreign:
        typer.echo(f"cevm: warning: {veh.label}: simulated at the own gross mass of trip {trip} ({own.describe()} "
                   f"{mass_kg:,.0f} kg), which another vehicle drove ({foreign}); give --mass-kg or --payload-kg for "
                   f"what {veh.label} would carry", err=True)
    for note in notes:
        typer.echo(f"cevm: note: {note}", err=True)
    if res.traction_deficit_j > 0.02 * max(res.wheel_energy_j, 1.0):
        typer.echo(f"cevm: warning: the vehicle could not follow the trace: {row['traction_deficit_kwh']:.2f} kWh "
                   "of wheel work beyond its powertrain's limits", err=True)


def _beside_ce(row: dict[str, Any], veh, res, params) -> list[str]:
    """The CE model's figure on the same trace in ``row`` (``ce_energy_kwh`` or
    ``ce_fuel_l``, ``ce_vs_detailed_pct``; an EV's ``detailed_traction_efficiency``) and
    the note that says in which terms the two models differ
    (:mod:`cevm.core.detailed.comparison`)."""
    from cevm.core.detailed.comparison import compare

    c = compare(veh, res)
    pct = 100.0 * c.difference
    if not veh.is_ev:
        row["ce_fuel_l"], row["ce_vs_detailed_pct"] = c.ce, pct
        return [f"the CE model (cevm predict) gives {c.ce:.2f} l here ({pct:+.1f} % on the detailed model's "
                f"{res.fuel_l:.2f} l): one efficiency eta {veh.eta:g} and the file's idle and kinetic terms, where the "
                "detailed model has the engine's fuel map, the gearbox and its shifts, the rotating inertia"]
    row["ce_energy_kwh"], row["ce_vs_detailed_pct"] = c.ce / J_PER_KWH, pct
    row["detailed_traction_efficiency"] = c.detailed_efficiency
    kwh = J_PER_KWH
    regen = ("its regeneration limited to " f"{params.regen_max_power_w / 1e3:g} kW and faded out below "
             f"{params.regen_fade_high_mps * 3.6:g} km/h")
    return [f"the CE model (cevm predict) gives {c.ce / kwh:.2f} kWh here ({pct:+.1f} % on the detailed model's "
            f"{res.energy_j / kwh:.2f} kWh), in these terms: traction {c.ce_traction_j / kwh:.2f} kWh with one "
            f"efficiency eta {veh.eta:g} (battery to wheel) against {c.detailed_traction_j / kwh:.2f} kWh through the "
            f"detailed drivetrain, {c.detailed_efficiency:.2f} over this trace (motor and inverter loss map, "
            f"transmission {params.transmission_efficiency:g}); regenerated {c.ce_regen_j / kwh:.2f} kWh (eta x "
            f"regen, no limit) against {c.detailed_regen_j / kwh:.2f} kWh ({regen}); auxiliaries "
            f"{c.ce_aux_j / kwh:.2f} kWh (aux_power_kw at {c.ambient_c:g} degC) against {c.detailed_aux_j / kwh:.2f} "
            "kWh ([detailed] aux_base_power_kw + hvac_power_kw); the detailed model also has the battery's internal "
            "resistance and the rotating inertia. A calibrated eta (cevm calibrate) holds every loss the maps split "
            "out; the [detailed] table's figures are plausible, not measured"]


#: Decimals of simulate's table by the end of a quantity's name (the rest: 3), as the
#: other commands' tables show them: whole kg, s, kW of demand; one decimal of %, km/h.
TABLE_DECIMALS = (("_kg", 0), ("_s", 0), ("_pct", 1), ("_kmh", 1), ("demand_kw", 0), ("_km", 2), ("_kwh", 2),
                  ("_l", 2), ("_100km", 1))


def table_rows(row: dict[str, Any]) -> list[dict[str, str]]:
    """Simulate's row as the table's (quantity, value) pairs: numbers at the decimals of
    :data:`TABLE_DECIMALS` with thousands separators, "-" where there is no value; the
    verdict as predict's table says it (``yes``, or ``NO`` and why: over max gross, where
    it runs empty, what it cannot follow), the other flags in capitals where they fail
    (``NO`` for a check that fails, ``YES`` for a limit exceeded)."""
    from cevm.cli.prediction_columns import verdict_text

    out = []
    for k, v in row.items():
        if v is None or (isinstance(v, float) and v != v):
            text = "-"
        elif k == "feasible":
            ev = "energy_kwh" in row
            text = verdict_text({**row, "powertrain": "ev" if ev else "ice", "tank_ok": row.get("tank_ok", True)})
        elif isinstance(v, (bool, np.bool_)):
            text = ("YES" if v else "no") if k.startswith("over_") else ("yes" if v else "NO")
        elif isinstance(v, (int, float, np.integer, np.floating)):
            d = next((n for end, n in TABLE_DECIMALS if k.endswith(end)), 3)
            text = f"{float(v):,.{d}f}"
        else:
            text = str(v)
        out.append({"quantity": k, "value": text})
    return out


def _stored_trip(store: Path | None, trip: str, veh, mass_kg: float | None, mass_source: str,
                 soc_start_pct: float | None) -> tuple[tuple, tuple, tuple[float, str], str]:
    """A stored trip for ``simulate --trip``: its trace (name, t, v, h), its mass (mass_kg,
    mass_source, the measurement, a foreign-mass note, its TripMass; the trip's own mass
    unless one was given), its start state of charge (the logged one unless given) and
    its elevation source."""
    from cevm.store import TripStore, existing_store_path
    from cevm.store.codec import MAX_PROFILE_SAMPLES
    from cevm.store.masses import trip_masses
    from cevm.store.queries import row_measurement
    from cevm.store.sources import MAX_SOURCE_SAMPLES, too_long_trip

    foreign = None
    with TripStore.open(existing_store_path(store), readonly=True) as st:
        listed = st.list_trips(trip_ids=[trip])
        n_listed = int(listed["n_samples"].iloc[0])
        # bounded as a cycle file is; a count no stored profile can hold is the store's
        # damage, which load_profile names (exit 4) without inflating anything
        if MAX_SOURCE_SAMPLES < n_listed <= MAX_PROFILE_SAMPLES:
            raise CevmError(too_long_trip(trip, n_listed))
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
    trace = (trip, prof["time_s"], prof["speed_mps"], prof["elevation_m"])
    return (trace, (mass_kg, mass_source, measured, foreign, own), start_soc(r, soc_start_pct),  # logged unless given
            r["elevation_source"])


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


def simulation_verdict(veh, res, *, mass_kg: float, soc_start_pct: float, reserve_pct: float, logged: bool,
                       elevation_source: str | None) -> dict:
    """The verdict of a detailed simulation, the flags of every command
    (:mod:`cevm.core.limits`): over max gross, the power and speed the trace asks against
    max_power_kw and max_speed_kmh (a stored trip with its log's tolerance), the reserve
    (EV: where it is first crossed and where the battery runs empty; the state of
    charge never below 0) or the tank (ICE: where it runs dry), and ``feasible``."""
    from cevm.core import limits
    from cevm.core.sweep import LegProfile, build_step_table

    t, v = res.time_s, res.speed_mps
    d = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))])
    leg = LegProfile(t, v, res.elevation_m)
    demand = limits.source_demand(build_step_table([leg]), [leg], logged=logged,
                                  elevation_sd=limits.elevation_sd_m(elevation_source) if logged else 0.0)
    over_p, over_v, need_w = limits.follow_flags(demand, veh, mass_kg)
    out: dict = {}
    crossings = {}
    if veh.is_ev:
        soc = res.samples["soc"] * 100.0
        crossings["reserve"] = limits.first_below(t, d, soc, reserve_pct)
        crossings["empty"] = limits.first_below(t, d, soc, 0.0)
        empty = np.isfinite(crossings["empty"][0])
        out["soc_end_pct"] = None if empty else float(soc[-1])
        out["soc_min_pct"] = max(0.0, float(np.min(soc)))
        soc_min = out["soc_min_pct"] if not empty else -1.0
        fuel = None
    else:
        cum = res.samples["fuel_cum_l"]
        tank = np.nan if veh.tank_l is None else veh.tank_l
        crossings["empty"] = limits.first_below(t, d, tank - cum, 0.0) if veh.tank_l is not None else (np.nan, np.nan)
        soc_min, fuel = None, float(cum[-1])
    flags = limits.verdict(is_ev=veh.is_ev, over_max_gross=float(veh.max_gross_kg is not None and
                                                                 mass_kg > veh.max_gross_kg),
                           over_power=over_p[0], over_speed=over_v[0], soc_min_pct=soc_min, reserve_pct=reserve_pct,
                           fuel_l=fuel, tank_l=np.nan if veh.tank_l is None else veh.tank_l)

    def value(x):
        x = float(x)
        return None if x != x else x

    def flag(x):
        x = value(x)
        return None if x is None else x == 1.0

    for key in ("over_max_gross", "over_power", "over_speed"):
        out[key] = flag(flags[key])
    out["reserve_ok" if veh.is_ev else "tank_ok"] = flag(flags["reserve_ok" if veh.is_ev else "tank_ok"])
    out["feasible"] = flag(flags["feasible"])
    if veh.is_ev:
        out["reserve_at_km"] = value(crossings["reserve"][1] / 1e3)
        out["reserve_at_s"] = value(crossings["reserve"][0])
    out["empty_at_km"], out["empty_at_s"] = value(crossings["empty"][1] / 1e3), value(crossings["empty"][0])
    has_limits = veh.max_power_w is not None or veh.max_speed_mps is not None
    out["power_demand_kw"] = float(need_w[0]) / 1e3 if has_limits else None
    out["top_speed_kmh"] = demand.top_speed_mps * 3.6 if has_limits else None
    out["limits_tolerance"] = (f"log: speed +10 % +4 km/h, elevation sd {demand.elevation_sd_m:g} m" if logged
                               else "exact")
    return out


#: Rows of ``--out`` made and written at a time: the per-second frame of a long trace is
#: never held whole beside the result (a million samples: 200 MB more).
OUT_BLOCK_ROWS = 100_000


def _soc_until_empty(time_s: np.ndarray, soc_pct: np.ndarray, empty_at_s: float) -> np.ndarray:
    """The state of charge [%] with no value after ``empty_at_s``: no charge below 0, the
    series ends where the battery runs empty (``--out`` and ``--plot`` alike)."""
    return np.where(time_s > empty_at_s, np.nan, soc_pct)


def _plot_columns(res, empty_at_s: float | None = None) -> dict[str, np.ndarray]:
    """The columns of :meth:`SimulationResult.to_frame` the figure draws (time, state of
    charge or fuel used, elevation), without the rest of the frame."""
    cols = {"time_s": res.time_s}
    if res.powertrain == "ev":
        soc_pct = res.samples["soc"] * 100.0
        cols["soc_pct"] = soc_pct if empty_at_s is None else _soc_until_empty(res.time_s, soc_pct, empty_at_s)
    else:
        cols["fuel_cum_l"] = res.samples["fuel_cum_l"]
    if res.elevation_m is not None:
        cols["elevation_m"] = res.elevation_m
    return cols
