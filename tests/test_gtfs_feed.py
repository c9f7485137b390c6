"""The GTFS reader, calendar, geometry and blocks (cevm.io.gtfs, cevm.core.timetable) on the
small synthetic feed of tests/data/gtfs/small (its README says what it holds), against hand
computations; malformed feeds refused with file, line and column; the real feeds of
../shared/gtfs where present."""

from __future__ import annotations

import math
import shutil
from datetime import date
from pathlib import Path

import numpy as np
import pytest
from tests.conftest import shared_or_skip

from cevm.core.timetable import geometry as geo
from cevm.core.timetable.blocks import DeadheadRule, block_legs, day_blocks, infer_blocks
from cevm.core.timetable.schedule import trip_geometry
from cevm.errors import CevmError, InputError
from cevm.io.gtfs import parse_dates, read_feed

SMALL = Path(__file__).parent / "data" / "gtfs" / "small"
A_WGS84 = 6378137.0


def equator_m(dlon_deg: float) -> float:
    """Along the equator the WGS84 geodesic is the equatorial radius times the longitude
    difference (radians): the hand computation of every distance of the small feed."""
    return A_WGS84 * math.radians(dlon_deg)


def hms(h: int, m: int, s: int = 0) -> float:
    return h * 3600.0 + m * 60.0 + s


@pytest.fixture(scope="module")
def monday():
    return read_feed(SMALL)


def test_default_date_is_the_first_busiest_weekday(monday):
    # WK runs Monday to Friday from 2026-01-05 (a Monday): 9 trips in trips.txt, the first
    # such weekday is the 5th
    assert monday.dates == (date(2026, 1, 5).toordinal(),)
    assert "2026-01-05 (Monday)" in monday.date_from and "(9 in trips.txt)" in monday.date_from
    assert monday.timezone == "Europe/Paris"


def test_trips_of_a_weekday_with_frequencies_expanded(monday):
    # T9 is Saturday's; F1 runs 06:00-07:00 every 1200 s: 06:00, 06:20, 06:40 (07:00 excluded)
    assert sorted(monday.trip_id.tolist()) == sorted(["T1", "T2", "T3", "T4", "T5", "T6", "T7", "T8", "F1@06:00:00",
                                                      "F1@06:20:00", "F1@06:40:00"])
    assert any("expanded into 3 departures" in n for n in monday.notes)
    i = monday.trip_id.tolist().index("F1@06:20:00")
    a = monday.bounds[i]
    assert monday.departure_s[a] == hms(6, 20) and monday.arrival_s[a + 1] == hms(6, 26)
    assert monday.block_id[i] == ""  # an expanded trip's block is inferred


def test_calendar_dates_exceptions():
    # Wednesday 2026-01-07: WK removed (exception 2), SA added (exception 1): T9 only
    tt = read_feed(SMALL, parse_dates(["2026-01-07"]))
    assert tt.trip_id.tolist() == ["T9"]
    # a range: Tuesday to Thursday, the Wednesday without WK
    tt = read_feed(SMALL, parse_dates(["2026-01-06:2026-01-08"]))
    i = tt.trip_id.tolist().index("T1")
    assert tt.runs[i].tolist() == [True, False, True]
    assert tt.runs[tt.trip_id.tolist().index("T9")].tolist() == [False, True, False]


def test_no_trip_on_a_date():
    with pytest.raises(CevmError, match="no trip runs on 2026-02-02"):
        read_feed(SMALL, parse_dates(["2026-02-02"]))


@pytest.mark.parametrize("spec", ["2026-13-01", "2026-01-05:2026-01-01", "yesterday"])
def test_bad_date_option(spec):
    with pytest.raises(CevmError, match="--date"):
        parse_dates([spec])


def test_times_after_midnight_and_untimed_stops(monday):
    gm = trip_geometry(monday)
    ids = monday.trip_id.tolist()
    _, arr, dep = gm.stops_of(monday, ids.index("T6"))
    assert arr[0] == hms(24, 10) and arr[-1] == hms(24, 16)
    # T2: C 08:20:00, B untimed, A 08:26:00; B halfway by distance: 08:23:00
    d, arr, dep = gm.stops_of(monday, ids.index("T2"))
    assert arr[1] == pytest.approx(hms(8, 23), abs=1e-6) and dep[1] == arr[1]


def test_stop_distances_by_km_and_by_projection(monday):
    gm = trip_geometry(monday)
    ids = monday.trip_id.tolist()
    expect = [0.0, equator_m(0.009), equator_m(0.018)]
    d, _, _ = gm.stops_of(monday, ids.index("T1"))
    assert d == pytest.approx(expect, abs=0.01)
    assert gm.placed[ids.index("T1")] == "shape_dist_traveled (km)"
    d, _, _ = gm.stops_of(monday, ids.index("T5"))  # no shape_dist_traveled: projected onto S1
    assert d == pytest.approx(expect, abs=0.01)
    assert gm.placed[ids.index("T5")] == "projected onto the shape"
    d, _, _ = gm.stops_of(monday, ids.index("T7"))  # no shape: the straight line C-D
    assert d == pytest.approx([0.0, equator_m(0.018)], abs=0.01)
    assert "straight lines" in gm.placed[ids.index("T7")]


@pytest.mark.parametrize("unit,factor", [("m", 1.0), ("km", 1000.0), ("ft", 0.3048), ("mi", 1609.344)])
def test_unit_detected(unit, factor):
    geodesic = 12_345.0
    assert geo.detect_unit(geodesic / factor * 1.03, geodesic) == (unit, factor)
    assert geo.detect_unit(geodesic / factor * 2.0, geodesic) is None  # no unit fits: projected instead


def test_resampled_shape_keeps_its_points_and_length():
    lat = np.zeros(3)
    lon = np.array([0.0, 0.0045, 0.018])
    s = geo.resample(lat, lon, step_m=10.0)
    assert s.length_m == pytest.approx(equator_m(0.018), abs=1e-3)
    assert np.all(np.diff(s.dist_m) <= 10.0 + 1e-9)
    assert np.isin(s.point_m, s.dist_m).all()


def test_projection_follows_a_loop_in_order():
    # a shape out along the equator and back: a stop passed twice is placed in order
    lon = np.array([0.0, 0.018, 0.0])
    s = geo.resample(np.zeros(3), lon)
    d = geo.project_in_order(s, np.zeros(3), np.array([0.009, 0.018, 0.009]))
    assert d == pytest.approx([equator_m(0.009), equator_m(0.018), equator_m(0.027)], abs=0.5)


def _day(tt, gm):
    first, last = gm.first_last(tt)
    s, e = gm.departure_s[first], gm.arrival_s[last]
    x = np.radians(tt.stop_lon) * A_WGS84
    y = np.radians(tt.stop_lat) * A_WGS84
    fs, ls = tt.stop[first], tt.stop[last]
    return s, e, fs, ls, (x[fs], y[fs]), (x[ls], y[ls])


def test_blocks_by_block_id_and_inferred(monday):
    gm = trip_geometry(monday)
    s, e, fs, ls, sxy, exy = _day(monday, gm)
    b = day_blocks(monday.trip_id, monday.block_id, s, e, fs, ls, sxy, exy, min_layover_s=300.0)
    ids = monday.trip_id
    got = {n: (src, [ids[i] for i in t]) for n, src, t in zip(b.names, b.source, b.trips, strict=True)}
    # T3 ends at C 09:06 and T4 leaves C 09:15 (9 min >= 5): one block; T5 leaves A: its own
    assert got == {"B1": ("feed", ["T1", "T2", "T6"]), "B2": ("feed", ["T7", "T8"]),
                   "inferred:T3": ("inferred", ["T3", "T4"]), "inferred:T5": ("inferred", ["T5"]),
                   "inferred:F1@06:00:00": ("inferred", ["F1@06:00:00"]),
                   "inferred:F1@06:20:00": ("inferred", ["F1@06:20:00"]),
                   "inferred:F1@06:40:00": ("inferred", ["F1@06:40:00"])}
    # with 10 min, T3's block (free at C from 09:06) is too late for T4 (09:15): T4 takes
    # the block of F1@06:40 (free at C from 06:46)
    b = day_blocks(ids, monday.block_id, s, e, fs, ls, sxy, exy, min_layover_s=600.0)
    k = b.names.index("inferred:F1@06:40:00")
    assert [ids[i] for i in b.trips[k]] == ["F1@06:40:00", "T4"]
    assert [ids[i] for i in b.trips[b.names.index("inferred:T3")]] == ["T3"]


def test_inference_takes_the_block_free_latest():
    # two blocks end at stop 0 (at 100 s and 200 s); a trip leaving stop 0 at 1000 s takes
    # the one that ended last (the least idle time)
    z = np.zeros(3)
    chains = infer_blocks(np.array([0.0, 50.0, 1000.0]), np.array([100.0, 200.0, 1100.0]), np.array([1, 2, 0]),
                          np.array([0, 0, 1]), (z, z), (z, z), min_layover_s=0.0, radius_m=0.0)
    assert chains == [[0], [1, 2]]


def test_deadhead_and_depot_runs(monday):
    gm = trip_geometry(monday)
    s, e, fs, ls, _, _ = _day(monday, gm)
    ids = monday.trip_id.tolist()
    t = np.array([ids.index("T7"), ids.index("T8")])
    ll_s = (monday.stop_lat[fs], monday.stop_lon[fs])
    ll_e = (monday.stop_lat[ls], monday.stop_lon[ls])
    rule = DeadheadRule(detour=1.3, speed_mps=30 / 3.6)
    legs = block_legs(t, s, e, gm.distance_m(monday), ll_s, ll_e, geo.geodesic_m, rule)
    # T7 ends at D (0.036), T8 leaves A (0): 0.036 degrees of the equator x 1.3 at 30 km/h
    road = equator_m(0.036) * 1.3
    assert legs.kind == ("trip", "deadhead", "trip")
    assert legs.distance_m[1] == pytest.approx(road, rel=1e-9)
    assert legs.end_s[1] - legs.start_s[1] == pytest.approx(road / (30 / 3.6), rel=1e-9)
    assert legs.start_s[1] == hms(10, 5)
    assert legs.late_s[1] == 0.0  # 625 s of the 25 min layover
    # a depot at B: pull-out B->C before T7, pull-in B->B is none (it ends at B)
    rule = DeadheadRule(depot=(0.0, 0.009))
    legs = block_legs(t, s, e, gm.distance_m(monday), ll_s, ll_e, geo.geodesic_m, rule)
    assert legs.kind == ("pull-out", "trip", "deadhead", "trip")
    assert legs.distance_m[0] == pytest.approx(equator_m(0.009) * 1.3, rel=1e-9)
    assert legs.end_s[0] == hms(10, 0)


# ------------------------------------------------------------------ malformed feeds


def _broken(tmp_path: Path, name: str, old: str, new: str) -> Path:
    feed = tmp_path / "feed"
    shutil.copytree(SMALL, feed)
    p = feed / name
    text = p.read_text()
    assert old in text
    p.write_text(text.replace(old, new, 1))
    return feed


@pytest.mark.parametrize("name,old,new,line,column,what", [
    ("stop_times.txt", "T1,08:03:00,08:03:30", "T1,08:6x:00,08:03:30", 3, "arrival_time", "not a time"),
    ("stop_times.txt", "T3,09:06:00,09:06:00,C,2", "T3,09:06:00,09:06:00,Q,2", 9, "stop_id", "not in stops.txt"),
    ("stop_times.txt", "T4,09:21:00,09:21:00,A,2", "T4,09:21:00,09:21:00,A,1", 11, "stop_sequence", "appears twice"),
    ("stop_times.txt", "T1,08:06:00,08:06:00,C,3,2.0037508", "T1,08:06:00,08:06:00,C,3,far", 4, "shape_dist_traveled",
     "not a number"),
    ("stop_times.txt", "T4,09:21:00,09:21:00", "T4,09:01:00,09:01:00", 11, "arrival_time", "goes back"),
    ("trips.txt", "R1,WK,T4,,S2", "R1,WK,T3,,S2", 5, "trip_id", "appears twice"),
    ("calendar.txt", "WK,1,1,1,1,1,0,0,20260105", "WK,1,1,1,1,1,0,0,20261305", 2, "start_date", "not a date"),
    ("calendar_dates.txt", "WK,20260107,2", "WK,20260107,3", 2, "exception_type", "whole number in 1..2"),
    ("shapes.txt", "S1,0.0,0.009,3", "S1,95.0,0.009,3", 4, "shape_pt_lat", "latitude"),
    ("stops.txt", "C,Stop C,0.0,0.018", "C,Stop C,0.0,east", 4, "stop_lon", "not a number"),
    ("agency.txt", "Europe/Paris", "Mars/Olympus", 2, "agency_timezone", "not a time zone"),
    ("frequencies.txt", "F1,06:00:00,07:00:00,1200", "F1,06:00:00,07:00:00,0", 2, "headway_secs", "whole number"),
])
def test_malformed_feed_names_file_line_column(tmp_path, name, old, new, line, column, what):
    feed = _broken(tmp_path, name, old, new)
    with pytest.raises(InputError) as info:
        read_feed(feed)
    exc = info.value
    assert str(exc.path).endswith(name) and exc.line == line and exc.column == column
    assert what in exc.message
    assert "\n" not in str(exc)


def test_wrong_field_count_and_missing_column(tmp_path):
    feed = _broken(tmp_path, "stop_times.txt", "T3,09:00:00,09:00:00,A,1,0.0", "T3,09:00:00,A,1,0.0")
    with pytest.raises(InputError) as info:
        read_feed(feed)
    assert info.value.line == 8 and "fields where the header has 6" in info.value.message
    feed = _broken(tmp_path / "b", "trips.txt", "route_id,service_id,trip_id", "route_id,service,trip_id")
    with pytest.raises(InputError, match="no column 'service_id'") as info:
        read_feed(feed)
    assert info.value.line == 1


def test_zip_feed_reads_as_the_folder(tmp_path):
    z = shutil.make_archive(str(tmp_path / "small"), "zip", SMALL)
    a, b = read_feed(SMALL), read_feed(z)
    assert a.trip_id.tolist() == b.trip_id.tolist()
    assert np.array_equal(a.arrival_s, b.arrival_s, equal_nan=True) and np.array_equal(a.dist, b.dist, equal_nan=True)


def test_not_a_feed(tmp_path):
    (tmp_path / "x.zip").write_bytes(b"not a zip")
    with pytest.raises(InputError, match="neither a folder nor a readable zip"):
        read_feed(tmp_path / "x.zip")
    with pytest.raises(InputError, match=r"has no agency\.txt"):
        read_feed(tmp_path)


# ------------------------------------------------------------------ real feeds (../shared/gtfs)


def test_ann_arbor_weekday_blocks():
    z = shared_or_skip("gtfs", "ann-arbor-umich-2022.zip")
    tt = read_feed(z, parse_dates(["2022-01-11:2022-01-13"]))  # Tuesday to Thursday
    assert tt.timezone == "America/Detroit"
    for day in range(3):  # the feed's README: 83 blocks on a Tuesday-Thursday, every trip with one
        blocks = set(tt.block_id[tt.runs[:, day]].tolist())
        assert len(blocks) == 83 and "" not in blocks
    gm = trip_geometry(tt)
    assert all(p.startswith("shape_dist_traveled") for p in gm.placed)
    # the feed's distances (metres here) agree with the geodesic along the shapes
    assert {s.unit[0] for s in gm.shapes.values() if s.unit is not None} == {"m"}


def test_trimet_extract_blocks():
    z = shared_or_skip("gtfs", "trimet-vermont-2018.zip")
    tt = read_feed(z, parse_dates(["2017-11-20:2018-06-01"]))
    assert tt.n == 78 and len(set(tt.block_id.tolist())) == 5
