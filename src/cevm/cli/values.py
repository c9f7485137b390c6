"""Option values that stand for many numbers: a number, a list ``a,b`` or a range
``start:stop:step`` (``--mass-kg``, ``--payload-kg``), parsed into the arrays the core
takes. Configuration parsing is the command line's job; :mod:`cevm.core` sees arrays."""

from __future__ import annotations

import math

import numpy as np

from cevm.errors import InputError

#: Largest number of values a range option may expand to (a typo guard).
MAX_RANGE_VALUES = 10_000_000


def parse_values(spec: str, option: str = "value") -> np.ndarray:
    """The numbers of one option value [whatever unit the option has].

    ``spec`` is a number (``"12000"``), a comma-separated list (``"12000,20000"``), or a
    range ``start:stop:step`` whose ``stop`` is *included* when it lies on the grid:
    ``"0:26000:2000"`` gives the 14 values 0, 2000, ..., 26000; ``"0:25000:2000"`` gives
    0 ... 24000 (13 values). Values are ``start + k step`` (no accumulated rounding);
    the last is snapped to ``stop`` when within 1e-9 steps of it. Items of a list may
    themselves be ranges. Raises :class:`~cevm.errors.InputError` naming ``option``.
    """
    out: list[np.ndarray] = []
    for item in str(spec).split(","):
        item = item.strip()
        if not item:
            raise InputError(option, f"empty value in {spec!r}")
        parts = item.split(":")
        try:
            nums = [float(p) for p in parts]
        except ValueError:
            raise InputError(option, f"not a number or a start:stop:step range: {item!r}") from None
        if not all(math.isfinite(v) for v in nums):
            raise InputError(option, f"values must be finite: {item!r}")
        if len(nums) == 1:
            out.append(np.array(nums))
            continue
        if len(nums) != 3:
            raise InputError(option, f"a range is start:stop:step (three numbers), got {item!r}")
        start, stop, step = nums
        if step <= 0:
            raise InputError(option, f"range {item!r}: step must be > 0")
        if stop < start:
            raise InputError(option, f"range {item!r}: stop is below start")
        n = int(math.floor((stop - start) / step + 1e-9)) + 1
        if n > MAX_RANGE_VALUES:
            raise InputError(option, f"range {item!r} has {n} values, more than {MAX_RANGE_VALUES}")
        vals = start + step * np.arange(n, dtype=np.float64)
        if abs(vals[-1] - stop) <= 1e-9 * step:
            vals[-1] = stop
        out.append(vals)
    return np.concatenate(out)


def parse_value_options(specs: list[str] | None, option: str) -> np.ndarray | None:
    """The numbers of a repeatable option (each value as :func:`parse_values`), in order;
    None when the option was not given."""
    if not specs:
        return None
    return np.concatenate([parse_values(s, option) for s in specs])
