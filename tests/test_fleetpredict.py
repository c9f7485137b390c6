"""Fleet predictions: state of charge, lowest SoC, feasibility, ranges, sweeps, the CLI.

Expected values come from hand computations and from plain per-step loops written here
(one Python loop over samples, the paper's equations as printed), never from the code
under test.
"""

import csv
import io
import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from cevm.cli import app
from cevm.cli.values import parse_values
from cevm.core.cycle import DriveCycle
from cevm.core.feasibility import feasibility
from cevm.core.model import ev_energy_j, ice_fuel_l
from cevm.core.sweep import (
    LegProfile,
    PredictionSet,
    Source,
    energy_trajectory,
    peak_energy_j,
    predict_source,
    sweep,
)
from cevm.core.vehicle import Vehicle
from cevm.errors import InputError
from cevm.io import read_cycle_csv
from cevm_samplegen.cycles import MicroTripSpec, micro_trip_cycle

RHO, G, CR0 = 1.225, 9.81, 0.004
runner = CliRunner()


# ----------------------------------------------------------------- plain reference


def plain_run(legs, m, cda, cr, eta, w, aux_w=0.0):
    """Battery energy drawn [J] after every step, plainly: returns (end, peak), peak =
    max(0, max_j E_j). Non-simplified steps (criterion 8 with Cr0) with Delta <= 0 are
    weighted by w; each step adds Delta / eta + aux dt."""
    e = 0.0
    peak = 0.0
    for t, v, h in legs:
        for i in range(len(t) - 1):
            dt = t[i + 1] - t[i]
            k = 0.5 * (v[i + 1] ** 2 - v[i] ** 2)
            a = 0.25 * RHO * (v[i] ** 3 + v[i + 1] ** 3) * dt
            r = 0.5 * G * (v[i] + v[i + 1]) * dt
            dh = 0.0 if h is None else h[i + 1] - h[i]
            x = k + G * dh
            d = m * x + cda * a + cr * m * r
            if not (x + CR0 * r > 0) and d <= 0:
                d *= w
            e += d / eta + aux_w * dt
            peak = max(peak, e)
    return e, peak


def plain_fuel(legs, m, cda, cr, eta, lhv, no_credit):
    """ICE fuel [l] plainly (eq. 24/26), braking credited or not."""
    total = 0.0
    for t, v, h in legs:
        for i in range(len(t) - 1):
            dt = t[i + 1] - t[i]
            k = 0.5 * (v[i + 1] ** 2 - v[i] ** 2)
            a = 0.25 * RHO * (v[i] ** 3 + v[i + 1] ** 3) * dt
            r = 0.5 * G * (v[i] + v[i + 1]) * dt
            x = k + (0.0 if h is None else G * (h[i + 1] - h[i]))
            d = m * x + cda * a + cr * m * r
            if no_credit and not (x + CR0 * r > 0) and d <= 0:
                d = 0.0
            total += d
    return total / (lhv * eta)


def legs_of(cycle):
    return [(list(cycle.time_s), list(cycle.speed_mps), None if cycle.elevation_m is None else list(cycle.elevation_m))]


def ev(name="EV", kerb=9000.0, cda=3.99, cr=0.0066, eta=0.78, battery_kwh=124.0, aux_w=0.0, max_gross=None):
    return Vehicle(name=name, powertrain="ev", mass_kg=kerb, kerb_mass_kg=kerb, max_gross_kg=max_gross, cda_m2=cda,
                   cr=cr, eta=eta, battery_j=battery_kwh * 3.6e6, aux_power_w=aux_w)


def ice(name="HGV", kerb=18000.0, cda=6.62, cr=0.0066, eta=0.45, tank_l=400.0, braking="paper", max_gross=44000.0):
    return Vehicle(name=name, powertrain="ice", mass_kg=kerb, kerb_mass_kg=kerb, max_gross_kg=max_gross, cda_m2=cda,
                   cr=cr, eta=eta, fuel_lhv_j_per_l=35.8e6, tank_l=tank_l, ice_braking=braking)


@pytest.fixture(scope="module")
def hilly():
    """Two hilly stop-go cycles (about 20 and 10 minutes at 1 Hz)."""
    return [micro_trip_cycle(MicroTripSpec(n_trips=18, hill_amplitude_m=25.0), seed=5, name="hilly-a"),
            micro_trip_cycle(MicroTripSpec(n_trips=9, cruise_kmh=(40.0, 70.0), hill_amplitude_m=40.0), seed=6,
                             name="hilly-b")]


# -------------------------------------------------------------------- value ranges


def test_payload_range_is_inclusive_of_stop_on_the_grid():
    v = parse_values("0:26000:2000", "--payload-kg")
    assert v.size == 14 and v[0] == 0 and v[-1] == 26000 and np.all(np.diff(v) == 2000)
    assert parse_values("0:25000:2000").tolist() == [2000.0 * i for i in range(13)]  # 25000 is off the grid
    assert parse_values("12000").tolist() == [12000.0]
    assert parse_values("1000, 5000,0:2:1").tolist() == [1000.0, 5000.0, 0.0, 1.0, 2.0]
    tenth = parse_values("0:1:0.1")
    assert tenth.size == 11 and tenth[-1] == 1.0 and tenth[3] == pytest.approx(0.3, abs=1e-15)


@pytest.mark.parametrize("spec, why", [("0:10:0", "step must be > 0"), ("10:0:1", "stop is below start"),
                                       ("a", "not a number"), ("1:2", "three numbers"), ("1,,2", "empty value"),
                                       ("0:1e9:1e-3", "more than"), ("nan", "finite")])
def test_bad_ranges_name_the_option(spec, why):
    with pytest.raises(InputError) as exc:
        parse_values(spec, "--payload-kg")
    assert str(exc.value).startswith("--payload-kg: ") and why in str(exc.value)


# ------------------------------------------------------------------ state of charge


def test_state_of_charge_by_hand():
    # 0 -> 10 m/s in 10 s, then back to 0 in 10 s, flat. Per step (paper eq. 11-17):
    # k = +-50 J/kg, a = 1/4 1.225 (0 + 1000) 10 = 3062.5 J/m^2, r = 1/2 9.81 10 10 = 490.5 J/kg.
    # Step 1 is simplified (50 + 0.004 490.5 > 0), step 2 is not (-50 + 1.962 < 0).
    # m = 1000 kg, CdA = 1 m^2, Cr = 0.01, eta = 0.8, 1 kWh battery, aux 1 kW:
    # Delta_1 = 1000 (50 + 4.905) + 3062.5 = 57967.5 J; battery 57967.5 / 0.8 + 10 000 = 82459.375 J
    # Delta_2 = 1000 (-50 + 4.905) + 3062.5 = -42032.5 J; regenerated 0.64 x that / 0.8 = -33626 J,
    # plus 10 000 J of auxiliary load: 82459.375 - 23626 = 58833.375 J at the end.
    cyc = DriveCycle(np.array([0.0, 10.0, 20.0]), np.array([0.0, 10.0, 0.0]), None, "hand")
    veh = Vehicle(name="hand", powertrain="ev", mass_kg=1000.0, cda_m2=1.0, cr=0.01, eta=0.8, battery_j=3.6e6,
                  aux_power_w=1000.0)
    block = predict_source(Source.from_cycle(cyc), PredictionSet.build([veh]), soc_start_pct=90.0, reserve_pct=85.0)
    assert block.energy_j[0] == pytest.approx(58833.375, rel=1e-12)
    assert block.soc_end_pct[0] == pytest.approx(90.0 - 100.0 * 58833.375 / 3.6e6, rel=1e-12)  # 88.3657...
    assert block.soc_min_pct[0] == pytest.approx(90.0 - 100.0 * 82459.375 / 3.6e6, rel=1e-12)  # 87.7094...
    assert bool(block.reserve_ok[0]) is True  # 87.7 % >= 85 %
    strict = predict_source(Source.from_cycle(cyc), PredictionSet.build([veh]), soc_start_pct=90.0, reserve_pct=88.0)
    assert bool(strict.reserve_ok[0]) is False  # dips to 87.7 % although it ends at 88.4 %


def test_final_soc_equals_the_ce_model_total(root, hilly):
    cycles = [read_cycle_csv(root / "configs/cycles/urban-bus.csv"), *hilly]
    vehicles = [ev(), ev("small", kerb=2500.0, cda=2.1, cr=0.009, eta=0.85, battery_kwh=60.0, aux_w=3000.0),
                ice(), ice("no-credit", braking="no-credit")]
    pset = PredictionSet.build(vehicles, payload_kg=[0.0, 1500.0, 7000.0])
    for cyc in cycles:
        src = Source.from_cycle(cyc)
        block = predict_source(src, pset)
        for i in range(pset.n):
            v = vehicles[pset.vehicle_index[i]]
            m = float(pset.mass_kg[i])
            if v.is_ev:
                ce = float(ev_energy_j(src.vector, m, v.cda_m2, v.cr, v.eta, aux_power_w=v.aux_power_w))
                assert block.energy_j[i] == pytest.approx(ce, rel=1e-12)
                assert block.soc_end_pct[i] == pytest.approx(100.0 - 100.0 * ce / v.battery_j, rel=1e-12)
                end, _ = plain_run(legs_of(cyc), m, v.cda_m2, v.cr, v.eta, v.eta**2, v.aux_power_w)
                assert end == pytest.approx(ce, rel=1e-9)  # the cumulative path ends at the CE total
                assert block.soc_min_pct[i] <= block.soc_end_pct[i]
            else:
                ce = float(ice_fuel_l(src.vector, m, v.cda_m2, v.cr, v.eta, v.fuel_lhv_j_per_l, braking=v.ice_braking))
                assert block.fuel_l[i] == pytest.approx(ce, rel=1e-12)
                assert block.tank_ok[i] == 1.0


def test_lowest_soc_matches_a_plain_loop_on_real_and_hilly_cycles(root, hilly):
    cycles = [read_cycle_csv(root / "configs/cycles/regional-delivery.csv"), *hilly]
    vehicles = [ev(), ev("van", kerb=2200.0, cda=2.4, cr=0.008, eta=0.88, battery_kwh=75.0, aux_w=1500.0),
                ev("artic", kerb=16000.0, cda=6.2, cr=0.0055, eta=0.8, battery_kwh=540.0, aux_w=4000.0)]
    pset = PredictionSet.build(vehicles, payload_kg=parse_values("0:26000:2000"))
    for cyc in cycles:
        block = predict_source(Source.from_cycle(cyc), pset)
        for i in range(0, pset.n, 3):
            v = vehicles[pset.vehicle_index[i]]
            _, peak = plain_run(legs_of(cyc), float(pset.mass_kg[i]), v.cda_m2, v.cr, v.eta, v.eta**2, v.aux_power_w)
            assert block.soc_min_pct[i] == pytest.approx(100.0 - 100.0 * peak / v.battery_j, abs=1e-9)


def test_lowest_soc_in_mid_route_before_a_long_descent():
    # climb 60 m at 15 m/s, then descend 80 m: the battery is lowest at the top
    t = np.arange(0.0, 401.0)
    v = np.clip(np.minimum(t, 400 - t), 0, 15.0)
    x = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]))])
    h = np.where(t <= 200, 60.0 * t / 200, 60.0 - 80.0 * (t - 200) / 200)
    cyc = DriveCycle(t, v, h, "hill")
    src = Source.from_cycle(cyc)
    veh = ev(kerb=12000.0, battery_kwh=20.0)
    block = predict_source(src, PredictionSet.build([veh]))
    end, peak = plain_run(legs_of(cyc), 12000.0, veh.cda_m2, veh.cr, veh.eta, veh.eta**2)
    assert peak > end + 1e6 and x[-1] > 2000  # a real dip, not rounding
    assert block.soc_min_pct[0] == pytest.approx(100 - 100 * peak / veh.battery_j, abs=1e-10)
    assert block.soc_end_pct[0] == pytest.approx(100 - 100 * end / veh.battery_j, abs=1e-9)


def test_both_searches_for_the_sign_change_give_the_plain_loop(hilly, monkeypatch):
    # many vehicles with distinct CdA/Cr and payloads: a step's sign differs between the
    # masses of a vehicle, found by a table of prefix counts or (large sweeps) by a binary
    # search on complex keys; both must give the plain loop's totals and lowest SoC
    import cevm.core.sweep.wheel as fp

    rng = np.random.default_rng(3)
    vehicles = [ev(f"ev{i}", kerb=float(rng.uniform(2000, 16000)), cda=float(rng.uniform(2, 7)),
                   cr=float(rng.choice([0.004, 0.0055, 0.0081])), eta=float(rng.uniform(0.7, 0.9)),
                   battery_kwh=300.0, aux_w=float(rng.choice([0.0, 2500.0]))) for i in range(7)]
    pset = PredictionSet.build(vehicles, payload_kg=parse_values("0:20000:2500"))
    src = Source.from_cycle(hilly[0])
    results = []
    for cells in (fp._COUNT_TABLE_CELLS, 0):
        monkeypatch.setattr(fp, "_COUNT_TABLE_CELLS", cells)
        results.append(predict_source(src, pset))
    for block in results:
        for i in range(0, pset.n, 4):
            v = vehicles[pset.vehicle_index[i]]
            end, peak = plain_run(legs_of(hilly[0]), float(pset.mass_kg[i]), v.cda_m2, v.cr, v.eta, v.eta**2,
                                  v.aux_power_w)
            assert block.energy_j[i] == pytest.approx(end, rel=1e-9)
            assert block.soc_min_pct[i] == pytest.approx(100.0 - 100.0 * peak / v.battery_j, abs=1e-9)
    np.testing.assert_allclose(results[0].soc_min_pct, results[1].soc_min_pct, rtol=0, atol=1e-12)


@pytest.mark.slow
@settings(max_examples=30, deadline=None)
@given(
    m=st.floats(300.0, 60000.0), cda=st.floats(0.0, 9.0), cr=st.sampled_from([0.004, 0.0066, 0.012]),
    eta=st.floats(0.5, 1.0), w=st.floats(0.0, 1.0), aux=st.sampled_from([0.0, 800.0, 25000.0]),
    which=st.integers(0, 1),
)
def test_peak_energy_matches_a_plain_loop(hilly, m, cda, cr, eta, w, aux, which):
    cyc = hilly[which]
    got = peak_energy_j(Source.from_cycle(cyc).steps, [m, m * 1.7], cda, cr, eta, w, aux)
    for mm, g in zip([m, m * 1.7], got, strict=True):
        _, peak = plain_run(legs_of(cyc), mm, cda, cr, eta, w, aux)
        assert g == pytest.approx(peak, rel=1e-9, abs=1e-3)


def test_route_legs_follow_each_other_without_a_joining_step(hilly):
    a, b = hilly
    route = Source(name="ab", kind="route", vector=Source.from_cycle(a).vector + Source.from_cycle(b).vector,
                   legs=[LegProfile(a.time_s, a.speed_mps, a.elevation_m),
                         LegProfile(b.time_s, b.speed_mps, b.elevation_m)])
    veh = ev(kerb=3000.0, cda=2.5, cr=0.008, eta=0.85, battery_kwh=40.0, aux_w=2000.0)
    block = predict_source(route, PredictionSet.build([veh], payload_kg=[0.0, 800.0]))
    for i, m in enumerate([3000.0, 3800.0]):
        end, peak = plain_run(legs_of(a) + legs_of(b), m, 2.5, 0.008, 0.85, 0.85**2, 2000.0)
        assert block.energy_j[i] == pytest.approx(end, rel=1e-9)
        assert block.soc_min_pct[i] == pytest.approx(100 - 100 * peak / veh.battery_j, abs=1e-9)
    t, d, e = energy_trajectory(route, veh, 3000.0)
    assert t[-1] == pytest.approx(a.duration_s + b.duration_s) and e[-1] == pytest.approx(block.energy_j[0], rel=1e-9)
    assert d[-1] == pytest.approx(route.distance_m, rel=1e-12)


# ---------------------------------------------------------------- prediction sets


def test_payloads_masses_and_the_gross_limit():
    pset = PredictionSet.build([ice(max_gross=40000.0), ev(max_gross=None)], payload_kg=[0.0, 20000.0, 26000.0])
    assert pset.mass_kg.tolist() == [18000.0, 38000.0, 44000.0, 9000.0, 29000.0, 35000.0]
    assert pset.payload_kg.tolist() == [0.0, 20000.0, 26000.0] * 2
    assert pset.over_max_gross.tolist() == [False, False, True, False, False, False]
    nokerb = Vehicle(name="nk", powertrain="ev", mass_kg=2000.0, cda_m2=1.0, cr=0.01, eta=0.8, battery_j=1e8)
    with pytest.raises(Exception, match="no kerb_mass_kg"):
        PredictionSet.build([nokerb], payload_kg=[100.0])
    gross = PredictionSet.build([nokerb], mass_kg=[2500.0])
    assert math.isnan(gross.payload_kg[0]) and gross.mass_kg[0] == 2500.0


def test_sweep_streams_one_block_per_source_in_order(root, hilly):
    sources = [Source.from_cycle(c)
               for c in hilly] + [Source.from_cycle(read_cycle_csv(root / "configs/cycles/urban-bus.csv"))]
    pset = PredictionSet.build([ev(), ice()], payload_kg=[0.0, 5000.0])
    blocks = list(sweep(sources, pset))
    assert [b.source_index for b in blocks] == [0, 1, 2] and [b.source.name
                                                              for b in blocks] == ["hilly-a", "hilly-b", "urban-bus"]
    for src, b in zip(sources, blocks, strict=True):
        one = predict_source(src, pset)
        assert np.allclose(b.wheel_energy_j, one.wheel_energy_j, rtol=1e-13)
        assert np.allclose(b.soc_min_pct, one.soc_min_pct, rtol=1e-13, equal_nan=True)


# ---------------------------------------------------------------------- feasibility


def plain_soc_min(cyc, veh, payload, soc_start=100.0):
    _, peak = plain_run(legs_of(cyc), veh.kerb_mass_kg + payload, veh.cda_m2, veh.cr, veh.eta, veh.eta**2,
                        veh.aux_power_w)
    return soc_start - 100.0 * peak / veh.battery_j


def bisect_last_ok(ok, lo, hi):
    """Largest integer p in [lo, hi] with ok(p), given ok(lo) and not ok(hi)."""
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (mid, hi) if ok(mid) else (lo, mid)
    return lo


def test_largest_payload_keeping_the_reserve_against_a_plain_bisection(hilly):
    cyc = hilly[0]
    src = Source.from_cycle(cyc)
    # battery sized so that the reserve binds inside the payload range
    buses = [ev("bus", kerb=9000.0, battery_kwh=11.0, max_gross=19000.0, aux_w=2000.0),
             ev("van", kerb=2500.0, cda=2.4, cr=0.009, eta=0.86, battery_kwh=2.2, max_gross=4250.0)]
    res = feasibility(src, buses, reserve_pct=15.0)
    for i, veh in enumerate(buses):
        plim = int(veh.max_gross_kg - veh.kerb_mass_kg)
        assert plain_soc_min(cyc, veh, 0) >= 15.0 > plain_soc_min(cyc, veh, plim)  # the case is what we think
        want = bisect_last_ok(lambda p, v=veh: plain_soc_min(cyc, v, p) >= 15.0, 0, plim)
        assert res.max_payload_kg[i] == want and res.limited_by[i] == "reserve" and res.min_payload_kg[i] == 0
    # margins at the default load (kerb mass: payload 0)
    assert res.soc_min_pct[0] == pytest.approx(plain_soc_min(cyc, buses[0], 0.0), abs=1e-9)
    assert res.reserve_margin_pct[0] == pytest.approx(res.soc_min_pct[0] - 15.0)
    assert res.feasible[0] == 1.0


def test_largest_payload_for_the_tank_and_the_gross_limit(hilly):
    cyc = hilly[1]
    src = Source.from_cycle(cyc)
    small_tank = ice("small tank", tank_l=5.0, braking="no-credit")
    big_tank = ice("big tank", tank_l=400.0)
    no_tank = ice("no tank", tank_l=None)
    res = feasibility(src, [small_tank, big_tank, no_tank])

    def fuel(p):
        return plain_fuel(legs_of(cyc), 18000.0 + p, 6.62, 0.0066, 0.45, 35.8e6, no_credit=True)

    assert fuel(0) <= 5.0 < fuel(26000)
    assert res.max_payload_kg[0] == bisect_last_ok(lambda p: fuel(p) <= 5.0, 0, 26000)
    assert res.limited_by[0] == "tank"
    assert res.max_payload_kg[1] == 26000 and res.limited_by[1] == "max_gross_kg"
    assert res.max_payload_kg[2] == 26000 and np.isnan(res.feasible[2])  # no tank_l: unknown
    assert res.tank_margin_l[1] == pytest.approx(400.0 - plain_fuel(legs_of(cyc), 18000.0, 6.62, 0.0066, 0.45,
                                                                    35.8e6, no_credit=False), rel=1e-9)


def test_energy_falling_with_mass_gives_a_smallest_payload():
    # 3 km down a 2 % slope at 10 m/s, then 3 km flat: a heavier vehicle regenerates more
    # on the descent than it spends rolling on the flat, so the battery energy drawn
    # falls with mass (0.51 kWh at 2 t, 0.15 kWh at 8 t, by the plain loop).
    t = np.arange(0.0, 621.0)
    v = np.clip(np.minimum(t, 620 - t), 0, 10.0)
    dist = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]))])
    h = np.where(dist <= 3000, 60.0 - 0.02 * dist, 0.0)
    cyc = DriveCycle(t, v, h, "downhill")
    veh = ev("downhill EV", kerb=2000.0, cda=6.0, cr=0.005, eta=0.95, battery_kwh=0.5, max_gross=8000.0)

    def soc_min(p):
        _, peak = plain_run(legs_of(cyc), 2000.0 + p, 6.0, 0.005, 0.95, 0.95**2)
        return 100.0 - 100.0 * peak / veh.battery_j

    assert soc_min(0) < 15.0 <= soc_min(6000)  # the empty vehicle fails, a loaded one passes
    res = feasibility(Source.from_cycle(cyc), [veh])
    lo, hi = 0, 6000  # first ok payload: soc_min rises with the payload here
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (lo, mid) if soc_min(mid) >= 15.0 else (mid, hi)
    assert res.min_payload_kg[0] == hi
    assert res.max_payload_kg[0] == 6000 and res.limited_by[0] == "max_gross_kg"
    assert res.feasible[0] == 0.0


def test_infeasible_at_every_payload():
    cyc = micro_trip_cycle(MicroTripSpec(n_trips=10), seed=3)
    res = feasibility(Source.from_cycle(cyc), [ev("tiny", kerb=9000.0, battery_kwh=0.5, max_gross=12000.0)])
    assert np.isnan(res.max_payload_kg[0]) and res.limited_by[0] == "infeasible" and res.feasible[0] == 0.0


# ------------------------------------------------------------------------------ CLI


@pytest.mark.slow
def test_cli_payload_sweep_csv_json_and_plot(tmp_path, root):
    bus, hgv = root / "configs/vehicles/electric-bus.toml", root / "configs/vehicles/diesel-hgv.toml"
    urban = root / "configs/cycles/urban-bus.csv"
    args = ["predict", "-v", str(bus), "-v", str(hgv), "-c", str(urban), "-p", "0:26000:2000"]
    res = runner.invoke(app, args + ["-f", "json"])
    assert res.exit_code == 0, res.output
    rows = json.loads(res.stdout)
    assert len(rows) == 2 * 14 and [r["payload_kg"] for r in rows[:14]] == [2000.0 * i for i in range(14)]
    for r in rows:
        if r["powertrain"] == "ev":
            assert r["soc_min_pct"] <= r["soc_end_pct"] < 100.0 and r["reserve_ok"] is True
            assert set(r) >= {"energy_kwh", "energy_kwh_per_km", "soc_end_pct", "soc_min_pct", "reserve_ok"}
        else:
            assert r["tank_ok"] is True and r["over_max_gross"] is (r["mass_kg"] > 44000.0)
    out = tmp_path / "sweep.csv"
    res = runner.invoke(app, args + ["-f", "csv", "-o", str(out), "--plot", str(tmp_path / "payload.png")])
    assert res.exit_code == 0, res.output
    table = list(csv.DictReader(io.StringIO(out.read_text())))
    assert len(table) == 28 and table[0]["cycle"] == "urban-bus"
    for j, c in zip(rows, table, strict=True):
        for key in ("mass_kg", "energy_kwh", "fuel_l", "soc_min_pct", "wheel_energy_kwh"):
            if j.get(key) is None:
                assert c[key] == ""
            else:
                assert float(c[key]) == pytest.approx(j[key], abs=2e-6)
        assert c["over_max_gross"] == ("true" if j["over_max_gross"] else "false")
    assert (tmp_path / "payload.png").stat().st_size > 10_000
    res = runner.invoke(app, ["predict", "-v", str(bus), "-c", str(urban), "--plot", str(tmp_path / "soc.png"),
                              "--soc-start", "80", "--reserve-pct", "75"])
    assert res.exit_code == 0 and (tmp_path / "soc.png").stat().st_size > 10_000
    assert "NO" in res.stdout  # 80 % start, 75 % reserve: the urban cycle takes more than 5 %


def test_cli_rejects_bad_sweeps(root):
    bus = str(root / "configs/vehicles/electric-bus.toml")
    urban = str(root / "configs/cycles/urban-bus.csv")
    for extra, msg in ((["-p", "0:10:0"], "--payload-kg: range '0:10:0': step must be > 0"),
                       (["-p", "1", "-m", "2"], "not both"), (["--soc-start", "120"], "--soc-start"),
                       (["-m", "0"], "positive")):
        res = runner.invoke(app, ["predict", "-v", bus, "-c", urban, *extra])
        assert res.exit_code == 2 and msg in res.output, res.output
