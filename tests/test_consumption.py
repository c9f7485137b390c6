"""Tests of cevm.ingest.consumption: rates, counters, SoC, uncertainty and source choice.

Expected values are hand computations written out in each test.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cevm.ingest.consumption import ConsumptionParams
from cevm.ingest.measured import (
    counter_increases,
    estimate_sources,
    integrate_rates,
    measure_trip,
    soc_energies,
)


# one trip's call of each estimator (they run over many trips at once)
def integrate_rate(ts, rate, t0, t1, **kw):
    return integrate_rates(ts, rate, np.array([0, ts.size]), np.array([t0]), np.array([t1]), **kw)[0]


def counter_increase(ts, counter, t0, t1, **kw):
    return counter_increases(ts, counter, np.array([0, ts.size]), np.array([t0]), np.array([t1]), **kw)[0]


def soc_energy(ts, soc_pct, t0, t1, **kw):
    return soc_energies(ts, soc_pct, np.array([0, ts.size]), np.array([t0]), np.array([t1]), **kw)[0]


def estimate_source(time_s, columns, source, t0, t1, params=ConsumptionParams()):
    return estimate_sources(time_s, columns, source, np.array([t0]), np.array([t1]), params)[0]


@dataclass(frozen=True)
class Src:
    """Stand-in for cevm.ingest.reading.EnergySource (same attributes)."""

    column: str
    kind: str
    quantity: str
    resolution: float
    priority: int
    capacity_j: float | None = None


@dataclass(frozen=True)
class WrappingSrc(Src):
    modulus: float | None = None


T = np.arange(0.0, 1001.0)  # 0..1000 s at 1 Hz


# ----------------------------------------------------------------------------- rates


def test_constant_rate_over_known_time_is_exact():
    rate = np.full(T.size, 0.002)  # l/s
    raw = integrate_rate(T, rate, 0.0, 1000.0)
    assert raw.value == pytest.approx(2.0, rel=1e-12)
    assert raw.gap_share == 0.0
    assert raw.uncertainty == 0.0  # no resolution, no gaps
    # a span that does not start or end on a sample: still rate x time
    raw = integrate_rate(T, rate, 10.5, 990.25)
    assert raw.value == pytest.approx(0.002 * 979.75, rel=1e-12)


def test_rate_gap_is_bridged_and_reported():
    keep = (T <= 100) | (T >= 400)  # a 300 s gap
    t, rate = T[keep], np.full(keep.sum(), 0.002)
    raw = integrate_rate(t, rate, 0.0, 1000.0, max_gap_s=15.0)
    assert raw.value == pytest.approx(2.0, rel=1e-12)  # constant: linear bridge exact
    assert raw.gap_share == pytest.approx(300.0 / 1000.0)
    # via estimate_source: 30 % gaps > 10 % allowed -> not valid
    est = estimate_source(t, {"fuel_rate_lps": rate}, Src("fuel_rate_lps", "rate", "fuel_l", 0.0, 1),
                          0.0, 1000.0)
    assert not est.valid and "gap share" in est.reason


def test_rate_gap_uncertainty_uses_spread_of_rate():
    # rate alternates 1 and 3 (std 1) except a 100 s gap: sigma = 1 * 100
    t = np.concatenate((np.arange(0.0, 201.0), np.arange(300.0, 501.0)))
    rate = np.where(np.arange(t.size) % 2 == 0, 1.0, 3.0)
    raw = integrate_rate(t, rate, 0.0, 500.0, max_gap_s=15.0)
    assert raw.gap_share == pytest.approx(100.0 / 500.0)
    vals = np.interp(np.concatenate(([0.0], t[(t > 0) & (t < 500)], [500.0])), t, rate)
    assert raw.uncertainty == pytest.approx(np.std(vals) * 100.0, rel=1e-12)


def test_rate_quantisation_noise_formula():
    # resolution q [l/s]; trapezoid weights on a 1 s grid: 0.5 at the ends, 1 inside
    q = 0.01
    t = np.arange(0.0, 101.0)
    raw = integrate_rate(t, np.full(t.size, 0.05), 0.0, 100.0, resolution=q)
    sum_w2 = 2 * 0.5**2 + 99 * 1.0**2
    assert raw.uncertainty == pytest.approx(q / math.sqrt(12) * math.sqrt(sum_w2), rel=1e-12)


def test_battery_power_v_times_i_hand_computed():
    # current every 1 s: +50 A up to t=100, -20 A (regeneration) from t=101
    # voltage only every 2 s, constant 400 V (interpolated at the current's times)
    t = np.arange(0.0, 201.0)
    current = np.where(t <= 100, 50.0, -20.0)
    voltage = np.where(t % 2 == 0, 400.0, np.nan)
    # integral of current: 50*100 + (50-20)/2*1 - 20*99 = 5000 + 15 - 1980 = 3035 A s
    expected_j = 400.0 * 3035.0
    cols = {"battery_voltage_v": voltage, "battery_current_a": current}
    for column in ("battery_power_w", "battery_voltage_v*battery_current_a"):
        est = estimate_source(t, cols, Src(column, "rate", "energy_j", 0.0, 1), 0.0, 200.0)
        assert est.valid, est.reason
        assert est.value == pytest.approx(expected_j, rel=1e-12)
        assert est.resolution == 0.0


def test_negative_fuel_rate_rejected():
    rate = np.full(T.size, 0.002)
    rate[500] = -5.0  # junk
    est = estimate_source(T, {"fuel_rate_lps": rate}, Src("fuel_rate_lps", "rate", "fuel_l", 0.0, 1),
                          0.0, 1000.0)
    assert est.counts["rate_values_rejected"] == 1
    assert est.value == pytest.approx(2.0, rel=1e-12)


@settings(max_examples=30, deadline=None)
@given(
    a=st.floats(0, 300), b=st.floats(300, 700), c=st.floats(700, 1000),
    seed=st.integers(0, 2**32 - 1),
)
def test_rate_integral_is_additive(a, b, c, seed):
    rate = np.random.default_rng(seed).uniform(0, 0.01, T.size)
    whole = integrate_rate(T, rate, a, c).value
    parts = integrate_rate(T, rate, a, b).value + integrate_rate(T, rate, b, c).value
    assert whole == pytest.approx(parts, rel=1e-9, abs=1e-12)


# -------------------------------------------------------------------------- counters


def test_counter_quantisation_uncertainty_is_q_over_sqrt6():
    t = np.arange(0.0, 1001.0, 10.0)
    c = 1000.0 + np.floor(t * 0.003 / 0.5) * 0.5  # 0.5 l counter, 3 l over the trip
    src = Src("total_fuel_l", "counter", "fuel_l", 0.5, 1)
    m, q = measure_trip(t, {"total_fuel_l": c}, [src], 0.0, 1000.0)
    assert m.value == pytest.approx(3.0)
    assert m.resolution == 0.5
    # quantisation 0.5 / sqrt(6) = 0.204 l (7 %); with the counter kind's default
    # systematic 2 % of 3 l = 0.06 l in quadrature
    assert q["sources"][0]["random_uncertainty"] == pytest.approx(0.5 / math.sqrt(6), rel=1e-12)
    assert q["sources"][0]["systematic_uncertainty"] == pytest.approx(0.06, rel=1e-12)
    assert m.uncertainty == pytest.approx(math.sqrt(0.5**2 / 6 + 0.06**2), rel=1e-12)
    assert q["source"] == "total_fuel_l"


def test_counter_wrap_at_known_modulus_is_exact():
    k = np.arange(41)
    t = 10.0 * k
    c = (990.0 + 0.5 * k) % 1000.0  # 990 ... 999.5, 0, 0.5 ... 10
    src = WrappingSrc("total_fuel_l", "counter", "fuel_l", 0.5, 1, modulus=1000.0)
    est = estimate_source(t, {"total_fuel_l": c}, src, 0.0, 400.0)
    assert est.valid
    assert est.value == pytest.approx(20.0)  # 41 readings, 40 steps of 0.5 l
    assert est.counts["counter_wraps"] == 1
    assert est.counts["counter_resets"] == 0


def test_counter_reset_continues_from_new_base():
    t = 10.0 * np.arange(18)
    c = np.concatenate((100.0 + 0.5 * np.arange(11), 0.5 * np.arange(7)))
    # 100 .. 105 (+5 l), reset to 0, 0 .. 3 (+3 l): 8 l; the reset step itself counts 0
    src = Src("total_fuel_l", "counter", "fuel_l", 0.5, 1)
    est = estimate_source(t, {"total_fuel_l": c}, src, 0.0, 170.0)
    assert est.value == pytest.approx(8.0)
    assert est.counts["counter_resets"] == 1
    # the lost step adds the mean rate x its duration to the uncertainty
    mean_rate = 8.0 / 170.0
    expected = math.sqrt(0.5**2 / 6 + (mean_rate * 10.0) ** 2)
    assert est.random_uncertainty == pytest.approx(expected, rel=1e-12)
    assert est.uncertainty == pytest.approx(math.hypot(expected, 0.02 * 8.0), rel=1e-12)  # + 2 % of 8 l


def test_counter_wrap_without_modulus_counts_as_reset():
    k = np.arange(41)
    c = (990.0 + 0.5 * k) % 1000.0
    raw = counter_increase(10.0 * k, c, 0.0, 400.0, resolution=0.5, max_rate=0.1)
    assert raw.counts["counter_resets"] == 1
    assert raw.value == pytest.approx(19.5)  # the wrap step's 0.5 l is lost


def test_counter_glitch_is_a_jump():
    t = 10.0 * np.arange(21)
    c = 500.0 + 0.5 * np.arange(21)
    c[10] = 1.0e6  # a glitch: up and down again
    raw = counter_increase(t, c, 0.0, 200.0, resolution=0.5, max_rate=0.1)
    assert raw.counts["counter_jumps"] == 2
    assert raw.value == pytest.approx(10.0 - 1.0)  # the two steps around the glitch lost


def test_energy_counter_runs_backwards_during_regeneration():
    t = np.arange(0.0, 11.0)
    c = np.array([0, 10, 20, 30, 25, 20, 30, 40, 50, 60, 70], float) * 1e3  # J
    src = Src("total_energy_j", "counter", "energy_j", 0.0, 1)
    est = estimate_source(t, {"total_energy_j": c}, src, 0.0, 10.0)
    assert est.value == pytest.approx(70e3)
    assert est.counts["counter_resets"] == 0 and est.counts["counter_jumps"] == 0


def test_counter_coverage_too_low_is_invalid():
    t = np.arange(0.0, 1001.0)
    c = np.where((t > 250) & (t < 750), t * 0.001, np.nan)
    est = estimate_source(t, {"total_fuel_l": c}, Src("total_fuel_l", "counter", "fuel_l", 0.0, 1),
                          0.0, 1000.0)
    assert not est.valid and "coverage" in est.reason


@settings(max_examples=30, deadline=None)
@given(st.lists(st.floats(0, 0.05, allow_nan=False), min_size=2, max_size=200))
def test_monotone_counter_value_is_last_minus_first(increments):
    c = 1234.5 + np.cumsum(increments)
    t = np.arange(c.size, dtype=float)
    raw = counter_increase(t, c, 0.0, t[-1], resolution=0.0, max_rate=0.1)
    assert raw.value == pytest.approx(c[-1] - c[0], rel=1e-9, abs=1e-12)


# ------------------------------------------------------------------------------- SoC


def test_soc_times_capacity():
    t = np.arange(0.0, 2001.0)
    soc = np.round(80.0 - 20.0 * t / 2000.0, 2)  # 80.00 % -> 60.00 % in 0.01 % steps
    cap = 10.0 * 3.6e6  # 10 kWh
    src = Src("soc_pct", "soc", "energy_j", 0.01, 1, capacity_j=cap)
    m, _ = measure_trip(t, {"soc_pct": soc}, [src], 0.0, 2000.0)
    assert m.kind == "energy_j"
    assert m.value == pytest.approx(0.20 * cap)  # 7.2 MJ = 2 kWh
    assert m.resolution == pytest.approx(0.0001 * cap)  # 3600 J
    # quantisation of two readings, and the SoC kind's default systematic 5 % of 2 kWh
    assert m.uncertainty == pytest.approx(math.hypot(0.0001 * cap / math.sqrt(6), 0.05 * 0.20 * cap), rel=1e-9)


def test_soc_uses_first_and_last_valid_readings():
    t = np.arange(0.0, 101.0)
    soc = np.full(t.size, np.nan)
    soc[[2, 50, 98]] = [70.0, 69.0, 68.5]
    raw = soc_energy(t, soc, 0.0, 100.0, resolution_pct=0.01, capacity_j=1e6)
    assert raw.value == pytest.approx(0.015 * 1e6)
    assert raw.coverage == pytest.approx(0.96)


def test_soc_without_capacity_is_invalid():
    t = np.arange(0.0, 11.0)
    est = estimate_source(t, {"soc_pct": 50 - t}, Src("soc_pct", "soc", "energy_j", 0.01, 1), 0.0, 10.0)
    assert not est.valid and "capacity" in est.reason


def test_every_trip_of_many_says_its_soc_wants_a_capacity():
    # eight short trips at once (the batch of short trips once took another code path,
    # which gave the generic reason): each says what its readings lack; one without
    # readings (trip 7, past the log's end) does not
    from cevm.ingest.measured import measure_trips

    t = np.arange(0.0, 81.0)
    t0 = np.array([0.0, 10, 20, 30, 40, 50, 60, 200])
    got = measure_trips(t, {"soc_pct": 90 - 0.1 * t}, [Src("soc_pct", "soc", "energy_j", 0.01, 1)], t0, t0 + 9.0)
    for m, q in got[:7]:
        assert m is None and len(q["warnings"]) == 1 and "capacity" in q["warnings"][0]
        assert q["sources"][0]["reason"] == "state of charge logged, but no capacity_j to turn it into energy"
    assert got[7][0] is None and got[7][1]["warnings"] == []


def test_a_logged_soc_that_cannot_measure_for_want_of_a_capacity_is_said():
    # acceptance: an e-bus logging only its state of charge, under a profile whose soc
    # entry has no capacity (the shipped srf's), got no measured energy without a word
    t = np.arange(0.0, 11.0)
    m, q = measure_trip(t, {"soc_pct": 50 - t}, [Src("soc_pct", "soc", "energy_j", 0.01, 1)], 0.0, 10.0)
    assert m is None and len(q["warnings"]) == 1 and "capacity" in q["warnings"][0]
    # with its capacity: measured, 10 points of 100 kWh = 10 kWh, and nothing to say
    m, q = measure_trip(t, {"soc_pct": 50 - t}, [Src("soc_pct", "soc", "energy_j", 0.01, 1, capacity_j=3.6e8)],
                        0.0, 10.0)
    assert m.value == pytest.approx(3.6e7) and q["warnings"] == []
    # no readings at all: nothing to say either (a column the log does not hold)
    m, q = measure_trip(t, {"soc_pct": np.full(t.size, np.nan)}, [Src("soc_pct", "soc", "energy_j", 0.01, 1)],
                        0.0, 10.0)
    assert m is None and q["warnings"] == []


# --------------------------------------------------------------------- source choice


def _three_fuel_sources():
    t = np.arange(0.0, 1001.0)
    cols = {
        "flowmeter_fuel_lps": np.full(t.size, 0.002),  # 2.00 l
        "fuel_rate_lps": np.full(t.size, 0.00206),  # 2.06 l: +3.0 %
        "total_fuel_l": 100.0 + np.floor(t * 0.0019 / 0.5) * 0.5,  # 1.5 l: -25.0 %
    }
    sources = [
        Src("total_fuel_l", "counter", "fuel_l", 0.5, 2),
        Src("fuel_rate_lps", "rate", "fuel_l", 0.0, 1),
        Src("flowmeter_fuel_lps", "rate", "fuel_l", 0.0, 0),
    ]
    return t, cols, sources


def test_most_trusted_valid_source_is_chosen_and_others_cross_checked():
    t, cols, sources = _three_fuel_sources()
    m, q = measure_trip(t, cols, sources, 0.0, 1000.0)
    assert m.source == "flowmeter_fuel_lps"
    assert m.value == pytest.approx(2.0)
    # defaults 2 %: flow meter 0.04 l, ECU rate 0.0412 l, counter sqrt(0.5^2/6 + 0.03^2)
    # = 0.2063 l; 0.06 / hypot(0.04, 0.0412) = 1.0 sigma, 0.5 / hypot(0.04, 0.2063) = 2.4
    assert "fuel_rate_lps vs flowmeter_fuel_lps: +3.0 % (1.0 sigma)" in q["cross_checks"]
    assert "total_fuel_l vs flowmeter_fuel_lps: -25.0 % (2.4 sigma)" in q["cross_checks"]
    assert q["warnings"] == []
    assert len(q["sources"]) == 3


def test_invalid_trusted_source_falls_back_to_next():
    t, cols, sources = _three_fuel_sources()
    cols["flowmeter_fuel_lps"] = np.where(t < 500, 0.002, np.nan)  # half the trip only
    m, q = measure_trip(t, cols, sources, 0.0, 1000.0)
    assert m.source == "fuel_rate_lps"
    flow = next(s for s in q["sources"] if s["source"] == "flowmeter_fuel_lps")
    assert flow["valid"] is False and flow["reason"]


@dataclass(frozen=True)
class AccSrc(Src):
    accuracy_pct: float | None = None


def _shipped_srf_sources(*columns):
    """The shipped srf profile's energy sources of ``columns`` (as the reader makes them)."""
    from cevm.ingest.profiles import load_profiles
    from cevm.ingest.reading import EnergySource

    specs = {e.column: e for e in load_profiles()["srf"].energy}
    return [EnergySource(e.column, e.kind, e.quantity, e.resolution, e.priority, e.capacity_j, "", e.modulus,
                         e.accuracy_pct) for e in (specs[c] for c in columns)]


@pytest.mark.parametrize("energy_kwh, duration_s, chosen", [(2.0, 360.0, "battery_power_w"),
                                                            (100.0, 7200.0, "total_energy_j")])
def test_integrated_power_beats_a_coarse_counter_on_a_short_trip_only(energy_kwh, duration_s, chosen):
    """The shipped srf figures: a 0.1 kWh counter (quantisation 0.1 / sqrt(6) = 0.041
    kWh, systematic 1 %) and V x I at 1 Hz (systematic 1.005 %). On 2 kWh: 0.020 kWh
    against hypot(0.041, 0.020) = 0.045: the power. On 100 kWh: 1.005 kWh against
    hypot(0.041, 1.0) = 1.0008: the counter (they cross at 0.041 / sqrt(1.005^2 - 1) %
    = 41 kWh), although the counter is the profile's most trusted (priority 1)."""
    t = np.arange(0.0, duration_s + 1.0)
    power_w = energy_kwh * 3.6e6 / duration_s
    q = 0.1 * 3.6e6
    cols = {
        "total_energy_j": np.floor((12345.0 * 3.6e6 + power_w * t) / q) * q,
        "battery_voltage_v": np.full(t.size, 600.0),
        "battery_current_a": np.full(t.size, power_w / 600.0),
    }
    sources = _shipped_srf_sources("total_energy_j", "battery_power_w")
    m, qual = measure_trip(t, cols, sources, 0.0, duration_s)
    assert m.source == chosen and qual["chosen_by"] == "least uncertainty"
    assert {s["source"] for s in qual["sources"] if s["valid"]} == {"total_energy_j", "battery_power_w"}
    assert qual["warnings"] == []  # the two agree within their uncertainties


def test_equal_accuracies_do_not_favour_the_lower_reading():
    """Two rates of one accuracy differ by 5 %: the more trusted is chosen whichever
    reads less (their uncertainties are compared at one common value)."""
    t = np.arange(0.0, 1001.0)
    sources = [AccSrc("flowmeter_fuel_lps", "rate", "fuel_l", 0.0, 1, accuracy_pct=2.0),
               AccSrc("fuel_rate_lps", "rate", "fuel_l", 0.0, 2, accuracy_pct=2.0)]
    for a, b in ((0.002, 0.0019), (0.0019, 0.002)):
        cols = {"flowmeter_fuel_lps": np.full(t.size, a), "fuel_rate_lps": np.full(t.size, b)}
        m, _ = measure_trip(t, cols, sources, 0.0, 1000.0)
        assert m.source == "flowmeter_fuel_lps"


def test_more_accurate_source_wins_over_priority():
    t = np.arange(0.0, 1001.0)
    sources = [AccSrc("fuel_rate_lps", "rate", "fuel_l", 0.0, 1, accuracy_pct=3.0),
               AccSrc("flowmeter_fuel_lps", "rate", "fuel_l", 0.0, 2, accuracy_pct=1.0)]
    cols = {"flowmeter_fuel_lps": np.full(t.size, 0.002), "fuel_rate_lps": np.full(t.size, 0.00201)}
    m, q = measure_trip(t, cols, sources, 0.0, 1000.0)
    assert m.source == "flowmeter_fuel_lps"
    assert m.uncertainty == pytest.approx(0.01 * 2.0)  # 1 % of 2 l, no random part
    assert q["sources"][1]["accuracy_pct"] == 1.0


def test_disagreement_beyond_the_combined_uncertainty_is_a_warning():
    """1 % sources 10 % apart: 0.2 l / hypot(0.02, 0.022) = 6.7 sigma, a warning; 1 %
    apart: 0.7 sigma, none."""
    t = np.arange(0.0, 1001.0)
    sources = [AccSrc("flowmeter_fuel_lps", "rate", "fuel_l", 0.0, 1, accuracy_pct=1.0),
               AccSrc("fuel_rate_lps", "rate", "fuel_l", 0.0, 2, accuracy_pct=1.0)]
    cols = {"flowmeter_fuel_lps": np.full(t.size, 0.002), "fuel_rate_lps": np.full(t.size, 0.0022)}
    m, q = measure_trip(t, cols, sources, 0.0, 1000.0)
    assert q["cross_checks"] == ["fuel_rate_lps vs flowmeter_fuel_lps: +10.0 % (6.7 sigma)"]
    assert len(q["warnings"]) == 1 and "disagrees" in q["warnings"][0] and "+10.0 %" in q["warnings"][0]
    cols["fuel_rate_lps"] = np.full(t.size, 0.00202)
    _, q = measure_trip(t, cols, sources, 0.0, 1000.0)
    assert q["cross_checks"] == ["fuel_rate_lps vs flowmeter_fuel_lps: +1.0 % (0.7 sigma)"] and q["warnings"] == []


def test_default_accuracy_by_kind():
    from cevm.ingest.consumption import DEFAULT_ACCURACY_PCT, accuracy_pct_of

    assert accuracy_pct_of(Src("soc_pct", "soc", "energy_j", 0.01, 1)) == DEFAULT_ACCURACY_PCT["soc"] == 5.0
    assert accuracy_pct_of(Src("total_fuel_l", "counter", "fuel_l", 0.5, 1)) == 2.0
    assert accuracy_pct_of(AccSrc("total_fuel_l", "counter", "fuel_l", 0.5, 1, accuracy_pct=0.3)) == 0.3


def test_missing_column_and_no_sources():
    t = np.arange(0.0, 11.0)
    m, q = measure_trip(t, {}, [Src("total_fuel_l", "counter", "fuel_l", 0.5, 0)], 0.0, 10.0)
    assert m is None and q["sources"][0]["reason"] == "column not in the log"
    m, q = measure_trip(t, {}, [], 0.0, 10.0)
    assert m is None and q["source"] is None


def test_params_are_used():
    t = np.arange(0.0, 101.0)
    keep = (t <= 40) | (t >= 60)  # 20 s gap = 20 % of the trip
    cols = {"fuel_rate_lps": np.where(keep, 0.001, np.nan)}
    src = [Src("fuel_rate_lps", "rate", "fuel_l", 0.0, 0)]
    assert measure_trip(t, cols, src, 0.0, 100.0)[0] is None
    lenient = ConsumptionParams(max_gap_share=0.25, min_coverage=0.7)
    m, _ = measure_trip(t, cols, src, 0.0, 100.0, lenient)
    assert m.value == pytest.approx(0.1)


@settings(max_examples=60, deadline=None)
@given(n=st.integers(2, 60), seed=st.integers(0, 2**32 - 1), share_v=st.floats(0.0, 1.0),
       share_i=st.floats(0.0, 1.0))
def test_battery_power_samples_equal_a_plain_loop(n, seed, share_v, share_i):
    """Power = V * I at every time where either is logged, each factor interpolated
    over at most max_gap_s between its own samples (plain-loop reference)."""
    from cevm.ingest.measured import window_samples

    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.choice([1.0, 2.0, 30.0], n))
    volt = np.where(rng.random(n) < share_v, rng.uniform(300, 400, n), np.nan)
    amp = np.where(rng.random(n) < share_i, rng.uniform(-50, 200, n), np.nan)
    ts, p, _ = window_samples(t, {"battery_voltage_v": volt, "battery_current_a": amp}, "battery_power_w",
                              np.array([0]), np.array([n]), 15.0)

    def at(tq, x):
        ti, xi = t[np.isfinite(x)], x[np.isfinite(x)]
        for k in range(ti.size):
            if ti[k] == tq:
                return xi[k]
        for k in range(ti.size - 1):
            if ti[k] < tq < ti[k + 1] and ti[k + 1] - ti[k] <= 15.0:
                return xi[k] + (tq - ti[k]) / (ti[k + 1] - ti[k]) * (xi[k + 1] - xi[k])
        return math.nan

    want_t, want_p = [], []
    for k in range(n):
        if np.isfinite(volt[k]) or np.isfinite(amp[k]):
            pk = at(t[k], volt) * at(t[k], amp)
            if math.isfinite(pk):
                want_t.append(t[k])
                want_p.append(pk)
    np.testing.assert_array_equal(ts, want_t)
    np.testing.assert_allclose(p, want_p, rtol=1e-12, atol=1e-9)


def test_disagreeing_sources_are_a_repair_of_the_ingested_file(tmp_path):
    """Through the per-file task: a flow meter and an ECU rate 20 % apart (1 % and 3 %
    declared by the srf profile: 0.3 l / hypot(0.015, 0.054) = 5.4 sigma) are named in
    the file's repairs, and the trip keeps both estimates."""
    import pandas as pd

    from cevm.ingest.task import IngestOptions, process_file

    tau = np.arange(0.0, 601.0)
    times = pd.to_datetime(1.6e9 + tau, unit="s", utc=True).strftime("%Y-%m-%dT%H:%M:%S.000Z")
    df = pd.DataFrame({"timestamp_utc": times, "fms_wheel_speed_kmh": 36.0,
                       "flowmeter_fuel_lph": 9.0, "fms_fuel_rate_lph": 10.8})
    with open(tmp_path / "hgv.csv", "w") as f:
        f.write("# vehicle_id=HGV-9\n")
        df.to_csv(f, index=False)
    out = process_file(tmp_path / "hgv.csv", IngestOptions())
    assert out.ok, out.error
    (rec,) = out.trips
    assert rec.measured.source == "flowmeter_fuel_lps" and rec.measured.value == pytest.approx(1.5)
    assert [s["source"] for s in rec.quality["consumption"]["sources"] if s["valid"]] == [
        "flowmeter_fuel_lps", "fuel_rate_lps"]
    (warning,) = [r for r in out.repairs if "disagrees" in r]
    assert rec.trip_id in warning and "+20.0 % (5.4 sigma)" in warning
