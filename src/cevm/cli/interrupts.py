"""SIGINT and SIGTERM under the command line: both stop a command the same way.

:func:`interrupts_raise` (around every command, in :func:`cevm.cli.main`) makes both
signals raise :class:`Interrupted` in the main thread, a :class:`KeyboardInterrupt`
that knows its signal: the command stops dispatching work, the open store transaction
is finished (:func:`cevm.runtime.signals_deferred`) or rolled back, local workers are
killed, and the exit code is ``128 + the signal's number``: **130** after SIGINT
(Ctrl-C), **143** after SIGTERM (``kill``, systemd, a cron job's timeout), whichever
command it was and however its libraries handle the interrupt (typer turns it into exit
130 without a word: :func:`stopped` puts the signal's code and line back). ``cevm
ingest`` says in one line what it stored and what it did not; every other command says
``cevm COMMAND: interrupted by SIGTERM: ...`` (:func:`stopped_line`). Before the command
starts and after it ends, :mod:`cevm.stops` (installed first by the entry point) says the
same and exits with the same codes.
"""

from __future__ import annotations

import signal
import sys
from collections.abc import Iterator, Sequence
from contextlib import contextmanager

from cevm.stops import EXIT_SIGNAL_BASE, STOP_SIGNALS, command_name, stopped_line

__all__ = ["EXIT_SIGNAL_BASE", "STOP_SIGNALS", "Interrupted", "command_name", "exit_code", "interrupts_raise",
           "late_signals_noted", "received", "signal_name", "stopped", "stopped_line"]

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


def _reported_by_command(exc: BaseException) -> bool:
    """Whether the command itself handled the interrupt and said so (``cevm ingest``:
    it raises its exit code from the interrupt it caught, ``from None``), as opposed to
    typer (which raises exit 130 *from* the KeyboardInterrupt), click ("Aborted!", exit
    1) or nobody (the KeyboardInterrupt itself)."""
    if isinstance(exc, KeyboardInterrupt):
        return False
    for link in (exc, exc.__context__):  # typer calls sys.exit(code) inside its "except Exit"
        if link is None:
            continue
        if isinstance(link.__cause__, KeyboardInterrupt):
            return False  # typer's conversion: "raise Exit(130) from e"
        if isinstance(link.__context__, KeyboardInterrupt) and link.__suppress_context__:
            return True  # the command's own: "raise typer.Exit(code) from None" in its handler
    return getattr(exc, "code", None) not in (1, 130)  # click's "Aborted!" (1), a bare 130


def stopped(exc: BaseException, argv: Sequence[str]) -> int | str | None:
    """The exit code of a command that ended with ``exc`` (SystemExit or an interrupt):
    after a stop signal, ``128 + its number`` (130, 143) and, unless the command said so
    itself, :func:`stopped_line` on stderr; otherwise the command's own code."""
    signum = received()
    code = getattr(exc, "code", None) if isinstance(exc, SystemExit) else EXIT_SIGNAL_BASE + int(
        getattr(exc, "signum", signal.SIGINT))
    if signum is None:
        if isinstance(exc, KeyboardInterrupt):  # an interrupt without the handler (a library's)
            signum = int(getattr(exc, "signum", signal.SIGINT))
        else:
            return code
    if isinstance(exc, SystemExit) and code in (0, None):
        return code  # it finished, the signal came too late to stop it
    if not _reported_by_command(exc):
        try:
            sys.stderr.write(stopped_line(signum, command_name(list(argv))) + "\n")
            sys.stderr.flush()
        except OSError:
            pass
        return EXIT_SIGNAL_BASE + signum
    return code


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
