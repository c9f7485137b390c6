"""The repairs of the cleaning steps, with the time at which each happened, so that
each trip counts its own."""

from __future__ import annotations

import numpy as np


class RepairEvents:
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
