"""cevm.ingest.measured and cevm.ingest.evidence run over many trips at once: a trip
measured among many (overlapping windows, trips of no duration, empty windows) is
measured bit for bit as when it is alone. The estimators' values themselves are checked
against hand computations in tests/test_consumption.py and tests/test_evidence.py."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from cevm.ingest.consumption import ConsumptionParams
from cevm.ingest.measured import measure_trip, measure_trips


@dataclass(frozen=True)
class Src:
    column: str
    kind: str
    quantity: str
    resolution: float
    priority: int
    capacity_j: float | None = None
    modulus: float | None = None
    accuracy_pct: float | None = None


SOURCES = [
    Src("total_fuel_l", "counter", "fuel_l", 0.5, 2, modulus=1000.0),
    Src("fuel_rate_lps", "rate", "fuel_l", 0.0001, 1),
    Src("flowmeter_fuel_lps", "rate", "fuel_l", 0.0, 0, accuracy_pct=1.0),
    Src("battery_power_w", "rate", "energy_j", 0.0, 1),
    Src("total_energy_j", "counter", "energy_j", 3.6e5, 2),
    Src("soc_pct", "soc", "energy_j", 0.5, 3, capacity_j=2.2e7),
    Src("no_such_column", "rate", "fuel_l", 0.0, 4),
]


def _same(a, b) -> bool:
    if isinstance(a, float) and isinstance(b, float):
        return (math.isnan(a) and math.isnan(b)) or (a == b and math.copysign(1, a) == math.copysign(1, b))
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    return a == b


def _log(seed: int, n: int):
    """A log of ``n`` rows (1-20 s apart, with gaps) of every source column, with NaN
    ticks, wraps, resets, junk and missing readings."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.choice([1.0, 1.0, 2.0, 5.0, 17.0, 40.0], n)) + 1.6e9
    cols = {
        "total_fuel_l": np.floor((990.0 + np.cumsum(rng.uniform(0, 0.02, n))) / 0.5) * 0.5 % 1000.0,
        "fuel_rate_lps": rng.uniform(-0.001, 0.03, n),
        "flowmeter_fuel_lps": rng.uniform(0.0, 0.03, n),
        "battery_voltage_v": rng.uniform(500, 700, n),
        "battery_current_a": rng.normal(50, 80, n),
        "total_energy_j": np.floor(np.cumsum(rng.uniform(0, 2e5, n)) / 3.6e5) * 3.6e5,
        "soc_pct": 90 - np.cumsum(rng.uniform(0, 0.01, n)),
    }
    for name, a in cols.items():
        a[rng.random(n) < rng.choice([0.0, 0.2, 0.7])] = np.nan
        if name == "total_energy_j" and n > 10:
            a[n // 2:] -= 1e9 * (seed % 2)  # a reset
    cols["soc_pct"][rng.integers(0, n, 2)] = 150.0  # junk
    cols["battery_voltage_v"] = cols["battery_voltage_v"].astype(np.float32)  # as the reader may keep it
    return t, cols


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(2, 400), st.integers(1, 6))
def test_a_trip_among_many_is_measured_as_alone(seed, n, n_trips):
    t, cols = _log(seed, n)
    rng = np.random.default_rng(seed + 1)
    edges = np.sort(rng.uniform(t[0] - 30, t[-1] + 30, 2 * n_trips)).reshape(-1, 2)  # overlapping windows too
    t0, t1 = edges[:, 0], edges[:, 1]
    t1[0] = t0[0]  # a trip of no duration
    params = ConsumptionParams(max_gap_s=float(rng.choice([15.0, 3.0])))
    got = measure_trips(t, cols, SOURCES, t0, t1, params)
    for (m, q), a, b in zip(got, t0, t1, strict=True):
        want_m, want_q = measure_trip(t, cols, SOURCES, float(a), float(b), params)
        assert (m is None and want_m is None) or _same(m.__dict__, want_m.__dict__)
        assert _same(q, want_q), (q, want_q)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(3, 300), st.integers(1, 5), st.booleans())
def test_a_trips_evidence_among_many_is_as_alone(seed, n, n_trips, with_ignition):
    """cevm.ingest.evidence.batch_evidence of many trips against that of each trip alone
    (trip_evidence, with only its window of rows): ambient temperature with junk and far
    readings, standstill with and without ignition readings, battery power and fuel rates
    at standstill."""
    from cevm.ingest.evidence import EvidenceParams, batch_evidence, trip_evidence
    from cevm.ingest.segments import bounds_of

    t, cols = _log(seed, n)
    rng = np.random.default_rng(seed + 2)
    cols["ambient_temp_c"] = np.where(rng.random(n) < 0.3, rng.uniform(-5, 25, n), np.nan)
    cols["ambient_temp_c"][rng.integers(0, n, 2)] = 1775.0
    if with_ignition:
        cols["ignition"] = np.where(rng.random(n) < 0.2, rng.integers(0, 2, n).astype(float), np.nan)
    rows = {c: cols[c] for c in ("ambient_temp_c", "battery_voltage_v", "battery_current_a", "flowmeter_fuel_lps",
                                 "fuel_rate_lps", "ignition") if c in cols}
    # trips: grids of whole seconds inside the log, in time order
    k = min(2 * n_trips, int(t[-1] - t[0])) // 2 * 2
    cuts = np.sort(rng.choice(np.arange(int(t[0]) + 1, int(t[-1]) + 1), k, replace=False))
    spans = [(float(a), float(b)) for a, b in cuts.reshape(-1, 2) if b - a >= 1]
    if not spans:
        return
    grids = [np.arange(a, b + 1.0) for a, b in spans]
    speeds = [np.where(rng.random(g.size) < 0.4, 0.0, rng.uniform(0, 20, g.size)) for g in grids]
    w = 15.0
    window = np.array([(np.searchsorted(t, g[0] - w, "left"), np.searchsorted(t, g[-1] + w, "right")) for g in grids])
    params = EvidenceParams()
    got = batch_evidence(np.concatenate(grids), np.concatenate(speeds), bounds_of([g.size for g in grids]), t, rows,
                         window, 0.5, params)
    for (f, q), g, v, (a, b) in zip(got, grids, speeds, window, strict=True):
        want_f, want_q = trip_evidence(g, v, t[a:b], {c: x[a:b].astype(np.float64) for c, x in rows.items()}, 0.5,
                                       params)
        assert _same(f, want_f) and list(f) == list(want_f), (f, want_f)
        assert _same(q, want_q), (q, want_q)
