"""A store that checks itself (``cevm store check``): SQLite's integrity check, then every
blob read back, checked against its checksum and decoded; and a summary of what a store
holds (``cevm store info``). Both only read."""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field

from cevm.errors import CevmError
from cevm.store.codec import decode_vector
from cevm.store.failures import StoreDamagedError
from cevm.store.routes import load_route_legs, route_names
from cevm.store.schema import SCHEMA_VERSION, TRIP_COLUMNS
from cevm.store.trips import TripStore


@dataclass(frozen=True)
class Problem:
    """One thing found damaged: ``kind`` ('database', 'trip', 'blob' or 'route'), the
    trip id or route name (``ident``; the table for 'database'), and what is wrong."""

    kind: str
    ident: str
    problem: str


@dataclass
class CheckReport:
    """What :func:`check_store` found: SQLite's verdict (``integrity``: 'ok' or its
    messages), how many trips and routes were read back, and the :class:`Problem`\\ s."""

    path: str
    integrity: str = "not run"
    trips_checked: int = 0
    routes_checked: int = 0
    problems: list[Problem] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return self.integrity == "ok" and not self.problems

    def as_dict(self) -> dict:
        return {"store": self.path, "ok": self.ok, "integrity": self.integrity, "trips_checked": self.trips_checked,
                "routes_checked": self.routes_checked,
                "problems": [{"kind": p.kind, "id": p.ident, "problem": p.problem} for p in self.problems]}


def check_store(store: TripStore, progress: Callable[[int, int], None] | None = None) -> CheckReport:
    """Check ``store``: ``PRAGMA integrity_check``; every trip's vector and profile read
    one by one (so that damaged pages cost only the trips on them), checked against
    their checksums and decoded, the profile's length against the trip's sample count;
    blobs without a trip; every route's legs (their own blobs, and trips that are gone or
    damaged). ``progress(done, total)`` is called as trips are read."""
    report = CheckReport(str(store.path))
    try:
        report.integrity = store.integrity_check()
    except StoreDamagedError as exc:
        report.integrity = f"could not run: {exc.__cause__ or exc}"
    if report.integrity != "ok":
        lines = [ln for ln in report.integrity.splitlines() if not ln.startswith("*** in database")]
        report.integrity = "\n".join(lines)
        report.problems += [Problem("database", "", line) for line in lines[:20]]
        if len(lines) > 20:
            report.problems.append(Problem("database", "", f"... and {len(lines) - 20} more from SQLite's check"))
    if store.layout_problems:  # tables or columns missing: the blobs cannot be read back
        report.problems += [Problem("database", "", text) for text in store.layout_problems]
        return report
    if store.schema_version < SCHEMA_VERSION:  # opened without migrating (it failed): SQLite's check only
        report.problems.append(Problem("database", "", f"schema version {store.schema_version} could not be migrated "
                                                       f"to {SCHEMA_VERSION}, so its blobs were not read back"))
        return report
    try:
        trips = store.con.execute("SELECT trip_id, n_samples FROM trips ORDER BY trip_id").fetchall()
    except StoreDamagedError as exc:
        report.problems.append(Problem("database", "trips", f"the trips cannot be listed: {exc.__cause__ or exc}"))
        trips = []
    for i, (tid, n_samples) in enumerate(trips):
        report.problems += _trip_problems(store, tid, n_samples)
        report.trips_checked += 1
        if progress is not None:
            progress(i + 1, len(trips))
    try:
        for (tid,) in store.con.execute(
                "SELECT trip_id FROM trip_blobs WHERE trip_id NOT IN (SELECT trip_id FROM trips)").fetchall():
            report.problems.append(Problem("blob", tid, "blobs of a trip that is not in the trips table"))
    except StoreDamagedError as exc:
        report.problems.append(Problem("database", "trip_blobs", f"cannot be listed: {exc.__cause__ or exc}"))
    try:
        names = route_names(store)
    except StoreDamagedError as exc:
        report.problems.append(Problem("database", "routes", f"the routes cannot be listed: {exc.__cause__ or exc}"))
        names = []
    for name in names:
        try:
            load_route_legs(store, name, profiles=True)
        except CevmError as exc:
            report.problems.append(Problem("route", name, str(exc)))
        report.routes_checked += 1
    return report


def _trip_problems(store: TripStore, trip_id: str, n_samples: int) -> list[Problem]:
    out = _row_problems(store, trip_id)
    try:
        decode_vector(store.load_vector_bytes(trip_id))  # a zip of format 1 bounded by its declared sizes
    except CevmError as exc:  # DamagedTripError (checksum, unreadable page) or a store error
        out.append(Problem("trip", trip_id, str(exc)))
    except Exception as exc:  # whatever a damaged vector makes the decoder raise
        out.append(Problem("trip", trip_id, f"vector does not decode: {exc}"))
    try:
        prof = store.load_profile(trip_id)
        if prof["time_s"].size != n_samples:
            out.append(Problem("trip", trip_id, f"profile has {prof['time_s'].size} samples, the trip {n_samples}"))
    except CevmError as exc:
        out.append(Problem("trip", trip_id, str(exc)))
    return out


def _row_problems(store: TripStore, trip_id: str) -> list[Problem]:
    """The trip's row read whole, as the commands that list trips read it: text that is
    not UTF-8 (damaged pages: ``cevm trips`` stopped on it) and a quality summary that is
    not JSON are damage."""
    try:
        row = store.con.execute(f"SELECT {', '.join(TRIP_COLUMNS)} FROM trips WHERE trip_id = ?", (trip_id,)).fetchone()
    except StoreDamagedError as exc:
        return [Problem("trip", trip_id, f"its row cannot be read: {exc.__cause__ or exc}")]
    try:
        json.loads(row[TRIP_COLUMNS.index("quality_json")])
    except (TypeError, ValueError) as exc:
        return [Problem("trip", trip_id, f"its quality summary is not JSON: {exc}")]
    return []


def _journal_mode(store: TripStore) -> str:
    """The journal the file was written with, from its header (byte 18: 2 for WAL): an
    immutable opening reports 'delete' whatever the file says."""
    with open(store.path, "rb") as f:
        header = f.read(20)
    return "wal" if len(header) == 20 and header[18] == 2 else "rollback journal"


def store_info(store: TripStore) -> dict:
    """What the store holds and how it was made: schema version, creation, counts of
    files (ok, failed), trips, vehicles and routes, masses given to trips (and to trips no
    longer stored: they come back with their trip), the last ingest run, the journal."""
    con = store.con
    meta = dict(con.execute("SELECT key, value FROM meta").fetchall())
    files = dict(con.execute("SELECT status, COUNT(*) FROM files GROUP BY status").fetchall())
    runs = store.list_runs(limit=1)
    last = None
    if len(runs):
        r = runs.iloc[0]
        last = {"run_id": int(r["run_id"]), "started_utc_s": float(r["started_utc_s"]),
                "finished_utc_s": None if r["finished_utc_s"] != r["finished_utc_s"] else float(r["finished_utc_s"]),
                "host": r["host"], "counts": r["counts"]}
    size = store.path.stat().st_size
    return {
        "store": str(store.path),
        "size_bytes": size,
        "schema_version": int(meta.get("schema_version", 0)),
        "created_utc_s": float(meta["created_utc_s"]) if "created_utc_s" in meta else None,
        "created_by": meta.get("cevm_version"),
        "journal_mode": _journal_mode(store),
        "opened": "immutable (read-only directory)" if store.immutable else ("read-only" if store.readonly
                                                                               else "read-write"),
        "files_ok": int(files.get("ok", 0)),
        "files_failed": int(files.get("failed", 0)),
        "trips": store.count_trips(),
        "vehicles": len(store.vehicle_ids()),
        "routes": len(route_names(store)),
        "trip_masses": int(con.execute("SELECT COUNT(*) FROM trip_masses").fetchone()[0]),
        "trip_masses_of_trips_gone": int(con.execute(
            "SELECT COUNT(*) FROM trip_masses WHERE trip_id NOT IN (SELECT trip_id FROM trips)").fetchone()[0]),
        "last_run": last,
    }
