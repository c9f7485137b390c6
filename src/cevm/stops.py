"""Stop signals from a command's first instant to its last, before the command line is
even imported.

The command line's own handling (:mod:`cevm.cli.interrupts`) starts only once its
modules are imported and the command is chosen (0.1-0.8 s: typer, numpy, pandas), and
it ends when the command returns. Outside that window SIGTERM killed the process without
a word (status -15) and SIGINT printed a KeyboardInterrupt traceback. :func:`install`,
the first thing the entry point does (``cevm``, ``python -m cevm``:
:mod:`cevm.__main__`), closes both ends: a stop signal before the command starts or
after it has finished prints the one line every command prints (:func:`stopped_line`)
and exits with the documented code, 130 after SIGINT and 143 after SIGTERM, at once
(nothing has begun, or everything is done and flushed). Between the two, the command
line's handlers replace these and put them back when the command ends.

Before this module runs, only the interpreter's own start (about 20 ms: its encodings,
``site`` and the ``cevm`` package) has no handler: there SIGTERM ends the process
with status -15 and SIGINT with a KeyboardInterrupt, as for any Python program. So that
the window stays that short, this module imports nothing beyond what the interpreter has
already loaded (``os``, ``sys``) and the C module ``_signal`` (``signal`` would import
``enum``, ``functools`` and ``collections``: 10-15 ms).
"""

from __future__ import annotations

import _signal  # type: ignore[import-not-found]  # the C module behind signal (no stubs)
import os
import sys

#: The exit code after a signal is this plus its number (the shells' convention).
EXIT_SIGNAL_BASE = 128

#: Signals that stop a command, and their names.
SIGNAL_NAMES = {int(_signal.SIGINT): "SIGINT", int(_signal.SIGTERM): "SIGTERM"}
STOP_SIGNALS = tuple(SIGNAL_NAMES)

#: The command groups, whose second word names the command (``cevm route add``).
GROUPS = ("trips", "route", "store", "fleet", "vehicle", "gtfs")

#: Whether the command has finished (:func:`finished`): the line then says so.
_finished = False


def command_name(argv: list[str] | tuple[str, ...]) -> str:
    """The command's words from the arguments: ``calibrate``, ``trips set-mass``,
    ``route add`` (a group's first word, and its subcommand when one follows)."""
    words = [a for a in argv[:2] if not a.startswith("-")]
    if words and words[0] in GROUPS and len(argv) > 1 and words[1:]:
        return " ".join(words[:2])
    return words[0] if words else ""


def stopped_line(signum: int, command: str) -> str:
    """The line a command (other than ingest, which says what it stored) prints when a
    stop signal ended it."""
    name = SIGNAL_NAMES.get(signum, f"signal {signum}")
    return (f"cevm {command}: interrupted by {name}: stopped before the end (each write to the store is made whole "
            "or not at all; no --out file is left half-written; output on stdout may be cut short)").replace(
        "cevm :", "cevm:")


def finished_line(signum: int, command: str) -> str:
    """The line for a stop signal that arrived once the command had finished."""
    return (f"cevm {command}: interrupted by {SIGNAL_NAMES.get(signum, signum)} as it exited, after its end (what it "
            "wrote and said stands)").replace("cevm :", "cevm:")


def _stop_now(signum: int, frame) -> None:
    """The handler outside the command: the line, and the exit code, at once (written
    to the file descriptor: Python's stderr may be in the middle of a write)."""
    command = command_name(sys.argv[1:])
    line = finished_line(signum, command) if _finished else stopped_line(signum, command)
    try:  # noqa: SIM105 (contextlib.suppress would import collections and functools, see the module's notes)
        os.write(2, (line + "\n").encode("utf-8", "replace"))
    except OSError:
        pass
    os._exit(EXIT_SIGNAL_BASE + signum)


def install() -> None:
    """SIGINT and SIGTERM end the process with their line and code (:func:`_stop_now`);
    main thread only (elsewhere nothing changes). The command has not finished yet."""
    global _finished
    _finished = False
    try:
        for s in STOP_SIGNALS:
            _signal.signal(s, _stop_now)
    except ValueError:  # not the main thread
        pass


def installed() -> bool:
    """Whether :func:`install`'s handlers are the ones in place."""
    return all(_signal.getsignal(s) is _stop_now for s in STOP_SIGNALS)


def finished() -> None:
    """The command has finished: a stop signal from now on says so."""
    global _finished
    _finished = True


def exit_now(code: int | str | None) -> None:
    """End the process as ``sys.exit(code)`` would, with :func:`install`'s handlers in
    place to its last instant: the exit handlers run (``atexit``: multiprocessing's, which
    remove the pool's semaphores, those of temporary files), the standard streams are
    flushed, then ``os._exit``. Python's own end would run its exit handlers too, but then
    put the default handlers back before the process ends: a signal in those last
    milliseconds ended it with status -2 or -15 and no word."""
    import atexit

    if isinstance(code, str):  # sys.exit's convention: the text on stderr, status 1
        try:  # noqa: SIM105 (see the module's notes)
            sys.stderr.write(code + "\n")
        except (OSError, ValueError):
            pass
        code = 1
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:  # noqa: SIM105 (see the module's notes)
            stream.flush()
        except (OSError, ValueError, AttributeError):
            pass
    os._exit(0 if code is None else int(code))

