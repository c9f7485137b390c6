"""Timestamp parsing for the reading stage (vectorised): datetime text to int64
nanoseconds, by fixed-width layouts straight from the bytes where possible.

:func:`parse_datetimes` parses a column of strings (ISO 8601, a strptime layout, or
numbers since the Unix epoch: :data:`EPOCH_FORMATS`);
:func:`fast_first_column` parses the first field of every line of a file's bytes without
one Python string per row. Date repair and time zones are in :mod:`cevm.ingest.reading`.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from cevm.lazy import pd

#: Not-a-time, as int64 nanoseconds (numpy's NaT).
NAT = np.iinfo(np.int64).min
NS_PER_S = 1_000_000_000
NS_PER_DAY = 86_400 * NS_PER_S

#: Time formats of plain numbers: seconds or milliseconds since 1970-01-01T00:00:00 UTC
#: (what many CAN and OBD loggers write) -> nanoseconds per unit. Such times are UTC by
#: definition: a profile's zone does not apply to them.
EPOCH_FORMATS = {"unix_s": NS_PER_S, "unix_ms": 1_000_000}


_FIXED_FIELDS = {"%Y": 4, "%m": 2, "%d": 2, "%H": 2, "%M": 2, "%S": 2}


_ISO_RE = re.compile(r"^\d{4}-\d\d-\d\d([T ])\d\d:\d\d:\d\d(\.\d{1,9})?(Z?)$")


@dataclass(frozen=True)
class _Layout:
    """A datetime text layout of fixed width: numeric fields (directive -> (start,
    width)) and literal characters (start, code point)."""

    fields: dict[str, tuple[int, int]]
    literals: tuple[tuple[int, int], ...]
    width: int


def _fixed_layout(fmt: str, frac_digits: int = 0) -> _Layout | None:
    """Layout of a strptime format made only of %Y %m %d %H %M %S (and %f with
    ``frac_digits`` digits) and literal characters; ``None`` otherwise."""
    fields: dict[str, tuple[int, int]] = {}
    lits: list[tuple[int, int]] = []
    i = pos = 0
    while i < len(fmt):
        if fmt[i] == "%":
            d = fmt[i:i + 2]
            w = frac_digits if d == "%f" else _FIXED_FIELDS.get(d, 0)
            if w == 0 or d in fields:
                return None
            fields[d] = (pos, w)
            pos += w
            i += 2
        else:
            lits.append((pos, ord(fmt[i])))
            pos += 1
            i += 1
    return _Layout(fields, tuple(lits), pos)


def _iso_layout(sample: str) -> tuple[_Layout, bool] | None:
    """Fixed layout of an ISO 8601 sample such as '2019-05-14T07:00:01.250Z' and whether
    it is UTC ('Z'); ``None`` for other shapes (offsets, week dates, ...)."""
    m = _ISO_RE.match(sample)
    if not m:
        return None
    frac = len(m.group(2)) - 1 if m.group(2) else 0
    fmt = "%Y-%m-%d" + m.group(1) + "%H:%M:%S" + (".%f" if frac else "") + m.group(3)
    return _fixed_layout(fmt, frac), m.group(3) == "Z"  # type: ignore[return-value]


def _parse_codes(cp: np.ndarray, layout: _Layout) -> tuple[np.ndarray, np.ndarray]:
    """Parse a matrix of character codes (rows = strings, at least ``layout.width``
    columns; uint8 bytes or uint32 code points) with numpy only.

    Returns (ns since epoch as int64, ok mask). Rows that do not match the layout
    (non-digits, wrong literals, impossible dates such as 31/02) have ``ok == False``.
    Missing date fields default to 1900-01-01, as in strptime.
    """
    n = cp.shape[0]
    ok = np.ones(n, bool)
    if layout.literals:
        lit_pos = np.array([p for p, _ in layout.literals], np.intp)
        lit_chr = np.array([ch for _, ch in layout.literals], cp.dtype)
        ok &= (cp[:, lit_pos] == lit_chr).all(axis=1)
    values: dict[str, np.ndarray] = {}
    if layout.fields:
        spans = list(layout.fields.values())
        pos = np.concatenate([np.arange(p, p + w) for p, w in spans])
        # unsigned (uint8 / uint32) so that non-digits wrap to large values
        dig = cp[:, pos] - cp.dtype.type(48)
        ok &= (dig <= 9).all(axis=1)
        # every field's number from its digits' place values, in integer arithmetic (a
        # float matrix product would start a BLAS thread pool for a handful of columns)
        dig = dig.astype(np.int64)
        nums = np.empty((dig.shape[0], len(spans)), dtype=np.int64)
        k = 0
        for j, (_, w) in enumerate(spans):  # a few fields, not rows
            nums[:, j] = dig[:, k:k + w] @ (10 ** np.arange(w - 1, -1, -1, dtype=np.int64))
            k += w
        values = {d: nums[:, j] for j, d in enumerate(layout.fields)}

    def num(d: str, default: int) -> np.ndarray:
        got = values.get(d)
        return np.full(n, default, np.int64) if got is None else got

    year, month, day = num("%Y", 1900), num("%m", 1), num("%d", 1)
    hour, minute, sec = num("%H", 0), num("%M", 0), num("%S", 0)
    ok &= (hour <= 23) & (minute <= 59) & (sec <= 59)
    # The date's checks and day number once per run of rows with one date (a log holds
    # few dates). Rows rejected so far share key -1; the others hold digits only, so
    # their fields are below 2**14 and the key is exact.
    key = np.where(ok, (year << 28) | (month << 14) | day, -1)
    first = np.flatnonzero(np.concatenate(([True], key[1:] != key[:-1]))) if n else np.zeros(0, np.intp)
    y, m, d = year[first], month[first], day[first]
    date_ok = (m >= 1) & (m <= 12) & (d >= 1) & (y >= 1678) & (y <= 2261)  # int64 ns range
    m = np.where(date_ok, m, 1)
    leap = (y % 4 == 0) & ((y % 100 != 0) | (y % 400 == 0))
    date_ok &= d <= _DAYS_IN_MONTH[m - 1] + (leap & (m == 2))  # e.g. 31/02 fails
    run_length = np.diff(np.append(first, n))
    ok &= np.repeat(date_ok, run_length)
    days = np.repeat(_days_from_civil(y, m, d), run_length)
    ns = (days * 86_400 + (hour * 60 + minute) * 60 + sec) * NS_PER_S
    if "%f" in layout.fields:
        ns += num("%f", 0) * 10 ** (9 - layout.fields["%f"][1])
    return np.where(ok, ns, NAT), ok


_DAYS_IN_MONTH = np.array([31, 28, 31, 30, 31, 30, 31, 31, 30, 31, 30, 31], np.int64)


def _days_from_civil(y: np.ndarray, m: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Days since 1970-01-01 of proleptic Gregorian dates (H. Hinnant's algorithm),
    vectorised integer arithmetic; valid for any year."""
    y = y - (m <= 2)
    era = np.floor_divide(y, 400)
    yoe = y - era * 400
    doy = (153 * (m + np.where(m > 2, -3, 9)) + 2) // 5 + d - 1
    doe = yoe * 365 + yoe // 4 - yoe // 100 + doy
    return era * 146_097 + doe - 719_468


def parse_datetimes(values: np.ndarray, fmt: str) -> np.ndarray:
    """Naive datetimes [ns since epoch, int64; ``NAT`` where unparseable] of strings
    (object array, NaN for empty fields) in ``fmt`` ("ISO8601" or strptime).

    Fixed-width numeric formats are parsed with numpy (:func:`_parse_codes`); other rows
    and formats go through ``pandas.to_datetime`` with the explicit format. ISO 8601
    strings with a zone designator ('Z', '+01:00') are converted to UTC; the caller must
    then not localise them again (see :func:`has_offset`).
    """
    if fmt in EPOCH_FORMATS:
        return epoch_ns(values, EPOCH_FORMATS[fmt])
    n = len(values)
    out = np.full(n, NAT, np.int64)
    rest = np.ones(n, bool)
    layout = _fixed_layout(fmt) if fmt != "ISO8601" else None
    if layout is not None and n:
        u = values.astype("U")
        cols = u.dtype.itemsize // 4
        if cols >= layout.width:
            cp32 = u.view(np.uint32).reshape(n, cols)
            ok_len = cp32[:, layout.width - 1] != 0
            if cols > layout.width:
                ok_len &= cp32[:, layout.width] == 0
            # to bytes (faster below); non-Latin code points become 255, never a digit
            cp = np.minimum(cp32[:, :layout.width], 255).astype(np.uint8)
            ns, ok = _parse_codes(cp, layout)
            ok &= ok_len
            out[ok] = ns[ok]
            rest = ~ok
    if rest.any():
        sub = pd.Series(values[rest], dtype=object)
        kw = {"utc": True} if fmt == "ISO8601" and has_offset(values) else {}
        parsed = pd.to_datetime(sub, format=fmt, errors="coerce", **kw)
        if getattr(parsed.dt, "tz", None) is not None:
            parsed = parsed.dt.tz_convert("UTC").dt.tz_localize(None)
        out[rest] = parsed.to_numpy(dtype="datetime64[ns]").astype(np.int64)  # NaT -> NAT
    return out


def epoch_ns(values: np.ndarray, ns_per_unit: int, decimal: str = ".") -> np.ndarray:
    """UTC times [ns since epoch, int64; ``NAT`` where empty or not a finite number] of
    numbers since the Unix epoch written as text (object array, NaN for empty fields),
    ``ns_per_unit`` nanoseconds per unit (:data:`EPOCH_FORMATS`).

    Whole numbers are converted exactly; a fractional part to float64's precision (about
    0.2 µs at today's epoch seconds)."""
    s = pd.Series(values, dtype=object)
    if decimal != ".":
        s = s.str.replace(decimal, ".", regex=False)
    x = pd.to_numeric(s, errors="coerce").to_numpy(np.float64)
    ok = np.isfinite(x) & (np.abs(x) < 9e18 / ns_per_unit)
    out = np.full(len(x), NAT, np.int64)
    whole = ok & (x == np.floor(x))
    out[whole] = x[whole].astype(np.int64) * ns_per_unit
    frac = ok & ~whole
    out[frac] = np.round(x[frac] * ns_per_unit).astype(np.int64)
    return out


@dataclass(frozen=True)
class FastTimes:
    ns: np.ndarray  # int64 ns, naive or UTC (see is_utc)
    is_utc: bool
    blank: np.ndarray  # bool, blank lines


def fast_first_column(body: bytes, b: np.ndarray, starts: np.ndarray, sep: str, fmt: str) -> FastTimes | None:
    """Parse the first field of every line straight from the bytes (``b``: uint8 view
    of ``body`` without quote characters, ``starts``: line starts) when it is a
    fixed-width datetime (ISO 8601 or a fixed strptime layout).

    This avoids one Python string per row (half the reading time of an srf file). Returns
    ``None`` when the fast path does not apply or any non-blank line fails to parse;
    the caller then reads the column as text and reports errors with lines.
    """
    if not body or fmt in EPOCH_FORMATS:
        return None
    first_line = body[: body.find(b"\n") if b"\n" in body else len(body)].decode("utf-8", "replace").strip()
    sample = first_line.split(sep)[0].strip()
    layout: _Layout | None
    if fmt == "ISO8601":
        got = _iso_layout(sample)
        if got is None:
            return None
        layout, is_utc = got
    else:
        layout, is_utc = _fixed_layout(fmt), False
        if layout is None:
            return None
    w = layout.width
    if len(b) < w + 1:
        return None
    windows = np.lib.stride_tricks.sliding_window_view(b, w + 1)  # no copy
    last = len(b) - (w + 1)
    cp = windows[np.minimum(starts, last)]  # (rows, w + 1) bytes, one gather
    ns, ok = _parse_codes(cp, layout)
    ok &= (cp[:, w] == ord(sep)) & (starts <= last)
    first = b[starts]
    blank = (first == 10) | (first == 13)
    if not (ok | blank).all():
        return None
    return FastTimes(ns, is_utc, blank)


def has_offset(values: np.ndarray) -> bool:
    """Whether the first non-empty ISO 8601 string carries a zone ('Z' or +-HH:MM)."""
    for v in values[:100]:
        if isinstance(v, str) and v.strip():
            return bool(re.search(r"(Z|[+-]\d\d:?\d\d)\s*$", v.strip()))
    return False
