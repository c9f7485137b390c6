"""cevm replay's core: duties, the levels carried from trip to trip with
charging, where a duty fails, the sizes it needs, and its probability of completing;
against the plain per-step reference (tests/reference.py) and hand computations."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.special import ndtr

from cevm.core.replay import (
    Charging,
    Lanes,
    Place,
    ReplaySettings,
    Stops,
    TripSpread,
    find_depot,
    group_duties,
    p_complete,
    plan_vehicle,
    run_chains,
    smallest_passing,
    stops_at,
    trip_energies,
)
from cevm.core.replay.montecarlo import DrawPlan
from cevm.core.vehicle import predict
from replay_cases import (
    cycle,
    ev,
    ice,
    logged,
    reference_energy,
    reference_ev_crossing,
    reference_ev_peak,
    tables,
)

KWH = 3.6e6
H = 3600.0


# ------------------------------------------------------------------------ duties


def test_a_long_stop_ends_a_duty_and_a_night_shift_stays_whole():
    # day shift 06:00-10:00 with a 2 h break, then a night shift 22:00-03:00 across midnight
    start = np.array([6, 9, 22, 25, 27.5]) * H
    end = np.array([7, 10, 24, 26.5, 28]) * H
    d = group_duties(start, end, gap_s=6 * H)
    assert d.bounds.tolist() == [0, 2, 5]
    assert d.dwell_s.tolist()[:4] == [2 * H, 12 * H, 1 * H, 1 * H] and math.isnan(d.dwell_s[-1])
    by_day = group_duties(start, end, rule="day", day=(start // (24 * H)).astype(int))
    assert by_day.bounds.tolist() == [0, 3, 5]  # the calendar cuts the night shift at midnight
    assert group_duties(start, end, gap_s=0.5 * H).bounds.tolist() == [0, 1, 2, 3, 4, 5]


def test_overlapping_trips_give_no_negative_stop():
    d = group_duties(np.array([0.0, 100.0, 150.0]), np.array([200.0, 120.0, 300.0]))
    assert d.dwell_s.tolist()[:2] == [0.0, 0.0]  # the latest end so far decides


# ---------------------------------------------------------------- trip energies


@pytest.mark.parametrize("kind", ["ev", "ice"])
def test_trip_energies_are_the_model_trip_by_trip(tmp_path, kind):
    veh = ev(tmp_path) if kind == "ev" else ice(tmp_path)
    cycles = [cycle(s) for s in range(4)]
    masses = np.array([20e3, 30e3, 40e3, 25e3])
    temps = np.array([-5.0, 3.0, np.nan, 18.0])  # NaN: not logged, the default 20 degC
    trips = logged(cycles, np.arange(4) * 2 * H, masses=masses, temps=temps)
    te = trip_energies(trips.vectors, veh, masses, temps)
    for i, c in enumerate(cycles):
        t = 20.0 if np.isnan(temps[i]) else temps[i]
        assert te.ambient_c[i] == t
        p = predict(trips.vectors[i], veh, float(masses[i]), ambient_c=t)
        model = p.energy_j if kind == "ev" else p.fuel_l
        assert te.energy[i] == pytest.approx(float(model), rel=1e-12)
        assert te.energy[i] == pytest.approx(reference_energy(c, masses[i], veh, t), rel=1e-9)
    assert te.ambient_from.tolist() == [1, 1, 3, 1]


def test_a_duty_is_the_sum_of_its_trips_and_the_levels_match_a_hand_computation(tmp_path):
    veh = ev(tmp_path, 300.0)
    cycles = [cycle(10), cycle(11), cycle(12)]
    dur = [c[0][-1] for c in cycles]
    starts = [0.0, dur[0] + 20 * 60, dur[0] + 20 * 60 + dur[1] + 45 * 60]  # stops of 20 and 45 min
    trips = logged(cycles, starts, masses=[28e3, 28e3, 28e3], temps=[5.0, 5.0, 5.0])
    s = ReplaySettings(soc_start_pct=90.0, charging=Charging(power_w=50e3, efficiency=0.9))
    plan = plan_vehicle(trips, veh, s, tables(cycles, trips))
    e = [reference_energy(c, 28e3, veh, 5.0) for c in cycles]
    assert plan.duties.n == 1
    assert plan.energies.energy.sum() == pytest.approx(sum(e), rel=1e-9)
    cap = 300 * KWH
    l0 = 0.9 * cap
    l1 = l0 - e[0]  # the 20 min stop is shorter than --min-dwell-min 30: no charge
    l2 = l1 - e[1]
    gain = min(0.9 * 50e3 * 45 * 60, cap - l2)
    l3 = l2 + gain
    np.testing.assert_allclose(plan.before, [l0, l1, l3], rtol=1e-9)
    np.testing.assert_allclose(plan.after, [l1, l2, l3 - e[2]], rtol=1e-9)
    np.testing.assert_allclose(plan.gain[:2], [0.0, gain], rtol=1e-12)
    assert plan.levels.gained[0] == pytest.approx(gain) and plan.levels.charges[0] == 1
    assert plan.levels.end[0] == pytest.approx(l3 - e[2], rel=1e-9)


def test_charging_stops_at_full(tmp_path):
    veh = ev(tmp_path, 300.0)
    cycles = [cycle(20), cycle(21)]
    starts = [0.0, cycles[0][0][-1] + 5 * H]
    trips = logged(cycles, starts, masses=[30e3, 30e3])
    plan = plan_vehicle(trips, veh, ReplaySettings(charging=Charging(power_w=350e3)), tables(cycles, trips))
    assert plan.before[1] == pytest.approx(300 * KWH)  # full again, not beyond
    assert plan.gain[0] == pytest.approx(plan.energies.energy[0])


def _failing_case(tmp_path):
    """Three trips, the last a short one; a 45 min stop after the first, 20 min after the
    second; a battery that falls below its reserve in the second trip, but would run the
    last two from full."""
    cycles = [cycle(30), cycle(31), cycle(32, n_trips=2)]
    dur = [c[0][-1] for c in cycles]
    starts = [0.0, dur[0] + 45 * 60, dur[0] + 45 * 60 + dur[1] + 20 * 60]
    trips = logged(cycles, starts, masses=[35e3] * 3, temps=[10.0] * 3)
    probe = ev(tmp_path, 300.0)
    e = [reference_energy(c, 35e3, probe, 10.0) for c in cycles]
    peak = [reference_ev_peak(c, 35e3, probe, 10.0)[0] for c in cycles]
    usable = 1.1 * max(peak[1], e[1] + peak[2])  # above the reserve: runs the last two from full
    assert peak[0] < usable < e[0] + peak[1]  # but not the first two
    return cycles, trips, e, ev(tmp_path, round(usable / 0.85 / KWH, 6))


def test_a_duty_the_battery_cannot_run_is_named_with_where_it_fails(tmp_path):
    cycles, trips, e, veh = _failing_case(tmp_path)
    plan = plan_vehicle(trips, veh, ReplaySettings(), tables(cycles, trips))
    assert not plan.levels.low[0] >= plan.reserve
    assert plan.reserve_trip[0] == 1  # the second trip
    level = plan.before[1] - plan.reserve
    _, inside = reference_ev_crossing(cycles[1], 35e3, veh, 10.0, level)
    assert plan.reserve_at_m[0] == pytest.approx(trips.distance_m[0] + inside, rel=1e-6)
    level, lows = veh.battery_j, []  # what it lacks: at its lowest point, by brute force
    for c in cycles:
        peak, end = reference_ev_peak(c, 35e3, veh, 10.0)
        lows.append(level - peak)
        level -= end
    assert plan.reserve - plan.levels.low[0] == pytest.approx(plan.reserve - min(lows), rel=1e-9)
    assert plan.empty_trip[0] == -1 or plan.empty_trip[0] >= 1


def test_with_a_charger_it_completes(tmp_path):
    cycles, trips, _, veh = _failing_case(tmp_path)
    plan = plan_vehicle(trips, veh, ReplaySettings(charging=Charging(power_w=150e3)), tables(cycles, trips))
    assert plan.levels.low[0] >= plan.reserve and plan.reserve_trip[0] == -1
    assert plan.gain[0] > 0 and plan.levels.charges[0] == 1


def test_the_lowest_point_inside_a_trip_that_ends_downhill(tmp_path):
    veh = ev(tmp_path, 300.0)
    cycles = [cycle(40), cycle(41, descent_m=80.0)]
    starts = [0.0, cycles[0][0][-1] + 10 * 60]
    trips = logged(cycles, starts, masses=[40e3, 40e3], temps=[15.0, 15.0])
    read = tables(cycles, trips)
    plan = plan_vehicle(trips, veh, ReplaySettings(), read)
    peak, end = reference_ev_peak(cycles[1], 40e3, veh, 15.0)
    assert peak - end > 1e5  # the descent gives energy back after the peak
    e0 = reference_energy(cycles[0], 40e3, veh, 15.0)
    assert plan.levels.low[0] == pytest.approx(300 * KWH - e0 - peak, rel=1e-9)
    assert set(read.calls) <= {0, 1}


def test_step_tables_are_read_only_where_they_could_decide(tmp_path):
    veh = ev(tmp_path, 3000.0)  # a battery far larger than the day: no trip can matter but the lowest
    cycles = [cycle(50 + k) for k in range(6)]
    starts = np.cumsum([0.0] + [c[0][-1] + 600 for c in cycles[:-1]])
    trips = logged(cycles, starts, masses=[30e3] * 6)
    read = tables(cycles, trips)
    plan = plan_vehicle(trips, veh, ReplaySettings(battery_step=0.0, charger_step_w=0.0), read)
    assert len(set(read.calls)) <= 2
    lows = []
    level = 3000 * KWH
    for c in cycles:  # the duty's lowest point by brute force: every trip's peak
        peak, end = reference_ev_peak(c, 30e3, veh, 20.0)
        lows.append(level - peak)
        level -= end
    assert plan.levels.low[0] == pytest.approx(min(lows), rel=1e-9)


# ------------------------------------------------------------------------ sizing


def test_battery_and_charger_sizes_are_exact_to_their_step(tmp_path):
    cycles, trips, _, veh = _failing_case(tmp_path)
    s = ReplaySettings(charging=Charging(power_w=2e3))
    plan = plan_vehicle(trips, veh, s, tables(cycles, trips))
    assert plan.reserve_trip[0] >= 0  # 2 kW at the long stop do not save it
    need = plan.battery_needed[0] / KWH
    assert need == round(need) and need > veh.battery_j / KWH
    for kwh, ok in ((need, True), (need - 1, False)):
        v = dataclasses.replace(veh, battery_j=kwh * KWH)
        p = plan_vehicle(trips, v, s, tables(cycles, trips), size=False)
        assert bool(p.levels.low[0] >= p.reserve) is ok, kwh
    kw = plan.charger_needed_w[0] / 1e3
    assert kw == round(kw) and kw > 2
    for p_kw, ok in ((kw, True), (kw - 1, False)):
        s2 = dataclasses.replace(s, charging=Charging(power_w=p_kw * 1e3))
        p = plan_vehicle(trips, veh, s2, tables(cycles, trips), size=False)
        assert bool(p.levels.low[0] >= p.reserve) is ok, p_kw


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(0, 400), min_size=1, max_size=30), st.integers(0, 400))
def test_smallest_passing_is_the_first_that_passes(thresholds, hi):
    thr = np.array(thresholds)
    got = smallest_passing(lambda k: k >= thr, np.zeros_like(thr), np.full(thr.shape, hi))
    want = np.where(thr <= hi, thr, hi + 1)
    assert got.tolist() == want.tolist()


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(-5.0, 60.0), st.floats(0.0, 5.0), st.floats(0.0, 3.0), st.booleans()),
                min_size=1, max_size=8),
       st.floats(20.0, 200.0), st.floats(0.0, 100.0))
def test_levels_never_fall_with_a_bigger_battery_or_charger(trips, cap, power):
    e = np.array([t[0] for t in trips])
    x = np.array([t[1] for t in trips])
    dwell = np.array([t[2] for t in trips])
    charge = np.array([t[3] for t in trips])
    stops = Stops(dwell, np.where(charge, power, 0.0), charge, np.zeros(len(trips), bool))
    lanes = Lanes.of([0], [len(trips)])
    base = run_chains(lanes, e, x, stops, capacity=cap, start=cap, efficiency=0.9)
    more = run_chains(lanes, e, x, stops, capacity=cap + 7.0, start=cap + 7.0, efficiency=0.9)
    stronger = run_chains(lanes, e, x, stops, capacity=cap, start=cap, efficiency=0.9,
                          power_w=stops.with_power(power + 13.0))
    assert np.all(more.low >= base.low - 1e-9) and np.all(stronger.low >= base.low - 1e-9)
    # the reserve kept at a share of the capacity: monotone too (the sizing's premise)
    for r in (0.1, 0.3):
        if base.low.min() >= r * cap:
            assert more.low.min() >= r * (cap + 7.0) - 1e-9


# ------------------------------------------------------------------- probability


def _spread(n, aux, share, rho):
    z = np.zeros(n)
    return TripSpread(np.zeros((n, 0)), np.zeros((0, 0)), 0.0, np.full(n, aux), np.full(n, share), z, rho, "posterior")


def _draw_plan(mean, spread, dwell, power, cap, start, reserve, bounds=None, key="V"):
    n = mean.size
    bounds = np.array([0, n]) if bounds is None else np.asarray(bounds)
    end = np.zeros(n, bool)
    end[bounds[1:] - 1] = True
    stops = Stops(np.asarray(dwell, float), np.asarray(power, float), np.asarray(power, float) > 0, end)
    return DrawPlan(mean=mean, excess=np.zeros(n), spread=spread, stops=stops, bounds=bounds, chained=False,
                    capacity=cap, start=start, reserve=reserve, efficiency=0.9, key=key,
                    duty_start_s=np.arange(bounds.size - 1) * 86400.0)


def test_p_complete_without_charging_is_the_gaussian_of_the_sum():
    mean = np.array([30.0, 25.0, 40.0])
    aux, share, rho = 3.0, 0.0, 0.4
    sp = _spread(3, aux, share, rho)
    plan = _draw_plan(mean, sp, [0.5, 0.5, np.nan], [0.0, 0.0, 0.0], 150.0, 150.0, 45.0)
    var = rho * (3 * aux) ** 2 + (1 - rho) * 3 * aux ** 2
    assert sp.duty_sd(mean, np.array([0, 3]))[0] == pytest.approx(math.sqrt(var))
    want = float(ndtr((105.0 - 95.0) / math.sqrt(var)))
    draws = 20000
    got = p_complete(plan, draws=draws, seed=5)[0]
    assert abs(got - want) < 4.5 * math.sqrt(want * (1 - want) / draws)


def test_p_complete_matches_a_simulation_with_known_scatter():
    """A charger that fills up at the middle stop: the duty's lowest level is a
    non-linear function of the draws; a plain simulation of the stated scatter gives the
    same frequency."""
    mean = np.array([40.0, 35.0, 45.0, 30.0])
    aux, share, rho = 6.0, 0.05, 0.6
    sp = _spread(4, aux, share, rho)
    dwell, power = [0.2, 1.0, 0.2, np.nan], [0.0, 80.0, 0.0, 0.0]  # fills up to 72 of the 75 used
    plan = _draw_plan(mean, sp, dwell, power, 150.0, 150.0, 60.0)
    draws = 20000
    got = p_complete(plan, draws=draws, seed=11)[0]
    rng = np.random.default_rng(99)
    ok = 0
    sims = 20000
    a, s = aux, share * mean
    for _ in range(sims):
        za, zs = rng.standard_normal(2)
        own = rng.standard_normal((4, 2))
        y = mean + math.sqrt(rho) * (a * za + s * zs) + math.sqrt(1 - rho) * (a * own[:, 0] + s * own[:, 1])
        level, low = 150.0, 150.0
        for i in range(4):
            low = min(low, level - y[i])
            level = min(level - y[i], 150.0)
            if power[i] > 0:
                level = min(150.0, level + 0.9 * power[i] * dwell[i])
        ok += low >= 60.0
    want = ok / sims
    assert 0.05 < want < 0.95
    assert abs(got - want) < 4.5 * math.sqrt(want * (1 - want) * (1 / draws + 1 / sims))


def test_draws_do_not_depend_on_how_they_are_chunked(monkeypatch):
    from cevm.core.replay import montecarlo

    mean = np.array([60.0, 50.0, 55.0, 45.0, 70.0])
    sp = _spread(5, 6.0, 0.05, 0.5)
    plan = _draw_plan(mean, sp, [0.2, np.nan, 1.0, 0.2, np.nan], [0.0] * 5, 150.0, 150.0, 22.5, bounds=[0, 2, 5])
    whole = p_complete(plan, draws=3000)
    monkeypatch.setattr(montecarlo, "DRAW_CHUNK_CELLS", 64)  # 64 cells: many small chunks
    assert np.array_equal(p_complete(plan, draws=3000), whole)
    assert not np.array_equal(p_complete(plan, draws=3000, seed=24), whole)


# --------------------------------------------------------------------- places


def test_the_depot_is_where_the_vehicle_rests_most():
    home = (52.0600, -0.7040)
    lat = np.array([52.0601, 52.0598, 51.5, 52.0603, np.nan, 52.0599])
    lon = np.array([-0.7041, -0.7038, -0.1, -0.7044, np.nan, -0.7040])
    depot = find_depot(lat, lon, 500.0)
    assert depot is not None and depot.rests_there == 4 and depot.rests_known == 5
    assert depot.place.lat_deg == pytest.approx(home[0], abs=5e-4)
    assert find_depot(np.array([52.0, 53.0, 54.0]), np.array([0.0, 0.0, 0.0])) is None  # no home base
    at = stops_at([depot.place], np.array([52.0601, 51.5, np.nan, np.nan]), np.array([-0.7041, -0.1, np.nan, np.nan]),
                  np.array([52.0602, 51.5, 52.06, np.nan]), np.array([-0.7042, -0.1, -0.704, np.nan]))
    assert at.tolist() == [True, False, True, False]


def test_charging_only_at_the_depot(tmp_path):
    cycles, trips, _, veh = _failing_case(tmp_path)
    far, home = (51.5, -0.1), (52.06, -0.704)
    # trip 0 ends far away (the 45 min stop is not at the depot); every duty starts and ends at home
    pos = (np.array([home[0], far[0], home[0]]), np.array([home[1], far[1], home[1]]),
           np.array([far[0], home[0], home[0]]), np.array([far[1], home[1], home[1]]))
    trips = dataclasses.replace(trips, start_lat=pos[0], start_lon=pos[1], end_lat=pos[2], end_lon=pos[3])
    s = ReplaySettings(charging=Charging(power_w=150e3, depot=True))
    plan = plan_vehicle(trips, veh, s, tables(cycles, trips))
    assert plan.depot is not None and plan.gain[0] == 0.0  # the stop that could save it is not at the depot
    assert plan.reserve_trip[0] == 1
    here = dataclasses.replace(s, charging=Charging(power_w=150e3, places=(Place(*far, 300.0),)))
    assert plan_vehicle(trips, veh, here, tables(cycles, trips)).reserve_trip[0] == -1


# --------------------------------------------------------------- levels carried


def test_levels_carry_across_duties_without_an_overnight_charge(tmp_path):
    veh = ev(tmp_path, 300.0)
    cycles = [cycle(60), cycle(61), cycle(62)]
    starts = [0.0, 24 * H, 48 * H]  # three duties, a day apart
    trips = logged(cycles, starts, masses=[30e3] * 3)
    e = [reference_energy(c, 30e3, veh, 20.0) for c in cycles]
    cap = 300 * KWH
    none = plan_vehicle(trips, veh, ReplaySettings(charging=Charging(overnight="none")), tables(cycles, trips))
    np.testing.assert_allclose(none.levels.start, [cap, cap - e[0], cap - e[0] - e[1]], rtol=1e-9)
    assert np.isnan(none.battery_needed).all()  # sized for the fleet, not per duty
    night = plan_vehicle(trips, veh, ReplaySettings(charging=Charging(overnight="power", overnight_w=11e3,
                                                                      efficiency=0.9)), tables(cycles, trips))
    rest = starts[1] - trips.end_s[0]
    assert night.levels.start[1] == pytest.approx(min(cap, cap - e[0] + 0.9 * 11e3 * rest), rel=1e-9)
    full = plan_vehicle(trips, veh, ReplaySettings(), tables(cycles, trips))
    np.testing.assert_allclose(full.levels.start, [cap] * 3)


def test_a_diesel_candidate_refuels_at_the_places_named(tmp_path):
    veh = ice(tmp_path, 30.0)
    cycles = [cycle(70, n_trips=20), cycle(71, n_trips=20), cycle(72, n_trips=20)]
    dur = [c[0][-1] for c in cycles]
    starts = [0.0, dur[0] + 45 * 60, dur[0] + dur[1] + 90 * 60]
    pump = (52.1, -0.8)
    pos = tuple(np.full(3, v) for v in (pump[0], pump[1], pump[0], pump[1]))
    trips = logged(cycles, starts, masses=[40e3] * 3, temps=[5.0] * 3, positions=pos)
    fuel = [reference_energy(c, 40e3, veh, 5.0) for c in cycles]
    plain = plan_vehicle(trips, veh, ReplaySettings(), tables(cycles, trips))
    assert plain.energies.energy.sum() == pytest.approx(sum(fuel), rel=1e-9)
    assert plain.levels.gained[0] == 0.0  # no place named: a diesel refuels overnight only
    s = ReplaySettings(charging=Charging(places=(Place(*pump, 200.0),)))
    plan = plan_vehicle(trips, veh, s, tables(cycles, trips))
    np.testing.assert_allclose(plan.gain[:2], fuel[:2], rtol=1e-9)  # back to full at both stops
    assert plan.levels.end[0] == pytest.approx(30.0 - fuel[2], rel=1e-9)


def test_the_fleets_battery_with_levels_carried_is_exact_to_its_step(tmp_path):
    from cevm.core.replay.fleet import Chain, chained_sizes

    veh = ev(tmp_path, 300.0)
    cycles = [cycle(80 + k) for k in range(6)]
    starts = [0.0, 3600.0, 86400.0, 90000.0, 172800.0, 176400.0]  # three duties of two trips, a day apart
    trips = logged(cycles, starts, masses=[30e3] * 6)
    s = ReplaySettings(charging=Charging(overnight="power", overnight_w=3e3))
    plan = plan_vehicle(trips, veh, s, tables(cycles, trips))
    exact = tables(cycles, trips)

    def learn(idx):
        from cevm.core.replay import trips_excess
        return trips_excess([exact(int(i)) for i in idx], veh, plan.energies.mass_kg[idx], plan.energies.ambient_c[idx])

    chain = Chain(plan.energies.energy, plan.excess, learn, plan.stops, plan.duties.bounds)
    battery, _ = chained_sizes([chain], 1.0, soc_start=1.0, reserve=0.15, efficiency=0.9, capacity=veh.battery_j,
                               battery_step=KWH, charger_step=1e3)
    kwh = battery / KWH
    assert kwh == round(kwh)
    for size, ok in ((kwh, True), (kwh - 1, False)):
        p = plan_vehicle(trips, dataclasses.replace(veh, battery_j=size * KWH), s, tables(cycles, trips), size=False)
        assert bool((p.levels.low >= p.reserve).all()) is ok, size


def test_duties_sure_by_six_sd_are_not_drawn(monkeypatch):
    from cevm.core.replay import montecarlo

    mean = np.array([30.0, 25.0])
    sp = _spread(2, 1.0, 0.01, 0.5)
    plan = _draw_plan(mean, sp, [0.5, np.nan], [0.0, 0.0], 400.0, 400.0, 60.0)
    assert montecarlo.sure_duties(plan).all() and p_complete(plan, draws=100)[0] == 1.0
    monkeypatch.setattr(montecarlo, "SURE_SD", 1e9)  # now drawn: every draw keeps the reserve too
    assert not montecarlo.sure_duties(plan).any() and p_complete(plan, draws=2000)[0] == 1.0


def test_levels_at_the_trips_ends_only_read_no_profile(tmp_path):
    cycles, trips, e, veh = _failing_case(tmp_path)
    read = tables(cycles, trips)
    plan = plan_vehicle(trips, veh, ReplaySettings(within_trips=False, battery_step=0.0, charger_step_w=0.0), read)
    assert read.calls == []
    ends = np.cumsum(e)
    assert plan.levels.low[0] == pytest.approx(veh.battery_j - ends[-1], rel=1e-9)
    assert plan.reserve_trip[0] == 1  # where: in proportion to the trip's energy
    share = (plan.before[1] - plan.reserve) / e[1]
    assert plan.reserve_at_m[0] == pytest.approx(trips.distance_m[0] + share * trips.distance_m[1], rel=1e-9)


def test_the_spread_taken_apart_gives_the_predictive_distributions_back(tmp_path):
    """The predictive API (cevm.core.predictive) gives each trip's spread and each day's
    total: the parts replay draws from add up to the same (a vehicle never calibrated: its
    class's prior, no extrapolation)."""
    pr = pytest.importorskip("cevm.core.predictive")
    from cevm.core.replay import trip_spread

    veh = ev(tmp_path)
    cycles = [cycle(90 + k) for k in range(5)]
    trips = logged(cycles, [0.0, 3600.0, 7200.0, 86400.0, 90000.0], masses=[30e3, 35e3, 25e3, 40e3, 30e3],
                   temps=[-3.0, 0.0, 2.0, 15.0, 18.0])
    te = trip_energies(trips.vectors, veh, trips.gross_kg, trips.ambient_c)
    sp = trip_spread(veh, te)
    if sp.source == "none":
        pytest.skip("the test vehicle has no priors")
    f = pr.Features(te.positive_j, te.negative_j, te.duration_s, te.idle_s, te.traction_s, te.kinetic_j,
                    te.ambient_c, np.ones(te.n), spec=te.spec)  # with the spec sheet's CdA and Cr derivatives
    np.testing.assert_allclose(sp.trip_sd(te.energy), pr.predictive(veh, f).sd, rtol=1e-9)
    bounds = np.array([0, 3, 5])
    # the scatter's part that does not grow with a trip is folded into each trip's
    # auxiliary part, and the spec sheet's CdA and Cr into the common part with the
    # extrapolation (exact per trip, above); a duty's sum of those square roots is a
    # little wider than the exact (the parts summed apart): within 1e-4 here
    np.testing.assert_allclose(sp.duty_sd(te.energy, bounds), pr.total(veh, f, groups=[0, 0, 0, 1, 1]).sd, rtol=1e-4)
    assert (sp.duty_sd(te.energy, bounds) >= pr.total(veh, f, groups=[0, 0, 0, 1, 1]).sd * (1 - 1e-12)).all()


def test_the_candidates_mass_on_each_trip(tmp_path):
    from cevm.core.replay import candidate_masses

    veh = ev(tmp_path)  # kerb 18 t, mass_kg 28 t
    trips = logged([cycle(1)] * 4, [0.0, 1e4, 2e4, 3e4], masses=[30e3, np.nan, 40e3, np.nan])
    trips = dataclasses.replace(trips, payload_kg=np.array([np.nan, np.nan, np.nan, 5e3]))
    np.testing.assert_array_equal(candidate_masses(trips, veh, None), [30e3, 28e3, 40e3, 23e3])
    # the logged trucks weigh 16 t empty: the candidate carries their payloads on its 18 t
    np.testing.assert_array_equal(candidate_masses(trips, veh, 16e3), [32e3, 28e3, 42e3, 23e3])


# ------------------------------------------------------------- sizing at a confidence


def test_energy_at_confidence_adds_the_quantile_as_the_trips_draw():
    """Each duty's total moves to its one-sided quantile (the log-normal's of the total's
    mean and sd where that is positive, the Gaussian's where it is not:
    cevm.core.distribution), the addition shared over its trips in proportion to the
    energy each draws (a trip that gives energy back gets none); a duty whose trips draw
    nothing shares it equally."""
    from cevm.core.replay.spread import energy_at_confidence

    mean = np.array([10.0, 30.0, -5.0, 0.0, -2.0])
    sd = np.array([4.0, 1.0])
    bounds = np.array([0, 3, 5])
    z = 1.6448536269514722  # the standard normal's 0.95 quantile
    s2 = np.log(1.0 + (4.0 / 35.0) ** 2)  # duty 0: total 35, sd 4
    add0 = np.exp(np.log(35.0) - s2 / 2 + z * np.sqrt(s2)) - 35.0
    got = energy_at_confidence(mean, sd, bounds, 0.95)
    want = [10.0 + add0 * 0.25, 30.0 + add0 * 0.75, -5.0, 0.0 + z * 0.5, -2.0 + z * 0.5]
    np.testing.assert_allclose(got, want, rtol=1e-12)
    # at 0.5: the median, below a positive total's mean; the mean of the Gaussian one
    median0 = np.exp(np.log(35.0) - s2 / 2) - 35.0
    np.testing.assert_allclose(energy_at_confidence(mean, sd, bounds, 0.5),
                               [10.0 + median0 * 0.25, 30.0 + median0 * 0.75, -5.0, 0.0, -2.0], rtol=0, atol=1e-12)
    with pytest.raises(ValueError):
        energy_at_confidence(mean, sd, bounds, 1.0)


def test_the_battery_at_a_confidence_runs_the_duty_at_its_quantile(tmp_path):
    """One trip a duty, no charging, levels at the trips' ends: the battery that keeps the
    reserve when the duty takes its 0.95 quantile is E_c / (start - reserve) rounded up to
    1 kWh, E_c the 0.95 quantile of the log-normal of mean E and standard deviation sd (a
    hand computation); it is never below the mean's battery."""
    veh = ev(tmp_path)
    cycles = [cycle(40 + k) for k in range(3)]
    trips = logged(cycles, [0.0, 86400.0, 2 * 86400.0], masses=[30e3, 35e3, 25e3], temps=[-3.0, 5.0, 15.0])
    s = ReplaySettings(within_trips=False, size_confidence=0.95)
    plan = plan_vehicle(trips, veh, s, tables(cycles, trips))
    if plan.spread.source == "none":
        pytest.skip("the test vehicle has no predictive distribution")
    assert plan.duties.n == 3 and (plan.energy_sd > 0).all()
    z = 1.6448536269514722
    e, sd = plan.energies.energy, plan.energy_sd
    s2 = np.log(1.0 + (sd / e) ** 2)
    e_c = np.exp(np.log(e) - s2 / 2 + z * np.sqrt(s2))
    frac = (s.soc_start_pct - s.reserve_pct) / 100.0
    want = np.ceil(e_c / frac / KWH - 1e-9)
    np.testing.assert_array_equal(plan.battery_needed_conf / KWH, want)
    assert (plan.battery_needed_conf >= plan.battery_needed).all()
    np.testing.assert_array_equal(plan.battery_needed / KWH, np.ceil(plan.energies.energy / frac / KWH - 1e-9))
    none = plan_vehicle(trips, veh, dataclasses.replace(s, size_confidence=None), tables(cycles, trips))
    assert np.isnan(none.battery_needed_conf).all()


def test_a_trip_mostly_inside_an_earlier_one_is_the_same_driving_logged_twice():
    from cevm.core.replay.duties import logged_twice

    # [0,100] then: an exact copy; one overlapping by 10 s of 100 (a clock step: kept); one
    # 60 % inside [0, 100] after the copy; one inside a long trip; one after a gap
    start = np.array([0.0, 0.0, 90.0, 40.0, 300.0, 310.0, 1000.0])
    end = np.array([100.0, 100.0, 190.0, 140.0, 900.0, 320.0, 1100.0])
    order = np.argsort(start, kind="stable")
    got = logged_twice(start[order], end[order])
    # sorted: [0,100] [0,100] [40,140] [90,190] [300,900] [310,320] [1000,1100]
    # [40,140] is 60 s of 100 inside; [90,190] 50 of 100 (not more than half: kept)
    assert got.tolist() == [False, True, True, False, False, True, False]
    assert logged_twice([], []).tolist() == [] and logged_twice([5.0], [9.0]).tolist() == [False]
