"""``cevm gtfs``: a timetable's trips and blocks with a candidate vehicle, from the driving
learnt in the fleet's own logs; a thin layer over :mod:`cevm.io.gtfs` (the feed),
:mod:`cevm.core.timetable` (geometry, drive cycles, blocks, duties) and replay's machinery
(:mod:`cevm.core.replay`), rows as :mod:`cevm.cli.gtfs_columns` describes them.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from contextlib import ExitStack
from datetime import UTC, datetime
from pathlib import Path
from types import SimpleNamespace
from typing import Annotated, Any

import numpy as np
import typer

from cevm.cli.columnar import csv_text, json_objects, table_row
from cevm.cli.common import (
    PNG,
    TABLE_MAX_ROWS,
    FormatOption,
    OutOption,
    ReserveOption,
    StoreOption,
    VehicleOption,
    check_common,
    check_output_path,
    fail,
    open_out,
    warn,
)
from cevm.cli.duty_options import build_charging, candidate_vehicle, describe_run
from cevm.cli.gtfs_columns import BLOCKS, BLOCKS_TABLE, TRIPS, TRIPS_TABLE, columns_of
from cevm.cli.output import OutputFormat, write_lines, write_rows
from cevm.core.replay import (
    DEFAULT_CHARGE_EFFICIENCY,
    DEFAULT_CONFIDENCE,
    DEFAULT_DRAWS,
    DEFAULT_INTERVAL,
    DEFAULT_MIN_DWELL_MIN,
    DEFAULT_SEED,
    ReplaySettings,
    central_interval,
    p_complete,
    standard_error,
)
from cevm.core.sweep import DEFAULT_RESERVE_PCT
from cevm.core.timetable.blocks import DEFAULT_DEADHEAD_SPEED_MPS, DEFAULT_DETOUR, DEFAULT_MIN_LAYOVER_S
from cevm.errors import CevmError
from cevm.units import J_PER_KWH

#: Default draws of each trip's synthesised cycle (the synthesis's spread).
DEFAULT_SYNTHESIS_DRAWS = 8


def _depot(text: str | None) -> tuple[float, float] | None:
    if text is None:
        return None
    parts = [p.strip() for p in text.split(",")]
    try:
        lat, lon = (float(p) for p in parts)
    except ValueError:
        raise CevmError(f"--depot {text!r}: give LAT,LON in degrees (e.g. 42.28,-83.74)") from None
    if not (abs(lat) <= 90 and abs(lon) <= 180):
        raise CevmError(f"--depot {text!r}: latitude within 90 and longitude within 180 degrees")
    return lat, lon


def _mass(o: SimpleNamespace, vehicle) -> tuple[float, str]:
    """The candidate's gross mass on every trip, as predict takes it."""
    if o.mass_kg is not None and o.payload_kg is not None:
        raise CevmError("give --mass-kg or --payload-kg, not both")
    if o.mass_kg is not None:
        return float(o.mass_kg), "given (--mass-kg)"
    if o.payload_kg is not None:
        try:
            m = float(vehicle.with_payload(o.payload_kg).mass_kg)
            return m, f"given: {o.payload_kg:g} kg payload (--payload-kg) on kerb_mass_kg"
        except ValueError as exc:
            raise CevmError(str(exc)) from None
    return float(vehicle.mass_kg), "the vehicle file's mass_kg (kerb + default payload)"


def _driving(o: SimpleNamespace, vehicle):
    from cevm.core.timetable.driving import driving_prior
    from cevm.core.timetable.learning import learn_driving

    prior = driving_prior(vehicle.vehicle_class)
    if not o.vehicle_id:
        return prior
    from cevm.store import TripStore, existing_store_path
    from cevm.store.driving import load_driving_series

    with TripStore.open(existing_store_path(o.store), readonly=True) as st:
        known = set(st.vehicle_ids())
        unknown = [v for v in o.vehicle_id if v not in known]
        if unknown:
            raise CevmError(f"no stored trips of vehicle id(s) {', '.join(map(repr, unknown))}; 'cevm trips' "
                            "shows the stored vehicles")
        series = load_driving_series(st, list(dict.fromkeys(o.vehicle_id)))
    return learn_driving(series, prior=prior)


def _settings(o: SimpleNamespace, vehicle) -> ReplaySettings:
    charging = build_charging(vehicle, o.charger_kw, o.min_dwell_min, o.charge_efficiency, o.charge_at, None,
                              200.0, o.overnight, None)
    if charging.depot:
        raise CevmError("--charge-at depot: give the depot's position (--charge-at LAT,LON,RADIUS_M); layovers at "
                        "the depot are where blocks pass by it")
    try:
        return ReplaySettings(rule="given", soc_start_pct=o.soc_start, reserve_pct=o.reserve_pct, charging=charging,
                              interval=o.interval, draws=o.draws, seed=o.seed,
                              battery_step=J_PER_KWH if vehicle.is_ev else 1.0, within_trips=False,
                              size_confidence=o.confidence)
    except ValueError as exc:
        raise CevmError(str(exc)) from None


class _Progress:
    """A progress bar on a terminal's stderr for the trips' cycles (none otherwise)."""

    def __init__(self, total: int):
        self.bar = None
        if sys.stderr.isatty() and total > 50:
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

            self.bar = Progress(TextColumn("gtfs"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                                transient=True)
            self.task = self.bar.add_task("trips", total=total)
            self.bar.start()

    def __call__(self, k: int) -> None:
        if self.bar is not None:
            self.bar.advance(self.task, k)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.stop()


def _ambient(o: SimpleNamespace, vehicle, tt, gm, trip, date, origin, zone) -> tuple[np.ndarray, str]:
    """Each trip instance's temperature at its midpoint, and where it comes from."""
    from cevm.core.vehicle import default_ambient_c

    if o.weather is not None and o.ambient_c is not None:
        raise CevmError("give --weather or --ambient-c, not both")
    if o.ambient_c is not None:
        return np.full(trip.size, float(o.ambient_c)), "given (--ambient-c)"
    if o.weather is not None:
        from cevm.io.gtfs.weather import ambient_at, read_weather

        first, last = gm.first_last(tt)
        mid = origin[date] + 0.5 * (gm.departure_s[first][trip] + gm.arrival_s[last][trip])
        return ambient_at(read_weather(o.weather, zone), mid, str(o.weather)), f"weather file {Path(o.weather).name}"
    t, src = default_ambient_c(vehicle)
    return np.full(trip.size, float(t)), src


def _iso(epoch: np.ndarray, zone) -> list[str]:
    return [datetime.fromtimestamp(float(s), UTC).astimezone(zone).isoformat(timespec="seconds") for s in epoch]


@dataclasses.dataclass
class _Run:
    """What a run computed: the timetable, its trips' geometry and energies, the blocks'
    plans and probabilities, and the rows' shared texts."""

    tt: Any  # Timetable
    gm: Any  # TripGeometry
    sch: Any  # Scheduled
    vehicle: Any  # Vehicle
    settings: ReplaySettings
    zone: Any  # ZoneInfo
    origin: np.ndarray
    plans: list
    probs: list
    infos: list  # per plan, (block name, BlockDay) of each of its duties
    days: dict
    context: dict
    notes: list


def _compute(o: SimpleNamespace) -> _Run:
    """Read the feed, place and synthesise its trips, run its blocks (the command's work)."""
    from zoneinfo import ZoneInfo

    from cevm.core.timetable.blocks import DeadheadRule
    from cevm.core.timetable.duties import block_trips, blocks_by_date, empty_energy, join_blocks, plan_block
    from cevm.core.timetable.schedule import instances, schedule_energies, trip_geometry
    from cevm.io.gtfs import parse_dates, read_feed
    from cevm.io.gtfs.calendar import noon_minus_12h
    from cevm.io.gtfs.elevation import ShapeElevation

    vehicle = candidate_vehicle(o)
    settings = _settings(o, vehicle)
    mass, mass_from = _mass(o, vehicle)
    try:
        rule = DeadheadRule(detour=o.deadhead_detour, speed_mps=o.deadhead_kmh / 3.6, depot=_depot(o.depot))
    except ValueError as exc:
        raise CevmError(str(exc)) from None
    tt = read_feed(o.feed, parse_dates(o.date) if o.date else None)
    zone = ZoneInfo(tt.timezone)
    origin = np.array([noon_minus_12h(d, zone) for d in tt.dates])
    params = _driving(o, vehicle)
    gm = trip_geometry(tt)
    trip, date = instances(tt)
    ambient, ambient_from = _ambient(o, vehicle, tt, gm, trip, date, origin, zone)
    elevation = ShapeElevation(o.dsm)
    progress = _Progress(int(trip.size))
    try:
        sch = schedule_energies(tt, gm, trip, date, ambient, vehicle, params, mass, elevation,
                                draws=o.synthesis_draws, seed=o.seed, progress=progress)
    finally:
        progress.close()
        elevation.close()
    days = blocks_by_date(tt, gm, sch, rule, min_layover_s=60.0 * o.min_layover_min)
    empty_cache: dict = {}

    def empty_run(dist: float, dur: float, amb: float) -> tuple:
        key = (round(dist), round(dur), amb)
        if key not in empty_cache:
            empty_cache[key] = empty_energy(vehicle, dist, dur, amb, mass, params, draws=o.synthesis_draws,
                                            seed=o.seed)
        return empty_cache[key]

    by_name: dict[str, list] = {}
    for bd in days:
        by_name.setdefault(bd.name, []).append(bd)
    for bds in by_name.values():
        bds.sort(key=lambda b: b.date)
    blocks = [block_trips(name, bds, tt, sch, origin, empty_run) for name, bds in by_name.items()]
    names = list(by_name)
    # one run of every block-day (replay's sizing vectorised over them), or with levels
    # carried between a block's dates, one run per block
    groups = [list(range(len(blocks)))] if not settings.charging.chained else [[k] for k in range(len(blocks))]
    plans, probs, infos = [], [], []
    for g in groups:
        plan = plan_block(join_blocks([blocks[k] for k in g]), vehicle, settings)
        plans.append(plan)
        probs.append(p_complete(plan.draw_plan(), settings.draws, settings.seed))
        infos.append([(names[k], bd) for k in g for bd in by_name[names[k]]])
    ctx = describe_run(vehicle, settings, tt.timezone)
    context = {"mass_kg": mass, "mass_from": mass_from, "ambient_from": ambient_from, "driving_from": params.source,
               "charge_places": ctx["charge_places"] if vehicle.is_ev else "nowhere: a diesel refuels overnight",
               "overnight": ctx["overnight"]}
    return _Run(tt, gm, sch, vehicle, settings, zone, origin, plans, probs, infos, by_name, context, list(tt.notes))


def _block_rows(r: _Run) -> tuple[dict, int]:
    """The block rows (one per block and date) as columns."""
    cols: dict[str, list] = {}
    ev = bool(r.vehicle.is_ev)
    unit = J_PER_KWH if ev else 1.0
    for plan, p, info in zip(r.plans, r.probs, r.infos, strict=True):
        by_date = [bd for _, bd in info]
        d = plan.duties
        tr = plan.trips
        revenue = np.array([not t.startswith("(") for t in tr.trip_ids])
        first = d.first
        energy = np.add.reduceat(plan.energies.energy, first)
        lo, hi = central_interval(energy, plan.energy_sd, r.settings.interval)
        lv = plan.levels
        ran_empty = plan.empty_trip >= 0
        pct = 100.0 / plan.capacity
        vals = {
            "block_id": [name for name, _ in info],
            "date": [str(datetime.fromordinal(r.tt.dates[b.date]).date()) for b in by_date],
            "block_from": [b.source for b in by_date],
            "start_time": _iso(tr.start_s[first], r.zone), "end_time": _iso(tr.end_s[d.last], r.zone),
            "trips": np.add.reduceat(revenue.astype(float), first),
            "deadheads": np.add.reduceat((~revenue).astype(float), first),
            "distance_km": np.add.reduceat(tr.distance_m, first) / 1e3,
            "deadhead_km": np.add.reduceat(np.where(revenue, 0.0, tr.distance_m), first) / 1e3,
            ("energy_kwh" if ev else "fuel_l"): energy / unit,
            ("energy_kwh_low" if ev else "fuel_l_low"): lo / unit,
            ("energy_kwh_high" if ev else "fuel_l_high"): hi / unit,
            "soc_start_pct": lv.start * pct, "soc_min_pct": np.maximum(lv.low * pct, 0.0),
            "soc_end_pct": np.where(ran_empty, np.nan, lv.end * pct),
            "tank_min_pct": np.maximum(lv.low * pct, 0.0), "tank_end_pct": np.where(ran_empty, np.nan, lv.end * pct),
            ("charged_kwh" if ev else "refuelled_l"): lv.gained / unit, "charges": lv.charges.astype(float),
            "completes": (lv.low >= plan.reserve).astype(float), "p_complete": p,
            "p_complete_se": standard_error(p, r.settings.draws), "reserve_at_km": plan.reserve_at_m / 1e3,
            ("battery_needed_kwh" if ev else "tank_needed_l"): plan.battery_needed / unit,
            "battery_needed_kwh_conf": plan.battery_needed_conf / unit,
            "charger_needed_kw": np.where(np.isfinite(plan.charger_needed_w), plan.charger_needed_w / 1e3, np.nan),
            "charger_needed_kw_conf": np.where(np.isfinite(plan.charger_needed_w_conf),
                                               plan.charger_needed_w_conf / 1e3, np.nan),
            "ambient_min_c": np.minimum.reduceat(plan.energies.ambient_c, first),
            "ambient_max_c": np.maximum.reduceat(plan.energies.ambient_c, first),
            "deadhead_late_min": np.array([b.legs.late_s.max() / 60.0 for b in by_date]),
            "interval_from": [plan.spread.source] * d.n,
        }
        vals["feasible"] = _verdict(plan, vals["completes"], d.n)
        elev = [sorted({r.sch.elevation_from[i] for i in b.instance[b.instance >= 0].tolist()}) for b in by_date]
        vals["elevation_from"] = ["; ".join(e) for e in elev]
        for k, x in vals.items():
            cols.setdefault(k, []).append(x if not isinstance(x, list) else np.array(x, dtype=object))
    n = sum(p.duties.n for p in r.plans)
    out: dict[str, Any] = {k: (list(np.concatenate(v)) if v and v[0].dtype == object else np.concatenate(v))
                           for k, v in cols.items()}
    c = r.context
    s = r.settings
    out |= {"vehicle_key": r.vehicle.label, "powertrain": r.vehicle.powertrain, "reserve_pct": s.reserve_pct,
            "charger_kw": s.charging.power_w / 1e3, "min_dwell_min": s.charging.min_dwell_s / 60.0,
            "charge_places": c["charge_places"], "overnight": c["overnight"], "mass_kg": c["mass_kg"],
            "mass_from": c["mass_from"], "ambient_from": c["ambient_from"], "driving_from": c["driving_from"]}
    order = np.lexsort((np.array(out["block_id"], dtype=object).astype(str), np.array(out["start_time"],
                                                                                       dtype=object).astype(str),
                        np.array(out["date"], dtype=object).astype(str)))
    out = {k: ([v[i] for i in order] if isinstance(v, list) else (v[order] if np.ndim(v) else v))
           for k, v in out.items()}
    return out, n


def _verdict(plan, completes: np.ndarray, n: int) -> np.ndarray:
    from cevm.core import limits

    limit = plan.vehicle.max_gross_kg
    heaviest = np.maximum.reduceat(plan.energies.mass_kg, plan.duties.first)
    over = np.zeros(n) if limit is None else (heaviest > limit).astype(np.float64)
    nan = np.full(n, np.nan)
    return limits.verdict(is_ev=np.full(n, bool(plan.vehicle.is_ev)), over_max_gross=over, over_power=nan,
                          over_speed=nan, energy_ok=completes)["feasible"]


def _trip_rows(r: _Run) -> tuple[dict, int]:
    """The trip rows (one per trip and date) as columns."""
    tt, sch, gm = r.tt, r.sch, r.gm
    ev = bool(r.vehicle.is_ev)
    unit = J_PER_KWH if ev else 1.0
    block_of = {}
    for name, bds in r.days.items():
        for b in bds:
            for i in b.instance[b.instance >= 0].tolist():
                block_of[i] = name
    lo, hi = central_interval(sch.energy, sch.sd, r.settings.interval)
    first, _ = gm.first_last(tt)
    start = r.origin[sch.date] + gm.departure_s[first][sch.trip]
    m = sch.trip.size
    out = {"trip_id": list(tt.trip_id[sch.trip]), "route_id": list(tt.route_id[sch.trip]),
           "block_id": [block_of.get(k, "") for k in range(m)],
           "date": [str(datetime.fromordinal(tt.dates[d]).date()) for d in sch.date.tolist()],
           "start_time": _iso(start, r.zone), "distance_km": sch.distance_m / 1e3, "duration_s": sch.duration_s,
           "stops": sch.stops, "ascent_m": sch.ascent_m, ("energy_kwh" if ev else "fuel_l"): sch.energy / unit,
           ("energy_kwh_low" if ev else "fuel_l_low"): lo / unit,
           ("energy_kwh_high" if ev else "fuel_l_high"): hi / unit,
           "mass_kg": sch.mass_kg, "ambient_c": sch.ambient_c, "ambient_from": r.context["ambient_from"],
           "cycle_from": list(sch.cycle_from), "stops_from": list(gm.placed[sch.trip]),
           "elevation_from": list(sch.elevation_from)}
    return out, m


def _write(o: SimpleNamespace, spec, table_cols, rows: dict, n: int, ev: bool, title: str, stream) -> None:
    cols = columns_of(spec, rows, n, ev)
    if o.fmt == OutputFormat.csv:
        stream.write(",".join(spec.names) + "\n")
        if n:
            stream.write(csv_text(cols, spec))
    elif o.fmt == OutputFormat.json:
        objs = json_objects(cols, spec, np.full(n, ev)) if n else []
        stream.write("[\n  " + ",\n  ".join(objs) + "\n]\n" if objs else "[]\n")
    else:
        shown = min(n, TABLE_MAX_ROWS)
        table = []
        for i in range(shown):
            row = table_row(cols, spec, i)
            # a verdict in words as every command's table says it (yes / NO)
            table.append({k: ("yes" if v else "NO") if isinstance(v, bool) else v for k, v in row.items()})
        names = [c for c in table_cols if any(t.get(c) is not None for t in table)]
        shown_cols = [dataclasses.replace(spec[c], kind="text") if spec[c].kind == "bool" else spec[c] for c in names]
        write_rows(table, OutputFormat.table, columns=shown_cols,
                   title=title + (f" (first {shown} of {n})" if n > shown else ""), stream=stream)
        if n > shown:
            typer.echo(f"cevm: {n - shown} more rows not shown; use --format csv or json (and --out FILE)", err=True)
    stream.flush()


def _summary(o: SimpleNamespace, r: _Run, rows: dict, n: int) -> list[str]:
    from cevm.core.replay import size_for_share

    ev = bool(r.vehicle.is_ev)
    unit = "kWh" if ev else "l"
    tt = r.tt
    dates = ", ".join(str(datetime.fromordinal(d).date()) for d in tt.dates[:5]) + (" ..." if len(tt.dates) > 5
                                                                                     else "")
    p = np.asarray(rows.get("p_complete", np.zeros(0)), dtype=np.float64)
    completes = np.asarray(rows.get("completes", np.zeros(0)), dtype=np.float64) > 0.5
    inferred = sum(1 for s in rows.get("block_from", []) if s == "inferred")
    lines = [f"{tt.source}: {r.sch.trip.size} trips on {len(tt.dates)} date(s) ({dates}; {tt.date_from}); "
             f"{r.sch.synthesised} distinct drive cycles synthesised",
             f"{n} block-days ({inferred} inferred) with {r.vehicle.label}: {int(completes.sum())} keep the "
             f"{r.settings.reserve_pct:g} % reserve at the mean energies, {int(np.count_nonzero(p >= o.confidence))} "
             f"with a probability of at least {o.confidence:g}"]
    if n:
        need = np.concatenate([pl.battery_needed for pl in r.plans])
        size = size_for_share(need, o.target_share)
        if math.isfinite(size):
            cap = (r.vehicle.battery_j / J_PER_KWH) if ev else r.vehicle.tank_l
            lines.append(f"a usable {'battery' if ev else 'tank'} of {size / (J_PER_KWH if ev else 1):,.0f} {unit} "
                         f"completes {100 * o.target_share:.0f} % of the block-days at the mean energies (the "
                         f"candidate has {cap:,.0f} {unit})")
    lines.append(f"driving: {r.context['driving_from']}; mass: {r.context['mass_kg']:,.0f} kg "
                 f"({r.context['mass_from']}); temperature: {r.context['ambient_from']}")
    return lines


def _say(o: SimpleNamespace, r: _Run, rows: dict, n: int) -> None:
    lines = _summary(o, r, rows, n)
    to_stderr = o.fmt != OutputFormat.table or o.out is not None
    for line in lines:
        if to_stderr:
            typer.echo(f"cevm gtfs: {line}", err=True)
        else:
            write_lines([f"cevm gtfs: {line}"], sys.stdout)
    for note in r.notes:
        typer.echo(f"cevm: note: {note}", err=True)
    if not o.dsm:
        typer.echo("cevm: note: no --dsm: every road is taken as flat (column elevation_from); on hilly routes an "
                   "error of tens of percent", err=True)
    late = np.asarray(rows.get("deadhead_late_min", np.zeros(0)), dtype=np.float64)
    if np.any(late > 0):
        warn(f"{int(np.count_nonzero(late > 0))} block-days have empty running that arrives after the next departure "
             f"at --deadhead-kmh {o.deadhead_kmh:g} (column deadhead_late_min; up to {late.max():.0f} min)")


def _plot(o: SimpleNamespace, r: _Run) -> None:
    from cevm.io.gtfs_plot import plot_blocks

    ev = bool(r.vehicle.is_ev)
    curves = []
    for plan in r.plans:
        d = plan.duties
        for k in range(d.n):
            a, b = int(d.bounds[k]), int(d.bounds[k + 1])
            # each leg from its start to its end, the layover after it flat or charging
            t = np.column_stack([plan.trips.start_s[a:b], plan.trips.end_s[a:b]]).ravel()
            lvl = np.column_stack([plan.before[a:b], plan.after[a:b]]).ravel()
            curves.append((f"{plan.trips.vehicle_id} {datetime.fromtimestamp(float(t[0]), UTC).date()}", t,
                           100.0 * lvl / plan.capacity, bool(plan.levels.low[k] >= plan.reserve)))
    try:
        plot_blocks(o.plot, curves, reserve_pct=r.settings.reserve_pct, zone=r.zone,
                    what="state of charge" if ev else "tank", title=f"cevm gtfs: {r.vehicle.label}")
    except CevmError as exc:
        raise fail(exc, 3) from None


def gtfs_cmd(
    feed: Annotated[Path, typer.Argument(metavar="FEED", help="The GTFS feed: a .zip or a folder of .txt files.")],
    vehicle: VehicleOption,
    dsm: Annotated[Path | None, typer.Option(metavar="FILE|DIR", help="Elevation (a DSM, as ingest takes it) along "
                                             "the shapes. Default: flat, said in every row.")] = None,
    date: Annotated[list[str] | None, typer.Option("--date", metavar="YYYY-MM-DD[:YYYY-MM-DD]", help="Service "
                                                   "date(s), or a range. Repeatable. Default: the first weekday of "
                                                   "the feed with the most trips (said).")] = None,
    weather: Annotated[Path | None, typer.Option(metavar="CSV", help="Temperatures: columns time (ISO 8601; "
                                                 "without offset, in the feed's time zone) and ambient_c, "
                                                 "interpolated at each trip's midpoint.")] = None,
    ambient_c: Annotated[float | None, typer.Option(help="One ambient temperature for every trip [degC]. Default: "
                                                    "the vehicle's reference_temp_c.")] = None,
    store: StoreOption = None,
    vehicle_id: Annotated[list[str] | None, typer.Option("--vehicle-id", metavar="ID", help="Learn the driving "
                                                         "between stops from these vehicles' stored trips. "
                                                         "Repeatable. Default: the class prior.")] = None,
    trips: Annotated[bool, typer.Option("--trips", help="Rows per trip and date instead of per block.")] = False,
    mass_kg: Annotated[float | None, typer.Option(help="The candidate's gross mass on every trip [kg].")] = None,
    payload_kg: Annotated[float | None, typer.Option(help="Payload on the candidate's kerb mass [kg].")] = None,
    min_layover_min: Annotated[float, typer.Option(help="Shortest layover when chaining trips without block_id into "
                                                   "blocks [min].")] = DEFAULT_MIN_LAYOVER_S / 60.0,
    deadhead_detour: Annotated[float, typer.Option(help="Empty running's road over the straight line (default 1.3: "
                                                   "road networks' circuity).")] = DEFAULT_DETOUR,
    deadhead_kmh: Annotated[float, typer.Option(help="Empty running's mean speed [km/h].")] = (
        DEFAULT_DEADHEAD_SPEED_MPS * 3.6),
    depot: Annotated[str | None, typer.Option(metavar="LAT,LON", help="The depot: a pull-out to each block's first "
                                              "stop and a pull-in from its last.")] = None,
    soc_start: Annotated[float, typer.Option("--soc-start", help="Level at each block's start [%].")] = 100.0,
    reserve_pct: ReserveOption = DEFAULT_RESERVE_PCT,
    charger_kw: Annotated[float | None, typer.Option(help="Charger at the layovers [kW] (EV; default none).")] = None,
    min_dwell_min: Annotated[float, typer.Option(help="Shortest layover that charges [min].")] = DEFAULT_MIN_DWELL_MIN,
    charge_efficiency: Annotated[float, typer.Option(help="Grid to battery.")] = DEFAULT_CHARGE_EFFICIENCY,
    charge_at: Annotated[list[str] | None, typer.Option(metavar="LAT,LON,RADIUS_M", help="Charge only at layovers "
                                                        "here. Repeatable. Default: any layover.")] = None,
    overnight: Annotated[str | None, typer.Option(help="Between a block's dates: 'full' (default) or 'none'.")] = None,
    battery_kwh: Annotated[float | None, typer.Option(help="The candidate's usable battery instead of its "
                                                      "file's [kWh].")] = None,
    interval: Annotated[float, typer.Option(help="Interval of the energies.")] = DEFAULT_INTERVAL,
    confidence: Annotated[float, typer.Option(help="A block counts as completed in the summary at this "
                                              "probability.")] = DEFAULT_CONFIDENCE,
    target_share: Annotated[float, typer.Option(help="Share of block-days the sized battery completes.")] = 0.95,
    draws: Annotated[int, typer.Option(min=1, help="Monte Carlo draws per block.")] = DEFAULT_DRAWS,
    synthesis_draws: Annotated[int, typer.Option(min=1, help="Draws of each trip's synthesised cycle (the "
                                                 "synthesis's spread).")] = DEFAULT_SYNTHESIS_DRAWS,
    seed: Annotated[int, typer.Option(help="Seed of the draws.")] = DEFAULT_SEED,
    store_route: Annotated[list[str] | None, typer.Option(metavar="BLOCK[=NAME]", help="Store a block (on the first "
                                                          "date) as a route in --store, for feasibility and fleet "
                                                          "plan. Repeatable.")] = None,
    fmt: FormatOption = OutputFormat.table,
    out: OutOption = None,
    plot: Annotated[Path | None, typer.Option(metavar="FILE.png", help="Write a PNG: each block's state of charge "
                                              "through the day.")] = None,
) -> None:
    """A GTFS timetable's blocks (or trips) with a candidate vehicle.

    Each trip running on the dates asked gets a drive cycle synthesised from its stop
    times along its shape (the driving learnt from --vehicle-id's stored trips, else the
    vehicle class's prior), its energy and interval from the candidate's model; each block
    (block_id, else trips chained) on each date is run as replay runs a duty: the level
    carried from trip to trip, charged at long layovers, the reserve, p_complete, the
    battery and charger it needs."""
    o = SimpleNamespace(**locals())
    check_common(None, soc_start, reserve_pct)
    check_output_path(out, "--out")
    check_output_path(plot, "--plot", PNG)
    for name, value in (("--interval", interval), ("--confidence", confidence), ("--target-share", target_share)):
        if not 0 < value < 1 and not (name != "--interval" and value == 1):
            raise fail(f"{name} {value:g} must be in (0, 1)")
    if not min_layover_min >= 0:
        raise fail(f"--min-layover-min {min_layover_min:g} must be >= 0")
    try:
        r = _compute(o)
        with ExitStack() as stack:
            stream = open_out(stack, out)
            if trips:
                rows, n = _trip_rows(r)
                _write(o, TRIPS, TRIPS_TABLE, rows, n, bool(r.vehicle.is_ev), "cevm gtfs: trips", stream)
            brows, bn = _block_rows(r)
            if not trips:
                _write(o, BLOCKS, BLOCKS_TABLE, brows, bn, bool(r.vehicle.is_ev), "cevm gtfs: blocks", stream)
        _say(o, r, brows, bn)
        if plot is not None and bn:
            _plot(o, r)
        if store_route:
            _store_routes(o, r)
    except CevmError as exc:
        raise fail(exc) from None


def _store_routes(o: SimpleNamespace, r: _Run) -> None:
    """``--store-route BLOCK[=NAME]``: the block's legs on its first date stored as cycle
    legs of a route (their synthesised drive cycles, the representative draw's seed), so
    that feasibility and fleet plan take it as any route."""
    from cevm.core.timetable.routes import block_cycles
    from cevm.store import TripStore
    from cevm.store.location import resolve_store_path
    from cevm.store.routes import CycleLeg, add_route, check_route_name

    wanted = []
    for spec in o.store_route:
        block, _, name = spec.partition("=")
        name = name or f"gtfs-{block}"
        check_route_name(name)
        if block not in r.days:
            raise CevmError(f"--store-route {spec!r}: no block {block!r} on the dates run (the rows' block_id)")
        wanted.append((block, name))
    from cevm.core.timetable.driving import driving_prior

    params = driving_prior(r.vehicle.vehicle_class) if not o.vehicle_id else _driving(o, r.vehicle)
    with TripStore.open(resolve_store_path(o.store)) as st:
        for block, name in wanted:
            bd = min(r.days[block], key=lambda b: b.date)
            cycles = block_cycles(r.tt, r.gm, r.sch, bd, params, seed=o.seed)
            legs = [CycleLeg(cycle=c, ref=f"gtfs:{Path(o.feed).name}#{c.name}") for c in cycles]
            add_route(st, name, legs, replace=True, note=f"cevm gtfs {Path(o.feed).name}: block {block} on "
                      f"{datetime.fromordinal(r.tt.dates[bd.date]).date()} ({params.source})")
            typer.echo(f"cevm gtfs: block {block} stored as route {name!r} ({len(legs)} legs) in the store", err=True)
