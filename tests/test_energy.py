"""The terms beyond the wheel (cevm.core.energy): analytic cases, the plain per-step
reference (tests/reference.py), the sweep and the payload search against them, and the
vector format that carries their per-trip sums."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cevm.core import energy
from cevm.core.cycle import CycleVector, drive_cycle_vector
from cevm.core.feasibility import feasibility
from cevm.core.sweep import PredictionSet, Source, energy_trajectory, predict_sources
from cevm.core.vehicle import FitDomain, Vehicle, domain_warnings, predict
from cevm.io.vehicles import vehicle_from_mapping
from reference import RHO, G, reference_consumption

EV = Vehicle(name="bus", powertrain="ev", mass_kg=12000.0, cda_m2=4.0, cr=0.007, eta=0.8, kerb_mass_kg=9000.0,
             battery_j=120 * 3.6e6, aux_power_w=3000.0, regen_eta=0.6, aux_heating_w_per_k=250.0,
             aux_cooling_w_per_k=150.0, warmup_j_per_k=2.0e5, heating_below_c=16.0, cooling_above_c=22.0)
ICE = Vehicle(name="truck", powertrain="ice", mass_kg=30000.0, cda_m2=6.0, cr=0.006, eta=0.45, kerb_mass_kg=18000.0,
              fuel_lhv_j_per_l=35.8e6, idle_fuel_lps=2.0 / 3600, running_fuel_lps=5.0 / 3600, kinetic_eta=0.3,
              heating_fuel_lps_per_k=0.05 / 3600, cooling_fuel_lps_per_k=0.08 / 3600, warmup_fuel_l_per_k=0.02,
              tank_l=400.0)


def _fields(v: Vehicle) -> dict:
    return dataclasses.asdict(v)


# --- analytic cases -------------------------------------------------------------------


def test_ev_constant_speed_with_heating_by_hand():
    """10 m/s on a flat road for 600 s at 6 degC: traction (rolling + drag) / eta plus
    (p0 + 10 K x p_heat) x 600 s plus the warm-up of 10 K."""
    t = np.arange(601.0)
    v = np.full(t.size, 10.0)
    vec = drive_cycle_vector(t, v)
    m = 11000.0
    traction = m * EV.cr * G * 10.0 * 600 + EV.cda_m2 * 0.5 * RHO * 1000.0 * 600
    want = traction / EV.eta + (3000.0 + 10 * 250.0) * 600 + 10 * 2.0e5
    got = float(predict(vec, EV, m, ambient_c=6.0).energy_j)
    assert got == pytest.approx(want, rel=1e-12)
    # at 30 degC: cooling 8 K, no heating, no warm-up
    want30 = traction / EV.eta + (3000.0 + 8 * 150.0) * 600
    assert float(predict(vec, EV, m, ambient_c=30.0).energy_j) == pytest.approx(want30, rel=1e-12)
    # between the balance temperatures only the base load
    assert float(predict(vec, EV, m, ambient_c=19.0).energy_j) == pytest.approx(traction / EV.eta + 3000.0 * 600,
                                                                                 rel=1e-12)


def test_ev_regeneration_efficiency_by_hand():
    """A stop from 10 m/s to 0 in one 1 s step on flat ground is non-simplified; its
    negative wheel energy returns regen_eta of it, not eta."""
    t = np.array([0.0, 1.0])
    v = np.array([10.0, 0.0])
    vec = drive_cycle_vector(t, v)
    m = 10000.0
    delta = m * (-50.0) + EV.cda_m2 * 0.25 * RHO * 1000.0 + EV.cr * m * 0.5 * G * 10.0
    assert delta < 0
    base = dataclasses.replace(EV, aux_power_w=0.0, aux_heating_w_per_k=0.0, aux_cooling_w_per_k=0.0,
                               warmup_j_per_k=0.0)
    assert float(predict(vec, base, m).energy_j) == pytest.approx(0.6 * delta, rel=1e-12)
    paper = dataclasses.replace(base, regen_eta=None)
    assert float(predict(vec, paper, m).energy_j) == pytest.approx(0.8 * delta, rel=1e-12)


def test_ice_willans_and_kinetic_terms_by_hand():
    """Accelerate 0 -> 10 m/s in 10 s (simplified steps: traction time 10 s), cruise
    50 s, then stand 30 s: wheel work / (U eta) + kinetic surcharge + running fuel over
    the 60 s of traction + idle fuel over 30 s + temperature rates over 90 s + cold start."""
    t = np.arange(91.0)
    v = np.concatenate([np.linspace(0, 10, 11), np.full(50, 10.0), [0.0] * 30])
    v[60] = 10.0
    v = v[:91]
    vec = drive_cycle_vector(t, v)
    m = 25000.0
    assert vec.k_pos == pytest.approx(50.0)
    lhv = ICE.fuel_lhv_j_per_l
    wheel_pos = sum(max(0.0, d) for d in _deltas(t, v, m, ICE))
    simplified_time = sum(1.0 for k, r in _kr(t, v) if k + 0.004 * r > 0)
    assert vec.traction_s == pytest.approx(simplified_time)
    ambient = 4.0  # 12 K below the heating balance
    want = (wheel_pos / (lhv * 0.45) + m * 50.0 * (1 / 0.3 - 1 / 0.45) / lhv + 5.0 / 3600 * simplified_time
            + 2.0 / 3600 * vec.idle_s + 0.05 / 3600 * 12 * 90 + 0.02 * 12)
    assert float(predict(vec, ICE, m, ambient_c=ambient).fuel_l) == pytest.approx(want, rel=1e-12)


def _kr(t, v):
    for i in range(len(t) - 1):
        dt = t[i + 1] - t[i]
        yield 0.5 * (v[i + 1] ** 2 - v[i] ** 2), 0.5 * G * (v[i] + v[i + 1]) * dt


def _deltas(t, v, m, veh):
    for i in range(len(t) - 1):
        dt = t[i + 1] - t[i]
        k = 0.5 * (v[i + 1] ** 2 - v[i] ** 2)
        a = 0.25 * RHO * (v[i] ** 3 + v[i + 1] ** 3) * dt
        r = 0.5 * G * (v[i] + v[i + 1]) * dt
        yield m * k + veh.cda_m2 * a + veh.cr * m * r


def test_zero_terms_are_the_paper_model():
    """With every new term zero (and regen at eta), predictions are eq. 26 / 31."""
    rng = np.random.default_rng(3)
    t = np.arange(400.0)
    v = np.abs(np.cumsum(rng.normal(0, 0.5, t.size)))
    h = np.cumsum(rng.normal(0, 0.1, t.size))
    vec = drive_cycle_vector(t, v, h)
    from cevm.core.model import ev_energy_j, ice_fuel_l

    ev0 = Vehicle(name="e", powertrain="ev", mass_kg=1e4, cda_m2=4.0, cr=0.007, eta=0.8, battery_j=1e9)
    ice0 = Vehicle(name="i", powertrain="ice", mass_kg=2e4, cda_m2=6.0, cr=0.006, eta=0.4, fuel_lhv_j_per_l=35.8e6)
    assert float(predict(vec, ev0, 1e4, ambient_c=-20.0).energy_j) == pytest.approx(
        float(ev_energy_j(vec, 1e4, 4.0, 0.007, 0.8)), rel=1e-13)
    assert float(predict(vec, ice0, 2e4, ambient_c=40.0).fuel_l) == pytest.approx(
        float(ice_fuel_l(vec, 2e4, 6.0, 0.006, 0.4, 35.8e6)), rel=1e-13)


# --- against the per-step reference -------------------------------------------------


def _random_cycle(rng, n=300, standstill=True):
    t = np.cumsum(rng.uniform(0.5, 2.0, n))
    v = np.maximum(0.0, 8 + np.cumsum(rng.normal(0, 0.8, n)))
    if standstill:
        v[n // 3 : n // 3 + 20] = 0.0
    h = np.cumsum(rng.normal(0, 0.3, n))
    return t, v, h


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), ambient=st.floats(-25.0, 40.0), ev=st.booleans(),
       braking=st.sampled_from(["no-credit", "paper"]))
def test_predict_with_every_term_equals_the_reference(seed, ambient, ev, braking):
    rng = np.random.default_rng(seed)
    t, v, h = _random_cycle(rng)
    vec = drive_cycle_vector(t, v, h)
    veh = EV if ev else dataclasses.replace(ICE, ice_braking=braking)
    masses = rng.uniform(9000, 40000, 5)
    got = predict(vec, veh, masses, ambient_c=ambient)
    got = got.energy_j if ev else got.fuel_l
    want = [reference_consumption(t, v, h, m, _fields(veh), ambient) for m in masses]
    np.testing.assert_allclose(got, want, rtol=1e-9)


@pytest.mark.slow
@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 10_000), ambient=st.floats(-25.0, 40.0))
def test_sweep_totals_and_lowest_soc_equal_the_reference(seed, ambient):
    """The sweep (vectorised, with pruned blocks) gives the reference totals, and its
    lowest state of charge the reference's lowest running sum, with every term."""
    rng = np.random.default_rng(seed)
    t, v, h = _random_cycle(rng, 400)
    src = Source.from_cycle(_cycle(t, v, h))
    src_cold = dataclasses.replace(src, name="cold", ambient_c=ambient)
    vehicles = [EV, ICE]
    pset = PredictionSet.build(vehicles, mass_kg=[18000.0, 30000.0])
    blocks = predict_sources([src, src_cold], pset)
    for block in blocks:
        for p in range(pset.n):
            veh = vehicles[pset.vehicle_index[p]]
            m = pset.mass_kg[p]
            t_c = block.source.ambient_c if block.source.ambient_c is not None else energy.AMBIENT_DEFAULT_C
            want = reference_consumption(t, v, h, m, _fields(veh), t_c)
            got = block.energy_j[p] if veh.is_ev else block.fuel_l[p]
            assert got == pytest.approx(want, rel=1e-9)
            assert block.ambient_c[p] == t_c
            if veh.is_ev:
                run = [_fields(veh)["warmup_j_per_k"] * max(0.0, 16.0 - t_c)]
                run.extend(reference_consumption(t[: j + 1], v[: j + 1], h[: j + 1], m, _fields(veh), t_c)
                           for j in range(1, len(t)))
                lowest = 100.0 - 100.0 * max(0.0, max(run)) / veh.battery_j
                assert block.soc_min_pct[p] == pytest.approx(lowest, abs=1e-9)


def _cycle(t, v, h):
    from cevm.core.cycle import DriveCycle

    return DriveCycle(time_s=t, speed_mps=v, elevation_m=h, name="c")


def test_energy_trajectory_ends_at_the_total_with_every_term():
    rng = np.random.default_rng(11)
    t, v, h = _random_cycle(rng)
    src = Source.from_cycle(_cycle(t, v, h))
    for veh in (EV, ICE):
        _, _, e = energy_trajectory(src, veh, 20000.0, ambient_c=3.0)
        p = predict(src.vector, veh, 20000.0, ambient_c=3.0)
        assert e[-1] == pytest.approx(float(p.energy_j if veh.is_ev else p.fuel_l), rel=1e-9)


def test_feasibility_uses_every_term():
    """The payload search's load function at a payload equals the sweep's prediction."""
    rng = np.random.default_rng(5)
    t, v, h = _random_cycle(rng, 600)
    src = dataclasses.replace(Source.from_cycle(_cycle(t, v, h)), ambient_c=-5.0)
    res = feasibility(src, [EV, ICE], payload_kg=2000.0)
    pset = PredictionSet.build([EV, ICE], payload_kg=[2000.0])
    (block,) = predict_sources([src], pset)
    assert res.energy_j[0] == pytest.approx(block.energy_j[0], rel=1e-12)
    assert res.fuel_l[1] == pytest.approx(block.fuel_l[1], rel=1e-12)
    assert res.soc_min_pct[0] == pytest.approx(block.soc_min_pct[0], abs=1e-9)
    assert list(res.ambient_c) == [-5.0, -5.0] and res.ambient_from == ("source", "source")


# --- temperature: where it comes from, what is refused --------------------------------


def test_ambient_origin_order():
    t = np.arange(100.0)
    src = Source.from_cycle(_cycle(t, np.full(100, 5.0), None))
    ref = dataclasses.replace(EV, reference_temp_c=8.0)
    pset = PredictionSet.build([EV, ref])
    (b,) = predict_sources([src], pset)
    assert list(b.ambient_c) == [energy.AMBIENT_DEFAULT_C, 8.0]
    assert list(b.ambient_from) == [3.0, 2.0]
    (b,) = predict_sources([dataclasses.replace(src, ambient_c=1.0)], pset)
    assert list(b.ambient_c) == [1.0, 1.0] and list(b.ambient_from) == [1.0, 1.0]
    (b,) = predict_sources([dataclasses.replace(src, ambient_c=1.0)], PredictionSet.build([EV, ref], ambient_c=-3.0))
    assert list(b.ambient_c) == [-3.0, -3.0] and list(b.ambient_from) == [0.0, 0.0]


@pytest.mark.parametrize("bad", [300.0, -80.0, math.nan])
def test_absurd_temperatures_are_refused(bad):
    vec = drive_cycle_vector(np.arange(10.0), np.full(10, 3.0))
    with pytest.raises(ValueError, match="degC"):
        predict(vec, EV, 1e4, ambient_c=bad)


def test_vehicle_file_keys_of_the_new_terms():
    base = {"name": "x", "powertrain": "ev", "mass_kg": 1000, "cda_m2": 1.0, "cr": 0.01, "eta": 0.8,
            "battery_kwh": 20}
    v = vehicle_from_mapping({**base, "regen_eta": 0.55, "aux_heating_kw_per_k": 0.2, "aux_cooling_kw_per_k": 0.1,
                              "warmup_kwh_per_k": 0.05, "heating_below_c": 14, "cooling_above_c": 25,
                              "reference_temp_c": 9.0})
    assert (v.regen_eta, v.aux_heating_w_per_k, v.aux_cooling_w_per_k, v.warmup_j_per_k) == (0.55, 200.0, 100.0,
                                                                                            0.05 * 3.6e6)
    assert (v.heating_below_c, v.cooling_above_c, v.reference_temp_c) == (14.0, 25.0, 9.0)
    from cevm.errors import InputError

    with pytest.raises(InputError, match="regen_eta"):
        vehicle_from_mapping({**base, "regen_eta": 1.5})
    with pytest.raises(InputError, match="heating_below_c"):
        vehicle_from_mapping({**base, "heating_below_c": 25, "cooling_above_c": 20})
    with pytest.raises(InputError, match="belongs to an ICE"):
        vehicle_from_mapping({**base, "running_fuel_lph": 3.0})


def test_domain_warnings_outside_the_calibration():
    d = FitDomain(terms=("eta", "aux", "heat"), n_trips=20, ambient_c=(12.0, 28.0), mass_kg=(10000.0, 13000.0),
                  mean_speed_mps=(4.0, 6.0))
    v = dataclasses.replace(EV, calibration=d)
    assert domain_warnings(v, mass_kg=11000.0, ambient_c=20.0, mean_speed_mps=5.0) == []
    w = domain_warnings(v, mass_kg=11000.0, ambient_c=-5.0, mean_speed_mps=5.0)
    assert len(w) == 1 and "12.0 to 28.0 degC" in w[0] and "-5.0" in w[0]
    assert "kg" in domain_warnings(v, mass_kg=20000.0)[0]
    assert "duty" in domain_warnings(v, mean_speed_mps=20.0)[0]
    assert domain_warnings(EV, ambient_c=-40.0) == []  # not calibrated: nothing to compare with


# --- the vector's per-trip sums ---------------------------------------------------------


def test_vector_v3_round_trip_and_v2_still_read():
    rng = np.random.default_rng(2)
    t, v, h = _random_cycle(rng)
    vec = drive_cycle_vector(t, v, h)
    back = CycleVector.from_bytes(vec.to_bytes())
    assert back.k_pos == vec.k_pos and back.traction_s == vec.traction_s and back.s_me == vec.s_me
    k = 0.5 * (v[1:] ** 2 - v[:-1] ** 2)
    assert vec.k_pos == pytest.approx(np.maximum(k, 0).sum())
    # a version-2 blob: same layout without the last two scalars
    raw = vec.to_bytes()
    n = vec.n_nonsimplified
    head = b"CEVMVEC2" + raw[8:12]
    scalars = raw[12 : 12 + 8 * 13]
    v2 = head + scalars[: 8 * 11] + raw[12 + 8 * 13 :]
    old = CycleVector.from_bytes(v2)
    assert math.isnan(old.k_pos) and math.isnan(old.traction_s) and old.n_nonsimplified == n
    assert float(predict(old, EV, 1e4).energy_j) == pytest.approx(float(predict(vec, EV, 1e4).energy_j), rel=1e-15)
    with pytest.raises(ValueError, match="kinetic"):
        predict(old, ICE, 2e4)
    with pytest.raises(ValueError, match="traction"):
        predict(old, dataclasses.replace(ICE, kinetic_eta=None), 2e4)


def test_vectors_of_pieces_add_their_new_sums():
    rng = np.random.default_rng(4)
    t, v, h = _random_cycle(rng)
    a = drive_cycle_vector(t[:150], v[:150], h[:150])
    b = drive_cycle_vector(t[150:], v[150:], h[150:])
    s = a + b
    assert s.k_pos == pytest.approx(a.k_pos + b.k_pos) and s.traction_s == pytest.approx(a.traction_s + b.traction_s)


# --- temperature through the commands ----------------------------------------------------


def test_fleet_days_take_their_temperature(tmp_path):
    """A scenario day's ambient temperature reaches every leg: an EV with heating uses
    more on a cold day, by exactly the heating power over the legs' duration."""
    from cevm.core.assignment import FleetVehicle, Leg, Route, Scenario, evaluate

    t = np.arange(0.0, 901.0)
    vec = drive_cycle_vector(t, np.full(t.size, 8.0))
    veh = dataclasses.replace(EV, max_gross_kg=18000.0)
    fv = FleetVehicle(id="B1", vehicle=veh, max_gross_kg=18000.0)
    leg = Leg(vector=vec)
    route = Route(id="R", vehicle_id="B1", stops=("S1",), legs=(leg, leg))
    sc = Scenario(name="x", vehicles=(fv,), routes=(route,), days=("cold", "mild"), payload_kg={"S1": (0.0, 0.0)},
                  ambient_c=(-4.0, 19.0))
    cold = evaluate(sc, "cold", {})
    mild = evaluate(sc, "mild", {})
    extra = (250.0 * 20 * 900 + 2.0e5 * 20) * 2  # heating 20 K over two 900 s legs, plus two warm-ups
    assert cold.total - mild.total == pytest.approx(extra, rel=1e-9)


def test_predict_cli_says_the_temperature_and_warns_outside_the_calibration(tmp_path):
    import json

    from typer.testing import CliRunner

    from cevm.cli import app

    cyc = tmp_path / "c.csv"
    cyc.write_text("time_s,speed_kmh\n" + "".join(f"{i},{30 if 5 < i < 590 else 0}\n" for i in range(600)))
    veh = tmp_path / "bus.toml"
    veh.write_text('name = "bus"\npowertrain = "ev"\nkerb_mass_kg = 9000\npayload_kg = 1000\ncda_m2 = 4.0\n'
                   'cr = 0.007\neta = 0.8\nbattery_kwh = 120\naux_power_kw = 3\naux_heating_kw_per_k = 0.25\n'
                   'reference_temp_c = 12.0\n\n[calibration]\nterms = ["eta", "aux", "heat"]\nn_trips = 30\n'
                   'ambient_c = [8.0, 25.0]\nmass_kg = [9500, 12000]\n')
    runner = CliRunner()
    res = runner.invoke(app, ["predict", "-v", str(veh), "--cycle", str(cyc), "-f", "json"])
    assert res.exit_code == 0, res.output
    (row,) = json.loads(res.stdout)
    assert row["ambient_c"] == 12.0 and row["ambient_from"] == "vehicle reference_temp_c"
    assert "ambient 12.0 degC (vehicle reference_temp_c)" in res.stderr and "warning" not in res.stderr
    res = runner.invoke(app, ["predict", "-v", str(veh), "--cycle", str(cyc), "--ambient-c", "-10", "-f", "json"])
    (cold,) = json.loads(res.stdout)
    assert cold["ambient_from"] == "given"
    # 12 degC is 4 K, -10 degC 26 K below the 16 degC heating balance: 22 K x 0.25 kW/K x 599 s
    assert cold["energy_kwh"] - row["energy_kwh"] == pytest.approx(0.25 * 22 * 599 / 3600, rel=1e-9)
    assert "calibrated on 30 trips at 8.0 to 25.0 degC" in res.stderr and "extrapolation" in res.stderr
    res = runner.invoke(app, ["predict", "-v", str(veh), "--cycle", str(cyc), "--ambient-c", "400"])
    assert res.exit_code == 2 and "degC" in res.stderr


def test_a_version_2_vector_gets_its_trip_sums_from_its_samples():
    rng = np.random.default_rng(8)
    t, v, h = _random_cycle(rng)
    vec = drive_cycle_vector(t, v, h)
    raw = vec.to_bytes()
    v2 = CycleVector.from_bytes(b"CEVMVEC2" + raw[8:12] + raw[12 : 12 + 8 * 11] + raw[12 + 8 * 13 :])
    assert not v2.has_trip_sums and vec.has_trip_sums
    up = v2.with_trip_sums(t, v, h)
    assert up.has_trip_sums and up.k_pos == vec.k_pos and up.traction_s == vec.traction_s
    assert float(predict(up, ICE, 2e4).fuel_l) == pytest.approx(float(predict(vec, ICE, 2e4).fuel_l), rel=1e-15)
