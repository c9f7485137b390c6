"""Reading stage of ``cevm ingest``: logger CSV exports -> canonical log frames.

A logger is described by a *profile* (:mod:`cevm.ingest.profiles`).
:func:`read_log` turns one file into one :class:`ParsedLog` per vehicle: a DataFrame
with canonical columns in SI units (rows in file order; cleaning, sorting and trip
splitting are later stages), the file's metadata, the energy sources available, and a
human-readable list of every repair made while reading. Bad input raises
:class:`cevm.errors.InputError` naming file, line and column.

Everything is vectorised (pandas C parser, numpy); nothing loops over rows in Python.

Not handled: quoted fields holding line breaks (line numbers would shift).
"""

from __future__ import annotations

import csv
import gzip
import hashlib
import io
import re
import zlib
from dataclasses import dataclass, field
from functools import cached_property, lru_cache
from pathlib import Path
from typing import Literal

import numpy as np
import pandas as pd

from cevm.errors import InputError
from cevm.ingest.profiles import VIRTUAL_COLUMNS, ColumnMap, EnergySpec, Profile, TimeSpec, load_profiles
from cevm.ingest.timestamps import NAT, NS_PER_DAY, FastTimes, fast_first_column, has_offset, parse_datetimes

__all__ = [
    "PLAUSIBLE_RANGE_SI",
    "EnergySource",
    "ParsedLog",
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
}

# Times outside this window are absurd (unset clocks read 1970 or 2000; corrupt dates).
_TIME_MIN = np.datetime64("1990-01-01T00:00:00", "ns").astype(np.int64)
_TIME_MAX = np.datetime64("2100-01-01T00:00:00", "ns").astype(np.int64)


# Text that means "no value" in a numeric column (besides an empty field).
_NUMERIC_NA = ["", "NA", "N/A", "n/a", "NaN", "nan", "null", "NULL", "None", "-", "--"]


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
    """

    column: str
    kind: Literal["rate", "counter", "soc"]
    quantity: Literal["fuel_l", "energy_j"]
    resolution: float
    priority: int
    capacity_j: float | None = None
    source_column: str = ""
    modulus: float | None = None


@dataclass(frozen=True, eq=False)
class ParsedLog:
    """One vehicle's rows of one logger file, in canonical columns.

    ``frame`` has ``time_s`` (UTC seconds since the Unix epoch, float64),
    ``source_line`` (1-based line in the file, int64), ``vehicle_id`` (str) and every
    canonical column the profile maps and the file has (float64, SI, NaN = no value),
    rows in file order. ``repairs`` lists every repair made while reading the file
    (file-wide, so shared by the logs of a multi-vehicle file). ``raw_bytes`` are the
    file's bytes as stored on disk (compressed bytes for a .gz file; shared by the logs
    of a file) and ``sha256`` their hex digest, computed on first use (the ingest
    pipeline hashes files itself, before reading them).
    """

    path: Path
    profile: str
    vehicle_id: str
    frame: pd.DataFrame
    metadata: dict[str, str]
    energy_sources: tuple[EnergySource, ...]
    repairs: list[str]
    raw_bytes: bytes = field(default=b"", repr=False)

    @cached_property
    def sha256(self) -> str:
        """Hex SHA-256 of ``raw_bytes``."""
        return hashlib.sha256(self.raw_bytes).hexdigest()


# ======================================================================================
# Bytes, text and header
# ======================================================================================
def _read_raw(path: Path) -> tuple[bytes, bytes]:
    """(raw bytes on disk, CSV bytes after gzip decompression if the magic bytes say so)."""
    return _decompress(_read_bytes(path), path)


def _read_bytes(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except OSError as exc:
        raise InputError(path, f"cannot read file: {exc.strerror or exc}") from None


def _decompress(raw: bytes, path: Path) -> tuple[bytes, bytes]:
    """(raw, CSV bytes): gunzipped if the magic bytes say so."""
    data = raw
    if raw[:2] == b"\x1f\x8b":
        try:
            data = gzip.decompress(raw)
        except (OSError, EOFError, zlib.error) as exc:
            raise InputError(path, f"corrupt gzip data: {exc}") from None
    return raw, data


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
    try:
        with open(path, "rb") as fh:
            head = fh.read(n)
            if head[:2] == b"\x1f\x8b":
                fh.seek(0)
                with gzip.GzipFile(fileobj=fh) as gz:
                    head = gz.read(n)
    except (OSError, EOFError, zlib.error) as exc:
        raise InputError(path, f"cannot read file: {getattr(exc, 'strerror', None) or exc}") from None
    return head


def _to_utf8(data: bytes, prof: Profile, path: Path) -> bytes:
    """The CSV bytes re-encoded as UTF-8 (no BOM), after checking they decode with the
    profile's encoding and hold no NUL byte (binary data)."""
    encoding = prof.encoding
    enc = encoding.lower().replace("_", "-")
    try:
        if enc in ("utf-8", "utf8", "utf-8-sig", "ascii", "us-ascii"):
            if not data.isascii():  # isascii is a fast scan; otherwise validate by decoding
                data.decode("utf-8" if "ascii" not in enc else "ascii")
            out = data
        else:
            out = data.decode(encoding).encode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        start = data.rfind(b"\n", 0, exc.start) + 1
        column = None
        if enc.startswith("utf-8") or enc in ("ascii", "us-ascii", "cp1252", "latin-1", "iso-8859-1"):
            hdr = _find_header(data[:start].decode(encoding, errors="replace").encode("utf-8"),
                               prof.comment_prefix, prof.separator)
            field_no = data.count(prof.separator.encode(), start, exc.start)
            if hdr is not None and line > hdr.line and field_no < len(hdr.names):
                column = hdr.names[field_no]
        raise InputError(
            path,
            f"byte 0x{data[exc.start]:02x} is not valid {encoding} text (binary data, or a file in "
            f"another encoding: check csv.encoding of profile {prof.name!r})",
            line=line,
            column=column,
        ) from None
    if out.startswith(b"\xef\xbb\xbf"):
        out = out[3:]
    nul = out.find(b"\x00")
    if nul >= 0:
        raise InputError(path, "binary data (NUL byte), not a CSV text file", line=out.count(b"\n", 0, nul) + 1)
    return out


@dataclass(frozen=True)
class _Header:
    names: tuple[str, ...]
    line: int  # 1-based line of the header
    body_offset: int  # byte offset of the first data line
    comments: tuple[str, ...]


def _find_header(data: bytes, prefix: str, sep: str) -> _Header | None:
    """Skip blank and comment lines; parse the header line. ``None`` if there is none."""
    pbytes = prefix.encode("utf-8") if prefix else None
    pos, line_no, comments = 0, 0, []
    n = len(data)
    while pos < n:
        nl = data.find(b"\n", pos)
        end = n if nl < 0 else nl
        line_no += 1
        raw_line = data[pos:end].strip()
        nxt = n if nl < 0 else nl + 1
        if pbytes and raw_line.startswith(pbytes):
            comments.append(raw_line[len(pbytes):].decode("utf-8", errors="replace").strip())
        elif raw_line:
            text = raw_line.decode("utf-8", errors="replace").replace("\r", " ")
            names = next(csv.reader([text], delimiter=sep))
            return _Header(tuple(s.strip() for s in names), line_no, nxt, tuple(comments))
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


@lru_cache(maxsize=64)
def _ascii_transparent(encoding: str) -> bool:
    """Whether ``encoding`` decodes every ASCII byte to that character (utf-8, cp1252,
    latin-1, ...; not utf-16 or utf-7), so that ASCII text needs no re-encoding."""
    try:
        return bytes(range(128)).decode(encoding) == "".join(map(chr, range(128)))
    except (UnicodeDecodeError, LookupError):
        return False


def _detect_in_head(path: Path, head: bytes, profiles: dict[str, Profile]) -> Profile:
    """:func:`detect_profile` on the first bytes ``head`` of the (decompressed) file."""
    if not head or head.isspace():
        raise InputError(path, "file is empty", line=1)
    if _looks_binary(head):
        raise InputError(path, "binary data, not a CSV text file", line=1)
    matches: list[Profile] = []
    seen_header: tuple[str, ...] = ()
    ascii_head = head.isascii()
    for prof in profiles.values():
        try:
            if ascii_head and _ascii_transparent(prof.encoding):
                text = head  # what decoding and re-encoding as UTF-8 would give
            else:
                text = head.decode(prof.encoding, errors="replace").encode("utf-8")
        except LookupError:
            continue
        if text.startswith(b"\xef\xbb\xbf"):
            text = text[3:]
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
                    values: np.ndarray | None = None) -> InputError:
    i = int(np.flatnonzero(bad)[0])
    val = ""
    if values is not None:
        v = values[i]
        val = f" {float(v):g}" if isinstance(v, (float, np.floating, int, np.integer)) else f" {str(v)!r}"
    extra = f" (and {int(bad.sum()) - 1} more rows)" if bad.sum() > 1 else ""
    return InputError(path, f"{msg}{val}{extra}", line=int(lines[i]), column=col)


def read_log(path: str | Path, profile: Profile | str | None = None,
             profiles: dict[str, Profile] | None = None, *,
             vehicle_id: str | None = None) -> list[ParsedLog]:
    """Read one logger CSV (plain or gzip-compressed) into one :class:`ParsedLog` per vehicle.

    Parameters
    ----------
    path : the file. Gzip is recognised by its magic bytes, whatever the extension.
    profile : a :class:`Profile`, a profile name (looked up in ``profiles``), or ``None``
        (default) to detect it from the header with :func:`detect_profile`.
    profiles : available profiles (default ``None``: :func:`load_profiles()`).
    vehicle_id : override the vehicle id from the profile (default ``None``: use the
        profile's vehicle source); not allowed for a file split by a vehicle column.

    Returns
    -------
    One ParsedLog per vehicle in order of first appearance in the file.

    Raises
    ------
    InputError : empty file, header only, bad encoding, binary data, missing time
        column, unreadable time or number (with line and column), no position and no
        speed, a column mostly absurd, a truncated last line when the profile says
        ``truncated_last_line = "error"``.

    The stages, each a function of its own: the file's bytes, decompressed, and its
    profile (:func:`_load_bytes`); the text as UTF-8 (:func:`_decode`); the header and
    metadata (:func:`_read_header`) and the columns the profile needs from it
    (:func:`_plan_columns`); the data lines (:func:`_data_body`) parsed into a table
    (:func:`_parse_body`); vehicle ids (:func:`_vehicle_codes`); times to UTC
    (:func:`_parse_times`); columns mapped to canonical SI columns and checked
    (:func:`_canonical_columns`); one log per vehicle (:func:`_split_vehicles`).
    """
    path = Path(path)
    prof, raw, data = _load_bytes(path, profile, profiles)
    data = _decode(data, prof, path)
    hdr, metadata = _read_header(data, prof, path)
    plan = _plan_columns(prof, hdr, path)
    repairs: list[str] = []
    body = _data_body(data, hdr, plan.names, prof, path, repairs)
    df, lines, fast = _parse_body(body, hdr, plan, prof, path, repairs)
    codes, vehicles = _vehicle_codes(df, prof, lines, path, vehicle_id, metadata, repairs)
    utc = _parse_times(df, fast, prof.time, lines, codes, path, repairs)
    out = _canonical_columns(df, plan.maps, utc, lines, prof, path, repairs)
    return _split_vehicles(out, codes, vehicles, plan.maps, prof, path, metadata, repairs, raw)


def _load_bytes(path: Path, profile: Profile | str | None,
                profiles: dict[str, Profile] | None) -> tuple[Profile, bytes, bytes]:
    """(profile, bytes on disk, CSV bytes after decompression); the profile given, or
    detected from the file's first bytes."""
    if profile is None:  # detect from the bytes read for the file itself (one read)
        profiles = load_profiles() if profiles is None else profiles
        if not profiles:
            raise InputError(path, "no logger profiles loaded")
        raw = _read_bytes(path)
        if raw[:2] == b"\x1f\x8b":  # gzip: detect from the decompressed head, as before
            prof = detect_profile(path, profiles)
        else:
            prof = _detect_in_head(path, raw[:_HEAD_BYTES], profiles)
        raw, data = _decompress(raw, path)
    else:
        prof = _resolve_profile(path, profile, profiles)
        raw, data = _read_raw(path)
    return prof, raw, data


def _decode(data: bytes, prof: Profile, path: Path) -> bytes:
    """The CSV bytes as UTF-8 text (see :func:`_to_utf8`); an empty file is an error."""
    if not data or data.isspace():  # isspace stops at the first other byte
        raise InputError(path, "file is empty", line=1)
    return _to_utf8(data, prof, path)


def _read_header(data: bytes, prof: Profile, path: Path) -> tuple[_Header, dict[str, str]]:
    """The header line (after comments and blank lines) and the metadata comments."""
    hdr = _find_header(data, prof.comment_prefix, prof.separator)
    if hdr is None:
        raise InputError(path, "no header line (only comments or blank lines)", line=data.count(b"\n") + 1)
    metadata = _parse_metadata(hdr.comments) if prof.metadata == "key=value" else {}
    return hdr, metadata


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


def _data_body(data: bytes, hdr: _Header, names: list[str], prof: Profile, path: Path,
               repairs: list[str]) -> bytes:
    """The data lines after the header; a truncated last line (fewer fields than the
    header, no line end) dropped and reported, or an error if the profile says so."""
    body = data[hdr.body_offset:]
    if body and not body.endswith(b"\n"):
        last_start = body.rfind(b"\n") + 1
        last = body[last_start:]
        n_fields = len(next(csv.reader([last.decode("utf-8", errors="replace")], delimiter=prof.separator), [])) if last.strip() else len(names)
        if last.strip() and n_fields < len(names):
            line_no = hdr.line + body.count(b"\n") + 1
            if prof.truncated_last_line == "error":
                raise InputError(path, f"truncated last line: {n_fields} of {len(names)} fields",
                                 line=line_no, column=names[n_fields - 1] if n_fields else names[0])
            body = body[:last_start]
            repairs.append(f"read: truncated last line ({n_fields} of {len(names)} fields) dropped: line {line_no}")
    if not body or body.isspace():
        raise InputError(path, "header only, no data rows", line=hdr.line + 1)
    return body


def _parse_body(body: bytes, hdr: _Header, plan: _ColumnPlan, prof: Profile, path: Path,
                repairs: list[str]) -> tuple[pd.DataFrame, np.ndarray, FastTimes | None]:
    """The used columns of the data lines as a table (numbers float64, text object),
    the file line of each row, and the first column's times when parsed straight from
    the bytes (:func:`fast_first_column`). Field counts are checked per line first;
    rows with no value in any used column are dropped and reported."""
    names, used = plan.names, plan.used
    first_line = hdr.line + 1
    tspec = prof.time
    # --- field counts per line (vectorised): pandas does not check them when reading
    # only some columns. Files with quotes are read whole instead, letting the tokenizer check.
    quoted = b'"' in body
    fast = None
    if not quoted:
        bview = np.frombuffer(body, np.uint8)
        starts, n_sep = _line_stats(bview, ord(prof.separator))
        _check_field_counts(bview, starts, n_sep, len(names), first_line, prof, path, repairs)
        # the time column straight from the bytes when it is first and fixed-width
        if len(tspec.columns) == 1 and names[0] == tspec.columns[0] and len(used) > 1 \
                and tspec.columns[0] not in used[1:]:
            fast = fast_first_column(body, bview, starts, prof.separator, tspec.format)  # type: ignore[arg-type]
    table_cols = used[1:] if fast is not None else used
    df = _read_table(body, path, prof, plan.unique_names, table_cols, plan.num_cols, plan.text_cols, hdr.line,
                     all_cols=quoted)
    if fast is not None and len(fast.ns) != len(df):  # alignment lost (should not happen): slow path
        fast = None
        df = _read_table(body, path, prof, plan.unique_names, used, plan.num_cols, plan.text_cols, hdr.line)
    lines = first_line + np.arange(len(df), dtype=np.int64)

    # blank lines and rows without any used value (with the fast time column, only a
    # blank line can be one: every other line holds a time)
    if fast is not None:
        empty = fast.blank.copy()
        if empty.any():
            empty &= df.isna().all(axis=1).to_numpy()
    else:
        empty = df.isna().all(axis=1).to_numpy().copy()
    if empty.any():
        repairs.append(f"read: {int(empty.sum())} blank rows (no value in any used column) skipped: {_lines_summary(lines[empty])}")
        df = df.loc[~empty].reset_index(drop=True)
        lines = lines[~empty]
        if fast is not None:
            fast = FastTimes(fast.ns[~empty], fast.is_utc, fast.blank[~empty])
    if len(df) == 0:
        raise InputError(path, "no data rows with values", line=first_line)
    return df, lines, fast


def _check_field_counts(bview: np.ndarray, starts: np.ndarray, n_sep: np.ndarray, n_names: int,
                        first_line: int, prof: Profile, path: Path, repairs: list[str]) -> None:
    """More fields than the header is an error (unless only empty trailing fields);
    fewer is reported (the missing fields read as empty)."""
    blank_line = (bview[starts] == 10) | (bview[starts] == 13)
    more = n_sep > n_names - 1
    if more.any():  # surplus fields that are all empty (trailing separators) are harmless
        more &= ~_only_trailing_separators(bview, starts, n_sep - (n_names - 1), ord(prof.separator))
    if more.any():
        i = int(np.flatnonzero(more)[0])
        raise InputError(path, f"malformed CSV: {int(n_sep[i]) + 1} fields, more than the {n_names} of "
                               f"the header", line=first_line + i)
    fewer = (n_sep < n_names - 1) & ~blank_line
    if fewer.any():
        repairs.append(f"read: {int(fewer.sum())} rows with fewer fields than the header (missing fields "
                       f"read as empty): {_lines_summary(first_line + np.flatnonzero(fewer))}")


def _vehicle_codes(df: pd.DataFrame, prof: Profile, lines: np.ndarray, path: Path, vehicle_id: str | None,
                   metadata: dict[str, str], repairs: list[str]) -> tuple[np.ndarray, list[str]]:
    """Per row, the index of its vehicle in the returned list of vehicle ids (in order
    of first appearance): from the vehicle column, else one id for the whole file."""
    if prof.vehicle_source != "column":
        vehicles = [vehicle_id if vehicle_id is not None else _vehicle_from_profile(prof, path, metadata, repairs)]
        return np.zeros(len(df), np.int64), vehicles
    if vehicle_id is not None:
        raise InputError(path, f"profile {prof.name!r} takes vehicle ids from column {prof.vehicle_key!r}; "
                               "a vehicle id override does not apply")
    raw_codes, raw_ids = pd.factorize(df[prof.vehicle_key], sort=False)  # hash, no per-row strip
    stripped = pd.Series(np.asarray(raw_ids, dtype=object)).str.strip()
    uniq_codes, vehicles_idx = pd.factorize(stripped, sort=False)  # ' AB12' and 'AB12' merge
    bad = (raw_codes < 0) | (np.asarray(stripped == "")[np.maximum(raw_codes, 0)] if len(stripped) else True)
    if np.any(bad):
        raise _line_col_error(path, "empty vehicle id", lines, np.asarray(bad), prof.vehicle_key)
    return uniq_codes[raw_codes], [str(v) for v in vehicles_idx]


def _parse_times(df: pd.DataFrame, fast: FastTimes | None, tspec: TimeSpec, lines: np.ndarray,
                 codes: np.ndarray, path: Path, repairs: list[str]) -> np.ndarray:
    """Each row's time as UTC ns since the epoch (int64): parsed (from the bytes, or
    one datetime column, or date and time-of-day columns with date repair), checked,
    and localised from the profile's zone unless the text carries one."""
    if fast is not None:
        col = tspec.columns[0]
        naive, aware = fast.ns, fast.is_utc
        _check_times(path, naive, lines, col, None)
        return naive if aware else _localize(naive, tspec.timezone, codes, lines, repairs)
    if len(tspec.columns) == 1:
        col = tspec.columns[0]
        vals = df[col].to_numpy(dtype=object)
        naive = parse_datetimes(vals, tspec.format)  # type: ignore[arg-type]
        aware = tspec.format == "ISO8601" and has_offset(vals)
        _check_times(path, naive, lines, col, vals)
        return naive if aware else _localize(naive, tspec.timezone, codes, lines, repairs)
    dcol, tcol = tspec.columns
    dvals = df[dcol].to_numpy(dtype=object)
    tvals = df[tcol].to_numpy(dtype=object)
    dcodes, duniq = pd.factorize(pd.Series(dvals), sort=False)
    uniq_ns = parse_datetimes(np.asarray(duniq, dtype=object), tspec.date_format)  # type: ignore[arg-type]
    uniq_ns = np.where((uniq_ns >= _TIME_MIN) & (uniq_ns < _TIME_MAX), uniq_ns, NAT)
    date_ns = np.where(dcodes >= 0, uniq_ns[np.maximum(dcodes, 0)] if len(uniq_ns) else NAT, NAT)
    tod = parse_datetimes(tvals, tspec.time_format)  # type: ignore[arg-type]
    ok_t = tod != NAT
    day0 = (tod[ok_t] // NS_PER_DAY) * NS_PER_DAY
    tod[ok_t] = tod[ok_t] - day0  # time of day [ns]
    badt = ~ok_t
    if badt.any():
        raise _line_col_error(path, "unreadable time of day", lines, badt, tcol, tvals)
    if tspec.date_repair == "dominant":
        date_ns = _repair_dates(date_ns, tod, dvals, lines, tspec.date_repair_max_days, path, dcol, repairs)
    badd = date_ns == NAT
    if badd.any():
        raise _line_col_error(path, f"unreadable date (format {tspec.date_format!r}):", lines, badd, dcol, dvals)
    naive = date_ns + tod
    _check_times(path, naive, lines, dcol, dvals)
    return _localize(naive, tspec.timezone, codes, lines, repairs)


def _canonical_columns(df: pd.DataFrame, maps: list[ColumnMap], utc: np.ndarray, lines: np.ndarray,
                       prof: Profile, path: Path, repairs: list[str]) -> dict[str, np.ndarray]:
    """The canonical columns (``time_s``, ``source_line`` and each mapped column in SI),
    with impossible positions and absurd values handled; a log with neither position nor
    speed values is an error."""
    out: dict[str, np.ndarray] = {"time_s": utc / 1e9, "source_line": lines}
    for m in maps:
        out[m.canonical] = _convert_column(df[m.source], m, lines, path, prof, repairs)
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


def _split_vehicles(out: dict[str, np.ndarray], codes: np.ndarray, vehicles: list[str], maps: list[ColumnMap],
                    prof: Profile, path: Path, metadata: dict[str, str], repairs: list[str],
                    raw: bytes) -> list[ParsedLog]:
    """One :class:`ParsedLog` per vehicle: its rows' canonical columns (a frame built
    around the arrays, no copy, for a single vehicle) and the energy sources they hold."""
    logs = []
    for k, vname in enumerate(vehicles):
        if len(vehicles) > 1:
            sel = codes == k
            arrays = {c: a[sel] for c, a in out.items()}
        else:
            arrays = out
        fr = pd.DataFrame(arrays, copy=False)
        fr.insert(2, "vehicle_id", vname)
        sources = tuple(_energy_source(e, fr, maps) for e in prof.energy if _has_energy_data(e, arrays))
        logs.append(ParsedLog(path, prof.name, vname, fr, dict(metadata), sources, list(repairs), raw))
    return logs


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
    return EnergySource(e.column, e.kind, e.quantity, e.resolution, e.priority, e.capacity_j, src, e.modulus)


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


def _check_times(path: Path, naive: np.ndarray, lines: np.ndarray, col: str, vals: np.ndarray | None) -> None:
    """Unparseable or absurd (before 1990 or from 2100) times are errors with their line."""
    bad = (naive == NAT) | (naive < _TIME_MIN) | (naive >= _TIME_MAX)
    if bad.any():
        raise _line_col_error(path, "unreadable or impossible time", lines, bad, col, vals)


def _convert_column(s: pd.Series, m: ColumnMap, lines: np.ndarray, path: Path, prof: Profile,
                    repairs: list[str]) -> np.ndarray:
    """One source column as float64 in SI (NaN = no value)."""
    if m.value_map is not None:
        mapping = dict(m.value_map)
        res = s.map(mapping)
        todo = (res.isna() & s.notna()).to_numpy()
        if todo.any():
            folded = {k.strip().casefold(): v for k, v in m.value_map}
            res2 = s[todo].str.strip().str.casefold().map(folded)
            res[todo] = res2
            still = (res.isna() & s.notna()).to_numpy()
            if still.any():
                raise _line_col_error(path, f"value not in the profile's map ({', '.join(k for k, _ in m.value_map)}):",
                                      lines, still, m.source, s.to_numpy())
        x = res.to_numpy(dtype=np.float64)
    else:
        x = s.to_numpy(dtype=np.float64, copy=True)
        if m.missing_values:
            miss = np.isin(x, np.asarray(m.missing_values))
            if miss.any():
                x[miss] = np.nan
                repairs.append(f"{m.canonical}: {int(miss.sum())} values equal to the logger's missing-value "
                               f"marker ({', '.join(f'{v:g}' for v in m.missing_values)}) in column "
                               f"'{m.source}' set to NaN: {_lines_summary(lines[miss])}")
        if m.factor != 1.0:
            x *= m.factor
    if m.negate:
        x = -x
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
    lo, hi = PLAUSIBLE_RANGE_SI[m.canonical]
    with np.errstate(invalid="ignore"):
        bad = (x < lo) | (x > hi)
    if not bad.any():
        return
    n_values = int(np.isfinite(x).sum())
    as_logged = (-x if m.negate else x) / m.factor  # for messages, in the logger's unit
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
    with np.errstate(invalid="ignore"):
        lat_bad, lon_bad = np.abs(lat) > 90.0, np.abs(lon) > 180.0
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
