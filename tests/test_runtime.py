"""cevm.runtime: the allocator settings the CLI applies."""

from __future__ import annotations

import platform
import sys

import numpy as np
import pytest

from cevm.runtime import tune_allocator


@pytest.mark.skipif(not sys.platform.startswith("linux") or platform.libc_ver()[0] != "glibc",
                    reason="glibc's mallopt only")
def test_tune_allocator_applies_on_glibc_and_can_be_repeated():
    assert tune_allocator() is True
    assert tune_allocator() is True
    # the process still allocates, frees and computes normally afterwards
    a = np.arange(1 << 20, dtype=np.float64)
    assert float(a.sum()) == (1 << 20) * ((1 << 20) - 1) / 2


def test_tune_allocator_never_raises():
    assert isinstance(tune_allocator(), bool)


def test_tune_allocator_can_be_switched_off(monkeypatch):
    monkeypatch.setenv("CEVM_TUNE_ALLOCATOR", "0")
    assert tune_allocator() is False


def test_signals_deferred_holds_a_signal_until_the_block_ends():
    import os
    import signal

    from cevm.runtime import signals_deferred

    steps = []
    with pytest.raises(KeyboardInterrupt), signals_deferred():
        os.kill(os.getpid(), signal.SIGINT)
        for _ in range(1000):  # the handler would run at one of these bytecodes
            steps.append(1)  # noqa: PERF401 (a loop of bytecodes is the point)
        steps.append("end of block")
    assert steps[-1] == "end of block" and len(steps) == 1001
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # restored
    with signals_deferred():  # nothing arrived: nothing raised
        steps.append("quiet")
    # a signal without a Python handler is left alone (its default action still applies)
    assert signal.getsignal(signal.SIGTERM) == signal.SIG_DFL
    with signals_deferred():
        assert signal.getsignal(signal.SIGTERM) == signal.SIG_DFL


def test_release_free_memory_never_raises():
    from cevm.runtime import release_free_memory

    assert isinstance(release_free_memory(), bool)


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux") or platform.libc_ver()[0] != "glibc",
                    reason="glibc's malloc_trim and /proc")
def test_release_free_memory_returns_what_many_small_arrays_freed():
    """The pieces of a file read in blocks: many arrays under the mapping threshold,
    joined and freed. With tune_allocator's settings glibc keeps their memory
    resident; release_free_memory returns it."""
    import subprocess

    code = """
import re, numpy as np
from cevm.runtime import release_free_memory, tune_allocator
def rss():
    return int(re.search(r"VmRSS:\\s+(\\d+)", open("/proc/self/status").read()).group(1)) / 1024
tune_allocator()
base = rss()
parts = [np.ones(40_000) for _ in range(600)]  # 600 x 320 kB, 190 MB in the heap
whole = np.concatenate(parts)
del parts
kept = rss() - base
assert release_free_memory()
print(kept, rss() - base)
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    kept, after = map(float, out.split())
    assert kept > 300  # the parts and the joined array: the parts' memory was kept
    assert after < kept - 150  # the parts' memory went back: about the joined array is left
