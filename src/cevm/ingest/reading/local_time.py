"""Times as a logger writes them, to UTC: corrupt dates repaired, local times localised
through the clock changes, one zone notation per file."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from cevm.errors import InputError
from cevm.ingest.reading.lines import _fmt_ns, _lines_summary
from cevm.ingest.timestamps import NAT, NS_PER_DAY
from cevm.lazy import pd


class RowValues(Protocol):
    """The text of a column by row: an array, or :class:`cevm.ingest.reading.gather.FactorisedValues`."""

    def __getitem__(self, idx: Any) -> Any: ...


def _repair_dates(date_ns: np.ndarray, tod_ns: np.ndarray, raw_dates: RowValues, lines: np.ndarray,
                  max_days: float, path: Path, col: str, repairs: list[str]) -> np.ndarray:
    """Replace corrupt dates (unparseable, or more than ``max_days`` from the file's
    most common date) by the date of the nearest preceding good row (following row for
    a corrupt run at the start), plus or minus one day where the time of day wrapped
    past midnight between that row and this one (a jump of more than 12 h)."""
    n = len(date_ns)
    valid = date_ns != NAT
    if not valid.any():
        raise InputError(path, "no row has a readable date", line=int(lines[0]), column=col)
    uniq, counts = np.unique(date_ns[valid], return_counts=True)
    dominant = uniq[np.argmax(counts)]
    bad = ~valid | (np.abs(date_ns - dominant) > max_days * NS_PER_DAY)
    if not bad.any():
        return date_ns
    idx = np.arange(n)
    prev = np.maximum.accumulate(np.where(~bad, idx, -1))
    nxt = np.minimum.accumulate(np.where(~bad, idx, n)[::-1])[::-1]
    donor = np.where(prev >= 0, prev, nxt)
    b = np.flatnonzero(bad)
    d = donor[b]
    half_day = NS_PER_DAY // 2
    shift = np.zeros(len(b), np.int64)
    from_prev = prev[b] >= 0
    shift[from_prev & (tod_ns[b] < tod_ns[d] - half_day)] = NS_PER_DAY
    shift[~from_prev & (tod_ns[b] > tod_ns[d] + half_day)] = -NS_PER_DAY
    fixed = date_ns.copy()
    fixed[b] = date_ns[d] + shift
    examples = pd.unique(pd.Series(raw_dates[b]).astype(str))[:4]
    repairs.append(
        f"time: {len(b)} rows with a corrupt date (e.g. {', '.join(repr(x) for x in examples)}; "
        f"the file's date is {_fmt_ns(dominant)[:10]}) took the date of the neighbouring rows, "
        f"the time of day kept: {_lines_summary(lines[b])}"
    )
    return fixed


def _localize(naive: np.ndarray, tz: str, groups: np.ndarray | None, lines: np.ndarray,
              repairs: list[str]) -> np.ndarray:
    """UTC ns of naive local times in zone ``tz``, in file order.

    Ambiguous times (the repeated hour when clocks go back) are resolved by row order
    within each group (vehicle): summer time until the local time first steps backwards
    inside the repeated hour, standard time from then on. Non-existent times (the hour
    skipped when clocks go forward) are read with the offset in force just before the
    jump (a logger clock that has not changed yet). Both are reported as repairs.
    """
    if tz in ("UTC", "Etc/UTC", "GMT", "Z"):
        return naive
    idx = pd.DatetimeIndex(naive.view("datetime64[ns]"))
    loc = idx.tz_localize(tz, ambiguous="NaT", nonexistent="NaT")
    odd = np.asarray(loc.isna()) & (naive != NAT)
    if not odd.any():
        return loc.tz_convert("UTC").as_unit("ns").asi8
    sub = idx[odd]
    as_dst = sub.tz_localize(tz, ambiguous=np.ones(len(sub), bool), nonexistent="NaT")
    nonexist_sub = np.asarray(as_dst.isna())
    odd_idx = np.flatnonzero(odd)
    amb_rows = odd_idx[~nonexist_sub]
    gap_rows = odd_idx[nonexist_sub]
    dst_flags = np.ones(len(naive), bool)
    if len(amb_rows):
        g = groups[amb_rows] if groups is not None else np.zeros(len(amb_rows), np.int64)
        day = naive[amb_rows] // NS_PER_DAY
        frame = pd.DataFrame({"g": g, "day": day, "t": naive[amb_rows]})
        back = frame.groupby(["g", "day"], sort=False)["t"].diff() < 0
        second = back.groupby([frame["g"], frame["day"]], sort=False).cumsum() > 0
        second = second.to_numpy()
        dst_flags[amb_rows[second]] = False
        repairs.append(
            f"time: {len(amb_rows)} rows fall in the repeated hour when clocks went back ({tz}); "
            f"{int(second.sum())} read as standard time after the local time stepped back, "
            f"the others as summer time (by row order): {_lines_summary(lines[amb_rows])}"
        )
    out = idx.tz_localize(tz, ambiguous=dst_flags, nonexistent="NaT").tz_convert("UTC").as_unit("ns").asi8.copy()
    if len(gap_rows):
        before = pd.DatetimeIndex((naive[gap_rows] - NS_PER_DAY).view("datetime64[ns]"))
        before_loc = before.tz_localize(tz, ambiguous=True, nonexistent="shift_forward")
        offset = (before_loc.tz_localize(None).as_unit("ns").asi8
                  - before_loc.tz_convert("UTC").tz_localize(None).as_unit("ns").asi8)
        out[gap_rows] = naive[gap_rows] - offset
        repairs.append(
            f"time: {len(gap_rows)} rows have local times that do not exist (skipped hour when "
            f"clocks went forward, {tz}); read with the offset before the change: "
            f"{_lines_summary(lines[gap_rows])}"
        )
    return out


#: ISO 8601 text that ends in a zone designator ('Z', +hh:mm, +hhmm), as
#: :func:`cevm.ingest.timestamps.has_offset` reads it.
_ZONE = r"(?:Z|[+-]\d\d:?\d\d)"


_ZONE_RE = _ZONE + r"\s*$"


#: The ISO 8601 forms pyarrow's timestamp parser reads (date, hours, minutes, seconds,
#: fraction; a zone designator); other forms are read as text.
_ISO_SAMPLE_RE = re.compile(r"^\d{4}-\d\d-\d\d(?:[T ]\d\d(?::\d\d(?::\d\d(?:\.\d{1,9})?)?)?)?" + _ZONE + "?$")


def _mixed_zone_message(first_zoned: bool) -> str:
    if first_zoned:
        return ("time zone notation mixed in one file: the file's first time carries a zone designator "
                "('Z' or +hh:mm), this one none")
    return ("time zone notation mixed in one file: the file's first time carries no zone designator, this one "
            "does ('Z' or +hh:mm)")
