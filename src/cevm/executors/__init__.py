"""Run one task function over many inputs: in this process, on a local process pool, or
on a Dask distributed cluster, with one driver and the same results.

The caller (e.g. :func:`cevm.ingest.ingest`, the store's single writer, or
:func:`cevm.core.sweep.sweep`) gives a task function and an iterable of :class:`Task`
items (``fn(*task.args)`` is one unit of work, such as one log file) and consumes
:class:`TaskResult` objects **in input order**, while the tasks run elsewhere. Items
that are not a :class:`Task` pass through unchanged (as results with ``attempts ==
0``), so a caller can mix work it resolved itself (an unchanged file) with work to do
and still see everything in order.

Executors, and :func:`make_executor`, which picks one from ``--workers`` /
``--scheduler``:

* :class:`SerialExecutor` (:mod:`~cevm.executors.serial`): runs each task inline, one
  at a time (``--workers 1``).
* :class:`ProcessExecutor` (:mod:`~cevm.executors.pool`): a
  :class:`concurrent.futures.ProcessPoolExecutor` with ``forkserver`` workers (no fork
  of a process with threads), whose lifetime :mod:`~cevm.executors.lifelines` ties to
  the process that made the pool.
* :class:`DaskExecutor` (:mod:`~cevm.executors.cluster`): a :class:`distributed.Client`
  (``pip install cevm[dask]``); Dask's scheduler places the tasks.

What is the libraries', what is cevm's own
    The libraries run the tasks: the process pool's workers, Dask's scheduler and
    workers (placement, retries of a task that raised, rescheduling a dead worker's
    tasks). Above them, :meth:`Executor.run` (:mod:`~cevm.executors.base`) is a small
    scheduler of cevm's own, for four things neither library does:

    - **Input order from a lazy input, in a bounded window.** Results are yielded in
      input order whatever the completion order, so a caller that writes them as they
      come writes exactly what a serial run writes. The input is consumed lazily: at
      most ``window`` tasks' worth of items (default: four per worker slot, at least
      32) are in flight or waiting for an earlier one, which bounds memory whatever the
      number of items (an item counts as a whole task unless it has a cost, then as its
      share of ``task_s``, at least ``1 / MAX_GROUP``). ``Executor.map`` submits every
      item at once (before Python 3.14) and ``as_completed`` yields in completion
      order.
    - **Tasks sized by work.** A submitted task costs a fixed amount whatever its work:
      a Dask task 7-10 ms of CPU here (its scheduler, client and worker event loops), a
      pool task 2-3 ms of pickling and pipes. Ingest files of 25-30 ms each, one per
      task, ran 22-82 % slower on a local Dask cluster than on the pool; in groups of
      about 0.1 s of work, 2-4 % (``benchmarks/bench_ingest_parallel.py``;
      docs/guide/cluster.md). So a :class:`Task` may say what it costs
      (``cost_s``: estimated seconds of work on one core), and a parallel executor
      submits consecutive small tasks together, as one **group** of about ``task_s``
      seconds (default :data:`TASK_S`; at most :data:`MAX_GROUP` tasks). A group runs
      its tasks one after the other in one worker and returns each one's result;
      results are still yielded one per task, in input order. Tasks without a cost (or
      costing ``task_s`` or more) go alone.
    - **Fault isolation in a process pool.** One dead worker breaks a whole
      ``ProcessPoolExecutor``; :class:`ProcessExecutor` finds which tasks were running,
      recreates the pool and charges the death only to a task that provably caused it
      (:mod:`~cevm.executors.pool`). On Dask the scheduler counts deaths itself
      (:mod:`~cevm.executors.cluster`).
    - **Groups split on failure.** A task that raises inside a group is run again
      alone (so what it reports is what it reports alone), and a group whose worker
      died is split: each of its tasks is run again alone, uncharged. A task whose
      worker dies ``max_attempts`` times (default 2) that are provably its own is
      reported as a failed result (``error`` set), never silently dropped.

Worker lifetime
    Local workers end with the process that made the pool, whatever ended it (a
    ``kill -9`` too), and ignore SIGINT (:mod:`~cevm.executors.lifelines`); closing an
    executor while an exception propagates (an interrupt) kills its workers instead of
    waiting for their tasks.

Worker resources
    :func:`worker_cache` keeps objects that are costly to open (a DSM sampler) once per
    worker process and thread, keyed by what they were opened from
    (:mod:`~cevm.executors.worker`).
"""

from __future__ import annotations

import os

from cevm.executors.base import (
    MAX_ATTEMPTS,
    MAX_GROUP,
    MIN_WINDOW,
    TASK_S,
    WINDOW_PER_SLOT,
    Executor,
    Task,
    TaskResult,
)
from cevm.executors.cluster import (
    DASK_CONNECT_TIMEOUT_S,
    SHARED_ARGS_KEPT,
    TLS_CLIENT_SETTINGS,
    DaskExecutor,
    local_dask_cluster,
)
from cevm.executors.lifelines import WATCHDOG_POLL_S
from cevm.executors.pool import (
    PARALLEL_EFFICIENCY,
    POOL_START_S,
    WORKER_ENV,
    ProcessExecutor,
    workers_for,
)
from cevm.executors.serial import SerialExecutor
from cevm.executors.worker import WORKER_CACHE_SIZE, worker_cache

__all__ = [
    "DASK_CONNECT_TIMEOUT_S",
    "MAX_ATTEMPTS",
    "MAX_GROUP",
    "MIN_WINDOW",
    "PARALLEL_EFFICIENCY",
    "POOL_START_S",
    "SHARED_ARGS_KEPT",
    "TASK_S",
    "TLS_CLIENT_SETTINGS",
    "WATCHDOG_POLL_S",
    "WINDOW_PER_SLOT",
    "WORKER_CACHE_SIZE",
    "WORKER_ENV",
    "DaskExecutor",
    "Executor",
    "ProcessExecutor",
    "SerialExecutor",
    "Task",
    "TaskResult",
    "local_dask_cluster",
    "make_executor",
    "worker_cache",
    "workers_for",
]


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
