"""One shape of output across commands: every JSON output writes its counts as integers
(replay wrote ``"trips": 1.0``) and its times in one ISO 8601 form (to the second, ``Z``
for UTC, else the zone's offset); feasibility's CSV numbers as predict's (fixed
decimals, no float noise such as 27.206589999999995); predict, feasibility and simulate
name their first column alike."""

from __future__ import annotations

import csv
import io
import json
import re
from pathlib import Path

import pytest
from typer.testing import CliRunner

from cevm.cli import app
from replay_cases import make_replay_store

runner = CliRunner()
ROOT = Path(__file__).resolve().parents[1]
TRUCK = str(ROOT / "configs/vehicles/electric-truck.toml")
BUS = str(ROOT / "configs/vehicles/electric-bus.toml")
HGV = str(ROOT / "configs/vehicles/diesel-hgv.toml")
URBAN = str(ROOT / "configs/cycles/urban-bus.csv")
REGIONAL = str(ROOT / "configs/cycles/regional-delivery.csv")

#: Keys that hold counts wherever a JSON output has them (a bool of the same name, such
#: as a replay row's "completes", is not a count).
COUNTS = {"trips", "duty", "charges", "draws", "missing_trips", "legs", "n_trips", "vehicles", "duties", "completes",
          "completes_at_confidence", "cannot_follow", "files", "samples", "n_samples", "days"}
#: A time as every output writes it.
ISO = re.compile(r"^\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d(Z|[+-]\d\d:\d\d)$")
#: Anything that looks like a time.
TIMEISH = re.compile(r"^\d{4}-\d\d-\d\d[T ]\d\d:")


@pytest.fixture(scope="module")
def store(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("shape")
    make_replay_store(d / "s.sqlite", d / "logs")
    return d / "s.sqlite"


def _walk(x, path: str, bad: list[str]) -> None:
    if isinstance(x, dict):
        for k, v in x.items():
            if k in COUNTS and isinstance(v, float):
                bad.append(f"{path}.{k} = {v!r} (a count)")
            _walk(v, f"{path}.{k}", bad)
    elif isinstance(x, list):
        for v in x:
            _walk(v, f"{path}[]", bad)
    elif isinstance(x, str) and TIMEISH.match(x) and not ISO.match(x):
        bad.append(f"{path} = {x!r} (not the one ISO 8601 form)")


def test_every_json_output_has_integer_counts_and_one_time_form(store, tmp_path):
    s = str(store)
    summary = tmp_path / "summary.json"
    commands = [
        ["trips", "--store", s, "-f", "json"],
        ["predict", "-v", TRUCK, "--vehicle-id", "TRK-1", "--store", s, "-f", "json"],
        ["feasibility", "-v", BUS, "-v", HGV, "-c", URBAN, "-c", REGIONAL, "-f", "json"],
        ["simulate", "-v", BUS, "-c", URBAN, "-f", "json"],
        ["replay", "-v", TRUCK, "--vehicle-id", "TRK-1", "--vehicle-id", "TRK-2", "--store", s, "-f", "json",
         "--summary", str(summary)],
        ["replay", "-v", TRUCK, "--vehicle-id", "TRK-1", "--store", s, "-f", "json", "--tz", "Asia/Tokyo"],
        ["fleet", "plan", str(ROOT / "configs/fleet/paper-case-study.toml"), "-f", "json"],
        ["vehicle", "show", TRUCK, "-f", "json"],
    ]
    bad: list[str] = []
    for args in commands:
        res = runner.invoke(app, args)
        assert res.exit_code == 0, (args, res.output)
        _walk(json.loads(res.stdout), " ".join(args[:2]), bad)
    _walk(json.loads(summary.read_text()), "replay --summary", bad)
    assert not bad, "\n".join(bad)


def test_feasibility_csv_is_written_as_predicts():
    args = ["-v", BUS, "-v", HGV, "-c", URBAN, "-c", REGIONAL, "-p", "3000", "-f", "csv"]
    pred = list(csv.DictReader(io.StringIO(runner.invoke(app, ["predict", *args]).stdout)))
    feas = list(csv.DictReader(io.StringIO(runner.invoke(app, ["feasibility", *args]).stdout)))
    assert len(pred) == len(feas) == 4
    first = {next(iter(r)) for r in pred + feas}
    assert first == {"cycle"}  # the first column named alike
    sim = runner.invoke(app, ["simulate", "-v", BUS, "-c", URBAN, "-f", "csv"]).stdout
    assert sim.startswith("cycle,")
    for p, f in zip(sorted(pred, key=lambda r: (r["cycle"], r["vehicle"])),
                    sorted(feas, key=lambda r: (r["cycle"], r["vehicle"])), strict=True):
        for key in ("distance_km", "mass_kg", "energy_kwh", "fuel_l", "power_demand_kw", "top_speed_kmh"):
            assert p[key] == f[key], (key, p[key], f[key])  # the same text: 27.20659, not 27.206589999999995
    # every number cell of feasibility's CSV has at most predict's 6 decimals
    cells = [v for r in feas for v in r.values()]
    assert not [v for v in cells if re.fullmatch(r"-?\d+\.\d{7,}", v)]


def test_simulate_table_says_whole_kilograms_and_yes_no():
    # the long-haul stand-in asks more than the truck's 235 kW at 18 t
    res = runner.invoke(app, ["simulate", "-v", HGV, "-c", str(ROOT / "configs/cycles/long-haul-standin.csv")])
    assert res.exit_code == 0, res.output
    out = res.stdout
    assert "18,000 " in out and "18,000.000" not in out and "True" not in out and "False" not in out
    assert "NO (cannot follow: power)" in out  # the verdict as predict's table says it
