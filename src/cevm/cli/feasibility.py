"""``cevm feasibility``: can each vehicle run each route, with what margin, and the
largest payload (:mod:`cevm.core.feasibility`). Its CSV and JSON columns are
:data:`cevm.cli.prediction_columns.FEASIBILITY`; its table (:data:`FEASIBILITY_TABLE`)
composes them for people."""

from __future__ import annotations

from collections import Counter
from contextlib import ExitStack
from typing import IO, Annotated

import typer

from cevm.cli.columns import Column
from cevm.cli.common import (
    DEFAULT_CONFIDENCE,
    EXIT_INPUT,
    EXIT_PARTIAL,
    TABLE_MAX_ROWS,
    AmbientOption,
    ConfidenceOption,
    Cr0Option,
    CycleOption,
    FormatOption,
    IceBrakingOption,
    IntervalOption,
    OutOption,
    ReserveOption,
    RouteOption,
    SocStartOption,
    StoreOption,
    TripOption,
    VehicleIdOption,
    VehicleOption,
    check_common,
    check_output_path,
    exit_code_for,
    fail,
    load_sources,
    note_flat_cycles,
    open_out,
    say_prior_values,
    start_soc,
    warn,
    warn_ambient_unused,
    warn_damaged,
    with_cycle_options,
)
from cevm.cli.output import OutputFormat, vehicle_legend, write_lines, write_rows
from cevm.cli.prediction_columns import FEASIBILITY, assumptions_line, feasibility_row, legend_name, verdict_text
from cevm.core.cycle import CR0_DEFAULT
from cevm.core.feasibility import feasibility
from cevm.core.sweep import DEFAULT_RESERVE_PCT
from cevm.errors import CevmError
from cevm.runtime import WHOLE_CYCLE_MMAP_THRESHOLD_BYTES, tune_allocator


def _mass_for(src, mass_kg: float | None, payload_kg: float | None) -> tuple[float | None, float | None, str]:
    """(gross mass, payload, mass_source) of the feasibility of ``src``: the given one,
    else a stored trip's own (given to it, else logged: :mod:`cevm.store.masses`), else
    each vehicle's mass_kg (both None)."""
    if mass_kg is not None:
        return mass_kg, None, "--mass-kg"
    if payload_kg is not None:
        return None, payload_kg, "--payload-kg"
    own = getattr(src, "mass", None)  # a stored trip's (cevm.store.sources.StoredTrip)
    key = None if own is None else own.sweep_key()
    if own is None or key is None:
        return None, None, "vehicle file"
    return (key[1], None, own.origin) if key[0] == "gross" else (None, key[1], own.origin)


@with_cycle_options
def feasibility_cmd(
    vehicle: VehicleOption,
    route: RouteOption = None,
    cycle: CycleOption = None,
    trip: TripOption = None,
    vehicle_id: VehicleIdOption = None,
    store: StoreOption = None,
    payload_kg: Annotated[
        float | None,
        typer.Option("--payload-kg", "-p",
                     help="Payload in kg at which margins are given. Default: each vehicle's default mass.")
    ] = None,
    mass_kg: Annotated[
        float | None,
        typer.Option("--mass-kg", "-m", help="Gross mass in kg at which margins are given (instead of --payload-kg).")
    ] = None,
    payload_cap_kg: Annotated[
        float | None,
        typer.Option(help="Where the payload search stops for vehicles without max_gross_kg, in kg. Default: their "
                          "kerb mass."),
    ] = None,
    soc_start: SocStartOption = None,
    reserve_pct: ReserveOption = DEFAULT_RESERVE_PCT,
    confidence: ConfidenceOption = DEFAULT_CONFIDENCE,
    interval: IntervalOption = 0.9,
    fmt: FormatOption = OutputFormat.table,
    out: OutOption = None,
    ice_braking: IceBrakingOption = None,
    ambient_c: AmbientOption = None,
    cr0: Cr0Option = CR0_DEFAULT,
    cycle_fmt=None,
) -> None:
    """Can each vehicle run each route, with what margin, and the largest payload?

    Margins (EV: lowest state of charge above the reserve; ICE: fuel against tank_l) and
    the largest payload that keeps the reserve (or fits the tank) within max_gross_kg,
    exact to the kilogram; where the reserve is first crossed or the battery or tank
    runs empty, and the range (the route driven again and again). The verdict and the
    payload hold with probability --confidence (default 0.95) under the vehicle's
    calibration (or its class's priors): p_reserve_ok / p_tank_ok give the probability
    at the evaluated load, *_low / *_high the interval at --interval."""
    if not (cycle or trip or vehicle_id or route):
        raise fail("give at least one route: --route (or --cycle, --trip, --vehicle-id)")
    tune_allocator(WHOLE_CYCLE_MMAP_THRESHOLD_BYTES)  # arrays of a cycle's length reused, not mapped anew
    if payload_kg is not None and mass_kg is not None:
        raise fail("give --mass-kg or --payload-kg, not both")
    check_common(ice_braking, soc_start, reserve_pct, interval)
    check_output_path(out, "--out")
    if not 0.5 <= confidence < 1.0:
        raise fail(f"--confidence must be at least 0.5 and below 1 (0.95: 19 times in 20), got {confidence:g}")
    try:
        from cevm.io import load_vehicles

        vehicles = load_vehicles(vehicle)
        rows: list[dict] = []
        skipped: list[CevmError] = []  # damaged stored trips of --vehicle-id, left out
        with ExitStack() as stack:
            sources = load_sources(stack, store, cycle or [], trip or [], vehicle_id or [], route or [], cr0,
                                   cycle_fmt, need_profiles=any(v.is_ev for v in vehicles),
                                   on_damaged=skipped.append)
            note_flat_cycles(sources)
            seen: list[tuple] = []
            for src in sources:
                src_mass, src_payload, mass_source = _mass_for(src, mass_kg, payload_kg)
                soc, soc_from = start_soc(src, soc_start)
                try:
                    res = feasibility(src, vehicles, soc_start_pct=soc, reserve_pct=reserve_pct,
                                      payload_kg=src_payload, mass_kg=src_mass, payload_cap_kg=payload_cap_kg,
                                      ice_braking=ice_braking, ambient_c=ambient_c, confidence=confidence)
                except CevmError as exc:
                    if mass_source in ("--mass-kg", "--payload-kg", "vehicle file") or exit_code_for(exc) != EXIT_INPUT:
                        raise  # the store's failures (a trip's profile damaged on disk: exit 4) as they are
                    raise CevmError(f"trip {src.name!r} ({src.mass.describe()} mass): {exc}") from None
                rows.extend(feasibility_row(res, i, ice_braking, mass_source, interval, soc_from)
                            for i in range(len(res.vehicles)))
                speed = src.distance_m / src.duration_s if src.duration_s > 0 else float("nan")
                idle = src.vector.idle_s / src.duration_s if src.duration_s > 0 else float("nan")
                amb = res.ambient_c
                seen += [(i, res.mass_kg[i], float("nan") if amb is None else amb[i], speed, idle)
                         for i in range(len(vehicles))]
                src.release()
            stream = open_out(stack, out)
            if fmt == OutputFormat.table:
                _print_feasibility(rows, stream)
            else:
                # every column in the spec's order, CSV numbers at its decimals (as predict's)
                write_rows(rows, fmt, stream=stream, columns=FEASIBILITY.columns)
    except CevmError as exc:
        raise fail(exc) from None
    _warn_outside_calibration(vehicles, seen)
    say_prior_values(vehicles)
    if mass_kg is None and payload_kg is None:  # stored trips at their own masses
        from cevm.store.sources import foreign_mass_warnings

        for w in foreign_mass_warnings(sources, vehicles):
            warn(w)
    if ambient_c is not None:
        from cevm.core.energy import uses_temperature

        warn_ambient_unused([(v.label, uses_temperature(v)) for v in vehicles], f"--ambient-c {ambient_c:g}")
    for problem in skipped:
        warn_damaged(problem)
    if skipped:
        raise typer.Exit(EXIT_PARTIAL)


def _warn_outside_calibration(vehicles, seen: list[tuple]) -> None:
    """One warning per vehicle asked outside what its calibration saw."""
    import numpy as np

    from cevm.core.vehicle import domain_warnings

    for i, veh in enumerate(vehicles):
        pts = np.array([(m, t, v, s) for j, m, t, v, s in seen if j == i], dtype=float).reshape(-1, 4)
        if pts.size == 0:
            continue
        speeds = pts[:, 2][np.isfinite(pts[:, 2])]
        idle = pts[:, 3][np.isfinite(pts[:, 3])]
        for w in domain_warnings(veh, mass_kg=pts[:, 0], ambient_c=pts[:, 1],
                                 mean_speed_mps=speeds if speeds.size else None,
                                 idle_share=idle if idle.size else None):
            typer.echo(f"cevm: warning: {w}", err=True)


#: The columns of feasibility's table, composed from its rows by :func:`_print_feasibility`.
FEASIBILITY_TABLE = (
    Column("cycle", "the source: a cycle, stored trip or route (column cycle)", kind="text", layout="id"),
    Column("vehicle", "the vehicle's key", kind="text", layout="id"),
    Column("payload kg", "the payload evaluated [kg]", digits=0),
    Column("feasible", "the verdict: yes, NO, or ? (ICE without tank_l), the reserve or tank at --confidence, and why "
           "not (where the energy's verdict is not sure, its probability at the payload evaluated)", kind="text",
           layout="wrap"),
    Column("state", "EV: lowest / end state of charge [%]; ICE: fuel / tank [l]", kind="text", layout="right",
           header="SoC min/end, fuel/tank"),
    Column("margin", "EV: lowest SoC less the reserve [pp]; ICE: tank less fuel [l]; where it runs empty",
           kind="text", layout="right"),
    Column("range km", "the range, the source driven again and again [km]", digits=1),
    Column("max payload kg", "the payloads that pass [kg]", kind="text", layout="right"),
    Column("limited by", "what limits the payload", kind="text", layout="right"),
)


def _print_feasibility(rows: list[dict], stream: IO[str]) -> None:
    table = []
    names: dict[str, tuple[str, str | None]] = {}
    for r in rows[:TABLE_MAX_ROWS]:
        if r["powertrain"] == "ev":
            end = "-" if r["soc_end_pct"] is None else f"{r['soc_end_pct']:.1f}"
            state = f"{r['soc_min_pct']:.1f}/{end} %"
            margin = f"{r['reserve_margin_pct']:+.1f} pp"
            if r.get("empty_at_km") is not None:
                margin += f" (empty at {r['empty_at_km']:,.1f} km)"
            elif r.get("reserve_at_km") is not None:
                margin += f" (reserve at {r['reserve_at_km']:,.1f} km)"
        else:
            state = f"{r['fuel_l']:.1f}/" + (f"{r['tank_l']:g} l" if r.get("tank_l") else "? l")
            margin = "-" if r.get("tank_margin_l") is None else f"{r['tank_margin_l']:+.1f} l"
            if r.get("empty_at_km") is not None:
                margin += f" (empty at {r['empty_at_km']:,.1f} km)"
        mp = r["max_payload_kg"]
        payload = "none" if mp is None else f"{mp:,.0f}"
        if r["min_payload_kg"]:
            payload = f"{r['min_payload_kg']:,.0f} to {payload}"
        table.append({"cycle": r["cycle"], "vehicle": r["vehicle_key"], "payload kg": r["payload_kg"],
                      "feasible": verdict_text(r, energy=False), "state": state, "margin": margin,
                      "range km": r["range_km"], "max payload kg": payload, "limited by": r["limited_by"]})
        names[r["vehicle_key"]] = (legend_name(r), r.get("ice_braking"))
    conf = rows[0].get("confidence") if rows else None
    title = "cevm feasibility" + (f" (first {len(table)} of {len(rows)})" if len(rows) > len(table) else "") + (
        f": verdicts and payloads at confidence {conf:g}" if conf is not None else "")
    write_rows(table, OutputFormat.table, title=title, columns=FEASIBILITY_TABLE, stream=stream,
               keep=("cycle", "feasible"), drop_order=("range km", "state", "limited by", "payload kg", "vehicle"))
    origins = Counter({r["cycle"]: r["mass_source"] for r in rows}.values())
    mass_line = ("mass from: " + ", ".join(f"{what} ({n} source{'s' if n > 1 else ''})" for what, n in
                                           sorted(origins.items(), key=lambda kv: (-kv[1], kv[0])))
                 + " (column mass_source in --format csv or json)")
    write_lines([vehicle_legend(names), assumptions_line(rows, "cycle")[0], mass_line], stream)
