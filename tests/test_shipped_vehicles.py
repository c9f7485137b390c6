"""The shipped vehicle files give realistic figures: each file's [[reference]] cases
(a shipped cycle, a gross mass, a published real-world range with its source) hold for
cevm's own predictions, on cycles the vehicle can follow; the paper's files stay the
paper's (eq. 24 for the truck, no auxiliaries for the bus), labelled as such."""

from __future__ import annotations

from pathlib import Path

import pytest

from cevm.core.sweep import PredictionSet, Source, predict_source
from cevm.io import load_vehicle, load_vehicles, read_cycle_csv

ROOT = Path(__file__).resolve().parents[1]
VEHICLES = sorted((ROOT / "configs/vehicles").glob("*.toml"))
REALISTIC = [p for p in VEHICLES if not p.stem.endswith("-paper")]


def _cases():
    for path in REALISTIC:
        for i, case in enumerate(load_vehicle(path).extra.get("reference", [])):
            yield pytest.param(path, case, id=f"{path.stem}[{i}]:{case.get('cycle')}@{case.get('mass_kg')}")


def test_every_realistic_file_states_its_ranges_with_sources():
    assert {p.stem for p in REALISTIC} >= {"diesel-hgv", "electric-bus", "renault-twizy"}
    for path in REALISTIC:
        cases = load_vehicle(path).extra.get("reference", [])
        assert cases, f"{path.name} states no [[reference]] range"
        for c in cases:
            assert set(c) >= {"cycle", "mass_kg", "range", "unit", "source"}, c
            lo, hi = c["range"]
            assert 0 < lo < hi and len(c["source"]) > 40
            assert (ROOT / "configs/cycles" / f"{c['cycle']}.csv").exists()


@pytest.mark.parametrize("path, case", list(_cases()))
def test_consumption_lies_in_the_published_range(path, case):
    v = load_vehicle(path)
    src = Source.from_cycle(read_cycle_csv(ROOT / "configs/cycles" / f"{case['cycle']}.csv"))
    b = predict_source(src, PredictionSet.build([v], mass_kg=[case["mass_kg"]]))
    assert not (b.over_power is not None and b.over_power[0] == 1.0), "a reference case the vehicle cannot follow"
    assert not (b.over_speed is not None and b.over_speed[0] == 1.0)
    km = src.distance_m / 1e3
    if case["unit"] == "kWh/km":
        value = b.energy_j[0] / 3.6e6 / km
    else:
        assert case["unit"] == "l/100km"
        value = 100.0 * b.fuel_l[0] / km
    lo, hi = case["range"]
    assert lo <= value <= hi, f"{path.name} on {case['cycle']} at {case['mass_kg']} kg: {value:.3f} {case['unit']}"


def test_the_papers_files_are_the_papers_and_say_so():
    truck = load_vehicle(ROOT / "configs/vehicles/diesel-hgv-paper.toml")
    assert (truck.ice_braking, truck.eta, truck.cda_m2, truck.cr) == ("paper", 0.45, 6.62, 0.0066)
    assert "paper" in truck.name and truck.id == "diesel-hgv-paper"
    bus = load_vehicle(ROOT / "configs/vehicles/electric-bus-paper.toml")
    assert (bus.eta, bus.cda_m2, bus.cr, bus.mass_kg, bus.aux_power_w) == (0.78, 3.99, 0.0066, 9825.0, 0.0)
    assert "paper" in bus.name


def test_the_default_truck_credits_no_braking_energy():
    assert load_vehicle(ROOT / "configs/vehicles/diesel-hgv.toml").ice_braking == "no-credit"


def test_the_papers_case_study_keeps_the_papers_mode():
    text = (ROOT / "configs/fleet/paper-case-study.toml").read_text()
    assert "diesel-hgv-paper.toml" in text and '"../vehicles/diesel-hgv.toml"' not in text


def test_all_shipped_files_load_together_with_distinct_ids():
    ids = [v.id for v in load_vehicles([ROOT / "configs/vehicles"])]
    assert len(ids) == len(set(ids)) == len(VEHICLES)


# ------------------------------------------------------------------ cevm vehicle show

def test_vehicle_show_prints_parameters_sources_figures_and_ranges():
    import json

    from typer.testing import CliRunner

    from cevm.cli import app

    res = CliRunner().invoke(app, ["vehicle", "show", str(ROOT / "configs/vehicles/diesel-hgv.toml"), "-f", "json"])
    assert res.exit_code == 0, res.output
    r = json.loads(res.stdout)
    assert r["id"] == "diesel-hgv" and r["powertrain"] == "ice"
    params = {p["parameter"]: p for p in r["parameters"]}
    assert params["cda_m2"]["value"] == "6.62" and params["cda_m2"]["basis"] == "Paper, section 5.2"
    assert params["kerb_mass_kg"]["basis"] == "Paper, section 5.2"  # the [sources] 'mass' entry
    loads = {(c["cycle"], c["load"]): c for c in r["consumption"]}
    cycles = {p.stem for p in (ROOT / "configs/cycles").glob("*.csv")}
    assert {c for c, _ in loads} == cycles and {lo for _, lo in loads} == {"kerb", "max gross"}
    kerb, full = loads[("urban-bus", "kerb")], loads[("urban-bus", "max gross")]
    assert (kerb["mass_kg"], full["mass_kg"]) == (18000.0, 44000.0)
    assert full["fuel_l_per_100km"] > kerb["fuel_l_per_100km"] > 0 and full["cannot_follow"] == "power"
    # the same figure predict gives
    p = CliRunner().invoke(app, ["predict", "-v", str(ROOT / "configs/vehicles/diesel-hgv.toml"), "-c",
                                 str(ROOT / "configs/cycles/urban-bus.csv"), "-f", "json"])
    assert json.loads(p.stdout)[0]["fuel_l_per_100km"] == pytest.approx(kerb["fuel_l_per_100km"], rel=1e-12)
    assert all(ref["within"] for ref in r["reference"]) and r["terms"][0]["term"] == "idle_fuel_lph"
    table = CliRunner().invoke(app, ["vehicle", "show", str(ROOT / "configs/vehicles/renault-twizy.toml")])
    assert table.exit_code == 0 and "cannot follow" in table.output and "refuses this file" in table.output


def test_vehicle_show_prints_the_calibration_table(tmp_path):
    import json

    from typer.testing import CliRunner

    from cevm.cli import app

    p = tmp_path / "cal.toml"
    p.write_text((ROOT / "configs/vehicles/electric-bus.toml").read_text().replace(
        "[sources]", '[calibration]\nterms = ["eta"]\nn_trips = 9\nmass_kg = [9825, 9825]\n\n[sources]', 1))
    r = json.loads(CliRunner().invoke(app, ["vehicle", "show", str(p), "-f", "json"]).stdout)
    assert r["calibration"]["n_trips"] == 9 and r["id"] == "cal"
    bad = CliRunner().invoke(app, ["vehicle", "show", str(tmp_path / "none.toml")])
    assert bad.exit_code == 2 and "not found" in bad.output
