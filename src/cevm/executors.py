"""Run one task function over many inputs: in this process, on a local process pool, or
on a Dask distributed cluster, with one driver and the same results.

The caller (e.g. :func:`cevm.ingest.ingest`, the store's single writer) gives a task
function and an iterable of :class:`Task` items (``fn(*task.args)`` is one unit of work,
such as one log file) and consumes :class:`TaskResult` objects **in input order**, while
the tasks run elsewhere. Items that are not a :class:`Task` pass through unchanged (as
results with ``attempts == 0``), so a caller can mix work it resolved itself (an
unchanged file) with work to do and still see everything in order.

Executors (thin wrappers, no home-made scheduling):

* :class:`SerialExecutor`: runs each task inline, one at a time (``--workers 1``).
* :class:`ProcessExecutor`: a :class:`concurrent.futures.ProcessPoolExecutor` with
  ``forkserver`` workers (no fork of a process with threads).
* :class:`DaskExecutor`: a :class:`distributed.Client` (``pip install cevm[dask]``);
  the scheduler places tasks, results come back to the client.

:func:`make_executor` picks one from ``--workers`` / ``--scheduler``.

Tasks sized by work
    A submitted task costs the executor a fixed amount (a Dask cluster ~9 ms of CPU for
    its scheduler, client and worker event loops; a process pool ~1 ms of pickling and
    pipes), whatever its work. A :class:`Task` may say what it costs
    (``cost_s``: estimated seconds of work on one core); a parallel executor then
    submits consecutive small tasks together, as one **group** of about ``task_s``
    seconds of work (default :data:`TASK_S`; at most :data:`MAX_GROUP` tasks). A group
    runs its tasks one after the other in one worker and returns each one's result;
    results are still yielded one per task, in input order. Tasks without a cost (or
    costing ``task_s`` or more) go alone, as before.

Faults
    Per-task isolation survives grouping: a task that raises inside a group is run
    again alone (so what it reports is what it reports alone), and a group whose worker
    died is split: each of its tasks is run again alone. A task whose worker process
    dies is run again elsewhere; after ``max_attempts`` (default 2) deaths that are
    provably its own, it is reported as a failed result (``error`` set), never silently
    dropped. In a process pool a dead worker breaks the whole pool
    (:class:`~concurrent.futures.process.BrokenProcessPool`): the pool is recreated,
    tasks that had not started are resubmitted for free, and the tasks that were running
    are suspects. Each worker writes the index of the task (or group) it runs into a
    shared array, so suspects are known exactly. A lone suspect task is charged the
    death; several suspects (or the tasks of one group) are not (only one of them killed
    its worker, and which is unknown). Every suspect is then re-run **alone** in the
    pool, where a death is its own. A task is failed once it has been charged
    ``max_attempts`` deaths: a task that kills every worker it runs on kills
    ``max_attempts`` of them (one more if its first death was beside another task or in
    a group), and neither a task that ran beside it nor one that killed its worker once,
    beside it, and then ran clean, is blamed. On Dask, the scheduler does this itself: a
    dead worker's tasks are rescheduled, and a task that was on
    ``distributed.scheduler.allowed-failures + 1`` dead workers fails with
    ``KilledWorker`` (a group that does is split into its tasks, which then run alone:
    the scheduler charges a death to every task the dead worker held, so a task that
    ran beside a killer could be failed with it;
    :class:`DaskExecutor` sets ``allowed-failures = max_attempts - 1`` on the clusters
    it creates; start a remote scheduler with
    ``DASK_DISTRIBUTED__SCHEDULER__ALLOWED_FAILURES=1`` for the same rule); exceptions
    raised by the task are retried ``max_attempts - 1`` times (``retries``).

Worker lifetime
    Local workers end with the process that made the pool, whatever ended it (a
    ``kill -9`` too): on Linux the forkserver and each worker ask the kernel for SIGKILL
    when their parent dies (``prctl(PR_SET_PDEATHSIG)``), and each worker also watches
    the pool's owner itself (a thread that waits on a pidfd of it, or polls it where
    there is none). Workers ignore SIGINT (a Ctrl-C in a terminal reaches the whole
    process group; the owner decides); closing an executor while an exception
    propagates (an interrupt) kills its workers instead of waiting for their tasks.

Worker resources
    :func:`worker_cache` keeps objects that are costly to open (a DSM sampler) once per
    worker process and thread, keyed by what they were opened from.

Determinism
    Results are yielded in input order whatever the completion order, so a caller that
    writes them as they come writes exactly what a serial run writes. At most
    ``window`` tasks' worth of items (default: four per worker slot, at least 32) are in
    flight or waiting for an earlier one, which bounds memory whatever the number of
    items: an item counts as a whole task unless it has a cost, then as its share of
    ``task_s`` (at least ``1 / MAX_GROUP``).
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import multiprocessing as mp
import os
import signal
import sys
import threading
import time
import uuid
from collections import OrderedDict, deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor
from concurrent.futures import wait as cf_wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from typing import Any

from cevm.errors import CevmError

__all__ = [
    "DaskExecutor",
    "Executor",
    "ProcessExecutor",
    "SerialExecutor",
    "Task",
    "TaskResult",
    "make_executor",
    "worker_cache",
]

MAX_ATTEMPTS = 2
"""Default number of worker deaths (or raised exceptions) a task may cause before it is
reported failed: one retry, as a file that kills a worker twice will do it again."""

WINDOW_PER_SLOT = 4
"""Default tasks' worth of items in flight or waiting, per worker slot: enough that a
slow task does not idle the other workers at once, few enough to bound the results held
in memory (an ingest result is a few MB per vehicle-day)."""

MIN_WINDOW = 32
"""Least default window of a parallel run: a Dask round trip costs milliseconds, so a
few tasks queued ahead per worker keep them busy (32 ingest results: ~100 MB at most)."""

TASK_S = 0.1
"""Default work per submitted task of a parallel executor [s]: tasks with a smaller
``cost_s`` are grouped up to this. A Dask task costs ~9 ms of CPU here (scheduler,
client, worker event loops), so a group of 100 ms spends under 10 % on it, and 4
groups per worker in flight are still only ~0.4 s of work each."""

MAX_GROUP = 64
"""Most tasks in one group (however cheap they claim to be)."""

WORKER_ENV = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
"""Environment of the local worker processes (where the user has not set these): one
thread per BLAS/OpenMP library, as Dask's nanny sets for its workers. The processes are
the parallelism; BLAS threads of their own oversubscribe the cores, and OpenBLAS's
spin after each call (a matrix product in the timestamp parser of cevm.ingest.timestamps made
two workers slower than one)."""

WORKER_CACHE_SIZE = 4
"""Objects :func:`worker_cache` keeps per worker thread: a run uses one or two (a DSM);
a Dask worker that lives for many runs with other DSMs must not keep every one of them
(a sampler's block cache is up to 256 MB)."""

#: Recurring task arguments a :class:`DaskExecutor` keeps on the cluster (oldest dropped).
SHARED_ARGS_KEPT = 16

POOL_START_S = 1.0
"""What a fresh local pool costs before its first result, in wall time [s], measured
on this project's 2-core machine (``benchmarks/bench_ingest_parallel.py``, small
batch: ``--workers 2`` 0.6-1.1 s slower than ``--workers 1`` on 0.4 s of work, so a
start of 0.8-1.3 s): the forkserver importing cevm, rasterio, pyproj and scipy
(0.7-0.8 s), each worker's first ingest task (a pyproj transformer, the DSM's rasters
opened: ~0.1 s), the first results' pickles. Erring high costs a medium batch some
speed, erring low makes it slower than one process."""

PARALLEL_EFFICIENCY = 0.85
"""Speed-up per worker a pool reaches on CPU-bound ingest work, measured here (2
workers: 1.6-1.9x one process)."""

WATCHDOG_POLL_S = 1.0
"""How often a worker without a pidfd (not Linux) checks that its pool's owner lives [s]."""

#: Environment variable that hands the forkserver the pid of the process it must not
#: outlive (set only while the forkserver starts; read once, by the forkserver).
_FORKSERVER_PARENT_ENV = "CEVM_FORKSERVER_PARENT"


def _identity(obj: Any) -> Any:
    """A task that returns its argument: how a recurring argument is put on a cluster."""
    return obj


#: The environment variables that give a client its TLS certificates (Dask's configuration).
TLS_CLIENT_SETTINGS = ("DASK_DISTRIBUTED__COMM__TLS__CA_FILE", "DASK_DISTRIBUTED__COMM__TLS__CLIENT__CERT",
                       "DASK_DISTRIBUTED__COMM__TLS__CLIENT__KEY")

DASK_CONNECT_TIMEOUT_S = 20.0
"""How long :class:`DaskExecutor` waits for a scheduler [s] before giving up: a scheduler
on a LAN answers in milliseconds; 20 s allows for one starting up."""


# --------------------------------------------------------------------------- values


@dataclass(frozen=True)
class Task:
    """One unit of work: ``fn(*args)`` for the run's task function ``fn``. ``key``
    names it in messages (for ingest: the file path); ``args`` must pickle.
    ``cost_s``: its estimated work [s on one core], if known; a parallel executor then
    groups it with its neighbours into a task of about ``task_s`` (see the module
    docstring). None: it always goes alone."""

    key: str
    args: tuple = ()
    cost_s: float | None = None


@dataclass(frozen=True, eq=False)
class TaskResult:
    """What became of item ``index`` of a run.

    ``value``: the task function's return value, or the item itself when it was not a
    :class:`Task` (``attempts == 0``). ``error``: why there is no value (the task raised,
    or its workers died ``max_attempts`` times); None if ok. ``attempts``: runs started
    (1 for a task that ran once; runs in a group that died, not charged to it, do not
    count). ``seconds``: wall time of the successful run in the worker [s] (0 if none).
    ``task``: the submitted :class:`Task` (None for a pass-through item).
    """

    index: int
    task: Task | None
    value: Any = None
    error: str | None = None
    attempts: int = 0
    seconds: float = 0.0

    @property
    def ok(self) -> bool:
        return self.error is None


# --------------------------------------------------------------------- worker side

_local = threading.local()


def worker_cache(key: Any, factory: Callable[[], Any]) -> Any:
    """The object ``factory()`` made for ``key`` in this process and thread, made on
    first use and kept for the next tasks.

    For resources that are costly to open and not thread-safe (a
    :class:`~cevm.ingest.dsm.DsmSampler`: headers over HTTP, a block cache), so that a
    worker opens them once and not once per task. Per thread because Dask workers run
    tasks in threads. ``key`` must be hashable and name everything the object depends
    on (e.g. the DSM path). A long-lived worker keeps the :data:`WORKER_CACHE_SIZE`
    most recently used objects; older ones are dropped (and closed if they have a
    ``close`` method).
    """
    cache = getattr(_local, "cache", None)
    if cache is None:
        cache = _local.cache = OrderedDict()
    try:
        cache.move_to_end(key)
        return cache[key]
    except KeyError:
        obj = cache[key] = factory()
        while len(cache) > WORKER_CACHE_SIZE:
            _, old = cache.popitem(last=False)
            close = getattr(old, "close", None)
            if callable(close):
                close()
        return obj


_ALLOCATOR_TUNED = False


def _tune_once() -> None:
    """The first task in a process applies :func:`cevm.runtime.tune_allocator` there (a
    Dask worker runs its tasks in a thread, whose malloc arena otherwise hands freed
    pages back to the system and faults them in again on the next task: a third of
    Dask's overhead measured)."""
    global _ALLOCATOR_TUNED
    if not _ALLOCATOR_TUNED:
        from cevm.runtime import tune_allocator

        tune_allocator()
        _ALLOCATOR_TUNED = True


def _execute(fn: Callable, args: tuple) -> tuple[Any, float]:
    """Run one task in a worker: ``(fn(*args), wall seconds)``."""
    _tune_once()
    t0 = time.perf_counter()
    value = fn(*args)
    return value, time.perf_counter() - t0


def _execute_group(fn: Callable, group: list[tuple]) -> list[tuple[Any, float, str | None]]:
    """Run a group's tasks one after the other in a worker: per task ``(value, wall
    seconds, None)``, or ``(None, 0, error)`` for one that raised (the caller runs that
    one again alone, so its own failure is what is reported)."""
    _tune_once()
    out = []
    for args in group:
        t0 = time.perf_counter()
        try:
            value = fn(*args)
        except Exception as exc:
            out.append((None, 0.0, _error_text(exc)))
        else:
            out.append((value, time.perf_counter() - t0, None))
    return out


# ------------------------------------------------------------------ worker lifetime

_PR_SET_PDEATHSIG = 1  # linux/prctl.h


def _set_parent_death_signal(sig: int = signal.SIGKILL) -> bool:
    """Ask the kernel to send ``sig`` to this process when its parent (the thread that
    forked it) dies; Linux only. True if set."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(_PR_SET_PDEATHSIG, int(sig), 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def _watch_owner(owner_pid: int) -> None:
    """End this process (``os._exit``) as soon as process ``owner_pid`` has ended: a
    daemon thread waits on a pidfd of it (Linux 5.3+), or else polls it every
    :data:`WATCHDOG_POLL_S`. If it has ended already, end now."""
    try:
        fd = os.pidfd_open(owner_pid)
    except ProcessLookupError:
        os._exit(1)
    except (AttributeError, OSError):
        fd = None

    def wait_pidfd() -> None:
        import select

        p = select.poll()
        p.register(fd, select.POLLIN)
        while not p.poll():
            pass
        os._exit(1)

    def poll_pid() -> None:
        while True:
            time.sleep(WATCHDOG_POLL_S)
            try:
                os.kill(owner_pid, 0)
            except ProcessLookupError:
                os._exit(1)
            except PermissionError:  # alive, another user's (its pid was reused: rare)
                pass

    threading.Thread(target=wait_pidfd if fd is not None else poll_pid, name="cevm-owner-watch", daemon=True).start()


def _forkserver_lifeline() -> None:
    """In the forkserver that :func:`_start_forkserver` started (it imports this module
    first): die with the process that started it, as its workers die with it. Does
    nothing in any other process."""
    want = os.environ.get(_FORKSERVER_PARENT_ENV)
    if want and want == str(os.getppid()):
        if not _set_parent_death_signal():
            _watch_owner(int(want))
        elif os.getppid() != int(want):  # it died before the request took effect
            os._exit(1)


_SLOTS = None  # shared array: index of the task (or group) each pool worker runs, -1 when idle
_SLOT = -1


def _pool_init(slots, counter, owner_pid: int) -> None:
    global _SLOTS, _SLOT
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the owner handles a Ctrl-C, and ends us
    parent = os.getppid()
    if _set_parent_death_signal() and os.getppid() != parent:
        os._exit(1)  # our parent (the forkserver) died before the request took effect
    _watch_owner(owner_pid)  # the pool's owner, which may not be our parent
    with counter.get_lock():
        _SLOT = counter.value % len(slots)
        counter.value += 1
    _SLOTS = slots


def _pool_execute(fn: Callable, index: int, payload, grouped: bool):
    _SLOTS[_SLOT] = index
    try:
        return _execute_group(fn, payload) if grouped else _execute(fn, payload)
    finally:
        _SLOTS[_SLOT] = -1


# ---------------------------------------------------------------------------- driver


@dataclass(eq=False)
class _Entry:
    """What one submission runs: one task, or a group of consecutive tasks."""

    items: list  # [(index, Task)], in input order
    attempts: int = 0  # runs started (deaths suspected of it + the current run)

    @property
    def index(self) -> int:
        return self.items[0][0]

    @property
    def task(self) -> Task:
        return self.items[0][1]

    @property
    def grouped(self) -> bool:
        return len(self.items) > 1

    def payload(self):
        """The submitted argument: a task's args, or a group's list of them."""
        return [t.args for _, t in self.items] if self.grouped else self.task.args

    def singles(self) -> list[_Entry]:
        """Each task of a group alone, its run in the group not counted."""
        return [_Entry([it], self.attempts - 1) for it in self.items]


@dataclass
class _RunState:
    pending: dict = field(default_factory=dict)  # handle -> _Entry
    retry: deque = field(default_factory=deque)  # entries to resubmit, any company
    alone: deque = field(default_factory=deque)  # entries to resubmit with nothing else running


class Executor(ABC):
    """Base class: the driver (:meth:`run`) over an executor's submit/wait hooks."""

    #: Runs tasks in the calling thread (objects need not pickle; nothing to protect).
    inline: bool = False
    #: Tasks that can run at once.
    slots: int = 1
    max_attempts: int = MAX_ATTEMPTS
    #: Work per submitted task [s]: tasks with a smaller ``cost_s`` are grouped (0: never).
    task_s: float = 0.0
    #: Submissions made so far (a group counts once; reruns count again).
    submitted: int = 0
    name: str = "executor"

    # ---- per-executor hooks ---------------------------------------------------------

    @abstractmethod
    def _submit(self, fn: Callable, entry: _Entry):
        """Start ``fn`` on ``entry``'s task (or group); return a handle."""

    @abstractmethod
    def _wait(self, handles: list) -> Iterable:
        """The handles that are done, waiting for at least one."""

    @abstractmethod
    def _finish(self, handle, entry: _Entry, st: _RunState) -> list[TaskResult]:
        """Results made final by ``handle`` being done (none if it was resubmitted)."""

    def _cancel(self, handles: list) -> None:
        for h in handles:
            h.cancel()

    # ---- shared by the hooks ----------------------------------------------------------

    @staticmethod
    def _finished(entry: _Entry, value, seconds: float, st: _RunState) -> list[TaskResult]:
        """The results of a finished submission: a task's, or a group's (a task that
        raised in its group goes to run again alone)."""
        if not entry.grouped:
            return [TaskResult(entry.index, entry.task, value=value, attempts=entry.attempts, seconds=seconds)]
        out = []
        for (i, task), (v, s, error), single in zip(entry.items, value, entry.singles()):
            if error is None:
                out.append(TaskResult(i, task, value=v, attempts=entry.attempts, seconds=s))
            else:
                st.retry.append(single)
        return out

    # ---- the driver -------------------------------------------------------------------

    def run(self, fn: Callable, items: Iterable, *, window: int | None = None) -> Iterator[TaskResult]:
        """Run ``fn(*task.args)`` for every :class:`Task` in ``items``; yield one
        :class:`TaskResult` per item, in input order.

        ``items`` is consumed lazily, at most ``window`` tasks' worth ahead of the last
        one yielded (default: :data:`WINDOW_PER_SLOT` per slot, at least
        :data:`MIN_WINDOW`; 1 for a serial executor, which runs a task as it is
        submitted), so work the caller does to make an item (hashing a file) overlaps
        the running tasks. Consecutive tasks with a ``cost_s`` below :attr:`task_s` are
        submitted together (module docstring). ``fn`` must be a module-level function
        (workers import it by name). Closing the generator (breaking out of the loop, an
        exception in it) cancels the tasks not yet started.
        """
        if window is None:
            window = 1 if self.inline else max(MIN_WINDOW, WINDOW_PER_SLOT * self.slots)
        window = max(1, int(window))
        target = 0.0 if self.inline else float(self.task_s)
        least = 1.0 / MAX_GROUP
        source = enumerate(items)
        exhausted = False
        st = _RunState()
        ready: dict[int, TaskResult] = {}
        weight: dict[int, float] = {}  # window share of each item pulled and not yet yielded
        load = 0.0
        group: list = []
        group_s = 0.0
        next_out = 0

        def flush() -> None:
            nonlocal group, group_s
            if group:
                self._put(fn, _Entry(group), st)
                group, group_s = [], 0.0

        try:
            while True:
                if st.alone:
                    if not st.pending:
                        self._put(fn, st.alone.popleft(), st)
                else:
                    while st.retry:
                        self._put(fn, st.retry.popleft(), st)
                    while not exhausted and not st.alone and load < window:
                        try:
                            i, item = next(source)
                        except StopIteration:
                            exhausted = True
                            break
                        if not isinstance(item, Task):
                            weight[i] = least
                            ready[i] = TaskResult(i, None, value=item)
                        elif target > 0 and item.cost_s is not None and item.cost_s < target:
                            weight[i] = max(least, item.cost_s / target)
                            group.append((i, item))
                            group_s += item.cost_s
                            if group_s >= target or len(group) >= MAX_GROUP:
                                flush()
                        else:
                            weight[i] = 1.0
                            flush()
                            self._put(fn, _Entry([(i, item)]), st)
                        load += weight[i]
                        while next_out in ready:  # overlap the caller's work with the tasks
                            load -= weight.pop(next_out)
                            yield ready.pop(next_out)
                            next_out += 1
                    flush()
                while next_out in ready:
                    load -= weight.pop(next_out)
                    yield ready.pop(next_out)
                    next_out += 1
                if not st.pending:
                    if exhausted and not st.retry and not st.alone:
                        break
                    continue
                for h in list(self._wait(list(st.pending))):
                    entry = st.pending.pop(h, None)
                    if entry is None:  # handled with an earlier one (a broken pool)
                        continue
                    for res in self._finish(h, entry, st):
                        ready[res.index] = res
        finally:
            if st.pending:
                self._cancel(list(st.pending))

    def _put(self, fn: Callable, entry: _Entry, st: _RunState) -> None:
        entry.attempts += 1
        self.submitted += 1
        st.pending[self._submit(fn, entry)] = entry

    def sized_for(self, work_s: float, n_tasks: int) -> Executor:
        """The executor to run ``n_tasks`` tasks of ``work_s`` estimated seconds of work
        in all on: this one (an executor chosen by the user), or for the default one
        (:func:`make_executor` without a number of workers) one that pays for itself."""
        return self

    def close(self) -> None:
        """Release the workers (a no-op for executors that hold none)."""

    def terminate(self) -> None:
        """Release the workers now, without waiting for running tasks (their results
        are lost): what leaving a ``with`` block on an exception does."""
        self.close()

    def __enter__(self):
        return self

    def __exit__(self, exc_type, *exc) -> None:
        if exc_type is None:
            self.close()
        else:  # an interrupt, an error of the caller: no result of a running task is wanted
            self.terminate()

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r}, slots={self.slots})"


def _error_text(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0]}" if text else type(exc).__name__


class SerialExecutor(Executor):
    """Runs each task inline in the calling thread, one at a time (``--workers 1``).
    Task arguments are passed as they are (an open DSM sampler may be one)."""

    inline = True
    slots = 1
    name = "serial"

    def _submit(self, fn, entry):
        fut: Future = Future()
        t0 = time.perf_counter()
        try:
            value = fn(*entry.task.args)
        except Exception as exc:  # a task that raises fails alone, as in a pool
            fut.set_exception(exc)
        else:
            fut.set_result((value, time.perf_counter() - t0))
        return fut

    def _wait(self, handles):
        return handles

    def _finish(self, handle, entry, st):
        exc = handle.exception()
        if exc is not None:
            return [TaskResult(entry.index, entry.task, error=_error_text(exc), attempts=entry.attempts)]
        return self._finished(entry, *handle.result(), st)


def workers_for(work_s: float, n_tasks: int, cores: int, *, start_s: float = POOL_START_S,
                efficiency: float = PARALLEL_EFFICIENCY) -> int:
    """How many local workers pay for themselves on ``n_tasks`` tasks of ``work_s``
    seconds of work in all: the number ``n`` (1: this process, no pool) of the least
    estimated wall time, ``work_s`` in one process, ``start_s + work_s / (n efficiency)``
    on a fresh pool of ``n``; never more than the cores or the tasks."""
    best_n, best_t = 1, work_s
    for n in range(2, max(1, min(int(cores), int(n_tasks))) + 1):
        t = start_s + work_s / (n * efficiency)
        if t < best_t:
            best_n, best_t = n, t
    return best_n


class ProcessExecutor(Executor):
    """Tasks on a local :class:`~concurrent.futures.ProcessPoolExecutor` of ``workers``
    processes (started on first use, kept until :meth:`close`).

    Parameters
    ----------
    workers : int
        Worker processes; the machine's cores (``os.cpu_count()``) are the useful most
        for CPU-bound tasks.
    max_attempts : int, default :data:`MAX_ATTEMPTS` (2)
        Worker deaths a task may provably cause before it is failed (see the module
        docstring for how deaths are attributed).
    start_method : str, default ``"forkserver"``
        How workers start. ``forkserver`` forks them from a clean server process that
        imported ``preload`` once (~0.5 s the first time in a process, ~30 ms for a
        pool after that), never from this process: ``fork`` from a process with threads
        (a progress bar, a Dask client) can deadlock a child. ``spawn`` works too and
        pays the imports in every worker. With ``forkserver`` the workers run with
        :data:`WORKER_ENV` (single-threaded BLAS).
    preload : tuple of str, default ``("cevm.ingest.task", "rasterio", "pyproj", "scipy.ndimage")``
        Modules the forkserver imports before forking workers (the ingest task's, some
        imported lazily), so that a new worker does not import them again.
    task_s : float, default :data:`TASK_S`
        Work per submitted task [s]: tasks with a smaller ``cost_s`` are grouped (0:
        never).
    auto : bool, default False
        ``workers`` is a most, not a choice: :meth:`sized_for` uses fewer, or this
        process alone, where a pool would not pay for its start (:func:`workers_for`).
    """

    name = "processes"

    def __init__(self, workers: int, *, max_attempts: int = MAX_ATTEMPTS, start_method: str = "forkserver",
                 preload: tuple[str, ...] = ("cevm.ingest.task", "rasterio", "pyproj", "scipy.ndimage"),
                 task_s: float = TASK_S, auto: bool = False):
        if workers < 1:
            raise ValueError("workers must be >= 1")
        if max_attempts < 1:
            raise ValueError("max_attempts must be >= 1")
        self.slots = int(workers)
        self.max_attempts = int(max_attempts)
        self.task_s = float(task_s)
        self.auto = bool(auto)
        self._ctx = mp.get_context(start_method)
        if start_method == "forkserver":  # first: the forkserver must not outlive us
            self._ctx.set_forkserver_preload(["cevm.executors", *preload])
        self._pool: ProcessPoolExecutor | None = None
        self._slots_arr = None
        self.restarts = 0  # pools recreated after a worker died

    def sized_for(self, work_s: float, n_tasks: int) -> Executor:
        if not self.auto or self._pool is not None:
            return self
        n = workers_for(work_s, n_tasks, self.slots)
        if n < 2:
            return SerialExecutor()
        self.slots = n
        return self

    def _ensure_pool(self) -> ProcessPoolExecutor:
        if self._pool is None:
            if self._ctx.get_start_method() == "forkserver":
                _start_forkserver()
            self._slots_arr = self._ctx.Array("q", [-1] * self.slots, lock=False)
            counter = self._ctx.Value("i", 0)
            self._pool = ProcessPoolExecutor(self.slots, mp_context=self._ctx, initializer=_pool_init,
                                             initargs=(self._slots_arr, counter, os.getpid()))
        return self._pool

    def _submit(self, fn, entry):
        try:
            return self._ensure_pool().submit(_pool_execute, fn, entry.index, entry.payload(), entry.grouped)
        except BrokenProcessPool as exc:  # broke since the last wait: _finish sorts it out
            fut: Future = Future()
            fut.set_exception(exc)
            return fut

    def _wait(self, handles):
        return cf_wait(handles, return_when=FIRST_COMPLETED).done

    def _finish(self, handle, entry, st):
        exc = handle.exception()
        if isinstance(exc, BrokenProcessPool):
            return self._on_broken(entry, st)
        if exc is not None:  # a lone task raised (a group catches its tasks' exceptions)
            if entry.grouped:
                st.retry.extend(entry.singles())
                return []
            return [TaskResult(entry.index, entry.task, error=_error_text(exc), attempts=entry.attempts)]
        return self._finished(entry, *_unpack(handle.result(), entry), st)

    def _on_broken(self, first: _Entry, st: _RunState) -> list[TaskResult]:
        """A worker died: sort the submissions the pool held into done, free to
        resubmit and suspects (running when it broke); recreate the pool lazily."""
        started = {int(i) for i in self._slots_arr if i >= 0} if self._slots_arr is not None else set()
        pool, self._pool = self._pool, None
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)  # every future is now done
        self.restarts += 1
        results: list[TaskResult] = []
        victims = [first]
        for h, e in list(st.pending.items()):
            del st.pending[h]
            if h.done() and not h.cancelled() and h.exception() is None:  # finished before the break
                results.extend(self._finished(e, *_unpack(h.result(), e), st))
            else:
                victims.append(e)
        suspects = sorted((e for e in victims if e.index in started), key=lambda e: e.index)
        for e in sorted((e for e in victims if e.index not in started), key=lambda e: e.index):
            e.attempts -= 1  # never started: this run does not count
            st.retry.append(e)
        lone = len(suspects) == 1 and not suspects[0].grouped  # then the death is provably its own
        for e in suspects:
            if e.grouped:  # which of its tasks killed the worker is unknown: each runs alone, uncharged
                st.alone.extend(e.singles())
            elif not lone:
                e.attempts -= 1  # not provably its death: run alone, uncharged
                st.alone.append(e)
            elif e.attempts >= self.max_attempts:
                results.append(TaskResult(
                    e.index, e.task, attempts=e.attempts,
                    error=f"its worker process died {e.attempts} times while running it (killed, out of memory "
                          "or crashed in native code)"))
            else:
                st.alone.append(e)  # from now on it runs alone: a death is then its own
        return results

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None

    def terminate(self) -> None:
        """Kill the workers (SIGKILL), then release the pool: for an interrupt, when
        nothing a running task returns is wanted and waiting for it would delay the
        exit by up to a task."""
        pool, self._pool = self._pool, None
        if pool is None:
            return
        kill = getattr(pool, "kill_workers", None)  # Python 3.14+
        if callable(kill):
            kill()
        else:
            for p in list((getattr(pool, "_processes", None) or {}).values()):
                try:
                    p.kill()
                except (OSError, ValueError):
                    pass  # gone already
        pool.shutdown(wait=True, cancel_futures=True)


def _unpack(result, entry: _Entry) -> tuple[Any, float]:
    """``(value, seconds)`` of a finished submission: a group returns its list."""
    return (result, 0.0) if entry.grouped else result


def _start_forkserver() -> None:
    """Start this process's forkserver (if not running) with :data:`WORKER_ENV`: its
    preload imports numpy, whose BLAS reads the thread count then, and the workers it
    forks inherit that. Started from the main thread, it also learns this process's pid
    (:func:`_forkserver_lifeline`: it dies with it). Not from another thread: Linux's
    parent-death signal follows the thread that forks, which may end long before this
    process (the workers still watch this process themselves)."""
    from multiprocessing import forkserver

    env = dict(WORKER_ENV)
    if threading.current_thread() is threading.main_thread():
        env[_FORKSERVER_PARENT_ENV] = str(os.getpid())
    saved = {k: os.environ.get(k) for k in env}
    try:
        for k, v in env.items():
            if k == _FORKSERVER_PARENT_ENV:
                os.environ[k] = v
            else:
                os.environ.setdefault(k, v)
        forkserver.ensure_running()
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


class DaskExecutor(Executor):
    """Tasks on a Dask distributed cluster (``pip install cevm[dask]``).

    Work travels to the workers as pickles, and unpickling can run any code: whoever can
    reach the scheduler can run code as the workers (and in this client, through the
    results). Run the cluster on a private network, or with TLS (a ``tls://`` address;
    this client's certificates from Dask's configuration, :data:`TLS_CLIENT_SETTINGS`):
    README, "More than one machine".

    Parameters
    ----------
    address : str or None
        The scheduler, e.g. ``tcp://10.0.0.5:8786`` (``dask scheduler`` prints it).
        Workers must import cevm (same version) and read the task's inputs (for ingest:
        the log files at the same paths, and the DSM) themselves.
    client : distributed.Client or None
        An existing client instead of ``address`` (it is not closed by :meth:`close`).
    max_attempts : int, default :data:`MAX_ATTEMPTS` (2)
        A task that raises is retried ``max_attempts - 1`` times (``retries``). Worker
        deaths are counted by the scheduler (``allowed-failures``, see module docstring).
    timeout_s : float, default :data:`DASK_CONNECT_TIMEOUT_S`
        How long to wait for the scheduler [s].
    task_s : float, default :data:`TASK_S`
        Work per submitted task [s]: tasks with a smaller ``cost_s`` are grouped (0:
        never).
    """

    name = "dask"

    def __init__(self, address: str | None = None, *, client=None, max_attempts: int = MAX_ATTEMPTS,
                 timeout_s: float = DASK_CONNECT_TIMEOUT_S, task_s: float = TASK_S):
        try:
            import distributed
        except ImportError:
            raise CevmError("a Dask scheduler needs the optional extra: pip install 'cevm[dask]'") from None
        if client is None and address is None:
            raise ValueError("give a scheduler address or a client")
        self.max_attempts = int(max_attempts)
        self.task_s = float(task_s)
        self._own = client is None
        if client is None:
            if str(address).startswith("tls://"):
                import dask

                if not (dask.config.get("distributed.comm.tls.ca-file", None)  # (a key may be in the cert)
                        and dask.config.get("distributed.comm.tls.client.cert", None)):
                    raise CevmError(f"{address}: a tls:// scheduler needs this client's certificates: set "
                                    f"{', '.join(TLS_CLIENT_SETTINGS)} (or the same in Dask's configuration file)")
            try:
                client = distributed.Client(address, timeout=timeout_s, set_as_default=False)
            except (OSError, TimeoutError, ValueError, TypeError) as exc:  # TypeError: a TLS setting missing
                raise CevmError(f"cannot reach the Dask scheduler at {address}: {_error_text(exc)}") from None
        self.client = client
        self.slots = max(1, sum(w.get("nthreads", 1) for w in client.scheduler_info()["workers"].values()))
        self._token = uuid.uuid4().hex[:12]
        self._n_submitted = 0
        self._shared: dict[int, tuple] = {}  # id(arg) -> (arg, future of it), oldest first
        self._n_shared = 0
        # Completed futures and their results arrive here from the client's event loop
        # (no round trip per task, as future.result() or wait() would make).
        self._done = distributed.as_completed(loop=client.loop, with_results=True, raise_errors=False)
        self._results: dict = {}

    def _by_reference(self, arg):
        """``arg`` itself, or for an argument that recurs from task to task (the same
        object: a run's options, the logger profiles, the DSM headers) a future of it,
        made once: the task specs then carry a key instead of the pickled object, which
        the client, the scheduler and each worker would otherwise encode and decode again
        for every task (measured: 0.3 s less client and scheduler CPU over 200 tasks).
        The future is a task that returns the object, so the cluster can make it again
        if every worker holding it dies. Arguments of a task's own (paths, hashes,
        numbers) go by value. Callers must not mutate an argument after submitting it."""
        if arg is None or isinstance(arg, (str, bytes, int, float, os.PathLike)):
            return arg
        hit = self._shared.get(id(arg))
        # (not hit[0] is arg: the id of an object since freed and reused; a cancelled
        # future: the client restarted the cluster)
        if hit is None or hit[0] is not arg or hit[1].status in ("cancelled", "lost", "error"):
            self._n_shared += 1
            fut = self.client.submit(_identity, arg, key=f"shared-{self._token}-{self._n_shared}", pure=False)
            hit = self._shared[id(arg)] = (arg, fut)
            while len(self._shared) > SHARED_ARGS_KEPT:
                self._shared.pop(next(iter(self._shared)))[1].release()
        return hit[1]

    def _submit(self, fn, entry):
        self._n_submitted += 1
        key = f"{getattr(fn, '__name__', 'task')}-{self._token}-{entry.index}-{self._n_submitted}"
        if entry.grouped:
            group = [tuple(self._by_reference(a) for a in t.args) for _, t in entry.items]
            fut = self.client.submit(_execute_group, fn, group, key=key, pure=False, retries=self.max_attempts - 1)
        else:
            args = tuple(self._by_reference(a) for a in entry.task.args)
            fut = self.client.submit(_execute, fn, args, key=key, pure=False, retries=self.max_attempts - 1)
        self._done.add(fut)
        return fut

    def _wait(self, handles):
        done = []
        for fut, result in self._done.next_batch(block=True):
            self._results[fut] = result
            done.append(fut)
        return done

    def _finish(self, handle, entry, st):
        from distributed import KilledWorker

        result = self._results.pop(handle)
        status = handle.status
        handle.release()
        if status == "finished":
            return self._finished(entry, *_unpack(result, entry), st)
        if entry.grouped:  # its workers died (or it could not run): each of its tasks alone, where
            st.alone.extend(entry.singles())  # the scheduler's count of deaths is then the task's own
            return []
        exc = result[1] if isinstance(result, tuple) and len(result) == 3 else result
        if isinstance(exc, KilledWorker):
            return [TaskResult(entry.index, entry.task, attempts=self.max_attempts,
                               error=f"its Dask worker died while running it, on every attempt ({_error_text(exc)})")]
        return [TaskResult(entry.index, entry.task, error=_error_text(exc), attempts=entry.attempts)]

    def _cancel(self, handles):
        self.client.cancel(handles)

    def close(self) -> None:
        for _, fut in self._shared.values():
            fut.release()
        self._shared.clear()
        if self._own:
            self.client.close()


def local_dask_cluster(n_workers: int = 2, threads_per_worker: int = 1, *, processes: bool = True,
                       max_attempts: int = MAX_ATTEMPTS):
    """A :class:`distributed.LocalCluster` on the loopback address with
    ``allowed-failures = max_attempts - 1`` (for tests and benchmarks; close it after).
    ``threads_per_worker`` defaults to 1: the tasks are CPU-bound Python/numpy."""
    import dask
    from distributed import LocalCluster

    with dask.config.set({"distributed.scheduler.allowed-failures": max_attempts - 1,
                          "distributed.worker.profile.enabled": False}):
        return LocalCluster(n_workers=n_workers, threads_per_worker=threads_per_worker, processes=processes,
                            host="127.0.0.1", dashboard_address=None)


def make_executor(workers: int | None = None, scheduler: str | None = None, *,
                  max_attempts: int = MAX_ATTEMPTS) -> Executor:
    """The executor for ``--workers N`` / ``--scheduler ADDRESS``.

    ``scheduler`` set: a :class:`DaskExecutor` on it (``workers`` must then be None).
    ``workers`` 1 gives the :class:`SerialExecutor`, more a :class:`ProcessExecutor` of
    that many. None (the default): up to every core (``os.cpu_count()``), as many as the
    run's work pays for (:meth:`Executor.sized_for`, which callers that know their work
    ask; one that does not gets every core); this process alone for a small run.
    """
    if scheduler is not None:
        if workers is not None:
            raise ValueError("give either a number of local workers or a Dask scheduler, not both")
        return DaskExecutor(scheduler, max_attempts=max_attempts)
    if workers is None:
        cores = os.cpu_count() or 1
        return SerialExecutor() if cores == 1 else ProcessExecutor(cores, max_attempts=max_attempts, auto=True)
    n = int(workers)
    if n < 1:
        raise ValueError(f"workers must be >= 1, got {n}")
    return SerialExecutor() if n == 1 else ProcessExecutor(n, max_attempts=max_attempts)


_forkserver_lifeline()
