"""A GTFS feed read for the dates asked: the trips that run, their stop times, the stops
and the shapes they use (:func:`read_feed`).

Only what the run needs is kept: trips.txt whole (a row per trip), then stop_times.txt
streamed batch by batch (:func:`cevm.io.gtfs.tables.batches`), each batch filtered to the
trips that run on the dates before its columns are converted to numbers (trip and stop as
int32 indices, times as float64 seconds, the distance as float64): ten million rows of a
city's feed pass through in bounded memory (benchmarks/bench_gtfs.py measures it).
shapes.txt the same way, filtered to the shapes the trips use.

``frequencies.txt``: a trip listed there is a template run at every headway from
start_time up to (not including) end_time; it is expanded into one trip per departure,
``TRIPID@HH:MM:SS``, its stop times shifted (GTFS: the template's first departure is the
origin of its offsets). An expanded trip keeps no block_id (its vehicles are not said):
its blocks are inferred.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import date
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from cevm.core.timetable.schedule import Timetable
from cevm.errors import CevmError, InputError
from cevm.io.gtfs.calendar import Calendar, busiest_weekday, read_calendar
from cevm.io.gtfs.tables import FeedSource, batches, read_table, require, texts, to_float, to_int, to_seconds


def _timezone(src: FeedSource) -> str:
    where = src.shown("agency.txt")
    _, t = read_table(src, "agency.txt", ["agency_timezone"], required=("agency_timezone",))
    require(t["agency_timezone"], where, "agency_timezone", 2)
    zones = list(dict.fromkeys(texts(t["agency_timezone"]).tolist()))
    if not zones:
        raise InputError(where, "no agency: the feed's time zone is unknown")
    from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

    try:
        ZoneInfo(zones[0])
    except (ZoneInfoNotFoundError, ValueError):
        raise InputError(where, f"{zones[0]!r} is not a time zone (an IANA name such as America/Detroit)", line=2,
                         column="agency_timezone") from None
    return zones[0]


@dataclass(frozen=True, eq=False)
class _Trips:
    trip_id: np.ndarray
    route_id: np.ndarray
    service_id: np.ndarray
    block_id: np.ndarray
    shape_id: np.ndarray


def _trips(src: FeedSource) -> _Trips:
    where = src.shown("trips.txt")
    _, t = read_table(src, "trips.txt", ["trip_id", "route_id", "service_id", "block_id", "shape_id"],
                      required=("trip_id", "route_id", "service_id"))
    for c in ("trip_id", "route_id", "service_id"):
        require(t[c], where, c, 2)
    ids = texts(t["trip_id"])
    uniq, first, counts = np.unique(ids, return_index=True, return_counts=True)
    if np.any(counts > 1):
        k = int(np.flatnonzero(counts > 1)[0])
        again = np.flatnonzero(ids == uniq[k])[1]
        raise InputError(where, f"trip_id {uniq[k]!r} appears twice (first on line {first[k] + 2})",
                         line=int(again) + 2, column="trip_id")
    n = ids.size
    blank = np.full(n, "", dtype=object)
    return _Trips(ids, texts(t["route_id"]), texts(t["service_id"]),
                  texts(t["block_id"]) if "block_id" in t else blank,
                  texts(t["shape_id"]) if "shape_id" in t else blank.copy())


def _dates_and_runs(cal: Calendar, trips: _Trips, dates: list[int] | None) -> tuple[list[int], str, np.ndarray]:
    if dates:
        how = "asked (--date)"
    else:
        svc, counts = np.unique(trips.service_id, return_counts=True)
        day, how = busiest_weekday(cal, dict(zip(svc.tolist(), counts.tolist(), strict=True)))
        dates = [day]
    runs = np.column_stack([np.isin(trips.service_id, list(cal.running(d))) for d in dates])
    return dates, how, runs


def _stops(src: FeedSource) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    where = src.shown("stops.txt")
    _, t = read_table(src, "stops.txt", ["stop_id", "stop_lat", "stop_lon"], required=("stop_id",))
    require(t["stop_id"], where, "stop_id", 2)
    ids = texts(t["stop_id"])
    lat = to_float(t["stop_lat"], where, "stop_lat", 2) if "stop_lat" in t else np.full(ids.size, np.nan)
    lon = to_float(t["stop_lon"], where, "stop_lon", 2) if "stop_lon" in t else np.full(ids.size, np.nan)
    for name, x, lim in (("stop_lat", lat, 90.0), ("stop_lon", lon, 180.0)):
        bad = np.flatnonzero(np.abs(x) > lim)
        if bad.size:
            raise InputError(where, f"{x[bad[0]]:g} is not a {name[5:]}itude in degrees", line=int(bad[0]) + 2,
                             column=name)
    return ids, lat, lon


@dataclass
class _StopTimes:
    trip: list[np.ndarray] = field(default_factory=list)
    seq: list[np.ndarray] = field(default_factory=list)
    stop: list[np.ndarray] = field(default_factory=list)
    arr: list[np.ndarray] = field(default_factory=list)
    dep: list[np.ndarray] = field(default_factory=list)
    dist: list[np.ndarray] = field(default_factory=list)
    line: list[np.ndarray] = field(default_factory=list)
    rows: int = 0


def _stop_times(src: FeedSource, trip_ids: np.ndarray, stop_ids: np.ndarray) -> tuple[dict[str, np.ndarray], int]:
    """The stop times of ``trip_ids`` (all others dropped batch by batch), sorted by trip
    (its index in ``trip_ids``) and stop_sequence."""
    name = "stop_times.txt"
    where = src.shown(name)
    want = pa.array(trip_ids.tolist(), pa.string())
    stops = pa.array(stop_ids.tolist(), pa.string())
    acc = _StopTimes()
    cols = ["trip_id", "arrival_time", "departure_time", "stop_id", "stop_sequence", "shape_dist_traveled"]
    for line, t in batches(src, name, cols, required=("trip_id", "stop_id", "stop_sequence")):
        n_rows = len(t["trip_id"])
        acc.rows += n_rows
        require(t["trip_id"], where, "trip_id", line)
        code = pc.index_in(t["trip_id"], value_set=want)
        keep = pc.is_valid(code)
        rows = np.flatnonzero(np.asarray(keep.to_numpy(zero_copy_only=False), dtype=bool))
        if not rows.size:
            continue
        idx = pa.array(rows)
        sub = {c: pc.take(a, idx) for c, a in t.items()}
        lines = (line + rows).astype(np.int32)

        def at(k: int, lines=lines) -> int:
            return int(lines[k])

        if sub["stop_id"].null_count:
            k = int(np.flatnonzero(~np.asarray(pc.is_valid(sub["stop_id"]), dtype=bool))[0])
            raise InputError(where, "empty: a value is required", line=at(k), column="stop_id")
        s = pc.index_in(sub["stop_id"], value_set=stops)
        if s.null_count:
            k = int(np.flatnonzero(~np.asarray(pc.is_valid(s), dtype=bool))[0])
            raise InputError(where, f"stop_id {sub['stop_id'][k].as_py()!r} is not in stops.txt", line=at(k),
                             column="stop_id")
        acc.trip.append(np.asarray(pc.take(code, idx).to_numpy(zero_copy_only=False), dtype=np.int32))
        acc.stop.append(np.asarray(s.to_numpy(zero_copy_only=False), dtype=np.int32))
        acc.seq.append(_located(lambda a, w, c, f: to_int(a, w, c, f, 0, 2 ** 31 - 1), sub, "stop_sequence",
                                where, lines).astype(np.int32))
        for key, c in (("arr", "arrival_time"), ("dep", "departure_time")):
            x = (_located(to_seconds, sub, c, where, lines) if c in sub else np.full(rows.size, np.nan))
            getattr(acc, key).append(x)
        acc.dist.append(_located(to_float, sub, "shape_dist_traveled", where, lines)
                        if "shape_dist_traveled" in sub else np.full(rows.size, np.nan))
        acc.line.append(lines)
    if not acc.trip:
        return {"trip": np.zeros(0, np.int32), "seq": np.zeros(0, np.int32), "stop": np.zeros(0, np.int32),
                "arr": np.zeros(0), "dep": np.zeros(0), "dist": np.zeros(0), "line": np.zeros(0, np.int32)}, acc.rows
    out = {k: np.concatenate(getattr(acc, k)) for k in ("trip", "seq", "stop", "arr", "dep", "dist", "line")}
    order = np.lexsort((out["seq"], out["trip"]))
    out = {k: v[order] for k, v in out.items()}
    same = (out["trip"][1:] == out["trip"][:-1]) & (out["seq"][1:] == out["seq"][:-1])
    if same.any():
        k = int(np.flatnonzero(same)[0]) + 1
        raise InputError(where, f"stop_sequence {out['seq'][k]} appears twice in trip "
                         f"{trip_ids[out['trip'][k]]!r} (also line {out['line'][k - 1]})", line=int(out["line"][k]),
                         column="stop_sequence")
    return out, acc.rows


def _located(conv, sub: dict, column: str, where: str, lines: np.ndarray) -> np.ndarray:
    """``conv`` on a filtered batch's column, a bad value's line taken from ``lines``."""
    try:
        return np.asarray(conv(sub[column], where, column, 0))
    except InputError as exc:
        raise InputError(where, exc.message, line=int(lines[exc.line or 0]), column=column) from None


def _check_times(where: str, st: dict[str, np.ndarray], bounds: np.ndarray, trip_ids: np.ndarray) -> None:
    """Every trip times its first and last stop; its times never go back."""
    arr, dep = st["arr"], st["dep"]
    arr_f = np.where(np.isnan(arr), dep, arr)
    dep_f = np.where(np.isnan(dep), arr, dep)
    st["arr"], st["dep"] = arr_f, dep_f
    n = bounds.size - 1
    if n == 0:
        return
    sizes = np.diff(bounds)
    if np.any(sizes < 2):
        i = int(np.flatnonzero(sizes < 2)[0])
        raise InputError(where, f"trip {trip_ids[i]!r} has {sizes[i]} stop time(s): a trip needs two stops at least",
                         line=int(st["line"][bounds[i]]) if sizes[i] else None)
    ends = np.concatenate([bounds[:-1], bounds[1:] - 1])
    untimed = np.isnan(arr_f[ends])
    if untimed.any():
        k = int(ends[np.flatnonzero(untimed)[0]])
        raise InputError(where, "a trip's first and last stops must be timed (arrival_time, departure_time)",
                         line=int(st["line"][k]), column="arrival_time")
    bad = dep_f < arr_f
    t = np.where(np.isnan(dep_f), arr_f, dep_f)
    # timed stops never go back in time along a trip
    trip_of = np.repeat(np.arange(n), sizes)
    ok = np.isfinite(t)
    tt, tr, rows = t[ok], trip_of[ok], np.flatnonzero(ok)
    back = (tr[1:] == tr[:-1]) & (arr_f[rows[1:]] < tt[:-1])
    if bad.any() or back.any():
        k = int(np.flatnonzero(bad)[0]) if bad.any() else int(rows[1:][np.flatnonzero(back)[0]])
        raise InputError(where, "a time goes back: a stop's departure before its arrival, or an arrival before the "
                         "stop before it departed", line=int(st["line"][k]), column="arrival_time")


def _frequencies(src: FeedSource, known: set[str], running: set[str]) -> tuple[dict[str, list[float]], str]:
    """The departures of each frequency-based trip that runs: template id -> start times
    [s]; and the sentence on frequencies.txt."""
    if not src.has("frequencies.txt"):
        return {}, ""
    name = "frequencies.txt"
    where = src.shown(name)
    n, t = read_table(src, name, ["trip_id", "start_time", "end_time", "headway_secs"],
                      required=("trip_id", "start_time", "end_time", "headway_secs"))
    if n == 0:
        return {}, "frequencies.txt: present, no entry"
    require(t["trip_id"], where, "trip_id", 2)
    ids = texts(t["trip_id"])
    start = to_seconds(t["start_time"], where, "start_time", 2)
    end = to_seconds(t["end_time"], where, "end_time", 2)
    head = to_int(t["headway_secs"], where, "headway_secs", 2, 1, 86400 * 2)
    for x, c in ((start, "start_time"), (end, "end_time")):
        if np.isnan(x).any():
            raise InputError(where, "empty: a value is required", line=int(np.flatnonzero(np.isnan(x))[0]) + 2,
                             column=c)
    out: dict[str, list[float]] = {}
    for k in range(n):
        if ids[k] not in known:
            raise InputError(where, f"trip_id {ids[k]!r} is not in trips.txt", line=k + 2, column="trip_id")
        if end[k] <= start[k]:
            raise InputError(where, "end_time must be after start_time", line=k + 2, column="end_time")
        if ids[k] in running:
            out.setdefault(ids[k], []).extend(np.arange(start[k], end[k], head[k]).tolist())
    count = sum(len(v) for v in out.values())
    return out, (f"frequencies.txt: {n} entr{'y' if n == 1 else 'ies'}; {len(out)} frequency-based trip(s) that run "
                 f"expanded into {count} departures (TRIPID@HH:MM:SS, blocks inferred)")


def _hms(s: float) -> str:
    s = int(round(s))
    return f"{s // 3600:02d}:{s % 3600 // 60:02d}:{s % 60:02d}"


def _expand(st: dict[str, np.ndarray], bounds: np.ndarray, trips: _Trips, runs: np.ndarray,
            freq: dict[str, list[float]]) -> tuple[_Trips, np.ndarray, dict[str, np.ndarray], np.ndarray]:
    """Frequency templates replaced by their departures (module notes)."""
    if not freq:
        return trips, runs, st, bounds
    index = {t: i for i, t in enumerate(trips.trip_id.tolist())}
    keep = np.ones(trips.trip_id.size, dtype=bool)
    pieces: list[tuple[int, float]] = []  # (template index, departure)
    for tid, deps in freq.items():
        i = index[tid]
        keep[i] = False
        pieces += [(i, d) for d in sorted(deps)]
    order_keep = np.flatnonzero(keep)
    src_rows = [np.arange(bounds[i], bounds[i + 1]) for i in order_keep]
    shift = [np.zeros(bounds[i + 1] - bounds[i]) for i in order_keep]
    for i, d in pieces:
        r = np.arange(bounds[i], bounds[i + 1])
        src_rows.append(r)
        shift.append(np.full(r.size, d - st["dep"][bounds[i]]))
    rows = np.concatenate(src_rows) if src_rows else np.zeros(0, np.int64)
    sh = np.concatenate(shift) if shift else np.zeros(0)
    new_st = {k: v[rows] for k, v in st.items()}
    new_st["arr"] = new_st["arr"] + sh
    new_st["dep"] = new_st["dep"] + sh
    expanded = np.zeros(rows.size, dtype=bool)
    expanded[sum(r.size for r in src_rows[:order_keep.size]):] = True
    new_st["line"] = np.where(expanded, 0, new_st["line"]).astype(np.int32)
    tix = np.concatenate([order_keep, np.array([i for i, _ in pieces], dtype=np.int64)])
    ids = np.concatenate([trips.trip_id[order_keep], np.array([f"{trips.trip_id[i]}@{_hms(d)}" for i, d in pieces],
                                                               dtype=object)])
    blocks = trips.block_id[tix].copy()
    blocks[order_keep.size:] = ""
    new = _Trips(ids, trips.route_id[tix], trips.service_id[tix], blocks, trips.shape_id[tix])
    sizes = np.diff(bounds)[tix]
    return new, runs[tix], new_st, np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)


def _shapes(src: FeedSource, wanted: set[str]) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    name = "shapes.txt"
    if not wanted or not src.has(name):
        return {}
    where = src.shown(name)
    want = pa.array(sorted(wanted), pa.string())
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("id", "seq", "lat", "lon", "dist")}
    for line, t in batches(src, name, ["shape_id", "shape_pt_lat", "shape_pt_lon", "shape_pt_sequence",
                                       "shape_dist_traveled"],
                           required=("shape_id", "shape_pt_lat", "shape_pt_lon", "shape_pt_sequence")):
        code = pc.index_in(t["shape_id"], value_set=want)
        rows = np.flatnonzero(np.asarray(pc.is_valid(code).to_numpy(zero_copy_only=False), dtype=bool))
        if not rows.size:
            continue
        idx = pa.array(rows)
        sub = {c: pc.take(a, idx) for c, a in t.items()}
        lines = line + rows
        parts["id"].append(np.asarray(pc.take(code, idx).to_numpy(zero_copy_only=False), dtype=np.int32))
        parts["seq"].append(_located(lambda a, w, c, f: to_int(a, w, c, f, 0, 2 ** 31 - 1), sub,
                                     "shape_pt_sequence", where, lines))
        for k, c in (("lat", "shape_pt_lat"), ("lon", "shape_pt_lon")):
            x = _located(to_float, sub, c, where, lines)
            if np.isnan(x).any() or np.any(np.abs(x) > (90 if k == "lat" else 180)):
                j = int(np.flatnonzero(np.isnan(x) | (np.abs(x) > (90 if k == "lat" else 180)))[0])
                raise InputError(where, f"not a {k}itude in degrees", line=int(lines[j]), column=c)
            parts[k].append(x)
        parts["dist"].append(_located(to_float, sub, "shape_dist_traveled", where, lines)
                             if "shape_dist_traveled" in sub else np.full(rows.size, np.nan))
    if not parts["id"]:
        return {}
    a = {k: np.concatenate(v) for k, v in parts.items()}
    order = np.lexsort((a["seq"], a["id"]))
    a = {k: v[order] for k, v in a.items()}
    cut = np.flatnonzero(np.diff(a["id"])) + 1
    names = want.to_pylist()
    out = {}
    for s, lat, lon, d in zip(np.split(a["id"], cut), np.split(a["lat"], cut), np.split(a["lon"], cut),
                              np.split(a["dist"], cut), strict=True):
        out[names[int(s[0])]] = (lat, lon, d)
    return out


def read_feed(path: str | Path, dates: list[int] | None = None) -> Timetable:
    """The feed at ``path`` (zip or folder) for the service dates ``dates`` (ordinals;
    None: :func:`~cevm.io.gtfs.calendar.busiest_weekday`): module notes."""
    src = FeedSource.open(path)
    for required in ("agency.txt", "stops.txt", "trips.txt", "stop_times.txt"):
        if not src.has(required):
            raise InputError(src.path, f"not a GTFS feed: it has no {required}")
    tz = _timezone(src)
    cal = read_calendar(src)
    trips = _trips(src)
    days, how, runs = _dates_and_runs(cal, trips, dates)
    notes: list[str] = []
    mask = runs.any(axis=1)
    if not mask.any():
        raise CevmError(f"{src.path}: no trip runs on {', '.join(str(date.fromordinal(d)) for d in days)} (the "
                        f"feed's services run from {date.fromordinal(cal.period()[0])} to "
                        f"{date.fromordinal(cal.period()[1])})")
    freq, fnote = _frequencies(src, set(trips.trip_id.tolist()), set(trips.trip_id[mask].tolist()))
    trips = _Trips(*(getattr(trips, f)[mask] for f in ("trip_id", "route_id", "service_id", "block_id", "shape_id")))
    runs = runs[mask]
    if fnote:
        notes.append(fnote)
    stop_ids, lat, lon = _stops(src)
    st, total_rows = _stop_times(src, trips.trip_id, stop_ids)
    counts = np.bincount(st["trip"], minlength=trips.trip_id.size)
    if np.any(counts == 0):
        missing = trips.trip_id[counts == 0]
        notes.append(f"{missing.size} trip(s) that run have no stop times, left out (e.g. {missing[0]})")
        keep = counts > 0
        remap = np.cumsum(keep) - 1
        st["trip"] = remap[st["trip"]].astype(np.int32)
        trips = _Trips(*(getattr(trips, f)[keep] for f in ("trip_id", "route_id", "service_id", "block_id",
                                                           "shape_id")))
        runs = runs[keep]
        counts = counts[keep]
    bounds = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    _check_times(src.shown("stop_times.txt"), st, bounds, trips.trip_id)
    trips, runs, st, bounds = _expand(st, bounds, trips, runs, freq)
    used_stops = np.unique(st["stop"])
    bad = used_stops[~(np.isfinite(lat[used_stops]) & np.isfinite(lon[used_stops]))]
    if bad.size:
        raise InputError(src.shown("stops.txt"), f"stop {stop_ids[bad[0]]!r} is served by a trip but has no position",
                         column="stop_lat")
    shapes = _shapes(src, set(trips.shape_id.tolist()) - {""})
    lost = sorted(set(trips.shape_id.tolist()) - {""} - set(shapes))
    if lost:
        notes.append(f"{len(lost)} shape(s) named by trips are not in shapes.txt (e.g. {lost[0]}): their trips run on "
                     "straight lines between stops")
        trips.shape_id[np.isin(trips.shape_id, lost)] = ""
    return Timetable(source=str(src.path), timezone=tz, dates=tuple(days), date_from=how, trip_id=trips.trip_id,
                route_id=trips.route_id, block_id=trips.block_id, shape_id=trips.shape_id, runs=runs, bounds=bounds,
                stop=st["stop"], arrival_s=st["arr"], departure_s=st["dep"], dist=st["dist"], line=st["line"],
                stop_id=stop_ids, stop_lat=lat, stop_lon=lon, shapes=shapes, stop_times_rows=total_rows,
                notes=tuple(notes))
