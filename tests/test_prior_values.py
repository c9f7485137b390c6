"""What a vehicle file does not state is its class's prior, not zero; and no interval of a
consumption goes below zero. Expected numbers are computed here by hand from the
shipped class priors (configs/priors/classes.toml, read with tomllib) and the
physics of a constant-speed cycle on a flat road, not by the code under test."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import norm

from cevm.core import distribution
from cevm.core.cycle import drive_cycle_vector
from cevm.core.predictive import Features, predictive
from cevm.io import load_vehicle
from cevm.io.vehicles import vehicle_from_mapping

CLASSES = tomllib.loads((Path(__file__).resolve().parents[1] / "configs" / "priors" / "classes.toml").read_text())
Z95 = norm.ppf(0.975)
V, T_S = 10.0, 600.0  # m/s, s: 6 km at constant speed, flat
MASS, CDA, CR, ETA = 1500.0, 0.6, 0.01, 0.8
SPEC = {"name": "spec-sheet car", "powertrain": "ev", "class": "car", "mass_kg": MASS, "cda_m2": CDA, "cr": CR,
        "eta": ETA, "battery_kwh": 50.0}


def _vector():
    t = np.arange(0.0, T_S + 1.0)
    return drive_cycle_vector(t, np.full(t.size, V))


def _mid_sd(lo_hi):
    lo, hi = lo_hi
    return 0.5 * (lo + hi), (hi - lo) / (2 * Z95)


def test_a_cold_trip_without_heating_keys_takes_the_class_heating_and_its_spread():
    car = CLASSES["car"]["ev"]
    v = vehicle_from_mapping(dict(SPEC))
    assert v.from_prior == ("aux", "heat", "cool")
    ambient = -5.0
    p = predictive(v, Features.of(_vector(), v, ambient_c=ambient))
    # by hand: the wheel's work at constant speed (rolling + drag, every step driving)
    rolling, drag = MASS * 9.81 * CR * V * T_S, 0.5 * 1.225 * CDA * V ** 3 * T_S
    wheel = rolling + drag
    aux_w, aux_sd = (1e3 * x for x in _mid_sd(car["aux_power_kw"]))
    heat_w, heat_sd = (1e3 * x for x in _mid_sd(car["aux_heating_kw_per_k"]))
    _, cool_sd = _mid_sd(car["aux_cooling_kw_per_k"])
    kelvin = 16.0 - ambient  # below the default heating balance temperature
    mean = wheel / ETA + (aux_w + heat_w * kelvin) * T_S
    assert float(p.mean) == pytest.approx(mean, rel=1e-9)
    eta_lo, eta_hi = car["eta"]
    coef_sd = (1 / eta_lo - 1 / eta_hi) / (2 * Z95)  # of 1 / eta, whose gradient is the wheel's work
    var = ((wheel * coef_sd) ** 2 + (aux_sd * T_S) ** 2 + (heat_sd * kelvin * T_S) ** 2
           + (1e3 * car["scatter_aux_kw"] * T_S) ** 2 + (car["scatter_share"] * mean) ** 2
           + (3.6e6 * car["scatter_trip_kwh"]) ** 2  # A/C: none at -5 degC, whatever its spread
           # the stated CdA and Cr, uncertain by their class's factors: drag and rolling move with them
           + (drag / ETA * _mid_sd(car["cda_m2_factor"])[1]) ** 2 + (rolling / ETA * _mid_sd(car["cr_factor"])[1]) ** 2)
    assert cool_sd > 0
    assert float(p.sd) == pytest.approx(math.sqrt(var), rel=1e-9)
    assert p.source == "prior"
    # the interval: the log-normal of that mean and standard deviation
    s2 = math.log1p(var / mean ** 2)
    lo, hi = p.interval(0.9)
    assert float(lo) == pytest.approx(math.exp(math.log(mean) - s2 / 2 - norm.ppf(0.95) * math.sqrt(s2)), rel=1e-9)
    assert float(hi) == pytest.approx(math.exp(math.log(mean) - s2 / 2 + norm.ppf(0.95) * math.sqrt(s2)), rel=1e-9)


def test_a_stated_zero_is_zero_and_the_legend_says_what_came_from_priors():
    car = CLASSES["car"]["ev"]
    stated = vehicle_from_mapping({**SPEC, "aux_power_kw": 0.0, "aux_heating_kw_per_k": 0.0})
    left_out = vehicle_from_mapping(dict(SPEC))
    assert stated.aux_power_w == 0.0 and stated.aux_heating_w_per_k == 0.0
    assert stated.from_prior == ("cool",)
    vec = _vector()
    f = dict(ambient_c=0.0)
    gap = float(predictive(left_out, Features.of(vec, left_out, **f)).mean
                - predictive(stated, Features.of(vec, stated, **f)).mean)
    aux_mid, heat_mid = _mid_sd(car["aux_power_kw"])[0], _mid_sd(car["aux_heating_kw_per_k"])[0]
    assert gap == pytest.approx(1e3 * (aux_mid + heat_mid * 16.0) * T_S, rel=1e-9)


def test_a_file_without_class_says_the_class_it_was_given(tmp_path):
    from cevm.io.priors import prior_values_note

    path = tmp_path / "nocls.toml"
    path.write_text('name = "x"\npowertrain = "ev"\nmass_kg = 1500\ncda_m2 = 0.6\ncr = 0.01\neta = 0.8\n'
                    'battery_kwh = 50\naux_power_kw = 0.3\naux_heating_kw_per_k = 0.1\naux_cooling_kw_per_k = 0.1\n')
    v = load_vehicle(path)
    assert v.vehicle_class == "car" and v.from_prior == ()
    note = prior_values_note(v)
    assert note is not None and "inferred from its mass" in note and "class car" in note


def test_a_diesel_trucks_interval_stays_above_zero_where_a_gaussian_would_not():
    # a short trip of a truck file never calibrated: sd large against the mean
    truck = vehicle_from_mapping({"name": "t", "powertrain": "ice", "class": "truck", "mass_kg": 30000.0,
                                  "cda_m2": 6.0, "cr": 0.006, "eta": 0.4, "fuel_lhv_mj_per_l": 35.8})
    t = np.arange(0.0, 31.0)
    vec = drive_cycle_vector(t, np.minimum(t, 5.0))
    p = predictive(truck, Features.of(vec, truck, ambient_c=10.0))
    assert float(p.mean - 1.645 * p.sd) < 0  # where the Gaussian's 90 % interval would cross zero
    lo, hi = p.interval(0.9)
    assert float(lo) > 0 and float(hi) > float(p.mean)


@settings(max_examples=200, deadline=None)
@given(mean=st.floats(1e-6, 1e6), rel=st.just(0.0) | st.floats(1e-6, 5.0), q=st.floats(0.01, 0.99))
def test_the_distribution_is_positive_and_its_probability_inverts_its_quantile(mean, rel, q):
    sd = rel * mean
    x = distribution.quantile(mean, sd, q)
    assert float(x) >= 0.0
    if sd > 0:
        assert float(distribution.prob_at_most(mean, sd, x)) == pytest.approx(q, abs=1e-9)


def test_a_negative_mean_is_gaussian():
    lo, hi = distribution.interval(-10.0, 2.0, 0.9)
    assert float(lo) == pytest.approx(-10.0 - norm.ppf(0.95) * 2.0)
    assert float(hi) == pytest.approx(-10.0 + norm.ppf(0.95) * 2.0)
