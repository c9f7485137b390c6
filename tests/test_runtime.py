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
    with pytest.raises(KeyboardInterrupt):
        with signals_deferred():
            os.kill(os.getpid(), signal.SIGINT)
            for _ in range(1000):  # the handler would run at one of these bytecodes
                steps.append(1)
            steps.append("end of block")
    assert steps[-1] == "end of block" and len(steps) == 1001
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # restored
    with signals_deferred():  # nothing arrived: nothing raised
        steps.append("quiet")
    # a signal without a Python handler is left alone (its default action still applies)
    assert signal.getsignal(signal.SIGTERM) == signal.SIG_DFL
    with signals_deferred():
        assert signal.getsignal(signal.SIGTERM) == signal.SIG_DFL
