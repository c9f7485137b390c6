"""Trip manifests and stored trip masses: a manifest read as a transport
management system exports it, its rows matched to stored trips or reported by line,
masses stored with their source, replaced, cleared, carried into a file's next version,
and the precedence of a trip's masses (:mod:`cevm.io.manifest`, :mod:`cevm.store.masses`)."""

from __future__ import annotations

import dataclasses
import time

import pytest

from cevm.errors import CevmError, InputError
from cevm.io import load_vehicle
from cevm.io.manifest import ManifestFormat, read_manifest
from cevm.store import TripStore
from cevm.store.integrity import store_info
from cevm.store.masses import AssignedMass, TripMass, assigned_masses, clear_masses, match_manifest, set_masses
from fleet_store import DIESEL, make_fleet, unlogged, write_manifest


@pytest.fixture
def fleet(tmp_path):
    return make_fleet(tmp_path)


# ---------------------------------------------------------------------- reading manifests


def test_a_manifest_is_read_as_exported(tmp_path):
    p = tmp_path / "m.csv"
    p.write_text("\ufeffVehicle ID,Trip,Start,End,Gross weight (kg),Payload_kg\n"
                 "HGV-11,,2019-05-14T06:00:00+02:00,2019-05-14T09:00:00Z,\"43,240\",\n"
                 "HGV-11,HGV-11:1557812349:3e6cc93b,,,,\"12,000.5\"\n"
                 "HGV-12,,2019-05-14 06:00,2019-05-14 09:00,30000,\n", encoding="utf-8")
    m = read_manifest(p, ManifestFormat(tz="+01:00"))
    assert m.columns == {"vehicle": "Vehicle ID", "trip": "Trip", "start": "Start", "end": "End",
                         "gross": "Gross weight (kg)", "payload": "Payload_kg"} and m.problems == ()
    a, b, c = m.rows
    assert (a.line, a.kind, a.mass_kg, a.start_utc_s, a.end_utc_s) == (2, "gross", 43240.0, 1557806400.0, 1557824400.0)
    assert (b.trip_id, b.kind, b.mass_kg, b.start_utc_s) == ("HGV-11:1557812349:3e6cc93b", "payload", 12000.5, None)
    assert c.start_utc_s == 1557810000.0  # 06:00 at +01:00 is 05:00 UTC


def test_manifest_times_need_a_zone_and_are_exact_across_dst(tmp_path):
    p = tmp_path / "m.csv"
    p.write_text("vehicle;start;end;payload_kg\nV;2024-03-31 00:30;2024-03-31 03:30;1000\n"
                 "V;2024-03-31 01:30;2024-03-31 04:00;1000\nV;2024-10-27 01:30;2024-10-27 04:00;1000\n")
    m = read_manifest(p)
    assert m.rows == () and [ln for ln, _ in m.problems] == [2, 3, 4]
    assert all("no time zone" in why and "--tz" in why for _, why in m.problems)
    m = read_manifest(p, ManifestFormat(tz="Europe/London"))
    assert [r.start_utc_s for r in m.rows] == [1711845000.0]  # 00:30 GMT; the end, 03:30, is BST
    assert m.rows[0].end_utc_s == 1711845000.0 + 2 * 3600
    assert "does not exist" in m.problems[0][1] and m.problems[0][0] == 3  # 01:30 is skipped that night
    assert "happens twice" in m.problems[1][1] and m.problems[1][0] == 4  # and happens twice in October


def test_a_bad_row_is_named_by_line_and_column_and_the_rest_is_read(tmp_path):
    p = tmp_path / "m.csv"
    p.write_text("trip_id,gross_kg\nA:1:x,43240\nB:1:x,43.24\nC:1:x,heavy\nD:1:x,\nE:1:x,2e9\n")
    m = read_manifest(p)
    assert [r.trip_id for r in m.rows] == ["A:1:x"]
    why = dict(m.problems)
    assert "not a plausible gross mass" in why[3] and "--mass-unit t" in why[3] and "'gross_kg'" in why[3]
    assert "not a number" in why[4] and "no mass" in why[5] and "not a plausible" in why[6]
    with pytest.raises(InputError, match="no mass column"):
        (tmp_path / "n.csv").write_text("trip_id,weight\nA:1:x,1\n")
        read_manifest(tmp_path / "n.csv")
    with pytest.raises(InputError, match="needs a trip id column, or vehicle, start and end"):
        (tmp_path / "o.csv").write_text("vehicle,gross_kg\nA,1000\n")
        read_manifest(tmp_path / "o.csv")
    with pytest.raises(InputError, match="no column 'Truck'"):
        read_manifest(p, ManifestFormat(vehicle_col="Truck"))


# ------------------------------------------------------------------- matching and storing


def test_manifest_rows_are_matched_by_window_midpoint_and_the_rest_reported(fleet, tmp_path):
    db, ids, hgv, starts = fleet
    m = read_manifest(write_manifest(tmp_path / "tms.csv", ids, starts), ManifestFormat(tz="Europe/London"))
    with TripStore(db) as st:
        match = match_manifest(st, m)
    assert {x.trip_id: x.mass_kg for x in match.masses} == {t: ids["hgv_mass_kg"][t] for t in unlogged(ids)}
    assert all(x.source == "manifest" and x.source_file == m.path for x in match.masses)
    assert [x.source_line for x in match.masses] == [2, 3, 4, 5]
    why = dict(match.problems)
    assert set(why) == {6, 7, 8}
    assert "no stored trip of 'HGV-77' has its midpoint" in why[6]
    assert "2 stored trips of 'HGV-77'" in why[7] and "give trip ids" in why[7]
    assert "no stored trips of vehicle 'XX-01'" in why[8]


def test_conflicting_rows_and_a_trip_of_another_vehicle_are_not_applied(fleet, tmp_path):
    db, ids, hgv, starts = fleet
    a, b = ids["HGV-77"][0], ids["HGV-77"][2]
    p = tmp_path / "m.csv"
    p.write_text(f"vehicle,trip_id,gross_kg\n,{a},30000\n,{a},31000\nEB-09,{b},30000\n,{b},30000\n,{b},30000\n")
    with TripStore(db) as st:
        match = match_manifest(st, read_manifest(p))
    assert [(x.trip_id, x.source_line) for x in match.masses] == [(b, 6)]  # the same value twice is one value
    why = dict(match.problems)
    assert "different masses by lines 2, 3" in why[2] and "different masses by lines 2, 3" in why[3]
    assert f"trip {b!r} is a trip of 'HGV-77', not of 'EB-09'" in why[4]


def test_masses_are_stored_with_their_source_replaced_and_cleared(fleet):
    db, ids, hgv, starts = fleet
    t = ids["HGV-77"][0]
    with TripStore(db) as st:
        t0 = time.time()
        assert set_masses(st, [AssignedMass(t, "gross", 31000.0, "manifest", "/m/a.csv", 7)]) == (1, 0)
        assert set_masses(st, [AssignedMass(t, "payload", 9000.0, "hand")]) == (0, 1)  # the later one replaces
        got = assigned_masses(st)[t]
        assert (got.kind, got.mass_kg, got.source, got.source_file, got.source_line) == ("payload", 9000.0, "hand",
                                                                                        None, None)
        assert got.set_utc_s >= t0 and got.describe() == "by hand"
        with pytest.raises(CevmError, match="unknown trip id 'nope'"):
            set_masses(st, [AssignedMass("nope", "gross", 1.0, "hand")])
        assert store_info(st)["trip_masses"] == 1
        assert clear_masses(st, [t, ids["HGV-77"][1]]) == 1 and assigned_masses(st) == {}


def test_a_mass_follows_its_trip_into_the_files_next_version(fleet, tmp_path):
    """A log file re-exported with a changed row: its trips get new ids (the content hash),
    and those that keep their vehicle and start keep their given masses."""
    db, ids, hgv, starts = fleet
    with TripStore(db) as st:
        old = st.list_trips(vehicle_id="HGV-77").iloc[:2]
        trips = [st.load_trip(t) for t in old["trip_id"]]
        set_masses(st, [AssignedMass(trips[0].trip_id, "gross", 33000.0, "hand")])
        path = trips[0].source_file
        vectors = [st.load_vector_bytes(t.trip_id) for t in trips]
        sha = "ee" * 32
        moved = [dataclasses.replace(trips[0], source_sha256=sha),
                 dataclasses.replace(trips[1], source_sha256=sha, start_utc_s=trips[1].start_utc_s + 5)]
        st.replace_file_trips(path, moved, vectors, sha256=sha, size_bytes=2, mtime_s=1.0, profile="test")
        masses = assigned_masses(st)
    assert set(masses) == {moved[0].trip_id} and masses[moved[0].trip_id].mass_kg == 33000.0
    assert moved[0].trip_id != trips[0].trip_id


def test_precedence_given_then_logged_then_the_vehicle_file():
    veh = load_vehicle(DIESEL)
    no_kerb = dataclasses.replace(veh, kerb_mass_kg=None)
    logged = TripMass("t", None, 43240.0)
    given = TripMass("t", AssignedMass("t", "gross", 41000.0, "manifest", "/x/tms.csv", 3), 43240.0)
    payload = TripMass("t", AssignedMass("t", "payload", 20000.0, "hand"), None)
    none = TripMass("t", None, None)
    assert (logged.gross_kg(veh), logged.origin) == (43240.0, "logged")
    assert (given.gross_kg(veh), given.origin, given.describe()) == (41000.0, "manifest", "manifest tms.csv:3")
    assert (payload.gross_kg(veh), payload.origin) == (18000.0 + 20000.0, "by hand payload")
    assert (none.gross_kg(veh), none.origin, none.known) == (veh.mass_kg, "vehicle file", False)
    with pytest.raises(CevmError, match="no kerb_mass_kg to add it to"):
        payload.gross_kg(no_kerb)
    assert "-5.2 %" in given.disagreement() and "manifest tms.csv:3" in given.disagreement()
    near = TripMass("t", AssignedMass("t", "gross", 41500.0, "manifest", "/x/tms.csv", 3), 43240.0)
    assert near.disagreement() is None  # -4.0 %: within 5 %
    assert payload.disagreement(veh) is None and TripMass("t", payload.assigned, 30000.0).disagreement(veh) is not None
    assert TripMass("t", payload.assigned, 30000.0).disagreement() is None  # no kerb mass to compare with
