"""``cevm fleet plan``: the paper's fleet assignment (:mod:`cevm.core.assignment`,
scenario files :mod:`cevm.io.scenario`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from cevm.cli.common import AmbientOption, StoreOption, fail, warn_ambient_unused
from cevm.cli.output import OutputFormat, vehicle_legend, write_rows
from cevm.errors import CevmError

app = typer.Typer(help="Fleet assignment: which vehicle serves the shared stops (the paper's section 6).",
                  no_args_is_help=True, rich_markup_mode=None)


@app.command("plan")
def fleet_plan(
    scenario: Annotated[Path, typer.Argument(metavar="SCENARIO", help="Scenario TOML (see configs/fleet/paper-case-study.toml).")],
    day: Annotated[list[str] | None, typer.Option("--day", "-d", metavar="DAY", help="A day by name, or by its number counted from 1 as the paper numbers days (1 is the first day; 0 is refused). Repeatable. Default: every day.")] = None,
    method: Annotated[str, typer.Option(help="auto (enumerate when small, else MILP), enumerate, or milp.")] = "auto",
    store: StoreOption = None,
    ambient_c: AmbientOption = None,
    fmt: Annotated[OutputFormat, typer.Option("--format", "-f", help="Output format.")] = OutputFormat.table,
    min_p_complete: Annotated[float | None, typer.Option(
        "--min-p-complete", metavar="P",
        help="Require every vehicle with a budget (an EV's battery above its reserve, an ICE's tank_l) to complete "
             "its day with at least this probability (0.5 to 1, e.g. 0.95), from its calibration or its class's "
             "priors; still proven optimal. Every plan reports each vehicle's probability (p_complete).")] = None,
) -> None:
    """The assignment of shared stops that minimises total fuel (or energy, or cost),
    within gross-weight limits and EV reserves: proven optimal (enumeration or MILP).

    Each day's ambient temperature: --ambient-c for every day, else the scenario's
    ambient_c per day, else each vehicle's reference."""
    import json
    from contextlib import ExitStack

    from cevm.io.scenario import default_resolver, fleet_report
    from cevm.store import TripStore, resolve_store_path
    from cevm.store.sources import store_resolver

    if method not in ("auto", "enumerate", "milp"):
        raise fail("--method must be auto, enumerate or milp")
    if min_p_complete is not None and not 0.5 <= min_p_complete < 1.0:
        raise fail(f"--min-p-complete must be at least 0.5 and below 1 (0.95: 19 days in 20), got {min_p_complete:g}")
    days = list(day) if day else None  # names or 1-based numbers (cevm.io.scenario.resolve_day)
    try:
        store_path = resolve_store_path(store)
        if store_path.exists():  # legs may be stored trips or routes: opened read-only when one is
            with ExitStack() as stack:
                resolver = store_resolver(lambda: stack.enter_context(TripStore.open(store_path, readonly=True)))
                report = fleet_report(scenario, days, method=method, resolve_leg=resolver, ambient_c=ambient_c,
                                      min_p_complete=min_p_complete)
        else:
            report = fleet_report(scenario, days, method=method, resolve_leg=default_resolver, ambient_c=ambient_c,
                                  min_p_complete=min_p_complete)
    except CevmError as exc:
        raise fail(exc) from None
    if fmt == OutputFormat.json:
        typer.echo(json.dumps(report, indent=2))
        return _warn(report)
    unit = report["unit"]
    if fmt == OutputFormat.csv:
        rows = [{"day": p["day"], "vehicle": v["vehicle"], "stops": " ".join(v["stops"]), f"consumption_{unit}": v["value"],
                 "p_complete": v.get("p_complete")} for p in report["plans"] for v in p["vehicles"]]
        write_rows(rows, fmt)
        return _warn(report)
    day_cols = [k for k in report["table"][0] if k != "vehicle"] if report["table"] else []
    write_rows(report["table"], OutputFormat.table, columns=["vehicle", *day_cols],
               title=f"{report['scenario']}: stops per vehicle (the paper's table 4)")
    files: dict[tuple, list[str]] = {}  # the fleet's ids per vehicle file: what the litres assumed
    for v in report["vehicles"]:
        files.setdefault((v["vehicle_key"], v["vehicle"], v["ice_braking"]), []).append(v["id"])
    legend = vehicle_legend({", ".join(ids): (f"{key}: {name}", braking) for (key, name, braking), ids in files.items()})
    if legend:
        typer.echo(legend)
    temps = {d: t for d, t in report.get("ambient_c", {}).items() if t is not None}
    if temps:
        typer.echo("ambient: " + ", ".join(f"{d} {t:g} degC" for d, t in temps.items()))
    rows = []
    for p in report["plans"]:
        for v in p["vehicles"]:
            rows.append({"day": p["day"], "vehicle": v["vehicle"], unit: v["value"], "max gross kg": v["max_gross_used_kg"],
                         "P complete": v.get("p_complete")})
    if not any(r["P complete"] is not None for r in rows):
        for r in rows:
            del r["P complete"]
    write_rows(rows, OutputFormat.table, title=f"consumption per vehicle [{unit}]"
               + ("; P complete: the probability of completing the day within its battery reserve or tank"
                  if rows and "P complete" in rows[0] else ""), digits={unit: 2, "max gross kg": 0, "P complete": 3})
    summary = [{"day": s["day"], f"total {unit}": s["total"], f"default {unit}": s["default_total"],
                "saving %": s["saving_pct"], "method": s["method"], "status": s["status"],
                "solve ms": s["solve_time_s"] * 1e3} for s in report["summary"]]
    write_rows(summary, OutputFormat.table, title="optimum against the default assignment",
               digits={f"total {unit}": 2, f"default {unit}": 2, "saving %": 2, "solve ms": 2})
    _warn(report)


def _warn(report: dict) -> None:
    """After the output, in every format: each vehicle planned outside what its
    calibration saw."""
    for w in report["warnings"]:
        typer.echo(f"cevm: warning: {w}", err=True)
    temps = [t for t in report["ambient_c"].values() if t is not None]
    if temps:  # asked by --ambient-c or the scenario's days
        asked = "the days' ambient temperatures" if len(set(temps)) > 1 else f"an ambient of {temps[0]:g} degC"
        by_file = {v["vehicle_key"]: v["uses_temperature"] for v in report["vehicles"]}
        warn_ambient_unused(list(by_file.items()), asked)
