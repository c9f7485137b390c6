"""Priors and posteriors in vehicle files (cevm.io.priors): the shipped class defaults, a
file's class (or the one its mass implies, said so), its [prior] table, the checks of
both, and the [posterior] table a calibration writes, read back as it was written."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from typer.testing import CliRunner

from cevm.cli import app
from cevm.core.uncertainty import VEHICLE_CLASSES, Posterior, Scatter
from cevm.core.vehicle import coefficients
from cevm.errors import InputError
from cevm.io import load_vehicle
from cevm.io.priors import class_defaults, posterior_table
from cevm.io.vehicles import vehicle_from_mapping

BUS = dict(name="bus", powertrain="ev", kerb_mass_kg=9000.0, payload_kg=825.0, cda_m2=3.99, cr=0.0066, eta=0.78,
           battery_kwh=124.0)
TRUCK = dict(name="truck", powertrain="ice", kerb_mass_kg=18000.0, cda_m2=6.62, cr=0.0066, eta=0.38,
             fuel_lhv_mj_per_l=35.8)


def test_every_class_has_every_terms_range_with_a_source_and_inside_physics():
    d = class_defaults()
    for cls in VEHICLE_CLASSES:
        for pt in ("ev", "ice"):
            terms, scatter, _spec = d["classes"][(cls, pt)]  # and the spec-sheet factors
            assert "eta" in terms and scatter.aux > 0 and 0 < scatter.share < 0.5
            for p in terms.values():
                assert p.low <= p.high and p.source


@pytest.mark.parametrize("mass, pt, cls", [(500.0, "ev", "quadricycle"), (1800.0, "ev", "car"),
                                           (3500.0, "ice", "van"), (12000.0, "ev", "bus"), (18000.0, "ice", "truck")])
def test_the_class_of_a_file_without_one_follows_its_mass_and_says_so(mass, pt, cls):
    base = BUS if pt == "ev" else TRUCK
    data = {k: v for k, v in base.items() if k not in ("kerb_mass_kg", "payload_kg")}
    v = vehicle_from_mapping({**data, "mass_kg": mass}, "v.toml")
    assert v.vehicle_class == cls and v.priors.vehicle_class == cls
    assert "inferred from its mass" in v.priors.class_from
    own = vehicle_from_mapping({**data, "mass_kg": mass, "class": "van"}, "v.toml")
    assert own.vehicle_class == "van" and own.priors.class_from == "vehicle file"


def test_a_prior_table_overrides_its_keys_and_keeps_the_class_for_the_rest():
    v = vehicle_from_mapping({**BUS, "class": "bus", "prior": {
        "eta": [0.75, 0.85], "aux_power_kw": [3.0, 6.0], "scatter_aux_kw": 1.0,
        "sources": {"eta": "the maker's data sheet"}}}, "v.toml")
    p = v.priors
    assert (p.get("eta").low, p.get("eta").high) == (0.75, 0.85) and "data sheet" in p.get("eta").source
    assert (p.get("aux").low, p.get("aux").high) == (3000.0, 6000.0)
    bus = class_defaults()["classes"][("bus", "ev")][0]
    assert p.get("heat") == bus["heat"] and p.scatter.aux == 1000.0


@pytest.mark.parametrize("prior, words", [
    ({"eta": [0.8, 0.95]}, "leaves the physical range 0.3 to 0.89"),
    ({"eta": [0.9, 0.8]}, "low <= high"),
    ({"aux_power_kw": [-1.0, 2.0]}, "physical range"),
    ({"idle_fuel_lph": [1.0, 2.0]}, "unknown key 'prior.idle_fuel_lph'"),
    ({"scatter_aux_lph": 1.0}, "an EV vehicle's is 'scatter_aux_kw'"),
    ({"scatter_share": 0}, "must be a number > 0"),
])
def test_a_prior_that_physics_or_the_format_refuses_names_its_key(prior, words):
    with pytest.raises(InputError, match="prior"):
        try:
            vehicle_from_mapping({**BUS, "prior": prior}, "v.toml")
        except InputError as exc:
            assert words in str(exc)
            raise


def test_an_unknown_class_is_refused():
    with pytest.raises(InputError, match="key 'class' must be one of bus, truck, van, car, quadricycle"):
        vehicle_from_mapping({**BUS, "class": "tram"}, "v.toml")


def test_a_posterior_table_reads_back_as_written():
    v = vehicle_from_mapping({**BUS, "aux_power_kw": 4.0, "aux_heating_kw_per_k": 0.3}, "v.toml")
    terms = ("eta", "aux", "heat")
    coef = coefficients(v, terms)
    rng = np.random.default_rng(1)
    a = rng.normal(size=(3, 3)) * np.array([0.02, 300.0, 40.0])
    cov = a.T @ a  # some covariance of the coefficients
    p = Posterior(terms, cov, Scatter(700.0, 0.03, 0.6, "estimated"), "calibrated on 9 trips of X", 9,
                  meter_share=0.01)
    table = posterior_table(p, v)
    back = vehicle_from_mapping({**BUS, "aux_power_kw": 4.0, "aux_heating_kw_per_k": 0.3, "posterior": table},
                                "v.toml").posterior
    assert back.terms == terms and back.n_trips == 9 and back.source == p.source
    assert back.cov == pytest.approx(cov, rel=1e-4, abs=1e-12 * np.abs(cov).max())
    assert (back.scatter.aux, back.scatter.share, back.scatter.day_corr) == pytest.approx((700.0, 0.03, 0.6))
    assert back.meter_share == 0.01 and np.all(np.isfinite(coef))


@pytest.mark.parametrize("change, words", [
    ({"terms": ["eta", "nope"]}, "must list the model's terms"),
    ({"std": [1.0]}, "must hold 2 numbers"),
    ({"correlation": [[1.0, 2.0], [2.0, 1.0]]}, "symmetric 2 x 2 matrix of correlations"),
    ({"correlation": [[1.0, 0.99], [-0.99, 1.0]]}, "symmetric"),
])
def test_a_broken_posterior_table_is_refused(change, words):
    table = {"terms": ["eta", "aux"], "std": [0.01, 300.0], "correlation": [[1.0, 0.1], [0.1, 1.0]],
             "n_trips": 5, "scatter": {"aux_kw": 0.5, "share": 0.03}}
    with pytest.raises(InputError, match="posterior"):
        try:
            vehicle_from_mapping({**BUS, "aux_power_kw": 4.0, "posterior": {**table, **change}}, "v.toml")
        except InputError as exc:
            assert words in str(exc)
            raise


def test_shipped_files_have_priors_and_no_posterior(root):
    for f in sorted((root / "configs" / "vehicles").glob("*.toml")):
        v = load_vehicle(f)
        assert v.priors is not None and v.posterior is None, f.name


@pytest.mark.slow
def test_calibrate_writes_what_reads_back_and_reports_its_intervals(tmp_path, root):
    """cevm calibrate on the sample HGV-11: every held-out row has an ordered interval,
    the summary's coverage counts them, the file says how many candidates there were and
    how many were compared as the table does, carries [sources] for what it
    changed, and reads back with its posterior."""
    from cevm.ingest import IngestOptions, ingest
    from cevm.store import TripStore

    store = tmp_path / "s.sqlite"
    with TripStore.open(store) as st:
        ingest([p for p in sorted((root / "sample_logs" / "srf").iterdir()) if "HGV-11" in p.name], st,
               IngestOptions(dsm=str(root / "sample_logs" / "dsm")))
    out = tmp_path / "hgv.toml"
    args = ["calibrate", "-v", str(root / "configs/vehicles/diesel-hgv.toml"), "--vehicle-id", "HGV-11",
            "--store", str(store), "--no-nested", "--out", str(out)]
    res = CliRunner().invoke(app, [*args, "-f", "json"])
    assert res.exit_code == 0, res.output
    r = json.loads(res.stdout)
    held = [row for row in r["trips"] if row["held_out"]]
    assert held and all(row["predicted_low"] < row["predicted"] < row["predicted_high"] for row in held)
    assert all(row["inside"] == (row["predicted_low"] <= row["measured"] <= row["predicted_high"]) for row in held)
    cov = r["coverage"]
    assert cov["inside"] == sum(row["inside"] for row in held) and cov["trips"] == len(held) and cov["level"] == 0.9
    text = out.read_text()
    import tomllib

    data = tomllib.loads(text)
    assert data["calibration"]["candidates"] == r["candidates_total"] == len(r["candidates"])
    assert data["calibration"]["candidates_compared"] == r["candidates_compared"]
    assert data["calibration"]["cv_coverage"] == pytest.approx(cov["share"], abs=1e-3)
    assert data["sources"]["idle_fuel_lph"].startswith("cevm calibrate, calibrated on")
    assert "1.5-3 l/h" not in data["sources"]["idle_fuel_lph"]
    back = load_vehicle(out)
    assert back.posterior is not None and back.posterior.n_trips == r["n_trips"]
    assert back.posterior.terms == tuple(r["terms"]) and math.isclose(back.eta, r["eta"], rel_tol=1e-5)
    # the template's comment that introduces [[reference]] still does (new sources go before it)
    lines = text.splitlines()
    at = next(i for i, line in enumerate(lines) if line.startswith("# Published real-world consumption"))
    assert next(line for line in lines[at:] if not line.startswith("#")) == "[[reference]]"
    # vehicle show says where its intervals come from
    shown = json.loads(CliRunner().invoke(app, ["vehicle", "show", str(out), "-f", "json"]).stdout)
    assert shown["uncertainty"]["interval_from"] == "posterior"
    assert shown["uncertainty"]["source"].startswith(f"calibrated on {r['n_trips']} trips of HGV-11")
    shipped = CliRunner().invoke(app, ["vehicle", "show", str(root / "configs/vehicles/diesel-hgv.toml"), "-f", "json"])
    assert json.loads(shipped.stdout)["uncertainty"]["interval_from"] == "prior"
    # the table says the same counts
    res = CliRunner().invoke(app, args[:-2])
    assert res.exit_code == 0, res.output
    assert f"{r['candidates_total']} candidates, {r['candidates_compared']} compared" in res.stdout.replace("\n", " ")
    assert "held-out trips inside their 90 % interval" in res.stdout


@pytest.mark.slow
def test_forced_fits_respect_the_physical_bounds(tmp_path, root):
    """--fit eta,kin once wrote a diesel eta of 1.0 and --fit eta,run 0.55-0.66
    with exit 0. Forced fits now start from the class's priors and stay inside the
    physical ranges (a fit the data push beyond them is refused, exit 2:
    tests/test_selection.py)."""
    from cevm.ingest import IngestOptions, ingest
    from cevm.store import TripStore

    store = tmp_path / "s.sqlite"
    with TripStore.open(store) as st:
        ingest([p for p in sorted((root / "sample_logs" / "srf").iterdir()) if "HGV-11" in p.name], st,
               IngestOptions(dsm=str(root / "sample_logs" / "dsm")))
    for forced, key in (("eta,kin", "kinetic_eta"), ("eta,run", "running_fuel_lps")):
        out = tmp_path / f"{key}.toml"
        res = CliRunner().invoke(app, ["calibrate", "-v", str(root / "configs/vehicles/diesel-hgv.toml"),
                                       "--vehicle-id", "HGV-11", "--store", str(store), "--fit", forced,
                                       "--no-nested", "--out", str(out)])
        assert res.exit_code == 0, res.output
        v = load_vehicle(out)
        assert 0.1 <= v.eta <= 0.55
        assert 0.05 <= (v.kinetic_eta if key == "kinetic_eta" else 0.5) <= 0.8
        assert 0.0 <= v.running_fuel_lps * 3600 <= 30.0
