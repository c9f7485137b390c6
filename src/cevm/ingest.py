"""The ingest pipeline: logger files -> clean trips with elevation -> the store.

Stages, per file (:func:`process_file`, a pure-enough task: it reads the file and the
DSM, and returns everything to store; it never writes): read with a logger profile
(:mod:`cevm.loggers`), clean and split into trips with measured consumption
(:mod:`cevm.clean`, :mod:`cevm.consumption`), road elevation from the DSM
(:mod:`cevm.elevation`), and the trip's drive-cycle vector (:mod:`cevm.core.cycle`).

:func:`ingest` runs the task over many files and is the store's single writer: one
transaction per file, so a crash mid-file leaves the store as it was, an unchanged file
is skipped, a changed file replaces its trips, and a bad file is reported and skipped
while the batch goes on (its previously stored trips are kept).

Parallel runs (:mod:`cevm.executors`): the same :func:`process_file` runs in worker
processes or on a Dask cluster; the outcomes come back to :func:`ingest`, which writes
them in input order, so the store ends up exactly as after a serial run. A worker opens
the DSM once (:func:`worker_sampler`), not once per file.
"""

from __future__ import annotations

import csv
import glob
import hashlib
import time
import traceback
from collections.abc import Callable, Iterable
from contextlib import closing
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from cevm.clean import CleanParams, CleanTrip, clean_log
from cevm.core.cycle import CR0_DEFAULT, drive_cycle_vector
from cevm.elevation import DsmHeaders, DsmSampler, ElevationParams, trip_elevation
from cevm.errors import CevmError, InputError
from cevm.loggers import Profile, load_profiles, read_log
from cevm.executors import Executor, SerialExecutor, Task, TaskResult, worker_cache
from cevm.store import TripStore, trip_profile_blob
from cevm.core.trip import Trip, TripRecord

#: File names taken from a directory (recursively).
LOG_PATTERNS = ("*.csv", "*.csv.gz", "*.CSV", "*.CSV.GZ")


@dataclass(frozen=True)
class IngestOptions:
    """What an ingest run does to each file (the per-file task's parameters)."""

    dsm: str | None = None  # GeoTIFF, directory of tiles, VRT, or GDAL/HTTP name
    profile: str | None = None  # force a logger profile by name; None: detect
    profiles_dir: str | None = None  # extra profiles directory (besides configs/loggers)
    clean: CleanParams = field(default_factory=CleanParams)
    elevation: ElevationParams = field(default_factory=ElevationParams)
    cr0: float = CR0_DEFAULT
    force: bool = False  # re-ingest files even when unchanged


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
    profile_blobs: tuple[bytes, ...] = ()  # each trip's stored profile (trip_profile_blob)
    n_rows: int = 0
    n_samples: int = 0
    dropped: tuple[dict, ...] = ()
    repairs: tuple[str, ...] = ()
    error: str | None = None
    stage_s: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.error is None


@dataclass
class FileReport:
    """One line of the run's report."""

    path: str
    status: str  # "ingested", "unchanged", "failed"
    trips: int = 0
    samples: int = 0
    km: float = 0.0
    seconds: float = 0.0
    profile: str | None = None
    error: str | None = None
    duplicates: int = 0
    repairs: tuple[str, ...] = ()


@dataclass
class IngestReport:
    files: list[FileReport] = field(default_factory=list)
    seconds: float = 0.0
    stage_s: dict = field(default_factory=dict)
    rows: int = 0

    def count(self, status: str) -> int:
        return sum(1 for f in self.files if f.status == status)

    @property
    def failed(self) -> int:
        return self.count("failed")

    def summary(self) -> dict:
        return {
            "files": len(self.files),
            "ingested": self.count("ingested"),
            "unchanged": self.count("unchanged"),
            "failed": self.failed,
            "trips": sum(f.trips for f in self.files),
            "samples": sum(f.samples for f in self.files),
            "rows": self.rows,
            "km": round(sum(f.km for f in self.files), 3),
            "seconds": round(self.seconds, 3),
            "stage_s": {k: round(v, 3) for k, v in self.stage_s.items()},
        }


def discover(inputs: Iterable[str | Path]) -> tuple[list[Path], list[str]]:
    """Expand files, directories (recursive) and glob patterns into a sorted, unique
    list of files; return it with a message for each input that matched nothing."""
    found: dict[str, Path] = {}
    missing: list[str] = []
    for item in inputs:
        s = str(item)
        p = Path(s)
        if p.is_dir():
            hits = [q for pat in LOG_PATTERNS for q in p.rglob(pat) if q.is_file()]
        elif p.is_file():
            hits = [p]
        elif glob.has_magic(s):
            hits = [Path(q) for q in glob.glob(s, recursive=True) if Path(q).is_file()]
        else:
            hits = []
        if not hits:
            missing.append(f"{s}: no such file, directory or matching log files")
        for q in hits:
            found.setdefault(str(q.resolve()), q)
    return [found[k] for k in sorted(found)], missing


def file_sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _trip_from_clean(ct: CleanTrip, *, vehicle_id: str, path: Path, sha256: str, index: int,
                     sampler: DsmSampler | None, params: ElevationParams, repairs: list[str]) -> Trip:
    gps_alt = ct.gps_alt_m if np.isfinite(ct.gps_alt_m).any() else None
    elev = trip_elevation(ct.distance_m, ct.lon_deg, ct.lat_deg, gps_alt, sampler, params)
    quality = dict(ct.quality)
    quality["elevation"] = elev.quality()
    quality["source_lines"] = [ct.first_source_line, ct.last_source_line]
    if repairs:
        quality["read_repairs"] = list(repairs)
    return Trip(
        vehicle_id=vehicle_id,
        source_file=str(path),
        source_sha256=sha256,
        trip_index=index,
        start_utc_s=ct.start_utc_s,
        time_s=ct.time_s,
        speed_mps=ct.speed_mps,
        distance_m=ct.distance_m,
        lat_deg=ct.lat_deg,
        lon_deg=ct.lon_deg,
        elevation_m=elev.elevation_m,
        elevation_source=elev.source,
        dsm_coverage_pct=elev.dsm_coverage_pct,
        measured=ct.measured,
        gross_weight_kg=ct.gross_weight_kg,
        quality=quality,
    )


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
    ``profiles``: the logger profiles (None: :func:`~cevm.loggers.load_profiles`).
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
        return FileOutcome(str(path), None, None, None, error=f"{path}: cannot read: {exc.strerror}")
    try:
        if sampler is None and options.dsm is not None:
            sampler = worker_sampler(options.dsm, dsm_headers)
        t0 = time.perf_counter()
        logs = read_log(path, options.profile, profiles)
        stage["read"] = time.perf_counter() - t0
        trips: list[TripRecord] = []
        vectors: list[bytes] = []
        blobs: list[bytes] = []
        dropped: list[dict] = []
        n_rows = 0
        for log in logs:
            n_rows += len(log.frame)
            t0 = time.perf_counter()
            result = clean_log(log.frame, log.energy_sources, options.clean, path=path)
            stage["clean"] = stage.get("clean", 0.0) + time.perf_counter() - t0
            dropped.extend({"vehicle_id": log.vehicle_id, **d} for d in result.dropped)
            for ct in result.trips:
                t0 = time.perf_counter()
                trip = _trip_from_clean(
                    ct, vehicle_id=log.vehicle_id, path=path, sha256=sha, index=len(trips),
                    sampler=sampler, params=options.elevation, repairs=log.repairs,
                )
                t1 = time.perf_counter()
                vec = drive_cycle_vector(trip.time_s, trip.speed_mps, trip.elevation_m, cr0=options.cr0)
                vectors.append(vec.to_bytes())
                t2 = time.perf_counter()
                blobs.append(trip_profile_blob(trip))
                stage["elevation"] = stage.get("elevation", 0.0) + t1 - t0
                stage["vector"] = stage.get("vector", 0.0) + t2 - t1
                stage["profile"] = stage.get("profile", 0.0) + time.perf_counter() - t2
                trips.append(trip.record())
        return FileOutcome(
            str(path), sha, size, mtime,
            profile=logs[0].profile if logs else None,
            trips=tuple(trips), vectors=tuple(vectors), profile_blobs=tuple(blobs), n_rows=n_rows,
            n_samples=sum(t.n_samples for t in trips),
            dropped=tuple(dropped), repairs=tuple(logs[0].repairs) if logs else (),
            stage_s=stage,
        )
    except CevmError as exc:
        return FileOutcome(str(path), sha, size, mtime, error=str(exc), stage_s=stage)
    except (ValueError, OSError, csv.Error, UnicodeError) as exc:  # a file we could not make sense of
        return FileOutcome(str(path), sha, size, mtime, error=f"{path}: {type(exc).__name__}: {exc}", stage_s=stage)
    except Exception as exc:  # a bug in cevm: still only this file fails, and it says so
        where = traceback.extract_tb(exc.__traceback__)[-1]
        return FileOutcome(
            str(path), sha, size, mtime, stage_s=stage,
            error=f"{path}: internal error (a cevm bug, please report): {type(exc).__name__}: {exc} "
                  f"at {Path(where.filename).name}:{where.lineno}",
        )


def open_sampler(dsm: str | None) -> DsmSampler | None:
    """Open the DSM, or None. A DSM that cannot be opened is the user's error."""
    if dsm is None:
        return None
    try:
        return DsmSampler.open(dsm)
    except CevmError:
        raise
    except Exception as exc:  # rasterio errors have many types
        raise InputError(dsm, f"cannot open the DSM: {exc}") from None


def worker_sampler(dsm: str, headers: DsmHeaders | None = None) -> DsmSampler:
    """This worker's (process and thread) sampler of ``dsm``, opened on first use and
    kept for the next files (:func:`cevm.executors.worker_cache`). ``headers``: the
    rasters' headers as the writer read them (:attr:`DsmSampler.headers`), so that a
    new worker does not read every tile's header again (~1.5 ms a tile); rasters
    are then opened when a window of them is needed. A long-lived worker given other
    headers (a DSM changed between runs) opens a new sampler."""
    if headers is None:
        return worker_cache(("cevm.ingest.DsmSampler", dsm), lambda: open_sampler(dsm))
    return worker_cache(("cevm.ingest.DsmSampler", dsm, headers), lambda: DsmSampler.from_headers(headers))


def ingest(
    inputs: Iterable[str | Path],
    store: TripStore,
    options: IngestOptions = IngestOptions(),
    *,
    on_file: Callable[[FileReport], None] | None = None,
    on_start: Callable[[int], None] | None = None,
    executor: Executor | None = None,
) -> IngestReport:
    """Ingest files into ``store`` (the single writer); return the run's report.

    ``on_start(n_files)`` is called once the inputs are expanded, ``on_file(report)``
    after each file, in input order (for progress bars and JSON logs).

    ``executor`` runs :func:`process_file` on each file to (re-)ingest (default None:
    serially in this thread; see :func:`cevm.executors.make_executor`); it stays open
    for the caller to reuse and close. The hashing of files and the store writes stay
    here, and results are written in input order, so the store holds the same after a
    serial or a parallel run. A file whose worker died twice is failed, as a bad file.
    """
    t_start = time.perf_counter()
    files, missing = discover(inputs)
    report = IngestReport()
    for m in missing:
        fr = FileReport(path=m.split(":")[0], status="failed", error=m)
        report.files.append(fr)
        if on_file:
            on_file(fr)
    if on_start:
        on_start(len(files))
    profiles = load_profiles(options.profiles_dir) if options.profiles_dir else load_profiles()
    if options.profile is not None and options.profile not in profiles:
        raise InputError(options.profile, f"unknown logger profile; available: {', '.join(sorted(profiles))}")
    sampler = open_sampler(options.dsm)  # here too: a bad DSM stops the run before any work
    if executor is None or len(files) < 2:  # one file cannot run in parallel
        executor = SerialExecutor()
    headers = None
    if not executor.inline and sampler is not None:
        headers = sampler.headers  # workers open their own, from these headers
        sampler.close()
        sampler = None
    run_id = store.start_run()
    try:
        jobs = (_prepare(path, store, options, profiles, sampler, headers) for path in files)
        with closing(executor.run(process_file, jobs)) as results:  # closing: cancels what is left on errors
            for res in results:
                t0 = time.perf_counter()
                fr = _write_result(res, store, options, report)
                fr.seconds += time.perf_counter() - t0
                report.files.append(fr)
                if on_file:
                    on_file(fr)
    finally:
        if sampler is not None:
            sampler.close()
        report.seconds = time.perf_counter() - t_start
        store.finish_run(run_id, {k: v for k, v in report.summary().items() if not isinstance(v, dict)})
    return report


def _prepare(path: Path, store: TripStore, options: IngestOptions, profiles, sampler, headers) -> FileReport | Task:
    """In the writer, before the task: hash the file and skip it if unchanged; else the
    task's arguments (``sampler`` is None for workers: they open their own)."""
    t0 = time.perf_counter()
    try:
        sha = file_sha256(path)
    except OSError as exc:
        return FileReport(str(path), "failed", error=f"{path}: cannot read: {exc.strerror}",
                          seconds=time.perf_counter() - t0)
    if not options.force and not store.needs_ingest(path, sha):
        return FileReport(str(path), "unchanged", seconds=time.perf_counter() - t0)
    return Task(str(path), (path, options, profiles, sampler, sha, headers))


def _write_result(res: TaskResult, store: TripStore, options: IngestOptions, report: IngestReport) -> FileReport:
    """Write one task's outcome to the store (or report the file that needed no task);
    ``seconds`` is the worker's time, the writer's is added by the caller."""
    if res.task is None:
        return res.value
    path, sha = Path(res.task.key), res.task.args[4]
    if not res.ok:  # the task itself failed: its worker died max_attempts times, or it raised
        error = f"{path}: {res.error}"
        try:
            st = path.stat()
            size, mtime = st.st_size, st.st_mtime
        except OSError:
            size = mtime = None
        store.record_failure(path, error, sha256=sha, size_bytes=size, mtime_s=mtime)
        return FileReport(str(path), "failed", error=error)
    fr = _store_outcome(path, res.value, store, options, report)
    fr.seconds = res.seconds
    return fr


def _store_outcome(path: Path, out: FileOutcome, store: TripStore, options: IngestOptions,
                   report: IngestReport) -> FileReport:
    for k, v in out.stage_s.items():
        report.stage_s[k] = report.stage_s.get(k, 0.0) + v
    report.rows += out.n_rows
    if not out.ok:
        if out.sha256 is None:  # could not even be read: nothing to record against
            return FileReport(str(path), "failed", error=out.error)
        store.record_failure(path, out.error, sha256=out.sha256, size_bytes=out.size_bytes,
                             mtime_s=out.mtime_s, profile=out.profile)
        return FileReport(str(path), "failed", error=out.error, profile=out.profile)
    t0 = time.perf_counter()
    res = store.replace_file_trips(
        path, list(out.trips), list(out.vectors), sha256=out.sha256, size_bytes=out.size_bytes,
        mtime_s=out.mtime_s, profile=out.profile, force=options.force, profile_blobs=list(out.profile_blobs),
    )
    report.stage_s["store"] = report.stage_s.get("store", 0.0) + time.perf_counter() - t0
    if res.unchanged:
        return FileReport(str(path), "unchanged", profile=out.profile)
    return FileReport(
        str(path), "ingested", trips=len(out.trips), samples=out.n_samples,
        km=sum(t.length_m for t in out.trips) / 1000.0, profile=out.profile,
        duplicates=res.skipped_duplicates, repairs=out.repairs,
    )

