"""Range, not negative charge: where an EV crosses its reserve or runs empty along a
source, where an ICE runs its tank dry, and the range with the source repeated, against
the plain per-step reference (tests/reference.py); never a state of charge below 0."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cevm.core.cycle import drive_cycle_vector
from cevm.core.sweep import LegProfile, PredictionSet, Source, predict_source
from cevm.core.vehicle import Vehicle
from reference import reference_crossing

J_PER_KWH = 3.6e6


def _leg(n=900, seed=0, climb_m=30.0):
    rng = np.random.default_rng(seed)
    t = np.arange(n, dtype=float)
    v = np.clip(12 + 8 * np.sin(t / 37.0) + rng.normal(0, 0.5, n), 0, None)
    v[::150] = 0.0  # stops
    v[1::150] = 0.0
    h = climb_m * np.sin(t / 120.0) + 0.01 * t
    return t, v, h


def _source(legs):
    vec = drive_cycle_vector(*legs[0])
    for leg in legs[1:]:
        vec = vec + drive_cycle_vector(*leg)
    return Source("route", "route", vec, legs=tuple(LegProfile(*leg) for leg in legs))


LEGS = [_leg(900, 1), _leg(700, 2, climb_m=60.0)]
EV = Vehicle(name="bus", id="bus", powertrain="ev", mass_kg=12000.0, kerb_mass_kg=10000.0, cda_m2=4.0, cr=0.007,
             eta=0.8, battery_j=24.0 * J_PER_KWH, aux_power_w=4000.0)
ICE = Vehicle(name="truck", id="truck", powertrain="ice", mass_kg=20000.0, kerb_mass_kg=15000.0, cda_m2=6.0, cr=0.006,
              eta=0.38, fuel_lhv_j_per_l=35.8e6, tank_l=12.0, idle_fuel_lps=2.0 / 3600, ice_braking="no-credit")


def _ev_step(v: Vehicle, m: float, ambient_c: float = 20.0) -> dict:
    regen = v.eta if v.regen_eta is None else v.regen_eta
    heat = max(0.0, v.heating_below_c - ambient_c)
    return dict(m=m, cda=v.cda_m2, cr=v.cr, eta=v.eta, w=v.eta * regen,
                aux=v.aux_power_w + v.aux_heating_w_per_k * heat)


def _ice_step(v: Vehicle, m: float) -> dict:
    return dict(m=m, cda=v.cda_m2, cr=v.cr, eta=v.eta, w=1.0 if v.ice_braking == "paper" else 0.0,
                lhv=v.fuel_lhv_j_per_l, idle=v.idle_fuel_lps, run=v.running_fuel_lps,
                ck=0.0 if v.kinetic_eta is None else m * (1 / v.kinetic_eta - 1 / v.eta) / v.fuel_lhv_j_per_l)


def _close(got, want):
    assert want is not None
    assert got == pytest.approx(want, rel=1e-9, abs=1e-6)


@pytest.mark.parametrize("payload", [0.0, 2000.0, 8000.0])
def test_ev_crosses_the_reserve_and_runs_empty_where_the_reference_says(payload):
    src = _source(LEGS)
    ps = PredictionSet.build([EV], payload_kg=[payload])
    b = predict_source(src, ps, soc_start_pct=90.0, reserve_pct=20.0, ranges=True)
    m = EV.kerb_mass_kg + payload
    step = _ev_step(EV, m)
    cap = EV.battery_j
    for level, t_got, d_got, repeat in ((0.70 * cap, b.reserve_at_s, b.reserve_at_m, False),
                                         (0.90 * cap, b.empty_at_s, b.empty_at_m, False)):
        want = reference_crossing(LEGS, level, repeat=repeat, **step)
        if want is None:
            assert math.isnan(t_got[0]) and math.isnan(d_got[0])
        else:
            _close(t_got[0], want[0])
            _close(d_got[0], want[1])
    _close(b.range_m[0], reference_crossing(LEGS, 0.90 * cap, repeat=True, **step)[1])
    _close(b.range_reserve_m[0], reference_crossing(LEGS, 0.70 * cap, repeat=True, **step)[1])


def test_the_test_route_runs_the_small_battery_empty_at_the_heavy_load():
    b = predict_source(_source(LEGS), PredictionSet.build([EV], payload_kg=[0.0, 8000.0]), ranges=True)
    assert np.isfinite(b.empty_at_m[1]) and math.isnan(b.empty_at_m[0])  # both cases above were exercised
    assert b.range_m[0] > _source(LEGS).distance_m  # the light bus's range needs the repetition


def test_no_state_of_charge_below_zero():
    b = predict_source(_source(LEGS), PredictionSet.build([EV], payload_kg=[8000.0]))
    assert math.isnan(b.soc_end_pct[0]) and b.soc_min_pct[0] == 0.0  # ran empty: no end, lowest 0
    assert b.empty_at_m[0] < _source(LEGS).distance_m and not b.reserve_ok[0]
    assert b.range_m is None  # not asked for


def test_energy_terms_are_in_the_running_sum():
    v = dataclasses.replace(EV, regen_eta=0.5, aux_heating_w_per_k=300.0, reference_temp_c=-5.0)
    b = predict_source(_source(LEGS), PredictionSet.build([v], payload_kg=[1000.0]), ranges=True)
    step = _ev_step(v, 11000.0, ambient_c=-5.0)
    _close(b.range_m[0], reference_crossing(LEGS, v.battery_j, repeat=True, **step)[1])
    plain = predict_source(_source(LEGS), PredictionSet.build([EV], payload_kg=[1000.0]), ranges=True)
    assert b.range_m[0] < plain.range_m[0]  # heating draws more


@pytest.mark.parametrize("braking", ["no-credit", "paper"])
def test_ice_runs_its_tank_dry_where_the_reference_says(braking):
    v = dataclasses.replace(ICE, ice_braking=braking, running_fuel_lps=1.0 / 3600, kinetic_eta=0.3)
    for payload in (0.0, 20000.0):
        b = predict_source(_source(LEGS), PredictionSet.build([v], payload_kg=[payload]), ranges=True)
        step = _ice_step(v, v.kerb_mass_kg + payload)
        want = reference_crossing(LEGS, v.tank_l, **step)
        if want is None:
            assert math.isnan(b.empty_at_m[0])
        else:
            _close(b.empty_at_s[0], want[0])
            _close(b.empty_at_m[0], want[1])
        _close(b.range_m[0], reference_crossing(LEGS, v.tank_l, repeat=True, **step)[1])
        assert math.isnan(b.reserve_at_m[0]) and math.isnan(b.range_reserve_m[0])


def test_a_source_that_gives_back_what_it_takes_has_no_range_limit():
    t = np.arange(600, dtype=float)
    v = np.full(600, 15.0)
    h = -0.2 * 15.0 * t  # 20 % downhill all the way
    src = _source([(t, v, h)])
    b = predict_source(src, PredictionSet.build([EV]), ranges=True)
    assert b.energy_j[0] < 0 and b.range_m[0] == math.inf


def test_the_running_sum_ends_at_the_ce_total():
    """The per-step energies the range sums give the CE model's total at the end (no
    term left out): a battery of exactly the total runs empty at the last sample."""
    src = _source(LEGS)
    e = predict_source(src, PredictionSet.build([EV])).energy_j[0]
    exact = dataclasses.replace(EV, battery_j=e * (1 + 1e-12))
    b = predict_source(src, PredictionSet.build([exact]), ranges=True)
    assert b.range_m[0] == pytest.approx(src.distance_m, rel=1e-6)


@settings(max_examples=25, deadline=None)
@given(payload=st.floats(0, 10000), battery_kwh=st.floats(0.5, 20), soc=st.floats(30, 100),
       seed=st.integers(0, 50))
def test_range_equals_the_reference_for_any_load(payload, battery_kwh, soc, seed):
    legs = [_leg(300, seed)]
    v = dataclasses.replace(EV, battery_j=battery_kwh * J_PER_KWH)
    b = predict_source(_source(legs), PredictionSet.build([v], payload_kg=[payload]), soc_start_pct=soc, ranges=True)
    want = reference_crossing(legs, soc / 100 * v.battery_j, repeat=True, **_ev_step(v, v.kerb_mass_kg + payload))
    _close(b.range_m[0], want[1])


# --------------------------------------------------------------------- command line

from typer.testing import CliRunner  # noqa: E402

from cevm.cli import app  # noqa: E402

runner = CliRunner()


def _small_ev(tmp_path, root, battery_kwh=1.5):
    text = (root / "configs/vehicles/electric-bus.toml").read_text()
    p = tmp_path / "small-bus.toml"
    p.write_text(text.replace("battery_kwh = 124.0", f"battery_kwh = {battery_kwh}"))
    return p


def test_predict_says_where_an_ev_runs_empty_never_a_negative_charge(tmp_path, root):
    import json

    ev = _small_ev(tmp_path, root)
    urban = root / "configs/cycles/urban-bus.csv"
    res = runner.invoke(app, ["predict", "-v", str(ev), "-c", str(urban), "-f", "json", "--range"])
    assert res.exit_code == 0, res.output
    row = json.loads(res.stdout)[0]
    assert row["vehicle_key"] == "small-bus" and row["soc_end_pct"] is None and row["soc_min_pct"] == 0.0
    assert 0 < row["empty_at_km"] < row["distance_km"] and row["range_km"] == pytest.approx(row["empty_at_km"])
    assert 0 < row["reserve_at_km"] < row["empty_at_km"] and row["reserve_ok"] is False
    assert "run empty on the way" in res.output
    # the plain reference on the cycle file
    from cevm.io import load_vehicle, read_cycle_csv

    v, cyc = load_vehicle(ev), read_cycle_csv(urban)
    want = reference_crossing([(cyc.time_s, cyc.speed_mps, cyc.elevation_m)], v.battery_j, **_ev_step(v, v.mass_kg))
    assert row["empty_at_km"] == pytest.approx(want[1] / 1e3, rel=1e-9)
    table = runner.invoke(app, ["predict", "-v", str(ev), "-c", str(urban)])
    assert table.exit_code == 0 and "NO (empty at" in table.output


def test_feasibility_gives_the_range_and_no_negative_charge(tmp_path, root):
    import json

    ev = _small_ev(tmp_path, root)
    res = runner.invoke(app, ["feasibility", "-v", str(ev), "-c", str(root / "configs/cycles/urban-bus.csv"),
                              "-f", "json"])
    assert res.exit_code == 0, res.output
    row = json.loads(res.stdout)[0]
    assert row["soc_end_pct"] is None and row["soc_min_pct"] == 0.0 and row["feasible"] is False
    assert row["range_km"] == pytest.approx(row["empty_at_km"]) and row["range_reserve_km"] < row["range_km"]


@pytest.mark.parametrize("chunk_steps, chunk_rows", [((7, 7), 2), ((64, 64), 1 << 12), ((1 << 10, 1 << 16), 3)])
def test_ranges_are_the_same_bit_for_bit_however_the_running_sum_is_cut(monkeypatch, chunk_steps, chunk_rows):
    """The running sums are made a chunk of steps at a time and stop where every row has
    crossed its levels: cut anywhere, the crossings are the reference's and the same to
    the last bit as one sum over the whole source."""
    import cevm.core.sweep.ranges as ranges

    src = _source(LEGS)
    ps = PredictionSet.build([EV, ICE], payload_kg=[0.0, 3000.0, 8000.0, 20000.0])
    whole = predict_source(src, ps, soc_start_pct=90.0, reserve_pct=20.0, ranges=True)
    assert np.isfinite(whole.empty_at_m).sum() >= 2 and np.isfinite(whole.reserve_at_m).sum() >= 2
    monkeypatch.setattr(ranges, "_RANGE_CHUNK_STEPS", chunk_steps)
    monkeypatch.setattr(ranges, "_RANGE_CHUNK_ROWS", chunk_rows)
    for repeat in (True, False):
        cut = predict_source(src, ps, soc_start_pct=90.0, reserve_pct=20.0, ranges=repeat)
        for f in ranges.RANGE_FIELDS:
            got, want = getattr(cut, f), getattr(whole, f)
            if not repeat and f.startswith("range"):
                assert got is None
            else:
                assert got.tobytes() == want.tobytes(), f
    for i in range(ps.n):
        v = ps.vehicles[ps.vehicle_index[i]]
        m = float(ps.mass_kg[i])
        if v.is_ev:
            want = reference_crossing(LEGS, 0.90 * v.battery_j, repeat=True, **_ev_step(v, m))
        else:
            want = reference_crossing(LEGS, v.tank_l, repeat=True, **_ice_step(v, m))
        _close(whole.range_m[i], want[1])
