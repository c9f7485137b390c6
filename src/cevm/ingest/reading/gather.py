"""The parsed blocks gathered into whole-file columns, with what is done per block while
its text is at hand: vehicle ids to codes, times to ns, value maps to numbers, the row
limit (:class:`ColumnGatherer`)."""

from __future__ import annotations

import csv
import re
from pathlib import Path

import numpy as np

from cevm.errors import InputError, has_control
from cevm.ingest.profiles import ColumnMap, Profile
from cevm.ingest.reading.blocks import ParsedBlock, ReadRepairs
from cevm.ingest.reading.cells import BadCells, check_bad_cells
from cevm.ingest.reading.engine_arrow import _arrow
from cevm.ingest.reading.header import ColumnPlan, Header
from cevm.ingest.reading.lines import _line_col_error, _lines_summary
from cevm.ingest.reading.local_time import (
    _ISO_SAMPLE_RE,
    _ZONE_RE,
    _localize,
    _mixed_zone_message,
    _repair_dates,
)
from cevm.ingest.reading.plausibility import _TIME_MAX, _TIME_MIN, _check_times
from cevm.ingest.textfile import ReadLimits
from cevm.ingest.timestamps import (
    EPOCH_FORMATS,
    NAT,
    NS_PER_DAY,
    epoch_ns,
    parse_datetimes,
)
from cevm.lazy import pd
from cevm.runtime import release_free_memory


class ColumnGatherer:
    """The blocks' columns gathered into whole-file arrays, with what must be done per
    block while the text is at hand: vehicle ids (to codes), the time column (to ns),
    value-map columns (to numbers); the row limit."""

    def __init__(self, plan: ColumnPlan, prof: Profile, path: Path, limits: ReadLimits, repairs: ReadRepairs) -> None:
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
        self._bad_cells: dict[str, BadCells] = {}  # measured columns' cells that were not numbers
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
    def set_vehicle(self, vehicle_id: str | None, metadata: dict[str, str], hdr: Header) -> None:
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
            src: str = prof.vehicle_source
            line = None
            if src == "metadata" and not metadata.get(prof.vehicle_key or "", "").strip():
                src = prof.vehicle_fallback
            elif src == "metadata":
                line = next((ln for c, ln in zip(hdr.comments, hdr.comment_lines, strict=True)
                             if c.partition("=")[0].strip() == prof.vehicle_key), None)
            where = {"metadata": f"metadata key {prof.vehicle_key!r}", "fixed": "the profile's vehicle.value",
                     "file_stem": "the file name", "parent_dir": "the directory name"}[src]
            _check_vehicle_id(vid, path, line, None, where)
        self.vehicle = vid

    def arrow_time_type(self, block: bytes, plan: ColumnPlan, prof: Profile):
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
    def add(self, part: ParsedBlock, last: bool) -> None:
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
        for c, found in part.bad_cells.items():
            self._bad_cells.setdefault(c, BadCells()).add(found)
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

    def _vehicle_part(self, part: ParsedBlock, upto: int | None) -> np.ndarray:
        key = self.prof.vehicle_key
        assert key is not None  # a vehicle column's profile names it
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

    def _time_part(self, part: ParsedBlock, upto: int | None) -> None:
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
        dvals = FactorisedValues(values, date_codes)
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
        canonical name), each as one array; the blocks' pieces are released as it goes.
        The cells of a measured column that were not numbers are reported (or, when they
        are most of it, refused: :func:`~.cells.check_bad_cells`)."""
        out: dict[str, np.ndarray] = {}
        for c in list(self._numbers):
            out[c] = _concat(self._numbers.pop(c))
            found = self._bad_cells.pop(c, None)
            if found is not None:
                m = next(m for m in self.plan.maps if m.source == c and m.value_map is None)
                check_bad_cells(self.path, c, m.canonical, m.unit, found, int(np.count_nonzero(~np.isnan(out[c]))),
                                self.prof.absurd_error_share, self.repairs.columns)
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


class FactorisedValues:
    """Row values of a factorised text column, made on demand (for messages)."""

    def __init__(self, values: np.ndarray, codes: np.ndarray) -> None:
        self.values, self.codes = values, codes

    def __getitem__(self, idx):
        c = self.codes[idx]
        if np.ndim(c) == 0:
            return self.values[c] if c >= 0 else np.nan
        return np.where(c >= 0, self.values[np.maximum(c, 0)] if len(self.values) else np.nan, np.nan)


def _first_value(block: bytes, index: int, sep: str, max_lines: int = 50) -> str | None:
    """The first non-empty value of field ``index`` in the first lines of ``block``."""
    head = bytes(block[: 1 << 16]).decode("utf-8", errors="replace").splitlines()[:max_lines]
    for row in csv.reader(head, delimiter=sep):
        if index < len(row) and row[index].strip():
            return row[index].strip()
    return None


#: Longest vehicle id a log may give [characters]: a vehicle file's bound
#: (:data:`cevm.io.vehicles.ID_MAX_CHARS`), so that every id a log gives can be a vehicle
#: file's, and a 900 kB metadata comment is not stored as an id printed in every row.
LOG_ID_MAX_CHARS = 80


def _check_vehicle_id(vid: str, path: Path, line: int | None, column: str | None, where: str | None) -> None:
    """A vehicle id may not hold control characters (a carriage return or line feed in
    an id breaks CSV output and forges lines), nor be longer than
    :data:`LOG_ID_MAX_CHARS`; refused at read."""
    src = f" from {where}" if where else ""
    if len(vid) > LOG_ID_MAX_CHARS:
        raise InputError(path, f"vehicle id {vid[:40]!r}...{src} is {len(vid):,} characters long, more than "
                               f"{LOG_ID_MAX_CHARS}", line=line, column=column)
    if has_control(vid):
        raise InputError(path, f"vehicle id {vid!r}{src} holds a control character; ids must be printable text",
                         line=line, column=column)


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
        repairs.append(f"vehicle: no '{prof.vehicle_key}' metadata; vehicle id taken from the file's "
                       f"{src.replace('_', ' ')}")
    name = path.name
    for suffix in (".gz", ".csv", ".txt"):
        if name.lower().endswith(suffix):
            name = name[: -len(suffix)]
    return path.resolve().parent.name if src == "parent_dir" else name


def _map_values(vals: np.ndarray, m: ColumnMap, lines: np.ndarray, path: Path, upto: int | None) -> np.ndarray:
    """A value-map column's text (e.g. ``On``/``Off``) as float64 (NaN = no value);
    matched exactly, else ignoring case and surrounding space; other text is an error."""
    s = pd.Series(vals, dtype=object)
    value_map = m.value_map
    assert value_map is not None  # a value-map column
    mapping = dict(value_map)
    res = s.map(mapping)
    todo = (res.isna() & s.notna()).to_numpy()
    if todo.any():
        folded = {k.strip().casefold(): v for k, v in value_map}
        res2 = s[todo].str.strip().str.casefold().map(folded)
        res[todo] = res2
        still = (res.isna() & s.notna()).to_numpy()
        if still.any():
            raise _line_col_error(path, f"value not in the profile's map ({', '.join(k for k, _ in value_map)}):",
                                  lines, still, m.source, vals, upto)
    return res.to_numpy(dtype=np.float64)
