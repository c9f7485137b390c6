"""``cevm fleet plan``: the paper's fleet assignment (:mod:`cevm.core.assignment`,
scenario files :mod:`cevm.io.scenario`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from cevm.cli.common import (
    EXIT_INPUT,
    EXIT_PARTIAL,
    AmbientOption,
    OutOption,
    StoreOption,
    check_output_path,
    fail,
    open_out,
    warn_ambient_unused,
)
from cevm.cli.output import OutputFormat, vehicle_legend, write_lines, write_rows
from cevm.errors import CevmError
from cevm.text import printable
from cevm.units import J_PER_KWH

app = typer.Typer(help="Fleet assignment: which vehicle serves the shared stops (the paper's section 6).",
                  no_args_is_help=True, rich_markup_mode=None)


@app.command("plan")
def fleet_plan(
    scenario: Annotated[Path, typer.Argument(metavar="SCENARIO",
                                             help="Scenario TOML (see configs/fleet/paper-case-study.toml).")],
    day: Annotated[list[str] | None,
                   typer.Option("--day", "-d", metavar="DAY",
                                help="A day by name, or by its number counted from 1 as the paper numbers days (1 is "
                                     "the first day; 0 is refused). Repeatable. Default: every day.")] = None,
    method: Annotated[str, typer.Option(help="auto (enumerate when small, else MILP), enumerate, or milp.")] = "auto",
    store: StoreOption = None,
    ambient_c: AmbientOption = None,
    fmt: Annotated[OutputFormat, typer.Option("--format", "-f", help="Output format.")] = OutputFormat.table,
    out: OutOption = None,
    min_p_complete: Annotated[float | None, typer.Option(
        "--min-p-complete", metavar="P",
        help="Require every vehicle with a budget (an EV's battery above its reserve, an ICE's tank_l) to complete "
             "its day with at least this probability (0.5 to 1, e.g. 0.95), from its calibration or its class's "
             "priors; still proven optimal. Every plan reports each vehicle's probability (p_complete).")] = None,
) -> None:
    """The assignment of shared stops that minimises total fuel (or energy, or cost),
    within gross-weight limits and EV reserves: proven optimal (enumeration or MILP).

    Each day's ambient temperature: --ambient-c for every day, else the scenario's
    ambient_c per day, else each vehicle's reference. Each vehicle's day gets the verdict
    every command gives (within max_gross_kg, max_power_kw and max_speed_kmh on every leg,
    the energy budget or the tank); a day without a feasible assignment is named with
    why and the others are planned (exit 1). A scenario's [reference] (the paper's table
    4) is compared with the choices."""
    from contextlib import ExitStack

    from cevm.io.scenario import default_resolver, fleet_report
    from cevm.store import TripStore, resolve_store_path
    from cevm.store.sources import store_leg_demand, store_resolver

    if method not in ("auto", "enumerate", "milp"):
        raise fail("--method must be auto, enumerate or milp")
    check_output_path(out, "--out")
    if min_p_complete is not None and not 0.5 <= min_p_complete < 1.0:
        raise fail(f"--min-p-complete must be at least 0.5 and below 1 (0.95: 19 days in 20), got {min_p_complete:g}")
    days = list(day) if day else None  # names or 1-based numbers (cevm.io.scenario.resolve_day)
    try:
        store_path = resolve_store_path(store)
        if store_path.exists():  # legs may be stored trips or routes: opened read-only when one is
            with ExitStack() as stack:
                opened: list = []

                def opener():
                    if not opened:
                        opened.append(stack.enter_context(TripStore.open(store_path, readonly=True)))
                    return opened[0]

                report = fleet_report(scenario, days, method=method, resolve_leg=store_resolver(opener),
                                      ambient_c=ambient_c, leg_demand=store_leg_demand(opener, scenario.parent),
                                      min_p_complete=min_p_complete)
        else:
            report = fleet_report(scenario, days, method=method, resolve_leg=default_resolver, ambient_c=ambient_c,
                                  min_p_complete=min_p_complete)
    except CevmError as exc:
        raise fail(exc) from None
    try:
        with ExitStack() as stack:
            _write_report(report, fmt, open_out(stack, out))
    except CevmError as exc:
        raise fail(exc) from None
    if out is not None:
        typer.echo(f"cevm fleet plan: {len(report['plans'])} day(s) planned -> {printable(str(out))}", err=True)
    _warn(report)


def _write_report(report: dict, fmt: OutputFormat, stream) -> None:
    """The plan in ``fmt`` on ``stream``."""
    import json

    def echo(line: str) -> None:
        write_lines([line], stream)

    if fmt == OutputFormat.json:
        json.dump(report, stream, indent=2)
        stream.write("\n")
        return
    unit, scale = report["unit"], 1.0
    if unit == "J":  # an electric fleet's energy, as every other table and CSV says it (the JSON: SI and kWh)
        unit, scale = "kWh", 1.0 / J_PER_KWH

    def said(x: float | None) -> float | None:
        return None if x is None else x * scale

    if fmt == OutputFormat.csv:
        rows = [{"day": p["day"], "vehicle": v["vehicle"], "stops": " ".join(v["stops"]),
                 f"consumption_{unit}": said(v["value"]), "p_complete": v.get("p_complete"),
                 "feasible": v["verdict"]["feasible"], "why": "; ".join(_why_not(v["verdict"]))}
                for p in report["plans"] for v in p["vehicles"]]
        rows += [{"day": d["day"], "vehicle": None, "stops": None, f"consumption_{unit}": None, "p_complete": None,
                  "feasible": False, "why": f"not planned: {d['why']}"} for d in report["infeasible_days"]]
        write_rows(rows, fmt, stream=stream)
        return
    day_cols = [k for k in report["table"][0] if k != "vehicle"] if report["table"] else []
    if report["table"]:
        write_rows(report["table"], OutputFormat.table, columns=["vehicle", *day_cols],
                   title=f"{report['scenario']}: stops per vehicle", stream=stream)
    for line in _reference_lines(report):
        echo(line)
    files: dict[tuple, list[str]] = {}  # the fleet's ids per vehicle file: what the litres assumed
    for v in report["vehicles"]:
        files.setdefault((v["vehicle_key"], v["vehicle"], v["ice_braking"]), []).append(v["id"])
    legend = vehicle_legend({", ".join(ids): (f"{key}: {name}", braking)
                             for (key, name, braking), ids in files.items()})
    if legend:
        echo(legend)
    temps = {d: t for d, t in report.get("ambient_c", {}).items() if t is not None}
    if temps:
        echo("ambient: " + ", ".join(f"{d} {t:g} degC" for d, t in temps.items()))
    rows = []
    for p in report["plans"]:
        for v in p["vehicles"]:
            vd = v["verdict"]
            mark = "?" if vd["feasible"] is None else "yes" if vd["feasible"] else "NO"
            why = _why_not(vd)
            rows.append({"day": p["day"], "vehicle": v["vehicle"], unit: said(v["value"]),
                         "max gross kg": v["max_gross_used_kg"], "P complete": v.get("p_complete"),
                         "feasible": mark + (f" ({'; '.join(why)})" if why else "")})
    if not any(r["P complete"] is not None for r in rows):
        for r in rows:
            del r["P complete"]
    if rows:
        write_rows(rows, OutputFormat.table, title=f"consumption per vehicle [{unit}]"
                   + ("; P complete: the probability of completing the day within its battery reserve or tank"
                      if "P complete" in rows[0] else ""), digits={unit: 2, "max gross kg": 0, "P complete": 3},
                   keep=("day", "vehicle", unit, "feasible"), stream=stream)
    summary = [{"day": s["day"], f"total {unit}": said(s["total"]), f"default {unit}": said(s["default_total"]),
                "saving %": s["saving_pct"], "method": s["method"], "status": s["status"],
                "solve ms": None if s["solve_time_s"] is None else s["solve_time_s"] * 1e3} for s in report["summary"]]
    if summary:
        write_rows(summary, OutputFormat.table, title="optimum against the default assignment",
                   digits={f"total {unit}": 2, f"default {unit}": 2, "saving %": 2, "solve ms": 2},
                   keep=("day", f"total {unit}", "saving %"), drop_order=("solve ms", "method", "status"),
                   stream=stream)


def _why_not(verdict: dict) -> list[str]:
    """Why a vehicle's planned day is not a plain yes (its verdict), in words."""
    out = []
    if verdict["over_max_gross"]:
        out.append("over max gross")
    if verdict["energy_ok"] is False:
        out.append("over its energy budget or tank")
    cannot = []
    for what, key in (("power", "over_power"), ("speed", "over_speed")):
        legs = verdict.get(key)
        if legs:  # the first leg named, with its route and what it asks
            first = legs[0]
            asks = (f", {first['power_demand_kw']:,.0f} kW at {first['mass_kg']:,.0f} kg"
                    if first.get("power_demand_kw") is not None and what == "power" else "")
            more = f" and {len(legs) - 1} more leg(s)" if len(legs) > 1 else ""
            cannot.append(f"{what} on route {first['route']} leg {first['leg']}{asks}{more}")
    if cannot:
        out.append("cannot follow: " + ", ".join(cannot))
    return out


def _reference_lines(report: dict) -> list[str]:
    """Lines that compare the plans' choices with the scenario's [reference] (the
    paper's table 4): the same, or where they differ and why they may."""
    ref = report.get("reference")
    if not ref or not report["plans"]:
        return []
    diffs = ref["differences"]
    if not diffs:
        return [f"the same choices as {ref['source']}"]
    days: dict[str, list[str]] = {}
    for d in diffs:
        days.setdefault(d["day"], []).append(f"{d['stop']}: {d['planned']} here, {d['reference']} there")
    text = f"differs from {ref['source']} on " + "; ".join(f"{day} ({', '.join(what)})" for day, what in days.items())
    why = [ref["why"]] if ref.get("why") else []
    calibrated = sorted({v["id"] for v in report["vehicles"] if v["calibrated"]})
    if calibrated:
        why.append(f"vehicles {', '.join(calibrated)} are calibrated on logs, not the paper's model")
    return [text + (": " + "; ".join(why) if why else "")]


def _warn(report: dict) -> None:
    """After the output, in every format: each vehicle planned outside what its
    calibration saw or on legs it cannot follow; the days not planned (exit 1 when
    others were, 2 when none was)."""
    for w in report["warnings"]:
        typer.echo(f"cevm: warning: {w}", err=True)
    for note in dict.fromkeys(v["prior_note"] for v in report["vehicles"] if v.get("prior_note")):
        typer.echo(printable(f"cevm: note: {note}"), err=True)
    temps = [t for t in report["ambient_c"].values() if t is not None]
    if temps:  # asked by --ambient-c or the scenario's days
        asked = "the days' ambient temperatures" if len(set(temps)) > 1 else f"an ambient of {temps[0]:g} degC"
        by_file = {v["vehicle_key"]: v["uses_temperature"] for v in report["vehicles"]}
        warn_ambient_unused(list(by_file.items()), asked)
    bad = report["infeasible_days"]
    if bad:
        for d in bad:
            typer.echo(f"cevm: error: not planned: {d['why']}", err=True)
        raise typer.Exit(EXIT_PARTIAL if report["plans"] else EXIT_INPUT)
