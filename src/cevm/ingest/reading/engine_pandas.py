"""The pandas parse engine: a block read by pandas' C parser, field counts checked per line
and the first column's times taken straight from the bytes where they are fixed-width
(:func:`cevm.ingest.timestamps.fast_first_column`, the byte-level time path); it repairs
what it can (and says so) or names the line and column of what it cannot. It parses the
blocks the pyarrow engine (:mod:`.engine_arrow`) refuses, and gives the same columns on
the others."""

from __future__ import annotations

import io
import re
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from cevm.errors import InputError
from cevm.ingest.profiles import Profile
from cevm.ingest.reading.blocks import _NUMERIC_NA, ParsedBlock, _drop_empty_rows
from cevm.ingest.reading.cells import BadCells, cell_numbers, not_a_number
from cevm.ingest.reading.header import ColumnPlan
from cevm.ingest.reading.lines import _check_field_counts, _line_stats
from cevm.ingest.timestamps import fast_first_column


def _pandas_block(block: bytes, first_line: int, plan: ColumnPlan, prof: Profile, path: Path) -> ParsedBlock:
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
    bad_cells: dict = {}
    df = _read_table(block, path, prof, plan.unique_names, table_cols, plan.num_cols, plan.text_cols,
                     first_line - 1, all_cols=quoted, required=plan.required_num, units=plan.units, bad_out=bad_cells)
    if fast is not None and len(fast.ns) != len(df):  # alignment lost (should not happen): slow path
        fast = None
        bad_cells = {}
        df = _read_table(block, path, prof, plan.unique_names, used, plan.num_cols, plan.text_cols, first_line - 1,
                         required=plan.required_num, units=plan.units, bad_out=bad_cells)
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
    part = ParsedBlock(lines, numbers, text, fast.ns if fast is not None else None,
                       bool(fast is not None and fast.is_utc),
                 fewer=fewer, last_line=first_line + len(df) - 1, bad_cells=bad_cells)
    return _drop_empty_rows(part, empty)


def _writable(x: np.ndarray) -> np.ndarray:
    """``x``, or a copy of it where it is a read-only view (the columns are converted in
    place later)."""
    return x if x.flags.writeable else x.copy()


def _read_table(body: bytes, path: Path, prof: Profile, names: list[str], usecols: list[str],
                num_cols: list[str], text_cols: list[str], header_line: int,
                all_cols: bool = False, required: frozenset[str] = frozenset(), units: dict | None = None,
                bad_out: dict | None = None) -> pd.DataFrame:
    """The ``usecols`` columns of the data lines with pandas' C parser: numbers as float64
    (NaN for empty or NA-like fields), text as object. With ``all_cols`` every column is
    tokenised (so that the parser checks field counts) and the others dropped after.
    Malformed rows raise InputError with the file line; a cell that is not a number is an
    error in a ``required`` column, else a missing value whose line and text go to
    ``bad_out`` (column -> :class:`~.cells.BadCells`; :mod:`.cells`)."""
    kw = dict(sep=prof.separator, decimal=prof.decimal, header=None, names=names, index_col=False,
              usecols=None if all_cols else usecols, keep_default_na=False, skip_blank_lines=False,
              engine="c", encoding="utf-8", quotechar='"', low_memory=False)
    na_values = {c: _NUMERIC_NA for c in num_cols if c in usecols}
    na_values.update({c: [""] for c in text_cols if c in usecols})
    dtype: dict[str, Any] = {c: "float64" for c in num_cols if c in usecols}
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
            # a field that is not a number: a missing value in a measured column (reported),
            # an error in a required one (slow path, blocks with such a cell only)
            df = pd.read_csv(io.BytesIO(body), dtype=object, na_values=na_values, **kw)
            if not _cells_to_numbers(df, path, prof, num_cols, usecols, header_line, required, units, bad_out):
                raise _unparsed(path, prof, df, num_cols, usecols, header_line, exc) from None
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


def _unparsed(path: Path, prof: Profile, df: pd.DataFrame, num_cols: list[str], usecols: list[str],
              header_line: int, exc: ValueError) -> InputError:
    """The error for numeric columns the parser refused though every cell is a number
    once its decimal mark is read as '.': a file written with '.' under a profile whose
    decimal mark is another (its first such cell named), else the parser's own words."""
    for c in num_cols:
        if c not in usecols or prof.decimal == ".":
            continue
        dotted = df[c].astype("string").str.contains(".", regex=False).fillna(False).to_numpy(dtype=bool)
        if dotted.any():
            i = int(np.flatnonzero(dotted)[0])
            return InputError(path, f"'{df[c].iloc[i]}' is written with a '.' but the profile {prof.name!r} reads "
                                    f"'{prof.decimal}' as the decimal mark ([csv] decimal): a wrong profile, or a "
                                    "file exported with other settings", line=header_line + 1 + i,
                              column=c.split("\x00")[0])
    return InputError(path, f"numeric columns unreadable: {exc}")


def _cells_to_numbers(df: pd.DataFrame, path: Path, prof: Profile, num_cols: list[str], usecols: list[str],
                      header_line: int, required: frozenset[str], units: dict | None, bad_out: dict | None) -> bool:
    """The numeric columns of ``df`` (read as text) as float64 in place; their cells that
    are not numbers are errors in a ``required`` column, else missing values recorded in
    ``bad_out``. False when every cell was a number (the parser's error was another)."""
    lines = header_line + 1 + np.arange(len(df))
    any_bad = False
    for c in num_cols:
        if c not in usecols:
            continue
        name = c.split("\x00")[0]
        x, found = cell_numbers(df[c], prof.decimal, (units or {}).get(name), lines)
        if found.lines or found.unit_lines:
            any_bad = True
            if name in required or bad_out is None:
                bad = np.isin(lines, np.concatenate(found.lines + found.unit_lines))
                raise not_a_number(path, name, df[c], lines, bad)
            bad_out.setdefault(name, BadCells()).add(found)
        df[c] = x
    return any_bad
