"""Timetables as drive cycles: a scheduled trip's driving synthesised between its stops, and
blocks of scheduled trips run as duties (pure; the feed is read by :mod:`cevm.io.gtfs`)."""
