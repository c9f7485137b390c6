"""Tasks on a local process pool (``--workers N``): a
:class:`concurrent.futures.ProcessPoolExecutor` with ``forkserver`` workers, and the
fault isolation that pool lacks.

Worker deaths
    In a :class:`~concurrent.futures.ProcessPoolExecutor` one dead worker breaks the
    whole pool (:class:`~concurrent.futures.process.BrokenProcessPool`): every future
    in it fails, whichever task killed the worker. :class:`ProcessExecutor` recreates
    the pool, resubmits for free the tasks that had not started, and treats the tasks
    that were running as suspects. Each worker writes the index of the task (or group)
    it runs into a shared array, so suspects are known exactly. A lone suspect task is
    charged the death; several suspects (or the tasks of one group) are not (only one of
    them killed its worker, and which is unknown). Every suspect is then re-run
    **alone** in the pool, where a death is its own. A task is failed once it has been
    charged ``max_attempts`` deaths: a task that kills every worker it runs on kills
    ``max_attempts`` of them (one more if its first death was beside another task or in
    a group), and neither a task that ran beside it nor one that killed its worker once,
    beside it, and then ran clean, is blamed.

When a pool pays for itself
    :func:`workers_for` weighs a pool's start (:data:`POOL_START_S`) against the work:
    without ``--workers``, a small batch runs in this process.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor
from concurrent.futures import wait as cf_wait
from concurrent.futures.process import BrokenProcessPool
from typing import Any

from cevm.executors.base import (
    MAX_ATTEMPTS,
    TASK_S,
    Entry,
    Executor,
    RunState,
    TaskResult,
    error_text,
    unpack,
)
from cevm.executors.lifelines import start_forkserver, worker_lifelines
from cevm.executors.serial import SerialExecutor
from cevm.executors.worker import execute, execute_group

WORKER_ENV = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
"""Environment of the local worker processes (where the user has not set these): one
thread per BLAS/OpenMP library, as Dask's nanny sets for its workers. The processes are
the parallelism; BLAS threads of their own oversubscribe the cores, and OpenBLAS's
spin after each call (a matrix product in the timestamp parser of cevm.ingest.timestamps made
two workers slower than one)."""

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

# shared ctypes array (multiprocessing): index of the task (or group) each pool worker runs, -1 when idle
_SLOTS: Any = None
_SLOT = -1


def pool_init(slots, counter, owner_pid: int) -> None:
    """A new worker's initializer: its lifelines, and its slot in the shared array."""
    global _SLOTS, _SLOT
    from cevm.runtime import warnings_as_lines

    warnings_as_lines()  # a warning in a worker is one line on the command's stderr, as in the command
    worker_lifelines(owner_pid)
    with counter.get_lock():
        _SLOT = counter.value % len(slots)
        counter.value += 1
    _SLOTS = slots


def pool_execute(fn: Callable, index: int, payload, grouped: bool):
    """Run a submission in a worker, its index in the worker's slot meanwhile."""
    _SLOTS[_SLOT] = index
    try:
        return execute_group(fn, payload) if grouped else execute(fn, payload)
    finally:
        _SLOTS[_SLOT] = -1


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
        Worker deaths a task may provably cause before it is failed (the module
        docstring says how deaths are attributed).
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
                start_forkserver(WORKER_ENV)
            self._slots_arr = self._ctx.Array("q", [-1] * self.slots, lock=False)
            counter = self._ctx.Value("i", 0)
            self._pool = ProcessPoolExecutor(self.slots, mp_context=self._ctx, initializer=pool_init,
                                             initargs=(self._slots_arr, counter, os.getpid()))
        return self._pool

    def _submit(self, fn, entry):
        try:
            return self._ensure_pool().submit(pool_execute, fn, entry.index, entry.payload(), entry.grouped)
        except BrokenProcessPool as exc:  # broke since the last wait: _finish sorts it out
            fut: Future = Future()
            fut.set_exception(exc)
            return fut

    def _wait(self, handles):
        return cf_wait(handles, return_when=FIRST_COMPLETED).done

    def _finish(self, handle, entry, state):
        exc = handle.exception()
        if isinstance(exc, BrokenProcessPool):
            return self._on_broken(entry, state)
        if exc is not None:  # a lone task raised (a group catches its tasks' exceptions)
            if entry.grouped:
                state.retry.extend(entry.singles())
                return []
            return [TaskResult(entry.index, entry.task, error=error_text(exc), attempts=entry.attempts)]
        return self._finished(entry, *unpack(handle.result(), entry), state)

    def _on_broken(self, first: Entry, state: RunState) -> list[TaskResult]:
        """A worker died: sort the submissions the pool held into done, free to
        resubmit and suspects (running when it broke); recreate the pool lazily."""
        started: set[int] = {int(i) for i in self._slots_arr if i >= 0} if self._slots_arr is not None else set()
        pool, self._pool = self._pool, None
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)  # every future is now done
        self.restarts += 1
        results: list[TaskResult] = []
        victims = [first]
        for h, e in list(state.pending.items()):
            del state.pending[h]
            if h.done() and not h.cancelled() and h.exception() is None:  # finished before the break
                results.extend(self._finished(e, *unpack(h.result(), e), state))
            else:
                victims.append(e)
        suspects = sorted((e for e in victims if e.index in started), key=lambda e: e.index)
        for e in sorted((e for e in victims if e.index not in started), key=lambda e: e.index):
            e.attempts -= 1  # never started: this run does not count
            state.retry.append(e)
        lone = len(suspects) == 1 and not suspects[0].grouped  # then the death is provably its own
        for e in suspects:
            if e.grouped:  # which of its tasks killed the worker is unknown: each runs alone, uncharged
                state.alone.extend(e.singles())
            elif not lone:
                e.attempts -= 1  # not provably its death: run alone, uncharged
                state.alone.append(e)
            elif e.attempts >= self.max_attempts:
                results.append(TaskResult(
                    e.index, e.task, attempts=e.attempts,
                    error=f"its worker process died {e.attempts} times while running it (killed, out of memory "
                          "or crashed in native code)"))
            else:
                state.alone.append(e)  # from now on it runs alone: a death is then its own
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
                with contextlib.suppress(OSError, ValueError):  # gone already
                    p.kill()
        pool.shutdown(wait=True, cancel_futures=True)


