"""The trip store's table layout (schema version :data:`SCHEMA_VERSION`), its
migrations (:data:`MIGRATIONS`, applied when a store is opened: :func:`ensure_schema`),
and how Python values are kept in its columns.

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
                   elevation source, DSM coverage [%]; the evidence of
                   :data:`cevm.core.trip.TRIP_EVIDENCE_FIELDS` (ambient temperature
                   [degC], standstill time [s] and rate [W or l/s]; NULL when not logged);
                   its start (:data:`TRIP_START_COLUMNS`: state of charge [%], standstill
                   since the vehicle's previous trip [s]).
    ``trip_blobs`` per trip: the drive-cycle vector (opaque bytes from the caller) and
                   the profile arrays (see :func:`cevm.store.codec.encode_profile`). Kept
                   apart from ``trips`` so that listing trips never reads the blobs.
    ``runs``       one row per ``cevm ingest`` run: start, end, host, pid, counts (JSON).
    ``routes``, ``route_legs``: named routes (:mod:`cevm.store.routes`).
    ``trip_masses`` a trip's gross mass or payload [kg] given by a manifest (its file and
                   line) or by hand, and when (:mod:`cevm.store.masses`); keyed on the
                   trip id, without a foreign key: a value outlives a re-ingest.

Checksums
    Every blob (a trip's vector and profile, a route's cycle leg's) is stored with its
    CRC-32 (:func:`blob_crc32`, zlib's), written with it in the same statement and
    checked by every reader: a blob damaged on disk is found and named, never decoded
    into wrong numbers. Blobs stored before version 3 got theirs when the store was
    migrated, so damage done before then is found only by decoding (``cevm store
    check`` decodes every blob).

Versions
    A new store is made by running every migration from version 0; an older store gets
    the ones it lacks, in order, in one write transaction when it is opened (all or
    none). A store of a higher version than this cevm's was written by a newer cevm and
    is refused, never opened.
"""

from __future__ import annotations

import functools
import json
import math
import time
import zlib
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cevm import __version__
from cevm.core.trip import TRIP_EVIDENCE_FIELDS
from cevm.errors import CevmError

#: A trip's state at its start (migration 6): the state of charge its log holds there [%]
#: (NULL where the log has none), and the time the vehicle stood since the end of its
#: previous stored trip [s] (NULL for its first, or where that trip overlaps this one);
#: the store keeps the second one right for every trip of a vehicle whenever its trips
#: change (:func:`cevm.store.writing.update_standstill_before`).
TRIP_START_COLUMNS: tuple[str, ...] = ("start_soc_pct", "standstill_before_s")

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
    *TRIP_EVIDENCE_FIELDS,
    *TRIP_START_COLUMNS,
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
    *TRIP_EVIDENCE_FIELDS,
    *TRIP_START_COLUMNS,
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


# ------------------------------------------------------------------------ migrations


@dataclass(frozen=True)
class Migration:
    """One step of the layout: from version ``version - 1`` to ``version``.

    ``statements`` run in order inside the opening's write transaction. A migration is
    never edited once released (stores out there were made by it): a new layout is a
    new migration at the end of :data:`MIGRATIONS`.
    """

    version: int
    what: str
    statements: tuple[str, ...]


_V1_STATEMENTS: tuple[str, ...] = (
    """CREATE TABLE meta (
        key TEXT PRIMARY KEY,
        value TEXT NOT NULL
    )""",
    """CREATE TABLE files (
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
    """CREATE TABLE trips (
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
    "CREATE INDEX trips_by_vehicle ON trips (vehicle_id, start_utc_s)",
    """CREATE TABLE trip_blobs (
        trip_id TEXT PRIMARY KEY REFERENCES trips(trip_id),
        vector BLOB NOT NULL,
        profile BLOB NOT NULL
    )""",
    """CREATE TABLE runs (
        run_id INTEGER PRIMARY KEY AUTOINCREMENT,
        started_utc_s REAL NOT NULL,
        finished_utc_s REAL,
        host TEXT,
        pid INTEGER,
        counts_json TEXT
    )""",
)

#: The trip evidence of migration 2, spelt out: a migration never changes, so a new
#: field of :data:`cevm.core.trip.TRIP_EVIDENCE_FIELDS` needs a new migration (a test
#: checks that the two agree).
_V2_EVIDENCE_COLUMNS = ("ambient_temp_c", "ambient_temp_min_c", "ambient_temp_max_c", "standstill_s",
                        "standstill_power_w", "standstill_fuel_lps")

#: Migration 3: a CRC-32 of every blob, computed for the blobs already stored (by the
#: ``crc32`` SQL function of the store's connection), and the route tables, which
#: :mod:`cevm.store.routes` created on first use (``routes_schema_version`` 1), made part
#: of the schema.
_V3_STATEMENTS: tuple[str, ...] = (
    "ALTER TABLE trip_blobs ADD COLUMN vector_crc32 INTEGER",
    "ALTER TABLE trip_blobs ADD COLUMN profile_crc32 INTEGER",
    "UPDATE trip_blobs SET vector_crc32 = crc32(vector), profile_crc32 = crc32(profile)",
    """CREATE TABLE IF NOT EXISTS routes (
        name TEXT PRIMARY KEY,
        created_utc_s REAL NOT NULL,
        n_legs INTEGER NOT NULL CHECK (n_legs > 0),
        note TEXT
    )""",
    """CREATE TABLE IF NOT EXISTS route_legs (
        route TEXT NOT NULL REFERENCES routes(name) ON DELETE CASCADE,
        position INTEGER NOT NULL,
        kind TEXT NOT NULL CHECK (kind IN ('trip', 'cycle')),
        ref TEXT NOT NULL,
        label TEXT NOT NULL,
        sha256 TEXT,
        vector BLOB,
        profile BLOB,
        PRIMARY KEY (route, position),
        CHECK ((kind = 'cycle') = (vector IS NOT NULL AND profile IS NOT NULL))
    )""",
    "ALTER TABLE route_legs ADD COLUMN vector_crc32 INTEGER",
    "ALTER TABLE route_legs ADD COLUMN profile_crc32 INTEGER",
    "UPDATE route_legs SET vector_crc32 = crc32(vector), profile_crc32 = crc32(profile) WHERE kind = 'cycle'",
    "DELETE FROM meta WHERE key = 'routes_schema_version'",
)

#: Migration 5: vectors stored before format 3 (``CEVMVEC2``, or the npz of format 1)
#: lack k_pos and traction_s. They are remade, scalars kept, from the profile stored
#: beside them by the SQL functions ``cevm_trip_vector_v3`` and
#: ``cevm_route_vector_v3`` of the store's connection (:func:`upgrade_trip_vector`), and
#: their checksums rewritten.
_OLD_VECTOR = "(substr(vector, 1, 8) = CAST('CEVMVEC2' AS BLOB) OR substr(vector, 1, 2) = CAST('PK' AS BLOB))"
_V5_STATEMENTS: tuple[str, ...] = (
    f"UPDATE trip_blobs SET vector = cevm_trip_vector_v3(vector, profile) WHERE {_OLD_VECTOR}",
    "UPDATE trip_blobs SET vector_crc32 = crc32(vector)",
    f"UPDATE route_legs SET vector = cevm_route_vector_v3(vector, profile) WHERE kind = 'cycle' AND {_OLD_VECTOR}",
    "UPDATE route_legs SET vector_crc32 = crc32(vector) WHERE kind = 'cycle'",
)

#: Each trip's standstill since the end of the previous trip of its vehicle (NULL for the
#: first, or an overlap), for the vehicles in ``{vehicles}`` (an SQL condition on
#: ``vehicle_id``).
STANDSTILL_BEFORE_SQL = """UPDATE trips SET standstill_before_s = g.gap FROM (
    SELECT trip_id, CASE WHEN gap >= 0 THEN gap END AS gap FROM (
        SELECT trip_id, start_utc_s - LAG(start_utc_s + duration_s)
            OVER (PARTITION BY vehicle_id ORDER BY start_utc_s, trip_id) AS gap
        FROM trips WHERE {vehicles})) AS g
    WHERE trips.trip_id = g.trip_id AND trips.standstill_before_s IS NOT g.gap"""

MIGRATIONS: tuple[Migration, ...] = (
    Migration(1, "files, trips, their blobs and ingest runs", _V1_STATEMENTS),
    Migration(2, "trip evidence: ambient temperature (mean, min, max), standstill time and rate",
              tuple(f"ALTER TABLE trips ADD COLUMN {c} REAL" for c in _V2_EVIDENCE_COLUMNS)),
    Migration(3, "a checksum with every blob; the route tables", _V3_STATEMENTS),
    Migration(4, "trip masses from manifests or by hand", (
        """CREATE TABLE trip_masses (
            trip_id TEXT PRIMARY KEY,
            kind TEXT NOT NULL CHECK (kind IN ('gross', 'payload')),
            mass_kg REAL NOT NULL CHECK (mass_kg >= 0),
            source TEXT NOT NULL CHECK (source IN ('manifest', 'hand')),
            source_file TEXT,
            source_line INTEGER,
            set_utc_s REAL NOT NULL
        )""",
    )),
    Migration(5, "cycle vectors in format 3 (with the positive kinetic energy and the traction time the "
                 "energy terms need), computed from each trip's or route leg's stored profile", _V5_STATEMENTS),
    Migration(6, "a trip's start: the state of charge logged there (known after a re-ingest of its file), the "
                 "time its vehicle stood since its previous trip", (
                     "ALTER TABLE trips ADD COLUMN start_soc_pct REAL",
                     "ALTER TABLE trips ADD COLUMN standstill_before_s REAL",
                     STANDSTILL_BEFORE_SQL.format(vehicles="1"),
                 )),
)

SCHEMA_VERSION = MIGRATIONS[-1].version
"""Version of the table layout written by this code: the last of :data:`MIGRATIONS`. A
store with a higher version was written by a newer cevm and is refused; a lower one is
migrated when opened."""


#: Tables that only a cevm store holds: a database with one of them and no schema
#: version in ``meta`` is a damaged store, not a database of something else.
_OWN_TABLES = frozenset({"trips", "trip_blobs", "files", "runs", "trip_masses"})


def stored_version(con, path: Path) -> int:
    """The schema version of the database on ``con``: 0 for an empty database; refuses a
    database of something else, and a store whose version is missing or not a version
    number (:class:`~cevm.store.failures.StoreDamagedError`: exit 4)."""
    from cevm.store.failures import DAMAGED_HINT, StoreDamagedError

    tables = {r[0] for r in con.execute("SELECT name FROM sqlite_master WHERE type='table'")}
    if "meta" in tables:
        row = con.execute("SELECT value FROM meta WHERE key='schema_version'").fetchone()
        if row is not None:
            text = str(row[0]).strip()
            if not text.isascii() or not text.isdigit():
                raise StoreDamagedError(f"{path}: the store is damaged: meta.schema_version is {str(row[0])[:40]!r}, "
                                        f"not a version number; {DAMAGED_HINT}")
            return int(text)
    if not tables - {"sqlite_sequence"}:
        return 0
    if tables & _OWN_TABLES:
        where = "its schema_version row in table meta" if "meta" in tables else "its table meta"
        raise StoreDamagedError(f"{path}: the store is damaged: {where} is missing (tables "
                                f"{', '.join(sorted(tables)[:8])}); {DAMAGED_HINT}")
    raise CevmError(
        f"{path}: an SQLite database of something else (tables "
        f"{sorted(tables)[:5]}), not a cevm store; choose another --store"
    )


@functools.cache
def expected_layout(version: int) -> dict[str, tuple[str, ...]]:
    """The tables and their columns of a store at ``version``: the migrations up to it run
    on an empty database in memory (so the layout is never written twice)."""
    import sqlite3

    con = sqlite3.connect(":memory:")
    try:
        con.create_function("crc32", 1, blob_crc32)
        for name in ("cevm_trip_vector_v3", "cevm_route_vector_v3"):  # never called: the tables are empty
            con.create_function(name, 2, lambda vector, profile: vector)
        for m in MIGRATIONS[:version]:
            for stmt in m.statements:
                con.execute(stmt)
        return _layout(con)
    finally:
        con.close()


def _layout(con) -> dict[str, tuple[str, ...]]:
    tables = [r[0] for r in con.execute("SELECT name FROM sqlite_master WHERE type='table' AND name NOT LIKE "
                                        "'sqlite_%' ORDER BY name")]
    return {t: tuple(r[1] for r in con.execute(f"PRAGMA table_info(\"{t}\")")) for t in tables}


def check_layout(con, path: Path, version: int) -> None:
    """Refuse (:class:`~cevm.store.failures.StoreDamagedError`, exit 4) a store whose
    tables or columns are not all those of its ``version`` (:func:`expected_layout`),
    naming what is missing: before any query meets "no such table" (SQLite's
    OperationalError), and before a writer writes anything. Tables and columns of its
    own that a store has beyond them are left alone."""
    from cevm.store.failures import DAMAGED_HINT, StoreDamagedError

    problems = layout_problems(con, version)
    if problems:
        raise StoreDamagedError(f"{path}: the store is damaged: {'; '.join(problems[:6])}"
                                f"{'; ...' if len(problems) > 6 else ''}; {DAMAGED_HINT}")


def layout_problems(con, version: int) -> list[str]:
    """What :func:`check_layout` finds missing, one text each ('table trip_blobs is
    missing', 'table trips lacks column vehicle_id')."""
    if not 0 < version <= SCHEMA_VERSION:
        return []
    have = _layout(con)
    problems = []
    for table, columns in expected_layout(version).items():
        if table not in have:
            problems.append(f"table {table} is missing")
            continue
        lacking = [c for c in columns if c not in have[table]]
        if lacking:
            problems.append(f"table {table} lacks column{'s' if len(lacking) > 1 else ''} {', '.join(lacking)}")
    return problems


def check_schema(con, path: Path) -> int:
    """The store's schema checked as a whole before it is used: its version a number
    (:func:`stored_version`), not a newer cevm's (:func:`refuse_newer`), and its tables
    and columns all there (:func:`check_layout`). Returns the version."""
    version = stored_version(con, path)
    refuse_newer(version, path)
    check_layout(con, path, version)
    return version


def ensure_schema(store) -> int:
    """Bring the store on ``store`` (a :class:`~cevm.store.TripStore`: its ``con``,
    ``path`` and ``_write()``) to :data:`SCHEMA_VERSION`; returns the version it had (0
    for a new store).

    A store at this version is only read. Otherwise the missing migrations run in order
    inside one write transaction (all or none: a failure leaves the store at the version
    it had), and ``schema_version`` in ``meta`` is set. Refuses an SQLite database of
    something else, and a store written by a newer cevm (a version above this one's).
    """
    con = store.con
    version = check_schema(con, store.path)
    if version == SCHEMA_VERSION:
        return version
    with store._write():
        version = check_schema(con, store.path)  # another process may have migrated it
        for m in MIGRATIONS[version:]:
            for stmt in m.statements:
                con.execute(stmt)
        if version == 0:
            con.executemany(
                "INSERT INTO meta (key, value) VALUES (?, ?)",
                [("created_utc_s", repr(time.time())), ("cevm_version", __version__)],
            )
        if version < SCHEMA_VERSION:
            con.execute(
                "INSERT INTO meta (key, value) VALUES ('schema_version', ?) "
                "ON CONFLICT (key) DO UPDATE SET value = excluded.value",
                (str(SCHEMA_VERSION),),
            )
    return version


def refuse_newer(version: int, path: Path) -> None:
    if version > SCHEMA_VERSION:
        raise CevmError(
            f"{path}: store schema version {version} was written by a newer "
            f"cevm; this cevm {__version__} reads up to version {SCHEMA_VERSION}. "
            "Upgrade cevm or use another --store."
        )


# ------------------------------------------------------------ values in the columns


def upgrade_trip_vector(vector: bytes, profile: bytes, decode) -> bytes:
    """A vector blob in format 3: ``vector`` with the k_pos and traction_s of the cycle in
    ``profile`` (decoded by ``decode`` into time_s, speed_mps, elevation_m arrays); an
    undecodable pair is left as it was (``cevm store check`` names it)."""
    from cevm.store.codec import decode_vector

    try:
        vec = decode_vector(vector)  # bounded: a zip of version 1 by its declared sizes
        if vec.has_trip_sums:
            return vector
        p = decode(profile)
        return vec.with_trip_sums(p["time_s"], p["speed_mps"], p.get("elevation_m")).to_bytes()
    except Exception:  # damaged: kept as it is, found by the checks that read it
        return vector


def blob_crc32(blob: bytes | None) -> int | None:
    """The checksum stored with a blob: zlib's CRC-32 (unsigned); None for None."""
    return None if blob is None else zlib.crc32(blob)


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

