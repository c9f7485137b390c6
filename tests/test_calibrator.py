"""cevm.Calibrator, the calibration in scikit-learn's shape: explicit parameters, fit
returning the estimator, results in attributes ending in ``_``, predictions with
intervals. Expected values come from the truth the synthetic trips were made with and
from the functions the estimator wraps (fit, select, predict, the predictive
distribution), which have their own tests against hand computations."""

from __future__ import annotations

import inspect
from dataclasses import replace

import numpy as np
import pytest

import cevm
from cevm.core.calibration import CalibrationError, Calibrator, Options, fit, select
from cevm.core.predictive import Features, predictive
from cevm.core.vehicle import predict
from test_calibration import BUS, pool, synth_trips  # noqa: F401 (pool: the fixture)


@pytest.fixture(scope="module")
def trips(pool):
    _, vecs = pool
    rng = np.random.default_rng(5)
    truth = replace(BUS, eta=0.74, aux_power_w=5000.0)
    groups = [f"day{i // 3}" for i in range(18)]
    return synth_trips(vecs[:18], truth, rng.uniform(9000, 14000, 18), rng, 0.01, groups=groups)


def test_parameters_are_explicit_in_init_and_kept_as_given():
    """scikit-learn's rule: every parameter is a named argument of __init__ with its
    default, stored under its own name; only the vehicle is positional."""
    sig = inspect.signature(Calibrator)
    params = list(sig.parameters.values())
    assert params[0].name == "vehicle" and params[0].kind is inspect.Parameter.POSITIONAL_OR_KEYWORD
    assert all(p.kind is inspect.Parameter.KEYWORD_ONLY for p in params[1:])
    names = {p.name for p in params}
    assert {"terms", "fit_terms", "nested", "cv_folds", "max_rel_uncertainty", "interval", "priors", "seed"} <= names
    cal = Calibrator(BUS, cv_folds=3, interval=0.8)
    assert (cal.vehicle, cal.cv_folds, cal.interval, cal.terms) == (BUS, 3, 0.8, None)
    assert cevm.Calibrator is Calibrator
    with pytest.raises(TypeError):
        Calibrator(BUS, 3)  # the options are keywords only
    with pytest.raises(AttributeError, match="not fitted"):
        Calibrator(BUS).terms_  # noqa: B018


def test_options_refuse_unknown_names():
    with pytest.raises(TypeError, match="cv_fold"):
        Options.of(cv_fold=3)
    with pytest.raises(TypeError, match="cv_fold"):
        fit(BUS, [], ("eta",), cv_fold=3)


def test_forced_terms_fit_is_fit(trips):
    cal = Calibrator(BUS, fit_terms=("eta", "aux"), cv_folds=3, time_repeats=0)
    assert cal.fit(trips) is cal
    ref = fit(BUS, trips, ("eta", "aux"), cv_folds=3, time_repeats=0)
    assert cal.terms_ == ("eta", "aux") and cal.selection_ is None and cal.nested_cv_ is None
    assert cal.fitted_ == ref.fitted
    assert cal.fitted_["eta"][0] == pytest.approx(0.74, rel=0.02)  # the truth, within the 1 % noise
    assert cal.fitted_["aux_power_w"][0] == pytest.approx(5000.0, rel=0.1)
    assert cal.vehicle_.eta == ref.vehicle.eta and cal.vehicle_.posterior is not None
    cv = cal.cv_results_
    assert cv["terms"] == ["eta+aux"] and cv["status"] == ["forced"] and cv["rank"] == [1]
    assert cv["std_cv_error_pct"] == [ref.cv.std_pct]


@pytest.mark.slow
def test_selection_and_cv_results(trips):
    cal = Calibrator(BUS, terms=("aux", "regen"), nested=False, time_repeats=0).fit(trips)
    ref = select(BUS, trips, terms=("aux", "regen"), nested=False, time_repeats=0)
    assert cal.terms_ == ref.chosen == ref.result.terms
    cv = cal.cv_results_
    assert len({len(v) for v in cv.values()}) == 1 and len(cv["terms"]) == len(ref.candidates)
    chosen = cv["status"].index("chosen")
    assert cv["terms"][chosen] == "+".join(cal.terms_)
    assert cv["loss"] == [c.mse for c in ref.candidates]
    ok = [i for i, s in enumerate(cv["status"]) if not s.startswith("refused")]
    best = min(ok, key=lambda i: cv["loss"][i])
    assert cv["rank"][best] == 1 and sorted(cv["rank"]) == list(range(1, len(cv["rank"]) + 1))


def test_predict_is_the_calibrated_vehicles_predictive_distribution(trips, pool):
    cycles, vecs = pool
    cal = Calibrator(BUS, fit_terms=("eta", "aux"), time_repeats=0).fit(trips)
    masses = np.array([9000.0, 12000.0])
    p = cal.predict(vecs[20], mass_kg=masses, ambient_c=5.0)
    ref = predictive(cal.vehicle_, Features.of(vecs[20], cal.vehicle_, masses, 5.0))
    np.testing.assert_array_equal(p.mean, ref.mean)
    np.testing.assert_array_equal(p.sd, ref.sd)
    # the mean is predict()'s, to the last bit; the interval is around it and not empty
    np.testing.assert_array_equal(p.mean, predict(vecs[20], cal.vehicle_, masses, ambient_c=5.0).energy_j)
    low, high = p.interval(0.9)
    assert np.all(low < p.mean) and np.all(p.mean < high)
    # a cycle is reduced to its vector; a list stacks the cycles on a leading axis
    np.testing.assert_array_equal(cal.predict(cycles[20], mass_kg=masses, ambient_c=5.0).mean, p.mean)
    both = cal.predict([vecs[20], cycles[21]], mass_kg=masses, ambient_c=5.0)
    assert both.mean.shape == (2, 2)
    np.testing.assert_array_equal(both.mean[0], p.mean)


def test_fit_refuses_too_few_trips(trips):
    with pytest.raises(CalibrationError, match="at least 3 usable trips"):
        Calibrator(BUS, fit_terms=("eta",)).fit(trips[:2])
