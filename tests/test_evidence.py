"""Per-trip evidence (cevm.ingest.evidence): ambient temperature and standstill
measurements against analytic cases, through the cleaning stage and on their own."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cevm.core.trip import TRIP_EVIDENCE_FIELDS
from cevm.ingest.cleaning import clean_log
from cevm.ingest.evidence import EvidenceParams, trip_evidence

T0 = 1_600_000_000.0


def _frame(tau, v, **cols) -> pd.DataFrame:
    data = {"time_s": T0 + np.asarray(tau, float), "source_line": np.arange(2, len(tau) + 2),
            "wheel_speed_mps": np.asarray(v, float)}
    data.update({k: np.asarray(a, float) for k, a in cols.items()})
    return pd.DataFrame(data)


def _evidence(frame: pd.DataFrame, params: EvidenceParams = EvidenceParams()):
    (ct,) = clean_log(frame).trips
    return trip_evidence(ct.start_utc_s + ct.time_s, ct.speed_mps, ct.rows_t_s, ct.rows, 0.5, params)


def _drive_stop_drive(stop_s: int = 120):
    """300 s at 10 m/s, a stop of ``stop_s`` s, 300 s at 10 m/s (1 Hz rows); speed and a
    mask of the standstill rows."""
    v = np.concatenate([np.full(300, 10.0), np.zeros(stop_s + 1), np.full(300, 10.0)])
    tau = np.arange(v.size, dtype=float)
    return tau, v, v == 0


def test_ambient_mean_min_max_of_a_linear_ramp():
    """Readings every 10 s of a ramp from 10 to 20 degC over the trip: the time-weighted
    mean is 15, the extremes 10 and 20, whatever the sampling."""
    tau = np.arange(0.0, 601.0)
    temp = np.where(tau % 10 == 0, 10.0 + tau / 60.0, np.nan)
    fields, q = _evidence(_frame(tau, np.full(tau.size, 10.0), ambient_temp_c=temp))
    assert fields["ambient_temp_c"] == pytest.approx(15.0, abs=1e-9)
    assert fields["ambient_temp_min_c"] == pytest.approx(10.0)
    assert fields["ambient_temp_max_c"] == pytest.approx(20.0)
    assert q["ambient_temp"]["readings"] == 61


def test_ambient_mean_is_time_weighted_not_per_reading():
    """Dense readings at 0 degC during the first 100 s, sparse ones at 30 degC after:
    the mean weights time (100 s at 0, a 10 s ramp, 490 s at 30), not readings."""
    tau = np.arange(0.0, 601.0)
    temp = np.where(tau <= 100, 0.0, np.where(tau % 30 == 0, 30.0, np.nan))
    temp[110] = 30.0
    fields, _ = _evidence(_frame(tau, np.full(tau.size, 10.0), ambient_temp_c=temp))
    assert fields["ambient_temp_c"] == pytest.approx((0 * 100 + 15 * 10 + 30 * 490) / 600.0, abs=1e-9)


def test_ambient_not_available_codes_are_rejected_and_counted():
    tau = np.arange(0.0, 601.0)
    temp = np.full(tau.size, 12.5)
    temp[100:110] = 1774.96875  # FMS 0xFFFF x 0.03125 - 273: "not available"
    temp[200] = -273.0
    fields, q = _evidence(_frame(tau, np.full(tau.size, 10.0), ambient_temp_c=temp))
    assert fields["ambient_temp_c"] == pytest.approx(12.5)
    assert fields["ambient_temp_max_c"] == pytest.approx(12.5)
    assert q["ambient_temp"]["rejected"] == 11


def test_ambient_none_without_column_or_when_held_too_long():
    tau = np.arange(0.0, 7201.0)
    v = np.full(tau.size, 10.0)
    fields, q = _evidence(_frame(tau, v))
    assert fields["ambient_temp_c"] is None and "no ambient_temp_c" in q["ambient_temp"]["why_none"]
    early = np.where(tau < 60, 8.0, np.nan)  # one minute of readings in a two-hour trip
    fields, q = _evidence(_frame(tau, v, ambient_temp_c=early))
    assert fields["ambient_temp_c"] is None and fields["ambient_temp_min_c"] is None
    assert q["ambient_temp"]["max_hold_s"] == pytest.approx(7200 - 59)
    gap = np.where((tau < 2000) | (tau > 5700), 8.0, np.nan)  # 62 min without a reading
    fields, q = _evidence(_frame(tau, v, ambient_temp_c=gap))
    assert fields["ambient_temp_c"] is None and q["ambient_temp"]["max_hold_s"] == pytest.approx(1851)
    fine = np.where((tau < 2000) | (tau > 5000), 8.0, np.nan)  # 50 min: each side holds 25
    fields, _ = _evidence(_frame(tau, v, ambient_temp_c=fine))
    assert fields["ambient_temp_c"] == pytest.approx(8.0)


def test_standstill_time_power_and_fuel():
    """A 120 s stop: standstill 120 s; battery 400 V x 10 A at rest (4 kW) and 100 A
    driving; flow meter 0.5 ml/s at rest; the means are those at rest only."""
    tau, v, rest = _drive_stop_drive(120)
    volt = np.full(v.size, 400.0)
    amp = np.where(rest, 10.0, 100.0)
    flow = np.where(rest, 5e-4, 5e-3)
    ecu = np.where(rest, 7e-4, 6e-3)
    fields, q = _evidence(_frame(tau, v, battery_voltage_v=volt, battery_current_a=amp,
                                 flowmeter_fuel_lps=flow, fuel_rate_lps=ecu))
    assert fields["standstill_s"] == pytest.approx(120.0)
    assert fields["standstill_power_w"] == pytest.approx(4000.0)
    assert fields["standstill_fuel_lps"] == pytest.approx(5e-4)
    assert q["standstill_fuel"]["source"] == "flowmeter_fuel_lps"


def test_standstill_fuel_falls_back_to_the_ecu_rate():
    tau, v, rest = _drive_stop_drive(120)
    flow = np.where(rest, np.nan, 5e-3)  # the flow meter sends nothing while idling
    ecu = np.where(rest, 7e-4, 6e-3)
    fields, q = _evidence(_frame(tau, v, flowmeter_fuel_lps=flow, fuel_rate_lps=ecu))
    assert fields["standstill_fuel_lps"] == pytest.approx(7e-4)
    assert q["standstill_fuel"]["source"] == "fuel_rate_lps"
    fields, q = _evidence(_frame(tau, v, flowmeter_fuel_lps=flow))
    assert fields["standstill_fuel_lps"] is None and "standstill time" in q["standstill_fuel"]["why_none"]


def test_no_standstill_or_no_columns_give_none():
    tau = np.arange(0.0, 601.0)
    v = np.full(tau.size, 10.0)
    fields, q = _evidence(_frame(tau, v, battery_voltage_v=np.full(tau.size, 400.0),
                                 battery_current_a=np.full(tau.size, 50.0)))
    assert fields["standstill_s"] == 0.0
    assert fields["standstill_power_w"] is None and q["standstill_power"]["why_none"] == "no standstill in the trip"
    assert set(fields) == set(TRIP_EVIDENCE_FIELDS)
    tau, v, _ = _drive_stop_drive(60)
    fields, q = _evidence(_frame(tau, v))
    assert fields["standstill_s"] == pytest.approx(60.0)
    assert fields["standstill_power_w"] is None and fields["standstill_fuel_lps"] is None


def test_standstill_excludes_ignition_off():
    """Given an ignition column, standstill counts only while it is on (an engine-off
    stop inside a span handed over is not idling)."""
    t = T0 + np.arange(0.0, 601.0)
    v = np.where((t - T0 >= 200) & (t - T0 <= 400), 0.0, 10.0)
    ign = np.where((t - T0 > 300) & (t - T0 < 350), 0.0, 1.0)
    ign[::2] = np.nan  # every other row carries no ignition value: the last one holds
    fields, q = trip_evidence(t, v, t, {"ignition": ign}, 0.5)
    # standstill steps 200..400 (200 s), minus the 51 with an end off: samples 301..350
    # (350 carries no value and holds the reading of 349)
    assert fields["standstill_s"] == pytest.approx(200.0 - 51.0)
    assert q["standstill"]["ignition"] == "from the ignition column"


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10_000), st.integers(3, 200))
def test_ambient_mean_lies_between_its_extremes(seed, n):
    rng = np.random.default_rng(seed)
    t = T0 + np.cumsum(rng.uniform(0.5, 20.0, n))
    temp = rng.uniform(-30, 40, n)
    temp[rng.random(n) < 0.3] = np.nan
    if not np.isfinite(temp).any():
        temp[0] = 5.0
    fields, _ = trip_evidence(t, np.full(n, 10.0), t, {"ambient_temp_c": temp}, 0.5,
                              EvidenceParams(ambient_max_hold_s=1e9))
    lo, hi = fields["ambient_temp_min_c"], fields["ambient_temp_max_c"]
    assert lo - 1e-9 <= fields["ambient_temp_c"] <= hi + 1e-9
    ok = np.isfinite(temp)
    assert lo >= temp[ok].min() - 1e-9 and hi <= temp[ok].max() + 1e-9


def _write_srf(path, tau, v_mps, **cols) -> None:
    """A small srf export (LOGGERS.md): '# key=value' metadata, ISO 8601 UTC times."""
    times = pd.to_datetime(T0 + np.asarray(tau), unit="s", utc=True).strftime("%Y-%m-%dT%H:%M:%S.000Z")
    df = pd.DataFrame({"timestamp_utc": times, "fms_wheel_speed_kmh": np.asarray(v_mps) * 3.6, **cols})
    with open(path, "w") as f:
        f.write("# vehicle_id=EV-1\n")
        df.to_csv(f, index=False)


def test_process_file_stores_the_standstill_evidence(tmp_path):
    """Through the per-file task: the trip record carries standstill time and battery
    power, and its quality says where they came from."""
    from cevm.ingest.task import IngestOptions, process_file

    tau, v, rest = _drive_stop_drive(90)
    _write_srf(tmp_path / "ev.csv", tau, v, fms_battery_voltage_v=np.full(v.size, 650.0),
               fms_battery_current_a=np.where(rest, 4.0, 80.0))
    out = process_file(tmp_path / "ev.csv", IngestOptions())
    assert out.ok, out.error
    (rec,) = out.trips
    assert rec.standstill_s == pytest.approx(90.0)
    assert rec.standstill_power_w == pytest.approx(650.0 * 4.0)
    assert rec.standstill_fuel_lps is None and rec.ambient_temp_c is None
    assert rec.quality["evidence"]["standstill_power"]["coverage"] == pytest.approx(1.0)
