"""The trip store's table layout (schema version :data:`SCHEMA_VERSION`), created or
checked when a store is opened (:func:`ensure_schema`), and how Python values are kept in
its columns.

Tables
    ``meta``       key/value: ``schema_version``, ``created_utc_s``, ``cevm_version``.
    ``files``      one row per source file, keyed on its resolved absolute path: content
                   sha256 of the version last seen, size, mtime, logger profile, status
                   (``'ok'`` | ``'failed'``), error message, when it was written, the
                   sha256 of the version whose trips are stored and how many.
    ``trips``      one row per trip (scalars only, SI units): ids, source, start time
                   [s since the Unix epoch, UTC], duration [s], distance [m], quality
                   summary (JSON), measured consumption (kind, value, source, resolution,
                   uncertainty; NULL when not measured), gross weight [kg],
                   elevation source, DSM coverage [%].
    ``trip_blobs`` per trip: the drive-cycle vector (opaque bytes from the caller) and
                   the profile arrays (see :func:`cevm.store.codec.encode_profile`). Kept
                   apart from ``trips`` so that listing trips never reads the blobs.
    ``runs``       one row per ``cevm ingest`` run: start, end, host, pid, counts (JSON).
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from cevm import __version__
from cevm.errors import CevmError

SCHEMA_VERSION = 1
"""Version of the table layout written by this code. A store with a higher version was
written by a newer cevm and is refused; lower versions would be migrated on open."""


TRIP_COLUMNS: tuple[str, ...] = (
    "trip_id",
    "vehicle_id",
    "source_file",
    "source_sha256",
    "trip_index",
    "start_utc_s",
    "duration_s",
    "distance_m",
    "n_samples",
    "elevation_source",
    "dsm_coverage_pct",
    "gross_weight_kg",
    "measured_kind",
    "measured_value",
    "measured_source",
    "measured_resolution",
    "measured_uncertainty",
    "quality_json",
)
TRIP_FLOAT_COLUMNS = (
    "start_utc_s",
    "duration_s",
    "distance_m",
    "dsm_coverage_pct",
    "gross_weight_kg",
    "measured_value",
    "measured_resolution",
    "measured_uncertainty",
)

FILE_COLUMNS: tuple[str, ...] = (
    "path",
    "sha256",
    "size_bytes",
    "mtime_s",
    "profile",
    "status",
    "error",
    "ingested_utc_s",
    "trips_sha256",
    "n_trips",
    "n_duplicates",
)

_SCHEMA_STATEMENTS: tuple[str, ...] = (
    """CREATE TABLE IF NOT EXISTS meta (
        key TEXT PRIMARY KEY,
        value TEXT NOT NULL
    )""",
    """CREATE TABLE IF NOT EXISTS files (
        path TEXT PRIMARY KEY,
        sha256 TEXT NOT NULL,
        size_bytes INTEGER,
        mtime_s REAL,
        profile TEXT,
        status TEXT NOT NULL CHECK (status IN ('ok', 'failed')),
        error TEXT,
        ingested_utc_s REAL NOT NULL,
        trips_sha256 TEXT,
        n_trips INTEGER NOT NULL DEFAULT 0,
        n_duplicates INTEGER NOT NULL DEFAULT 0
    )""",
    """CREATE TABLE IF NOT EXISTS trips (
        trip_id TEXT PRIMARY KEY,
        vehicle_id TEXT NOT NULL,
        source_file TEXT NOT NULL REFERENCES files(path),
        source_sha256 TEXT NOT NULL,
        trip_index INTEGER NOT NULL,
        start_utc_s REAL NOT NULL,
        duration_s REAL NOT NULL,
        distance_m REAL NOT NULL,
        n_samples INTEGER NOT NULL,
        elevation_source TEXT NOT NULL,
        dsm_coverage_pct REAL,
        gross_weight_kg REAL,
        measured_kind TEXT CHECK (measured_kind IN ('fuel_l', 'energy_j')),
        measured_value REAL,
        measured_source TEXT,
        measured_resolution REAL,
        measured_uncertainty REAL,
        quality_json TEXT NOT NULL,
        UNIQUE (source_file, trip_index)
    )""",
    "CREATE INDEX IF NOT EXISTS trips_by_vehicle ON trips (vehicle_id, start_utc_s)",
    """CREATE TABLE IF NOT EXISTS trip_blobs (
        trip_id TEXT PRIMARY KEY REFERENCES trips(trip_id),
        vector BLOB NOT NULL,
        profile BLOB NOT NULL
    )""",
    """CREATE TABLE IF NOT EXISTS runs (
        run_id INTEGER PRIMARY KEY AUTOINCREMENT,
        started_utc_s REAL NOT NULL,
        finished_utc_s REAL,
        host TEXT,
        pid INTEGER,
        counts_json TEXT
    )""",
)


def ensure_schema(store) -> None:
    """Create the tables of a new store, or check an existing one, in one write
    transaction of ``store`` (a :class:`~cevm.store.TripStore`; its ``con``, ``path`` and
    ``_write()``). Refuses an SQLite database of something else, and a store written by a
    newer cevm (schema version above :data:`SCHEMA_VERSION`)."""
    con = store.con
    with store._write():
        tables = {r[0] for r in con.execute("SELECT name FROM sqlite_master WHERE type='table'")}
        version = None
        if "meta" in tables:
            row = con.execute("SELECT value FROM meta WHERE key='schema_version'").fetchone()
            version = int(row[0]) if row else None
        elif tables - {"sqlite_sequence"}:
            raise CevmError(
                f"{store.path}: an SQLite database of something else (tables "
                f"{sorted(tables)[:5]}), not a cevm store; choose another --store"
            )
        if version is not None and version > SCHEMA_VERSION:
            raise CevmError(
                f"{store.path}: store schema version {version} was written by a newer "
                f"cevm; this cevm {__version__} reads up to version {SCHEMA_VERSION}. "
                "Upgrade cevm or use another --store."
            )
        for stmt in _SCHEMA_STATEMENTS:
            con.execute(stmt)
        if version is None:
            con.executemany(
                "INSERT OR IGNORE INTO meta (key, value) VALUES (?, ?)",
                [
                    ("schema_version", str(SCHEMA_VERSION)),
                    ("created_utc_s", repr(time.time())),
                    ("cevm_version", __version__),
                ],
            )


# ------------------------------------------------------------ values in the columns


def json_default(obj: object) -> object:
    """``json.dumps``'s ``default`` for what trips carry: numpy scalars and arrays, paths."""
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"{type(obj).__name__} is not JSON-serialisable")


def sql_real(x: float | None) -> float | None:
    """A float for SQLite, None for None/NaN (SQLite stores NaN as NULL anyway)."""
    if x is None:
        return None
    x = float(x)
    return None if math.isnan(x) else x


def nan_for_null(x: float | None) -> float:
    """A stored REAL as a float, NaN for NULL."""
    return math.nan if x is None else float(x)


def in_json(values: Iterable[str]) -> str:
    """A JSON array for ``IN (SELECT value FROM json_each(?))``: one parameter for any
    number of ids, so no limit on SQL variables."""
    return json.dumps([str(v) for v in values])

