"""Stored trips' 1 Hz speed series, the input of
:func:`cevm.core.timetable.learning.learn_driving`: read one profile at a time (each
decoded, its time and speed kept, the rest dropped), at most ``max_trips`` of them, so
that memory stays at one decoded profile plus the kept series (16 bytes a sample)."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from cevm.errors import CevmError
from cevm.store.failures import DamagedTripError
from cevm.store.tripstore import TripStore


def driving_trip_ids(store: TripStore, vehicle_ids: Sequence[str], *, max_trips: int = 500) -> list[str]:
    """The ids of the trips :func:`load_driving_series` reads: the vehicles' trips by
    start time, every n-th when there are more than ``max_trips`` (spread over the whole
    period, not its first weeks)."""
    if max_trips < 1:
        raise CevmError(f"max_trips must be at least 1, got {max_trips}")
    ids: list[str] = []
    for vid in dict.fromkeys(vehicle_ids):
        ids.extend(store.list_trips(vid)["trip_id"].tolist())  # unknown ids: CevmError naming the store
    if len(ids) > max_trips:
        pick = np.unique(np.linspace(0, len(ids) - 1, max_trips).round().astype(np.int64))
        ids = [ids[i] for i in pick.tolist()]
    return ids


def load_driving_series(store: TripStore, vehicle_ids: Sequence[str], *, max_trips: int = 500,
                        trip_ids: Sequence[str] | None = None,
                        on_damaged: Callable[[DamagedTripError], None] | None = None,
                        ) -> list[tuple[np.ndarray, np.ndarray]]:
    """(time_s, speed_mps) of the stored trips of ``vehicle_ids`` (or exactly
    ``trip_ids``), at most ``max_trips`` (:func:`driving_trip_ids`). A damaged profile
    raises :class:`DamagedTripError`, or with ``on_damaged`` is passed to it and left
    out."""
    ids = list(trip_ids) if trip_ids is not None else driving_trip_ids(store, vehicle_ids, max_trips=max_trips)
    out: list[tuple[np.ndarray, np.ndarray]] = []
    for tid in ids:
        try:
            p = store.load_profile(tid)
        except DamagedTripError as exc:
            if on_damaged is None:
                raise
            on_damaged(exc)
            continue
        out.append((p["time_s"], p["speed_mps"]))
        del p
    return out
