"""The repairs of the cleaning steps, with the time at which each happened, so that
each trip counts its own."""

from __future__ import annotations

from typing import Any

import numpy as np


class RepairEvents:
    """Repairs with the (sorted-frame) time at which they happened, to count per trip."""

    NAMES = (
        "time_outliers_dropped", "clock_steps", "duplicate_rows_dropped", "ticks_merged",
        "conflicting_values", "gps_rejected_invalid", "gps_rejected_stale",
        "gps_rejected_jump", "gps_unresolved_jumps", "speed_values_rejected",
        "speed_spikes_rejected", "speed_unresolved_jumps", "gps_speed_zeroed",
    )

    #: Lasting speed jumps kept per trip in its quality (the largest first), at most.
    MAX_JUMPS_LISTED = 10

    def __init__(self) -> None:
        self._t: dict[str, list[np.ndarray]] = {k: [] for k in self.NAMES}
        self._jumps: list[tuple[str, np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []

    def add_jumps(self, source: str, t_s, dt_s, from_mps, to_mps) -> None:
        """Lasting speed jumps of the speed column ``source`` that the cleaning could not
        repair (a spliced recording): the time [s, UTC] of the reading after each, the
        time step [s] and the speeds before and after [m/s]."""
        t_s = np.atleast_1d(np.asarray(t_s, dtype=float))
        if t_s.size:
            self._jumps.append((source, t_s, *(np.atleast_1d(np.asarray(a, dtype=float))
                                               for a in (dt_s, from_mps, to_mps))))

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

    @property
    def has_jumps(self) -> bool:
        """Whether any lasting speed jump was recorded."""
        return bool(self._jumps)

    def jumps_between(self, t0: float, t1: float) -> list[dict]:
        """The lasting speed jumps from ``t0`` to ``t1`` [s, UTC], the largest first (at
        most :data:`MAX_JUMPS_LISTED`): ``{"source", "utc_s", "dt_s", "from_mps",
        "to_mps"}`` each."""
        found: list[dict[str, Any]] = [{"source": source, "utc_s": float(t[i]), "dt_s": float(dt[i]),
                  "from_mps": float(v0[i]), "to_mps": float(v1[i])}
                 for source, t, dt, v0, v1 in self._jumps
                 for i in np.flatnonzero((t >= t0) & (t <= t1))]
        found.sort(key=lambda j: (-abs(j["to_mps"] - j["from_mps"]), j["utc_s"]))
        return found[: self.MAX_JUMPS_LISTED]

    def totals(self) -> dict:
        return {k: int(v.size) for k, v in self.times.items()}

    def between(self, t0: float, t1: float) -> dict:
        return {
            k: int(np.searchsorted(v, t1, "right") - np.searchsorted(v, t0, "left"))
            for k, v in self.times.items()
        }
