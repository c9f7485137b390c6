"""One specification of a command's output columns, from which every format derives.

A :class:`Column` says everything about one output column: its ``name`` (the CSV header
and the JSON key, with its unit in the name), what it means (one line, with the unit),
its ``kind`` (``"number"``, ``"bool"`` or ``"text"``), which powertrains' rows have it
(``"ev"``, ``"ice"``: the JSON objects of the others leave the key out and their CSV
cell is empty), its table header and decimals, its fixed CSV decimals, its table layout,
and ``value``: how the writer gets its values from what the command computed (a
function of the command's row context, e.g. a predict block in output units).

A :class:`ColumnSpec` is a command's columns in CSV order. From it derive:

- the CSV header and column order: :attr:`ColumnSpec.names`;
- the JSON keys of a row of each powertrain, in order: :meth:`ColumnSpec.json_keys`
  (``json_lead`` first, the keys of a command's first contract, then the rest in CSV
  order);
- table headers, decimals and layout: :attr:`Column.title`, :attr:`Column.digits`,
  :attr:`Column.layout` (:func:`cevm.cli.output.write_rows` takes Column objects);
- CSV decimals and how each kind is written: :mod:`cevm.cli.columnar`;
- a reference of the columns for the manual: :meth:`ColumnSpec.reference`.

**Adding an output column is one edit:** one ``Column(...)`` entry in the command's spec
(:mod:`cevm.cli.prediction_columns` for ``predict`` and ``feasibility``), at the place
it should stand in the CSV; CSV, JSON, formats and the reference follow. Whether the
(narrow, for people) table shows it is a separate choice: its name in the command's
table columns, in the same module.

This module is light (no numpy): :mod:`cevm.cli.output` imports it for every command.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

#: The kinds of values a column holds: numbers (floats; NaN where a row has none), booleans
#: (1.0 / 0.0, NaN where unknown; written true / false) and text.
KINDS = ("number", "bool", "text")
#: Table layouts: ``"id"`` left-aligned, never wrapped nor cut (a trip id is read
#: whole); ``"wrap"`` left-aligned free text that may wrap; ``"right"`` right-aligned,
#: never wrapped (numbers, short words).
LAYOUTS = ("id", "wrap", "right")
#: Powertrains a row may have.
POWERTRAINS = ("ev", "ice")


@dataclass(frozen=True)
class Column:
    """One output column (see the module notes).

    ``name``: CSV header and JSON key; ``meaning``: one line, with the unit;
    ``powertrains``: the rows that have the column; ``kind``: one of :data:`KINDS`;
    ``header``: table header (default the name); ``digits``: decimals in tables;
    ``decimals``: fixed decimals in CSV (trailing zeros dropped); ``layout``: one of
    :data:`LAYOUTS` (default ``"id"`` for text, else ``"right"``); ``value``: a function
    of the command's row context giving the column's values.
    """

    name: str
    meaning: str
    powertrains: tuple[str, ...] = POWERTRAINS
    kind: str = "number"
    header: str | None = None
    digits: int = 3
    decimals: int = 6
    layout: str | None = None
    value: Callable[[Any], Any] | None = field(default=None, compare=False, repr=False)

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"column {self.name!r}: kind {self.kind!r} is not one of {KINDS}")
        if self.layout is not None and self.layout not in LAYOUTS:
            raise ValueError(f"column {self.name!r}: layout {self.layout!r} is not one of {LAYOUTS}")
        if not self.powertrains or not set(self.powertrains) <= set(POWERTRAINS):
            raise ValueError(f"column {self.name!r}: powertrains {self.powertrains!r} not among {POWERTRAINS}")

    @property
    def title(self) -> str:
        """The table header."""
        return self.name if self.header is None else self.header

    @property
    def table_layout(self) -> str:
        """The table layout in force (see :data:`LAYOUTS`)."""
        if self.layout is not None:
            return self.layout
        return "id" if self.kind == "text" else "right"


@dataclass(frozen=True)
class ColumnSpec:
    """A command's output columns in CSV order; ``json_lead``: names that come first in
    every JSON object, in this order (the keys of a first contract), the others following
    in CSV order."""

    columns: tuple[Column, ...]
    json_lead: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        names = [c.name for c in self.columns]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"columns named twice: {', '.join(dup)}")
        missing = [n for n in self.json_lead if n not in names]
        if missing:
            raise ValueError(f"json_lead names unknown columns: {', '.join(missing)}")

    @property
    def names(self) -> tuple[str, ...]:
        """The column names in CSV order (the CSV header)."""
        return tuple(c.name for c in self.columns)

    def __getitem__(self, name: str) -> Column:
        for c in self.columns:
            if c.name == name:
                return c
        raise KeyError(name)

    def __contains__(self, name: object) -> bool:
        return any(c.name == name for c in self.columns)

    def of_kind(self, kind: str) -> frozenset[str]:
        """The names of the columns of one kind."""
        return frozenset(c.name for c in self.columns if c.kind == kind)

    def json_order(self) -> tuple[Column, ...]:
        """Every column in JSON order: ``json_lead`` first, then the rest in CSV order."""
        lead = [self[n] for n in self.json_lead]
        return tuple(lead + [c for c in self.columns if c.name not in self.json_lead])

    def json_keys(self, powertrain: str) -> tuple[str, ...]:
        """The keys of a JSON object of a row of ``powertrain``, in order."""
        return tuple(c.name for c in self.json_order() if powertrain in c.powertrains)

    def for_powertrain(self, powertrain: str) -> tuple[Column, ...]:
        """The columns a row of ``powertrain`` has, in JSON order."""
        return tuple(c for c in self.json_order() if powertrain in c.powertrains)

    def values(self, context: Any, columns: Iterable[Column] | None = None) -> dict[str, Any]:
        """Every column's values (or those of ``columns``) for one row context
        (``Column.value`` of each)."""
        out = {}
        for c in self.columns if columns is None else columns:
            if c.value is None:
                raise ValueError(f"column {c.name!r} says not how its values are got")
            out[c.name] = c.value(context)
        return out

    def table(self, names: Iterable[str], *extra: Column) -> list[Column]:
        """The Columns of a table, by name: this spec's, or ``extra`` columns that only
        the table has (e.g. a status composed for people)."""
        own = {c.name: c for c in extra}
        return [own[n] if n in own else self[n] for n in names]

    def reference(self) -> list[str]:
        """One Markdown table row per column: name, kind, powertrains, meaning."""
        lines = ["| column | kind | rows | meaning |", "|---|---|---|---|"]
        for c in self.columns:
            rows = "all" if set(c.powertrains) == set(POWERTRAINS) else ", ".join(p.upper() for p in c.powertrains)
            lines.append(f"| `{c.name}` | {c.kind} | {rows} | {c.meaning} |")
        return lines
