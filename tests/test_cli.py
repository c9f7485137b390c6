"""The command line: the JSON contract of predict, formats, exit codes, one-line errors."""

import csv
import io
import json
import subprocess
import sys

import pytest
from typer.testing import CliRunner

from cevm.cli import app
from cevm.core.cycle import drive_cycle_vector
from cevm.io import load_vehicle, read_cycle_csv
from reference import reference_wheel_energy_j

runner = CliRunner()


@pytest.fixture
def files(root):
    return {
        # the paper's figures: the values below are the paper's formulas on them
        "bus": root / "configs/vehicles/electric-bus-paper.toml",
        "hgv": root / "configs/vehicles/diesel-hgv-paper.toml",
        "urban": root / "configs/cycles/urban-bus.csv",
        "regional": root / "configs/cycles/regional-delivery.csv",
    }


def test_help_lists_the_commands():
    out = runner.invoke(app, ["--help"]).output
    for cmd in ("ingest", "calibrate", "predict"):
        assert cmd in out


def test_predict_json_contract(files):
    args = ["predict", "-v", str(files["bus"]), "-v", str(files["hgv"]), "-c", str(files["urban"]),
            "-c", str(files["regional"]), "-m", "18000", "-m", "20000", "-f", "json"]
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    rows = json.loads(res.stdout)
    assert len(rows) == 2 * 2 * 2  # cycles x vehicles x masses
    for r in rows:
        for key in ("cycle", "vehicle", "mass_kg", "distance_km", "duration_s", "wheel_energy_kwh"):
            assert key in r
        assert ("energy_kwh" in r) != ("fuel_l" in r)
    # values against the plain reference and the paper's conversions
    cyc = read_cycle_csv(files["urban"])
    r = next(r for r in rows if r["cycle"] == "urban-bus" and "fuel_l" in r and r["mass_kg"] == 20000)
    hgv = load_vehicle(files["hgv"])
    e = reference_wheel_energy_j(cyc.time_s, cyc.speed_mps, cyc.elevation_m, 20000.0, hgv.cda_m2, hgv.cr, "paper")
    assert r["wheel_energy_kwh"] == pytest.approx(e / 3.6e6, rel=1e-9)
    assert r["fuel_l"] == pytest.approx(e / (35.8e6 * 0.45), rel=1e-9)
    bus_row = next(r for r in rows if r["cycle"] == "urban-bus" and "energy_kwh" in r and r["mass_kg"] == 18000)
    e = reference_wheel_energy_j(cyc.time_s, cyc.speed_mps, cyc.elevation_m, 18000.0, 3.99, 0.0066, "ev", 0.78)
    assert bus_row["energy_kwh"] == pytest.approx(e / 0.78 / 3.6e6, rel=1e-9)
    assert bus_row["distance_km"] == pytest.approx(drive_cycle_vector(cyc.time_s, cyc.speed_mps).distance_m / 1e3)


def test_predict_default_mass_csv_and_table(files):
    res = runner.invoke(app, ["predict", "-v", str(files["bus"]), "-c", str(files["urban"]), "-f", "csv"])
    assert res.exit_code == 0
    rows = list(csv.DictReader(io.StringIO(res.stdout)))
    assert len(rows) == 1 and float(rows[0]["mass_kg"]) == 9825.0
    res = runner.invoke(app, ["predict", "-v", str(files["bus"]), "-c", str(files["urban"])])
    assert res.exit_code == 0 and "urban-bus" in res.stdout and "battery kWh" in res.stdout


def test_ice_braking_override_changes_fuel(files):
    base = ["predict", "-v", str(files["hgv"]), "-c", str(files["urban"]), "-f", "json"]
    paper = json.loads(runner.invoke(app, base).stdout)[0]
    nocredit = json.loads(runner.invoke(app, base + ["--ice-braking", "no-credit"]).stdout)[0]
    assert nocredit["ice_braking"] == "no-credit" and nocredit["fuel_l"] > paper["fuel_l"]


@pytest.mark.slow
def test_bad_input_is_one_line_on_stderr_exit_2(tmp_path, files):
    bad = tmp_path / "bad.csv"
    bad.write_text("time_s,speed_kmh\n0,1\n1,x\n")
    proc = subprocess.run(
        [sys.executable, "-m", "cevm", "predict", "-v", str(files["bus"]), "-c", str(bad)],
        capture_output=True, text=True,
    )
    assert proc.returncode == 2
    assert proc.stdout == ""
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr
    assert f"{bad}:3: column 'speed_kmh'" in lines[0]


@pytest.mark.slow
def test_simulate_writes_per_second_csv_and_plot(files, tmp_path, root):
    import pandas as pd

    out, png = tmp_path / "sim.csv", tmp_path / "sim.png"
    res = runner.invoke(app, ["simulate", "-v", str(root / "configs/vehicles/electric-bus.toml"), "-c",
                              str(files["urban"]), "--out", str(out),
                              "--plot", str(png), "-f", "json"])
    assert res.exit_code == 0, res.output
    summary = json.loads(res.stdout)[0]
    frame = pd.read_csv(out)
    cyc = read_cycle_csv(files["urban"])
    assert len(frame) == cyc.time_s.size and {"time_s", "speed_kmh", "soc_pct", "battery_power_kw"} <= set(frame)
    # the per-second output ends at the summary's energy and state of charge (the CSV is
    # written with 6 significant digits)
    assert frame["energy_cum_kwh"].iloc[-1] == pytest.approx(summary["energy_kwh"], rel=1e-5)
    assert frame["soc_pct"].iloc[-1] == pytest.approx(summary["soc_end_pct"], rel=1e-5)
    assert summary["soc_end_pct"] < 100.0 and png.stat().st_size > 10_000
    res = runner.invoke(app, ["simulate", "-v", str(files["bus"])])
    assert res.exit_code == 2 and "--cycle or --trip" in res.output


def test_a_worker_count_beyond_the_machine_is_refused(root, tmp_path):
    import os

    limit = 4 * (os.cpu_count() or 1)
    for cmd in (["predict", "-v", str(root / "configs/vehicles/electric-bus.toml"), "-c",
                 str(root / "configs/cycles/urban-bus.csv")],
                ["ingest", str(tmp_path), "--store", str(tmp_path / "s")]):
        res = runner.invoke(app, [*cmd, "--workers", str(limit + 1)])
        assert res.exit_code == 2 and f"at most {limit} on this machine" in res.output, res.output
