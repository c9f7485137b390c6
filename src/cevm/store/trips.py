"""The trip store's :class:`TripStore`: one SQLite file, no server. Where the file is:
:mod:`cevm.store.location`; how a trip's profile is packed: :mod:`cevm.store.codec`.

Tables (schema version :data:`SCHEMA_VERSION`)
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
                   the profile arrays (see :func:`cevm.store.codec.encode_profile`). Kept apart from
                   ``trips`` so that listing trips never reads the blobs.
    ``runs``       one row per ``cevm ingest`` run: start, end, host, pid, counts (JSON).

Idempotence and replacement
    A file is keyed on its resolved path. :meth:`TripStore.replace_file_trips` with the
    same path and sha256 as the stored ``'ok'`` version does nothing (unless ``force``);
    a new sha256 replaces *all* trips of that path in one transaction.
    :meth:`TripStore.record_failure` marks a file ``'failed'`` but keeps the trips of
    its last good version: a bad new version of a file is reported, and the data we had
    stays usable until a good version arrives.

Same content at another path (a moved or copied file)
    That is another file. Its trips whose ``trip_id`` is already stored (``trip_id``
    derives from vehicle, start time and content hash) are skipped and reported in
    :attr:`WriteResult.duplicates`, so every trip is stored once and stays attributed to
    the path that brought it first. After moving files, :meth:`TripStore.forget_file` on
    the old path and a forced re-ingest of the new path re-attribute them.

Concurrency and crashes
    WAL journal, a 60 s busy timeout and ``BEGIN IMMEDIATE`` for every write
    transaction: two ``cevm ingest`` processes serialise their writes file by file, and
    readers are never blocked. One file = one transaction, so a crash (even SIGKILL)
    mid-file leaves the store as it was before that file. Primary keys and UNIQUE
    constraints are the last line of defence against duplicates. WAL needs a local
    file system (not NFS/SMB), as SQLite documents.

Units: SI inside (s, m, m/s, kg, J; fuel in litres, ``_l``); :func:`format_trips` is the
edge that turns rows into what a person reads (ISO 8601 times, km, kWh).
"""

from __future__ import annotations

import json
import math
import os
import socket
import sqlite3
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from cevm import __version__
from cevm.core.trip import Measurement, Trip, TripRecord
from cevm.errors import CevmError
from cevm.store.codec import decode_profile, trip_profile_blob
from cevm.store.location import file_key, resolve_store_path
from cevm.units import J_PER_KWH

SCHEMA_VERSION = 1
"""Version of the table layout written by this code. A store with a higher version was
written by a newer cevm and is refused; lower versions would be migrated on open."""

BUSY_TIMEOUT_S = 60.0
"""How long a writer waits for another process's write transaction [s]. One file's
transaction lasts milliseconds to a second, so 60 s only runs out if a process hangs."""


_TRIP_COLUMNS: tuple[str, ...] = (
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
_TRIP_FLOAT_COLUMNS = (
    "start_utc_s",
    "duration_s",
    "distance_m",
    "dsm_coverage_pct",
    "gross_weight_kg",
    "measured_value",
    "measured_resolution",
    "measured_uncertainty",
)

_FILE_COLUMNS: tuple[str, ...] = (
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


def _checkpoint(stage: str) -> None:
    """Called between the statements of a write transaction; does nothing.

    Tests replace it to raise or to stall (and be killed) in mid-transaction.
    """


# ------------------------------------------------------------------------- value types


@dataclass(frozen=True)
class FileState:
    """What the store knows about one source file (a row of ``files``).

    ``sha256``/``size_bytes``/``mtime_s`` describe the version last seen, ``status`` is
    how its ingest ended, ``trips_sha256`` is the version whose ``n_trips`` trips are
    stored (it differs from ``sha256`` after a failed new version; None if none).
    """

    path: str
    sha256: str
    size_bytes: int | None
    mtime_s: float | None
    profile: str | None
    status: str
    error: str | None
    ingested_utc_s: float
    trips_sha256: str | None
    n_trips: int
    n_duplicates: int


@dataclass(frozen=True)
class WriteResult:
    """Outcome of :meth:`TripStore.replace_file_trips` for one file.

    ``unchanged``: the same version was already stored, nothing was written.
    ``inserted``: trips written. ``replaced``: trips of the previous version of this path
    that were deleted. ``duplicates``: ``(trip_id, path already holding it)`` for trips
    skipped because that trip_id was already stored (from another path, or twice in
    this file).
    """

    path: str
    unchanged: bool
    inserted: int
    replaced: int
    duplicates: tuple[tuple[str, str], ...] = ()

    @property
    def skipped_duplicates(self) -> int:
        return len(self.duplicates)


# ------------------------------------------------------------------------------ helpers


def _json_default(obj: object) -> object:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"{type(obj).__name__} is not JSON-serialisable")


def _real(x: float | None) -> float | None:
    """A float for SQLite, None for None/NaN (SQLite stores NaN as NULL anyway)."""
    if x is None:
        return None
    x = float(x)
    return None if math.isnan(x) else x


def _nan(x: float | None) -> float:
    return math.nan if x is None else float(x)


def _in_json(values: Iterable[str]) -> str:
    """A JSON array for ``IN (SELECT value FROM json_each(?))``: one parameter for any
    number of ids, so no limit on SQL variables."""
    return json.dumps([str(v) for v in values])


# -------------------------------------------------------------------------------- store


class TripStore:
    """A connection to the trip store (see the module docstring for the layout).

    ``TripStore(path)`` or ``TripStore.open(path_or_None)`` opens (and creates, with its
    parent directories) the store; use it as a context manager or call :meth:`close`.
    One instance per process/thread; many processes may open the same store at once.
    """

    def __init__(self, path: str | Path):
        self.path = Path(path).expanduser()
        self._con: sqlite3.Connection | None = None
        if self.path.is_dir():
            raise CevmError(f"{self.path}: is a directory, not a cevm store file")
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise CevmError(f"{self.path}: cannot create the store's directory: {exc}") from exc
        try:
            self._con = sqlite3.connect(
                str(self.path), timeout=BUSY_TIMEOUT_S, isolation_level=None
            )
            self._enable_wal()
            # NORMAL in WAL mode: a power cut may lose the last commits, never corrupts.
            self._con.execute("PRAGMA synchronous=NORMAL")
            self._con.execute("PRAGMA foreign_keys=ON")
            self._init_schema()
        except sqlite3.DatabaseError as exc:
            self.close()
            raise CevmError(f"{self.path}: not a usable cevm store: {exc}") from exc
        except BaseException:
            self.close()
            raise

    def _enable_wal(self) -> str:
        """Switch to the WAL journal (persistent in the file; a no-op once done).

        SQLite does not call the busy handler for this switch, so when several
        processes create a store at once it can fail with "database is locked": retry
        with growing sleeps (1 ms to 0.1 s) for up to :data:`BUSY_TIMEOUT_S`. Returns
        the journal mode in force (not 'wal' on file systems without shared memory).
        """
        deadline = time.monotonic() + BUSY_TIMEOUT_S
        delay_s = 0.001
        while True:
            try:
                return str(self.con.execute("PRAGMA journal_mode=WAL").fetchone()[0])
            except sqlite3.OperationalError as exc:
                msg = str(exc).lower()
                if ("locked" not in msg and "busy" not in msg) or time.monotonic() > deadline:
                    raise
                time.sleep(delay_s)
                delay_s = min(2.0 * delay_s, 0.1)

    @classmethod
    def open(cls, path: str | Path | None = None) -> TripStore:
        """Open the store at ``path``, or at :func:`default_store_path` if None."""
        return cls(resolve_store_path(path))

    def close(self) -> None:
        """Close the connection (idempotent)."""
        if self._con is not None:
            self._con.close()
            self._con = None

    def __enter__(self) -> TripStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ internals

    @property
    def con(self) -> sqlite3.Connection:
        if self._con is None:
            raise CevmError(f"{self.path}: store is closed")
        return self._con

    def _begin(self) -> None:
        self.con.execute("BEGIN IMMEDIATE")

    def _commit(self) -> None:
        self.con.execute("COMMIT")

    def _rollback(self) -> None:
        if self._con is not None and self._con.in_transaction:
            self._con.execute("ROLLBACK")

    def _init_schema(self) -> None:
        con = self.con
        self._begin()
        try:
            tables = {r[0] for r in con.execute("SELECT name FROM sqlite_master WHERE type='table'")}
            version = None
            if "meta" in tables:
                row = con.execute("SELECT value FROM meta WHERE key='schema_version'").fetchone()
                version = int(row[0]) if row else None
            elif tables - {"sqlite_sequence"}:
                raise CevmError(
                    f"{self.path}: an SQLite database of something else (tables "
                    f"{sorted(tables)[:5]}), not a cevm store; choose another --store"
                )
            if version is not None and version > SCHEMA_VERSION:
                raise CevmError(
                    f"{self.path}: store schema version {version} was written by a newer "
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
            self._commit()
        except BaseException:
            self._rollback()
            raise

    def _count_hint(self) -> str:
        n = self.count_trips()
        return f"the store {self.path} holds {n} trip{'s' if n != 1 else ''}; `cevm trips` lists them"

    # ----------------------------------------------------------------------- files

    def file_state(self, path: str | Path) -> FileState | None:
        """The stored state of a source file, or None if the store never saw it."""
        row = self.con.execute(
            f"SELECT {', '.join(_FILE_COLUMNS)} FROM files WHERE path = ?", (file_key(path),)
        ).fetchone()
        return None if row is None else FileState(*row)

    def needs_ingest(self, path: str | Path, sha256: str, *, retry_failed: bool = True) -> bool:
        """Whether the file with content ``sha256`` must be (re-)ingested.

        False only if this path is stored with this sha256 and status ``'ok'``, or (with
        ``retry_failed=False``) with this sha256 and status ``'failed'``. Default
        ``retry_failed=True``: a file that failed is tried again on every run, since the
        cause may be the configuration or cevm rather than the file, and the failure
        stays visible in every run's summary.
        """
        state = self.file_state(path)
        if state is None or state.sha256 != sha256:
            return True
        return state.status == "failed" and retry_failed

    def list_files(self, status: str | None = None) -> pd.DataFrame:
        """All known source files (columns of :class:`FileState`), optionally only those
        with ``status`` ``'ok'`` or ``'failed'``, ordered by path."""
        sql = f"SELECT {', '.join(_FILE_COLUMNS)} FROM files"
        args: tuple = ()
        if status is not None:
            sql += " WHERE status = ?"
            args = (status,)
        rows = self.con.execute(sql + " ORDER BY path", args).fetchall()
        return pd.DataFrame.from_records(rows, columns=list(_FILE_COLUMNS))

    def replace_file_trips(
        self,
        path: str | Path,
        trips: Sequence[Trip | TripRecord],
        vectors: Sequence[bytes],
        *,
        sha256: str,
        size_bytes: int | None,
        mtime_s: float | None,
        profile: str | None,
        force: bool = False,
        profile_blobs: Sequence[bytes] | None = None,
    ) -> WriteResult:
        """Store the trips of one source file, replacing all its earlier trips, in one
        transaction.

        Parameters
        ----------
        path : the source file; keyed on its resolved absolute path (:func:`file_key`),
            which is also stored as each trip's ``source_file``.
        trips : the file's trips (or their :class:`~cevm.core.trip.TripRecord`, with
            ``profile_blobs``); every ``trip.source_sha256`` must equal ``sha256``.
        vectors : the drive-cycle vector bytes of each trip, same order (opaque here).
        sha256 : hex sha256 of the file's content.
        size_bytes, mtime_s : file size [bytes] and modification time [s since epoch],
            kept so a caller can skip hashing unchanged files.
        profile : name of the logger profile used.
        force : default False; True rewrites even if this version is already stored
            (e.g. after a DSM or cevm update).
        profile_blobs : each trip's :func:`trip_profile_blob`, same order, if made
            already (by a worker); default None: made here.

        Returns a :class:`WriteResult`. If the same path and sha256 are already stored
        with status ``'ok'`` (checked inside the write lock, so two processes racing on
        one file write it once), nothing is written and ``unchanged`` is True. Trips
        whose trip_id is already stored from another path are skipped and listed in
        ``duplicates``. Any exception rolls the whole file back.
        """
        key = file_key(path)
        if len(trips) != len(vectors):
            raise ValueError(f"{len(trips)} trips but {len(vectors)} vectors for {key}")
        if profile_blobs is None:
            if not all(isinstance(t, Trip) for t in trips):
                raise ValueError(f"trip records without arrays need their profile_blobs ({key})")
            profile_blobs = [trip_profile_blob(t) for t in trips]
        elif len(profile_blobs) != len(trips):
            raise ValueError(f"{len(trips)} trips but {len(profile_blobs)} profiles for {key}")
        for t in trips:
            if t.source_sha256 != sha256:
                raise ValueError(
                    f"trip {t.trip_id} has source_sha256 {t.source_sha256[:12]}..., "
                    f"file {key} has {sha256[:12]}..."
                )
        indices = [int(t.trip_index) for t in trips]
        if len(set(indices)) != len(indices):
            raise ValueError(f"repeated trip_index in the trips of {key}")

        # Everything that costs CPU happens before the write lock is taken.
        trip_rows, blob_rows, ids = [], [], []
        for t, vec, prof in zip(trips, vectors, profile_blobs):
            trip_rows.append(self._trip_row(t, key))
            blob_rows.append((t.trip_id, sqlite3.Binary(bytes(vec)), prof))
            ids.append(t.trip_id)

        con = self.con
        self._begin()
        try:
            state = con.execute(
                "SELECT sha256, status FROM files WHERE path = ?", (key,)
            ).fetchone()
            if not force and state is not None and state == (sha256, "ok"):
                self._commit()
                return WriteResult(key, unchanged=True, inserted=0, replaced=0)
            _checkpoint("begun")
            (n_old,) = con.execute(
                "SELECT COUNT(*) FROM trips WHERE source_file = ?", (key,)
            ).fetchone()
            con.execute(
                "DELETE FROM trip_blobs WHERE trip_id IN "
                "(SELECT trip_id FROM trips WHERE source_file = ?)",
                (key,),
            )
            con.execute("DELETE FROM trips WHERE source_file = ?", (key,))
            _checkpoint("deleted")

            taken = dict(
                con.execute(
                    "SELECT trip_id, source_file FROM trips "
                    "WHERE trip_id IN (SELECT value FROM json_each(?))",
                    (_in_json(ids),),
                ).fetchall()
            )
            keep, duplicates = [], []
            for i, tid in enumerate(ids):
                if tid in taken:
                    duplicates.append((tid, taken[tid]))
                else:
                    taken[tid] = key
                    keep.append(i)

            con.execute(
                f"""INSERT INTO files ({', '.join(_FILE_COLUMNS)})
                    VALUES ({', '.join('?' * len(_FILE_COLUMNS))})
                    ON CONFLICT (path) DO UPDATE SET
                        sha256 = excluded.sha256, size_bytes = excluded.size_bytes,
                        mtime_s = excluded.mtime_s, profile = excluded.profile,
                        status = excluded.status, error = excluded.error,
                        ingested_utc_s = excluded.ingested_utc_s,
                        trips_sha256 = excluded.trips_sha256, n_trips = excluded.n_trips,
                        n_duplicates = excluded.n_duplicates""",
                (
                    key,
                    sha256,
                    None if size_bytes is None else int(size_bytes),
                    _real(mtime_s),
                    profile,
                    "ok",
                    None,
                    time.time(),
                    sha256,
                    len(keep),
                    len(duplicates),
                ),
            )
            con.executemany(
                f"INSERT INTO trips ({', '.join(_TRIP_COLUMNS)}) "
                f"VALUES ({', '.join('?' * len(_TRIP_COLUMNS))})",
                [trip_rows[i] for i in keep],
            )
            _checkpoint("trips_inserted")
            con.executemany(
                "INSERT INTO trip_blobs (trip_id, vector, profile) VALUES (?, ?, ?)",
                [blob_rows[i] for i in keep],
            )
            _checkpoint("blobs_inserted")
            self._commit()
        except BaseException:
            self._rollback()
            raise
        return WriteResult(
            key, unchanged=False, inserted=len(keep), replaced=n_old, duplicates=tuple(duplicates)
        )

    @staticmethod
    def _trip_row(t: Trip | TripRecord, key: str) -> tuple:
        m = t.measured
        return (
            t.trip_id,
            str(t.vehicle_id),
            key,
            t.source_sha256,
            int(t.trip_index),
            float(t.start_utc_s),
            t.duration_s,
            t.length_m,
            int(t.n_samples),
            str(t.elevation_source),
            _real(t.dsm_coverage_pct),
            _real(t.gross_weight_kg),
            None if m is None else m.kind,
            None if m is None else _real(m.value),
            None if m is None else m.source,
            None if m is None else _real(m.resolution),
            None if m is None else _real(m.uncertainty),
            json.dumps(t.quality, default=_json_default, sort_keys=True),
        )

    def record_failure(
        self,
        path: str | Path,
        error: str,
        *,
        sha256: str,
        size_bytes: int | None = None,
        mtime_s: float | None = None,
        profile: str | None = None,
    ) -> None:
        """Mark a source file as failed with ``error`` (one line for the operator).

        The trips of the file's last good version, if any, are kept (and its
        ``trips_sha256``/``n_trips`` with them): a broken new version of a file is
        reported, the data we had stays usable until a good version is ingested.
        """
        self._begin()
        try:
            self.con.execute(
                """INSERT INTO files (path, sha256, size_bytes, mtime_s, profile, status,
                                      error, ingested_utc_s, trips_sha256, n_trips)
                   VALUES (?, ?, ?, ?, ?, 'failed', ?, ?, NULL, 0)
                   ON CONFLICT (path) DO UPDATE SET
                       sha256 = excluded.sha256, size_bytes = excluded.size_bytes,
                       mtime_s = excluded.mtime_s, profile = excluded.profile,
                       status = 'failed', error = excluded.error,
                       ingested_utc_s = excluded.ingested_utc_s""",
                (
                    file_key(path),
                    sha256,
                    None if size_bytes is None else int(size_bytes),
                    _real(mtime_s),
                    profile,
                    str(error),
                    time.time(),
                ),
            )
            self._commit()
        except BaseException:
            self._rollback()
            raise

    def forget_file(self, path: str | Path) -> int:
        """Delete a source file's row and all its trips (one transaction); returns the
        number of trips deleted, 0 for an unknown path."""
        key = file_key(path)
        con = self.con
        self._begin()
        try:
            (n,) = con.execute("SELECT COUNT(*) FROM trips WHERE source_file = ?", (key,)).fetchone()
            con.execute(
                "DELETE FROM trip_blobs WHERE trip_id IN "
                "(SELECT trip_id FROM trips WHERE source_file = ?)",
                (key,),
            )
            con.execute("DELETE FROM trips WHERE source_file = ?", (key,))
            con.execute("DELETE FROM files WHERE path = ?", (key,))
            self._commit()
        except BaseException:
            self._rollback()
            raise
        return int(n)

    # ----------------------------------------------------------------------- trips

    def count_trips(self, vehicle_id: str | None = None) -> int:
        """Number of stored trips, of one vehicle if ``vehicle_id`` is given."""
        if vehicle_id is None:
            return int(self.con.execute("SELECT COUNT(*) FROM trips").fetchone()[0])
        return int(
            self.con.execute(
                "SELECT COUNT(*) FROM trips WHERE vehicle_id = ?", (vehicle_id,)
            ).fetchone()[0]
        )

    def vehicle_ids(self) -> list[str]:
        """The ids of all vehicles with stored trips, sorted."""
        return [r[0] for r in self.con.execute("SELECT DISTINCT vehicle_id FROM trips ORDER BY 1")]

    def _check_vehicle(self, vehicle_id: str) -> None:
        if self.con.execute(
            "SELECT 1 FROM trips WHERE vehicle_id = ? LIMIT 1", (vehicle_id,)
        ).fetchone() is None:
            known = self.vehicle_ids()
            shown = ", ".join(known[:10]) + (", ..." if len(known) > 10 else "")
            raise CevmError(
                f"no trips of vehicle '{vehicle_id}' in the store {self.path}; "
                f"{len(known)} vehicle(s) known" + (f": {shown}" if known else "")
                + "; `cevm trips` lists them"
            )

    def _check_trip_ids(self, trip_ids: Sequence[str]) -> None:
        found = {
            r[0]
            for r in self.con.execute(
                "SELECT trip_id FROM trips WHERE trip_id IN (SELECT value FROM json_each(?))",
                (_in_json(trip_ids),),
            )
        }
        missing = [t for t in dict.fromkeys(trip_ids) if t not in found]
        if missing:
            shown = ", ".join(f"'{t}'" for t in missing[:5]) + (" ..." if len(missing) > 5 else "")
            raise CevmError(
                f"unknown trip id{'s' if len(missing) > 1 else ''} {shown}; {self._count_hint()}"
            )

    def _where(self, vehicle_id: str | None, trip_ids: Sequence[str] | None) -> tuple[str, list]:
        clauses, args = [], []
        if vehicle_id is not None:
            self._check_vehicle(vehicle_id)
            clauses.append("t.vehicle_id = ?")
            args.append(vehicle_id)
        if trip_ids is not None:
            trip_ids = [str(t) for t in trip_ids]
            self._check_trip_ids(trip_ids)
            clauses.append("t.trip_id IN (SELECT value FROM json_each(?))")
            args.append(_in_json(trip_ids))
        return (" WHERE " + " AND ".join(clauses) if clauses else ""), args

    def list_trips(
        self, vehicle_id: str | None = None, trip_ids: Sequence[str] | None = None
    ) -> pd.DataFrame:
        """Stored trips as a DataFrame in SI units, ordered by vehicle and start time.

        Columns: trip_id, vehicle_id, source_file, source_sha256, trip_index,
        start_utc_s [s since epoch], duration_s, distance_m, n_samples,
        elevation_source, dsm_coverage_pct, gross_weight_kg, measured_kind ('fuel_l' |
        'energy_j' | None), measured_value [l or J], measured_source,
        measured_resolution, measured_uncertainty, quality_json. Float columns hold NaN
        for missing values. An unknown ``vehicle_id`` or any unknown id in ``trip_ids``
        raises :class:`CevmError`. :func:`format_trips` makes the display table.
        """
        where, args = self._where(vehicle_id, trip_ids)
        cols = ", ".join(f"t.{c}" for c in _TRIP_COLUMNS)
        rows = self.con.execute(
            f"SELECT {cols} FROM trips t{where} ORDER BY t.vehicle_id, t.start_utc_s, t.trip_id",
            args,
        ).fetchall()
        df = pd.DataFrame.from_records(rows, columns=list(_TRIP_COLUMNS))
        for c in _TRIP_FLOAT_COLUMNS:
            df[c] = df[c].astype(np.float64)
        for c in ("trip_index", "n_samples"):
            df[c] = df[c].astype(np.int64)
        return df

    def _blob(self, trip_id: str, column: str) -> bytes:
        row = self.con.execute(
            f"SELECT {column} FROM trip_blobs WHERE trip_id = ?", (trip_id,)
        ).fetchone()
        if row is None:
            raise CevmError(f"unknown trip id '{trip_id}'; {self._count_hint()}")
        return bytes(row[0])

    def load_vector_bytes(self, trip_id: str) -> bytes:
        """The drive-cycle vector bytes stored with a trip, as given at ingest."""
        return self._blob(trip_id, "vector")

    def load_profile(self, trip_id: str) -> dict[str, np.ndarray]:
        """A trip's profile: float64 arrays keyed as :data:`PROFILE_DTYPES` (time_s,
        speed_mps, distance_m, elevation_m, lat_deg, lon_deg)."""
        return decode_profile(self._blob(trip_id, "profile"))

    def load_vectors(
        self, vehicle_id: str | None = None, trip_ids: Sequence[str] | None = None
    ) -> dict[str, bytes]:
        """Vector bytes of many trips in one query: ``{trip_id: bytes}`` ordered by
        vehicle and start time; all trips, or those of ``vehicle_id`` and/or
        ``trip_ids`` (unknown ones raise :class:`CevmError`)."""
        where, args = self._where(vehicle_id, trip_ids)
        rows = self.con.execute(
            "SELECT t.trip_id, b.vector FROM trips t JOIN trip_blobs b USING (trip_id)"
            f"{where} ORDER BY t.vehicle_id, t.start_utc_s, t.trip_id",
            args,
        )
        return {tid: bytes(vec) for tid, vec in rows}

    def load_trip(self, trip_id: str) -> Trip:
        """Rebuild a stored :class:`~cevm.core.trip.Trip` with its profile arrays (float64;
        speed and elevation rounded to float32 by storage; NaN scalars come back as NaN,
        a NaN gross weight as None). ``source_file`` is the stored resolved path."""
        cols = ", ".join(f"t.{c}" for c in _TRIP_COLUMNS)
        row = self.con.execute(  # one statement: scalars and profile of one version
            f"SELECT {cols}, b.profile FROM trips t JOIN trip_blobs b USING (trip_id) "
            "WHERE t.trip_id = ?",
            (trip_id,),
        ).fetchone()
        if row is None:
            raise CevmError(f"unknown trip id '{trip_id}'; {self._count_hint()}")
        r = dict(zip(_TRIP_COLUMNS, row[:-1]))
        prof = decode_profile(row[-1])
        measured = None
        if r["measured_kind"] is not None:
            measured = Measurement(
                kind=r["measured_kind"],
                value=_nan(r["measured_value"]),
                source=r["measured_source"],
                resolution=_nan(r["measured_resolution"]),
                uncertainty=_nan(r["measured_uncertainty"]),
            )
        return Trip(
            vehicle_id=r["vehicle_id"],
            source_file=r["source_file"],
            source_sha256=r["source_sha256"],
            trip_index=int(r["trip_index"]),
            start_utc_s=float(r["start_utc_s"]),
            elevation_source=r["elevation_source"],
            dsm_coverage_pct=_nan(r["dsm_coverage_pct"]),
            measured=measured,
            gross_weight_kg=r["gross_weight_kg"],
            quality=json.loads(r["quality_json"]),
            **prof,
        )

    # ------------------------------------------------------------------------ runs

    def start_run(self) -> int:
        """Record the start of an ingest run (now, this host and pid); returns its id.
        A run without an end in :meth:`list_runs` crashed or is still going."""
        self._begin()
        try:
            cur = self.con.execute(
                "INSERT INTO runs (started_utc_s, host, pid) VALUES (?, ?, ?)",
                (time.time(), socket.gethostname(), os.getpid()),
            )
            self._commit()
        except BaseException:
            self._rollback()
            raise
        return int(cur.lastrowid)

    def finish_run(self, run_id: int, counts: Mapping[str, int | float]) -> None:
        """Record the end (now) and the counts (e.g. files seen/ingested/unchanged/
        failed, trips inserted/replaced/duplicate) of run ``run_id``."""
        self._begin()
        try:
            self.con.execute(
                "UPDATE runs SET finished_utc_s = ?, counts_json = ? WHERE run_id = ?",
                (time.time(), json.dumps(dict(counts), default=_json_default, sort_keys=True), run_id),
            )
            self._commit()
        except BaseException:
            self._rollback()
            raise

    def list_runs(self, limit: int = 20) -> pd.DataFrame:
        """The last ``limit`` runs (default 20, a screenful), newest first: run_id,
        started_utc_s, finished_utc_s (NaN if unfinished), host, pid, counts (dict)."""
        rows = self.con.execute(
            "SELECT run_id, started_utc_s, finished_utc_s, host, pid, counts_json FROM runs "
            "ORDER BY run_id DESC LIMIT ?",
            (int(limit),),
        ).fetchall()
        df = pd.DataFrame.from_records(
            rows, columns=["run_id", "started_utc_s", "finished_utc_s", "host", "pid", "counts_json"]
        )
        df["finished_utc_s"] = df["finished_utc_s"].astype(np.float64)
        df["counts"] = [json.loads(c) if c else {} for c in df.pop("counts_json")]
        return df

    # ------------------------------------------------------------------------ misc

    def integrity_check(self) -> str:
        """SQLite's ``PRAGMA integrity_check``: ``'ok'`` or the problems found."""
        return "\n".join(r[0] for r in self.con.execute("PRAGMA integrity_check"))


# ------------------------------------------------------------------------------ display


def format_utc(t_s: np.ndarray | pd.Series | float) -> pd.Series | str:
    """ISO 8601 UTC strings with ``Z`` (rounded to the second) for seconds since the
    Unix epoch; a scalar gives a str."""
    scalar = np.ndim(t_s) == 0
    ts = pd.to_datetime(pd.Series(np.atleast_1d(np.asarray(t_s, dtype=np.float64))), unit="s", utc=True)
    out = ts.dt.round("s").dt.strftime("%Y-%m-%dT%H:%M:%SZ")
    return str(out.iloc[0]) if scalar else out


def format_trips(df: pd.DataFrame) -> pd.DataFrame:
    """The display table of :meth:`TripStore.list_trips` rows: trip_id, vehicle_id,
    start_utc (ISO 8601, ``Z``), duration_s, distance_km, measured_fuel_l,
    measured_energy_kwh (from joules, 1 kWh = 3.6e6 J), dsm_coverage_pct,
    elevation_source, source_file. Unmeasured values are NaN."""
    kind = df["measured_kind"]
    value = df["measured_value"].astype(np.float64)
    return pd.DataFrame(
        {
            "trip_id": df["trip_id"],
            "vehicle_id": df["vehicle_id"],
            "start_utc": format_utc(df["start_utc_s"]).to_numpy(),
            "duration_s": df["duration_s"].astype(np.float64),
            "distance_km": df["distance_m"].astype(np.float64) / 1000.0,
            "measured_fuel_l": value.where(kind == "fuel_l"),
            "measured_energy_kwh": value.where(kind == "energy_j") / J_PER_KWH,
            "dsm_coverage_pct": df["dsm_coverage_pct"].astype(np.float64),
            "elevation_source": df["elevation_source"],
            "source_file": df["source_file"],
        },
        index=df.index,
    )
