"""``cevm predict``: energy or fuel for every source x vehicle x mass, a thin layer over
:mod:`cevm.core.sweep` (sources from :mod:`cevm.store.sources`), and its fast writers.

Output of ``predict`` (one row per source x vehicle x mass, source-major):

- JSON: a streamed array of objects. Every row has ``cycle`` (the source's name: file
  stem, trip id or route name), ``vehicle``, ``powertrain``, ``mass_kg``,
  ``distance_km``, ``duration_s``, ``wheel_energy_kwh``, then EV rows ``energy_kwh``,
  ``energy_kwh_per_km`` and ICE rows ``fuel_l``, ``fuel_l_per_100km``, ``ice_braking``
  (the contract of the first ``cevm predict``), and after them ``source_kind``,
  ``payload_kg``, ``over_max_gross``, EV: ``soc_end_pct`` (null when it runs empty on
  the way), ``soc_min_pct`` (never below 0), ``reserve_ok``; ICE: ``tank_ok`` (null
  without ``tank_l``); then ``vehicle_key`` (the vehicle's id: its file's ``id`` key or
  stem), EV: ``reserve_at_km``, ``reserve_at_s`` (where it first crosses the reserve,
  null if it keeps it); ``empty_at_km``, ``empty_at_s`` (where the battery or the tank
  runs empty, null if it does not); ``range_km`` (EV also ``range_reserve_km``) with
  ``--range``: the distance to empty (to the reserve) with the source driven again and
  again; ``over_power``, ``over_speed`` (the source asks more wheel power than
  ``max_power_kw`` at the row's mass, or more speed than ``max_speed_kmh``; null for a
  vehicle without them). Numbers in full precision.
- CSV: the same columns, the contract's first, written in blocks with fixed decimals
  (see :data:`CSV_DECIMALS`: 1 g, 1 mm, 1 ms, 3.6 J, 1 ul, 1e-6 %), trailing zeros
  dropped; empty cells where a column does not apply.
- table: for people, at most :data:`TABLE_MAX_ROWS` rows.
"""

from __future__ import annotations

import io
import json
import math
from collections import Counter
from collections.abc import Sequence
from contextlib import ExitStack
from pathlib import Path
from typing import IO, Annotated, Optional

import numpy as np
import typer

from cevm.cli.common import (
    EXIT_PARTIAL,
    TABLE_MAX_ROWS,
    AmbientOption,
    Cr0Option,
    CycleOption,
    FormatOption,
    IceBrakingOption,
    OutOption,
    ReserveOption,
    RouteOption,
    SocStartOption,
    StoreOption,
    TripOption,
    VehicleIdOption,
    VehicleOption,
    check_common,
    check_workers,
    fail,
    load_sources,
    note_flat_cycles,
    open_out,
    warn_ambient_unused,
    warn_damaged,
    with_cycle_options,
)
from cevm.cli.output import OutputFormat, csv_writer, vehicle_legend, write_rows
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
from cevm.executors import make_executor
from cevm.io.plots import PLOT_MAX_LINES, plot_predictions
from cevm.text import printable
from cevm.units import J_PER_KWH

#: Rows formatted at once when writing CSV or JSON.
WRITE_BATCH_ROWS = 32768

#: Decimals of the numeric CSV columns of ``predict``.
CSV_DECIMALS = {
    "mass_kg": 3, "payload_kg": 3, "distance_km": 6, "duration_s": 3, "wheel_energy_kwh": 6, "energy_kwh": 6,
    "energy_kwh_per_km": 6, "fuel_l": 6, "fuel_l_per_100km": 6, "soc_end_pct": 6, "soc_min_pct": 6, "ambient_c": 3,
    "reserve_at_km": 6, "reserve_at_s": 3, "empty_at_km": 6, "empty_at_s": 3, "range_km": 6, "range_reserve_km": 6,
    "measured_fuel_l": 6, "measured_energy_kwh": 6, "error_pct": 6,
}
#: Columns of a stored source's truth, after all others: where the mass of each row comes
#: from (:data:`cevm.store.masses.MASS_SOURCES`), and for a stored trip what it measured
#: and the error e = (modelled - measured) / measured [%] (at the trip's own mass only:
#: empty for rows at --mass-kg / --payload-kg). Made by :func:`_truth_columns`.
TRUTH_COLUMNS = ("mass_source", "measured_fuel_l", "measured_energy_kwh", "error_pct")
#: Columns of ``predict`` in CSV order: the first contract's, then the new ones.
PREDICT_COLUMNS = (
    "cycle", "vehicle", "mass_kg", "distance_km", "duration_s", "wheel_energy_kwh", "energy_kwh", "energy_kwh_per_km",
    "fuel_l", "fuel_l_per_100km", "source_kind", "powertrain", "payload_kg", "over_max_gross", "soc_end_pct",
    "soc_min_pct", "reserve_ok", "tank_ok", "ice_braking", "ambient_c", "ambient_from", "vehicle_key", "reserve_at_km",
    "reserve_at_s", "empty_at_km", "empty_at_s", "range_km", "range_reserve_km", "over_power", "over_speed",
) + TRUTH_COLUMNS
_EV_KEYS = ("cycle", "vehicle", "powertrain", "mass_kg", "distance_km", "duration_s", "wheel_energy_kwh",
            "energy_kwh", "energy_kwh_per_km", "source_kind", "payload_kg", "over_max_gross", "soc_end_pct",
            "soc_min_pct", "reserve_ok", "ambient_c", "ambient_from", "vehicle_key", "reserve_at_km", "reserve_at_s",
            "empty_at_km", "empty_at_s", "range_km", "range_reserve_km", "over_power", "over_speed"
            ) + ("mass_source", "measured_energy_kwh", "error_pct")
_ICE_KEYS = ("cycle", "vehicle", "powertrain", "mass_kg", "distance_km", "duration_s", "wheel_energy_kwh",
             "fuel_l", "fuel_l_per_100km", "ice_braking", "source_kind", "payload_kg", "over_max_gross", "tank_ok",
             "ambient_c", "ambient_from", "vehicle_key", "empty_at_km", "empty_at_s", "range_km", "over_power",
             "over_speed") + ("mass_source", "measured_fuel_l", "error_pct")
_TEXT = {"cycle", "vehicle", "source_kind", "powertrain", "ice_braking", "ambient_from", "vehicle_key", "mass_source"}
_BOOL = {"over_max_gross", "reserve_ok", "tank_ok", "over_power", "over_speed"}

PREDICT_HEADERS = {
    "mass_kg": "mass kg", "payload_kg": "payload kg", "distance_km": "km", "duration_s": "s",
    "wheel_energy_kwh": "wheel kWh", "energy_kwh": "battery kWh", "energy_kwh_per_km": "kWh/km", "fuel_l": "fuel l",
    "fuel_l_per_100km": "l/100km", "soc_end_pct": "SoC end %", "soc_min_pct": "SoC min %",
    "reserve_ok": "reserve ok", "tank_ok": "tank ok", "over_max_gross": "over max gross",
    "status": "reserve / tank ok", "ambient_c": "ambient degC", "vehicle_key": "vehicle", "range_km": "range km",
    "mass_source": "mass from", "measured_fuel_l": "measured l", "measured_energy_kwh": "measured kWh",
    "error_pct": "error %",
}
PREDICT_DIGITS = {"mass_kg": 0, "payload_kg": 0, "duration_s": 0, "distance_km": 2, "wheel_energy_kwh": 2,
                  "energy_kwh": 2, "energy_kwh_per_km": 3, "fuel_l": 2, "fuel_l_per_100km": 1, "soc_end_pct": 1,
                  "soc_min_pct": 1, "ambient_c": 1, "range_km": 1, "measured_fuel_l": 2, "measured_energy_kwh": 2,
                  "error_pct": 1}


# ------------------------------------------------------------------- predict columns


def _block_columns(block: SweepBlock, mass_source: str = "vehicle file") -> dict[str, object]:
    """Column arrays of a block (SI converted to the output units), whose masses come
    from ``mass_source``. Text columns are (codes, categories) pairs; boolean columns
    float 1/0/NaN."""
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
        "ambient_c": block.ambient_c,
        "ambient_from": (block.ambient_from.astype(np.int64), list(AMBIENT_ORIGINS)),
        "tank_ok": block.tank_ok,
        "ice_braking": (vi, list(ps.braking)),
        "vehicle_key": (vi, [v.label for v in ps.vehicles]),
        "reserve_at_km": _optional(block.reserve_at_m, n, 1e-3),
        "reserve_at_s": _optional(block.reserve_at_s, n),
        "empty_at_km": _optional(block.empty_at_m, n, 1e-3),
        "empty_at_s": _optional(block.empty_at_s, n),
        "range_km": _optional(block.range_m, n, 1e-3),
        "range_reserve_km": _optional(block.range_reserve_m, n, 1e-3),
        "over_power": _optional(block.over_power, n),
        "over_speed": _optional(block.over_speed, n),
        **_truth_columns(block, mass_source),
    }


def _truth_columns(block: SweepBlock, mass_source: str) -> dict[str, object]:
    """:data:`TRUTH_COLUMNS` of a block: its rows' mass source, and a stored trip's
    measured consumption (litres for a fuel measurement, kWh for a battery one) with the
    error of each row of the matching powertrain, when the rows are at the trip's own
    mass (not at a --mass-kg or --payload-kg given for every source)."""
    n = block.n
    fuel, energy, error = np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan)
    measured = getattr(block.source, "measured", None)  # a stored trip's (cevm.store.sources.StoredTrip)
    if measured is not None and measured.value > 0:
        if measured.kind == "fuel_l":
            fuel[:], modelled = measured.value, block.fuel_l
        else:
            energy[:], modelled = measured.value / J_PER_KWH, block.energy_j
        if mass_source not in ("--mass-kg", "--payload-kg"):
            error = 100.0 * (modelled - measured.value) / measured.value  # NaN on rows of the other powertrain
    return {"mass_source": (np.zeros(n, dtype=np.int64), [mass_source]), "measured_fuel_l": fuel,
            "measured_energy_kwh": energy, "error_pct": error}


def _optional(values: np.ndarray | None, n: int, scale: float = 1.0) -> np.ndarray:
    """An optional block array in output units (NaN where the block has none)."""
    return np.full(n, np.nan) if values is None else values * scale


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
    """One text cell as CSV bytes: control characters escaped, quoted as
    :func:`cevm.cli.output.csv_writer` quotes."""
    if not s:
        return b""
    buf = io.StringIO()
    csv_writer(buf).writerow([printable(s)])
    return buf.getvalue().rstrip("\n").encode("utf-8")


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

    def __init__(self, fmt: OutputFormat, stream: IO[str], temperature_used: bool = False):
        self.fmt = fmt
        self.stream = stream
        self.temperature_used = temperature_used
        self.pending: list[tuple[SweepBlock, str]] = []
        self.pending_rows = 0
        self.rows = 0
        self.table_rows: list[dict] = []
        self.names: dict[str, tuple[str, str | None]] = {}
        self.started = False

    def add(self, block: SweepBlock, mass_source: str = "vehicle file") -> None:
        self.rows += block.n
        if self.fmt == OutputFormat.table:
            if len(self.table_rows) < TABLE_MAX_ROWS:
                self._table_add(block, mass_source)
            return
        self.pending.append((block, mass_source))
        self.pending_rows += block.n
        if self.pending_rows >= WRITE_BATCH_ROWS:
            self._flush()

    def _flush(self) -> None:
        if not self.pending:
            return
        cols = _concat_columns([_block_columns(b, m) for b, m in self.pending])
        is_ev = np.concatenate([b.pset.is_ev for b, _ in self.pending])
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

    def _table_add(self, block: SweepBlock, mass_source: str) -> None:
        cols = _block_columns(block, mass_source)
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
            self.table_rows.append(_with_status(row))
            self.names[row["vehicle_key"]] = (row["vehicle"], row.get("ice_braking"))

    def close(self) -> None:
        if self.fmt == OutputFormat.table:
            rows = self.table_rows
            columns = ["cycle", "vehicle_key", "mass_kg", "mass_source", "distance_km", "energy_kwh",
                       "measured_energy_kwh", "energy_kwh_per_km", "soc_min_pct", "fuel_l", "measured_fuel_l",
                       "error_pct", "fuel_l_per_100km", "range_km", "status"]
            columns = [c for c in columns if any(r.get(c) is not None for r in rows)]
            if "error_pct" in columns:  # measured beside modelled: the per-km figures only in csv and json
                columns = [c for c in columns if c not in ("energy_kwh_per_km", "fuel_l_per_100km")]
            else:  # at masses given for every source the measurement is no comparison: csv and json only
                columns = [c for c in columns if c not in ("measured_energy_kwh", "measured_fuel_l")]
            if self.temperature_used:
                columns.insert(3, "ambient_c")
            title = "cevm predict" + (f" (first {len(rows)} of {self.rows} rows)" if self.rows > len(rows) else "")
            write_rows(rows, OutputFormat.table, columns=columns, title=title, digits=PREDICT_DIGITS,
                       headers=PREDICT_HEADERS, stream=self.stream)
            legend = vehicle_legend(self.names)
            if legend:
                self.stream.write(legend + "\n")
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
        self.origins: list[set] = [set() for _ in range(nv)]
        self.m_lo = np.full(nv, np.inf)
        self.m_hi = np.full(nv, -np.inf)

    def add(self, block: SweepBlock) -> None:
        vi = block.pset.vehicle_index  # a stored trip's block has a set at its own mass
        np.minimum.at(self.m_lo, vi, block.pset.mass_kg)
        np.maximum.at(self.m_hi, vi, block.pset.mass_kg)
        np.minimum.at(self.t_lo, vi, block.ambient_c)
        np.maximum.at(self.t_hi, vi, block.ambient_c)
        for v, code in set(zip(vi.tolist(), block.ambient_from.astype(int).tolist())):
            self.origins[v].add(AMBIENT_ORIGINS[code])
        src = block.source
        if src.duration_s > 0:
            speed = src.distance_m / src.duration_s
            self.v_lo, self.v_hi = min(self.v_lo, speed), max(self.v_hi, speed)

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
            for w in domain_warnings(veh, mass_kg=masses, ambient_c=np.array([lo, hi]), mean_speed_mps=speeds):
                out.append(f"cevm: warning: {w}")
        return out

def _count_flags(block: SweepBlock) -> np.ndarray:
    """How many rows of a block run empty on the way, ask too much power, ask too much
    speed."""
    def flagged(a: np.ndarray | None) -> int:
        return 0 if a is None else int(np.count_nonzero(a == 1.0))

    empty = 0 if block.empty_at_m is None else int(np.count_nonzero(np.isfinite(block.empty_at_m)))
    return np.array([empty, flagged(block.over_power), flagged(block.over_speed)])


def _with_status(row: dict) -> dict:
    """A table row with its 'status': reserve kept (EV) or tank enough (ICE), and where
    it is not, the first kilometre that fails; over max gross; what the vehicle cannot
    follow."""
    ev = row["powertrain"] == "ev"
    ok = row["reserve_ok"] if ev else row["tank_ok"]
    status = "?" if ok is None else "yes" if ok else "NO"
    if row.get("empty_at_km") is not None:
        status += f" (empty at {row['empty_at_km']:,.1f} km)"
    elif ev and row.get("reserve_at_km") is not None:
        status += f" (reserve at {row['reserve_at_km']:,.1f} km)"
    if row["over_max_gross"]:
        status += " (over max gross)"
    cannot = [what for what, key in (("power", "over_power"), ("speed", "over_speed")) if row.get(key)]
    if cannot:
        status += f" (cannot follow: {', '.join(cannot)})"
    row["status"] = status
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
        Optional[list[str]],
        typer.Option("--mass-kg", "-m", metavar="KG", help="Gross mass in kg: a value, a list a,b or a range start:stop:step "
                                             "(stop included). Repeatable. Default: each vehicle's mass_kg."),
    ] = None,
    payload_kg: Annotated[
        Optional[list[str]],
        typer.Option("--payload-kg", "-p", metavar="KG", help="Payload in kg on each vehicle's kerb mass: a value, a list or a "
                                                "range such as 0:26000:2000 (14 values, stop included). Repeatable."),
    ] = None,
    soc_start: SocStartOption = DEFAULT_SOC_START_PCT,
    reserve_pct: ReserveOption = DEFAULT_RESERVE_PCT,
    fmt: FormatOption = OutputFormat.table,
    out: OutOption = None,
    plot: Annotated[
        Optional[Path],
        typer.Option(metavar="FILE.png", help="Write a PNG: state of charge along each source (one mass per vehicle), or energy "
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
        Optional[int], typer.Option("--workers", "-w", min=1, metavar="N", help="Worker processes, a batch of sources per task "
                                    "(default 1: in this process; a large sweep of many routes runs ~1.3x faster "
                                    "on 2 cores, a small one is slower for the processes' start).")
    ] = None,
    scheduler: Annotated[
        Optional[str], typer.Option(help="Dask scheduler address (tcp://HOST:8786): evaluate the batches on that "
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
    if mass_kg and payload_kg:
        raise fail("give --mass-kg or --payload-kg, not both")
    if workers is not None and scheduler is not None:
        raise fail("give --workers (local processes) or --scheduler (a Dask cluster), not both")
    check_workers(workers)
    check_common(ice_braking, soc_start, reserve_pct)
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
            executor = stack.enter_context(make_executor(None if scheduler else (workers or 1), scheduler))
            stream = open_out(stack, out)
            writer = _PredictWriter(fmt, stream, temperature_used=any(uses_temperature(v) for v in vehicles))
            keep_for_plot = plot is not None and np.bincount(pset.vehicle_index).max() > 1
            flagged = np.zeros(3, dtype=np.int64)
            plot_data, psets = [], []
            over, used = 0, Counter()
            for run, run_pset, mass_source in _mass_runs(sources, pset, vehicles, masses, payloads, ice_braking,
                                                         ambient_c):
                for block in sweep(run, run_pset, soc_start_pct=soc_start, reserve_pct=reserve_pct,
                                   executor=executor, ranges=with_range):
                    flagged += _count_flags(block)
                    writer.add(block, mass_source)
                    assumed.add(block)
                    over += int(run_pset.over_max_gross.sum())
                    if block.source.kind == "trip":
                        used[mass_source] += 1
                    if keep_for_plot and len(psets) < PLOT_MAX_LINES:
                        plot_data.append({"energy_kwh": block.energy_j / J_PER_KWH, "fuel_l": block.fuel_l})
                    psets.append(run_pset)
                    if plot is None:
                        block.source.release()  # free its profile: the sweep is past it
            writer.close()
            if plot is not None:
                plot_predictions(plot, sources, pset if keep_for_plot else psets, plot_data, soc_start, reserve_pct,
                                 ice_braking, warn=lambda message: typer.echo(message, err=True))
    except CevmError as exc:
        raise fail(exc) from None
    for line in assumed.lines():
        typer.echo(line, err=True)
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
                                                "(column over_speed)")):
        if n_rows:
            typer.echo(f"cevm: warning: {n_rows} predictions {what}", err=True)
    if out is not None and fmt != OutputFormat.table:
        typer.echo(f"cevm predict: {writer.rows} rows -> {out}", err=True)
    for exc in skipped:
        warn_damaged(exc)
    if skipped:
        raise typer.Exit(EXIT_PARTIAL)

