"""A GTFS feed read for the dates asked: the trips that run, their stop times, the stops
and the shapes they use (:func:`read_feed`).

Only what the run needs is kept: trips.txt whole (a row per trip), then stop_times.txt
streamed batch by batch (:func:`cevm.io.gtfs.tables.batches`), each batch filtered to the
trips that run on the dates before its columns are converted to numbers (trip and stop as
int32 indices, times and the distance as float32): ten million rows of a
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


_TRIP_COLUMNS = ("trip_id", "route_id", "service_id", "block_id", "shape_id")


def _trips(src: FeedSource) -> dict[str, pa.Array]:
    """trips.txt's columns as text (arrow: a city's hundreds of thousands of trips stay
    compact until those that run are chosen), trip ids checked unique."""
    where = src.shown("trips.txt")
    n, t = read_table(src, "trips.txt", list(_TRIP_COLUMNS), required=("trip_id", "route_id", "service_id"))
    for c in ("trip_id", "route_id", "service_id"):
        require(t[c], where, c, 2)
    ids = pc.ascii_trim_whitespace(t["trip_id"])
    if pc.count_distinct(ids).as_py() != n:
        counts = pc.value_counts(ids)
        dup = pc.filter(counts.field("values"), pc.greater(counts.field("counts"), 1))[0]
        rows = np.flatnonzero(np.asarray(pc.equal(ids, dup).to_numpy(zero_copy_only=False), dtype=bool))
        raise InputError(where, f"trip_id {dup.as_py()!r} appears twice (first on line {rows[0] + 2})",
                         line=int(rows[1]) + 2, column="trip_id")
    out = {c: pc.ascii_trim_whitespace(t[c]) if c in t else pa.nulls(n, pa.string()) for c in _TRIP_COLUMNS}
    out["trip_id"] = ids
    return out


def _dates_and_runs(cal: Calendar, trips: dict[str, pa.Array], dates: list[int] | None
                    ) -> tuple[list[int], str, np.ndarray]:
    if dates:
        how = "asked (--date)"
    else:
        counts = pc.value_counts(trips["service_id"])
        per = dict(zip(counts.field("values").to_pylist(), counts.field("counts").to_pylist(), strict=True))
        day, how = busiest_weekday(cal, per)
        dates = [day]
    svc = trips["service_id"]
    runs = np.column_stack([np.asarray(pc.is_in(svc, value_set=pa.array(sorted(cal.running(d)), pa.string()))
                                       .to_numpy(zero_copy_only=False), dtype=bool) for d in dates])
    return dates, how, runs


def _running(trips: dict[str, pa.Array], rows: np.ndarray) -> _Trips:
    """The trips of ``rows`` as numpy text arrays."""
    sel = pa.array(rows)
    return _Trips(*(texts(pc.take(trips[c], sel)) for c in _TRIP_COLUMNS))


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


#: Kept rows joined into one array at a time while stop_times.txt is read.
CONSOLIDATE_ROWS = 1 << 20

_ST_KEYS = ("trip", "seq", "stop", "arr", "dep", "dist", "line")
_ST_TYPES = {"trip": np.int32, "seq": np.int32, "stop": np.int32, "arr": np.float32, "dep": np.float32,
             "dist": np.float32, "line": np.int32}


@dataclass
class _StopTimes:
    """The kept rows of stop_times.txt, batch by batch, in compact types: trip and stop
    (int32 indices), stop_sequence and line (int32), times and distance (float32: whole
    seconds are exact below 2^24 s, 194 days; a distance to 6e-8 of itself)."""

    parts: dict[str, list[np.ndarray]] = field(default_factory=lambda: {key: [] for key in _ST_KEYS})
    rows: int = 0
    loose: int = 0

    def add(self, **cols: np.ndarray) -> None:
        """A batch's kept rows; every :data:`CONSOLIDATE_ROWS` rows the small pieces are
        joined into one array (its own mapping: freed whole, never a hole in the heap)."""
        for k, v in cols.items():
            self.parts[k].append(v)
        self.loose += len(cols["trip"])
        if self.loose >= CONSOLIDATE_ROWS:
            for parts in self.parts.values():
                first = next(i for i, p in enumerate(parts) if p.size < CONSOLIDATE_ROWS) if parts else 0
                parts[first:] = [np.concatenate(parts[first:])]
            self.loose = 0
            _release()

    def take(self, key: str) -> np.ndarray:
        """One column concatenated, its batches freed."""
        parts = self.parts.pop(key)
        out = np.concatenate(parts) if parts else np.zeros(0, _ST_TYPES[key])
        parts.clear()
        return out


def _same_text(a: pa.Array, b: pa.Array) -> bool:
    """Whether two text columns hold the same values, empty in the same rows."""
    if a.null_count != b.null_count:
        return False
    if a.null_count and not pc.all(pc.equal(pc.is_null(a), pc.is_null(b))).as_py():
        return False
    return bool(pc.all(pc.equal(a, b)).as_py() is not False)


def _trip_codes(col: pa.Array, want: dict[str, int]) -> np.ndarray:
    """Each row's id (a trip's, a stop's) as its index in ``want`` (-1: not there): the
    batch's distinct ids (a trip's rows lie together) looked up once each in a dict built
    once for the file, not a hash of every wanted id built again for every batch."""
    d = pc.dictionary_encode(pc.ascii_trim_whitespace(col))
    codes = np.array([want.get(v, -1) for v in d.dictionary.to_pylist()], dtype=np.int32)
    return codes[np.asarray(d.indices.to_numpy(zero_copy_only=False), dtype=np.int64)]


def _batch_rows(t: dict, where: str, line: int, want: dict[str, int], stops: dict[str, int]
                ) -> dict[str, np.ndarray] | None:
    """One batch of stop_times.txt: the rows of the trips in ``want``, converted (None:
    none kept)."""
    require(t["trip_id"], where, "trip_id", line)
    code = _trip_codes(t["trip_id"], want)
    rows = np.flatnonzero(code >= 0)
    if not rows.size:
        return None
    idx = pa.array(rows)
    sub = {c: pc.ascii_trim_whitespace(pc.take(a, idx)) for c, a in t.items() if c != "trip_id"}
    lines = (line + rows).astype(np.int32)
    if sub["stop_id"].null_count:
        k = int(np.flatnonzero(~np.asarray(pc.is_valid(sub["stop_id"]), dtype=bool))[0])
        raise InputError(where, "empty: a value is required", line=int(lines[k]), column="stop_id")
    s = _trip_codes(sub["stop_id"], stops)
    if np.any(s < 0):
        k = int(np.flatnonzero(s < 0)[0])
        raise InputError(where, f"stop_id {sub['stop_id'][k].as_py()!r} is not in stops.txt", line=int(lines[k]),
                         column="stop_id")
    out = {"trip": code[rows],
           "stop": s,
           "seq": _located(lambda a, w, c, f: to_int(a, w, c, f, 0, 2 ** 31 - 1), sub, "stop_sequence", where,
                           lines).astype(np.int32),
           "line": lines}
    for key, c in (("arr", "arrival_time"), ("dep", "departure_time")):
        if key == "dep" and "arrival_time" in sub and c in sub and _same_text(sub[c], sub["arrival_time"]):
            out[key] = out["arr"].copy()  # the usual timetable: the same time twice, parsed once
            continue
        out[key] = (_located(to_seconds, sub, c, where, lines) if c in sub else np.full(rows.size, np.nan)
                    ).astype(np.float32)
    out["dist"] = (_located(to_float, sub, "shape_dist_traveled", where, lines) if "shape_dist_traveled" in sub
                   else np.full(rows.size, np.nan)).astype(np.float32)
    return out


def _stop_times(src: FeedSource, trip_ids: np.ndarray, stop_ids: np.ndarray) -> tuple[dict[str, np.ndarray], int]:
    """The stop times of ``trip_ids`` (all others dropped batch by batch), sorted by trip
    (its index in ``trip_ids``) and stop_sequence; one column at a time, so that the peak
    holds the kept rows once and a sort key (``benchmarks/bench_gtfs.py``)."""
    name = "stop_times.txt"
    where = src.shown(name)
    want = {str(t): i for i, t in enumerate(trip_ids.tolist())}
    stops = {str(t): i for i, t in enumerate(stop_ids.tolist())}
    acc = _StopTimes()
    cols = ["trip_id", "arrival_time", "departure_time", "stop_id", "stop_sequence", "shape_dist_traveled"]
    for line, t in batches(src, name, cols, required=("trip_id", "stop_id", "stop_sequence")):
        acc.rows += len(t["trip_id"])
        got = _batch_rows(t, where, line, want, stops)
        if got is not None:
            acc.add(**got)
    _release()  # the batches' temporaries, scattered between the kept pieces
    trip, seq = acc.take("trip"), acc.take("seq")
    order = _row_order(trip, seq)
    out: dict[str, np.ndarray] = {}
    for name in ("trip", "seq", *(c for c in _ST_KEYS if c not in ("trip", "seq"))):
        col = trip if name == "trip" else seq if name == "seq" else acc.take(name)
        out[name] = col if order is None else col[order]
        del col
        _release()  # its pieces
    del trip, seq, order
    tr, sq = out["trip"], out["seq"]
    same = np.flatnonzero((tr[1:] == tr[:-1]) & (sq[1:] == sq[:-1]))
    if same.size:
        k = int(same[0]) + 1
        raise InputError(where, f"stop_sequence {sq[k]} appears twice in trip {trip_ids[tr[k]]!r} (also line "
                         f"{out['line'][k - 1]})", line=int(out["line"][k]), column="stop_sequence")
    return out, acc.rows


def _release() -> None:
    """Return the memory freed by the reader to the system: arrow's pool and glibc's heap
    keep what was freed, and a feed read in blocks frees thousands of pieces between the
    rows it keeps (on ten million rows the kept half's pieces alone would be held twice,
    :func:`cevm.runtime.release_free_memory`)."""
    from cevm.runtime import release_free_memory

    pa.default_memory_pool().release_unused()
    release_free_memory()


def _row_order(trip: np.ndarray, seq: np.ndarray) -> np.ndarray | None:
    """The rows' order grouped by trip, by stop_sequence within a trip: None when the file
    has them so already (each trip's rows together, in sequence: the usual layout, and
    then nothing is sorted nor copied), else a stable sort by (trip, sequence)."""
    n = trip.size
    if n < 2:
        return None
    change = trip[1:] != trip[:-1]
    heads = trip[np.concatenate([[0], np.flatnonzero(change) + 1])]
    if np.unique(heads).size == heads.size and np.all(change | (seq[1:] > seq[:-1])):
        return None
    key = (trip.astype(np.int64) << 32) | seq.astype(np.int64)
    return np.argsort(key, kind="stable")


def _located(conv, sub: dict, column: str, where: str, lines: np.ndarray) -> np.ndarray:
    """``conv`` on a filtered batch's column, a bad value's line taken from ``lines``."""
    try:
        return np.asarray(conv(sub[column], where, column, 0))
    except InputError as exc:
        raise InputError(where, exc.message, line=int(lines[exc.line or 0]), column=column) from None


#: Rows checked together by :func:`_check_times` (bounds its temporaries).
CHECK_CHUNK_ROWS = 1 << 20


def _check_times(where: str, st: dict[str, np.ndarray], bounds: np.ndarray, trip_ids: np.ndarray) -> None:
    """A stop with only one of its times gets it for both (in place); every trip times its
    first and last stop; its times never go back. Trips a chunk of rows at a time."""
    arr, dep = st["arr"], st["dep"]
    np.copyto(arr, dep, where=np.isnan(arr))
    np.copyto(dep, arr, where=np.isnan(dep))
    n = bounds.size - 1
    if n == 0:
        return
    sizes = np.diff(bounds)
    if np.any(sizes < 2):
        i = int(np.flatnonzero(sizes < 2)[0])
        raise InputError(where, f"trip {trip_ids[i]!r} has {sizes[i]} stop time(s): a trip needs two stops at least",
                         line=int(st["line"][bounds[i]]) if sizes[i] else None)
    ends = np.concatenate([bounds[:-1], bounds[1:] - 1])
    untimed = np.isnan(arr[ends])
    if untimed.any():
        k = int(ends[np.flatnonzero(untimed)[0]])
        raise InputError(where, "a trip's first and last stops must be timed (arrival_time, departure_time)",
                         line=int(st["line"][k]), column="arrival_time")
    i0 = 0
    while i0 < n:
        i1 = max(int(np.searchsorted(bounds, bounds[i0] + CHECK_CHUNK_ROWS, side="right")) - 1, i0 + 1)
        i1 = min(i1, n)
        a, b = int(bounds[i0]), int(bounds[i1])
        k = _time_goes_back(arr[a:b], dep[a:b], sizes[i0:i1])
        if k >= 0:
            raise InputError(where, "a time goes back: a stop's departure before its arrival, or an arrival before "
                             "the stop before it departed", line=int(st["line"][a + k]), column="arrival_time")
        i0 = i1


def _time_goes_back(arr: np.ndarray, dep: np.ndarray, sizes: np.ndarray) -> int:
    """The first row (of whole trips' rows) whose departure is before its arrival, or
    whose arrival is before the last timed stop's departure in its trip; -1: none."""
    bad = dep < arr
    timed = np.flatnonzero(np.isfinite(arr))
    trip_of = np.repeat(np.arange(sizes.size, dtype=np.int32), sizes)[timed]
    back = (trip_of[1:] == trip_of[:-1]) & (arr[timed[1:]] < dep[timed[:-1]])
    rows = [int(np.flatnonzero(bad)[0])] if bad.any() else []
    if back.any():
        rows.append(int(timed[1:][np.flatnonzero(back)[0]]))
    return min(rows) if rows else -1


def _frequencies(src: FeedSource, known: pa.Array, running: set[str]) -> tuple[dict[str, list[float]], str]:
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
    unknown = ~np.asarray(pc.is_in(pa.array(ids, pa.string()), value_set=known).to_numpy(zero_copy_only=False),
                          dtype=bool)
    out: dict[str, list[float]] = {}
    for k in range(n):
        if unknown[k]:
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
    tcols = _trips(src)
    days, how, runs = _dates_and_runs(cal, tcols, dates)
    notes: list[str] = []
    mask = runs.any(axis=1)
    if not mask.any():
        raise CevmError(f"{src.path}: no trip runs on {', '.join(str(date.fromordinal(d)) for d in days)} (the "
                        f"feed's services run from {date.fromordinal(cal.period()[0])} to "
                        f"{date.fromordinal(cal.period()[1])})")
    all_ids = tcols["trip_id"]
    trips = _running(tcols, np.flatnonzero(mask))
    del tcols
    _release()  # trips.txt read whole
    freq, fnote = _frequencies(src, all_ids, set(trips.trip_id.tolist()))
    del all_ids
    runs = runs[mask]
    if fnote:
        notes.append(fnote)
    stop_ids, lat, lon = _stops(src)
    st, total_rows = _stop_times(src, trips.trip_id, stop_ids)
    # the trips in the order of their rows (the file's, when it groups them): no row moves
    change = np.flatnonzero(st["trip"][1:] != st["trip"][:-1]) + 1
    heads = st["trip"][np.concatenate([[0], change])] if st["trip"].size else np.zeros(0, np.int32)
    counts = np.diff(np.concatenate([[0], change, [st["trip"].size]])) if st["trip"].size else np.zeros(0, np.int64)
    if heads.size < trips.trip_id.size:
        missing = np.setdiff1d(np.arange(trips.trip_id.size), heads)
        notes.append(f"{missing.size} trip(s) that run have no stop times, left out (e.g. {trips.trip_id[missing[0]]})")
    trips = _Trips(*(getattr(trips, f)[heads] for f in ("trip_id", "route_id", "service_id", "block_id", "shape_id")))
    runs = runs[heads]
    del st["trip"], st["seq"]
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
