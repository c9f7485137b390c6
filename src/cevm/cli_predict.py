"""``cevm predict``, ``cevm feasibility`` and ``cevm route``: fleet decisions on the command
line, a thin layer over :mod:`cevm.core.sweep` and :mod:`cevm.store.routes`.

Registered on :data:`cevm.cli.app` when :mod:`cevm.cli` imports this module.

Output of ``predict`` (one row per source x vehicle x mass, source-major):

- JSON: a streamed array of objects. Every row has ``cycle`` (the source's name: file
  stem, trip id or route name), ``vehicle``, ``powertrain``, ``mass_kg``,
  ``distance_km``, ``duration_s``, ``wheel_energy_kwh``, then EV rows ``energy_kwh``,
  ``energy_kwh_per_km`` and ICE rows ``fuel_l``, ``fuel_l_per_100km``, ``ice_braking``
  (the contract of the first ``cevm predict``), and after them ``source_kind``,
  ``payload_kg``, ``over_max_gross``, EV: ``soc_end_pct``, ``soc_min_pct``,
  ``reserve_ok``; ICE: ``tank_ok`` (null without ``tank_l``). Numbers in full precision.
- CSV: the same columns, the contract's first, written in blocks with fixed decimals
  (see :data:`CSV_DECIMALS`: 1 g, 1 mm, 1 ms, 3.6 J, 1 ul, 1e-6 %), trailing zeros
  dropped; empty cells where a column does not apply.
- table: for people, at most :data:`TABLE_MAX_ROWS` rows.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import sys
from collections.abc import Sequence
from contextlib import ExitStack
from pathlib import Path
from typing import IO, Annotated, Optional

import numpy as np
import typer

from cevm.cli import StoreOption, _existing_store, _fail, app
from cevm.core.cycle import CR0_DEFAULT
from cevm.errors import CevmError
from cevm.store.sources import load_sources
from cevm.core.sweep import (
    DEFAULT_RESERVE_PCT,
    DEFAULT_SOC_START_PCT,
    PredictionSet,
    Source,
    SweepBlock,
    energy_trajectory,
    parse_values,
    sweep,
)
from cevm.core.feasibility import Feasibility, feasibility
from cevm.core.model import ICE_BRAKING_MODES
from cevm.executors import make_executor
from cevm.report import OutputFormat, write_rows
from cevm.units import J_PER_KWH

#: Rows printed by ``--format table``; beyond that, use csv or json.
TABLE_MAX_ROWS = 200
#: Rows formatted at once when writing CSV or JSON.
WRITE_BATCH_ROWS = 32768
#: Lines drawn at most by ``--plot`` (one per source and vehicle).
PLOT_MAX_LINES = 12

#: Decimals of the numeric CSV columns of ``predict``.
CSV_DECIMALS = {
    "mass_kg": 3, "payload_kg": 3, "distance_km": 6, "duration_s": 3, "wheel_energy_kwh": 6, "energy_kwh": 6,
    "energy_kwh_per_km": 6, "fuel_l": 6, "fuel_l_per_100km": 6, "soc_end_pct": 6, "soc_min_pct": 6,
}
#: Columns of ``predict`` in CSV order: the first contract's, then the new ones.
PREDICT_COLUMNS = (
    "cycle", "vehicle", "mass_kg", "distance_km", "duration_s", "wheel_energy_kwh", "energy_kwh", "energy_kwh_per_km",
    "fuel_l", "fuel_l_per_100km", "source_kind", "powertrain", "payload_kg", "over_max_gross", "soc_end_pct",
    "soc_min_pct", "reserve_ok", "tank_ok", "ice_braking",
)
_EV_KEYS = ("cycle", "vehicle", "powertrain", "mass_kg", "distance_km", "duration_s", "wheel_energy_kwh",
            "energy_kwh", "energy_kwh_per_km", "source_kind", "payload_kg", "over_max_gross", "soc_end_pct",
            "soc_min_pct", "reserve_ok")
_ICE_KEYS = ("cycle", "vehicle", "powertrain", "mass_kg", "distance_km", "duration_s", "wheel_energy_kwh",
             "fuel_l", "fuel_l_per_100km", "ice_braking", "source_kind", "payload_kg", "over_max_gross", "tank_ok")
_TEXT = {"cycle", "vehicle", "source_kind", "powertrain", "ice_braking"}
_BOOL = {"over_max_gross", "reserve_ok", "tank_ok"}

PREDICT_HEADERS = {
    "mass_kg": "mass kg", "payload_kg": "payload kg", "distance_km": "km", "duration_s": "s",
    "wheel_energy_kwh": "wheel kWh", "energy_kwh": "battery kWh", "energy_kwh_per_km": "kWh/km", "fuel_l": "fuel l",
    "fuel_l_per_100km": "l/100km", "soc_end_pct": "SoC end %", "soc_min_pct": "SoC min %",
    "reserve_ok": "reserve ok", "tank_ok": "tank ok", "over_max_gross": "over max gross",
    "status": "reserve / tank ok",
}
PREDICT_DIGITS = {"mass_kg": 0, "payload_kg": 0, "duration_s": 0, "distance_km": 2, "wheel_energy_kwh": 2,
                  "energy_kwh": 2, "energy_kwh_per_km": 3, "fuel_l": 2, "fuel_l_per_100km": 1, "soc_end_pct": 1,
                  "soc_min_pct": 1}

VehicleOption = Annotated[
    list[Path], typer.Option("--vehicle", "-v", help="Vehicle TOML file, or a directory of them. Repeatable.")
]
CycleOption = Annotated[
    Optional[list[Path]],
    typer.Option("--cycle", "-c", help="Cycle CSV (time_s, speed_kmh|speed_mps[, elevation_m]). Repeatable."),
]
TripOption = Annotated[
    Optional[list[str]], typer.Option("--trip", "-t", help="A stored trip id (see 'cevm trips'). Repeatable.")
]
VehicleIdOption = Annotated[
    Optional[list[str]], typer.Option("--vehicle-id", help="All stored trips of this vehicle id. Repeatable.")
]
RouteOption = Annotated[
    Optional[list[str]],
    typer.Option("--route", "-r", help="A stored route (see 'cevm route list'), or a glob such as 'block-*'. Repeatable."),
]
SocStartOption = Annotated[
    float, typer.Option("--soc-start", help="EV state of charge at the start [%] (default: full).")
]
ReserveOption = Annotated[
    float, typer.Option("--reserve-pct", help="EV state of charge to keep all along [%] (default 15, the paper's warning level).")
]
IceBrakingOption = Annotated[
    Optional[str],
    typer.Option(help=f"Override ICE braking mode: {' or '.join(ICE_BRAKING_MODES)}. Default: the vehicle file's."),
]
Cr0Option = Annotated[
    float, typer.Option(help="Cr0 of the simplification criterion, for --cycle files (stored trips and routes keep theirs).")
]
OutOption = Annotated[Optional[Path], typer.Option("--out", "-o", help="Write the output to this file instead of stdout.")]
FormatOption = Annotated[OutputFormat, typer.Option("--format", "-f", help="Output format.")]


def _values(specs: Optional[list[str]], option: str) -> np.ndarray | None:
    if not specs:
        return None
    return np.concatenate([parse_values(s, option) for s in specs])


def _check_common(ice_braking: Optional[str], soc_start: float, reserve_pct: float) -> None:
    if ice_braking is not None and ice_braking not in ICE_BRAKING_MODES:
        raise _fail(f"--ice-braking must be one of: {', '.join(ICE_BRAKING_MODES)}")
    if not (math.isfinite(soc_start) and 0.0 < soc_start <= 100.0):
        raise _fail("--soc-start must be in (0, 100] %")
    if not (math.isfinite(reserve_pct) and 0.0 <= reserve_pct < 100.0):
        raise _fail("--reserve-pct must be in [0, 100) %")


class _OutFile:
    """``--out`` as a context manager: written to ``PATH.partial``, renamed to PATH when
    the command succeeds, deleted when it fails (no truncated output left behind)."""

    def __init__(self, path: Path):
        self.path = Path(path)
        self.tmp = self.path.with_name(self.path.name + ".partial")

    def __enter__(self) -> IO[str]:
        try:
            self.fh = open(self.tmp, "w", encoding="utf-8", newline="")
        except OSError as exc:
            raise CevmError(f"{self.path}: cannot write: {exc.strerror or exc}") from None
        return self.fh

    def __exit__(self, exc_type, exc, tb) -> None:
        self.fh.close()
        if exc_type is None:
            os.replace(self.tmp, self.path)
        else:
            self.tmp.unlink(missing_ok=True)


def _open_out(stack: ExitStack, out: Optional[Path]) -> IO[str]:
    return sys.stdout if out is None else stack.enter_context(_OutFile(out))


# ------------------------------------------------------------------- predict columns


def _block_columns(block: SweepBlock) -> dict[str, object]:
    """Column arrays of a block (SI converted to the output units). Text columns are
    (codes, categories) pairs; boolean columns float 1/0/NaN."""
    ps = block.pset
    src = block.source
    n = ps.n
    km = src.distance_m / 1000.0
    vi = ps.vehicle_index
    names = [v.name for v in ps.vehicles]
    energy_kwh = block.energy_j / J_PER_KWH
    with np.errstate(invalid="ignore", divide="ignore"):
        per_km = energy_kwh / km if km > 0 else np.full(n, np.nan)
        per_100 = 100.0 * block.fuel_l / km if km > 0 else np.full(n, np.nan)
    zeros = np.zeros(n, dtype=np.int64)
    return {
        "cycle": (zeros, [src.name]),
        "vehicle": (vi, names),
        "mass_kg": ps.mass_kg,
        "distance_km": np.full(n, km),
        "duration_s": np.full(n, src.duration_s),
        "wheel_energy_kwh": block.wheel_energy_j / J_PER_KWH,
        "energy_kwh": energy_kwh,
        "energy_kwh_per_km": per_km,
        "fuel_l": block.fuel_l,
        "fuel_l_per_100km": per_100,
        "source_kind": (zeros, [src.kind]),
        "powertrain": (vi, [v.powertrain for v in ps.vehicles]),
        "payload_kg": ps.payload_kg,
        "over_max_gross": ps.over_max_gross.astype(float),
        "soc_end_pct": block.soc_end_pct,
        "soc_min_pct": block.soc_min_pct,
        "reserve_ok": np.where(ps.is_ev, block.reserve_ok.astype(float), np.nan),
        "tank_ok": block.tank_ok,
        "ice_braking": (vi, list(ps.braking)),
    }


def _concat_columns(cols: list[dict[str, object]]) -> dict[str, object]:
    if len(cols) == 1:
        return cols[0]
    out: dict[str, object] = {}
    for key in cols[0]:
        parts = [c[key] for c in cols]
        if isinstance(parts[0], tuple):
            cats: list[str] = []
            index: dict[str, int] = {}
            codes = []
            for c, names in parts:
                remap = np.array([index.setdefault(s, len(index)) for s in names], dtype=np.int64)
                codes.append(remap[c])
            cats = list(index)
            out[key] = (np.concatenate(codes), cats)
        else:
            out[key] = np.concatenate(parts)
    return out


# ---------------------------------------------------------------------- CSV, fast


def _num_chars(x: np.ndarray, decimals: int) -> tuple[np.ndarray, np.ndarray]:
    """Characters (n x W uint8) and keep-mask of ``x`` printed with ``decimals``
    decimals, trailing fractional zeros (and a bare point) dropped; NaN -> empty."""
    x = np.asarray(x, dtype=np.float64)
    n = x.size
    valid = np.isfinite(x)
    scaled = np.where(valid, np.abs(x), 0.0) * 10.0**decimals
    if n and scaled.max() >= 9.0e15:  # beyond int64 digits: Python formatting
        strs = np.array([f"{v:.{decimals}f}".rstrip("0").rstrip(".") if math.isfinite(v) else "" for v in x.tolist()],
                        dtype=bytes)
        return _text_chars(strs)
    iv = np.rint(scaled).astype(np.int64)
    neg = valid & (x < 0) & (iv > 0)
    nd = max(len(str(int(iv.max()))) if n else 1, decimals + 1)
    digits = np.empty((n, nd), dtype=np.uint8)
    rest = iv
    for j in range(nd - 1, -1, -1):
        rest, dig = np.divmod(rest, 10)
        digits[:, j] = dig
    ni = nd - decimals
    keep_int = np.logical_or.accumulate(digits[:, :ni] != 0, axis=1)
    keep_int[:, -1] = True
    parts = [np.full((n, 1), ord("-"), np.uint8), digits[:, :ni] + 48]
    keeps = [neg[:, None], keep_int]
    if decimals:
        frac = digits[:, ni:]
        keep_frac = np.logical_or.accumulate((frac != 0)[:, ::-1], axis=1)[:, ::-1]
        parts += [np.full((n, 1), ord("."), np.uint8), frac + 48]
        keeps += [keep_frac[:, :1], keep_frac]
    keep = np.concatenate(keeps, axis=1)
    keep &= valid[:, None]
    return np.concatenate(parts, axis=1), keep


def _text_chars(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    arr = np.asarray(values, dtype=bytes)
    if arr.dtype.itemsize == 0:
        arr = arr.astype("S1")
    chars = arr.view(np.uint8).reshape(arr.size, arr.dtype.itemsize)
    return chars, chars != 0


def _csv_quote(s: str) -> bytes:
    if not s:
        return b""
    buf = io.StringIO()
    csv.writer(buf, lineterminator="").writerow([s])
    return buf.getvalue().encode("utf-8")


_BOOL_CSV = np.array([b"false", b"true", b""])


def _csv_text(cols: dict[str, object], columns: Sequence[str], decimals: dict[str, int]) -> str:
    fields = []
    for name in columns:
        col = cols[name]
        if isinstance(col, tuple):
            codes, cats = col
            fields.append(_text_chars(np.array([_csv_quote(c) for c in cats], dtype=bytes)[codes]))
        elif name in _BOOL:
            v = np.asarray(col)
            code = np.where(np.isnan(v), 2, (v > 0.5).astype(np.int64))
            fields.append(_text_chars(_BOOL_CSV[code]))
        else:
            fields.append(_num_chars(col, decimals.get(name, 6)))
    n = fields[0][0].shape[0]
    parts, keeps = [], []
    comma = np.full((n, 1), ord(","), np.uint8)
    for i, (c, k) in enumerate(fields):
        if i:
            parts.append(comma)
            keeps.append(np.ones((n, 1), bool))
        parts.append(c)
        keeps.append(k)
    parts.append(np.full((n, 1), ord("\n"), np.uint8))
    keeps.append(np.ones((n, 1), bool))
    chars = np.concatenate(parts, axis=1)
    keep = np.concatenate(keeps, axis=1)
    return chars[keep].tobytes().decode("utf-8")


# ---------------------------------------------------------------------- JSON, streamed


def _json_values(col: object, name: str) -> list[str]:
    if isinstance(col, tuple):
        codes, cats = col
        enc = [json.dumps(c) for c in cats]
        return [enc[i] for i in codes.tolist()]
    v = np.asarray(col, dtype=np.float64)
    if name in _BOOL:
        return [("null" if x != x else ("true" if x > 0.5 else "false")) for x in v.tolist()]
    return [(repr(x) if math.isfinite(x) else "null") for x in v.tolist()]


def _json_rows(cols: dict[str, object], is_ev: np.ndarray) -> list[str]:
    vals = {k: _json_values(cols[k], k) for k in PREDICT_COLUMNS}
    ev_fmt = "{" + ", ".join(f'"{k}": %s' for k in _EV_KEYS) + "}"
    ice_fmt = "{" + ", ".join(f'"{k}": %s' for k in _ICE_KEYS) + "}"
    ev_rows = zip(*(vals[k] for k in _EV_KEYS))
    ice_rows = zip(*(vals[k] for k in _ICE_KEYS))
    return [ev_fmt % ev if e else ice_fmt % ice for e, ev, ice in zip(is_ev.tolist(), ev_rows, ice_rows)]


# --------------------------------------------------------------------------- writers


class _PredictWriter:
    """Streams predict blocks as CSV, JSON or a (bounded) table."""

    def __init__(self, fmt: OutputFormat, stream: IO[str]):
        self.fmt = fmt
        self.stream = stream
        self.pending: list[SweepBlock] = []
        self.pending_rows = 0
        self.rows = 0
        self.table_rows: list[dict] = []
        self.started = False

    def add(self, block: SweepBlock) -> None:
        self.rows += block.n
        if self.fmt == OutputFormat.table:
            if len(self.table_rows) < TABLE_MAX_ROWS:
                self._table_add(block)
            return
        self.pending.append(block)
        self.pending_rows += block.n
        if self.pending_rows >= WRITE_BATCH_ROWS:
            self._flush()

    def _flush(self) -> None:
        if not self.pending:
            return
        cols = _concat_columns([_block_columns(b) for b in self.pending])
        is_ev = np.concatenate([b.pset.is_ev for b in self.pending])
        self.pending, self.pending_rows = [], 0
        for lo in range(0, is_ev.size, WRITE_BATCH_ROWS):  # bounded memory for huge blocks
            sl = slice(lo, lo + WRITE_BATCH_ROWS)
            part = {k: ((c[0][sl], c[1]) if isinstance(c, tuple) else c[sl]) for k, c in cols.items()}
            if self.fmt == OutputFormat.csv:
                if not self.started:
                    self.stream.write(",".join(PREDICT_COLUMNS) + "\n")
                self.stream.write(_csv_text(part, PREDICT_COLUMNS, CSV_DECIMALS))
            else:
                rows = _json_rows(part, is_ev[sl])
                self.stream.write(("[\n  " if not self.started else ",\n  ") + ",\n  ".join(rows))
            self.started = True

    def _table_add(self, block: SweepBlock) -> None:
        cols = _block_columns(block)
        n = min(block.n, TABLE_MAX_ROWS - len(self.table_rows))
        for i in range(n):
            row = {}
            for k in PREDICT_COLUMNS:
                c = cols[k]
                if isinstance(c, tuple):
                    row[k] = c[1][int(c[0][i])] or None
                else:
                    x = float(c[i])
                    row[k] = None if x != x else (x > 0.5 if k in _BOOL else x)
            ok = row["reserve_ok"] if row["powertrain"] == "ev" else row["tank_ok"]
            row["status"] = ("?" if ok is None else "yes" if ok else "NO") + (" (over max gross)" if row["over_max_gross"] else "")
            self.table_rows.append(row)

    def close(self) -> None:
        if self.fmt == OutputFormat.table:
            rows = self.table_rows
            columns = ["cycle", "vehicle", "mass_kg", "distance_km", "energy_kwh", "energy_kwh_per_km", "soc_min_pct",
                       "fuel_l", "fuel_l_per_100km", "status"]
            columns = [c for c in columns if any(r.get(c) is not None for r in rows)]
            title = "cevm predict" + (f" (first {len(rows)} of {self.rows} rows)" if self.rows > len(rows) else "")
            write_rows(rows, OutputFormat.table, columns=columns, title=title, digits=PREDICT_DIGITS,
                       headers=PREDICT_HEADERS, stream=self.stream)
            self.stream.flush()
            if self.rows > len(rows):
                typer.echo(f"cevm: {self.rows - len(rows)} more rows not shown; use --format csv or json "
                           "(and --out FILE)", err=True)
            return
        self._flush()
        if self.fmt == OutputFormat.csv:
            if not self.started:
                self.stream.write(",".join(PREDICT_COLUMNS) + "\n")
        else:
            self.stream.write("\n]\n" if self.started else "[]\n")
        self.stream.flush()


# ----------------------------------------------------------------------------- plots


def _plot(path: Path, sources: list[Source], pset: PredictionSet, sweep_data: list, soc_start: float,
          reserve_pct: float, ice_braking: Optional[str]) -> None:
    """SoC (EV) or fuel (ICE) along each source for each vehicle (one mass each: the
    paper's figure 4), or energy / fuel against payload when vehicles have several
    masses."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    counts = np.bincount(pset.vehicle_index)
    pairs = [(s, v) for s in range(len(sources)) for v in range(len(pset.vehicles))]
    if len(pairs) > PLOT_MAX_LINES:
        typer.echo(f"cevm: warning: --plot draws the first {PLOT_MAX_LINES} of {len(pairs)} (source, vehicle) pairs",
                   err=True)
        pairs = pairs[:PLOT_MAX_LINES]
    has_ev = any(pset.vehicles[v].is_ev for _, v in pairs)
    has_ice = any(not pset.vehicles[v].is_ev for _, v in pairs)
    n_ax = int(has_ev) + int(has_ice)
    fig, axes = plt.subplots(n_ax, 1, figsize=(9, 4.5 * n_ax), squeeze=False)
    ax_ev = axes[0, 0] if has_ev else None
    ax_ice = axes[-1, 0] if has_ice else None
    if counts.max() > 1:  # a mass sweep: energy against payload (or mass)
        use_payload = bool(np.all(np.isfinite(pset.payload_kg)))
        xname = "payload [kg]" if use_payload else "gross mass [kg]"
        for s, v in pairs:
            sel = pset.vehicle_index == v
            x = (pset.payload_kg if use_payload else pset.mass_kg)[sel]
            veh = pset.vehicles[v]
            ys = sweep_data[s]
            label = f"{veh.name} on {sources[s].name}"
            if veh.is_ev:
                ax_ev.plot(x, ys["energy_kwh"][sel], marker="o", ms=3, label=label)
            else:
                ax_ice.plot(x, ys["fuel_l"][sel], marker="o", ms=3, label=label)
            over = pset.over_max_gross[sel]
            if over.any():
                ax = ax_ev if veh.is_ev else ax_ice
                ax.plot(x[over], (ys["energy_kwh"] if veh.is_ev else ys["fuel_l"])[sel][over], "x", color="red")
        if ax_ev is not None:
            ax_ev.set(xlabel=xname, ylabel="battery energy [kWh]", title="EV energy against load (x: over max_gross_kg)")
        if ax_ice is not None:
            ax_ice.set(xlabel=xname, ylabel="fuel [l]", title="ICE fuel against load (x: over max_gross_kg)")
    else:  # state of charge along the route (the paper's figure 4)
        for s, v in pairs:
            veh = pset.vehicles[v]
            m = float(pset.mass_kg[pset.vehicle_index == v][0])
            _, dist, e = energy_trajectory(sources[s], veh, m, ice_braking=ice_braking)
            label = f"{veh.name} on {sources[s].name} ({m:,.0f} kg)"
            if veh.is_ev:
                ax_ev.plot(dist / 1000.0, soc_start - 100.0 * e / veh.battery_j, label=label)
            else:
                ax_ice.plot(dist / 1000.0, e, label=label)
        if ax_ev is not None:
            ax_ev.axhline(reserve_pct, color="red", ls="--", lw=1, label=f"reserve {reserve_pct:g} %")
            ax_ev.set(xlabel="distance [km]", ylabel="state of charge [%]", title="State of charge along the route")
        if ax_ice is not None:
            ax_ice.set(xlabel="distance [km]", ylabel="fuel burnt [l]", title="Fuel along the route")
    for ax in axes[:, 0]:
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    try:
        fig.savefig(path, dpi=120)
    except OSError as exc:
        raise CevmError(f"{path}: cannot write the plot: {exc.strerror or exc}") from None
    finally:
        plt.close(fig)


# ---------------------------------------------------------------------------- predict


@app.command("predict")
def predict_cmd(
    vehicle: VehicleOption,
    cycle: CycleOption = None,
    trip: TripOption = None,
    vehicle_id: VehicleIdOption = None,
    route: RouteOption = None,
    store: StoreOption = None,
    mass_kg: Annotated[
        Optional[list[str]],
        typer.Option("--mass-kg", "-m", help="Gross mass in kg: a value, a list a,b or a range start:stop:step "
                                             "(stop included). Repeatable. Default: each vehicle's mass_kg."),
    ] = None,
    payload_kg: Annotated[
        Optional[list[str]],
        typer.Option("--payload-kg", "-p", help="Payload in kg on each vehicle's kerb mass: a value, a list or a "
                                                "range such as 0:26000:2000 (14 values, stop included). Repeatable."),
    ] = None,
    soc_start: SocStartOption = DEFAULT_SOC_START_PCT,
    reserve_pct: ReserveOption = DEFAULT_RESERVE_PCT,
    fmt: FormatOption = OutputFormat.table,
    out: OutOption = None,
    plot: Annotated[
        Optional[Path],
        typer.Option(help="Write a PNG: state of charge along each source (one mass per vehicle), or energy "
                          "against payload (a mass sweep)."),
    ] = None,
    ice_braking: IceBrakingOption = None,
    cr0: Cr0Option = CR0_DEFAULT,
    workers: Annotated[
        Optional[int], typer.Option("--workers", "-w", min=1, help="Worker processes, a batch of sources per task "
                                    "(default 1: in this process; a large sweep of many routes runs ~1.3x faster "
                                    "on 2 cores, a small one is slower for the processes' start).")
    ] = None,
    scheduler: Annotated[
        Optional[str], typer.Option(help="Dask scheduler address (tcp://HOST:8786): evaluate the batches on that "
                                         "cluster (pip install 'cevm[dask]'). Sources are read here and sent.")
    ] = None,
) -> None:
    """Predict energy (EV) or fuel (ICE) for every source x vehicle x mass.

    Sources are cycle files (--cycle), stored trips (--trip, --vehicle-id) and stored
    routes (--route); the 'cycle' column names each. EV rows give the state of charge at
    the end and at its lowest along the way, from --soc-start and the battery, and
    whether it stays above --reserve-pct; ICE rows whether the fuel fits tank_l. Masses
    above max_gross_kg are kept and flagged (over_max_gross)."""
    if not (cycle or trip or vehicle_id or route):
        raise _fail("give at least one source: --cycle, --trip, --vehicle-id or --route")
    if mass_kg and payload_kg:
        raise _fail("give --mass-kg or --payload-kg, not both")
    if workers is not None and scheduler is not None:
        raise _fail("give --workers (local processes) or --scheduler (a Dask cluster), not both")
    _check_common(ice_braking, soc_start, reserve_pct)
    try:
        masses = _values(mass_kg, "--mass-kg")
        payloads = _values(payload_kg, "--payload-kg")
        if masses is not None and np.any(masses <= 0):
            raise _fail("--mass-kg values must be positive")
        if payloads is not None and np.any(payloads < 0):
            raise _fail("--payload-kg values must be >= 0")
        from cevm.io import load_vehicles

        vehicles = load_vehicles(vehicle)
        pset = PredictionSet.build(vehicles, mass_kg=masses, payload_kg=payloads, ice_braking=ice_braking)
        with ExitStack() as stack:
            sources = load_sources(stack, store, cycle or [], trip or [], vehicle_id or [], route or [], cr0)
            executor = stack.enter_context(make_executor(None if scheduler else (workers or 1), scheduler))
            stream = _open_out(stack, out)
            writer = _PredictWriter(fmt, stream)
            keep_for_plot = plot is not None and np.bincount(pset.vehicle_index).max() > 1
            plot_data = []
            for block in sweep(sources, pset, soc_start_pct=soc_start, reserve_pct=reserve_pct, executor=executor):
                writer.add(block)
                if keep_for_plot and block.source_index < PLOT_MAX_LINES:
                    plot_data.append({"energy_kwh": block.energy_j / J_PER_KWH, "fuel_l": block.fuel_l})
                if plot is None:
                    block.source.release()  # free its profile: the sweep is past it
            writer.close()
            if plot is not None:
                _plot(plot, sources, pset, plot_data, soc_start, reserve_pct, ice_braking)
    except CevmError as exc:
        raise _fail(str(exc)) from None
    over = int(pset.over_max_gross.sum()) * len(sources)
    if over:
        typer.echo(f"cevm: warning: {over} predictions exceed their vehicle's max_gross_kg (column over_max_gross)",
                   err=True)
    if out is not None and fmt != OutputFormat.table:
        typer.echo(f"cevm predict: {writer.rows} rows -> {out}", err=True)


# ------------------------------------------------------------------------ feasibility


def _feasibility_rows(res: Feasibility) -> list[dict]:
    src = res.source
    rows = []

    def num(x):
        x = float(x)
        return None if x != x else x

    for i, veh in enumerate(res.vehicles):
        f = res.feasible[i]
        row = {
            "source": src.name, "source_kind": src.kind, "vehicle": veh.name, "powertrain": veh.powertrain,
            "distance_km": src.distance_m / 1000.0, "mass_kg": float(res.mass_kg[i]),
            "payload_kg": float(res.payload_kg[i]), "over_max_gross": bool(res.over_max_gross[i]),
            "feasible": None if f != f else bool(f > 0.5),
        }
        if veh.is_ev:
            row.update(energy_kwh=num(res.energy_j[i] / J_PER_KWH), soc_end_pct=num(res.soc_end_pct[i]),
                       soc_min_pct=num(res.soc_min_pct[i]), reserve_margin_pct=num(res.reserve_margin_pct[i]))
        else:
            row.update(fuel_l=num(res.fuel_l[i]), tank_l=veh.tank_l, tank_margin_l=num(res.tank_margin_l[i]))
        row.update(max_payload_kg=num(res.max_payload_kg[i]), min_payload_kg=num(res.min_payload_kg[i]),
                   limited_by=res.limited_by[i])
        rows.append(row)
    return rows


@app.command("feasibility")
def feasibility_cmd(
    vehicle: VehicleOption,
    route: RouteOption = None,
    cycle: CycleOption = None,
    trip: TripOption = None,
    vehicle_id: VehicleIdOption = None,
    store: StoreOption = None,
    payload_kg: Annotated[
        Optional[float], typer.Option("--payload-kg", "-p", help="Payload in kg at which margins are given. Default: each vehicle's default mass.")
    ] = None,
    mass_kg: Annotated[
        Optional[float], typer.Option("--mass-kg", "-m", help="Gross mass in kg at which margins are given (instead of --payload-kg).")
    ] = None,
    payload_cap_kg: Annotated[
        Optional[float],
        typer.Option(help="Where the payload search stops for vehicles without max_gross_kg, in kg. Default: their kerb mass."),
    ] = None,
    soc_start: SocStartOption = DEFAULT_SOC_START_PCT,
    reserve_pct: ReserveOption = DEFAULT_RESERVE_PCT,
    fmt: FormatOption = OutputFormat.table,
    out: OutOption = None,
    ice_braking: IceBrakingOption = None,
    cr0: Cr0Option = CR0_DEFAULT,
) -> None:
    """Can each vehicle run each route, with what margin, and the largest payload?

    Margins (EV: lowest state of charge above the reserve; ICE: fuel against tank_l) and
    the largest payload that keeps the reserve (or fits the tank) within max_gross_kg,
    exact to the kilogram."""
    if not (cycle or trip or vehicle_id or route):
        raise _fail("give at least one route: --route (or --cycle, --trip, --vehicle-id)")
    if payload_kg is not None and mass_kg is not None:
        raise _fail("give --mass-kg or --payload-kg, not both")
    _check_common(ice_braking, soc_start, reserve_pct)
    try:
        from cevm.io import load_vehicles

        vehicles = load_vehicles(vehicle)
        rows: list[dict] = []
        with ExitStack() as stack:
            sources = load_sources(stack, store, cycle or [], trip or [], vehicle_id or [], route or [], cr0)
            for src in sources:
                res = feasibility(src, vehicles, soc_start_pct=soc_start, reserve_pct=reserve_pct,
                                  payload_kg=payload_kg, mass_kg=mass_kg, payload_cap_kg=payload_cap_kg,
                                  ice_braking=ice_braking)
                rows.extend(_feasibility_rows(res))
                src.release()
            stream = _open_out(stack, out)
            if fmt == OutputFormat.table:
                _print_feasibility(rows, stream)
            else:
                write_rows(rows, fmt, stream=stream)
    except CevmError as exc:
        raise _fail(str(exc)) from None


def _print_feasibility(rows: list[dict], stream: IO[str]) -> None:
    def mark(f):
        return "?" if f is None else ("yes" if f else "NO")

    table = []
    for r in rows[:TABLE_MAX_ROWS]:
        if r["powertrain"] == "ev":
            state = f"{r['soc_min_pct']:.1f}/{r['soc_end_pct']:.1f} %"
            margin = f"{r['reserve_margin_pct']:+.1f} pp"
        else:
            state = f"{r['fuel_l']:.1f}/" + (f"{r['tank_l']:g} l" if r.get("tank_l") else "? l")
            margin = "-" if r.get("tank_margin_l") is None else f"{r['tank_margin_l']:+.1f} l"
        if r["over_max_gross"]:
            margin += " (over max gross)"
        mp = r["max_payload_kg"]
        payload = "none" if mp is None else f"{mp:,.0f}"
        if r["min_payload_kg"]:
            payload = f"{r['min_payload_kg']:,.0f} to {payload}"
        table.append({"route": r["source"], "vehicle": r["vehicle"], "payload kg": r["payload_kg"],
                      "feasible": mark(r["feasible"]), "state": state, "margin": margin,
                      "max payload kg": payload, "limited by": r["limited_by"]})
    title = "cevm feasibility" + (f" (first {len(table)} of {len(rows)})" if len(rows) > len(table) else "")
    write_rows(table, OutputFormat.table, title=title, digits={"payload kg": 0}, stream=stream,
               columns=["route", "vehicle", "payload kg", "feasible", "state", "margin", "max payload kg", "limited by"],
               headers={"state": "SoC min/end, fuel/tank"})


# ----------------------------------------------------------------------------- routes


route_app = typer.Typer(help="Named routes (a bus block, a delivery round): sequences of stored trips or cycle files.",
                        no_args_is_help=True)
app.add_typer(route_app, name="route")


@route_app.command("add")
def route_add(
    name: Annotated[str, typer.Argument(help="Route name: letters, digits, '.', '_', '-'.")],
    trip: TripOption = None,
    cycle: CycleOption = None,
    leg: Annotated[
        Optional[list[str]],
        typer.Option("--leg", help="A leg as trip:ID or cycle:PATH, in order (to mix trips and cycles). Repeatable."),
    ] = None,
    store: StoreOption = None,
    replace: Annotated[bool, typer.Option(help="Overwrite an existing route of this name.")] = False,
    note: Annotated[Optional[str], typer.Option(help="A note kept with the route.")] = None,
    cr0: Annotated[float, typer.Option(help="Cr0 for the cycle legs' vectors (trips keep theirs).")] = CR0_DEFAULT,
) -> None:
    """Store a named route: stored trips (--trip) or cycle files (--cycle) in the order
    given, or a mix with --leg trip:ID --leg cycle:PATH. Cycle legs are copied into the
    store (vector and profile), so the route does not depend on the files afterwards."""
    from cevm.store.routes import CycleLeg, TripLeg, add_route
    from cevm.store import TripStore, resolve_store_path

    given = sum(bool(x) for x in (trip, cycle, leg))
    if given == 0:
        raise _fail("give the legs: --trip ID ..., --cycle PATH ..., or --leg trip:ID|cycle:PATH ...")
    if given > 1:
        raise _fail("--trip, --cycle and --leg cannot be combined (their order would be lost); "
                    "to mix trips and cycles use --leg trip:ID --leg cycle:PATH in order")
    specs: list[tuple[str, str]] = [("trip", t) for t in trip or []] + [("cycle", str(c)) for c in cycle or []]
    for s in leg or []:
        kind, sep, ref = s.partition(":")
        if not sep or kind not in ("trip", "cycle") or not ref:
            raise _fail(f"--leg {s!r}: expected trip:ID or cycle:PATH")
        specs.append((kind, ref))
    path = resolve_store_path(store)
    if any(k == "trip" for k, _ in specs) and not path.exists():
        raise _fail(f"{path}: no trip store here; run 'cevm ingest' first or give --store")
    try:
        legs = [TripLeg(ref) if kind == "trip" else CycleLeg.from_file(ref) for kind, ref in specs]
        with TripStore.open(path) as st:
            info = add_route(st, name, legs, replace=replace, cr0=cr0, note=note)
    except CevmError as exc:
        raise _fail(str(exc)) from None
    n_trip = sum(1 for x in info.legs if x.kind == "trip")
    n_cycle = len(info.legs) - n_trip
    msg = f"route {info.name!r}: {len(info.legs)} legs ({n_trip} trips, {n_cycle} cycles) stored in {path}"
    if n_cycle:
        msg += "; cycle legs are copied into the store (vector and profile), the files are no longer needed"
    typer.echo(msg)


@route_app.command("list")
def route_list(
    store: StoreOption = None,
    fmt: FormatOption = OutputFormat.table,
) -> None:
    """List the stored routes: legs, distance, duration."""
    from cevm.store.routes import list_routes, load_route_legs
    from cevm.store import TripStore, format_utc

    path = _existing_store(store, "run 'cevm ingest' or 'cevm route add' first, or give --store")
    rows = []
    try:
        with TripStore.open(path) as st:
            for info in list_routes(st):
                row = {"route": info.name, "legs": len(info.legs),
                       "trips": sum(1 for x in info.legs if x.kind == "trip"),
                       "cycles": sum(1 for x in info.legs if x.kind == "cycle"),
                       "distance_km": None, "duration_s": None, "created_utc": format_utc(info.created_utc_s),
                       "status": "ok", "sources": " ".join(f"{x.kind}:{x.label}" for x in info.legs),
                       "note": info.note}
                try:
                    legs = load_route_legs(st, info.name, profiles=False)
                    row["distance_km"] = sum(x.vector.distance_m for x in legs) / 1000.0
                    row["duration_s"] = sum(x.vector.duration_s for x in legs)
                except CevmError as exc:
                    row["status"] = f"broken: {exc}"
                rows.append(row)
    except CevmError as exc:
        raise _fail(str(exc)) from None
    if fmt == OutputFormat.table:
        for r in rows:
            r["sources"] = _short_legs(r["sources"])
        write_rows(rows, fmt, title=f"cevm routes ({len(rows)})", digits={"distance_km": 2, "duration_s": 0},
                   columns=["route", "legs", "distance_km", "duration_s", "created_utc", "status", "sources"],
                   headers={"distance_km": "km", "duration_s": "s", "created_utc": "added (UTC)"})
    else:
        write_rows(rows, fmt)


def _short_legs(sources: str, width: int = 48) -> str:
    """'a a a b' -> 'a x3 b', cut to ``width`` characters (for the table)."""
    out: list[list] = []
    for item in sources.split():
        if out and out[-1][0] == item:
            out[-1][1] += 1
        else:
            out.append([item, 1])
    text = " ".join(f"{item} x{n}" if n > 1 else item for item, n in out)
    return text if len(text) <= width else text[: width - 3] + "..."


@route_app.command("remove")
def route_remove(
    name: Annotated[str, typer.Argument(help="The route to delete.")],
    store: StoreOption = None,
) -> None:
    """Delete a stored route (its trips stay in the store)."""
    from cevm.store.routes import remove_route
    from cevm.store import TripStore

    path = _existing_store(store, "give --store")
    try:
        with TripStore.open(path) as st:
            gone = remove_route(st, name)
    except CevmError as exc:
        raise _fail(str(exc)) from None
    if not gone:
        raise _fail(f"no route {name!r} in {path}; 'cevm route list' shows them")
    typer.echo(f"route {name!r} removed from {path}")
