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
