"""Step 6 of the cleaning for a batch of trips: each trip's speed on the regular time
grid, and what its speed rows say of holes and sources. Every trip of the batch at once
(:mod:`cevm.ingest.segments`), each with the values of a computation on that trip
alone."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cevm.ingest.cleaning.params import SPEED_SOURCES, CleanParams
from cevm.ingest.segments import (
    bounds_of,
    ranges,
    segment_diffs,
    segment_ids,
    segment_interp,
    segment_medians,
    segment_searchsorted,
    segment_sums,
)


@dataclass(frozen=True, eq=False)
class BatchSpeedRows:
    """The speed rows of the trips of a batch, end to end: times [s, UTC], speeds
    [m/s], speed source codes (``bounds``: each trip's rows); why each trip starts and
    ends, and the lowest and highest file line of the log's rows it spans."""

    t: np.ndarray
    v: np.ndarray
    src: np.ndarray
    bounds: np.ndarray
    split_before: list[str]
    split_after: list[str]
    lines: list[tuple[int, int]]

    def __len__(self) -> int:
        return self.bounds.size - 1


def grid_lengths(first_s: np.ndarray, last_s: np.ndarray, n_rows: np.ndarray, grid_s: float | None) -> np.ndarray:
    """Samples of each trip's grid: whole multiples of ``grid_s`` in UTC from its first
    to its last row time (``1e-9`` of a step of slack each side), none for a trip of
    one row; its rows themselves without a grid (``grid_s`` None)."""
    if grid_s is None:
        return np.where(n_rows > 1, n_rows, 0)
    k0 = np.ceil(first_s / grid_s - 1e-9)
    k1 = np.floor(last_s / grid_s + 1e-9)
    return np.where(n_rows > 1, np.maximum(k1 - k0 + 1, 0), 0).astype(np.int64)


def batch_grid(seg: BatchSpeedRows, trips: np.ndarray, lengths: np.ndarray, grid_s: float | None) -> np.ndarray:
    """The grid times [s, UTC] of the trips ``trips`` of ``seg`` (``lengths`` samples
    each), end to end: ``np.arange(k0, k1 + 1) * grid_s`` of each (the integers are
    exact in float64), or a copy of the trip's row times without a grid."""
    b = seg.bounds
    if grid_s is None:
        return seg.t[ranges(b[trips], lengths)]
    k0 = np.ceil(seg.t[b[trips]] / grid_s - 1e-9).astype(np.int64)
    return ranges(k0, lengths).astype(np.float64) * grid_s


def speed_on_grid(grid_t: np.ndarray, gb: np.ndarray, seg: BatchSpeedRows, trips: np.ndarray,
                  p: CleanParams) -> tuple[np.ndarray, np.ndarray]:
    """Speed at the grid times of the trips ``trips`` (grid bounds ``gb``): linear
    between the trip's rows, 0 inside the holes over ``max_fill_s`` that a trip keeps
    (between two standstill rows by construction: stops); and each trip's number of such
    holes."""
    b = seg.bounds
    starts, lens = b[trips], np.diff(b)[trips]
    gid = segment_ids(gb)
    v = segment_interp(grid_t, gid, seg.t, starts, lens, seg.v)
    # the holes: steps between two rows of a trip longer than max_fill_s
    rows = ranges(starts, lens - 1)
    step = seg.t[rows + 1] - seg.t[rows]
    hole = rows[step > p.max_fill_s]
    n_holes = np.zeros(trips.size, dtype=np.int64)
    if hole.size:
        hseg = np.searchsorted(starts, hole, side="right") - 1  # the trip (among ``trips``) of each hole
        n_holes = np.bincount(hseg, minlength=trips.size)
        glen = np.diff(gb)
        a = segment_searchsorted(grid_t, gb[:-1], glen, seg.t[hole], hseg, "right") + gb[hseg]
        e = segment_searchsorted(grid_t, gb[:-1], glen, seg.t[hole + 1], hseg, "left") + gb[hseg]
        diff = np.zeros(grid_t.size + 1, dtype=np.int64)
        np.add.at(diff, a, 1)
        np.add.at(diff, e, -1)
        v[np.cumsum(diff)[:-1] > 0] = 0.0
    return v, n_holes


def speed_holes_bridged(seg: BatchSpeedRows, trips: np.ndarray, p: CleanParams) -> tuple[np.ndarray, np.ndarray]:
    """Per trip of ``trips``: speed holes (steps over twice the trip's median row
    interval, up to ``max_fill_s``) interpolated across, their number and total
    duration [s]."""
    dts, db = _trip_steps(seg, trips)
    nominal = segment_medians(dts, segment_ids(db), trips.size)
    bridged = (dts > 2 * np.repeat(nominal, np.diff(db))) & (dts <= p.max_fill_s)
    sid = segment_ids(db)[bridged]
    count = np.bincount(sid, minlength=trips.size)
    return count, segment_sums(dts[bridged], bounds_of(count))


def _trip_steps(seg: BatchSpeedRows, trips: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The time steps between the rows of each trip of ``trips``, end to end, and their
    bounds."""
    if trips.size == len(seg):
        return segment_diffs(seg.t, seg.bounds)
    b = seg.bounds
    lens = np.diff(b)[trips]
    return segment_diffs(seg.t[ranges(b[trips], lens)], bounds_of(lens))


def speed_source_share(seg: BatchSpeedRows, trips: np.ndarray) -> list[tuple[str | None, dict]]:
    """Per trip of ``trips``: the speed source of most rows (None without rows) and each
    source's share of the rows."""
    b = seg.bounds
    lens = np.diff(b)[trips]
    k = len(SPEED_SOURCES)
    code = seg.src.astype(np.int64)
    ok = (code >= 0) & (code < k)
    key = segment_ids(b) * k + code
    counts = np.bincount(key[ok], minlength=len(seg) * k).reshape(len(seg), k)
    out = []
    for c_row, n in zip(counts[trips].tolist(), lens.tolist(), strict=True):
        share = {SPEED_SOURCES[c]: k / n for c, k in enumerate(c_row) if k}
        out.append(((max(share, key=lambda s: share[s]) if share else None), share))
    return out
