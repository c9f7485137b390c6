"""The per-file task of ``cevm ingest``: one logger file -> what to store of its trips.

:func:`process_file` (a pure-enough task: it reads the file and the DSM, and returns
everything to store; it never writes) runs the stages in the order the data flows
through them: read with a logger profile (:mod:`cevm.ingest.reading`), clean and split
into trips with measured consumption (:mod:`cevm.ingest.cleaning`,
:mod:`cevm.ingest.consumption`), road elevation from the DSM
(:mod:`cevm.ingest.elevation`), the trip's drive-cycle vector (:mod:`cevm.core.cycle`)
and its stored profile (:func:`cevm.store.encode_profiles`).

It is the one task of every ingest, serial, in a process pool or on a Dask cluster
(:mod:`cevm.executors`); a worker opens the DSM once (:func:`worker_sampler`), not once
per file. :func:`cevm.ingest.pipeline.ingest` dispatches it and writes the outcomes.
"""

from __future__ import annotations

import csv
import hashlib
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from cevm.core.cycle import CR0_DEFAULT, drive_cycle_vector
from cevm.core.trip import Trip, TripRecord
from cevm.errors import CevmError, InputError
from cevm.executors import worker_cache
from cevm.ingest.cleaning import CleanBatch, CleanParams, CleanStream
from cevm.ingest.dsm import DsmHeaders, DsmSampler
from cevm.ingest.elevation import ElevationParams, trip_elevation
from cevm.ingest.evidence import EvidenceParams, batch_evidence
from cevm.ingest.profiles import Profile
from cevm.ingest.reading import ReadLimits, read_log
from cevm.store import encode_profiles
from cevm.text import printable


@dataclass(frozen=True)
class IngestOptions:
    """What an ingest run does to each file (the per-file task's parameters)."""

    dsm: str | None = None  # GeoTIFF, directory of tiles, VRT, or GDAL/HTTP name
    allow_remote_dsm: bool | None = None  # network DSM names and VRT sources; None: $CEVM_ALLOW_REMOTE_DSM
    profile: str | None = None  # force a logger profile by name; None: detect
    profiles_dir: str | None = None  # extra profiles directory (besides configs/loggers)
    clean: CleanParams = field(default_factory=CleanParams)
    elevation: ElevationParams = field(default_factory=ElevationParams)
    evidence: EvidenceParams = field(default_factory=EvidenceParams)
    cr0: float = CR0_DEFAULT
    force: bool = False  # re-ingest files even when unchanged
    limits: ReadLimits = field(default_factory=ReadLimits)  # bounds on each file (size, gzip expansion, rows)


@dataclass(frozen=True, eq=False)
class FileOutcome:
    """What :func:`process_file` made of one file (picklable: crosses processes)."""

    path: str
    sha256: str | None
    size_bytes: int | None
    mtime_s: float | None
    profile: str | None = None
    trips: tuple[TripRecord, ...] = ()  # the arrays are in vectors and profile_blobs
    vectors: tuple[bytes, ...] = ()
    profile_blobs: tuple[bytes, ...] = ()  # each trip's stored profile (cevm.store.encode_profiles)
    n_rows: int = 0
    n_samples: int = 0
    dropped: tuple[dict, ...] = ()
    repairs: tuple[str, ...] = ()
    error: str | None = None
    stage_s: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.error is None


def file_sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


#: Samples of trips made at once (steps 6-9 of the cleaning, DSM lookups, elevation,
#: evidence, profiles): a large file's trips are done a bounded batch at a time, and
#: each batch is let go of once its trips are made.
TRIP_BATCH_SAMPLES = 1 << 16


def _finish_batch(batch: CleanBatch, log, path: Path, sha: str, sampler: DsmSampler | None,
                  options: IngestOptions, stage: dict, trips: list, vectors: list, blobs: list,
                  warnings: list) -> None:
    """Elevation, evidence, vector and stored profile of a batch of clean trips of
    ``log``, appended to ``trips``, ``vectors``, ``blobs`` and ``warnings``."""
    t0 = time.perf_counter()
    bounds = batch.bounds
    raw = sampler.sample(batch.lon_deg, batch.lat_deg) if sampler is not None else None
    elevations = []
    for i in range(len(batch)):
        a, b = int(bounds[i]), int(bounds[i + 1])
        alt = batch.gps_alt_m[a:b]
        elevations.append(trip_elevation(batch.distance_m[a:b], batch.lon_deg[a:b], batch.lat_deg[a:b],
                                         alt if np.isfinite(alt).any() else None, sampler, options.elevation,
                                         raw_dsm_m=None if raw is None else raw[a:b]))
    t1 = time.perf_counter()
    stage["elevation"] = stage.get("elevation", 0.0) + t1 - t0
    time_s = batch.time_s()
    start = batch.start_utc_s
    standstill = options.clean.standstill_mps
    evidence = batch_evidence(np.repeat(start, np.diff(bounds)) + time_s, batch.speed_mps, bounds, batch.row_t,
                              batch.rows, batch.row_window, standstill, options.evidence)
    stage["evidence"] = stage.get("evidence", 0.0) + time.perf_counter() - t1
    made = []
    for i, (elev, (fields, evidence_q)) in enumerate(zip(elevations, evidence, strict=True)):
        t1 = time.perf_counter()
        a, b = int(bounds[i]), int(bounds[i + 1])
        quality = dict(batch.quality[i])
        quality["elevation"] = elev.quality()
        quality["evidence"] = evidence_q
        quality["source_lines"] = list(batch.source_lines[i])
        if log.repairs:
            quality["read_repairs"] = list(log.repairs)
        trip = Trip(
            vehicle_id=log.vehicle_id, source_file=str(path), source_sha256=sha, trip_index=len(trips) + i,
            start_utc_s=float(start[i]), time_s=time_s[a:b], speed_mps=batch.speed_mps[a:b],
            distance_m=batch.distance_m[a:b], lat_deg=batch.lat_deg[a:b], lon_deg=batch.lon_deg[a:b],
            elevation_m=elev.elevation_m, elevation_source=elev.source, dsm_coverage_pct=elev.dsm_coverage_pct,
            measured=batch.measured[i], gross_weight_kg=batch.gross_weight_kg[i], quality=quality,
            start_soc_pct=batch.start_soc_pct[i], **fields,
        )
        t2 = time.perf_counter()
        vectors.append(drive_cycle_vector(trip.time_s, trip.speed_mps, trip.elevation_m, cr0=options.cr0).to_bytes())
        stage["elevation"] += t2 - t1
        stage["vector"] = stage.get("vector", 0.0) + time.perf_counter() - t2
        made.append(trip)
    t1 = time.perf_counter()
    blobs.extend(encode_profiles({"time_s": time_s, "speed_mps": batch.speed_mps, "distance_m": batch.distance_m,
                                  "elevation_m": np.concatenate([e.elevation_m for e in elevations]),
                                  "lat_deg": batch.lat_deg, "lon_deg": batch.lon_deg}, bounds))
    stage["profile"] = stage.get("profile", 0.0) + time.perf_counter() - t1
    for trip in made:
        trips.append(trip.record())
        warnings.extend(trip_warnings(trip))


def trip_warnings(trip: Trip) -> list[str]:
    """The warnings of a trip's quality (measured sources that disagree, DSM values
    refused), each naming the trip, for the file's repairs."""
    q = trip.quality
    found = [*q.get("consumption", {}).get("warnings", ()), *q.get("elevation", {}).get("elevation_warnings", ())]
    if q.get("speed_jumps"):
        found.append(speed_jump_warning(q["speed_jumps"], int(q.get("speed_unresolved_jumps", 0))))
    return [f"trip {trip.trip_id}: {w}" for w in found]


def speed_jump_warning(jumps: list[dict], n: int) -> str:
    """The repair note of a trip's lasting speed jumps (its quality's ``speed_jumps``, the
    largest first; ``n`` of them in all)."""
    from cevm.text import iso_time

    j = jumps[0]
    when = iso_time(j["utc_s"])
    return (f"speed: {max(n, len(jumps))} lasting speed jump(s) the cleaning could not repair, the largest "
            f"{3.6 * (j['to_mps'] - j['from_mps']):+.0f} km/h in {j['dt_s']:g} s at {when} in "
            f"{j['source']} (a spliced recording?); kept as logged, and listed in the trip's quality "
            "('speed_jumps') for calibrate to flag or down-weight the trip")


def stop_note_warnings(notes) -> list[str]:
    """The repair notes of the cleaning's charging stops and of the holes the vehicle
    drove through (the file quality's ``stop_notes``): one line for each kind."""
    import datetime as dt

    def when(t_s: float) -> str:
        return dt.datetime.fromtimestamp(t_s, dt.UTC).strftime("%Y-%m-%d %H:%M:%S")

    out = []
    charging = [n for n in notes if n["kind"] == "charging"]
    if charging:
        n = charging[0]
        what = (f"{n['kwh']:.1f} kWh taken in" if n.get("kwh") is not None
                else f"state of charge up {n['soc_rise_pct']:.1f} points")
        out.append(f"charging: {len(charging)} stop(s) where the battery charged, the first from {when(n['t0_s'])} "
                   f"to {when(n['t1_s'])} UTC ({what}): each ends its trip, so that a trip's measured energy is "
                   "what its driving used, not that net of a charge")
    moved = [n for n in notes if n["kind"] == "moved_hole"]
    if moved:
        n = max(moved, key=lambda m: m["displacement_m"])
        out.append(f"speed: {len(moved)} hole(s) in the log between two standstill readings over which the GPS "
                   f"position moved, the largest {n['displacement_m']:,.0f} m in {n['t1_s'] - n['t0_s']:,.0f} s from "
                   f"{when(n['t0_s'])} UTC: not a stop but driving the log did not record; the trip is split there")
    for n in (n for n in notes if n["kind"] == "max_duration"):
        hours = n["max_trip_s"] / 3600
        out.append(f"trips: {n['splits']} cut(s) of trips longer than {hours:g} h without a long stop, the first at "
                   f"{when(n['t0_s'])} UTC: each such trip is cut into pieces of at most {hours:g} h (a day's "
                   "driving without a stop is a log whose stops were not seen; and a worker holds a trip whole)")
    return out


def process_file(
    path: str | Path,
    options: IngestOptions,
    profiles: dict[str, Profile] | None = None,
    sampler: DsmSampler | None = None,
    sha256: str | None = None,
    dsm_headers: DsmHeaders | None = None,
) -> FileOutcome:
    """Read, clean, add elevation and compute vectors for one file; never raises for
    bad input: the outcome carries the error (file, line, column, why).

    The one task of every ingest, serial, in a process pool or on a Dask cluster.
    ``profiles``: the logger profiles (None: :func:`~cevm.ingest.profiles.load_profiles`).
    ``sampler``: an open sampler of ``options.dsm``; None with ``options.dsm`` set: this
    worker's own, opened on first use and kept (:func:`worker_sampler`).
    ``sha256`` is the file's hash if the caller has it already; ``dsm_headers`` the
    DSM's headers if the caller read them (:func:`worker_sampler`)."""
    path = Path(path)
    stage: dict[str, float] = {}
    try:
        st = path.stat()
        size, mtime = st.st_size, st.st_mtime
        sha = sha256 or file_sha256(path)
    except OSError as exc:
        return FileOutcome(str(path), None, None, None, error=printable(f"{path}: cannot read: {exc.strerror}"))
    try:
        if sampler is None and options.dsm is not None:
            sampler = worker_sampler(options.dsm, dsm_headers, options.allow_remote_dsm)
        t0 = time.perf_counter()
        logs = read_log(path, options.profile, profiles, limits=options.limits)
        stage["read"] = time.perf_counter() - t0
        trips: list[TripRecord] = []
        vectors: list[bytes] = []
        blobs: list[bytes] = []
        dropped: list[dict] = []
        warnings: list[str] = []
        n_rows = planned = 0
        for log in logs:
            n_rows += len(log)
            t0 = time.perf_counter()
            stream = CleanStream(log.columns, log.energy_sources, options.clean, path=path, release_frame=True)
            planned += stream.planned_samples
            _check_samples(path, planned, options.limits.max_samples)
            batches = stream.batches(TRIP_BATCH_SAMPLES)
            while True:  # trips a bounded batch at a time: a large file's trips are never all held
                batch = next(batches, None)
                stage["clean"] = stage.get("clean", 0.0) + time.perf_counter() - t0
                if batch is None:
                    break
                _finish_batch(batch, log, path, sha, sampler, options, stage, trips, vectors, blobs, warnings)
                del batch
                t0 = time.perf_counter()
            dropped.extend({"vehicle_id": log.vehicle_id, **d} for d in stream.dropped)
            warnings.extend(stop_note_warnings(stream.quality.get("stop_notes", ())))
        return FileOutcome(
            str(path), sha, size, mtime,
            profile=logs[0].profile if logs else None,
            trips=tuple(trips), vectors=tuple(vectors), profile_blobs=tuple(blobs), n_rows=n_rows,
            n_samples=sum(t.n_samples for t in trips),
            dropped=tuple(dropped), repairs=(*(logs[0].repairs if logs else ()), *warnings),
            stage_s=stage,
        )
    except CevmError as exc:
        return FileOutcome(str(path), sha, size, mtime, error=str(exc), stage_s=stage)
    except (ValueError, OSError, csv.Error, UnicodeError) as exc:  # a file we could not make sense of
        return FileOutcome(str(path), sha, size, mtime, error=printable(f"{path}: {type(exc).__name__}: {exc}"),
                           stage_s=stage)
    except Exception as exc:  # a bug in cevm: still only this file fails, and it says so
        where = traceback.extract_tb(exc.__traceback__)[-1]
        return FileOutcome(
            str(path), sha, size, mtime, stage_s=stage,
            error=printable(f"{path}: internal error (a cevm bug, please report): {type(exc).__name__}: {exc} "
                                 f"at {Path(where.filename).name}:{where.lineno}"),
        )


def _check_samples(path: Path, planned: int, limit: int | None) -> None:
    """Refuse a file whose trips would hold more than ``limit`` samples (known once its
    trips are cut, before any is made)."""
    if limit is not None and planned > limit:
        raise InputError(path, f"its trips would hold {planned:,} samples on the 1 s grid: more than the {limit:,} a "
                               "file may give (--max-samples), which keeps a worker's memory bounded (the stored trips "
                               "are held until written); split the file (by day or by vehicle)")


def open_sampler(dsm: str | None, allow_remote: bool | None = None) -> DsmSampler | None:
    """Open the DSM, or None. A DSM that cannot be opened is the user's error, and so
    is a remote one without ``allow_remote`` (None: ``$CEVM_ALLOW_REMOTE_DSM``)."""
    if dsm is None:
        return None
    try:
        return DsmSampler.open(dsm, allow_remote=allow_remote)
    except CevmError:
        raise
    except Exception as exc:  # rasterio errors have many types
        raise InputError(dsm, f"cannot open the DSM: {exc}") from None


def worker_sampler(dsm: str, headers: DsmHeaders | None = None, allow_remote: bool | None = None) -> DsmSampler:
    """This worker's (process and thread) sampler of ``dsm``, opened on first use and
    kept for the next files (:func:`cevm.executors.worker_cache`). ``headers``: the
    rasters' headers as the writer read them (:attr:`DsmSampler.headers`), so that a
    new worker does not read every tile's header again (~1.5 ms a tile); rasters
    are then opened when a window of them is needed. A long-lived worker given other
    headers (a DSM changed between runs) opens a new sampler. The headers carry the
    drivers the writer vetted the rasters for (:mod:`cevm.ingest.dsm_sources`)."""
    if headers is None:
        return worker_cache(("cevm.ingest.DsmSampler", dsm, allow_remote), lambda: open_sampler(dsm, allow_remote))
    return worker_cache(("cevm.ingest.DsmSampler", dsm, headers), lambda: DsmSampler.from_headers(headers))

