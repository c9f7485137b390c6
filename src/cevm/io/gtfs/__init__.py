"""GTFS feeds (zip or folder) read for ``cevm gtfs``: the trips that run on the dates
asked, their stop times, stops and shapes (:mod:`~cevm.io.gtfs.feed`), the calendar
(:mod:`~cevm.io.gtfs.calendar`), the text files read and checked as columns
(:mod:`~cevm.io.gtfs.tables`)."""

from cevm.io.gtfs.calendar import parse_dates
from cevm.io.gtfs.feed import read_feed

__all__ = ["parse_dates", "read_feed"]
