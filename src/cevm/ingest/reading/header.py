"""A log's header line and metadata comments, and the columns the profile reads from it."""

from __future__ import annotations

import csv
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from cevm.errors import InputError
from cevm.ingest.profiles import ColumnMap, Profile
from cevm.ingest.textfile import MAX_LINE_BYTES, Utf8Stream


@dataclass(frozen=True)
class Header:
    names: tuple[str, ...]
    line: int  # 1-based line of the header
    body_offset: int  # byte offset of the first data line
    comments: tuple[str, ...]
    comment_lines: tuple[int, ...] = ()  # 1-based line of each comment


def _find_header(data: bytes, prefix: str, sep: str) -> Header | None:
    """Skip blank and comment lines; parse the header line. ``None`` if there is none."""
    return _HeaderScan(prefix, sep).scan(data)


class _HeaderScan:
    """The lines before a header, scanned piece by piece: each piece of text is scanned
    once (the comments and their line numbers carried over), so that the time to find a
    header is linear in the text before it however many pieces it arrives in."""

    def __init__(self, prefix: str, sep: str) -> None:
        self.pbytes = prefix.encode("utf-8") if prefix else None
        self.sep = sep
        self.line_no = 0  # lines scanned
        self.offset = 0  # bytes scanned
        self.comments: list[str] = []
        self.comment_lines: list[int] = []

    def scan(self, data: bytes) -> Header | None:
        """Scan the whole lines of ``data`` (the text after what was scanned before; its
        last line is taken as whole too); the header, with ``body_offset`` counted from
        the start of the text, or ``None`` when ``data`` holds none."""
        pos, n, pbytes = 0, len(data), self.pbytes
        while pos < n:
            nl = data.find(b"\n", pos)
            end = n if nl < 0 else nl
            self.line_no += 1
            raw_line = data[pos:end].strip()
            nxt = n if nl < 0 else nl + 1
            if pbytes and raw_line.startswith(pbytes):
                self.comments.append(raw_line[len(pbytes):].decode("utf-8", errors="replace").strip())
                self.comment_lines.append(self.line_no)
            elif raw_line:
                text = raw_line.decode("utf-8", errors="replace").replace("\r", " ")
                names = next(csv.reader([text], delimiter=self.sep))
                return Header(tuple(s.strip() for s in names), self.line_no, self.offset + nxt,
                              tuple(self.comments), tuple(self.comment_lines))
            pos = nxt
        self.offset += n
        return None


def _parse_metadata(comments: tuple[str, ...]) -> dict[str, str]:
    """``key=value`` comment lines as a dict (stripped; later keys win)."""
    meta = {}
    for c in comments:
        k, eq, v = c.partition("=")
        if eq and k.strip():
            meta[k.strip()] = v.strip()
    return meta


def _read_header(text: Utf8Stream, prof: Profile, path: Path) -> tuple[Header, dict[str, str], bytes]:
    """The header line (after comments and blank lines), the metadata comments, and the
    text after the header read so far. Reads only as far as the header's line end; a
    first line longer than :data:`MAX_LINE_BYTES` (a file without line breaks) is
    refused there. Each piece of text is scanned once (:class:`_HeaderScan`): only a
    line cut at a piece's end is carried to the next."""
    scan = _HeaderScan(prof.comment_prefix, prof.separator)
    carry = b""
    while True:
        chunk = text.read()
        eof = not chunk
        data = carry + chunk if carry else chunk
        if eof and not scan.comments and (not data or data.isspace()):  # isspace stops at the first other byte
            raise InputError(path, "file is empty", line=1)
        last_nl = data.rfind(b"\n")
        if len(data) - last_nl - 1 > MAX_LINE_BYTES:
            line = scan.line_no + data.count(b"\n") + 1
            raise InputError(path, f"no line break in {MAX_LINE_BYTES >> 20} MiB of text from line {line}: not a "
                                   "CSV log (a line that long is binary data or a file without line breaks)",
                             line=line)
        complete = data if eof else data[:last_nl + 1]  # whole lines only: a cut header waits for its end
        start = scan.offset
        try:
            hdr = scan.scan(complete)
        except csv.Error as exc:
            raise InputError(path, f"unreadable header line: {exc}", line=scan.line_no) from None
        if hdr is not None:
            metadata = _parse_metadata(hdr.comments) if prof.metadata == "key=value" else {}
            return hdr, metadata, data[hdr.body_offset - start:]
        if eof:  # the line after the last, as a count of the text's line breaks plus one
            line = scan.line_no + (1 if not complete or complete.endswith(b"\n") else 0)
            raise InputError(path, "no header line (only comments or blank lines)", line=line)
        carry = data[last_nl + 1:]


@dataclass(frozen=True)
class ColumnPlan:
    """Which of the header's columns the profile reads, and as what."""

    names: list[str]  # the header's column names
    unique_names: list[str]  # the same, duplicates made unique (name NUL index)
    maps: list[ColumnMap]  # the profile's column maps whose source is in the header
    text_cols: list[str]  # read as text: time columns, vehicle column, value-map columns
    num_cols: list[str]  # read as numbers
    used: list[str]  # text_cols + num_cols, each once
    #: numeric columns whose every cell must be a number (the profile's ``required``
    #: columns, and those its detection needs): a cell that is not one is an error;
    #: in the others it is a missing value, reported (:mod:`.cells`)
    required_num: frozenset[str] = frozenset()
    units: dict[str, str] = field(default_factory=dict)  # numeric column -> the profile's unit


def _plan_columns(prof: Profile, hdr: Header, path: Path) -> ColumnPlan:
    """The columns to read; a header lacking a required, time or vehicle column, or
    naming a used column twice, is an error at the header's line."""
    names = list(hdr.names)
    # One pass over the header for every membership and duplicate test below: a header
    # may be 100,000 names wide, and a list's count or ``in`` per name was quadratic.
    counts = Counter(names)
    missing_req = [c for c in prof.required_columns if c not in counts]
    if missing_req:
        raise InputError(path, f"header lacks column(s) {missing_req} required by profile {prof.name!r}",
                         line=hdr.line, column=missing_req[0])
    for c in prof.time.columns:
        if c not in counts:
            raise InputError(path, f"no time column: header lacks {c!r} (profile {prof.name!r})", line=hdr.line,
                             column=c)
    if prof.vehicle_source == "column" and prof.vehicle_key not in counts:
        raise InputError(path, f"header lacks the vehicle column {prof.vehicle_key!r}", line=hdr.line,
                         column=prof.vehicle_key)
    maps = [m for m in prof.columns if m.source in counts]
    for m in prof.columns:
        if m.required and m.source not in counts:
            raise InputError(path, f"header lacks required column {m.source!r}", line=hdr.line, column=m.source)
    text_cols = list(prof.time.columns) + ([prof.vehicle_key] if prof.vehicle_source == "column" and prof.vehicle_key
                                           else [])
    text_cols += [m.source for m in maps if m.value_map is not None]
    num_cols = [m.source for m in maps if m.value_map is None]
    used = list(dict.fromkeys(text_cols + num_cols))
    dups = sorted({c for c in used if counts[c] > 1})
    if dups:
        raise InputError(path, f"column name(s) {dups} appear more than once in the header", line=hdr.line,
                         column=dups[0])
    unique_names = [f"{n}\x00{i}" if counts[n] > 1 else n for i, n in enumerate(names)]
    required_num = frozenset(m.source for m in maps if m.value_map is None and
                             (m.required or m.source in prof.required_columns))
    units = {m.source: m.unit for m in maps if m.value_map is None and m.unit}
    return ColumnPlan(names, unique_names, maps, text_cols, num_cols, used, required_num, units)


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
