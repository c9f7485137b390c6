"""A fast reader of numeric CSV columns, with errors that name file, line and column.

Two steps, for any CSV of numbers a user gives (cycle files, and other numeric tables):

1. :func:`sniff_csv` reads the first MiB (decompressed, for ``.gz`` or gzip magic bytes)
   and finds the layout: compression, encoding (UTF-8, a BOM dropped; the header may be
   cp1252), separator (``,`` ``;`` tab ``|``: the one that splits the header and the
   first lines into the same number of fields, more than one) and decimal mark (``,``
   when the separator is not a comma and the data show a digit, comma, digit; else
   ``.``), unless given. It refuses binary data and a file without line breaks.
2. :func:`read_numeric_columns` parses the columns asked for straight into float64
   arrays in C (pyarrow's typed CSV reader for a file of plain numbers, or
   ``numpy.loadtxt`` where pyarrow refuses a cell (a number padded with spaces), else
   pandas' C parser with float dtypes; every row's field count checked by the parser).
   Empty cells are NaN; what they mean is the caller's to say, and
   :func:`describe_missing` names an empty cell or a short line for its message. A cell
   that is not a finite number, or a line with more fields than the header, raises
   :class:`~cevm.errors.InputError` with the line (1-based, the header is line 1) and
   the column.

Only to explain an error is the file read again the careful way, line by line with the
``csv`` module (:func:`first_bad_cell`), which costs about 1 µs per cell; a file without
errors is never read so.

Reuse: ``layout = sniff_csv(path)``, then ``layout.index(name)`` for a column's position
and ``read_numeric_columns(layout, [i, j])``; ``layout.pandas_kwargs()`` reads other
(text) columns with the same separator, encoding and compression.
"""

from __future__ import annotations

import codecs
import csv
import gzip
import io
import re
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from cevm.errors import InputError
from cevm.io.inputs import csv_reason, open_regular
from cevm.runtime import release_free_memory
from cevm.text import shorten

#: Separators tried, in the order preferred when several split the lines alike (a
#: semicolon or a tab is rarely anything but a separator; a comma is also a decimal mark
#: and appears in column names).
SEPARATORS = ("\t", ";", ",", "|")
#: Bytes read to find the layout [bytes].
SNIFF_BYTES = 1 << 20
#: Lines after the header that the separator must split like the header.
SNIFF_LINES = 50

_GZIP_MAGIC = b"\x1f\x8b"
_DECIMAL_COMMA = re.compile(rb"\d,\d")
_NUMBER = re.compile(r"\s*[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?\s*")
_SEP_NAMES = {"\t": "tab", ";": "';'", ",": "','", "|": "'|'"}


def separator_name(sep: str) -> str:
    return _SEP_NAMES.get(sep, repr(sep))


@dataclass(frozen=True)
class CsvLayout:
    """How a CSV file is written: what :func:`sniff_csv` found (or was told)."""

    path: Path
    sep: str
    decimal: str
    encoding: str  # of the data; "utf-8-sig" unless the header needed cp1252
    compression: str | None  # "gzip" or None
    header: tuple[str, ...]  # column names, stripped

    def index(self, name: str) -> int:
        """Position of column ``name`` (its first occurrence); ValueError if absent."""
        return self.header.index(name)

    def pandas_kwargs(self) -> dict:
        """Keyword arguments of ``pandas.read_csv`` for this layout (header line skipped,
        columns named by position 0..n-1)."""
        return dict(sep=self.sep, decimal=self.decimal, encoding=self.encoding, compression=self.compression,
                    header=None, skiprows=1, names=list(range(len(self.header))), index_col=False, engine="c")

    def describe(self) -> str:
        return (f"separator {separator_name(self.sep)}, decimal mark {self.decimal!r}"
                + (", gzip" if self.compression else ""))


def _open_binary(path: Path, compression: str | None):
    return gzip.open(path, "rb") if compression == "gzip" else open(path, "rb")


def _head(path: Path) -> tuple[bytes, str | None, bool]:
    """(first SNIFF_BYTES of the content, compression, whether that is all of it)."""
    try:
        with open(path, "rb") as fh:
            magic = fh.read(2)
        compression = "gzip" if magic == _GZIP_MAGIC else None
        with _open_binary(path, compression) as fh:
            head = fh.read(SNIFF_BYTES + 1)
    except (OSError, EOFError, gzip.BadGzipFile) as exc:
        what = "not a readable gzip file" if path.suffix == ".gz" or magic == _GZIP_MAGIC else "cannot read"
        raise InputError(path, f"{what}: {getattr(exc, 'strerror', None) or exc}") from None
    return head[:SNIFF_BYTES], compression, len(head) <= SNIFF_BYTES


#: A line end in the sniffed bytes: CRLF, LF or a CR alone.
_LINE_END = re.compile(rb"\r\n|\n|\r")


def _split(line: str, sep: str, path: Path | None = None, line_no: int | None = None) -> list[str]:
    """The fields of one line; a line that is no CSV (a field over Python's csv limit,
    128 KiB; a NUL byte) is an :class:`InputError` with its file and line."""
    try:
        return next(csv.reader([line], delimiter=sep), [])
    except csv.Error as exc:
        raise InputError(path, f"not a CSV line: {csv_reason(exc)}", line=line_no) from None


def sniff_csv(path: str | Path, *, sep: str | None = None, decimal: str | None = None,
              what: str = "CSV file") -> CsvLayout:
    """The layout of a CSV file with a header line: compression, encoding, separator,
    decimal mark (each detected unless given) and the column names.

    Raises :class:`InputError` for a missing or unreadable file, binary data, a file
    without line breaks or header, or a separator that cannot be told (give ``sep``).
    """
    path = Path(path)
    open_regular(path, what).close()  # a regular file: a FIFO would hang the read, /dev/zero never end it
    if sep is not None and sep not in SEPARATORS:
        raise InputError(path,
                         f"separator {sep!r} not supported; use one of {', '.join(map(separator_name, SEPARATORS))}")
    if decimal is not None and decimal not in (".", ","):
        raise InputError(path, f"decimal mark {decimal!r} not supported; use '.' or ','")
    if sep is not None and sep == decimal:
        raise InputError(path, f"the separator and the decimal mark cannot both be {sep!r}")
    head, compression, whole = _head(path)
    if b"\x00" in head[:4096]:
        raise InputError(path, f"binary data, not a {what} (CSV text)")
    # LF, CRLF, or CR alone (a classic Mac export; csv raised on it); the header and the
    # SNIFF_LINES lines after it are all that is looked at, the rest of the head stays one piece
    lines = _LINE_END.split(head, maxsplit=SNIFF_LINES + 1)
    if not whole:
        lines = lines[:-1]  # the last one may be cut
        if not lines:
            raise InputError(path, f"no line break in the first {SNIFF_BYTES >> 20} MiB: not a {what} (CSV text)",
                             line=1)
    if not head.strip():
        raise InputError(path, f"empty file: a {what} starts with a header of column names", line=1)
    first = lines[0].rstrip(b"\r")
    if first.startswith(codecs.BOM_UTF8):
        first = first[len(codecs.BOM_UTF8):]
    encoding = "utf-8-sig"
    try:
        header_line = first.decode("utf-8")
    except UnicodeDecodeError:
        header_line, encoding = first.decode("cp1252", errors="replace"), "cp1252"
    if not header_line.strip():
        raise InputError(path, f"empty first line: a {what} starts with a header of column names", line=1)
    body = [ln.rstrip(b"\r").decode(encoding, errors="replace") for ln in lines[1:SNIFF_LINES + 1]]
    body_lines = [k for k, ln in enumerate(body, start=2) if ln.strip()]  # each line's number, for errors
    body = [ln for ln in body if ln.strip()]
    if sep is None:
        sep = _detect_separator(path, header_line, body, decimal, what, body_lines)
    header = tuple(c.strip() for c in _split(header_line, sep, path, 1))
    if decimal is None:
        data = head[len(lines[0]) + 1:]
        decimal = "," if sep != "," and _DECIMAL_COMMA.search(data) else "."
    if sep == decimal:
        raise InputError(path, f"the separator and the decimal mark cannot both be {sep!r}")
    return CsvLayout(path=path, sep=sep, decimal=decimal, encoding=encoding, compression=compression, header=header)


def _detect_separator(path: Path, header: str, body: list[str], decimal: str | None, what: str,
                      body_lines: list[int]) -> str:
    counts = {s: (len(_split(header, s, path, 1)), [len(_split(b, s, path, k)) for b, k in zip(body, body_lines,
                                                                                                strict=True)])
              for s in SEPARATORS if s != decimal}
    for s, (nh, nb) in counts.items():  # every line split alike, into more than one field
        if nh > 1 and all(n == nh for n in nb):
            return s
    for nh, nb in counts.values():  # a header of one column: a one-column file
        if nh == 1 and all(n == 1 for n in nb):
            return ","
    best = max(counts, key=lambda s: (counts[s][0] > 1, sum(n == counts[s][0] for n in counts[s][1])))
    nh, nb = counts[best]
    bad = next((i for i, n in enumerate(nb) if n != nh), None)
    detail = (f"with {separator_name(best)} the header has {nh} fields but a line below it has {nb[bad]}"
              if bad is not None else "")
    raise InputError(path, f"cannot tell the separator of this {what} ({detail}); give it "
                           f"(one of {', '.join(map(separator_name, SEPARATORS))})", line=1)


def _text_lines(layout: CsvLayout) -> Iterator[str]:
    """The file's lines as text (decompressed, decoded; undecodable bytes replaced)."""
    with (_open_binary(layout.path, layout.compression) as raw,
          io.TextIOWrapper(raw, encoding=layout.encoding, errors="replace", newline="") as fh):
        yield from fh


def _number_ok(cell: str, decimal: str) -> bool:
    if decimal == ",":
        if "." in cell:
            return False
        cell = cell.replace(",", ".")
    return _NUMBER.fullmatch(cell) is not None


def first_bad_cell(layout: CsvLayout, columns: Sequence[int], what: str = "CSV file") -> InputError | None:
    """The careful path: the first line with more fields than the header, or the first
    cell of ``columns`` that is neither empty nor a finite number, as an InputError to
    raise (None if there is none). Reads the file line by line."""
    n = len(layout.header)
    reader = csv.reader(_text_lines(layout), delimiter=layout.sep)
    rows = iter(lambda: next(reader, None), None)
    try:
        return _first_bad_row(layout, columns, n, enumerate(rows, start=1))
    except csv.Error as exc:  # a field over Python's csv limit, a NUL byte: with its line
        return InputError(layout.path, f"not a CSV line: {csv_reason(exc)}", line=reader.line_num)


def _first_bad_row(layout: CsvLayout, columns: Sequence[int], n: int, rows) -> InputError | None:
    for line_no, row in rows:
        if line_no == 1:
            continue
        if len(row) > n:
            return _too_many_fields(layout, line_no, len(row))
        for j in columns:
            cell = row[j].strip() if j < len(row) else ""
            if cell and not _number_ok(cell, layout.decimal):
                return InputError(layout.path, _not_a_number(layout, cell), line=line_no, column=layout.header[j])
            if cell and not np.isfinite(float(cell.replace(",", "."))):
                return InputError(layout.path, f"not a finite number: {shorten(cell)!r}", line=line_no,
                                  column=layout.header[j])
    return None


def _not_a_number(layout: CsvLayout, cell: str) -> str:
    msg = f"not a number: {shorten(cell)!r}"
    if layout.decimal == "." and re.fullmatch(r"\s*[+-]?\d*,\d+\s*", cell):
        msg += " (a decimal comma? give the decimal mark ',')"
    elif layout.decimal == "," and re.fullmatch(r"\s*[+-]?\d*\.\d+\s*", cell):
        msg += " (the decimal mark is ',' here; give '.' if the file uses points)"
    return msg


def _too_many_fields(layout: CsvLayout, line_no: int, got: int) -> InputError:
    msg = f"{got} fields, but the header has {len(layout.header)} (with separator {separator_name(layout.sep)})"
    if layout.sep == ",":
        msg += "; a decimal comma in a comma-separated file must be quoted"
    return InputError(layout.path, msg, line=line_no)


def data_line(layout: CsvLayout, row: int) -> int:
    """The file line (1-based) of data row ``row`` (0-based): row + 2, unless blank
    lines stand before it (they are no rows). Reads the file up to it (error path)."""
    seen = -1
    for line_no, text in enumerate(_text_lines(layout), start=1):
        if line_no > 1 and text.strip():
            seen += 1
            if seen == row:
                return line_no
    return row + 2


def describe_missing(layout: CsvLayout, row: int, column: int) -> InputError:
    """An InputError for the NaN of data row ``row`` (0-based) in ``column``: an empty
    cell, or a line with too few fields. Reads the file up to that line."""
    line_no = data_line(layout, row)
    name = layout.header[column]
    for i, text in enumerate(_text_lines(layout), start=1):
        if i == line_no:
            fields = _split(text.rstrip("\r\n"), layout.sep, layout.path, line_no)
            if len(fields) <= column:
                n = len(fields)
                return InputError(layout.path, f"only {n} field{'s' if n != 1 else ''}, the header has "
                                               f"{len(layout.header)}", line=line_no, column=name)
            cell = fields[column].strip()
            if cell:
                return InputError(layout.path, _not_a_number(layout, cell), line=line_no, column=name)
            break
    return InputError(layout.path, "empty cell", line=line_no, column=name)


def _undecodable(layout: CsvLayout, exc: UnicodeDecodeError) -> InputError:
    """The error for bytes that are not text in the layout's encoding, with their line."""
    name = layout.encoding.removesuffix("-sig").upper()
    with _open_binary(layout.path, layout.compression) as fh:
        for line_no, raw in enumerate(fh, start=1):
            try:
                raw.decode(layout.encoding)
            except UnicodeDecodeError as e:
                return InputError(layout.path, f"not {name} text ({e.reason} at byte {e.start} of the line)",
                                  line=line_no)
    return InputError(layout.path, f"not {name} text ({exc.reason})")


_PARSER_LINE = re.compile(r"Expected (\d+) fields in line (\d+), saw (\d+)")


def read_numeric_columns(layout: CsvLayout, columns: Sequence[int], *, what: str = "CSV file",
                         max_rows: int | None = None) -> list[np.ndarray]:
    """Float64 arrays of ``columns`` (positions in ``layout.header``), one value per data
    line (blank lines are no rows); empty cells (and the cells missing from a short line)
    are NaN.

    Raises :class:`InputError` naming line and column for a cell that is not a finite
    number and a line with more fields than the header; and for more than ``max_rows``
    data lines, when given (memory stays bounded).

    A file of numbers only, with a decimal point, is parsed by pyarrow's typed CSV
    reader on one thread, in blocks (2.5x faster than ``numpy.loadtxt`` on a 2 M-line
    cycle; both parse each number to the nearest double, so they give the same values),
    or where pyarrow refuses a cell by ``numpy.loadtxt`` (pandas is then not even
    imported, which is a third of a short command's time); any other (empty cells, a
    decimal comma, text columns) by pandas' C parser; the careful path only explains an
    error.
    """
    columns = list(columns)
    out = _read_arrow(layout, columns, max_rows)
    if out is None:
        out = _read_numpy(layout, columns, max_rows)
    if out is None:
        out = _read_pandas(layout, columns, what, max_rows)
    n = out[0].size if out else 0
    if max_rows is not None and n > max_rows:
        raise InputError(layout.path, f"more than {max_rows:,} data lines; the limit for a {what}",
                         line=data_line(layout, max_rows))
    for j, arr in zip(columns, out, strict=True):
        if np.isinf(arr).any():  # what the C parsers read as infinite ("inf", 1e999)
            i = int(np.flatnonzero(np.isinf(arr))[0])
            raise InputError(layout.path, f"not a finite number: {arr[i]:g}", line=data_line(layout, i),
                             column=layout.header[j])
    return out


#: Bytes of one block of pyarrow's CSV reader (:func:`_read_arrow`).
ARROW_BLOCK_BYTES = 1 << 22


def _read_arrow(layout: CsvLayout, columns: list[int], max_rows: int | None) -> list[np.ndarray] | None:
    """Every column with pyarrow's typed CSV reader, a block at a time (at most
    ``max_rows`` + 1 rows are kept: memory stays bounded; the blocks are allocated by the
    C library's malloc and returned to the system once joined), or None where it cannot be used
    or refuses the file (numpy, then pandas, read it and say what is wrong): a decimal
    comma, a header that is not UTF-8, a row whose field count is not the header's, a
    cell that is not a plain number, an empty cell, a NaN written out."""
    if layout.decimal != "." or layout.encoding != "utf-8-sig":
        return None
    import pyarrow as pa
    import pyarrow.csv as pacsv

    names = [f"c{i}" for i in range(len(layout.header))]
    wanted = [names[j] for j in columns]
    read = pacsv.ReadOptions(use_threads=False, block_size=ARROW_BLOCK_BYTES, skip_rows=1, column_names=names)
    parse = pacsv.ParseOptions(delimiter=layout.sep, quote_char='"', double_quote=True)
    convert = pacsv.ConvertOptions(column_types=dict.fromkeys(wanted, pa.float64()), include_columns=wanted,
                                   null_values=[""], strings_can_be_null=False, quoted_strings_can_be_null=False)
    batches = []
    rows = 0
    try:
        with pa.input_stream(str(layout.path), compression=layout.compression) as raw:
            reader = pacsv.open_csv(raw, read_options=read, parse_options=parse, convert_options=convert,
                                    memory_pool=pa.system_memory_pool())
            for batch in reader:
                if batch.num_rows:
                    batches.append(batch)
                rows += batch.num_rows
                if max_rows is not None and rows > max_rows:
                    break
    except (pa.ArrowException, OSError, EOFError, ValueError):
        return None
    if not batches:
        return [np.zeros(0) for _ in columns]
    out = []
    for name in wanted:
        chunks = [b.column(name) for b in batches]
        if any(c.null_count for c in chunks):
            return None  # an empty cell: pandas says which
        arr = np.concatenate([_doubles(c) for c in chunks])
        if max_rows is not None and arr.size > max_rows + 1:
            arr = arr[: max_rows + 1].copy()
        if np.isnan(arr).any():
            return None  # 'nan' written out: let pandas say
        out.append(arr)
    del batches, chunks
    release_free_memory()  # the blocks, freed, would stay resident beside the joined columns
    return out


def _doubles(values) -> np.ndarray:
    """A view of the values of a pyarrow double array without nulls (its data buffer;
    ``Array.to_numpy`` would import pandas, a third of a short command's time)."""
    return np.frombuffer(values.buffers()[1], dtype=np.float64, count=len(values), offset=8 * values.offset)


def _read_numpy(layout: CsvLayout, columns: list[int], max_rows: int | None) -> list[np.ndarray] | None:
    """Every column with numpy's C reader, or None where it cannot be used or fails
    (pandas then reads the file and names what is wrong)."""
    if layout.decimal != ".":
        return None
    kw: dict[str, Any] = dict(delimiter=layout.sep, skiprows=1, dtype=np.float64, comments=None, quotechar='"',
                              ndmin=2, max_rows=None if max_rows is None else max_rows + 1, encoding=layout.encoding)
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="Input line", category=UserWarning)  # blank lines: no rows
            warnings.filterwarnings("ignore", message="loadtxt: input contained no data", category=UserWarning)
            by_name = layout.compression is None or layout.path.suffix.lower() == ".gz"
            if by_name:  # numpy opens it (and .gz) itself: 30 % faster than from a file object
                table = np.loadtxt(layout.path, **kw)
            else:
                with gzip.open(layout.path, "rt", encoding=layout.encoding, newline="") as fh:
                    table = np.loadtxt(fh, **kw)
    except (ValueError, TypeError, OSError, EOFError):
        return None
    if table.shape[1] != len(layout.header) or (table.size and np.isnan(table[:, columns]).any()):
        return None  # a field count unlike the header's, or 'nan' written out: let pandas say
    return [np.ascontiguousarray(table[:, j]) for j in columns]


def _read_pandas(layout: CsvLayout, columns: list[int], what: str, max_rows: int | None) -> list[np.ndarray]:
    import pandas as pd

    kw = layout.pandas_kwargs()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", pd.errors.ParserWarning)
            df = pd.read_csv(layout.path, dtype=dict.fromkeys(columns, np.float64), keep_default_na=False,
                             na_values=[""], nrows=None if max_rows is None else max_rows + 1, **kw)
    except pd.errors.ParserError as exc:
        m = _PARSER_LINE.search(str(exc))
        if m:
            raise _too_many_fields(layout, int(m.group(2)), int(m.group(3))) from None
        raise first_bad_cell(layout, columns, what) or InputError(layout.path, f"malformed CSV: {exc}") from None
    except pd.errors.ParserWarning:  # the first data line is longer than the header
        raise first_bad_cell(layout, columns, what) or InputError(layout.path, "more fields than the header",
                                                                  line=2) from None
    except UnicodeDecodeError as exc:
        raise _undecodable(layout, exc) from None
    except (ValueError, TypeError) as exc:  # a cell that is not a number
        raise first_bad_cell(layout, columns, what) or InputError(layout.path, f"malformed CSV: {exc}") from None
    except (OSError, EOFError, gzip.BadGzipFile) as exc:
        raise InputError(layout.path, f"cannot read: {getattr(exc, 'strerror', None) or exc}") from None
    return [df[j].to_numpy(dtype=np.float64) for j in columns]
