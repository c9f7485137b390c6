"""How buses drive between stops (cevm.core.timetable.driving): measures on hand-made
series, the shrinkage towards the class prior, the class priors re-measured on the
public cycles they came from, and learning back what was synthesised."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from cevm.core.timetable.driving import (
    PRIORS,
    SHARE_LEVELS,
    SHRINK_N0,
    driving_prior,
    measure_driving,
    params_from_measures,
)
from cevm.core.timetable.learning import fit_driving, learn_driving
from cevm.core.timetable.synthesis import synthesise_trip, timetable_from_log
from conftest import shared_or_skip


def block(stand_s: int, accel: float, top: float, cruise_s: int, brake: float) -> np.ndarray:
    """Standing ``stand_s`` samples, a launch at ``accel`` to ``top``, a cruise, a braking
    at ``brake`` to 0 (whole seconds; the last sample of the braking is 0)."""
    up = accel * np.arange(1, int(round(top / accel)) + 1)
    down = top - brake * np.arange(1, int(round(top / brake)) + 1)
    return np.concatenate((np.zeros(stand_s), up, np.full(cruise_s, top), down))


def hand_series() -> tuple[np.ndarray, np.ndarray]:
    """Three runs at 1 m/s^2 to 10 m/s, 30 s of cruise, braking at 2 m/s^2; stands 10 s
    first, 20 s and 8 s between, 6 s at the end."""
    v = np.concatenate((block(10, 1.0, 10.0, 30, 2.0), block(19, 1.0, 10.0, 30, 2.0),
                        block(7, 1.0, 10.0, 30, 2.0), np.zeros(5)))
    return np.arange(v.size, dtype=np.float64), v


def test_the_measures_of_a_hand_made_series():
    """By hand: a launch reaches 7 m/s (0.7 of the peak) 7 s after its last standing
    sample: 1 m/s^2; a braking leaves 8 m/s (the last sample at or above 7) 4 s before
    its first standing sample: 2 m/s^2; the interior standstills hold 20 and 8 standing
    samples (the braking's last and the block's), 19 and 7 s from first to last (the
    steps the CE vector counts as idle); a part moves in 10 + 30 + 4 samples of 1..10,
    30 x 10 and 8, 6, 4, 2 m/s: its peak over its mean is 10 / (375 / 44); its cruise,
    from the launch's 7 m/s to the braking's 8 m/s, has the least-squares slope numpy's
    polyfit gives, times the 45 s from standstill to standstill over the peak (tilt); no
    slowdown; the distance is 3 x 375 m (trapezoids)."""
    t, v = hand_series()
    m = measure_driving([(t, v)])
    np.testing.assert_allclose(m.accel, [1.0, 1.0, 1.0])
    np.testing.assert_allclose(m.decel, [2.0, 2.0, 2.0])
    np.testing.assert_allclose(m.stop_s, [19.0, 7.0])
    np.testing.assert_allclose(m.km, [1.125])
    np.testing.assert_allclose(m.cruise_ratio, [10.0 / (375.0 / 44.0)] * 3, rtol=1e-12)
    cruise = np.array([7.0, 8.0, 9.0] + [10.0] * 31 + [8.0])
    slope = np.polyfit(np.arange(cruise.size, dtype=float), cruise, 1)[0]
    np.testing.assert_allclose(m.tilt, [-slope * 45.0 / 10.0] * 3, rtol=1e-9)
    assert m.dip_share.size == 0
    p = params_from_measures(m, "hand")
    assert p.accel_mps2 == pytest.approx(1.0) and p.decel_mps2 == pytest.approx(2.0)
    assert p.stops_per_km == pytest.approx(2 / 1.125)
    assert p.stop_s == pytest.approx(math.sqrt(19.0 * 7.0))  # the median of two logs
    assert p.top_speed_mps == pytest.approx(10.0)


def test_a_slowdown_is_seen_with_its_share():
    """A cruise at 10 m/s dipping to 6 m/s (at 1 m/s^2 down and up) is one slowdown at
    0.6 of the speeds around it; a dip of 0.3 m/s is not (under 0.5 m/s)."""
    cruise = np.concatenate((np.full(30, 10.0), 10.0 - np.arange(1, 5), 6.0 + np.arange(1, 5), np.full(30, 10.0),
                             [9.7], np.full(30, 10.0)))
    v = np.concatenate((np.zeros(5), np.arange(1.0, 10.0), cruise, 10.0 - 2.0 * np.arange(1, 6), np.zeros(5)))
    t = np.arange(v.size, dtype=np.float64)
    m = measure_driving([(t, v)])
    np.testing.assert_allclose(m.dip_share, [0.6])


def test_learning_shrinks_towards_the_prior_by_what_it_saw():
    """The launches of one trip (3 at 1 m/s^2) weigh 3 / (3 + 20) against the bus
    prior's median: on the log scale, by hand; 60 trips (180 launches) weigh 0.9."""
    t, v = hand_series()
    prior = driving_prior("bus")
    n0 = SHRINK_N0["launch"]
    one = learn_driving([(t, v)], prior=prior)
    w = 3.0 / (3.0 + n0)
    assert one.accel_mps2 == pytest.approx(math.exp(w * math.log(1.0) + (1 - w) * math.log(prior.accel_mps2)))
    many = learn_driving([(t, v)] * 60, prior=prior, label="X-1")
    w = 180.0 / (180.0 + n0)
    assert many.accel_mps2 == pytest.approx(math.exp((1 - w) * math.log(prior.accel_mps2)))
    assert many.n_trips == 60 and "learnt from 60 trips of X-1" in many.source and prior.source in many.source
    assert learn_driving([], prior=prior) is prior


def test_the_class_priors_say_where_they_come_from():
    assert driving_prior("bus") is PRIORS["bus"] and driving_prior("bus").n_trips == 0
    assert "ADVISOR" in driving_prior("bus").source
    van = driving_prior("van")
    assert van.accel_mps2 == PRIORS["truck"].accel_mps2 and "van" in van.source and "truck" in van.source
    assert "no class given" in driving_prior(None).source
    assert "no drive-cycle prior for class 'tram'" in driving_prior("tram").source
    for p in PRIORS.values():
        assert len(p.slowdown_quantiles) == len(SHARE_LEVELS)
        assert all(math.isfinite(getattr(p, f)) for f in ("accel_mps2", "decel_mps2", "stops_per_km", "stop_s",
                                                          "slowdowns_per_km", "cruise_tilt", "top_speed_mps"))


PRIOR_CYCLES = {
    "bus": ["CYC_MANHATTAN", "CYC_NewYorkBus", "CYC_OCC", "CYC_CBDBUS", "CYC_UKBUS6", "CYC_NurembergR36"],
    "truck": ["CYC_NYCTRUCK", "CYC_CBDTRUCK", "CYC_UDDSHDV", "CYC_WVUCITY", "CYC_WVUSUB", "CYC_CSHVR_Vehicle"],
    "car": ["CYC_ARTERIAL", "CYC_COMMUTER"],
}


@pytest.mark.parametrize("cls", sorted(PRIOR_CYCLES))
def test_the_class_priors_are_their_cycles_measured(cls):
    """Each prior is fit_driving on the public cycles its docstring names (the shared
    folder's ADVISOR cycles, km/h), to the 3 significant digits the table keeps."""
    folder = shared_or_skip("cycles", "advisor")
    series = []
    for name in PRIOR_CYCLES[cls]:
        df = pd.read_csv(folder / f"{name}.csv")
        series.append((df["time_s"].to_numpy(float), np.maximum(df["speed_kmh"].to_numpy(float) / 3.6, 0.0)))
    got = fit_driving(series, cls)
    want = PRIORS[cls]
    for f in ("accel_mps2", "decel_mps2", "stops_per_km", "stop_s", "slowdowns_per_km", "wobble", "cruise_tilt",
              "cruise_ratio", "top_speed_mps"):
        assert getattr(got, f) == pytest.approx(getattr(want, f), rel=5e-3, abs=1e-3), f


def test_what_is_synthesised_is_learnt_back():
    """Cycles synthesised with a driving of 1.1 m/s^2 launches and 1.3 m/s^2 brakings
    (no spread) measure back those values within 5 % (the synthesis' tilt and the 1 s
    grid move them a little), and the stops the timetable asked for."""
    p = replace(driving_prior("bus"), accel_mps2=1.1, accel_sd=0.0, accel_trip_sd=0.0, decel_mps2=1.3, decel_sd=0.0,
                decel_trip_sd=0.0, cruise_tilt=0.0, cruise_tilt_sd=0.0, slowdowns_per_km=0.0, stops_per_km=0.0,
                top_speed_mps=15.0, wobble=0.0)
    rng = np.random.default_rng(5)
    series = []
    for _ in range(10):
        gaps = rng.uniform(300, 900, 8)
        runs = gaps / rng.uniform(6.0, 9.0, 8) + 20.0
        dwell = rng.integers(8, 30, 9).astype(float)
        arr = np.concatenate(([0.0], np.cumsum(runs + dwell[:-1])))
        dep = arr + dwell
        c = synthesise_trip(np.concatenate(([0.0], np.cumsum(gaps))), np.round(arr), np.round(dep), p, rng,
                            with_terminals=True)
        series.append((c.time_s, c.speed_mps))
    back = params_from_measures(measure_driving(series), "back")
    assert back.accel_mps2 == pytest.approx(1.1, rel=0.05)
    assert back.decel_mps2 == pytest.approx(1.3, rel=0.05)
    assert back.stops_per_km == pytest.approx(7 * 10 / sum(float(s[1].sum()) for s in series) * 1000, rel=0.02)
    # and the timetable of a synthesised cycle is the schedule it came from
    d, arr, dep = timetable_from_log(*series[0])
    assert d.size == 9


def test_kinetic_matching_reaches_the_logs_kinetic_energy():
    """The cruise's wobbles are matched so that the logs' own timetables, synthesised,
    gain the logs' positive kinetic energy per km (fit_driving: the logs alone, no prior
    to shrink towards): measured here on a fresh synthesis of those timetables (other
    random draws) against the logs, within 6 % (the matching fits one set of draws of 36
    runs: its own draws' noise is a few per cent)."""
    rng = np.random.default_rng(2)
    series = []
    for _ in range(6):  # runs with a wobbly cruise: 8 +- 1.5 m/s every 12 s
        parts = []
        for _ in range(6):
            cruise = 8.0 + 1.5 * np.sin(2 * np.pi * np.arange(int(rng.integers(40, 90))) / 12.0)
            parts.append(np.concatenate((np.zeros(int(rng.integers(8, 25))), np.linspace(0.8, 8.0, 9), cruise,
                                         np.linspace(7.0, 0.0, 8))))
        v = np.concatenate(parts + [np.zeros(5)])
        series.append((np.arange(v.size, dtype=np.float64), v))
    p = fit_driving(series, "wobbly")
    assert max(p.wobble, p.wobble_slow) > 0.05 and p.kinetic_ratio == pytest.approx(1.0, abs=0.05)
    k_log = sum(float(np.maximum(0.5 * np.diff(v * v), 0).sum()) for _, v in series)
    d_log = sum(float(np.sum((v[:-1] + v[1:]) * 0.5)) for _, v in series)
    k_syn = d_syn = 0.0
    for seed in range(5):  # five fresh sets of draws (the matching used one)
        rng = np.random.default_rng(100 + seed)
        for t, v in series:
            c = synthesise_trip(*timetable_from_log(t, v), p, rng, with_terminals=True)
            k_syn += float(np.maximum(0.5 * np.diff(c.speed_mps ** 2), 0).sum())
            d_syn += float(c.distance_m[-1])
    assert d_syn == pytest.approx(5 * d_log, rel=1e-9)
    assert k_syn / d_syn == pytest.approx(k_log / d_log, rel=0.06)
