"""``cevm gtfs`` on the small synthetic feed (tests/data/gtfs/small): rows per block and
per trip against hand computations, the two agreeing with each other, the weather
interpolated at a trip's midpoint, the DSM along the shapes, the plot, a block stored as a
route, and one-line errors with exit 2."""

from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine
from typer.testing import CliRunner

from cevm.cli import app

SMALL = Path(__file__).parent / "data" / "gtfs" / "small"
runner = CliRunner()
A_WGS84 = 6378137.0


def equator_km(dlon_deg: float) -> float:
    return A_WGS84 * math.radians(dlon_deg) / 1e3


@pytest.fixture
def bus(root) -> str:
    return str(root / "configs" / "vehicles" / "electric-bus.toml")


def run(*args: str):
    res = runner.invoke(app, ["gtfs", *args])
    return res


def rows_of(text: str) -> list[dict]:
    return list(csv.DictReader(io.StringIO(text)))


@pytest.fixture
def blocks_and_trips(tmp_path, bus):
    b = tmp_path / "b.csv"
    t = tmp_path / "t.csv"
    assert run(str(SMALL), "-v", bus, "-f", "csv", "-o", str(b), "--draws", "500").exit_code == 0
    res = run(str(SMALL), "-v", bus, "-f", "csv", "-o", str(t), "--trips")
    assert res.exit_code == 0, res.output
    return rows_of(b.read_text()), rows_of(t.read_text())


def test_block_rows(blocks_and_trips):
    blocks, _ = blocks_and_trips
    by = {r["block_id"]: r for r in blocks}
    assert set(by) == {"B1", "B2", "inferred:T3", "inferred:T5", "inferred:F1@06:00:00", "inferred:F1@06:20:00",
                       "inferred:F1@06:40:00"}
    assert {r["date"] for r in blocks} == {"2026-01-05"}
    assert by["B1"]["block_from"] == "feed" and by["inferred:T3"]["block_from"] == "inferred"
    assert (by["B1"]["trips"], by["B2"]["trips"], by["inferred:T3"]["trips"]) == ("3", "2", "2")
    # B2: T7 C->D (0.018 deg), a deadhead D->A (0.036 deg x 1.3), T8 A->B (0.009 deg)
    assert by["B2"]["deadheads"] == "1"
    assert float(by["B2"]["deadhead_km"]) == pytest.approx(equator_km(0.036) * 1.3, abs=1e-5)
    assert float(by["B2"]["distance_km"]) == pytest.approx(equator_km(0.018 + 0.036 * 1.3 + 0.009), abs=1e-5)
    # B1: T1, T2, T6 each A<->C; T6 at 24:10 belongs to Monday's block, ends Tuesday 00:16 in Paris
    assert float(by["B1"]["distance_km"]) == pytest.approx(3 * equator_km(0.018), abs=1e-5)
    assert by["B1"]["end_time"] == "2026-01-06T00:16:00+01:00"
    assert by["B1"]["start_time"] == "2026-01-05T08:00:00+01:00"
    for r in blocks:
        e, lo, hi = float(r["energy_kwh"]), float(r["energy_kwh_low"]), float(r["energy_kwh_high"])
        assert 0 < lo < e < hi
        assert r["elevation_from"] == "flat: no --dsm" and r["driving_from"].startswith("class prior")
        assert r["completes"] == "true" and float(r["p_complete"]) > 0.99
        assert r["mass_from"].startswith("the vehicle file's mass_kg") and r["fuel_l"] == ""


def test_trip_rows_and_their_sum(blocks_and_trips):
    blocks, trips = blocks_and_trips
    by = {r["trip_id"]: r for r in trips}
    assert len(trips) == 11
    t1 = by["T1"]
    assert float(t1["distance_km"]) == pytest.approx(equator_km(0.018), abs=1e-5)
    assert (t1["duration_s"], t1["stops"], t1["block_id"], t1["route_id"]) == ("360", "3", "B1", "R1")
    assert t1["stops_from"] == "shape_dist_traveled (km)" and by["T5"]["stops_from"] == "projected onto the shape"
    assert by["F1@06:20:00"]["block_id"] == "inferred:F1@06:20:00"
    assert by["T6"]["start_time"] == "2026-01-06T00:10:00+01:00"
    # identical trips (same shape, same stops, same running times) have the same energy
    assert by["T3"]["energy_kwh"] == by["F1@06:00:00"]["energy_kwh"]
    # a block without empty running: its energy is its trips' (the synthesised means, the
    # duty carrying the same mean as the trip rows)
    b1 = next(r for r in blocks if r["block_id"] == "B1")
    total = sum(float(by[t]["energy_kwh"]) for t in ("T1", "T2", "T6"))
    assert float(b1["energy_kwh"]) == pytest.approx(total, rel=1e-9)
    for r in trips:
        assert float(r["energy_kwh_low"]) < float(r["energy_kwh"]) < float(r["energy_kwh_high"])
        assert r["cycle_from"].startswith("synthesised")


def test_json_and_table(bus):
    res = run(str(SMALL), "-v", bus, "-f", "json", "--trips")
    assert res.exit_code == 0, res.output
    objs = json.loads(res.stdout[res.stdout.index("["):res.stdout.rindex("]") + 1])
    assert len(objs) == 11 and list(objs[0])[:4] == ["trip_id", "route_id", "block_id", "date"]
    assert "fuel_l" not in objs[0]
    res = run(str(SMALL), "-v", bus)
    assert res.exit_code == 0 and "cevm gtfs: blocks" in res.stdout and "B2" in res.stdout


def test_weather_at_the_trips_midpoint(tmp_path, bus):
    w = tmp_path / "w.csv"
    # 0 degC at 08:00 and 6 degC at 09:00 (Paris): T1 runs 08:00-08:06, midpoint 08:03: 0.3 degC
    w.write_text("time,ambient_c\n2026-01-05T08:00:00,0\n2026-01-05T09:00:00+01:00,6\n"
                 "2026-01-06T02:00:00,6\n2026-01-05T05:00:00,0\n")
    out = tmp_path / "t.csv"
    res = run(str(SMALL), "-v", bus, "--weather", str(w), "--trips", "-f", "csv", "-o", str(out))
    assert res.exit_code == 0, res.output
    by = {r["trip_id"]: r for r in rows_of(out.read_text())}
    assert float(by["T1"]["ambient_c"]) == pytest.approx(0.3, abs=1e-9)
    assert by["T1"]["ambient_from"] == "weather file w.csv"
    # a weather file that does not cover the trips: refused
    w.write_text("time,ambient_c\n2025-01-05T08:00:00,0\n")
    res = run(str(SMALL), "-v", bus, "--weather", str(w))
    assert res.exit_code == 2 and "does not cover the trips" in res.output


def test_dsm_along_the_shapes(tmp_path, bus):
    # a DSM rising 5 m per 0.001 degree of longitude eastwards: A to C (0.018 deg) climbs 90 m
    dsm = tmp_path / "dsm.tif"
    lon = np.arange(-0.01, 0.05, 0.0001)
    data = np.tile(100.0 + 5000.0 * (lon + 0.00005), (40, 1)).astype(np.float32)
    grid = Affine(0.0001, 0.0, -0.01, 0.0, -0.0001, 0.002)
    with rasterio.open(dsm, "w", driver="GTiff", width=data.shape[1], height=data.shape[0], count=1,
                       dtype="float32", crs="EPSG:4326", transform=grid) as f:
        f.write(data, 1)
    out = tmp_path / "t.csv"
    res = run(str(SMALL), "-v", bus, "--dsm", str(dsm), "--trips", "-f", "csv", "-o", str(out))
    assert res.exit_code == 0, res.output
    by = {r["trip_id"]: r for r in rows_of(out.read_text())}
    assert float(by["T1"]["ascent_m"]) == pytest.approx(90.0, rel=0.1)  # eastwards: up
    assert float(by["T2"]["ascent_m"]) < 5.0  # westwards: down
    assert float(by["T1"]["energy_kwh"]) > float(by["T2"]["energy_kwh"])
    assert by["T1"]["elevation_from"].startswith("DSM")


def test_plot_and_store_route(tmp_path, bus):
    png = tmp_path / "soc.png"
    store = tmp_path / "s.sqlite"
    res = run(str(SMALL), "-v", bus, "--plot", str(png), "--store", str(store), "--store-route", "B2=b2-route")
    assert res.exit_code == 0, res.output
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    from cevm.store import TripStore
    from cevm.store.routes import list_routes, load_route_vector

    with TripStore.open(store, readonly=True) as st:
        (info,) = list_routes(st)
        assert info.name == "b2-route" and [leg.label for leg in info.legs] == ["T7", "deadhead-2", "T8"]
        vec = load_route_vector(st, "b2-route")
    # the route's distance is the block's (the synthesis keeps each leg's distance)
    assert vec.distance_m == pytest.approx(1e3 * equator_km(0.018 + 0.036 * 1.3 + 0.009), rel=1e-3)
    res = runner.invoke(app, ["feasibility", "-v", bus, "--route", "b2-route", "--store", str(store)])
    assert res.exit_code == 0, res.output


@pytest.mark.parametrize("args,what", [
    (["--ambient-c", "5", "--weather", "x.csv"], "--weather or --ambient-c"),
    (["--date", "2026-02-31"], "--date"),
    (["--depot", "91,0"], "--depot"),
    (["--store-route", "NOPE"], "no block 'NOPE'"),
])
def test_usage_errors(bus, args, what):
    res = run(str(SMALL), "-v", bus, *args)
    assert res.exit_code == 2 and what in res.output
    assert "Traceback" not in res.output


def test_malformed_feed_is_one_line_exit_2(tmp_path, bus):
    import shutil

    feed = tmp_path / "f"
    shutil.copytree(SMALL, feed)
    p = feed / "stop_times.txt"
    p.write_text(p.read_text().replace("T2,08:26:00", "T2,08:2x:00"))
    res = run(str(feed), "-v", bus)
    assert res.exit_code == 2
    err = [line for line in res.output.splitlines() if line.startswith("cevm: error")]
    assert err == [f"cevm: error: {p}:7: column 'arrival_time': '08:2x:00' is not a time H:MM:SS"]


def test_diesel_rows_in_litres_and_a_payload(tmp_path, root):
    hgv = str(root / "configs" / "vehicles" / "diesel-hgv.toml")
    out = tmp_path / "d.csv"
    res = run(str(SMALL), "-v", hgv, "--payload-kg", "2000", "-f", "csv", "-o", str(out))
    assert res.exit_code == 0, res.output
    rows = rows_of(out.read_text())
    from cevm.io import load_vehicle

    kerb = load_vehicle(hgv).kerb_mass_kg
    for r in rows:
        assert r["energy_kwh"] == "" and float(r["fuel_l_low"]) < float(r["fuel_l"]) < float(r["fuel_l_high"])
        assert float(r["mass_kg"]) == pytest.approx(kerb + 2000.0)
        assert "--payload-kg" in r["mass_from"] and r["soc_min_pct"] == "" and r["tank_min_pct"] != ""


def test_depot_pull_out_and_pull_in(tmp_path, bus):
    # a depot at B (0.009 deg): B1 (A..A..A..C) pulls out B->A and pulls in C->B, each
    # 0.009 deg of the equator x 1.3; B2 pulls out B->C and ends at B (no pull-in)
    out = tmp_path / "b.csv"
    res = run(str(SMALL), "-v", bus, "--depot", "0,0.009", "-f", "csv", "-o", str(out))
    assert res.exit_code == 0, res.output
    by = {r["block_id"]: r for r in rows_of(out.read_text())}
    leg = equator_km(0.009) * 1.3
    assert by["B1"]["deadheads"] == "2" and float(by["B1"]["deadhead_km"]) == pytest.approx(2 * leg, abs=1e-5)
    assert by["B2"]["deadheads"] == "2"  # pull-out and the D->A deadhead
    assert float(by["B2"]["deadhead_km"]) == pytest.approx(leg + equator_km(0.036) * 1.3, abs=1e-5)
    # the pull-out leaves before the first departure: 08:00 less 0.009 deg x 1.3 at 30 km/h
    # (156.3 s: 07:57:23.7, written to the second)
    early = leg * 1e3 / (30 / 3.6)
    assert early == pytest.approx(156.29, abs=0.01)
    assert by["B1"]["start_time"] == "2026-01-05T07:57:23+01:00"


def test_ann_arbor_weekday_blocks_through_the_command(tmp_path, bus):
    from tests.conftest import shared_or_skip

    z = shared_or_skip("gtfs", "ann-arbor-umich-2022.zip")
    out = tmp_path / "aa.csv"
    res = run(str(z), "-v", bus, "--date", "2022-01-11", "-f", "csv", "-o", str(out), "--draws", "200")
    assert res.exit_code == 0, res.output
    rows = rows_of(out.read_text())
    # the feed's README: 83 blocks, mean 17 trips and about 100 km each
    assert len(rows) == 83 and {r["block_from"] for r in rows} == {"feed"}
    assert 15 <= np.mean([float(r["trips"]) for r in rows]) <= 19
    assert 80 <= np.mean([float(r["distance_km"]) for r in rows]) <= 120
    assert sum(int(r["trips"]) for r in rows) == 1428
