"""Which services of a GTFS feed run on which dates: ``calendar.txt`` (weekdays over a
period) and ``calendar_dates.txt`` (a service added, exception_type 1, or removed, 2, on
one date), and the date a run takes when none is asked (:func:`busiest_weekday`).

Dates are proleptic Gregorian ordinals (``date.toordinal()``) inside.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import date, timedelta

import numpy as np

from cevm.errors import CevmError, InputError
from cevm.io.gtfs.tables import FeedSource, read_table, require, texts, to_date, to_int

_DAYS = ("monday", "tuesday", "wednesday", "thursday", "friday", "saturday", "sunday")

#: Longest period of dates looked at for the default date [days]: a feed's calendar may run
#: for years (an end date of 2099 is common); the default date is looked for in its first
#: year.
DEFAULT_SEARCH_DAYS = 366


@dataclass(frozen=True, eq=False)
class Calendar:
    """The services' weekly patterns (``service`` ids, ``weekdays`` (s, 7) bool, Monday
    first, ``start``/``end`` ordinals) and exceptions (``ex_service``, ``ex_date``,
    ``ex_added`` bool)."""

    service: np.ndarray
    weekdays: np.ndarray
    start: np.ndarray
    end: np.ndarray
    ex_service: np.ndarray
    ex_date: np.ndarray
    ex_added: np.ndarray

    def running(self, day: int) -> set[str]:
        """The service ids that run on the date ``day`` (an ordinal)."""
        wd = date.fromordinal(day).weekday()
        on = (self.start <= day) & (day <= self.end) & self.weekdays[:, wd]
        out = set(self.service[on].tolist())
        at = self.ex_date == day
        out |= set(self.ex_service[at & self.ex_added].tolist())
        out -= set(self.ex_service[at & ~self.ex_added].tolist())
        return out

    def period(self) -> tuple[int, int]:
        """The first and last dates any service runs on (ordinals)."""
        firsts = [int(self.start.min())] if self.start.size else []
        lasts = [int(self.end.max())] if self.end.size else []
        added = self.ex_date[self.ex_added]
        if added.size:
            firsts.append(int(added.min()))
            lasts.append(int(added.max()))
        if not firsts:
            raise CevmError("the feed's calendar has no date on which a service runs")
        return min(firsts), max(lasts)


def read_calendar(src: FeedSource) -> Calendar:
    """The feed's calendar.txt and calendar_dates.txt (one of them at least)."""
    if not src.has("calendar.txt") and not src.has("calendar_dates.txt"):
        raise InputError(src.path, "the feed has neither calendar.txt nor calendar_dates.txt: no service has a date")
    empty_s = np.zeros(0, dtype=object)
    service, weekdays, start, end = empty_s, np.zeros((0, 7), dtype=bool), np.zeros(0, np.int64), np.zeros(0, np.int64)
    if src.has("calendar.txt"):
        name = "calendar.txt"
        where = src.shown(name)
        cols = ["service_id", *_DAYS, "start_date", "end_date"]
        _, t = read_table(src, name, cols, required=tuple(cols))
        require(t["service_id"], where, "service_id", 2)
        service = texts(t["service_id"])
        weekdays = np.column_stack([to_int(t[d], where, d, 2, 0, 1) == 1 for d in _DAYS]) if service.size else weekdays
        start = to_date(t["start_date"], where, "start_date", 2)
        end = to_date(t["end_date"], where, "end_date", 2)
        bad = np.flatnonzero(end < start)
        if bad.size:
            raise InputError(where, "end_date is before start_date", line=2 + int(bad[0]), column="end_date")
    ex_s, ex_d, ex_a = empty_s, np.zeros(0, np.int64), np.zeros(0, dtype=bool)
    if src.has("calendar_dates.txt"):
        name = "calendar_dates.txt"
        where = src.shown(name)
        cols = ["service_id", "date", "exception_type"]
        _, t = read_table(src, name, cols, required=tuple(cols))
        require(t["service_id"], where, "service_id", 2)
        ex_s = texts(t["service_id"])
        ex_d = to_date(t["date"], where, "date", 2)
        ex_a = to_int(t["exception_type"], where, "exception_type", 2, 1, 2) == 1
    return Calendar(service, weekdays, start, end, ex_s, ex_d, ex_a)


def parse_dates(specs: list[str]) -> list[int]:
    """``--date`` values (``YYYY-MM-DD`` or a range ``FROM:TO``) as sorted distinct
    ordinals."""
    out: set[int] = set()
    for spec in specs:
        parts = spec.split(":")
        try:
            days = [date.fromisoformat(p.strip()) for p in parts]
        except ValueError:
            days = []
        if len(parts) not in (1, 2) or len(days) != len(parts):
            raise CevmError(f"--date {spec!r}: give YYYY-MM-DD or a range YYYY-MM-DD:YYYY-MM-DD")
        a, b = days[0], days[-1]
        if b < a:
            raise CevmError(f"--date {spec!r}: the range ends before it starts")
        if (b - a).days > DEFAULT_SEARCH_DAYS:
            raise CevmError(f"--date {spec!r}: a range of at most {DEFAULT_SEARCH_DAYS} days")
        out.update(range(a.toordinal(), b.toordinal() + 1))
    return sorted(out)


def busiest_weekday(cal: Calendar, trips_per_service: dict[str, int]) -> tuple[int, str]:
    """The default date: the first weekday (Monday to Friday) of the feed's period (its
    first :data:`DEFAULT_SEARCH_DAYS` days) with the most trips; the date and the sentence
    that says so. Weekends only if no weekday has a trip."""
    first, last = cal.period()
    last = min(last, first + DEFAULT_SEARCH_DAYS - 1)
    best: tuple[int, int] | None = None  # (trips, -day)
    best_any: tuple[int, int] | None = None
    for day in range(first, last + 1):
        n = sum(trips_per_service.get(s, 0) for s in cal.running(day))
        key = (n, -day)
        if date.fromordinal(day).weekday() < 5 and (best is None or key > best):
            best = key
        if best_any is None or key > best_any:
            best_any = key
    pick = best if best is not None and best[0] > 0 else best_any
    if pick is None or pick[0] == 0:
        raise CevmError("no trip of the feed runs on any date of its calendar")
    day = -pick[1]
    kind = "weekday" if date.fromordinal(day).weekday() < 5 else "day"
    span = f"{date.fromordinal(first)} to {date.fromordinal(last)}"
    return day, (f"{date.fromordinal(day)} ({date.fromordinal(day):%A}): the first {kind} of the feed's period "
                 f"({span}) with the most trips ({pick[0]} in trips.txt); --date for others")


def day_name(day: int) -> str:
    return str(date.fromordinal(day))


def noon_minus_12h(day: int, tz) -> float:
    """The epoch second of a service day's time origin: noon less 12 h in the feed's zone
    (GTFS: times count from there, so a day with a clock change still has its times right)."""
    from datetime import datetime

    d = date.fromordinal(day)
    noon = datetime(d.year, d.month, d.day, 12, tzinfo=tz)
    return (noon - timedelta(hours=12)).timestamp()
