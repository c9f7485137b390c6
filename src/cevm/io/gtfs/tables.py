"""A GTFS feed's text files read as columns (zip or folder), every value checked where it
is read, and a malformed one refused as ``FILE:LINE: column 'c': what is wrong`` (one line,
exit 2, as a log's).

Files are read with pyarrow's CSV reader, every column as text (so that a bad value never
becomes pyarrow's own message without a line) and only the columns asked for; numbers
and times are converted here, vectorised (:func:`to_float`, :func:`to_seconds`), and the
first bad value found is reported with its line. ``stop_times.txt`` (the only large file:
ten million rows in a city's feed) is read batch by batch (:func:`batches`) so that the
caller keeps only the rows of the trips it needs, converted to numbers.

A line number is the row's index plus 2 (the header is line 1); a quoted field holding a
line break (never in a GTFS time or number, seldom in a name) would shift the lines after
it.
"""

from __future__ import annotations

import csv
import io
import zipfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.csv as pacsv

from cevm.errors import FileAccessError, InputError

#: Bytes of a batch of stop_times.txt (pyarrow's block size, read on one thread): 1 MiB,
#: about 25,000 rows. On ten million rows (benchmarks/bench_gtfs.py) 1 MiB peaks at 423 MB
#: in 18.5 s, 4 MiB at 512 MB in 16.6 s; pyarrow's threads read blocks ahead (their
#: buffers add to the peak) and parse no faster on the two cores of a small machine.
BLOCK_BYTES = 1 << 20

_NUMBER = r"^\s*[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?\s*$"
_TIME = r"^\s*\d{1,3}:\d{2}:\d{2}\s*$"


@dataclass(frozen=True)
class FeedSource:
    """Where a feed's files are: a folder, or a zip archive (its files at the top or in
    one folder inside it)."""

    path: Path
    members: dict[str, str]  # file name -> member of the zip (or the file's path in the folder)
    is_zip: bool

    @classmethod
    def open(cls, path: str | Path) -> FeedSource:
        p = Path(path)
        if p.is_dir():
            return cls(p, {f.name: str(f) for f in p.iterdir() if f.suffix == ".txt" and f.is_file()}, False)
        if not p.exists():
            raise FileAccessError(p, "GTFS feed not found (give a .zip or a folder of .txt files)")
        try:
            with zipfile.ZipFile(p) as z:
                names = [n for n in z.namelist() if n.endswith(".txt") and not n.endswith("/")]
        except (zipfile.BadZipFile, OSError) as exc:
            raise FileAccessError(p, f"not a GTFS feed: neither a folder nor a readable zip archive ({exc})") from None
        members: dict[str, str] = {}
        for n in sorted(names, key=lambda s: s.count("/")):  # the top level first
            members.setdefault(n.rsplit("/", 1)[-1], n)
        return cls(p, members, True)

    def has(self, name: str) -> bool:
        return name in self.members

    def shown(self, name: str) -> str:
        """How a member is named in messages: ``feed.zip/stops.txt`` or the file's path."""
        return f"{self.path}/{self.members.get(name, name)}" if self.is_zip else self.members.get(name, name)

    def stream(self, name: str) -> IO[bytes]:
        if name not in self.members:
            raise InputError(self.path, f"the feed has no {name}")
        if self.is_zip:
            z = zipfile.ZipFile(self.path)
            return z.open(self.members[name])
        return open(self.members[name], "rb")


def _header(src: FeedSource, name: str) -> list[str]:
    with src.stream(name) as fh:
        first = fh.readline()
    text = first.decode("utf-8-sig", errors="replace").strip("\r\n")
    if not text.strip():
        raise InputError(src.shown(name), "empty file: no header line", line=1)
    return [c.strip() for c in next(csv.reader([text]))]


def _parse_error(src: FeedSource, name: str, exc: Exception) -> InputError:
    """Where pyarrow could not parse ``name`` (a row with the wrong number of fields, an
    unclosed quote): found again with Python's csv reader, to name the line."""
    with src.stream(name) as fh:
        text = io.TextIOWrapper(fh, encoding="utf-8-sig", errors="replace", newline="")
        reader = csv.reader(text)
        try:
            width = len(next(reader))
            for row in reader:
                if row and len(row) != width:
                    return InputError(src.shown(name), f"{len(row)} fields where the header has {width}",
                                      line=reader.line_num)
        except csv.Error as cexc:
            return InputError(src.shown(name), f"not CSV: {cexc}", line=reader.line_num)
    return InputError(src.shown(name), f"not readable as CSV: {str(exc).splitlines()[0]}")


def batches(src: FeedSource, name: str, columns: list[str], required: tuple[str, ...] = (),
            block_bytes: int = BLOCK_BYTES) -> Iterator[tuple[int, dict[str, pa.Array]]]:
    """``name``'s columns ``columns`` (those present; ``required`` must be) as text, batch
    by batch: (the first row's line, {column: array}). Empty fields are null."""
    header = _header(src, name)
    missing = [c for c in required if c not in header]
    if missing:
        raise InputError(src.shown(name), f"no column {missing[0]!r} (the header has {', '.join(header)})", line=1)
    present = [c for c in columns if c in header]
    if len(set(header)) != len(header):
        dup = next(c for c in header if header.count(c) > 1)
        raise InputError(src.shown(name), f"column {dup!r} appears twice in the header", line=1)
    read = pacsv.ReadOptions(column_names=header, skip_rows=1, block_size=block_bytes, encoding="utf8",
                             use_threads=False)
    conv = pacsv.ConvertOptions(include_columns=present, column_types={c: pa.string() for c in present},
                                strings_can_be_null=True, null_values=[""], quoted_strings_can_be_null=True)
    parse = pacsv.ParseOptions(newlines_in_values=False)
    line = 2
    with src.stream(name) as fh:
        try:
            reader = pacsv.open_csv(fh, read_options=read, convert_options=conv, parse_options=parse)
            for batch in reader:
                if batch.num_rows == 0:
                    continue
                cols = {c: pc.utf8_trim_whitespace(batch.column(c)) for c in present}
                yield line, cols
                line += batch.num_rows
        except pa.ArrowInvalid as exc:
            raise _parse_error(src, name, exc) from None
        except UnicodeDecodeError as exc:
            raise InputError(src.shown(name), f"not UTF-8 text ({exc.reason})") from None


def read_table(src: FeedSource, name: str, columns: list[str], required: tuple[str, ...] = ()
               ) -> tuple[int, dict[str, pa.Array]]:
    """A whole (small) file's columns, as :func:`batches` gives them, in one batch: (number
    of rows, {column: array}); an absent optional column is not in the dict."""
    parts: dict[str, list[pa.Array]] = {}
    n = 0
    for _, cols in batches(src, name, columns, required):
        for c, a in cols.items():
            parts.setdefault(c, []).append(a)
        n += len(next(iter(cols.values()))) if cols else 0
    header = _header(src, name)
    out = {c: pa.concat_arrays([x.combine_chunks() if isinstance(x, pa.ChunkedArray) else x for x in parts[c]])
           if c in parts else pa.array([], pa.string()) for c in columns if c in header}
    return n, out


def _chunk(a: pa.Array | pa.ChunkedArray) -> pa.Array:
    return a.combine_chunks() if isinstance(a, pa.ChunkedArray) else a


def texts(a: pa.Array | pa.ChunkedArray) -> np.ndarray:
    """A text column as a numpy array of str (null: ""), a value repeated in many rows one
    str object (a city's trips.txt: hundreds of thousands of rows, a few hundred routes)."""
    d = pc.dictionary_encode(_chunk(a))
    uniq = np.array([*d.dictionary.to_pylist(), ""], dtype=object)
    idx = np.asarray(pc.fill_null(d.indices, len(uniq) - 1).to_numpy(zero_copy_only=False), dtype=np.int64)
    return uniq[idx]


def _first_bad(ok: pa.Array) -> int:
    bad = np.flatnonzero(~np.asarray(pc.fill_null(ok, True).to_numpy(zero_copy_only=False), dtype=bool))
    return int(bad[0]) if bad.size else -1


def require(a: pa.Array, where: str, column: str, first_line: int) -> None:
    """Refuse a null (empty) value of a required column."""
    if a.null_count:
        i = _first_bad(pc.is_valid(a))
        raise InputError(where, "empty: a value is required", line=first_line + i, column=column)


def to_float(a: pa.Array, where: str, column: str, first_line: int) -> np.ndarray:
    """A text column as float64 (null: NaN), a value that is not a (finite) number refused
    with its line. pyarrow's cast first; the pattern, slower, only to find a bad value."""
    a = _chunk(a)
    try:
        x = np.asarray(pc.cast(a, pa.float64()).to_numpy(zero_copy_only=False), dtype=np.float64)
    except (pa.ArrowInvalid, pa.ArrowNotImplementedError):
        x = None
    if x is None or (np.isinf(x).any() or np.isnan(x).sum() != a.null_count):
        i = _first_bad(pc.match_substring_regex(a, _NUMBER))
        if i < 0 and x is not None:  # "inf", "nan": numbers to pyarrow, not to a feed
            i = int(np.flatnonzero(~np.isfinite(x) & np.asarray(pc.is_valid(a).to_numpy(zero_copy_only=False)))[0])
        raise InputError(where, f"{a[i].as_py()!r} is not a number", line=first_line + i, column=column)
    return x


def to_int(a: pa.Array, where: str, column: str, first_line: int, lo: int | None = None,
           hi: int | None = None) -> np.ndarray:
    """A required text column of whole numbers (within ``lo``..``hi``) as int64."""
    require(a, where, column, first_line)
    x = to_float(a, where, column, first_line)
    bad = (x != np.round(x)) | ((x < lo) if lo is not None else False) | ((x > hi) if hi is not None else False)
    if np.any(bad):
        i = int(np.flatnonzero(bad)[0])
        span = f" in {lo}..{hi}" if lo is not None and hi is not None else ""
        raise InputError(where, f"{_chunk(a)[i].as_py()!r} is not a whole number{span}", line=first_line + i,
                         column=column)
    return x.astype(np.int64)


def to_seconds(a: pa.Array, where: str, column: str, first_line: int) -> np.ndarray:
    """GTFS times ``H:MM:SS`` (hours past 24 allowed: a service day's trips after midnight)
    as seconds after the service day's noon less 12 h, float64 (null: NaN). The fields are
    cut at fixed places from the end (``MM:SS`` is always five characters) and cast; the
    pattern, slower, only to find a bad value."""
    a = _chunk(a)
    valid = np.asarray(pc.is_valid(a).to_numpy(zero_copy_only=False), dtype=bool)
    out = np.full(len(a), np.nan)
    if not valid.any():
        return out
    v = pc.drop_null(a) if a.null_count else a
    try:
        colons = pc.and_(pc.equal(pc.utf8_slice_codeunits(v, -3, -2), ":"),
                         pc.equal(pc.utf8_slice_codeunits(v, -6, -5), ":"))
        fields = [np.asarray(pc.cast(pc.utf8_slice_codeunits(v, lo, hi), pa.int32()).to_numpy(zero_copy_only=False))
                  for lo, hi in ((0, -6), (-5, -3), (-2, None))]
        ok = bool(pc.all(colons).as_py()) and bool(np.all(fields[0] >= 0))
        length = np.asarray(pc.utf8_length(v).to_numpy(zero_copy_only=False))
        ok = ok and bool(np.all((length >= 7) & (length <= 9)))
    except (pa.ArrowInvalid, pa.ArrowNotImplementedError):
        ok = False
    if not ok:
        i = _first_bad(pc.match_substring_regex(a, _TIME))
        raise InputError(where, f"{a[max(i, 0)].as_py()!r} is not a time H:MM:SS", line=first_line + max(i, 0),
                         column=column)
    h, m, sec = fields
    bad = (m > 59) | (sec > 59) | (m < 0) | (sec < 0)
    if bad.any():
        j = int(np.flatnonzero(valid)[np.flatnonzero(bad)[0]])
        raise InputError(where, f"{a[j].as_py()!r}: minutes and seconds must be 00 to 59", line=first_line + j,
                         column=column)
    out[valid] = h * 3600.0 + m * 60.0 + sec
    return out


def to_date(a: pa.Array, where: str, column: str, first_line: int) -> np.ndarray:
    """Required GTFS dates ``YYYYMMDD`` as proleptic Gregorian ordinals (int64)."""
    from datetime import date

    a = _chunk(a)
    require(a, where, column, first_line)
    i = _first_bad(pc.match_substring_regex(a, r"^\d{8}$"))
    if i >= 0:
        raise InputError(where, f"{a[i].as_py()!r} is not a date YYYYMMDD", line=first_line + i, column=column)
    out = np.empty(len(a), dtype=np.int64)
    cache: dict[str, int] = {}
    for k, s in enumerate(a.to_pylist()):  # a calendar's few hundred rows
        v = cache.get(s)
        if v is None:
            try:
                v = cache[s] = date(int(s[:4]), int(s[4:6]), int(s[6:])).toordinal()
            except ValueError:
                raise InputError(where, f"{s!r} is not a date of the calendar", line=first_line + k,
                                 column=column) from None
        out[k] = v
    return out
