"""The log's columns as the cleaning takes them from the reader's frame, and the
selection of their rows that the time repairs, the sort and the duplicates make."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from cevm.core.trip import CANONICAL_COLUMNS
from cevm.errors import InputError
from cevm.ingest.cleaning.arrays import _let_go
from cevm.ingest.evidence import EVIDENCE_COLUMNS
from cevm.lazy import is_pandas, pd

if TYPE_CHECKING:
    from cevm.ingest.cleaning.events import RepairEvents
    from cevm.ingest.cleaning.gps import GpsFixes


class LogRows:
    """The log's columns as they came and which of their rows are the current rows, in
    order. The time repairs, the sort and the duplicates select and reorder rows
    through one index into the columns (``sel``; None: all of them, in order) instead
    of copying every column at each step; :meth:`gather` (or the tick merge) then makes
    each column once, in the final order, dropping its source array as it goes."""

    def __init__(self, cols: dict[str, np.ndarray]) -> None:
        self.cols = cols
        self.sel: np.ndarray | None = None

    def __contains__(self, name: str) -> bool:
        return name in self.cols

    def select(self, idx: np.ndarray) -> None:
        """Keep the current rows ``idx`` (positions, or a mask), in that order."""
        if idx.dtype == bool:
            idx = np.flatnonzero(idx)
        self.sel = idx if self.sel is None else self.sel[idx]

    def positions(self, idx: np.ndarray | None = None) -> np.ndarray | None:
        """Where the current rows ``idx`` (positions or a mask; None: all) are in the
        source arrays (None: all of them, in order)."""
        if self.sel is None:
            return idx
        return self.sel if idx is None else self.sel[idx]

    def at(self, name: str, idx: np.ndarray) -> np.ndarray:
        """Column ``name`` at the current rows ``idx`` (float64)."""
        return self.cols[name][self.positions(idx)].astype(np.float64, copy=False)

    def gather(self, keep, wide=()) -> None:
        """The columns in ``keep`` at the current rows, in their order (a source array
        itself where nothing was selected), those in ``wide`` as float64 (the others
        keep their float32 or float64); the columns not in ``keep`` dropped."""
        names = list(self.cols)
        out = {}
        for name in sorted(names, key=lambda c: c in keep):  # the dropped ones first: their memory is free sooner
            src = self.cols.pop(name)
            if name in keep:
                a = src if self.sel is None else src[self.sel]
                out[name] = a.astype(np.float64) if name in wide and a.dtype != np.float64 else a
            del src
            _let_go(len(out[name]) if name in out else 0)
        self.cols, self.sel = {c: out[c] for c in names if c in out}, None


_FLOATS = (np.dtype(np.float64), np.dtype(np.float32))


#: Columns the row speeds and the GPS fixes are made from: float64 from the tick merge
#: on (the others, read per trip, keep their float32 where they have it).
_ROW_SPEED_COLUMNS = ("wheel_speed_mps", "gps_speed_mps", "lat_deg", "lon_deg", "gps_hdop", "gps_alt_m")


def _load(frame: pd.DataFrame | Mapping[str, np.ndarray], path, release: bool = False
          ) -> tuple[np.ndarray, np.ndarray, LogRows, int]:
    """Time, file lines and the other numeric columns of ``frame`` (a DataFrame, or the
    reader's columns as a dict of arrays: :attr:`cevm.ingest.reading.ParsedLog.columns`),
    their own arrays where they are float64 or float32 (no copy); rows without a finite
    time are left out of the current rows. ``release``: the columns are removed from
    ``frame`` once taken, so that the cleaning holds the only reference to its arrays."""
    table: Any = frame if is_pandas(frame, "DataFrame") else None  # a pandas DataFrame (pandas is untyped here)
    names = set(table.columns) if table is not None else set(frame)
    if "time_s" not in names:
        raise InputError(path, "no time column (canonical 'time_s')", column="time_s")
    n = len(frame) if table is not None else len(frame["time_s"])
    line = _lines(frame["source_line"], n) if "source_line" in names else np.arange(1, n + 1, dtype=np.int64)
    cols: dict[str, np.ndarray] = {}
    for name in dict.fromkeys((*CANONICAL_COLUMNS, *EVIDENCE_COLUMNS)):
        if name in ("source_line", "vehicle_id") or name not in names:
            continue
        cols[name] = _numbers(frame[name], name, line, path)
    if release:
        if table is not None:
            for c in list(table.columns):
                del table[c]
        else:
            frame.clear()  # type: ignore[union-attr]
    t = cols.pop("time_s").astype(np.float64, copy=False)
    rows = LogRows(cols)
    ok = np.isfinite(t)
    dropped = int(n - ok.sum())
    if dropped:
        t = t[ok]
        line = line[ok]
        rows.select(ok)
    return t, line, rows, dropped


def _lines(s, n: int) -> np.ndarray:
    """The file lines of a ``source_line`` column (an array or a Series): the reader's
    integers as they are, anything else made integers (-1 where unknown)."""
    a = s.to_numpy() if is_pandas(s, "Series") and isinstance(s.dtype, np.dtype) else s
    if isinstance(a, np.ndarray) and a.dtype.kind in "iu":
        return a
    x = pd.to_numeric(pd.Series(s), errors="coerce").to_numpy(dtype=float)
    return np.where(np.isfinite(x), x, -1).astype(np.int64)


def _numbers(s, name: str, line: np.ndarray, path) -> np.ndarray:
    """A column (an array or a Series) as numbers: its own array where it is float64 or
    float32 (values exactly float32 stay so until they are gathered), else float64; a
    value that is not a number is an error naming its line and column."""
    if isinstance(s, np.ndarray) and s.dtype in _FLOATS:
        return s
    s = pd.Series(s) if not is_pandas(s, "Series") else s
    try:
        return s.to_numpy() if s.dtype in _FLOATS else s.to_numpy(dtype=float, na_value=np.nan)
    except (TypeError, ValueError):
        num = pd.to_numeric(s, errors="coerce")
        bad = np.flatnonzero((num.isna() & s.notna()).to_numpy())
        i = int(bad[0]) if bad.size else 0
        raise InputError(path, f"not a number: {s.iloc[i]!r}", line=int(line[i]), column=name) from None


@dataclass(frozen=True, eq=False)
class CleanedLog:
    """The cleaned rows of one log that its trips are cut from: strictly increasing
    times ``t``, the canonical columns the trips read (float64; those read only per
    trip stay float32 where the log had them so, and are widened per trip), the cleaned
    GPS fixes and the repairs."""

    t: np.ndarray
    cols: dict
    fixes: GpsFixes
    ev: RepairEvents
