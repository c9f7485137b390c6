"""Smoke and sanity tests of benchmarks/bench_tables.py (the paper's tables 1 and 2).

The benchmark's core, run on three short public cycles with two payloads and a few
calibration draws. Expected values come from physics, not from the code under test:

- with every effect of the detailed EV model switched off (lossless motor, unlimited
  regeneration, no auxiliaries, no rotating inertia), the battery energy is the wheel
  energy divided by the transmission efficiency when driving and multiplied by it when
  braking: exactly the CE model with eta = transmission efficiency (0.95 in
  configs/vehicles/electric-bus.toml), so the fitted eta is 0.95 and the error is 0;
- a constant gradient g over a distance d raises the road by d g / sqrt(1 + g^2).
"""

import importlib.util
import math
import sys

import numpy as np
import pytest

from conftest import ROOT, SHARED

CYCLES = SHARED / "cycles"
pytestmark = pytest.mark.skipif(not (CYCLES / "advisor").is_dir(),
                                reason="../shared/cycles is not beside this checkout")


@pytest.fixture(scope="module")
def bt():
    spec = importlib.util.spec_from_file_location("bench_tables", ROOT / "benchmarks" / "bench_tables.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["bench_tables"] = mod  # dataclasses resolve annotations through it
    spec.loader.exec_module(mod)
    return mod


def _short(bt, names):
    return [bt.read_advisor(CYCLES / "advisor" / f"{n}.csv") for n in names]


TINY_TIMING = {"detailed": 1, "ce_raw": 1, "ce_cached": 2, "ce_scalar": 2, "ce_batch": 1}


def test_bus_table_structure_and_lossless_limit(bt):
    from cevm.io import load_vehicle

    bus = load_vehicle(bt.BUS_TOML)
    cycles = _short(bt, ["CYC_CBDBUS", "CYC_ARTERIAL", "CYC_COMMUTER"])  # the bus follows all three
    res = bt.run_table("bus", bus, cycles, (0.0, 1500.0), n_reps=3, n_calib=2, timing_repeats=TINY_TIMING)

    assert res.n_trips == 6 and res.excluded == ()
    assert res.draws.shape == (3, 2)  # C(3, 2) = 3 combinations, all of them
    assert {tuple(d) for d in res.draws.tolist()} == {(0, 1), (0, 2), (1, 2)}
    labels = set(res.detailed_labels)
    assert {"base", "all off", "- auxiliaries", "only auxiliaries"} <= labels
    assert set(res.results) == {(lbl, v.key) for lbl in res.detailed_labels for v in res.variants}
    base = res.results[("base", "a")]
    assert base.rep_mean.shape == base.rep_std.shape == (3,)
    # one held-out cycle x 2 payloads per draw: finite mean and std
    assert np.all(np.isfinite(base.rep_mean)) and np.all(np.isfinite(base.rep_std))
    assert 0.3 < np.nanmedian(base.fitted["eta"]) < 1.0
    # the detailed model draws 4 kW of auxiliaries: a fitted aux term must be positive
    aux = res.results[("base", "c")].fitted["aux_power_w"]
    assert np.nanmedian(aux) > 0.0

    off = res.results[("all off", "a")]
    assert np.allclose(off.fitted["eta"], 0.95, atol=1e-6)
    assert np.nanmax(np.abs(off.rep_mean)) < 1e-6 and np.nanmax(off.rep_std) < 1e-6

    tm = res.timing
    for name in bt.TIMED:
        assert tm.best[name].shape == (3,) and np.all(tm.best[name] > 0)
        assert np.all(tm.best[name] <= tm.mean[name] * (1 + 1e-12))
    assert tm.stats("ce_cached")[0] < tm.stats("detailed")[0]


def test_truck_variants_and_adapted_traces(bt):
    from cevm.core.detailed import simulate
    from cevm.io import load_vehicle
    from cevm.io.detailed import diesel_params_from_vehicle

    hgv = load_vehicle(bt.TRUCK_TOML)
    cycles = _short(bt, ["CYC_CBDTRUCK", "CYC_WVUCITY", "CYC_NYCTRUCK"])
    res = bt.run_table("truck", hgv, cycles, (0.0, 26000.0), n_reps=3, n_calib=2, ablation=False,
                       timing=False, adapt=True)
    assert res.timing is None and res.detailed_labels == ("base",)
    assert [v.key for v in res.variants] == ["a", "b", "c-paper", "c-nc"]
    for v in res.variants:
        r = res.results[("base", v.key)]
        assert r.rep_std.shape == (3,) and np.isfinite(r.summary("std")[0])
    assert res.n_trips == 6  # adapted traces: every payload is usable

    # NYCTRUCK at 44 t: far beyond a 235 kW truck as recorded, followed once adapted
    nyc = cycles[2]
    params = diesel_params_from_vehicle(hgv)
    raw = simulate(hgv, nyc.time_s, nyc.speed_mps, mass_kg=44000.0, params=params)
    adapted = bt.adapt_trace(nyc, hgv, params, 44000.0)
    sim = simulate(hgv, adapted.time_s, adapted.speed_mps, mass_kg=44000.0, params=params)
    positive = float(np.dot(np.maximum(sim.steps["wheel_power_w"], 0.0), sim.steps["dt_s"]))
    assert raw.traction_deficit_j > 0.05 * positive
    assert sim.traction_deficit_j < 0.02 * positive
    assert np.all(adapted.speed_mps <= nyc.speed_mps + 1e-12)
    assert np.array_equal(adapted.time_s, nyc.time_s)


def test_elevation_from_gradient_hand_value(bt):
    t = np.arange(11.0)
    v = np.full(11, 10.0)
    h = bt.elevation_from_gradient(t, v, np.full(11, 0.05))
    assert h[0] == 0.0
    assert h[-1] == pytest.approx(100.0 * 0.05 / math.sqrt(1.0 + 0.05**2), rel=1e-12)
    # standing still: no climb whatever the gradient
    assert np.all(bt.elevation_from_gradient(t, np.zeros(11), np.full(11, 0.08)) == 0.0)


def test_fixed_rule_picks_slow_medium_fast(bt):
    def cyc(name, speed):
        t = np.arange(0.0, 100.0)
        v = np.full(t.size, speed)
        v[0] = v[-1] = 0.0
        return bt.Cycle(name, "test", t, v, None)

    cycles = [cyc(str(s), s) for s in (5.0, 1.0, 9.0, 3.0, 7.0, 2.0)]  # sorted: 1 2 3 5 7 9
    picked = sorted(float(cycles[i].name) for i in bt.fixed_rule_draw(cycles, 3))
    # positions (n-1) q rounded half up: 5/6 -> 1, 5/2 -> 3, 25/6 -> 4 in 1, 2, 3, 5, 7, 9
    assert picked == [2.0, 5.0, 7.0]
