"""Reading cycle files (CSV), with errors that name file, line and column."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from cevm.core.cycle import DriveCycle
from cevm.errors import InputError
from cevm.units import KMH_TO_MPS


def _first_bad_row(mask: np.ndarray) -> int:
    return int(np.flatnonzero(mask)[0])


def read_cycle_csv(path: str | Path) -> DriveCycle:
    """Read a cycle CSV: header with ``time_s`` and ``speed_kmh`` or ``speed_mps``, and
    optionally ``elevation_m``; other columns are ignored.

    Errors (missing column, non-numeric or empty cell, non-increasing time, negative
    speed) raise :class:`~cevm.errors.InputError` with the file, the line (1-based, the
    header is line 1) and the column.
    """
    path = Path(path)
    if not path.exists():
        raise InputError(path, "cycle file not found")
    if path.is_dir():
        raise InputError(path, "is a directory, not a cycle file")
    raw = path.read_bytes()
    if b"\x00" in raw[:4096]:
        raise InputError(path, "binary data, not a CSV text file")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise InputError(path, f"not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    lines = text.splitlines()
    if not lines or not lines[0].strip():
        raise InputError(path, "empty file: expected a header with time_s and speed_kmh or speed_mps", line=1)
    header = [c.strip() for c in lines[0].split(",")]
    speed_col = "speed_mps" if "speed_mps" in header else "speed_kmh" if "speed_kmh" in header else None
    for need, ok in (("time_s", "time_s" in header), ("speed_kmh or speed_mps", speed_col is not None)):
        if not ok:
            raise InputError(path, f"missing column {need}; header has: {', '.join(header)}", line=1)
    cols = ["time_s", speed_col] + (["elevation_m"] if "elevation_m" in header else [])
    try:
        df = pd.read_csv(
            path,
            usecols=lambda c: c.strip() in cols,
            dtype=str,
            skip_blank_lines=False,
            keep_default_na=False,
            encoding="utf-8-sig",
        )
    except pd.errors.ParserError as exc:
        raise InputError(path, f"malformed CSV: {exc}") from None
    df.columns = [c.strip() for c in df.columns]
    if len(df) < 2:
        raise InputError(path, "a cycle needs at least 2 rows of samples", line=len(df) + 2)
    values: dict[str, np.ndarray] = {}
    for col in cols:
        s = df[col].fillna("").str.strip()
        num = pd.to_numeric(s, errors="coerce").to_numpy(dtype=np.float64)
        bad = ~np.isfinite(num)
        if bad.any():
            i = _first_bad_row(bad)
            cell = s.iloc[i]
            why = "empty cell" if cell == "" else f"not a finite number: {cell!r}"
            raise InputError(path, why, line=i + 2, column=col)
        values[col] = num
    t = values["time_s"]
    steps = np.diff(t)
    if np.any(steps <= 0):
        i = _first_bad_row(steps <= 0) + 1
        raise InputError(
            path, f"time does not increase ({t[i - 1]:g} then {t[i]:g})", line=i + 2, column="time_s"
        )
    v = values[speed_col]
    if np.any(v < 0):
        i = _first_bad_row(v < 0)
        raise InputError(path, f"negative speed {v[i]:g}", line=i + 2, column=speed_col)
    speed_mps = v * KMH_TO_MPS if speed_col == "speed_kmh" else v
    return DriveCycle(
        time_s=t,
        speed_mps=speed_mps,
        elevation_m=values.get("elevation_m"),
        name=path.stem,
    )
