"""A timetable's blocks run as duties with replay's machinery (pure): each block on each
date is one duty of a "vehicle" named after the block, its legs (the revenue trips and the
empty running between them, :mod:`cevm.core.timetable.blocks`) the duty's trips.

:func:`block_trips` turns one block's legs over the dates into the
:class:`~cevm.core.replay.LoggedTrips` replay takes: each leg's representative drive
cycle (its CE vector), its mass and temperature, its position, the service date as the
duty's day (replay's ``day`` rule: a block's trips after midnight stay in its service
day's duty), the synthesis's spread as each leg's own independent spread
(``own_sd``, added to the model's in the duty's distribution and its Monte Carlo) and the
synthesis's mean over its draws (``energy_offset``). :func:`plan_block` runs it:
:func:`cevm.core.replay.plan_vehicle`, the lowest level looked for at the legs' ends
(a synthesised cycle has no stored step table).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from cevm.core.replay import LoggedTrips, ReplaySettings, VehiclePlan, plan_vehicle
from cevm.core.timetable import geometry as geo
from cevm.core.timetable.blocks import DeadheadRule, Legs, block_legs, day_blocks
from cevm.core.timetable.schedule import Scheduled, Timetable, TripGeometry, native
from cevm.core.vehicle import Vehicle


@dataclass(frozen=True, eq=False)
class BlockDay:
    """One block on one date: ``name``, ``source`` ("feed" or "inferred"), ``date``
    (index into the timetable's dates), ``legs``, ``instance`` per leg (index into the
    :class:`~cevm.core.timetable.schedule.Scheduled` instances; -1 for empty running)."""

    name: str
    source: str
    date: int
    legs: Legs
    instance: np.ndarray


def blocks_by_date(tt: Timetable, gm: TripGeometry, sch: Scheduled, rule: DeadheadRule, *,
                   min_layover_s: float) -> list[BlockDay]:
    """Every date's blocks (by block_id, else inferred) with their legs, by date then
    first departure."""
    first, last = gm.first_last(tt)
    start_all = gm.departure_s[first]
    end_all = gm.arrival_s[last]
    lat0, lon0 = float(np.mean(tt.stop_lat[tt.stop])), float(np.mean(tt.stop_lon[tt.stop]))
    k = np.cos(np.radians(lat0))
    x = np.radians(tt.stop_lon - lon0) * k * 6371008.8
    y = np.radians(tt.stop_lat - lat0) * 6371008.8
    s_stop, e_stop = tt.stop[first], tt.stop[last]
    dist = gm.distance_m(tt)
    out: list[BlockDay] = []
    for di in range(len(tt.dates)):
        inst = np.flatnonzero(sch.date == di)
        if not inst.size:
            continue
        t = sch.trip[inst]
        b = day_blocks(tt.trip_id[t], tt.block_id[t], start_all[t], end_all[t], s_stop[t], e_stop[t],
                       (x[s_stop[t]], y[s_stop[t]]), (x[e_stop[t]], y[e_stop[t]]), min_layover_s=min_layover_s)
        ll_s = (tt.stop_lat[s_stop[t]], tt.stop_lon[s_stop[t]])
        ll_e = (tt.stop_lat[e_stop[t]], tt.stop_lon[e_stop[t]])
        for name, src, rows in zip(b.names, b.source, b.trips, strict=True):
            legs = block_legs(rows, start_all[t], end_all[t], dist[t], ll_s, ll_e, geo.geodesic_m, rule)
            out.append(BlockDay(name, src, di, legs, np.where(legs.trip >= 0, inst[np.maximum(legs.trip, 0)], -1)))
    return out


#: Empty running synthesised: (distance [m], duration [s], ambient [degC]) -> (vector,
#: energy [J or l], own spread, offset) (the caller synthesises it, cached).
EmptyRun = Callable[[float, float, float], tuple]


def block_trips(name: str, days: Sequence[BlockDay], tt: Timetable, sch: Scheduled, day_origin_s: np.ndarray,
                empty_run: EmptyRun) -> LoggedTrips:
    """One block's legs over its dates as replay's :class:`LoggedTrips` (module notes).
    ``day_origin_s`` (per date) the epoch second of the service day's noon less 12 h."""
    ids: list[str] = []
    cols: dict[str, list] = {k: [] for k in ("start", "end", "dist", "vec", "mass", "amb", "slat", "slon", "elat",
                                             "elon", "day", "own", "off")}
    for bd in days:
        lg = bd.legs
        origin = float(day_origin_s[bd.date])
        near = np.maximum.accumulate(np.where(bd.instance >= 0, bd.instance, -1))
        first_inst = int(bd.instance[bd.instance >= 0][0])
        for j in range(lg.n):
            inst = int(bd.instance[j])
            if inst >= 0:
                ids.append(str(tt.trip_id[sch.trip[inst]]))
                vec, off, own = sch.vectors[inst], float(sch.offset[inst]), float(sch.own_sd[inst])
                mass, amb = float(sch.mass_kg[inst]), float(sch.ambient_c[inst])
            else:
                ref = int(near[j]) if near[j] >= 0 else first_inst
                amb, mass = float(sch.ambient_c[ref]), float(sch.mass_kg[ref])
                vec, _, own, off = empty_run(float(lg.distance_m[j]), float(lg.end_s[j] - lg.start_s[j]), amb)
                ids.append(f"({lg.kind[j]})")
            cols["start"].append(origin + lg.start_s[j])
            cols["end"].append(origin + lg.end_s[j])
            cols["dist"].append(lg.distance_m[j])
            cols["vec"].append(vec)
            cols["mass"].append(mass)
            cols["amb"].append(amb)
            for c, v in (("slat", lg.start_lat), ("slon", lg.start_lon), ("elat", lg.end_lat), ("elon", lg.end_lon)):
                cols[c].append(v[j])
            cols["day"].append(tt.dates[bd.date])
            cols["own"].append(own)
            cols["off"].append(off)
    start = np.asarray(cols["start"], dtype=np.float64)
    order = np.argsort(start, kind="stable")

    def arr(k: str, dtype=np.float64) -> np.ndarray:
        return np.asarray(cols[k], dtype=dtype)[order]

    n = start.size
    return LoggedTrips(vehicle_id=name, trip_ids=tuple(ids[i] for i in order), start_s=start[order],
                       end_s=arr("end"), distance_m=arr("dist"), vectors=tuple(cols["vec"][i] for i in order),
                       gross_kg=arr("mass"), payload_kg=np.full(n, np.nan), mass_source=("given",) * n,
                       ambient_c=arr("amb"), start_lat=arr("slat"), start_lon=arr("slon"), end_lat=arr("elat"),
                       end_lon=arr("elon"), day=arr("day", np.int64), own_sd=arr("own"), energy_offset=arr("off"))


def join_blocks(blocks: Sequence[LoggedTrips]) -> LoggedTrips:
    """Blocks' trips (each as :func:`block_trips` gives them) as one run whose duties are
    the block-days, in order (replay's ``given`` rule: ``day`` becomes each trip's duty)."""
    def ranks(b: LoggedTrips) -> np.ndarray:  # its dates as 0, 1, ...
        assert b.day is not None, "block_trips gives each trip its date"
        return np.unique(b.day, return_inverse=True)[1].astype(np.int64)

    if len(blocks) == 1:
        return dataclasses.replace(blocks[0], day=ranks(blocks[0]))
    duty, offset = [], 0
    for b in blocks:
        rank = ranks(b)
        duty.append(rank + offset)
        offset += int(rank.max()) + 1 if rank.size else 0

    def cat(name: str) -> np.ndarray:
        return np.concatenate([getattr(b, name) for b in blocks])

    return LoggedTrips(vehicle_id=blocks[0].vehicle_id if len(blocks) == 1 else "blocks",
                       trip_ids=tuple(t for b in blocks for t in b.trip_ids), start_s=cat("start_s"),
                       end_s=cat("end_s"),
                       distance_m=cat("distance_m"), vectors=tuple(v for b in blocks for v in b.vectors),
                       gross_kg=cat("gross_kg"), payload_kg=cat("payload_kg"),
                       mass_source=tuple(m for b in blocks for m in b.mass_source), ambient_c=cat("ambient_c"),
                       start_lat=cat("start_lat"), start_lon=cat("start_lon"), end_lat=cat("end_lat"),
                       end_lon=cat("end_lon"), day=np.concatenate(duty), own_sd=cat("own_sd"),
                       energy_offset=cat("energy_offset"))


def _no_table(i: int) -> None:
    return None


def plan_block(trips: LoggedTrips, vehicle: Vehicle, settings: ReplaySettings) -> VehiclePlan:
    """Blocks' duties (:func:`join_blocks`: one per block and date) run with replay's
    machinery (module notes)."""
    s = dataclasses.replace(settings, rule="given", within_trips=False)
    return plan_vehicle(trips, vehicle, s, _no_table)


def empty_energy(vehicle: Vehicle, distance_m: float, duration_s: float, ambient_c: float, mass_kg: float, params,
                 *, draws: int, seed: int) -> tuple:
    """Empty running's cycle and energy: one run from stop to stop, flat (its road is not
    known), through :func:`cevm.core.timetable.energy.scheduled_trip_energy`; (vector,
    energy, own spread, offset) in the candidate's unit."""
    from cevm.core.replay import trip_energies
    from cevm.core.timetable.energy import scheduled_trip_energy

    dur = max(duration_s, 1.0)
    se = scheduled_trip_energy(vehicle, np.array([0.0, distance_m]), np.array([0.0, dur]), np.array([0.0, dur]),
                               profile_dist_m=None, profile_elev_m=None, mass_kg=mass_kg, ambient_c=ambient_c,
                               params=params, draws=draws, seed=seed)
    rep = float(trip_energies([se.vector], vehicle, mass_kg, ambient_c).energy[0])
    e = float(native(vehicle, se.energy_j))
    return se.vector, e, float(native(vehicle, se.sd_synthesis_j)), e - rep
