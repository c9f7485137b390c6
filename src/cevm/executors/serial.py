"""The executor of ``--workers 1``: each task inline in the calling thread."""

from __future__ import annotations

import time
from concurrent.futures import Future

from cevm.executors.base import Executor, TaskResult, error_text


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

    def _finish(self, handle, entry, state):
        exc = handle.exception()
        if exc is not None:
            return [TaskResult(entry.index, entry.task, error=error_text(exc), attempts=entry.attempts)]
        value, seconds = handle.result()
        return self._finished(entry, value, seconds, state)
