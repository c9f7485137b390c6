"""What every executor shares: the :class:`Task` and :class:`TaskResult` values, and
:class:`Executor`, whose :meth:`~Executor.run` is the driver (cevm's own scheduling:
input order, the window, groups of small tasks, reruns) over each executor's
submit / wait / finish hooks."""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Callable, Generator, Iterable, Iterator
from dataclasses import dataclass
from typing import Any

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


# --------------------------------------------------------------------------- values


@dataclass(frozen=True)
class Task:
    """One unit of work: ``fn(*args)`` for the run's task function ``fn``. ``key``
    names it in messages (for ingest: the file path); ``args`` must pickle.
    ``cost_s``: its estimated work [s on one core], if known; a parallel executor then
    groups it with its neighbours into a task of about ``task_s`` (see
    :mod:`cevm.executors`). None: it always goes alone."""

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


def error_text(exc: BaseException) -> str:
    """``"ExceptionType: first line of its message"``: how a task's failure is reported."""
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0]}" if text else type(exc).__name__


# ---------------------------------------------------------------------------- driver


@dataclass(eq=False)
class Entry:
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

    def singles(self) -> list[Entry]:
        """Each task of a group alone, its run in the group not counted."""
        return [Entry([it], self.attempts - 1) for it in self.items]


def unpack(result, entry: Entry) -> tuple[Any, float]:
    """``(value, seconds)`` of a finished submission: a group returns its list."""
    return (result, 0.0) if entry.grouped else result


class RunState:
    """One call of :meth:`Executor.run`: the items taken and not yet yielded, what is in
    flight, and what is to be submitted again.

    The hooks see ``pending`` (handle -> :class:`Entry`), ``retry`` (entries to
    resubmit, in any company) and ``alone`` (entries to resubmit with nothing else
    running, where a worker's death is provably theirs)."""

    def __init__(self, executor: Executor, fn: Callable, items: Iterable, window: int):
        self.executor = executor
        self.fn = fn
        self.window = window
        self.target = 0.0 if executor.inline else float(executor.task_s)
        self.source = enumerate(items)
        self.exhausted = False
        self.pending: dict = {}
        self.retry: deque = deque()
        self.alone: deque = deque()
        self.ready: dict[int, TaskResult] = {}  # results not yet yielded, by index
        self.weight: dict[int, float] = {}  # window share of each item taken and not yet yielded
        self.load = 0.0
        self.group: list = []  # tasks gathered for the next group, and their work [s]
        self.group_s = 0.0
        self.next_out = 0

    @property
    def finished(self) -> bool:
        return self.exhausted and not self.pending and not self.retry and not self.alone

    def put(self, entry: Entry) -> None:
        entry.attempts += 1
        self.executor.submitted += 1
        self.pending[self.executor._submit(self.fn, entry)] = entry

    def flush(self) -> None:
        """Submit the group gathered so far, if any."""
        if self.group:
            self.put(Entry(self.group))
            self.group, self.group_s = [], 0.0

    def take(self, i: int, item: Any) -> None:
        """Item ``i`` of the input: passed through, gathered into a group, or submitted."""
        least = 1.0 / MAX_GROUP
        if not isinstance(item, Task):
            self.weight[i] = least
            self.ready[i] = TaskResult(i, None, value=item)
        elif self.target > 0 and item.cost_s is not None and item.cost_s < self.target:
            self.weight[i] = max(least, item.cost_s / self.target)
            self.group.append((i, item))
            self.group_s += item.cost_s
            if self.group_s >= self.target or len(self.group) >= MAX_GROUP:
                self.flush()
        else:
            self.weight[i] = 1.0
            self.flush()
            self.put(Entry([(i, item)]))
        self.load += self.weight[i]

    def submit(self) -> Iterator[TaskResult]:
        """Submit what may run now: a task to run alone once nothing else runs; else the
        reruns, then new items while the window has room (yielding the results that are
        next in order meanwhile, so the caller's work to make an item overlaps the
        tasks)."""
        if self.alone:
            if not self.pending:
                self.put(self.alone.popleft())
            return
        while self.retry:
            self.put(self.retry.popleft())
        while not self.exhausted and not self.alone and self.load < self.window:
            try:
                i, item = next(self.source)
            except StopIteration:
                self.exhausted = True
                break
            self.take(i, item)
            yield from self.release()
        self.flush()

    def release(self) -> Iterator[TaskResult]:
        """Yield the results that are next in input order."""
        while self.next_out in self.ready:
            self.load -= self.weight.pop(self.next_out)
            yield self.ready.pop(self.next_out)
            self.next_out += 1

    def collect(self) -> None:
        """Wait for at least one submission to end; keep the results it made final."""
        ex = self.executor
        for h in list(ex._wait(list(self.pending))):
            entry = self.pending.pop(h, None)
            if entry is None:  # handled with an earlier one (a broken pool)
                continue
            for res in ex._finish(h, entry, self):
                self.ready[res.index] = res


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
    def _submit(self, fn: Callable, entry: Entry):
        """Start ``fn`` on ``entry``'s task (or group); return a handle."""

    @abstractmethod
    def _wait(self, handles: list) -> Iterable:
        """The handles that are done, waiting for at least one."""

    @abstractmethod
    def _finish(self, handle, entry: Entry, state: RunState) -> list[TaskResult]:
        """Results made final by ``handle`` being done (none if it was resubmitted)."""

    def _cancel(self, handles: list) -> None:
        for h in handles:
            h.cancel()

    # ---- shared by the hooks ----------------------------------------------------------

    @staticmethod
    def _finished(entry: Entry, value, seconds: float, state: RunState) -> list[TaskResult]:
        """The results of a finished submission: a task's, or a group's (a task that
        raised in its group goes to run again alone)."""
        if not entry.grouped:
            return [TaskResult(entry.index, entry.task, value=value, attempts=entry.attempts, seconds=seconds)]
        out = []
        for (i, task), (v, s, error), single in zip(entry.items, value, entry.singles(), strict=True):
            if error is None:
                out.append(TaskResult(i, task, value=v, attempts=entry.attempts, seconds=s))
            else:
                state.retry.append(single)
        return out

    # ---- the driver -------------------------------------------------------------------

    def run(self, fn: Callable, items: Iterable, *, window: int | None = None) -> Generator[TaskResult, None, None]:
        """Run ``fn(*task.args)`` for every :class:`Task` in ``items``; yield one
        :class:`TaskResult` per item, in input order.

        ``items`` is consumed lazily, at most ``window`` tasks' worth ahead of the last
        one yielded (default: :data:`WINDOW_PER_SLOT` per slot, at least
        :data:`MIN_WINDOW`; 1 for a serial executor, which runs a task as it is
        submitted), so work the caller does to make an item (hashing a file) overlaps
        the running tasks. Consecutive tasks with a ``cost_s`` below :attr:`task_s` are
        submitted together (:mod:`cevm.executors`). ``fn`` must be a module-level
        function (workers import it by name). Closing the generator (breaking out of the
        loop, an exception in it) cancels the tasks not yet started.
        """
        if window is None:
            window = 1 if self.inline else max(MIN_WINDOW, WINDOW_PER_SLOT * self.slots)
        state = RunState(self, fn, items, max(1, int(window)))
        try:
            while True:
                yield from state.submit()
                yield from state.release()
                if not state.pending:
                    if state.finished:
                        break
                    continue
                state.collect()
        finally:
            if state.pending:
                self._cancel(list(state.pending))

    def sized_for(self, work_s: float, n_tasks: int) -> Executor:
        """The executor to run ``n_tasks`` tasks of ``work_s`` estimated seconds of work
        in all on: this one (an executor chosen by the user), or for the default one
        (:func:`~cevm.executors.make_executor` without a number of workers) one that
        pays for itself."""
        return self

    def close(self) -> None:  # noqa: B027 (a no-op by default, not abstract: the serial executor holds nothing)
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
