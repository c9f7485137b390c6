"""Fault injection for the tests, kept out of cevm: task functions that wrap the real ones,
a command-line entry point that installs them in a subprocess, and a /proc scan.

Faults are described by marker files, which every worker sees (a worker's memory and
environment are not the test's: a forkserver keeps the environment it started with):

- ``sleep_or_die(marker_dir, name, seconds)``: a task that dies (``os._exit(1)``, as a
  process killed mid-task) if ``marker_dir`` holds a file ``<anything>.<name>``, which
  it renames to ``done-<pid>-<file>`` first (atomically: one worker wins; each marker
  kills one worker once); else it sleeps.
- ``process_file_or_die(path, ...)``: :func:`cevm.ingest.task.process_file`, but a file
  ``<log path>.kill-<k>`` beside the log kills its worker once (renamed to
  ``<log path>.killed-<k>-<pid>``), and a file ``<log path>.hold`` makes the task write
  ``<log path>.held-<pid>`` and wait forever. (Directories are searched for ``*.csv``
  and ``*.csv.gz``: the markers are never taken for logs.)

``python tests/faults.py [--task-s S] [--stall-write NAME] [--hold-after-ingest] [--hold-after-summary]
CEVM-ARGS...`` runs the
``cevm`` command (its :func:`cevm.cli.main`) with ``process_file_or_die`` as the
ingest task; ``--task-s`` sets the local pool's task size, ``--stall-write NAME``
stalls the store transaction of the log named NAME for a second (after writing
``<store>.in-transaction``); ``--hold-after-ingest`` holds ``cevm ingest`` for 3 s once
every file is stored, before its manifest is applied (after writing ``<store>.ingested``);
``--hold-after-summary`` for 3 s once its summary is printed (after writing
``<store>.summarised``).
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path


def _take_marker(marker: Path, taken: Path) -> bool:
    try:
        os.rename(marker, taken)
    except OSError:
        return False  # another worker took it
    return True


def sleep_or_die(marker_dir: str, name: str, seconds: float) -> float:
    for entry in sorted(os.listdir(marker_dir)):
        if entry.startswith("done-") or entry.partition(".")[2] != name:
            continue
        if _take_marker(Path(marker_dir, entry), Path(marker_dir, f"done-{os.getpid()}-{entry}")):
            os._exit(1)
    time.sleep(seconds)
    return seconds


def process_file_or_die(path, *args, **kwargs):
    from cevm.ingest.task import process_file

    path = Path(path)
    for marker in sorted(path.parent.glob(path.name + ".kill-*")):
        k = marker.name.rpartition("-")[2]
        if _take_marker(marker, marker.with_name(f"{path.name}.killed-{k}-{os.getpid()}")):
            os._exit(1)
    if path.with_name(path.name + ".hold").exists():
        path.with_name(f"{path.name}.held-{os.getpid()}").touch()
        while True:
            time.sleep(0.05)
    return process_file(path, *args, **kwargs)


def _hold(marker: str, seconds: float = 3.0) -> None:
    Path(marker).touch()
    t_end = time.monotonic() + seconds
    while time.monotonic() < t_end:  # signals may arrive
        time.sleep(0.01)


def _install_holds(holds: set[str], store: str) -> None:
    import typer

    import cevm.ingest

    if "--hold-after-ingest" in holds:
        real_ingest = cevm.ingest.ingest

        def ingest(*a, **kw):
            report = real_ingest(*a, **kw)
            _hold(store + ".ingested")
            return report

        cevm.ingest.ingest = ingest
    if "--hold-after-summary" in holds:
        real_echo = typer.echo

        def echo(message=None, *a, **kw):
            real_echo(message, *a, **kw)
            if isinstance(message, str) and ('"event": "summary"' in message or message.startswith("cevm ingest: ")):
                _hold(store + ".summarised")

        typer.echo = echo


def markers(directory: Path, pattern: str) -> list[str]:
    return sorted(p.name for p in Path(directory).rglob(pattern))


def session_processes(sid: int) -> list[tuple[int, str]]:
    """Live processes of session ``sid`` (pid, command), from /proc; zombies (ended,
    not yet reaped by their new parent) do not count."""
    out = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            stat = Path("/proc", entry, "stat").read_text()
            cmd = Path("/proc", entry, "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue  # gone meanwhile
        fields = stat[stat.rindex(")") + 2:].split()  # after "pid (comm) "
        state, session = fields[0], int(fields[3])
        if session == sid and state not in ("Z", "X"):
            out.append((int(entry), cmd.strip()))
    return out


def _main(argv: list[str]) -> None:
    task_s = None
    stall = None
    holds: set[str] = set()
    while argv and argv[0].startswith("--"):
        opt = argv.pop(0)
        if opt == "--task-s":
            task_s = float(argv.pop(0))
        elif opt == "--stall-write":
            stall = argv.pop(0)
        elif opt in ("--hold-after-ingest", "--hold-after-summary"):
            holds.add(opt)
        else:
            raise SystemExit(f"faults.py: unknown option {opt}")
    import cevm.executors as executors
    import cevm.ingest.pipeline as pipeline
    import cevm.store.tripstore as trips

    pipeline.process_file = process_file_or_die
    if task_s is not None:
        real_make = executors.make_executor

        def make_executor(workers=None, scheduler=None, **kw):
            ex = real_make(workers, scheduler, **kw)
            ex.task_s = task_s
            return ex

        executors.make_executor = make_executor
    if stall is not None:
        store_arg = argv[argv.index("--store") + 1]
        state = {}
        real_replace = trips.TripStore.replace_file_trips

        def replace_file_trips(self, path, *a, **kw):
            state["path"] = Path(path).name
            return real_replace(self, path, *a, **kw)

        def checkpoint(stage: str) -> None:
            if stage == "trips_inserted" and state.get("path") == stall:
                Path(store_arg + ".in-transaction").touch()
                t_end = time.monotonic() + 1.0
                while time.monotonic() < t_end:  # a busy transaction (signals may arrive)
                    time.sleep(0.01)

        trips.TripStore.replace_file_trips = replace_file_trips
        trips._checkpoint = checkpoint
    if holds:
        _install_holds(holds, argv[argv.index("--store") + 1])
    from cevm.cli import main

    sys.argv = ["cevm", *argv]
    main()


if __name__ == "__main__":
    _main(sys.argv[1:])
