"""No silent fallbacks: a percent option given as a fraction is warned about (one line
per option, saying how it reads), in every command that takes one; fleet plan says an
electric fleet's energy in kWh and names the vehicle, route and limit that make a day
infeasible."""

from __future__ import annotations

import csv
import io
import json
import re
from pathlib import Path

import pytest
from typer.testing import CliRunner

from cevm.cli import app

runner = CliRunner()
ROOT = Path(__file__).resolve().parents[1]
BUS = str(ROOT / "configs/vehicles/electric-bus.toml")
URBAN = str(ROOT / "configs/cycles/urban-bus.csv")


@pytest.mark.parametrize("command", [["predict", "-c", URBAN], ["feasibility", "-c", URBAN],
                                     ["simulate", "-c", URBAN]])
def test_a_percent_given_as_a_fraction_is_warned_about(command):
    res = runner.invoke(app, [command[0], "-v", BUS, *command[1:], "--soc-start", "0.8", "--reserve-pct", "0.15"])
    lines = [line for line in res.stderr.splitlines() if "reads as" in line]
    assert lines == ["cevm: warning: --soc-start 0.8 reads as 0.8 % (a percentage, not a fraction); for 80 % give "
                     "--soc-start 80",
                     "cevm: warning: --reserve-pct 0.15 reads as 0.15 % (a percentage, not a fraction); for 15 % "
                     "give --reserve-pct 15"]
    res = runner.invoke(app, [command[0], "-v", BUS, *command[1:], "--soc-start", "80", "--reserve-pct", "0"])
    assert "reads as" not in res.stderr


def _ev_scenario(tmp_path: Path, **changes: str) -> Path:
    """The paper's case study with the shipped electric tractor (its keys changed as
    given) for every truck, the energy as the objective."""
    vehicle = (ROOT / "configs/vehicles/electric-truck.toml").read_text()
    for key, value in changes.items():
        vehicle = re.sub(rf"(?m)^{key} = [0-9.]+", f"{key} = {value}", vehicle)
    (tmp_path / "ev.toml").write_text(vehicle)
    text = (ROOT / "configs/fleet/paper-case-study.toml").read_text()
    text = text.replace('objective = "fuel"', 'objective = "energy"')
    text = text.replace("../vehicles/diesel-hgv-paper.toml", str(tmp_path / "ev.toml"))
    text = text.replace("../cycles/", str(ROOT / "configs/cycles") + "/")
    path = tmp_path / "scenario.toml"
    path.write_text(text)
    return path


def test_fleet_plan_says_an_electric_fleet_in_kwh(tmp_path):
    sc = _ev_scenario(tmp_path)
    res = runner.invoke(app, ["fleet", "plan", str(sc), "-f", "json"])
    assert res.exit_code == 0, res.output
    plan = json.loads(res.stdout)["plans"][0]
    kwh = {v["vehicle"]: v["energy_kwh"] for v in plan["vehicles"]}
    res = runner.invoke(app, ["fleet", "plan", str(sc), "-f", "csv"])
    rows = [r for r in csv.DictReader(io.StringIO(res.stdout)) if r["day"] == plan["day"]]
    assert {r["vehicle"]: float(r["consumption_kWh"]) for r in rows} == pytest.approx(kwh)
    res = runner.invoke(app, ["fleet", "plan", str(sc)])
    assert "consumption per vehicle [kWh]" in res.stdout and "total kWh" in res.stdout
    assert "[J]" not in res.stdout and "total J" not in res.stdout


@pytest.mark.parametrize("method", ["enumerate", "milp"])
def test_fleet_plan_names_the_vehicle_route_and_limit_of_an_infeasible_day(tmp_path, method):
    res = runner.invoke(app, ["fleet", "plan", str(_ev_scenario(tmp_path, battery_kwh="60.0")), "--day", "1",
                              "--method", method])
    # 60 kWh, 51 above the 15 % reserve: HGV1's long-haul route asks more whatever it serves
    assert re.search(r"not planned: day 'day 1': .*\(HGV1 on route 'LH1': at least [\d.]+ kWh, over the 51\.0 kWh of "
                     r"its battery above the reserve\)", res.stderr), res.stderr
    res = runner.invoke(app, ["fleet", "plan", str(_ev_scenario(tmp_path, max_power_kw="150.0")), "--day", "1"])
    assert "NO (cannot follow: power on route LH1 leg depot -> LH1S1/R1S2, " in " ".join(res.stdout.split())


def test_calibrate_compares_with_the_paper_only_where_it_has_a_row(tmp_path):
    # the paper's tables 1 and 2 are an electric bus's and a diesel HGV's: a quadricycle
    # (or a car) has no row, and its report had the bus's beside it
    store = tmp_path / "s.sqlite"
    assert runner.invoke(app, ["ingest", str(ROOT / "tests/data/twizy"), "--store", str(store), "-q"]).exit_code == 0
    res = runner.invoke(app, ["calibrate", "-v", str(ROOT / "configs/vehicles/renault-twizy.toml"), "--vehicle-id",
                              "RSK-Twizy", "--store", str(store)])
    assert res.exit_code == 0, res.output
    out = " ".join(res.stdout.split())
    assert "paper (" not in out and "table 1" in out
    assert ("the paper has CE-model errors for an electric bus (table 1) and a diesel HGV (table 2) only: none to "
            "compare an electric quadricycle with") in out
