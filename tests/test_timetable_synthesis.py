"""The synthesis of a scheduled trip's drive cycle (cevm.core.timetable.synthesis): exact
distances and times, speeds within the caps, against hand computations and as properties
over random schedules."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cevm.core.cycle import trapezoid_distance_m
from cevm.core.timetable.driving import driving_prior
from cevm.core.timetable.synthesis import least_run_time_s, synthesise_trip, timetable_from_log
from cevm.errors import CevmError


def steady(a: float = 1.0, b: float = 0.5, top: float = 20.0, **kw):
    """A driving without spread, unscheduled stops or slowdowns."""
    return replace(driving_prior("bus"), accel_mps2=a, accel_sd=0.0, accel_trip_sd=0.0, decel_mps2=b, decel_sd=0.0,
                   decel_trip_sd=0.0, stops_per_km=0.0, slowdowns_per_km=0.0, top_speed_mps=top, stop_sd=0.0,
                   stop_trip_sd=0.0, cruise_tilt=0.0, cruise_tilt_sd=0.0, wobble=0.0, **kw)


def test_a_single_run_is_the_closed_form_trapezoid():
    """d = 450 m in T = 60 s at a = 1, b = 0.5 m/s^2: d = c T - c^2 (1/a + 1/b) / 2 gives
    c = 10 m/s (by hand: 600 - 100 * 1.5 = 450), reached after 10 s, braking from 40 s;
    the kinks fall on whole seconds, so the 1 s samples are the trapezoid itself."""
    c = synthesise_trip(np.array([0.0, 450.0]), np.array([0.0, 60.0]), np.array([0.0, 60.0]), steady(),
                        np.random.default_rng(0))
    t = np.arange(61.0)
    np.testing.assert_allclose(c.time_s, t)
    np.testing.assert_allclose(c.speed_mps, np.minimum.reduce([t * 1.0, np.full(61, 10.0), 0.5 * (60 - t)]),
                               atol=1e-9)
    assert c.distance_m[-1] == pytest.approx(450.0, abs=1e-9)
    assert c.late_s == 0.0


def test_a_triangle_when_the_time_is_tight():
    """d = 400 m in 40 s at a = b = 1: the least time is 2 sqrt(d / a) = 40 s (a triangle
    peaking at 20 m/s); with 0.5 s of grid margin the run is driven a little harder
    (within the 99th percentile: here the spread is 0, so not at all) and arrives late by
    at most the margin."""
    assert least_run_time_s(np.array([400.0]), np.array([1.0]), np.array([1.0]), np.array([30.0]))[0] == \
        pytest.approx(40.0)
    c = synthesise_trip(np.array([0.0, 400.0]), np.array([0.0, 40.0]), np.array([0.0, 40.0]), steady(1.0, 1.0, 30.0),
                        np.random.default_rng(0))
    assert c.distance_m[-1] == pytest.approx(400.0, abs=1e-9)
    assert 0.0 < c.late_s <= 0.5 + 1e-9
    assert c.speed_mps.max() <= 30.0


def test_a_dwell_is_drawn_where_the_timetable_gives_none():
    """Three stops, the middle one with arrival == departure: the bus stands there for
    the driving's stop duration (12 s, no spread) centred on its time."""
    p = steady(stop_s=12.0)
    c = synthesise_trip(np.array([0.0, 500.0, 1000.0]), np.array([0.0, 100.0, 200.0]),
                        np.array([0.0, 100.0, 200.0]), p, np.random.default_rng(0))
    standing = (c.time_s >= 94.0) & (c.time_s <= 106.0)
    assert np.all(c.speed_mps[standing] == 0.0)
    assert c.speed_mps[(c.time_s > 80) & (c.time_s < 94)].max() > 0
    i = np.searchsorted(c.time_s, 100.0)
    assert c.distance_m[i] == pytest.approx(500.0, abs=1e-9)


def test_impossible_schedules_are_refused_naming_the_stop():
    p = steady()
    with pytest.raises(CevmError, match="stops 2 to 3: the distance goes back"):
        synthesise_trip(np.array([0.0, 500.0, 400.0]), np.array([0.0, 60, 120]), np.array([0.0, 60, 120]), p,
                        np.random.default_rng(0))
    with pytest.raises(CevmError, match="stop 2: departs before it arrives"):
        synthesise_trip(np.array([0.0, 500.0, 900.0]), np.array([0.0, 60, 120]), np.array([0.0, 50, 120]), p,
                        np.random.default_rng(0))


@st.composite
def schedules(draw):
    """k stops, distances with repeats (0 m runs), run and dwell times in whole seconds or
    not, 0 s runs (minute-rounded feeds), one cap or none, the terminals or not."""
    k = draw(st.integers(2, 12))
    gaps = np.array(draw(st.lists(st.floats(0.0, 3000.0), min_size=k - 1, max_size=k - 1)))
    whole = draw(st.booleans())
    time = st.integers(0, 400) if whole else st.floats(0.0, 400.0)
    runs = np.array(draw(st.lists(time, min_size=k - 1, max_size=k - 1)), dtype=np.float64)
    dwell = np.array(draw(st.lists(st.integers(0, 60) if whole else st.floats(0.0, 60.0), min_size=k, max_size=k)),
                     dtype=np.float64)
    start = float(draw(st.integers(0, 86_400)))
    dist = np.concatenate(([0.0], np.cumsum(gaps))) + draw(st.floats(0.0, 100.0))
    arr = np.empty(k)
    dep = np.empty(k)
    t = start
    for j in range(k):
        arr[j] = t
        dep[j] = t + dwell[j]
        t = dep[j] + (runs[j] if j < k - 1 else 0.0)
    cap = draw(st.one_of(st.none(), st.floats(3.0, 30.0)))
    return dist, arr, dep, cap, draw(st.booleans()), draw(st.integers(0, 2**31))


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(schedules())
def test_a_synthesised_trip_keeps_its_distances_and_times(case):
    """Any schedule: the cycle covers the trip's distance exactly, is at each stop,
    standing, at its time (or, where the schedule cannot be kept, says how late),
    starts at the first departure (or arrival, with the terminals), keeps the speed
    within the cap, steps by at most 1 s, and its distance is the trapezoid's of its own
    speeds (float rounding aside: 1e-9 of the trip but at least a micrometre (hypothesis
    found a 60 nm trip ending 2 nm short: speeds of 1e-9 m/s rounded), 1e-6 m/s, 1e-6 s)."""
    dist, arr, dep, cap, terminals, seed = case
    p = driving_prior("bus")
    c = synthesise_trip(dist, arr, dep, p, np.random.default_rng(seed), speed_cap_mps=cap, with_terminals=terminals)
    tol = max(1e-9 * dist[-1], 1e-6)
    assert c.time_s[0] == pytest.approx(arr[0] if terminals else dep[0], abs=1e-6)
    assert np.all(np.diff(c.time_s) > 0) and np.all(np.diff(c.time_s) <= 1.0 + 1e-9)
    assert np.all(c.speed_mps >= 0) and c.speed_mps.max() <= (cap or p.top_speed_mps) + 1e-9
    assert c.speed_mps[0] == 0 and c.speed_mps[-1] == 0
    assert c.distance_m[-1] == pytest.approx(dist[-1] - dist[0], abs=tol)
    assert trapezoid_distance_m(c.time_s, c.speed_mps) == pytest.approx(c.distance_m[-1], abs=tol)
    if c.late_max_s == 0.0:
        assert c.time_s[-1] == pytest.approx(dep[-1] if terminals else arr[-1], abs=1e-6)
        for j in range(1, dist.size):  # at each stop's arrival the bus is there, standing
            assert np.interp(arr[j], c.time_s, c.distance_m) == pytest.approx(dist[j] - dist[0], abs=tol)
            assert np.interp(arr[j], c.time_s, c.speed_mps) <= 1e-6
    else:
        assert c.time_s[-1] == pytest.approx((dep[-1] if terminals else arr[-1]) + c.late_s, abs=1e-6) \
            or terminals


def test_a_logged_trip_becomes_its_stops():
    """A hand-made log: stands 10 s, drives 95 m (2.5 + 18 x 5 + 2.5), stands 9 s, drives, stands 3 s (not a
    stop: under 5 s), drives, stops at the end and stands 4 s."""
    v = np.concatenate((np.zeros(10), [5.0] * 21, np.zeros(8), [5.0] * 11, np.zeros(3), [5.0] * 11, np.zeros(4)))
    v[[10, 30, 39, 49, 53, 63]] = 0.0  # the ramps' ends at standstill
    t = np.arange(v.size, dtype=np.float64)
    d, arr, dep = timetable_from_log(t, v)
    assert d.size == 3
    assert arr[0] == 0 and dep[0] == 10
    assert arr[1] == 30 and dep[1] == 39
    assert arr[2] == 63 and dep[2] == t[-1]
    assert d[1] == pytest.approx(95.0) and d[2] == pytest.approx(trapezoid_distance_m(t, v))
