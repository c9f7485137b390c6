"""Cleaning stage of ``cevm ingest``: the canonical log frame of ONE vehicle -> clean trips.

Input: a DataFrame with columns of :data:`cevm.core.trip.CANONICAL_COLUMNS` and
:data:`cevm.ingest.evidence.EVIDENCE_COLUMNS` (``time_s``, UTC epoch seconds, and
``source_line`` required; asynchronous fields NaN where a tick carried
no value), rows in file order. Output: :class:`CleanTrip` segments with time from 0 on a
regular grid, speed, distance, position and the measured consumption
(:mod:`cevm.ingest.consumption`), each with a JSON-serialisable ``quality`` dict counting every
repair. Everything is vectorised; the only Python loops run over trips or over a handful
of passes.

The steps, in order (parameters in :class:`CleanParams`):

1. **Time.** Rows without a finite time are dropped. If more than ``unordered_share`` of
   the steps in file order go backwards, the file is *unordered* (an export sorted by
   something else, or newest first): it is simply sorted. Otherwise it is a log written
   in time order with rare faults, repaired in file order:

   - *time outliers*: a block of at most ``time_outlier_max_rows`` rows whose times lie
     far outside the bracket of their two neighbours, while the neighbours agree with
     each other (a junk timestamp), is dropped;
   - *clock steps*: the logger's clock corrected backwards (a backward jump of more than
     ``clock_step_min_s`` and at most ``max_clock_step_s``, with the next row still before
     the previous one: the log overlaps itself) or forwards (a forward jump, at most
     ``max_clock_step_s``, while the vehicle moves at >= ``clock_moving_mps`` on both
     sides and the positions, or the odometer, across the jump moved by about one tick,
     not by the jump). Repair: **keep file order and shift every row before the step**
     so that the step becomes one nominal tick (the median positive time step); the
     clock after the correction is taken as right. Steps compose (cumulative shifts). A
     forward step with no motion evidence cannot be told from a logging pause: it stays a
     gap. Larger backward jumps are blocks written out of order: sorted.

   Then rows are stably sorted by time.
2. **Duplicates.** Rows identical in every field but ``source_line`` are dropped. Rows
   sharing one timestamp are merged: per field the last non-NaN value in file order
   (asynchronous fields of one tick); the lowest ``source_line`` is kept. Fields with two
   different values in one tick are counted as conflicts.
3. **GPS fixes.** Rejected: NaN, out of range, exact zero latitude or longitude (a "no
   fix" marker; a true 0.0 fix is filled from its neighbours at no cost), HDOP above
   ``max_hdop``; *stale* fixes (exactly the previous fix repeated while the vehicle
   moves: a logger repeating its last value); then *impossible jumps*: consecutive fixes
   farther apart than ``max_speed_mps * dt + gps_jump_tolerance_m`` cut the fixes into
   runs, and runs of at most ``gps_outlier_max_fixes`` fixes are rejected (an outlier
   jumps away and back). Remaining jumps between long runs are counted as unresolved.
4. **Speed.** Per row, in order of preference: wheel speed (FMS), GPS speed, speed from
   positions (distance between consecutive fixes / dt, at the midpoint time). Each
   source is interpolated linearly in time between its own samples, over at most
   ``max_fill_s``; a row takes the first source available. Values outside
   ``[0, max_speed_mps]`` are rejected, and so are spikes: runs of at most
   ``speed_outlier_max_samples`` readings that a source reaches and leaves faster than
   ``max_accel_mps2`` (plus ``speed_jump_tolerance_mps``) allows. GPS-based speeds below ``standstill_mps`` are set
   to 0 (GPS speed noise at rest would otherwise accrue distance); wheel speed is kept.
5. **Trips.** Split (and the rows between dropped) at: ignition off (where an ignition
   column exists; NaN forward-filled, unknown before the first value = on; the first
   "off" row ends its trip), no speed for more than ``gap_s`` (``"gap"``), a hole longer
   than ``max_fill_s`` in the speed with the vehicle moving at either end
   (``"speed_gap"``: the profile inside is unknown; a hole between two standstill rows
   is a stop and is filled with 0), and standstill (speed <= ``standstill_mps``) lasting
   more than ``stop_s`` (``"long_stop"``: the trip ends where the stop starts, the next
   starts where it ends). Trips shorter than ``min_duration_s`` or ``min_distance_m`` are
   dropped and reported.
6. **Grid.** Each trip is resampled onto a regular grid of ``grid_s`` seconds aligned to
   whole multiples of ``grid_s`` in UTC, inside the trip's first and last sample (no
   extrapolation). The CE model takes any strictly increasing time, but a regular grid
   removes repeated and missed ticks and makes trips comparable sample by sample.
   ``grid_s=None`` keeps the sample times.
7. **Distance** = trapezoidal integral of speed, the same discretisation as the CE
   model's r_i = (v_i + v_{i+1}) / 2 dt_i. Cross-checked against the geodesic length of
   the GPS track on steps where both ends have a position (:func:`geodesic_steps_m`:
   WGS84, pyproj ``Geod.inv`` for steps >= 1 km, an equivalent fast local formula below)
   and against the odometer where one exists: ``distance_ratio_speed_vs_gps`` and
   ``distance_ratio_speed_vs_odometer`` (speed distance / other distance).
8. **Positions on the grid**: fixes interpolated linearly in time over at most
   ``gps_max_fill_s`` (dropouts filled), NaN beyond; at standstill each stop holds one
   position, the median of its samples (jitter frozen: GPS noise creates no distance
   or elevation wiggle). Longitude interpolation does not handle the antimeridian.
9. **Measured consumption** over the grid's span: :func:`cevm.ingest.consumption.measure_trip`.

Fast distances inside (jump tests, speed from positions) use a local ellipsoidal
approximation (meridian and prime-vertical radii of curvature of WGS84 at the mid
latitude), within 4e-8 (relative) of the geodesic for steps under a kilometre.

Memory: a large log's columns are held about once. The frame's own arrays are used
(with ``release_frame`` the frame lets go of them); steps 1 and 2 select and reorder
rows through one index and make each column once, in the final order, dropping its
source as they go, and drop the columns that only step 2 reads (an engine's speed, a
pedal); the row-wise steps work :data:`~cevm.ingest.consumption.CHUNK_ROWS` rows at a
time; the GPS fixes are rows of the log's columns, not copies; the speed and GPS
columns go once the row speeds are made; and :class:`CleanStream` makes the trips one
at a time (``python benchmarks/bench_memory.py``, 2 M rows: the cleaning's peak 416 MB,
9 MB above the read's).
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from pyproj import Geod

from cevm.core.trip import CANONICAL_COLUMNS, Measurement
from cevm.errors import InputError
from cevm.ingest import consumption
from cevm.ingest.consumption import (ConsumptionParams, EnergySourceLike, _interp_limited, chunks, columns_read,
                                     measure_trip)
from cevm.ingest.evidence import EVIDENCE_COLUMNS
from cevm.runtime import MMAP_THRESHOLD_BYTES, release_free_memory

_GEOD = Geod(ellps="WGS84")
_WGS84_A_M = 6378137.0
_WGS84_F = 1.0 / 298.257223563
_WGS84_E2 = _WGS84_F * (2.0 - _WGS84_F)
_RAD = math.pi / 180.0

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

    @property
    def duration_s(self) -> float:
        return float(self.time_s[-1] - self.time_s[0]) if len(self.time_s) else 0.0

    @property
    def length_m(self) -> float:
        return float(self.distance_m[-1]) if len(self.distance_m) else 0.0


@dataclass(frozen=True, eq=False)
class CleanResult:
    """Kept trips, dropped (too short) segments with the reason, file-level quality."""

    trips: tuple[CleanTrip, ...]
    dropped: tuple[dict, ...]
    quality: dict


# ----------------------------------------------------------------------------- helpers


def local_distance_m(lat1, lon1, lat2, lon2) -> np.ndarray:
    """Distance [m] between points [deg] by the local ellipsoidal (WGS84) approximation.

    sqrt((M dphi)^2 + (N cos(phi) dlambda)^2) with M, N the meridian and prime-vertical
    radii of curvature at the mid latitude: within 4e-8 of the geodesic under 1 km,
    fast (pure numpy). Longitude differences are wrapped to [-180, 180). Long 1-D
    arrays are done :data:`~cevm.ingest.consumption.CHUNK_ROWS` at a time (bounded
    temporaries).
    """
    lat1, lon1, lat2, lon2 = (np.asarray(a, dtype=float) for a in (lat1, lon1, lat2, lon2))
    n = lat1.size
    if lat1.ndim == 1 and n > consumption.CHUNK_ROWS and all(a.shape == lat1.shape for a in (lon1, lat2, lon2)):
        out = np.empty(n)
        for a, b in chunks(n):
            out[a:b] = _local_distance_m(lat1[a:b], lon1[a:b], lat2[a:b], lon2[a:b])
        return out
    return _local_distance_m(lat1, lon1, lat2, lon2)


def _local_distance_m(lat1, lon1, lat2, lon2) -> np.ndarray:
    s = np.sin((0.5 * _RAD) * (lat1 + lat2))
    s2 = s * s
    w2 = 1.0 - _WGS84_E2 * s2
    n_m = _WGS84_A_M / np.sqrt(w2)
    m_m = n_m * (1.0 - _WGS84_E2) / w2
    dlon = lon2 - lon1
    wrap = np.abs(dlon) > 180.0  # across the antimeridian (rare: wrapped only there)
    if wrap.any():
        dlon = np.where(wrap, (dlon + 180.0) % 360.0 - 180.0, dlon)
    east = n_m * np.sqrt(1.0 - s2) * (_RAD * dlon)  # cos(phi) >= 0 for |phi| <= 90 deg
    north = m_m * (_RAD * (lat2 - lat1))
    return np.sqrt(north * north + east * east)


#: Steps at least this long [m] are measured with pyproj's geodesic; shorter ones with
#: :func:`local_distance_m`, which agrees with it within 4e-8 (relative) below 1 km and
#: costs a tenth of a pyproj call (0.35 us per step, a third of the ingest budget).
GEODESIC_MIN_STEP_M = 1000.0


def geodesic_steps_m(lat_deg: np.ndarray, lon_deg: np.ndarray) -> np.ndarray:
    """Geodesic length [m] of each step of a track on the WGS84 ellipsoid, len - 1.

    pyproj ``Geod(ellps="WGS84").inv`` for steps of :data:`GEODESIC_MIN_STEP_M` or more,
    the local ellipsoidal formula (same result within 4e-8) below. Steps with an unknown
    end are NaN; steps that do not move are exactly 0.
    """
    lat = np.asarray(lat_deg, dtype=float)
    lon = np.asarray(lon_deg, dtype=float)
    if lat.size < 2:
        return np.empty(0)
    out = local_distance_m(lat[:-1], lon[:-1], lat[1:], lon[1:])
    moved = (lat[1:] != lat[:-1]) | (lon[1:] != lon[:-1])
    out[~moved] = 0.0
    out[~(np.isfinite(out))] = np.nan
    long_ = np.flatnonzero(out >= GEODESIC_MIN_STEP_M)
    if long_.size:
        _, _, d = _GEOD.inv(lon[long_], lat[long_], lon[long_ + 1], lat[long_ + 1])
        out[long_] = d
    return out


def _group_median(values: np.ndarray, group: np.ndarray, n_groups: int) -> np.ndarray:
    """Median of the finite values of each group 0..n_groups-1 (NaN for none)."""
    ok = np.isfinite(values)
    v, g = values[ok], group[ok]
    order = np.lexsort((v, g))
    v = v[order]
    count = np.bincount(g, minlength=n_groups)
    start = np.concatenate(([0], np.cumsum(count)[:-1]))
    med = np.full(n_groups, np.nan)
    has = count > 0
    lo = start[has] + (count[has] - 1) // 2
    hi = start[has] + count[has] // 2
    med[has] = 0.5 * (v[lo] + v[hi])
    return med


def _let_go(n_rows: int) -> None:
    """Return freed memory to the system (:func:`cevm.runtime.release_free_memory`) if
    the log's columns are large (``n_rows`` rows take at least the allocator's mapping
    threshold a column): glibc serves large arrays from the free memory in its heap and
    keeps what they free, so a step that makes and drops column after column would hold
    several times what it uses. A small log's arrays are left to the allocator."""
    if n_rows * 8 >= MMAP_THRESHOLD_BYTES:
        release_free_memory()


def _nonzero(mask: np.ndarray) -> np.ndarray:
    """``np.flatnonzero(mask)``, as int32 where the positions fit (half the memory of
    int64; made a chunk at a time, so no int64 array of them either)."""
    if mask.size >= 2**31:
        return np.flatnonzero(mask)
    out = np.empty(np.count_nonzero(mask), dtype=np.int32)
    k = 0
    for a, b in chunks(mask.size):
        nz = np.flatnonzero(mask[a:b])
        out[k:k + nz.size] = nz + a
        k += nz.size
    return out


def _last_valid_index(valid: np.ndarray) -> np.ndarray:
    """Index of the last True at or before each position, -1 if none."""
    idx = np.where(valid, np.arange(valid.size), -1)
    return np.maximum.accumulate(idx) if idx.size else idx


def _ffill(a: np.ndarray) -> np.ndarray:
    """Forward fill NaN (leading NaN stay NaN), a chunk at a time."""
    out = np.empty(a.size)
    last = np.nan  # the last finite value before the chunk
    for s, e in chunks(a.size):
        c = a[s:e]
        ok = np.isfinite(c)
        j = _last_valid_index(ok)
        out[s:e] = np.where(j >= 0, c[np.maximum(j, 0)], last)
        if ok.any():
            last = c[j[-1]]
    return out


def _runs(mask: np.ndarray, breaks: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """First and last index of each run of True in ``mask``; ``breaks[i]`` True also
    starts a new run at i."""
    m = mask.astype(bool)
    prev = np.concatenate(([False], m[:-1]))
    nxt = np.concatenate((m[1:], [False]))
    start = m & ~prev
    end = m & ~nxt
    if breaks is not None:
        start |= m & breaks
        end |= m & np.concatenate((breaks[1:], [False]))
    return np.flatnonzero(start), np.flatnonzero(end)


def _jsonable(x):
    t = type(x)
    if t is str or t is int or x is None or t is bool:
        return x
    if t is float:
        return x if math.isfinite(x) else None
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        x = float(x)
        return x if math.isfinite(x) else None
    return x


class _Events:
    """Repairs with the (sorted-frame) time at which they happened, to count per trip."""

    NAMES = (
        "time_outliers_dropped", "clock_steps", "duplicate_rows_dropped", "ticks_merged",
        "conflicting_values", "gps_rejected_invalid", "gps_rejected_stale",
        "gps_rejected_jump", "gps_unresolved_jumps", "speed_values_rejected",
        "speed_spikes_rejected", "speed_unresolved_jumps", "gps_speed_zeroed",
    )

    def __init__(self) -> None:
        self._t: dict[str, list[np.ndarray]] = {k: [] for k in self.NAMES}

    def add(self, name: str, times) -> None:
        arr = np.atleast_1d(np.asarray(times, dtype=float))
        self._t.setdefault(name, [])
        if arr.size:
            self._t[name].append(arr)

    def finish(self) -> None:
        self.times = {}
        for k, v in self._t.items():
            a = np.concatenate(v) if v else np.empty(0)
            if a.size > 1 and not (a[1:] >= a[:-1]).all():
                a = np.sort(a)
            self.times[k] = a

    def totals(self) -> dict:
        return {k: int(v.size) for k, v in self.times.items()}

    def between(self, t0: float, t1: float) -> dict:
        return {
            k: int(np.searchsorted(v, t1, "right") - np.searchsorted(v, t0, "left"))
            for k, v in self.times.items()
        }


# ------------------------------------------------------------------------------ load


class _Rows:
    """The log's columns as they came and which of their rows are the current rows, in
    order. The time repairs, the sort and the duplicates select and reorder rows
    through one index into the columns (``sel``; None: all of them, in order) instead
    of copying every column at each step; :meth:`gather` (or the tick merge) then makes
    each column once, in the final order, dropping its source array as it goes."""

    def __init__(self, cols: dict[str, np.ndarray]) -> None:
        self.cols = cols
        self.sel: np.ndarray | None = None

    def __contains__(self, name: str) -> bool:
        return name in self.cols

    def select(self, idx: np.ndarray) -> None:
        """Keep the current rows ``idx`` (positions, or a mask), in that order."""
        if idx.dtype == bool:
            idx = np.flatnonzero(idx)
        self.sel = idx if self.sel is None else self.sel[idx]

    def positions(self, idx: np.ndarray | None = None) -> np.ndarray | None:
        """Where the current rows ``idx`` (positions or a mask; None: all) are in the
        source arrays (None: all of them, in order)."""
        if self.sel is None:
            return idx
        return self.sel if idx is None else self.sel[idx]

    def at(self, name: str, idx: np.ndarray) -> np.ndarray:
        """Column ``name`` at the current rows ``idx`` (float64)."""
        return self.cols[name][self.positions(idx)].astype(np.float64, copy=False)

    def gather(self, keep, wide=()) -> None:
        """The columns in ``keep`` at the current rows, in their order (a source array
        itself where nothing was selected), those in ``wide`` as float64 (the others
        keep their float32 or float64); the columns not in ``keep`` dropped."""
        names = list(self.cols)
        out = {}
        for name in sorted(names, key=lambda c: c in keep):  # the dropped ones first: their memory is free sooner
            src = self.cols.pop(name)
            if name in keep:
                a = src if self.sel is None else src[self.sel]
                out[name] = a.astype(np.float64) if name in wide and a.dtype != np.float64 else a
            del src
            _let_go(len(out[name]) if name in out else 0)
        self.cols, self.sel = {c: out[c] for c in names if c in out}, None


_FLOATS = (np.dtype(np.float64), np.dtype(np.float32))

#: Columns the row speeds and the GPS fixes are made from: float64 from the tick merge
#: on (the others, read per trip, keep their float32 where they have it).
_ROW_SPEED_COLUMNS = ("wheel_speed_mps", "gps_speed_mps", "lat_deg", "lon_deg", "gps_hdop", "gps_alt_m")


def _load(frame: pd.DataFrame, path, release: bool = False) -> tuple[np.ndarray, np.ndarray, _Rows, int]:
    """Time, file lines and the other numeric columns of ``frame`` (the frame's own
    arrays where they are float64 or float32: no copy); rows without a finite time are left out of
    the current rows. ``release``: the frame's columns are removed once taken, so that
    the cleaning holds the only reference to its arrays."""
    if "time_s" not in frame.columns:
        raise InputError(path, "no time column (canonical 'time_s')", column="time_s")
    n = len(frame)
    if "source_line" in frame.columns:
        s = frame["source_line"]
        if isinstance(s.dtype, np.dtype) and s.dtype.kind in "iu":  # the reader's integer lines
            line = s.to_numpy()
        else:
            line = pd.to_numeric(s, errors="coerce").to_numpy(dtype=float)
            line = np.where(np.isfinite(line), line, -1).astype(np.int64)
    else:
        line = np.arange(1, n + 1, dtype=np.int64)
    cols: dict[str, np.ndarray] = {}
    present = set(frame.columns)
    for name in dict.fromkeys((*CANONICAL_COLUMNS, *EVIDENCE_COLUMNS)):
        if name in ("source_line", "vehicle_id") or name not in present:
            continue
        s = frame[name]
        try:
            # float32 columns (values exactly float32) stay so until they are gathered
            arr = s.to_numpy() if s.dtype in _FLOATS else s.to_numpy(dtype=float, na_value=np.nan)
        except (TypeError, ValueError):
            num = pd.to_numeric(s, errors="coerce")
            bad = np.flatnonzero((num.isna() & s.notna()).to_numpy())
            i = int(bad[0]) if bad.size else 0
            raise InputError(
                path, f"not a number: {s.iloc[i]!r}", line=int(line[i]), column=name
            ) from None
        cols[name] = arr
    if release:
        for c in list(frame.columns):
            del frame[c]
    t = cols.pop("time_s").astype(np.float64, copy=False)
    rows = _Rows(cols)
    ok = np.isfinite(t)
    dropped = int(n - ok.sum())
    if dropped:
        t = t[ok]
        line = line[ok]
        rows.select(ok)
    return t, line, rows, dropped


# ------------------------------------------------------------------------------ time


def _repair_time(t, line, rows: _Rows, p: CleanParams, ev: _Events):
    """File-order time repairs (step 1 of the module docstring). Returns (t, line,
    info) with rows still in file order, outlier rows removed (from ``rows`` too), times
    shifted at clock steps; an unordered file is returned as it is (it is simply sorted
    afterwards)."""
    n = t.size
    info: dict = {"file_order": "ordered", "clock_step_corrections_s": []}
    if n < 3:
        return t, line, info
    backward, forward = 0, 0
    for a, b in chunks(n - 1):
        dd = np.diff(t[a:b + 1])
        backward += int((dd < 0).sum())
        forward += int((dd > 0).sum())
    info["backward_steps_in_file"] = backward
    if backward > p.unordered_share * (n - 1):
        info["file_order"] = "unordered"
        return t, line, info
    nominal = _median_positive_step(t, forward)
    info["nominal_dt_s"] = nominal
    _let_go(n)
    d = np.diff(t)

    drop = _time_outlier_rows(t, d, nominal, p)
    outlier_at = np.empty(0, dtype=np.int64)  # kept row just before each dropped row
    if drop.any():
        keep = ~drop
        outlier_at = np.maximum(np.cumsum(keep)[np.flatnonzero(drop)] - 1, 0)
        t, line = t[keep], line[keep]
        rows.select(keep)
        n = t.size
        if n < 3:
            ev.add("time_outliers_dropped", t[outlier_at])
            return t, line, info
        d = np.diff(t)
    del drop

    back_step = _backward_clock_steps(t, d, p)
    fwd_step = _forward_clock_steps(t, d, rows, nominal, p)
    del d
    step = back_step | fwd_step
    info["clock_steps_backward"] = int(back_step.sum())
    info["clock_steps_forward"] = int(fwd_step.sum())
    if step.any():
        t, srows, corr = _shift_before_clock_steps(t, step, nominal)
        info["clock_step_corrections_s"] = [float(c) for c in corr[:20]]
        ev.add("clock_steps", t[srows])
    ev.add("time_outliers_dropped", t[outlier_at])
    return t, line, info


def _median_positive_step(t: np.ndarray, n_pos: int) -> float:
    """The median of the ``n_pos`` positive steps of ``t`` (1.0 without any), their array
    made a chunk at a time (not beside an array of every step)."""
    if not n_pos:
        return 1.0
    pos = np.empty(n_pos)
    k = 0
    for a, b in chunks(t.size - 1):
        dd = np.diff(t[a:b + 1])
        dd = dd[dd > 0]
        pos[k:k + dd.size] = dd
        k += dd.size
    return float(np.median(pos, overwrite_input=True))  # pos is ours: no copy


def _time_outlier_rows(t: np.ndarray, d: np.ndarray, nominal: float, p: CleanParams) -> np.ndarray:
    """Rows of junk timestamps: blocks of at most ``time_outlier_max_rows`` rows whose
    times lie far outside the bracket of their two neighbours, while the neighbours
    agree with each other (``d = diff(t)``, ``nominal`` the median positive step)."""
    n = t.size
    drop = np.zeros(n, dtype=bool)
    jumps = 1 + np.flatnonzero((d > p.clock_step_min_s) | (d < -p.clock_step_min_s))  # a block starts with a jump
    for k in range(1, p.time_outlier_max_rows + 1):
        if n < k + 2:
            break
        # block i .. i+k-1, neighbours i-1 and i+k
        i = jumps[jumps < n - k]
        prev, nxt = t[i - 1], t[i + k]
        width = nxt - prev
        agree = (width >= 0) & (width <= 2 * (k + 1) * nominal + p.clock_step_min_s)
        tol = np.maximum(p.clock_step_min_s, 2 * width)
        outside = np.ones(i.size, dtype=bool)
        for j in range(k):
            tj = t[i + j]
            outside &= (tj < prev - tol) | (tj > nxt + tol)
        hit = i[agree & outside]
        for j in range(k):
            drop[hit + j] = True
    return drop


def _backward_clock_steps(t: np.ndarray, d: np.ndarray, p: CleanParams) -> np.ndarray:
    """Steps (``d[i-1] = t[i] - t[i-1]``) where the clock was set back: a backward jump
    of more than ``clock_step_min_s`` and at most ``max_clock_step_s`` after which the
    next row is still before the previous one (the log overlaps itself)."""
    nxt_before_prev = np.concatenate((t[2:] < t[:-2], [True]))  # t[i+1] < t[i-1]
    return (d < -p.clock_step_min_s) & (d >= -p.max_clock_step_s) & nxt_before_prev


def _valid_near(ii: np.ndarray, n: int, valid_at) -> tuple[np.ndarray, np.ndarray]:
    """For each row ``ii`` (0 < ii < n): the last row of ii-4 .. ii-1 and the first of
    ii .. ii+3 where ``valid_at(rows)`` holds, -1 where there is none."""
    before = np.full(ii.size, -1, dtype=np.int64)
    after = np.full(ii.size, -1, dtype=np.int64)
    for off in range(4):
        for out, j in ((before, ii - 1 - off), (after, ii + off)):
            todo = np.flatnonzero((out < 0) & (j >= 0) & (j < n))
            if todo.size:
                hit = valid_at(j[todo])
                out[todo[hit]] = j[todo[hit]]
    return before, after


def _forward_clock_steps(t: np.ndarray, d: np.ndarray, rows: _Rows, nominal: float, p: CleanParams) -> np.ndarray:
    """Steps where the clock jumped forward: a jump of at most ``max_clock_step_s``
    while the vehicle moves at >= ``clock_moving_mps`` on both sides and the positions
    (or the odometer) across the jump moved by about one tick, not by the jump. Only
    the rows within 3 of a candidate jump are looked at."""
    n = t.size
    fwd_cand = (d > max(p.clock_step_min_s, 3 * nominal)) & (d <= p.max_clock_step_s)
    fwd_step = np.zeros(n - 1, dtype=bool)
    if not fwd_cand.any():
        return fwd_step

    def speed_at(j):
        spd = np.full(j.size, np.nan)
        for name in ("gps_speed_mps", "wheel_speed_mps"):  # wheel overrides GPS
            if name in rows:
                v = rows.at(name, j)
                spd = np.where(np.isfinite(v), v, spd)
        return spd

    ii = np.flatnonzero(fwd_cand) + 1
    jb_s, ja_s = _valid_near(ii, n, lambda j: np.isfinite(speed_at(j)))
    has_v = (jb_s >= 0) & (ja_s >= 0)
    vb = np.where(has_v, speed_at(np.clip(jb_s, 0, n - 1)), np.nan)
    va = np.where(has_v, speed_at(np.clip(ja_s, 0, n - 1)), np.nan)
    moving = (np.minimum(vb, va) >= p.clock_moving_mps)
    disp = np.full(ii.size, np.nan)
    extra = np.full(ii.size, np.nan)  # time within the two sides [s]
    if "lat_deg" in rows and "lon_deg" in rows:
        hdop = "gps_hdop" in rows

        def fix_at(j):
            return _valid_fix(rows.at("lat_deg", j), rows.at("lon_deg", j), rows.at("gps_hdop", j) if hdop else None, p)

        jb, ja = _valid_near(ii, n, fix_at)
        ok = (jb >= 0) & (ja >= 0)
        jb, ja = np.clip(jb, 0, n - 1), np.clip(ja, 0, n - 1)
        dd = local_distance_m(rows.at("lat_deg", jb), rows.at("lon_deg", jb), rows.at("lat_deg", ja),
                              rows.at("lon_deg", ja))
        disp = np.where(ok, dd, disp)
        extra = np.where(ok, (t[ii - 1] - t[jb]) + (t[ja] - t[ii]), extra)
    if "odometer_m" in rows:
        jb, ja = _valid_near(ii, n, lambda j: np.isfinite(rows.at("odometer_m", j)))
        ok = (jb >= 0) & (ja >= 0) & ~np.isfinite(disp)
        jb, ja = np.clip(jb, 0, n - 1), np.clip(ja, 0, n - 1)
        disp = np.where(ok, np.abs(rows.at("odometer_m", ja) - rows.at("odometer_m", jb)), disp)
        extra = np.where(ok, (t[ii - 1] - t[jb]) + (t[ja] - t[ii]), extra)
    vmax, vmin = np.maximum(vb, va), np.minimum(vb, va)
    one_tick = disp <= 2 * vmax * (extra + nominal) + p.gps_jump_tolerance_m
    not_gap = disp < 0.5 * vmin * (extra + d[ii - 1])
    fwd_step[ii - 1] = moving & one_tick & not_gap
    return fwd_step


def _shift_before_clock_steps(t: np.ndarray, step: np.ndarray, nominal: float):
    """Correct clock steps (``step[i-1]``: between rows i-1 and i) keeping file order:
    every row before a step is shifted so that the step becomes one ``nominal`` tick
    (the clock after a correction is right; steps compose). Returns the shifted times,
    the rows after each step and each step's correction [s]."""
    n = t.size
    rows = np.flatnonzero(step) + 1
    corr = (t[rows] - nominal) - t[rows - 1]
    after = np.cumsum(corr[::-1])[::-1]  # per step: the sum of its and the later corrections
    # a row moves by the corrections of the steps after it: piecewise constant
    offset = np.repeat(np.append(after, 0.0), np.diff(np.concatenate(([0], rows, [n]))))
    return t + offset, rows, corr


def _sort_by_time(t, line, rows: _Rows):
    """Rows stably sorted by time (file order among equal times); nothing to do for a
    log in order."""
    if t.size > 1 and not (t[1:] >= t[:-1]).all():
        order = np.argsort(t, kind="stable")
        t, line = t[order], line[order]
        rows.select(order)
    return t, line


def _dedupe(t, line, cols, ev: _Events):
    """Sorted frame -> strictly increasing time (:func:`_merge_ticks` on columns given
    as a dict: every column kept). Returns (t, line, cols)."""
    rows = _Rows(dict(cols))
    t, line = _merge_ticks(t, line, rows, set(cols), ev, wide=set(cols))
    return t, line, rows.cols


def _merge_ticks(t, line, rows: _Rows, keep, ev: _Events, wide=_ROW_SPEED_COLUMNS):
    """Time-sorted rows -> strictly increasing time: exact duplicates dropped, ticks
    with the same time merged (last non-NaN value per field); the columns in ``keep``
    made in the final row order (:meth:`_Rows.gather`; those in ``wide`` as float64),
    the others dropped.

    Rows equal in time and every field (NaN equal to NaN, -0.0 to 0.0) but the first are
    dropped (``duplicate_rows_dropped``); the remaining rows of one time are merged into
    one (``ticks_merged`` per merged tick): per field the last non-NaN value in file
    order, the lowest ``source_line``; a field with two or more distinct non-NaN values
    in one tick counts once in ``conflicting_values``. Numpy only, one field and a chunk
    of ticks at a time, over the rows in ticks of more than one row. Returns (t, line)."""
    same = t[1:] == t[:-1]
    if not same.any():
        rows.gather(keep, wide)
        return t, line
    cont = _nonzero(same) + 1  # the rows that continue the tick of the row before
    del same
    start = np.ones(t.size, dtype=bool)  # a tick's first row
    start[cont] = False
    multi = ~start
    multi[cont - 1] = True
    rows_m = _nonzero(multi)  # the rows in ticks of more than one row ...
    del multi
    g = np.empty(rows_m.size, dtype=rows_m.dtype)  # ... and their tick's place among the ticks
    for a, b in chunks(rows_m.size):
        g[a:b] = rows_m[a:b] - np.searchsorted(cont, rows_m[a:b], side="right")
    del cont
    names = list(rows.cols)
    dup = _exact_duplicates(g, rows_m, rows, names)
    if dup.any():
        ev.add("duplicate_rows_dropped", t[rows_m[dup]])
        keep_m = ~dup
        g, kept_rows = g[keep_m], rows_m[keep_m]
        del keep_m
    else:
        kept_rows = rows_m
    del dup, rows_m
    _let_go(t.size)
    # per tick: reduceat over runs of the same group id
    gstart = _nonzero(np.concatenate(([True], g[1:] != g[:-1])))
    ug = g[gstart]
    gend = np.concatenate((gstart[1:], np.array([g.size], dtype=gstart.dtype)))
    del g
    merged = (gend - gstart) > 1
    if merged.any():
        ev.add("ticks_merged", t[kept_rows[gstart[merged]]])
    n_ticks = gstart.size
    per_group = np.zeros(n_ticks, dtype=np.int32)  # conflicting fields per tick
    pos_first = rows.positions(start)
    out = {}
    for name in sorted(names, key=lambda c: c in keep):  # the dropped ones first: their memory is free sooner
        src = rows.cols.pop(name)
        last_val = np.empty(n_ticks) if name in keep else None
        for ga, gb in chunks(n_ticks):
            ra, rb = int(gstart[ga]), int(gend[gb - 1])  # the kept rows of these ticks
            vals = src[rows.positions(kept_rows[ra:rb])].astype(np.float64, copy=False)
            at = gstart[ga:gb] - ra
            if merged[ga:gb].any():
                with np.errstate(invalid="ignore"):
                    lo = np.fmin.reduceat(vals, at)
                    hi = np.fmax.reduceat(vals, at)
                per_group[ga:gb] += (lo != hi) & ~np.isnan(lo)
            if last_val is not None:
                # last non-NaN value of the field per tick (NaN if none)
                last = np.maximum.reduceat(np.where(np.isnan(vals), -1, np.arange(vals.size)), at)
                last_val[ga:gb] = np.where(last >= 0, vals[np.maximum(last, 0)], np.nan)
        if last_val is not None:
            a = src[pos_first]
            if name in wide:
                a = a.astype(np.float64, copy=False)
            a[ug] = last_val  # values of the column itself
            out[name] = a
        del src, last_val
        _let_go(t.size)
    if merged.any():
        ev.add("conflicting_values", np.repeat(t[kept_rows[gstart]], per_group))
    del per_group, merged
    rows.cols, rows.sel = {c: out[c] for c in names if c in out}, None
    t_out = t[start]  # made last: the columns above are made while only t and line are held twice
    line_out = line[start]
    line_out[ug] = np.minimum.reduceat(line[kept_rows], gstart)
    return t_out, line_out


def _exact_duplicates(g: np.ndarray, rows_m: np.ndarray, rows: _Rows, names: list[str]) -> np.ndarray:
    """Per row of ``rows_m`` (the current rows in ticks of more than one row, ``g`` their
    tick), whether an earlier one of its tick equals it in every field (NaN equal to NaN,
    -0.0 to 0.0). In a tick of two rows, the second is compared with the first, a field
    and a chunk at a time; in larger ticks, by :func:`_equal_classes`."""
    dup = np.zeros(g.size, dtype=bool)
    first = _nonzero(np.concatenate(([True], g[1:] != g[:-1])))  # each tick's first row in rows_m
    size = np.diff(np.append(first, g.size))
    pair = first[size == 2]
    if pair.size:
        same = np.ones(pair.size, dtype=bool)
        for name in names:
            for a, b in chunks(pair.size):
                r = rows_m[pair[a:b]]
                v0, v1 = rows.at(name, r), rows.at(name, r + 1)
                same[a:b] &= (v0 == v1) | (np.isnan(v0) & np.isnan(v1))
            if not same.any():
                break
        dup[pair[same] + 1] = True
    larger = size > 2
    if larger.any():
        idx = _nonzero(np.repeat(larger, size))
        dup[idx] = _later_of_equal(g[idx], rows_m[idx], rows, names)
    return dup


def _later_of_equal(g: np.ndarray, rows_m: np.ndarray, rows: _Rows, names: list[str]) -> np.ndarray:
    """Per row of ``rows_m`` (``g`` its tick), whether an earlier row of the tick equals it
    in every field: the rows' classes of equal values are refined one field at a time
    (sorted by class and value, a new class where either changes), so that one field of
    these rows is held at a time; the first row of each final class is kept."""
    cls = g
    n_cls = int(np.count_nonzero(g[1:] != g[:-1])) + 1
    for name in names:
        if n_cls == cls.size:  # every row alone in its class: no duplicates
            return np.zeros(cls.size, dtype=bool)
        v = rows.at(name, rows_m)
        order = np.lexsort((v, cls))
        new = np.empty(cls.size, dtype=bool)  # in sorted order: a class starts here
        new[0] = True
        for a, b in chunks(cls.size - 1):
            o0, o1 = order[a:b], order[a + 1:b + 1]
            v0, v1 = v[o0], v[o1]
            new[a + 1:b + 1] = (cls[o1] != cls[o0]) | ~((v1 == v0) | (np.isnan(v1) & np.isnan(v0)))
        del v
        sorted_cls = np.cumsum(new, dtype=g.dtype) - 1
        del new
        n_cls = int(sorted_cls[-1]) + 1
        cls = np.empty_like(sorted_cls)
        cls[order] = sorted_cls
        del order, sorted_cls
    if n_cls == cls.size:
        return np.zeros(cls.size, dtype=bool)
    dup = np.ones(cls.size, dtype=bool)
    dup[np.unique(cls, return_index=True)[1]] = False
    return dup


# ------------------------------------------------------------------------- GPS, speed


def _valid_fix(lat, lon, hdop, p: CleanParams) -> np.ndarray:
    ok = (
        np.isfinite(lat) & np.isfinite(lon)
        & (np.abs(lat) <= 90) & (np.abs(lon) <= 180)
        & (lat != 0) & (lon != 0)
    )
    if hdop is not None:
        ok &= ~(hdop > p.max_hdop)  # NaN HDOP = unknown = accepted
    return ok


@dataclass
class _Fixes:
    """The cleaned GPS fixes: the log rows that hold one (``rows``, increasing) and
    which of them have a plausible altitude (``alt_ok``); their values are the log's
    ``lat_deg``, ``lon_deg`` and ``gps_alt_m`` columns (no copies). ``step_m``: the
    distance between consecutive fixes [m] (len - 1), while the row speeds are made."""

    rows: np.ndarray
    alt_ok: np.ndarray
    step_m: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class _FixWindow:
    """The fixes of a stretch of the log: times [s], positions [deg], and the times and
    values [m] of those with an altitude."""

    t: np.ndarray
    lat: np.ndarray
    lon: np.ndarray
    alt_t: np.ndarray
    alt: np.ndarray


def _fixes_between(t: np.ndarray, cols: dict, fixes: _Fixes, t0: float, t1: float) -> _FixWindow:
    """The fixes from ``t0`` to ``t1`` [s] (``t`` the log's row times)."""
    r = np.array([np.searchsorted(t, t0, "left"), np.searchsorted(t, t1, "right")], dtype=fixes.rows.dtype)
    a, b = np.searchsorted(fixes.rows, r)  # r in the rows' own dtype: no copy of them to search
    f = fixes.rows[a:b]
    fa = f[fixes.alt_ok[a:b]]
    if not f.size:
        return _FixWindow(*(np.empty(0) for _ in range(5)))
    alt = cols["gps_alt_m"][fa] if fa.size else np.empty(0)
    return _FixWindow(t[f], cols["lat_deg"][f], cols["lon_deg"][f], t[fa], alt)


def _clean_gps(t, cols, moving, p: CleanParams, ev: _Events) -> tuple[_Fixes, np.ndarray]:
    """Clean GPS fixes (step 3 of the module docstring): invalid, then stale, then
    jumping fixes rejected. Returns the fixes and a per-row 'stale fix' mask."""
    n = t.size
    empty = np.empty(0, dtype=np.int64)
    stale_rows = np.zeros(n, dtype=bool)
    if "lat_deg" not in cols or "lon_deg" not in cols:
        return _Fixes(empty, np.zeros(0, dtype=bool)), stale_rows
    lat, lon = cols["lat_deg"], cols["lon_deg"]
    valid = _valid_fix(lat, lon, cols.get("gps_hdop"), p)
    carried = np.isfinite(lat) | np.isfinite(lon)
    ev.add("gps_rejected_invalid", t[carried & ~valid])
    del carried
    f = _nonzero(valid)
    del valid
    if f.size > 1:
        f, stale = _drop_stale_fixes(f, lat, lon, moving)
        stale_rows[stale] = True
        ev.add("gps_rejected_stale", t[stale])
    step_m = np.empty(0)
    if f.size > 1:
        f, step_m = _drop_gps_jumps(f, t, lat, lon, p, ev)
    alt_ok = np.zeros(f.size, dtype=bool)
    if "gps_alt_m" in cols:
        for a, b in chunks(f.size):
            alt = cols["gps_alt_m"][f[a:b]]
            alt_ok[a:b] = np.isfinite(alt) & (alt > -500) & (alt < 9000)
    return _Fixes(f, alt_ok, step_m), stale_rows


def _short_runs_between_jumps(jump: np.ndarray, max_len: int) -> np.ndarray | None:
    """Samples to reject, given ``jump[i]`` (an impossible step from sample i to i+1):
    the jumps cut the samples into runs, and runs of at most ``max_len`` samples are
    outliers (they jump away and back). None when every run is that short (nothing
    to tell the outliers from)."""
    run = np.concatenate(([0], np.cumsum(jump)))
    small = np.bincount(run) <= max_len
    return None if small.all() else small[run]


def _drop_stale_fixes(f: np.ndarray, lat, lon, moving) -> tuple[np.ndarray, np.ndarray]:
    """Fix rows ``f`` without the stale ones (exactly the previous fix repeated while
    the vehicle moves: a logger repeating its last value), and the stale rows."""
    rep = np.zeros(f.size - 1, dtype=bool)
    for a, b in chunks(f.size - 1):
        fa, fb = f[a:b], f[a + 1:b + 1]
        rep[a:b] = (lat[fb] == lat[fa]) & (lon[fb] == lon[fa]) & moving[fb]
    return f[np.concatenate(([True], ~rep))], f[1:][rep]


def _fix_steps_m(f: np.ndarray, lat, lon) -> np.ndarray:
    """Distance [m] between consecutive fixes ``f`` (rows of ``lat``, ``lon``)."""
    out = np.empty(f.size - 1)
    for a, b in chunks(f.size - 1):
        fa, fb = f[a:b], f[a + 1:b + 1]
        out[a:b] = local_distance_m(lat[fa], lon[fa], lat[fb], lon[fb])
    return out


def _steps_over(rows: np.ndarray, t: np.ndarray, change: np.ndarray, rate: float, tolerance: float) -> np.ndarray:
    """Per step between consecutive ``rows``: whether ``change`` (len - 1) exceeds
    ``rate * dt + tolerance`` (``t`` the row times)."""
    out = np.empty(change.size, dtype=bool)
    for a, b in chunks(change.size):
        out[a:b] = change[a:b] > rate * np.diff(t[rows[a:b + 1]]) + tolerance
    return out


def _drop_gps_jumps(f: np.ndarray, t, lat, lon, p: CleanParams, ev: _Events) -> tuple[np.ndarray, np.ndarray]:
    """Fix rows ``f`` (at least two) without outliers, and the distance between
    consecutive kept fixes [m].

    Consecutive fixes farther apart than ``max_speed_mps * dt + gps_jump_tolerance_m``
    cut the fixes into runs; runs of at most ``gps_outlier_max_fixes`` are rejected
    (``gps_rejected_jump``) unless every run is that short; jumps left between kept
    fixes are counted (``gps_unresolved_jumps``)."""
    dist = _fix_steps_m(f, lat, lon)
    jump = _steps_over(f, t, dist, p.max_speed_mps, p.gps_jump_tolerance_m)
    if not jump.any():
        return f, dist
    bad = _short_runs_between_jumps(jump, p.gps_outlier_max_fixes)
    if bad is not None:
        ev.add("gps_rejected_jump", t[f[bad]])
        f = f[~bad]
        if f.size > 1:
            dist = _fix_steps_m(f, lat, lon)
            jump = _steps_over(f, t, dist, p.max_speed_mps, p.gps_jump_tolerance_m)
    if f.size > 1:
        ev.add("gps_unresolved_jumps", t[f[1:][jump]])
        return f, dist
    return f, np.empty(0)


def _speed_rows(t, cols, name, p: CleanParams, ev: _Events) -> np.ndarray | None:
    """Rows with a plausible value of the speed column ``name`` (None without the
    column); implausible values are counted as ``speed_values_rejected``."""
    if name not in cols:
        return None
    v = cols[name]
    fin = np.isfinite(v)
    ok = fin & (v >= 0) & (v <= p.max_speed_mps)
    ev.add("speed_values_rejected", t[fin & ~ok])
    del fin
    return _drop_speed_spikes(t, v, ok, p, ev)


def _drop_speed_spikes(t, v, ok: np.ndarray, p: CleanParams, ev: _Events) -> np.ndarray:
    """``ok`` without speed spikes: consecutive readings whose change exceeds
    ``max_accel_mps2 * dt + speed_jump_tolerance_mps`` are impossible jumps; runs of at
    most ``speed_outlier_max_samples`` readings between them are rejected
    (``speed_spikes_rejected``), jumps left are counted (``speed_unresolved_jumps``)."""
    idx = _nonzero(ok)
    if idx.size < 2:
        return ok

    def jumps(rows):
        change = np.empty(rows.size - 1)
        for a, b in chunks(change.size):
            change[a:b] = np.abs(np.diff(v[rows[a:b + 1]]))
        return _steps_over(rows, t, change, p.max_accel_mps2, p.speed_jump_tolerance_mps)

    jump = jumps(idx)
    if not jump.any():
        return ok
    bad = _short_runs_between_jumps(jump, p.speed_outlier_max_samples)
    if bad is not None:
        ev.add("speed_spikes_rejected", t[idx[bad]])
        ok = ok.copy()
        ok[idx[bad]] = False
        idx = idx[~bad]
        jump = jumps(idx) if idx.size > 1 else np.zeros(0, dtype=bool)
    ev.add("speed_unresolved_jumps", t[idx[1:][jump]])
    return ok


def _interp_rows(t: np.ndarray, ok: np.ndarray | None, v: np.ndarray | None, max_fill_s: float,
                 at: np.ndarray | None = None) -> np.ndarray:
    """``_interp_limited(t, t[ok], v[ok], max_fill_s)`` (all NaN for ``ok`` None) for a
    strictly increasing ``t``, at the rows ``at`` (None: every row): the rows' own
    values where ``ok``, interpolated between them elsewhere. Cheaper, as the sample
    positions in ``t`` are known: only the other rows are interpolated, a chunk of
    them at a time between the samples around the chunk."""
    if ok is None:
        return np.full(t.shape if at is None else at.shape, np.nan)
    if at is None:
        if ok.all():  # every row is a sample: its own value (exact times)
            return v.copy()
        out = v.astype(np.float64, copy=True)
        fill = _nonzero(~ok)  # rows to interpolate, and their places in out
        where = fill
    else:
        out = v[at].astype(np.float64, copy=False)
        where = _nonzero(~ok[at])
        fill = at[where]
    if not fill.size:
        return out
    samples = _nonzero(ok)
    for a, b in chunks(fill.size):
        q = fill[a:b]
        lo = max(int(np.searchsorted(samples, q[0])) - 1, 0)  # the sample before the chunk ...
        hi = int(np.searchsorted(samples, q[-1])) + 1  # ... to the one after it
        s = samples[lo:hi]
        out[where[a:b]] = _interp_limited(t[q], t[s], v[s], max_fill_s)
    return out


def _speed_from_positions(t: np.ndarray, fixes: _Fixes, rows: np.ndarray, p: CleanParams) -> np.ndarray:
    """Speed [m/s] at the log rows ``rows`` from positions: the distance between
    consecutive fixes over their time step, at its midpoint time, for steps of at most
    ``max_fill_s`` and ``max_speed_mps``, interpolated over at most ``max_fill_s``."""
    m = fixes.rows.size - 1
    tm, vm = np.empty(m), np.empty(m)
    k = 0
    for a, b in chunks(m):
        ft = t[fixes.rows[a:b + 1]]
        dt = np.diff(ft)
        v = fixes.step_m[a:b] / dt
        ok = (dt <= p.max_fill_s) & (v <= p.max_speed_mps)
        j = k + int(ok.sum())
        tm[k:j] = (0.5 * (ft[1:] + ft[:-1]))[ok]
        vm[k:j] = v[ok]
        k = j
    return _interp_limited(t[rows], tm[:k], vm[:k], p.max_fill_s)


def _row_speed(t, cols, p: CleanParams, ev: _Events):
    """Per-row speed [m/s] and source code (int8: 0 wheel, 1 GPS speed, 2 positions, -1
    none), plus the cleaned GPS fixes. The speed columns and ``gps_hdop`` are removed
    from ``cols`` once used (nothing after needs them)."""
    ok_w = _speed_rows(t, cols, "wheel_speed_mps", p, ev)
    ok_g = _speed_rows(t, cols, "gps_speed_mps", p, ev)
    _let_go(t.size)
    v = _interp_rows(t, ok_w, cols.pop("wheel_speed_mps", None), p.max_fill_s)
    del ok_w
    _let_go(t.size)
    gps = cols.get("gps_speed_mps")
    moving = v > p.standstill_mps  # the wheel speed, else the GPS speed
    no_w = _nonzero(~np.isfinite(v))
    if no_w.size and gps is not None:
        moving[no_w] = _interp_rows(t, ok_g, gps, p.max_fill_s, at=no_w) > p.standstill_mps
    fixes, stale = _clean_gps(t, cols, moving, p, ev)
    del moving
    cols.pop("gps_hdop", None)
    _let_go(t.size)
    src = np.full(t.size, -1, dtype=np.int8)
    src[np.isfinite(v)] = 0
    if no_w.size and gps is not None:
        if (ok_g & stale).any():  # GPS speeds of stale fixes dropped too
            ok_g = ok_g & ~stale
        v_g = _interp_rows(t, ok_g, gps, p.max_fill_s, at=no_w)
        use = np.isfinite(v_g)
        v[no_w[use]] = v_g[use]
        src[no_w[use]] = 1
        del v_g, use
    del ok_g, stale, no_w, gps
    cols.pop("gps_speed_mps", None)
    _let_go(t.size)
    need = _nonzero(~np.isfinite(v))
    if need.size and fixes.rows.size > 1:
        v_p = _speed_from_positions(t, fixes, need, p)
        use = np.isfinite(v_p)
        v[need[use]] = v_p[use]
        src[need[use]] = 2
        del v_p, use
    fixes.step_m = None
    del need
    gps_based = src >= 1
    noisy = gps_based & (v < p.standstill_mps) & (v > 0)
    ev.add("gps_speed_zeroed", t[noisy])
    v[gps_based & (v < p.standstill_mps)] = 0.0
    return v, src, fixes


# ------------------------------------------------------------------------ segmentation


_SPLIT_REASONS = ("start", "ignition", "gap", "speed_gap", "long_stop")


def _segment(ts, vs, on, p: CleanParams):
    """Split the speed rows (times ts, speeds vs, ignition on) into trips (step 5 of
    the module docstring).

    Returns the kept row indices (into ts; None: every row), the position of each
    trip's first row among the kept rows, and the reason each trip started ('start',
    'ignition', 'gap', 'speed_gap', 'long_stop')."""
    if not ts.size:
        return np.empty(0, dtype=np.int64), np.zeros(0, dtype=np.int64), []
    keep = on.copy()
    keep[1:] |= on[:-1]  # the first "off" row ends the trip before it
    if keep.all():
        idx, tt, vv, oo = None, ts, vs, on
    else:
        idx = _nonzero(keep)
        if idx.size == 0:
            return idx, np.zeros(0, dtype=np.int64), []
        tt, vv, oo = ts[idx], vs[idx], on[idx]
    del keep
    reason = _split_points(tt, vv, oo, idx, p)
    idx, reason = _split_long_stops(tt, vv, idx, reason, p)
    starts = np.concatenate(([0], np.flatnonzero(reason > 0)))
    start_reasons = [_SPLIT_REASONS[int(reason[s])] if s > 0 else "start" for s in starts]
    return idx, starts, start_reasons


def _split_points(tt, vv, oo, idx, p: CleanParams) -> np.ndarray:
    """Per kept row, why a trip starts there (an index into :data:`_SPLIT_REASONS`, 0
    for none): the ignition turned on (or came back after dropped rows; ``idx`` the
    kept rows, None: all), no speed for more than ``gap_s``, or a hole over
    ``max_fill_s`` with the vehicle moving at either end (a hole between two standstill
    rows is a stop)."""
    k = tt.size
    reason = np.zeros(k, dtype=np.int8)
    dt = np.diff(tt)
    st = vv <= p.standstill_mps
    sgap = np.concatenate(([False], (dt > p.max_fill_s) & ~(st[1:] & st[:-1])))
    reason[sgap] = 3
    del sgap, st
    gap = np.concatenate(([False], dt > p.gap_s))
    reason[gap] = 2
    del gap, dt
    back = ~oo[:-1] if idx is None else ~oo[:-1] | (np.diff(idx) > 1)
    ign = np.concatenate(([False], oo[1:] & back))
    reason[ign] = 1
    return reason


def _split_long_stops(tt, vv, idx, reason, p: CleanParams):
    """Standstill runs (not crossing a split) lasting more than ``stop_s`` end their
    trip where the stop starts; the next starts where it ends, and the rows inside are
    dropped. Returns the kept ``idx`` (None: all rows) and ``reason``."""
    k = tt.size
    st = vv <= p.standstill_mps
    first, last = _runs(st, reason > 0)
    del st
    long_ = (tt[last] - tt[first]) > p.stop_s
    if not long_.any():
        return idx, reason
    f, l = first[long_], last[long_]
    diff = np.zeros(k + 1, dtype=np.int8)  # runs are disjoint: the sum is 0 or 1
    np.add.at(diff, f + 1, 1)
    np.add.at(diff, l, -1)
    sel = ~(np.cumsum(diff, dtype=np.int8)[:k] > 0)  # not inside a long stop
    reason[l[reason[l] == 0]] = 4
    return (_nonzero(sel) if idx is None else idx[sel]), reason[sel]


def _ignition_on(cols: dict, rows: np.ndarray | None, n: int) -> np.ndarray:
    """Ignition state of ``rows`` (None: all ``n``): the ignition column forward-filled
    (unknown before its first value = on); all on without the column."""
    if "ignition" in cols and np.isfinite(cols["ignition"]).any():
        ign = _ffill(cols["ignition"])
        return ~((ign if rows is None else ign[rows]) < 0.5)  # NaN before the first value = on
    return np.ones(n if rows is None else rows.size, dtype=bool)


# ------------------------------------------------------------------------------ trips


def _grid(tt: np.ndarray, grid_s: float | None) -> np.ndarray:
    if grid_s is None:
        return tt.copy()
    k0 = math.ceil(tt[0] / grid_s - 1e-9)
    k1 = math.floor(tt[-1] / grid_s + 1e-9)
    if k1 < k0:
        return np.empty(0)
    return np.arange(k0, k1 + 1, dtype=float) * grid_s


def _freeze_standstill(v, arrays, p: CleanParams):
    """Hold one position per stop: every sample of a standstill run (speed <=
    ``standstill_mps``) gets the median of the run's known values."""
    st = v <= p.standstill_mps
    first, _ = _runs(st)
    if first.size == 0:
        return arrays, 0
    starts = np.zeros(v.size, dtype=np.int64)
    starts[first] = 1
    run = (np.cumsum(starts) - 1)[st]
    out = []
    for a in arrays:
        b = a.copy()
        b[st] = _group_median(a[st], run, first.size)[run]
        out.append(b)
    return out, int(st.sum())


@dataclass(frozen=True, eq=False)
class _Log:
    """The cleaned rows of one log that its trips are cut from: strictly increasing
    times ``t``, the canonical columns the trips read (float64; those read only per
    trip stay float32 where the log had them so, and are widened per trip), the cleaned
    GPS fixes and the repairs."""

    t: np.ndarray
    cols: dict
    fixes: _Fixes
    ev: _Events


@dataclass(frozen=True, eq=False)
class _Segment:
    """The speed rows of one trip (times, speeds, speed source codes), why it starts
    and ends, and the lowest and highest file line of the log's rows it spans."""

    t: np.ndarray
    v: np.ndarray
    src: np.ndarray
    split_before: str
    split_after: str
    lines: tuple[int, int]


def _speed_on_grid(q: np.ndarray, seg: _Segment, p: CleanParams) -> tuple[np.ndarray, int]:
    """Speed at the grid times ``q`` (linear between rows), 0 inside the holes over
    ``max_fill_s`` that a trip keeps (between two standstill rows by construction:
    stops); and the number of such holes."""
    v = np.interp(q, seg.t, seg.v)
    hole = np.flatnonzero(np.diff(seg.t) > p.max_fill_s)
    if hole.size:
        a = np.searchsorted(q, seg.t[hole], "right")
        b = np.searchsorted(q, seg.t[hole + 1], "left")
        diff = np.zeros(q.size + 1, dtype=np.int64)
        np.add.at(diff, a, 1)
        np.add.at(diff, b, -1)
        v[np.cumsum(diff)[:-1] > 0] = 0.0
    return v, int(hole.size)


def _trapezoid_distance(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Cumulative distance [m] from 0: the trapezoidal integral of speed (the CE
    model's r_i = (v_i + v_{i+1}) / 2 dt_i)."""
    return np.concatenate(([0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(q))))


def _dropped(start_s: float, duration_s: float, distance_m: float, lines: tuple[int, int], reason: str) -> dict:
    return _jsonable({
        "start_utc_s": start_s, "duration_s": duration_s, "distance_m": distance_m,
        "first_source_line": lines[0], "last_source_line": lines[1], "reason": reason,
    })


def _positions_on_grid(q: np.ndarray, v: np.ndarray, fixes: _FixWindow, p: CleanParams):
    """Positions and GPS altitude at the grid times: fixes interpolated over at most
    ``gps_max_fill_s`` (dropouts filled), NaN beyond; each stop frozen at the median of
    its samples. ``fixes``: the fixes from at least ``gps_max_fill_s`` before the grid
    to as long after it (the only ones the interpolation may use). Returns (lat, lon,
    alt, frozen samples, the raw GPS steps [m] at standstill before freezing, and their
    step indices)."""
    lat, lon = _interp_limited(q, fixes.t, fixes.lat, p.gps_max_fill_s, fixes.lon)
    alt = _interp_limited(q, fixes.alt_t, fixes.alt, p.gps_max_fill_s)
    still = (v[1:] <= p.standstill_mps) & (v[:-1] <= p.standstill_mps)
    si = np.flatnonzero(still)
    raw_still = local_distance_m(lat[si], lon[si], lat[si + 1], lon[si + 1])
    (lat, lon, alt), frozen = _freeze_standstill(v, [lat, lon, alt], p)
    return lat, lon, alt, frozen, raw_still, si


def _gps_distance_check(lat, lon, dist: np.ndarray, raw_still: np.ndarray, si: np.ndarray) -> dict:
    """The speed distance against the geodesic length of the GPS track, on the steps
    where both ends have a position; and the GPS path length that freezing removed."""
    gps_steps = geodesic_steps_m(lat, lon)
    okstep = np.isfinite(gps_steps)
    gps_dist = float(gps_steps[okstep].sum())
    speed_on_gps = float(np.diff(dist)[okstep].sum())
    return {
        "jitter_removed_m": float(np.nansum(raw_still - gps_steps[si])),
        "distance_gps_m": gps_dist,
        "distance_ratio_speed_vs_gps": speed_on_gps / gps_dist if gps_dist > 1.0 else None,
    }
def _gps_fix_stats(q: np.ndarray, fixes: _FixWindow, p: CleanParams) -> tuple[int, int]:
    """Fixes inside the trip's grid span (``fixes``: at least those), and the dropouts
    among them that were filled (steps over twice the nominal fix interval, up to
    ``gps_max_fill_s``)."""
    fix_in = (fixes.t >= q[0]) & (fixes.t <= q[-1])
    fdt = np.diff(fixes.t[fix_in])
    if not fdt.size:
        return int(fix_in.sum()), 0
    nominal_fix = float(np.median(fdt))
    return int(fix_in.sum()), int(((fdt > 2 * nominal_fix) & (fdt <= p.gps_max_fill_s)).sum())


def _speed_holes_bridged(seg: _Segment, p: CleanParams) -> tuple[int, float]:
    """Speed holes (steps over twice the nominal row interval, up to ``max_fill_s``)
    interpolated across: their number and total duration [s]."""
    dts = np.diff(seg.t)
    nominal_row = float(np.median(dts)) if dts.size else math.nan
    bridged = (dts > 2 * nominal_row) & (dts <= p.max_fill_s)
    return int(bridged.sum()), float(dts[bridged].sum())


def _speed_source_share(seg: _Segment) -> tuple[str | None, dict]:
    """The speed source of most rows (None without rows) and each source's share."""
    share = {SPEED_SOURCES[c]: float(np.mean(seg.src == c)) for c in range(3) if np.any(seg.src == c)}
    return (max(share, key=share.get) if share else None), share


def _odometer_ratio(log: _Log, lo: int, hi: int, q: np.ndarray, dist: np.ndarray) -> float | None:
    """Speed distance over odometer distance between the trip's first and last odometer
    readings inside the grid span (None without two readings or odometer progress)."""
    if "odometer_m" not in log.cols:
        return None
    odo_t = log.t[lo:hi]
    odo = log.cols["odometer_m"][lo:hi].astype(np.float64, copy=False)
    ok = np.isfinite(odo) & (odo_t >= q[0]) & (odo_t <= q[-1])
    if ok.sum() < 2:
        return None
    o_t, o_v = odo_t[ok], odo[ok]
    d_odo = float(o_v[-1] - o_v[0])
    d_spd = float(np.interp(o_t[-1], q, dist) - np.interp(o_t[0], q, dist))
    return d_spd / d_odo if d_odo > 0 else None


def _gross_weight(log: _Log, lo: int, hi: int) -> float | None:
    """Median of the trip's positive gross-weight readings, or None."""
    if "gross_weight_kg" not in log.cols:
        return None
    w = log.cols["gross_weight_kg"][lo:hi].astype(np.float64, copy=False)
    w = w[np.isfinite(w) & (w > 0)]
    return float(np.median(w)) if w.size else None


def _clean_trip(log: _Log, seg: _Segment, sources: Sequence[EnergySourceLike], p: CleanParams) -> CleanTrip | dict:
    """One trip from its speed rows (steps 6-9 of the module docstring): a
    :class:`CleanTrip`, or the dict of a dropped segment (too short)."""
    lo = int(np.searchsorted(log.t, seg.t[0], "left"))
    hi = int(np.searchsorted(log.t, seg.t[-1], "right"))
    lines = seg.lines
    q = _grid(seg.t, p.grid_s) if seg.t.size > 1 else np.empty(0)
    if q.size < 2:
        return _dropped(float(seg.t[0]), float(seg.t[-1] - seg.t[0]), 0.0, lines, "shorter than one grid step")
    v, standstill_holes = _speed_on_grid(q, seg, p)
    dist = _trapezoid_distance(q, v)
    duration = float(q[-1] - q[0])
    if duration < p.min_duration_s or dist[-1] < p.min_distance_m:
        return _dropped(float(q[0]), duration, float(dist[-1]), lines,
                        f"shorter than {p.min_duration_s:g} s or {p.min_distance_m:g} m")
    # the fixes the grid's positions may use (1 s more each side than the fill allows)
    fixes = _fixes_between(log.t, log.cols, log.fixes, float(q[0]) - p.gps_max_fill_s - 1.0,
                           float(q[-1]) + p.gps_max_fill_s + 1.0)
    lat, lon, alt, frozen, raw_still, si = _positions_on_grid(q, v, fixes, p)
    gps_check = _gps_distance_check(lat, lon, dist, raw_still, si)
    n_fixes, dropouts = _gps_fix_stats(q, fixes, p)
    del fixes
    holes_bridged, hole_s = _speed_holes_bridged(seg, p)
    speed_source, share = _speed_source_share(seg)
    measured, mq = measure_trip(log.t, log.cols, sources, float(q[0]), float(q[-1]), p.consumption)
    rows_t, rows = _evidence_rows(log, float(q[0]), float(q[-1]), p)
    tq = {
        "rows": int(hi - lo),
        "samples": int(q.size),
        "grid_s": p.grid_s,
        "split_before": seg.split_before,
        "split_after": seg.split_after,
        **log.ev.between(float(seg.t[0]), float(seg.t[-1])),
        "speed_source": speed_source,
        "speed_source_share": share,
        "speed_holes_filled": holes_bridged,
        "speed_hole_s": hole_s,
        "standstill_holes_filled": standstill_holes,
        "gps_fixes": n_fixes,
        "gps_coverage": float(np.mean(np.isfinite(lat))),
        "gps_dropouts_filled": dropouts,
        "gps_alt_coverage": float(np.mean(np.isfinite(alt))) if "gps_alt_m" in log.cols else 0.0,
        "jitter_frozen_samples": frozen,
        "jitter_removed_m": gps_check["jitter_removed_m"],
        "distance_speed_m": float(dist[-1]),
        "distance_gps_m": gps_check["distance_gps_m"],
        "distance_ratio_speed_vs_gps": gps_check["distance_ratio_speed_vs_gps"],
        "distance_ratio_speed_vs_odometer": _odometer_ratio(log, lo, hi, q, dist),
        "consumption": mq,
    }
    return CleanTrip(
        start_utc_s=float(q[0]),
        time_s=q - q[0],
        speed_mps=v,
        distance_m=dist,
        lat_deg=lat,
        lon_deg=lon,
        gps_alt_m=alt,
        gross_weight_kg=_gross_weight(log, lo, hi),
        measured=measured,
        quality=_jsonable(tq),
        first_source_line=lines[0],
        last_source_line=lines[1],
        rows_t_s=rows_t,
        rows=rows,
    )


def _evidence_rows(log: _Log, t0: float, t1: float, p: CleanParams) -> tuple[np.ndarray, dict]:
    """The log's rows from ``consumption.max_gap_s`` before ``t0`` to as long after
    ``t1``: their times and the evidence columns the log has (views of the log's
    arrays, which nothing writes to; float64 copies of its float32 ones)."""
    names = [c for c in EVIDENCE_COLUMNS if c in log.cols]
    if not names:
        return np.empty(0), {}
    w = p.consumption.max_gap_s
    a = int(np.searchsorted(log.t, t0 - w, "left"))
    b = int(np.searchsorted(log.t, t1 + w, "right"))
    return log.t[a:b], {c: log.cols[c][a:b].astype(np.float64, copy=False) for c in names}


def _require_speed_or_position(cols: dict, path) -> None:
    if not any(c in cols for c in ("wheel_speed_mps", "gps_speed_mps")) and not (
        "lat_deg" in cols and "lon_deg" in cols
    ):
        raise InputError(path, "no speed or position column (wheel_speed_mps, gps_speed_mps or lat_deg+lon_deg)")


def _columns_needed(sources: Sequence[EnergySourceLike]) -> set[str]:
    """The canonical columns that the steps after the tick merge read: those of the row
    speeds and the GPS fixes, each trip's ignition, odometer, gross weight and evidence
    columns, and the energy sources' columns. The others (an engine's speed, a pedal)
    count only in the duplicates and tick merging, and are dropped there."""
    need = {*_ROW_SPEED_COLUMNS, "ignition", "odometer_m", "gross_weight_kg", *EVIDENCE_COLUMNS}
    for s in sources:
        need |= columns_read(str(s.column))
    return need


class CleanStream:
    """:func:`clean_log` one trip at a time.

    Made, it runs the steps over the whole log (1 to 5 of the module docstring; errors
    are raised here); iterated, it makes each trip (steps 6 to 9) when it is asked
    for. Once the iteration has ended, ``dropped`` (the dropped segments) and
    ``quality`` (the file-level quality) are complete and the log's arrays are
    released. Iterate it once. The trips of a large log then need not all be held at
    once: :func:`cevm.ingest.task.process_file` hands each to the next stages and lets
    it go. Parameters as :func:`clean_log`.
    """

    def __init__(self, frame: pd.DataFrame, sources: Sequence[EnergySourceLike] = (),
                 params: CleanParams = CleanParams(), *, path: str | Path | None = None,
                 release_frame: bool = False) -> None:
        p = params
        n_in = len(frame)
        t, line, rows, no_time = _load(frame, path, release_frame)
        _require_speed_or_position(rows.cols, path)
        ev = _Events()
        # Each step over the whole log returns its temporaries' memory to the system once
        # done (for a large log, :func:`_let_go`), and so do the steps that make column
        # after column.
        t, line, tinfo = _repair_time(t, line, rows, p, ev)
        _let_go(t.size)
        t, line = _sort_by_time(t, line, rows)
        _let_go(t.size)
        t, line = _merge_ticks(t, line, rows, _columns_needed(sources), ev)
        _let_go(t.size)
        cols = rows.cols
        self.dropped: list[dict] = []
        self.quality: dict = {"rows_in": n_in, "rows_without_time": no_time, "rows_clean": int(t.size), **tinfo}
        self._sources, self._params = tuple(sources), p
        self._work: tuple | None = None
        if t.size < 2:
            ev.finish()
            self.quality.update(ev.totals(), trips=0, trips_dropped=0)
            self.quality = _jsonable(self.quality)
            return

        v, src, fixes = _row_speed(t, cols, p, ev)
        _let_go(t.size)
        ev.finish()
        fin = np.isfinite(v)
        rows_v = None if fin.all() else _nonzero(fin)  # the rows with a speed (None: all)
        del fin
        ts, vs = (t, v) if rows_v is None else (t[rows_v], v[rows_v])
        keep_idx, starts, start_reasons = _segment(ts, vs, _ignition_on(cols, rows_v, t.size), p)
        del ts, vs
        # the log rows of the kept speed rows, in trip order (None: every row)
        if keep_idx is None:
            rows_k = rows_v
        else:
            rows_k = keep_idx if rows_v is None else rows_v[keep_idx]
        del keep_idx
        _let_go(t.size)
        n_kept = t.size if rows_k is None else rows_k.size
        self.quality.update(ev.totals())
        self.quality.update(
            splits={r: start_reasons[1:].count(r) for r in _SPLIT_REASONS[1:]},
            trips=0,
            trips_dropped=0,
            speed_rows=int(t.size if rows_v is None else rows_v.size),
            gps_fixes_kept=int(fixes.rows.size),
        )
        bounds = np.append(starts, n_kept)
        # each trip's lowest and highest file line (its rows' span), so that the lines
        # need not be kept while the trips are made
        first = bounds[:-1] if rows_k is None else rows_k[bounds[:-1]]
        last = bounds[1:] - 1 if rows_k is None else rows_k[bounds[1:] - 1]
        lines = [(int(line[a:b + 1].min()), int(line[a:b + 1].max())) for a, b in zip(first.tolist(), last.tolist())]
        del line
        self._work = (_Log(t, cols, fixes, ev), v, src, rows_k, bounds, start_reasons, lines)

    def __iter__(self) -> Iterator[CleanTrip]:
        work, self._work = self._work, None
        if work is None:
            return
        log, v, src, rows_k, bounds, reasons, lines = work
        del work
        n_trips = len(reasons)
        kept = 0
        for j in range(n_trips):
            a, b = int(bounds[j]), int(bounds[j + 1])
            r = slice(a, b) if rows_k is None else rows_k[a:b]
            seg = _Segment(log.t[r], v[r], src[r], reasons[j], reasons[j + 1] if j + 1 < n_trips else "end", lines[j])
            out = _clean_trip(log, seg, self._sources, self._params)
            if isinstance(out, CleanTrip):
                kept += 1
                yield out
            else:
                self.dropped.append(out)
        self.quality.update(trips=kept, trips_dropped=len(self.dropped))
        self.quality = _jsonable(self.quality)


def clean_log(
    frame: pd.DataFrame,
    sources: Sequence[EnergySourceLike] = (),
    params: CleanParams = CleanParams(),
    *,
    path: str | Path | None = None,
    release_frame: bool = False,
) -> CleanResult:
    """Clean a canonical log frame of one vehicle into trips (see the module docstring;
    :class:`CleanStream` makes them one at a time).

    Parameters
    ----------
    frame : canonical columns (``time_s`` [s, UTC epoch] required), rows in file order.
    sources : energy sources for the measured consumption (:class:`EnergySourceLike`).
    params : :class:`CleanParams`.
    path : the source file, for error messages.
    release_frame : remove the columns from ``frame`` as soon as their arrays are taken
        (the cleaning then holds the only reference to them and drops each once it has
        made its own), so that a large log is not held twice; the caller's frame is
        left without columns (default False).

    Returns
    -------
    :class:`CleanResult` with the kept trips in time order, the dropped segments and a
    file-level quality dict. Raises :class:`cevm.errors.InputError` for a frame without
    time, with non-numeric values, or without any speed or position column.
    """
    stream = CleanStream(frame, sources, params, path=path, release_frame=release_frame)
    trips = tuple(stream)
    return CleanResult(trips, tuple(stream.dropped), stream.quality)


def clean_trips(
    frame: pd.DataFrame,
    sources: Sequence[EnergySourceLike] = (),
    params: CleanParams = CleanParams(),
    *,
    path: str | Path | None = None,
) -> list[CleanTrip]:
    """The kept trips of :func:`clean_log` (dropped segments and file quality dropped)."""
    return list(clean_log(frame, sources, params, path=path).trips)
