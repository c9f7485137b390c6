"""``cevm replay``: the fleet's logged working days run again with a candidate vehicle,
charging included; a thin layer over :mod:`cevm.core.replay` (trips from
:mod:`cevm.store.replay_trips`, rows as :data:`cevm.cli.replay_columns.REPLAY` describes
them).

Vehicles are replayed one after another: a vehicle's trips are read, its duties run and
sized here (reading the few step tables that need it), and the Monte Carlo of its duties'
probabilities goes to the executor (``--workers``, ``--scheduler``); rows come back in
input order and are written as they come, so a parallel run writes the bytes of a
serial one and holds a few vehicles at a time (the executor's window).
"""

from __future__ import annotations

import dataclasses
import json
import math
import sys
from collections.abc import Iterator
from contextlib import ExitStack
from datetime import UTC, datetime, tzinfo
from pathlib import Path
from types import SimpleNamespace
from typing import IO, Annotated

import numpy as np
import typer

from cevm.cli.columnar import concat_columns, csv_text, json_objects, table_row
from cevm.cli.common import (
    EXIT_PARTIAL,
    PNG,
    TABLE_MAX_ROWS,
    FormatOption,
    IceBrakingOption,
    OutOption,
    ReserveOption,
    StoreOption,
    VehicleOption,
    check_common,
    check_output_path,
    check_workers,
    fail,
    open_out,
    say_prior_values,
    warn,
    warn_damaged,
)
from cevm.cli.duty_options import build_charging, candidate_vehicle, describe_run
from cevm.cli.output import OutputFormat, write_lines, write_rows
from cevm.cli.replay_columns import (
    REPLAY,
    REPLAY_TABLE,
    REPLAY_TABLE_DROP,
    REPLAY_TABLE_KEEP,
    STATUS,
    DutyRows,
    replay_values,
)
from cevm.core.replay import (
    DEFAULT_CHARGE_EFFICIENCY,
    DEFAULT_CONFIDENCE,
    DEFAULT_DRAWS,
    DEFAULT_DUTY_GAP_H,
    DEFAULT_INTERVAL,
    DEFAULT_MIN_DWELL_MIN,
    DEFAULT_PLACE_RADIUS_M,
    DEFAULT_SEED,
    DEFAULT_TARGET_SHARE,
    ReplaySettings,
    central_interval,
    p_complete,
    plan_vehicle,
)
from cevm.core.replay.fleet import Chain, Fleet, chained_sizes, duty_extrapolation
from cevm.core.replay.sizing import size_for_share
from cevm.core.sweep import DEFAULT_RESERVE_PCT
from cevm.errors import CevmError
from cevm.executors import Task, make_executor
from cevm.units import J_PER_KWH

# ----------------------------------------------------------------------- options


def time_zone(name: str) -> tzinfo:
    """``--tz``: UTC or an IANA zone name (Europe/London)."""
    if name.upper() == "UTC":
        return UTC
    from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

    try:
        return ZoneInfo(name)
    except (ZoneInfoNotFoundError, ValueError):
        raise CevmError(f"--tz {name!r}: not a time zone (give UTC or an IANA name such as Europe/London)") from None


def day_numbers(tz: tzinfo):
    """Each trip's calendar day in ``tz`` (an ordinal) from its start [s]."""
    def of(start_s: np.ndarray) -> np.ndarray:
        return np.array([datetime.fromtimestamp(float(s), UTC).astimezone(tz).date().toordinal()
                         for s in start_s], dtype=np.int64)
    return of


# ----------------------------------------------------------------------- writing


class ReplayWriter:
    """Streams duty rows as CSV, JSON or a (bounded) table, with the columns of
    :data:`~cevm.cli.replay_columns.REPLAY`."""

    def __init__(self, fmt: OutputFormat, stream: IO[str]):
        self.fmt = fmt
        self.stream = stream
        self.rows = 0
        self.started = False
        self.table_rows: list[dict] = []

    def add(self, ctx: DutyRows) -> None:
        self.rows += ctx.n
        if ctx.n == 0:
            return
        cols = replay_values(ctx)
        if self.fmt == OutputFormat.table:
            self._table_add(cols, ctx.n)
            return
        cols = concat_columns([cols])
        if self.fmt == OutputFormat.csv:
            if not self.started:
                self.stream.write(",".join(REPLAY.names) + "\n")
            self.stream.write(csv_text(cols, REPLAY))
        else:
            rows = json_objects(cols, REPLAY, np.full(ctx.n, ctx.ev))
            self.stream.write(("[\n  " if not self.started else ",\n  ") + ",\n  ".join(rows))
        self.started = True

    def _table_add(self, cols: dict, n: int) -> None:
        for i in range(min(n, TABLE_MAX_ROWS - len(self.table_rows))):
            self.table_rows.append(with_status(table_row(cols, REPLAY, i)))

    def close(self) -> None:
        if self.fmt == OutputFormat.table:
            rows = self.table_rows
            columns = [c for c in REPLAY_TABLE if c == "status" or any(r.get(c) is not None for r in rows)]
            title = "cevm replay" + (f" (first {len(rows)} of {self.rows} duties)" if self.rows > len(rows) else "")
            write_rows(rows, OutputFormat.table, columns=REPLAY.table(columns, STATUS), title=title,
                       stream=self.stream, keep=REPLAY_TABLE_KEEP, drop_order=REPLAY_TABLE_DROP)
            if self.rows > len(rows):
                typer.echo(f"cevm: {self.rows - len(rows)} more duties not shown; use --format csv or json "
                           "(and --out FILE)", err=True)
        elif self.fmt == OutputFormat.csv:
            if not self.started:
                self.stream.write(",".join(REPLAY.names) + "\n")
        else:
            self.stream.write("\n]\n" if self.started else "[]\n")
        self.stream.flush()


def with_status(row: dict) -> dict:
    """A table row with its 'status': the reserve kept, or the trip and limit the candidate
    cannot follow, or where the reserve is first crossed (or the battery or tank runs
    empty) [km into the duty]."""
    if row.get("completes"):
        row["status"] = "yes"
    elif row.get("cannot_follow"):
        row["status"] = f"NO: cannot follow: {row['cannot_follow']}"
    elif row.get("empty_at_km") is not None:
        row["status"] = f"NO: empty at {row['empty_at_km']:,.1f} km"
    elif row.get("reserve_at_km") is not None:
        row["status"] = f"NO: reserve at {row['reserve_at_km']:,.1f} km"
    else:
        row["status"] = "NO"
    return row


# ----------------------------------------------------------------------- the run


@dataclasses.dataclass
class Run:
    """What a replay gathers while its vehicles go by: the fleet's duties, the chains for a
    fleet sizing with levels carried across duties, notes, damaged trips."""

    fleet: Fleet = dataclasses.field(default_factory=Fleet.empty)
    chains: list = dataclasses.field(default_factory=list)
    notes: list = dataclasses.field(default_factory=list)
    skipped: list = dataclasses.field(default_factory=list)
    damaged_profiles: dict = dataclasses.field(default_factory=dict)
    sources: set = dataclasses.field(default_factory=set)
    extrapolating: int = 0
    read: int = 0
    judged: int = 0
    trips: int = 0


def _plans(st, vehicle, settings: ReplaySettings, ids: list[str], *, positions: bool, day_of, run: Run
           ) -> Iterator[tuple]:
    """Each vehicle's plan, with the Monte Carlo task (or None where there is nothing to
    draw), in the order of ``ids``."""
    from cevm.store.replay_trips import demand_reader, logged_trips, step_table_reader

    for vid in ids:
        def profile(exc) -> None:
            run.damaged_profiles.setdefault(exc.trip_id, exc)

        def twice(ids: list[str], vid=vid) -> None:
            run.notes.append(f"{vid}: {len(ids)} trip(s) lie mostly inside an earlier trip of the vehicle, the same "
                             f"driving logged twice (two loggers, or one log under two names): each counted once, "
                             f"left out: {', '.join(ids[:3])}{' ...' if len(ids) > 3 else ''}")

        trips = logged_trips(st, vid, positions=positions, day_of=day_of, on_damaged=run.skipped.append,
                             on_damaged_profile=profile, on_logged_twice=twice)
        read = step_table_reader(st, trips, profile)
        plan = plan_vehicle(trips, vehicle, settings, read, demand=demand_reader(st, trips, profile))
        plan = dataclasses.replace(plan, trips=dataclasses.replace(trips, vectors=()))  # free the vectors
        run.read += plan.excess.read
        run.judged += plan.follow.read
        run.trips += plan.trips.n
        if plan.unplaced:
            run.notes.append(f"{vid}: {plan.unplaced} stop(s) long enough to charge have no known position: not "
                             "charged")
        if settings.charging.chained:
            run.chains.append(Chain(plan.energies.energy, plan.excess, _excess_reader(plan, read), plan.stops,
                                    plan.duties.bounds, plan.follows))
        task = None
        if plan.spread.source != "none":
            task = Task(f"{vid} ({plan.duties.n} duties)", (plan.draw_plan(), settings.draws, settings.seed),
                        cost_s=2e-7 * settings.draws * max(1, plan.trips.n))
        yield plan, task


def _excess_reader(plan, read):
    from cevm.core.replay import trips_excess

    def exact(indices: np.ndarray) -> np.ndarray:
        e = plan.energies
        return trips_excess([read(int(i)) for i in indices], plan.vehicle, e.mass_kg[indices], e.ambient_c[indices],
                            ice_braking=plan.settings.ice_braking)
    return exact


def _replayed(executor, plans: Iterator[tuple]) -> Iterator[tuple]:
    """(plan, p_complete) in order: the tasks on the executor, the rest passed through."""
    pending: list = []

    def items():
        for plan, task in plans:
            pending.append(plan)
            yield task if task is not None else ("deterministic",)

    for res in executor.run(p_complete, items()):
        plan = pending.pop(0)
        if not res.ok:
            raise CevmError(f"the Monte Carlo of vehicle {plan.trips.vehicle_id!r} failed on a worker: {res.error}")
        p = res.value if res.attempts else (plan.levels.low >= plan.reserve).astype(np.float64)
        yield plan, plan.judged(p)


def fleet_summary(run: Run, vehicle, settings: ReplaySettings, confidence: float, target: float) -> dict:
    """The fleet's figures (module notes of :mod:`cevm.core.replay.fleet`)."""
    f = run.fleet
    n = f.n
    ev = vehicle.is_ev
    unit, scale = ("kWh", J_PER_KWH) if ev else ("l", 1.0)
    completes = f.array("completes").astype(bool)
    p = f.array("p")
    follows = f.array("follows").astype(bool)
    cap = vehicle.battery_j if ev else vehicle.tank_l
    s, r = settings.soc_start_pct / 100.0, settings.reserve_pct / 100.0
    if settings.charging.chained:
        battery, charger = chained_sizes(run.chains, target, soc_start=s, reserve=r,
                                         efficiency=settings.charging.efficiency, capacity=cap,
                                         battery_step=settings.battery_step, charger_step=settings.charger_step_w)
        battery_c = charger_c = math.nan  # sized at the mean only: the levels carried across duties
    else:
        battery = size_for_share(f.array("battery"), target)
        battery_c = size_for_share(f.array("battery_conf"), target)
        need = f.array("charger")  # NaN: the duty's vehicle has no stop that may charge
        charger = charger_c = math.nan
        if not np.isnan(need).all():
            charger = size_for_share(np.where(np.isnan(need), np.where(completes, 0.0, np.inf), need), target)
            need_c = f.array("charger_conf")
            # a duty without a stop that may charge needs no charger if it keeps the reserve at its confidence
            # energy with the candidate's battery: where its battery need there is within the battery
            kept_c = f.array("battery_conf") <= cap
            charger_c = size_for_share(np.where(np.isnan(need_c), np.where(kept_c, 0.0, np.inf), need_c), target)
    per = "kWh" if ev else "l"
    out = {
        "candidate": vehicle.label, "powertrain": vehicle.powertrain, "vehicles": len(set(f.vehicle)), "duties": n,
        "completes": int(completes.sum()), "completes_share": completes.mean() if n else math.nan,
        "cannot_follow": int(np.count_nonzero(~follows)),
        "confidence": confidence, "completes_at_confidence": int(np.count_nonzero(p >= confidence)),
        "share_at_confidence": float(np.count_nonzero(p >= confidence)) / n if n else math.nan,
        "mean_p_complete": float(p.mean()) if n else math.nan,
        "p_method": (f"Monte Carlo, {settings.draws} draws per duty, seed {settings.seed}"
                     if run.sources - {"none"} else "none: no predictive distribution, p is 0 or 1 at the mean"),
        "p_standard_error_max": 0.5 / math.sqrt(settings.draws) if run.sources - {"none"} else 0.0,
        "interval_from": ", ".join(sorted(run.sources)), "target_share": target,
        f"battery_for_target_{per}": battery / scale,
        f"battery_for_target_{per}_at_confidence": battery_c / scale,
        f"battery_step_{per}": settings.battery_step / scale,
        f"capacity_{per}": cap / scale,
    }
    if ev:
        out["charger_for_target_kw"] = charger / 1e3
        out["charger_for_target_kw_at_confidence"] = charger_c / 1e3
        out["charger_step_kw"] = settings.charger_step_w / 1e3
    out["unit"] = unit
    return out


def _charger_line(c: float, sm: dict, at: str) -> str:
    """The summary's line on the charger [kW] that completes the target share ``at`` a level."""
    share = f"{100 * sm['target_share']:.0f} %"
    if c == 0:
        return f"no charger is needed to complete {share} of the duties {at}"
    if math.isfinite(c):
        return (f"a charger of {c:,.0f} kW (to {sm['charger_step_kw']:g} kW) at the stops that may charge completes "
                f"{share} of the duties with the candidate's battery {at}")
    return f"no charger at the stops that may charge completes {share} of the duties with the candidate's battery {at}"


def summary_lines(sm: dict, settings: ReplaySettings) -> list[str]:
    """The summary for people."""
    n = sm["duties"]
    unit = sm["unit"]
    per = "kWh" if unit == "kWh" else "l"

    def pct(x):
        return "-" if not math.isfinite(x) else f"{100 * x:.0f} %"

    lines = [f"{n} duties of {sm['vehicles']} vehicle(s) replayed with {sm['candidate']}: {sm['completes']} "
             f"({pct(sm['completes_share'])}) keep the {settings.reserve_pct:g} % reserve at the mean energies "
             f"on trips it can follow, "
             f"{sm['completes_at_confidence']} ({pct(sm['share_at_confidence'])}) with a probability of at least "
             f"{sm['confidence']:g}"]
    if sm.get("cannot_follow"):
        lines.append(f"{sm['cannot_follow']} duties have a trip the candidate cannot follow (its max_power_kw, "
                     "max_speed_kmh or max_gross_kg, as cevm predict judges the trips): they do not complete "
                     "(column cannot_follow)")
    b = sm[f"battery_for_target_{per}"]
    what = "battery" if unit == "kWh" else "tank"
    bc = sm[f"battery_for_target_{per}_at_confidence"]
    if math.isfinite(b):
        lines.append(f"a usable {what} of {b:,.0f} {unit} (to {sm[f'battery_step_{per}']:g} {unit}) completes "
                     f"{pct(sm['target_share'])} of the duties at the mean energies"
                     + (f", {bc:,.0f} {unit} with each duty's energy at its {sm['confidence']:g} quantile"
                        if math.isfinite(bc) else "")
                     + f" (the candidate has {sm[f'capacity_{per}']:,.0f} {unit})")
    c = sm.get("charger_for_target_kw", math.nan)
    cc = sm.get("charger_for_target_kw_at_confidence", math.nan)
    at_c = f"with each duty's energy at its {sm['confidence']:g} quantile"
    if unit == "kWh" and not math.isnan(c):
        lines.append(_charger_line(c, sm, f"at the mean energies and {at_c}" if c == cc else "at the mean energies"))
    if unit == "kWh" and not math.isnan(cc) and cc != c:
        lines.append(_charger_line(cc, sm, at_c))
    lines.append(f"p_complete: {sm['p_method']}" + (f" (standard error at most {sm['p_standard_error_max']:.3f}; "
                                                     f"from the {sm['interval_from']} distribution)"
                                                     if sm["p_standard_error_max"] else ""))
    return lines


def replay_cmd(
    vehicle: VehicleOption,
    vehicle_id: Annotated[list[str], typer.Option("--vehicle-id", metavar="ID", help="A logged vehicle whose stored "
                                                  "trips are replayed. Repeatable.")],
    store: StoreOption = None,
    duty: Annotated[str, typer.Option(help="How trips form duties: 'gap' (a stop of at least --duty-gap-h ends a duty: "
                                           "a night shift stays one duty) or 'day' (calendar days in --tz).")] = "gap",
    duty_gap_h: Annotated[float, typer.Option(help="The stop [h] that ends a duty (default 6: longer than a day's "
                                                   "breaks and split shifts, shorter than the 9 h daily rest of EU "
                                                   "drivers' hours).")] = DEFAULT_DUTY_GAP_H,
    tz: Annotated[str, typer.Option(help="Time zone of the rows' days and times and of --duty day: UTC or an IANA "
                                         "name (Europe/London).")] = "UTC",
    soc_start: Annotated[float, typer.Option("--soc-start", help="Level at the start [% of the battery or tank]: "
                                             "of every duty with --overnight full, else of each vehicle's "
                                             "first.")] = 100.0,
    reserve_pct: ReserveOption = DEFAULT_RESERVE_PCT,
    charger_kw: Annotated[float | None, typer.Option(help="Charger power at the stops inside a duty [kW] (EV; "
                                                        "default none).")] = None,
    min_dwell_min: Annotated[float, typer.Option(help="Shortest stop that charges or refuels [min] (default 30: a "
                                                      "driver's break, plugging in and out).")] = DEFAULT_MIN_DWELL_MIN,
    charge_efficiency: Annotated[float, typer.Option(help="Grid to battery (default 0.90: DC charging, 85-93 % "
                                                          "measured).")] = DEFAULT_CHARGE_EFFICIENCY,
    charge_at: Annotated[list[str] | None, typer.Option(metavar="LAT,LON,RADIUS_M|depot", help="Charge only at "
                         "stops here (where the trip before ended and the next began); 'depot': where the vehicle "
                         "most often stands between duties. Repeatable. Default: any stop.")] = None,
    refuel_at: Annotated[list[str] | None, typer.Option(metavar="LAT,LON,RADIUS_M|depot", help="Diesel candidate: "
                         "refuel to full at stops here. Repeatable. Default: only overnight.")] = None,
    depot_radius_m: Annotated[float, typer.Option(help="Radius of the depot found [m].")] = DEFAULT_PLACE_RADIUS_M,
    overnight: Annotated[str | None, typer.Option(help="The rests between duties: 'full' (default: each duty "
                                                          "starts at --soc-start, a depot charge) or 'none' (levels "
                                                          "carried).")] = None,
    overnight_kw: Annotated[float | None, typer.Option(help="Instead: a charger of this power [kW] for the whole "
                                                          "rest between duties, levels carried.")] = None,
    logged_kerb_kg: Annotated[float | None, typer.Option(help="The logged vehicles' kerb mass [kg]: the candidate "
                                                            "carries each trip's payload (gross less this) on its own "
                                                            "kerb mass. Default: each trip's gross mass as it "
                                                            "is.")] = None,
    battery_kwh: Annotated[float | None, typer.Option(help="Replay with this usable battery [kWh] instead of the "
                                                         "candidate file's.")] = None,
    within_trips: Annotated[str, typer.Option(help="Where the lowest level is looked for: 'exact' (inside the trips "
                                                   "that could decide anything: their stored profiles read) or 'ends' "
                                                   "(at the trips' ends only: no profile read for it, for a large "
                                                   "fleet fast; a candidate's max_power_kw and max_speed_kmh are "
                                                   "judged on every trip's profile either way).")] = "exact",
    interval: Annotated[float, typer.Option(help="Interval of the duties' energy.")] = DEFAULT_INTERVAL,
    confidence: Annotated[float, typer.Option(help="A duty counts as completed in the summary at this probability "
                                                   "(default 0.95: the high end of the 90 % "
                                                   "interval).")] = DEFAULT_CONFIDENCE,
    target_share: Annotated[float, typer.Option(help="Share of duties the sized battery and charger must "
                                                     "complete.")] = DEFAULT_TARGET_SHARE,
    draws: Annotated[int, typer.Option(min=1, help="Monte Carlo draws per duty.")] = DEFAULT_DRAWS,
    seed: Annotated[int, typer.Option(help="Seed of the draws.")] = DEFAULT_SEED,
    ice_braking: IceBrakingOption = None,
    fmt: FormatOption = OutputFormat.table,
    out: OutOption = None,
    plot: Annotated[Path | None, typer.Option(metavar="FILE.png", help="Write a PNG: each duty's energy against "
                                                 "the usable battery and the reserve.")] = None,
    summary: Annotated[Path | None, typer.Option(metavar="FILE.json", help="Also write the fleet's summary as "
                                                    "JSON.")] = None,
    workers: Annotated[int | None, typer.Option("--workers", "-w", min=1, metavar="N", help="Worker processes for "
                                                   "the Monte Carlo (default 1: in this process).")] = None,
    scheduler: Annotated[str | None, typer.Option(help="Dask scheduler address (tcp://HOST:8786) for the Monte "
                                                     "Carlo (pip install 'cevm[dask]').")] = None,
) -> None:
    """Run the logged vehicles' duties again with a candidate vehicle, charging included.

    Each vehicle's stored trips are grouped into duties (--duty), and each duty is run
    trip by trip in time order with the candidate: every trip at its own mass (given,
    logged, else the candidate's) and ambient temperature, the battery's level (or the
    tank's) carried from trip to trip and charged at the stops long enough
    (--min-dwell-min), where allowed (--charge-at), up to full. Rows per duty: its energy
    and interval, its lowest and last level, what it charged, whether it keeps
    --reserve-pct and its probability to, where it first crosses the reserve and what it
    lacks, the battery and charger it needs; then the fleet's summary."""
    opts = SimpleNamespace(**locals())
    if workers is not None and scheduler is not None:
        raise fail("give --workers (local processes) or --scheduler (a Dask cluster), not both")
    check_workers(workers)
    check_common(ice_braking, soc_start, reserve_pct)
    check_output_path(out, "--out")
    check_output_path(plot, "--plot", PNG)
    check_output_path(summary, "--summary", (".json", "the fleet's summary (JSON)"))
    for name, value, lo, hi in (("--interval", interval, 0.0, 1.0), ("--confidence", confidence, 0.0, 1.0),
                                ("--target-share", target_share, 0.0, 1.0)):
        if not lo < value < hi if name == "--interval" else not lo < value <= hi:
            raise fail(f"{name} {value:g} must be in (0, 1{')' if name == '--interval' else ']'}")
    if not duty_gap_h > 0:
        raise fail(f"--duty-gap-h {duty_gap_h:g} must be > 0")
    if duty not in ("gap", "day"):
        raise fail(f"--duty {duty!r}: give gap or day")
    if within_trips not in ("exact", "ends"):
        raise fail(f"--within-trips {within_trips!r}: give exact or ends")
    if battery_kwh is not None and not battery_kwh > 0:
        raise fail(f"--battery-kwh {battery_kwh:g} must be > 0")
    try:
        run = _replay(opts)
    except CevmError as exc:
        raise fail(exc) from None
    for damaged in run.skipped:
        warn_damaged(damaged)
    if run.skipped or run.damaged_profiles:
        raise typer.Exit(EXIT_PARTIAL)


def _settings(o: SimpleNamespace, vehicle) -> ReplaySettings:
    charging = build_charging(vehicle, o.charger_kw, o.min_dwell_min, o.charge_efficiency, o.charge_at, o.refuel_at,
                              o.depot_radius_m, o.overnight, o.overnight_kw)
    try:
        return ReplaySettings(rule=o.duty, gap_s=3600.0 * o.duty_gap_h, soc_start_pct=o.soc_start,
                              reserve_pct=o.reserve_pct, charging=charging, interval=o.interval, draws=o.draws,
                              seed=o.seed, battery_step=J_PER_KWH if vehicle.is_ev else 1.0,
                              ice_braking=o.ice_braking, logged_kerb_kg=o.logged_kerb_kg,
                              within_trips=o.within_trips == "exact", size_confidence=o.confidence)
    except ValueError as exc:
        raise CevmError(str(exc)) from None


def _replay(o: SimpleNamespace) -> Run:
    """The run (the command's body): rows written, summary said, damaged profiles warned
    about; returns the run (its damaged trips: exit 1)."""
    from cevm.store import TripStore, existing_store_path

    vehicle = candidate_vehicle(o)
    settings = _settings(o, vehicle)
    zone = time_zone(o.tz)
    run = Run()
    ids = list(dict.fromkeys(o.vehicle_id))
    with ExitStack() as stack:
        st = stack.enter_context(TripStore.open(existing_store_path(o.store), readonly=True))
        known = set(st.vehicle_ids())
        unknown = [v for v in ids if v not in known]
        if unknown:
            raise CevmError(f"no stored trips of vehicle id(s) {', '.join(map(repr, unknown))}; 'cevm trips' lists "
                            "the stored trips and their vehicles")
        executor = stack.enter_context(make_executor(None if o.scheduler else (o.workers or 1), o.scheduler))
        stream = open_out(stack, o.out)
        writer = ReplayWriter(o.fmt, stream)
        context = describe_run(vehicle, settings, o.tz)
        plans = _plans(st, vehicle, settings, ids, positions=not settings.charging.anywhere,
                       day_of=day_numbers(zone) if settings.rule == "day" else None, run=run)
        for plan, p in _replayed(executor, plans):
            ctx = dict(context)
            if settings.charging.depot:
                found = plan.depot.describe() if plan.depot is not None else "depot: none found"
                ctx["charge_places"] = ctx["charge_places"].replace("the vehicle's depot", found)
                if plan.depot is None:
                    run.notes.append(f"{plan.trips.vehicle_id}: no depot found (no place holds half of its rests "
                                     "between duties): it charges nowhere but at the places named")
            extrapolation = duty_extrapolation(plan)
            run.extrapolating += sum(x != "none" for x in extrapolation)
            writer.add(DutyRows(plan, p, settings.draws, zone, ctx, extrapolation))
            low, high = central_interval(np.add.reduceat(plan.energies.energy, plan.duties.first), plan.energy_sd,
                                         settings.interval)
            run.fleet.add(plan, p, low, high)
            run.sources.add(plan.spread.source)
        writer.close()
        sm = fleet_summary(run, vehicle, settings, o.confidence, o.target_share)
    _say(o, sm, settings, run, vehicle)
    for exc in run.damaged_profiles.values():
        warn(f"{exc}: its start and end positions are unknown (its stops do not charge at named places or the "
             "depot) and its lowest point inside the trip is bounded by what it regenerates, not exact")
    return run


def _say(o: SimpleNamespace, sm: dict, settings: ReplaySettings, run: Run, vehicle) -> None:
    """The summary (stdout under a table, else stderr), its JSON, the notes, the plot."""
    lines = summary_lines(sm, settings)
    to_stderr = o.fmt != OutputFormat.table or o.out is not None
    for line in lines:
        if to_stderr:
            typer.echo(f"cevm replay: {line}", err=True)
        else:  # under the table: wrapped between words on a terminal, as the table fits it
            write_lines([f"cevm replay: {line}"], sys.stdout)
    for note in run.notes:
        typer.echo(f"cevm: note: {note}", err=True)
    say_prior_values([vehicle])
    if settings.within_trips and vehicle.is_ev:
        typer.echo(f"cevm: note: the lowest level inside the trips: stored profiles read for {run.read} of "
                   f"{run.trips} trips (those that could hold a duty's lowest point or decide it; --within-trips "
                   "ends reads none)", err=True)
    if run.judged:
        typer.echo(f"cevm: note: the candidate's max_power_kw and max_speed_kmh judged on the stored profiles of "
                   f"{run.judged} of {run.trips} trips, as cevm predict judges them", err=True)
    if run.extrapolating:
        warn(f"{run.extrapolating} duties ask what {vehicle.label}'s calibration did not see (column extrapolation)")
    if o.summary is not None:
        from cevm.io.outputs import write_text

        try:  # whole or not at all, a device written (never replaced); a full disk: exit 3
            write_text(o.summary, json.dumps({k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                                              for k, v in sm.items()}, indent=2) + "\n")
        except CevmError as exc:
            raise fail(exc) from None
    if o.plot is not None and run.fleet.n:
        from cevm.io.replay_plot import plot_duties

        f = run.fleet
        scale = J_PER_KWH if vehicle.is_ev else 1.0
        cap = (vehicle.battery_j if vehicle.is_ev else vehicle.tank_l) / scale
        try:
            plot_duties(o.plot, vehicle=f.vehicle, start_s=f.array("start_s"), energy=f.array("energy") / scale,
                        low=f.array("low") / scale, high=f.array("high") / scale,
                        completes=f.array("completes").astype(bool), usable=settings.soc_start_pct / 100 * cap,
                        above_reserve=(settings.soc_start_pct - settings.reserve_pct) / 100 * cap,
                        unit="kWh" if vehicle.is_ev else "l", title=f"cevm replay: {vehicle.label}")
        except CevmError as exc:
            raise fail(exc, 3) from None
    if o.out is not None and o.fmt != OutputFormat.table:
        typer.echo(f"cevm replay: {sm['duties']} duties -> {o.out}", err=True)
