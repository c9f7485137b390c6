"""Values no logger of a road vehicle can mean: the physically possible range of each
canonical column (:data:`PLAUSIBLE_RANGE_SI`), impossible positions and times; a few are
repaired (set to NaN, reported), most are an error naming the line and column."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cevm.ingest.profiles import ColumnMap, Profile
from cevm.ingest.reading.lines import _line_col_error, _lines_summary
from cevm.ingest.timestamps import NAT

# Physically possible values (SI, inclusive). A value outside is *absurd*: a logger error
# or a wrong unit/column in the profile, never a real measurement. Chosen wide so that
# no real value of any road vehicle falls outside.
PLAUSIBLE_RANGE_SI: dict[str, tuple[float, float]] = {
    "lat_deg": (-90.0, 90.0),
    "lon_deg": (-180.0, 180.0),
    "gps_alt_m": (-500.0, 9000.0),  # Dead Sea shore -430 m .. highest roads ~5800 m + GPS error
    "gps_speed_mps": (0.0, 100.0),  # 360 km/h
    "wheel_speed_mps": (0.0, 100.0),
    "gps_hdop": (0.0, 100.0),  # 99.99 is the usual "no fix" value
    "ignition": (0.0, 1.0),
    "odometer_m": (0.0, 1e10),  # 10 million km
    "gross_weight_kg": (0.0, 200_000.0),
    "fuel_rate_lps": (0.0, 0.5),  # 1800 l/h
    "flowmeter_fuel_lps": (0.0, 0.5),
    "total_fuel_l": (0.0, 2.2e9),  # FMS counter maximum 0xFFFFFFFF * 0.5 l
    "total_energy_j": (-3.6e15, 3.6e15),  # +-1e9 kWh
    "battery_voltage_v": (0.0, 2000.0),
    "battery_current_a": (-5000.0, 5000.0),
    "soc_pct": (0.0, 100.0),
    "accel_pedal_pct": (0.0, 100.0),  # FMS codes above 100 % are error / not available
    "brake_switch": (0.0, 1.0),
    "engine_speed_rpm": (-30000.0, 30000.0),  # electric motors may report reverse as negative
    "engine_torque_pct": (-125.0, 125.0),
    # coldest and hottest air a road vehicle meets (-60 .. +57 degC on record) with margin;
    # the FMS "not available" code 0xFFFF reads 1775 degC and is caught
    "ambient_temp_c": (-80.0, 80.0),
    "hvac_power_w": (0.0, 150_000.0),  # a coach's heaters and A/C draw tens of kW
}


# Times outside this window are absurd (unset clocks read 1970 or 2000; corrupt dates).
_TIME_MIN = np.datetime64("1990-01-01T00:00:00", "ns").astype(np.int64)


_TIME_MAX = np.datetime64("2100-01-01T00:00:00", "ns").astype(np.int64)


def _check_times(path: Path, naive: np.ndarray, lines: np.ndarray, col: str, vals=None,
                 upto: int | None = None) -> None:
    """Unparseable or absurd (before 1990 or from 2100) times are errors with their line."""
    bad = (naive == NAT) | (naive < _TIME_MIN) | (naive >= _TIME_MAX)
    if bad.any():
        raise _line_col_error(path, "unreadable or impossible time", lines, bad, col, vals, upto)


def _absurd_verdict(n_bad: int, n_values: int, canon: str, src: str, lines: np.ndarray, bad: np.ndarray,
                    raw: np.ndarray, path: Path, prof: Profile, repairs: list[str], what: str,
                    unit: str | None) -> None:
    """Error or repair message for ``n_bad`` absurd values (``raw``: as logged)."""
    lo, hi = PLAUSIBLE_RANGE_SI[canon]
    u = f" {unit}" if unit and unit != "-" else ""
    if n_bad == n_values or n_bad > prof.absurd_error_share * n_values:
        raise _line_col_error(
            path, f"{n_bad} of {n_values} values are impossible for {canon} (allowed {lo:g}..{hi:g} in SI; "
                  f"wrong unit or column in profile {prof.name!r}?), first [{unit or '-'}]:",
            lines, bad, src, raw)
    repairs.append(f"{canon}: {n_bad} impossible {what} in column '{src}' (e.g. {raw[np.flatnonzero(bad)[0]]:g}{u}; "
                   f"allowed {lo:g}..{hi:g} in SI) set to NaN: {_lines_summary(lines[bad])}")


def _check_absurd(out: dict[str, np.ndarray], m: ColumnMap, lines: np.ndarray, path: Path,
                  prof: Profile, repairs: list[str]) -> None:
    """Mark values outside PLAUSIBLE_RANGE_SI as NaN and report them; too many -> error.

    Policy: absurd values that are a minority are logger glitches (NaN + repair, with
    count and lines); if every value, or more than ``profile.absurd_error_share`` of them
    (default 0.5: most values), is absurd, the profile's unit or column must be wrong and
    guessing would hide it: InputError at the first absurd line. A share, not a count,
    so that a burst of junk in a short file is still repaired, not refused.
    """
    x = out[m.canonical]
    lo, hi = (np.float64(b) for b in PLAUSIBLE_RANGE_SI[m.canonical])  # compared as float64 for float32 columns too
    with np.errstate(invalid="ignore"):
        bad = (x < lo) | (x > hi)
    if not bad.any():
        return
    n_values = int((~np.isnan(x)).sum())  # values logged, an infinite one too (it is among the absurd)
    as_logged = ((-x if m.negate else x) - m.offset) / m.factor  # for messages, in the logger's unit
    _absurd_verdict(int(bad.sum()), n_values, m.canonical, m.source, lines, bad, as_logged, path, prof,
                    repairs, "values", m.unit)
    x[bad] = np.nan


def _check_position(out: dict[str, np.ndarray], prof: Profile, lines: np.ndarray, path: Path,
                    repairs: list[str]) -> None:
    """A position is one fix: if latitude or longitude is impossible (|lat| > 90,
    |lon| > 180) or, with ``zero_position_is_no_fix``, exactly 0 (the value GPS modules
    write without a fix), both become NaN. A latitude column without a longitude column
    (or the reverse: a header cell lost) gives no positions, with a repair note. Zeros are never
    an error (a logger may have no GPS at all); impossible values follow the absurd-value policy."""
    if "lat_deg" not in out and "lon_deg" not in out:
        return
    if "lat_deg" not in out or "lon_deg" not in out:  # half a position is none: left out, and said
        have = "lat_deg" if "lat_deg" in out else "lon_deg"
        src = next((m.source for m in prof.columns if m.canonical == have), have)
        del out[have]
        repairs.append(f"position: column {src!r} without its {'longitude' if have == 'lat_deg' else 'latitude'} "
                       "column: no GPS positions read")
        return
    lat, lon = out["lat_deg"], out["lon_deg"]
    with np.errstate(invalid="ignore"):  # |x| > 90 without an array of |x|
        lat_bad, lon_bad = (lat > 90.0) | (lat < -90.0), (lon > 180.0) | (lon < -180.0)
    absurd = lat_bad | lon_bad
    zero = ((lat == 0.0) | (lon == 0.0)) & ~absurd if prof.zero_position_is_no_fix else np.zeros(len(lat), bool)
    n_values = int((~(np.isnan(lat) & np.isnan(lon))).sum())  # fixes logged (either half), infinite ones too
    for canon, bad, x in (("lat_deg", lat_bad, lat), ("lon_deg", lon_bad, lon)):
        if bad.any():
            src = next(m.source for m in prof.columns if m.canonical == canon)
            _absurd_verdict(int(bad.sum()), n_values, canon, src, lines, bad, x, path, prof, repairs,
                            "GPS fixes (the whole fix set to NaN)", "deg")
    if zero.any():
        repairs.append(f"position: {int(zero.sum())} GPS fixes with latitude or longitude exactly 0 (no fix) "
                       f"set to NaN: {_lines_summary(lines[zero])}")
    drop = absurd | zero
    if drop.any():
        lat[drop] = np.nan
        lon[drop] = np.nan
