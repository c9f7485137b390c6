"""cevm calibrate end to end: a store of trips measured with a known eta, through the CLI."""

import json
import tomllib

import numpy as np
import pytest
from typer.testing import CliRunner

from cevm.cli import app
from cevm.core.cycle import drive_cycle_vector
from cevm.core.trip import Measurement, Trip
from cevm.io import load_vehicle
from cevm.store import TripStore
from cevm_samplegen.cycles import MicroTripSpec, micro_trip_cycle
from reference import reference_wheel_energy_j

runner = CliRunner()
TRUE_ETA = 0.71


@pytest.fixture
def store(tmp_path, root):
    """12 bus trips over 6 days whose battery energy is the plain per-step model with
    eta = 0.71, plus 1 % noise, measured by a 0.1 kWh counter."""
    bus = load_vehicle(root / "configs/vehicles/electric-bus.toml")
    rng = np.random.default_rng(4)
    path = tmp_path / "s.sqlite"
    with TripStore.open(path) as st:
        for day in range(6):
            trips, vectors = [], []
            for k in range(2):
                spec = MicroTripSpec(n_trips=int(rng.integers(8, 20)), cruise_kmh=(15.0, float(rng.uniform(30, 60))))
                c = micro_trip_cycle(spec, seed=100 + 2 * day + k)
                e_wheel = reference_wheel_energy_j(c.time_s, c.speed_mps, c.elevation_m, bus.mass_kg, bus.cda_m2,
                                                   bus.cr, "ev", TRUE_ETA)
                energy = e_wheel / TRUE_ETA * (1 + rng.normal(0, 0.01))
                dist = np.concatenate([[0.0], np.cumsum((c.speed_mps[1:] + c.speed_mps[:-1]) / 2)])
                sha = f"{day:02d}" * 32
                trips.append(Trip(
                    vehicle_id="EB-09", source_file=str(tmp_path / f"day{day}.csv"), source_sha256=sha, trip_index=k,
                    start_utc_s=1.6e9 + day * 86400 + k * 7200, time_s=c.time_s, speed_mps=c.speed_mps,
                    distance_m=dist, lat_deg=np.full(c.time_s.size, 52.0), lon_deg=np.full(c.time_s.size, -0.7),
                    elevation_m=c.elevation_m, elevation_source="dsm", dsm_coverage_pct=100.0,
                    measured=Measurement("energy_j", energy, "counter", 0.1 * 3.6e6, 0.1 * 3.6e6 / np.sqrt(6)),
                    gross_weight_kg=None,
                ))
                vectors.append(drive_cycle_vector(c.time_s, c.speed_mps, c.elevation_m).to_bytes())
            st.replace_file_trips(tmp_path / f"day{day}.csv", trips, vectors, sha256=sha, size_bytes=1, mtime_s=0.0,
                                  profile="test")
    return path


@pytest.mark.slow
def test_calibrate_recovers_eta_and_reports_the_papers_figures(store, root, tmp_path):
    bus = root / "configs/vehicles/electric-bus.toml"
    out = tmp_path / "bus-calibrated.toml"
    plot = tmp_path / "fit.png"
    res = runner.invoke(app, ["calibrate", "-v", str(bus), "--vehicle-id", "EB-09", "--store", str(store),
                              "--out", str(out), "--plot", str(plot), "-f", "json"])
    assert res.exit_code == 0, res.output
    r = json.loads(res.stdout)
    assert r["eta"] == pytest.approx(TRUE_ETA, abs=3 * r["fitted"]["eta"]["std"] + 0.005)
    assert r["n_trips"] == 12 and r["cross_validated"]["n"] == 12
    assert abs(r["cross_validated"]["mean_pct"]) < 2.0 and r["cross_validated"]["std_pct"] < 3.0
    rows = r["trips"]
    assert {row["held_out"] for row in rows} == {True, False} and len(rows) == 24
    for row in rows:
        assert row["error_pct"] == pytest.approx(100 * (row["predicted"] - row["measured"]) / row["measured"], rel=1e-9)
    # the calibrated file loads, holds the fitted eta, and kept everything else
    written = load_vehicle(out)
    assert written.eta == pytest.approx(r["eta"], rel=1e-5) and written.cda_m2 == 3.99
    assert "detailed" in tomllib.loads(out.read_text()) and out.read_text().startswith("# calibrated by cevm")
    assert plot.stat().st_size > 10_000
    # never overwrite silently
    res = runner.invoke(app, ["calibrate", "-v", str(bus), "--vehicle-id", "EB-09", "--store", str(store), "--out",
                              str(out)])
    assert res.exit_code == 2 and "overwrite" in res.output
    res = runner.invoke(app, ["calibrate", "-v", str(bus), "--vehicle-id", "EB-09", "--store", str(store), "--out",
                              str(bus)])
    assert res.exit_code == 2 and "is the input --vehicle" in res.output


def test_calibrate_table_refuses_what_the_data_cannot_identify(store, root):
    res = runner.invoke(app,
                        ["calibrate", "-v", str(root / "configs/vehicles/electric-bus.toml"), "--vehicle-id", "EB-09",
                              "--store", str(store), "--fit", "cr"])
    assert res.exit_code == 0, res.output
    assert "sigma(e)" in res.stdout and "cross-validated" in res.stdout and "paper" in res.stdout
    assert "refused" in res.stdout


def test_calibrate_unknown_vehicle_id_is_a_clear_error(store, root):
    res = runner.invoke(app,
                        ["calibrate", "-v", str(root / "configs/vehicles/electric-bus.toml"), "--vehicle-id", "NOPE",
                              "--store", str(store)])
    assert res.exit_code == 2 and "NOPE" in res.output and "EB-09" in res.output


def test_calibrated_toml_replaces_values_keeps_the_rest_and_says_so():
    from cevm.io.calibrated import calibrated_toml

    text = 'name = "x"  # a name\neta = 0.45   # from the paper\ncr = 0.0066\n\n[sources]\neta = "paper"\n'
    out = calibrated_toml(text, {"eta": 0.3712345678, "ice_braking": "no-credit"}, "calibrated\nfitted: eta")
    data = tomllib.loads(out)
    assert data["eta"] == pytest.approx(0.371235) and data["ice_braking"] == "no-credit"
    assert data["sources"]["eta"] == "paper" and data["cr"] == 0.0066 and data["name"] == "x"
    assert "# cevm calibrate (was 0.45)" in out and "from the paper" not in out
    assert out.startswith("# calibrated\n# fitted: eta\n")
