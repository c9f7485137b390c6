"""The store's schema versions: an old store is migrated on open (in one transaction, its
data intact), a newer one is refused, and the evidence columns of migration 2 round-trip."""

from __future__ import annotations

import dataclasses
import json
import math
import sqlite3
import zlib
from pathlib import Path

import numpy as np
import pytest

import cevm.store.schema as schema
from cevm.core.cycle import DriveCycle, cycle_vector
from cevm.core.trip import TRIP_EVIDENCE_FIELDS, Measurement, Trip
from cevm.errors import CevmError
from cevm.store import SCHEMA_VERSION, TripStore, encode_profile
from cevm.store.codec import encode_cycle_profile
from cevm.store.routes import load_route_legs

# The layout of schema version 1 as cevm 0.1 wrote it, verbatim (not taken from the code
# under test: this is what stores out there hold).
V1_DDL = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS files (
    path TEXT PRIMARY KEY, sha256 TEXT NOT NULL, size_bytes INTEGER, mtime_s REAL, profile TEXT,
    status TEXT NOT NULL CHECK (status IN ('ok', 'failed')), error TEXT, ingested_utc_s REAL NOT NULL,
    trips_sha256 TEXT, n_trips INTEGER NOT NULL DEFAULT 0, n_duplicates INTEGER NOT NULL DEFAULT 0);
CREATE TABLE IF NOT EXISTS trips (
    trip_id TEXT PRIMARY KEY, vehicle_id TEXT NOT NULL, source_file TEXT NOT NULL REFERENCES files(path),
    source_sha256 TEXT NOT NULL, trip_index INTEGER NOT NULL, start_utc_s REAL NOT NULL,
    duration_s REAL NOT NULL, distance_m REAL NOT NULL, n_samples INTEGER NOT NULL,
    elevation_source TEXT NOT NULL, dsm_coverage_pct REAL, gross_weight_kg REAL,
    measured_kind TEXT CHECK (measured_kind IN ('fuel_l', 'energy_j')), measured_value REAL,
    measured_source TEXT, measured_resolution REAL, measured_uncertainty REAL, quality_json TEXT NOT NULL,
    UNIQUE (source_file, trip_index));
CREATE INDEX IF NOT EXISTS trips_by_vehicle ON trips (vehicle_id, start_utc_s);
CREATE TABLE IF NOT EXISTS trip_blobs (
    trip_id TEXT PRIMARY KEY REFERENCES trips(trip_id), vector BLOB NOT NULL, profile BLOB NOT NULL);
CREATE TABLE IF NOT EXISTS runs (
    run_id INTEGER PRIMARY KEY AUTOINCREMENT, started_utc_s REAL NOT NULL, finished_utc_s REAL, host TEXT,
    pid INTEGER, counts_json TEXT);
"""

# The route tables as cevm 0.1's routes module made them on first use (routes_schema_version 1).
V1_ROUTES_DDL = """
CREATE TABLE IF NOT EXISTS routes (
    name TEXT PRIMARY KEY, created_utc_s REAL NOT NULL, n_legs INTEGER NOT NULL CHECK (n_legs > 0), note TEXT);
CREATE TABLE IF NOT EXISTS route_legs (
    route TEXT NOT NULL REFERENCES routes(name) ON DELETE CASCADE, position INTEGER NOT NULL,
    kind TEXT NOT NULL CHECK (kind IN ('trip', 'cycle')), ref TEXT NOT NULL, label TEXT NOT NULL, sha256 TEXT,
    vector BLOB, profile BLOB, PRIMARY KEY (route, position),
    CHECK ((kind = 'cycle') = (vector IS NOT NULL AND profile IS NOT NULL)));
INSERT INTO meta (key, value) VALUES ('routes_schema_version', '1');
"""

SHA = "ab" * 32
TRIP_ID = f"HGV-11:1700000000:{SHA[:8]}"


def as_version_2(vector: bytes) -> bytes:
    """A format-3 vector blob as cevm 0.1 wrote it (format 2: ``CEVMVEC2``, the 11
    scalars before k_pos and traction_s), from the layout documented in
    CycleVector.to_bytes."""
    assert vector[:8] == b"CEVMVEC3"
    return b"CEVMVEC2" + vector[8:12] + vector[12 : 12 + 8 * 11] + vector[12 + 8 * 13 :]


def v1_profile() -> dict[str, np.ndarray]:
    t = np.arange(0.0, 121.0)
    v = np.clip(np.minimum(t, 120.0 - t) * 0.5, 0.0, None)
    return {"time_s": t, "speed_mps": v, "distance_m": np.concatenate([[0.0], np.cumsum(v[1:])]),
            "elevation_m": np.linspace(100.0, 112.0, t.size), "lat_deg": np.full(t.size, 51.5),
            "lon_deg": np.full(t.size, -0.1)}


def make_v1_store(path: Path, with_route: bool = False) -> dict:
    """A store as cevm 0.1 made it: the version-1 DDL and one file, trip, blob and run
    (and, ``with_route``, the route tables and a route of the trip and a cycle)."""
    prof = v1_profile()
    fresh = cycle_vector(DriveCycle(prof["time_s"], prof["speed_mps"], prof["elevation_m"], name="t")).to_bytes()
    vector = as_version_2(fresh)
    con = sqlite3.connect(path)
    con.executescript(V1_DDL)
    with con:
        con.executemany("INSERT INTO meta VALUES (?, ?)",
                        [("schema_version", "1"), ("created_utc_s", "1700000000.0"), ("cevm_version", "0.1.0")])
        con.execute("INSERT INTO files VALUES ('/logs/a.csv', ?, 10, 1.6e9, 'srf', 'ok', NULL, 1.7e9, ?, 1, 0)",
                    (SHA, SHA))
        con.execute("INSERT INTO trips VALUES (?, 'HGV-11', '/logs/a.csv', ?, 0, 1700000000.0, 120.0, 1800.0, 121,"
                    " 'dsm', 98.5, 43240.0, 'fuel_l', 10.6, 'fms_total_fuel', 0.5, 0.3, ?)",
                    (TRIP_ID, SHA, json.dumps({"repairs": ["clock_jump"]})))
        con.execute("INSERT INTO trip_blobs VALUES (?, ?, ?)", (TRIP_ID, vector, encode_profile(prof)))
        con.execute("INSERT INTO runs (started_utc_s, finished_utc_s, host, pid, counts_json) "
                    "VALUES (1.7e9, 1.7e9 + 5, 'h', 7, '{\"files\": 1}')")
    made = {"vector": vector, "vector_v3": fresh, "profile": prof}
    if with_route:
        cyc = DriveCycle(np.arange(0.0, 61.0), np.full(61, 10.0), None, name="flat")
        made["cycle_vector_v3"] = cycle_vector(cyc).to_bytes()
        made["cycle_vector"] = as_version_2(made["cycle_vector_v3"])
        made["cycle_profile"] = encode_cycle_profile(cyc)
        con.executescript(V1_ROUTES_DDL)
        with con:
            con.execute("INSERT INTO routes VALUES ('R1', 1.7e9, 2, 'old')")
            con.execute("INSERT INTO route_legs VALUES ('R1', 0, 'trip', ?, ?, NULL, NULL, NULL)", (TRIP_ID, TRIP_ID))
            con.execute("INSERT INTO route_legs VALUES ('R1', 1, 'cycle', '/c/flat.csv', 'flat', 'ff', ?, ?)",
                        (made["cycle_vector"], made["cycle_profile"]))
    con.execute("PRAGMA journal_mode=WAL")
    con.close()
    return made


def stored_version(path: Path) -> int:
    con = sqlite3.connect(path)
    try:
        return int(con.execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchone()[0])
    finally:
        con.close()


def trip_columns(path: Path) -> list[str]:
    con = sqlite3.connect(path)
    try:
        return [r[1] for r in con.execute("PRAGMA table_info(trips)")]
    finally:
        con.close()


def test_a_version_1_store_is_migrated_with_its_data_intact(tmp_path):
    db = tmp_path / "old.sqlite"
    made = make_v1_store(db)
    assert stored_version(db) == 1 and "ambient_temp_c" not in trip_columns(db)
    with TripStore(db) as st:
        df = st.list_trips()
        assert df["trip_id"].tolist() == [TRIP_ID]
        row = df.iloc[0]
        assert (row["vehicle_id"], row["gross_weight_kg"], row["measured_value"]) == ("HGV-11", 43240.0, 10.6)
        assert (row["distance_m"], row["dsm_coverage_pct"], row["n_samples"]) == (1800.0, 98.5, 121)
        assert all(math.isnan(row[f]) for f in TRIP_EVIDENCE_FIELDS)  # not logged before version 2
        # migration 5 remade the format-2 vector in format 3 from the stored profile: the
        # same as a vector made from those samples today
        assert st.load_vector_bytes(TRIP_ID) == made["vector_v3"]
        trip = st.load_trip(TRIP_ID)
        assert trip.measured == Measurement("fuel_l", 10.6, "fms_total_fuel", 0.5, 0.3)
        assert trip.quality == {"repairs": ["clock_jump"]}
        assert all(getattr(trip, f) is None for f in TRIP_EVIDENCE_FIELDS)
        np.testing.assert_array_equal(trip.time_s, made["profile"]["time_s"])
        assert st.file_state("/logs/a.csv").n_trips == 1
        assert st.list_runs()["counts"].iloc[0] == {"files": 1}
        assert st.integrity_check() == "ok"
    assert stored_version(db) == SCHEMA_VERSION > 1
    assert set(TRIP_EVIDENCE_FIELDS) <= set(trip_columns(db))
    con = sqlite3.connect(db)  # created_utc_s and cevm_version still say who made it
    assert dict(con.execute("SELECT key, value FROM meta WHERE key != 'schema_version'")) == {
        "created_utc_s": "1700000000.0", "cevm_version": "0.1.0"}
    con.close()


def test_a_version_1_store_with_routes_gets_checksums_and_keeps_its_routes(tmp_path):
    db = tmp_path / "old.sqlite"
    made = make_v1_store(db, with_route=True)
    with TripStore(db) as st:
        legs = load_route_legs(st, "R1")
        assert [leg.info.kind for leg in legs] == ["trip", "cycle"]
        assert legs[1].vector.to_bytes() == made["cycle_vector_v3"]
        np.testing.assert_array_equal(legs[0].profile["time_s"], made["profile"]["time_s"])
    con = sqlite3.connect(db)
    crcs = con.execute("SELECT vector, vector_crc32, profile, profile_crc32 FROM trip_blobs").fetchall()
    legs = con.execute("SELECT kind, vector, vector_crc32, profile, profile_crc32 FROM route_legs").fetchall()
    keys = {r[0] for r in con.execute("SELECT key FROM meta")}
    con.close()
    assert [(zlib.crc32(v), zlib.crc32(p)) for v, _, p, _ in crcs] == [(vc, pc) for _, vc, _, pc in crcs]
    assert [(k, vc, pc) for k, _, vc, _, pc in legs] == [
        ("trip", None, None), ("cycle", zlib.crc32(made["cycle_vector_v3"]), zlib.crc32(made["cycle_profile"]))]
    assert "routes_schema_version" not in keys  # one schema version for the whole store


def test_a_new_store_has_every_column_the_code_writes(tmp_path):
    """Migrations are frozen; this fails when a field is added to the trips without a new
    migration that adds its column."""
    db = tmp_path / "new.sqlite"
    TripStore(db).close()
    assert stored_version(db) == SCHEMA_VERSION
    assert set(schema.TRIP_COLUMNS) <= set(trip_columns(db))
    assert set(TRIP_EVIDENCE_FIELDS) <= set(trip_columns(db))


def test_a_failing_migration_leaves_the_store_at_its_version(tmp_path, monkeypatch):
    db = tmp_path / "old.sqlite"
    make_v1_store(db)
    bad = schema.Migration(SCHEMA_VERSION + 1, "a broken one",
                           ("ALTER TABLE trips ADD COLUMN half_done REAL", "SELECT no_such_function()"))
    monkeypatch.setattr(schema, "MIGRATIONS", schema.MIGRATIONS + (bad,))
    monkeypatch.setattr(schema, "SCHEMA_VERSION", SCHEMA_VERSION + 1)
    with pytest.raises(CevmError, match="no such function: no_such_function"):
        TripStore(db)
    assert stored_version(db) == 1  # migrations 2.. and the broken one: all rolled back together
    cols = trip_columns(db)
    assert "half_done" not in cols and "ambient_temp_c" not in cols
    monkeypatch.undo()
    with TripStore(db) as st:  # and a good cevm still migrates it
        assert st.count_trips() == 1
    assert stored_version(db) == SCHEMA_VERSION


def test_a_store_of_a_newer_cevm_is_refused_untouched(tmp_path):
    db = tmp_path / "new.sqlite"
    make_v1_store(db)
    con = sqlite3.connect(db)
    with con:
        con.execute("UPDATE meta SET value = ? WHERE key = 'schema_version'", (str(SCHEMA_VERSION + 1),))
    con.close()
    before = db.read_bytes()
    with pytest.raises(CevmError, match=rf"schema version {SCHEMA_VERSION + 1} was written by a newer cevm"):
        TripStore(db)
    assert db.read_bytes() == before and "ambient_temp_c" not in trip_columns(db)


def test_trip_evidence_round_trips(tmp_path):
    prof = v1_profile()
    evidence = {"ambient_temp_c": -4.5, "ambient_temp_min_c": -9.0, "ambient_temp_max_c": 1.25,
                "standstill_s": 312.0, "standstill_power_w": None, "standstill_fuel_lps": 6.1e-4}
    assert set(evidence) == set(TRIP_EVIDENCE_FIELDS)
    trip = Trip(vehicle_id="HGV-11", source_file="/logs/a.csv", source_sha256=SHA, trip_index=0,
                start_utc_s=1.7e9, elevation_source="dsm", dsm_coverage_pct=100.0, measured=None,
                gross_weight_kg=None, **prof, **evidence)
    with TripStore(tmp_path / "s.sqlite") as st:
        st.replace_file_trips("/logs/a.csv", [trip], [b"vec"], sha256=SHA, size_bytes=1, mtime_s=0.0,
                              profile="srf")
        row = st.list_trips().iloc[0]
        back = st.load_trip(trip.trip_id)
        record = dataclasses.replace(trip.record(), source_sha256="cd" * 32, start_utc_s=1.8e9)
        res = st.replace_file_trips("/logs/b.csv", [record], [b"v"], sha256="cd" * 32, size_bytes=1,
                                    mtime_s=0.0, profile="srf", profile_blobs=[encode_profile(prof)])
        assert res.inserted == 1  # from a TripRecord (what ingest's workers send) too
        row_b = st.list_trips().iloc[1]
    for f, x in evidence.items():
        if x is None:
            assert math.isnan(row[f]) and getattr(back, f) is None and math.isnan(row_b[f])
        else:
            assert row[f] == x and getattr(back, f) == x and row_b[f] == x


def _record(vehicle: str, start_s: float, duration_s: float, sha: str, index: int = 0, soc: float | None = None):
    from cevm.core.trip import TripRecord

    return TripRecord(vehicle, "/logs/x.csv", sha, index, start_s, duration_s, 1000.0, 2, "flat", 0.0, None, None,
                      start_soc_pct=soc)


def _starts(st: TripStore, vehicle: str = "EB-1") -> list:
    df = st.list_trips(vehicle_id=vehicle)
    return [(float(s), None if math.isnan(g) else float(g), None if math.isnan(c) else float(c))
            for s, g, c in zip(df["start_utc_s"], df["standstill_before_s"], df["start_soc_pct"], strict=True)]


def test_migration_6_gives_stored_trips_their_standstill_before(tmp_path):
    """A store of version 1 with two trips of one vehicle: migration 6 adds the start
    columns, the time the vehicle stood between them (none before its first), and no
    state of charge (not known before the file is ingested again)."""
    db = tmp_path / "old.sqlite"
    make_v1_store(db)
    con = sqlite3.connect(db)
    with con:  # a second trip of HGV-11, 600 s after the first ends (1700000000 + 120 s)
        con.execute("INSERT INTO trips VALUES ('HGV-11:1700000720:ab', 'HGV-11', '/logs/a.csv', ?, 1, 1700000720.0, "
                    "60.0, 500.0, 61, 'dsm', 98.5, NULL, NULL, NULL, NULL, NULL, NULL, '{}')", (SHA,))
    con.close()
    with TripStore(db) as st:
        assert _starts(st, "HGV-11") == [(1700000000.0, None, None), (1700000720.0, 600.0, None)]
    assert {"start_soc_pct", "standstill_before_s"} <= set(trip_columns(db))


def test_standstill_before_stays_right_when_files_come_in_any_order_change_or_go(tmp_path):
    """The time a vehicle stood before each trip, by hand: trips at 1000-1100 (file a),
    1500-1600 and 2000-2050 (file b), 3000-3100 (file c). Ingested c, a, b; then b
    replaced by a version whose last trip ends later; then b forgotten; then an
    overlapping trip (another file, starting before the previous ends): no standstill."""
    sha = {k: k * 64 for k in "abcd"}
    with TripStore(tmp_path / "s.sqlite") as st:
        def put(name, trips):
            recs = [_record("EB-1", s, d, sha[name], i, soc) for i, (s, d, soc) in enumerate(trips)]
            st.replace_file_trips(f"/logs/{name}.csv", recs, [b"v"] * len(recs), sha256=sha[name], size_bytes=1,
                                  mtime_s=0.0, profile="srf", profile_blobs=[b"p"] * len(recs), force=True)

        put("c", [(3000.0, 100.0, 55.0)])
        put("a", [(1000.0, 100.0, 90.5)])
        assert _starts(st) == [(1000.0, None, 90.5), (3000.0, 1900.0, 55.0)]
        put("b", [(1500.0, 100.0, None), (2000.0, 50.0, 70.0)])
        assert _starts(st) == [(1000.0, None, 90.5), (1500.0, 400.0, None), (2000.0, 400.0, 70.0),
                               (3000.0, 950.0, 55.0)]
        sha["b"] = "e" * 64  # a changed file b: its second trip now ends at 2400
        put("b", [(1500.0, 100.0, None), (2000.0, 400.0, 70.0)])
        assert _starts(st)[-1] == (3000.0, 600.0, 55.0)
        st.forget_file("/logs/b.csv")
        assert _starts(st) == [(1000.0, None, 90.5), (3000.0, 1900.0, 55.0)]
        put("d", [(3050.0, 10.0, None)])  # starts before the trip at 3000 ends
        assert _starts(st)[-1] == (3050.0, None, None)
