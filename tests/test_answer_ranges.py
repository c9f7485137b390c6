"""Every answer with its range: predict's and feasibility's intervals,
their probabilities, and the rows that say where the interval comes from and what they
extrapolate.

The probability of keeping the reserve is checked against its frequency in simulation:
vehicles drawn from the posterior a row is given, each with the trip scatter it assumes,
driven over the cycle with the CE model itself.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import json

import numpy as np
import pytest
from typer.testing import CliRunner

from cevm.cli import app
from cevm.core.intervals import block_ranges, p_reserve_ok, p_tank_ok
from cevm.core.sweep import PredictionSet, Source, sweep
from cevm.core.uncertainty import Posterior, Scatter
from cevm.core.vehicle import FitDomain, coefficients, predict
from cevm.io import load_vehicle, read_cycle_csv

runner = CliRunner()


def _calibrated_bus(root, margin: float = 1.0):
    """The shipped bus with a posterior over eta, aux, heat (a calibration's) and a battery
    whose reserve is at stake on the urban cycle at 12 t and 5 degC (its 85 % is
    ``margin`` times what the cycle needs there)."""
    bus = load_vehicle(root / "configs/vehicles/electric-bus.toml")
    bus = dataclasses.replace(bus, aux_heating_w_per_k=300.0)
    vec = Source.from_cycle(read_cycle_csv(root / "configs/cycles/urban-bus.csv")).vector
    need = float(predict(vec, bus, 12000.0, ambient_c=5.0).energy_j)
    bus = dataclasses.replace(bus, battery_j=margin * need / 0.85)
    terms = ("eta", "aux", "heat")
    cov = np.diag([0.04, 600.0, 80.0]) ** 2
    cov[0, 1] = cov[1, 0] = -0.3 * 0.04 * 600.0
    post = Posterior(terms, cov, Scatter(700.0, 0.04, 0.6), "calibrated on 30 trips of TEST", 30, priors=bus.priors)
    dom = FitDomain(terms=terms, n_trips=30, ambient_c=(-2.0, 25.0), mass_kg=(9000.0, 13000.0),
                    mean_speed_mps=(4.0, 8.0), idle_share=(0.1, 0.4))
    return dataclasses.replace(bus, posterior=post, calibration=dom)


@pytest.mark.slow
def test_p_reserve_ok_is_the_frequency_in_simulation(root):
    """Draw vehicles from the posterior and trips from the scatter: the share that keeps
    the reserve all along (each drawn vehicle's lowest state of charge on the cycle,
    its scatter in proportion to the energy drawn until then) equals p_reserve_ok
    (2000 draws: +-0.035 is 3 sigma)."""
    bus = _calibrated_bus(root)
    src = Source.from_cycle(read_cycle_csv(root / "configs/cycles/urban-bus.csv"))
    masses = [11500.0, 12500.0]
    pset = PredictionSet.build([bus], mass_kg=masses, ambient_c=5.0)
    (block,) = sweep([src], pset, soc_start_pct=100.0, reserve_pct=15.0)
    p = p_reserve_ok(block, block_ranges(block), 100.0, 15.0)
    assert np.all((p > 0.05) & (p < 0.95))  # the reserve is at stake: a test of the middle, not of 0 or 1
    rng = np.random.default_rng(1)
    post = bus.posterior
    draws = rng.multivariate_normal(coefficients(bus, post.terms), post.cov, 2000)
    fleet = [dataclasses.replace(bus, eta=1.0 / c[0], aux_power_w=c[1], aux_heating_w_per_k=c[2], id=f"d{i}")
             for i, c in enumerate(draws)]
    for j, m in enumerate(masses):
        (b,) = sweep([src], PredictionSet.build(fleet, mass_kg=[m], ambient_c=5.0), soc_start_pct=100.0,
                     reserve_pct=15.0)
        e_min = (100.0 - b.soc_min_pct) / 100.0 * bus.battery_j
        noise = (post.scatter.aux * src.duration_s * rng.standard_normal(len(fleet))
                 + post.scatter.share * b.energy_j * rng.standard_normal(len(fleet)))
        kept = e_min * (1.0 + noise / b.energy_j) <= 0.85 * bus.battery_j
        assert float(p[j]) == pytest.approx(float(np.mean(kept)), abs=0.035), m


@pytest.mark.slow
def test_predict_rows_carry_ordered_intervals_in_csv_json_and_the_table(root, tmp_path):
    shipped = root / "configs/vehicles/electric-bus.toml"
    hgv = root / "configs/vehicles/diesel-hgv.toml"
    args = ["predict", "-v", str(shipped), "-v", str(hgv), "-c", str(root / "configs/cycles/urban-bus.csv"),
            "-p", "0,3000"]
    res = runner.invoke(app, [*args, "-f", "json"])
    assert res.exit_code == 0, res.output
    rows = json.loads(res.stdout)
    for r in rows:
        assert r["interval"] == 0.9 and r["interval_from"] == "prior" and r["extrapolation"] == "none"
        if r["powertrain"] == "ev":
            assert r["energy_kwh_low"] < r["energy_kwh"] < r["energy_kwh_high"]
            assert r["soc_end_pct_low"] < r["soc_end_pct"] < r["soc_end_pct_high"]
            assert 0.0 <= r["p_reserve_ok"] <= 1.0 and "fuel_l_low" not in r
        else:
            assert r["fuel_l_low"] < r["fuel_l"] < r["fuel_l_high"]
            assert r["fuel_left_l_low"] < r["fuel_left_l_high"] and 0.0 <= r["p_tank_ok"] <= 1.0
    wide = runner.invoke(app, [*args, "-f", "json", "--interval", "0.99"])
    for a, b in zip(rows, json.loads(wide.stdout), strict=True):
        key = "energy_kwh" if a["powertrain"] == "ev" else "fuel_l"
        assert b[f"{key}_low"] < a[f"{key}_low"] and b[f"{key}_high"] > a[f"{key}_high"]
    text = runner.invoke(app, [*args, "-f", "csv"]).stdout
    got = list(csv.DictReader(io.StringIO(text)))
    assert [float(r["energy_kwh_low"] or r["fuel_l_low"]) for r in got] == pytest.approx(
        [r.get("energy_kwh_low", r.get("fuel_l_low")) for r in rows], rel=1e-6)
    table = runner.invoke(app, args)
    assert table.exit_code == 0
    for r in rows:  # the table's interval column: half its width, from the JSON's ends
        key, unit = ("energy_kwh", "kWh") if r["powertrain"] == "ev" else ("fuel_l", "l")
        assert f"+-{(r[f'{key}_high'] - r[f'{key}_low']) / 2:,.2f} {unit}" in table.stdout
    assert "+- (90 %)" in table.stdout
    # the table's status says the probability where the verdict is not sure
    from cevm.cli.predict import with_status

    base = {"powertrain": "ev", "reserve_ok": True, "feasible": True, "over_max_gross": False, "interval_from": "prior"}
    assert with_status({**base, "p_reserve_ok": 0.9996})["status"] == "yes"
    assert with_status({**base, "p_reserve_ok": 0.862})["status"] == "yes (P 0.86)"
    assert with_status({**base, "p_reserve_ok": 0.862, "interval_from": "none"})["status"] == "yes"
    bad = runner.invoke(app, [*args, "--interval", "1.5"])
    assert bad.exit_code == 2 and "--interval must be a level between 0 and 1" in bad.output


def test_a_calibrated_file_says_posterior_and_what_it_extrapolates(root, tmp_path):
    from cevm.io.calibrated import write_calibrated_vehicle  # noqa: F401 (the file's writer is the real one)
    from cevm.io.priors import posterior_table

    bus = _calibrated_bus(root)
    src = tmp_path / "cal.toml"
    text = (root / "configs/vehicles/electric-bus.toml").read_text()
    import tomlkit

    doc = tomlkit.parse(text)
    doc["battery_kwh"] = 16.0
    doc["aux_heating_kw_per_k"] = 0.3
    doc["posterior"] = posterior_table(bus.posterior, bus)
    doc["calibration"] = {"terms": ["eta", "aux", "heat"], "n_trips": 30, "ambient_c": [-2.0, 25.0],
                          "mass_kg": [9000.0, 13000.0], "mean_speed_kmh": [14.4, 28.8], "idle_share": [0.1, 0.4]}
    src.write_text(tomlkit.dumps(doc))
    res = runner.invoke(app, ["predict", "-v", str(src), "-c", str(root / "configs/cycles/urban-bus.csv"), "-m",
                              "12000,20000", "--ambient-c", "-10", "-f", "json"])
    assert res.exit_code == 0, res.output
    a, b = json.loads(res.stdout)
    assert a["interval_from"] == b["interval_from"] == "posterior"
    assert a["extrapolation"] == "temperature" and b["extrapolation"] == "temperature+mass"
    assert "an extrapolation" in res.stderr if hasattr(res, "stderr") else True


def test_the_interval_widens_beyond_the_calibrations_coldest_trip(root):
    """Colder than the calibration saw: the heating line may bend, and the interval says
    so (no change of the point prediction)."""
    from cevm.core.predictive import Features, predictive

    bus = _calibrated_bus(root)
    vec = Source.from_cycle(read_cycle_csv(root / "configs/cycles/urban-bus.csv")).vector
    plain = dataclasses.replace(bus, calibration=None)
    for t in (-1.0, -12.0):
        f = Features.of(vec, bus, [11000.0], [t])
        inside, beyond = predictive(plain, f), predictive(bus, f)
        assert beyond.mean[0] == inside.mean[0]
        assert (beyond.sd[0] > inside.sd[0]) == (t < -2.0)


def test_feasibility_at_a_confidence(root):
    """At confidence 0.95 the largest payload is smaller than the point prediction's
    (0.5), the verdict holds where p_reserve_ok >= 0.95, and 0.5 is the old verdict."""
    from cevm.core.feasibility import feasibility

    # without a gross-weight limit, so that the reserve is what limits the payload
    bus = dataclasses.replace(_calibrated_bus(root, margin=1.3), max_gross_kg=None)
    src = Source.from_cycle(read_cycle_csv(root / "configs/cycles/urban-bus.csv"))
    point = feasibility(src, [bus], payload_kg=2500.0, ambient_c=5.0)
    sure = feasibility(src, [bus], payload_kg=2500.0, ambient_c=5.0, confidence=0.95)
    assert point.max_payload_kg[0] > sure.max_payload_kg[0] >= 0
    assert point.energy_j[0] == sure.energy_j[0] and point.p_ok[0] == sure.p_ok[0]
    assert bool(sure.feasible[0]) == (sure.p_ok[0] >= 0.95)
    assert bool(point.feasible[0]) == (point.soc_min_pct[0] >= 15.0)
    # the largest payload at 0.95 keeps the reserve with probability 0.95 there, not 1 kg more
    at = feasibility(src, [bus], payload_kg=float(sure.max_payload_kg[0]), ambient_c=5.0, confidence=0.95)
    over = feasibility(src, [bus], payload_kg=float(sure.max_payload_kg[0]) + 1.0, ambient_c=5.0, confidence=0.95)
    assert at.p_ok[0] >= 0.95 > over.p_ok[0]


def test_feasibility_cli_says_its_confidence(root):
    args = ["feasibility", "-v", str(root / "configs/vehicles/electric-bus.toml"), "-c",
            str(root / "configs/cycles/urban-bus.csv")]
    res = runner.invoke(app, [*args, "-f", "json"])
    assert res.exit_code == 0, res.output
    (row,) = json.loads(res.stdout)
    assert row["confidence"] == 0.95 and row["interval_from"] == "prior" and row["extrapolation"] == "none"
    assert row["energy_kwh_low"] < row["energy_kwh"] < row["energy_kwh_high"] and 0 <= row["p_reserve_ok"] <= 1
    table = runner.invoke(app, args)
    assert "at confidence 0.95" in table.output
    bad = runner.invoke(app, [*args, "--confidence", "0.3"])
    assert bad.exit_code == 2 and "--confidence must be at least 0.5" in bad.output


def test_a_vehicle_without_priors_has_no_interval(root):
    """A vehicle built in code without a class: the rows say none, and the interval is the
    point."""
    bus = dataclasses.replace(load_vehicle(root / "configs/vehicles/electric-bus.toml"), priors=None)
    src = Source.from_cycle(read_cycle_csv(root / "configs/cycles/urban-bus.csv"))
    (block,) = sweep([src], PredictionSet.build([bus]))
    rr = block_ranges(block)
    assert np.all(rr.sd == 0) and rr.source.tolist() == [2]
    assert p_tank_ok(block, rr).tolist() == [pytest.approx(np.nan, nan_ok=True)]


@pytest.mark.slow
def test_fleet_plan_with_a_chance_constraint_is_the_optimum_of_plain_enumeration():
    """Random EV fleets whose batteries make some assignments unsure: with
    min_p_complete, the enumeration's and the MILP's (no-good cuts) plans equal the
    cheapest assignment whose every day completes with that probability, found by
    trying them all with the exact evaluation; and every plan reports p_complete."""
    import itertools
    import math
    import random

    from cevm.core.assignment import evaluate, plan
    from cevm.core.assignment.chance import p_complete
    from cevm.core.uncertainty import Priors, ScatterPrior, TermPrior
    from cevm.errors import InputError
    from test_fleet import random_scenario, small_vectors

    priors = Priors("bus", "test", (TermPrior("eta", 0.72, 0.86), TermPrior("aux", 0.0, 3000.0),
                                    TermPrior("heat", 0.0, 400.0), TermPrior("cool", 0.0, 300.0)),
                    ScatterPrior(800.0, 0.04))
    vectors = small_vectors.__wrapped__() if hasattr(small_vectors, "__wrapped__") else small_vectors()
    rng = random.Random("chance")
    tested = 0
    for _ in range(20):
        sc = random_scenario(rng, vectors, "ev", "carried")
        sc = dataclasses.replace(sc, vehicles=tuple(dataclasses.replace(v, vehicle=dataclasses.replace(
            v.vehicle, priors=priors)) for v in sc.vehicles))
        free = [s for s in sc.stops() if len(sc.options(s)) > 1]
        best, best_total = None, math.inf
        for combo in itertools.product(*(sc.options(s) for s in free)):
            ev = evaluate(sc, 0, dict(zip(free, combo, strict=True)))
            ps = p_complete(sc, 0, ev)
            if ev.feasible and all(p is None or p >= 0.85 for p in ps.values()) and ev.total < best_total:
                best, best_total = combo, ev.total
        for method in ("enumerate", "milp"):
            if best is None:
                with pytest.raises(InputError):
                    plan(sc, 0, method=method, min_p_complete=0.85)
                continue
            p = plan(sc, 0, method=method, min_p_complete=0.85)
            assert p.total == pytest.approx(best_total, rel=1e-9)
            assert all(x is None or x >= 0.85 for x in p.p_complete.values())
        plain = plan(sc, 0) if plan_feasible(sc) else None
        if plain is not None and best is not None:
            tested += plain.total < best_total - 1e-9  # the constraint changed the plan
            assert set(plain.p_complete) == {v.id for v in sc.vehicles}
    assert tested >= 1  # at least one fleet where the chance constraint moved a stop


def plan_feasible(sc) -> bool:
    from cevm.core.assignment import plan
    from cevm.errors import InputError

    try:
        plan(sc, 0)
        return True
    except InputError:
        return False


def test_the_enumerations_day_spread_is_the_exact_one_with_a_leg_that_gives_energy_back():
    """The enumeration's per-combination day spread (chance.DayMoments) equals
    cevm.core.predictive.total on the same legs, also when a leg's mean is negative (a
    long descent regenerates more than it draws): the shared scatter's share part is of
    each leg's energy drawn, not of the day's net (it was, so the enumeration found a day
    surer than it is: 0.854 against 0.849, and planned it at min_p_complete 0.85). With a
    spec sheet's CdA and Cr spread (one CdA for every leg) in both."""
    from cevm.core.assignment.chance import DayMoments
    from cevm.core.assignment.scenario import FleetVehicle
    from cevm.core.cycle import drive_cycle_vector
    from cevm.core.predictive import Features, total
    from cevm.core.uncertainty import Priors, ScatterPrior, TermPrior
    from test_fleet import ebus

    priors = Priors("bus", "test", (TermPrior("eta", 0.72, 0.86), TermPrior("aux", 0.0, 3000.0)),
                    ScatterPrior(800.0, 0.04), spec=(("cda", 0.85, 1.15), ("cr", 0.8, 1.2)))
    veh = dataclasses.replace(ebus(regen_eta=0.7), priors=priors)
    fv = FleetVehicle("V0", veh, veh.kerb_mass_kg + 3000.0)
    t = np.arange(0.0, 601.0)
    v = np.full(t.size, 12.0)
    down = drive_cycle_vector(t, v, 600.0 - 0.08 * 12.0 * t)  # 8 % down for 7.2 km
    flat = drive_cycle_vector(t, v, np.zeros(t.size))
    legs = [(down, 12000.0), (flat, 9500.0), (down, 11000.0)]
    day = DayMoments(fv, 1)
    for vec, m in legs:
        day.add(vec, np.array([[m]]), np.ones((1, 1)), None)
    parts = [Features.of(vec, veh, [m], None) for vec, m in legs]
    assert all(p.spec is not None for p in parts)
    exact = total(veh, Features.concat(parts))
    from cevm.core.predictive import mean
    assert (np.asarray(mean(veh, parts[0])) < 0).all()  # the descent gives energy back
    np.testing.assert_allclose(day.mu, exact.mean, rtol=1e-12)
    np.testing.assert_allclose(day.sd(), exact.sd, rtol=1e-12)
