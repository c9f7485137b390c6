"""How local worker processes start and end: the forkserver that forks them, and the
lifelines that end them with the process that made their pool, whatever ended it (a
``kill -9`` too).

On Linux the forkserver and each worker ask the kernel for SIGKILL when their parent
dies (``prctl(PR_SET_PDEATHSIG)``), and each worker also watches the pool's owner
itself (a thread that waits on a pidfd of it, or polls it where there is none), as the
owner need not be its parent. Workers ignore SIGINT: a Ctrl-C in a terminal reaches the
whole process group, and the owner decides (it kills its workers on the way out).

Importing this module (the forkserver preloads :mod:`cevm.executors`) is what gives a
forkserver its lifeline: :func:`forkserver_lifeline` runs at import and does nothing in
any other process.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
from collections.abc import Mapping

WATCHDOG_POLL_S = 1.0
"""How often a worker without a pidfd (not Linux) checks that its pool's owner lives [s]."""

#: Environment variable that hands the forkserver the pid of the process it must not
#: outlive (set only while the forkserver starts; read once, by the forkserver).
FORKSERVER_PARENT_ENV = "CEVM_FORKSERVER_PARENT"

_PR_SET_PDEATHSIG = 1  # linux/prctl.h


def set_parent_death_signal(sig: int = signal.SIGKILL) -> bool:
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


def watch_owner(owner_pid: int) -> None:
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

        assert fd is not None  # run only when the pidfd opened
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


def worker_lifelines(owner_pid: int) -> None:
    """In a new pool worker: ignore SIGINT, die with the forkserver that forked it and
    with ``owner_pid``, the pool's owner."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the owner handles a Ctrl-C, and ends us
    parent = os.getppid()
    if set_parent_death_signal() and os.getppid() != parent:
        os._exit(1)  # our parent (the forkserver) died before the request took effect
    watch_owner(owner_pid)  # the pool's owner, which may not be our parent


def start_forkserver(env: Mapping[str, str]) -> None:
    """Start this process's forkserver (if not running) with ``env`` added to its
    environment where the user has not set those variables: its preload imports numpy,
    whose BLAS reads the thread count then, and the workers it forks inherit that.
    Started from the main thread, it also learns this process's pid
    (:func:`forkserver_lifeline`: it dies with it). Not from another thread: Linux's
    parent-death signal follows the thread that forks, which may end long before this
    process (the workers still watch this process themselves). This process's own
    environment is left as it was."""
    from multiprocessing import forkserver, resource_tracker

    env = dict(env)
    if threading.current_thread() is threading.main_thread():
        env[FORKSERVER_PARENT_ENV] = str(os.getpid())
    saved = {k: os.environ.get(k) for k in env}
    # SIGINT blocked while the forkserver is made: it starts with it blocked (the mask is
    # inherited across fork and exec), so that a Ctrl-C during its preload (a second or
    # so: numpy, rasterio, pyproj) cannot print a KeyboardInterrupt traceback of its own
    # before it ignores SIGINT; here (in this thread) a Ctrl-C only waits for the block to end.
    # The resource tracker first: starting it unblocks SIGINT whatever the mask was.
    resource_tracker.ensure_running()
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT}) if hasattr(signal, "pthread_sigmask") else None
    try:
        for k, v in env.items():
            if k == FORKSERVER_PARENT_ENV:
                os.environ[k] = v
            else:
                os.environ.setdefault(k, v)
        forkserver.ensure_running()
    finally:
        if mask is not None:
            signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        for k, old in saved.items():
            if old is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = old


def owner_gone(owner_pid: int) -> bool:
    """Whether process ``owner_pid`` has ended (gone, or a zombie not yet reaped)."""
    try:
        os.kill(owner_pid, 0)
    except ProcessLookupError:
        return True
    except PermissionError:  # alive, another user's (its pid reused)
        return False
    try:
        with open(f"/proc/{owner_pid}/stat", "rb") as fh:
            stat = fh.read()
        return stat[stat.rindex(b")") + 2:][:1] in (b"Z", b"X")
    except (OSError, ValueError):
        return False


def quiet_when_orphaned(owner_pid: int) -> None:
    """In the forkserver (and the workers it forks, which inherit it): an exception that
    ends a process after the pool's owner has ended prints nothing. A worker forked as
    the owner stops on a signal fails to rebuild the pool's semaphores, which the owner
    has removed (``FileNotFoundError`` in ``SemLock``), and multiprocessing prints that
    through ``sys.excepthook``: beside the owner's one line, a traceback that is no
    failure of anyone's. So is that error itself, which arrives as the owner ends, before
    it has ended. Other exceptions print as before while the owner lives (a worker that
    fails to start is also reported by the owner's pool, as a broken pool)."""
    default = sys.excepthook

    def hook(exc_type, exc, tb) -> None:
        if owner_gone(owner_pid) or issubclass(exc_type, (FileNotFoundError, KeyboardInterrupt)):
            return  # a semaphore already removed: the owner is ending (it may not have ended yet)
        default(exc_type, exc, tb)

    sys.excepthook = hook


def forkserver_lifeline() -> None:
    """In the forkserver that :func:`start_forkserver` started (it imports this module
    first): die with the process that started it, as its workers die with it. Does
    nothing in any other process."""
    want = os.environ.get(FORKSERVER_PARENT_ENV)
    if want and want == str(os.getppid()):
        quiet_when_orphaned(int(want))
        if not set_parent_death_signal():
            watch_owner(int(want))
        elif os.getppid() != int(want):  # it died before the request took effect
            os._exit(1)


forkserver_lifeline()
