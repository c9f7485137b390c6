"""Reading vehicle files and cycle files, with errors that name file, line and column."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd

from cevm.cycle import DriveCycle
from cevm.errors import InputError
from cevm.vehicle import Vehicle, vehicle_from_mapping

KMH_TO_MPS = 1.0 / 3.6


def read_toml(path: str | Path, what: str = "file") -> dict:
    """Parse a TOML file; errors name the file, the line and what the file should be."""
    path = Path(path)
    try:
        text = path.read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise InputError(path, f"{what} not found") from None
    except IsADirectoryError:
        raise InputError(path, f"is a directory, not a {what}") from None
    except UnicodeDecodeError as exc:
        raise InputError(path, f"not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        # Python 3.11's message ends "(at line L, column C)"; newer ones also set lineno.
        found = re.search(r"\(at line (\d+), column \d+\)", str(exc))
        line = getattr(exc, "lineno", None) or (int(found.group(1)) if found else None)
        msg = getattr(exc, "msg", None) or str(exc)
        raise InputError(path, f"not valid TOML: {msg}", line=line) from None


def load_vehicle(path: str | Path) -> Vehicle:
    """Read and validate a vehicle TOML file (keys: see :mod:`cevm.vehicle`)."""
    return vehicle_from_mapping(read_toml(path, "vehicle file"), str(path))


def load_vehicles(paths: list[str | Path]) -> list[Vehicle]:
    """Load vehicle files; a directory contributes its ``*.toml`` files, sorted."""
    out: list[Vehicle] = []
    for p in paths:
        p = Path(p)
        if p.is_dir():
            files = sorted(p.glob("*.toml"))
            if not files:
                raise InputError(p, "directory holds no vehicle files (*.toml)")
            out.extend(load_vehicle(f) for f in files)
        else:
            out.append(load_vehicle(p))
    return out


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
