"""What runs in a worker, whichever executor started it: a task or a group of tasks,
timed, and :func:`worker_cache` for objects a worker opens once for many tasks."""

from __future__ import annotations

import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from typing import Any

from cevm.executors.base import error_text

WORKER_CACHE_SIZE = 4
"""Objects :func:`worker_cache` keeps per worker thread: a run uses one or two (a DSM);
a Dask worker that lives for many runs with other DSMs must not keep every one of them
(a sampler's block cache is up to 256 MB)."""

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
    ``close`` method). (:func:`functools.lru_cache` would keep one cache for every
    thread and not close what it drops.)
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


def tune_once() -> None:
    """The first task in a process applies :func:`cevm.runtime.tune_allocator` there (a
    Dask worker runs its tasks in a thread, whose malloc arena otherwise hands freed
    pages back to the system and faults them in again on the next task: a third of
    Dask's overhead measured)."""
    global _ALLOCATOR_TUNED
    if not _ALLOCATOR_TUNED:
        from cevm.runtime import tune_allocator

        tune_allocator()
        _ALLOCATOR_TUNED = True


def execute(fn: Callable, args: tuple) -> tuple[Any, float]:
    """Run one task in a worker: ``(fn(*args), wall seconds)``."""
    tune_once()
    t0 = time.perf_counter()
    value = fn(*args)
    return value, time.perf_counter() - t0


def execute_group(fn: Callable, group: list[tuple]) -> list[tuple[Any, float, str | None]]:
    """Run a group's tasks one after the other in a worker: per task ``(value, wall
    seconds, None)``, or ``(None, 0, error)`` for one that raised (the caller runs that
    one again alone, so its own failure is what is reported)."""
    tune_once()
    out: list[tuple[Any, float, str | None]] = []
    for args in group:
        t0 = time.perf_counter()
        try:
            value = fn(*args)
        except Exception as exc:
            out.append((None, 0.0, error_text(exc)))
        else:
            out.append((value, time.perf_counter() - t0, None))
    return out
