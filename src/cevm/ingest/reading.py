"""Reading stage of ``cevm ingest``: logger CSV exports -> canonical log frames.

A logger is described by a *profile* (:mod:`cevm.ingest.profiles`).
:func:`read_log` turns one file into one :class:`ParsedLog` per vehicle: a DataFrame
with canonical columns in SI units (rows in file order; cleaning, sorting and trip
splitting are later stages), the file's metadata, the energy sources available, and a
human-readable list of every repair made while reading. Bad input raises
:class:`cevm.errors.InputError` naming file, line and column.

A file is streamed, never held whole: its bytes, decompressed and decoded in chunks
(:mod:`cevm.ingest.textfile`, within :class:`ReadLimits`), are cut into blocks of whole
lines of about 4 MiB, and each block is parsed on its own into the columns the profile
maps (the others are dropped by the parser), so the memory of reading a file is that of
its canonical columns plus one block; the blocks' pieces are returned to the system once
a column is joined. A column that is in SI as logged and whose every value is exactly a
float32 (binary steps: 1/8 rpm, whole kg, 1/32 degC, a 0/1 switch) is kept as float32,
the same values in half the memory; file lines are int32. Each block is parsed by
pyarrow's CSV reader on one thread, numbers and ISO 8601 times included; a block that
reader refuses (a row with fewer or more fields than the header, a value that is not a
number, mixed time notation, ...) is parsed again by pandas' C parser, which either
repairs what it can (and says so) or raises the error with its line and column.

Everything is vectorised (pyarrow, pandas, numpy); nothing loops over rows in Python.

Not handled: quoted fields holding line breaks (line numbers would shift).
"""

from __future__ import annotations

import csv
import hashlib
import io
import re
from dataclasses import dataclass, field
from functools import cached_property, lru_cache
from pathlib import Path
from typing import Literal

import numpy as np
import pandas as pd

from cevm.errors import InputError, has_control
from cevm.runtime import release_free_memory
from cevm.ingest.profiles import VIRTUAL_COLUMNS, ColumnMap, EnergySpec, Profile, load_profiles
from cevm.ingest.textfile import (MAX_LINE_BYTES, ByteStream, ReadLimits, Utf8Stream, _ascii_transparent,
                                  sniff_bom, utf16_hint)
from cevm.ingest.timestamps import EPOCH_FORMATS, NAT, NS_PER_DAY, epoch_ns, fast_first_column, parse_datetimes

__all__ = [
    "PLAUSIBLE_RANGE_SI",
    "EnergySource",
    "ParsedLog",
    "ReadLimits",
    "detect_profile",
    "read_log",
]

# Physically possible values (SI, inclusive). A value outside is *absurd*: a logger error
# or a wrong unit/column in the profile, never a real measurement. Chosen wide so that
# no real value of any road vehicle falls outside.
PLAUSIBLE_RANGE_SI: dict[str, tuple[float, float]] = {
    "lat_deg": (-90.0, 90.0),
    "lon_deg": (-180.0, 180.0),
    "gps_alt_m": (-500.0, 9000.0),  # Dead Sea shore -430 m .. highest roads ~5800 m + GPS error
    "gps_speed_mps": (0.0, 100.0),  # 360 km/h
    "wheel_speed_mps": (0.0, 100.0),
    "gps_hdop": (0.0, 100.0),  # 99.99 is the usual "no fix" value
    "ignition": (0.0, 1.0),
    "odometer_m": (0.0, 1e10),  # 10 million km
    "gross_weight_kg": (0.0, 200_000.0),
    "fuel_rate_lps": (0.0, 0.5),  # 1800 l/h
    "flowmeter_fuel_lps": (0.0, 0.5),
    "total_fuel_l": (0.0, 2.2e9),  # FMS counter maximum 0xFFFFFFFF * 0.5 l
    "total_energy_j": (-3.6e15, 3.6e15),  # +-1e9 kWh
    "battery_voltage_v": (0.0, 2000.0),
    "battery_current_a": (-5000.0, 5000.0),
    "soc_pct": (0.0, 100.0),
    "accel_pedal_pct": (0.0, 100.0),  # FMS codes above 100 % are error / not available
    "brake_switch": (0.0, 1.0),
    "engine_speed_rpm": (-30000.0, 30000.0),  # electric motors may report reverse as negative
    "engine_torque_pct": (-125.0, 125.0),
    # coldest and hottest air a road vehicle meets (-60 .. +57 degC on record) with margin;
    # the FMS "not available" code 0xFFFF reads 1775 degC and is caught
    "ambient_temp_c": (-80.0, 80.0),
    "hvac_power_w": (0.0, 150_000.0),  # a coach's heaters and A/C draw tens of kW
}

# Times outside this window are absurd (unset clocks read 1970 or 2000; corrupt dates).
_TIME_MIN = np.datetime64("1990-01-01T00:00:00", "ns").astype(np.int64)
_TIME_MAX = np.datetime64("2100-01-01T00:00:00", "ns").astype(np.int64)


# Text that means "no value" in a numeric column (besides an empty field).
_NUMERIC_NA = ["", "NA", "N/A", "n/a", "NaN", "nan", "null", "NULL", "None", "-", "--"]

#: Text parsed at a time: blocks of whole lines of about this many bytes.
BLOCK_BYTES = 4 << 20

#: Parsers: "pyarrow" (default; pandas explains or repairs a block it refuses) or
#: "pandas" (the parser before pyarrow, kept for comparison in benchmarks).
Engine = Literal["pyarrow", "pandas"]


# ======================================================================================
# Parsed logs
# ======================================================================================


@dataclass(frozen=True)
class EnergySource:
    """A measured-energy column present in a parsed log, for the consumption stage.

    Parameters
    ----------
    column : canonical column of ``ParsedLog.frame`` holding the measurement, or the
        virtual ``"battery_power_w"`` (= battery_voltage_v * battery_current_a, both in
        the frame; formed by :mod:`cevm.ingest.consumption`).
    kind : ``"rate"`` (fuel rate [l/s] or battery power [W], integrate over time),
        ``"counter"`` (cumulative total [l] or [J], take differences; may wrap or reset)
        or ``"soc"`` (state of charge [%]; energy = -delta SoC / 100 * ``capacity_j``).
    quantity : ``"fuel_l"`` (litres of fuel) or ``"energy_j"`` (joules at the battery).
    resolution : quantisation step in the column's SI unit: l/s for a fuel rate, W for
        battery power, l for a fuel counter, J for an energy counter, % for a state of
        charge; 0 when unknown or continuous.
    priority : trust rank, 1 = most trusted (e.g. the flow meter on trucks, the FMS total
        energy on buses, per LOGGERS.md); the consumption stage prefers the lowest number
        among sources of the same quantity that have usable data.
    capacity_j : usable battery capacity [J] for ``kind == "soc"`` when the profile knows
        it (the Twizy's 6.1 kWh); ``None`` otherwise (take it from the vehicle config).
    source_column : the logger's own column name(s), for messages.
    modulus : value at which a counter wraps to 0 (same unit), when the profile knows it
        (the FMS 32-bit fuel counter at 0.5 l per bit: 2**31 l); ``None`` otherwise.
    accuracy_pct : the profile's systematic (calibration) uncertainty of the source, 1
        sigma, in % of the value; ``None``: the default of its kind
        (:data:`cevm.ingest.consumption.DEFAULT_ACCURACY_PCT`).
    """

    column: str
    kind: Literal["rate", "counter", "soc"]
    quantity: Literal["fuel_l", "energy_j"]
    resolution: float
    priority: int
    capacity_j: float | None = None
    source_column: str = ""
    modulus: float | None = None
    accuracy_pct: float | None = None

@dataclass(frozen=True, eq=False)
class ParsedLog:
    """One vehicle's rows of one logger file, in canonical columns.

    ``frame`` has ``time_s`` (UTC seconds since the Unix epoch, float64),
    ``source_line`` (1-based line in the file, int32; int64 past 2**31 lines),
    ``vehicle_id`` (categorical: one id) and every canonical column the profile maps and
    the file has (SI, NaN = no value; float64, or float32 where the column is SI as
    logged and every value is exactly a float32: the same values), rows in file order.
    ``repairs`` lists every repair made while reading the file (file-wide, so shared by
    the logs of a multi-vehicle file).
    ``sha256`` is the hex digest of the file's bytes on disk (compressed bytes for a .gz
    file), computed on first use from the file (the ingest pipeline hashes files
    itself, before reading them).
    """

    path: Path
    profile: str
    vehicle_id: str
    frame: pd.DataFrame
    metadata: dict[str, str]
    energy_sources: tuple[EnergySource, ...]
    repairs: list[str]

    @cached_property
    def sha256(self) -> str:
        """Hex SHA-256 of the file's bytes on disk."""
        with open(self.path, "rb") as fh:
            return hashlib.file_digest(fh, "sha256").hexdigest()


# ======================================================================================
# Detection from the first bytes
# ======================================================================================

#: Bytes read from the start of a file to detect its profile.
_HEAD_BYTES = 65536

#: Bytes that never occur in a text CSV: C0 controls other than tab, LF, CR; and DEL.
_BINARY_BYTES = bytes(b for b in range(32) if b not in (9, 10, 13)) + b"\x7f"


def _looks_binary(head: bytes) -> bool:
    """True when the first bytes hold a NUL, or more than 1 % control bytes: a binary file
    (an image, a spreadsheet, random junk), whatever the text encoding would be."""
    sample = head[:8192]
    if b"\x00" in sample:
        return True
    n_ctrl = len(sample) - len(sample.translate(None, _BINARY_BYTES))
    return n_ctrl > 0.01 * len(sample)

def _head_bytes(path: Path, n: int = _HEAD_BYTES) -> bytes:
    """First ``n`` bytes of the (decompressed) file, for detection."""
    with ByteStream(path, ReadLimits()) as raw:
        return raw.peek(n)


def detect_profile(path: str | Path, profiles: dict[str, Profile] | None = None) -> Profile:
    """The profile whose required header columns all appear in the file's header.

    The header is read with each profile's own encoding, comment prefix and separator.
    When several match, the most specific (most required columns) wins; a tie, or no
    match, raises :class:`InputError` listing the profiles and the header found.
    """
    path = Path(path)
    profiles = load_profiles() if profiles is None else profiles
    if not profiles:
        raise InputError(path, "no logger profiles loaded")
    return _detect_in_head(path, _head_bytes(path), profiles)

def _detect_in_head(path: Path, head: bytes, profiles: dict[str, Profile]) -> Profile:
    """:func:`detect_profile` on the first bytes ``head`` of the (decompressed) file.

    A byte order mark decides the encoding for every profile (UTF-16 and UTF-32 text is
    decoded, not called binary); otherwise each profile's own encoding is tried."""
    if not head or head.isspace():
        raise InputError(path, "file is empty", line=1)
    bom = sniff_bom(head)
    if bom is not None:
        enc, n = bom
        head = head[n:].decode(enc, errors="replace").encode("utf-8")
        if not head or head.isspace():
            raise InputError(path, "file is empty", line=1)
    if _looks_binary(head):
        raise InputError(path, "binary data, not a CSV text file" + utf16_hint(head), line=1)
    matches: list[Profile] = []
    seen_header: tuple[str, ...] = ()
    ascii_head = head.isascii()
    for prof in profiles.values():
        try:
            if bom is not None or (ascii_head and _ascii_transparent(prof.encoding)):
                text = head  # what decoding and re-encoding as UTF-8 would give
            else:
                text = head.decode(prof.encoding, errors="replace").encode("utf-8")
        except LookupError:
            continue
        hdr = _find_header(text, prof.comment_prefix, prof.separator)
        if hdr is None:
            continue
        if len(hdr.names) > len(seen_header):
            seen_header = hdr.names
        if set(prof.required_columns) <= set(hdr.names):
            matches.append(prof)
    if not matches:
        shown = ", ".join(seen_header[:12]) + (", ..." if len(seen_header) > 12 else "")
        listing = "; ".join(f"{p.name} (needs {', '.join(p.required_columns)})" for p in profiles.values())
        raise InputError(path, f"no logger profile matches the header [{shown}]; profiles: {listing}. "
                               "Add a profile (see configs/loggers) or force one.")
    best = max(len(p.required_columns) for p in matches)
    top = [p for p in matches if len(p.required_columns) == best]
    if len(top) > 1:
        raise InputError(path, f"header matches several profiles equally well: {', '.join(p.name for p in top)}; force one")
    return top[0]


# ======================================================================================
# Header and metadata
# ======================================================================================


@dataclass(frozen=True)
class _Header:
    names: tuple[str, ...]
    line: int  # 1-based line of the header
    body_offset: int  # byte offset of the first data line
    comments: tuple[str, ...]
    comment_lines: tuple[int, ...] = ()  # 1-based line of each comment


def _find_header(data: bytes, prefix: str, sep: str) -> _Header | None:
    """Skip blank and comment lines; parse the header line. ``None`` if there is none."""
    pbytes = prefix.encode("utf-8") if prefix else None
    pos, line_no, comments, comment_lines = 0, 0, [], []
    n = len(data)
    while pos < n:
        nl = data.find(b"\n", pos)
        end = n if nl < 0 else nl
        line_no += 1
        raw_line = data[pos:end].strip()
        nxt = n if nl < 0 else nl + 1
        if pbytes and raw_line.startswith(pbytes):
            comments.append(raw_line[len(pbytes):].decode("utf-8", errors="replace").strip())
            comment_lines.append(line_no)
        elif raw_line:
            text = raw_line.decode("utf-8", errors="replace").replace("\r", " ")
            names = next(csv.reader([text], delimiter=sep))
            return _Header(tuple(s.strip() for s in names), line_no, nxt, tuple(comments), tuple(comment_lines))
        pos = nxt
    return None


def _parse_metadata(comments: tuple[str, ...]) -> dict[str, str]:
    """``key=value`` comment lines as a dict (stripped; later keys win)."""
    meta = {}
    for c in comments:
        k, eq, v = c.partition("=")
        if eq and k.strip():
            meta[k.strip()] = v.strip()
    return meta

def _read_header(text: Utf8Stream, prof: Profile, path: Path) -> tuple[_Header, dict[str, str], bytes]:
    """The header line (after comments and blank lines), the metadata comments, and the
    text after the header read so far. Reads only as far as the header's line end; a
    first line longer than :data:`MAX_LINE_BYTES` (a file without line breaks) is
    refused there."""
    parts: list[bytes] = []
    while True:
        chunk = text.read()
        eof = not chunk
        if chunk:
            parts.append(chunk)
        data = b"".join(parts) if len(parts) != 1 else parts[0]
        parts = [data] if data else []
        if eof and (not data or data.isspace()):  # isspace stops at the first other byte
            raise InputError(path, "file is empty", line=1)
        last_nl = data.rfind(b"\n")
        if len(data) - last_nl - 1 > MAX_LINE_BYTES:
            line = data.count(b"\n") + 1
            raise InputError(path, f"no line break in {MAX_LINE_BYTES >> 20} MiB of text from line {line}: not a "
                                   "CSV log (a line that long is binary data or a file without line breaks)",
                             line=line)
        complete = data if eof else data[:last_nl + 1]  # whole lines only: a cut header waits for its end
        try:
            hdr = _find_header(complete, prof.comment_prefix, prof.separator)
        except csv.Error as exc:
            raise InputError(path, f"unreadable header line: {exc}", line=complete.count(b"\n")) from None
        if hdr is not None:
            metadata = _parse_metadata(hdr.comments) if prof.metadata == "key=value" else {}
            return hdr, metadata, data[hdr.body_offset:]
        if eof:
            raise InputError(path, "no header line (only comments or blank lines)", line=data.count(b"\n") + 1)


@dataclass(frozen=True)
class _ColumnPlan:
    """Which of the header's columns the profile reads, and as what."""

    names: list[str]  # the header's column names
    unique_names: list[str]  # the same, duplicates made unique (name NUL index)
    maps: list[ColumnMap]  # the profile's column maps whose source is in the header
    text_cols: list[str]  # read as text: time columns, vehicle column, value-map columns
    num_cols: list[str]  # read as numbers
    used: list[str]  # text_cols + num_cols, each once

def _plan_columns(prof: Profile, hdr: _Header, path: Path) -> _ColumnPlan:
    """The columns to read; a header lacking a required, time or vehicle column, or
    naming a used column twice, is an error at the header's line."""
    names = list(hdr.names)
    missing_req = [c for c in prof.required_columns if c not in names]
    if missing_req:
        raise InputError(path, f"header lacks column(s) {missing_req} required by profile {prof.name!r}",
                         line=hdr.line, column=missing_req[0])
    for c in prof.time.columns:
        if c not in names:
            raise InputError(path, f"no time column: header lacks {c!r} (profile {prof.name!r})", line=hdr.line, column=c)
    if prof.vehicle_source == "column" and prof.vehicle_key not in names:
        raise InputError(path, f"header lacks the vehicle column {prof.vehicle_key!r}", line=hdr.line, column=prof.vehicle_key)
    maps = [m for m in prof.columns if m.source in names]
    for m in prof.columns:
        if m.required and m.source not in names:
            raise InputError(path, f"header lacks required column {m.source!r}", line=hdr.line, column=m.source)
    text_cols = list(prof.time.columns) + ([prof.vehicle_key] if prof.vehicle_source == "column" else [])
    text_cols += [m.source for m in maps if m.value_map is not None]
    num_cols = [m.source for m in maps if m.value_map is None]
    used = list(dict.fromkeys(text_cols + num_cols))
    dups = sorted({c for c in used if names.count(c) > 1})
    if dups:
        raise InputError(path, f"column name(s) {dups} appear more than once in the header", line=hdr.line, column=dups[0])
    unique_names = [f"{n}\x00{i}" if names.count(n) > 1 else n for i, n in enumerate(names)]
    return _ColumnPlan(names, unique_names, maps, text_cols, num_cols, used)

def _column_finder(names: list[str], sep: str):
    """For :attr:`Utf8Stream.column_of`: the header column of a byte in a data line."""
    sepb = sep.encode()

    def column_of(_before: bytes, line_bytes: bytes) -> str | None:
        k = line_bytes.count(sepb)
        return names[k] if k < len(names) else None

    return column_of


def _column_finder_before_header(prof: Profile):
    """For :attr:`Utf8Stream.column_of` while the header is not read yet: the header
    found in the text before the bad line, if any."""

    def column_of(before: bytes, line_bytes: bytes) -> str | None:
        hdr = _find_header(before, prof.comment_prefix, prof.separator)
        if hdr is None or hdr.body_offset > len(before):
            return None
        return _column_finder(list(hdr.names), prof.separator)(before, line_bytes)

    return column_of


# ======================================================================================
# Lines, date repair and time zones
# ======================================================================================


_CHUNK_BYTES = 1 << 22  # 4 MiB: keeps temporaries in cache and avoids huge allocations


def _line_stats(b: np.ndarray, sep: int) -> tuple[np.ndarray, np.ndarray]:
    """(byte offset of the start of every line, number of ``sep`` bytes on it) of the
    text ``b`` (uint8 view), computed in chunks of whole lines of about 4 MiB (a loop
    over blocks, not rows): counts per line by ``np.add.reduceat`` of the separator
    mask, no array of separator positions."""
    parts = [np.zeros(1, np.int64)]
    for lo in range(0, len(b), _CHUNK_BYTES):
        parts.append(np.flatnonzero(b[lo:lo + _CHUNK_BYTES] == 10) + (lo + 1))
    starts = np.concatenate(parts)
    if starts[-1] >= len(b):
        starts = starts[:-1]
    n_sep = np.empty(len(starts), np.int64)
    i, n = 0, len(starts)
    while i < n:  # lines i..j-1, bytes starts[i]..hi
        lo = int(starts[i])
        j = max(int(np.searchsorted(starts, lo + _CHUNK_BYTES, side="left")), i + 1)
        hi = int(starts[j]) if j < n else len(b)
        is_sep = (b[lo:hi] == sep).view(np.uint8)
        n_sep[i:j] = np.add.reduceat(is_sep, starts[i:j] - lo, dtype=np.int32)
        i = j
    return starts, n_sep

def _only_trailing_separators(b: np.ndarray, starts: np.ndarray, surplus: np.ndarray, sep: int,
                              max_surplus: int = 8) -> np.ndarray:
    """Per line: whether its ``surplus`` (> 0) extra fields are empty, i.e. the line
    ends with that many separators (before an optional CR). Lines with more than
    ``max_surplus`` extra fields are never excused (a merged or corrupt line)."""
    ends = np.append(starts[1:], len(b))  # one past the '\n' (or end of data)
    last = ends - 1
    last = np.where((last >= 0) & (b[np.maximum(last, 0)] == 10), last - 1, last)  # skip '\n'
    last = np.where((last >= 0) & (b[np.maximum(last, 0)] == 13), last - 1, last)  # skip '\r'
    ok = (surplus > 0) & (surplus <= max_surplus)
    for k in range(max_surplus):  # loop over surplus fields, not rows
        need = ok & (surplus > k)
        pos = last - k
        ok &= ~need | ((pos >= starts) & (b[np.maximum(pos, 0)] == sep))
    return ok

def _lines_summary(lines: np.ndarray, limit: int = 6) -> str:
    """'lines 3-7, 12, 20-21' for sorted line numbers, at most ``limit`` runs shown."""
    lines = np.asarray(lines, np.int64)
    if len(lines) == 0:
        return "no lines"
    breaks = np.flatnonzero(np.diff(lines) != 1) + 1
    starts = np.concatenate([[0], breaks])
    ends = np.concatenate([breaks - 1, [len(lines) - 1]])
    runs = [f"{lines[s]}" if s == e else f"{lines[s]}-{lines[e]}" for s, e in zip(starts[:limit], ends[:limit])]
    more = f", ... ({len(starts) - limit} more runs)" if len(starts) > limit else ""
    return ("line " if len(lines) == 1 else "lines ") + ", ".join(runs) + more

def _fmt_ns(ns: int) -> str:
    return str(np.datetime64(int(ns), "ns").astype("datetime64[s]")).replace("T", " ")

def _repair_dates(date_ns: np.ndarray, tod_ns: np.ndarray, raw_dates: np.ndarray, lines: np.ndarray,
                  max_days: float, path: Path, col: str, repairs: list[str]) -> np.ndarray:
    """Replace corrupt dates (unparseable, or more than ``max_days`` from the file's
    most common date) by the date of the nearest preceding good row (following row for
    a corrupt run at the start), plus or minus one day where the time of day wrapped
    past midnight between that row and this one (a jump of more than 12 h)."""
    n = len(date_ns)
    valid = date_ns != NAT
    if not valid.any():
        raise InputError(path, "no row has a readable date", line=int(lines[0]), column=col)
    uniq, counts = np.unique(date_ns[valid], return_counts=True)
    dominant = uniq[np.argmax(counts)]
    bad = ~valid | (np.abs(date_ns - dominant) > max_days * NS_PER_DAY)
    if not bad.any():
        return date_ns
    idx = np.arange(n)
    prev = np.maximum.accumulate(np.where(~bad, idx, -1))
    nxt = np.minimum.accumulate(np.where(~bad, idx, n)[::-1])[::-1]
    donor = np.where(prev >= 0, prev, nxt)
    b = np.flatnonzero(bad)
    d = donor[b]
    half_day = NS_PER_DAY // 2
    shift = np.zeros(len(b), np.int64)
    from_prev = prev[b] >= 0
    shift[from_prev & (tod_ns[b] < tod_ns[d] - half_day)] = NS_PER_DAY
    shift[~from_prev & (tod_ns[b] > tod_ns[d] + half_day)] = -NS_PER_DAY
    fixed = date_ns.copy()
    fixed[b] = date_ns[d] + shift
    examples = pd.unique(pd.Series(raw_dates[b]).astype(str))[:4]
    repairs.append(
        f"time: {len(b)} rows with a corrupt date (e.g. {', '.join(repr(x) for x in examples)}; "
        f"the file's date is {_fmt_ns(dominant)[:10]}) took the date of the neighbouring rows, "
        f"the time of day kept: {_lines_summary(lines[b])}"
    )
    return fixed

def _localize(naive: np.ndarray, tz: str, groups: np.ndarray | None, lines: np.ndarray,
              repairs: list[str]) -> np.ndarray:
    """UTC ns of naive local times in zone ``tz``, in file order.

    Ambiguous times (the repeated hour when clocks go back) are resolved by row order
    within each group (vehicle): summer time until the local time first steps backwards
    inside the repeated hour, standard time from then on. Non-existent times (the hour
    skipped when clocks go forward) are read with the offset in force just before the
    jump (a logger clock that has not changed yet). Both are reported as repairs.
    """
    if tz in ("UTC", "Etc/UTC", "GMT", "Z"):
        return naive
    idx = pd.DatetimeIndex(naive.view("datetime64[ns]"))
    loc = idx.tz_localize(tz, ambiguous="NaT", nonexistent="NaT")
    odd = np.asarray(loc.isna()) & (naive != NAT)
    if not odd.any():
        return loc.tz_convert("UTC").as_unit("ns").asi8
    sub = idx[odd]
    as_dst = sub.tz_localize(tz, ambiguous=np.ones(len(sub), bool), nonexistent="NaT")
    nonexist_sub = np.asarray(as_dst.isna())
    odd_idx = np.flatnonzero(odd)
    amb_rows = odd_idx[~nonexist_sub]
    gap_rows = odd_idx[nonexist_sub]
    dst_flags = np.ones(len(naive), bool)
    if len(amb_rows):
        g = groups[amb_rows] if groups is not None else np.zeros(len(amb_rows), np.int64)
        day = naive[amb_rows] // NS_PER_DAY
        frame = pd.DataFrame({"g": g, "day": day, "t": naive[amb_rows]})
        back = frame.groupby(["g", "day"], sort=False)["t"].diff() < 0
        second = back.groupby([frame["g"], frame["day"]], sort=False).cumsum() > 0
        second = second.to_numpy()
        dst_flags[amb_rows[second]] = False
        repairs.append(
            f"time: {len(amb_rows)} rows fall in the repeated hour when clocks went back ({tz}); "
            f"{int(second.sum())} read as standard time after the local time stepped back, "
            f"the others as summer time (by row order): {_lines_summary(lines[amb_rows])}"
        )
    out = idx.tz_localize(tz, ambiguous=dst_flags, nonexistent="NaT").tz_convert("UTC").as_unit("ns").asi8.copy()
    if len(gap_rows):
        before = pd.DatetimeIndex((naive[gap_rows] - NS_PER_DAY).view("datetime64[ns]"))
        before_loc = before.tz_localize(tz, ambiguous=True, nonexistent="shift_forward")
        offset = (before_loc.tz_localize(None).as_unit("ns").asi8
                  - before_loc.tz_convert("UTC").tz_localize(None).as_unit("ns").asi8)
        out[gap_rows] = naive[gap_rows] - offset
        repairs.append(
            f"time: {len(gap_rows)} rows have local times that do not exist (skipped hour when "
            f"clocks went forward, {tz}); read with the offset before the change: "
            f"{_lines_summary(lines[gap_rows])}"
        )
    return out

# ======================================================================================
# Reading
# ======================================================================================
def _resolve_profile(path: Path, profile: Profile | str | None,
                     profiles: dict[str, Profile] | None) -> Profile:
    if isinstance(profile, Profile):
        return profile
    if profiles is None:
        profiles = load_profiles()
    if profile is None:
        return detect_profile(path, profiles)
    if profile not in profiles:
        raise InputError(path, f"unknown logger profile {profile!r}; known: {', '.join(sorted(profiles))}")
    return profiles[profile]

def _line_col_error(path: Path, msg: str, lines: np.ndarray, bad: np.ndarray, col: str,
                    values=None, upto_line: int | None = None) -> InputError:
    """The error at the first ``bad`` row (its value from ``values`` if given), with the
    count of the other bad rows (up to ``upto_line`` when only part of the file was
    seen)."""
    i = int(np.flatnonzero(bad)[0])
    val = ""
    if values is not None:
        v = values[i]
        if isinstance(v, (float, np.floating, int, np.integer)):
            val = f" {float(v):g}"
        else:
            v = str(v)
            val = f" {v!r}" if len(v) <= 60 else f" {v[:50]!r}... ({len(v):,} characters)"
    n_more = int(bad.sum()) - 1
    extra = ""
    if n_more:
        extra = f" (and {n_more} more rows" + (f" up to line {upto_line})" if upto_line is not None else ")")
    return InputError(path, f"{msg}{val}{extra}", line=int(lines[i]), column=col)


def read_log(path: str | Path, profile: Profile | str | None = None,
             profiles: dict[str, Profile] | None = None, *,
             vehicle_id: str | None = None, limits: ReadLimits = ReadLimits(),
             engine: Engine = "pyarrow") -> list[ParsedLog]:
    """Read one logger CSV (plain or gzip-compressed) into one :class:`ParsedLog` per vehicle.

    Parameters
    ----------
    path : the file. Gzip is recognised by its magic bytes, whatever the extension.
    profile : a :class:`Profile`, a profile name (looked up in ``profiles``), or ``None``
        (default) to detect it from the header with :func:`detect_profile`.
    profiles : available profiles (default ``None``: :func:`load_profiles()`).
    vehicle_id : override the vehicle id from the profile (default ``None``: use the
        profile's vehicle source); not allowed for a file split by a vehicle column.
    limits : bounds on the file's size, gzip expansion and rows (:class:`ReadLimits`;
        default: its defaults).
    engine : ``"pyarrow"`` (default) or ``"pandas"``: the CSV parser of each block (see
        the module docstring); the result is the same.

    Returns
    -------
    One ParsedLog per vehicle in order of first appearance in the file.

    Raises
    ------
    InputError : empty file, header only, bad encoding, binary data, missing time
        column, unreadable time or number (with line and column), mixed time zone
        notation, a vehicle id holding a control character, no position and no speed, a
        column mostly absurd, a truncated last line when the profile says
        ``truncated_last_line = "error"``, a file over a limit of ``limits``.

    The stages, each a function of its own: the file's bytes, decompressed, and its
    profile (:func:`_open_log`); the text as UTF-8 (:class:`Utf8Stream`); the header and
    metadata (:func:`_read_header`) and the columns the profile needs from it
    (:func:`_plan_columns`); blocks of data lines (:func:`_data_blocks`) each parsed into
    the used columns (:func:`_parse_block`) and gathered (:class:`_Gather`: vehicle ids,
    times, value maps, per block); times to UTC (:meth:`_Gather.utc_ns`); columns mapped
    to canonical SI columns and checked (:func:`_canonical_columns`); one log per vehicle
    (:func:`_split_vehicles`).
    """
    path = Path(path)
    with ByteStream(path, limits) as raw:
        prof = _open_log(path, raw, profile, profiles)
        text = Utf8Stream(raw, prof.encoding, prof.name)
        text.column_of = _column_finder_before_header(prof)
        hdr, metadata, rest = _read_header(text, prof, path)
        plan = _plan_columns(prof, hdr, path)
        text.column_of = _column_finder(plan.names, prof.separator)
        repairs = _Repairs()
        gather = _Gather(plan, prof, path, limits, repairs)
        gather.set_vehicle(vehicle_id, metadata, hdr)
        for first_line, block, last in _data_blocks(text, rest, hdr, plan.names, prof, path, repairs):
            gather.add(_parse_block(block, first_line, plan, prof, path, engine, gather), last)
            del block
    lines = gather.lines()
    codes, vehicles = gather.vehicle_codes()
    utc = gather.utc_ns(codes, lines)
    out = _canonical_columns(gather.pop_columns(), plan.maps, utc, lines, prof, path, repairs.columns)
    return _split_vehicles(out, codes, vehicles, plan.maps, prof, path, metadata, repairs.all())


def _open_log(path: Path, raw: ByteStream, profile: Profile | str | None,
              profiles: dict[str, Profile] | None) -> Profile:
    """The profile given, or detected from the file's first bytes; a plain file over the
    size limit is refused before anything is read."""
    raw.check_size()
    if profile is None:
        profiles = load_profiles() if profiles is None else profiles
        if not profiles:
            raise InputError(path, "no logger profiles loaded")
        prof = _detect_in_head(path, raw.peek(_HEAD_BYTES), profiles)
    else:
        prof = _resolve_profile(path, profile, profiles)
    return prof


@dataclass
class _Repairs:
    """Repair messages by stage, put together in the order the stages run."""

    read: list[str] = field(default_factory=list)  # truncated last line
    rows: list[str] = field(default_factory=list)  # fewer fields, blank rows
    vehicle: list[str] = field(default_factory=list)
    time: list[str] = field(default_factory=list)
    columns: list[str] = field(default_factory=list)

    def all(self) -> list[str]:
        return self.read + self.rows + self.vehicle + self.time + self.columns


def _data_blocks(text: Utf8Stream, rest: bytes, hdr: _Header, names: list[str], prof: Profile, path: Path,
                 repairs: _Repairs):
    """Yield (first line number, block, is last) for blocks of whole data lines of about
    :data:`BLOCK_BYTES`; the last block may end without a line break. A truncated last
    line (fewer fields than the header, no line end) is dropped and reported, or an
    error if the profile says so; a body of blank lines only is "header only"; more than
    :data:`MAX_LINE_BYTES` without a line break is refused as soon as it is read."""
    first_line = hdr.line + 1
    parts, size = ([rest] if rest else []), len(rest)
    nl = rest.rfind(b"\n")
    has_nl, since_nl = nl >= 0, len(rest) - nl - 1  # bytes after the last line break read
    eof = seen_data = False
    while True:
        while not eof and (size < BLOCK_BYTES or not has_nl):
            chunk = text.read()
            if not chunk:
                eof = True
                break
            parts.append(chunk)
            size += len(chunk)
            k = chunk.rfind(b"\n")
            has_nl, since_nl = (True, len(chunk) - k - 1) if k >= 0 else (has_nl, since_nl + len(chunk))
            if since_nl > MAX_LINE_BYTES:
                line = first_line + sum(p.count(b"\n") for p in parts)
                raise InputError(path, f"no line break in {MAX_LINE_BYTES >> 20} MiB of text from line {line}: "
                                       "not a CSV log (binary data, or a file without line breaks)", line=line)
        data = b"".join(parts) if len(parts) != 1 else parts[0]
        if eof:
            data = _drop_truncated_last_line(data, first_line, names, prof, path, repairs)
            if not (seen_data or (data and not data.isspace())):
                raise InputError(path, "header only, no data rows", line=hdr.line + 1)
            yield first_line, data, True
            return
        cut = data.rfind(b"\n") + 1  # > 0: a line break was read
        block, tail = (data[:cut], data[cut:]) if cut < len(data) else (data, b"")
        del data
        parts, size, has_nl, since_nl = ([tail] if tail else []), len(tail), False, len(tail)
        seen_data = seen_data or not block.isspace()
        yield first_line, block, False
        first_line += block.count(b"\n")


def _drop_truncated_last_line(data: bytes, first_line: int, names: list[str], prof: Profile, path: Path,
                              repairs: _Repairs) -> bytes:
    """``data`` (the end of the file) without a truncated last line: one with fewer
    fields than the header and no line end (reported), or an error if the profile says
    ``truncated_last_line = "error"``."""
    if data and not data.endswith(b"\n"):
        last_start = data.rfind(b"\n") + 1
        last = data[last_start:]
        n_fields = _count_fields(last, prof.separator) if last.strip() else len(names)
        if last.strip() and n_fields < len(names):
            line_no = first_line + data.count(b"\n")
            if prof.truncated_last_line == "error":
                raise InputError(path, f"truncated last line: {n_fields} of {len(names)} fields",
                                 line=line_no, column=names[n_fields - 1] if n_fields else names[0])
            repairs.read.append(f"read: truncated last line ({n_fields} of {len(names)} fields) dropped: line {line_no}")
            return data[:last_start]
    return data


def _count_fields(line: bytes, sep: str) -> int:
    """Fields on one line, quotes respected where they parse (a stray carriage return
    or quote falls back to counting separators)."""
    text = line.decode("utf-8", errors="replace").replace("\r", " ")
    try:
        return len(next(csv.reader([text], delimiter=sep), []))
    except csv.Error:
        return text.count(sep) + 1


@dataclass
class _Part:
    """One block's rows, parsed: the file line of each row kept, numeric source columns
    (float64, the logger's units), text columns (object arrays, NaN = empty), the time
    column when the parser read it (int64 ns; UTC if ``time_utc``), and the lines of the
    blank rows skipped and of rows with fewer fields than the header."""

    lines: np.ndarray
    numbers: dict[str, np.ndarray]
    text: dict[str, np.ndarray]
    time_ns: np.ndarray | None = None
    time_utc: bool = False
    blank: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    fewer: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    last_line: int = 0  # the block's last line


def _parse_block(block: bytes, first_line: int, plan: _ColumnPlan, prof: Profile, path: Path, engine: Engine,
                 gather: _Gather) -> _Part:
    """A block of whole lines parsed into the used columns: by pyarrow when it takes the
    block as it is, else by pandas (which repairs, or raises with line and column)."""
    if engine == "pyarrow":
        part = _arrow_block(block, first_line, plan, prof, gather.arrow_time_type(block, plan, prof))
        if part is not None:
            return part
    return _pandas_block(block, first_line, plan, prof, path)


@lru_cache(maxsize=1)
def _arrow():
    """pyarrow's csv and compute modules (imported on first use; pandas imports pyarrow
    anyway where it is installed)."""
    import pyarrow as pa
    import pyarrow.compute as pc
    import pyarrow.csv as pacsv

    return pa, pc, pacsv


def _arrow_block(block: bytes, first_line: int, plan: _ColumnPlan, prof: Profile,
                 time_type) -> _Part | None:
    """The block parsed by pyarrow's CSV reader (one thread): numeric columns as
    float64, the single ISO 8601 time column as a timestamp (``time_type``), other text
    as strings; ``None`` where pyarrow refuses the block (a row with more or fewer
    fields, a value it cannot convert) or its rows do not match the lines."""
    pa, pc, pacsv = _arrow()
    n_lines = block.count(b"\n") + (0 if block.endswith(b"\n") else 1)
    types = {c: pa.float64() for c in plan.num_cols}
    types.update({c: pa.string() for c in plan.text_cols})
    tcol = prof.time.columns[0] if len(prof.time.columns) == 1 else None
    if time_type is not None:
        types[tcol] = time_type
    try:
        tbl = pacsv.read_csv(
            pa.py_buffer(block), memory_pool=pa.system_memory_pool(),
            read_options=pacsv.ReadOptions(use_threads=False, column_names=plan.unique_names,
                                           block_size=max(len(block) + 1, 1 << 16)),
            parse_options=pacsv.ParseOptions(delimiter=prof.separator, quote_char='"', double_quote=True,
                                             newlines_in_values=False, ignore_empty_lines=False),
            convert_options=pacsv.ConvertOptions(column_types=types, include_columns=plan.used,
                                                 null_values=_NUMERIC_NA, strings_can_be_null=False,
                                                 decimal_point=prof.decimal),
        )
    except (pa.ArrowInvalid, pa.ArrowNotImplementedError):
        return None
    if tbl.num_rows != n_lines:
        return None
    has_value = np.zeros(n_lines, bool)
    numbers: dict[str, np.ndarray] = {}
    for c in plan.num_cols:
        x = _arrow_values(tbl.column(c), np.float64, np.nan)
        numbers[c] = x
        has_value |= ~np.isnan(x)
    text: dict[str, np.ndarray] = {}
    time_ns = None
    for c in plan.text_cols:
        col = tbl.column(c)
        if c == tcol and time_type is not None:
            time_ns = _arrow_values(col, np.int64, NAT)  # timestamps are int64 ns
            has_value |= time_ns != NAT
            continue
        col = pc.if_else(pc.equal(col, ""), pa.scalar(None, pa.string()), col)
        has_value |= col.is_valid().to_numpy(zero_copy_only=False)
        vals = col.to_numpy(zero_copy_only=False)
        vals[pd.isna(vals)] = np.nan  # None -> NaN, as pandas gives
        text[c] = vals
    del tbl
    lines = first_line + np.arange(n_lines, dtype=np.int64)
    part = _Part(lines, numbers, text, time_ns, time_type is not None and time_type.tz is not None,
                 last_line=first_line + n_lines - 1)
    return _drop_empty_rows(part, ~has_value)


def _arrow_values(col, dtype, null) -> np.ndarray:
    """A pyarrow column of fixed-width values as a numpy array of its own (``null``
    where a value is missing). Copied from pyarrow's buffers here rather than by
    ``to_numpy``, which allocates in pyarrow's pool: memory that pool keeps after a
    block would add up to a second copy of the columns."""
    out = np.empty(len(col), dtype)
    pos = 0
    for ch in col.chunks:
        n = len(ch)
        validity, data = ch.buffers()[:2]
        seg = out[pos:pos + n]
        if data is None or ch.null_count == n:
            seg[:] = null
        else:
            seg[:] = np.frombuffer(data, dtype, count=n, offset=ch.offset * out.itemsize)
            if ch.null_count:
                bits = np.unpackbits(np.frombuffer(validity, np.uint8), bitorder="little")[ch.offset:ch.offset + n]
                seg[bits == 0] = null
        pos += n
    return out


def _drop_empty_rows(part: _Part, empty: np.ndarray) -> _Part:
    """``part`` without its rows that hold no value in any used column (blank lines)."""
    if not empty.any():
        return part
    keep = ~empty
    part.blank = part.lines[empty]
    part.lines = part.lines[keep]
    part.numbers = {c: a[keep] for c, a in part.numbers.items()}
    part.text = {c: a[keep] for c, a in part.text.items()}
    if part.time_ns is not None:
        part.time_ns = part.time_ns[keep]
    return part


def _pandas_block(block: bytes, first_line: int, plan: _ColumnPlan, prof: Profile, path: Path) -> _Part:
    """The block parsed by pandas' C parser (the parser before pyarrow): field counts
    checked per line first (more fields than the header is an error unless they are
    empty trailing fields; fewer are read as empty, and reported), the first column's
    times straight from the bytes where it is a fixed-width datetime
    (:func:`fast_first_column`), then the used columns; rows with no value in any used
    column dropped (and reported)."""
    names, used = plan.names, plan.used
    tspec = prof.time
    quoted = b'"' in block
    fast = None
    fewer = np.zeros(0, np.int64)
    if not quoted:
        bview = np.frombuffer(block, np.uint8)
        starts, n_sep = _line_stats(bview, ord(prof.separator))
        fewer = _check_field_counts(bview, starts, n_sep, len(names), first_line, prof, path)
        # the time column straight from the bytes when it is first and fixed-width
        if len(tspec.columns) == 1 and names[0] == tspec.columns[0] and len(used) > 1 \
                and tspec.columns[0] not in used[1:]:
            fast = fast_first_column(block, bview, starts, prof.separator, tspec.format)  # type: ignore[arg-type]
    table_cols = used[1:] if fast is not None else used
    df = _read_table(block, path, prof, plan.unique_names, table_cols, plan.num_cols, plan.text_cols,
                     first_line - 1, all_cols=quoted)
    if fast is not None and len(fast.ns) != len(df):  # alignment lost (should not happen): slow path
        fast = None
        df = _read_table(block, path, prof, plan.unique_names, used, plan.num_cols, plan.text_cols, first_line - 1)
    lines = first_line + np.arange(len(df), dtype=np.int64)
    # rows without any used value (with the fast time column, only a blank line can be
    # one: every other line holds a time)
    if fast is not None:
        empty = fast.blank.copy()
        if empty.any():
            empty &= df.isna().all(axis=1).to_numpy()
    else:
        empty = df.isna().all(axis=1).to_numpy().copy()
    numbers = {c: _writable(df[c].to_numpy(dtype=np.float64)) for c in plan.num_cols}  # copy-on-write views
    text = {c: df[c].to_numpy(dtype=object) for c in plan.text_cols if c in df.columns}
    part = _Part(lines, numbers, text, fast.ns if fast is not None else None, bool(fast is not None and fast.is_utc),
                 fewer=fewer, last_line=first_line + len(df) - 1)
    return _drop_empty_rows(part, empty)


def _check_field_counts(bview: np.ndarray, starts: np.ndarray, n_sep: np.ndarray, n_names: int,
                        first_line: int, prof: Profile, path: Path) -> np.ndarray:
    """More fields than the header is an error (unless only empty trailing fields);
    returns the lines with fewer (the missing fields read as empty)."""
    blank_line = (bview[starts] == 10) | (bview[starts] == 13)
    more = n_sep > n_names - 1
    if more.any():  # surplus fields that are all empty (trailing separators) are harmless
        more &= ~_only_trailing_separators(bview, starts, n_sep - (n_names - 1), ord(prof.separator))
    if more.any():
        i = int(np.flatnonzero(more)[0])
        raise InputError(path, f"malformed CSV: {int(n_sep[i]) + 1} fields, more than the {n_names} of "
                               f"the header", line=first_line + i)
    return first_line + np.flatnonzero((n_sep < n_names - 1) & ~blank_line)


#: ISO 8601 text that ends in a zone designator ('Z', +hh:mm, +hhmm), as
#: :func:`cevm.ingest.timestamps.has_offset` reads it.
_ZONE = r"(?:Z|[+-]\d\d:?\d\d)"
_ZONE_RE = _ZONE + r"\s*$"
#: The ISO 8601 forms pyarrow's timestamp parser reads (date, hours, minutes, seconds,
#: fraction; a zone designator); other forms are read as text.
_ISO_SAMPLE_RE = re.compile(r"^\d{4}-\d\d-\d\d(?:[T ]\d\d(?::\d\d(?::\d\d(?:\.\d{1,9})?)?)?)?" + _ZONE + "?$")


class _Gather:
    """The blocks' columns gathered into whole-file arrays, with what must be done per
    block while the text is at hand: vehicle ids (to codes), the time column (to ns),
    value-map columns (to numbers); the row limit."""

    def __init__(self, plan: _ColumnPlan, prof: Profile, path: Path, limits: ReadLimits, repairs: _Repairs) -> None:
        self.plan, self.prof, self.path, self.limits, self.repairs = plan, prof, path, limits, repairs
        self._lines: list[np.ndarray] = []
        self._numbers: dict[str, list[np.ndarray]] = {c: [] for c in plan.num_cols}
        self._mapped: dict[str, list[np.ndarray]] = {m.canonical: [] for m in plan.maps if m.value_map is not None}
        self._time: list[np.ndarray] = []  # single time column: ns, naive or UTC (self.time_utc)
        self._dates: list[np.ndarray] = []  # two time columns: codes into self._date_values
        self._tods: list[np.ndarray] = []  # ... and times of day [ns]
        self._date_index: dict[str, int] = {}
        self._vcodes: list[np.ndarray] = []
        self._vindex: dict[str, int] = {}
        self._blank: list[np.ndarray] = []
        self._fewer: list[np.ndarray] = []
        # numeric columns that are SI as logged and so far exactly float32 (kept so)
        self._narrow = {m.source for m in plan.maps if m.value_map is None and m.factor == 1.0 and m.offset == 0.0}
        self.rows = 0
        self.time_utc: bool | None = None  # whether the file's times carry a zone (single ISO column)
        self._time_type_decided = False
        self._time_type = None
        self.vehicle: str | None = None
        self.first_data_line = 0

    # --- before the data
    def set_vehicle(self, vehicle_id: str | None, metadata: dict[str, str], hdr: _Header) -> None:
        """The file's one vehicle id (unless the profile takes ids from a column)."""
        prof, path = self.prof, self.path
        if prof.vehicle_source == "column":
            if vehicle_id is not None:
                raise InputError(path, f"profile {prof.name!r} takes vehicle ids from column {prof.vehicle_key!r}; "
                                       "a vehicle id override does not apply")
            return
        self.first_data_line = hdr.line + 1
        if vehicle_id is not None:
            vid = vehicle_id
            _check_vehicle_id(vid, path, None, None, "the vehicle id given")
        else:
            vid = _vehicle_from_profile(prof, path, metadata, self.repairs.vehicle)
            src, line = prof.vehicle_source, None
            if src == "metadata" and not metadata.get(prof.vehicle_key or "", "").strip():
                src = prof.vehicle_fallback
            elif src == "metadata":
                line = next((ln for c, ln in zip(hdr.comments, hdr.comment_lines)
                             if c.partition("=")[0].strip() == prof.vehicle_key), None)
            where = {"metadata": f"metadata key {prof.vehicle_key!r}", "fixed": "the profile's vehicle.value",
                     "file_stem": "the file name", "parent_dir": "the directory name"}[src]
            _check_vehicle_id(vid, path, line, None, where)
        self.vehicle = vid

    def arrow_time_type(self, block: bytes, plan: _ColumnPlan, prof: Profile):
        """The pyarrow type of the time column: a timestamp for one ISO 8601 column (with
        a zone if the file's first time has one), else None (read as text)."""
        if not self._time_type_decided:
            self._time_type_decided = True
            if len(prof.time.columns) == 1 and prof.time.format == "ISO8601":
                sample = _first_value(block, plan.names.index(prof.time.columns[0]), prof.separator)
                if sample is not None and _ISO_SAMPLE_RE.match(sample):
                    pa = _arrow()[0]
                    zoned = bool(re.search(_ZONE_RE, sample))
                    self._time_type = pa.timestamp("ns", tz="UTC") if zoned else pa.timestamp("ns")
        return self._time_type

    # --- per block
    def add(self, part: _Part, last: bool) -> None:
        n = len(part.lines)
        self.rows += n
        limit = self.limits.row_limit(len(self.plan.used))
        if self.rows > limit:
            over = part.lines[n - (self.rows - limit)]
            if limit < self.limits.max_rows:  # the values bound: a wide log
                raise InputError(self.path, f"more than {limit:,} data rows of {len(self.plan.used)} columns "
                                            f"({self.limits.max_values:,} values): over the limit per file that keeps "
                                            "memory bounded (--max-rows N sets the rows alone)", line=int(over))
            raise InputError(self.path, f"more than {limit:,} data rows: over the limit per file "
                                        "that keeps memory bounded (--max-rows)", line=int(over))
        if len(part.blank):
            self._blank.append(part.blank)
        if len(part.fewer):
            self._fewer.append(part.fewer)
        if n == 0:
            return
        upto = None if last else part.last_line
        self._lines.append(part.lines.astype(np.int32) if part.last_line < _INT32_LINES else part.lines)
        if self.prof.vehicle_source == "column":
            self._vcodes.append(self._vehicle_part(part, upto))
        self._time_part(part, upto)
        for m in self.plan.maps:
            if m.value_map is not None:
                self._mapped[m.canonical].append(_map_values(part.text[m.source], m, part.lines, self.path, upto))
        for c, x in part.numbers.items():
            if c in self._narrow:
                x32 = _exact_float32(x)
                if x32 is None:
                    self._narrow.discard(c)
                else:
                    x = x32
            self._numbers[c].append(x)

    def _vehicle_part(self, part: _Part, upto: int | None) -> np.ndarray:
        key = self.prof.vehicle_key
        raw_codes, raw_ids = pd.factorize(part.text[key], sort=False)  # hash, no per-row strip
        stripped = pd.Series(np.asarray(raw_ids, dtype=object)).str.strip()
        bad = (raw_codes < 0) | (np.asarray(stripped == "")[np.maximum(raw_codes, 0)] if len(stripped) else True)
        if np.any(bad):
            raise _line_col_error(self.path, "empty vehicle id", part.lines, np.asarray(bad), key, upto_line=upto)
        to_global = np.empty(len(stripped), np.int64)
        for j, vid in enumerate(stripped):  # ' AB12' and 'AB12' merge; a few ids, not rows
            if vid not in self._vindex:
                _check_vehicle_id(vid, self.path, int(part.lines[np.argmax(raw_codes == j)]), key, None)
                self._vindex[vid] = len(self._vindex)
            to_global[j] = self._vindex[vid]
        return to_global[raw_codes]

    def _time_part(self, part: _Part, upto: int | None) -> None:
        tspec, path = self.prof.time, self.path
        if len(tspec.columns) == 2:
            dcol, tcol = tspec.columns
            dvals, tvals = part.text[dcol], part.text[tcol]
            dcodes, duniq = pd.factorize(pd.Series(dvals, dtype=object), sort=False)
            to_global = np.array([self._date_index.setdefault(u, len(self._date_index)) for u in duniq], np.int64)
            self._dates.append(np.where(dcodes >= 0, to_global[np.maximum(dcodes, 0)] if len(to_global) else -1, -1))
            tod = parse_datetimes(tvals, tspec.time_format)  # type: ignore[arg-type]
            ok_t = tod != NAT
            tod[ok_t] -= (tod[ok_t] // NS_PER_DAY) * NS_PER_DAY  # time of day [ns]
            if not ok_t.all():
                raise _line_col_error(path, "unreadable time of day", part.lines, ~ok_t, tcol, tvals, upto)
            self._tods.append(tod)
            return
        col = tspec.columns[0]
        if part.time_ns is not None:
            ns, vals = part.time_ns, None
            self._time_notation(part.time_utc, part.lines[0], col)
        elif tspec.format in EPOCH_FORMATS:  # numbers since the epoch: UTC by definition
            vals = part.text[col]
            self._time_notation(True, part.lines[0], col)
            ns = epoch_ns(vals, EPOCH_FORMATS[tspec.format], self.prof.decimal)
        else:
            vals = part.text[col]
            if tspec.format == "ISO8601":
                self._check_notation(vals, part.lines, col, upto)
            ns = parse_datetimes(vals, tspec.format)  # type: ignore[arg-type]
        _check_times(path, ns, part.lines, col, vals, upto)
        self._time.append(ns)

    def _time_notation(self, utc: bool, line: int, col: str, value=None) -> None:
        if self.time_utc is None:
            self.time_utc = utc
        elif utc != self.time_utc:
            raise InputError(self.path, _mixed_zone_message(self.time_utc) + (f" {value!r}" if value else ""),
                             line=int(line), column=col)

    def _check_notation(self, vals: np.ndarray, lines: np.ndarray, col: str, upto: int | None) -> None:
        """One file, one notation: every ISO 8601 time carries a zone designator, or none
        does (a mix would put some rows an offset away from the others)."""
        s = pd.Series(vals, dtype=object)
        present = s.notna().to_numpy()
        if not present.any():
            return
        zoned = s[present].astype(str).str.contains(_ZONE_RE, regex=True).to_numpy()
        if self.time_utc is None:
            self.time_utc = bool(zoned[0])
        bad = np.zeros(len(vals), bool)
        bad[present] = zoned != self.time_utc
        if bad.any():
            raise _line_col_error(self.path, _mixed_zone_message(self.time_utc) + ":", lines, bad, col, vals, upto)

    # --- after the data
    def lines(self) -> np.ndarray:
        if self.rows == 0:
            raise InputError(self.path, "no data rows with values", line=self.first_data_line)
        if self._fewer:
            f = np.concatenate(self._fewer)
            self.repairs.rows.append(f"read: {len(f)} rows with fewer fields than the header (missing fields "
                                     f"read as empty): {_lines_summary(f)}")
        if self._blank:
            b = np.concatenate(self._blank)
            self.repairs.rows.append(f"read: {len(b)} blank rows (no value in any used column) skipped: "
                                     f"{_lines_summary(b)}")
        self._line_array = _concat(self._lines)
        return self._line_array

    def vehicle_codes(self) -> tuple[np.ndarray, list[str]]:
        """Per row, the index of its vehicle in the list of vehicle ids (in order of
        first appearance)."""
        if self.prof.vehicle_source != "column":
            return np.zeros(self.rows, np.int8), [self.vehicle]  # type: ignore[list-item]
        return _concat(self._vcodes), list(self._vindex)

    def utc_ns(self, codes: np.ndarray, lines: np.ndarray) -> np.ndarray:
        """Each row's time as UTC ns since the epoch (int64): localised from the
        profile's zone unless the text carries one; dates repaired (two columns)."""
        tspec, path, repairs = self.prof.time, self.path, self.repairs.time
        if len(tspec.columns) == 1:
            naive = _concat(self._time)
            return naive if self.time_utc else _localize(naive, tspec.timezone, codes, lines, repairs)
        dcol = tspec.columns[0]
        values = np.array(list(self._date_index), dtype=object)
        date_codes = _concat(self._dates)
        tod = _concat(self._tods)
        uniq_ns = parse_datetimes(values, tspec.date_format)  # type: ignore[arg-type]
        uniq_ns = np.where((uniq_ns >= _TIME_MIN) & (uniq_ns < _TIME_MAX), uniq_ns, NAT)
        date_ns = np.where(date_codes >= 0, uniq_ns[np.maximum(date_codes, 0)] if len(uniq_ns) else NAT, NAT)
        dvals = _Lookup(values, date_codes)
        if tspec.date_repair == "dominant":
            date_ns = _repair_dates(date_ns, tod, dvals, lines, tspec.date_repair_max_days, path, dcol, repairs)
        badd = date_ns == NAT
        if badd.any():
            raise _line_col_error(path, f"unreadable date (format {tspec.date_format!r}):", lines, badd, dcol, dvals)
        naive = date_ns + tod
        del date_ns, tod
        _check_times(path, naive, lines, dcol, dvals)
        return _localize(naive, tspec.timezone, codes, lines, repairs)

    def pop_columns(self) -> dict[str, np.ndarray]:
        """The numeric source columns (by source name) and the value-map columns (by
        canonical name), each as one array; the blocks' pieces are released as it goes."""
        out: dict[str, np.ndarray] = {}
        for c in list(self._numbers):
            out[c] = _concat(self._numbers.pop(c))
        for c in list(self._mapped):
            out[c] = _concat(self._mapped.pop(c))
        return out


#: File lines below this are kept as int32 (half the memory of int64).
_INT32_LINES = 2**31 - 1


def _exact_float32(x: np.ndarray) -> np.ndarray | None:
    """``x`` (float64) as float32 if every value is exactly a float32 (NaN included:
    what a logger writes in binary steps, such as 1/8 rpm, whole kg or 1/32 degC), else
    None. The values are the same; the column takes half the memory."""
    with np.errstate(over="ignore", invalid="ignore"):
        x32 = x.astype(np.float32)
        exact = bool(((x32 == x) | np.isnan(x)).all())
    return x32 if exact else None


def _writable(x: np.ndarray) -> np.ndarray:
    """``x``, or a copy of it where it is a read-only view (the columns are converted in
    place later)."""
    return x if x.flags.writeable else x.copy()


def _concat(parts: list[np.ndarray]) -> np.ndarray:
    """One array of the parts (the part itself if there is one: no copy). The parts'
    memory is returned to the system once they are joined: freed, it would stay
    resident between the joined columns, and the process would hold a large file's
    columns twice at its peak (:func:`cevm.runtime.release_free_memory`)."""
    if len(parts) == 1:
        a = parts[0]
        parts.clear()
        return a
    a = np.concatenate(parts)
    parts.clear()
    release_free_memory()
    return a


class _Lookup:
    """Row values of a factorised text column, made on demand (for messages)."""

    def __init__(self, values: np.ndarray, codes: np.ndarray) -> None:
        self.values, self.codes = values, codes

    def __getitem__(self, idx):
        c = self.codes[idx]
        if np.ndim(c) == 0:
            return self.values[c] if c >= 0 else np.nan
        return np.where(c >= 0, self.values[np.maximum(c, 0)] if len(self.values) else np.nan, np.nan)


def _mixed_zone_message(first_zoned: bool) -> str:
    if first_zoned:
        return ("time zone notation mixed in one file: the file's first time carries a zone designator "
                "('Z' or +hh:mm), this one none")
    return ("time zone notation mixed in one file: the file's first time carries no zone designator, this one "
            "does ('Z' or +hh:mm)")


def _first_value(block: bytes, index: int, sep: str, max_lines: int = 50) -> str | None:
    """The first non-empty value of field ``index`` in the first lines of ``block``."""
    head = block[: 1 << 16].decode("utf-8", errors="replace").splitlines()[:max_lines]
    for row in csv.reader(head, delimiter=sep):
        if index < len(row) and row[index].strip():
            return row[index].strip()
    return None


def _check_vehicle_id(vid: str, path: Path, line: int | None, column: str | None, where: str | None) -> None:
    """A vehicle id may not hold control characters (a carriage return or line feed in
    an id breaks CSV output and forges lines); refused at read."""
    if has_control(vid):
        src = f" from {where}" if where else ""
        raise InputError(path, f"vehicle id {vid!r}{src} holds a control character; ids must be printable text",
                         line=line, column=column)


def _read_table(body: bytes, path: Path, prof: Profile, names: list[str], usecols: list[str],
                num_cols: list[str], text_cols: list[str], header_line: int,
                all_cols: bool = False) -> pd.DataFrame:
    """The ``usecols`` columns of the data lines with pandas' C parser: numbers as float64
    (NaN for empty or NA-like fields), text as object. With ``all_cols`` every column is
    tokenised (so that the parser checks field counts) and the others dropped after.
    Malformed rows and non-numbers raise InputError with the file line."""
    kw = dict(sep=prof.separator, decimal=prof.decimal, header=None, names=names, index_col=False,
              usecols=None if all_cols else usecols, keep_default_na=False, skip_blank_lines=False,
              engine="c", encoding="utf-8", quotechar='"', low_memory=False)
    na_values = {c: _NUMERIC_NA for c in num_cols if c in usecols}
    na_values.update({c: [""] for c in text_cols if c in usecols})
    dtype = {c: "float64" for c in num_cols if c in usecols}
    dtype.update({c: object for c in text_cols if c in usecols})
    if all_cols:
        dtype.update({c: object for c in names if c not in usecols})
    elif len(na_values) == len(usecols) and all(v is _NUMERIC_NA for v in na_values.values()):
        # only numeric columns: the same settings given once (per-column dicts cost
        # pandas a third of the parse time on a 5000-row file)
        na_values, dtype = _NUMERIC_NA, np.dtype(np.float64)  # type: ignore[assignment]
    try:
        try:
            df = pd.read_csv(io.BytesIO(body), dtype=dtype, na_values=na_values, **kw)
        except ValueError as exc:
            if isinstance(exc, pd.errors.ParserError):
                raise
            # a field that is not a number: find it (slow path, error only)
            df = pd.read_csv(io.BytesIO(body), dtype=object, na_values=na_values, **kw)
            lines = header_line + 1 + np.arange(len(df))
            for c in num_cols:
                if c not in usecols:
                    continue
                col = df[c]
                txt = col if prof.decimal == "." else col.str.replace(prof.decimal, ".", regex=False)
                conv = pd.to_numeric(txt, errors="coerce")
                bad = (conv.isna() & col.notna()).to_numpy()
                if bad.any():
                    raise _line_col_error(path, "not a number:", lines, bad, c.split("\x00")[0], col.to_numpy())
            raise
    except pd.errors.ParserError as exc:
        m = re.search(r"line (\d+)", str(exc))
        line = header_line + int(m.group(1)) if m else None
        detail = str(exc).split("C error: ")[-1].strip()
        if m:
            detail = detail.replace(f"line {m.group(1)}", "this line")
        raise InputError(path, f"malformed CSV: {detail}", line=line) from None
    if all_cols:
        df = df[usecols]
    df.columns = [c.split("\x00")[0] for c in df.columns]
    return df

def _canonical_columns(columns: dict[str, np.ndarray], maps: list[ColumnMap], utc: np.ndarray,
                       lines: np.ndarray, prof: Profile, path: Path, repairs: list[str]) -> dict[str, np.ndarray]:
    """The canonical columns (``time_s``, ``source_line`` and each mapped column in SI),
    with impossible positions and absurd values handled; a log with neither position nor
    speed values is an error. ``columns`` (numbers by source name, value-map columns by
    canonical name) are converted in place and released from the dict."""
    out: dict[str, np.ndarray] = {"time_s": _ns_to_s(utc), "source_line": lines}
    del utc
    for m in maps:
        if m.value_map is not None:
            out[m.canonical] = columns.pop(m.canonical)
        else:
            out[m.canonical] = _to_si(columns.pop(m.source), m, lines, repairs)
        if m.negate:
            out[m.canonical] = np.negative(out[m.canonical], out=out[m.canonical])
    _check_position(out, prof, lines, path, repairs)
    for m in maps:
        if m.canonical not in ("lat_deg", "lon_deg"):
            _check_absurd(out, m, lines, path, prof, repairs)

    has_pos = "lat_deg" in out and np.isfinite(out["lat_deg"]).any()
    has_speed = any(c in out and np.isfinite(out[c]).any() for c in ("wheel_speed_mps", "gps_speed_mps"))
    if not (has_pos or has_speed):
        cands = [m.source for m in prof.columns if m.canonical in ("lat_deg", "lon_deg", "wheel_speed_mps", "gps_speed_mps")]
        raise InputError(path, "no position and no speed values: cannot derive a drive cycle "
                               f"(profile {prof.name!r} looks for {', '.join(cands) or 'none'})")
    return out


def _ns_to_s(ns: np.ndarray) -> np.ndarray:
    """Times [ns, int64] in seconds (float64), in the same memory where the array is its
    own (a chunk at a time: no second array of the file's length)."""
    if not (ns.flags.writeable and ns.flags.c_contiguous and ns.base is None):
        return ns / 1e9
    s = ns.view(np.float64)
    step = 1 << 16
    for a in range(0, ns.size, step):
        s[a:a + step] = ns[a:a + step] / 1e9
    return s


def _split_vehicles(out: dict[str, np.ndarray], codes: np.ndarray, vehicles: list[str], maps: list[ColumnMap],
                    prof: Profile, path: Path, metadata: dict[str, str], repairs: list[str]) -> list[ParsedLog]:
    """One :class:`ParsedLog` per vehicle: its rows' canonical columns (a frame built
    around the arrays, no copy) and the energy sources they hold. With several vehicles
    each column is reordered by vehicle once (stable: file order within a vehicle) and
    the vehicles' frames are slices of it."""
    if len(vehicles) == 1:
        per = [out]
    else:
        order = np.argsort(codes, kind="stable")
        bounds = np.searchsorted(codes[order], np.arange(len(vehicles) + 1))
        per = [{} for _ in vehicles]
        for c in list(out):
            a = out.pop(c)[order]
            for k in range(len(vehicles)):
                per[k][c] = a[bounds[k]:bounds[k + 1]]
    logs = []
    for vname, arrays in zip(vehicles, per):
        n = len(arrays["time_s"])
        names = list(arrays)
        ids = pd.Categorical.from_codes(np.zeros(n, np.int8), dtype=pd.CategoricalDtype([vname]))
        # built in column order at once (an insert afterwards costs pandas 3 ms a file)
        fr = pd.DataFrame({**{c: arrays[c] for c in names[:2]}, "vehicle_id": ids,
                           **{c: arrays[c] for c in names[2:]}}, copy=False)
        sources = tuple(_energy_source(e, fr, maps) for e in prof.energy if _has_energy_data(e, arrays))
        logs.append(ParsedLog(path, prof.name, vname, fr, dict(metadata), sources, list(repairs)))
    return logs


def _has_energy_data(e: EnergySpec, arrays: dict[str, np.ndarray]) -> bool:
    """Whether the canonical columns ``arrays`` hold any value of the source (both
    factors for a virtual one)."""
    if e.column in VIRTUAL_COLUMNS:
        a, b = VIRTUAL_COLUMNS[e.column][0]
        return a in arrays and b in arrays and bool(
            (np.isfinite(arrays[a]).any() and np.isfinite(arrays[b]).any()))
    return e.column in arrays and bool(np.isfinite(arrays[e.column]).any())

def _energy_source(e: EnergySpec, fr: pd.DataFrame, maps: list[ColumnMap]) -> EnergySource:
    cols = VIRTUAL_COLUMNS[e.column][0] if e.column in VIRTUAL_COLUMNS else (e.column,)
    src = "*".join(next(m.source for m in maps if m.canonical == c) for c in cols)
    return EnergySource(e.column, e.kind, e.quantity, e.resolution, e.priority, e.capacity_j, src, e.modulus,
                        e.accuracy_pct)

def _vehicle_from_profile(prof: Profile, path: Path, metadata: dict[str, str], repairs: list[str]) -> str:
    src = prof.vehicle_source
    if src == "fixed":
        return prof.vehicle_value  # type: ignore[return-value]
    if src == "metadata":
        val = metadata.get(prof.vehicle_key or "", "").strip()
        if val:
            return val
        if prof.vehicle_fallback == "error":
            raise InputError(path, f"no '{prof.vehicle_key}=' metadata line for the vehicle id", line=1)
        src = prof.vehicle_fallback
        repairs.append(f"vehicle: no '{prof.vehicle_key}' metadata; vehicle id taken from the file's {src.replace('_', ' ')}")
    name = path.name
    for suffix in (".gz", ".csv", ".txt"):
        if name.lower().endswith(suffix):
            name = name[: -len(suffix)]
    return path.resolve().parent.name if src == "parent_dir" else name


def _check_times(path: Path, naive: np.ndarray, lines: np.ndarray, col: str, vals=None,
                 upto: int | None = None) -> None:
    """Unparseable or absurd (before 1990 or from 2100) times are errors with their line."""
    bad = (naive == NAT) | (naive < _TIME_MIN) | (naive >= _TIME_MAX)
    if bad.any():
        raise _line_col_error(path, "unreadable or impossible time", lines, bad, col, vals, upto)


def _map_values(vals: np.ndarray, m: ColumnMap, lines: np.ndarray, path: Path, upto: int | None) -> np.ndarray:
    """A value-map column's text (e.g. ``On``/``Off``) as float64 (NaN = no value);
    matched exactly, else ignoring case and surrounding space; other text is an error."""
    s = pd.Series(vals, dtype=object)
    mapping = dict(m.value_map)  # type: ignore[arg-type]
    res = s.map(mapping)
    todo = (res.isna() & s.notna()).to_numpy()
    if todo.any():
        folded = {k.strip().casefold(): v for k, v in m.value_map}  # type: ignore[union-attr]
        res2 = s[todo].str.strip().str.casefold().map(folded)
        res[todo] = res2
        still = (res.isna() & s.notna()).to_numpy()
        if still.any():
            raise _line_col_error(path, f"value not in the profile's map ({', '.join(k for k, _ in m.value_map)}):",
                                  lines, still, m.source, vals, upto)
    return res.to_numpy(dtype=np.float64)


def _to_si(x: np.ndarray, m: ColumnMap, lines: np.ndarray, repairs: list[str]) -> np.ndarray:
    """A numeric source column in SI, in place: the logger's missing-value markers to
    NaN (reported), then ``x * factor + offset``."""
    if m.missing_values:
        miss = np.isin(x, np.asarray(m.missing_values))
        if miss.any():
            x[miss] = np.nan
            repairs.append(f"{m.canonical}: {int(miss.sum())} values equal to the logger's missing-value "
                           f"marker ({', '.join(f'{v:g}' for v in m.missing_values)}) in column "
                           f"'{m.source}' set to NaN: {_lines_summary(lines[miss])}")
    if m.factor != 1.0:
        x *= m.factor
    if m.offset != 0.0:
        x += m.offset
    return x


def _absurd_verdict(n_bad: int, n_values: int, canon: str, src: str, lines: np.ndarray, bad: np.ndarray,
                    raw: np.ndarray, path: Path, prof: Profile, repairs: list[str], what: str,
                    unit: str | None) -> None:
    """Error or repair message for ``n_bad`` absurd values (``raw``: as logged)."""
    lo, hi = PLAUSIBLE_RANGE_SI[canon]
    u = f" {unit}" if unit and unit != "-" else ""
    if n_bad == n_values or n_bad > prof.absurd_error_share * n_values:
        raise _line_col_error(
            path, f"{n_bad} of {n_values} values are impossible for {canon} (allowed {lo:g}..{hi:g} in SI; "
                  f"wrong unit or column in profile {prof.name!r}?), first [{unit or '-'}]:",
            lines, bad, src, raw)
    repairs.append(f"{canon}: {n_bad} impossible {what} in column '{src}' (e.g. {raw[np.flatnonzero(bad)[0]]:g}{u}; "
                   f"allowed {lo:g}..{hi:g} in SI) set to NaN: {_lines_summary(lines[bad])}")

def _check_absurd(out: dict[str, np.ndarray], m: ColumnMap, lines: np.ndarray, path: Path,
                  prof: Profile, repairs: list[str]) -> None:
    """Mark values outside PLAUSIBLE_RANGE_SI as NaN and report them; too many -> error.

    Policy: absurd values that are a minority are logger glitches (NaN + repair, with
    count and lines); if every value, or more than ``profile.absurd_error_share`` of them
    (default 0.5: most values), is absurd, the profile's unit or column must be wrong and
    guessing would hide it: InputError at the first absurd line. A share, not a count,
    so that a burst of junk in a short file is still repaired, not refused.
    """
    x = out[m.canonical]
    lo, hi = (np.float64(b) for b in PLAUSIBLE_RANGE_SI[m.canonical])  # compared as float64 for float32 columns too
    with np.errstate(invalid="ignore"):
        bad = (x < lo) | (x > hi)
    if not bad.any():
        return
    n_values = int(np.isfinite(x).sum())
    as_logged = ((-x if m.negate else x) - m.offset) / m.factor  # for messages, in the logger's unit
    _absurd_verdict(int(bad.sum()), n_values, m.canonical, m.source, lines, bad, as_logged, path, prof,
                    repairs, "values", m.unit)
    x[bad] = np.nan

def _check_position(out: dict[str, np.ndarray], prof: Profile, lines: np.ndarray, path: Path,
                    repairs: list[str]) -> None:
    """A position is one fix: if latitude or longitude is impossible (|lat| > 90,
    |lon| > 180) or, with ``zero_position_is_no_fix``, exactly 0 (the value GPS modules
    write without a fix), both become NaN. Zeros are never an error (a logger may have no
    GPS at all); impossible values follow the absurd-value policy."""
    if "lat_deg" not in out:
        return
    lat, lon = out["lat_deg"], out["lon_deg"]
    with np.errstate(invalid="ignore"):  # |x| > 90 without an array of |x|
        lat_bad, lon_bad = (lat > 90.0) | (lat < -90.0), (lon > 180.0) | (lon < -180.0)
    absurd = lat_bad | lon_bad
    zero = ((lat == 0.0) | (lon == 0.0)) & ~absurd if prof.zero_position_is_no_fix else np.zeros(len(lat), bool)
    n_values = int((np.isfinite(lat) & np.isfinite(lon)).sum())
    for canon, bad, x in (("lat_deg", lat_bad, lat), ("lon_deg", lon_bad, lon)):
        if bad.any():
            src = next(m.source for m in prof.columns if m.canonical == canon)
            _absurd_verdict(int(bad.sum()), n_values, canon, src, lines, bad, x, path, prof, repairs,
                            "GPS fixes (the whole fix set to NaN)", "deg")
    if zero.any():
        repairs.append(f"position: {int(zero.sum())} GPS fixes with latitude or longitude exactly 0 (no fix) "
                       f"set to NaN: {_lines_summary(lines[zero])}")
    drop = absurd | zero
    if drop.any():
        lat[drop] = np.nan
        lon[drop] = np.nan
