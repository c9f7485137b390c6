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


class OutputFormat(str, Enum):  # noqa: UP042 (StrEnum's str() differs: kept as typer sees it today)
    table = "table"
    csv = "csv"
    json = "json"


#: Columns of identifiers, by name (for columns given without a :class:`Column`):
#: left-aligned, never wrapped nor cut in tables.
ID_COLUMNS = {"cycle", "vehicle", "vehicle_key", "trip_id", "vehicle_id", "source", "route", "file", "id", "day",
              "mass_source",
              "vehicle id", "start_utc", "created_utc"}
#: Columns printed left-aligned and allowed to wrap in tables.
TEXT_COLUMNS = {"kind", "problem", "value", "basis", "what", "cycle", "vehicle", "trip_id", "vehicle_id", "source",
                "route", "file", "status", "profile", "start_utc", "elevation_source", "day", "day 1", "day 2", "day 3",
                "method", "stops", "item", "parameter", "std", "in-sample", "cross-validated", "quantity", "terms",
                "parameters"}


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


def _csv_cell(value: Any, decimals: int | None = None) -> Any:
    """A CSV cell; a number of a column with ``decimals`` written as predict's fast CSV
    path writes it (:mod:`cevm.cli.columnar`): that many decimals, trailing zeros and a
    bare point dropped."""
    value = _clean(value)
    if value is None:
        return ""
    if isinstance(value, (bool, np.bool_)):  # as predict's fast CSV path and JSON write them
        return "true" if value else "false"
    if isinstance(value, str):
        return csv_safe(value)  # control characters escaped, formula prefixes neutralised
    if decimals is not None and isinstance(value, (float, int, np.floating, np.integer)):
        text = f"{float(value):.{decimals}f}"
        text = text.rstrip("0").rstrip(".") if "." in text else text
        return "0" if text == "-0" else text
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
    keep: Sequence[str] = (),
    drop_order: Sequence[str] = (),
    width: int | None = None,
) -> None:
    """Write rows (dicts) in the chosen format.

    JSON: a list of objects with every key of each row (non-finite floats become null).
    CSV: a header of ``columns`` (default: the union of keys in first-seen order); the
    numbers of a column given as a :class:`~cevm.cli.columns.Column` at its decimals.
    Table: a table of ``columns`` titled by ``headers`` (default the column names),
    floats rounded to ``digits[column]`` (default 3), laid out by :func:`print_table`:
    never a cut number or identifier; on a terminal too narrow for every column, columns
    are folded or left out (``keep``: never left out, default the first column;
    ``drop_order``: the first ones to leave out) and a line says which. A column given
    as a :class:`~cevm.cli.columns.Column` brings its own header, decimals and layout.
    ``width``: the width to fit (default: the terminal's; none when not a terminal).
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
        places = [c.decimals if isinstance(c, Column) else None for c in columns]
        for r in rows:
            w.writerow([_csv_cell(r.get(k), d) for k, d in zip(names, places, strict=True)])
    else:
        specs = [_as_column(c, digits or {}, headers or {}) for c in columns]
        cells = [[_fmt(r.get(c.name), c.digits) for c in specs] for r in rows]
        print_table(specs, cells, stream, title=title, keep=keep, drop_order=drop_order, width=width)


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



# ------------------------------------------------------------------ fitting a table
#
# One table layout for every command (a table never cuts a number: 13,5 read at 80 columns was 13,500 cut). The
# widths are decided here, not by rich (which cuts cells with an ellipsis when a table
# is wider than the console): each column's narrowest width is its longest cell
# (identifiers and numbers never wrap; free text wraps between words, so no word is
# cut) and its header's longest word (headers wrap between words). On a terminal too
# narrow for that, columns whose value is the same on every row are folded into a line
# under the table, then columns are left out (those of ``drop_order`` first, then from
# the right; never those of ``keep``), and a line says which and how to see them; when
# even the kept columns do not fit, every row is printed as a list of "name value"
# lines. Piped or redirected output has no width: every column, at full width.

#: Width [characters] up to which a free-text column is laid out on one line when
#: there is room (longer texts wrap between words).
WRAP_NATURAL_MAX = 60
#: Characters a table spends per column (a space either side and a rule) and once.
_PER_COLUMN, _PER_TABLE = 3, 1


def terminal_width(stream: IO[str]) -> int | None:
    """The width to fit a table to on ``stream``: the terminal's columns (``COLUMNS``
    when set), or None when ``stream`` is not a terminal (a file, a pipe)."""
    from rich.console import Console

    console = Console(file=stream)
    return console.width if console.is_terminal else None


def _lines(text: str) -> list[str]:
    return text.split("\n") or [""]


def _longest_word(text: str) -> int:
    return max((len(w) for w in text.split()), default=0)


class _Fit:
    """One column's cells and widths: ``least`` (the narrowest that cuts nothing) and
    ``natural`` (the widest it uses)."""

    def __init__(self, spec: Column, cells: list[str]):
        self.spec = spec
        self.name = spec.name
        self.header = printable(spec.title)
        self.cells = cells
        self.layout = spec.table_layout
        head_word = _longest_word(self.header)
        longest = max([len(line) for c in cells for line in _lines(c)], default=0)
        if self.layout == "wrap":
            self.least = max(1, head_word, max((_longest_word(c) for c in cells), default=0))
            self.natural = max(self.least, min(WRAP_NATURAL_MAX, max(longest, len(self.header))))
        else:
            self.least = max(1, head_word, longest)
            self.natural = max(longest, len(self.header))

    def constant(self) -> bool:
        return len(self.cells) > 1 and len(set(self.cells)) == 1


def _table_width(widths: Sequence[int]) -> int:
    return sum(widths) + _PER_COLUMN * len(widths) + _PER_TABLE


def fit_columns(fits: list[_Fit], width: int | None, keep: Sequence[str] = (), drop_order: Sequence[str] = ()
                ) -> tuple[list[_Fit], list[_Fit], list[_Fit], list[int] | None]:
    """(shown, folded, left out, widths) of a table fitted to ``width`` characters
    (None: no limit); widths None when not even the kept columns fit (then a vertical
    layout)."""
    if width is None or _table_width([f.natural for f in fits]) <= width:
        return fits, [], [], [f.natural for f in fits]
    kept = set(keep) or {fits[0].name}
    order = [n for n in drop_order if n not in kept]
    order += [f.name for f in reversed(fits) if f.name not in kept and f.name not in order]
    # fold (nothing is lost) the same-on-every-row columns, the least important first and
    # the kept ones last (never the first column), then leave out what must go
    fold_order = order + [f.name for f in reversed(fits[1:]) if f.name in kept]
    shown, folded, dropped = list(fits), [], []  # type: list[_Fit], list[_Fit], list[_Fit]
    for name, into in [(n, folded) for n in fold_order] + [(n, dropped) for n in order]:
        if _table_width([f.least for f in shown]) <= width:
            break
        hit = [f for f in shown if f.name == name and (into is dropped or f.constant())]
        if hit:
            shown.remove(hit[0])
            into.append(hit[0])
    if not shown or _table_width([f.least for f in shown]) > width:
        return fits, [], [], None
    widths = [f.least for f in shown]
    spare = width - _table_width(widths)
    for i, f in enumerate(shown):  # identifiers, numbers: their headers on one line
        if f.layout != "wrap":
            add = min(spare, f.natural - widths[i])
            widths[i] += add
            spare -= add
    while spare > 0:  # free text: one character at a time to those that still wrap
        grow = [i for i, f in enumerate(shown) if f.layout == "wrap" and widths[i] < f.natural]
        if not grow:
            break
        for i in grow[:spare]:
            widths[i] += 1
        spare -= min(spare, len(grow))
    return shown, folded, dropped, widths


def print_table(specs: Sequence[Column], cells: list[list[str]], stream: IO[str], *, title: str | None = None,
                keep: Sequence[str] = (), drop_order: Sequence[str] = (), width: int | None = None) -> None:
    """Print rows of formatted ``cells`` under the columns ``specs``, fitted to ``width``
    (default :func:`terminal_width`), as the notes above this function say."""
    import textwrap

    from rich.console import Console
    from rich.table import Table

    if width is None:
        width = terminal_width(stream)
    fits = [_Fit(c, [row[j] for row in cells]) for j, c in enumerate(specs)]
    shown, folded, dropped, widths = fit_columns(fits, width, keep, drop_order)
    title = None if title is None else printable(title)
    if widths is None:
        _print_vertical(fits, stream, title, width or 80)
        return
    table = Table(title=title)
    for f, w in zip(shown, widths, strict=True):
        header = "\n".join(textwrap.wrap(f.header, w, break_long_words=False)) if len(f.header) > w else f.header
        if f.layout == "wrap":
            table.add_column(header, justify="left", overflow="fold", width=w)
        else:
            table.add_column(header, justify="left" if f.layout == "id" else "right", no_wrap=True, width=w)
    for i in range(len(cells)):
        table.add_row(*[f.cells[i] for f in shown])
    total = _table_width(widths)
    Console(file=stream, width=total, markup=False, highlight=False).print(table)
    notes = []
    if folded:  # each "name = value" kept on one line where it fits one
        items = [f"{f.header} = {f.cells[0]}" for f in folded]
        notes.append("every row: " + "; ".join(i.replace(" ", _KEEP) if len(i) < (width or 80) - 4 else i
                                               for i in items))
    if dropped:
        notes.append(f"not shown at {width} columns: {', '.join(f.name for f in dropped)} (every column: "
                     "--format csv or json, or a wider terminal)")
    write_lines(notes, stream, width)


#: A space that :func:`write_lines` does not break a line at.
_KEEP = "\xa0"


def write_lines(lines: Sequence[str | None], stream: IO[str], width: int | None = None) -> None:
    """Lines of text under a table (legends, notes), each wrapped between words to
    ``width`` (default the terminal's: :func:`terminal_width`; not wrapped when the
    output is not a terminal); None entries are skipped. A word is never cut."""
    import textwrap

    if width is None:
        width = terminal_width(stream)
    for line in lines:
        if not line:
            continue
        lead = " " * (len(line) - len(line.lstrip(" ")) + 2)  # continuation lines indented under the first
        parts = [line] if width is None else textwrap.wrap(line, max(width, 20), break_long_words=False,
                                                           break_on_hyphens=False, initial_indent="",
                                                           subsequent_indent=lead)
        stream.write("\n".join(parts).replace(_KEEP, " ") + "\n")


def _print_vertical(fits: list[_Fit], stream: IO[str], title: str | None, width: int) -> None:
    """Each row as lines of "header  value" (for a terminal too narrow for a table):
    values wrap between words, never inside one."""
    import textwrap

    n = len(fits[0].cells) if fits else 0
    key = max((len(f.header) for f in fits), default=0)
    room = max(width - key - 4, 20)
    for i in range(n):
        head = f"{title}: " if title else ""
        stream.write(f"{head}row {i + 1} of {n}\n")
        for f in fits:
            value = textwrap.wrap(f.cells[i], room, break_long_words=False, break_on_hyphens=False) or [""]
            stream.write(f"  {f.header:<{key}}  {value[0]}\n")
            for more in value[1:]:
                stream.write(f"  {'':<{key}}  {more}\n")
