"""The cleaning's parameters and results: :class:`CleanParams`, :class:`CleanTrip`,
:class:`CleanResult`, and the names of the speed sources."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from cevm.core.trip import Measurement
from cevm.ingest.consumption import ConsumptionParams

#: Speed sources in order of preference (``quality["speed_source"]`` uses these names).
SPEED_SOURCES = ("wheel_speed_mps", "gps_speed_mps", "gps_positions")


@dataclass(frozen=True)
class CleanParams:
    """Parameters of the cleaning stage (all times in s, speeds in m/s, lengths in m).

    - ``gap_s = 300``: no speed data for 5 min ends a trip; a logger pause that long
      rarely hides continuous driving and the profile inside is unknowable.
    - ``stop_s = 1800``: standstill over 30 min ends a trip (a parked vehicle with the
      logger on); shorter stops (traffic, deliveries, layovers) stay in the trip.
    - ``min_duration_s = 60``, ``min_distance_m = 200``: shorter segments (yard moves,
      logger restarts) are dropped and reported; they carry too little energy for a
      quantised measurement to mean anything.
    - ``grid_s = 1.0``: the paper's loggers tick at about 1 Hz; None keeps raw times.
    - ``max_fill_s = 15``: speed holes up to 15 s are interpolated: 1 Hz loggers with
      missed ticks and telematics portals logging every 1-10 s while moving.
    - ``gps_max_fill_s = 30``: GPS dropouts up to 30 s are interpolated along time
      (positions feed elevation look-ups, where a straight chord over 30 s is good
      enough); longer dropouts stay NaN.
    - ``max_speed_mps = 70``: 252 km/h; faster implied GPS motion is impossible for a
      road vehicle; also bounds speed readings (FMS "not available" 0xFFFF = 256 km/h).
    - ``max_accel_mps2 = 15``: 1.5 g. Tyre grip limits a road vehicle's acceleration and
      braking to about 1.0-1.2 g (sports cars on dry asphalt; buses and trucks well
      under 0.7 g), so a speed reading that jumps faster, and back, is a spike.
    - ``speed_jump_tolerance_mps = 1``: speed noise allowed on top of the acceleration
      bound (phone GPS speed at 1 Hz scatters by a few tenths of a m/s).
    - ``speed_outlier_max_samples = 3``: runs of at most 3 speed readings between two
      impossible jumps are spikes (rejected); longer runs are kept and the jump reported.
    - ``gps_jump_tolerance_m = 20``: position noise allowed on top of the speed bound
      (a consumer GPS is good to a few metres, 20 m keeps short-dt fixes from tripping).
    - ``gps_outlier_max_fixes = 5``: runs of at most 5 fixes between two jumps are
      outliers (multipath, cold start); longer runs are kept and the jump reported.
    - ``max_hdop = 20``: HDOP above 20 is a very poor fix (positions off by ~100 m).
    - ``standstill_mps = 0.5``: 1.8 km/h; below walking pace the vehicle is stopped,
      above the speed noise of a phone GPS at rest (~0.1-0.3 m/s).
    - ``clock_step_min_s = 2``: backward jumps up to 2 s are local reordering (sorted).
    - ``max_clock_step_s = 3600``: clock corrections are seconds to minutes, or an hour
      (time zone / DST slip); bigger jumps are out-of-order blocks (sorted) or pauses.
    - ``clock_moving_mps = 2``: motion needed on both sides of a forward jump to take it
      as a clock step (positions must then have moved by about one tick).
    - ``unordered_share = 0.05``: more than 5 % backward steps = unordered file.
    - ``time_outlier_max_rows = 3``: longest junk-timestamp block dropped.
    - ``start_soc_window_s = 60``: a trip's start state of charge is the reading at or
      last before its start within 60 s, else the first within 60 s after it (a BMS
      reports every few seconds; in a minute a vehicle's SoC moves by well under 1 %).
    - ``charge_power_w = 2000``, ``charge_min_s = 60``, ``charge_soc_rise_pct = 2``,
      ``charge_counter_kwh = 0.5``: a stop during which the battery takes in more than
      2 kW (V x I below -2 kW) for at least 60 s, its state of charge rises by 2 points
      or more, or its energy counter (net of regeneration) falls by 0.5 kWh (five of
      an FMS counter's 0.1 kWh steps) is a charging stop
      (an opportunity charger at a terminus): it ends the trip like a long stop, since a
      trip's measured energy is the battery's net and would otherwise lose what was
      charged. At standstill nothing else makes the battery take in power (regeneration
      needs motion; an idle vehicle draws its auxiliaries), and 2 kW is above a current
      sensor's offset (1-2 A at 650 V) and below the slowest charger (a 10 A socket).
    - ``stop_max_displacement_m = 100``: a hole in the log between two standstill rows is
      a stop only if the GPS fixes at its ends are within 100 m (a consumer GPS at rest
      scatters by metres, by tens in a street canyon); farther, the vehicle drove in the
      hole, whose profile is unknown: a ``speed_gap``.
    - ``max_trip_s = 86400``: a trip longer than a day is split into pieces of a day
      (``"max_duration"``; None: never). No vehicle drives a day without a stop of
      ``stop_s`` (drivers' hours rules and charging see to it), so such a trip is a log
      whose stops were not seen (a speed that never reads zero); and a worker holds a
      trip's samples whole through its elevation, vector and stored profile, so a trip
      of weeks (2.2 M samples: 0.87 GB) would break the 500 MB a worker is kept within
      (``python benchmarks/bench_memory.py --cases "one trip 2.2M"``). The second of
      driving between two pieces belongs to neither.
    - ``consumption``: :class:`cevm.ingest.consumption.ConsumptionParams`.
    """

    gap_s: float = 300.0
    stop_s: float = 1800.0
    min_duration_s: float = 60.0
    min_distance_m: float = 200.0
    grid_s: float | None = 1.0
    max_fill_s: float = 15.0
    gps_max_fill_s: float = 30.0
    max_speed_mps: float = 70.0
    max_accel_mps2: float = 15.0
    speed_jump_tolerance_mps: float = 1.0
    speed_outlier_max_samples: int = 3
    gps_jump_tolerance_m: float = 20.0
    gps_outlier_max_fixes: int = 5
    max_hdop: float = 20.0
    standstill_mps: float = 0.5
    clock_step_min_s: float = 2.0
    max_clock_step_s: float = 3600.0
    clock_moving_mps: float = 2.0
    unordered_share: float = 0.05
    time_outlier_max_rows: int = 3
    start_soc_window_s: float = 60.0
    charge_power_w: float = 2000.0
    charge_min_s: float = 60.0
    charge_soc_rise_pct: float = 2.0
    charge_counter_kwh: float = 0.5
    stop_max_displacement_m: float = 100.0
    max_trip_s: float | None = 86_400.0
    consumption: ConsumptionParams = field(default_factory=ConsumptionParams)


@dataclass(frozen=True, eq=False)
class CleanTrip:
    """One clean trip segment (the lead adds elevation and builds a :class:`Trip`).

    Arrays share one length; ``time_s`` [s] starts at 0 and strictly increases;
    ``start_utc_s`` is the absolute time of sample 0 (Unix epoch, UTC).
    ``speed_mps`` >= 0; ``distance_m`` cumulative trapezoidal distance from 0;
    ``lat_deg``/``lon_deg`` (WGS84) and ``gps_alt_m`` NaN where unknown;
    ``gross_weight_kg`` median of the trip's readings or None; ``measured`` the measured
    consumption or None; ``first_source_line``/``last_source_line`` the lowest and
    highest file line of the trip's rows. ``rows`` holds the trip's cleaned readings of
    the :data:`cevm.ingest.evidence.EVIDENCE_COLUMNS` the log has, at the row times
    ``rows_t_s`` [s, UTC epoch] from ``consumption.max_gap_s`` before the first sample
    to as long after the last (for :func:`cevm.ingest.evidence.trip_evidence`).
    ``start_soc_pct`` is the state of charge logged at the trip's start [%] (None where
    the log has none near it; ``CleanParams.start_soc_window_s``).
    """

    start_utc_s: float
    time_s: np.ndarray
    speed_mps: np.ndarray
    distance_m: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    gps_alt_m: np.ndarray
    gross_weight_kg: float | None
    measured: Measurement | None
    quality: dict
    first_source_line: int
    last_source_line: int
    rows_t_s: np.ndarray = field(default_factory=lambda: np.empty(0))
    rows: dict = field(default_factory=dict)
    start_soc_pct: float | None = None

    @property
    def duration_s(self) -> float:
        return float(self.time_s[-1] - self.time_s[0]) if len(self.time_s) else 0.0

    @property
    def length_m(self) -> float:
        return float(self.distance_m[-1]) if len(self.distance_m) else 0.0


@dataclass(frozen=True, eq=False)
class CleanBatch:
    """Clean trips of one log, their arrays end to end (trip ``i``'s samples are
    ``bounds[i]:bounds[i + 1]``): what :class:`CleanTrip` holds of each, for the stages
    after the cleaning to work on all of them at once.

    ``t_abs`` are the samples' times [s, UTC epoch] (a trip's ``time_s`` is ``t_abs``
    minus its first); the evidence rows of trip ``i`` are ``row_window[i]`` of the log's
    row times ``row_t`` and evidence columns ``rows`` (the log's own arrays: nothing
    writes to them).
    """

    bounds: np.ndarray
    t_abs: np.ndarray
    speed_mps: np.ndarray
    distance_m: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    gps_alt_m: np.ndarray
    quality: list[dict]
    measured: list[Measurement | None]
    gross_weight_kg: list[float | None]
    source_lines: list[tuple[int, int]]
    start_soc_pct: list[float | None]
    row_t: np.ndarray
    rows: dict[str, np.ndarray]
    row_window: np.ndarray

    def __len__(self) -> int:
        return self.bounds.size - 1

    @property
    def samples(self) -> int:
        return int(self.bounds[-1])

    @property
    def start_utc_s(self) -> np.ndarray:
        """Each trip's first sample time [s, UTC epoch]."""
        return self.t_abs[self.bounds[:-1]]

    def time_s(self) -> np.ndarray:
        """Each trip's sample times from its start [s], end to end."""
        return self.t_abs - np.repeat(self.start_utc_s, np.diff(self.bounds))

    def evidence_rows(self, i: int) -> tuple[np.ndarray, dict]:
        """Trip ``i``'s evidence rows: their times and the evidence columns (float64)."""
        if not self.rows:
            return np.empty(0), {}
        a, b = (int(x) for x in self.row_window[i])
        return self.row_t[a:b], {c: x[a:b].astype(np.float64, copy=False) for c, x in self.rows.items()}

    def trip(self, i: int) -> CleanTrip:
        """Trip ``i`` as a :class:`CleanTrip` (views of the batch's arrays)."""
        a, b = int(self.bounds[i]), int(self.bounds[i + 1])
        t = self.t_abs[a:b]
        rows_t, rows = self.evidence_rows(i)
        return CleanTrip(
            start_utc_s=float(t[0]), time_s=t - t[0], speed_mps=self.speed_mps[a:b],
            distance_m=self.distance_m[a:b], lat_deg=self.lat_deg[a:b], lon_deg=self.lon_deg[a:b],
            gps_alt_m=self.gps_alt_m[a:b], gross_weight_kg=self.gross_weight_kg[i], measured=self.measured[i],
            quality=self.quality[i], first_source_line=self.source_lines[i][0],
            last_source_line=self.source_lines[i][1], rows_t_s=rows_t, rows=rows,
            start_soc_pct=self.start_soc_pct[i],
        )


@dataclass(frozen=True, eq=False)
class CleanResult:
    """Kept trips, dropped (too short) segments with the reason, file-level quality."""

    trips: tuple[CleanTrip, ...]
    dropped: tuple[dict, ...]
    quality: dict
