"""Reading cycle files (CSV, or gzip-compressed CSV) as users have them, fast, with
plausibility bounds and errors that name file, line and column.

A cycle file has a header line and one sample per line: a time column (or a fixed time
step, :attr:`CycleFormat.time_step_s`), one or more speed columns (each selected column
is one cycle: the VECTO files hold one mission per column), and optionally an elevation
or a road-grade column, in the same file or, for the grade, in a second file with the
same rows (VECTO's ``gradient_*.csv``). The old layout ``time_s``, ``speed_kmh`` or
``speed_mps``, ``elevation_m`` reads as before.

What is not given in a :class:`CycleFormat` is detected:

- separator, decimal mark, gzip, encoding: :func:`cevm.io.numeric_csv.sniff_csv`;
- columns by name, ignoring case, spaces and underscores, with the unit in the name
  (``speed_kmh``, ``Speed [km/h]``, ``v (m/s)``, ``speed_mph``, ``time_s``,
  ``elevation_m``, ``altitude (ft)``, ``grade_pct``, ``Gradient [%]``): time is
  ``time`` or ``t``; speed ``speed``, ``v``, ``velocity`` or ``vehicle speed``; elevation
  ``elevation``, ``altitude``, ``height`` or ``alt``; grade ``grade``, ``gradient``,
  ``slope`` or ``road grade``. A time column without a unit is in seconds and an
  elevation column without one in metres; a speed or grade column without a unit needs
  it given (km/h, m/s, mph; % or fraction): no guess. A file with an elevation and a
  grade column uses the elevation.

In a file of several missions (speed columns selected), a column may end before the
others (trailing empty cells: missions of different lengths); its cycle ends with its
last value. In a file of one cycle every line with a time needs a speed. Blank lines at
the end are ignored; an empty cell followed by a value is an error.

**Grade to elevation.** A grade g (rise over run: % / 100, or a fraction) is integrated
along the distance travelled, as the CE model's rolling term measures it::

    h_0 = 0,   h_{i+1} = h_i + d_i s_i / sqrt(1 + s_i^2)
    d_i = (v_i + v_{i+1}) / 2 (t_{i+1} - t_i),   s_i = (g_i + g_{i+1}) / 2

(d_i along the road, so the rise is d_i sin(atan s_i)).

**Plausibility bounds** (refused with file, line and column; docs/reference/formats.md, "Cycle files"):
speed at most :data:`MAX_SPEED_KMH`, acceleration and deceleration at most
:data:`MAX_ACCEL_MPS2` between samples, grade at most :data:`MAX_GRADE` (given, or of
an elevation profile: each step's rise at most MAX_GRADE times its distance plus
:data:`ELEVATION_ROUNDING_M`), elevation within +-:data:`MAX_ABS_ELEVATION_M`, at most
:data:`MAX_CYCLE_SAMPLES` samples in a file (over its cycles) and
:data:`MAX_COMMAND_CYCLE_SAMPLES` over the files of one command (:func:`read_cycle_files`),
which bound the memory a command takes (refused at the line past the bound, before the
rest is read), a median sample spacing within
:data:`MAX_MEDIAN_STEP_S` (a time column in milliseconds read as seconds). A grade
column read in % that looks like fractions (all within :data:`FLAT_GRADE_MAX_PCT` over
kilometres) is read, with a :class:`CycleWarning`.
"""

from __future__ import annotations

import dataclasses
import difflib
import fnmatch
import math
import re
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from cevm.core.cycle import DriveCycle
from cevm.errors import InputError
from cevm.io.numeric_csv import (
    SEPARATORS,
    CsvLayout,
    data_line,
    describe_missing,
    read_numeric_columns,
    separator_name,
    sniff_csv,
)
from cevm.units import FT_TO_M, KMH_TO_MPS, MPH_TO_MPS, S_PER_H

#: Highest speed of a cycle [km/h]: above every road vehicle a fleet runs (production
#: cars are mostly limited to 250 km/h; EU speed limiters hold trucks to 90 and buses to
#: 100 km/h). A cycle at 99,999 km/h (a unit mistake a user made) is refused here.
MAX_SPEED_KMH = 300.0
#: Largest acceleration or deceleration between two samples [m/s^2], about 1.5 g: more
#: than tyre grip on a dry road allows any road vehicle (friction coefficient about
#: 1.0-1.3), so a step beyond it is a recording or unit error.
MAX_ACCEL_MPS2 = 15.0
#: Steepest road grade [-] (40 %): the steepest public streets are about 35-37 %.
MAX_GRADE = 0.40
#: Allowance on an elevation step [m] beyond MAX_GRADE x its distance: a profile given
#: in whole metres changes by 1 m at once, even at walking pace.
ELEVATION_ROUNDING_M = 1.0
#: Largest elevation, absolute or relative to the start [m]: no road lies above
#: 5,800 m or below -430 m.
MAX_ABS_ELEVATION_M = 10_000.0
#: Most samples in one cycle file, over all its cycles (lines x the speed columns read):
#: 11.6 days at 1 Hz, 28 h at 10 Hz; a drive cycle holds thousands (WLTC 1,800, VECTO's
#: long haul about 10,000). It bounds what one file costs: at this bound ``cevm simulate``
#: peaked at 363-405 MB, ``predict`` and ``feasibility`` at 290-330 MB (at 9.9 million
#: samples, the bound before: 1.75 GB; benchmarks/bench_memory.py).
MAX_CYCLE_SAMPLES = 1_000_000
#: Most samples over all the cycle files one command reads (``--cycle`` given several
#: times): they are held together. Two files at the per-file bound peaked at 370-430 MB
#: in ``predict`` and ``feasibility`` with three vehicles and ``--range``.
MAX_COMMAND_CYCLE_SAMPLES = 2_000_000
#: Widest typical spacing of a cycle's samples [s] (the median step): drive cycles and
#: loggers sample every 0.1-10 s; a median step of minutes cannot describe driving (a
#: stop, a start), and is a time column in milliseconds read as seconds (UKBUS6 at
#: 1,000 "s" a step: 12,125 km).
MAX_MEDIAN_STEP_S = 60.0
#: A grade column in % whose largest value is below this [%] over at least
#: :data:`FLAT_GRADE_MIN_DISTANCE_M` of road is warned about: roads climb 1 % somewhere
#: in a few km, so such values are likelier fractions (0.02 = 2 %) read as percent, which
#: flattens the road (``--grade-unit``).
FLAT_GRADE_MAX_PCT = 1.0
#: Road a grade column must cover before a flat-looking one in % is warned about [m].
FLAT_GRADE_MIN_DISTANCE_M = 2000.0


class CycleWarning(UserWarning):
    """A cycle file that reads, but probably not as meant (a grade in % that looks like
    fractions): the command line prints it as one ``cevm: warning:`` line."""


#: Speed units: accepted spellings -> (canonical name, factor to m/s).
SPEED_UNITS = {"km/h": ("km/h", KMH_TO_MPS), "kmh": ("km/h", KMH_TO_MPS), "kph": ("km/h", KMH_TO_MPS),
               "m/s": ("m/s", 1.0), "mps": ("m/s", 1.0), "mph": ("mph", MPH_TO_MPS)}
#: Grade units: accepted spellings -> (canonical name, factor to a fraction).
GRADE_UNITS = {"%": ("%", 0.01), "pct": ("%", 0.01), "percent": ("%", 0.01),
               "fraction": ("fraction", 1.0), "frac": ("fraction", 1.0), "-": ("fraction", 1.0)}
_TIME_UNITS = {"s": 1.0, "sec": 1.0, "secs": 1.0, "seconds": 1.0, "ms": 1e-3, "min": 60.0, "h": S_PER_H}
_ELEVATION_UNITS = {"m": 1.0, "ft": FT_TO_M}
_BASES = {
    "time": {"time", "t"},
    "speed": {"speed", "v", "velocity", "vehiclespeed"},
    "elevation": {"elevation", "altitude", "height", "alt"},
    "grade": {"grade", "gradient", "slope", "roadgrade"},
}
_UNIT_SUFFIX = re.compile(r"^(?P<base>[a-z][a-z ]*?)_(?P<unit>kmh|kph|mps|mph|s|ms|min|h|m|ft|pct|percent|fraction)$")
_UNIT_BRACKET = re.compile(r"^(?P<base>.+?)\s*[\[(]\s*(?P<unit>[^\])]*?)\s*[\])]$")


def _name_parts(name: str) -> tuple[str, str | None]:
    """(base, unit) of a column name: 'Speed [km/h]' -> ('speed', 'km/h');
    'speed_kmh' -> ('speed', 'kmh'); 'Long haul, 26t' -> ('longhaul,26t', None)."""
    low = name.strip().lower()
    m = _UNIT_BRACKET.match(low) or _UNIT_SUFFIX.match(low)
    base, unit = (m.group("base"), m.group("unit")) if m else (low, None)
    return re.sub(r"[\s_\-]+", "", base), unit


def _norm_unit(text: str | None, table: dict, what: str, where: str | Path) -> tuple[str, float] | None:
    if text is None:
        return None
    key = text.strip().lower().replace(" ", "")
    if key not in table:
        names = sorted({v[0] if isinstance(v, tuple) else k for k, v in table.items()})
        raise InputError(where, f"unknown {what} unit {text!r}; use one of {', '.join(names)}")
    return table[key]


@dataclass(frozen=True)
class CycleFormat:
    """How to read a cycle file; every field None (or empty) is detected.

    - ``sep``, ``decimal``: separator (``,`` ``;`` tab ``|``) and decimal mark (``.`` or ``,``)
    - ``time_column``; or ``time_step_s``: samples evenly spaced, from t = 0 (any time column ignored)
    - ``speed_columns``: names or glob patterns (``Long haul*``); each column is one cycle
    - ``speed_unit``: ``km/h``, ``m/s`` or ``mph`` (else from the column name)
    - ``elevation_column`` [m, or ft by name]; or ``grade_column`` with ``grade_unit``
      (``%`` or ``fraction``, else from the name) and optionally ``grade_file``, a second
      file with the same rows (its grade column for a speed column is the one of the
      same name unless ``grade_column`` is given)
    """

    sep: str | None = None
    decimal: str | None = None
    time_column: str | None = None
    time_step_s: float | None = None
    speed_columns: tuple[str, ...] = ()
    speed_unit: str | None = None
    elevation_column: str | None = None
    grade_column: str | None = None
    grade_unit: str | None = None
    grade_file: Path | None = None

    def __post_init__(self) -> None:
        if isinstance(self.speed_columns, str):
            object.__setattr__(self, "speed_columns", (self.speed_columns,))
        else:
            object.__setattr__(self, "speed_columns", tuple(self.speed_columns))
        if self.grade_file is not None:
            object.__setattr__(self, "grade_file", Path(self.grade_file))

    def check(self, where: str | Path | None = None) -> CycleFormat:
        """Refuse contradictory or impossible options (InputError naming ``where``)."""
        where = where if where is not None else "cycle options"
        if self.sep is not None and self.sep not in SEPARATORS:
            raise InputError(where, f"separator {self.sep!r} not supported; use one of "
                                    f"{', '.join(map(separator_name, SEPARATORS))}")
        if self.decimal is not None and self.decimal not in (".", ","):
            raise InputError(where, f"decimal mark {self.decimal!r} not supported; use '.' or ','")
        if self.sep is not None and self.sep == self.decimal:
            raise InputError(where, f"the separator and the decimal mark cannot both be {self.sep!r}")
        if self.time_step_s is not None:
            if not (isinstance(self.time_step_s, (int, float)) and math.isfinite(self.time_step_s)
                    and self.time_step_s > 0):
                raise InputError(where, f"time step must be a positive number of seconds, got {self.time_step_s!r}")
            if self.time_column is not None:
                raise InputError(where, "give a time column or a time step, not both")
        if self.elevation_column is not None and (self.grade_column is not None or self.grade_file is not None):
            raise InputError(where, "give an elevation column or a grade (column, file), not both")
        _norm_unit(self.speed_unit, SPEED_UNITS, "speed", where)
        _norm_unit(self.grade_unit, GRADE_UNITS, "grade", where)
        return self

    def is_default(self) -> bool:
        return self == CycleFormat()

    #: Keys of a leg table (fleet scenarios) and of :meth:`from_mapping`.
    KEYS = ("sep", "decimal", "time_column", "time_step_s", "speed_column", "speed_unit", "elevation_column",
            "grade_column", "grade_unit", "grade_file")

    @classmethod
    def from_mapping(cls, table: Mapping[str, Any], where: str | Path, base_dir: Path | None = None) -> CycleFormat:
        """From keys of :data:`KEYS` (a fleet scenario's leg table): strings, except
        ``time_step_s`` (a number) and ``speed_column`` (a string or a list); a
        relative ``grade_file`` is taken relative to ``base_dir``."""
        kw: dict[str, Any] = {}
        for key, value in table.items():
            if key not in cls.KEYS:
                continue
            if key == "time_step_s":
                if isinstance(value, bool) or not isinstance(value, (int, float)):
                    raise InputError(where, f"{key} must be a number, got {value!r}")
                kw[key] = float(value)
            elif key == "speed_column":
                vals = [value] if isinstance(value, str) else value
                if not isinstance(vals, (list, tuple)) or not vals or not all(isinstance(v, str) and v for v in vals):
                    raise InputError(where, f"{key} must be a column name or a list of them, got {value!r}")
                kw["speed_columns"] = tuple(vals)
            else:
                if not isinstance(value, str) or not value:
                    raise InputError(where, f"{key} must be a non-empty string, got {value!r}")
                if key == "grade_file":
                    p = Path(value)
                    kw[key] = p if p.is_absolute() or base_dir is None else base_dir / p
                else:
                    kw[key] = value
        return cls(**kw).check(where)

    def to_items(self) -> tuple[tuple[str, Any], ...]:
        """The options that differ from the default, as (key, value) pairs (hashable)."""
        out = []
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if v != f.default and v != ():
                out.append((f.name, str(v) if isinstance(v, Path) else v))
        return tuple(out)

    @classmethod
    def from_items(cls, items) -> CycleFormat:
        return cls(**dict(items))


# ----------------------------------------------------------------------------- columns


def _find_named(layout: CsvLayout, name: str, option: str) -> int:
    """Position of the column the user named (exactly, else ignoring case and spaces)."""
    if name in layout.header:
        return layout.index(name)
    folded = [re.sub(r"\s+", "", h.lower()) for h in layout.header]
    key = re.sub(r"\s+", "", name.lower())
    if key in folded:
        return folded.index(key)
    close = difflib.get_close_matches(name, layout.header, n=1)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    raise InputError(layout.path, f"no column {name!r} ({option}){hint}; the header has: {_header_list(layout)}",
                     line=1)


def _header_list(layout: CsvLayout, limit: int = 12) -> str:
    names = [repr(h) for h in layout.header[:limit]]
    more = f", ... ({len(layout.header)} columns)" if len(layout.header) > limit else ""
    return ", ".join(names) + more


def _detect(layout: CsvLayout, kind: str) -> list[int]:
    return [i for i, h in enumerate(layout.header) if _name_parts(h)[0] in _BASES[kind]]


def _pick_one(layout: CsvLayout, kind: str, option: str) -> int | None:
    found = _detect(layout, kind)
    if len(found) > 1:
        if kind == "speed":  # the old layout: speed_mps wins over speed_kmh
            legacy = [i for i in found if layout.header[i] in ("speed_mps", "speed_kmh")]
            if len(legacy) == len(found):
                return layout.index("speed_mps") if "speed_mps" in layout.header else legacy[0]
        names = ", ".join(repr(layout.header[i]) for i in found)
        raise InputError(layout.path, f"several {kind} columns ({names}); choose one ({option})", line=1)
    return found[0] if found else None


def _speed_columns(layout: CsvLayout, fmt: CycleFormat, exclude: set[int | None]) -> list[int]:
    """The selected speed columns; patterns do not match the ``exclude``d (time) column."""
    if not fmt.speed_columns:
        i = _pick_one(layout, "speed", "--speed-col")
        if i is None:
            raise InputError(layout.path, "no speed column found (speed_kmh, speed_mps, 'Speed [km/h]', ...); name it "
                                          f"(--speed-col); the header has: {_header_list(layout)}", line=1)
        return [i]
    out: list[int] = []
    for spec in fmt.speed_columns:
        if any(ch in spec for ch in "*?["):
            hits = [i for i, h in enumerate(layout.header) if fnmatch.fnmatchcase(h, spec) and i not in exclude]
            if not hits:
                raise InputError(layout.path, f"no column matches {spec!r} (--speed-col); the header has: "
                                              f"{_header_list(layout)}", line=1)
        else:
            hits = [_find_named(layout, spec, "--speed-col")]
        out += [i for i in hits if i not in out]
    return out


def _unit_of(layout: CsvLayout, col: int, given: str | None, table: dict, what: str, option: str,
             default: tuple[str, float] | None = None) -> tuple[str, float]:
    """The (unit, factor) of a column: the given unit, else its name's, else ``default``,
    else an error asking for it; a name that says otherwise than the option is refused."""
    name = layout.header[col]
    from_name = None
    unit = _name_parts(name)[1]
    if unit is not None:
        from_name = table.get(unit.replace(" ", ""))
    chosen = _norm_unit(given, table, what, layout.path)
    if chosen is not None:
        if from_name is not None and from_name[0] != chosen[0]:
            raise InputError(layout.path, f"the column name says {from_name[0]} but the {what} unit given is "
                                          f"{chosen[0]}", line=1, column=name)
        return chosen
    if from_name is not None:
        return from_name
    if default is not None:
        return default
    names = sorted({v[0] for v in table.values()})
    raise InputError(layout.path, f"the {what} unit is not in the column name; give it ({option} "
                                  f"{' or '.join(names)})", line=1, column=name)


# ----------------------------------------------------------------------------- reading


def _extent(values: np.ndarray) -> int:
    """Number of rows up to the column's last value (trailing empty cells end it)."""
    if values.size and not np.isnan(values[-1]):
        return int(values.size)
    finite = np.flatnonzero(~np.isnan(values))
    return int(finite[-1]) + 1 if finite.size else 0


def _require(layout: CsvLayout, values: np.ndarray, n: int, col: int) -> np.ndarray:
    """The first ``n`` values of a column, all present (else the error for the first
    missing one)."""
    part = values[:n]
    if part.size < n:  # another file (the grade file) with fewer rows
        raise InputError(layout.path, f"{part.size} data lines, but the cycle has {n} samples; the rows must be "
                                      "the cycle's", line=data_line(layout, part.size), column=layout.header[col])
    if math.isnan(part.sum()):  # no infinities here (refused when read): NaN iff a cell is missing
        raise describe_missing(layout, int(np.flatnonzero(np.isnan(part))[0]), col)
    return part


def _grade_source(layout: CsvLayout, fmt: CycleFormat, speed_cols: list[int], time_col: int | None,
                  grade_col: int | None, arrays: dict, max_rows: int) -> tuple:
    """Where each speed column's road grade comes from: (the grade's layout, its column
    per speed column, the grade file's own time column, the arrays read, the unit factor);
    no grade: (None, {}, None, {}, None). A grade file is read here (the columns named as
    the speed columns, or --grade-col)."""
    grade_cols: dict[int, int]
    grade_layout, grade_cols, grade_time, grade_arrays = None, {}, None, {}
    if fmt.grade_file is not None:
        grade_layout = sniff_csv(fmt.grade_file, sep=fmt.sep, decimal=fmt.decimal, what="grade file")
        for c in speed_cols:
            name = fmt.grade_column if fmt.grade_column is not None else layout.header[c]
            grade_cols[c] = _find_named(grade_layout, name, "--grade-col" if fmt.grade_column else
                                        "the speed column's name in the grade file; else give --grade-col")
        # the grade file's own time column, when it has one of the same name: its rows
        # must be the cycle's (checked below)
        grade_time = (grade_layout.header.index(layout.header[time_col])
                      if time_col is not None and layout.header[time_col] in grade_layout.header else None)
        gcols = list(dict.fromkeys([*grade_cols.values(), *([grade_time] if grade_time is not None else [])]))
        grade_arrays = dict(zip(gcols, read_numeric_columns(grade_layout, gcols, what="grade file",
                                                            max_rows=max_rows), strict=True))
    elif grade_col is not None:
        grade_layout, grade_arrays = layout, arrays
        grade_cols = dict.fromkeys(speed_cols, grade_col)
    grade_factor = None
    if grade_cols:
        assert grade_layout is not None  # set with grade_cols
        gunits = {_unit_of(grade_layout, g, fmt.grade_unit, GRADE_UNITS, "grade", "--grade-unit")
                  for g in set(grade_cols.values())}
        if len(gunits) > 1:
            raise InputError(grade_layout.path, "the grade columns have different units; give --grade-unit", line=1)
        grade_factor = gunits.pop()[1]
    return grade_layout, grade_cols, grade_time, grade_arrays, grade_factor


def read_cycles(path: str | Path, fmt: CycleFormat | None = None, *,
                max_samples: int | None = None) -> list[DriveCycle]:
    """Every cycle of a cycle file: one per selected speed column (see the module
    docstring). Names: the file's stem, or ``stem[column]`` when the speed columns were
    chosen by :attr:`CycleFormat.speed_columns`.

    Raises :class:`~cevm.errors.InputError` naming file, line (1-based, the header is
    line 1) and column: missing or unreadable file, an undetectable layout or column, a
    cell that is not a number, a gap in a column, time not increasing, fewer than 2
    samples, and every plausibility bound of the module docstring, and more than
    ``max_samples`` samples over the file's cycles (default :data:`MAX_CYCLE_SAMPLES`).
    """
    fmt = (fmt or CycleFormat()).check()
    max_samples = MAX_CYCLE_SAMPLES if max_samples is None else min(max_samples, MAX_CYCLE_SAMPLES)
    path = Path(path)
    layout = sniff_csv(path, sep=fmt.sep, decimal=fmt.decimal, what="cycle file")
    time_col = None
    time_factor = 1.0
    if fmt.time_step_s is None:
        time_col = (_find_named(layout, fmt.time_column, "--time-col") if fmt.time_column is not None
                    else _pick_one(layout, "time", "--time-col"))
        if time_col is None:
            raise InputError(layout.path, "no time column found (time_s, 'Time', ...); name it (--time-col), or give "
                                          f"a time step (--time-step-s); the header has: {_header_list(layout)}",
                             line=1)
        time_factor = _unit_of(layout, time_col, None, {k: (k, f) for k, f in _TIME_UNITS.items()}, "time", "",
                               default=("s", 1.0))[1]
    speed_cols = _speed_columns(layout, fmt, {time_col})
    units = [_unit_of(layout, c, fmt.speed_unit, SPEED_UNITS, "speed", "--speed-unit") for c in speed_cols]
    if time_col in speed_cols:
        raise InputError(layout.path, "the time column cannot also be a speed column", line=1,
                         column=layout.header[time_col])

    # the road: elevation, or grade in this file or another
    elev_col = grade_col = None
    if fmt.elevation_column is not None:
        elev_col = _find_named(layout, fmt.elevation_column, "--elevation-col")
    elif fmt.grade_file is None and fmt.grade_column is not None:
        grade_col = _find_named(layout, fmt.grade_column, "--grade-col")
    elif fmt.grade_file is None:
        elev_col = _pick_one(layout, "elevation", "--elevation-col")
        if elev_col is None:
            grade_col = _pick_one(layout, "grade", "--grade-col")

    wanted = [c for c in [time_col, *speed_cols, elev_col, grade_col] if c is not None]
    wanted = list(dict.fromkeys(wanted))
    max_rows = max(max_samples // len(speed_cols), 0)  # every cycle of the file has at most this many samples
    try:
        arrays = dict(zip(wanted, read_numeric_columns(layout, wanted, what="cycle file", max_rows=max_rows),
                          strict=True))
    except InputError as exc:
        if exc.message.startswith("more than "):
            raise _too_long(layout.path, max_rows, len(speed_cols), max_samples, exc.line) from None
        raise

    grade_layout, grade_cols, grade_time, grade_arrays, grade_factor = _grade_source(
        layout, fmt, speed_cols, time_col, grade_col, arrays, max_rows)
    elev_factor = (_unit_of(layout, elev_col, None, {k: (k, f) for k, f in _ELEVATION_UNITS.items()}, "elevation",
                            "", default=("m", 1.0))[1] if elev_col is not None else None)

    stem = Path(path.name.removesuffix(".gz")).stem
    cycles = []
    for c, (unit, factor) in zip(speed_cols, units, strict=True):
        speed_raw = arrays[c]
        n = _extent(speed_raw)
        if time_col is not None and not fmt.speed_columns:
            # one cycle in the file: every line with a time has a speed (a short or
            # truncated last line is an error, not the end of the cycle)
            n = max(n, _extent(arrays[time_col]))
        if time_col is not None:
            n_time = _extent(arrays[time_col])
            if n_time < n:
                raise InputError(layout.path, f"column {layout.header[time_col]!r} ends at line "
                                              f"{data_line(layout, n_time - 1)} but {layout.header[c]!r} goes on to "
                                              f"line {data_line(layout, n - 1)}; if the samples are "
                                              "evenly spaced, give the time step (--time-step-s)",
                                 line=data_line(layout, n_time), column=layout.header[time_col])
        if n < 2:
            raise InputError(layout.path, "a cycle needs at least 2 samples", line=data_line(layout, n))
        v_raw = _require(layout, speed_raw, n, c)
        if time_col is not None:
            t = _require(layout, arrays[time_col], n, time_col)
            t = t * time_factor if time_factor != 1.0 else t
        else:
            assert fmt.time_step_s is not None  # CycleFormat.checked: a time column or a time step
            t = np.arange(n, dtype=np.float64) * fmt.time_step_s
        dt = np.diff(t)
        _check_time(layout, t, dt, time_col)
        _check_spacing(layout, dt, time_col, time_factor)
        v = v_raw * factor if factor != 1.0 else v_raw
        _check_speed(layout, c, v, v_raw, t, dt, unit)
        elevation = None
        if elev_col is not None:
            h = _require(layout, arrays[elev_col], n, elev_col)
            h = h * elev_factor if elev_factor != 1.0 else h
            _check_elevation(layout, elev_col, v, dt, h)
            elevation = h
        elif c in grade_cols:
            assert grade_layout is not None and grade_factor is not None  # set with grade_cols
            if grade_time is not None:
                _same_rows(grade_layout, grade_time, grade_arrays[grade_time], t / time_factor, layout)
            g_raw = _require(grade_layout, grade_arrays[grade_cols[c]], n, grade_cols[c])
            g = g_raw * grade_factor
            _check_grade(grade_layout, grade_cols[c], g, g_raw)
            _check_grade_unit(grade_layout, grade_cols[c], g_raw, grade_factor, v, dt)
            elevation = elevation_from_grade(t, v, g)
        name = f"{stem}[{layout.header[c]}]" if fmt.speed_columns else stem
        cycles.append(DriveCycle(time_s=t, speed_mps=v, elevation_m=elevation, name=name))
    return cycles


def read_cycle_csv(path: str | Path, fmt: CycleFormat | None = None) -> DriveCycle:
    """The one cycle of a cycle file (see :func:`read_cycles`; a selection of several
    speed columns is refused here).

    The old layout needs no options: a header with ``time_s`` and ``speed_kmh`` or
    ``speed_mps``, and optionally ``elevation_m``; other columns are ignored. Errors raise
    :class:`~cevm.errors.InputError` with the file, the line (1-based, the header is
    line 1) and the column.
    """
    cycles = read_cycles(path, fmt)
    if len(cycles) != 1:
        names = ", ".join(repr(c.name) for c in cycles[:5])
        raise InputError(path, f"{len(cycles)} speed columns selected ({names}); one is needed here")
    return cycles[0]


def read_cycle_files(paths, fmt: CycleFormat | None = None) -> list[DriveCycle]:
    """:func:`read_cycles` of each path, in order, concatenated: at most
    :data:`MAX_COMMAND_CYCLE_SAMPLES` samples over them all (they are held together), a
    file refused at the line past what the files before it left."""
    out: list[DriveCycle] = []
    left = MAX_COMMAND_CYCLE_SAMPLES
    for p in paths:
        used = MAX_COMMAND_CYCLE_SAMPLES - left
        together = (f"the cycle files of one command hold at most {MAX_COMMAND_CYCLE_SAMPLES:,} samples together, "
                    f"and the ones before it {used:,}: give fewer or shorter files")
        if left < 2:
            raise InputError(p, together)
        try:
            cycles = read_cycles(p, fmt, max_samples=left)
        except CycleTooLong as exc:
            if exc.max_samples < MAX_CYCLE_SAMPLES:  # the budget the files before it left, not the file's own
                raise InputError(exc.path, f"more than the {left:,} samples left: {together}", line=exc.line) from None
            raise
        left -= sum(c.time_s.size for c in cycles)
        out += cycles
    return out


class CycleTooLong(InputError):
    """A cycle file beyond the samples it may hold (``max_samples``, over its cycles:
    the file's own bound, or what a command's or a route's files before it left)."""

    max_samples: int = 0


def _too_long(path: Path, max_rows: int, n_cycles: int, max_samples: int, line: int | None) -> CycleTooLong:
    each = f" ({n_cycles} speed columns: {max_rows:,} lines each)" if n_cycles > 1 else ""
    err = CycleTooLong(path, f"more than {max_samples:,} samples{each}: the most a cycle file may hold (about 400 "
                         "bytes of memory a sample at the peak of 'cevm simulate'); give a shorter part", line=line)
    err.max_samples = max_samples
    return err


# ------------------------------------------------------------------------------ checks


def _check_time(layout: CsvLayout, t: np.ndarray, dt: np.ndarray, col: int | None) -> None:
    if not dt.min() > 0:
        i = int(np.flatnonzero(~(dt > 0))[0]) + 1
        raise InputError(layout.path, f"time does not increase ({t[i - 1]:g} then {t[i]:g})", line=data_line(layout, i),
                         column=layout.header[col] if col is not None else None)


def _check_speed(layout: CsvLayout, col: int, v: np.ndarray, v_raw: np.ndarray, t: np.ndarray, dt: np.ndarray,
                 unit: str) -> None:
    """Speeds within [0, MAX_SPEED_KMH] and accelerations within +-MAX_ACCEL_MPS2
    (reductions first; the first offender is looked for only when there is one)."""
    name = layout.header[col]
    if v.min() < 0:
        i = int(np.flatnonzero(v < 0)[0])
        raise InputError(layout.path, f"negative speed {v_raw[i]:g}", line=data_line(layout, i), column=name)
    vmax = MAX_SPEED_KMH * KMH_TO_MPS
    if v.max() > vmax:
        i = int(np.flatnonzero(v > vmax)[0])
        raise InputError(layout.path, f"speed {v_raw[i]:g} {unit} ({v[i] / KMH_TO_MPS:.0f} km/h) is beyond "
                                      f"{MAX_SPEED_KMH:g} km/h, the bound for road vehicles (wrong unit?)",
                         line=data_line(layout, i), column=name)
    acc = np.diff(v)
    acc /= dt
    if acc.max() > MAX_ACCEL_MPS2 or acc.min() < -MAX_ACCEL_MPS2:
        i = int(np.flatnonzero(np.abs(acc) > MAX_ACCEL_MPS2)[0])
        raise InputError(layout.path, f"{'acceleration' if acc[i] > 0 else 'deceleration'} "
                                      f"{abs(acc[i]):.3g} m/s^2 ({v_raw[i]:g} to {v_raw[i + 1]:g} {unit} in "
                                      f"{t[i + 1] - t[i]:g} s) is beyond {MAX_ACCEL_MPS2:g} m/s^2, more than "
                                      "tyres allow any road vehicle", line=data_line(layout, i + 1), column=name)


def _check_elevation(layout: CsvLayout, col: int, v: np.ndarray, dt: np.ndarray, h: np.ndarray) -> None:
    """Elevations within +-MAX_ABS_ELEVATION_M, each step's rise at most MAX_GRADE times
    its distance plus ELEVATION_ROUNDING_M."""
    name = layout.header[col]
    if h.max() > MAX_ABS_ELEVATION_M or h.min() < -MAX_ABS_ELEVATION_M:
        i = int(np.flatnonzero(np.abs(h) > MAX_ABS_ELEVATION_M)[0])
        raise InputError(layout.path, f"elevation {h[i]:g} m is beyond +-{MAX_ABS_ELEVATION_M:g} m (no road is "
                                      "higher than 5,800 m; wrong unit or scale?)", line=data_line(layout, i),
                         column=name)
    allowed = v[1:] + v[:-1]
    allowed *= dt
    allowed *= 0.5 * MAX_GRADE
    allowed += ELEVATION_ROUNDING_M
    excess = np.diff(h)
    np.abs(excess, out=excess)
    excess -= allowed
    if excess.max() > 0:
        i = int(np.flatnonzero(excess > 0)[0])
        d = 0.5 * (v[i] + v[i + 1]) * dt[i]
        raise InputError(layout.path, f"elevation changes by {h[i + 1] - h[i]:+.3g} m over {d:.3g} m of road: "
                                      f"steeper than {MAX_GRADE:.0%} (plus {ELEVATION_ROUNDING_M:g} m for rounding)",
                         line=data_line(layout, i + 1), column=name)


def _same_rows(grade_layout: CsvLayout, col: int, grade_t: np.ndarray, t: np.ndarray, layout: CsvLayout) -> None:
    """A grade file's time column must hold the cycle file's times, row for row."""
    other = _require(grade_layout, grade_t, t.size, col)
    diff = ~(other == t)
    if diff.any():
        i = int(np.flatnonzero(diff)[0])
        raise InputError(grade_layout.path, f"time {other[i]:g} where the cycle file {layout.path.name} has "
                                            f"{t[i]:g} (line {data_line(layout, i)}): the grade file's rows must be "
                                            "the cycle's", line=data_line(grade_layout, i),
                         column=grade_layout.header[col])


def _check_spacing(layout: CsvLayout, dt: np.ndarray, col: int | None, factor: float) -> None:
    """A median sample spacing within :data:`MAX_MEDIAN_STEP_S` (a time column in
    milliseconds read as seconds is refused, naming the column)."""
    if dt.size and np.count_nonzero(dt <= MAX_MEDIAN_STEP_S) > dt.size // 2:
        return  # more than half the steps within the bound: so is the median (no sort)
    step = float(np.median(dt)) if dt.size else 0.0
    if step <= MAX_MEDIAN_STEP_S:
        return
    name = None if col is None else layout.header[col]
    if col is None:
        raise InputError(layout.path, f"a time step of {step:g} s: drive cycles are sampled every 0.1-10 s "
                                      f"(at most {MAX_MEDIAN_STEP_S:g} s); give --time-step-s in seconds")
    unit = "s" if factor == 1.0 else f"s after its unit ({factor:g} s per unit)"
    raise InputError(layout.path, f"samples are {step:g} {unit} apart (the median step): drive cycles are sampled "
                                  f"every 0.1-10 s (at most {MAX_MEDIAN_STEP_S:g} s); a time in milliseconds read "
                                  "as seconds? name the unit in the column (time_ms, 'Time [ms]') or give "
                                  "--time-step-s", line=data_line(layout, 1), column=name)


def _check_grade_unit(layout: CsvLayout, col: int, g_raw: np.ndarray, factor: float, v: np.ndarray,
                      dt: np.ndarray) -> None:
    """A warning (:class:`CycleWarning`) for a grade column read in % whose values all
    stay below :data:`FLAT_GRADE_MAX_PCT` over at least
    :data:`FLAT_GRADE_MIN_DISTANCE_M` of road: likelier fractions, which % flattens."""
    if factor != 0.01 or not np.any(g_raw != 0):
        return
    distance = float(np.sum(0.5 * (v[1:] + v[:-1]) * dt))
    top = float(np.max(np.abs(g_raw)))
    if top < FLAT_GRADE_MAX_PCT and distance >= FLAT_GRADE_MIN_DISTANCE_M:
        warnings.warn(CycleWarning(
            f"{layout.path}: column {layout.header[col]!r}: read in %, its grades stay within +-{top:g} % over "
            f"{distance / 1000:,.1f} km, a nearly flat road; if they are fractions ({top:g} = {top:.0%}), give "
            "--grade-unit fraction"), stacklevel=2)


def _check_grade(layout: CsvLayout, col: int, g: np.ndarray, g_raw: np.ndarray) -> None:
    steep = np.abs(g) > MAX_GRADE
    if steep.any():
        i = int(np.flatnonzero(steep)[0])
        raise InputError(layout.path, f"grade {g_raw[i]:g} ({g[i]:.1%}) is steeper than {MAX_GRADE:.0%}, the "
                                      "bound for roads (wrong unit? give the grade unit)", line=data_line(layout, i),
                         column=layout.header[col])


def elevation_from_grade(time_s: np.ndarray, speed_mps: np.ndarray, grade: np.ndarray) -> np.ndarray:
    """Elevation [m], 0 at the start, from a per-sample road grade [-] (rise over run)
    integrated along the trapezoidal distance of each step: h_{i+1} = h_i + d_i s_i /
    sqrt(1 + s_i^2), s_i the mean grade of the step's two samples."""
    v = np.asarray(speed_mps, dtype=np.float64)
    g = np.asarray(grade, dtype=np.float64)
    d = 0.5 * (v[1:] + v[:-1]) * np.diff(np.asarray(time_s, dtype=np.float64))
    s = 0.5 * (g[1:] + g[:-1])
    h = np.empty(v.size)
    h[0] = 0.0
    np.cumsum(d * s / np.sqrt(1.0 + s * s), out=h[1:])
    return h
