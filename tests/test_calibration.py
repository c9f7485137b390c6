"""Calibration: recovery of known parameters from synthetic trips, honest standard
errors, exclusions, refusals of unidentifiable parameters, and leak-free validation.

Expected values come from the truth the trips were synthesised with, from the plain
per-step reference (tests/reference.py) and from a closed-form weighted least squares
written out here.
"""

from dataclasses import replace

import numpy as np
import pytest

from cevm.core.calibration import CalibrationError, TripData, fit, predict_trips
from cevm.core.cycle import cycle_vector, drive_cycle_vector
from cevm.core.trip import Measurement
from cevm.core.vehicle import Vehicle
from cevm_samplegen.cycles import MicroTripSpec, micro_trip_cycle
from reference import reference_wheel_energy_j

URBAN = MicroTripSpec(n_trips=8)
FAST = MicroTripSpec(n_trips=3, cruise_kmh=(50.0, 85.0), cruise_s=(60.0, 200.0), dwell_s=(5.0, 20.0),
                     accel_mps2=(0.3, 0.6), decel_mps2=(0.5, 0.9), hill_amplitude_m=20.0)

BUS = Vehicle(name="bus", powertrain="ev", mass_kg=9825.0, cda_m2=3.99, cr=0.0066, eta=0.78,
              battery_j=124 * 3.6e6)
TRUCK = Vehicle(name="truck", powertrain="ice", mass_kg=30000.0, cda_m2=6.62, cr=0.0066, eta=0.45,
                fuel_lhv_j_per_l=35.8e6, ice_braking="paper")  # the paper's eq. (24), stated


@pytest.fixture(scope="module")
def pool():
    """24 cycles: urban stop-and-go and faster regional ones, with their vectors."""
    cycles = [micro_trip_cycle(URBAN if i % 2 else FAST, 100 + i) for i in range(24)]
    return cycles, [cycle_vector(c) for c in cycles]


def synth_trips(vectors, truth, masses, rng, rel_noise, ids=None, groups=None, reported=None):
    """Trips measured with Gaussian relative noise of std rel_noise, reported as a
    relative uncertainty ``reported`` (default: rel_noise, at least 1 %)."""
    ids = ids or [f"t{i}" for i in range(len(vectors))]
    clean = [TripData(i, v, m, None, None) for i, v, m in zip(ids, vectors, masses, strict=True)]
    y = predict_trips(truth, clean)
    meas = y * (1.0 + rel_noise * rng.normal(size=y.size)) if rel_noise > 0 else y
    groups = groups or [None] * len(vectors)
    rep = max(rel_noise, 0.01) if reported is None else reported
    return [replace(t, measured=float(mv), uncertainty=float(rep * yv), group=g)
            for t, mv, yv, g in zip(clean, meas, y, groups, strict=True)]


# --- recovery without noise -------------------------------------------------------------

def test_noise_free_ev_recovers_eta_aux_cda(pool):
    _, vecs = pool
    rng = np.random.default_rng(1)
    truth = replace(BUS, eta=0.71, aux_power_w=7000.0, cda_m2=4.6)
    trips = synth_trips(vecs[:16], truth, rng.uniform(9000, 14000, 16), rng, 0.0)
    r = fit(BUS, trips, ("eta", "aux_power_w", "cda_m2"), cv_folds=0, time_repeats=0)
    assert not r.refused and not r.excluded
    assert r.fitted["eta"][0] == pytest.approx(0.71, rel=1e-6)
    assert r.fitted["aux_power_w"][0] == pytest.approx(7000.0, rel=1e-6)
    assert r.fitted["cda_m2"][0] == pytest.approx(4.6, rel=1e-6)
    assert r.vehicle.eta == r.fitted["eta"][0] and r.vehicle.cr == BUS.cr
    assert r.in_sample.rms_pct < 1e-6


@pytest.mark.parametrize("braking", ["paper", "no-credit"])
def test_noise_free_ice_recovers_eta_idle(pool, braking):
    _, vecs = pool
    rng = np.random.default_rng(2)
    prior = replace(TRUCK, ice_braking=braking)
    truth = replace(prior, eta=0.41, idle_fuel_lps=2.5 / 3600)
    trips = synth_trips(vecs[:14], truth, rng.uniform(18000, 44000, 14), rng, 0.0)
    r = fit(prior, trips, ("eta", "idle_fuel"), cv_folds=0, time_repeats=0)
    assert r.fitted["eta"][0] == pytest.approx(0.41, rel=1e-6)
    assert r.fitted["idle_fuel_lps"][0] == pytest.approx(2.5 / 3600, rel=1e-6)
    assert r.unit == "l" and r.vehicle.ice_braking == braking


# --- against independent computations -------------------------------------------------

def test_ice_eta_equals_closed_form_weighted_least_squares(pool):
    """Paper-mode ICE, eta alone, the scatter held at 0 (the measurement uncertainties
    alone weigh the trips): fuel = c_i x + d_i with x = 1/eta, so the posterior mode
    without a prior is the weighted least-squares estimate, sum (p_i - y_i)^2 /
    (u_i y_i)^2 minimised, and its standard deviation that of known weights (the
    least-squares estimator: robust=False; the default Huber estimate differs where
    trips lie beyond 2.5 sigma)."""
    cycles, vecs = pool
    rng = np.random.default_rng(3)
    prior = replace(TRUCK, idle_fuel_lps=1.8 / 3600)
    masses = rng.uniform(18000, 44000, 8)
    y = rng.uniform(0.9, 1.1, 8) * predict_trips(replace(prior, eta=0.43),
                                                 [TripData(str(i), v, m, None, None)
                                                  for i, (v, m) in enumerate(zip(vecs[:8], masses, strict=True))])
    u = rng.uniform(0.01, 0.05, 8)
    trips = [TripData(str(i), v, m, float(yy), float(uu * yy)) for i, (v, m, yy, uu)
             in enumerate(zip(vecs[:8], masses, y, u, strict=True))]
    r = fit(prior, trips, cv_folds=0, scatter=(0.0, 0.0), time_repeats=0, robust=False)  # least squares
    c = np.empty(8)
    d = np.empty(8)
    for i, (cyc, m) in enumerate(zip(cycles[:8], masses, strict=True)):
        t, v, h = cyc.time_s, cyc.speed_mps, cyc.elevation_m
        c[i] = reference_wheel_energy_j(t, v, h, m, prior.cda_m2, prior.cr, "paper") / prior.fuel_lhv_j_per_l
        stand = sum(t[j + 1] - t[j] for j in range(len(t) - 1) if v[j] == 0 and v[j + 1] == 0)
        d[i] = prior.idle_fuel_lps * stand
    W = 1.0 / (u * y) ** 2
    x = np.sum(W * c * (y - d)) / np.sum(W * c * c)
    res = (c * x + d - y) / y
    sd_x = np.sqrt(1.0 / np.sum(W * c * c))
    assert r.fitted["eta"][0] == pytest.approx(1 / x, rel=1e-9)
    assert r.fitted["eta"][1] == pytest.approx(sd_x / x**2, rel=1e-6)
    assert [row.error_pct_in_sample for row in r.rows] == pytest.approx(list(100 * res), abs=1e-7)


def test_reported_predictions_match_plain_reference(pool):
    cycles, vecs = pool
    rng = np.random.default_rng(4)
    masses = rng.uniform(9000, 14000, 6)
    trips = synth_trips(vecs[:6], replace(BUS, eta=0.74, aux_power_w=3000.0), masses, rng, 0.02)
    r = fit(BUS, trips, ("eta", "aux_power_w"), cv_folds=0, time_repeats=0)
    eta, aux = r.vehicle.eta, r.vehicle.aux_power_w
    for row, cyc, m in zip(r.rows, cycles[:6], masses, strict=True):
        e = reference_wheel_energy_j(cyc.time_s, cyc.speed_mps, cyc.elevation_m, m, BUS.cda_m2, BUS.cr, "ev", eta)
        assert row.predicted_in_sample == pytest.approx(e / eta + aux * cyc.duration_s, rel=1e-9)


# --- honest standard errors ------------------------------------------------------------

@pytest.mark.parametrize("noise, reported", [
    (0.02, 0.02),  # honest measurement uncertainty
    (0.03, 0.01),  # understated: the fitted scatter takes the rest
])
def test_standard_errors_are_honest_over_repetitions(pool, noise, reported):
    """30 noisy data sets: z = (estimate - truth) / reported std has about unit spread,
    and the fitted scatter is what the measurement uncertainty leaves unexplained."""
    _, vecs = pool
    rng = np.random.default_rng(5)
    truth = replace(BUS, eta=0.76, aux_power_w=5000.0)
    z, extra = [], []
    for _ in range(30):
        pick = rng.choice(len(vecs), 16, replace=False)
        trips = synth_trips([vecs[i] for i in pick], truth, rng.uniform(9000, 14000, 16), rng, noise,
                            reported=reported)
        r = fit(BUS, trips, ("eta", "aux_power_w"), cv_folds=0, time_repeats=0)
        assert not r.refused
        z.append([(r.fitted[n][0] - getattr(truth, n)) / r.fitted[n][1] for n in ("eta", "aux_power_w")])
        # the fitted scatter at the trips: relative to their predictions
        sc = r.scatter
        rel = [np.hypot(sc.aux * v.duration_s / row.predicted_in_sample, sc.share)
               for row, v in zip(r.rows, [vecs[i] for i in pick], strict=True)]
        extra.append(float(np.mean(rel)))
    z = np.array(z)
    expected = np.sqrt(noise**2 - reported**2)
    assert np.sqrt(np.mean(np.square(extra))) == pytest.approx(expected, abs=0.01)
    assert np.all(np.abs(z) < 4.0)
    assert np.all(np.abs(z.mean(axis=0)) < 0.6)
    assert np.all((z.std(axis=0, ddof=1) > 0.6) & (z.std(axis=0, ddof=1) < 1.5))


# --- weights and exclusions -------------------------------------------------------------

def test_quantised_counter_weighs_less_and_coarse_trips_are_excluded(pool):
    _, vecs = pool
    rng = np.random.default_rng(6)
    truth = replace(TRUCK, eta=0.44)
    trips = synth_trips(vecs[:12], truth, rng.uniform(18000, 44000, 12), rng, 0.01)
    step = 0.5  # FMS fuel counter resolution [l]: reading at both ends -> std step/sqrt(6)
    sigma_q = step / np.sqrt(6)
    counter = {}
    for i in range(0, 12, 2):  # every other trip measured by the counter instead of a flow meter
        yq = round(trips[i].measured / step) * step
        counter[trips[i].trip_id] = sigma_q / yq
        trips[i] = TripData.from_measurement(
            trips[i].trip_id, trips[i].vector, Measurement("fuel_l", yq, "fms", step, sigma_q),
            mass_kg=trips[i].mass_kg)
    r = fit(TRUCK, trips, cv_folds=0, time_repeats=0)
    coarse = {k for k, u in counter.items() if u > 0.10}
    assert coarse and coarse != set(counter)  # the data exercise both cases
    assert set(r.excluded) == coarse
    assert all("relative uncertainty" in r.excluded[k] and "> 10.0 %" in r.excluded[k] for k in coarse)
    rows = {row.trip_id: row for row in r.rows}
    assert sum(row.weight for row in r.rows) == pytest.approx(1.0)
    # each trip weighs 1 / (its measurement's variance + the fitted scatter's there,
    # with its part that does not grow with a trip: Scatter.trip)
    sc = r.scatter
    dur = {t.trip_id: t.vector.duration_s for t in trips}

    def variance(row):
        return (row.rel_uncertainty * row.measured) ** 2 + (sc.aux * dur[row.trip_id]) ** 2 + (
            sc.share * row.predicted_in_sample) ** 2 + sc.trip ** 2

    flow = [row for row in r.rows if row.trip_id not in counter]
    for k in set(counter) - coarse:
        assert rows[k].weight < min(f.weight for f in flow)
        f = flow[0]
        assert rows[k].weight / f.weight == pytest.approx(variance(f) / variance(rows[k]), rel=1e-6)


def test_exclusions_name_their_reason(pool):
    _, vecs = pool
    rng = np.random.default_rng(7)
    trips = synth_trips(vecs[:5], BUS, rng.uniform(9000, 14000, 5), rng, 0.01)
    t = np.arange(0.0, 201.0)
    downhill = drive_cycle_vector(t, np.full(t.size, 10.0), 200.0 - 0.5 * t)  # 2 km at -5 %
    short = drive_cycle_vector(t[:60], np.full(60, 10.0))  # 590 m
    bad = [
        TripData("none", vecs[5], None, None, None),
        TripData("neg", vecs[6], None, -3.0e6, 1e4),
        TripData("nan-unc", vecs[7], None, 3.0e7, float("nan")),
        TripData("kind", vecs[8], None, 3.0, 0.01, kind="fuel_l"),
        TripData("q0", vecs[9], None, 3.0e7, 1e5, quality=0.0),
        TripData("short", short, None, 1e6, 1e3),
        TripData("descent", downhill, None, 1e6, 1e3),
    ]
    r = fit(BUS, trips + bad, cv_folds=0, time_repeats=0)
    assert set(r.excluded) == {b.trip_id for b in bad}
    assert "no measured" in r.excluded["none"]
    assert "<= 0" in r.excluded["neg"]
    assert "uncertainty" in r.excluded["nan-unc"]
    assert "'fuel_l'" in r.excluded["kind"]
    assert "quality" in r.excluded["q0"]
    assert "590 m < 1000 m" in r.excluded["short"]
    assert "wheel energy" in r.excluded["descent"]
    assert len(r.rows) == 5


def test_too_few_trips():
    t = np.arange(0.0, 301.0)
    vecs = [drive_cycle_vector(t, np.full(t.size, v)) for v in (8.0, 12.0, 16.0, 20.0)]
    rng = np.random.default_rng(8)
    trips = synth_trips(vecs, BUS, [BUS.mass_kg] * 4, rng, 0.01)
    with pytest.raises(CalibrationError, match="at least 3 usable trips, 2 of 3"):
        fit(BUS, trips[:2] + [TripData("x", vecs[2], None, None, None)], time_repeats=0)
    r = fit(BUS, trips, ("eta", "aux_power_w", "cda_m2"), cv_folds=0, time_repeats=0)
    assert "at least 5 usable trips" in r.refused["cda_m2"]
    assert set(r.fitted) == {"eta", "aux_power_w"}


def test_bad_requests():
    with pytest.raises(CalibrationError, match="idle_fuel_lps"):
        fit(BUS, [], ("eta", "idle_fuel_lps"))
    with pytest.raises(CalibrationError, match="'eta' must"):
        fit(BUS, [], ("aux_power_w",))
    t = np.arange(0.0, 301.0)
    v = drive_cycle_vector(t, np.full(t.size, 10.0))
    with pytest.raises(CalibrationError, match="twice"):
        fit(BUS, [TripData("a", v, None, 1e7, 1e4)] * 3)


# --- identifiability ------------------------------------------------------------------

def test_aux_power_refused_when_all_trips_share_one_speed_profile(pool):
    _, vecs = pool
    base = vecs[1]
    scaled = [base]
    for _ in range(7):
        scaled.append(scaled[-1] + base)  # the same profile driven 1..8 times
    rng = np.random.default_rng(9)
    trips = synth_trips(scaled, replace(BUS, eta=0.72, aux_power_w=6000.0), [None] * 8, rng, 0.01)
    r = fit(BUS, trips, ("eta", "aux_power_w"), cv_folds=0, time_repeats=0)
    assert set(r.fitted) == {"eta"}
    assert "confounded with eta" in r.refused["aux_power_w"]
    assert r.vehicle.aux_power_w == BUS.aux_power_w


def test_cda_and_cr_refused_with_a_single_cycle_shape(pool):
    _, vecs = pool
    base = vecs[0]
    trips_v = [base]
    for _ in range(6):
        trips_v.append(trips_v[-1] + base)
    rng = np.random.default_rng(10)
    trips = synth_trips(trips_v, replace(TRUCK, eta=0.4), [None] * 7, rng, 0.01)
    r = fit(TRUCK, trips, ("eta", "cda_m2", "cr"), cv_folds=0, time_repeats=0)
    assert set(r.fitted) == {"eta"}
    assert set(r.refused) == {"cda_m2", "cr"}
    assert all("not identifiable" in why for why in r.refused.values())


def test_idle_fuel_refused_when_no_trip_stands_still():
    t = np.arange(0.0, 601.0)
    vecs = [drive_cycle_vector(t, v0 + 3.0 * np.sin(t / p) ** 2) for v0, p in
            [(8, 20), (12, 30), (16, 15), (20, 40), (25, 25), (10, 60)]]
    assert all(v.idle_s == 0 for v in vecs)
    rng = np.random.default_rng(11)
    trips = synth_trips(vecs, TRUCK, rng.uniform(18000, 44000, 6), rng, 0.01)
    r = fit(TRUCK, trips, ("eta", "idle_fuel_lps"), cv_folds=0, time_repeats=0)
    assert "no effect" in r.refused["idle_fuel_lps"]


# --- validation ---------------------------------------------------------------------------

def test_cv_prediction_never_sees_its_own_measurement(pool):
    _, vecs = pool
    rng = np.random.default_rng(12)
    trips = synth_trips(vecs[:12], replace(BUS, aux_power_w=4000.0), rng.uniform(9000, 14000, 12), rng, 0.03)
    r1 = fit(BUS, trips, ("eta", "aux_power_w"), time_repeats=0)
    assert r1.cv_scheme == "5-fold"
    j = 4
    trips2 = list(trips)
    trips2[j] = replace(trips[j], measured=trips[j].measured * 1.08)
    r2 = fit(BUS, trips2, ("eta", "aux_power_w"), time_repeats=0)
    assert r2.rows[j].predicted_cv == pytest.approx(r1.rows[j].predicted_cv, rel=1e-9)
    assert r2.rows[j].predicted_in_sample != pytest.approx(r1.rows[j].predicted_in_sample, rel=1e-6)
    # trips in another fold did see it
    other = next(i for i, row in enumerate(r1.rows) if row.fold != r1.rows[j].fold)
    assert r2.rows[other].predicted_cv != pytest.approx(r1.rows[other].predicted_cv, rel=1e-9)


@pytest.mark.slow
def test_cv_error_exceeds_in_sample_error_on_average(pool):
    _, vecs = pool
    rng = np.random.default_rng(13)
    truth = replace(BUS, eta=0.75, aux_power_w=5000.0)
    ratios = []
    for _ in range(8):
        pick = rng.choice(len(vecs), 8, replace=False)
        trips = synth_trips([vecs[i] for i in pick], truth, rng.uniform(9000, 14000, 8), rng, 0.03)
        r = fit(BUS, trips, ("eta", "aux_power_w"), time_repeats=0)
        assert r.cv_scheme == "leave-one-out"
        ratios.append(r.cv.rms_pct / r.in_sample.rms_pct)
    # with k = 2 parameters fitted to n = 8 trips, in-sample residuals shrink by about
    # sqrt((n - k) / n) = 0.87, while held-out errors grow
    assert np.mean(ratios) > 1.1
    assert min(ratios) > 1.0


def test_grouped_cv_keeps_each_group_on_one_side(pool):
    _, vecs = pool
    rng = np.random.default_rng(14)
    sizes = [1, 2, 3, 4, 2, 3, 5]
    groups = [f"day{g}" for g, s in enumerate(sizes) for _ in range(s)]
    n = len(groups)
    trips = synth_trips(vecs[:n], BUS, rng.uniform(9000, 14000, n), rng, 0.02, groups=groups)
    r = fit(BUS, trips, cv_folds=3, loo_below=5, time_repeats=0)
    assert r.cv_scheme == "grouped 3-fold (7 groups)"
    fold_of = {}
    for row in r.rows:
        assert fold_of.setdefault(row.group, row.fold) == row.fold
    assert sorted(set(fold_of.values())) == [0, 1, 2]
    # changing a trip's measurement moves no CV prediction of its own group
    j = groups.index("day3")
    trips2 = list(trips)
    trips2[j] = replace(trips[j], measured=trips[j].measured * 1.1)
    r2 = fit(BUS, trips2, cv_folds=3, loo_below=5, time_repeats=0)
    for a, b in zip(r.rows, r2.rows, strict=True):
        if a.group == "day3":
            assert a.predicted_cv == pytest.approx(b.predicted_cv, rel=1e-12)
    # leave-one-group-out when there are few groups
    r3 = fit(BUS, trips, time_repeats=0)
    assert r3.cv_scheme == "leave-one-group-out (7 groups)"


def test_summary_statistics_and_timing(pool):
    _, vecs = pool
    rng = np.random.default_rng(15)
    trips = synth_trips(vecs[:10], BUS, rng.uniform(9000, 14000, 10), rng, 0.03)
    r = fit(BUS, trips, time_repeats=5)
    e = np.array([row.error_pct_in_sample for row in r.rows])
    ecv = np.array([row.error_pct_cv for row in r.rows])
    assert r.in_sample.mean_pct == pytest.approx(e.mean())
    assert r.in_sample.std_pct == pytest.approx(e.std(ddof=1))
    assert r.cv.std_pct == pytest.approx(ecv.std(ddof=1))
    meas = np.array([row.measured for row in r.rows])
    pred = np.array([row.predicted_in_sample for row in r.rows])
    assert e == pytest.approx(100 * (pred - meas) / meas)
    mean_s, std_s = r.time_per_prediction_s
    assert 0 < mean_s < 0.01 and std_s >= 0
    assert fit(BUS, trips, cv_folds=0, time_repeats=0).time_per_prediction_s is None


def test_imprecise_extra_parameter_is_refused_by_its_standard_error(pool):
    """A zero aux power is judged against 10 % of the median consumption rate y/D: a
    precise zero is kept, an imprecise one refused."""
    _, vecs = pool
    truth = replace(BUS, eta=0.74, aux_power_w=0.0)
    masses = np.random.default_rng(16).uniform(9000, 14000, 6)
    trips = synth_trips(vecs[:6], truth, masses, np.random.default_rng(17), 0.06, reported=0.08)
    kept = fit(BUS, trips, ("eta", "aux_power_w"), cv_folds=0, time_repeats=0)
    value, sd = kept.fitted["aux_power_w"]
    assert abs(value) < 1.0 and sd > 100.0  # at its bound 0, with a large error
    assert any("aux_power_w" in w and "bound" in w for w in kept.warnings)
    assert not kept.excluded
    ref = 0.1 * np.median([t.measured / t.vector.duration_s for t in trips])
    ratio = sd / ref
    assert ratio < 0.5  # 0 +- sd says aux is small compared with the bus's power draw
    refused = fit(BUS, trips, ("eta", "aux_power_w"), cv_folds=0, time_repeats=0, max_rel_se=0.95 * ratio)
    assert set(refused.fitted) == {"eta"}
    assert "standard error" in refused.refused["aux_power_w"] and "reference" in refused.refused["aux_power_w"]
    again = fit(BUS, trips, ("eta", "aux_power_w"), cv_folds=0, time_repeats=0, max_rel_se=1.05 * ratio)
    assert set(again.fitted) == {"eta", "aux_power_w"}
