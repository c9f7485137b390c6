"""Calibration as inference: on trips simulated with known coefficients and
scatter, posterior intervals hold the true coefficients and predictive intervals hold new
trips at their nominal rate; with no data the posterior is the prior, with much data the
prior stops mattering, and a term the trips cannot identify keeps its prior.

Truths are drawn from the priors the fit is given (a Bayesian interval holds the truth
at its nominal rate when the truth comes from its prior), trips are the CE model itself
plus Gaussian scatter of the form the model assumes, so every expected rate is known
exactly; binomial tolerances are 3 standard deviations.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.special import ndtri

from cevm.core.calibration import TripData, fit
from cevm.core.calibration import posterior as post
from cevm.core.calibration.data import select_trips
from cevm.core.calibration.terms import TermModel
from cevm.core.cycle import drive_cycle_vector
from cevm.core.predictive import Features, predictive, total
from cevm.core.uncertainty import Priors, ScatterPrior, TermPrior, coefficient_prior
from cevm.core.vehicle import Vehicle, predict
from cevm_samplegen.cycles import MicroTripSpec, micro_trip_cycle

BUS = Vehicle(name="bus", powertrain="ev", mass_kg=11000.0, cda_m2=4.0, cr=0.007, eta=0.8, kerb_mass_kg=9000.0,
              battery_j=120 * 3.6e6)
PRIORS = Priors("bus", "test", (TermPrior("eta", 0.72, 0.86), TermPrior("aux", 2000.0, 6000.0),
                                TermPrior("heat", 100.0, 700.0), TermPrior("cool", 100.0, 600.0)),
                ScatterPrior(800.0, 0.03))
NAMES = ("eta", "aux", "heat", "cool")
Z90 = float(ndtri(0.95))


@pytest.fixture(scope="module")
def vectors():
    specs = [MicroTripSpec(n_trips=10, cruise_kmh=(15.0, 40.0), cruise_s=(10.0, 60.0), dwell_s=(10.0, 60.0)),
             MicroTripSpec(n_trips=6, cruise_kmh=(35.0, 60.0), cruise_s=(40.0, 150.0), dwell_s=(5.0, 30.0))]
    out = []
    for i in range(16):
        c = micro_trip_cycle(specs[i % 2], 700 + i)
        out.append(drive_cycle_vector(c.time_s, c.speed_mps, c.elevation_m))
    return out


def _draw_truth(rng) -> Vehicle:
    """Coefficients drawn from PRIORS (truncated at the physical ranges)."""
    cp = coefficient_prior("ev", NAMES, PRIORS, BUS.eta)
    c = np.clip(cp.mean + cp.sd * rng.standard_normal(len(NAMES)), cp.lb, cp.ub)
    return dataclasses.replace(BUS, eta=1.0 / c[0], aux_power_w=c[1], aux_heating_w_per_k=c[2],
                               aux_cooling_w_per_k=c[3])


def _trips(truth, vectors, rng, n, temps, s_aux=500.0, s_share=0.02, u=0.005, prefix="t"):
    """n trips of ``truth`` with scatter (s_aux D, s_share mu) and a measurement of
    relative uncertainty u, each on its own day."""
    out = []
    for i in range(n):
        vec = vectors[int(rng.integers(len(vectors)))]
        m = float(rng.uniform(0.85, 1.15) * truth.mass_kg)
        t = float(temps[i])
        mu = float(predict(vec, truth, m, ambient_c=t).energy_j)
        y = mu + s_aux * vec.duration_s * rng.standard_normal() + s_share * mu * rng.standard_normal()
        y = y * (1.0 + u * rng.standard_normal())
        out.append(TripData(f"{prefix}{i}", vec, m, y, u * y, group=f"{prefix}day{i}", ambient_c=t))
    return out


@pytest.mark.slow
def test_posterior_intervals_hold_the_true_coefficients_at_their_nominal_rate(vectors):
    """80 truths drawn from the prior, 20 trips each: the 90 % intervals of eta, aux,
    heat, cool hold the truth 90 % of the time (320 trials)."""
    rng = np.random.default_rng(1)
    inside = []
    for _ in range(80):
        truth = _draw_truth(rng)
        trips = _trips(truth, vectors, rng, 20, rng.uniform(-5.0, 32.0, 20))
        r = fit(dataclasses.replace(BUS, priors=PRIORS), trips, NAMES, cv_folds=0, time_repeats=0)
        for field in ("eta", "aux_power_w", "aux_heating_w_per_k", "aux_cooling_w_per_k"):
            value, sd = r.fitted[field]
            inside.append(abs(value - getattr(truth, field)) <= Z90 * sd)
    rate = float(np.mean(inside))
    tol = 3 * math.sqrt(0.9 * 0.1 / len(inside))
    assert abs(rate - 0.9) <= tol, rate


@pytest.mark.slow
def test_predictive_intervals_hold_new_trips_at_their_nominal_rate(vectors):
    """40 truths, calibrated on 24 trips, each predicting 10 new trips through the public
    predictive API (the calibrated vehicle's posterior): 90 % of them inside their 90 %
    interval, 50 % inside their 50 % one."""
    rng = np.random.default_rng(2)
    z = []
    for k in range(40):
        truth = _draw_truth(rng)
        trips = _trips(truth, vectors, rng, 24, rng.uniform(-5.0, 32.0, 24))
        v = fit(dataclasses.replace(BUS, priors=PRIORS), trips, NAMES, time_repeats=0).vehicle
        for t in _trips(truth, vectors, rng, 10, rng.uniform(-5.0, 32.0, 10), prefix=f"n{k}"):
            p = predictive(v, Features.of(t.vector, v, [t.mass_kg], [t.ambient_c]), measurement_sd=t.uncertainty)
            z.append(float((t.measured - p.mean[0]) / p.sd[0]))
    z = np.abs(np.array(z))
    for level in (0.5, 0.9):
        rate = float(np.mean(z <= ndtri(0.5 + level / 2)))
        # the 10 trips of a truth share its parameter error: a wider tolerance than
        # independent trials' (the design effect of 10 correlated trials, at most 2)
        tol = 3 * math.sqrt(2 * level * (1 - level) / z.size)
        assert abs(rate - level) <= tol, (level, rate)


def test_with_no_trips_the_posterior_is_the_prior(vectors):
    """The posterior of no trips: the prior's mean and covariance."""
    rng = np.random.default_rng(3)
    trips = _trips(BUS, vectors, rng, 3, [10.0, 12.0, 30.0])
    data, _ = select_trips(BUS, trips, 0.1, 1000.0, 0.001)
    model = TermModel(BUS, data)
    cp = coefficient_prior("ev", NAMES, PRIORS, BUS.eta)
    f = post.solve(model, NAMES, np.arange(0), cp, post.Noise(500.0, 0.02), huber_c=None)
    assert f.theta == pytest.approx(cp.mean, rel=1e-12)
    assert f.cov == pytest.approx(np.diag(cp.sd ** 2), rel=1e-9)


@pytest.mark.slow
def test_with_much_data_the_prior_stops_mattering(vectors):
    """The posterior mode under a prior centred far from the truth and the fit without
    any prior draw together as the trips grow (their difference, in standard
    deviations, shrinks from 100 to 800 trips, below one at 800), and both hold the
    truth."""
    rng = np.random.default_rng(4)
    truth = dataclasses.replace(BUS, eta=0.76, aux_power_w=3500.0, aux_heating_w_per_k=350.0,
                                aux_cooling_w_per_k=250.0)
    trips = _trips(truth, vectors, rng, 800, rng.uniform(-5.0, 32.0, 800))
    off = Priors("bus", "test", (TermPrior("eta", 0.80, 0.88), TermPrior("aux", 4000.0, 8000.0),
                                 TermPrior("heat", 400.0, 1000.0), TermPrior("cool", 400.0, 900.0)),
                 ScatterPrior(800.0, 0.03))
    gap = {}
    for n in (100, 800):
        with_prior = fit(dataclasses.replace(BUS, priors=off), trips[:n], NAMES, cv_folds=0, time_repeats=0)
        flat = fit(BUS, trips[:n], NAMES, cv_folds=0, time_repeats=0)
        gap[n] = max(abs(with_prior.fitted[f][0] - flat.fitted[f][0]) / flat.fitted[f][1]
                     for f in ("eta", "aux_power_w", "aux_heating_w_per_k", "aux_cooling_w_per_k"))
        for f in ("eta", "aux_power_w", "aux_heating_w_per_k", "aux_cooling_w_per_k"):
            assert abs(with_prior.fitted[f][0] - getattr(truth, f)) < 4 * with_prior.fitted[f][1], (n, f)
    assert gap[800] < gap[100] and gap[800] < 1.0, gap


def test_a_term_the_trips_cannot_identify_keeps_its_prior_and_widens_the_interval(vectors):
    """A summer-only calibration (every trip above the heating balance temperature)
    keeps the heating term at its prior; a winter prediction carries it, with an
    interval as wide as the prior's heating says, and holds the truth."""
    rng = np.random.default_rng(5)
    truth = dataclasses.replace(BUS, eta=0.78, aux_power_w=3000.0, aux_heating_w_per_k=400.0,
                                aux_cooling_w_per_k=300.0)
    summer = _trips(truth, vectors, rng, 30, rng.uniform(18.0, 32.0, 30))
    r = fit(dataclasses.replace(BUS, priors=PRIORS), summer, NAMES, time_repeats=0)
    cp = coefficient_prior("ev", NAMES, PRIORS, BUS.eta)
    value, sd = r.fitted["aux_heating_w_per_k"]
    assert value == pytest.approx(cp.mean[2], rel=1e-6) and sd == pytest.approx(cp.sd[2], rel=1e-6)
    assert "aux_heating_w_per_k" in r.prior_kept and "colder than" in r.prior_kept["aux_heating_w_per_k"]
    v = r.vehicle
    vec = vectors[0]
    mild, cold = (predictive(v, Features.of(vec, v, None, [t])) for t in (20.0, -5.0))
    # at -5 degC: 21 K of heating demand for the whole trip, whose prior sd is cp.sd[2] W/K
    assert cold.sd[0] > mild.sd[0]
    assert cold.sd[0] >= 0.9 * cp.sd[2] * 21.0 * vec.duration_s
    lo, hi = cold.interval(0.9)
    true = float(predict(vec, truth, ambient_c=-5.0).energy_j)
    assert lo[0] < true < hi[0]


def test_the_predictive_mean_is_predicts_to_the_bit(vectors):
    """:func:`cevm.core.predictive.mean` is :func:`cevm.core.vehicle.predict`, for an EV
    with every term and a no-credit ICE with a kinetic efficiency."""
    ev = dataclasses.replace(BUS, aux_power_w=3000.0, aux_heating_w_per_k=300.0, aux_cooling_w_per_k=200.0,
                             warmup_j_per_k=1e5, regen_eta=0.6)
    ice = Vehicle(name="truck", powertrain="ice", mass_kg=30000.0, cda_m2=6.0, cr=0.006, eta=0.4,
                  fuel_lhv_j_per_l=35.8e6, ice_braking="no-credit", idle_fuel_lps=2 / 3600,
                  running_fuel_lps=3 / 3600, kinetic_eta=0.3, cooling_fuel_lps_per_k=0.05 / 3600)
    m = np.array([9000.0, 12000.0, 25000.0])
    t = np.array([-3.0, 15.0, 30.0])
    for v in (ev, ice):
        for vec in vectors[:4]:
            want = predict(vec, v, m, ambient_c=t)
            got = predictive(v, Features.of(vec, v, m, t)).mean
            assert np.array_equal(got, want.energy_j if v.is_ev else want.fuel_l)


def test_a_days_total_has_the_variance_of_a_sum_of_correlated_trips(vectors):
    """total(): the day's sum of trips whose scatter shares a day effect rho, against the
    empirical variance of simulated sums (the parameters held exactly)."""
    from cevm.core.uncertainty import Posterior, Scatter

    rho, s_aux, s_share = 0.6, 700.0, 0.03
    post_ = Posterior(("eta",), np.zeros((1, 1)), Scatter(s_aux, s_share, rho), "test", n_trips=10)
    v = dataclasses.replace(BUS, aux_power_w=3000.0, posterior=post_)
    vecs = vectors[:5]
    f = [Features.of(vec, v) for vec in vecs]
    feats = Features(*(np.concatenate([np.atleast_1d(getattr(x, name)) for x in f]) for name in
                       ("positive_j", "negative_j", "duration_s", "idle_s", "traction_s", "kinetic_j", "ambient_c")))
    day = total(v, feats)
    mu = predictive(v, feats).mean
    d = feats.duration_s
    rng = np.random.default_rng(6)
    n = 40000
    b = rng.normal(0, math.sqrt(rho) * s_aux, n)[:, None]
    a = rng.normal(0, math.sqrt(rho) * s_share, n)[:, None]
    e = (d * (b + rng.normal(0, math.sqrt(1 - rho) * s_aux, (n, d.size)))
         + mu * (a + rng.normal(0, math.sqrt(1 - rho) * s_share, (n, d.size))))
    sums = mu.sum() + e.sum(axis=1)
    assert day.mean[0] == pytest.approx(mu.sum(), rel=1e-12)
    assert day.sd[0] == pytest.approx(sums.std(), rel=0.02)
    # independent days: the sum of per-day variances
    two = total(v, feats, groups=["a", "a", "b", "b", "b"])
    assert two.mean.sum() == pytest.approx(mu.sum(), rel=1e-12)
    assert two.sd.size == 2


def test_p_within_budget_is_the_frequency_in_simulation(vectors):
    """prob_at_most(budget) against the share of simulated trips within it: trips drawn
    from the log-normal of the prediction's mean and sd (a consumption is never
    negative; cevm.core.distribution), its parameters from the moments by hand."""
    v = dataclasses.replace(BUS, aux_power_w=3000.0, priors=PRIORS)
    p = predictive(v, Features.of(vectors[2], v))
    rng = np.random.default_rng(7)
    mean, sd = float(p.mean), float(p.sd)
    sigma2 = np.log(1.0 + (sd / mean) ** 2)
    draws = rng.lognormal(np.log(mean) - sigma2 / 2, np.sqrt(sigma2), 100000)
    assert draws.mean() == pytest.approx(mean, rel=0.01) and draws.std() == pytest.approx(sd, rel=0.03)
    for budget in (mean - sd, mean + 0.3 * sd, mean + 2 * sd):
        assert float(p.prob_at_most(budget)) == pytest.approx(float(np.mean(draws <= budget)), abs=0.005)
    assert p.source == "prior"
