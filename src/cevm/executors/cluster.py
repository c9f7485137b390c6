"""Tasks on a Dask distributed cluster (``--scheduler ADDRESS``, ``pip install
cevm[dask]``): a :class:`distributed.Client`; the scheduler places tasks, results come
back to the client.

Worker deaths
    The scheduler handles them itself: a dead worker's tasks are rescheduled, and a task
    that was on ``distributed.scheduler.allowed-failures + 1`` dead workers fails with
    ``KilledWorker``. It charges a death to every task the dead worker held, so a group
    that fails so is split into its tasks, which then run alone (a task that ran beside
    a killer could otherwise be failed with it). :func:`local_dask_cluster` sets
    ``allowed-failures = max_attempts - 1``; start a remote scheduler with
    ``DASK_DISTRIBUTED__SCHEDULER__ALLOWED_FAILURES=1`` for the same rule. Exceptions
    raised by a task are retried ``max_attempts - 1`` times (Dask's ``retries``).
"""

from __future__ import annotations

import contextlib
import os
import uuid
from typing import Any

from cevm.errors import CevmError
from cevm.executors.base import (
    MAX_ATTEMPTS,
    TASK_S,
    Executor,
    TaskResult,
    error_text,
    unpack,
)
from cevm.executors.worker import execute, execute_group

#: Recurring task arguments a :class:`DaskExecutor` keeps on the cluster (oldest dropped).
SHARED_ARGS_KEPT = 16

#: The environment variables that give a client its TLS certificates (Dask's configuration).
TLS_CLIENT_SETTINGS = ("DASK_DISTRIBUTED__COMM__TLS__CA_FILE", "DASK_DISTRIBUTED__COMM__TLS__CLIENT__CERT",
                       "DASK_DISTRIBUTED__COMM__TLS__CLIENT__KEY")

DASK_CONNECT_TIMEOUT_S = 20.0
"""How long :class:`DaskExecutor` waits for a scheduler [s] before giving up: a scheduler
on a LAN answers in milliseconds; 20 s allows for one starting up."""


def identity(obj: Any) -> Any:
    """A task that returns its argument: how a recurring argument is put on a cluster."""
    return obj


class DaskExecutor(Executor):
    """Tasks on a Dask distributed cluster (``pip install cevm[dask]``).

    Work travels to the workers as pickles, and unpickling can run any code: whoever can
    reach the scheduler can run code as the workers (and in this client, through the
    results). Run the cluster on a private network, or with TLS (a ``tls://`` address;
    this client's certificates from Dask's configuration, :data:`TLS_CLIENT_SETTINGS`):
    docs/guide/cluster.md.

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
        deaths are counted by the scheduler (``allowed-failures``: the module
        docstring).
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
                client = _client_class(distributed)(address, timeout=timeout_s, set_as_default=False)
            except (OSError, TimeoutError, ValueError, TypeError) as exc:  # TypeError: a TLS setting missing
                raise CevmError(f"cannot reach the Dask scheduler at {address}: {error_text(exc)}") from None
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
            fut = self.client.submit(identity, arg, key=f"shared-{self._token}-{self._n_shared}", pure=False)
            hit = self._shared[id(arg)] = (arg, fut)
            while len(self._shared) > SHARED_ARGS_KEPT:
                self._shared.pop(next(iter(self._shared)))[1].release()
        return hit[1]

    def _submit(self, fn, entry):
        self._n_submitted += 1
        key = f"{getattr(fn, '__name__', 'task')}-{self._token}-{entry.index}-{self._n_submitted}"
        if entry.grouped:
            group = [tuple(self._by_reference(a) for a in t.args) for _, t in entry.items]
            fut = self.client.submit(execute_group, fn, group, key=key, pure=False, retries=self.max_attempts - 1)
        else:
            args = tuple(self._by_reference(a) for a in entry.task.args)
            fut = self.client.submit(execute, fn, args, key=key, pure=False, retries=self.max_attempts - 1)
        self._done.add(fut)
        return fut

    def _wait(self, handles):
        done = []
        for fut, result in self._done.next_batch(block=True):
            self._results[fut] = result
            done.append(fut)
        return done

    def _finish(self, handle, entry, state):
        from distributed import KilledWorker

        result = self._results.pop(handle)
        status = handle.status
        handle.release()
        if status == "finished":
            return self._finished(entry, *unpack(result, entry), state)
        if entry.grouped:  # its workers died (or it could not run): each of its tasks alone, where
            state.alone.extend(entry.singles())  # the scheduler's count of deaths is then the task's own
            return []
        exc = result[1] if isinstance(result, tuple) and len(result) == 3 else result
        if isinstance(exc, KilledWorker):
            return [TaskResult(entry.index, entry.task, attempts=self.max_attempts,
                               error=f"its Dask worker died while running it, on every attempt ({error_text(exc)})")]
        return [TaskResult(entry.index, entry.task, error=error_text(exc), attempts=entry.attempts)]

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


def _client_class(distributed: Any) -> Any:
    """``distributed.Client``, but one whose failed start leaves nothing to close.

    A client that cannot reach its scheduler (an unknown scheme, a refused or timed-out
    connection) raises from its constructor, and the half-made object closes itself when it
    is collected, at the latest when the interpreter exits: waiting 40 s on an event loop
    that will never answer, then printing a TimeoutError traceback, after cevm had already
    said the one line and chosen its exit code. Here the failed start stops the client's
    loop at once and leaves ``__del__`` nothing to do."""

    class Client(distributed.Client):
        def start(self, **kwargs):
            try:
                return super().start(**kwargs)
            except BaseException:
                self._Client__loop = None  # Client.__del__ closes only a client with a loop
                with contextlib.suppress(Exception):  # a loop that never ran: nothing to stop
                    self._loop_runner.stop()
                raise

    return Client
