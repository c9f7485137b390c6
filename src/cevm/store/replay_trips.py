"""A logged vehicle's stored trips as ``cevm replay`` needs them
(:class:`cevm.core.replay.LoggedTrips`), and the step tables of single trips on demand.

Positions: where each trip starts and ends (for charging at named places and finding a
depot) come from :func:`trip_positions`, the one place that reads them: from the trips'
``start_lat_deg`` / ``start_lon_deg`` / ``end_lat_deg`` / ``end_lon_deg`` columns where
the store has them (ingest stores them since the store's evidence columns), else from each trip's stored
profile (its first and last valid GPS fix: one profile read per trip, about 2 ms).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import lru_cache

import numpy as np
import pandas as pd

from cevm.core.cycle import CycleVector
from cevm.core.limits import Demand, elevation_sd_m, source_demand
from cevm.core.replay import LoggedTrips
from cevm.core.replay.duties import logged_twice
from cevm.core.sweep import LegProfile, StepTable, build_step_table
from cevm.errors import CevmError
from cevm.store.failures import DamagedTripError
from cevm.store.masses import trip_masses
from cevm.store.tripstore import TripStore

#: The trips' position columns, once the store has them.
POSITION_COLUMNS = ("start_lat_deg", "start_lon_deg", "end_lat_deg", "end_lon_deg")

#: Step tables kept per vehicle (a trip's crossing and its excess read the same one).
STEP_TABLES_KEPT = 16


def _fix(lat: np.ndarray, lon: np.ndarray, last: bool) -> tuple[float, float]:
    ok = np.flatnonzero(np.isfinite(lat) & np.isfinite(lon))
    if not ok.size:
        return math.nan, math.nan
    i = int(ok[-1] if last else ok[0])
    return float(lat[i]), float(lon[i])


def trip_positions(st: TripStore, rows: pd.DataFrame,
                   on_damaged: Callable[[DamagedTripError], None] | None = None) -> tuple[np.ndarray, ...]:
    """(start_lat, start_lon, end_lat, end_lon) [deg] of the trips of ``rows`` (a
    :meth:`~cevm.store.TripStore.list_trips` frame), NaN where unknown: the store's
    position columns if it has them, else each profile's first and last valid fix (a
    damaged profile: unknown, and passed to ``on_damaged``)."""
    if all(c in rows.columns for c in POSITION_COLUMNS):
        return tuple(rows[c].to_numpy(dtype=np.float64) for c in POSITION_COLUMNS)
    n = len(rows)
    out = np.full((4, n), np.nan)
    for j, tid in enumerate(rows["trip_id"]):
        try:
            p = st.load_profile(tid)
        except DamagedTripError as exc:
            if on_damaged is not None:
                on_damaged(exc)
            continue
        lat, lon = p.get("lat_deg"), p.get("lon_deg")
        if lat is None or lon is None:
            continue
        out[0, j], out[1, j] = _fix(lat, lon, last=False)
        out[2, j], out[3, j] = _fix(lat, lon, last=True)
    return tuple(out)


def logged_trips(st: TripStore, vehicle_id: str, *, positions: bool = False,
                 day_of: Callable[[np.ndarray], np.ndarray] | None = None,
                 on_damaged: Callable[[DamagedTripError], None] | None = None,
                 on_damaged_profile: Callable[[DamagedTripError], None] | None = None,
                 on_logged_twice: Callable[[list[str]], None] | None = None) -> LoggedTrips:
    """The stored trips of ``vehicle_id`` sorted by start, with their masses (a mass given
    to the trip, else its logged gross weight; :mod:`cevm.store.masses`), temperatures,
    and with ``positions`` their start and end positions; ``day_of`` gives each trip's
    day number from its start [s] (for duties by calendar day). Damaged trips go to
    ``on_damaged`` and are left out (counted in ``missing``); a trip whose profile alone is
    damaged stays (its positions unknown) and goes to ``on_damaged_profile``. A trip
    lying mostly inside an earlier one (:func:`~cevm.core.replay.duties.logged_twice`:
    the same driving logged twice) is left out and its id goes to ``on_logged_twice``."""
    missing: list[DamagedTripError] = []

    def damaged(exc: DamagedTripError) -> None:
        missing.append(exc)
        if on_damaged is not None:
            on_damaged(exc)

    vectors: dict[str, CycleVector] = st.load_cycle_vectors(vehicle_id=vehicle_id, on_damaged=damaged)
    if not vectors:
        raise CevmError(f"vehicle id {vehicle_id!r} has no usable stored trips"
                        + (" (all are damaged; 'cevm store check' lists them)" if missing else ""))
    rows = st.list_trips(vehicle_id=vehicle_id)
    rows = rows[rows["trip_id"].isin(list(vectors))].sort_values(["start_utc_s", "trip_id"], kind="stable")
    twice = logged_twice(rows["start_utc_s"].to_numpy(dtype=np.float64),
                         (rows["start_utc_s"] + rows["duration_s"]).to_numpy(dtype=np.float64))
    if twice.any():
        if on_logged_twice is not None:
            on_logged_twice(list(rows["trip_id"][twice]))
        rows = rows[~twice]
    masses = trip_masses(st, rows)
    gross = np.full(len(rows), np.nan)
    payload = np.full(len(rows), np.nan)
    sources = []
    for j, tid in enumerate(rows["trip_id"]):
        m = masses[tid]
        key = m.sweep_key()
        if key is not None:
            (gross if key[0] == "gross" else payload)[j] = key[1]
        sources.append(m.origin)
    start = rows["start_utc_s"].to_numpy(dtype=np.float64)
    pos = trip_positions(st, rows, on_damaged_profile) if positions else (None,) * 4
    return LoggedTrips(vehicle_id=vehicle_id, trip_ids=tuple(rows["trip_id"]), start_s=start,
                       end_s=start + rows["duration_s"].to_numpy(dtype=np.float64),
                       distance_m=rows["distance_m"].to_numpy(dtype=np.float64),
                       vectors=tuple(vectors[t] for t in rows["trip_id"]), gross_kg=gross, payload_kg=payload,
                       mass_source=tuple(sources), ambient_c=rows["ambient_temp_c"].to_numpy(dtype=np.float64),
                       start_lat=pos[0], start_lon=pos[1], end_lat=pos[2], end_lon=pos[3],
                       day=None if day_of is None else day_of(start), missing=len(missing),
                       elevation_source=tuple(rows["elevation_source"]) if "elevation_source" in rows else None)


def step_table_reader(st: TripStore, trips: LoggedTrips,
                      on_damaged: Callable[[DamagedTripError], None] | None = None
                      ) -> Callable[[int], StepTable | None]:
    """``read(i)``: the step table of trip i of ``trips`` (its stored profile with its
    vector's Cr0 and physics), None when the profile is damaged (passed to
    ``on_damaged``); the last few kept."""

    terms = [(v.cr0, v.physics) for v in trips.vectors]  # not the vectors: the caller may free them

    @lru_cache(maxsize=STEP_TABLES_KEPT)
    def read(i: int) -> StepTable | None:
        got = _trip_table(st, trips.trip_ids[i], terms[i], on_damaged)
        return None if got is None else got[1]

    return read


def _trip_table(st: TripStore, trip_id: str, terms: tuple, on_damaged: Callable[[DamagedTripError], None] | None
                ) -> tuple[list[LegProfile], StepTable] | None:
    """A stored trip's leg and step table (with its vector's ``terms``: Cr0, physics),
    None when its profile is damaged (passed to ``on_damaged``)."""
    cr0, physics = terms
    try:
        profile = st.load_profile(trip_id)
    except DamagedTripError as exc:
        if on_damaged is not None:
            on_damaged(exc)
        return None
    legs = [LegProfile.from_profile(profile)]
    return legs, build_step_table(legs, cr0=cr0, physics=physics)


def demand_reader(st: TripStore, trips: LoggedTrips,
                  on_damaged: Callable[[DamagedTripError], None] | None = None) -> Callable[[int], Demand | None]:
    """``demand(i)``: what trip i of ``trips`` asks of a vehicle's power and speed
    (:class:`cevm.core.limits.Demand`, from its stored profile: a logged trace, held with
    its measurement's tolerance as ``cevm predict`` holds a stored trip), None when the
    profile is damaged (passed to ``on_damaged``). Nothing kept: each trip is judged once
    (:mod:`cevm.core.replay.follow`)."""
    terms = [(v.cr0, v.physics) for v in trips.vectors]
    elevation = trips.elevation_source or (None,) * trips.n

    def demand(i: int) -> Demand | None:
        got = _trip_table(st, trips.trip_ids[i], terms[i], on_damaged)
        if got is None:
            return None
        legs, table = got
        return source_demand(table, legs, logged=True, elevation_sd=elevation_sd_m(elevation[i]))

    return demand
