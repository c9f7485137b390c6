"""Trip manifests: a transport management system's CSV export of who carried what, read
into :class:`ManifestRow`\\ s (matching them to stored trips is
:mod:`cevm.store.masses`).

A row names a vehicle and a trip: a stored trip id, or a time window (start and end);
and a mass: the gross mass or the payload, in kg (or t). What the options do not say is
detected from the header:

- the separator: the most frequent of ``,`` ``;`` tab ``|`` in the header line;
- the decimal mark: ``.``, but ``,`` in a ``;``-separated file (the European habit);
  thousands separators are read where they are unambiguous (``43,240`` with a decimal
  point, ``43.240`` with a decimal comma);
- the columns, by name (case, spaces and punctuation ignored, a unit at the end too):
  vehicle (``vehicle_id``, ``vehicle``, ``registration``, ``plate``, ``truck``, ``unit``,
  ...), trip (``trip_id``), start (``start``, ``departure``, ``window_start``, ...), end
  (``end``, ``arrival``, ``window_end``, ...), gross (``gross_kg``, ``Gross weight (t)``,
  ``gvw``, ``gcw``, ``total_weight``, ...), payload (``payload_kg``, ``cargo``,
  ``net_weight``, ``load``, ...); the mass unit from the name (``gross_t``, ``Payload
  (t)``; else kg). :data:`_NAMES` lists them.

Times are ISO 8601 (``2019-05-14T08:00:00``, a space for the ``T`` allowed, seconds
optional); one with a zone (``Z``, ``+02:00``) is taken as it says, one without needs
``tz`` (an IANA name such as ``Europe/London``, ``UTC``, or an offset ``+01:00``) and is
refused otherwise: a local time read as UTC would match the wrong trips. A row with both
a gross mass and a payload uses the gross.

Problems of a single row (a bad number, a bad time, no mass) are reported with file, line
and column and that row is left out (:attr:`Manifest.problems`); a file without the
columns it needs is an :class:`~cevm.errors.InputError`. Masses out of
:data:`GROSS_RANGE_KG` / :data:`PAYLOAD_RANGE_KG` are refused (a mass in tonnes read as
kg, a thousands separator read as a decimal mark).

Bounds, checked before the work: a manifest is a regular file (not a FIFO or a device:
:mod:`cevm.io.inputs`) of at most :data:`MAX_MANIFEST_BYTES` (refused from its size
before it is read) and :data:`MAX_MANIFEST_ROWS` rows (refused at the row past it); it
is read as a stream, line by line, and a line (a field) longer than
:data:`MAX_FIELD_BYTES`, a NUL byte or text that is not UTF-8 is refused with its line.
"""

from __future__ import annotations

import csv
import datetime as dt
import heapq
import io
import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

from cevm.errors import InputError
from cevm.io.inputs import CSV_FIELD_BYTES, check_size, csv_reason, open_regular

#: Largest manifest read [bytes]: about a million rows of a TMS export (56 MB for a
#: million window rows of vehicle, start, end and mass).
MAX_MANIFEST_BYTES = 64 << 20
#: Most rows a manifest may hold (a fleet of 500 vehicles, 5 trips a day, a year: 0.9 M);
#: a larger export is given in parts (by month, by depot). Streamed, its rows are never
#: all held: ``cevm trips set-mass --manifest`` of a million rows peaked at 126 MB
#: (before: 585-631 MB, and 1.67 GB at 3 M rows), and took 24-37 s.
MAX_MANIFEST_ROWS = 1_000_000
#: Longest field of a manifest [bytes] (Python's csv reader's own limit, 128 KiB).
MAX_FIELD_BYTES = CSV_FIELD_BYTES

#: Plausible gross masses [kg] of a road vehicle in a manifest: below, a light
#: quadricycle's kerb mass; above, nothing that drives on a road.
GROSS_RANGE_KG = (200.0, 1_000_000.0)
#: Plausible payloads [kg].
PAYLOAD_RANGE_KG = (0.0, 1_000_000.0)

#: Column names each role is recognised by, in order of preference (normalised: lower
#: case, runs of other characters as one ``_``, a unit at the end dropped: ``gross_kg``).
_NAMES = {
    "vehicle": ("vehicle_id", "vehicle", "vehicleid", "vehicle_no", "vehicle_number", "vehicle_reg", "registration",
                "registration_number", "reg", "reg_no", "plate", "licence_plate", "license_plate", "number_plate",
                "truck", "truck_id", "tractor", "unit", "unit_id", "asset", "asset_id", "fahrzeug", "kennzeichen"),
    "trip": ("trip_id", "tripid", "trip", "cevm_trip_id", "cevm_trip"),
    "start": ("start", "start_utc", "start_time", "start_datetime", "window_start", "departure", "departure_time",
              "depart", "departed", "begin", "from", "dispatch", "dispatched", "abfahrt"),
    "end": ("end", "end_utc", "end_time", "end_datetime", "window_end", "arrival", "arrival_time", "arrive", "arrived",
            "to", "until", "returned", "ankunft"),
    "gross": ("gross", "gross_weight", "gross_mass", "gross_vehicle_weight", "gross_combination_weight",
              "gross_combination_mass", "gvw", "gcw", "gcm", "total_weight", "total_mass", "gesamtgewicht"),
    "payload": ("payload", "payload_weight", "payload_mass", "cargo", "cargo_weight", "cargo_mass", "net_weight",
                "load", "load_weight", "nutzlast", "ladung", "ladegewicht"),
}
_UNIT_TOKENS = {"kg": "kg", "kgs": "kg", "t": "t", "tonnes": "t", "tonne": "t", "tons": "t", "ton": "t"}
_SEPARATORS = (",", ";", "\t", "|")
_ISO = re.compile(r"\d{4}-\d{2}-\d{2}([T ]\d{2}:\d{2}(:\d{2}(\.\d+)?)?)?(Z|[+-]\d{2}:?\d{2})?")
_OFFSET = re.compile(r"(?:UTC)?([+-])(\d{2}):?(\d{2})")


@dataclass(frozen=True)
class ManifestFormat:
    """How to read a manifest; None: detect (see the module notes). ``sep``: ``,`` ``;``
    ``tab`` ``|``; ``decimal``: ``.`` or ``,``; the ``*_col`` options: a column's name
    in the header; ``mass_unit``: ``kg`` or ``t``; ``tz``: the zone of times without
    one."""

    sep: str | None = None
    decimal: str | None = None
    vehicle_col: str | None = None
    trip_col: str | None = None
    start_col: str | None = None
    end_col: str | None = None
    gross_col: str | None = None
    payload_col: str | None = None
    mass_unit: str | None = None
    tz: str | None = None


@dataclass(frozen=True, slots=True)
class ManifestRow:
    """One usable row: its 1-based ``line`` in the file, the vehicle id (or None), a trip
    id or a window [s since the Unix epoch, UTC], and ``kind`` ('gross' | 'payload')
    with ``mass_kg``."""

    line: int
    vehicle_id: str | None
    trip_id: str | None
    start_utc_s: float | None
    end_utc_s: float | None
    kind: str
    mass_kg: float


@dataclass(frozen=True)
class Manifest:
    """A read manifest: its resolved ``path``, the usable ``rows``, the ``problems`` of
    the others (``(line, message)``, message naming the column), and the column used for
    each role (``columns``) with the mass unit and decimal mark."""

    path: str
    rows: tuple[ManifestRow, ...]
    problems: tuple[tuple[int, str], ...]
    columns: dict[str, str] = field(default_factory=dict)
    mass_unit: str = "kg"
    decimal: str = "."

    @property
    def n_rows(self) -> int:
        """Rows read (usable or not; blank lines not counted)."""
        return len(self.rows) + len(self.problems)

    def items(self) -> Iterator[ManifestRow | tuple[int, str]]:
        """The rows and the problems of the others, in the order of their lines (as
        :meth:`ManifestReader.items` gives them)."""
        return heapq.merge(self.rows, self.problems, key=lambda x: x.line if isinstance(x, ManifestRow) else x[0])


def _norm(name: str) -> str:
    return re.sub(r"[^0-9a-z]+", "_", name.strip().lower()).strip("_")


def _unit_of(norm_name: str) -> str | None:
    for tok in reversed(norm_name.split("_")):
        if tok in _UNIT_TOKENS:
            return _UNIT_TOKENS[tok]
    return None


def _strip_unit(norm_name: str) -> str:
    toks = norm_name.split("_")
    while len(toks) > 1 and toks[-1] in _UNIT_TOKENS:
        toks.pop()
    return "_".join(toks)


def _find(header: list[str], role: str) -> str | None:
    """The first column, in the order of :data:`_NAMES`' candidates, named for ``role``."""
    norms = {h: _strip_unit(_norm(h)) for h in header}
    for cand in _NAMES[role]:
        for h, n in norms.items():
            if n == cand:
                return h
    return None


def _column(path: Path, header: list[str], role: str, given: str | None) -> str | None:
    if given is None:
        return _find(header, role)
    if given not in header:
        raise InputError(path, f"no column {given!r} (for the {role}); the header has: {', '.join(header)}", line=1)
    return given


def parse_zone(tz: str | None) -> dt.tzinfo | None:
    """``tz`` as a tzinfo: an IANA name (``Europe/London``), ``UTC``, or an offset
    (``+01:00``, ``UTC+0100``); None for None. Raises ValueError for anything else."""
    if tz is None:
        return None
    if tz.strip().upper() in ("UTC", "Z", "GMT"):
        return dt.UTC
    m = _OFFSET.fullmatch(tz.strip())
    if m:
        sign = 1 if m.group(1) == "+" else -1
        return dt.timezone(sign * dt.timedelta(hours=int(m.group(2)), minutes=int(m.group(3))))
    try:
        return ZoneInfo(tz.strip())
    except (ZoneInfoNotFoundError, ValueError):
        raise ValueError(f"unknown time zone {tz!r}: give an IANA name (Europe/London), UTC or an offset "
                         "(+01:00)") from None


def _time(text: str, zone: dt.tzinfo | None) -> float:
    """Seconds since the Unix epoch of an ISO 8601 time; ValueError with the reason."""
    s = text.strip()
    if not _ISO.fullmatch(s):
        raise ValueError(f"{text!r} is not an ISO 8601 time (YYYY-MM-DDTHH:MM[:SS][Z|+HH:MM])")
    t = dt.datetime.fromisoformat(s.replace("Z", "+00:00") if s.endswith("Z") else s)
    if t.tzinfo is None:
        if zone is None:
            raise ValueError(f"{text!r} has no time zone: give the manifest's zone (--tz Europe/London, --tz UTC, "
                             "--tz +01:00)")
        if isinstance(zone, dt.timezone):
            t = t.replace(tzinfo=zone)
        else:  # an IANA zone: refuse the hour that does not exist or happens twice
            naive = t
            t0, t1 = t.replace(tzinfo=zone, fold=0), t.replace(tzinfo=zone, fold=1)
            if all(x.astimezone(dt.UTC).astimezone(zone).replace(tzinfo=None) != naive for x in (t0, t1)):
                raise ValueError(f"{text!r} does not exist in {zone} (clocks going forward)")
            if t0.utcoffset() != t1.utcoffset():
                raise ValueError(f"{text!r} happens twice in {zone} (clocks going back); give it with its offset")
            t = t0
    return t.timestamp()


def _number(text: str, decimal: str) -> float:
    s = text.strip().replace("\u00a0", "").replace(" ", "")
    if decimal == ",":
        if re.fullmatch(r"-?\d{1,3}(\.\d{3})+(,\d*)?", s):
            s = s.replace(".", "")
        s = s.replace(",", ".")
    elif re.fullmatch(r"-?\d{1,3}(,\d{3})+(\.\d*)?", s):
        s = s.replace(",", "")
    if not re.fullmatch(r"-?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?", s):
        raise ValueError(f"{text!r} is not a number (decimal mark {decimal!r})")
    return float(s)


class ManifestReader:
    """A manifest opened for reading, as a stream (:func:`open_manifest`): its header
    read and checked (``path``, ``columns``, ``mass_unit``, ``decimal``), its rows given
    one at a time by :meth:`items`, so that a manifest of any length within the bounds
    is matched without holding its rows (:func:`cevm.store.masses.match_manifest`)."""

    def __init__(self, path: Path, raw, fmt: ManifestFormat, max_rows: int):
        self.path = str(path.resolve())
        self._file = path
        self._raw = raw
        self._text = io.TextIOWrapper(raw, encoding="utf-8-sig", newline="")
        self.max_rows = max_rows
        self.n_rows = 0
        self._guard(lambda: self._header(fmt))

    def __enter__(self) -> ManifestReader:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self._text.close()

    def _guard(self, step):
        """``step()``, with the file's read errors as :class:`InputError`."""
        try:
            return step()
        except UnicodeDecodeError as exc:
            raise InputError(self._file, f"not UTF-8 text ({exc.reason}): export the manifest as UTF-8 CSV") from None
        except OSError as exc:
            raise InputError(self._file, f"cannot read: {exc.strerror or exc}") from None

    def _header(self, fmt: ManifestFormat) -> None:
        path = self._file
        first = self._text.readline(MAX_FIELD_BYTES + 1)
        if len(first) > MAX_FIELD_BYTES:
            raise InputError(path, f"a header line longer than {MAX_FIELD_BYTES // 1024} KiB: not a manifest", line=1)
        if not first.strip():
            raise InputError(path, "empty: a manifest starts with a header line", line=1)
        sep = {"tab": "\t", "\\t": "\t"}.get(fmt.sep, fmt.sep) if fmt.sep else max(_SEPARATORS, key=first.count)
        if sep not in _SEPARATORS:
            raise InputError(path, f"separator {fmt.sep!r}: use one of , ; tab |")
        decimal = fmt.decimal or ("," if sep == ";" else ".")
        if decimal not in (".", ","):
            raise InputError(path, f"decimal mark {decimal!r}: use . or ,")
        if decimal == sep:
            raise InputError(path, f"the decimal mark and the separator are both {sep!r}")
        try:
            self.zone = parse_zone(fmt.tz)
        except ValueError as exc:
            raise InputError(path, str(exc)) from None
        header = [h.strip() for h in _records(path, io.StringIO(first), sep)[0]]
        cols = {role: _column(path, header, role, getattr(fmt, f"{role}_col"))
                for role in ("vehicle", "trip", "start", "end", "gross", "payload")}
        if fmt.payload_col is not None and fmt.gross_col is None:
            cols["gross"] = None  # the payload was asked for
        if fmt.gross_col is not None and fmt.payload_col is None:
            cols["payload"] = None
        if cols["gross"] is None and cols["payload"] is None:
            raise InputError(path, "no mass column: name one gross_kg or payload_kg (or give --gross-col / "
                                   f"--payload-col); the header has: {', '.join(header)}", line=1)
        if cols["trip"] is None and (cols["start"] is None or cols["end"] is None or cols["vehicle"] is None):
            raise InputError(path, "a manifest needs a trip id column, or vehicle, start and end columns (give "
                                   f"--trip-col, or --vehicle-col, --start-col, --end-col); the header has: "
                                   f"{', '.join(header)}", line=1)
        units = {}
        for role in ("gross", "payload"):
            col = cols[role]
            if col is not None:
                units[role] = fmt.mass_unit or _unit_of(_norm(col)) or "kg"
                if units[role] not in ("kg", "t"):
                    raise InputError(path, f"mass unit {units[role]!r}: use kg or t")
        self.sep, self.decimal, self._cols, self._units = sep, decimal, cols, units
        self._index = {h: i for i, h in enumerate(header)}
        self.columns = {k: v for k, v in cols.items() if v is not None}
        self.mass_unit = units.get("gross", units.get("payload", "kg"))

    def items(self) -> Iterator[ManifestRow | tuple[int, str]]:
        """Each row as a :class:`ManifestRow`, or ``(line, why)`` for a row that cannot
        be used, in the file's order; :class:`InputError` for a line that is no CSV
        (a field over :data:`MAX_FIELD_BYTES`, a NUL byte) or past ``max_rows`` rows."""
        reader = csv.reader(self._text, delimiter=self.sep)
        cols, index = self._cols, self._index
        while True:
            try:
                rec = self._guard(lambda: next(reader, None))
            except csv.Error as exc:
                raise InputError(self._file, f"not a CSV line: {csv_reason(exc)}", line=reader.line_num + 1) from None
            if rec is None:
                return
            line_no = reader.line_num + 1  # the header was line 1 (a record spanning lines: its last)
            if not any(x.strip() for x in rec):
                continue  # a blank line
            self.n_rows += 1
            if self.n_rows > self.max_rows:
                raise InputError(self._file, f"more than {self.max_rows:,} rows: give the manifest in parts (by "
                                             "month, by depot)", line=line_no)
            cell = {role: (rec[index[c]].strip() if c is not None and index[c] < len(rec) else "")
                    for role, c in cols.items()}
            try:
                yield _row(line_no, cell, cols, self._units, self.decimal, self.zone)
            except ValueError as exc:
                yield line_no, str(exc)


def open_manifest(path: str | Path, fmt: ManifestFormat | None = None, *,
                  max_rows: int | None = None) -> ManifestReader:
    """Open the manifest at ``path`` for streaming (:class:`ManifestReader`; use it as a
    context manager): a regular file of at most :data:`MAX_MANIFEST_BYTES`, refused from
    its size before it is read, its header read and checked now."""
    path = Path(path)
    raw = open_regular(path, "manifest")
    try:
        check_size(path, raw, MAX_MANIFEST_BYTES, "manifest", ": give it in parts (by month, by depot)")
        return ManifestReader(path, raw, fmt or ManifestFormat(), MAX_MANIFEST_ROWS if max_rows is None else max_rows)
    except BaseException:
        raw.close()
        raise


def read_manifest(path: str | Path, fmt: ManifestFormat | None = None, *,
                  max_rows: int | None = None) -> Manifest:
    """Read the manifest at ``path`` whole (see the module notes; :func:`open_manifest`
    streams it); raises :class:`~cevm.errors.InputError` for a file it cannot use at all,
    or beyond the bounds (:data:`MAX_MANIFEST_BYTES`, ``max_rows``, default
    :data:`MAX_MANIFEST_ROWS`, :data:`MAX_FIELD_BYTES`)."""
    with open_manifest(path, fmt, max_rows=max_rows) as reader:
        rows: list[ManifestRow] = []
        problems: list[tuple[int, str]] = []
        for item in reader.items():
            if isinstance(item, ManifestRow):
                rows.append(item)
            else:
                problems.append(item)
    return Manifest(reader.path, tuple(rows), tuple(problems), reader.columns, reader.mass_unit, reader.decimal)


def _records(path: Path, stream, sep: str) -> list[list[str]]:
    """The CSV records of ``stream`` (the header line), errors as :class:`InputError`."""
    try:
        return list(csv.reader(stream, delimiter=sep))
    except csv.Error as exc:
        raise InputError(path, f"not a CSV line: {csv_reason(exc)}", line=1) from None


def _row(line: int, cell: dict, cols: dict, units: dict, decimal: str, zone) -> ManifestRow:
    """One row as a :class:`ManifestRow`; ValueError naming the column otherwise."""

    def fail(role: str, why: str) -> ValueError:
        return ValueError(f"column {cols[role]!r}: {why}")

    kind = "gross" if cell["gross"] else "payload" if cell["payload"] else None
    if kind is None:
        names = " or ".join(repr(cols[r]) for r in ("gross", "payload") if cols[r] is not None)
        raise ValueError(f"no mass in column {names}")
    try:
        value = _number(cell[kind], decimal) * (1000.0 if units[kind] == "t" else 1.0)
    except ValueError as exc:
        raise fail(kind, str(exc)) from None
    lo, hi = GROSS_RANGE_KG if kind == "gross" else PAYLOAD_RANGE_KG
    if not lo <= value <= hi:
        hint = ("" if value > hi else f": in tonnes? (give --mass-unit t) a thousands separator read as the decimal "
                f"mark? (give --decimal {'.' if decimal == ',' else ','})")
        raise fail(kind, f"{value:,.6g} kg is not a plausible {kind} mass ({lo:,.0f} to {hi:,.0f} kg){hint}")
    trip_id = cell["trip"] or None
    start = end = None
    if trip_id is None:
        for role in ("start", "end", "vehicle"):
            if cols[role] is None or not cell[role]:
                raise ValueError(f"no trip id, and no {role}" + (f" in column {cols[role]!r}" if cols[role] else ""))
        try:
            start = _time(cell["start"], zone)
        except ValueError as exc:
            raise fail("start", str(exc)) from None
        try:
            end = _time(cell["end"], zone)
        except ValueError as exc:
            raise fail("end", str(exc)) from None
        if end <= start:
            raise fail("end", f"{cell['end']!r} is not after the start {cell['start']!r}")
    return ManifestRow(line, cell["vehicle"] or None, trip_id, start, end, kind, value)
