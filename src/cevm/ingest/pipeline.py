""":func:`ingest`: log files -> the per-file task on an executor -> the trip store.

Discovery expands files, directories and globs (:func:`discover`); each file to
(re-)ingest becomes one task (:func:`cevm.ingest.task.process_file`) on an executor
(:mod:`cevm.executors`: serial, a process pool or a Dask cluster), with its work
estimated from its size (:func:`estimated_work_s`): the executor groups small files into
tasks of about 0.1 s, and the default executor runs a batch too small to pay for a
pool's start in this process.

:func:`ingest` is the store's single writer: one transaction per file, so a crash
mid-file leaves the store as it was, an unchanged file is skipped, a changed file
replaces its trips, and a bad file is reported and skipped while the batch goes on (its
previously stored trips are kept). The outcomes of parallel runs come back in input
order and are written in that order, so the store ends up exactly as after a serial
run. A signal (SIGINT, or SIGTERM under the command line) never splits the writing of a
file's outcome from its report: it is raised once the file is written, so the reports a
caller has seen are exactly what is stored.
"""

from __future__ import annotations

import fnmatch
import glob
import os
import sys
import time
from collections.abc import Callable, Iterable
from contextlib import closing
from dataclasses import dataclass, field
from pathlib import Path

from cevm.errors import InputError
from cevm.executors import Executor, SerialExecutor, Task, TaskResult
from cevm.ingest.profiles import load_profiles
from cevm.ingest.task import FileOutcome, IngestOptions, file_sha256, open_sampler, process_file
from cevm.ingest.textfile import mb
from cevm.runtime import signals_deferred
from cevm.store import TripStore
from cevm.store.failures import StoreAccessError
from cevm.text import printable

#: File names taken from a directory (recursively).
LOG_PATTERNS = ("*.csv", "*.csv.gz", "*.CSV", "*.CSV.GZ")

INGEST_S_PER_BYTE = 4.0e-8
"""Ingest work per byte of (uncompressed) log [s], DSM lookup included, measured on this
project's 2-core machine: 38-42 ns per byte of srf on working-day and 1.4-hour files
(``benchmarks/bench_ingest_parallel.py``, serial). Only for sizing tasks and choosing the
default number of workers: within a factor of two is enough."""

INGEST_FILE_S = 0.002
"""Fixed ingest work per file [s] (open, detect the profile, one trip's set-up)."""

GZIP_RATIO = 6.0
"""Assumed expansion of a gzip log whose trailer cannot tell its size (several members)."""


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
    list of files; return it with a message for each input that matched nothing and for
    each directory that could not be read (its logs, if any, are not ingested: the run
    reports it as failed, never skips it in silence)."""
    found: dict[str, Path] = {}
    missing: list[str] = []
    for item in inputs:
        s = str(item)
        p = Path(s)
        unreadable: list[str] = []
        if p.is_dir():
            hits = _logs_under(p, unreadable)
        elif p.is_file():
            hits = [p]
        elif glob.has_magic(s):
            hits = [Path(q) for q in glob.glob(s, recursive=True) if Path(q).is_file()]
        else:
            hits = []
        missing.extend(unreadable)
        if not hits and not unreadable:
            missing.append(printable(f"{s}: no such file, directory or matching log files"))
        for q in hits:
            found.setdefault(str(q.resolve()), q)
    return [found[k] for k in sorted(found)], missing


def _logs_under(root: Path, unreadable: list[str]) -> list[Path]:
    """The log files (:data:`LOG_PATTERNS`) in ``root`` and its subdirectories (symbolic
    links to directories not followed, as ``Path.rglob``); a message for each directory
    that cannot be listed goes to ``unreadable``."""

    def note(exc: OSError) -> None:
        why = exc.strerror or type(exc).__name__
        unreadable.append(printable(f"{exc.filename}: cannot read this directory ({why}); the logs in it, if "
                                    "any, were not ingested"))

    hits = []
    for dirpath, _, filenames in os.walk(root, onerror=note):
        for name in filenames:
            if any(fnmatch.fnmatchcase(name, pat) for pat in LOG_PATTERNS):
                q = Path(dirpath, name)
                if q.is_file():
                    hits.append(q)
    return hits


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
    profiles = load_profiles()  # the shipped ones, then $CEVM_PROFILES's
    if options.profiles_dir:  # then --profiles-dir's: added, one of the same name replacing the one before
        profiles.update(load_profiles(options.profiles_dir, include_env=False))
    if options.profile is not None and options.profile not in profiles:
        raise InputError(options.profile, f"unknown logger profile; available: {', '.join(sorted(profiles))}")
    sampler = open_sampler(options.dsm, options.allow_remote_dsm)  # here too: a bad DSM stops the run before any work
    costs = _work_to_do(files, store, options)
    if executor is None or len(costs) < 2:  # one file cannot run in parallel
        executor = SerialExecutor()
    else:  # the default executor: as many workers as the work pays for (maybe none)
        executor = executor.sized_for(sum(costs.values()), len(costs))
    headers = None
    if not executor.inline and sampler is not None:
        headers = sampler.headers  # workers open their own, from these headers
        sampler.close()
        sampler = None
    run_id = store.start_run()
    try:
        jobs = (_prepare(path, store, options, profiles, sampler, headers, costs.get(str(path))) for path in files)
        with closing(executor.run(process_file, jobs)) as results:  # closing: cancels what is left on errors
            for res in results:
                with signals_deferred():  # a file written is a file reported
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
        counts = {k: v for k, v in report.summary().items() if not isinstance(v, dict)}
        stopped_by = sys.exc_info()[1]  # the run ends with an exception: say so in its record
        if stopped_by is not None:
            counts["stopped_by"] = str(stopped_by) or type(stopped_by).__name__
        with signals_deferred():
            try:
                store.finish_run(run_id, counts)
            except StoreAccessError:
                if stopped_by is None:  # else report the write that failed first, not this one
                    raise
    return report


def estimated_work_s(path: Path, size_bytes: int) -> float:
    """Ingest work of one log file [s on one core], from its size (a gzip file's from the
    uncompressed size its trailer records): :data:`INGEST_FILE_S` +
    :data:`INGEST_S_PER_BYTE` per byte. An estimate for scheduling, never a limit."""
    return INGEST_FILE_S + INGEST_S_PER_BYTE * _content_size(path, size_bytes)


def _content_size(path: Path, size_bytes: int) -> int:
    """The file's size, or for a gzip file (by its magic bytes) the uncompressed size its
    trailer records (modulo 4 GiB, of its last member only), or :data:`GZIP_RATIO` times
    its size where that is implausible."""
    try:
        with open(path, "rb") as f:
            if f.read(2) != b"\x1f\x8b":
                return size_bytes
            f.seek(-4, os.SEEK_END)
            isize = int.from_bytes(f.read(4), "little")
    except OSError:
        return size_bytes
    plausible = size_bytes <= isize <= 1032 * size_bytes  # deflate expands at most 1032x
    return isize if plausible else int(GZIP_RATIO * size_bytes)


def _work_to_do(files: list[Path], store: TripStore, options: IngestOptions) -> dict[str, float]:
    """The estimated work [s] of each file that will probably be (re-)ingested: all of
    them but those the store holds ingested at the same size and modification time
    (the writer still hashes every file to decide)."""
    costs = {}
    for path in files:
        try:
            st = path.stat()
        except OSError:
            continue  # reported by _prepare
        state = None if options.force else store.file_state(path)
        if (state is not None and state.status == "ok" and state.size_bytes == st.st_size
                and state.mtime_s == st.st_mtime):
            continue
        costs[str(path)] = estimated_work_s(path, st.st_size)
    return costs


def _prepare(path: Path, store: TripStore, options: IngestOptions, profiles, sampler, headers,
             cost_s: float | None) -> FileReport | Task:
    """In the writer, before the task: hash the file and skip it if unchanged; else the
    task's arguments (``sampler`` is None for workers: they open their own) and its
    estimated work (None for a file thought unchanged: it goes alone)."""
    t0 = time.perf_counter()
    try:
        size = path.stat().st_size
        if size > options.limits.max_file_bytes and not _is_gzip(path):  # refused unread, not hashed first
            return FileReport(str(path), "failed", seconds=time.perf_counter() - t0, error=printable(
                f"{path}: file of {mb(size)} MB: more than the limit of {options.limits.max_file_mb:g} MB "
                "per file (--max-file-mb)"))
        sha = file_sha256(path)
    except OSError as exc:
        return FileReport(str(path), "failed", error=printable(f"{path}: cannot read: {exc.strerror}"),
                          seconds=time.perf_counter() - t0)
    if not options.force and not store.needs_ingest(path, sha):
        return FileReport(str(path), "unchanged", seconds=time.perf_counter() - t0)
    return Task(str(path), (path, options, profiles, sampler, sha, headers), cost_s=cost_s)


def _is_gzip(path: Path) -> bool:
    with open(path, "rb") as fh:
        return fh.read(2) == b"\x1f\x8b"


def _write_result(res: TaskResult, store: TripStore, options: IngestOptions, report: IngestReport) -> FileReport:
    """Write one task's outcome to the store (or report the file that needed no task);
    ``seconds`` is the worker's time, the writer's is added by the caller."""
    if res.task is None:
        return res.value
    path, sha = Path(res.task.key), res.task.args[4]
    if not res.ok:  # the task itself failed: its worker died max_attempts times, or it raised
        error = printable(f"{path}: {res.error}")
        size: int | None
        mtime: float | None
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
        assert out.error is not None  # a failed outcome says why
        store.record_failure(path, out.error, sha256=out.sha256, size_bytes=out.size_bytes,
                             mtime_s=out.mtime_s, profile=out.profile)
        return FileReport(str(path), "failed", error=out.error, profile=out.profile)
    assert out.sha256 is not None  # a file read has its digest
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
