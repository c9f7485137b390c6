"""Run a ``cevm`` command that stalls in the middle, for tests that stop it with a real
signal (tests/test_signals.py), kept out of cevm.

``python tests/stall.py MODULE:NAME[.METHOD] MARKER CEVM-ARGS...`` replaces the function
``MODULE.NAME`` (or the method ``NAME.METHOD`` of a class there) with one that, when it is
first called, creates the file MARKER and then waits for ever (a loop of short sleeps, in
which Python runs signal handlers), and runs ``cevm CEVM-ARGS`` (its
:func:`cevm.cli.main`, so the exit code and stderr are the command line's). The command is
then certainly in the middle of its work when the test sees MARKER: its store open, its
worker processes started, its output begun.
"""

from __future__ import annotations

import importlib
import sys
import time
from pathlib import Path


def stall_at(target: str, marker: Path) -> None:
    module_name, _, attr = target.partition(":")
    owner = importlib.import_module(module_name)
    *path, name = attr.split(".")
    for part in path:
        owner = getattr(owner, part)
    real = getattr(owner, name)

    def stalled(*args, **kwargs):
        marker.touch()
        while True:
            time.sleep(0.02)
        return real(*args, **kwargs)  # never reached

    setattr(owner, name, stalled)


def _main(argv: list[str]) -> None:
    target, marker, *args = argv
    stall_at(target, Path(marker))
    from cevm.cli import main

    sys.argv = ["cevm", *args]
    main()


if __name__ == "__main__":
    _main(sys.argv[1:])
