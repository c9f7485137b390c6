"""The ingest pipeline end to end: logger files -> store, through the CLI as a user runs it."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pyproj import Transformer
from typer.testing import CliRunner

from cevm.cli import app
from cevm.core.cycle import CycleVector, drive_cycle_vector
from cevm.store import TripStore

runner = CliRunner()
DATA = Path(__file__).parent / "data"

# A DSM that is a tilted plane in British National Grid: z = A + B x + C y [m]
PLANE = (120.0, 0.004, -0.003)
ORIGIN_BNG = (485000.0, 238000.0)


def plane(x, y):
    return PLANE[0] + PLANE[1] * (x - ORIGIN_BNG[0]) + PLANE[2] * (y - ORIGIN_BNG[1])


@pytest.fixture
def dsm(tmp_path):
    import rasterio
    from rasterio.transform import from_origin

    res = 2.0
    n = 3000  # 6 km x 6 km
    x0, y1 = ORIGIN_BNG[0] - 1000.0, ORIGIN_BNG[1] + 5000.0
    xs = x0 + res * (np.arange(n) + 0.5)
    ys = y1 - res * (np.arange(n) + 0.5)
    z = plane(xs[None, :], ys[:, None]).astype(np.float32)
    path = tmp_path / "dsm.tif"
    with rasterio.open(path, "w", driver="GTiff", width=n, height=n, count=1, dtype="float32",
                       crs="EPSG:27700", transform=from_origin(x0, y1, res, res), nodata=-9999.0,
                       tiled=True, blockxsize=256, blockysize=256, compress="deflate") as ds:
        ds.write(z, 1)
    return path


def write_srf(path: Path, vehicle_id: str, start_epoch: int, seed: int, *, n: int = 900) -> dict:
    """A small srf export: 1 Hz, a stop-go speed trace heading north-east from the
    origin, FMS wheel speed and an energy counter (0.1 kWh). Returns the truth."""
    rng = np.random.default_rng(seed)
    t = np.arange(n, dtype=float)
    v = np.clip(12.0 * np.sin(np.pi * t / 300.0) ** 2 + rng.normal(0, 0.2, n), 0, None)
    v[:20] = 0.0
    v[-20:] = 0.0
    s = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]))])
    x = ORIGIN_BNG[0] + s / np.sqrt(2)
    y = ORIGIN_BNG[1] + s / np.sqrt(2)
    lon, lat = Transformer.from_crs("EPSG:27700", "EPSG:4326", always_xy=True).transform(x, y)
    energy_kwh = 50.0 + np.cumsum(np.concatenate([[0.0], 0.0004 * v[1:] + 0.0001]))
    iso = [np.datetime_as_string(np.datetime64(start_epoch + int(ti), "s"), unit="ms") + "Z" for ti in t]
    lines = [f"# vehicle_id={vehicle_id}", "# logger=SRF Logger 2.4.1", f"# started={iso[0]}",
             "timestamp_utc,gps_lat_deg,gps_lon_deg,gps_alt_m,gps_speed_kmh,fms_wheel_speed_kmh,fms_total_energy_used_kwh"]
    for i in range(n):
        counter = f"{np.floor(energy_kwh[i] * 10) / 10:.1f}" if i % 5 == 0 else ""
        lines.append(f"{iso[i]},{lat[i]:.7f},{lon[i]:.7f},{100 + rng.normal(0, 10):.1f},{v[i] * 3.6:.2f},"
                     f"{np.round(v[i] * 3.6 * 256) / 256:.4f},{counter}")
    path.write_text("\n".join(lines) + "\n")
    return {"x": x, "y": y, "distance_m": s[-1], "energy_kwh": energy_kwh[-1] - energy_kwh[0]}


@pytest.fixture
def fleet(tmp_path):
    logs = tmp_path / "logs"
    (logs / "bus1").mkdir(parents=True)
    truth = {
        "a": write_srf(logs / "bus1" / "day1.csv", "EB-01", 1_557_820_800, 1),
        "b": write_srf(logs / "bus1" / "day2.csv", "EB-01", 1_557_907_200, 2),
        "c": write_srf(logs / "eb02.csv", "EB-02", 1_557_820_800, 3),
    }
    return logs, truth


def run(*args, env=None):
    return runner.invoke(app, [str(a) for a in args], env=env)


@pytest.mark.slow
def test_ingest_srf_with_dsm_then_trips_and_predict(tmp_path, fleet, dsm, root):
    logs, truth = fleet
    store = tmp_path / "s.sqlite"
    res = run("ingest", logs, "--store", store, "--dsm", dsm, "--log-json")
    assert res.exit_code == 0, res.output
    events = [json.loads(line) for line in res.stdout.splitlines()]
    summary = events[-1]
    assert summary["event"] == "summary" and summary["files"] == 3 and summary["failed"] == 0
    assert summary["trips"] == 3

    rows = json.loads(run("trips", "--store", store, "--format", "json").stdout)
    assert {r["vehicle_id"] for r in rows} == {"EB-01", "EB-02"}
    for r in rows:
        for key in ("trip_id", "vehicle_id", "start_utc", "distance_km", "duration_s", "measured_energy_kwh",
                    "dsm_coverage_pct"):
            assert key in r
        assert r["dsm_coverage_pct"] > 95.0
        # the counter (0.1 kWh steps, every 5th tick) brackets the true energy
        assert r["measured_energy_kwh"] == pytest.approx(truth["a"]["energy_kwh"], abs=0.25)
        assert r["distance_km"] == pytest.approx(truth["a"]["distance_m"] / 1000, rel=0.03)

    with TripStore.open(store) as st:
        trip = st.load_trip(rows[0]["trip_id"])
        vec = CycleVector.from_bytes(st.load_vector_bytes(rows[0]["trip_id"]))
    # road elevation from the DSM follows the plane: climb = plane difference along the route
    t = truth["a"]
    climb = plane(t["x"][-1], t["y"][-1]) - plane(t["x"][0], t["y"][0])
    assert trip.elevation_m[-1] - trip.elevation_m[0] == pytest.approx(climb, abs=1.0)
    assert trip.elevation_source.startswith("dsm")
    # the stored vector is the vector of the stored profile (kept as float32 for speed and
    # elevation, so to float32 rounding; the vector itself was computed in float64)
    again = drive_cycle_vector(trip.time_s, trip.speed_mps, trip.elevation_m)
    assert vec.delta == pytest.approx(again.delta, rel=1e-5)

    bus = root / "configs/vehicles/electric-bus.toml"
    pred = json.loads(run("predict", "-v", bus, "--vehicle-id", "EB-01", "--store", store, "-f", "json").stdout)
    assert len(pred) == 2 and all(p["energy_kwh"] > 0 for p in pred)
    one = json.loads(run("predict", "-v", bus, "--trip", rows[0]["trip_id"], "--store", store, "-f", "json").stdout)
    assert one[0]["cycle"] == rows[0]["trip_id"]


def test_ingest_is_idempotent_and_a_changed_file_replaces_its_trips(tmp_path, fleet):
    logs, _ = fleet
    store = tmp_path / "s.sqlite"
    assert run("ingest", logs, "--store", store, "-q").exit_code == 0
    before = json.loads(run("trips", "--store", store, "-f", "json").stdout)
    res = run("ingest", logs, "--store", store, "--log-json")
    assert json.loads(res.stdout.splitlines()[-1])["unchanged"] == 3
    assert json.loads(run("trips", "--store", store, "-f", "json").stdout) == before
    # change one file: its trip is replaced, the others are untouched
    write_srf(logs / "eb02.csv", "EB-02", 1_557_824_400, 9)
    res = run("ingest", logs, "--store", store, "--log-json")
    s = json.loads(res.stdout.splitlines()[-1])
    assert (s["ingested"], s["unchanged"]) == (1, 2)
    after = json.loads(run("trips", "--store", store, "-f", "json").stdout)
    assert len(after) == 3
    old_ids = {r["trip_id"] for r in before if r["vehicle_id"] == "EB-02"}
    new_ids = {r["trip_id"] for r in after if r["vehicle_id"] == "EB-02"}
    assert old_ids.isdisjoint(new_ids) and len(new_ids) == 1


def test_bad_files_are_reported_skipped_and_the_batch_goes_on(tmp_path, fleet):
    logs, _ = fleet
    store = tmp_path / "s.sqlite"
    assert run("ingest", logs, "--store", store, "-q").exit_code == 0
    (logs / "junk.csv").write_bytes(np.random.default_rng(5).bytes(2000))
    (logs / "empty.csv").write_text("")
    # a previously good file turns bad: its stored trip stays
    good = (logs / "eb02.csv").read_text().splitlines()
    (logs / "eb02.csv").write_text("\n".join(good[:10] + [good[10].replace(",", ";x;", 1)] + good[11:]) + "\n")
    res = run("ingest", logs, "--store", store, "--log-json")
    assert res.exit_code == 1
    events = [json.loads(line) for line in res.stdout.splitlines()]
    failed = {Path(e["path"]).name: e["error"] for e in events if e.get("status") == "failed"}
    assert set(failed) >= {"junk.csv", "empty.csv"}
    for name, err in failed.items():
        assert name in err  # the message names the file
    trips = json.loads(run("trips", "--store", store, "-f", "json").stdout)
    assert len(trips) == 3 and "EB-02" in {t["vehicle_id"] for t in trips}


def test_missing_input_and_unknown_profile(tmp_path, fleet):
    logs, _ = fleet
    store = tmp_path / "s.sqlite"
    res = run("ingest", tmp_path / "nowhere", "--store", store)
    assert res.exit_code == 2 and "nowhere" in res.output  # no input at all: bad usage
    assert not store.exists()  # and no store for it
    res = run("ingest", tmp_path / "nowhere", logs, "--store", store, "-q")
    assert res.exit_code == 1 and "nowhere" in res.output  # part of a batch failed
    res = run("ingest", logs, "--store", store, "--profile", "nosuch")
    assert res.exit_code == 2 and "nosuch" in res.output
    assert store.exists()  # the store made by the run before is kept


@pytest.mark.parametrize("bad", [("--profile", "nosuch"), ("--dsm", "no-such-dsm.tif")], ids=["profile", "dsm"])
def test_options_refused_once_the_store_is_open_leave_no_new_store(tmp_path, fleet, bad):
    logs, _ = fleet
    store = tmp_path / "new.sqlite"
    res = run("ingest", logs, "--store", store, *bad)
    assert res.exit_code == 2 and bad[1] in res.output
    assert not list(tmp_path.glob("new.sqlite*"))  # neither the store nor SQLite's side files


@pytest.mark.slow
def test_two_ingests_at_once_store_everything_once(tmp_path, fleet):
    logs, _ = fleet
    store = tmp_path / "s.sqlite"
    cmd = [sys.executable, "-m", "cevm", "ingest", str(logs), "--store", str(store), "-q"]
    procs = [subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE) for _ in range(2)]
    for p in procs:
        out, err = p.communicate(timeout=120)
        assert p.returncode == 0, err.decode()
    with TripStore.open(store) as st:
        assert st.count_trips() == 3
        assert st.integrity_check() == "ok"


def test_twizy_excerpt_ingests_with_its_repairs_reported(tmp_path):
    src = DATA / "twizy_excerpt.csv"
    if not src.exists():
        pytest.skip("no twizy excerpt")
    store = tmp_path / "s.sqlite"
    res = run("ingest", src, "--store", store, "--log-json")
    assert res.exit_code == 0, res.output
    event = json.loads(res.stdout.splitlines()[0])
    assert event["profile"] == "twizy" and event["status"] == "ingested"


def test_real_twizy_logs_ingest_cleanly(tmp_path, twizy_logs):
    real, n_files = twizy_logs
    store = tmp_path / "s.sqlite"
    res = run("ingest", real, "--store", store, "--log-json")
    assert res.exit_code == 0, res.output
    summary = json.loads(res.stdout.splitlines()[-1])
    assert summary["failed"] == 0 and summary["files"] == n_files and summary["trips"] >= n_files
    rows = json.loads(run("trips", "--store", store, "-f", "json").stdout)
    # a Twizy uses roughly 0.06-0.15 kWh/km
    per_km = [r["measured_energy_kwh"] / r["distance_km"] for r in rows if r["measured_energy_kwh"]]
    assert len(per_km) >= n_files - 2 and 0.05 < np.median(per_km) < 0.15


from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from cevm.ingest import IngestOptions, process_file  # noqa: E402
from cevm.ingest.profiles import load_profiles  # noqa: E402

SRF_HEAD = "timestamp_utc,gps_lat_deg,gps_lon_deg,fms_wheel_speed_kmh\n"


@pytest.mark.slow
@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.one_of(
    st.binary(min_size=0, max_size=3000),
    st.text(min_size=0, max_size=2000),
    st.text(alphabet="0123456789,.:-TZ\n\r;# ", min_size=0, max_size=2000).map(lambda s: SRF_HEAD + s),
))
def test_property_any_bytes_give_a_clear_error_or_trips_never_a_crash(tmp_path, content):
    path = tmp_path / "f.csv"
    path.write_bytes(content.encode("utf-8") if isinstance(content, str) else content)
    out = process_file(path, IngestOptions(), PROFILES)
    if out.error is not None:
        assert "internal error" not in out.error, out.error
        assert str(path) in out.error


PROFILES = load_profiles()


def test_an_unreadable_subfolder_is_reported_and_fails_the_run(tmp_path, fleet, monkeypatch):
    """A subfolder that cannot be listed (here: os.scandir refused for it, as for a
    folder without read permission, which root's tests cannot make) is named in one
    line, in --log-json too, and the run exits 1, not 0: a cron job learns it missed
    logs. The readable logs are ingested."""
    import os

    logs, _ = fleet
    locked = Path(logs) / "locked"
    locked.mkdir()
    real_scandir = os.scandir

    def scandir(path="."):
        if Path(path) == locked:
            raise PermissionError(13, "Permission denied", str(path))
        return real_scandir(path)

    monkeypatch.setattr(os, "scandir", scandir)
    res = run("ingest", logs, "--store", tmp_path / "s.sqlite", "--log-json")
    assert res.exit_code == 1, res.output
    events = [json.loads(line) for line in res.stdout.splitlines()]
    failed = [e for e in events if e["event"] == "file" and e["status"] == "failed"]
    assert len(failed) == 1 and str(locked) in failed[0]["error"] and "Permission denied" in failed[0]["error"]
    assert events[-1]["event"] == "summary" and events[-1]["ingested"] == 3 and events[-1]["failed"] == 1
    res = run("ingest", logs, "--store", tmp_path / "t.sqlite", "-q")
    assert res.exit_code == 1 and str(locked) in res.output


def test_a_trip_starts_at_the_state_of_charge_its_log_holds_there(root):
    """A stored trip records the state of charge logged at its start:
    the reading at or last before the start within 60 s, else the first within 60 s
    after it. Expected values read from the file with the csv module."""
    import csv
    from datetime import datetime

    from cevm.ingest.task import IngestOptions, process_file

    path = root / "sample_logs" / "srf" / "EB-01_2019-01-31.csv"
    with open(path) as fh:
        rows = list(csv.DictReader(line for line in fh if not line.startswith("#")))
    soc = [(datetime.fromisoformat(r["timestamp_utc"].replace("Z", "+00:00")).timestamp(),
            float(r["fms_battery_soc_pct"])) for r in rows if r["fms_battery_soc_pct"]]
    out = process_file(path, IngestOptions())
    assert out.error is None and len(out.trips) >= 2
    for trip in out.trips:
        t0 = trip.start_utc_s
        before = [(t, x) for t, x in soc if t0 - 60 <= t <= t0]
        after = [(t, x) for t, x in soc if t0 < t <= t0 + 60]
        t_want, want = before[-1] if before else after[0]
        assert trip.start_soc_pct == want
        assert trip.quality["start_soc"] == {"pct": want, "reading_offset_s": pytest.approx(t_want - t0, abs=1e-6)}
    # a log without a state of charge: none
    out = process_file(root / "sample_logs" / "srf" / "HGV-11_2019-01-31.csv", IngestOptions())
    assert out.trips and all(t.start_soc_pct is None and "start_soc" not in t.quality for t in out.trips)


def test_trips_shows_the_start_state_and_sources_carry_it(tmp_path, root):
    """`cevm trips` lists each trip's start SoC and the time its vehicle stood before it;
    the stored trips handed to predict (load_sources) carry both."""
    from contextlib import ExitStack

    from cevm.store.sources import load_sources

    store = tmp_path / "s.sqlite"
    srf = root / "sample_logs" / "srf"
    assert run("ingest", srf / "EB-01_2019-01-31.csv", "--store", store, "--workers", "1", "-q").exit_code == 0
    rows = json.loads(run("trips", "--store", store, "--format", "json").stdout)
    rows.sort(key=lambda r: r["start_utc"])
    assert rows[0]["standstill_before_s"] is None and rows[0]["start_soc_pct"] == 97.2
    for b in rows[1:]:
        assert b["standstill_before_s"] > 0 and b["start_soc_pct"] is not None
    with ExitStack() as stack:
        srcs = load_sources(stack, store, [], [], ["EB-01"], [], cr0=0.0, need_profiles=False)
        by_id = {s.name: s for s in srcs}
        for r in rows:
            assert by_id[r["trip_id"]].start_soc_pct == r["start_soc_pct"]
            assert by_id[r["trip_id"]].standstill_before_s == r["standstill_before_s"]


def test_a_file_whose_trips_hold_too_many_samples_is_refused_before_they_are_made(tmp_path):
    """A log ticking every 5 s gives five trip samples a row on the 1 s grid, and
    a worker holds a file's stored trips until they are written: a 2.5 M-row portal
    export reached 0.79 GB. The trips' samples are bounded (--max-samples), checked once
    the trips are cut, before any is made. Here a 1 Hz log of 900 rows: about 900
    samples, refused at 500, stored at 1,000."""
    from cevm.ingest.task import IngestOptions, process_file
    from cevm.ingest.textfile import ReadLimits

    f = tmp_path / "a.csv"
    write_srf(f, "EB-01", 1_557_820_800, 0, n=900)
    out = process_file(f, IngestOptions(limits=ReadLimits(max_samples=500)))
    assert out.error is not None and "samples on the 1 s grid: more than the 500" in out.error
    assert "--max-samples" in out.error
    n = process_file(f, IngestOptions(limits=ReadLimits(max_samples=1000))).n_samples
    assert 500 < n <= 900
    res = run("ingest", f, "--store", tmp_path / "s.sqlite", "--max-samples", "500", "-q", "--workers", "1")
    assert res.exit_code == 1 and "--max-samples" in res.output


def test_a_charge_inside_a_trip_is_named_in_the_files_repairs_and_split_off(tmp_path):
    # acceptance: a bus's 5-min opportunity charge at a terminus (battery power -100 kW at
    # standstill) was inside its trip, whose measured energy became the net of the charge
    import datetime as dt

    t0 = dt.datetime(2026, 6, 11, 5, 0, tzinfo=dt.UTC)
    lines = ["# vehicle_id=EB-CH", "timestamp_utc,fms_wheel_speed_kmh,fms_battery_voltage_v,fms_battery_current_a"]
    for i in range(1501):
        stopped = 600 <= i < 900
        amps = -100e3 / 650 if stopped else 20e3 / 650
        stamp = (t0 + dt.timedelta(seconds=i)).strftime("%Y-%m-%dT%H:%M:%S.000Z")
        lines.append(f"{stamp},{0 if stopped else 36},650,{amps:.4f}")
    path = tmp_path / "EB-CH.csv"
    path.write_text("\n".join(lines) + "\n")
    out = process_file(path, IngestOptions(), PROFILES)
    assert out.error is None
    kwh = [t.measured.value / 3.6e6 for t in out.trips]
    # 20 kW while driving: 600 s and 600 s (+ the row at each end of the stop), charge excluded
    assert kwh == [pytest.approx(20 * 600 / 3600, rel=0.01), pytest.approx(20 * 600 / 3600, rel=0.01)]
    (note,) = [r for r in out.repairs if r.startswith("charging:")]
    assert "2026-06-11 05:10:00 to 2026-06-11 05:14:59 UTC (8.3 kWh taken in)" in note
