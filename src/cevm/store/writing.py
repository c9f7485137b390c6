"""Writing the trip store: a source file's trips (:meth:`TripWriting.replace_file_trips`),
a file that failed (:meth:`~TripWriting.record_failure`), forgetting a file
(:meth:`~TripWriting.forget_file`), and the ``runs`` of ``cevm ingest``.

Idempotence and replacement
    A file is keyed on its resolved path. :meth:`TripWriting.replace_file_trips` with the
    same path and sha256 as the stored ``'ok'`` version does nothing (unless ``force``);
    a new sha256 replaces *all* trips of that path in one transaction.
    :meth:`TripWriting.record_failure` marks a file ``'failed'`` but keeps the trips of
    its last good version: a bad new version of a file is reported, and the data we had
    stays usable until a good version arrives.

A trip's given mass (:mod:`cevm.store.masses`) follows it into a file's new version when
the trip keeps its vehicle and start.

Same content at another path (a moved or copied file)
    That is another file. Its trips whose ``trip_id`` is already stored (``trip_id``
    derives from vehicle, start time and content hash) are skipped and reported in
    :attr:`WriteResult.duplicates`, so every trip is stored once and stays attributed to
    the path that brought it first. After moving files, :meth:`TripWriting.forget_file`
    on the old path and a forced re-ingest of the new path re-attribute them.

Every method is one write transaction (``BEGIN IMMEDIATE``): all of it or nothing.
"""

from __future__ import annotations

import json
import os
import socket
import time
from collections.abc import Iterable, Mapping, Sequence
from contextlib import AbstractContextManager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from cevm.core.trip import TRIP_EVIDENCE_FIELDS, Trip, TripRecord
from cevm.store.codec import trip_profile_blob
from cevm.store.location import file_key
from cevm.store.schema import (
    FILE_COLUMNS,
    STANDSTILL_BEFORE_SQL,
    TRIP_COLUMNS,
    blob_crc32,
    in_json,
    json_default,
    sql_real,
)

if TYPE_CHECKING:
    from cevm.store.failures import StoreConnection


@dataclass(frozen=True)
class WriteResult:
    """Outcome of :meth:`TripWriting.replace_file_trips` for one file.

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


def trip_row(t: Trip | TripRecord, key: str) -> tuple:
    """The ``trips`` row of a trip (columns :data:`cevm.store.schema.TRIP_COLUMNS`) whose
    source file is keyed ``key``."""
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
        sql_real(t.dsm_coverage_pct),
        sql_real(t.gross_weight_kg),
        None if m is None else m.kind,
        None if m is None else sql_real(m.value),
        None if m is None else m.source,
        None if m is None else sql_real(m.resolution),
        None if m is None else sql_real(m.uncertainty),
        json.dumps(t.quality, default=json_default, sort_keys=True),
        *(sql_real(getattr(t, f)) for f in TRIP_EVIDENCE_FIELDS),
        sql_real(getattr(t, "start_soc_pct", None)),
        None,  # standstill_before_s: made by update_standstill_before once the file's trips are in
    )


def update_standstill_before(con, vehicle_ids: Iterable[str]) -> None:
    """Each stored trip's ``standstill_before_s`` for the vehicles ``vehicle_ids``: the
    time from the end of the vehicle's previous trip (by start) to its start [s]; NULL
    for its first trip, or when the previous one ends after this one starts (an overlap:
    the previous trip is not known). Run in the transaction that changed their trips,
    so that the trip after a replaced or removed one is right too."""
    con.execute(STANDSTILL_BEFORE_SQL.format(vehicles="vehicle_id IN (SELECT value FROM json_each(?))"),
                (in_json(sorted(set(vehicle_ids))),))


def _carry_masses(con, old_ids: Sequence[str], new_ids: Sequence[str]) -> None:
    """Give the trips of a file's new version the masses of its old version's trips that
    had the same vehicle and start (the same trip, its file grown or corrected: only the
    content hash in its id differs). Masses of trips that are gone stay, keyed on their
    old id (:mod:`cevm.store.masses`)."""
    if not old_ids or not new_ids:
        return
    old_by_start = {tid.rsplit(":", 1)[0]: tid for tid in old_ids}
    moves = [(new, old_by_start[new.rsplit(":", 1)[0]]) for new in new_ids
             if old_by_start.get(new.rsplit(":", 1)[0], new) != new]
    if moves:
        taken = {r[0] for r in con.execute("SELECT trip_id FROM trip_masses WHERE trip_id IN "
                                           "(SELECT value FROM json_each(?))", (in_json([n for n, _ in moves]),))}
        con.executemany("UPDATE trip_masses SET trip_id = ? WHERE trip_id = ?",
                        [(new, old) for new, old in moves if new not in taken])


def _rows(key: str, trips: Sequence[Trip | TripRecord], vectors: Sequence[bytes], sha256: str,
          profile_blobs: Sequence[bytes] | None) -> tuple[list[tuple], list[tuple], list[str]]:
    """The ``trips`` and ``trip_blobs`` rows of a file's trips, and their ids, after
    checking that they belong together (everything that costs CPU, before the write
    lock is taken)."""
    if len(trips) != len(vectors):
        raise ValueError(f"{len(trips)} trips but {len(vectors)} vectors for {key}")
    if profile_blobs is None:
        if not all(isinstance(t, Trip) for t in trips):
            raise ValueError(f"trip records without arrays need their profile_blobs ({key})")
        profile_blobs = [trip_profile_blob(t) for t in trips if isinstance(t, Trip)]  # all of them (checked)
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
    trip_rows, blob_rows, ids = [], [], []
    for t, vec, prof in zip(trips, vectors, profile_blobs, strict=True):
        trip_rows.append(trip_row(t, key))
        vec, prof = bytes(vec), bytes(prof)
        blob_rows.append((t.trip_id, vec, prof, blob_crc32(vec), blob_crc32(prof)))
        ids.append(t.trip_id)
    return trip_rows, blob_rows, ids


def _delete_trips_of(con, key: str) -> list[tuple[str, str]]:
    """Delete the trips (and their blobs) of the file keyed ``key``; their
    ``(trip_id, vehicle_id)``."""
    old = [(r[0], r[1]) for r in con.execute("SELECT trip_id, vehicle_id FROM trips WHERE source_file = ?", (key,))]
    con.execute(
        "DELETE FROM trip_blobs WHERE trip_id IN "
        "(SELECT trip_id FROM trips WHERE source_file = ?)",
        (key,),
    )
    con.execute("DELETE FROM trips WHERE source_file = ?", (key,))
    return old


def _not_stored(con, key: str, ids: Sequence[str]) -> tuple[list[int], list[tuple[str, str]]]:
    """Which of a file's trips to insert (their positions in ``ids``), and the
    duplicates: ``(trip_id, path already holding it)`` for a trip_id stored from
    another path, or met earlier in this file."""
    taken = dict(
        con.execute(
            "SELECT trip_id, source_file FROM trips "
            "WHERE trip_id IN (SELECT value FROM json_each(?))",
            (in_json(ids),),
        ).fetchall()
    )
    keep, duplicates = [], []
    for i, tid in enumerate(ids):
        if tid in taken:
            duplicates.append((tid, taken[tid]))
        else:
            taken[tid] = key
            keep.append(i)
    return keep, duplicates


def _file_ok(con, key: str, sha256: str, size_bytes: int | None, mtime_s: float | None, profile: str | None, *,
             n_trips: int, n_duplicates: int) -> None:
    """The ``files`` row of a file stored ``'ok'`` at this version (inserted, or the
    path's row updated)."""
    con.execute(
        f"""INSERT INTO files ({', '.join(FILE_COLUMNS)})
            VALUES ({', '.join('?' * len(FILE_COLUMNS))})
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
            sql_real(mtime_s),
            profile,
            "ok",
            None,
            time.time(),
            sha256,
            n_trips,
            n_duplicates,
        ),
    )


class TripWriting:
    """The writes of :class:`~cevm.store.TripStore` (a mixin: it needs the store's
    ``con``, ``_write()`` transaction and ``_checkpoint(stage)`` hook)."""

    if TYPE_CHECKING:  # what TripStore provides
        @property
        def con(self) -> StoreConnection: ...

        def _write(self) -> AbstractContextManager[StoreConnection]: ...

        def _checkpoint(self, stage: str) -> None: ...

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
        path
            the source file; keyed on its resolved absolute path (:func:`file_key`),
            which is also stored as each trip's ``source_file``.
        trips
            the file's trips (or their :class:`~cevm.core.trip.TripRecord`, with
            ``profile_blobs``); every ``trip.source_sha256`` must equal ``sha256``.
        vectors
            the drive-cycle vector bytes of each trip, same order (opaque here).
        sha256
            hex sha256 of the file's content.
        size_bytes, mtime_s
            file size [bytes] and modification time [s since epoch],
            kept so a caller can skip hashing unchanged files.
        profile
            name of the logger profile used.
        force
            default False; True rewrites even if this version is already stored
            (e.g. after a DSM or cevm update).
        profile_blobs
            each trip's :func:`trip_profile_blob`, same order, if made
            already (by a worker); default None: made here.

        Returns
        -------
        WriteResult
            If the same path and sha256 are already stored with status ``'ok'``
            (checked inside the write lock, so two processes racing on one file write
            it once), nothing is written and ``unchanged`` is True. Trips whose trip_id
            is already stored from another path are skipped and listed in
            ``duplicates``. Any exception rolls the whole file back.
        """
        key = file_key(path)
        trip_rows, blob_rows, ids = _rows(key, trips, vectors, sha256, profile_blobs)
        con = self.con
        with self._write():
            state = con.execute(
                "SELECT sha256, status FROM files WHERE path = ?", (key,)
            ).fetchone()
            if not force and state is not None and state == (sha256, "ok"):
                return WriteResult(key, unchanged=True, inserted=0, replaced=0)
            self._checkpoint("begun")
            old = _delete_trips_of(con, key)
            old_ids = [r[0] for r in old]
            self._checkpoint("deleted")
            keep, duplicates = _not_stored(con, key, ids)
            _file_ok(con, key, sha256, size_bytes, mtime_s, profile, n_trips=len(keep), n_duplicates=len(duplicates))
            con.executemany(
                f"INSERT INTO trips ({', '.join(TRIP_COLUMNS)}) "
                f"VALUES ({', '.join('?' * len(TRIP_COLUMNS))})",
                [trip_rows[i] for i in keep],
            )
            self._checkpoint("trips_inserted")
            con.executemany(
                "INSERT INTO trip_blobs (trip_id, vector, profile, vector_crc32, profile_crc32) "
                "VALUES (?, ?, ?, ?, ?)",
                [blob_rows[i] for i in keep],
            )
            self._checkpoint("blobs_inserted")
            _carry_masses(con, old_ids, [ids[i] for i in keep])
            update_standstill_before(con, {r[1] for r in old} | {trip_rows[i][1] for i in keep})
        return WriteResult(
            key, unchanged=False, inserted=len(keep), replaced=len(old_ids), duplicates=tuple(duplicates)
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
        with self._write():
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
                    sql_real(mtime_s),
                    profile,
                    str(error),
                    time.time(),
                ),
            )

    def forget_file(self, path: str | Path) -> int:
        """Delete a source file's row and all its trips (one transaction); returns the
        number of trips deleted, 0 for an unknown path."""
        key = file_key(path)
        con = self.con
        with self._write():
            vehicles = {r[0] for r in con.execute("SELECT vehicle_id FROM trips WHERE source_file = ?", (key,))}
            (n,) = con.execute("SELECT COUNT(*) FROM trips WHERE source_file = ?", (key,)).fetchone()
            con.execute(
                "DELETE FROM trip_blobs WHERE trip_id IN "
                "(SELECT trip_id FROM trips WHERE source_file = ?)",
                (key,),
            )
            con.execute("DELETE FROM trips WHERE source_file = ?", (key,))
            con.execute("DELETE FROM files WHERE path = ?", (key,))
            update_standstill_before(con, vehicles)
        return int(n)

    # ------------------------------------------------------------------------ runs

    def start_run(self) -> int:
        """Record the start of an ingest run (now, this host and pid); returns its id.
        A run without an end in :meth:`~cevm.store.TripStore.list_runs` crashed or is
        still going."""
        with self._write():
            cur = self.con.execute(
                "INSERT INTO runs (started_utc_s, host, pid) VALUES (?, ?, ?)",
                (time.time(), socket.gethostname(), os.getpid()),
            )
        assert cur.lastrowid is not None  # set by the INSERT
        return int(cur.lastrowid)

    def finish_run(self, run_id: int, counts: Mapping[str, int | float | str]) -> None:
        """Record the end (now) and the counts (e.g. files seen/ingested/unchanged/
        failed, trips inserted/replaced/duplicate; ``stopped_by``: the error that ended
        it early) of run ``run_id``."""
        with self._write():
            self.con.execute(
                "UPDATE runs SET finished_utc_s = ?, counts_json = ? WHERE run_id = ?",
                (time.time(), json.dumps(dict(counts), default=json_default, sort_keys=True), run_id),
            )
