"""Cleaning stage of ``cevm ingest``: the canonical log frame of ONE vehicle -> clean trips.

A package of its steps, one module each: :mod:`.clock` (1), :mod:`.duplicates` (2),
:mod:`.gps` (3), :mod:`.speed` and :mod:`.plausibility` (4), :mod:`.splitting` (5),
:mod:`.grid` (6), :mod:`.distance` (7), :mod:`.jitter` (8), :mod:`.trip` (6-9 for one
trip), driven by :mod:`.stream`; :mod:`.params` holds the parameters and results,
:mod:`.rows`, :mod:`.events`, :mod:`.geodesy` and :mod:`.arrays` what the steps share.

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
   is a stop and is filled with 0, unless the GPS fixes at its ends are more than
   ``stop_max_displacement_m`` apart), and standstill (speed <= ``standstill_mps``)
   lasting more than ``stop_s`` (``"long_stop"``: the trip ends where the stop starts,
   the next starts where it ends) or during which the battery charged (``"charging"``:
   ``charge_power_w`` taken in for ``charge_min_s``, or the state of charge up
   ``charge_soc_rise_pct``), split the same way; and a trip longer than ``max_trip_s``
   (a day) is cut into pieces of that long (``"max_duration"``: a log whose stops were
   not seen; a worker's memory bound). Trips shorter than ``min_duration_s`` or ``min_distance_m`` are
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
9. **Measured consumption** over the grid's span: :func:`cevm.ingest.measured.measure_trips`
   (every trip of a batch at once).

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

from cevm.ingest.cleaning.geodesy import (
    GEODESIC_MIN_STEP_M,
    geodesic_steps_m,
    local_distance_m,
)
from cevm.ingest.cleaning.params import (
    SPEED_SOURCES,
    CleanBatch,
    CleanParams,
    CleanResult,
    CleanTrip,
)
from cevm.ingest.cleaning.stream import CleanStream, clean_log, clean_trips

__all__ = [
    "GEODESIC_MIN_STEP_M",
    "SPEED_SOURCES",
    "CleanBatch",
    "CleanParams",
    "CleanResult",
    "CleanStream",
    "CleanTrip",
    "clean_log",
    "clean_trips",
    "geodesic_steps_m",
    "local_distance_m",
]
