"""Step 6 of the cleaning: a trip's speed on the regular time grid, and what its speed rows
say of holes and sources."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cevm.ingest.cleaning.params import SPEED_SOURCES, CleanParams


def _grid(t_kept: np.ndarray, grid_s: float | None) -> np.ndarray:
    if grid_s is None:
        return t_kept.copy()
    k0 = math.ceil(t_kept[0] / grid_s - 1e-9)
    k1 = math.floor(t_kept[-1] / grid_s + 1e-9)
    if k1 < k0:
        return np.empty(0)
    return np.arange(k0, k1 + 1, dtype=float) * grid_s


@dataclass(frozen=True, eq=False)
class TripSpeedRows:
    """The speed rows of one trip (times, speeds, speed source codes), why it starts
    and ends, and the lowest and highest file line of the log's rows it spans."""

    t: np.ndarray
    v: np.ndarray
    src: np.ndarray
    split_before: str
    split_after: str
    lines: tuple[int, int]


def _speed_on_grid(grid_t: np.ndarray, seg: TripSpeedRows, p: CleanParams) -> tuple[np.ndarray, int]:
    """Speed at the grid times ``grid_t`` (linear between rows), 0 inside the holes over
    ``max_fill_s`` that a trip keeps (between two standstill rows by construction:
    stops); and the number of such holes."""
    v = np.interp(grid_t, seg.t, seg.v)
    hole = np.flatnonzero(np.diff(seg.t) > p.max_fill_s)
    if hole.size:
        a = np.searchsorted(grid_t, seg.t[hole], "right")
        b = np.searchsorted(grid_t, seg.t[hole + 1], "left")
        diff = np.zeros(grid_t.size + 1, dtype=np.int64)
        np.add.at(diff, a, 1)
        np.add.at(diff, b, -1)
        v[np.cumsum(diff)[:-1] > 0] = 0.0
    return v, int(hole.size)


def _speed_holes_bridged(seg: TripSpeedRows, p: CleanParams) -> tuple[int, float]:
    """Speed holes (steps over twice the nominal row interval, up to ``max_fill_s``)
    interpolated across: their number and total duration [s]."""
    dts = np.diff(seg.t)
    nominal_row = float(np.median(dts)) if dts.size else math.nan
    bridged = (dts > 2 * nominal_row) & (dts <= p.max_fill_s)
    return int(bridged.sum()), float(dts[bridged].sum())


def _speed_source_share(seg: TripSpeedRows) -> tuple[str | None, dict]:
    """The speed source of most rows (None without rows) and each source's share."""
    share = {SPEED_SOURCES[c]: float(np.mean(seg.src == c)) for c in range(3) if np.any(seg.src == c)}
    return (max(share, key=share.get) if share else None), share
