"""Printing result rows as a table (for people), CSV or JSON (for scripts)."""

from __future__ import annotations

import csv
import json
import math
import sys
from collections.abc import Sequence
from enum import Enum
from typing import IO, Any


class OutputFormat(str, Enum):
    table = "table"
    csv = "csv"
    json = "json"


#: Columns printed left-aligned and allowed to wrap in tables.
TEXT_COLUMNS = {"cycle", "vehicle", "trip_id", "vehicle_id", "source", "route", "file", "status", "profile", "start_utc", "elevation_source", "day", "day 1", "day 2", "day 3", "method", "stops", "item", "parameter", "std", "in-sample", "cross-validated", "quantity", "terms", "parameters"}


def _clean(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def write_rows(
    rows: Sequence[dict[str, Any]],
    fmt: OutputFormat,
    *,
    columns: Sequence[str] | None = None,
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
    the output is not a terminal (so piped or logged tables do not wrap).
    """
    stream = stream or sys.stdout
    if columns is None:
        seen: dict[str, None] = {}
        for r in rows:
            for k in r:
                seen.setdefault(k, None)
        columns = list(seen)
    if fmt == OutputFormat.json:
        json.dump([{k: _clean(v) for k, v in r.items()} for r in rows], stream, indent=2)
        stream.write("\n")
    elif fmt == OutputFormat.csv:
        w = csv.DictWriter(stream, fieldnames=list(columns), extrasaction="ignore", lineterminator="\n")
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if _clean(r.get(k)) is None else r.get(k)) for k in columns})
    else:
        from rich.console import Console
        from rich.table import Table

        digits = digits or {}
        headers = headers or {}
        table = Table(title=title)
        for c in columns:
            if c in TEXT_COLUMNS:
                table.add_column(headers.get(c, c), justify="left", overflow="fold")
            else:
                table.add_column(headers.get(c, c), justify="right", no_wrap=True)
        for r in rows:
            table.add_row(*(_fmt(r.get(c), digits.get(c, 3)) for c in columns))
        console = Console(file=stream)
        if not console.is_terminal:
            console = Console(file=stream, width=max(console.width, 120))
        console.print(table)


def _fmt(value: Any, digits: int) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        if not math.isfinite(value):
            return "-"
        return f"{value:,.{digits}f}"
    return str(value)

