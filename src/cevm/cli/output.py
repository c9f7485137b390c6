"""Printing result rows as a table (for people), CSV or JSON (for scripts).

Text in tables and CSV goes through :func:`cevm.text.printable` (control characters in
ids and file names escaped, so no cell can forge a line or break a record); CSV fields
are quoted where they need it (a comma, a quote), and a text cell that a spreadsheet
would take for a formula (starting with ``=``, ``+``, ``-``, ``@``, a tab or a carriage
return, and not a plain number) gets a leading apostrophe (:func:`cevm.text.csv_safe`);
numbers are written as numbers. JSON escapes by its own rules and keeps the exact value.
Identifier columns never wrap: a trip id is read whole. A command that describes its
columns (:class:`cevm.cli.columns.Column`: ``predict``, ``feasibility``) passes them to
:func:`write_rows`, which takes each one's header, decimals and layout from it; for plain
column names, :data:`ID_COLUMNS` and :data:`TEXT_COLUMNS` say the layout.
"""

from __future__ import annotations

import csv
import json
import math
import sys
from collections.abc import Sequence
from enum import Enum
from typing import IO, Any

import numpy as np

from cevm.cli.columns import Column
from cevm.text import csv_safe, printable


class OutputFormat(str, Enum):
    table = "table"
    csv = "csv"
    json = "json"


#: Columns of identifiers, by name (for columns given without a :class:`Column`):
#: left-aligned, never wrapped nor cut in tables.
ID_COLUMNS = {"cycle", "vehicle", "vehicle_key", "trip_id", "vehicle_id", "source", "route", "file", "id", "day",
              "mass_source",
              "vehicle id", "start_utc", "created_utc"}
#: Columns printed left-aligned and allowed to wrap in tables.
TEXT_COLUMNS = {"kind", "problem", "value", "basis", "what", "cycle", "vehicle", "trip_id", "vehicle_id", "source", "route", "file", "status", "profile", "start_utc", "elevation_source", "day", "day 1", "day 2", "day 3", "method", "stops", "item", "parameter", "std", "in-sample", "cross-validated", "quantity", "terms", "parameters"}


#: How a table's legend says an ICE braking mode (:data:`cevm.core.model.ICE_BRAKING_MODES`):
#: the assumption that moves a truck's fuel most in stop-and-go driving.
BRAKING_WORDS = {"no-credit": "braking energy not credited", "paper": "braking energy credited (eq. 24)"}


def vehicle_legend(vehicles: dict[str, tuple[str, str | None]]) -> str | None:
    """The ``vehicles:`` line under a table, from ``{key: (name, ICE braking mode or
    None)}``: each key with its name where they differ, and each ICE vehicle's braking
    mode; ``None`` when there is nothing to say."""
    parts = []
    for key, (name, braking) in vehicles.items():
        text = key if key == name else f"{key} = {name}"
        if braking:
            text += f" (ICE, {BRAKING_WORDS.get(braking, 'braking ' + braking)})"
        if text != key:
            parts.append(text)
    return printable("vehicles: " + "; ".join(parts)) if parts else None


def _clean(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _csv_cell(value: Any) -> Any:
    value = _clean(value)
    if value is None:
        return ""
    if isinstance(value, (bool, np.bool_)):  # as predict's fast CSV path and JSON write them
        return "true" if value else "false"
    if isinstance(value, str):
        return csv_safe(value)  # control characters escaped, formula prefixes neutralised
    return value


def csv_writer(stream: IO[str]):
    """The CSV writer of every cevm CSV output: minimal quoting (a field with a comma,
    a quote or a line break is quoted, quotes doubled), ``\n`` line ends."""
    return csv.writer(stream, lineterminator="\n", quoting=csv.QUOTE_MINIMAL)


def write_rows(
    rows: Sequence[dict[str, Any]],
    fmt: OutputFormat,
    *,
    columns: Sequence[str | Column] | None = None,
    title: str | None = None,
    stream: IO[str] | None = None,
    digits: dict[str, int] | None = None,
    headers: dict[str, str] | None = None,
) -> None:
    """Write rows (dicts) in the chosen format.

    JSON: a list of objects with every key of each row (non-finite floats become null).
    CSV: a header of ``columns`` (default: the union of keys in first-seen order).
    Table: a rich table of ``columns`` titled by ``headers`` (default the column names),
    floats rounded to ``digits[column]`` (default 3), at least 120 characters wide when
    the output is not a terminal, and as wide as its identifier and number columns need
    (so piped or logged tables never cut them; free text wraps). A column given as a
    :class:`~cevm.cli.columns.Column` brings its own header, decimals and layout.
    """
    stream = stream or sys.stdout
    if columns is None:
        seen: dict[str, None] = {}
        for r in rows:
            for k in r:
                seen.setdefault(k, None)
        columns = list(seen)
    names = [c.name if isinstance(c, Column) else c for c in columns]
    if fmt == OutputFormat.json:
        json.dump([{k: _clean(v) for k, v in r.items()} for r in rows], stream, indent=2)
        stream.write("\n")
    elif fmt == OutputFormat.csv:
        w = csv_writer(stream)
        w.writerow([csv_safe(str(c)) for c in names])
        for r in rows:
            w.writerow([_csv_cell(r.get(k)) for k in names])
    else:
        from rich.console import Console
        from rich.measure import Measurement
        from rich.table import Table

        specs = [_as_column(c, digits or {}, headers or {}) for c in columns]
        cells = [[_fmt(r.get(c.name), c.digits) for c in specs] for r in rows]
        table = Table(title=None if title is None else printable(title))
        for j, c in enumerate(specs):
            header = printable(c.title)
            if c.table_layout == "id":
                longest = max([len(header)] + [len(row[j]) for row in cells])
                table.add_column(header, justify="left", no_wrap=True, min_width=longest)
            elif c.table_layout == "wrap":
                table.add_column(header, justify="left", overflow="fold")
            else:
                table.add_column(header, justify="right", no_wrap=True)
        for row in cells:
            table.add_row(*row)
        console = Console(file=stream, markup=False, highlight=False)
        if not console.is_terminal:  # piped or logged: wide enough for every unwrapped column
            wide = Console(file=stream, width=10_000, markup=False, highlight=False)
            need = Measurement.get(wide, wide.options, table).minimum
            console = Console(file=stream, width=max(console.width, 120, need), markup=False, highlight=False)
        console.print(table)


def _as_column(c: str | Column, digits: dict[str, int], headers: dict[str, str]) -> Column:
    """A table column: a Column as given; a name with its ``digits`` and ``headers``
    entries (default 3 decimals, the name) and the layout of :data:`ID_COLUMNS` and
    :data:`TEXT_COLUMNS` (else right-aligned)."""
    if isinstance(c, Column):
        return c
    layout = "id" if c in ID_COLUMNS else "wrap" if c in TEXT_COLUMNS else "right"
    return Column(c, "", header=headers.get(c, c), digits=digits.get(c, 3), layout=layout)


def _fmt(value: Any, digits: int) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        if not math.isfinite(value):
            return "-"
        return f"{value:,.{digits}f}"
    return printable(str(value))

