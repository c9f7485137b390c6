"""Fast, deterministic CSV formatting (no per-value Python)."""

from __future__ import annotations

import numpy as np


def num_field(x, decimals: int, *, strip: bool = False, dec: bytes = b".") -> tuple[np.ndarray, np.ndarray]:
    """Characters (N x W uint8) and keep-mask of numbers printed with ``decimals``
    decimals (``strip``: trailing fractional zeros dropped); NaN -> empty field."""
    x = np.asarray(x, dtype=float)
    nrow = x.size
    valid = np.isfinite(x)
    n = np.rint(np.where(valid, x, 0.0) * 10.0**decimals).astype(np.int64)
    neg = n < 0
    a = np.abs(n)
    amax = int(a.max()) if nrow else 0
    nd = max(len(str(amax)), decimals + 1)
    pw = 10 ** np.arange(nd - 1, -1, -1, dtype=np.int64)
    digits = ((a[:, None] // pw[None, :]) % 10).astype(np.uint8)
    ni = nd - decimals
    keep_i = np.logical_or.accumulate(digits[:, :ni] != 0, axis=1)
    keep_i[:, -1] = True
    if decimals:
        if strip:
            keep_f = np.logical_or.accumulate((digits[:, ni:] != 0)[:, ::-1], axis=1)[:, ::-1]
            dot = np.asarray(keep_f.any(axis=1))
        else:
            keep_f = np.ones((nrow, decimals), bool)
            dot = np.ones(nrow, bool)
        chars = np.concatenate([np.full((nrow, 1), ord("-"), np.uint8), digits[:, :ni] + 48,
                                np.full((nrow, 1), dec[0], np.uint8), digits[:, ni:] + 48], axis=1)
        keep = np.concatenate([neg[:, None], keep_i, dot[:, None], keep_f], axis=1)
    else:
        chars = np.concatenate([np.full((nrow, 1), ord("-"), np.uint8), digits + 48], axis=1)
        keep = np.concatenate([neg[:, None], keep_i], axis=1)
    return chars, keep & valid[:, None]


def text_field(values) -> tuple[np.ndarray, np.ndarray]:
    """Characters and keep-mask of byte strings (empty string -> empty field)."""
    arr = np.asarray(values, dtype=bytes)
    if arr.dtype.itemsize == 0:
        arr = arr.astype("S1")
    chars = arr.view(np.uint8).reshape(arr.size, arr.dtype.itemsize)
    return chars, chars != 0


def assemble(fields: list[tuple[np.ndarray, np.ndarray]], sep: bytes, eol: bytes) -> bytes:
    """Rows of ``fields`` joined by ``sep`` and ended by ``eol``, as bytes."""
    nrow = fields[0][0].shape[0]
    parts, keeps = [], []
    for i, (c, k) in enumerate(fields):
        if i:
            parts.append(np.full((nrow, len(sep)), np.frombuffer(sep, np.uint8), np.uint8))
            keeps.append(np.ones((nrow, len(sep)), bool))
        parts.append(c)
        keeps.append(k)
    parts.append(np.tile(np.frombuffer(eol, np.uint8), (nrow, 1)))
    keeps.append(np.ones((nrow, len(eol)), bool))
    return np.concatenate(parts, axis=1)[np.concatenate(keeps, axis=1)].tobytes()


def iso_utc_ms(epoch_ms: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``YYYY-MM-DDTHH:MM:SS.mmmZ`` characters of integer epoch milliseconds."""
    s = np.datetime_as_string(epoch_ms.astype("datetime64[ms]"), unit="ms").astype("S23")
    c = np.concatenate([s.view(np.uint8).reshape(-1, 23), np.full((s.size, 1), ord("Z"), np.uint8)], axis=1)
    return c, np.ones(c.shape, bool)


def uk_local(epoch_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``dd/mm/yyyy HH:MM:SS`` characters of UTC epoch seconds in Europe/London time."""
    import pandas as pd

    idx = pd.DatetimeIndex(np.asarray(epoch_s, dtype=np.int64).astype("datetime64[s]"), tz="UTC")
    local = idx.tz_convert("Europe/London").tz_localize(None).values.astype("datetime64[s]")
    s = np.datetime_as_string(local, unit="s").astype("S19").view(np.uint8).reshape(-1, 19)
    order = [8, 9, 7, 5, 6, 4, 0, 1, 2, 3, 10, 11, 12, 13, 14, 15, 16, 17, 18]
    c = s[:, order].copy()
    c[:, 2] = c[:, 5] = ord("/")
    c[:, 10] = ord(" ")
    return c, np.ones(c.shape, bool)


