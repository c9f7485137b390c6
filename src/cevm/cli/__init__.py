"""The ``cevm`` command line: a thin layer over the library.

Exit codes: 0 success; 1 some inputs of a batch failed (the rest was done);
2 bad usage or bad input (nothing was done); 3 the store could not be written (nothing
was changed); 4 the store is damaged (see :mod:`cevm.cli.common`); 130 after SIGINT and
143 after SIGTERM (:mod:`~cevm.cli.interrupts`). Errors caused by input are printed as
one line on stderr, without a traceback.

This module makes the app and registers the commands of one module per command (group):
:mod:`~cevm.cli.ingest`, :mod:`~cevm.cli.trips`, :mod:`~cevm.cli.calibrate`,
:mod:`~cevm.cli.simulate`, :mod:`~cevm.cli.fleet`, :mod:`~cevm.cli.predict`,
:mod:`~cevm.cli.feasibility`, :mod:`~cevm.cli.replay`, :mod:`~cevm.cli.gtfs`,
:mod:`~cevm.cli.route`, :mod:`~cevm.cli.vehicle`,
:mod:`~cevm.cli.store`; what they share is
:mod:`~cevm.cli.common` and :mod:`~cevm.cli.output`. The command modules never import
this package's app, nor each other; the library never imports the command line.
``app`` (the whole command line) is made on first use; :func:`main` makes one with only
the command it was asked for when its first argument names one (:func:`make_app`): the
other commands' modules are not imported nor their options built, a tenth of a second of
every command's start. For the same reason a command's module imports the library it
runs (pandas, SciPy, the store, matplotlib) inside the command function, not at its top:
``cevm X --help`` and the parsing of its options load none of it.
"""

from __future__ import annotations

import importlib
import signal
import sys
from typing import Annotated

import typer

from cevm import __version__
from cevm.cli.common import exit_code_for, fail
from cevm.cli.paths import guard_app
from cevm.errors import CevmError

#: The commands in the order of 'cevm --help': (name, module in cevm.cli, its command
#: function or its group's Typer app, whether it is a group).
COMMANDS = (
    ("ingest", "ingest", "ingest", False),
    ("trips", "trips", "app", True),
    ("calibrate", "calibrate", "calibrate", False),
    ("simulate", "simulate", "simulate", False),
    ("fleet", "fleet", "app", True),
    ("predict", "predict", "predict_cmd", False),
    ("feasibility", "feasibility", "feasibility_cmd", False),
    ("replay", "replay", "replay_cmd", False),
    ("gtfs", "gtfs", "gtfs_cmd", False),
    ("route", "route", "app", True),
    ("vehicle", "vehicle", "app", True),
    ("store", "store", "app", True),
)


def _version(value: bool) -> None:
    if value:
        typer.echo(f"cevm {__version__}")
        raise typer.Exit()


def _root(
    version: Annotated[
        bool, typer.Option("--version", callback=_version, is_eager=True, help="Print the version and exit.")
    ] = False,
) -> None:
    """cevm: how much diesel or electricity a vehicle uses on a route."""
    _warnings_as_lines()


def _warnings_as_lines() -> None:
    """Print every warning as one ``cevm: warning:`` line (:func:`cevm.runtime.warnings_as_lines`:
    never Python's source file and code line), and the library's input warnings
    (:class:`cevm.io.cycles.CycleWarning`: a file that reads, but probably not as meant)
    every time they occur."""
    import warnings

    from cevm.io.cycles import CycleWarning
    from cevm.runtime import warnings_as_lines

    warnings_as_lines(own=(CycleWarning,))
    warnings.simplefilter("always", CycleWarning)


def _usage_errors_one_line() -> None:
    """A usage error (an option value out of its range, a value that is not a number, an
    unknown option) is one ``cevm: error:`` line and exit 2, as every other error of
    the command line, not click's three lines of usage, hint and error."""
    from cevm.text import one_line

    try:  # typer 0.29 carries its own copy of click
        click_exceptions = importlib.import_module("typer._click.exceptions")
    except ImportError:  # pragma: no cover - an older typer on click itself
        click_exceptions = importlib.import_module("click.exceptions")

    def show(self, file=None) -> None:
        hint = f" (see '{self.ctx.command_path} --help')" if self.ctx is not None else ""
        typer.echo(f"cevm: error: {one_line(self.format_message())}{hint}", err=True)

    click_exceptions.UsageError.show = show


def make_app(only: str | None = None) -> typer.Typer:
    """The ``cevm`` app: every command of :data:`COMMANDS`, or only the one named
    ``only`` (its module alone imported; its help, options and errors are the same)."""
    app = typer.Typer(
        name="cevm",
        help="Vehicle energy and fuel from drive cycles, fast: the computationally efficient (CE) model.",
        no_args_is_help=True,
        add_completion=False,
        pretty_exceptions_enable=False,
        rich_markup_mode=None,  # help texts are plain: "[detailed]", "[kg]", "cevm[dask]" are words, not markup
    )
    app.callback()(_root)
    _usage_errors_one_line()
    for name, module, attr, group in COMMANDS:
        if only is not None and name != only:
            continue
        command = getattr(importlib.import_module(f"cevm.cli.{module}"), attr)
        if group:
            app.add_typer(command, name=name)
        else:
            app.command(name)(command)
    guard_app(app)  # no output onto an input or the store, for every command (cevm.cli.paths)
    return app


def __getattr__(name: str) -> typer.Typer:
    """``app``: the whole command line, made on first use (module ``__getattr__``)."""
    if name == "app":
        app = globals()["app"] = make_app()
        return app
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def main() -> None:
    """Console entry point: the command, then what no command may leave to Python's
    defaults: a stop signal ends every command the same way (one line, 130 or 143:
    :func:`cevm.cli.interrupts.stopped`), and an output or file that cannot be written
    (a full disk, ``> /dev/full``, an I/O error) is one line and exit 3
    (:func:`cevm.cli.common.os_error_exit`), never a traceback, even when it shows only
    as the last flush of stdout."""
    from cevm import stops

    own = not stops.installed()  # called in a process that did not start at cevm.__main__ (a test's)
    saved = {s: signal.getsignal(s) for s in stops.STOP_SIGNALS} if own else {}
    stops.install()  # a signal before the command starts: its line and code (the entry point did this already)
    from cevm.cli import interrupts
    from cevm.cli.common import flush_stdout, os_error_exit
    from cevm.runtime import text_streams_replace, tune_allocator

    text_streams_replace()  # a character the terminal cannot take is escaped, not a UnicodeEncodeError
    tune_allocator()
    first = sys.argv[1] if len(sys.argv) > 1 else None
    app = make_app(first if first in {c[0] for c in COMMANDS} else None)
    with interrupts.interrupts_raise():  # SIGTERM stops a command as SIGINT does
        try:
            said = False
            try:
                app()
                code: int | str | None = 0
            except CevmError as exc:  # a user's mistake that escaped a command: one line, no traceback
                fail(exc)
                code = exit_code_for(exc)
            except SystemExit as exc:
                code = interrupts.stopped(exc, sys.argv[1:])
            except KeyboardInterrupt as exc:  # one that escaped typer's own handling
                code = interrupts.stopped(exc, sys.argv[1:])
            except OSError as exc:  # of the environment (a full disk, an I/O error), not of cevm
                code, said = os_error_exit(exc), True
            code = flush_stdout(code, said=said)
        except KeyboardInterrupt as exc:  # a signal while the above was reporting another end
            code = interrupts.stopped(exc, sys.argv[1:])
    stops.finished()  # a signal from now on: cevm.stops's line, after the work was done
    for s, handler in saved.items():
        signal.signal(s, handler)
    if own:  # called by a test in its own process: it goes on after this
        sys.exit(code)
    stops.exit_now(code)  # the process's end with the handlers in place to the last instant
