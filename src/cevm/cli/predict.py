"""``cevm predict``: energy or fuel for every source x vehicle x mass, a thin layer over
:mod:`cevm.core.sweep` (sources from :mod:`cevm.store.sources`).

Output of ``predict`` (one row per source x vehicle x mass, source-major), its columns
as :data:`cevm.cli.prediction_columns.PREDICT` describes them (each column's meaning,
unit, kind, and which powertrains' rows have it):

- JSON: a streamed array of objects, each with the keys of its row's powertrain; the
  contract of the first ``cevm predict`` first (``cycle``, ``vehicle``, ``powertrain``,
  ``mass_kg``, ``distance_km``, ``duration_s``, ``wheel_energy_kwh``, then EV rows
  ``energy_kwh``, ``energy_kwh_per_km`` and ICE rows ``fuel_l``, ``fuel_l_per_100km``,
  ``ice_braking``), then the others in CSV order. Numbers in full precision, null where
  a row has no value.
- CSV: every column, written in blocks with each column's fixed decimals (1 g, 1 mm,
  1 ms, 3.6 J, 1 ul, 1e-6 %), trailing zeros dropped; empty cells where a column does
  not apply (:mod:`cevm.cli.columnar`).
- table: for people, at most :data:`TABLE_MAX_ROWS` rows of the columns of
  :data:`cevm.cli.prediction_columns.PREDICT_TABLE` that have a value.
"""

from __future__ import annotations

from collections import Counter
from contextlib import ExitStack
from dataclasses import replace
from pathlib import Path
from typing import IO, Annotated, Any

import numpy as np
import typer

from cevm.cli.columnar import concat_columns, csv_text, json_objects
from cevm.cli.common import (
    EXIT_PARTIAL,
    PNG,
    SOC_FROM_DEFAULT,
    TABLE_MAX_ROWS,
    AmbientOption,
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
    check_workers,
    fail,
    load_sources,
    note_flat_cycles,
    open_out,
    say_prior_values,
    start_soc,
    warn_ambient_unused,
    warn_damaged,
    with_cycle_options,
)
from cevm.cli.output import OutputFormat, vehicle_legend, write_lines, write_rows
from cevm.cli.prediction_columns import (
    INTERVAL_TEXT,
    PREDICT,
    PREDICT_TABLE,
    PREDICT_TABLE_DROP,
    PREDICT_TABLE_KEEP,
    STATUS,
    BlockRows,
    RangeOptions,
    assumptions_line,
    interval_text,
    legend_name,
    verdict_text,
)
from cevm.cli.values import parse_value_options
from cevm.core.cycle import CR0_DEFAULT
from cevm.core.sweep import (
    AMBIENT_ORIGINS,
    DEFAULT_RESERVE_PCT,
    DEFAULT_SOC_START_PCT,
    PredictionSet,
    SweepBlock,
    sweep,
)
from cevm.errors import CevmError
from cevm.io.plots import PLOT_MAX_LINES, plot_predictions
from cevm.runtime import WHOLE_CYCLE_MMAP_THRESHOLD_BYTES, tune_allocator
from cevm.units import J_PER_KWH

#: Rows formatted at once when writing CSV or JSON.
WRITE_BATCH_ROWS = 32768


# --------------------------------------------------------------------------- writers


class PredictWriter:
    """Streams predict blocks as CSV, JSON or a (bounded) table, with the columns of
    :data:`~cevm.cli.prediction_columns.PREDICT`."""

    def __init__(self, fmt: OutputFormat, stream: IO[str], temperature_used: bool = False,
                 options: RangeOptions | None = None):
        self.fmt = fmt
        self.stream = stream
        self.options = options or RangeOptions()
        self.temperature_used = temperature_used
        self.pending: list[tuple[SweepBlock, str, str]] = []
        self.pending_rows = 0
        self.rows = 0
        self.table_rows: list[dict] = []
        self.names: dict[str, tuple[str, str | None]] = {}
        self.started = False

    def add(self, block: SweepBlock, mass_source: str = "vehicle file", soc_from: str = SOC_FROM_DEFAULT) -> None:
        self.rows += block.n
        if self.fmt == OutputFormat.table:
            if len(self.table_rows) < TABLE_MAX_ROWS:
                self._table_add(block, mass_source, soc_from)
            return
        self.pending.append((block, mass_source, soc_from))
        self.pending_rows += block.n
        if self.pending_rows >= WRITE_BATCH_ROWS:
            self._flush()

    def _flush(self) -> None:
        if not self.pending:
            return
        cols = concat_columns([PREDICT.values(BlockRows(b, m, self.options, f)) for b, m, f in self.pending])
        is_ev = np.concatenate([b.pset.is_ev for b, _, _ in self.pending])
        self.pending, self.pending_rows = [], 0
        for lo in range(0, is_ev.size, WRITE_BATCH_ROWS):  # bounded memory for huge blocks
            sl = slice(lo, lo + WRITE_BATCH_ROWS)
            part = {k: ((c[0][sl], c[1]) if isinstance(c, tuple) else c[sl]) for k, c in cols.items()}
            if self.fmt == OutputFormat.csv:
                if not self.started:
                    self.stream.write(",".join(PREDICT.names) + "\n")
                self.stream.write(csv_text(part, PREDICT))
            else:
                rows = json_objects(part, PREDICT, is_ev[sl])
                self.stream.write(("[\n  " if not self.started else ",\n  ") + ",\n  ".join(rows))
            self.started = True

    def _table_add(self, block: SweepBlock, mass_source: str, soc_from: str) -> None:
        cols = PREDICT.values(BlockRows(block, mass_source, self.options, soc_from))
        n = min(block.n, TABLE_MAX_ROWS - len(self.table_rows))
        for i in range(n):
            row: dict[str, Any] = {}
            for column in PREDICT.columns:
                k = column.name
                c = cols[k]
                if isinstance(c, tuple):
                    row[k] = c[1][int(c[0][i])] or None
                else:
                    x = float(c[i])
                    row[k] = None if x != x else (x > 0.5 if column.kind == "bool" else x)
            self.table_rows.append(with_status(row))
            self.names[row["vehicle_key"]] = (legend_name(row), row.get("ice_braking"))

    def close(self) -> None:
        if self.fmt == OutputFormat.table:
            rows = self.table_rows
            columns = [c for c in PREDICT_TABLE if any(r.get(c) is not None for r in rows)]
            if "error_pct" in columns:  # measured beside modelled: the per-km figures only in csv and json
                columns = [c for c in columns if c not in ("energy_kwh_per_km", "fuel_l_per_100km")]
            else:  # at masses given for every source the measurement is no comparison: csv and json only
                columns = [c for c in columns if c not in ("measured_energy_kwh", "measured_fuel_l")]
            if "energy_kwh" in columns and "fuel_l" in columns:  # EV and ICE rows: room for the intervals
                columns = [c for c in columns if c not in ("energy_kwh_per_km", "fuel_l_per_100km")]
            assumed, soc_varies = assumptions_line(rows)
            if not soc_varies and "soc_start_pct" in columns:  # one start for every row: said under the table
                columns.remove("soc_start_pct")
            if self.temperature_used:
                columns.insert(3, "ambient_c")
            title = "cevm predict" + (f" (first {len(rows)} of {self.rows} rows)" if self.rows > len(rows) else "")
            level = next((r["interval"] for r in rows if r.get("interval") is not None), None)
            shown = replace(INTERVAL_TEXT, header=f"+- ({100 * level:g} %)") if level else INTERVAL_TEXT
            write_rows(rows, OutputFormat.table, columns=PREDICT.table(columns, STATUS, shown), title=title,
                       stream=self.stream, keep=PREDICT_TABLE_KEEP, drop_order=PREDICT_TABLE_DROP)
            write_lines([vehicle_legend(self.names), assumed], self.stream)
            self.stream.flush()
            if self.rows > len(rows):
                typer.echo(f"cevm: {self.rows - len(rows)} more rows not shown; use --format csv or json "
                           "(and --out FILE)", err=True)
            return
        self._flush()
        if self.fmt == OutputFormat.csv:
            if not self.started:
                self.stream.write(",".join(PREDICT.names) + "\n")
        else:
            self.stream.write("\n]\n" if self.started else "[]\n")
        self.stream.flush()


# -------------------------------------------------------------------- assumptions


class Assumptions:
    """What the predictions of a sweep assumed, per vehicle, gathered block by block:
    the ambient temperatures (and where they came from) and the sources' mean speeds;
    :meth:`lines` says them, with a warning for each vehicle asked outside what its
    calibration saw (:func:`cevm.core.vehicle.domain_warnings`)."""

    def __init__(self, pset: PredictionSet):
        self.pset = pset
        nv = len(pset.vehicles)
        self.t_lo = np.full(nv, np.inf)
        self.t_hi = np.full(nv, -np.inf)
        self.v_lo = np.inf
        self.v_hi = -np.inf
        self.i_lo = np.inf  # the sources' share of time at standstill (their duty)
        self.i_hi = -np.inf
        self.origins: list[set] = [set() for _ in range(nv)]
        self.m_lo = np.full(nv, np.inf)
        self.m_hi = np.full(nv, -np.inf)

    def add(self, block: SweepBlock) -> None:
        vi = block.pset.vehicle_index  # a stored trip's block has a set at its own mass
        np.minimum.at(self.m_lo, vi, block.pset.mass_kg)
        np.maximum.at(self.m_hi, vi, block.pset.mass_kg)
        np.minimum.at(self.t_lo, vi, block.ambient_c)
        np.maximum.at(self.t_hi, vi, block.ambient_c)
        for v, code in set(zip(vi.tolist(), block.ambient_from.astype(int).tolist(), strict=True)):
            self.origins[v].add(AMBIENT_ORIGINS[code])
        src = block.source
        if src.duration_s > 0:
            speed = src.distance_m / src.duration_s
            self.v_lo, self.v_hi = min(self.v_lo, speed), max(self.v_hi, speed)
            idle = src.vector.idle_s / src.duration_s
            self.i_lo, self.i_hi = min(self.i_lo, idle), max(self.i_hi, idle)

    def lines(self) -> list[str]:
        from cevm.core.energy import uses_temperature
        from cevm.core.vehicle import domain_warnings

        out = []
        for v, veh in enumerate(self.pset.vehicles):
            if not np.isfinite(self.t_lo[v]):
                continue
            lo, hi = self.t_lo[v], self.t_hi[v]
            if uses_temperature(veh):
                span = f"{lo:.1f}" if lo == hi else f"{lo:.1f} to {hi:.1f}"
                out.append(f"cevm: note: {veh.name}: ambient {span} degC ({', '.join(sorted(self.origins[v]))})")
            masses = np.array([self.m_lo[v], self.m_hi[v]])
            speeds = np.array([self.v_lo, self.v_hi]) if np.isfinite(self.v_lo) else None
            idle = np.array([self.i_lo, self.i_hi]) if np.isfinite(self.i_lo) else None
            out.extend(f"cevm: warning: {w}"
                       for w in domain_warnings(veh, mass_kg=masses, ambient_c=np.array([lo, hi]),
                                                mean_speed_mps=speeds, idle_share=idle))
        return out

def _count_flags(block: SweepBlock) -> np.ndarray:
    """How many rows of a block run empty on the way, ask too much power, ask too much
    speed."""
    def flagged(a: np.ndarray | None) -> int:
        return 0 if a is None else int(np.count_nonzero(a == 1.0))

    empty = 0 if block.empty_at_m is None else int(np.count_nonzero(np.isfinite(block.empty_at_m)))
    return np.array([empty, flagged(block.over_power), flagged(block.over_speed)])


def with_status(row: dict) -> dict:
    """A table row with its 'status': the verdict (column feasible) and why
    (:func:`cevm.cli.prediction_columns.verdict_text`), and its interval as text."""
    row["status"] = verdict_text(row)
    row["interval_text"] = interval_text(row)
    return row


# ------------------------------------------------------------------------ masses


def _mass_runs(sources, pset: PredictionSet, vehicles, masses, payloads, ice_braking, ambient_c):
    """(sources, prediction set, mass_source) runs: every source at the given masses, or
    each stored trip at its own (:func:`cevm.store.sources.mass_runs`), the rest at each
    vehicle's mass_kg."""
    if masses is not None or payloads is not None:
        return [(sources, pset, "--mass-kg" if masses is not None else "--payload-kg")]
    if not any(src.kind == "trip" for src in sources):
        return [(sources, pset, "vehicle file")]
    from cevm.store.sources import mass_runs

    def build(**mass) -> PredictionSet:
        return PredictionSet.build(vehicles, ice_braking=ice_braking, ambient_c=ambient_c, **mass) if mass else pset

    return mass_runs(sources, build)


def _soc_runs(sources, given: float | None):
    """(sources, start state of charge [%], where it comes from) runs of consecutive
    sources that start at the same state of charge (:func:`cevm.cli.common.start_soc`:
    --soc-start, else a stored trip's logged start, else full)."""
    runs: list[tuple[list, float, str]] = []
    for src in sources:
        soc, origin = start_soc(src, given)
        if runs and runs[-1][1] == soc and runs[-1][2] == origin:
            runs[-1][0].append(src)
        else:
            runs.append(([src], soc, origin))
    return runs


def _mass_lines(sources, used: Counter) -> list[str]:
    """A note on the masses the stored trips were predicted at, and a warning for the
    given masses that disagree with the logged gross weights."""
    if not used:
        return []
    counts = ", ".join(f"{n} {what}" for what, n in sorted(used.items(), key=lambda kv: (-kv[1], kv[0])))
    out = [f"cevm: note: stored trips' masses: {counts} (column mass_source)"]
    off = [t for t in (getattr(src, "mass", None) for src in sources) if t is not None and t.disagreement()]
    if off:
        out.append(f"cevm: warning: {len(off)} trip(s) have a given mass more than 5 % from their logged gross weight "
                   f"(the given one is used), e.g. {off[0].disagreement()}")
    return out


# ---------------------------------------------------------------------------- predict


@with_cycle_options
def predict_cmd(
    vehicle: VehicleOption,
    cycle: CycleOption = None,
    trip: TripOption = None,
    vehicle_id: VehicleIdOption = None,
    route: RouteOption = None,
    store: StoreOption = None,
    mass_kg: Annotated[
        list[str] | None,
        typer.Option("--mass-kg", "-m", metavar="KG",
                     help="Gross mass in kg: a value, a list a,b or a range start:stop:step "
                          "(stop included). Repeatable. Default: each vehicle's mass_kg."),
    ] = None,
    payload_kg: Annotated[
        list[str] | None,
        typer.Option("--payload-kg", "-p", metavar="KG",
                     help="Payload in kg on each vehicle's kerb mass: a value, a list or a "
                          "range such as 0:26000:2000 (14 values, stop included). Repeatable."),
    ] = None,
    soc_start: SocStartOption = None,
    reserve_pct: ReserveOption = DEFAULT_RESERVE_PCT,
    interval: IntervalOption = 0.9,
    fmt: FormatOption = OutputFormat.table,
    out: OutOption = None,
    plot: Annotated[
        Path | None,
        typer.Option(metavar="FILE.png",
                     help="Write a PNG: state of charge along each source (one mass per vehicle), or energy "
                          "against payload (a mass sweep)."),
    ] = None,
    ice_braking: IceBrakingOption = None,
    ambient_c: AmbientOption = None,
    cr0: Cr0Option = CR0_DEFAULT,
    with_range: Annotated[
        bool, typer.Option("--range", help="Add each row's range: the distance to empty (range_km) and to the "
                                           "reserve (range_reserve_km, EV), with the source driven again and again "
                                           "without recharging or refuelling. One step-by-step sum per row "
                                           "(about 10x the time of a sweep without it).")
    ] = False,
    workers: Annotated[
        int | None,
        typer.Option("--workers", "-w", min=1, metavar="N",
                     help="Worker processes, a batch of sources per task "
                          "(default 1: in this process; a large sweep of many routes runs ~1.3x faster "
                          "on 2 cores, a small one is slower for the processes' start).")
    ] = None,
    scheduler: Annotated[
        str | None, typer.Option(help="Dask scheduler address (tcp://HOST:8786): evaluate the batches on that "
                                         "cluster (pip install 'cevm[dask]'). Sources are read here and sent.")
    ] = None,
    cycle_fmt=None,
) -> None:
    """Predict energy (EV) or fuel (ICE) for every source x vehicle x mass.

    Sources are cycle files (--cycle), stored trips (--trip, --vehicle-id) and stored
    routes (--route); the 'cycle' column names each (a cycle file's stem, and with
    --speed-col its column: 'trucks[Long haul, 26t]'). EV rows give the state of charge at
    the end and at its lowest along the way, from --soc-start and the battery, and
    whether it stays above --reserve-pct, and where it first crosses the reserve or runs
    empty (never a state of charge below 0); ICE rows whether the fuel fits tank_l, and
    where the tank runs dry. --range adds the range. Masses above max_gross_kg are kept
    and flagged (over_max_gross); a source that asks more than a vehicle's max_power_kw
    or max_speed_kmh is flagged (over_power, over_speed). Every row says the ambient
    temperature it assumed (ambient_c, ambient_from); a prediction outside what a
    calibrated vehicle was fitted on (temperature, mass, duty) is warned about."""
    if not (cycle or trip or vehicle_id or route):
        raise fail("give at least one source: --cycle, --trip, --vehicle-id or --route")
    tune_allocator(WHOLE_CYCLE_MMAP_THRESHOLD_BYTES)  # arrays of a cycle's length reused, not mapped anew
    if mass_kg and payload_kg:
        raise fail("give --mass-kg or --payload-kg, not both")
    if workers is not None and scheduler is not None:
        raise fail("give --workers (local processes) or --scheduler (a Dask cluster), not both")
    check_workers(workers)
    check_common(ice_braking, soc_start, reserve_pct, interval)
    check_output_path(out, "--out")
    check_output_path(plot, "--plot", PNG)
    try:
        masses = parse_value_options(mass_kg, "--mass-kg")
        payloads = parse_value_options(payload_kg, "--payload-kg")
        from cevm.io import load_vehicles

        vehicles = load_vehicles(vehicle)
        from cevm.core.energy import uses_temperature

        pset = PredictionSet.build(vehicles, mass_kg=masses, payload_kg=payloads, ice_braking=ice_braking,
                                   ambient_c=ambient_c)
        assumed = Assumptions(pset)
        skipped: list[CevmError] = []  # damaged stored trips of --vehicle-id, left out
        with ExitStack() as stack:
            sources = load_sources(stack, store, cycle or [], trip or [], vehicle_id or [], route or [], cr0,
                                   cycle_fmt, need_profiles=any(v.is_ev for v in vehicles),
                                   on_damaged=skipped.append)
            note_flat_cycles(sources)
            executor = None  # in this process: the executors are not even imported
            if scheduler is not None or (workers or 1) > 1:
                from cevm.executors import make_executor

                executor = stack.enter_context(make_executor(None if scheduler else workers, scheduler))
            stream = open_out(stack, out)
            writer = PredictWriter(fmt, stream, temperature_used=any(uses_temperature(v) for v in vehicles),
                                   options=RangeOptions(interval,
                                                        DEFAULT_SOC_START_PCT if soc_start is None else soc_start,
                                                        reserve_pct))
            keep_for_plot = plot is not None and np.bincount(pset.vehicle_index).max() > 1
            flagged = np.zeros(3, dtype=np.int64)
            plot_data: list[dict] = []
            psets: list[PredictionSet] = []
            over, used = 0, Counter[str]()

            def yield_block(block: SweepBlock, run_pset: PredictionSet, mass_source: str, soc_from: str) -> None:
                nonlocal flagged, over
                flagged += _count_flags(block)
                writer.add(block, mass_source, soc_from)
                assumed.add(block)
                over += int(run_pset.over_max_gross.sum())
                if block.source.kind == "trip":
                    used[mass_source] += 1
                if keep_for_plot and len(psets) < PLOT_MAX_LINES:
                    plot_data.append({"energy_kwh": block.energy_j / J_PER_KWH, "fuel_l": block.fuel_l})
                psets.append(run_pset)
                if plot is None:
                    block.source.release()  # free its profile: the sweep is past it

            socs: dict[str, float] = {}
            for run, run_pset, mass_source in _mass_runs(sources, pset, vehicles, masses, payloads, ice_braking,
                                                         ambient_c):
                for group, soc, soc_from in _soc_runs(run, soc_start):
                    socs.update((src.name, soc) for src in group)
                    for block in sweep(group, run_pset, soc_start_pct=soc, reserve_pct=reserve_pct,
                                       executor=executor, ranges=with_range):
                        yield_block(block, run_pset, mass_source, soc_from)
            writer.close()
            if plot is not None:
                plot_predictions(plot, sources, pset if keep_for_plot else psets, plot_data,
                                 [socs.get(src.name, DEFAULT_SOC_START_PCT) for src in sources], reserve_pct,
                                 ice_braking, warn=lambda message: typer.echo(message, err=True))
    except CevmError as exc:
        raise fail(exc) from None
    for line in assumed.lines():
        typer.echo(line, err=True)
    say_prior_values(vehicles)
    if ambient_c is not None:
        warn_ambient_unused([(v.label, uses_temperature(v)) for v in vehicles], f"--ambient-c {ambient_c:g}")
    for line in _mass_lines(sources, used):
        typer.echo(line, err=True)
    if used and masses is None and payloads is None:  # stored trips at their own masses
        from cevm.store.sources import foreign_mass_warnings

        for w in foreign_mass_warnings(sources, vehicles):
            typer.echo(f"cevm: warning: {w}", err=True)
    if over:
        typer.echo(f"cevm: warning: {over} predictions exceed their vehicle's max_gross_kg (column over_max_gross)",
                   err=True)
    for n_rows, what in zip(flagged.tolist(), ("run empty on the way (columns empty_at_km, empty_at_s)",
                                                "ask more wheel power than their vehicle's max_power_kw (column "
                                                "over_power)", "ask more speed than their vehicle's max_speed_kmh "
                                                "(column over_speed)"), strict=True):
        if n_rows:
            typer.echo(f"cevm: warning: {n_rows} predictions {what}", err=True)
    if out is not None and fmt != OutputFormat.table:
        typer.echo(f"cevm predict: {writer.rows} rows -> {out}", err=True)
    for problem in skipped:
        warn_damaged(problem)
    if skipped:
        raise typer.Exit(EXIT_PARTIAL)

