"""A scheduled trip's energy with its spread (cevm.core.timetable.energy), against
predict and the predictive distribution on each drawn cycle's own vector."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

import cevm
from cevm.core.cycle import drive_cycle_vector
from cevm.core.energy import ev_negative_weight
from cevm.core.predictive import Features, predictive
from cevm.core.timetable.driving import driving_prior
from cevm.core.timetable.energy import draw_features, scheduled_trip_energy
from cevm.core.timetable.synthesis import synthesise_trips
from cevm.errors import CevmError
from conftest import ROOT

STOPS = np.array([0.0, 420.0, 900.0, 1500.0, 1900.0, 2600.0])
ARR = np.array([0.0, 70.0, 160.0, 260.0, 330.0, 440.0])
DEP = np.array([0.0, 70.0, 185.0, 260.0, 350.0, 440.0])


@pytest.fixture(scope="module")
def bus():
    return cevm.load_vehicle(ROOT / "configs/vehicles/electric-bus.toml")


@pytest.fixture(scope="module")
def truck():
    return cevm.load_vehicle(ROOT / "configs/vehicles/diesel-hgv.toml")


def test_each_draw_is_predicted_as_its_own_vector_would_be(bus):
    """The draws' features, taken from their step terms in one pass, predict what each
    draw's own CE vector predicts (Features.of, predictive), on a road that climbs."""
    p = driving_prior("bus")
    cycles = synthesise_trips(STOPS, ARR, DEP, p, np.random.default_rng(3), 5)
    elev = [20.0 * np.sin(c.distance_m / 400.0) + 0.01 * c.distance_m for c in cycles]
    f = draw_features(cycles, elev, bus, 12_000.0, 4.0)
    got = predictive(bus, f)
    for i, (c, e) in enumerate(zip(cycles, elev, strict=True)):
        vec = drive_cycle_vector(c.time_s, c.speed_mps, e)
        want = predictive(bus, Features.of(vec, bus, 12_000.0, 4.0))
        assert got.mean[i] == pytest.approx(float(want.mean), rel=1e-9)
        assert got.sd[i] == pytest.approx(float(want.sd), rel=1e-9)
        assert f.kinetic_j[i] == pytest.approx(12_000.0 * vec.k_pos, rel=1e-9)
        assert f.idle_s[i] == pytest.approx(vec.idle_s) and f.traction_s[i] == pytest.approx(vec.traction_s)


def test_the_spread_adds_the_draws_to_the_model(bus):
    """sd_synthesis is the sample sd of the draws' predicted means and the synthesis' own
    error (synthesis_sd of the wheel's part: W / eta for the bus, from cevm.predict's
    wheel energy) in quadrature, sd_model the mean of their predictive sds, sd their
    root sum of squares; energy the draws' mean. Each checked against the draws
    synthesised again with the same seed and predicted one by one."""
    p = replace(driving_prior("bus"), synthesis_sd=0.1)
    e = scheduled_trip_energy(bus, STOPS, ARR, DEP, profile_dist_m=None, profile_elev_m=None, mass_kg=12_000.0,
                              ambient_c=4.0, params=p, draws=6, seed=11)
    cycles = synthesise_trips(STOPS, ARR, DEP, p, np.random.default_rng(11), 6)
    vecs = [drive_cycle_vector(c.time_s, c.speed_mps) for c in cycles]
    preds = [predictive(bus, Features.of(v, bus, 12_000.0, 4.0)) for v in vecs]
    means = np.array([float(q.mean) for q in preds])
    sds = np.array([float(q.sd) for q in preds])
    wheel = np.mean([float(cevm.predict(v, bus, 12_000.0, ambient_c=4.0).wheel_energy_j) / bus.eta for v in vecs])
    assert e.energy_j == pytest.approx(means.mean(), rel=1e-9)
    assert e.sd_synthesis_j == pytest.approx(math.hypot(means.std(ddof=1), 0.1 * wheel), rel=1e-6)
    assert e.sd_model_j == pytest.approx(sds.mean(), rel=1e-9)
    assert e.sd_j == pytest.approx(math.hypot(e.sd_model_j, e.sd_synthesis_j))
    assert e.stops == 6 and e.draws == 6 and e.distance_m == pytest.approx(2600.0)
    assert e.duration_s == pytest.approx(440.0) and e.late_s == 0.0
    assert "flat road" in e.cycle_from and p.source in e.cycle_from and "6 draws" in e.cycle_from
    # the representative vector is one of the draws': the one nearest the mean
    rep = int(np.argmin(np.abs(means - means.mean())))
    assert e.vector.k_pos == pytest.approx(vecs[rep].k_pos)


def test_deterministic_for_a_seed(bus):
    p = driving_prior("bus")
    kw = dict(profile_dist_m=None, profile_elev_m=None, mass_kg=11_000.0, ambient_c=15.0, params=p)
    a = scheduled_trip_energy(bus, STOPS, ARR, DEP, seed=5, **kw)
    b = scheduled_trip_energy(bus, STOPS, ARR, DEP, seed=5, **kw)
    c = scheduled_trip_energy(bus, STOPS, ARR, DEP, seed=6, **kw)
    assert a.energy_j == b.energy_j and a.sd_j == b.sd_j
    assert c.energy_j != a.energy_j


def test_one_draw_is_predict_on_its_vector(bus, truck):
    """With one draw (and no synthesis error) there is no synthesis spread and the energy
    is cevm.predict's on the
    returned vector: the battery's energy for the bus, the fuel times its heating value
    for the diesel truck."""
    p = replace(driving_prior("bus"), synthesis_sd=0.0)
    for veh, mass in ((bus, 12_500.0), (truck, 30_000.0)):
        e = scheduled_trip_energy(veh, STOPS, ARR, DEP, profile_dist_m=None, profile_elev_m=None, mass_kg=mass,
                                  ambient_c=8.0, params=p, draws=1)
        pred = cevm.predict(e.vector, veh, mass, ambient_c=8.0)
        want = pred.energy_j if veh.is_ev else pred.fuel_l * veh.fuel_lhv_j_per_l
        assert e.energy_j == pytest.approx(float(want), rel=1e-9)
        assert e.sd_synthesis_j == 0.0 and e.sd_j == pytest.approx(e.sd_model_j)


def test_the_road_climbs_into_the_energy(bus):
    """A road climbing 30 m over the trip (the same draws): ascent 30 m, and the energy
    grows by (dP + w dN) / eta with dP + dN = m g h, dP, dN >= 0 (the climb adds to each
    step's wheel energy: traction steps need more, braking steps give less back), so by
    between w / eta and 1 / eta times m g h, w = eta eta_r the regeneration's weight."""
    p = driving_prior("bus")
    kw = dict(mass_kg=12_000.0, ambient_c=15.0, params=p, seed=2)
    flat = scheduled_trip_energy(bus, STOPS, ARR, DEP, profile_dist_m=None, profile_elev_m=None, **kw)
    up = scheduled_trip_energy(bus, STOPS, ARR, DEP, profile_dist_m=np.array([0.0, 2600.0]),
                               profile_elev_m=np.array([100.0, 130.0]), **kw)
    assert up.ascent_m == pytest.approx(30.0)
    assert "flat road" not in up.cycle_from
    mgh = 12_000.0 * 9.81 * 30.0
    w = ev_negative_weight(bus)
    assert w / bus.eta * mgh * (1 - 1e-9) <= up.energy_j - flat.energy_j <= mgh / bus.eta * (1 + 1e-9)


def test_refusals(bus):
    p = driving_prior("bus")
    kw = dict(profile_dist_m=None, profile_elev_m=None, mass_kg=12_000.0, ambient_c=15.0, params=p)
    with pytest.raises(CevmError, match="draws must be at least 1"):
        scheduled_trip_energy(bus, STOPS, ARR, DEP, draws=0, **kw)
    with pytest.raises(CevmError, match="elevation profile"):
        scheduled_trip_energy(bus, STOPS, ARR, DEP, **{**kw, "profile_dist_m": np.array([0.0, 1.0]),
                                                       "profile_elev_m": np.array([1.0])})
