"""SIGINT and SIGTERM under the command line: both stop a command the same way.

:func:`interrupts_raise` (around every command, in :func:`cevm.cli.main`) makes both
signals raise :class:`Interrupted` in the main thread, a :class:`KeyboardInterrupt`
that knows its signal: the command stops dispatching work, the open store transaction
is finished (:func:`cevm.runtime.signals_deferred`) or rolled back, local workers are
killed, and the exit code is ``128 + the signal's number``: **130** after SIGINT
(Ctrl-C), **143** after SIGTERM (``kill``, systemd, a cron job's timeout). ``cevm
ingest`` says in one line what it stored and what it did not; other commands say
"Aborted!".
"""

from __future__ import annotations

import signal
from collections.abc import Iterator
from contextlib import contextmanager

#: The exit code after a signal is this plus its number (the shells' convention).
EXIT_SIGNAL_BASE = 128

#: Signals that stop a command.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)

_received: list[int] = []


class Interrupted(KeyboardInterrupt):
    """A stop signal arrived (``signum``: SIGINT or SIGTERM)."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = int(signum)


def signal_name(exc: BaseException) -> str:
    """``SIGINT`` or ``SIGTERM``: the signal behind an interrupt (a bare
    KeyboardInterrupt is SIGINT's)."""
    return signal.Signals(getattr(exc, "signum", signal.SIGINT)).name


def exit_code(exc: BaseException) -> int:
    """The documented exit code after an interrupt: 130 (SIGINT), 143 (SIGTERM)."""
    return EXIT_SIGNAL_BASE + int(getattr(exc, "signum", signal.SIGINT))


def received() -> int | None:
    """The first stop signal received under :func:`interrupts_raise`, or None."""
    return _received[0] if _received else None


def _raise(signum: int, frame) -> None:
    _received.append(signum)
    raise Interrupted(signum)


@contextmanager
def interrupts_raise() -> Iterator[None]:
    """SIGINT and SIGTERM raise :class:`Interrupted` within the block (main thread
    only; elsewhere nothing changes); the previous handlers come back after it."""
    try:
        saved = {s: signal.signal(s, _raise) for s in STOP_SIGNALS}
    except ValueError:  # not the main thread
        yield
        return
    _received.clear()
    try:
        yield
    finally:
        for s, handler in saved.items():
            signal.signal(s, handler)


@contextmanager
def late_signals_noted() -> Iterator[list[int]]:
    """Within the block, in the main thread, SIGINT and SIGTERM are only noted in the list
    yielded (in the order they arrive), not raised: for a command whose work is finished
    and stored, so that a late signal neither cuts its report nor turns its exit code
    into an interrupted run's (the command says that it arrived). The handlers before
    the block come back after it."""
    noted: list[int] = []
    try:
        saved = {s: signal.signal(s, lambda signum, frame: noted.append(signum)) for s in STOP_SIGNALS}
    except ValueError:  # not the main thread
        yield noted
        return
    try:
        yield noted
    finally:
        for s, handler in saved.items():
            signal.signal(s, handler)
