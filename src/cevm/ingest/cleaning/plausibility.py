"""Readings a road vehicle cannot produce: speeds out of range, spikes that a speed
reaches and leaves faster than tyres allow; runs between impossible jumps."""

from __future__ import annotations

import numpy as np

from cevm.ingest.cleaning.arrays import _nonzero
from cevm.ingest.cleaning.events import RepairEvents
from cevm.ingest.cleaning.params import CleanParams
from cevm.ingest.consumption import chunks


def _short_runs_between_jumps(jump: np.ndarray, max_len: int) -> np.ndarray | None:
    """Samples to reject, given ``jump[i]`` (an impossible step from sample i to i+1):
    the jumps cut the samples into runs, and runs of at most ``max_len`` samples are
    outliers (they jump away and back). None when every run is that short (nothing
    to tell the outliers from)."""
    run = np.concatenate(([0], np.cumsum(jump)))
    small = np.bincount(run) <= max_len
    return None if small.all() else small[run]


def _steps_over(rows: np.ndarray, t: np.ndarray, change: np.ndarray, rate: float, tolerance: float) -> np.ndarray:
    """Per step between consecutive ``rows``: whether ``change`` (len - 1) exceeds
    ``rate * dt + tolerance`` (``t`` the row times)."""
    out = np.empty(change.size, dtype=bool)
    for a, b in chunks(change.size):
        out[a:b] = change[a:b] > rate * np.diff(t[rows[a:b + 1]]) + tolerance
    return out


def _speed_rows(t, cols, name, p: CleanParams, ev: RepairEvents) -> np.ndarray | None:
    """Rows with a plausible value of the speed column ``name`` (None without the
    column); implausible values are counted as ``speed_values_rejected``."""
    if name not in cols:
        return None
    v = cols[name]
    fin = np.isfinite(v)
    ok = fin & (v >= 0) & (v <= p.max_speed_mps)
    ev.add("speed_values_rejected", t[fin & ~ok])
    del fin
    return _drop_speed_spikes(t, v, ok, p, ev, name)


def _drop_speed_spikes(t, v, ok: np.ndarray, p: CleanParams, ev: RepairEvents, name: str = "speed") -> np.ndarray:
    """``ok`` without speed spikes: consecutive readings whose change exceeds
    ``max_accel_mps2 * dt + speed_jump_tolerance_mps`` are impossible jumps; runs of at
    most ``speed_outlier_max_samples`` readings between them are rejected
    (``speed_spikes_rejected``), jumps left are counted (``speed_unresolved_jumps``) and
    kept with their time and size (:meth:`RepairEvents.add_jumps`, column ``name``)."""
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
    after = idx[1:][jump]
    ev.add("speed_unresolved_jumps", t[after])
    if after.size:
        before = idx[:-1][jump]
        ev.add_jumps(name, t[after], t[after] - t[before], v[before], v[after])
    return ok
