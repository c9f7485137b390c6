"""Tests of the synthetic sample-log generator (cevm_samplegen), on its --small fleet.

Files are read back with plain pandas / rasterio and checked against LOGGERS.md and
against truth.json; reference computations (bilinear interpolation, trapezoid
integrals, number formatting, UK local time) are written plainly here.
"""

from __future__ import annotations

import gzip
import hashlib
import io
import itertools
import json
import math
import subprocess
import sys
from datetime import UTC, datetime, timedelta
from pathlib import Path
from zoneinfo import ZoneInfo

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import cevm_samplegen as sg
from cevm_samplegen import auxiliaries as aux
from cevm_samplegen import csvfmt

SRF_BUS = {
    "timestamp_utc", "gps_lat_deg", "gps_lon_deg", "gps_alt_m", "gps_speed_kmh", "gps_hdop",
    "fms_wheel_speed_kmh", "fms_accel_pedal_pct", "fms_brake_switch", "fms_engine_speed_rpm",
    "fms_engine_torque_pct", "fms_battery_soc_pct", "fms_battery_voltage_v",
    "fms_battery_current_a", "fms_total_energy_used_kwh", "fms_ambient_air_temp_c",
}
SRF_TRUCK_BASE = {
    "timestamp_utc", "gps_lat_deg", "gps_lon_deg", "gps_alt_m", "gps_speed_kmh", "gps_hdop",
    "fms_wheel_speed_kmh", "fms_accel_pedal_pct", "fms_brake_switch", "fms_engine_speed_rpm",
    "fms_engine_torque_pct", "fms_total_fuel_used_l", "fms_fuel_rate_lph", "fms_gross_weight_kg",
    "fms_ambient_air_temp_c",
}
PORTAL = ["Registration", "Date/Time", "Latitude", "Longitude", "Speed (mph)", "Odometer (mi)",
          "Fuel Used (l)", "Ignition", "Event"]


@pytest.fixture(scope="module")
def small(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("small")
    sg.generate_sample_logs(out, small=True)
    return out


@pytest.fixture(scope="module")
def truth(small) -> dict:
    return json.loads((small / "truth.json").read_text(encoding="utf-8"))


def _raw(path: Path) -> bytes:
    data = path.read_bytes()
    return gzip.decompress(data) if path.suffix == ".gz" else data


def read_srf(path: Path) -> tuple[pd.DataFrame, dict[str, str]]:
    """srf file -> (frame with a 'line' column = 1-based file line, metadata)."""
    text = _raw(path).decode("utf-8")
    lines = text.split("\n")
    meta = {}
    k = 0
    while lines[k].startswith("#"):
        key, _, val = lines[k][1:].strip().partition("=")
        meta[key] = val
        k += 1
    df = pd.read_csv(io.StringIO("\n".join(lines[k:])), sep=",", dtype={"timestamp_utc": str})
    df["line"] = np.arange(len(df)) + k + 2
    return df, meta


def srf_files(small: Path) -> list[Path]:
    return sorted((small / "srf").iterdir())


def epoch_s(t: pd.Series) -> np.ndarray:
    """Seconds since 1970 of naive datetimes (any pandas resolution)."""
    return ((t - pd.Timestamp(0)) / pd.Timedelta(1, "s")).to_numpy()


def utc_s(ts: pd.Series) -> np.ndarray:
    return epoch_s(pd.to_datetime(ts, format="%Y-%m-%dT%H:%M:%S.%fZ"))


def steps_of(x, q) -> np.ndarray:
    """x / q for the non-empty values (should be integers when x has resolution q)."""
    x = np.asarray(x, dtype=float)
    return x[np.isfinite(x)] / q


def is_integral(a, tol=1e-6) -> bool:
    return bool(np.all(np.abs(a - np.round(a)) < tol))


# --------------------------------------------------------------------------------------
# srf dialect
# --------------------------------------------------------------------------------------


@pytest.mark.slow
def test_srf_columns_metadata_and_resolutions(small, truth):
    files = srf_files(small)
    assert any(p.name.endswith(".csv.gz") for p in files)  # one gzipped file exercised
    for p in files:
        df, meta = read_srf(p)
        vid = p.name.split("_")[0]
        assert meta["vehicle_id"] == vid
        assert meta["logger"].startswith("SRF Logger")
        assert meta["started"].endswith("Z") and datetime.strptime(meta["started"], "%Y-%m-%dT%H:%M:%SZ")
        info = truth["vehicles"][vid]
        cols = set(df.columns) - {"line"}
        if info["vehicle_type"] == "electric-bus":
            assert cols == SRF_BUS
            assert is_integral(steps_of(df.fms_total_energy_used_kwh, 0.1))
            assert is_integral(steps_of(df.fms_battery_soc_pct, 0.4))
        else:
            assert cols == SRF_TRUCK_BASE | ({"flowmeter_fuel_lph"} if info["flowmeter"] else set())
            assert is_integral(steps_of(df.fms_total_fuel_used_l, 0.5))
            assert is_integral(steps_of(df.fms_fuel_rate_lph, 0.05))
            assert is_integral(steps_of(df.fms_gross_weight_kg, 10.0))
        assert df.timestamp_utc.str.match(r"^\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z$").all()
        assert is_integral(steps_of(df.fms_wheel_speed_kmh, 1 / 256))
        assert is_integral(steps_of(df.fms_ambient_air_temp_c, 0.03125))  # J1939 SPN 171
        assert is_integral(steps_of(df.fms_accel_pedal_pct, 0.4))
        assert set(df.fms_brake_switch.dropna().unique()) <= {0.0, 1.0}
        tq = df.fms_engine_torque_pct.dropna()
        assert is_integral(tq.to_numpy()) and tq.between(-125, 125).all()
        assert df.gps_lat_deg.dropna().between(51.5, 53.5).all()
        assert df.gps_lon_deg.dropna().between(-1.5, 0.0).all()
        # about 1 Hz
        dt = np.diff(utc_s(df.timestamp_utc))
        assert 0.9 < np.median(dt) < 1.1


def test_srf_asynchronous_fields_and_gps_gaps(small):
    for p in srf_files(small):
        df, _ = read_srf(p)
        counter = "fms_total_energy_used_kwh" if "fms_total_energy_used_kwh" in df else "fms_total_fuel_used_l"
        for c in (counter, "fms_ambient_air_temp_c"):
            share = df[c].notna().mean()
            assert 0.05 < share < 0.4, (p.name, c, share)  # every 4-10 s: mostly empty
        assert df.fms_wheel_speed_kmh.notna().mean() > 0.98
        # no fix at the start of the session (cold start), fixes later
        assert df.gps_lat_deg.iloc[:5].isna().all() and df.gps_lat_deg.notna().mean() > 0.8
        # GPS altitude is poor: far from a smooth profile (tens of metres of error)
        assert df.gps_alt_m.dropna().std() > 3.0
        if "fms_gross_weight_kg" in df:
            assert 0.02 < df.fms_gross_weight_kg.notna().mean() < 0.2


def test_srf_missed_and_repeated_ticks(small, truth):
    srf = [f for f in truth["files"] if f["dialect"] == "srf"]
    assert sum(f["repeated_ticks"] for f in srf) > 0
    for f in srf:
        lines = _raw(small / f["path"]).decode().split("\n")
        assert sum(a == b for a, b in itertools.pairwise(lines)) == f["repeated_ticks"]
        df, _ = read_srf(small / f["path"])
        dt = np.diff(utc_s(df.timestamp_utc))
        assert ((dt > 1.5) & (dt < 60)).any()  # missed ticks inside trips


def test_srf_clock_step_backwards(small, truth):
    steps = [(f, x) for f in truth["files"] for x in f["faults"] if x["kind"] == "clock_step_backwards"]
    assert len(steps) == 1
    f, fault = steps[0]
    for g in truth["files"]:
        if g["dialect"] != "srf":
            continue
        df, _ = read_srf(small / g["path"])
        t = utc_s(df.timestamp_utc)
        back = np.flatnonzero(np.diff(t) < 0) + 1
        if g is f:
            assert df.line.to_numpy()[back].tolist() == [fault["line"]]
            jump = t[back[0] - 1] - t[back[0]]
            # the clock was 4.25 s ahead; one tick (1 s, or 2-3 s after missed ticks) passed
            assert fault["seconds"] - 3.1 < jump < fault["seconds"] - 0.9
        else:
            assert back.size == 0


def test_srf_fuel_counter_reset_and_large_start(small, truth):
    resets = [(f, x) for f in truth["files"] for x in f["faults"] if x["kind"] == "fuel_counter_reset"]
    assert len(resets) == 1
    f, fault = resets[0]
    df, _ = read_srf(small / f["path"])
    c = df[["line", "fms_total_fuel_used_l"]].dropna()
    assert c.fms_total_fuel_used_l.iloc[0] > 1e6  # an old ECU: counter near 1.84 million litres
    drop = np.flatnonzero(np.diff(c.fms_total_fuel_used_l.to_numpy()) < 0)
    assert drop.size == 1
    after = c.iloc[drop[0] + 1]
    assert after.line >= fault["line"] and after.fms_total_fuel_used_l < fault["to_l"] + 1.0


# --------------------------------------------------------------------------------------
# portal dialect
# --------------------------------------------------------------------------------------


def portal_file(small: Path) -> Path:
    (p,) = sorted((small / "portal").iterdir())
    return p


def test_portal_encoding_separators_and_columns(small):
    raw = portal_file(small).read_bytes()
    assert raw.count(b"\r\n") == raw.count(b"\n") > 10  # CRLF everywhere
    with pytest.raises(UnicodeDecodeError):
        raw.decode("utf-8")  # cp1252, not UTF-8
    text = raw.decode("cp1252")
    assert "£" in text and "é" in text
    df = pd.read_csv(io.BytesIO(raw), sep=";", decimal=",", encoding="cp1252")
    assert list(df.columns) == PORTAL
    assert df.Registration.nunique() == 2
    assert set(df.Ignition) == {"On", "Off"}
    for c in ("Latitude", "Longitude", "Speed (mph)", "Odometer (mi)", "Fuel Used (l)"):
        assert df[c].dtype == np.float64, c  # the decimal comma parsed
    assert is_integral(df["Fuel Used (l)"].to_numpy() / 0.5)
    assert b"," in raw.split(b"\r\n")[1]  # decimal commas are really there
    assert pd.to_datetime(df["Date/Time"], format="%d/%m/%Y %H:%M:%S").notna().all()


def test_portal_rows_sparser_when_stopped(small):
    df = pd.read_csv(portal_file(small), sep=";", decimal=",", encoding="cp1252")
    for _, g in df.groupby("Registration"):
        t = epoch_s(pd.to_datetime(g["Date/Time"], format="%d/%m/%Y %H:%M:%S"))
        dt = np.diff(t)
        on = (g.Ignition.to_numpy()[:-1] == "On") & (dt > 0)
        moving = on & (g["Speed (mph)"].to_numpy()[:-1] > 3) & (g["Speed (mph)"].to_numpy()[1:] > 3)
        stopped = on & (g["Speed (mph)"].to_numpy()[:-1] == 0) & (g["Speed (mph)"].to_numpy()[1:] == 0)
        assert moving.any() and stopped.any()
        assert np.all((dt[moving] >= 1) & (dt[moving] <= 10))
        assert np.median(dt[stopped]) > 2 * np.median(dt[moving])


def test_portal_local_time_crosses_dst(small, truth):
    df = pd.read_csv(portal_file(small), sep=";", decimal=",", encoding="cp1252")
    crossed = 0
    london = ZoneInfo("Europe/London")
    for reg, g in df.groupby("Registration", sort=False):
        local = pd.to_datetime(g["Date/Time"], format="%d/%m/%Y %H:%M:%S")
        back = np.flatnonzero(np.diff(epoch_s(local)) < 0)
        if back.size == 0:
            continue
        crossed += 1
        assert back.size == 1
        i = back[0] + 1
        assert local.iloc[i - 1].hour == 1 and local.iloc[i].hour == 1  # the repeated hour
        assert local.iloc[i - 1].strftime("%d/%m/%Y") == "27/10/2019"
        # rows before the step are BST (fold 0), after it GMT (fold 1): UTC increases
        utc = [local.iloc[k].to_pydatetime().replace(tzinfo=london, fold=int(k >= i)).astimezone(UTC)
               for k in range(len(local))]
        assert all(b > a for a, b in itertools.pairwise(utc))
        # the truth trips of this vehicle start at these UTC instants (first_line rows)
        for r in truth["trips"]:
            if r["vehicle_id"] == reg:
                k = r["first_line"] - 2 - int(np.flatnonzero(df.Registration.to_numpy() == reg)[0])
                assert g.Ignition.iloc[k] == "On"
                assert abs(utc[k].timestamp() - r["start_utc_s"]) < 1e-6
    assert crossed == 1


# --------------------------------------------------------------------------------------
# Truth consistency
# --------------------------------------------------------------------------------------


def trip_rows(small: Path, r: dict) -> pd.DataFrame:
    df, _ = read_srf(small / r["file"])
    return df[(df.line >= r["first_line"]) & (df.line <= r["last_line"])]


def test_truth_bus_energy_counter(small, truth):
    """Counter difference over a trip vs the truth: within one 0.1 kWh step, plus the
    consumption at standstill between the trip's ends and the first/last reading (at
    most 6 s each side at the stand-in's 4 kW base auxiliaries and at most 45 kW of
    HVAC, its heaters' full capacity: 0.15 kWh)."""
    bus = [r for r in truth["trips"] if r["vehicle_type"] == "electric-bus"]
    assert bus
    for r in bus:
        rows = trip_rows(small, r)
        e = rows.fms_total_energy_used_kwh.dropna().to_numpy()
        measured_kwh = e[-1] - e[0]
        assert abs(measured_kwh - r["consumption"] / 3.6e6) <= 0.1 + 0.15
        # voltage x current integrates to the same energy (trapezoid over the ticks)
        t = utc_s(rows.timestamp_utc)
        p = (rows.fms_battery_voltage_v * rows.fms_battery_current_a).to_numpy()
        ok = np.isfinite(p)
        keep = np.concatenate(([True], np.diff(t) > 0))  # repeated ticks out
        tt, pp = t[ok & keep], p[ok & keep]
        e_vi = float(np.sum(0.5 * (pp[1:] + pp[:-1]) * np.diff(tt)))
        assert e_vi == pytest.approx(r["consumption"], rel=0.03)


def test_truth_truck_weight_flowmeter_distance(small, truth):
    trucks = [r for r in truth["trips"] if r["vehicle_type"] == "diesel-hgv" and r["dialect"] == "srf"]
    assert trucks
    for r in trucks:
        v = truth["vehicles"][r["vehicle_id"]]
        rows = trip_rows(small, r)
        gw = rows.fms_gross_weight_kg.dropna()
        assert len(gw) > 0 and (gw == round(r["mass_kg"] / 10) * 10).all()
        assert r["mass_kg"] - v["kerb_mass_kg"] == r["load"]
        assert 0 <= r["load"] <= 26000
        t = utc_s(rows.timestamp_utc)
        keep = np.concatenate(([True], np.diff(t) > 0))
        if v["flowmeter"]:
            f = rows.flowmeter_fuel_lph.to_numpy()
            ok = np.isfinite(f) & keep
            litres = float(np.sum(0.5 * (f[ok][1:] + f[ok][:-1]) * np.diff(t[ok]))) / 3600
            assert litres == pytest.approx(r["consumption"], rel=0.03)
        w = rows.fms_wheel_speed_kmh.to_numpy() / 3.6 / v["wheel_speed_scale"]
        ok = np.isfinite(w) & keep
        dist = float(np.sum(0.5 * (w[ok][1:] + w[ok][:-1]) * np.diff(t[ok])))
        assert dist == pytest.approx(r["distance_m"], rel=0.01)


def test_truth_trip_times_match_rows(small, truth):
    for r in truth["trips"]:
        if r["dialect"] != "srf":
            continue
        rows = trip_rows(small, r)
        assert len(rows) > 60
        assert r["end_utc_s"] - r["start_utc_s"] == pytest.approx(r["duration_s"], abs=1.5e-3)  # each to 1 ms
        start = datetime.fromtimestamp(round(r["start_utc_s"], 3), UTC)
        assert r["start_utc"] == start.strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z"
    # layovers: no rows for more than 5 minutes between the trips of a file
    by_file: dict[str, list[dict]] = {}
    for r in truth["trips"]:
        by_file.setdefault(r["file"], []).append(r)
    for rs in by_file.values():
        rs.sort(key=lambda r: r["start_utc_s"])
        for a, b in itertools.pairwise(rs):
            assert b["start_utc_s"] - a["end_utc_s"] > 600


def test_injected_consumption_function_is_used(tmp_path):
    calls = []

    def fake(kind, time_s, speed_mps, elevation_m, mass_kg, *, conditions):
        calls.append((kind, float(np.mean(conditions.ambient_c)), conditions.soak_s, conditions.occupants, mass_kg))
        return 0.01 * time_s if kind == "diesel-hgv" else 2.0e4 * time_s

    doc = sg.generate_sample_logs(tmp_path, fake, small=True, write_dsm=False)
    assert {c[0] for c in calls} == {"diesel-hgv", "electric-bus"}
    assert doc["consumption_fn"].endswith("fake")
    assert len(calls) == len(doc["trips"])
    for r in doc["trips"]:
        rate = 0.01 if r["vehicle_type"] == "diesel-hgv" else 2.0e4
        assert r["consumption"] == pytest.approx(rate * r["duration_s"], abs=rate * 1e-3)  # duration to 1 ms
        assert not any(k.endswith(("_fuel_l", "_energy_j")) for k in r)  # a plain array has no parts
    # the conditions passed are the truth's: its air temperature, soak time and occupants
    by_mass = {}
    for c in calls:
        by_mass.setdefault(round(c[4], 3), []).append(c)
    for r in doc["trips"]:
        match = [c for c in by_mass[round(r["mass_kg"], 3)] if c[2] == pytest.approx(r["soak_s"], abs=0.1)]
        assert any(abs(c[1] - r["ambient_c"]) < 0.05 for c in match)
        bus = r["vehicle_type"] == "electric-bus"
        assert r["occupants"] == (1 + r["load"] if bus else 1)
    firsts = {}
    for r in sorted(doc["trips"], key=lambda r: r["start_utc_s"]):
        firsts.setdefault((r["vehicle_id"], r["day_index"]), r["start_utc_s"])
    for r in doc["trips"]:
        first = firsts[(r["vehicle_id"], r["day_index"])] == r["start_utc_s"]
        assert r["soak_s"] == 43200.0 if first else 600 < r["soak_s"] < 1900  # overnight, or a layover


def test_a_consumption_function_without_conditions_is_refused(tmp_path, capsys, monkeypatch):
    def old(kind, time_s, speed_mps, elevation_m, mass_kg):
        return time_s

    with pytest.raises(TypeError, match="conditions"):
        sg.generate_sample_logs(tmp_path, old, small=True, write_dsm=False)
    assert not (tmp_path / "truth.json").exists()
    monkeypatch.setattr(sys.modules[__name__], "old_style_fn", old, raising=False)
    with pytest.raises(SystemExit) as e:
        sg.main([str(tmp_path), "--small", "--consumption", f"{__name__}:old_style_fn"])
    assert "conditions" in str(e.value) and "--consumption" in str(e.value)


def test_generator_does_not_import_the_ce_model():
    code = "import sys, cevm_samplegen; print('cevm.core.model' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def _conditions(n, ambient_c=20.0, solar=0.0, soak_s=0.0, occupants=1.0):
    return sg.TripConditions(np.full(n, float(ambient_c)), np.full(n, float(solar)), soak_s, occupants)


def test_standin_consumption_by_hand():
    """Bus at a constant 10 m/s on a flat road for 10 s, at 20 degC without sun (the
    cabin floats inside its 18-24 degC band: only the ventilation blower runs): rolling
    + drag at the wheel, through the drive efficiency, plus drive loss and auxiliaries."""
    p = sg.STANDIN["electric-bus"]
    m, v = 12000.0, 10.0
    t = np.arange(11.0)
    e = sg.standin_consumption("electric-bus", t, np.full(11, v), np.zeros(11), m, conditions=_conditions(11))
    cr = p.cr + p.cr_speed_per_mps * v
    wheel_w = cr * m * 9.81 * v + 0.5 * 1.225 * p.cda_m2 * v**3
    expect = (wheel_w / p.drive_eff + p.drive_loss_w + p.aux_w + aux.BUS_CABIN.blower_w) * 10.0
    assert e.cumulative[0] == 0.0 and e.cumulative[-1] == pytest.approx(expect, rel=1e-12)
    assert e.parts["hvac_energy_j"] == pytest.approx(aux.BUS_CABIN.blower_w * 10.0)
    # a truck coasting downhill at speed burns nothing (fuel cut-off), cold engine or not
    for ambient, soak in ((20.0, 0.0), (-5.0, 43200.0)):
        f = sg.standin_consumption("diesel-hgv", t, np.full(11, 20.0), -2.0 * t, 40000.0,
                                   conditions=_conditions(11, ambient, soak_s=soak))
        assert f.cumulative[-1] == 0.0
    with pytest.raises(ValueError):
        sg.standin_consumption("tram", t, t, t, 1.0, conditions=_conditions(11))
    with pytest.raises(ValueError, match="samples"):
        sg.standin_consumption("electric-bus", t, t, t, 1.0, conditions=_conditions(5))


def test_standin_adds_the_cabin_hvac_energy():
    """The same trace at 0 degC and at 20 degC: the bus's extra energy is the cabin's
    extra electric energy (heating: trapezoid of its per-sample power), nothing else."""
    t = np.arange(0.0, 601.0)
    v = np.where((t % 100) < 70, 9.0, 0.0)
    v[0] = v[-1] = 0.0
    h = np.zeros(t.size)
    warm = sg.standin_consumption("electric-bus", t, v, h, 11000.0, conditions=_conditions(t.size, 20.0))
    cold = sg.standin_consumption("electric-bus", t, v, h, 11000.0, conditions=_conditions(t.size, 0.0))
    load = aux.cabin_load(aux.BUS_CABIN, t, v, np.zeros(t.size), np.zeros(t.size), occupants=1.0, soak_s=0.0)
    hvac = float(np.sum(0.5 * (load.electric_w[1:] + load.electric_w[:-1])))
    blower = aux.BUS_CABIN.blower_w * 600.0
    assert cold.cumulative[-1] - warm.cumulative[-1] == pytest.approx(hvac - blower, rel=1e-9)
    assert cold.parts["hvac_energy_j"] == pytest.approx(hvac, rel=1e-9)
    assert hvac > 10 * blower  # heating at 0 degC costs kilowatts


def test_detailed_consumption_carries_hvac_and_cold_start():
    """logged_consumption: the bus's HVAC energy reaches the battery (within the battery's
    resistive losses); a cold-soaked truck burns more than a warm one, and its parts say
    how much."""
    t = np.arange(0.0, 901.0)
    v = np.clip(np.minimum(t, 900.0 - t) * 0.8, 0.0, 13.0)
    h = np.zeros(t.size)
    warm = sg.logged_consumption("electric-bus", t, v, h, 11000.0, conditions=_conditions(t.size, 20.0))
    cold = sg.logged_consumption("electric-bus", t, v, h, 11000.0, conditions=_conditions(t.size, -5.0, soak_s=1800.0))
    extra = cold.parts["hvac_energy_j"] - warm.parts["hvac_energy_j"]
    assert cold.cumulative[-1] - warm.cumulative[-1] == pytest.approx(extra, rel=0.02)
    assert cold.parts["warmup_energy_j"] > 0.0 == warm.parts["warmup_energy_j"]
    hot = sg.logged_consumption("diesel-hgv", t, v, h, 30000.0, conditions=_conditions(t.size, 5.0, soak_s=0.0))
    soaked = sg.logged_consumption("diesel-hgv", t, v, h, 30000.0, conditions=_conditions(t.size, 5.0, soak_s=43200.0))
    assert hot.parts["cold_start_fuel_l"] == pytest.approx(0.0, abs=1e-12)
    assert hot.parts["engine_start_c"] == pytest.approx(aux.DIESEL_WARMUP.hot_c)
    assert soaked.parts["engine_start_c"] == pytest.approx(5.0 + 83.0 * math.exp(-4.0))  # 12 h, tau 3 h
    # soaked, the cab's heater also makes up its deficit (its fans on the alternator)
    hvac_extra = soaked.parts["hvac_fuel_l"] - hot.parts["hvac_fuel_l"]
    assert soaked.cumulative[-1] - hot.cumulative[-1] == pytest.approx(soaked.parts["cold_start_fuel_l"] + hvac_extra,
                                                                         rel=1e-9)
    # a short, light trip: cold throughout
    assert 0.02 < soaked.parts["cold_start_fuel_l"] < 0.2 * soaked.cumulative[-1]


# --------------------------------------------------------------------------------------
# Determinism
# --------------------------------------------------------------------------------------


def tree_hashes(root: Path) -> dict[str, str]:
    return {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.mark.slow
def test_same_bytes_on_every_run(small, tmp_path):
    sg.generate_sample_logs(tmp_path, small=True)
    a, b = tree_hashes(small), tree_hashes(tmp_path)
    assert len(a) >= 6 and a == b
    sg.generate_sample_logs(tmp_path / "other", small=True, seed=8, write_dsm=False)
    assert tree_hashes(tmp_path / "other")["truth.json"] != a["truth.json"]


# --------------------------------------------------------------------------------------
# DSM tiles
# --------------------------------------------------------------------------------------


def open_tiles(small: Path, truth: dict):
    import rasterio

    tiles = []
    for rel in truth["dsm"]["tiles"]:
        with rasterio.open(small / rel) as ds:
            assert ds.crs.to_epsg() == 27700
            assert ds.dtypes == ("float32",)
            assert ds.compression.name.lower() == "deflate"
            assert ds.tags(ns="IMAGE_STRUCTURE").get("PREDICTOR") == "3"
            assert ds.nodata == -9999.0
            assert ds.res == (truth["dsm"]["resolution_m"],) * 2
            tiles.append((ds.bounds, ds.read(1), ds.transform))
    return tiles


def small_world_and_trips():
    return sg.simulate_fleet(sg.SMALL_FLEET)


def test_tiles_cover_routes_except_documented_gaps(small, truth):
    tiles = open_tiles(small, truth)
    assert len(tiles) >= 2
    world, _ = small_world_and_trips()
    for name, route in world.routes.items():
        s = np.arange(0.0, route.length_m, 5.0)
        x, y = route.xy(s)
        inside = in_any_tile(tiles, x, y)
        in_gap = np.zeros(s.size, bool)
        for a, z in truth["routes"][name]["dsm_gaps_m"]:
            in_gap |= (s >= a - 1.0) & (s <= z + 1.0)
        edge = np.zeros(s.size, bool)
        for a, z in truth["routes"][name]["dsm_gaps_m"]:
            edge |= (np.abs(s - a) <= 1.5) | (np.abs(s - z) <= 1.5)
        assert np.all(inside[~in_gap]), name
        assert not np.any(inside[in_gap & ~edge]), name
        assert inside.any() and (~inside).any()  # partly covered, on purpose


def in_any_tile(tiles, x, y) -> np.ndarray:
    inside = np.zeros(np.shape(x), bool)
    for b, _, _ in tiles:
        inside |= (x >= b.left) & (x < b.right) & (y > b.bottom) & (y <= b.top)
    return inside


def mosaic_bilinear(tiles, x, y, nodata=-9999.0):
    """Bilinear interpolation between pixel centres over a mosaic of same-grid tiles;
    NaN where a neighbour is nodata or outside every tile."""
    left = min(b.left for b, _, _ in tiles)
    top = max(b.top for b, _, _ in tiles)
    res = tiles[0][2].a
    right = max(b.right for b, _, _ in tiles)
    bottom = min(b.bottom for b, _, _ in tiles)
    W, H = int(round((right - left) / res)), int(round((top - bottom) / res))
    z = np.full((H, W), np.nan)
    for b, a, _ in tiles:
        r0, c0 = int(round((top - b.top) / res)), int(round((b.left - left) / res))
        z[r0 : r0 + a.shape[0], c0 : c0 + a.shape[1]] = np.where(a == nodata, np.nan, a)
    fc = (x - left) / res - 0.5
    fr = (top - y) / res - 0.5
    c, r = np.floor(fc).astype(int), np.floor(fr).astype(int)
    ok = (c >= 0) & (r >= 0) & (c + 1 < W) & (r + 1 < H)
    out = np.full(x.shape, np.nan)
    c, r, u, v = c[ok], r[ok], fc[ok] - c[ok], fr[ok] - r[ok]
    out[ok] = (z[r, c] * (1 - u) * (1 - v) + z[r, c + 1] * u * (1 - v)
               + z[r + 1, c] * (1 - u) * v + z[r + 1, c + 1] * u * v)
    return out


def test_dsm_road_elevation_matches_truth(small, truth):
    tiles = open_tiles(small, truth)
    world, trips = small_world_and_trips()
    checked = spikes = 0
    for days in trips.values():
        for tr in (t for day in days for t in day):
            s = world.routes[tr.route].along_m(tr.route_from_m + tr.distance_m)
            z = mosaic_bilinear(tiles, tr.x_m, tr.y_m)
            near_object = np.zeros(s.size, bool)
            for o in truth["routes"][tr.route]["surface_objects"]:
                near_object |= (s >= o["from_m"] - 2.0) & (s <= o["to_m"] + 2.0)
                if o["kind"] in ("tree", "bridge"):
                    inside = (s >= o["from_m"]) & (s <= o["to_m"]) & np.isfinite(z)
                    spikes += int(np.any(z[inside] - tr.elevation_m[inside] > 2.0))
            ok = np.isfinite(z) & ~near_object
            assert np.all(np.abs(z[ok] - tr.elevation_m[ok]) < 0.05)
            checked += int(ok.sum())
            # inside the tiles, the DSM has no value only near a hole, or within a pixel
            # of the edge of the tiled area (a bilinear neighbour is missing)
            explained = np.zeros(s.size, bool)
            for o in truth["routes"][tr.route]["surface_objects"]:
                if o["kind"] == "hole":
                    explained |= (s >= o["from_m"]) & (s <= o["to_m"])
            res = truth["dsm"]["resolution_m"]
            for dx, dy in ((res, 0), (-res, 0), (0, res), (0, -res)):
                explained |= ~in_any_tile(tiles, tr.x_m + dx, tr.y_m + dy)
            missing = ~np.isfinite(z) & in_any_tile(tiles, tr.x_m, tr.y_m)
            assert np.all(explained[missing])
    assert checked > 200
    assert spikes >= 1  # the raw road profile does show trees or bridges


def test_dsm_has_buildings_beside_roads_and_holes(small, truth):
    tiles = open_tiles(small, truth)
    world, _ = small_world_and_trips()
    n_nodata = sum(int((a == -9999.0).sum()) for _, a, _ in tiles)
    assert n_nodata > 0
    # surface minus terrain: objects (buildings, trees) metres high somewhere
    b, a, tr = tiles[0]
    rows, cols = np.mgrid[0 : a.shape[0], 0 : a.shape[1]]
    x = tr.c + (cols + 0.5) * tr.a
    y = tr.f + (rows + 0.5) * tr.e
    terrain = world.terrain.elevation_m(x, y)
    above = np.where(a == -9999.0, 0.0, a - terrain)
    assert (above > 3.0).mean() > 0.002
    assert np.abs(np.where(above > 0.01, 0.0, above)).max() < 0.01  # never below the terrain


# --------------------------------------------------------------------------------------
# Formatting helpers and the benchmark fleet
# --------------------------------------------------------------------------------------


@settings(max_examples=60, deadline=None)
@given(st.lists(st.one_of(st.floats(-1e7, 1e7, allow_nan=False), st.just(float("nan"))), min_size=1, max_size=30),
       st.integers(0, 8), st.booleans())
def test_number_formatting_matches_python(values, decimals, strip):
    x = np.array(values)
    x = np.round(x, decimals)  # the formatter prints numbers already on their grid
    chars, keep = csvfmt.num_field(x, decimals, strip=strip)
    got = csvfmt.assemble([(chars, keep)], b",", b"\n").decode().split("\n")[:-1]
    for g, v in zip(got, x, strict=True):
        if not np.isfinite(v):
            assert g == ""
            continue
        ref = f"{v:.{decimals}f}"
        if ref.startswith("-") and float(ref) == 0:
            ref = ref[1:]
        if strip and "." in ref:
            ref = ref.rstrip("0").rstrip(".")
        assert g == ref


def test_uk_local_time_formatting():
    london = ZoneInfo("Europe/London")
    base = datetime(2019, 10, 27, 0, 30, tzinfo=UTC)
    ts = [base + timedelta(minutes=20 * k) for k in range(6)] + [datetime(2019, 3, 31, 0, 59, 59, tzinfo=UTC),
                                                                 datetime(2019, 3, 31, 1, 0, 0, tzinfo=UTC)]
    chars, keep = csvfmt.uk_local(np.array([int(t.timestamp()) for t in ts]))
    got = csvfmt.assemble([(chars, keep)], b";", b"\n").decode().split("\n")[:-1]
    assert got == [t.astimezone(london).strftime("%d/%m/%Y %H:%M:%S") for t in ts]


@pytest.mark.slow
def test_fleet_for_benchmark(tmp_path):
    doc = sg.fleet_for_benchmark(2, 1, tmp_path)
    files = sorted((tmp_path / "srf").glob("*.csv"))
    assert [p.name for p in files] == ["BM-001_2019-05-13.csv", "BM-002_2019-05-13.csv"]
    n = 0
    for p in files:
        df, meta = read_srf(p)
        assert set(df.columns) - {"line"} == SRF_BUS
        n += len(df)
    assert n == doc["rows"] > 2000
    assert json.loads((tmp_path / "truth.json").read_text())["rows"] == n
    # working days: the same vehicles and routes, more trips a day (about 3x the samples)
    full = sg.fleet_for_benchmark(2, 1, tmp_path / "full", full_days=True)
    per_day = {t["vehicle_id"]: 0 for t in doc["trips"]}
    for t in doc["trips"]:
        per_day[t["vehicle_id"]] += 1
    full_per_day = {v: sum(t["vehicle_id"] == v for t in full["trips"]) for v in per_day}
    assert full_per_day == {v: 4 * k for v, k in per_day.items()}
    assert 2.5 * doc["rows"] < full["rows"] < 6 * doc["rows"]


def test_os_tile_names():
    assert sg.os_tile_name(485000, 238000) == "SP8538"
    assert sg.os_tile_name(530000, 180000) == "TQ3080"  # central London
    assert sg.os_tile_name(325000, 673000) == "NT2573"  # Edinburgh


# --------------------------------------------------------------------------------------
# Weather, the temperature column, the loads that follow it, duties
# --------------------------------------------------------------------------------------

from cevm_samplegen import weather as wx  # noqa: E402


def test_seasonal_mean_and_forced_days():
    c = wx.MILTON_KEYNES
    assert c.seasonal_mean_c(c.coldest_day_of_year) == pytest.approx(c.mean_jan_c)
    assert c.seasonal_mean_c(c.coldest_day_of_year + 365.25 / 2) == pytest.approx(c.mean_jul_c)
    assert 3.5 < c.mean_jan_c < 5.0 and 16.5 < c.mean_jul_c < 18.0  # Milton Keynes
    cold = wx.day_weather("2019-01-31", 7, wx.ForcedDay("2019-01-31", -5.5, 1.0, 0.15))
    t = cold.midnight_utc_s + np.arange(0.0, 86400.0, 60.0)
    temp = cold.ambient_c(t)
    # the profile spans the forced extremes (to within the 0.25 K noise)
    assert temp.min() == pytest.approx(-5.5, abs=1.0) and temp.max() == pytest.approx(1.0, abs=1.0)
    hour_min = (t[np.argmin(temp)] - cold.midnight_utc_s) / 3600.0
    hour_max = (t[np.argmax(temp)] - cold.midnight_utc_s) / 3600.0
    assert abs(hour_min - (cold.sunrise_utc_h + 0.5)) < 2.5  # coldest around sunrise
    assert 13.0 < hour_max < 16.5  # warmest in the afternoon
    assert 7.6 < cold.sunrise_utc_h < 8.1  # sunrise near Milton Keynes on 31 January: about 07:50 UTC
    with pytest.raises(ValueError):
        wx.day_weather("2019-01-31", 7, wx.ForcedDay("2019-02-01", -5.0, 1.0, 0.1))


def test_weather_is_deterministic_and_differs_by_date():
    a, b = wx.day_weather("2019-04-10", 7), wx.day_weather("2019-04-10", 7)
    t = a.midnight_utc_s + np.arange(0.0, 86400.0, 300.0)
    np.testing.assert_array_equal(a.ambient_c(t), b.ambient_c(t))
    np.testing.assert_array_equal(a.solar_w_m2(t), b.solar_w_m2(t))
    means = [wx.day_weather(f"2019-{m:02d}-15", 7).mean_c for m in range(1, 13)]
    assert len(set(means)) == 12
    assert np.mean(means[5:8]) - np.mean([means[0], means[1], means[11]]) > 6.0  # summer warmer than winter


def test_sunshine_by_hand_at_solar_noon_and_none_at_night():
    w = wx.day_weather("2019-06-21", 7, wx.ForcedDay("2019-06-21", 12.0, 24.0, 0.0))
    noon = w.midnight_utc_s + w.solar_noon_utc_h * 3600.0
    elev = math.radians(90.0 - 52.04) + w.declination_rad  # at solar noon: 90 deg - latitude + declination
    assert float(w.solar_elevation_sin(noon)) == pytest.approx(math.sin(elev), rel=1e-9)
    assert math.degrees(w.declination_rad) == pytest.approx(23.44, abs=0.1)  # midsummer
    clear = 1098.0 * math.sin(elev) * math.exp(-0.057 / math.sin(elev))  # Haurwitz
    assert 0.7 * clear <= float(w.solar_w_m2(noon)) <= clear  # cloud 0: passing clouds only dim it
    assert float(w.solar_w_m2(w.midnight_utc_s)) == 0.0


def test_temperature_column_follows_the_days_weather(small, truth):
    """The logged fms_ambient_air_temp_c of every srf trip: the true air temperature of
    the trip (truth.json) plus the vehicle's sensor bias, warmed only by sun at low speed
    (at most 2 K at 800 W/m^2), within the lag and the 1/32 degC steps."""
    seen = set()
    for r in (r for r in truth["trips"] if r["dialect"] == "srf"):
        rows = trip_rows(small, r)
        temp = rows.fms_ambient_air_temp_c.dropna().to_numpy()
        assert temp.size > 5
        bias = truth["vehicles"][r["vehicle_id"]]["ambient_bias_k"]
        sun_k = 2.0 * r["solar_w_m2"] / 800.0
        excess = temp.mean() - (r["ambient_c"] + bias)
        assert -0.3 < excess < sun_k + 0.3, (r["vehicle_id"], r["day_index"], r["trip_index"], excess)
        day = truth["weather"][datetime.fromtimestamp(r["start_utc_s"], UTC).date().isoformat()]
        assert day["min_c"] - 1.0 <= r["ambient_min_c"] <= r["ambient_max_c"] <= day["max_c"] + 1.0
        seen.add(day["max_c"] < 5.0)
    assert seen == {True, False}  # a cold and a warm day in the small sample


def test_portal_export_has_no_temperature_column(small):
    header = portal_file(small).read_bytes().split(b"\r\n")[0].decode("cp1252")
    assert "temp" not in header.lower()


def _steady(cabin, ambient_c, solar=0.0, occupants=1.0, moving=True, n=200):
    t = np.arange(float(n))
    v = np.full(n, 8.0 if moving else 0.0)
    return aux.cabin_load(cabin, t, v, np.full(n, float(ambient_c)), np.full(n, float(solar)),
                          occupants=occupants, soak_s=0.0)


def test_bus_heating_by_hand():
    """At 0 degC, moving, 11 people, no sun, cabin held at 18 degC: demand
    (UA + ventilation) x 18 K - gains, from the heat pump (COP 0.40 x 318.15 / 53) within
    its capacity (18 kW x (1 - 0.03 x 7)); electric power = that / COP + fans in
    proportion to the load + the blower."""
    c = aux.BUS_CABIN
    q = (350.0 + 200.0) * 18.0 - (600.0 + 11 * 80.0)
    cap = 18e3 * (1 - 0.03 * 7.0)
    assert q < cap
    cop = 0.40 * (45.0 + 273.15) / (45.0 - (0.0 - 8.0))
    fans = 900.0 * (0.3 + 0.7 * q / (cap + 20e3))
    load = _steady(c, 0.0, occupants=11.0)
    np.testing.assert_allclose(load.heating_w, q)
    np.testing.assert_allclose(load.electric_w, q / cop + fans + 400.0, rtol=1e-12)
    assert np.all(load.compressor_w == 0.0) and np.all(load.warmup_electric_w == 0.0)


def test_bus_cooling_by_hand_and_the_deadband():
    c = aux.BUS_CABIN
    # 30 degC, sun 700 W/m^2, 40 people: gains + L (T - 24), at an EER of 0.35 x 278.15 / 40
    q = 600.0 + 40 * 80.0 + 4.0 * 700.0 + 550.0 * 6.0
    eer = 0.35 * (5.0 + 273.15) / (30.0 + 15.0 - 5.0)
    load = _steady(c, 30.0, solar=700.0, occupants=40.0)
    np.testing.assert_allclose(load.cooling_w, q)
    np.testing.assert_allclose(load.electric_w, q / eer + 900.0 * (0.3 + 0.7 * q / 20e3) + 400.0, rtol=1e-12)
    # 20 degC, no sun, the driver alone: the cabin floats at 20 + 680 / 550 degC, inside the band
    idle = _steady(c, 20.0)
    np.testing.assert_allclose(idle.electric_w, 400.0)
    # 21 degC in sun: warmer than 24 degC inside, but fresh air cools it for free
    free = _steady(c, 21.0, solar=500.0, occupants=20.0)
    assert 600.0 + 20 * 80.0 + 2000.0 > 550.0 * 3.0  # it would need cooling without the economiser
    np.testing.assert_allclose(free.cooling_w, 0.0)


def test_bus_hvac_is_convex_in_the_cold_not_a_hinge():
    """The heat pump's COP falls with the cold and the resistive heater takes over: the
    electric power rises faster than the heat demand, which is linear in the temperature."""
    temps = np.arange(-10.0, 14.0, 2.0)
    power = np.array([_steady(aux.BUS_CABIN, T, occupants=20.0).electric_w.mean() for T in temps])
    demand = np.array([_steady(aux.BUS_CABIN, T, occupants=20.0).heating_w.mean() for T in temps])
    slope = -np.diff(power) / 2.0  # W per K colder
    assert np.all(slope > 0) and slope[0] > 2.5 * slope[-1]  # steeper in the cold: not a straight hinge
    assert np.all(np.diff(slope[2:]) < 0)  # convex while the heat pump covers the demand
    np.testing.assert_allclose(np.diff(demand), np.diff(demand)[0])  # the demand itself: a straight line
    cop = aux.BUS_CABIN.heating_cop(temps)
    assert np.all(np.diff(cop) > 0)


def test_warmup_makes_up_the_layovers_deficit():
    """After a soak the cabin starts between its held and its parked temperature; the
    heating beyond the steady demand adds up to capacity x (setpoint - start), and grows
    with the soak and the cold."""
    c = aux.BUS_CABIN
    n = 1500
    t = np.arange(float(n))
    v = np.full(n, 8.0)

    def load(ambient, soak):
        return aux.cabin_load(c, t, v, np.full(n, ambient), np.zeros(n), occupants=10.0, soak_s=soak)

    steady = load(-5.0, 0.0)
    soaked = load(-5.0, 1200.0)
    tau = 300e3 / 320.0
    start = -5.0 + (18.0 - -5.0) * math.exp(-1200.0 / tau)
    assert soaked.start_c == pytest.approx(start)
    extra_heat = float(np.sum(soaked.heating_w - steady.heating_w))
    assert extra_heat == pytest.approx(300e3 * (18.0 - start), rel=1e-9)
    warm = [float(np.sum(load(T, s).warmup_electric_w)) for T, s in ((-5.0, 600.0), (-5.0, 2400.0), (5.0, 2400.0))]
    assert warm[1] > warm[0] and warm[1] > warm[2] > 0.0


def test_engine_warmup_by_hand():
    w = aux.DIESEL_WARMUP
    assert w.start_c(5.0, 0.0) == pytest.approx(88.0)
    assert w.start_c(5.0, 3 * 3600.0) == pytest.approx(5.0 + 83.0 / math.e)
    t = np.arange(0.0, 2001.0)
    temp = w.temperature_c(t, np.full(2000, 200e3), 10.0)  # 200 kW of fuel: 60 kW into 650 kJ/K
    np.testing.assert_allclose(temp, np.minimum(10.0 + 60e3 * t / 650e3, 88.0))
    assert temp[-1] == 88.0 and temp[800] < 88.0  # hot after 845 s
    with_cab = w.temperature_c(t, np.full(2000, 200e3), 10.0, cab_heat_w=3e3)
    assert with_cab[500] == pytest.approx(10.0 + 57e3 * 500 / 650e3)  # the cab heater slows it
    assert float(w.friction_scale(20.0)) == pytest.approx(1.0 + 0.012 * 68.0)
    assert float(w.friction_scale(95.0)) == 1.0


def test_truck_duties_differ_by_day(small, truth):
    """HGV-11 delivers in town on its second small day: slower, with more stops per km,
    on the town road, with a smaller payload that falls at each round."""
    spec = next(v for v in sg.SMALL_FLEET.srf_vehicles if v.vehicle_id == "HGV-11")
    assert spec.duty_on(0) == ("truck-short", "regional") and spec.duty_on(1) == ("urban-short", "bus-1")
    assert spec.duty_on(2) == spec.duty_on(0)  # the schedule repeats
    trips = [r for r in truth["trips"] if r["vehicle_id"] == "HGV-11"]
    stats = {}
    for r in trips:
        rows = trip_rows(small, r)
        v = rows.fms_wheel_speed_kmh.dropna().to_numpy()
        stops = int(np.sum((v[1:] < 1.0) & (v[:-1] >= 1.0)))
        stats.setdefault(r["duty"], []).append((r["distance_m"] / r["duration_s"], stops / (r["distance_m"] / 1000)))
        assert r["route"] == dict([spec.duty_on(0), spec.duty_on(1)])[r["duty"]]
    (reg,), (urb,) = [np.mean(stats[d], axis=0, keepdims=True) for d in ("truck-short", "urban-short")]
    assert urb[0] < 0.75 * reg[0] and urb[1] > reg[1]
    urban = sorted((r for r in trips if r["duty"] == "urban-short"), key=lambda r: r["trip_index"])
    assert all(6000 <= r["load"] <= 12000 for r in urban[:1]) and urban[1]["load"] < urban[0]["load"]


def test_sample_fleet_spans_the_seasons_and_mixes_duties():
    """The shipped fleet (spec only, nothing simulated): logging days from winter to
    summer with cold and hot days forced, buses of 4-5 trips a day, trucks on two
    duties each."""
    f = sg.SAMPLE_FLEET
    months = {int(d[5:7]) for d in f.srf_dates}
    assert len(f.srf_dates) >= 5 and min(months) <= 2 and max(months) >= 7
    forced = {d.date: d for d in f.forced_weather}
    assert sum(d.min_c <= -4.0 for d in forced.values() if d.date in f.srf_dates) >= 2
    assert sum(d.max_c >= 29.0 for d in forced.values() if d.date in f.srf_dates) >= 2
    for v in f.srf_vehicles:
        duties = {v.duty_on(i)[0] for i in range(len(f.srf_dates))}
        if v.vehicle_type == "electric-bus":
            assert sg.fleet.DUTIES[v.duty].trips_per_day == (4, 5)
        else:
            assert len(duties) == 2, v.vehicle_id


def test_manifests_give_the_true_loads(small, truth):
    """The operator's manifests: the buses' passenger counts (x 75 kg) and the portal
    trucks' TMS gross weights (to 0.1 t), each trip's window around its true start and
    end, read back with cevm's manifest reader."""
    from cevm.io.manifest import read_manifest

    trips = {(r["vehicle_id"], round(r["start_utc_s"])): r for r in truth["trips"]}
    assert sorted(truth["manifests"]) == ["manifests/bus-loads.csv", "manifests/portal-tms.csv"]
    bus = read_manifest(small / "manifests" / "bus-loads.csv")
    portal = read_manifest(small / "manifests" / "portal-tms.csv")
    assert not bus.problems and not portal.problems
    n_bus = sum(1 for r in truth["trips"] if r["load_unit"] == "passengers")
    n_portal = sum(1 for r in truth["trips"] if r["dialect"] == "portal")
    assert (len(bus.rows), len(portal.rows)) == (n_bus, n_portal) and n_bus and n_portal
    for row in bus.rows + portal.rows:
        match = [r for (vid, _), r in trips.items()
                 if vid == row.vehicle_id and row.start_utc_s <= r["start_utc_s"] and r["end_utc_s"] <= row.end_utc_s]
        assert len(match) == 1, row
        r = match[0]
        assert row.end_utc_s - row.start_utc_s < r["end_utc_s"] - r["start_utc_s"] + 121  # to the minute at most
        if row.kind == "payload":
            assert row.mass_kg == r["load"] * 75.0
        else:
            assert abs(row.mass_kg - r["mass_kg"]) <= 50.0
