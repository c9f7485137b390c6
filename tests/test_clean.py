"""Tests of cevm.ingest.cleaning: each cleaning rule on small synthetic frames with known answers.

Reference positions and lengths come from pyproj's geodesic (Geod.fwd / line_length),
independent of the fast formula used inside cevm.ingest.cleaning.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pyproj import Geod

from cevm.errors import InputError
from cevm.ingest.cleaning import (
    CleanParams,
    CleanTrip,
    clean_log,
    clean_trips,
    geodesic_steps_m,
    local_distance_m,
)

GEOD = Geod(ellps="WGS84")
T0 = 1_600_000_000.0  # a whole second, UTC
LAT0, LON0 = 52.0, -1.5


@dataclass(frozen=True)
class Src:
    """Stand-in for cevm.ingest.reading.EnergySource."""

    column: str
    kind: str
    quantity: str
    resolution: float
    priority: int
    capacity_j: float | None = None


def make(tau, **cols) -> pd.DataFrame:
    """Canonical frame: time_s = T0 + tau, source_line 2.. (after a header)."""
    tau = np.asarray(tau, dtype=float)
    data = {"time_s": T0 + tau, "source_line": np.arange(2, tau.size + 2)}
    data.update({k: np.asarray(v, dtype=float) for k, v in cols.items()})
    return pd.DataFrame(data)


def north(dist_m):
    """Positions [deg] at distances [m] north of (LAT0, LON0) along the meridian."""
    d = np.asarray(dist_m, dtype=float)
    lon, lat, _ = GEOD.fwd(np.full(d.shape, LON0), np.full(d.shape, LAT0), np.zeros(d.shape), d)
    return np.asarray(lat), np.asarray(lon)


def only(result) -> CleanTrip:
    trips = result.trips if hasattr(result, "trips") else result
    assert len(trips) == 1, [t.quality.get("split_before") for t in trips]
    return trips[0]


def drive(tau, v=10.0, with_gps=True, **extra) -> pd.DataFrame:
    """A vehicle at constant speed v [m/s] going north, wheel speed (and GPS) each row."""
    tau = np.asarray(tau, dtype=float)
    cols = {"wheel_speed_mps": np.full(tau.size, v)}
    if with_gps:
        cols["lat_deg"], cols["lon_deg"] = north(v * tau)
    cols.update(extra)
    return make(tau, **cols)


TAU = np.arange(0.0, 601.0)


# ------------------------------------------------------------------ distance, geodesy


def test_constant_speed_distance_is_v_times_t():
    trip = only(clean_log(drive(TAU, v=10.0)))
    np.testing.assert_array_equal(trip.time_s, TAU)
    np.testing.assert_array_equal(trip.distance_m, 10.0 * TAU)
    assert trip.start_utc_s == T0
    assert trip.length_m == 6000.0 and trip.duration_s == 600.0
    assert (trip.first_source_line, trip.last_source_line) == (2, 602)
    json.dumps(trip.quality, allow_nan=False)  # JSON-serialisable, strict


def test_gps_cross_check_on_a_meridian():
    trip = only(clean_log(drive(TAU, v=10.0)))
    lat, lon = north(10.0 * TAU)
    reference = GEOD.line_length(lon, lat)  # independent geodesic length
    assert reference == pytest.approx(6000.0, abs=1e-6)
    assert trip.quality["distance_gps_m"] == pytest.approx(reference, rel=1e-7)
    assert trip.quality["distance_ratio_speed_vs_gps"] == pytest.approx(1.0, abs=1e-7)


def test_one_degree_of_latitude_at_the_equator():
    # WGS84 meridian arc from 0 to 1 deg: 110 574.389 m (the brief's 110.574 km)
    d = geodesic_steps_m(np.array([0.0, 1.0]), np.array([0.0, 0.0]))
    assert d[0] == pytest.approx(110574.389, abs=0.01)


def test_local_distance_matches_geodesic_below_one_km():
    rng = np.random.default_rng(3)
    n = 5000
    lat, lon = rng.uniform(-80, 80, n), rng.uniform(-180, 180, n)
    dist = rng.uniform(1.0, 1000.0, n)
    lon2, lat2, _ = GEOD.fwd(lon, lat, rng.uniform(0, 360, n), dist)
    rel = np.abs(local_distance_m(lat, lon, lat2, lon2) - dist) / dist
    assert rel.max() < 1e-7


# ----------------------------------------------------------------------------- time


def test_duplicates_dropped_and_async_ticks_merged():
    base = drive(TAU)
    expected = only(clean_log(base))
    # 5 ticks written twice, next to each other
    dups = base.iloc[[10, 20, 30, 40, 50]].copy()
    # 10 ticks split in two rows with the same time: wheel speed in one, GPS in the other
    split = base.iloc[100:110].copy()
    gps_part = split.copy()
    split[["lat_deg", "lon_deg"]] = np.nan
    gps_part["wheel_speed_mps"] = np.nan
    frame = pd.concat([base.drop(index=range(100, 110)), dups, split, gps_part])
    frame = frame.sort_index(kind="stable").reset_index(drop=True)  # file order
    frame["source_line"] = np.arange(2, len(frame) + 2)
    res = clean_log(frame)
    trip = only(res)
    assert res.quality["duplicate_rows_dropped"] == 5
    assert res.quality["ticks_merged"] == 10
    assert res.quality["conflicting_values"] == 0
    assert trip.quality["duplicate_rows_dropped"] == 5
    np.testing.assert_array_equal(trip.speed_mps, expected.speed_mps)
    np.testing.assert_array_equal(trip.lat_deg, expected.lat_deg)


def test_conflicting_values_in_one_tick_keep_the_later_row():
    base = drive(TAU)
    extra = base.iloc[[300]].copy()
    extra["wheel_speed_mps"] = 12.0
    extra["source_line"] = 9999
    frame = pd.concat([base, extra]).sort_index(kind="stable")  # right after its twin
    res = clean_log(frame.reset_index(drop=True))
    trip = only(res)
    assert res.quality["conflicting_values"] == 1
    assert trip.speed_mps[300] == 12.0  # later in the file wins
    assert trip.first_source_line == 2  # lowest line of the merged tick kept


def _profile(tau):
    return 10.0 + 5.0 * np.sin(tau / 50.0)


def test_backward_clock_step_shifts_the_earlier_segment():
    tau = np.arange(0.0, 1000.0)
    logged = np.where(tau < 500, tau + 30.0, tau)  # clock 30 s fast, corrected at 500
    res = clean_log(make(logged, wheel_speed_mps=_profile(tau)))
    trip = only(res)
    assert trip.start_utc_s == T0
    np.testing.assert_array_equal(trip.time_s, tau)
    np.testing.assert_allclose(trip.speed_mps, _profile(tau), rtol=0, atol=1e-12)
    assert res.quality["clock_steps"] == 1
    assert res.quality["clock_step_corrections_s"] == [-30.0]
    assert trip.quality["clock_steps"] == 1


def test_forward_clock_step_with_motion_evidence():
    tau = np.arange(0.0, 1000.0)
    logged = np.where(tau < 500, tau, tau + 120.0)  # clock jumps 120 s ahead at 500
    lat, lon = north(15.0 * tau)
    frame = make(logged, wheel_speed_mps=np.full(tau.size, 15.0), lat_deg=lat, lon_deg=lon)
    res = clean_log(frame)
    trip = only(res)
    assert res.quality["clock_steps_forward"] == 1
    assert trip.start_utc_s == T0 + 120.0  # the later clock is taken as right
    np.testing.assert_array_equal(trip.time_s, tau)
    assert trip.length_m == pytest.approx(15.0 * 999.0)
    # without positions nothing shows that the vehicle did not drive through a pause
    res = clean_log(make(logged, wheel_speed_mps=np.full(tau.size, 15.0)))
    assert len(res.trips) == 2
    assert res.trips[1].quality["split_before"] == "speed_gap"


def test_junk_timestamp_row_dropped():
    frame = drive(TAU)
    frame.loc[300, "time_s"] = T0 + 1.0e7
    res = clean_log(frame)
    trip = only(res)
    assert res.quality["time_outliers_dropped"] == 1
    assert trip.quality["time_outliers_dropped"] == 1
    assert trip.quality["rows"] == 600
    np.testing.assert_array_equal(trip.distance_m, 10.0 * TAU)


def test_rows_without_time_are_dropped():
    frame = drive(TAU)
    frame.loc[[5, 6], "time_s"] = np.nan
    res = clean_log(frame)
    assert res.quality["rows_without_time"] == 2
    assert only(res).length_m == 6000.0


def test_reversed_file_is_sorted():
    expected = only(clean_log(drive(TAU)))
    res = clean_log(drive(TAU).iloc[::-1])
    assert res.quality["file_order"] == "unordered"
    trip = only(res)
    np.testing.assert_array_equal(trip.distance_m, expected.distance_m)
    np.testing.assert_array_equal(trip.lat_deg, expected.lat_deg)


# ---------------------------------------------------------------------------- splits


def test_split_at_ignition_off():
    tau = np.arange(0.0, 1201.0)
    v = np.where((tau >= 400) & (tau < 600), 0.0, 10.0)
    ign = np.full(tau.size, np.nan)  # asynchronous: only where it changes
    ign[[0, 400, 600]] = [1.0, 0.0, 1.0]
    res = clean_log(make(tau, wheel_speed_mps=v, ignition=ign))
    assert len(res.trips) == 2
    a, b = res.trips
    assert a.start_utc_s == T0 and a.duration_s == 400.0  # ends at the first "off" row
    assert b.start_utc_s == T0 + 600.0 and b.duration_s == 600.0
    assert (a.quality["split_after"], b.quality["split_before"]) == ("ignition", "ignition")


def test_split_at_long_gap():
    tau = np.arange(0.0, 1201.0)
    tau = tau[(tau < 200) | (tau >= 550)]  # 350 s without rows > gap_s = 300
    res = clean_log(drive(tau))
    assert len(res.trips) == 2
    assert res.trips[1].quality["split_before"] == "gap"
    assert res.trips[1].start_utc_s == T0 + 550.0
    # 250 s without rows while stopped: no split
    v = np.where((TAU > 200) & (TAU < 500), 0.0, 10.0)
    keep = (TAU <= 220) | (TAU >= 470)
    assert only(clean_log(make(TAU[keep], wheel_speed_mps=v[keep]))).duration_s == 600.0


def test_split_at_long_stop_and_stop_removed():
    tau = np.arange(0.0, 3301.0)
    v = np.where((tau >= 600) & (tau < 2700), 0.0, 10.0)  # 2100 s stop > stop_s = 1800
    res = clean_log(make(tau, wheel_speed_mps=v))
    assert len(res.trips) == 2
    a, b = res.trips
    assert a.duration_s == 600.0  # ends where the stop starts
    assert b.start_utc_s == T0 + 2699.0  # starts where it ends
    assert b.quality["split_before"] == "long_stop"
    # a short stop stays in the trip
    v = np.where((tau >= 600) & (tau < 700), 0.0, 10.0)
    assert only(clean_log(make(tau, wheel_speed_mps=v))).duration_s == 3300.0


def test_moving_hole_splits_standstill_hole_is_filled():
    tau = TAU[(TAU < 300) | (TAU >= 360)]  # 61 s hole while moving
    res = clean_log(drive(tau, with_gps=False))
    assert len(res.trips) == 2 and res.trips[1].quality["split_before"] == "speed_gap"
    v = np.where((TAU >= 250) & (TAU <= 450), 0.0, 10.0)
    keep = (TAU <= 300) | (TAU >= 420)  # 120 s without rows during a stop
    trip = only(clean_log(make(TAU[keep], wheel_speed_mps=v[keep])))
    assert trip.quality["standstill_holes_filled"] == 1
    np.testing.assert_array_equal(trip.speed_mps[250:451], 0.0)
    # 0..249 s at 10 m/s, braking step 5 m, stop, starting step 5 m, 451..600 s at 10 m/s
    assert trip.length_m == 2490.0 + 5.0 + 5.0 + 1490.0  # nothing accrues while stopped


def test_short_trips_dropped_and_reported():
    tau = np.concatenate((np.arange(0.0, 31.0), np.arange(1000.0, 1601.0), np.arange(3000.0, 3101.0)))
    v = np.where(tau >= 3000, 1.0, 10.0)  # last segment: 100 s but only 100 m
    res = clean_log(make(tau, wheel_speed_mps=v))
    trip = only(res)
    assert trip.start_utc_s == T0 + 1000.0
    assert len(res.dropped) == 2
    assert all("shorter" in d["reason"] for d in res.dropped)
    assert res.dropped[0]["duration_s"] == 30.0
    assert res.dropped[1]["distance_m"] == 100.0
    assert res.quality["trips_dropped"] == 2


# ----------------------------------------------------------------------------- speed


def test_speed_source_preference_wheel_then_gps_then_positions():
    lat, lon = north(12.0 * TAU)
    wheel, gps = np.full(TAU.size, 10.0), np.full(TAU.size, 11.0)
    t = only(clean_log(make(TAU, wheel_speed_mps=wheel, gps_speed_mps=gps, lat_deg=lat, lon_deg=lon)))
    assert t.quality["speed_source"] == "wheel_speed_mps"
    np.testing.assert_array_equal(t.speed_mps, 10.0)
    t = only(clean_log(make(TAU, gps_speed_mps=gps, lat_deg=lat, lon_deg=lon)))
    assert t.quality["speed_source"] == "gps_speed_mps"
    np.testing.assert_array_equal(t.speed_mps, 11.0)
    t = only(clean_log(make(TAU, lat_deg=lat, lon_deg=lon)))
    assert t.quality["speed_source"] == "gps_positions"
    np.testing.assert_allclose(t.speed_mps, 12.0, rtol=1e-6)


def test_wheel_dropout_filled_from_gps_speed():
    wheel = np.where((TAU >= 300) & (TAU < 360), np.nan, 10.0)  # 61 s without wheel speed
    t = only(clean_log(make(TAU, wheel_speed_mps=wheel, gps_speed_mps=np.full(TAU.size, 11.0))))
    np.testing.assert_array_equal(t.speed_mps[300:360], 11.0)
    np.testing.assert_array_equal(t.speed_mps[:300], 10.0)
    share = t.quality["speed_source_share"]
    assert share["gps_speed_mps"] == pytest.approx(60 / 601)


def test_async_speed_interpolated_in_time():
    wheel = np.where(TAU % 2 == 0, 0.02 * TAU, np.nan)  # value every other tick: a ramp
    t = only(clean_log(make(TAU, wheel_speed_mps=wheel)))
    np.testing.assert_allclose(t.speed_mps, 0.02 * TAU, rtol=0, atol=1e-12)


def test_impossible_speed_values_rejected():
    wheel = np.full(TAU.size, 10.0)
    wheel[[100, 200]] = [255.996 / 3.6, -1.0]  # FMS "not available", junk
    res = clean_log(make(TAU, wheel_speed_mps=wheel))
    trip = only(res)
    assert trip.quality["speed_values_rejected"] == 2
    np.testing.assert_array_equal(trip.speed_mps, 10.0)


def test_noisy_gps_speed_at_rest_is_zeroed():
    rng = np.random.default_rng(7)
    v = np.where((TAU >= 200) & (TAU < 400), np.abs(rng.normal(0, 0.15, TAU.size)), 10.0)
    trip = only(clean_log(make(TAU, gps_speed_mps=v)))
    np.testing.assert_array_equal(trip.speed_mps[200:400], 0.0)
    assert trip.distance_m[399] == trip.distance_m[200]


# ------------------------------------------------------------------------------- GPS


def test_impossible_gps_jump_and_junk_fixes_rejected():
    frame = drive(TAU)
    lat_true, lon_true = frame["lat_deg"].to_numpy().copy(), frame["lon_deg"].to_numpy().copy()
    frame.loc[300, "lat_deg"] += 0.05  # 5.6 km away for one fix
    frame.loc[[400, 401, 402], "lon_deg"] += 0.02  # a run of three
    frame.loc[200, "lon_deg"] = 1555.6333  # junk seen in real logs
    frame.loc[100, "lat_deg"] = 0.0  # "no fix" marker
    res = clean_log(frame)
    trip = only(res)
    assert trip.quality["gps_rejected_jump"] == 4
    assert trip.quality["gps_rejected_invalid"] == 2
    for i in (100, 200, 300, 401):
        assert trip.lat_deg[i] == pytest.approx(lat_true[i], abs=1e-9)
        assert trip.lon_deg[i] == pytest.approx(lon_true[i], abs=1e-9)
    assert trip.quality["distance_gps_m"] == pytest.approx(6000.0, rel=1e-6)


def test_gps_dropouts_filled_when_short_left_unknown_when_long():
    frame = drive(TAU)
    lat_true = frame["lat_deg"].to_numpy().copy()
    frame.loc[200:219, ["lat_deg", "lon_deg"]] = np.nan  # 20 s: filled
    frame.loc[300:359, ["lat_deg", "lon_deg"]] = np.nan  # 60 s > gps_max_fill_s: unknown
    trip = only(clean_log(frame))
    assert trip.quality["gps_dropouts_filled"] == 1
    assert trip.lat_deg[210] == pytest.approx(lat_true[210], abs=1e-9)
    assert np.isnan(trip.lat_deg[300:360]).all()
    assert trip.quality["gps_coverage"] == pytest.approx(541 / 601)


def test_jitter_frozen_at_standstill():
    rng = np.random.default_rng(11)
    v = np.where((TAU >= 300) & (TAU < 500), 0.0, 10.0)
    dist = np.concatenate(([0.0], np.cumsum(0.5 * (v[1:] + v[:-1]))))
    lat, lon = north(dist)
    stop = (TAU >= 300) & (TAU < 500)
    lat[stop] += rng.normal(0, 4e-5, stop.sum())  # ~4 m of noise
    lon[stop] += rng.normal(0, 6e-5, stop.sum())
    alt = np.where(stop, 100 + rng.normal(0, 5, TAU.size), 100.0)
    trip = only(clean_log(make(TAU, wheel_speed_mps=v, lat_deg=lat, lon_deg=lon, gps_alt_m=alt)))
    np.testing.assert_array_equal(trip.lat_deg[300:500], np.median(lat[stop]))
    np.testing.assert_array_equal(trip.lon_deg[300:500], np.median(lon[stop]))
    np.testing.assert_array_equal(trip.gps_alt_m[300:500], np.median(alt[stop]))
    assert trip.distance_m[499] == trip.distance_m[300]  # no distance while stopped
    assert trip.quality["jitter_frozen_samples"] == 200
    assert trip.quality["jitter_removed_m"] > 500  # 199 noisy steps of several metres
    # the GPS track's length is the driven length plus at most the two steps into and
    # out of the frozen point (a few metres), not the noise
    assert trip.quality["distance_gps_m"] == pytest.approx(trip.length_m, abs=20)


def test_stale_repeated_fixes_while_moving_rejected():
    frame = drive(TAU)
    lat_true = frame["lat_deg"].to_numpy().copy()
    hold = (np.arange(TAU.size) // 5) * 5  # the logger repeats each fix for 5 ticks
    frame["lat_deg"] = frame["lat_deg"].to_numpy()[hold]
    frame["lon_deg"] = frame["lon_deg"].to_numpy()[hold]
    trip = only(clean_log(frame))
    assert trip.quality["gps_rejected_stale"] == 480  # 600 rows minus 120 fresh fixes
    assert trip.lat_deg[302] == pytest.approx(lat_true[302], abs=1e-9)


# ------------------------------------------------------------ weight, consumption, API


def test_gross_weight_median_and_measured_fuel():
    w = np.full(TAU.size, np.nan)
    w[[5, 300, 590]] = [18000.0, 18010.0, 25000.0]
    frame = drive(TAU, gross_weight_kg=w, fuel_rate_lps=np.full(TAU.size, 0.002))
    trip = only(clean_log(frame, [Src("fuel_rate_lps", "rate", "fuel_l", 0.0, 0)]))
    assert trip.gross_weight_kg == 18010.0
    assert trip.measured.kind == "fuel_l"
    assert trip.measured.value == pytest.approx(0.002 * 600.0, rel=1e-12)
    assert trip.quality["consumption"]["source"] == "fuel_rate_lps"
    assert only(clean_log(drive(TAU))).gross_weight_kg is None


def test_irregular_times_resampled_on_whole_seconds():
    tau = np.cumsum(np.r_[0.3, np.full(599, 1.07)])  # 0.3 .. 641.23 s
    trip = only(clean_log(drive(tau)))
    assert trip.start_utc_s == T0 + 1.0
    np.testing.assert_array_equal(trip.time_s, np.arange(0.0, 641.0))
    np.testing.assert_allclose(trip.distance_m, 10.0 * trip.time_s, rtol=1e-12)
    raw = only(clean_log(drive(tau), params=CleanParams(grid_s=None)))
    np.testing.assert_allclose(raw.time_s, tau - tau[0], rtol=0, atol=1e-6)


def test_input_errors():
    with pytest.raises(InputError, match="time"):
        clean_log(pd.DataFrame({"wheel_speed_mps": [1.0, 2.0]}), path="a.csv")
    with pytest.raises(InputError, match="speed or position"):
        clean_log(make([0.0, 1.0], soc_pct=[50.0, 49.0]), path="a.csv")
    bad = drive(TAU[:10])
    bad["wheel_speed_mps"] = bad["wheel_speed_mps"].astype(object)
    bad.loc[4, "wheel_speed_mps"] = "fast"
    with pytest.raises(InputError) as e:
        clean_log(bad, path="a.csv")
    assert e.value.line == 6 and e.value.column == "wheel_speed_mps"


def test_clean_trips_returns_the_list():
    assert isinstance(clean_trips(drive(TAU)), list)


# ---------------------------------------------------------------------- properties


def _random_drive(n, seed):
    rng = np.random.default_rng(seed)
    tau = np.cumsum(rng.uniform(0.5, 1.5, n))
    v = np.clip(np.cumsum(rng.normal(0, 0.5, n)) + 8, 0, 30)
    dist = np.concatenate(([0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(tau))))
    lat, lon = north(dist)
    wheel = np.where(rng.random(n) < 0.2, np.nan, v)  # asynchronous holes
    return make(tau, wheel_speed_mps=wheel, lat_deg=lat, lon_deg=lon,
                fuel_rate_lps=rng.uniform(0, 0.01, n))


SOURCES = [Src("fuel_rate_lps", "rate", "fuel_l", 0.0, 0)]


def assert_same_trips(a, b):
    assert len(a.trips) == len(b.trips)
    for x, y in zip(a.trips, b.trips, strict=True):
        assert x.start_utc_s == y.start_utc_s
        for name in ("time_s", "speed_mps", "distance_m", "lat_deg", "lon_deg"):
            np.testing.assert_array_equal(getattr(x, name), getattr(y, name))
        assert x.measured == y.measured


@settings(max_examples=15, deadline=None)
@given(n=st.integers(150, 400), seed=st.integers(0, 2**32 - 1))
def test_shuffled_frame_gives_the_same_trips(n, seed):
    frame = _random_drive(n, seed)
    perm = np.random.default_rng(seed + 1).permutation(n)
    assert_same_trips(clean_log(frame, SOURCES), clean_log(frame.iloc[perm], SOURCES))


@settings(max_examples=15, deadline=None)
@given(n=st.integers(150, 400), seed=st.integers(0, 2**32 - 1), swaps=st.data())
def test_adjacent_rows_swapped_give_the_same_trips(n, seed, swaps):
    frame = _random_drive(n, seed)
    pairs = swaps.draw(st.sets(st.integers(0, n // 2 - 1), max_size=n // 20))
    order = np.arange(n)
    for k in pairs:  # disjoint pairs (2k, 2k+1)
        order[[2 * k, 2 * k + 1]] = order[[2 * k + 1, 2 * k]]
    assert_same_trips(clean_log(frame, SOURCES), clean_log(frame.iloc[order], SOURCES))


def _messy_drive(n, seed):
    """A random drive with what the whole-log steps repair: repeated rows, ticks split
    over two rows (GPS in one, the rest in the other), a few junk times, rows shuffled
    in places, GPS fix jumps, and columns that only the tick merge reads."""
    rng = np.random.default_rng(seed)
    fr = _random_drive(n, seed)
    fr["engine_speed_rpm"] = np.round(rng.uniform(600, 2000, n) * 8) / 8
    fr["gps_hdop"] = np.where(rng.random(n) < 0.05, 50.0, 1.0)
    fr["gps_alt_m"] = 100 + np.cumsum(rng.normal(0, 0.3, n))
    jump = rng.random(n) < 0.01
    fr.loc[jump, "lat_deg"] += 0.05
    split = rng.random(n) < 0.3  # half the fields in a second row of the same time
    extra = fr[split].copy()
    extra[["lat_deg", "lon_deg", "gps_alt_m"]] = np.nan
    fr.loc[split, ["wheel_speed_mps", "engine_speed_rpm"]] = np.nan
    dup = fr[rng.random(n) < 0.1]
    out = pd.concat([fr, extra, dup]).sort_values(["time_s"], kind="stable").reset_index(drop=True)
    idx = np.arange(out.shape[0])
    for k in rng.integers(0, out.shape[0] - 2, max(1, n // 50)):  # local swaps
        idx[[k, k + 1]] = idx[[k + 1, k]]
    out = out.iloc[idx].reset_index(drop=True)
    out.loc[rng.integers(10, out.shape[0] - 10, 2), "time_s"] += 86400.0  # junk times
    out["source_line"] = np.arange(2, out.shape[0] + 2)
    return out


@pytest.mark.slow
@settings(max_examples=20, deadline=None)
@given(n=st.integers(150, 400), seed=st.integers(0, 2**32 - 1))
def test_results_do_not_depend_on_the_chunk_size(n, seed):
    """The row-wise steps work a chunk of rows at a time; chunks of 7 rows (every
    boundary inside runs, ticks, jumps and gaps) give the same trips, quality and
    dropped segments as one chunk."""
    import cevm.ingest.consumption as consumption

    frame = _messy_drive(n, seed)
    want = clean_log(frame.copy(), SOURCES)
    old = consumption.CHUNK_ROWS
    consumption.CHUNK_ROWS = 7
    try:
        got = clean_log(frame.copy(), SOURCES)
    finally:
        consumption.CHUNK_ROWS = old
    assert_same_trips(got, want)
    assert [t.quality for t in got.trips] == [t.quality for t in want.trips]
    assert got.quality == want.quality and got.dropped == want.dropped


def test_clean_stream_makes_the_trips_a_batch_at_a_time():
    """CleanStream: errors when made; the trips as they are asked for, a bounded batch
    at a time (here one trip a batch); the dropped segments and the file's quality
    complete once the iteration ends; the caller's frame let go of with
    release_frame; nothing the second time; the same trips whatever the batches."""
    from cevm.ingest.cleaning import CleanStream

    with pytest.raises(InputError, match="time"):
        CleanStream(pd.DataFrame({"wheel_speed_mps": [1.0, 2.0]}), path="a.csv")
    # three trips: 600 s, a 400 s gap, 600 s, a 400 s gap, 20 s (dropped: too short)
    tau = np.concatenate((TAU, 1000.0 + TAU, 2000.0 + np.arange(21.0)))
    frame = drive(tau)
    stream = CleanStream(frame, release_frame=True)
    assert list(frame.columns) == []
    batches = stream.batches(max_samples=601)
    first = next(batches)
    assert len(first) == 1 and first.trip(0).duration_s == 600.0 and stream.dropped == []
    rest = list(batches)
    assert [b.trip(0).start_utc_s for b in rest] == [T0 + 1000.0]
    assert len(stream.dropped) == 1 and stream.dropped[0]["duration_s"] == 20.0
    assert stream.quality["trips"] == 2 and stream.quality["trips_dropped"] == 1
    assert list(stream) == [] and list(stream.batches()) == []
    whole = clean_log(drive(tau))  # one batch of both trips
    for a, b in zip(whole.trips, [first.trip(0), rest[0].trip(0)], strict=True):
        assert a.quality == b.quality
        for name in ("time_s", "speed_mps", "distance_m", "lat_deg", "lon_deg", "gps_alt_m"):
            assert getattr(a, name).tobytes() == getattr(b, name).tobytes()


@settings(max_examples=25, deadline=None)
@given(n=st.integers(70, 300), seed=st.integers(0, 2**32 - 1))
def test_trip_invariants(n, seed):
    for trip in clean_log(_random_drive(n, seed)).trips:
        assert trip.time_s[0] == 0.0 and (np.diff(trip.time_s) > 0).all()
        assert (trip.speed_mps >= 0).all()
        assert trip.distance_m[0] == 0.0 and (np.diff(trip.distance_m) >= 0).all()
        v, t = trip.speed_mps, trip.time_s
        trapezoid = sum((v[i] + v[i + 1]) / 2 * (t[i + 1] - t[i]) for i in range(v.size - 1))
        assert trip.length_m == pytest.approx(trapezoid, rel=1e-12)
        assert math.isfinite(trip.start_utc_s) and trip.start_utc_s == round(trip.start_utc_s)


# ------------------------------------------------------- tick merging against pandas


def _dedupe_reference(t, line, cols):
    """Plain pandas statement of the tick rules (module docstring, step 2): drop rows
    equal to an earlier one in time and every field, merge the rest per time (last
    non-NaN value per field, lowest line), count merged ticks and conflicting fields."""
    names = list(cols)
    df = pd.DataFrame({"t": t, "line": line, **cols})
    dup = df.duplicated(subset=["t", *names], keep="first").to_numpy()
    kept = df.loc[~dup]
    g = kept.groupby("t", sort=True)
    merged = g.last()
    sizes = g.size()
    conflicts = int((g[names].nunique() > 1).to_numpy().sum()) if names else 0
    return (merged.index.to_numpy(), g["line"].min().to_numpy(),
            {k: merged[k].to_numpy(dtype=float) for k in names},
            int(dup.sum()), int((sizes > 1).sum()), conflicts)


@pytest.mark.slow
@settings(max_examples=60, deadline=None)
@given(n=st.integers(1, 40), n_cols=st.integers(0, 3), seed=st.integers(0, 2**32 - 1))
def test_tick_merging_matches_a_pandas_statement_of_the_rules(n, n_cols, seed):
    from cevm.ingest.cleaning.duplicates import _dedupe
    from cevm.ingest.cleaning.events import RepairEvents

    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(0, max(2, n // 2), n)).astype(float)  # many shared times
    line = rng.permutation(n).astype(np.int64) + 2
    # few distinct values (duplicates and conflicts), NaN often, signed zeros
    pool = np.array([np.nan, np.nan, 0.0, -0.0, 1.5, 2.0])
    cols = {f"c{j}": pool[rng.integers(0, pool.size, n)] for j in range(n_cols)}
    ev = RepairEvents()
    t_out, line_out, cols_out = _dedupe(t, line, dict(cols), ev)
    ev.finish()
    want_t, want_line, want_cols, n_dup, n_merged, n_conf = _dedupe_reference(t, line, cols)
    np.testing.assert_array_equal(t_out, want_t)
    np.testing.assert_array_equal(line_out, want_line)
    for k in cols:
        np.testing.assert_array_equal(cols_out[k], want_cols[k])  # NaN where NaN
    counts = ev.totals()
    if (t[1:] == t[:-1]).any():
        assert (counts["duplicate_rows_dropped"], counts["ticks_merged"], counts["conflicting_values"]) == (
            n_dup, n_merged, n_conf)
    else:  # nothing to merge: the input comes back as it is
        assert counts["ticks_merged"] == 0 and t_out is t


@settings(max_examples=60, deadline=None)
@given(n=st.integers(1, 60), seed=st.integers(0, 2**32 - 1), share=st.floats(0.0, 1.0))
def test_row_interpolation_shortcut_equals_general_interpolation(n, seed, share):
    from cevm.ingest.cleaning.speed import _interp_rows
    from cevm.ingest.consumption import interp_limited

    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.choice([0.5, 1.0, 3.0, 20.0], n))  # strictly increasing, some gaps
    v = rng.normal(size=n)
    ok = rng.random(n) < share
    got = _interp_rows(t, ok, v, 15.0)
    want = interp_limited(t, t[ok], v[ok], 15.0)  # the general path: binary search
    np.testing.assert_array_equal(got, want)
    assert np.isnan(_interp_rows(t, None, None, 15.0)).all()


# ------------------------------------------------------- stops: charging, holes driven through
# (acceptance: a charge at a terminus inside a trip made its measured energy the battery's net;
# a 4-min hole in the log between two standstill readings, with the GPS 1.2 km further on, was
# taken as a stop and the driving in it lost without a word)

POWER = [Src("battery_power_w", "rate", "energy_j", 0.0, 0)]


def bus_with_a_stop(stop_power_w, stop_s=300, soc=None):
    """Drive 600 s at 10 m/s drawing 20 kW, stand ``stop_s`` at ``stop_power_w``, drive
    600 s more at 20 kW; 650 V, current positive = discharge."""
    tau = np.arange(0.0, 1200.0 + stop_s + 1)
    stopped = (tau >= 600) & (tau < 600 + stop_s)
    v = np.where(stopped, 0.0, 10.0)
    p_w = np.where(stopped, stop_power_w, 20e3)
    cols = dict(wheel_speed_mps=v, battery_voltage_v=np.full(tau.size, 650.0), battery_current_a=p_w / 650.0)
    if soc is not None:
        cols["soc_pct"] = soc(tau)
    return make(tau, **cols)


def test_a_charge_at_a_stop_ends_the_trip_and_the_trips_measure_their_driving():
    res = clean_log(bus_with_a_stop(-100e3), POWER)
    assert [t.quality["split_before"] for t in res.trips][1:] == ["charging"]
    a, b = res.trips
    # the rate is integrated over each trip's own span: 20 kW x its duration, charge excluded
    assert a.measured.value == pytest.approx(20e3 * a.duration_s, rel=0.01)
    assert b.measured.value == pytest.approx(20e3 * b.duration_s, rel=0.01)
    assert a.duration_s == 600.0 and b.start_utc_s == T0 + 899.0
    (note,) = res.quality["stop_notes"]
    assert note["kind"] == "charging"
    assert note["kwh"] == pytest.approx(100e3 * 300 / 3.6e6, rel=0.01)  # 8.33 kWh taken in


def test_a_stop_drawing_auxiliaries_or_charging_too_briefly_stays_in_the_trip():
    only(clean_log(bus_with_a_stop(+5e3), POWER))  # 5 kW of auxiliaries at a stop
    only(clean_log(bus_with_a_stop(-100e3, stop_s=40), POWER))  # 40 s < charge_min_s
    only(clean_log(bus_with_a_stop(-1e3), POWER))  # within a current sensor's offset


def test_a_state_of_charge_rising_at_a_stop_is_a_charge_without_current_readings():
    def soc(tau):  # 80 % falling 1 point per 300 s while driving; +5 points during the stop
        return np.where(tau < 600, 80 - tau / 300,
                        np.where(tau < 900, 78 + 5 * (tau - 600) / 300, 83 - (tau - 900) / 300))

    frame = bus_with_a_stop(-100e3, soc=soc).drop(columns=["battery_voltage_v", "battery_current_a"])
    res = clean_log(frame)
    assert [t.quality["split_before"] for t in res.trips][1:] == ["charging"]
    assert res.quality["stop_notes"][0]["soc_rise_pct"] == pytest.approx(5.0, abs=0.1)


def test_a_hole_between_standstill_rows_that_the_gps_crossed_is_driving_not_a_stop():
    tau = np.arange(0.0, 1201.0)
    dist = np.where(tau < 600, 10.0 * tau, 6000.0 + 1200.0 + 10.0 * (tau - 840))  # 1.2 km in the hole
    v = np.where((tau == 599) | (tau == 840), 0.0, 10.0)  # the readings at the hole's ends: standing
    keep = (tau < 600) | (tau >= 840)  # 240 s without rows (< gap_s)
    lat, lon = north(dist)
    res = clean_log(make(tau[keep], wheel_speed_mps=v[keep], lat_deg=lat[keep], lon_deg=lon[keep]))
    assert [t.quality["split_before"] for t in res.trips][1:] == ["speed_gap"]
    (note,) = res.quality["stop_notes"]
    assert note["displacement_m"] == pytest.approx(GEOD.inv(lon[599], lat[599], lon[840], lat[840])[2], rel=1e-6)
    # the same hole with the GPS where it was: a stop, filled with 0
    lat2, lon2 = north(np.where(tau < 600, 10.0 * tau, 5990.0 + 10.0 * (tau - 840)))
    only(clean_log(make(tau[keep], wheel_speed_mps=v[keep], lat_deg=lat2[keep], lon_deg=lon2[keep])))


def test_an_energy_counter_falling_at_a_stop_is_a_charge_without_current_readings():
    # 20 kW while driving, 100 kW charged in the 300 s stop: the counter (net) falls 8.33 kWh
    tau = np.arange(0.0, 1501.0)
    stopped = (tau >= 600) & (tau < 900)
    p_w = np.where(stopped, -100e3, 20e3)
    counter = 50e6 + np.concatenate(([0.0], np.cumsum(p_w[:-1])))
    res = clean_log(make(tau, wheel_speed_mps=np.where(stopped, 0.0, 10.0), total_energy_j=counter),
                    [Src("total_energy_j", "counter", "energy_j", 0.0, 0)])
    assert [t.quality["split_before"] for t in res.trips][1:] == ["charging"]
    a, b = res.trips
    # a: rows 0-600, 600 s at 20 kW; b: rows 899-1500, its first second the stop's last (charging)
    assert a.measured.value == pytest.approx(20e3 * 600.0) and b.measured.value == pytest.approx(20e3 * 600.0 - 100e3)
    assert res.quality["stop_notes"][0]["kwh"] == pytest.approx(100e3 * 299 / 3.6e6, rel=0.01)
