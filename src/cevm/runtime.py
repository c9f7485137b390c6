"""Process-wide settings for long numerical runs (the CLI applies them; a library user
may call them in their own program).

glibc's allocator returns freed memory at the top of the heap to the system once more
than a (dynamic) threshold is free, and serves large arrays with fresh ``mmap`` pages.
A sweep that allocates and frees many arrays of a few hundred kB then pays a page fault
per 4 kB on every new array: about a quarter of the run time of
``benchmarks/bench_sweep.py``. :func:`tune_allocator` keeps freed memory in the process
instead (it is reused by the next arrays), at the cost of a higher resident size after
a peak. :func:`release_free_memory` returns free memory when a program knows that what it
freed will not be reused soon (the pieces of a file read in blocks, once joined).

:func:`signals_deferred` holds back SIGINT and SIGTERM handlers over a short piece of
work that must not be split (a store write and its report).
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import os
import signal
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from functools import lru_cache
from types import FrameType

#: glibc's mallopt parameters (malloc.h)
_M_TRIM_THRESHOLD = -1
_M_TOP_PAD = -2
_M_MMAP_THRESHOLD = -3

#: Free memory kept at the top of the heap before any is returned to the system [bytes].
TRIM_THRESHOLD_BYTES = 256 << 20
#: Extra memory taken from the system whenever the heap grows [bytes].
TOP_PAD_BYTES = 64 << 20
#: Arrays larger than this still get their own mapping (returned when freed) [bytes]:
#: the columns of a large log (4 MB at 500,000 rows), so that a step that replaces them
#: one by one does not leave them as holes in the heap that the next, differently sized
#: arrays cannot reuse (the peak of cleaning a 2.5 M-row log: 504 MB at 32 MB, 427 MB at
#: 4 MB; no change in speed). The arrays a sweep allocates by the thousand are ~100 kB.
MMAP_THRESHOLD_BYTES = 4 << 20
#: The mmap threshold of commands that work on whole long cycles (``cevm predict``,
#: ``cevm feasibility``): they make and free arrays of a cycle's length (16 MB at 2 M
#: samples) dozens of times, which from the heap are reused and from fresh mappings cost
#: their page faults every time (on benchmarks/bench_predict_cli.py: 0.1-0.2 s of system
#: time of 1.1-1.5 s, and the same peak memory).
WHOLE_CYCLE_MMAP_THRESHOLD_BYTES = 256 << 20


#: Set to ``0`` to leave the allocator alone (e.g. workers under a tight memory limit).
TUNE_ENV = "CEVM_TUNE_ALLOCATOR"


@lru_cache(maxsize=1)
def _libc():
    """glibc's functions (None where there is no glibc)."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        libc.malloc_trim  # noqa: B018 - glibc only
    except (OSError, AttributeError):
        return None
    return libc


def release_free_memory() -> bool:
    """Return the allocator's free memory to the system (glibc's ``malloc_trim``).

    For use after a large array was made of many small ones (the blocks of a streamed
    file): the small ones, freed, lie scattered between live arrays, where the allocator
    would keep them resident (and, with :func:`tune_allocator`, keeps even what it could
    return), so the process would hold the data twice at its peak. Costs about a
    millisecond a call. Returns False where it does not apply (no glibc)."""
    libc = _libc()
    if libc is None:
        return False
    libc.malloc_trim(0)
    return True


def tune_allocator(mmap_threshold_bytes: int = MMAP_THRESHOLD_BYTES) -> bool:
    """Keep freed memory for reuse instead of returning it to the system (glibc only).

    Arrays larger than ``mmap_threshold_bytes`` still get their own mapping (default
    :data:`MMAP_THRESHOLD_BYTES`; :data:`WHOLE_CYCLE_MMAP_THRESHOLD_BYTES` for the
    commands on whole long cycles). Returns True if the settings were applied, False
    where they do not apply (another C library or operating system) or
    ``$CEVM_TUNE_ALLOCATOR`` is ``0``, which is
    harmless: only speed differs. A process keeps up to :data:`TRIM_THRESHOLD_BYTES`
    of freed memory (plus :data:`TOP_PAD_BYTES`) after a peak.
    """
    libc = _libc()
    if libc is None or os.environ.get(TUNE_ENV, "").strip() == "0":
        return False
    try:
        mallopt = libc.mallopt
    except AttributeError:
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    settings = ((_M_MMAP_THRESHOLD, mmap_threshold_bytes), (_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES),
                (_M_TOP_PAD, TOP_PAD_BYTES))
    # a list, not a generator: every setting is applied even when one fails
    return all([mallopt(param, value) == 1 for param, value in settings])  # noqa: C419


@contextmanager
def signals_deferred(signums: tuple[int, ...] = (signal.SIGINT, signal.SIGTERM)) -> Iterator[None]:
    """Hold back the Python handlers of ``signums`` (SIGINT's KeyboardInterrupt, the
    command line's SIGTERM) for the duration of the block, then run the first one that
    arrived: for a few milliseconds of work that must not be split, such as writing one
    file's outcome to the store and reporting it.

    Only in the main thread (where Python runs signal handlers) and only for signals with
    a Python handler: a signal whose action is the system default (SIGTERM in a program
    that set none) still ends the process at once, which the store survives (its
    transactions are atomic).
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    arrived: list[tuple[int, FrameType | None]] = []
    saved = {}
    for s in signums:
        handler = signal.getsignal(s)
        if callable(handler):
            saved[s] = handler
            signal.signal(s, lambda signum, frame: arrived.append((signum, frame)))
    try:
        yield
    finally:
        for s, handler in saved.items():
            signal.signal(s, handler)
        if arrived:
            signum, frame = arrived[0]
            saved[signum](signum, frame)


def warnings_as_lines(stream=None, own: tuple[type[Warning], ...] = ()) -> None:
    """Show every warning of this process as one ``cevm: warning:`` line on stderr (or
    ``stream``), never as Python's two lines with a source file and its code line: a
    NumPy ``RuntimeWarning`` that escapes the places where the result is handled (an
    infinite value in a user's file) says what it is and nothing of cevm's source. The
    command line applies it, and so does a worker of its local process pool (whose
    stderr is the command's). Each distinct message is shown once per place, as
    Python's default filter does. Where a host installed its own display (a test
    runner's recorder), warnings other than the ``own`` categories (cevm's words to the
    user, always lines) still go to it."""
    import warnings

    from cevm.text import one_line

    previous = warnings.showwarning
    # a host's display: showwarning replaced, or the recorder of catch_warnings(record=True)
    # (pytest's) in place of the warnings module's own writer
    impl = getattr(warnings, "_showwarnmsg_impl", None)
    hosted = (previous is not getattr(warnings, "_showwarning_orig", previous)
              or getattr(impl, "__module__", "warnings") != "warnings")

    def show(message, category, filename, lineno, file=None, line=None):
        if hosted and not issubclass(category, own):
            previous(message, category, filename, lineno, file, line)
            return
        out = stream or file or sys.stderr
        text = str(message)
        if not issubclass(category, own) and category is not UserWarning:
            text += f" ({category.__name__})"
        try:
            out.write(f"cevm: warning: {one_line(text)}\n")
            out.flush()
        except (OSError, ValueError):  # a closed or broken stderr: nowhere to say it
            pass

    warnings.showwarning = show


def text_streams_replace() -> None:
    """Reconfigure stdout and stderr to replace what their encoding cannot take (a
    vehicle id in Greek on a terminal or pipe that takes only ASCII: ``\\u03b1``
    escaped) instead of ending the command with a UnicodeEncodeError: stdout with
    ``backslashreplace`` (the value can still be told), stderr likewise."""
    for stream in (sys.stdout, sys.stderr):
        reconfigure = getattr(stream, "reconfigure", None)
        if reconfigure is None:
            continue
        with contextlib.suppress(ValueError, OSError):  # a stream already detached or closed
            reconfigure(errors="backslashreplace")
