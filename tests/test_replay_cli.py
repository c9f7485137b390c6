"""``cevm replay`` end to end on a small store: rows in CSV, JSON and the table, the same
duties as ``cevm predict``'s trips summed, charging at the depot only, the night shift as
one duty, the summary and the plot, a parallel run writing the bytes of a serial one, and
one clear message for each wrong input."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from cevm.cli import app
from replay_cases import make_replay_store

runner = CliRunner()
ROOT = Path(__file__).resolve().parents[1]
TRUCK = str(ROOT / "configs/vehicles/electric-truck.toml")
DIESEL = str(ROOT / "configs/vehicles/diesel-hgv.toml")


@pytest.fixture(scope="module")
def store(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("replay")
    make_replay_store(d / "s.sqlite", d / "logs")
    return d / "s.sqlite"


def replay(store: Path, *args: str):
    return runner.invoke(app, ["replay", "--store", str(store), "--vehicle-id", "TRK-1", "--vehicle-id", "TRK-2",
                               *args])


@pytest.mark.slow
def test_rows_in_csv_json_and_table_say_the_same(store):
    args = ["-v", TRUCK, "--battery-kwh", "40", "--charger-kw", "50"]
    res = replay(store, *args, "-f", "json")
    assert res.exit_code == 0, res.output
    rows = json.loads(res.stdout)
    assert [(r["vehicle_id"], r["trips"]) for r in rows] == [("TRK-1", 3)] * 3 + [("TRK-2", 2)] * 2
    assert "fuel_l" not in rows[0] and rows[0]["energy_kwh_low"] <= rows[0]["energy_kwh"] <= rows[0]["energy_kwh_high"]
    res = replay(store, *args, "-f", "csv")
    assert res.exit_code == 0, res.output
    table = list(csv.DictReader(io.StringIO(res.stdout)))
    assert len(table) == len(rows)
    for j, c in zip(rows, table, strict=True):
        for key in ("energy_kwh", "soc_min_pct", "soc_end_pct", "charged_kwh", "p_complete", "battery_needed_kwh"):
            assert (c[key] == "") if j[key] is None else float(c[key]) == pytest.approx(j[key], abs=2e-6)
        assert c["completes"] == ("true" if j["completes"] else "false") and c["fuel_l"] == ""
        assert c["vehicle_key"] == "electric-truck" and c["charge_places"] == "anywhere"
    res = replay(store, *args)
    assert res.exit_code == 0 and "TRK-2" in res.stdout and "keep the 15 % reserve" in res.stdout


@pytest.mark.slow
def test_a_duty_is_the_sum_of_the_trips_cevm_predict_gives(store):
    res = runner.invoke(app, ["predict", "--store", str(store), "-v", TRUCK, "--vehicle-id", "TRK-1", "-f", "json"])
    assert res.exit_code == 0, res.output
    trips = json.loads(res.stdout)
    days = json.loads(replay(store, "-v", TRUCK, "-f", "json").stdout)
    per_day = np.add.reduceat([t["energy_kwh"] for t in trips], [0, 3, 6])
    # predict sums an EV's steps from the stored profile (its float32 speeds and heights),
    # replay takes the trip's vector (its samples' float64): the same model to 1e-7
    np.testing.assert_allclose([d["energy_kwh"] for d in days if d["vehicle_id"] == "TRK-1"], per_day, rtol=1e-7)
    assert days[0]["mass_sources"] == "3 logged"


@pytest.mark.slow
def test_the_night_shift_is_one_duty_and_two_calendar_days(store):
    gap = json.loads(replay(store, "-v", TRUCK, "-f", "json").stdout)
    assert [r["day"] for r in gap if r["vehicle_id"] == "TRK-2"] == ["2020-09-13", "2020-09-14"]
    res = replay(store, "-v", TRUCK, "-f", "json", "--duty", "day")
    days = json.loads(res.stdout)
    # cut at midnight: the second "day" holds the end of one night and the start of the next
    assert [r["trips"] for r in days if r["vehicle_id"] == "TRK-2"] == [1, 2, 1]
    assert days[-1]["duty_rule"] == "calendar day in UTC"
    local = json.loads(replay(store, "-v", TRUCK, "-f", "json", "--tz", "Asia/Tokyo").stdout)
    assert local[0]["start_time"].endswith("+09:00")


@pytest.mark.slow
def test_charging_at_the_depot_only(store):
    anywhere = json.loads(replay(store, "-v", TRUCK, "--battery-kwh", "40", "--charger-kw", "50", "-f", "json").stdout)
    depot = json.loads(replay(store, "-v", TRUCK, "--battery-kwh", "40", "--charger-kw", "50", "--charge-at", "depot",
                              "-f", "json").stdout)
    a1 = [r for r in anywhere if r["vehicle_id"] == "TRK-1"]
    d1 = [r for r in depot if r["vehicle_id"] == "TRK-1"]
    assert all(r["charges"] == 2 for r in a1) and all(r["charges"] == 1 for r in d1)  # not at the customer
    assert d1[0]["charge_places"].startswith("depot 52.06")
    d2 = [r for r in depot if r["vehicle_id"] == "TRK-2"]
    assert all(r["charges"] == 0 for r in d2)  # its one stop is at the customer


@pytest.mark.slow
def test_summary_plot_and_a_diesel_candidate(store, tmp_path):
    png, summary = tmp_path / "days.png", tmp_path / "summary.json"
    # the truck cannot follow 3 of the 5 duties (a trip each over its 600 kW: test_replay_judges_
    # as_predict): no battery completes 95 % of them; the largest need of the
    # two it can follow, 41 kWh, more than its 30) completes 40 %
    res = replay(store, "-v", TRUCK, "--battery-kwh", "30", "--plot", str(png), "--summary", str(summary), "-f", "csv",
                 "-o", str(tmp_path / "rows.csv"), "--target-share", "0.4")
    assert res.exit_code == 0, res.output
    sm = json.loads(summary.read_text())
    assert sm["duties"] == 5 and sm["battery_step_kWh"] == 1.0 and sm["completes"] < 5 and sm["cannot_follow"] == 3
    assert sm["battery_for_target_kWh"] > 30 and png.stat().st_size > 10_000
    res = replay(store, "-v", TRUCK, "--battery-kwh", "30", "--summary", str(summary), "-f", "csv",
                 "-o", str(tmp_path / "rows.csv"))
    assert json.loads(summary.read_text())["battery_for_target_kWh"] is None  # inf: none completes 95 %
    res = replay(store, "-v", DIESEL, "-f", "json")
    assert res.exit_code == 0, res.output
    rows = json.loads(res.stdout)
    assert "energy_kwh" not in rows[0] and rows[0]["fuel_l"] > 0 and rows[0]["tank_l"] == 400.0


@pytest.mark.slow
def test_a_parallel_run_writes_the_bytes_of_a_serial_one(store, monkeypatch):
    from cevm.core.replay import TripSpread, plan

    def stated(vehicle, trips, *, ice_braking=None):  # a spread, as a calibrated file gives
        n = trips.n
        return TripSpread(np.zeros((n, 0)), np.zeros((0, 0)), 0.02, 2000.0 * trips.duration_s,
                          0.05 * trips.energy, np.zeros(n), 0.5, "posterior", "stated")

    monkeypatch.setattr(plan, "trip_spread", stated)
    args = ["-v", TRUCK, "--battery-kwh", "36", "-f", "csv", "--draws", "400"]
    serial = replay(store, *args)
    par = replay(store, *args, "--workers", "2")
    assert serial.exit_code == par.exit_code == 0, serial.output + par.output
    assert serial.stdout == par.stdout
    p = [float(r["p_complete"]) for r in csv.DictReader(io.StringIO(serial.stdout))]
    assert any(0 < x < 1 for x in p) and "Monte Carlo, 400 draws" in serial.output


@pytest.mark.parametrize("extra, words", [
    (["--charge-at", "52.1"], "--charge-at '52.1': give LAT,LON,RADIUS_M"),
    (["--charge-at", "95,0,100"], "latitude 95 is not in [-90, 90]"),
    (["--refuel-at", "depot"], "--refuel-at is for a diesel candidate"),
    (["--overnight", "none", "--overnight-kw", "11"], "not both"),
    (["--overnight", "sometimes"], "--overnight 'sometimes'"),
    (["--tz", "Mars/Olympus"], "--tz 'Mars/Olympus': not a time zone"),
    (["--duty", "week"], "--duty 'week'"),
    (["--confidence", "1.5"], "--confidence 1.5 must be in (0, 1]"),
    (["--charge-efficiency", "1.2"], "charging efficiency 1.2 must be in (0, 1]"),
])
def test_wrong_inputs_get_one_line(store, extra, words):
    res = replay(store, "-v", TRUCK, *extra)
    assert res.exit_code == 2 and words in res.output, res.output
    assert "Traceback" not in res.output


def test_unknown_vehicles_and_candidates_that_do_not_fit(store):
    res = runner.invoke(app, ["replay", "--store", str(store), "-v", TRUCK, "--vehicle-id", "NOPE"])
    assert res.exit_code == 2 and "no stored trips of vehicle id(s) 'NOPE'" in res.output
    res = replay(store, "-v", DIESEL, "--charger-kw", "50")
    assert res.exit_code == 2 and "for an electric candidate" in res.output
    res = replay(store, "-v", TRUCK, "-v", DIESEL)
    assert res.exit_code == 2 and "one candidate vehicle file" in res.output


def test_a_damaged_trip_is_left_out_said_and_counted(store, tmp_path):
    import shutil
    import sqlite3

    db = tmp_path / "damaged.sqlite"
    shutil.copy(store, db)
    con = sqlite3.connect(db)
    with con:
        tid = con.execute("SELECT trip_id FROM trips WHERE vehicle_id = 'TRK-1' ORDER BY start_utc_s LIMIT 1 OFFSET 4"
                          ).fetchone()[0]
        con.execute("UPDATE trip_blobs SET vector = randomblob(400) WHERE trip_id = ?", (tid,))
        damaged = con.execute("SELECT trip_id FROM trips WHERE vehicle_id = 'TRK-2' ORDER BY start_utc_s LIMIT 1"
                              ).fetchone()[0]
        con.execute("UPDATE trip_blobs SET profile = randomblob(900) WHERE trip_id = ?", (damaged,))
    con.close()
    res = runner.invoke(app, ["replay", "--store", str(db), "-v", TRUCK, "--vehicle-id", "TRK-1", "--vehicle-id",
                              "TRK-2", "--charge-at", "depot", "--battery-kwh", "36", "-f", "json"])
    assert res.exit_code == 1, res.output
    assert f"skipped: trip {tid!r} is damaged" in res.output  # its vector: left out
    assert f"trip {damaged!r} is damaged" in res.output and "its start and end positions are unknown" in res.output
    rows = json.loads(res.stdout)
    trk1 = [r for r in rows if r["vehicle_id"] == "TRK-1"]
    assert [r["trips"] for r in trk1] == [3, 2, 3] and all(r["missing_trips"] == 1 for r in trk1)


def test_levels_carried_overnight_and_the_logged_trucks_kerb(store):
    res = replay(store, "-v", TRUCK, "--battery-kwh", "60", "--overnight-kw", "11", "--logged-kerb-kg", "15000",
                 "-f", "json")
    assert res.exit_code == 0, res.output
    rows = [r for r in json.loads(res.stdout) if r["vehicle_id"] == "TRK-1"]
    assert rows[0]["soc_start_pct"] == 100.0 and all(r["overnight"] == "11 kW" for r in rows)
    assert rows[1]["soc_start_pct"] <= 100.0 and rows[0]["battery_needed_kwh"] is None  # sized for the fleet
    assert rows[0]["mass_min_kg"] == 33000.0  # 30 t logged, 15 t of it the logged truck: 15 t on the candidate's 18


def test_sizes_at_the_confidence_are_the_quantile_of_the_duties_needs_at_it(store, tmp_path):
    """The summary's battery at --confidence is the --target-share quantile of the rows'
    battery_needed_kwh_conf (the smallest on the 1 kWh grid that completes the share), as
    the mean's is of battery_needed_kwh; never below it; the lines say both."""
    summary = tmp_path / "summary.json"
    strong = tmp_path / "strong.toml"  # a truck that can follow every trip of the store (they ask up to 935 kW)
    strong.write_text(Path(TRUCK).read_text().replace("max_power_kw = 600.0", "max_power_kw = 1000.0"))
    res = replay(store, "-v", str(strong), "--battery-kwh", "30", "--target-share", "0.6", "--summary", str(summary),
                 "-f", "csv")
    assert res.exit_code == 0, res.output
    rows = list(csv.DictReader(io.StringIO(res.stdout)))
    sm = json.loads(summary.read_text())
    mean_need = sorted(float(r["battery_needed_kwh"]) for r in rows)
    conf_need = sorted(float(r["battery_needed_kwh_conf"]) for r in rows)
    k = int(np.ceil(0.6 * len(rows))) - 1  # the smallest size that completes at least 60 % of the duties
    assert sm["battery_for_target_kWh"] == mean_need[k]
    assert sm["battery_for_target_kWh_at_confidence"] == conf_need[k]
    assert all(c >= m for c, m in zip(conf_need, mean_need, strict=True)) and conf_need[k] > mean_need[k]
    table = replay(store, "-v", str(strong), "--battery-kwh", "30", "--target-share", "0.6")
    assert f"{conf_need[k]:,.0f} kWh with each duty's energy at its 0.95 quantile" in " ".join(table.output.split())


def _with_a_day_logged_twice(store: Path, tmp_path: Path) -> Path:
    """A copy of ``store`` where TRK-1's first day, as make_replay_store logged it, is
    stored again from a second logger's file."""
    import shutil

    from cevm.core.cycle import drive_cycle_vector
    from cevm.store import TripStore
    from replay_cases import CUSTOMER, DEPOT, _stored_trip, cycle

    db = tmp_path / "twice.sqlite"
    shutil.copy(store, db)
    day0 = 1.6e9 - (1.6e9 % 86400)
    t = day0 + 7.0 * 3600
    trips, vectors = [], []
    for k, (frm, to, stop_min) in enumerate([(DEPOT, CUSTOMER, 45), (CUSTOMER, DEPOT, 40), (DEPOT, DEPOT, 0)]):
        cyc = cycle(200 + k, n_trips=12)
        trips.append(_stored_trip("TRK-1", "ab" * 32, k, t, cyc, 30e3 + 4e3 * k, 4.0, frm, to,
                                  tmp_path / "second-logger.csv"))
        vectors.append(drive_cycle_vector(*cyc).to_bytes())
        t += cyc[0][-1] + stop_min * 60
    with TripStore(db) as st:
        st.replace_file_trips(tmp_path / "second-logger.csv", trips, vectors, sha256="ab" * 32, size_bytes=1,
                              mtime_s=0.0, profile="test")
    return db


def test_a_day_logged_twice_counts_once_and_is_said(store, tmp_path):
    # acceptance: a bus carrying two loggers (two formats) had each trip stored twice; a
    # duty then held both copies, twice its distance and energy, without a word
    db = _with_a_day_logged_twice(store, tmp_path)
    once = json.loads(replay(store, "-v", TRUCK, "-f", "json").stdout)
    res = runner.invoke(app, ["replay", "--store", str(db), "--vehicle-id", "TRK-1", "--vehicle-id", "TRK-2",
                              "-v", TRUCK, "-f", "json"])
    assert res.exit_code == 0, res.output
    twice = json.loads(res.stdout)
    assert [(r["trips"], r["energy_kwh"]) for r in twice] == [(r["trips"], r["energy_kwh"]) for r in once]
    assert "TRK-1: 3 trip(s) lie mostly inside an earlier trip of the vehicle" in res.output


def test_calibrate_fits_a_trip_logged_twice_once(store, tmp_path):
    from cevm.io.vehicles import load_vehicle
    from cevm.store import TripStore
    from cevm.store.calibration import trips_for_calibration

    db = _with_a_day_logged_twice(store, tmp_path)
    with TripStore(store) as st:
        ids = [t.trip_id for t in trips_for_calibration(st, "TRK-1", load_vehicle(DIESEL)).trips]
    with TripStore(db) as st:
        sel = trips_for_calibration(st, "TRK-1", load_vehicle(DIESEL))
    assert sorted(t.trip_id for t in sel.trips) == sorted(ids)  # 9 trips, not 12
    assert any(n.startswith("3 trip(s) lie mostly inside an earlier trip") for n in sel.notes)


def test_replay_judges_each_trip_as_predict(store, tmp_path):
    """A hand-made candidate that cannot follow some of the logged trips (its max speed,
    max power and max gross mass set between the trips' figures): replay's verdict on
    each duty is predict's on its trips (any trip failing fails the duty), the duty does
    not complete (p 0), and it names its first failing trip and the limit."""
    text = Path(TRUCK).read_text()
    for old, new in (("max_speed_kmh = 90.0", "max_speed_kmh = 62.0"),
                     ("max_power_kw = 600.0", "max_power_kw = 700.0"),
                     ("max_gross_kg = 44000.0", "max_gross_kg = 36000.0"),
                     ("payload_kg = 22000.0", "payload_kg = 18000.0")):
        text = text.replace(old, new)
    cand = tmp_path / "slow-truck.toml"
    cand.write_text(text)
    res = runner.invoke(app, ["predict", "--store", str(store), "-v", str(cand), "--vehicle-id", "TRK-1",
                              "--vehicle-id", "TRK-2", "-f", "json"])
    assert res.exit_code == 0, res.output
    trips = json.loads(res.stdout)
    res = replay(store, "-v", str(cand), "-f", "json")
    assert res.exit_code == 0, res.output
    duties = json.loads(res.stdout)
    flags = ("over_power", "over_speed", "over_max_gross")
    # each flag fails on some trips and passes on others: the candidate is between them
    assert all(0 < sum(t[f] for t in trips) < len(trips) for f in flags)
    i = 0
    for d in duties:
        mine = trips[i:i + d["trips"]]
        i += d["trips"]
        for f in flags:
            assert d[f] == any(t[f] for t in mine), (d["vehicle_id"], d["day"], f)
        bad = [t for t in mine if any(t[f] for f in flags)]
        assert d["feasible"] == (not bad and d["completes"])
        if bad:
            assert not d["completes"] and d["p_complete"] == 0.0
            first = bad[0]
            said = d["cannot_follow"]
            assert said.split(" on trip ")[1].split(" ")[0] == first["cycle"]
            if first["over_speed"]:
                assert said.startswith("speed on trip") and "> 62)" in said
            if first["over_max_gross"]:
                assert f"gross mass on trip {first['cycle']} ({first['mass_kg']:,.0f} kg > 36,000)" in said
        else:
            assert d["cannot_follow"] in ("", None)
    assert i == len(trips)


def test_levels_carried_sizing_counts_no_duty_the_candidate_cannot_follow(store, tmp_path):
    # the shipped truck cannot follow 3 of the 5 duties (a trip each over its 600 kW):
    # with levels carried across duties no battery completes 95 % of them, and a share
    # of 40 % is completed by the two it can follow
    summary = tmp_path / "summary.json"
    for share, sized in (("0.95", False), ("0.4", True)):
        res = replay(store, "-v", TRUCK, "--overnight", "none", "--target-share", share, "--summary", str(summary),
                     "-f", "csv")
        assert res.exit_code == 0, res.output
        sm = json.loads(summary.read_text())
        assert sm["cannot_follow"] == 3
        assert (sm["battery_for_target_kWh"] is not None) is sized, sm
