"""Fault injection for the tests, kept out of cevm: task functions that wrap the real ones.

Faults are described by marker files, which every worker sees (a worker's memory and
environment are not the test's: a forkserver keeps the environment it started with):

- ``sleep_or_die(marker_dir, name, seconds)``: a task that dies (``os._exit(1)``, as a
  process killed mid-task) if ``marker_dir`` holds a file ``<anything>.<name>``, which
  it renames to ``done-<pid>-<file>`` first (atomically: one worker wins; each marker
  kills one worker once); else it sleeps.
- ``process_file_or_die(path, ...)``: :func:`cevm.ingest.task.process_file`, but a file
  ``<log path>.kill-<k>`` beside the log kills its worker once (renamed to
  ``<log path>.killed-<k>-<pid>``). (Directories are searched for ``*.csv`` and
  ``*.csv.gz``: the markers are never taken for logs.) A test installs it as the
  ingest's task with ``monkeypatch.setattr(cevm.ingest.pipeline, "process_file", ...)``.
"""

from __future__ import annotations

import os
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
    return process_file(path, *args, **kwargs)


def markers(directory: Path, pattern: str) -> list[str]:
    return sorted(p.name for p in Path(directory).rglob(pattern))
