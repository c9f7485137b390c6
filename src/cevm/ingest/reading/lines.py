"""Lines of a block of text at the byte level: where each starts, its separators and
fields; line numbers in messages and errors naming line and column."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from cevm.errors import InputError
from cevm.ingest.profiles import Profile

_CHUNK_BYTES = 1 << 22  # 4 MiB: keeps temporaries in cache and avoids huge allocations


def _line_stats(b: np.ndarray, sep: int) -> tuple[np.ndarray, np.ndarray]:
    """(byte offset of the start of every line, number of ``sep`` bytes on it) of the
    text ``b`` (uint8 view), computed in chunks of whole lines of about 4 MiB (a loop
    over blocks, not rows): counts per line by ``np.add.reduceat`` of the separator
    mask, no array of separator positions."""
    parts = [np.zeros(1, np.int64)]
    parts.extend(np.flatnonzero(b[lo:lo + _CHUNK_BYTES] == 10) + (lo + 1) for lo in range(0, len(b), _CHUNK_BYTES))
    starts = np.concatenate(parts)
    if starts[-1] >= len(b):
        starts = starts[:-1]
    n_sep = np.empty(len(starts), np.int64)
    i, n = 0, len(starts)
    while i < n:  # lines i..j-1, bytes starts[i]..hi
        lo = int(starts[i])
        j = max(int(np.searchsorted(starts, lo + _CHUNK_BYTES, side="left")), i + 1)
        hi = int(starts[j]) if j < n else len(b)
        is_sep = (b[lo:hi] == sep).view(np.uint8)
        n_sep[i:j] = np.add.reduceat(is_sep, starts[i:j] - lo, dtype=np.int32)
        i = j
    return starts, n_sep


def _only_trailing_separators(b: np.ndarray, starts: np.ndarray, surplus: np.ndarray, sep: int,
                              max_surplus: int = 8) -> np.ndarray:
    """Per line: whether its ``surplus`` (> 0) extra fields are empty, i.e. the line
    ends with that many separators (before an optional CR). Lines with more than
    ``max_surplus`` extra fields are never excused (a merged or corrupt line)."""
    ends = np.append(starts[1:], len(b))  # one past the '\n' (or end of data)
    last = ends - 1
    last = np.where((last >= 0) & (b[np.maximum(last, 0)] == 10), last - 1, last)  # skip '\n'
    last = np.where((last >= 0) & (b[np.maximum(last, 0)] == 13), last - 1, last)  # skip '\r'
    ok = (surplus > 0) & (surplus <= max_surplus)
    for k in range(max_surplus):  # loop over surplus fields, not rows
        need = ok & (surplus > k)
        pos = last - k
        ok &= ~need | ((pos >= starts) & (b[np.maximum(pos, 0)] == sep))
    return ok


def _lines_summary(lines: np.ndarray, limit: int = 6) -> str:
    """'lines 3-7, 12, 20-21' for sorted line numbers, at most ``limit`` runs shown."""
    lines = np.asarray(lines, np.int64)
    if len(lines) == 0:
        return "no lines"
    breaks = np.flatnonzero(np.diff(lines) != 1) + 1
    starts = np.concatenate([[0], breaks])
    ends = np.concatenate([breaks - 1, [len(lines) - 1]])
    runs = [f"{lines[s]}" if s == e else f"{lines[s]}-{lines[e]}"
            for s, e in zip(starts[:limit], ends[:limit], strict=True)]
    more = f", ... ({len(starts) - limit} more runs)" if len(starts) > limit else ""
    return ("line " if len(lines) == 1 else "lines ") + ", ".join(runs) + more


def _fmt_ns(ns: int) -> str:
    return str(np.datetime64(int(ns), "ns").astype("datetime64[s]")).replace("T", " ")


def _line_col_error(path: Path, msg: str, lines: np.ndarray, bad: np.ndarray, col: str,
                    values=None, upto_line: int | None = None) -> InputError:
    """The error at the first ``bad`` row (its value from ``values`` if given), with the
    count of the other bad rows (up to ``upto_line`` when only part of the file was
    seen)."""
    i = int(np.flatnonzero(bad)[0])
    val = ""
    if values is not None:
        v = values[i]
        if isinstance(v, (float, np.floating, int, np.integer)):
            val = f" {float(v):g}"
        else:
            v = str(v)
            val = f" {v!r}" if len(v) <= 60 else f" {v[:50]!r}... ({len(v):,} characters)"
    n_more = int(bad.sum()) - 1
    extra = ""
    if n_more:
        extra = f" (and {n_more} more rows" + (f" up to line {upto_line})" if upto_line is not None else ")")
    return InputError(path, f"{msg}{val}{extra}", line=int(lines[i]), column=col)


def _count_fields(line: bytes, sep: str) -> int:
    """Fields on one line, quotes respected where they parse (a stray carriage return
    or quote falls back to counting separators)."""
    text = line.decode("utf-8", errors="replace").replace("\r", " ")
    try:
        return len(next(csv.reader([text], delimiter=sep), []))
    except csv.Error:
        return text.count(sep) + 1


def _check_field_counts(bview: np.ndarray, starts: np.ndarray, n_sep: np.ndarray, n_names: int,
                        first_line: int, prof: Profile, path: Path) -> np.ndarray:
    """More fields than the header is an error (unless only empty trailing fields);
    returns the lines with fewer (the missing fields read as empty)."""
    blank_line = (bview[starts] == 10) | (bview[starts] == 13)
    more = n_sep > n_names - 1
    if more.any():  # surplus fields that are all empty (trailing separators) are harmless
        more &= ~_only_trailing_separators(bview, starts, n_sep - (n_names - 1), ord(prof.separator))
    if more.any():
        i = int(np.flatnonzero(more)[0])
        raise InputError(path, f"malformed CSV: {int(n_sep[i]) + 1} fields, more than the {n_names} of "
                               f"the header", line=first_line + i)
    return first_line + np.flatnonzero((n_sep < n_names - 1) & ~blank_line)
