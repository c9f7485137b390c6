"""The cleaning's driver: steps 1 to 5 over the whole log, then the trips one at a time
(:class:`CleanStream`, :func:`clean_log`, :func:`clean_trips`)."""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path

import numpy as np

from cevm.errors import InputError
from cevm.ingest.cleaning.arrays import _ffill, _jsonable, _let_go, _nonzero
from cevm.ingest.cleaning.clock import _repair_time, _sort_by_time
from cevm.ingest.cleaning.duplicates import _merge_ticks
from cevm.ingest.cleaning.events import RepairEvents
from cevm.ingest.cleaning.geodesy import local_distance_m
from cevm.ingest.cleaning.grid import BatchSpeedRows, grid_lengths
from cevm.ingest.cleaning.params import CleanBatch, CleanParams, CleanResult, CleanTrip
from cevm.ingest.cleaning.rows import _ROW_SPEED_COLUMNS, CleanedLog, _load
from cevm.ingest.cleaning.speed import _row_speed
from cevm.ingest.cleaning.splitting import _SPLIT_REASONS, StopSignals, _ignition_on, _segment
from cevm.ingest.cleaning.trip import clean_batch
from cevm.ingest.consumption import EnergySourceLike, columns_read
from cevm.ingest.evidence import EVIDENCE_COLUMNS
from cevm.lazy import is_pandas, pd


def _require_speed_or_position(cols: dict, path) -> None:
    if not any(c in cols for c in ("wheel_speed_mps", "gps_speed_mps")) and not (
        "lat_deg" in cols and "lon_deg" in cols
    ):
        raise InputError(path, "no speed or position column (wheel_speed_mps, gps_speed_mps or lat_deg+lon_deg)")


def _columns_needed(sources: Sequence[EnergySourceLike]) -> set[str]:
    """The canonical columns that the steps after the tick merge read: those of the row
    speeds and the GPS fixes, each trip's ignition, odometer, gross weight, start state of
    charge and evidence columns, and the energy sources' columns. The others (an engine's speed, a pedal)
    count only in the duplicates and tick merging, and are dropped there."""
    need = {*_ROW_SPEED_COLUMNS, "ignition", "odometer_m", "gross_weight_kg", "soc_pct", *EVIDENCE_COLUMNS}
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

    def __init__(self, frame: pd.DataFrame | Mapping[str, np.ndarray], sources: Sequence[EnergySourceLike] = (),
                 params: CleanParams = CleanParams(), *, path: str | Path | None = None,
                 release_frame: bool = False) -> None:
        p = params
        n_in = len(frame) if is_pandas(frame, "DataFrame") else len(frame.get("time_s", ()))
        t, line, rows, no_time = _load(frame, path, release_frame)
        _require_speed_or_position(rows.cols, path)
        ev = RepairEvents()
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
        #: the samples the trips will hold on the grid, at most (dropped trips counted
        #: too), known before any trip is made: for a caller's bound on a file's trips
        self.planned_samples = 0
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
        notes: list[dict] = []
        keep_idx, starts, start_reasons = _segment(ts, vs, _ignition_on(cols, rows_v, t.size), p,
                                                   _stop_signals(t, cols, fixes, rows_v, p), notes)
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
            stop_notes=notes,
        )
        bounds = np.append(starts, n_kept)
        # each trip's lowest and highest file line (its rows' span), so that the lines
        # need not be kept while the trips are made
        first = bounds[:-1] if rows_k is None else rows_k[bounds[:-1]]
        last = bounds[1:] - 1 if rows_k is None else rows_k[bounds[1:] - 1]
        lines = [(int(line[a:b + 1].min()), int(line[a:b + 1].max()))
                 for a, b in zip(first.tolist(), last.tolist(), strict=True)]
        self.planned_samples = _grid_samples(t[first], t[last], p.grid_s)
        del line
        self._work = (CleanedLog(t, cols, fixes, ev), v, src, rows_k, bounds, start_reasons, lines)

    def batches(self, max_samples: int = 1 << 16) -> Iterator[CleanBatch]:
        """The kept trips (steps 6 to 9), a :class:`CleanBatch` of consecutive trips at a
        time, each of at most ``max_samples`` samples on the grid unless one trip alone
        has more (a batch is made whole, at once: a large log's trips are never all
        held); the dropped segments are added to ``dropped`` as they are met."""
        work, self._work = self._work, None
        if work is None:
            return
        log, v, src, rows_k, bounds, reasons, lines = work
        del work
        n_trips = len(reasons)
        kept = 0
        t_first = log.t[bounds[:-1] if rows_k is None else rows_k[bounds[:-1]]]
        t_last = log.t[bounds[1:] - 1 if rows_k is None else rows_k[bounds[1:] - 1]]
        size = grid_lengths(t_first, t_last, np.diff(bounds), self._params.grid_s)
        if self._params.grid_s is None:
            size = np.diff(bounds)
        j0 = 0
        while j0 < n_trips:
            j1 = _batch_end(size, j0, max_samples)
            a, b = int(bounds[j0]), int(bounds[j1])
            r = slice(a, b) if rows_k is None else rows_k[a:b]
            seg = BatchSpeedRows(log.t[r], v[r], src[r], bounds[j0:j1 + 1] - a, reasons[j0:j1],
                                 [*reasons[j0 + 1:j1], *(["end"] if j1 == n_trips else [reasons[j1]])],
                                 lines[j0:j1])
            batch, dropped = clean_batch(log, seg, self._sources, self._params)
            del seg
            self.dropped.extend(d for _, d in dropped)
            j0 = j1
            if batch is not None:
                kept += len(batch)
                yield batch
        self.quality.update(trips=kept, trips_dropped=len(self.dropped))
        self.quality = _jsonable(self.quality)

    def __iter__(self) -> Iterator[CleanTrip]:
        """The kept trips one at a time (made a batch at a time: :meth:`batches`)."""
        for batch in self.batches():
            yield from (batch.trip(i) for i in range(len(batch)))


def _stop_signals(t: np.ndarray, cols: dict, fixes, rows_v: np.ndarray | None, p: CleanParams) -> StopSignals:
    """The battery power, state of charge, energy counter and GPS displacement that tell
    a charging stop or a hole the vehicle drove through
    (:class:`~cevm.ingest.cleaning.splitting.StopSignals`), at the speed rows ``rows_v``
    (None: all) of the log rows at times ``t``."""
    def at_rows(a: np.ndarray) -> np.ndarray:
        # a reading holds until the next (loggers write each column at its own rate); float32
        # (7 digits: a 1e11 J counter to 0.02 MJ) to hold the signals in half the memory
        a = _ffill(a)
        return (a if rows_v is None else a[rows_v]).astype(np.float32)

    power = None
    if "battery_voltage_v" in cols and "battery_current_a" in cols:
        power = at_rows(cols["battery_voltage_v"])
        power *= at_rows(cols["battery_current_a"])
    soc = at_rows(cols["soc_pct"]) if "soc_pct" in cols and np.isfinite(cols["soc_pct"]).any() else None
    counter = (at_rows(cols["total_energy_j"]) if "total_energy_j" in cols and np.isfinite(cols["total_energy_j"]).any()
               else None)
    displacement = None
    if fixes.rows.size >= 2 and "lat_deg" in cols and "lon_deg" in cols:
        lat, lon = cols["lat_deg"], cols["lon_deg"]

        def displacement(t0: np.ndarray, t1: np.ndarray) -> np.ndarray:
            """Distance [m] from the last fix at or before ``t0`` to the first at or after
            ``t1``, each within ``gps_max_fill_s`` of its time (else NaN)."""
            ft = t[fixes.rows]
            a = np.searchsorted(ft, t0, "right") - 1
            b = np.searchsorted(ft, t1, "left")
            ok = (a >= 0) & (b < ft.size)
            a, b = np.clip(a, 0, ft.size - 1), np.clip(b, 0, ft.size - 1)
            ok &= (t0 - ft[a] <= p.gps_max_fill_s) & (ft[b] - t1 <= p.gps_max_fill_s)
            ra, rb = fixes.rows[a], fixes.rows[b]
            return np.where(ok, local_distance_m(lat[ra], lon[ra], lat[rb], lon[rb]), np.nan)

    return StopSignals(power, soc, displacement, counter)


def _batch_end(size: np.ndarray, j0: int, max_samples: int) -> int:
    """The end (exclusive) of the batch of trips from ``j0``: as many as fit in
    ``max_samples`` samples (``size`` each), at least one."""
    total = np.cumsum(size[j0:])
    return j0 + max(1, int(np.searchsorted(total, max_samples, side="right")))


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
    frame : canonical columns (``time_s`` [s, UTC epoch] required), rows in file order:
        a DataFrame, or a dict of arrays (:attr:`cevm.ingest.reading.ParsedLog.columns`).
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


def _grid_samples(first_s: np.ndarray, last_s: np.ndarray, grid_s: float | None) -> int:
    """The samples of trips from ``first_s`` to ``last_s`` [s] on the grid as
    :func:`~cevm.ingest.cleaning.grid._grid` makes it (None: no grid, an upper bound of
    one sample a second is not known: 0)."""
    if grid_s is None:
        return 0
    k0 = np.ceil(first_s / grid_s - 1e-9)
    k1 = np.floor(last_s / grid_s + 1e-9)
    return int(np.maximum(k1 - k0 + 1, 0).sum())
