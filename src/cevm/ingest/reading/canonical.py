"""The gathered columns in canonical SI columns, checked, and split into one log per
vehicle."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cevm.errors import InputError
from cevm.ingest.profiles import VIRTUAL_COLUMNS, ColumnMap, EnergySpec, Profile
from cevm.ingest.reading.lines import _lines_summary
from cevm.ingest.reading.logs import EnergySource, ParsedLog
from cevm.ingest.reading.plausibility import _check_absurd, _check_position


def _canonical_columns(columns: dict[str, np.ndarray], maps: list[ColumnMap], utc: np.ndarray,
                       lines: np.ndarray, prof: Profile, path: Path, repairs: list[str]) -> dict[str, np.ndarray]:
    """The canonical columns (``time_s``, ``source_line`` and each mapped column in SI),
    with impossible positions and absurd values handled; a log with neither position nor
    speed values is an error. ``columns`` (numbers by source name, value-map columns by
    canonical name) are converted in place and released from the dict."""
    out: dict[str, np.ndarray] = {"time_s": _ns_to_s(utc), "source_line": lines}
    del utc
    for m in maps:
        if m.value_map is not None:
            out[m.canonical] = columns.pop(m.canonical)
        else:
            out[m.canonical] = _to_si(columns.pop(m.source), m, lines, repairs)
        if m.negate:
            out[m.canonical] = np.negative(out[m.canonical], out=out[m.canonical])
    _check_position(out, prof, lines, path, repairs)
    for m in maps:
        if m.canonical not in ("lat_deg", "lon_deg"):
            _check_absurd(out, m, lines, path, prof, repairs)

    has_pos = "lat_deg" in out and np.isfinite(out["lat_deg"]).any()
    has_speed = any(c in out and np.isfinite(out[c]).any() for c in ("wheel_speed_mps", "gps_speed_mps"))
    if not (has_pos or has_speed):
        cands = [m.source for m in prof.columns
                 if m.canonical in ("lat_deg", "lon_deg", "wheel_speed_mps", "gps_speed_mps")]
        raise InputError(path, "no position and no speed values: cannot derive a drive cycle "
                               f"(profile {prof.name!r} looks for {', '.join(cands) or 'none'})")
    return out


def _ns_to_s(ns: np.ndarray) -> np.ndarray:
    """Times [ns, int64] in seconds (float64), in the same memory where the array is its
    own (a chunk at a time: no second array of the file's length)."""
    if not (ns.flags.writeable and ns.flags.c_contiguous and ns.base is None):
        return ns / 1e9
    s = ns.view(np.float64)
    step = 1 << 16
    for a in range(0, ns.size, step):
        s[a:a + step] = ns[a:a + step] / 1e9
    return s


def _split_vehicles(out: dict[str, np.ndarray], codes: np.ndarray, vehicles: list[str], maps: list[ColumnMap],
                    prof: Profile, path: Path, metadata: dict[str, str], repairs: list[str]) -> list[ParsedLog]:
    """One :class:`ParsedLog` per vehicle: its rows' canonical columns (the arrays
    themselves) and the energy sources they hold. With several vehicles
    each column is reordered by vehicle once (stable: file order within a vehicle) and
    the vehicles' frames are slices of it."""
    if len(vehicles) == 1:
        per = [out]
    else:
        order = np.argsort(codes, kind="stable")
        bounds = np.searchsorted(codes[order], np.arange(len(vehicles) + 1))
        per = [{} for _ in vehicles]
        for c in list(out):
            a = out.pop(c)[order]
            for k in range(len(vehicles)):
                per[k][c] = a[bounds[k]:bounds[k + 1]]
    logs = []
    for vname, arrays in zip(vehicles, per, strict=True):
        sources = tuple(_energy_source(e, maps) for e in prof.energy if _has_energy_data(e, arrays))
        logs.append(ParsedLog(path, prof.name, vname, arrays, dict(metadata), sources, list(repairs)))
    return logs


def _has_energy_data(e: EnergySpec, arrays: dict[str, np.ndarray]) -> bool:
    """Whether the canonical columns ``arrays`` hold any value of the source (both
    factors for a virtual one)."""
    if e.column in VIRTUAL_COLUMNS:
        a, b = VIRTUAL_COLUMNS[e.column][0]
        return a in arrays and b in arrays and bool(
            np.isfinite(arrays[a]).any() and np.isfinite(arrays[b]).any())
    return e.column in arrays and bool(np.isfinite(arrays[e.column]).any())


def _energy_source(e: EnergySpec, maps: list[ColumnMap]) -> EnergySource:
    cols = VIRTUAL_COLUMNS[e.column][0] if e.column in VIRTUAL_COLUMNS else (e.column,)
    src = "*".join(next(m.source for m in maps if m.canonical == c) for c in cols)
    return EnergySource(e.column, e.kind, e.quantity, e.resolution, e.priority, e.capacity_j, src, e.modulus,
                        e.accuracy_pct)


def _to_si(x: np.ndarray, m: ColumnMap, lines: np.ndarray, repairs: list[str]) -> np.ndarray:
    """A numeric source column in SI, in place: the logger's missing-value markers to
    NaN (reported), then ``x * factor + offset``."""
    if m.missing_values:
        miss = np.isin(x, np.asarray(m.missing_values))
        if miss.any():
            x[miss] = np.nan
            repairs.append(f"{m.canonical}: {int(miss.sum())} values equal to the logger's missing-value "
                           f"marker ({', '.join(f'{v:g}' for v in m.missing_values)}) in column "
                           f"'{m.source}' set to NaN: {_lines_summary(lines[miss])}")
    if m.factor != 1.0:
        x *= m.factor
    if m.offset != 0.0:
        x += m.offset
    return x
