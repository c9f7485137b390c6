"""A weather file for ``cevm gtfs --weather``: a CSV of ``time`` (ISO 8601; without an
offset, in the feed's time zone) and ``ambient_c`` [degC], interpolated linearly in time
at each trip's midpoint (:func:`ambient_at`)."""

from __future__ import annotations

from datetime import datetime
from pathlib import Path

import numpy as np

from cevm.errors import InputError
from cevm.io.inputs import open_regular

#: Largest weather file read [bytes]: an hourly year is 0.3 MB.
MAX_WEATHER_BYTES = 64 << 20
#: A trip further than this outside the weather's span [s] is refused: holding the last
#: value for hours would be a quiet guess.
MAX_OUTSIDE_S = 3 * 3600.0


def read_weather(path: str | Path, tz) -> tuple[np.ndarray, np.ndarray]:
    """The file's (epoch seconds, ambient_c), sorted by time; a bad row refused with its
    line and column."""
    import csv
    import io

    p = Path(path)
    with open_regular(p, "weather file") as fh:
        data = fh.read(MAX_WEATHER_BYTES + 1)
    if len(data) > MAX_WEATHER_BYTES:
        raise InputError(p, f"larger than a weather file may be ({MAX_WEATHER_BYTES >> 20} MiB)")
    reader = csv.reader(io.StringIO(data.decode("utf-8-sig", errors="replace")))
    header = [h.strip() for h in next(reader, [])]
    for c in ("time", "ambient_c"):
        if c not in header:
            raise InputError(p, f"no column {c!r} (give time, ISO 8601, and ambient_c, degC)", line=1)
    it, ia = header.index("time"), header.index("ambient_c")
    ts, vs = [], []
    for row in reader:
        line = reader.line_num
        if not row or not any(x.strip() for x in row):
            continue
        try:
            t = datetime.fromisoformat(row[it].strip())
        except (ValueError, IndexError):
            raise InputError(p, f"{row[it] if it < len(row) else ''!r} is not an ISO 8601 time", line=line,
                             column="time") from None
        if t.tzinfo is None:
            t = t.replace(tzinfo=tz)
        try:
            v = float(row[ia])
        except (ValueError, IndexError):
            raise InputError(p, "not a number", line=line, column="ambient_c") from None
        if not -60.0 <= v <= 60.0:
            raise InputError(p, f"{v:g} degC is outside -60..60", line=line, column="ambient_c")
        ts.append(t.timestamp())
        vs.append(v)
    if not ts:
        raise InputError(p, "no rows")
    t_arr, v_arr = np.asarray(ts), np.asarray(vs)
    order = np.argsort(t_arr, kind="stable")
    return t_arr[order], v_arr[order]


def ambient_at(weather: tuple[np.ndarray, np.ndarray], epoch_s: np.ndarray, where: str) -> np.ndarray:
    """The temperature at ``epoch_s``, linear between the file's rows; a time more than
    :data:`MAX_OUTSIDE_S` outside them refused."""
    t, v = weather
    x = np.asarray(epoch_s, dtype=np.float64)
    out = (x < t[0] - MAX_OUTSIDE_S) | (x > t[-1] + MAX_OUTSIDE_S)
    if out.any():
        when = datetime.fromtimestamp(float(x[out][0])).isoformat(timespec="minutes")
        raise InputError(where, f"does not cover the trips (one runs at {when}, more than "
                                f"{MAX_OUTSIDE_S / 3600:g} h outside the file's times)")
    return np.interp(x, t, v)
