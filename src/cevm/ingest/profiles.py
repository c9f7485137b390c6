"""Logger profiles: how each logger writes its CSV, loaded and validated.

A *profile* (a small TOML file, see ``configs/loggers/*.toml``) says how one logger
writes its CSV: how to recognise it from the header, text encoding, separator, decimal
mark, leading comment/metadata lines, where the time is and in which zone, where the
vehicle id comes from, which column feeds each canonical column (``CANONICAL_COLUMNS``
in :mod:`cevm.core.trip`) in which unit, and which columns measure energy. Supporting a new
logger means writing a profile, not code.

:func:`load_profile` reads and checks one profile (every key; a mistake names the file
and the key), :func:`load_profiles` the shipped ones (``configs/loggers``), a user's
directory and ``$CEVM_PROFILES``. Reading a file with a profile is
:mod:`cevm.ingest.reading`.

Profile format (all keys; ``[columns]`` entries and ``[[energy]]`` tables repeat)::

    name = "srf"                         # unique profile name
    description = "..."                  # free text
    [detect]
    required_columns = ["timestamp_utc"] # header must hold all of these
    [csv]
    encoding = "utf-8"                   # any Python codec name (utf-8, cp1252, utf-16, ...)
    separator = ","
    decimal = "."
    comment_prefix = "#"                 # leading lines starting with it are comments ("" = none)
    metadata = "key=value"               # parse comments as key=value, or "none"
    truncated_last_line = "drop"         # "drop" (and report) or "error"
    [time]
    columns = ["timestamp_utc"]          # one datetime column, or [date, time-of-day]
    format = "ISO8601"                   # one column: "ISO8601", a strptime format, or "unix_s" /
                                         # "unix_ms" (numbers since 1970-01-01 UTC; no zone applies)
    date_format = "%m/%d/%Y"             # two columns: strptime formats of each
    time_format = "%H:%M:%S"
    timezone = "UTC"                     # IANA zone of naive times
    date_repair = "none"                 # two columns only: "none" or "dominant"
    date_repair_max_days = 1             # a date further from the dominant one is corrupt
    [vehicle]
    source = "metadata"                  # metadata | column | file_stem | parent_dir | fixed
    key = "vehicle_id"                   # metadata key or column name
    value = "..."                        # for source = "fixed"
    fallback = "file_stem"               # when the metadata key is absent: file_stem | parent_dir | error
    [quality]
    zero_position_is_no_fix = true       # latitude or longitude exactly 0 -> no fix
    absurd_error_share = 0.5             # more absurd values than this share -> error
    [columns]
    wheel_speed_mps = { source = "fms_wheel_speed_kmh", unit = "km/h" }
    ignition = { source = "Ignition", map = { On = 1, Off = 0 } }
    gps_alt_m = { source = "ALT", unit = "m", missing_values = [-111] }
    ambient_temp_c = { source = "OAT", unit = "degF" }   # degC, K or degF (see UNITS)
    # per column also: required = true (error if absent from the header), negate = true
    # (not with K or degF: an offset scale)
    fuel_rate_lps = { source = "Fuel mass flow", unit = "g/s", density_kg_per_l = 0.835 }
    # fuel by mass (PEMS, gravimetric meters: g/s, kg/h; counters in kg): litres through
    # the fuel's stated density (required there, refused elsewhere; 0.6-1.0 kg/l);
    # [[energy]] resolution_unit / modulus_unit may then be mass units too
    [[energy]]
    column = "total_energy_j"            # canonical column carrying the measurement
    kind = "counter"                     # rate | counter | soc
    resolution = 0.1                     # quantisation step ...
    resolution_unit = "kWh"              # ... in this unit (converted to SI)
    priority = 1                         # 1 = most trusted
    capacity = 6.1                       # soc only: usable capacity ...
    capacity_unit = "kWh"                # ... in this unit
    modulus = 2147483648                 # counter only: wraps to 0 at this value ...
    modulus_unit = "l"                   # ... in this unit
    accuracy_pct = 1.0                   # systematic (calibration) uncertainty, 1 sigma, % of
                                         # the value (default by kind: cevm.ingest.consumption)
    # column may also be "battery_power_w" (rate, W): battery_voltage_v * battery_current_a

Defaults and why: encoding utf-8, separator ',', decimal '.' (the CSV norm); no comment
prefix and no metadata (most exports have none); ``truncated_last_line = "drop"`` (a
logger losing power mid-write leaves a cut last line; the rest of the file is good, and
the drop is reported); timezone UTC; ``date_repair = "none"`` (repairing is opt-in);
``date_repair_max_days = 1`` (a session lasts under a day, and a drive across midnight
keeps the next day's date); vehicle id from the file name stem; zero latitude or
longitude means no fix (GPS modules write 0 without one; a real fix exactly on the
equator or the Greenwich meridian, to the logged precision, is rare and losing it is
harmless); ``absurd_error_share = 0.5`` (see :func:`cevm.ingest.reading.plausibility._check_absurd`).
Energy ``priority`` has no default: trust is the profile author's statement.
"""

from __future__ import annotations

import os
import re
import tomllib
import zoneinfo
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, NamedTuple

from cevm.configs_dir import shipped_configs_dir
from cevm.errors import InputError
from cevm.ingest.timestamps import EPOCH_FORMATS
from cevm.io.inputs import MAX_TOML_BYTES, read_bounded
from cevm.lazy import pd
from cevm.units import (
    FT_TO_M,
    J_PER_KWH,
    J_PER_MJ,
    J_PER_WH,
    KG_PER_LB,
    KMH_TO_MPS,
    KNOT_TO_MPS,
    L_PER_GAL_IMP,
    L_PER_GAL_US,
    M_PER_MILE,
    MPH_TO_MPS,
    S_PER_H,
    W_PER_KW,
)

__all__ = [
    "CANONICAL_DIMENSIONS",
    "UNITS",
    "VIRTUAL_COLUMNS",
    "ColumnMap",
    "EnergySpec",
    "Profile",
    "TimeSpec",
    "Unit",
    "builtin_profile_dirs",
    "load_profile",
    "load_profiles",
]

# --------------------------------------------------------------------------------------
# Units: the only place where conversion factors live. Profiles name units; code looks
# them up here. unit name -> Unit(dimension, factor, offset): a value in the unit is
# ``value * factor + offset`` in the canonical unit of its dimension. SI units per
# dimension: angle deg, length m, speed m/s, volume l (litres by project convention),
# volume_rate l/s, energy J, power W, mass kg, voltage V, current A, percent %,
# rotational_speed rpm, temperature degC (the canonical columns say _c), dimensionless -,
# mass_rate kg/s (fuel by mass, see FUEL_MASS_DIMENSIONS).
# Only temperatures are affine (offset != 0): a temperature *difference* (a resolution)
# converts with the factor alone.
# --------------------------------------------------------------------------------------
class Unit(NamedTuple):
    """A unit: its dimension, and ``canonical = value * factor + offset``."""

    dimension: str
    factor: float
    offset: float = 0.0


UNITS: dict[str, Unit] = {
    "deg": Unit("angle", 1.0),
    "m": Unit("length", 1.0),
    "km": Unit("length", 1000.0),
    "mi": Unit("length", M_PER_MILE),
    "ft": Unit("length", FT_TO_M),
    "m/s": Unit("speed", 1.0),
    "km/h": Unit("speed", KMH_TO_MPS),
    "mph": Unit("speed", MPH_TO_MPS),
    "kn": Unit("speed", KNOT_TO_MPS),
    "l": Unit("volume", 1.0),
    "ml": Unit("volume", 1e-3),
    "gal_us": Unit("volume", L_PER_GAL_US),
    "gal_imp": Unit("volume", L_PER_GAL_IMP),
    "l/s": Unit("volume_rate", 1.0),
    "l/h": Unit("volume_rate", 1.0 / S_PER_H),
    "ml/s": Unit("volume_rate", 1e-3),
    "gal_us/h": Unit("volume_rate", L_PER_GAL_US / S_PER_H),
    "J": Unit("energy", 1.0),
    "kJ": Unit("energy", 1e3),
    "MJ": Unit("energy", J_PER_MJ),
    "Wh": Unit("energy", J_PER_WH),
    "kWh": Unit("energy", J_PER_KWH),
    "W": Unit("power", 1.0),
    "kW": Unit("power", W_PER_KW),
    "kg": Unit("mass", 1.0),
    "t": Unit("mass", 1000.0),
    "lb": Unit("mass", KG_PER_LB),
    "g": Unit("mass", 1e-3),
    "kg/s": Unit("mass_rate", 1.0),
    "kg/h": Unit("mass_rate", 1.0 / S_PER_H),
    "g/s": Unit("mass_rate", 1e-3),
    "g/h": Unit("mass_rate", 1e-3 / S_PER_H),
    "V": Unit("voltage", 1.0),
    "A": Unit("current", 1.0),
    "%": Unit("percent", 1.0),
    "rpm": Unit("rotational_speed", 1.0),
    "degC": Unit("temperature", 1.0),
    "K": Unit("temperature", 1.0, -273.15),
    "degF": Unit("temperature", 5.0 / 9.0, -32.0 * 5.0 / 9.0),
    "-": Unit("dimensionless", 1.0),
}


# Dimension of every mappable canonical column (time_s, source_line and vehicle_id are
# produced by the reader itself).
CANONICAL_DIMENSIONS: dict[str, str] = {
    "lat_deg": "angle",
    "lon_deg": "angle",
    "gps_alt_m": "length",
    "gps_speed_mps": "speed",
    "gps_hdop": "dimensionless",
    "wheel_speed_mps": "speed",
    "ignition": "dimensionless",
    "odometer_m": "length",
    "gross_weight_kg": "mass",
    "fuel_rate_lps": "volume_rate",
    "flowmeter_fuel_lps": "volume_rate",
    "total_fuel_l": "volume",
    "total_energy_j": "energy",
    "battery_voltage_v": "voltage",
    "battery_current_a": "current",
    "soc_pct": "percent",
    "accel_pedal_pct": "percent",
    "brake_switch": "dimensionless",
    "engine_speed_rpm": "rotational_speed",
    "engine_torque_pct": "percent",
    "ambient_temp_c": "temperature",
    "hvac_power_w": "power",
}


# Fuel given by mass (a PEMS or a gravimetric flow meter: g/s, kg/h; a counter in kg) is
# converted to litres with the density the profile states: canonical dimension -> the
# mass dimension that may feed it.
FUEL_MASS_DIMENSIONS: dict[str, str] = {"volume_rate": "mass_rate", "volume": "mass"}
#: Plausible densities of liquid fuels [kg/l]: petrol 0.72-0.78, diesel and HVO 0.77-0.85,
#: biodiesel 0.86-0.90 (EN 228, EN 590, EN 15940, EN 14214), with margin.
FUEL_DENSITY_RANGE_KG_PER_L = (0.6, 1.0)


# Energy source kinds and the canonical columns they may use.
_ENERGY_COLUMNS: dict[str, dict[str, str]] = {
    # kind -> {canonical column: quantity}
    "rate": {"fuel_rate_lps": "fuel_l", "flowmeter_fuel_lps": "fuel_l", "battery_power_w": "energy_j"},
    "counter": {"total_fuel_l": "fuel_l", "total_energy_j": "energy_j"},
    "soc": {"soc_pct": "energy_j"},
}


# Virtual energy columns: products of two canonical columns, formed by the consumption
# stage (cevm.ingest.consumption.BATTERY_POWER_COLUMN), not stored in the frame.
VIRTUAL_COLUMNS: dict[str, tuple[tuple[str, str], str]] = {
    "battery_power_w": (("battery_voltage_v", "battery_current_a"), "power"),  # W = V * A, + = discharge
}


# The profiles shipped with cevm: configs/loggers (a checkout's, or an installed wheel's).
_SHIPPED_PROFILES = shipped_configs_dir() / "loggers"


# Environment variable: extra profile directories (os.pathsep separated).
PROFILES_ENV = "CEVM_PROFILES"


@dataclass(frozen=True)
class ColumnMap:
    """How one canonical column is read: ``canonical = source * factor + offset`` (SI;
    ``offset`` is 0 except for temperatures in K or degF), or through ``value_map`` for
    categorical text (e.g. ``On`` -> 1.0).

    ``missing_values`` are numbers (in the source unit) that mean "no value" for this
    logger (e.g. the Twizy's altitude -111); they become NaN and are reported.
    """

    canonical: str
    source: str
    unit: str | None
    factor: float
    value_map: tuple[tuple[str, float], ...] | None = None
    missing_values: tuple[float, ...] = ()
    required: bool = False
    negate: bool = False
    offset: float = 0.0
    density_kg_per_l: float | None = None  # fuel given by mass: its density (factor includes it)


@dataclass(frozen=True)
class EnergySpec:
    """An energy measurement the profile's logger can provide (see :class:`EnergySource`)."""

    column: str
    kind: Literal["rate", "counter", "soc"]
    quantity: Literal["fuel_l", "energy_j"]
    resolution: float
    priority: int
    capacity_j: float | None = None
    modulus: float | None = None
    note: str = ""
    accuracy_pct: float | None = None  # None: the default of its kind (cevm.ingest.consumption)


@dataclass(frozen=True)
class TimeSpec:
    """Where the time is and how to read it (see the module docstring for keys)."""

    columns: tuple[str, ...]
    format: str | None  # single column
    date_format: str | None  # two columns
    time_format: str | None
    timezone: str
    date_repair: Literal["none", "dominant"] = "none"
    date_repair_max_days: float = 1.0


@dataclass(frozen=True)
class Profile:
    """A parsed, validated logger profile. Build with :func:`load_profile`."""

    name: str
    path: Path | None
    description: str
    required_columns: tuple[str, ...]
    encoding: str
    separator: str
    decimal: str
    comment_prefix: str
    metadata: Literal["key=value", "none"]
    truncated_last_line: Literal["drop", "error"]
    time: TimeSpec
    vehicle_source: Literal["metadata", "column", "file_stem", "parent_dir", "fixed"]
    vehicle_key: str | None
    vehicle_value: str | None
    vehicle_fallback: Literal["file_stem", "parent_dir", "error"]
    columns: tuple[ColumnMap, ...]
    energy: tuple[EnergySpec, ...]
    zero_position_is_no_fix: bool = True
    absurd_error_share: float = 0.5


_TOP_KEYS = {"name", "description", "detect", "csv", "time", "vehicle", "quality", "columns", "energy"}


_SECTION_KEYS = {
    "detect": {"required_columns"},
    "csv": {"encoding", "separator", "decimal", "comment_prefix", "metadata", "truncated_last_line"},
    "time": {"columns", "format", "date_format", "time_format", "timezone", "date_repair", "date_repair_max_days"},
    "vehicle": {"source", "key", "value", "fallback"},
    "quality": {"zero_position_is_no_fix", "absurd_error_share"},
}


_COLUMN_KEYS = {"source", "unit", "map", "missing_values", "required", "negate", "density_kg_per_l"}


_ENERGY_KEYS = {"column", "kind", "quantity", "resolution", "resolution_unit", "priority", "capacity",
                "capacity_unit", "modulus", "modulus_unit", "note", "accuracy_pct"}


def _convert_unit(value: float, unit: str, want_dim: str, path: Path | None, key: str, *,
                  interval: bool = False) -> float:
    """``value`` in ``unit`` converted to the SI unit of dimension ``want_dim``; with
    ``interval`` a difference of two values (a resolution), without the unit's offset."""
    factor, offset = _unit_factor(unit, want_dim, path, key)
    return float(value) * factor + (0.0 if interval else offset)


def _unit_factor(unit: str, want_dim: str, path: Path | None, key: str) -> tuple[float, float]:
    """(factor, offset) of ``unit``, checked to be of dimension ``want_dim``."""
    if unit not in UNITS:
        raise InputError(path, f"unknown unit {unit!r}; known units: {', '.join(UNITS)}", column=key)
    u = UNITS[unit]
    if u.dimension != want_dim:
        raise InputError(path, f"unit {unit!r} is a {u.dimension}, expected a {want_dim}", column=key)
    return u.factor, u.offset


# --------------------------------------------------------------------------------------
# Loading: TOML text -> a dict, then typed values out of it (every mistake names the key)
# --------------------------------------------------------------------------------------
class _Required:
    pass


_REQUIRED = _Required()


def _read_toml(source: str | Path | dict, path: Path | None) -> tuple[dict, Path | None]:
    """The profile's TOML document (``source`` itself if already parsed) and its path."""
    if isinstance(source, dict):
        return source, path
    path = Path(source)
    data = read_bounded(path, MAX_TOML_BYTES, "logger profile")  # a regular file of at most 1 MiB: no FIFO
    try:
        return tomllib.loads(data.decode("utf-8-sig")), path
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(path, f"not a valid TOML profile: {exc}") from None
    except RecursionError:
        raise InputError(path, "not a valid TOML profile: its arrays or tables nest too deeply") from None


@dataclass(frozen=True)
class _Keys:
    """Typed access to a profile's TOML tables; every error names the file and the key."""

    path: Path | None

    def fail(self, msg: str, key: str) -> InputError:
        return InputError(self.path, msg, column=key)

    def table(self, table: Any, allowed: set[str], where: str) -> dict:
        """``table`` checked to be a table holding only ``allowed`` keys."""
        if not isinstance(table, dict):
            raise self.fail("must be a table", where)
        for k in table:
            if k not in allowed:
                raise self.fail(f"unknown key (allowed: {', '.join(sorted(allowed))})", f"{where}.{k}" if where else k)
        return table

    def get(self, table: dict, key: str, typ: type | tuple, default: Any, where: str) -> Any:
        """``table[key]`` of type ``typ`` (an int is a float), ``default`` if absent
        (:data:`_REQUIRED`: an error)."""
        if key not in table:
            if default is _REQUIRED:
                raise self.fail("missing required key", f"{where}.{key}" if where else key)
            return default
        val = table[key]
        if typ is float and isinstance(val, int) and not isinstance(val, bool):
            val = float(val)
        if not isinstance(val, typ) or (typ is not bool and isinstance(val, bool)):
            tname = typ.__name__ if isinstance(typ, type) else "/".join(t.__name__ for t in typ)
            raise self.fail(f"must be a {tname}, got {val!r}", f"{where}.{key}" if where else key)
        return val

    def choice(self, val: str, options: tuple[str, ...], key: str) -> str:
        if val not in options:
            raise self.fail(f"{val!r} is not one of {', '.join(options)}", key)
        return val

    def unit(self, value: float, unit: str, want_dim: str, key: str, *, interval: bool = False) -> float:
        return _convert_unit(value, unit, want_dim, self.path, key, interval=interval)


def load_profile(source: str | Path | dict, path: Path | None = None) -> Profile:
    """Parse and validate one profile from a TOML file path or an already-parsed dict.

    Unknown or ill-typed keys raise :class:`InputError` naming the file and the key, so
    a typo in a user's profile is caught at load time, not silently ignored. Each
    section is read and checked by its own function, in this order: the tables' keys,
    ``name``, ``[csv]``, ``[time]``, ``[vehicle]``, ``[quality]``, ``[columns]``,
    ``[[energy]]``, ``[detect]``.
    """
    doc, path = _read_toml(source, path)
    k = _Keys(path)
    k.table(doc, _TOP_KEYS, "")
    name = k.get(doc, "name", str, _REQUIRED, "")
    if not re.fullmatch(r"[A-Za-z0-9_.-]+", name):
        raise k.fail("profile name may hold only letters, digits, '_', '.', '-'", "name")
    description = k.get(doc, "description", str, "", "")
    detect = k.table(doc.get("detect", {}), _SECTION_KEYS["detect"], "detect")
    csv_t = k.table(doc.get("csv", {}), _SECTION_KEYS["csv"], "csv")
    time_t = k.table(doc.get("time", None) if "time" in doc else {}, _SECTION_KEYS["time"], "time")
    veh_t = k.table(doc.get("vehicle", {}), _SECTION_KEYS["vehicle"], "vehicle")
    qual_t = k.table(doc.get("quality", {}), _SECTION_KEYS["quality"], "quality")

    csv_opts = _csv_section(csv_t, k)
    time_spec = _time_section(time_t, k)
    vehicle = _vehicle_section(veh_t, csv_opts["metadata"], k)
    quality = _quality_section(qual_t, k)
    maps = _columns_section(doc.get("columns", {}), k)
    specs = _energy_section(doc.get("energy", []), {m.canonical: m for m in maps}, k)
    required = _detect_section(detect, k)
    return Profile(
        name=name,
        path=path,
        description=description,
        required_columns=required,
        **csv_opts,
        time=time_spec,
        **vehicle,
        columns=maps,
        energy=specs,
        **quality,
    )


# --------------------------------------------------------------------------------------
# Validation: one function per section, and the rules across keys
# --------------------------------------------------------------------------------------
def _csv_section(t: dict, k: _Keys) -> dict[str, Any]:
    """``[csv]``: encoding, separator, decimal, comments, metadata, truncated last line."""
    encoding = k.get(t, "encoding", str, "utf-8", "csv")
    try:
        "x".encode(encoding)
    except LookupError:
        raise k.fail(f"unknown text encoding {encoding!r}", "csv.encoding") from None
    separator = k.get(t, "separator", str, ",", "csv")
    decimal = k.get(t, "decimal", str, ".", "csv")
    if len(separator) != 1 or len(decimal) != 1 or separator == decimal:
        raise k.fail("separator and decimal must be single, different characters", "csv.separator")
    comment_prefix = k.get(t, "comment_prefix", str, "", "csv")
    metadata = k.choice(k.get(t, "metadata", str, "none", "csv"), ("key=value", "none"), "csv.metadata")
    if metadata != "none" and not comment_prefix:
        raise k.fail("metadata needs a comment_prefix", "csv.metadata")
    truncated = k.choice(k.get(t, "truncated_last_line", str, "drop", "csv"), ("drop", "error"),
                         "csv.truncated_last_line")
    return dict(encoding=encoding, separator=separator, decimal=decimal, comment_prefix=comment_prefix,
                metadata=metadata, truncated_last_line=truncated)


def _time_section(t: dict, k: _Keys) -> TimeSpec:
    """``[time]``: one datetime column with ``format``, or date and time columns with
    their formats; the zone; date repair (two columns only)."""
    tcols = k.get(t, "columns", list, _REQUIRED, "time")
    if not (1 <= len(tcols) <= 2) or not all(isinstance(c, str) and c for c in tcols):
        raise k.fail("must list one datetime column or [date column, time column]", "time.columns")
    fmt = k.get(t, "format", str, None, "time")
    dfmt = k.get(t, "date_format", str, None, "time")
    tfmt = k.get(t, "time_format", str, None, "time")
    if len(tcols) == 1 and (fmt is None or dfmt or tfmt):
        raise k.fail("one time column needs 'format' (and no date_format/time_format)", "time.format")
    if len(tcols) == 2 and (fmt is not None or not dfmt or not tfmt):
        raise k.fail("two time columns need 'date_format' and 'time_format' (and no 'format')", "time.date_format")
    tz = _check_timezone(k.get(t, "timezone", str, "UTC", "time"), k)
    if fmt in EPOCH_FORMATS and tz != "UTC":
        raise k.fail(f"times in {fmt!r} count from 1970-01-01 UTC: no zone applies to them (remove 'timezone')",
                     "time.timezone")
    date_repair = k.choice(k.get(t, "date_repair", str, "none", "time"), ("none", "dominant"), "time.date_repair")
    if date_repair != "none" and len(tcols) != 2:
        raise k.fail("date_repair needs separate date and time columns", "time.date_repair")
    max_days = k.get(t, "date_repair_max_days", float, 1.0, "time")
    if not max_days >= 0:
        raise k.fail("must be >= 0", "time.date_repair_max_days")
    return TimeSpec(tuple(tcols), fmt, dfmt, tfmt, tz, date_repair, max_days)  # type: ignore[arg-type]


def _check_timezone(tz: str, k: _Keys) -> str:
    try:
        zoneinfo.ZoneInfo(tz)  # an IANA name (no pandas import for it)
        return tz
    except Exception:
        pass
    try:
        pd.Timestamp("2020-01-01").tz_localize(tz)  # whatever else pandas takes
    except Exception:
        raise k.fail(f"unknown time zone {tz!r} (use an IANA name such as 'Europe/London')", "time.timezone") from None
    return tz


def _vehicle_section(t: dict, metadata: str, k: _Keys) -> dict[str, Any]:
    """``[vehicle]``: where the vehicle id comes from (``metadata`` needs the csv's
    ``key=value`` metadata)."""
    vsrc = k.choice(k.get(t, "source", str, "file_stem", "vehicle"),
                    ("metadata", "column", "file_stem", "parent_dir", "fixed"), "vehicle.source")
    vkey = k.get(t, "key", str, None, "vehicle")
    vval = k.get(t, "value", str, None, "vehicle")
    vfb = k.choice(k.get(t, "fallback", str, "file_stem", "vehicle"), ("file_stem", "parent_dir", "error"),
                   "vehicle.fallback")
    if vsrc in ("metadata", "column") and not vkey:
        raise k.fail(f"vehicle source {vsrc!r} needs 'key'", "vehicle.key")
    if vsrc == "metadata" and metadata == "none":
        raise k.fail("vehicle source 'metadata' needs csv.metadata = 'key=value'", "vehicle.source")
    if vsrc == "fixed" and not vval:
        raise k.fail("vehicle source 'fixed' needs 'value'", "vehicle.value")
    return dict(vehicle_source=vsrc, vehicle_key=vkey, vehicle_value=vval, vehicle_fallback=vfb)


def _quality_section(t: dict, k: _Keys) -> dict[str, Any]:
    """``[quality]``: zero positions, the share of absurd values that is an error."""
    zero_nofix = k.get(t, "zero_position_is_no_fix", bool, True, "quality")
    share = k.get(t, "absurd_error_share", float, 0.5, "quality")
    if not 0.0 <= share <= 1.0:
        raise k.fail("must be within 0..1", "quality.absurd_error_share")
    return dict(zero_position_is_no_fix=zero_nofix, absurd_error_share=share)


def _columns_section(t: Any, k: _Keys) -> tuple[ColumnMap, ...]:
    """``[columns]``: one :class:`ColumnMap` per entry, then the rules across them."""
    if not isinstance(t, dict):
        raise k.fail("must be a table", "columns")
    maps = tuple(_column_map(canon, spec, k) for canon, spec in t.items())
    _check_column_set(maps, k)
    return maps


def _column_map(canon: str, spec: Any, k: _Keys) -> ColumnMap:
    """One ``[columns]`` entry: a source column with a unit (or a value map)."""
    key = f"columns.{canon}"
    if canon not in CANONICAL_DIMENSIONS:
        raise k.fail(f"not a mappable canonical column (known: {', '.join(CANONICAL_DIMENSIONS)})", key)
    if isinstance(spec, str):
        raise k.fail("must be a table such as { source = \"...\", unit = \"...\" }", key)
    k.table(spec, _COLUMN_KEYS, key)
    src = k.get(spec, "source", str, _REQUIRED, key)
    unit = k.get(spec, "unit", str, None, key)
    vmap = k.get(spec, "map", dict, None, key)
    if (unit is None) == (vmap is None):
        raise k.fail("give exactly one of 'unit' or 'map'", key)
    factor, offset = 1.0, 0.0
    map_t = None
    density = _fuel_density(canon, spec, unit, k, key)
    if density is not None:  # fuel by mass: litres through the stated density
        factor = UNITS[unit].factor / density
    elif unit is not None:
        factor, offset = _unit_factor(unit, CANONICAL_DIMENSIONS[canon], k.path, f"{key}.unit")
    else:
        map_t = _value_map(vmap, f"{key}.map", k)
    negate = k.get(spec, "negate", bool, False, key)
    if negate and offset:
        raise k.fail(f"negate does not apply to a value in {unit!r} (an offset scale)", f"{key}.negate")
    miss = k.get(spec, "missing_values", list, [], key)
    if not all(isinstance(m, (int, float)) and not isinstance(m, bool) for m in miss):
        raise k.fail("missing_values must be numbers", f"{key}.missing_values")
    return ColumnMap(
        canonical=canon,
        source=src,
        unit=unit,
        factor=factor,
        value_map=map_t,
        missing_values=tuple(float(m) for m in miss),
        required=k.get(spec, "required", bool, False, key),
        negate=negate,
        offset=offset,
        density_kg_per_l=density,
    )


def _fuel_density(canon: str, spec: dict, unit: str | None, k: _Keys, key: str) -> float | None:
    """The ``density_kg_per_l`` of a fuel column given in a mass unit (required there,
    refused anywhere else, within :data:`FUEL_DENSITY_RANGE_KG_PER_L`); None otherwise."""
    mass_dim = FUEL_MASS_DIMENSIONS.get(CANONICAL_DIMENSIONS[canon])
    udim = UNITS[unit].dimension if unit in UNITS else None
    density = k.get(spec, "density_kg_per_l", float, None, key)
    if density is None:
        if mass_dim is not None and udim == mass_dim:
            raise k.fail(f"unit {unit!r} is a {udim}: give the fuel's density_kg_per_l to convert it to litres "
                         "(diesel EN 590: 0.820-0.845 kg/l)", f"{key}.density_kg_per_l")
        return None
    if mass_dim is None or udim != mass_dim:
        raise k.fail("density_kg_per_l applies to a fuel column given in a mass unit "
                     "(g/s, kg/h, kg/s, g/h; a counter in kg or g)", f"{key}.density_kg_per_l")
    lo, hi = FUEL_DENSITY_RANGE_KG_PER_L
    if not lo <= density <= hi:
        raise k.fail(f"must be within {lo}-{hi} kg/l (liquid fuels: petrol 0.72-0.78, diesel 0.82-0.85); "
                     f"got {density!r}", f"{key}.density_kg_per_l")
    return density


def _value_map(vmap: dict, key: str, k: _Keys) -> tuple[tuple[str, float], ...]:
    items = []
    for name, v in vmap.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise k.fail(f"map value for {name!r} must be a number", key)
        items.append((str(name), float(v)))
    if not items:
        raise k.fail("map is empty", key)
    return tuple(items)


def _check_column_set(maps: tuple[ColumnMap, ...], k: _Keys) -> None:
    """Rules across ``[columns]``: latitude with longitude; no source mapped twice."""
    mapped = {m.canonical for m in maps}
    if ("lat_deg" in mapped) != ("lon_deg" in mapped):
        raise k.fail("map both lat_deg and lon_deg, or neither", "columns")
    counts = Counter(m.source for m in maps)  # one pass: a count per source was quadratic
    dup = {s for s, n in counts.items() if n > 1}
    if dup:
        raise k.fail(f"source column(s) {sorted(dup)} mapped twice", "columns")


def _energy_section(t: Any, mapped: dict[str, ColumnMap], k: _Keys) -> tuple[EnergySpec, ...]:
    """``[[energy]]``: one :class:`EnergySpec` per table (its columns must be mapped)."""
    if not isinstance(t, list):
        raise k.fail("must be an array of tables ([[energy]])", "energy")
    return tuple(_energy_spec(e, f"energy[{i}]", mapped, k) for i, e in enumerate(t))


def _energy_spec(e: Any, key: str, mapped: dict[str, ColumnMap], k: _Keys) -> EnergySpec:
    """One ``[[energy]]`` table: a source's kind, column, resolution, trust, capacity or
    modulus, each quantity converted to SI."""
    k.table(e, _ENERGY_KEYS, key)
    col = k.get(e, "column", str, _REQUIRED, key)
    kind = k.choice(k.get(e, "kind", str, _REQUIRED, key), ("rate", "counter", "soc"), f"{key}.kind")
    allowed = _ENERGY_COLUMNS[kind]
    if col not in allowed:
        raise k.fail(f"a {kind} source must use one of {', '.join(allowed)}", f"{key}.column")
    needs = VIRTUAL_COLUMNS[col][0] if col in VIRTUAL_COLUMNS else (col,)
    for c in needs:
        if c not in mapped:
            raise k.fail(f"column {c!r} is not mapped in [columns]", f"{key}.column")
    dim = VIRTUAL_COLUMNS[col][1] if col in VIRTUAL_COLUMNS else CANONICAL_DIMENSIONS[col]
    density = mapped[col].density_kg_per_l if col in mapped else None

    def to_si(value: float, unit: str, what: str, interval: bool) -> float:
        """``value`` in ``unit``: the column's own dimension, or mass for fuel by mass."""
        if density is not None and unit in UNITS and UNITS[unit].dimension == FUEL_MASS_DIMENSIONS[dim]:
            return float(value) * UNITS[unit].factor / density
        return k.unit(value, unit, dim, what, interval=interval)

    quantity = allowed[col]
    if "quantity" in e and k.get(e, "quantity", str, None, key) != quantity:
        raise k.fail(f"column {col!r} measures {quantity}", f"{key}.quantity")
    res = k.get(e, "resolution", float, 0.0, key)
    if not res >= 0:
        raise k.fail("must be >= 0", f"{key}.resolution")
    res_unit = k.get(e, "resolution_unit", str, None, key)
    if res_unit is not None:
        res = to_si(res, res_unit, f"{key}.resolution_unit", True)
    elif res:
        raise k.fail("resolution needs resolution_unit", f"{key}.resolution_unit")
    prio = k.get(e, "priority", int, _REQUIRED, key)
    if prio < 1:
        raise k.fail("must be >= 1 (1 = most trusted)", f"{key}.priority")
    cap = k.get(e, "capacity", float, None, key)
    cap_j = None
    if cap is not None:
        if kind != "soc":
            raise k.fail("capacity applies to soc sources only", f"{key}.capacity")
        if not cap > 0:
            raise k.fail("must be > 0", f"{key}.capacity")
        cap_j = k.unit(cap, k.get(e, "capacity_unit", str, _REQUIRED, key), "energy", f"{key}.capacity_unit")
    modulus = k.get(e, "modulus", float, None, key)
    if modulus is not None:
        if kind != "counter" or not modulus > 0:
            raise k.fail("modulus (> 0) applies to counter sources only", f"{key}.modulus")
        modulus = to_si(modulus, k.get(e, "modulus_unit", str, _REQUIRED, key), f"{key}.modulus_unit", False)
    accuracy = k.get(e, "accuracy_pct", float, None, key)
    if accuracy is not None and not 0 <= accuracy < 100:
        raise k.fail("must be >= 0 and < 100 (1-sigma systematic uncertainty, % of the value)", f"{key}.accuracy_pct")
    return EnergySpec(col, kind, quantity, res, prio, cap_j, modulus,  # type: ignore[arg-type]
                      k.get(e, "note", str, "", key), accuracy)


def _detect_section(t: dict, k: _Keys) -> tuple[str, ...]:
    """``[detect]``: the header columns that identify the logger."""
    req = k.get(t, "required_columns", list, _REQUIRED, "detect")
    if not req or not all(isinstance(c, str) and c for c in req):
        raise k.fail("must be a non-empty list of header column names", "detect.required_columns")
    return tuple(req)


def builtin_profile_dirs() -> list[Path]:
    """Directories of the profiles shipped with cevm that exist: ``configs/loggers`` of
    the source checkout or of the installed package (:mod:`cevm.configs_dir`)."""
    return [_SHIPPED_PROFILES] if _SHIPPED_PROFILES.is_dir() else []


#: Profiles parsed from files, by (path, modification time, size): each ingest, detection
#: and worker asks for the profiles again, and parsing the shipped three costs about 2 ms
#: (the TOML, the checks, the zone and unit look-ups); a file changed is parsed again.
_PARSED: dict[tuple[str, int, int], Profile] = {}
_PARSED_MAX = 256


def _load_profile_cached(f: Path) -> Profile:
    """:func:`load_profile` of the file ``f``, parsed once while it is unchanged."""
    try:
        st = f.stat()
    except OSError:
        return load_profile(f)  # says what is wrong with it
    key = (str(f), st.st_mtime_ns, st.st_size)
    p = _PARSED.get(key)
    if p is None:
        p = load_profile(f)
        if len(_PARSED) >= _PARSED_MAX:
            _PARSED.clear()
        _PARSED[key] = p
    return p


def load_profiles(directory: str | Path | None = None, *, include_env: bool = True) -> dict[str, Profile]:
    """Load every ``*.toml`` profile, keyed by profile name.

    Parameters
    ----------
    directory : directory to read instead of the built-in ones (default ``None``: the
        profiles shipped with cevm, see :func:`builtin_profile_dirs`).
    include_env : also read the directories listed in the ``CEVM_PROFILES`` environment
        variable (``os.pathsep`` separated) after the others (default ``True``), so that
        a user adds loggers without touching the installation. A later directory's
        profile replaces an earlier one of the same name.
    """
    dirs = [Path(directory)] if directory is not None else builtin_profile_dirs()
    if include_env and os.environ.get(PROFILES_ENV):
        dirs += [Path(p) for p in os.environ[PROFILES_ENV].split(os.pathsep) if p]
    profiles: dict[str, Profile] = {}
    for d in dirs:
        if not d.is_dir():
            raise InputError(d, "profile directory does not exist")
        seen: dict[str, Path] = {}
        for f in sorted(d.glob("*.toml")):
            p = _load_profile_cached(f)
            if p.name in seen:
                raise InputError(f, f"profile name {p.name!r} already used by {seen[p.name]}", column="name")
            seen[p.name] = f
            profiles[p.name] = p
    return profiles
