"""Reading the trip store: source files, trips (scalars as DataFrames; vectors, profiles
and whole trips by id), runs, and SQLite's integrity check. Nothing here writes.

Every blob read is checked against the checksum stored with it (a blob without one, its
checksum NULL, is damaged too: every writer stores both in one statement, and migration 3
gave the older blobs theirs); a damaged one raises
:class:`~cevm.store.failures.DamagedTripError` naming the trip (and its log file, to
re-ingest), and the readers of many trips can skip such trips and say which
(``on_damaged``)."""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from cevm.core.cycle import CycleVector
from cevm.core.trip import TRIP_EVIDENCE_FIELDS, Measurement, MeasurementKind, Trip
from cevm.errors import CevmError
from cevm.lazy import pd
from cevm.store.codec import decode_profile, decode_vector
from cevm.store.failures import DAMAGED_HINT, DamagedTripError, StoreDamagedError
from cevm.store.location import file_key
from cevm.store.schema import FILE_COLUMNS, TRIP_COLUMNS, TRIP_FLOAT_COLUMNS, blob_crc32, in_json, nan_for_null

if TYPE_CHECKING:
    from cevm.store.failures import StoreConnection


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


def row_measurement(kind, value, source, resolution, uncertainty) -> Measurement | None:
    """The :class:`~cevm.core.trip.Measurement` of a :meth:`TripQueries.list_trips` row's
    measured_* columns; None when the trip has none."""
    if not isinstance(kind, str) or value is None or not np.isfinite(value):
        return None
    # the kinds the store writes (fuel_l, energy_j): the stored measured_kind as it is
    return Measurement(cast(MeasurementKind, kind), float(value), str(source), float(resolution), float(uncertainty))


class TripQueries:
    """The reads of :class:`~cevm.store.TripStore` (a mixin: it needs the store's ``con``
    and ``path``)."""

    if TYPE_CHECKING:  # what TripStore provides
        path: Path

        @property
        def con(self) -> StoreConnection: ...

    def _count_hint(self) -> str:
        n = self.count_trips()
        return f"the store {self.path} holds {n} trip{'s' if n != 1 else ''}; `cevm trips` lists them"

    # ----------------------------------------------------------------------- files

    def file_state(self, path: str | Path) -> FileState | None:
        """The stored state of a source file, or None if the store never saw it."""
        row = self.con.execute(
            f"SELECT {', '.join(FILE_COLUMNS)} FROM files WHERE path = ?", (file_key(path),)
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
        sql = f"SELECT {', '.join(FILE_COLUMNS)} FROM files"
        args: tuple = ()
        if status is not None:
            sql += " WHERE status = ?"
            args = (status,)
        rows = self.con.execute(sql + " ORDER BY path", args).fetchall()
        return pd.DataFrame.from_records(rows, columns=list(FILE_COLUMNS))

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
                (in_json(trip_ids),),
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
            args.append(in_json(trip_ids))
        return (" WHERE " + " AND ".join(clauses) if clauses else ""), args

    def list_trips(
        self, vehicle_id: str | None = None, trip_ids: Sequence[str] | None = None
    ) -> pd.DataFrame:
        """Stored trips as a DataFrame in SI units, ordered by vehicle and start time.

        Columns: trip_id, vehicle_id, source_file, source_sha256, trip_index,
        start_utc_s [s since epoch], duration_s, distance_m, n_samples,
        elevation_source, dsm_coverage_pct, gross_weight_kg, measured_kind ('fuel_l' |
        'energy_j' | None), measured_value [l or J], measured_source,
        measured_resolution, measured_uncertainty, quality_json, then the evidence of
        :data:`~cevm.core.trip.TRIP_EVIDENCE_FIELDS` (ambient_temp_c, ...,
        standstill_fuel_lps), then the trip's start (start_soc_pct [%], standstill_before_s
        [s] since the vehicle's previous trip: :data:`~cevm.store.schema.TRIP_START_COLUMNS`).
        Float columns hold NaN for missing values. An unknown ``vehicle_id`` or any unknown id in ``trip_ids``
        raises :class:`CevmError`. :func:`~cevm.store.format_trips` makes the display
        table.
        """
        where, args = self._where(vehicle_id, trip_ids)
        cols = ", ".join(f"t.{c}" for c in TRIP_COLUMNS)
        rows = self.con.execute(
            f"SELECT {cols} FROM trips t{where} ORDER BY t.vehicle_id, t.start_utc_s, t.trip_id",
            args,
        ).fetchall()
        df = pd.DataFrame.from_records(rows, columns=list(TRIP_COLUMNS))
        for c in TRIP_FLOAT_COLUMNS:
            df[c] = df[c].astype(np.float64)
        for c in ("trip_index", "n_samples"):
            df[c] = df[c].astype(np.int64)
        return df

    # ----------------------------------------------------------------------- blobs

    def _damaged(self, trip_id: str, part: str, problem: str) -> DamagedTripError:
        try:
            row = self.con.execute("SELECT source_file FROM trips WHERE trip_id = ?", (trip_id,)).fetchone()
        except StoreDamagedError:
            row = None
        return DamagedTripError(trip_id, part, problem, row[0] if row else None)

    def _checked(self, trip_id: str, part: str, blob: bytes | None, crc: int | None) -> bytes:
        """``blob`` if it matches its stored checksum ``crc``, else :class:`DamagedTripError`."""
        if blob is None:
            raise self._damaged(trip_id, part, "missing")
        if crc is None:
            raise self._damaged(trip_id, part, "its checksum is missing (NULL)")
        blob = bytes(blob)
        if blob_crc32(blob) != crc:
            raise self._damaged(trip_id, part, "checksum mismatch")
        return blob

    def _blob(self, trip_id: str, column: str) -> bytes:
        return self._blob_row(trip_id, column)[0]

    def _blob_row(self, trip_id: str, column: str) -> tuple[bytes, int | None]:
        """A trip's checked blob, and its trip's sample count (None if its trip row is gone)."""
        try:
            row = self.con.execute(
                f"SELECT b.{column}, b.{column}_crc32, t.n_samples FROM trip_blobs b LEFT JOIN trips t "
                "USING (trip_id) WHERE b.trip_id = ?", (trip_id,)
            ).fetchone()
        except StoreDamagedError as exc:  # the page holding it: name the trip
            raise self._damaged(trip_id, column, f"unreadable: {exc.__cause__ or exc}") from exc
        if row is None:
            if self.con.execute("SELECT 1 FROM trips WHERE trip_id = ?", (trip_id,)).fetchone() is not None:
                raise self._damaged(trip_id, column, "missing")
            raise CevmError(f"unknown trip id '{trip_id}'; {self._count_hint()}")
        return self._checked(trip_id, column, row[0], row[1]), row[2]

    def load_vector_bytes(self, trip_id: str) -> bytes:
        """The drive-cycle vector bytes stored with a trip, as given at ingest, checked
        against their checksum (:class:`DamagedTripError` if they fail it)."""
        return self._blob(trip_id, "vector")

    def load_profile(self, trip_id: str) -> dict[str, np.ndarray]:
        """A trip's profile: float64 arrays keyed as :data:`PROFILE_DTYPES` (time_s,
        speed_mps, distance_m, elevation_m, lat_deg, lon_deg). A blob that fails its
        checksum or does not decode raises :class:`DamagedTripError`."""
        return self._decoded_profile(trip_id, *self._blob_row(trip_id, "profile"))

    def _decoded_profile(self, trip_id: str, blob: bytes, n_samples: int | None) -> dict[str, np.ndarray]:
        """The profile ``blob`` decoded, no larger than its trip's ``n_samples`` says
        (:func:`~cevm.store.codec.decode_profile`: a header that says more is damage)."""
        try:
            return decode_profile(blob, n_samples)
        except Exception as exc:  # whatever a damaged blob makes the decoder raise
            raise self._damaged(trip_id, "profile", f"does not decode: {exc}") from None

    def load_vectors(
        self, vehicle_id: str | None = None, trip_ids: Sequence[str] | None = None,
        on_damaged: Callable[[DamagedTripError], None] | None = None,
    ) -> dict[str, bytes]:
        """Vector bytes of many trips in one query: ``{trip_id: bytes}`` ordered by
        vehicle and start time; all trips, or those of ``vehicle_id`` and/or
        ``trip_ids`` (unknown ones raise :class:`CevmError`), each checked against its
        checksum. A damaged one raises :class:`DamagedTripError`, or, with
        ``on_damaged``, is passed to it and left out (also when the database pages
        holding it cannot be read: the trips are then read one by one)."""
        where, args = self._where(vehicle_id, trip_ids)
        order = " ORDER BY t.vehicle_id, t.start_utc_s, t.trip_id"
        out: dict[str, bytes] = {}
        try:
            rows = self.con.execute(
                "SELECT t.trip_id, b.vector, b.vector_crc32 FROM trips t LEFT JOIN trip_blobs b USING (trip_id)"
                f"{where}{order}", args)
            for tid, vec, crc in rows:
                try:
                    out[tid] = self._checked(tid, "vector", vec, crc)
                except DamagedTripError as exc:
                    if on_damaged is None:
                        raise
                    on_damaged(exc)
        except StoreDamagedError:  # a damaged page: read them one by one, to name the trips on it
            out = {}
            for (tid,) in self.con.execute(f"SELECT t.trip_id FROM trips t{where}{order}", args).fetchall():
                try:
                    out[tid] = self._blob(tid, "vector")
                except DamagedTripError as exc:
                    if on_damaged is None:
                        raise
                    on_damaged(exc)
        return out

    def load_cycle_vectors(
        self, vehicle_id: str | None = None, trip_ids: Sequence[str] | None = None,
        on_damaged: Callable[[DamagedTripError], None] | None = None,
    ) -> dict[str, CycleVector]:
        """:meth:`load_vectors` decoded into :class:`~cevm.core.cycle.CycleVector`\\ s; a
        vector that does not decode is damaged like one that fails its checksum."""
        out: dict[str, CycleVector] = {}
        for tid, blob in self.load_vectors(vehicle_id, trip_ids, on_damaged).items():
            try:
                out[tid] = decode_vector(blob)
            except Exception as exc:  # whatever a damaged blob makes the decoder raise
                err = self._damaged(tid, "vector", f"does not decode: {exc}")
                if on_damaged is None:
                    raise err from None
                on_damaged(err)
        return out

    def damaged_profiles(self, trip_ids: Sequence[str]) -> list[DamagedTripError]:
        """The trips of ``trip_ids`` whose profile fails its checksum or cannot be read,
        found without keeping any profile in memory (for a reader that will load them
        one at a time later, and must skip the damaged ones now)."""
        found: list[DamagedTripError] = []
        try:
            ids = in_json(trip_ids)
            bad = {r[0] for r in self.con.execute(
                "SELECT trip_id FROM trip_blobs WHERE trip_id IN (SELECT value FROM json_each(?)) "
                "AND crc32(profile) IS NOT profile_crc32", (ids,))}
            no_crc = {r[0]: bool(r[1]) for r in self.con.execute(
                "SELECT trip_id, profile_crc32 IS NULL FROM trip_blobs WHERE trip_id IN (SELECT value FROM "
                "json_each(?))", (ids,))}
            present = set(no_crc)
            found = [self._damaged(tid, "profile", "missing" if tid not in present else "checksum mismatch"
                                   if no_crc.get(tid) is False else "its checksum is missing (NULL)")
                     for tid in dict.fromkeys(trip_ids) if tid in bad or tid not in present]
        except StoreDamagedError:
            found = []
            for tid in trip_ids:
                try:
                    self._blob(tid, "profile")
                except DamagedTripError as exc:
                    found.append(exc)
        return found

    def load_trip(self, trip_id: str) -> Trip:
        """Rebuild a stored :class:`~cevm.core.trip.Trip` with its profile arrays (float64;
        speed and elevation rounded to float32 by storage; NaN scalars come back as NaN,
        a NaN gross weight and missing evidence as None). ``source_file`` is the stored
        resolved path. A damaged profile raises :class:`DamagedTripError`."""
        cols = ", ".join(f"t.{c}" for c in TRIP_COLUMNS)
        row = self.con.execute(  # one statement: scalars and profile of one version
            f"SELECT {cols}, b.profile, b.profile_crc32 FROM trips t LEFT JOIN trip_blobs b USING (trip_id) "
            "WHERE t.trip_id = ?",
            (trip_id,),
        ).fetchone()
        if row is None:
            raise CevmError(f"unknown trip id '{trip_id}'; {self._count_hint()}")
        r = dict(zip(TRIP_COLUMNS, row[:-2], strict=True))
        prof: dict[str, Any] = self._decoded_profile(trip_id, self._checked(trip_id, "profile", row[-2], row[-1]),
                                                     r["n_samples"])
        measured = None
        if r["measured_kind"] is not None:
            measured = Measurement(
                kind=r["measured_kind"],
                value=nan_for_null(r["measured_value"]),
                source=r["measured_source"],
                resolution=nan_for_null(r["measured_resolution"]),
                uncertainty=nan_for_null(r["measured_uncertainty"]),
            )
        try:
            quality = json.loads(r["quality_json"])
        except (TypeError, ValueError) as exc:  # damaged text that is still UTF-8
            raise self._damaged(trip_id, "quality", f"not JSON: {exc}") from None
        return Trip(
            vehicle_id=r["vehicle_id"],
            source_file=r["source_file"],
            source_sha256=r["source_sha256"],
            trip_index=int(r["trip_index"]),
            start_utc_s=float(r["start_utc_s"]),
            elevation_source=r["elevation_source"],
            dsm_coverage_pct=nan_for_null(r["dsm_coverage_pct"]),
            measured=measured,
            gross_weight_kg=r["gross_weight_kg"],
            quality=quality,
            **{f: r[f] for f in TRIP_EVIDENCE_FIELDS},
            start_soc_pct=r["start_soc_pct"],
            **prof,
        )

    # ------------------------------------------------------------------------ runs

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

    def integrity_check(self, quick: bool = False) -> str:
        """SQLite's ``PRAGMA integrity_check`` (``quick``: ``quick_check``, which skips
        the indexes' agreement with their tables): ``'ok'`` or the problems found. A
        database too damaged to be checked raises :class:`StoreDamagedError`."""
        pragma = "quick_check" if quick else "integrity_check"
        return "\n".join(r[0] for r in self.con.execute(f"PRAGMA {pragma}"))

    def require_intact(self) -> None:
        """Raise :class:`StoreDamagedError` unless SQLite's quick check finds the database
        sound: before writing into a store (writing into a damaged database can spread
        the damage). It reads the whole file: 0.3 s for 530 MB here, from the page cache;
        once it passed, a second call on the same connection costs nothing (a writable
        :class:`~cevm.store.TripStore` runs it when it opens)."""
        if getattr(self, "_intact", False):
            return
        try:
            problems = self.integrity_check(quick=True)
        except StoreDamagedError as exc:  # too damaged for the check to run, or not a database
            raise StoreDamagedError(f"{exc}; nothing was written to it") from exc
        if problems != "ok":
            first = problems.splitlines()[0]
            raise StoreDamagedError(f"{self.path}: the store is damaged ({first}); nothing was written to it; "
                                    f"{DAMAGED_HINT}")
        self._intact = True
