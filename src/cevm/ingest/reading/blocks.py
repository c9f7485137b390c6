"""A log's data lines cut into blocks of whole lines (a truncated last line dropped), and
what a parse engine makes of one block (:class:`ParsedBlock`)."""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from cevm.errors import InputError
from cevm.ingest.profiles import Profile
from cevm.ingest.reading.header import Header
from cevm.ingest.reading.lines import _count_fields
from cevm.ingest.textfile import MAX_LINE_BYTES, Utf8Stream, count_newlines

# Text that means "no value" in a numeric column (besides an empty field).
_NUMERIC_NA = ["", "NA", "N/A", "n/a", "NaN", "nan", "null", "NULL", "None", "-", "--"]


#: Any byte but ASCII whitespace (what ``bytes.isspace`` is true of).
_NON_SPACE = re.compile(rb"[^ \t\n\r\x0b\x0c]")

#: Text parsed at a time: blocks of whole lines of about this many bytes.
BLOCK_BYTES = 4 << 20


#: Parsers: "pyarrow" (default; pandas explains or repairs a block it refuses) or
#: "pandas" (the parser before pyarrow, kept for comparison in benchmarks).
Engine = Literal["pyarrow", "pandas"]


@dataclass
class ReadRepairs:
    """Repair messages by stage, put together in the order the stages run."""

    read: list[str] = field(default_factory=list)  # truncated last line
    rows: list[str] = field(default_factory=list)  # fewer fields, blank rows
    vehicle: list[str] = field(default_factory=list)
    time: list[str] = field(default_factory=list)
    columns: list[str] = field(default_factory=list)

    def all(self) -> list[str]:
        return self.read + self.rows + self.vehicle + self.time + self.columns


def _data_blocks(text: Utf8Stream, rest: bytes, hdr: Header, names: list[str], prof: Profile, path: Path,
                 repairs: ReadRepairs):
    """Yield (first line number, block, is last) for blocks of whole data lines of about
    :data:`BLOCK_BYTES` (bytes, or a memoryview of them); the last block may end without
    a line break. A truncated last
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
        # the block as a view of the text read (no copy of its megabytes); the rest
        # waits for the next block
        block, tail = (memoryview(data)[:cut], data[cut:]) if cut < len(data) else (data, b"")
        parts, size, has_nl, since_nl = ([tail] if tail else []), len(tail), False, len(tail)
        seen_data = seen_data or _NON_SPACE.search(data, 0, cut) is not None  # not block.isspace(), uncopied
        yield first_line, block, False
        first_line += count_newlines(data, 0, cut)
        del data, block


def _drop_truncated_last_line(data: bytes, first_line: int, names: list[str], prof: Profile, path: Path,
                              repairs: ReadRepairs) -> bytes:
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
            repairs.read.append(f"read: truncated last line ({n_fields} of {len(names)} fields) dropped: "
                                f"line {line_no}")
            return data[:last_start]
    return data


@dataclass
class ParsedBlock:
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
    #: cells of measured (not required) numeric columns that are not numbers, read as
    #: missing: per column, their lines and text (:class:`~.cells.BadCells`)
    bad_cells: dict = field(default_factory=dict)


def _drop_empty_rows(part: ParsedBlock, empty: np.ndarray) -> ParsedBlock:
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
