"""Tests of the reading stage (cevm.ingest.profiles, cevm.ingest.reading): profiles, detection, the three dialects,
gzip, time zones and DST, date repair, and every kind of bad input.

Expected values are hand computations (unit factors, UTC times of local times worked
out by hand) or plain reference code (datetime / zoneinfo), never the code under test.
"""

from __future__ import annotations

import gzip
import hashlib
import re
import shutil
from datetime import UTC, datetime, timedelta
from pathlib import Path
from zoneinfo import ZoneInfo

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cevm.core.trip import CANONICAL_COLUMNS
from cevm.errors import InputError
from cevm.ingest.profiles import CANONICAL_DIMENSIONS, UNITS, load_profile, load_profiles
from cevm.ingest.reading import PLAUSIBLE_RANGE_SI, EnergySource, detect_profile, read_log
from cevm.ingest.timestamps import parse_datetimes

DATA = Path(__file__).parent / "data"
KMH = 1 / 3.6  # m/s per km/h
MPH = 0.44704  # m/s per mph (exact by definition)
MILE = 1609.344  # m per mile (exact)
UTC = UTC


@pytest.fixture(scope="module")
def profiles():
    return load_profiles(include_env=False)


def utc_s(*args) -> float:
    """Seconds since the epoch of a UTC datetime (reference, plain datetime)."""
    return datetime(*args, tzinfo=UTC).timestamp()


def write(path: Path, text: str | bytes) -> Path:
    path.write_bytes(text.encode("utf-8") if isinstance(text, str) else text)
    return path


SRF_HEADER = "timestamp_utc,gps_lat_deg,gps_lon_deg,gps_speed_kmh,fms_wheel_speed_kmh,fms_total_energy_used_kwh"


def srf_rows(n: int, start_s: int = 0, speed_kmh: float = 36.0) -> list[str]:
    """n 1-Hz srf rows from 2020-06-01T10:00:00Z."""
    t0 = datetime(2020, 6, 1, 10, 0, 0, tzinfo=UTC)
    out = []
    for i in range(n):
        t = (t0 + timedelta(seconds=start_s + i)).strftime("%Y-%m-%dT%H:%M:%S.000Z")
        out.append(f"{t},51.5{i:04d},-0.1{i:04d},{speed_kmh},{speed_kmh},{100 + i * 0.1:.1f}")
    return out


def srf_file(tmp_path: Path, rows: list[str], name: str = "log.csv", header: str = SRF_HEADER,
             meta: str = "# vehicle_id=BUS-1\n") -> Path:
    return write(tmp_path / name, meta + header + "\n" + "\n".join(rows) + "\n")


def raises_at(match: str, line: int | None = None, column: str | None = None):
    """Context manager: InputError whose message matches and whose line/column are given."""

    class _Ctx:
        def __enter__(self):
            self.cm = pytest.raises(InputError, match=match)
            self.info = self.cm.__enter__()
            return self.info

        def __exit__(self, *exc):
            ok = self.cm.__exit__(*exc)
            err = self.info.value
            assert err.line == line, f"line {err.line} != {line}: {err}"
            assert err.column == column, f"column {err.column!r} != {column!r}: {err}"
            return ok

    return _Ctx()


# ======================================================================================
# Profiles
# ======================================================================================
def test_builtin_profiles_load(profiles):
    assert set(profiles) >= {"srf", "portal", "twizy"}
    tw = profiles["twizy"]
    [soc] = tw.energy
    assert soc.kind == "soc" and soc.quantity == "energy_j"
    assert soc.capacity_j == pytest.approx(6.1 * 3.6e6)  # 6.1 kWh
    assert soc.resolution == pytest.approx(0.01)
    srf = {e.column: e for e in profiles["srf"].energy}
    assert srf["total_fuel_l"].resolution == pytest.approx(0.5)
    assert srf["fuel_rate_lps"].resolution == pytest.approx(0.05 / 3600)
    assert srf["total_energy_j"].resolution == pytest.approx(0.1 * 3.6e6)
    assert srf["flowmeter_fuel_lps"].priority < srf["total_fuel_l"].priority
    assert profiles["portal"].energy[0].resolution == 0.5


def test_shipped_energy_sources_declare_their_accuracy(profiles):
    """Every shipped [[energy]] entry states its systematic uncertainty (a meter's
    calibration error is common to all its trips, not scatter)."""
    for prof in profiles.values():
        if prof.path is not None and prof.path.parent.name == "loggers":
            for e in prof.energy:
                assert e.accuracy_pct is not None and 0 < e.accuracy_pct < 10, (prof.name, e.column)
    srf = {e.column: e for e in profiles["srf"].energy}
    assert srf["flowmeter_fuel_lps"].accuracy_pct < srf["fuel_rate_lps"].accuracy_pct


def test_unit_table_and_dimensions_cover_canonical_columns():
    mappable = set(CANONICAL_COLUMNS) - {"time_s", "source_line", "vehicle_id"}
    assert set(CANONICAL_DIMENSIONS) == mappable
    assert set(PLAUSIBLE_RANGE_SI) == mappable
    assert UNITS["mph"][1] == pytest.approx(MPH)
    assert UNITS["mi"][1] == pytest.approx(MILE)
    assert UNITS["kWh"][1] == 3.6e6
    assert UNITS["l/h"][1] == pytest.approx(1 / 3600)


BASE_PROFILE = {
    "name": "mine",
    "detect": {"required_columns": ["t", "v"]},
    "time": {"columns": ["t"], "format": "ISO8601", "timezone": "UTC"},
    "columns": {"wheel_speed_mps": {"source": "v", "unit": "km/h"}},
}


@pytest.mark.parametrize(
    "patch, key",
    [
        ({"colums": {}}, "colums"),
        ({"csv": {"encodin": "utf-8"}}, "csv.encodin"),
        ({"csv": {"encoding": "klingon"}}, "csv.encoding"),
        ({"time": {"columns": ["t"], "format": "ISO8601", "timezone": "Mars/Olympus"}}, "time.timezone"),
        ({"columns": {"wheel_speed_mps": {"source": "v", "unit": "furlong/fortnight"}}},
         "columns.wheel_speed_mps.unit"),
        ({"columns": {"wheel_speed_mps": {"source": "v", "unit": "kWh"}}}, "columns.wheel_speed_mps.unit"),
        ({"columns": {"speed": {"source": "v", "unit": "km/h"}}}, "columns.speed"),
        ({"vehicle": {"source": "column"}}, "vehicle.key"),
        ({"energy": [{"column": "wheel_speed_mps", "kind": "rate", "priority": 1}]}, "energy[0].column"),
        ({"time": {"columns": ["t"], "format": "ISO8601", "date_repair": "dominant"}}, "time.date_repair"),
        ({"columns": {"wheel_speed_mps": {"source": "v", "unit": "km/h"}, "total_fuel_l": {"source": "f", "unit": "l"}},
          "energy": [{"column": "total_fuel_l", "kind": "counter", "priority": 1, "accuracy_pct": -1.0}]},
         "energy[0].accuracy_pct"),
        ({"columns": {"wheel_speed_mps": {"source": "v", "unit": "km/h"}, "total_fuel_l": {"source": "f", "unit": "l"}},
          "energy": [{"column": "total_fuel_l", "kind": "counter", "priority": 1, "accuracy_pct": 100.0}]},
         "energy[0].accuracy_pct"),
    ],
)
def test_bad_profile_keys_are_named(tmp_path, patch, key):
    doc = {**BASE_PROFILE, **patch}
    with pytest.raises(InputError) as info:
        load_profile(doc, path=tmp_path / "mine.toml")
    assert info.value.column == key, str(info.value)


def test_profile_toml_error_names_file(tmp_path):
    bad = write(tmp_path / "bad.toml", "name = 'x'\n[detect\n")
    with pytest.raises(InputError, match="not a valid TOML"):
        load_profile(bad)


def test_env_var_adds_user_profile(tmp_path, monkeypatch):
    user = tmp_path / "profiles"
    user.mkdir()
    write(user / "mine.toml", """
name = "mine"
[detect]
required_columns = ["when", "kmh"]
[time]
columns = ["when"]
format = "%Y/%m/%d %H:%M:%S"
timezone = "UTC"
[vehicle]
source = "parent_dir"
[columns]
wheel_speed_mps = { source = "kmh", unit = "km/h" }
""")
    monkeypatch.setenv("CEVM_PROFILES", str(user))
    profs = load_profiles()
    assert {"srf", "portal", "twizy", "mine"} <= set(profs)
    veh = tmp_path / "VAN-3"
    veh.mkdir()
    f = write(veh / "x.csv", "when,kmh\n2021/01/02 03:04:05,72\n2021/01/02 03:04:06,36\n")
    assert detect_profile(f, profs).name == "mine"
    [log] = read_log(f, profiles=profs)
    assert log.vehicle_id == "VAN-3"
    assert log.frame["time_s"].tolist() == [utc_s(2021, 1, 2, 3, 4, 5), utc_s(2021, 1, 2, 3, 4, 6)]
    assert log.frame["wheel_speed_mps"].tolist() == pytest.approx([20.0, 10.0])


# ======================================================================================
# srf
# ======================================================================================
def test_srf_sample(profiles):
    path = DATA / "srf_sample.csv"
    assert detect_profile(path, profiles).name == "srf"
    [log] = read_log(path, profiles=profiles)
    fr = log.frame
    assert log.profile == "srf" and log.vehicle_id == "EB-07"
    assert log.metadata == {"vehicle_id": "EB-07", "logger": "SRF Logger 2.4.1", "started": "2019-05-14T06:58:12Z"}
    assert log.sha256 == hashlib.sha256(path.read_bytes()).hexdigest()
    assert log.repairs == []
    # 3 metadata lines + header: data from line 5, file order kept (repeats, gaps, step back)
    assert fr["source_line"].tolist() == list(range(5, 13))
    base = utc_s(2019, 5, 14, 7, 0, 0)
    assert fr["time_s"].to_numpy() - base == pytest.approx([0.25, 1.25, 2.25, 2.25, 5.25, 6.25, 5.75, 6.75], abs=1e-6)
    assert (fr["vehicle_id"] == "EB-07").all()
    assert fr["wheel_speed_mps"].tolist() == pytest.approx([0.0, 1.0, 2.0, 2.0, 5.0, 6.0, 6.0, 7.0])
    lat = fr["lat_deg"].to_numpy()
    assert np.isnan(lat[[1, 5, 7]]).all() and lat[0] == pytest.approx(52.205337)
    assert fr["total_fuel_l"].to_numpy()[[0, 4]] == pytest.approx([12345.5, 12346.0])
    assert np.isnan(fr["total_fuel_l"].to_numpy()[[1, 2, 3, 5, 6, 7]]).all()
    assert fr["flowmeter_fuel_lps"].iloc[1] == pytest.approx(1.17 / 3600)
    assert fr["fuel_rate_lps"].iloc[4] == pytest.approx(8.5 / 3600)
    assert fr["gross_weight_kg"].iloc[4] == 18010
    assert fr["brake_switch"].tolist() == [1, 0, 0, 0, 0, 0, 0, 0]
    # energy sources present in this file, with SI resolutions
    src = {e.column: e for e in log.energy_sources}
    assert set(src) == {"flowmeter_fuel_lps", "total_fuel_l", "fuel_rate_lps"}
    assert src["total_fuel_l"] == EnergySource("total_fuel_l", "counter", "fuel_l", 0.5, 2, None,
                                               "fms_total_fuel_used_l", 2.0**31, 3.0)
    assert src["flowmeter_fuel_lps"].priority == 1
    # lines int32; a column in SI as logged whose every value is exactly a float32 (the
    # 0/1 switch, the 0.5 l counter, whole kg) is float32, every other one float64 (the
    # speeds are converted from km/h; 10.4 %, 15.2 m, 0.9 and 52.205337 are not float32)
    assert str(fr["source_line"].dtype) == "int32"
    narrow = {"brake_switch", "total_fuel_l", "gross_weight_kg"}
    assert {c for c in fr.columns if str(fr[c].dtype) == "float32"} == narrow
    assert all(str(fr[c].dtype) == "float64" for c in fr.columns if c not in (*narrow, "source_line", "vehicle_id"))


def test_srf_electric_energy_sources(tmp_path, profiles):
    head = ("timestamp_utc,fms_wheel_speed_kmh,fms_battery_voltage_v,fms_battery_current_a,fms_battery_soc_pct,"
            "fms_total_energy_used_kwh")
    rows = ["2020-06-01T10:00:00.000Z,36,650.5,120.0,80.0,1000.0", "2020-06-01T10:00:01.000Z,36,,,,",
            "2020-06-01T10:00:02.000Z,36,650.0,-40.0,79.9,1000.1"]
    [log] = read_log(srf_file(tmp_path, rows, header=head), profiles=profiles)
    src = {e.column: e for e in log.energy_sources}
    assert set(src) == {"total_energy_j", "battery_power_w", "soc_pct"}
    assert src["total_energy_j"].priority < src["battery_power_w"].priority < src["soc_pct"].priority
    assert src["battery_power_w"].kind == "rate" and src["battery_power_w"].quantity == "energy_j"
    assert src["battery_power_w"].source_column == "fms_battery_voltage_v*fms_battery_current_a"
    assert src["soc_pct"].capacity_j is None  # vehicle-specific: from the vehicle config
    assert log.frame["battery_current_a"].tolist()[::2] == [120.0, -40.0]
    assert log.frame["total_energy_j"].iloc[2] == pytest.approx(1000.1 * 3.6e6)


def test_srf_slow_path_equals_fast_path(tmp_path, profiles):
    """Timestamp not in the first column (or quoted fields) disables the byte-level fast
    path; the result must be the same."""
    text = (DATA / "srf_sample.csv").read_text()
    lines = text.splitlines()
    moved = []
    for ln in lines:
        if ln.startswith("#"):
            moved.append(ln)
        else:
            first, rest = ln.split(",", 1)
            moved.append(rest + "," + first)
    f = write(tmp_path / "moved.csv", "\n".join(moved) + "\n")
    [a] = read_log(DATA / "srf_sample.csv", profiles=profiles)
    [b] = read_log(f, profiles=profiles)
    assert a.frame.equals(b.frame[a.frame.columns])


def test_srf_vehicle_fallback_to_file_stem(tmp_path, profiles):
    f = srf_file(tmp_path, srf_rows(3), name="EB-09_2020-06-01.csv", meta="# logger=x\n")
    [log] = read_log(f, profiles=profiles)
    assert log.vehicle_id == "EB-09_2020-06-01"
    assert any("file stem" in r for r in log.repairs)
    [log2] = read_log(f, profiles=profiles, vehicle_id="OVERRIDE")
    assert log2.vehicle_id == "OVERRIDE"


def test_srf_blank_lines_and_bom_and_crlf(tmp_path, profiles):
    rows = srf_rows(4)
    text = "\ufeff# vehicle_id=A\r\n" + SRF_HEADER + "\r\n" + rows[0] + "\r\n\r\n" + "\r\n".join(rows[1:]) + "\r\n"
    [log] = read_log(write(tmp_path / "x.csv", text), profiles=profiles)
    assert log.frame["source_line"].tolist() == [3, 5, 6, 7]
    assert any("blank" in r and "line 4" in r for r in log.repairs)
    assert log.frame["time_s"].tolist() == [utc_s(2020, 6, 1, 10, 0, s) for s in range(4)]


def test_gzip_by_magic_bytes(tmp_path, profiles):
    raw = (DATA / "srf_sample.csv").read_bytes()
    gz = tmp_path / "sample.csv.gz"
    gz.write_bytes(gzip.compress(raw))
    disguised = tmp_path / "sample_really_gzip.csv"
    shutil.copy(gz, disguised)
    [ref] = read_log(DATA / "srf_sample.csv", profiles=profiles)
    for f in (gz, disguised):
        assert detect_profile(f, profiles).name == "srf"
        [log] = read_log(f, profiles=profiles)
        assert log.frame.equals(ref.frame)
        assert log.sha256 == hashlib.sha256(f.read_bytes()).hexdigest()  # bytes on disk
    bad = write(tmp_path / "broken.csv.gz", gzip.compress(raw)[:40])
    with raises_at("corrupt gzip"):
        read_log(bad, "srf", profiles)


# ======================================================================================
# portal
# ======================================================================================
def test_portal_fixture_is_cp1252_crlf():
    raw = (DATA / "portal_dst.csv").read_bytes()
    assert b"\r\n" in raw and b"\xa3" in raw and b"\xe9" in raw  # CRLF, '£', 'é' in cp1252
    with pytest.raises(UnicodeDecodeError):
        raw.decode("utf-8")


def test_portal_two_vehicles_and_dst(profiles):
    path = DATA / "portal_dst.csv"
    assert detect_profile(path, profiles).name == "portal"
    logs = read_log(path, profiles=profiles)
    assert [g.vehicle_id for g in logs] == ["AB12 CDE", "XY19 ZZZ"]
    a, b = (g.frame for g in logs)
    # local -> UTC worked out by hand: GMT = UTC, BST = UTC+1;
    # spring 31/03/2024 01:00 GMT -> 02:00 BST; autumn 27/10/2024 02:00 BST -> 01:00 GMT
    expect_a = [
        utc_s(2024, 3, 31, 0, 59, 50), utc_s(2024, 3, 31, 0, 59, 55),
        utc_s(2024, 3, 31, 1, 0, 0), utc_s(2024, 3, 31, 1, 0, 5),
        utc_s(2024, 10, 26, 23, 59, 59), utc_s(2024, 10, 27, 0, 0, 4), utc_s(2024, 10, 27, 0, 59, 58),
        utc_s(2024, 10, 27, 1, 0, 3), utc_s(2024, 10, 27, 1, 30, 0), utc_s(2024, 10, 27, 2, 0, 5),
    ]
    expect_b = [utc_s(2024, 10, 27, 0, 10, 0), utc_s(2024, 10, 27, 0, 20, 0), utc_s(2024, 10, 27, 1, 0, 30)]
    assert a["time_s"].tolist() == expect_a
    assert b["time_s"].tolist() == expect_b
    assert (np.diff(a["time_s"]) > 0).all() and (np.diff(b["time_s"]) > 0).all()
    assert a["source_line"].tolist() == [2, 3, 4, 5, 6, 8, 9, 11, 12, 14]
    assert b["source_line"].tolist() == [7, 10, 13]
    # decimal comma and units
    assert a["lat_deg"].iloc[0] == pytest.approx(51.501364)
    assert a["lon_deg"].iloc[0] == pytest.approx(-0.141890)
    assert a["gps_speed_mps"].iloc[0] == pytest.approx(12.5 * MPH)
    assert a["odometer_m"].iloc[0] == pytest.approx(10234.1 * MILE)
    assert a["total_fuel_l"].iloc[-1] == pytest.approx(5415.5)
    assert a["ignition"].tolist() == [1, 1, 1, 0, 1, 1, 1, 1, 1, 0]
    assert b["ignition"].tolist() == [1, 1, 0]
    assert [e.column for e in logs[0].energy_sources] == ["total_fuel_l"]
    assert any("repeated hour" in r for r in logs[0].repairs)


def test_portal_nonexistent_spring_time(tmp_path, profiles):
    head = "Registration;Date/Time;Latitude;Longitude;Speed (mph);Odometer (mi);Fuel Used (l);Ignition;Event\r\n"
    rows = ["V1;31/03/2024 00:59:59;51,5;-0,1;10;1;1;On;", "V1;31/03/2024 01:30:00;51,5;-0,1;10;1;1;On;",
            "V1;31/03/2024 02:45:00;51,5;-0,1;10;1;1;On;"]
    f = write(tmp_path / "p.csv", (head + "\r\n".join(rows) + "\r\n").encode("cp1252"))
    [log] = read_log(f, profiles=profiles)
    # 01:30 does not exist in London that day: read as GMT (clock not yet changed) = 01:30 UTC
    assert log.frame["time_s"].tolist() == [utc_s(2024, 3, 31, 0, 59, 59), utc_s(2024, 3, 31, 1, 30, 0),
                                           utc_s(2024, 3, 31, 1, 45, 0)]
    assert any("do not exist" in r and "line 3" in r for r in log.repairs)


def test_portal_unmapped_ignition_value(tmp_path, profiles):
    head = "Registration;Date/Time;Latitude;Longitude;Speed (mph);Odometer (mi);Fuel Used (l);Ignition;Event\r\n"
    rows = ["V1;01/06/2024 10:00:00;51,5;-0,1;10;1;1; on ;", "V1;01/06/2024 10:00:05;51,5;-0,1;10;1;1;Maybe;"]
    f = write(tmp_path / "p.csv", (head + "\r\n".join(rows) + "\r\n").encode("cp1252"))
    with raises_at("not in the profile's map.*'Maybe'", line=3, column="Ignition"):
        read_log(f, profiles=profiles)


def test_portal_empty_registration(tmp_path, profiles):
    head = "Registration;Date/Time;Latitude;Longitude;Speed (mph);Odometer (mi);Fuel Used (l);Ignition;Event\r\n"
    rows = ["V1;01/06/2024 10:00:00;51,5;-0,1;10;1;1;On;", ";01/06/2024 10:00:05;51,5;-0,1;10;1;1;On;"]
    f = write(tmp_path / "p.csv", (head + "\r\n".join(rows) + "\r\n").encode("cp1252"))
    with raises_at("empty vehicle id", line=3, column="Registration"):
        read_log(f, profiles=profiles)


# ======================================================================================
# twizy
# ======================================================================================
CASA = ZoneInfo("Africa/Casablanca")


def casa_utc_s(month_day_year: str, hms: str) -> float:
    """Reference: local Moroccan wall time -> UTC seconds with zoneinfo."""
    m, d, y = (int(x) for x in month_day_year.split("/"))
    hh, mm, ss = (int(x) for x in hms.split(":"))
    return datetime(y, m, d, hh, mm, ss, tzinfo=CASA).timestamp()


def test_twizy_excerpt_dates_repaired(profiles):
    path = DATA / "twizy_excerpt.csv"
    assert detect_profile(path, profiles).name == "twizy"
    [log] = read_log(path, profiles=profiles)
    fr = log.frame
    assert len(fr) == 250 and log.vehicle_id == "RSK-Twizy"
    rows = [ln.split(",") for ln in path.read_text().splitlines()[1:]]
    # every row, corrupt or not, is 06/30/2021 at its own (clean) time of day
    expect = [casa_utc_s("06/30/2021", r[1]) for r in rows]
    assert fr["time_s"].tolist() == expect
    assert (np.diff(fr["time_s"]) == 1.0).all()
    # 30 June 2021 Morocco is UTC+1: 13:34:01 local is 12:34:01 UTC
    assert fr["time_s"].iloc[0] == utc_s(2021, 6, 30, 12, 34, 1)
    [date_rep] = [r for r in log.repairs if r.startswith("time:")]
    assert "19 rows" in date_rep and "'03/00/2000'" in date_rep and "lines 24-42" in date_rep
    # the altitude marker -111 -> NaN, other values in metres
    alt = fr["gps_alt_m"].to_numpy()
    raw_alt = np.array([float(r[7]) for r in rows])
    assert np.isnan(alt[raw_alt == -111]).all() and (raw_alt == -111).sum() == 37
    assert alt[raw_alt != -111] == pytest.approx(raw_alt[raw_alt != -111])
    assert any("-111" in r and "lines 215-251" in r for r in log.repairs)
    # units: Speed (CAN) and GpsSpeed km/h -> m/s
    assert fr["wheel_speed_mps"].iloc[0] == pytest.approx(35.29 / 3.6)
    assert fr["gps_speed_mps"].iloc[0] == pytest.approx(49.541 / 3.6)
    assert fr["soc_pct"].iloc[0] == pytest.approx(94.16)
    [soc] = log.energy_sources
    assert (soc.kind, soc.column, soc.source_column) == ("soc", "soc_pct", "Soc")
    assert soc.capacity_j == pytest.approx(21.96e6)


def test_twizy_excerpt_junk_gps(profiles):
    [log] = read_log(DATA / "twizy_excerpt_gps.csv", profiles=profiles)
    lat, lon = log.frame["lat_deg"].to_numpy(), log.frame["lon_deg"].to_numpy()
    bad = np.zeros(20, bool)
    bad[10:13] = True  # excerpt lines 12-14
    assert np.isnan(lat[bad]).all() and np.isnan(lon[bad]).all()
    assert np.isfinite(lat[~bad]).all() and np.isfinite(lon[~bad]).all()
    assert any("lon_deg" in r and "1555.63" in r and "lines 12-14" in r for r in log.repairs)
    # unpadded M/D/Y date 6/7/2021 (7 June, not 6 July)
    assert log.frame["time_s"].iloc[0] == casa_utc_s("6/7/2021", "16:24:32") == utc_s(2021, 6, 7, 15, 24, 32)


TWIZY_HEADER = ("Date,Time,Soc,Speed,Mode,LAT,LON,ALT,GpsSpeed,Temperature,Humidity,Weather,WindSpeedAv,Traffic,"
                "SpeedLimit")


def twizy_row(date: str, hms: str, lat: str = "33.98", lon: str = "-6.72") -> str:
    return f"{date},{hms},80.0,10.0,D,{lat},{lon},100.0,10.0,20.0,60.0,Clouds,2.0,0,40.0"


def test_twizy_date_repair_across_midnight(tmp_path, profiles):
    rows = [twizy_row("3/29/2021", "23:59:57"), twizy_row("3/29/2021", "23:59:58"),
            twizy_row("90/02/2032", "23:59:59"), twizy_row("29/00/2003", "00:00:00"),
            twizy_row("3/30/2021", "00:00:01")]
    f = write(tmp_path / "t.csv", TWIZY_HEADER + "\n" + "\n".join(rows) + "\n")
    [log] = read_log(f, profiles=profiles)
    expect = [casa_utc_s("3/29/2021", "23:59:57"), casa_utc_s("3/29/2021", "23:59:58"),
              casa_utc_s("3/29/2021", "23:59:59"), casa_utc_s("3/30/2021", "00:00:00"),
              casa_utc_s("3/30/2021", "00:00:01")]
    assert log.frame["time_s"].tolist() == expect
    assert (np.diff(log.frame["time_s"]) == 1).all()


def test_twizy_corrupt_dates_at_start_before_midnight(tmp_path, profiles):
    rows = [twizy_row("03/00/2000", "23:59:58"), twizy_row("03/00/2000", "23:59:59"),
            twizy_row("3/30/2021", "00:00:00"), twizy_row("3/30/2021", "00:00:01")]
    f = write(tmp_path / "t.csv", TWIZY_HEADER + "\n" + "\n".join(rows) + "\n")
    [log] = read_log(f, profiles=profiles)
    assert log.frame["time_s"].tolist() == [casa_utc_s("3/29/2021", "23:59:58"), casa_utc_s("3/29/2021", "23:59:59"),
                                           casa_utc_s("3/30/2021", "00:00:00"), casa_utc_s("3/30/2021", "00:00:01")]


def test_twizy_latitude_zero_is_no_fix(tmp_path, profiles):
    rows = [twizy_row("6/30/2021", f"10:00:0{i}", lat="0.000000" if i in (2, 3) else "33.99") for i in range(6)]
    f = write(tmp_path / "t.csv", TWIZY_HEADER + "\n" + "\n".join(rows) + "\n")
    [log] = read_log(f, profiles=profiles)
    assert np.isnan(log.frame["lat_deg"].to_numpy()[[2, 3]]).all()
    assert np.isnan(log.frame["lon_deg"].to_numpy()[[2, 3]]).all()
    assert any("exactly 0" in r and "lines 4-5" in r for r in log.repairs)


def test_date_repair_disabled_reports_line(tmp_path, profiles):
    prof = profiles["twizy"]
    from dataclasses import replace
    strict = replace(prof, time=replace(prof.time, date_repair="none"))
    rows = [twizy_row("6/30/2021", "10:00:00"), twizy_row("30/00/2006", "10:00:01")]
    f = write(tmp_path / "t.csv", TWIZY_HEADER + "\n" + "\n".join(rows) + "\n")
    with raises_at("unreadable date.*'30/00/2006'", line=3, column="Date"):
        read_log(f, strict)
    bad_time = write(tmp_path / "u.csv", TWIZY_HEADER + "\n" + twizy_row("6/30/2021", "10:61:00") + "\n")
    with raises_at("unreadable time of day.*'10:61:00'", line=2, column="Time"):
        read_log(bad_time, profiles=profiles)


def test_all_real_twizy_files(profiles, twizy_logs):
    folder, n_files = twizy_logs
    files = sorted(folder.glob("*.csv*"))
    assert len(files) == n_files
    report = []
    for f in files:
        [log] = read_log(f, profiles=profiles)
        assert log.profile == "twizy"
        t = log.frame["time_s"].to_numpy()
        text = gzip.decompress(f.read_bytes()).decode() if f.suffix == ".gz" else f.read_text()
        assert len(t) == len(text.splitlines()) - 1  # every data row kept
        assert (np.diff(t) > 0).all(), f.name
        # the local date of every row equals the session date in the file name (M_D_Y)
        m, d, y = (int(x) for x in re.search(r"_(\d\d)_(\d\d)_(\d{4})", f.name).groups())
        first = datetime.fromtimestamp(t[0], CASA)
        last = datetime.fromtimestamp(t[-1], CASA)
        assert first.date() == last.date() == datetime(y, m, d).date(), f.name
        assert t[-1] - t[0] < 4 * 3600
        report.append(f"{f.name}: {len(t)} rows; " + (" | ".join(log.repairs) or "no repairs"))
    print("\n".join(report))


# ======================================================================================
# Detection and forcing
# ======================================================================================
def test_detect_no_match_lists_profiles(tmp_path, profiles):
    f = write(tmp_path / "odd.csv", "when,where,how_fast\n1,2,3\n")
    with pytest.raises(InputError) as info:
        detect_profile(f, profiles)
    msg = str(info.value)
    assert "odd.csv" in msg and "srf" in msg and "portal" in msg and "twizy" in msg and "how_fast" in msg


def test_force_profile(tmp_path, profiles):
    with raises_at("unknown logger profile 'nope'"):
        read_log(DATA / "srf_sample.csv", "nope", profiles)
    # portal has no comment prefix: its header is line 1 of this file
    with raises_at(r"header lacks column\(s\) \['Registration'", line=1, column="Registration"):
        read_log(DATA / "srf_sample.csv", "portal", profiles)
    [log] = read_log(DATA / "srf_sample.csv", profiles["srf"])
    assert log.profile == "srf"


# ======================================================================================
# Bad input
# ======================================================================================
def test_empty_file(tmp_path, profiles):
    f = write(tmp_path / "e.csv", b"")
    with raises_at("file is empty", line=1):
        read_log(f, "srf", profiles)
    with raises_at("file is empty", line=1):
        detect_profile(f, profiles)


def test_header_only(tmp_path, profiles):
    f = write(tmp_path / "h.csv", "# vehicle_id=A\n" + SRF_HEADER + "\n")
    with raises_at("header only", line=3):
        read_log(f, "srf", profiles)
    g = write(tmp_path / "c.csv", "# vehicle_id=A\n# nothing else\n")
    with raises_at("no header line", line=3):
        read_log(g, "srf", profiles)


def test_truncated_last_line(tmp_path, profiles):
    rows = srf_rows(5)
    text = "# vehicle_id=A\n" + SRF_HEADER + "\n" + "\n".join(rows[:4]) + "\n" + rows[4][:30]
    f = write(tmp_path / "t.csv", text)
    [log] = read_log(f, "srf", profiles)
    assert log.frame["source_line"].tolist() == [3, 4, 5, 6]
    assert any("truncated last line" in r and "line 7" in r for r in log.repairs)
    from dataclasses import replace
    strict = replace(profiles["srf"], truncated_last_line="error")
    # rows[4][:30] is '2020-06-01T10:00:04.000Z,51.50': 2 fields, the second cut
    with raises_at("truncated last line: 2 of 6 fields", line=7, column="gps_lat_deg"):
        read_log(f, strict)
    # a complete last line without a final newline is fine
    g = write(tmp_path / "g.csv", "# vehicle_id=A\n" + SRF_HEADER + "\n" + "\n".join(rows))
    [log] = read_log(g, strict)
    assert len(log.frame) == 5 and log.repairs == []


def test_wrong_encoding(tmp_path, profiles):
    rows = srf_rows(3)
    text = ("# vehicle_id=A\n" + SRF_HEADER + "\n" + "\n".join(rows) + "\n").encode()
    bad = text.replace(b"51.50001", b"51.5\xe9001")  # cp1252 'e acute' inside a utf-8 file
    f = write(tmp_path / "w.csv", bad)
    with raises_at("0xe9 is not valid utf-8", line=4, column="gps_lat_deg"):
        read_log(f, "srf", profiles)


def test_binary_junk(tmp_path, profiles):
    png = write(tmp_path / "img.csv", b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR" + bytes(range(256)))
    with raises_at("0x89 is not valid utf-8", line=1):
        read_log(png, "srf", profiles)
    with pytest.raises(InputError, match="binary data, not a CSV text file"):
        detect_profile(png, profiles)
    nul = write(tmp_path / "nul.csv", b"timestamp_utc,gps_speed_kmh\n2020-01-01T00:00:00Z,1\n\x00\x00\x00\n")
    with raises_at("binary data", line=3):
        read_log(nul, "srf", profiles)


def test_no_usable_time_column(tmp_path):
    prof = load_profile({**BASE_PROFILE, "detect": {"required_columns": ["v"]}})
    f = write(tmp_path / "x.csv", "time,v\n2020-01-01T00:00:00Z,1\n")
    with raises_at("no time column: header lacks 't'", line=1, column="t"):
        read_log(f, prof)


def test_time_column_empty_or_unreadable(tmp_path, profiles):
    rows = srf_rows(4)
    rows[2] = "," + rows[2].split(",", 1)[1]  # empty timestamp on line 5
    f = srf_file(tmp_path, rows)
    with raises_at("unreadable or impossible time", line=5, column="timestamp_utc"):
        read_log(f, profiles=profiles)
    rows = srf_rows(4)
    rows[1] = "2020-06-01T10:00:61.000Z" + rows[1][24:]
    with raises_at("unreadable or impossible time '2020-06-01T10:00:61.000Z'", line=4, column="timestamp_utc"):
        read_log(srf_file(tmp_path, rows, name="b.csv"), profiles=profiles)
    rows = srf_rows(4)
    rows[3] = "1970-01-01T00:00:03.000Z" + rows[3][24:]  # unset clock
    with raises_at("impossible time", line=6, column="timestamp_utc"):
        read_log(srf_file(tmp_path, rows, name="c.csv"), profiles=profiles)


def test_no_position_no_speed(tmp_path, profiles):
    f = srf_file(tmp_path, ["2020-06-01T10:00:00.000Z,100.0", "2020-06-01T10:00:01.000Z,100.1"],
                 header="timestamp_utc,fms_total_energy_used_kwh")
    with raises_at("no position and no speed"):
        read_log(f, profiles=profiles)


def test_all_nan(tmp_path, profiles):
    rows = [r.split(",")[0] + ",,,,," for r in srf_rows(5)]
    with raises_at("no position and no speed"):
        read_log(srf_file(tmp_path, rows), profiles=profiles)
    rows = [",,,,," for _ in range(5)]
    with raises_at("no data rows with values", line=3):
        read_log(srf_file(tmp_path, rows, name="b.csv"), profiles=profiles)


def test_absurd_values_few_are_nan(tmp_path, profiles):
    rows = srf_rows(40)
    parts = rows[10].split(",")
    parts[4] = "900"  # wheel speed 900 km/h on line 13
    rows[10] = ",".join(parts)
    parts = rows[20].split(",")
    parts[1] = "95.0"  # latitude 95 on line 23
    rows[20] = ",".join(parts)
    [log] = read_log(srf_file(tmp_path, rows), profiles=profiles)
    fr = log.frame
    assert np.isnan(fr["wheel_speed_mps"].iloc[10]) and fr["wheel_speed_mps"].iloc[9] == pytest.approx(10.0)
    assert np.isnan(fr["lat_deg"].iloc[20]) and np.isnan(fr["lon_deg"].iloc[20])
    assert any("wheel_speed_mps" in r and "line 13" in r for r in log.repairs)
    assert any("lat_deg" in r and "line 23" in r for r in log.repairs)


def test_absurd_values_whole_column_is_error(tmp_path, profiles):
    rows = srf_rows(10, speed_kmh=900.0)  # looks like a wrong unit
    with raises_at("10 of 10 values are impossible for gps_speed_mps", line=3, column="gps_speed_kmh"):
        read_log(srf_file(tmp_path, rows), profiles=profiles)


def _requiring(prof, source: str):
    """``prof`` with the column ``source`` required (every cell a number)."""
    from dataclasses import replace

    return replace(prof, columns=tuple(replace(m, required=True) if m.source == source else m for m in prof.columns))


def test_not_a_number_in_a_required_column_is_an_error(tmp_path, profiles):
    rows = srf_rows(5)
    rows[3] = rows[3].rsplit(",", 1)[0] + ",abc"
    with raises_at("not a number: 'abc'", line=6, column="fms_total_energy_used_kwh"):
        read_log(srf_file(tmp_path, rows), _requiring(profiles["srf"], "fms_total_energy_used_kwh"))


@pytest.mark.parametrize("cell", ["ERR", "abc", "---", "#N/A", "#VALUE!", "error"])
def test_a_bad_cell_in_a_measured_column_is_a_missing_value_with_a_note(tmp_path, profiles, cell):
    """One 'ERR' in a measured column (an energy counter here, a flow meter on a
    truck) cost the whole day's log. Now it is a missing value, as 'N/A' is, and the
    repair names the line and the column; the other rows are read as written."""
    rows = srf_rows(6)
    rows[3] = rows[3].rsplit(",", 1)[0] + "," + cell  # line 2 + 4 = 6
    [log] = read_log(srf_file(tmp_path, rows), profiles=profiles)
    e = log.frame["total_energy_j"].to_numpy()
    assert np.isnan(e[3]) and e[2] == pytest.approx(100.2 * 3.6e6) and e[4] == pytest.approx(100.4 * 3.6e6)
    notes = [r for r in log.repairs if "not numbers" in r]
    assert len(notes) == 1 and "'fms_total_energy_used_kwh'" in notes[0] and notes[0].endswith("line 6")
    assert repr(cell) in notes[0]


def test_a_value_written_with_its_unit_is_read_as_that_number(tmp_path, profiles):
    """'36.5 km/h' in a km/h column is 36.5 km/h (any case and spacing), reported; '36.5 mph'
    there is not a km/h value: a missing one, reported."""
    rows = srf_rows(6)
    rows[2] = rows[2].replace(",36.0,36.0,", ",36.0,36.5 km/h,", 1)  # line 5: the wheel speed
    rows[3] = rows[3].replace(",36.0,36.0,", ",36.0,36.5KM/H,", 1)  # line 6
    rows[4] = rows[4].replace(",36.0,36.0,", ",36.0,36.5 mph,", 1)  # line 7
    [log] = read_log(srf_file(tmp_path, rows), profiles=profiles)
    v = log.frame["wheel_speed_mps"].to_numpy()
    assert v[2] == pytest.approx(36.5 / 3.6) and v[3] == pytest.approx(36.5 / 3.6) and np.isnan(v[4])
    assert any("2 values written with their unit ('km/h')" in r and r.endswith("lines 5-6") for r in log.repairs)
    assert any("'36.5 mph'" in r and r.endswith("line 7") for r in log.repairs)


def test_a_column_of_mostly_bad_cells_is_refused(tmp_path, profiles):
    """More than the profile's absurd_error_share of a column not numbers: not what the
    profile says the column is (a wrong decimal mark, a wrong column), an error at the
    first such cell."""
    rows = [r.rsplit(",", 1)[0] + ",12;5" for r in srf_rows(6)]
    with raises_at("6 of 6 cells are not numbers", line=3, column="fms_total_energy_used_kwh"):
        read_log(srf_file(tmp_path, rows), profiles=profiles)


def test_na_like_text_is_nan(tmp_path, profiles):
    rows = srf_rows(3)
    rows[1] = rows[1].rsplit(",", 1)[0] + ",N/A"
    [log] = read_log(srf_file(tmp_path, rows), profiles=profiles)
    assert np.isnan(log.frame["total_energy_j"].iloc[1])
    assert log.frame["total_energy_j"].iloc[0] == pytest.approx(100.0 * 3.6e6)


def test_too_many_fields(tmp_path, profiles):
    rows = srf_rows(5)
    rows[2] += ",1,2"
    with raises_at("malformed CSV: 8 fields, more than the 6 of the header", line=5):
        read_log(srf_file(tmp_path, rows), profiles=profiles)
    # with quotes in the file the tokenizer checks the counts
    rows[0] = rows[0].replace("51.5", '"51.5') .replace(",-0.1", '",-0.1', 1)
    with raises_at("malformed CSV: Expected 6 fields in this line, saw 8", line=5):
        read_log(srf_file(tmp_path, rows, name="q.csv"), profiles=profiles)


def test_trailing_separators_are_harmless(tmp_path, profiles):
    rows = [r + ",," for r in srf_rows(4)]
    [log] = read_log(srf_file(tmp_path, rows), profiles=profiles)
    [ref] = read_log(srf_file(tmp_path, srf_rows(4), name="ref.csv"), profiles=profiles)
    assert log.frame.equals(ref.frame)
    rows[2] = rows[2][:-2] + ",x,"  # a non-empty surplus field is not
    with raises_at("malformed CSV: 8 fields, more than the 6", line=5):
        read_log(srf_file(tmp_path, rows, name="b.csv"), profiles=profiles)


def test_fewer_fields_reported(tmp_path, profiles):
    rows = srf_rows(5)
    rows[2] = ",".join(rows[2].split(",")[:4])
    [log] = read_log(srf_file(tmp_path, rows), profiles=profiles)
    assert np.isnan(log.frame["wheel_speed_mps"].iloc[2]) and np.isnan(log.frame["total_energy_j"].iloc[2])
    assert log.frame["gps_speed_mps"].iloc[2] == pytest.approx(10.0)
    assert any("fewer fields" in r and "line 5" in r for r in log.repairs)


def test_missing_file(tmp_path, profiles):
    with raises_at("cannot read file"):
        read_log(tmp_path / "nope.csv", "srf", profiles)


# ======================================================================================
# Properties of the vectorised time parser
# ======================================================================================
@pytest.mark.slow
@settings(max_examples=60, deadline=None)
@given(st.lists(st.datetimes(min_value=datetime(1990, 1, 1), max_value=datetime(2099, 12, 31)), min_size=1,
                max_size=30),
       st.sampled_from(["%d/%m/%Y %H:%M:%S", "%Y-%m-%d %H:%M:%S", "%m/%d/%Y", "%H:%M:%S"]))
def test_parse_datetimes_matches_strptime(dts, fmt):
    texts = np.array([d.strftime(fmt) for d in dts], dtype=object)
    got = parse_datetimes(texts, fmt)
    epoch = datetime(1970, 1, 1)
    want = [int((datetime.strptime(s, fmt) - epoch) / timedelta(microseconds=1)) * 1000 for s in texts]
    assert got.tolist() == want


@settings(max_examples=60, deadline=None)
@given(st.lists(st.text(alphabet="0123456789/: -Tx", min_size=0, max_size=21), min_size=1, max_size=20))
def test_parse_datetimes_rejects_what_strptime_rejects(texts):
    fmt = "%d/%m/%Y %H:%M:%S"
    got = parse_datetimes(np.array(texts, dtype=object), fmt)
    for s, g in zip(texts, got, strict=True):
        try:
            datetime.strptime(s, fmt)
            ok = True
        except ValueError:
            ok = False
        if not ok:
            assert g == np.iinfo(np.int64).min, s


def test_iso_offsets_converted_to_utc(tmp_path):
    prof = load_profile({**BASE_PROFILE, "time": {"columns": ["t"], "format": "ISO8601", "timezone": "Europe/Paris"}})
    f = write(tmp_path / "x.csv", "v,t\n36,2021-07-01T12:00:00+02:00\n36,2021-07-01T12:00:01+02:00\n")
    [log] = read_log(f, prof)
    assert log.frame["time_s"].tolist() == [utc_s(2021, 7, 1, 10, 0, 0), utc_s(2021, 7, 1, 10, 0, 1)]
    # naive ISO times are local to the profile's zone (Paris, UTC+2 in July)
    g = write(tmp_path / "y.csv", "t,v\n2021-07-01T12:00:00,36\n")
    [log] = read_log(g, prof)
    assert log.frame["time_s"].tolist() == [utc_s(2021, 7, 1, 10, 0, 0)]


@settings(max_examples=80, deadline=None)
@given(st.text(alphabet="ab,\n\r", max_size=60), st.integers(1, 7))
def test_line_stats_match_plain_python(text, chunk):
    import cevm.ingest.reading.lines as loggers

    data = text.encode()
    old = loggers._CHUNK_BYTES
    loggers._CHUNK_BYTES = chunk  # exercise lines spanning chunk borders
    try:
        starts, n_sep = loggers._line_stats(np.frombuffer(data, np.uint8), ord(","))
    finally:
        loggers._CHUNK_BYTES = old
    want_starts, want_counts, pos = [], [], 0
    for line in data.split(b"\n"):
        if pos < len(data):
            want_starts.append(pos)
            want_counts.append(line.count(b","))
        pos += len(line) + 1
    assert starts.tolist() == want_starts and n_sep.tolist() == want_counts


def test_ascii_heads_skip_re_encoding_only_for_ascii_compatible_codecs(tmp_path, profiles):
    import pandas as pd

    from cevm.sniff import ascii_transparent as _ascii_transparent

    assert all(_ascii_transparent(e) for e in ("utf-8", "utf-8-sig", "cp1252", "latin-1", "ascii"))
    assert not any(_ascii_transparent(e) for e in ("utf-16", "utf-32", "utf-7", "cp500", "no-such-codec"))
    # the cp1252 portal export with its few non-ASCII bytes replaced: detected the same
    raw = (DATA / "portal_dst.csv").read_bytes()
    f = tmp_path / "ascii_portal.csv"
    f.write_bytes(bytes(b if b < 128 else ord("?") for b in raw))
    assert detect_profile(f, profiles).name == "portal"
    logs = read_log(f, profiles=profiles)
    assert [g.profile for g in logs] == ["portal", "portal"]
    want = read_log(DATA / "portal_dst.csv", profiles=profiles)
    for a, b in zip(logs, want, strict=True):
        pd.testing.assert_frame_equal(a.frame, b.frame)  # no used column held those bytes


def test_a_file_written_with_dots_under_a_decimal_comma_profile_is_named(tmp_path, profiles):
    # acceptance: a portal export saved with '.' decimals (another locale) failed with
    # pandas' "ValueError: cannot safely convert passed user dtype of float64 for object
    # dtyped data in column 2", no line, no column
    text = (DATA / "portal_dst.csv").read_bytes().decode("cp1252")
    head, *rows = text.split("\r\n")
    dotted = [";".join(f.replace(",", ".") for f in r.split(";")) for r in rows]
    path = tmp_path / "dots.csv"
    path.write_bytes("\r\n".join([head, *dotted]).encode("cp1252"))
    with raises_at("'51.501364' is written with a '.' but the profile 'portal' reads ',' as the decimal mark",
                   line=2, column="Latitude"):
        read_log(path, "portal", profiles)
