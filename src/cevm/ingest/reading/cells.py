"""Cells of a measured column that are not numbers, as loggers write them: ``ERR``,
``---``, ``#N/A``, ``#VALUE!``, ``error``, a reading with its unit written after it.

In a *measured* numeric column (not one the profile requires, nor one its detection
needs) such a cell is a missing value, as an empty cell or ``N/A`` already is: one bad
cell must not lose a day's log. Each is reported with its file line and column; a value
followed by the column's own unit (``12.5 km/h`` in a km/h column, any case and spacing)
is read as that number, and reported too. In a *required* column a cell that is not a
number stays an error naming file, line and column. When more than the profile's
``absurd_error_share`` of a column's cells are not numbers, the column is not what the
profile says it is (a wrong column, a wrong decimal mark): an error at the first one.

Text that means "no value" (:data:`~cevm.ingest.reading.blocks._NUMERIC_NA`: empty,
``NA``, ``N/A``, ``NaN``, ``nan``, ``null``, ``-``, ``--`` ...) is missing without a
note; ``inf`` is a number, and out of every plausible range
(:mod:`~cevm.ingest.reading.plausibility`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from cevm.errors import InputError
from cevm.ingest.reading.lines import _line_col_error, _lines_summary
from cevm.lazy import pd


@dataclass
class BadCells:
    """A numeric column's cells that were not numbers (their file lines and text), and
    the lines of those read as numbers once their unit was taken off."""

    lines: list[np.ndarray] = field(default_factory=list)
    values: list[np.ndarray] = field(default_factory=list)
    unit_lines: list[np.ndarray] = field(default_factory=list)

    def add(self, other: BadCells) -> None:
        self.lines += other.lines
        self.values += other.values
        self.unit_lines += other.unit_lines


def cell_numbers(cells: pd.Series, decimal: str, unit: str | None, lines: np.ndarray) -> tuple[np.ndarray, BadCells]:
    """A column's cells (text, NaN where empty or NA-like) as float64 (NaN where not a
    number), and its :class:`BadCells`."""
    txt = cells if decimal == "." else cells.str.replace(decimal, ".", regex=False)
    x = np.array(pd.to_numeric(txt, errors="coerce"), dtype=np.float64)  # our own, writable
    bad = np.isnan(x) & cells.notna().to_numpy()
    found = BadCells()
    if not bad.any():
        return x, found
    if unit and unit != "-":
        stripped = txt[bad].astype(str).str.replace(_unit_suffix(unit), "", regex=True)
        with_unit = pd.to_numeric(stripped, errors="coerce").to_numpy(dtype=np.float64, na_value=np.nan)
        ok = ~np.isnan(with_unit) & (stripped.to_numpy(dtype=object) != txt[bad].to_numpy(dtype=object))
        if ok.any():
            where = np.flatnonzero(bad)[ok]
            x[where] = with_unit[ok]
            bad[where] = False
            found.unit_lines.append(lines[where])
    if bad.any():
        found.lines.append(lines[bad])
        found.values.append(cells.to_numpy(dtype=object)[bad])
    return x, found


def _unit_suffix(unit: str) -> re.Pattern:
    return re.compile(r"\s*" + re.escape(unit.replace(" ", "")).replace(r"\/", "/") + r"\s*$", re.IGNORECASE)


def check_bad_cells(path: Path, column: str, canonical: str, unit: str | None, found: BadCells,
                    n_numbers: int, error_share: float, repairs: list[str]) -> None:
    """Report a column's bad cells (``n_numbers``: its cells read as numbers), or refuse
    the column when they are more than ``error_share`` of its cells."""
    if found.unit_lines:
        lines = np.sort(np.concatenate(found.unit_lines))
        repairs.append(f"{canonical}: {lines.size} values written with their unit ({unit!r}) in column "
                       f"'{column}' read as numbers: {_lines_summary(lines)}")
    if not found.lines:
        return
    lines = np.concatenate(found.lines)
    values = np.concatenate(found.values)
    order = np.argsort(lines, kind="stable")
    lines, values = lines[order], values[order]
    n_bad = lines.size
    if n_bad > error_share * (n_bad + n_numbers):
        raise _line_col_error(path, f"{n_bad} of {n_bad + n_numbers} cells are not numbers (a wrong column or "
                                    "decimal mark in the profile?), first:", lines, np.ones(n_bad, bool),
                              column, values)
    examples = ", ".join(repr(str(v)) for v in pd.unique(pd.Series(values).astype(str))[:3])
    repairs.append(f"{canonical}: {n_bad} cells that are not numbers ({examples}) in column '{column}' read as "
                   f"missing values: {_lines_summary(lines)}")


def not_a_number(path: Path, column: str, cells: pd.Series, lines: np.ndarray, bad: np.ndarray) -> InputError:
    """The error for a required column's cell that is not a number."""
    return _line_col_error(path, "not a number:", lines, bad, column, cells.to_numpy())
