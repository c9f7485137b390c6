"""Fast CSV and JSON of column arrays: a command's rows as numpy columns, written in
blocks without a Python object per cell (``cevm predict`` writes a million rows so).

Columns are given as a dict name -> values, as a :class:`~cevm.cli.columns.ColumnSpec`
describes them: numbers and booleans as float arrays (NaN: no value), text as a pair
(codes, categories) (an int array indexing a list of strings: one name per vehicle, not
one per row). CSV: numbers with the column's fixed decimals, trailing zeros (and a bare
point) dropped, booleans ``true``/``false``, empty cells where a row has no value; text
quoted as :func:`cevm.cli.output.csv_writer` quotes, control characters escaped, formula
prefixes neutralised (:func:`cevm.text.csv_safe`). JSON:
one object per row with the keys of its powertrain (:meth:`ColumnSpec.json_keys`),
numbers in full precision (``repr``; a column of no decimals, a count, as an integer),
``null`` where a row has no value.
"""

from __future__ import annotations

import io
import json
import math
from typing import cast

import numpy as np

from cevm.cli.columns import ColumnSpec
from cevm.cli.output import csv_writer
from cevm.text import csv_safe

#: A column of a block: numbers, or text as (codes, categories).
ColumnValues = np.ndarray | tuple[np.ndarray, list[str]]


def concat_columns(cols: list[dict[str, ColumnValues]]) -> dict[str, ColumnValues]:
    """The columns of several blocks one after another (text categories merged)."""
    if len(cols) == 1:
        return cols[0]
    out: dict[str, ColumnValues] = {}
    for key in cols[0]:
        parts = [c[key] for c in cols]
        if isinstance(parts[0], tuple):
            cats: list[str] = []
            index: dict[str, int] = {}
            codes = []
            for c, names in cast(list[tuple[np.ndarray, list[str]]], parts):  # a column's kind is every block's
                remap = np.array([index.setdefault(s, len(index)) for s in names], dtype=np.int64)
                codes.append(remap[c])
            cats = list(index)
            out[key] = (np.concatenate(codes), cats)
        else:
            out[key] = np.concatenate(cast(list[np.ndarray], parts))
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
    """One text cell as CSV bytes: control characters escaped and formula prefixes
    neutralised (:func:`cevm.text.csv_safe`), quoted as :func:`cevm.cli.output.csv_writer`
    quotes."""
    if not s:
        return b""
    buf = io.StringIO()
    csv_writer(buf).writerow([csv_safe(s)])
    return buf.getvalue().rstrip("\n").encode("utf-8")


_BOOL_CSV = np.array([b"false", b"true", b""])


def csv_text(cols: dict[str, ColumnValues], spec: ColumnSpec) -> str:
    """The CSV lines (no header) of the rows of ``cols``, columns in ``spec``'s order."""
    fields = []
    for column in spec.columns:
        col = cols[column.name]
        if isinstance(col, tuple):
            codes, cats = col
            fields.append(_text_chars(np.array([_csv_quote(c) for c in cats], dtype=bytes)[codes]))
        elif column.kind == "bool":
            v = np.asarray(col)
            code = np.where(np.isnan(v), 2, (v > 0.5).astype(np.int64))
            fields.append(_text_chars(_BOOL_CSV[code]))
        else:
            fields.append(_num_chars(col, column.decimals))
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


def _json_values(col: object, kind: str, decimals: int = 6) -> list[str]:
    """A column's JSON values: text quoted, booleans, numbers in full precision; a
    column of no decimals (a count, a number: duties, trips, draws) as integers."""
    if isinstance(col, tuple):
        codes, cats = col
        enc = [json.dumps(c) for c in cats]
        return [enc[i] for i in codes.tolist()]
    v = np.asarray(col, dtype=np.float64)
    if kind == "bool":
        return [("null" if x != x else ("true" if x > 0.5 else "false")) for x in v.tolist()]
    if decimals == 0:
        return [(str(int(round(x))) if math.isfinite(x) else "null") for x in v.tolist()]
    return [(repr(x) if math.isfinite(x) else "null") for x in v.tolist()]


def json_objects(cols: dict[str, ColumnValues], spec: ColumnSpec, is_ev: np.ndarray) -> list[str]:
    """One JSON object (text) per row of ``cols``: an EV row (``is_ev``) with the keys
    ``spec`` gives EV rows, the others with an ICE row's."""
    vals = {c.name: _json_values(cols[c.name], c.kind, c.decimals) for c in spec.columns}
    ev_keys, ice_keys = spec.json_keys("ev"), spec.json_keys("ice")
    ev_fmt = "{" + ", ".join(f'"{k}": %s' for k in ev_keys) + "}"
    ice_fmt = "{" + ", ".join(f'"{k}": %s' for k in ice_keys) + "}"
    ev_rows = zip(*(vals[k] for k in ev_keys), strict=True)
    ice_rows = zip(*(vals[k] for k in ice_keys), strict=True)
    return [ev_fmt % ev if e else ice_fmt % ice for e, ev, ice in zip(is_ev.tolist(), ev_rows, ice_rows, strict=True)]


def table_row(cols: dict[str, ColumnValues], spec: ColumnSpec, i: int) -> dict[str, object]:
    """Row ``i`` of columnar values as a row of a table for people: a text column's
    string (None where empty), a number as a float (None where NaN), a bool column's
    value as a bool (None where NaN)."""
    row: dict[str, object] = {}
    for column in spec.columns:
        c = cols[column.name]
        if isinstance(c, tuple):
            row[column.name] = c[1][int(c[0][i])] or None
        else:
            x = float(c[i])
            row[column.name] = None if x != x else (x > 0.5 if column.kind == "bool" else x)
    return row
