"""A timetable's trips placed on the map and given their energy (pure): the feed's arrays
(:class:`Timetable`, read by :mod:`cevm.io.gtfs`), each trip's stops along its shape
(:func:`trip_geometry`), and each trip on each date with its drive cycle's energy
(:func:`schedule_energies`, through :func:`cevm.core.timetable.energy.scheduled_trip_energy`).

Identical trips are synthesised once: a city's weekday repeats a route's pattern (the same
shape, the same stops, the same running times from the first departure) dozens of times.
The synthesis runs at the first such trip's temperature; every other trip of the pattern
takes that energy moved by what its own temperature changes on the representative cycle
(the CE model's terms beyond the wheel on the cached vector, :func:`cevm.core.replay.trip_energies`),
the synthesis's spread kept.
"""

from __future__ import annotations

import zlib
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from cevm.core.replay.trip_energies import trip_energies
from cevm.core.timetable import geometry as geo
from cevm.core.vehicle import Vehicle


@dataclass(frozen=True, eq=False)
class Timetable:
    """A feed's trips on the dates asked (read by :func:`cevm.io.gtfs.read_feed`).

    Per trip (n): ``trip_id``, ``route_id``, ``block_id`` ("" where none), ``shape_id`` (""
    where none), ``runs`` (n, len(dates)) bool. Stop times, trip i's in rows
    ``bounds[i]:bounds[i+1]`` in stop_sequence order: ``stop`` (index into the stops),
    ``arrival_s`` and ``departure_s`` (seconds from the service day's noon less 12 h, NaN
    where the feed leaves a stop untimed), ``dist`` (the feed's shape_dist_traveled in
    its own unit; NaN where not given): float32 (whole seconds exact; a city's ten million
    rows in half the memory), ``line`` (stop_times.txt line, 0 for an expanded
    frequency trip). Stops: ``stop_id``, ``stop_lat``, ``stop_lon`` [deg]. ``shapes``:
    shape id -> (lat, lon, dist) in shape_pt_sequence order. ``dates`` service dates
    (ordinals) and ``date_from`` how they were chosen; ``timezone`` the agency's."""

    source: str
    timezone: str
    dates: tuple[int, ...]
    date_from: str
    trip_id: np.ndarray
    route_id: np.ndarray
    block_id: np.ndarray
    shape_id: np.ndarray
    runs: np.ndarray
    bounds: np.ndarray
    stop: np.ndarray
    arrival_s: np.ndarray
    departure_s: np.ndarray
    dist: np.ndarray
    line: np.ndarray
    stop_id: np.ndarray
    stop_lat: np.ndarray
    stop_lon: np.ndarray
    shapes: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]
    stop_times_rows: int = 0
    notes: tuple[str, ...] = field(default=())

    @property
    def n(self) -> int:
        return int(self.trip_id.size)


@dataclass(frozen=True, eq=False)
class TripGeometry:
    """Where each trip runs: per stop time (rows of the timetable) ``along_m`` its
    distance along the trip's geometry [m], ``arrival_s``/``departure_s`` with untimed
    stops filled (:func:`cevm.core.timetable.geometry.fill_times`); per trip ``key`` (its
    geometry: the shape id, or ``stops:...`` for straight lines), ``placed`` (how its
    stops were placed); ``shapes`` key -> :class:`~cevm.core.timetable.geometry.Shape`."""

    along_m: np.ndarray
    arrival_s: np.ndarray
    departure_s: np.ndarray
    key: np.ndarray
    placed: np.ndarray
    shapes: dict[str, geo.Shape]

    def stops_of(self, tt: Timetable, i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Trip i's stops' distances from its first stop [m], arrivals and departures [s]."""
        a, b = int(tt.bounds[i]), int(tt.bounds[i + 1])
        d = self.along_m[a:b]
        return d - d[0], self.arrival_s[a:b], self.departure_s[a:b]

    def first_last(self, tt: Timetable) -> tuple[np.ndarray, np.ndarray]:
        return tt.bounds[:-1], tt.bounds[1:] - 1

    def distance_m(self, tt: Timetable) -> np.ndarray:
        f, la = self.first_last(tt)
        return self.along_m[la] - self.along_m[f]


def trip_geometry(tt: Timetable) -> TripGeometry:
    """Each trip's stops placed along its shape (or straight lines between its stops where
    it has none), one placement per distinct (shape, stops, distances) pattern."""
    along = np.zeros(tt.stop.size)
    shapes: dict[str, geo.Shape] = {}
    for sid, (lat, lon, dist) in tt.shapes.items():
        shapes[sid] = geo.resample(lat, lon, dist)
    key = np.empty(tt.n, dtype=object)
    placed = np.empty(tt.n, dtype=object)
    done: dict[tuple, tuple[np.ndarray, str]] = {}
    for i in range(tt.n):  # trips; a placement per distinct pattern
        a, b = int(tt.bounds[i]), int(tt.bounds[i + 1])
        stops = tt.stop[a:b]
        sid = str(tt.shape_id[i])
        if not sid:
            ends = "-".join(str(tt.stop_id[s]) for s in stops[[0, -1]])
            sid = f"stops:{ends}:{zlib.crc32(stops.tobytes()):08x}"
            if sid not in shapes:
                shapes[sid] = geo.straight_shape(tt.stop_lat[stops], tt.stop_lon[stops])
        pattern = (sid, stops.tobytes(), tt.dist[a:b].tobytes())
        hit = done.get(pattern)
        if hit is None:
            hit = done[pattern] = geo.place_stops(shapes[sid], tt.stop_lat[stops], tt.stop_lon[stops], tt.dist[a:b])
        along[a:b] = hit[0]
        key[i] = sid
        placed[i] = hit[1]
    arr = tt.arrival_s.astype(np.float64)
    dep = tt.departure_s.astype(np.float64)
    untimed = np.isnan(arr)
    if untimed.any():
        for i in np.unique(np.searchsorted(tt.bounds, np.flatnonzero(untimed), side="right") - 1).tolist():
            a, b = int(tt.bounds[i]), int(tt.bounds[i + 1])
            arr[a:b], dep[a:b] = geo.fill_times(along[a:b], arr[a:b], dep[a:b])
    return TripGeometry(along, arr, dep, key, placed, shapes)


#: An elevation profile source: (geometry key, shape) -> (distance [m], elevation [m],
#: what it is) or None (flat). The edge samples the DSM; the core never opens it.
Elevation = Callable[[str, geo.Shape], "tuple[np.ndarray, np.ndarray, str] | None"]


@dataclass(frozen=True, eq=False)
class Scheduled:
    """Each trip on each date it runs (m instances): ``trip`` and ``date`` (index into the
    timetable's dates), ``energy`` [J or l: battery energy of an EV, fuel of an ICE], ``sd``
    the model's and the synthesis's combined, ``own_sd`` the synthesis's alone [J or l],
    ``vectors`` (the representative cycles), ``offset`` the synthesised mean less the
    representative cycle's energy [J or l], ``mass_kg``, ``ambient_c``, ``distance_m``,
    ``duration_s``, ``stops``, ``ascent_m``, ``cycle_from`` and ``elevation_from`` per
    instance; ``synthesised`` how many distinct cycles were synthesised; ``profiles`` the
    elevation profile of each geometry key (None: flat)."""

    trip: np.ndarray
    date: np.ndarray
    energy: np.ndarray
    sd: np.ndarray
    own_sd: np.ndarray
    vectors: tuple
    offset: np.ndarray
    mass_kg: np.ndarray
    ambient_c: np.ndarray
    distance_m: np.ndarray
    duration_s: np.ndarray
    stops: np.ndarray
    ascent_m: np.ndarray
    cycle_from: tuple[str, ...]
    elevation_from: tuple[str, ...]
    synthesised: int = 0
    profiles: dict = field(default_factory=dict)


def native(vehicle: Vehicle, energy_j) -> np.ndarray:
    """ScheduledEnergy's joules in the candidate's own unit: J of battery energy (EV), or
    litres of fuel (ICE: fuel energy over the fuel's lower heating value)."""
    x = np.asarray(energy_j, dtype=np.float64)
    if vehicle.is_ev:
        return x
    return x / float(vehicle.fuel_lhv_j_per_l or 1.0)


def instances(tt: Timetable) -> tuple[np.ndarray, np.ndarray]:
    """(trip, date index) of every trip on every date it runs, by date then trip."""
    d, t = np.nonzero(tt.runs.T)
    return t.astype(np.int64), d.astype(np.int64)


def schedule_energies(tt: Timetable, gm: TripGeometry, trip: np.ndarray, date: np.ndarray, ambient_c: np.ndarray,
                      vehicle: Vehicle, params, mass_kg: float, elevation: Elevation, *, draws: int = 8,
                      seed: int = 0, progress: Callable[[int], None] | None = None) -> Scheduled:
    """Each instance (``trip``, ``date``) at its ``ambient_c`` (module notes)."""
    from cevm.core.timetable.energy import scheduled_trip_energy

    profiles: dict[str, tuple[np.ndarray, np.ndarray, str] | None] = {}
    cache: dict[tuple, tuple] = {}
    m = trip.size
    out_e, out_sd, out_own, out_off = np.zeros(m), np.zeros(m), np.zeros(m), np.zeros(m)
    vecs: list = []
    dist, dur, stops, asc = np.zeros(m), np.zeros(m), np.zeros(m), np.zeros(m)
    cyc: list[str] = []
    elev_from: list[str] = []
    for k in range(m):  # trip instances; a synthesis per distinct pattern
        i = int(trip[k])
        key = gm.key[i]
        if key not in profiles:
            profiles[key] = elevation(key, gm.shapes[key])
        prof = profiles[key]
        d, arr, dep = gm.stops_of(tt, i)
        t0 = dep[0]
        pattern = (key, float(gm.along_m[tt.bounds[i]]), d.tobytes(), (arr - t0).tobytes(), (dep - t0).tobytes())
        hit = cache.get(pattern)
        if hit is None:
            pd = pz = None
            if prof is not None:
                start = float(gm.along_m[tt.bounds[i]])
                pd, pz = geo.profile_between(prof[0], prof[1], start, start + float(d[-1]))
            # a seed per pattern: the synthesis's draws of two trips independent, as the duty's
            # distribution takes them (one seed for all would correlate them fully)
            own_seed = (seed + zlib.crc32(b"".join(x if isinstance(x, bytes) else repr(x).encode()
                                                   for x in pattern))) & 0x7FFFFFFF
            se = scheduled_trip_energy(vehicle, d, arr - t0, dep - t0, profile_dist_m=pd, profile_elev_m=pz,
                                       mass_kg=mass_kg, ambient_c=float(ambient_c[k]), params=params, draws=draws,
                                       seed=own_seed)
            rep = float(trip_energies([se.vector], vehicle, mass_kg, float(ambient_c[k])).energy[0])
            hit = cache[pattern] = (se, float(ambient_c[k]), rep)
        se, t_syn, rep = hit
        e_syn = float(native(vehicle, se.energy_j))
        shift = 0.0
        if float(ambient_c[k]) != t_syn:
            now = float(trip_energies([se.vector], vehicle, mass_kg, float(ambient_c[k])).energy[0])
            shift = now - rep
        out_e[k] = e_syn + shift
        out_sd[k] = float(native(vehicle, se.sd_j))
        out_own[k] = float(native(vehicle, se.sd_synthesis_j))
        out_off[k] = e_syn - rep
        vecs.append(se.vector)
        dist[k], dur[k], stops[k], asc[k] = se.distance_m, se.duration_s, se.stops, se.ascent_m
        cyc.append(se.cycle_from)
        elev_from.append(prof[2] if prof is not None else "flat: no --dsm")
        if progress is not None:
            progress(1)
    return Scheduled(trip=trip, date=date, energy=out_e, sd=out_sd, own_sd=out_own, vectors=tuple(vecs),
                     offset=out_off, mass_kg=np.full(m, float(mass_kg)), ambient_c=np.asarray(ambient_c, float),
                     distance_m=dist, duration_s=dur, stops=stops, ascent_m=asc, cycle_from=tuple(cyc),
                     elevation_from=tuple(elev_from), synthesised=len(cache), profiles=profiles)
