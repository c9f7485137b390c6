"""Data types shared by the ingest pipeline: the canonical log frame's columns, a
measured consumption, and a cleaned trip.

Everything is SI inside: seconds, metres, m/s, kg, joules; fuel volume in litres
(names say so: ``_l``). Conversions happen where files are read or printed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

# Columns of the canonical log frame (a pandas DataFrame) that every logger profile maps
# its own columns onto. All float64 with NaN where a tick carries no value, except
# ``vehicle_id`` (str) and ``source_line`` (int, the 1-based line of the file the row
# came from, for error messages). A profile maps only the columns its logger has.
CANONICAL_COLUMNS: dict[str, str] = {
    "time_s": "UTC time, seconds since the Unix epoch",
    "source_line": "1-based line number in the source file",
    "vehicle_id": "vehicle identifier (str)",
    "lat_deg": "WGS84 latitude [deg]",
    "lon_deg": "WGS84 longitude [deg]",
    "gps_alt_m": "GPS altitude [m]",
    "gps_speed_mps": "GPS speed [m/s]",
    "gps_hdop": "GPS horizontal dilution of precision [-]",
    "wheel_speed_mps": "wheel-based vehicle speed (FMS / CAN) [m/s]",
    "ignition": "1 on, 0 off",
    "odometer_m": "odometer [m]",
    "gross_weight_kg": "gross combination weight [kg]",
    "fuel_rate_lps": "fuel rate from the ECU [l/s]",
    "flowmeter_fuel_lps": "external flow meter fuel rate [l/s]",
    "total_fuel_l": "cumulative fuel counter [l]",
    "total_energy_j": "cumulative electric energy counter, net of regeneration [J]",
    "battery_voltage_v": "HV battery voltage [V]",
    "battery_current_a": "HV battery current, positive = discharge [A]",
    "soc_pct": "battery state of charge [%]",
    "accel_pedal_pct": "accelerator pedal [%]",
    "brake_switch": "brake switch, 1 pressed",
    "engine_speed_rpm": "engine or motor speed [rpm]",
    "engine_torque_pct": "engine or motor torque [% of reference]",
    "ambient_temp_c": "ambient (outside) air temperature [degC]",
    "hvac_power_w": "heating, ventilation and air-conditioning power drawn [W]",
}

MeasurementKind = Literal["fuel_l", "energy_j"]


@dataclass(frozen=True)
class Measurement:
    """A trip's measured consumption.

    ``value`` is litres of fuel (``kind == "fuel_l"``) or joules of electric energy at
    the battery (``kind == "energy_j"``), net of regeneration. ``resolution`` is the
    quantisation step of the source in the same unit (0.5 l for an FMS fuel counter, 0.0
    for an integrated rate), and ``uncertainty`` a 1-sigma estimate of the error of
    ``value`` in the same unit, from resolution, noise and gaps.
    """

    kind: MeasurementKind
    value: float
    source: str
    resolution: float
    uncertainty: float


@dataclass(frozen=True, eq=False)
class Trip:
    """One cleaned trip, ready for a drive-cycle vector and the store.

    Arrays share one length (samples); ``time_s`` starts at 0 and strictly increases.
    """

    vehicle_id: str
    source_file: str
    source_sha256: str
    trip_index: int  # 0-based index of the trip within its source file
    start_utc_s: float  # absolute start, seconds since the Unix epoch (UTC)
    time_s: np.ndarray
    speed_mps: np.ndarray
    distance_m: np.ndarray  # cumulative, starts at 0
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    elevation_m: np.ndarray
    elevation_source: str  # "dsm", "dsm+gps", "gps", "flat", ...
    dsm_coverage_pct: float  # share of samples with a valid DSM value (0 without a DSM)
    measured: Measurement | None
    gross_weight_kg: float | None
    quality: dict = field(default_factory=dict)  # repairs and warnings, JSON-serialisable
    # weather and evidence (None where the log has no such column)
    ambient_temp_c: float | None = None  # time-weighted mean ambient temperature [degC]
    ambient_temp_min_c: float | None = None
    ambient_temp_max_c: float | None = None
    standstill_s: float | None = None  # time at standstill with the ignition on [s]
    standstill_power_w: float | None = None  # EV: mean measured battery power at standstill [W]
    standstill_fuel_lps: float | None = None  # ICE: mean measured fuel rate at standstill [l/s]
    start_soc_pct: float | None = None  # state of charge logged at the start [%] (None: not logged)

    @property
    def trip_id(self) -> str:
        """Stable id: vehicle, start time and source content hash."""
        return trip_id_of(self.vehicle_id, self.start_utc_s, self.source_sha256)

    @property
    def duration_s(self) -> float:
        return float(self.time_s[-1] - self.time_s[0]) if len(self.time_s) else 0.0

    @property
    def length_m(self) -> float:
        return float(self.distance_m[-1]) if len(self.distance_m) else 0.0

    @property
    def n_samples(self) -> int:
        return int(len(self.time_s))

    def record(self) -> TripRecord:
        """The trip without its arrays: what the store keeps in its ``trips`` table."""
        return TripRecord(
            self.vehicle_id, self.source_file, self.source_sha256, int(self.trip_index), float(self.start_utc_s),
            self.duration_s, self.length_m, self.n_samples, self.elevation_source, self.dsm_coverage_pct,
            self.measured, self.gross_weight_kg, self.quality, **{k: getattr(self, k) for k in TRIP_EVIDENCE_FIELDS},
            start_soc_pct=self.start_soc_pct,
        )


@dataclass(frozen=True)
class TripRecord:
    """A trip's summary without its sample arrays (:meth:`Trip.record`): what the
    store's ``trips`` table holds, and what ingest's workers send back to the writer
    (the arrays travel as the encoded profile, a third of their size)."""

    vehicle_id: str
    source_file: str
    source_sha256: str
    trip_index: int
    start_utc_s: float  # [s since the Unix epoch, UTC]
    duration_s: float
    length_m: float
    n_samples: int
    elevation_source: str
    dsm_coverage_pct: float
    measured: Measurement | None
    gross_weight_kg: float | None
    quality: dict = field(default_factory=dict, hash=False)
    ambient_temp_c: float | None = None
    ambient_temp_min_c: float | None = None
    ambient_temp_max_c: float | None = None
    standstill_s: float | None = None
    standstill_power_w: float | None = None
    standstill_fuel_lps: float | None = None
    start_soc_pct: float | None = None

    @property
    def trip_id(self) -> str:
        """Stable id: vehicle, start time and source content hash (as :attr:`Trip.trip_id`)."""
        return trip_id_of(self.vehicle_id, self.start_utc_s, self.source_sha256)


#: The optional per-trip scalars of weather and evidence that :class:`Trip` and
#: :class:`TripRecord` carry (and the store keeps), all float or None: the time-weighted
#: mean, minimum and maximum ambient temperature [degC], the time at standstill with the
#: ignition on [s], and the measured mean battery power [W] (EV) or fuel rate [l/s] (ICE)
#: while standing still (evidence that a calibration's auxiliary and idle terms are
#: checked against, never a model input).
TRIP_EVIDENCE_FIELDS: tuple[str, ...] = (
    "ambient_temp_c", "ambient_temp_min_c", "ambient_temp_max_c", "standstill_s", "standstill_power_w",
    "standstill_fuel_lps",
)


def trip_id_of(vehicle_id: str, start_utc_s: float, source_sha256: str) -> str:
    """A trip's stable id: ``vehicle:start second:first 8 hex digits of the file hash``."""
    return f"{vehicle_id}:{int(round(start_utc_s))}:{source_sha256[:8]}"
