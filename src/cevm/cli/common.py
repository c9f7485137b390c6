"""What the command modules share: exit codes, common options, the one-line error.

Exit codes: 0 success; 1 some inputs of a batch failed (the rest was done: failed files,
manifest rows that matched no trip, damaged trips skipped); 2 bad usage or bad input
(nothing was done); 3 the store could not be written (or read): disk full, read-only,
locked by another process past the busy timeout, an I/O error; the store is as it was
before the write that failed; likewise an output that could not be written (stdout, an
--out or --plot file: a full disk, an I/O error; :func:`os_error_exit`); 4 the store is
damaged (a damaged database file, or a damaged trip or route asked for by name): restore
a backup or re-ingest, 'cevm store check' says where.
"""

from __future__ import annotations

import errno
import functools
import inspect
import math
import os
import sys
from contextlib import ExitStack
from pathlib import Path
from typing import IO, Annotated

import typer

from cevm.cli.output import OutputFormat
from cevm.core.model import ICE_BRAKING_MODES
from cevm.errors import CevmError, OutputError, os_error_text
from cevm.io.outputs import OutFile
from cevm.text import one_line, printable

EXIT_OK = 0
EXIT_PARTIAL = 1
EXIT_INPUT = 2
EXIT_STORE_ACCESS = 3
EXIT_STORE_DAMAGED = 4
#: The reader of the output went away (``cevm trips | head``): nothing is said, and the
#: code is the one a shell gives a process that SIGPIPE ended (128 + 13).
EXIT_BROKEN_PIPE = 141


StoreOption = Annotated[
    Path | None,
    typer.Option("--store", envvar="CEVM_STORE", metavar="FILE",
                 help="Trip store (SQLite). Default: $CEVM_STORE, else ~/.local/share/cevm/cevm.sqlite."),
]


def exit_code_for(exc: BaseException) -> int:
    """The exit code of an error that stops a command: :data:`EXIT_STORE_ACCESS` or
    :data:`EXIT_STORE_DAMAGED` for the store's failures, else :data:`EXIT_INPUT`."""
    from cevm.store.failures import DamagedRowError, StoreAccessError, StoreDamagedError

    if isinstance(exc, (StoreAccessError, OutputError)):
        return EXIT_STORE_ACCESS
    if isinstance(exc, (StoreDamagedError, DamagedRowError)):
        return EXIT_STORE_DAMAGED
    return EXIT_INPUT


def fail(message: str | BaseException, code: int | None = None) -> typer.Exit:
    """Print the one-line error (control characters escaped: a file name holding a
    newline cannot forge a second line) and return the Exit to raise: ``fail(exc)``
    picks the code for the error (:func:`exit_code_for`), ``fail(text)`` is bad input (2)."""
    if code is None:
        code = exit_code_for(message) if isinstance(message, BaseException) else EXIT_INPUT
    typer.echo(f"cevm: error: {one_line(str(message))}", err=True)
    return typer.Exit(code)


def warn(message: str) -> None:
    """A one-line warning on stderr (control characters escaped)."""
    typer.echo(f"cevm: warning: {one_line(message)}", err=True)


def note_flat_cycles(sources) -> None:
    """A note for the cycles that give no elevation or grade, and the stored trips that
    had neither DSM nor GPS elevation at ingest: their road is taken as flat (on hilly
    roads an error of tens of percent), so the number says it."""
    def note(flat: list[str], what: str, remedy: str) -> None:
        if flat:
            names = ", ".join(flat[:3]) + (", ..." if len(flat) > 3 else "")
            typer.echo(f"cevm: note: {len(flat)} {what} ({printable(names)}): a flat road assumed ({remedy})", err=True)

    note([s.name for s in sources if s.kind == "cycle" and all(leg.elevation_m is None for leg in s.leg_profiles)],
         "cycle(s) without elevation or grade", "add an elevation column, or give --grade-col / --grade-file")
    note([s.name for s in sources if getattr(s, "elevation_source", None) == "flat"],
         "stored trip(s) had neither DSM nor GPS elevation at ingest", "re-ingest with --dsm")


def warn_ambient_unused(vehicles: list[tuple[str, bool]], asked: str) -> None:
    """For each ``(vehicle label, whether a term of its model depends on the ambient
    temperature)`` without one: a warning that the temperature ``asked`` for (e.g.
    "--ambient-c -10") changes nothing for it, so that a winter question does not get a
    summer answer without a word."""
    for label, uses in vehicles:
        if not uses:
            warn(f"{label}: no term of its model depends on the ambient temperature (heating, A/C, warm-up), so "
                 f"{asked} changes nothing for it; calibrating it on trips whose logged temperatures span heating "
                 "and A/C weather can add them")


def warn_damaged(exc: BaseException) -> None:
    """The warning for a damaged trip that a command skips (and counts: exit 1)."""
    warn(f"skipped: {exc}")


def existing_store(store: Path | None, hint: str | None = None) -> Path:
    """The store a reading command needs, or the usual one-line error (exit 2)."""
    from cevm.store import NO_STORE_HINT, existing_store_path

    try:
        return existing_store_path(store, hint or NO_STORE_HINT)
    except CevmError as exc:
        raise fail(exc) from None


#: Rows printed by ``--format table``; beyond that, use csv or json.
TABLE_MAX_ROWS = 200


VehicleOption = Annotated[
    list[Path],
    typer.Option("--vehicle", "-v", metavar="FILE|DIR", help="Vehicle TOML file, or a directory of them. Repeatable.")
]
CycleOption = Annotated[
    list[Path] | None,
    typer.Option("--cycle", "-c", metavar="FILE",
                 help="Cycle file, CSV or .csv.gz: time_s, speed_kmh or speed_mps, elevation_m "
                      "(optional), or the columns the cycle options name. Repeatable."),
]
TripOption = Annotated[
    list[str] | None,
    typer.Option("--trip", "-t", metavar="ID", help="A stored trip id (see 'cevm trips'). Repeatable.")
]
VehicleIdOption = Annotated[
    list[str] | None,
    typer.Option("--vehicle-id", metavar="ID", help="All stored trips of this vehicle id. Repeatable.")
]
RouteOption = Annotated[
    list[str] | None,
    typer.Option("--route", "-r", metavar="NAME",
                 help="A stored route (see 'cevm route list'), or a glob such as 'block-*'. Repeatable."),
]
SocStartOption = Annotated[
    float | None, typer.Option("--soc-start", help="EV state of charge at the start [%]. Default: a stored trip's "
                                  "own logged start, else full (100); column soc_start_from says which.")
]

#: Where a row's start state of charge comes from (column ``soc_start_from``): "given"
#: (``--soc-start``; not the option's own name, which CSV would write as '--soc-start, a
#: cell starting with "-" being neutralised as a formula), "logged" or "default".
SOC_FROM_GIVEN, SOC_FROM_LOGGED, SOC_FROM_DEFAULT = "given", "logged", "default"


def start_soc(source, given: float | None) -> tuple[float, str]:
    """(start state of charge [%], where it comes from) of an EV row on ``source``:
    ``--soc-start`` when given, else a stored trip's own logged start state of charge
    (its ``start_soc_pct``), else full (:data:`cevm.core.sweep.DEFAULT_SOC_START_PCT`)."""
    from cevm.core.sweep import DEFAULT_SOC_START_PCT

    if given is not None:
        return float(given), SOC_FROM_GIVEN
    logged = getattr(source, "start_soc_pct", None)
    if logged is not None and math.isfinite(logged) and 0.0 < logged <= 100.0:
        return float(logged), SOC_FROM_LOGGED
    return DEFAULT_SOC_START_PCT, SOC_FROM_DEFAULT
ReserveOption = Annotated[
    float, typer.Option("--reserve-pct",
                        help="EV state of charge to keep all along [%] (default 15, the paper's warning level).")
]
IntervalOption = Annotated[
    float, typer.Option("--interval", metavar="LEVEL", help="Level of each row's interval of energy or fuel "
                        "(columns *_low, *_high): 0.9 is the central 90 % (default). The interval comes from the "
                        "vehicle's calibration, or for a file never calibrated from its class's priors "
                        "(column interval_from).")
]
#: The default confidence of feasibility's verdict and largest payload: the verdict
#: then fails only where the energy (fuel) may land above the default 90 % interval's
#: upper end (energy_kwh_high), which happens 1 time in 20: a planner's "almost surely",
#: and the same number predict shows.
DEFAULT_CONFIDENCE = 0.95
ConfidenceOption = Annotated[
    float, typer.Option("--confidence", metavar="P", help="The probability with which the verdict (feasible) and "
                        "the largest payload keep the reserve or fit the tank. Default 0.95: they fail only where "
                        "the energy or fuel lands above the default 90 % interval's upper end (1 time in 20); 0.5 "
                        "is the point prediction's verdict.")
]
IceBrakingOption = Annotated[
    str | None,
    typer.Option(help=f"Override ICE braking mode: {' or '.join(ICE_BRAKING_MODES)}. Default: the vehicle file's."),
]
AmbientOption = Annotated[
    float | None,
    typer.Option("--ambient-c", help="Ambient temperature [degC] of every prediction (heating and A/C terms). "
                                     "Default: a stored trip's own logged mean, else the vehicle file's "
                                     "reference_temp_c, else 20 degC."),
]
def cr0_check(ctx: typer.Context, param: typer.CallbackParam, value: float) -> float:
    """--cr0 is a rolling resistance coefficient: finite and at least 0 (one line, exit 2)."""
    if value is not None and not (math.isfinite(value) and value >= 0):
        from cevm.core.cycle import CR0_DEFAULT

        raise fail(f"{param.opts[0] if param.opts else '--cr0'} {value:g}: must be a finite number of at least 0 "
                   f"(Cr0 of the simplification criterion; default {CR0_DEFAULT:g})")
    return value


Cr0Option = Annotated[
    float,
    typer.Option(help="Cr0 of the simplification criterion, for --cycle files (stored trips and routes keep theirs).",
                 callback=cr0_check)
]
OutOption = Annotated[Path | None, typer.Option("--out", "-o", metavar="FILE",
                                                help="Write the output to this file instead of stdout.")]

# How cycle files (--cycle) are read: every option is detected when not given
# (cevm.io.cycles). One set applies to every --cycle file of the command.
_CYCLE_PANEL = "Reading cycle files (detected unless given)"
CycleSepOption = Annotated[
    str | None, typer.Option("--cycle-sep", help="Separator: ',', ';', 'tab' or '|'.", rich_help_panel=_CYCLE_PANEL)
]
CycleDecimalOption = Annotated[
    str | None, typer.Option("--cycle-decimal", help="Decimal mark: '.' or ','.", rich_help_panel=_CYCLE_PANEL)
]
TimeColOption = Annotated[
    str | None, typer.Option("--time-col", help="Time column, in seconds. Default: time_s, Time, t, ...",
                             rich_help_panel=_CYCLE_PANEL)
]
TimeStepOption = Annotated[
    float | None,
    typer.Option("--time-step-s", help="Samples evenly spaced by this many seconds, from 0 (no time column).",
                 rich_help_panel=_CYCLE_PANEL),
]
SpeedColOption = Annotated[
    list[str] | None,
    typer.Option("--speed-col", metavar="COLUMN",
                 help="Speed column, or a glob such as 'Long haul*': each column is one cycle "
                      "(files with one mission per column). Repeatable.", rich_help_panel=_CYCLE_PANEL),
]
SpeedUnitOption = Annotated[
    str | None, typer.Option("--speed-unit", help="km/h, m/s or mph. Default: from the column name (speed_kmh, "
                                                     "'Speed (m/s)').", rich_help_panel=_CYCLE_PANEL)
]
ElevationColOption = Annotated[
    str | None, typer.Option("--elevation-col", help="Elevation column, in metres.", rich_help_panel=_CYCLE_PANEL)
]
GradeColOption = Annotated[
    str | None, typer.Option("--grade-col", help="Road grade column, integrated along distance into elevation.",
                                rich_help_panel=_CYCLE_PANEL)
]
GradeUnitOption = Annotated[
    str | None, typer.Option("--grade-unit", help="'%' or 'fraction'. Default: from the column name (grade_pct).",
                                rich_help_panel=_CYCLE_PANEL)
]
GradeFileOption = Annotated[
    Path | None,
    typer.Option("--grade-file", metavar="FILE", help="A second file with the same rows holding the grade: the column "
                                                      "named like the speed column, or --grade-col (VECTO's "
                                                      "gradient_*.csv).", rich_help_panel=_CYCLE_PANEL)
]


_CYCLE_OPTIONS = {
    "cycle_sep": CycleSepOption, "cycle_decimal": CycleDecimalOption, "time_col": TimeColOption,
    "time_step_s": TimeStepOption, "speed_col": SpeedColOption, "speed_unit": SpeedUnitOption,
    "elevation_col": ElevationColOption, "grade_col": GradeColOption, "grade_unit": GradeUnitOption,
    "grade_file": GradeFileOption,
}


def cycle_format(cycle_sep: str | None = None, cycle_decimal: str | None = None, time_col: str | None = None,
                 time_step_s: float | None = None, speed_col: list[str] | None = None,
                 speed_unit: str | None = None, elevation_col: str | None = None, grade_col: str | None = None,
                 grade_unit: str | None = None, grade_file: Path | None = None):
    """The :class:`cevm.io.cycles.CycleFormat` of the cycle options (bad ones: exit 2)."""
    from cevm.io.cycles import CycleFormat

    sep = {"tab": "\t", "\\t": "\t"}.get(cycle_sep, cycle_sep) if cycle_sep is not None else None
    try:
        return CycleFormat(sep=sep, decimal=cycle_decimal, time_column=time_col, time_step_s=time_step_s,
                           speed_columns=tuple(speed_col or ()), speed_unit=speed_unit, elevation_column=elevation_col,
                           grade_column=grade_col, grade_unit=grade_unit, grade_file=grade_file).check("cycle options")
    except CevmError as exc:
        raise fail(exc) from None


def load_sources(stack: ExitStack, store: Path | None, cycles, trips, vehicle_ids, routes, cr0: float, cycle_fmt,
                 **stored):
    """:func:`cevm.store.sources.load_sources`, but cycle files are read without the
    store package, which is imported only for stored sources: a command on cycle files
    alone then imports neither it nor pandas (a third of a short command's time).
    ``stored``: its keywords for stored sources (``need_profiles``, ``on_damaged``)."""
    from cevm.core.sweep import Source
    from cevm.io.cycles import read_cycle_files

    sources = [Source.from_cycle(c, cr0=cr0) for c in read_cycle_files(cycles or [], cycle_fmt)]
    if trips or vehicle_ids or routes:
        from cevm.store.sources import load_sources as load_stored

        sources += load_stored(stack, store, [], trips or [], vehicle_ids or [], routes or [], cr0, **stored)
    return sources


def with_cycle_options(command):
    """Give a command the cycle-reading options (:data:`_CYCLE_OPTIONS`, shown in their
    own help panel): the command takes one keyword ``cycle_fmt``, a
    :class:`cevm.io.cycles.CycleFormat`, instead of the ten options."""
    sig = inspect.signature(command, eval_str=True)
    params = [p for p in sig.parameters.values() if p.name != "cycle_fmt"]
    extra = [inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY, default=None, annotation=ann)
             for name, ann in _CYCLE_OPTIONS.items()]

    @functools.wraps(command)
    def run(*args, **kwargs):
        opts = {name: kwargs.pop(name, None) for name in _CYCLE_OPTIONS}
        return command(*args, cycle_fmt=cycle_format(**opts), **kwargs)

    new_sig = sig.replace(parameters=[p.replace(kind=inspect.Parameter.KEYWORD_ONLY) for p in params] + extra)
    run.__signature__ = new_sig  # type: ignore[attr-defined]  # typer reads a function's __signature__
    run.__annotations__ = {p.name: p.annotation for p in new_sig.parameters.values()}
    return run
FormatOption = Annotated[OutputFormat, typer.Option("--format", "-f", help="Output format.")]


#: Most local worker processes per core (--workers): beyond the cores a pool only adds
#: processes' memory and start-up, never speed.
MAX_WORKERS_PER_CORE = 4


def check_workers(workers: int | None) -> None:
    """Refuse a --workers count beyond :data:`MAX_WORKERS_PER_CORE` per core (exit 2)."""
    limit = MAX_WORKERS_PER_CORE * (os.cpu_count() or 1)
    if workers is not None and workers > limit:
        raise fail(f"--workers {workers}: at most {limit} on this machine ({MAX_WORKERS_PER_CORE} per core; more "
                   "processes only add memory)")


def check_common(ice_braking: str | None, soc_start: float | None, reserve_pct: float,
                 interval: float | None = None) -> None:
    if ice_braking is not None and ice_braking not in ICE_BRAKING_MODES:
        raise fail(f"--ice-braking must be one of: {', '.join(ICE_BRAKING_MODES)}")
    check_soc(soc_start, reserve_pct)
    if interval is not None and not 0.0 < interval < 1.0:
        raise fail(f"--interval must be a level between 0 and 1 (0.9: the central 90 %), got {interval:g}")


def check_soc(soc_start: float | None, reserve_pct: float | None = None) -> None:
    """--soc-start (None: not given) and --reserve-pct, with the words of
    :func:`cevm.core.physical_inputs.soc_pct` (the same message from every command)."""
    from cevm.core import physical_inputs

    try:
        physical_inputs.soc_pct(100.0 if soc_start is None else soc_start)
    except CevmError as exc:
        raise fail(f"--soc-start: {exc}") from None
    if reserve_pct is not None:
        try:
            physical_inputs.soc_pct(100.0, reserve_pct)
        except CevmError as exc:
            raise fail(f"--reserve-pct: {exc}") from None


def os_error_exit(exc: OSError, what: str | None = None) -> int:
    """Print :func:`os_error_text` as the one error line; returns exit code 3 (the
    environment's failure, like a store that could not be written). A broken pipe (the
    reader went away: ``cevm trips | head``) is no error: nothing is printed, and the code
    is 141, as a shell reports a process ended by SIGPIPE."""
    if exc.errno == errno.EPIPE:
        _quiet_stdout()
        return EXIT_BROKEN_PIPE
    if what is None and not exc.filename:  # no file named: was it stdout? (it fails again if so)
        try:
            sys.stdout.flush()
        except OSError:
            what = "the output (stdout)"
        except (ValueError, AttributeError):
            pass
    fail(os_error_text(exc, what), EXIT_STORE_ACCESS)
    return EXIT_STORE_ACCESS


def _quiet_stdout() -> None:
    """Point stdout at /dev/null, so that Python's last flush of what could not be
    written cannot fail again at exit ("Exception ignored ...")."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError, AttributeError):
        pass


def flush_stdout(code, *, said: bool = False):
    """Flush stdout before the exit: output still buffered (a short table) meets a full
    device only here. Returns ``code``, or :func:`os_error_exit`'s when the flush
    fails; ``said``: an output error was printed already (the flush meets the same full
    device: nothing more is said)."""
    if code == 1 and type(sys.stdout).__name__ == "PacifyFlushWrapper":  # typer's quiet exit 1 after EPIPE
        _quiet_stdout()
        return EXIT_BROKEN_PIPE
    try:
        sys.stdout.flush()
    except OSError as exc:
        if said:
            _quiet_stdout()
            return code
        new = os_error_exit(exc, "the output (stdout)")
        _quiet_stdout()
        return new if code in (0, None) else code
    except (ValueError, AttributeError):  # closed or replaced
        pass
    return code


#: What the output options write, by file name ending: the check of
#: :func:`check_output_path`.
PNG, TOML = (".png", "a PNG image"), (".toml", "a vehicle file")


def check_output_path(path: Path | None, option: str, kind: tuple[str, str] | None = None) -> None:
    """An output file's path checked before any work, the same for every command's
    ``--out`` and ``--plot``: a mistake is one line and exit 2 (bad usage). Refused: a
    folder given as the file, a file in a folder that does not exist (or is not a
    folder, or cannot be written into), and for ``kind`` ((ending, what), e.g.
    :data:`PNG`) a name without that ending (``--plot out.txt``: the image format is
    the ending's). None (the option not given) passes."""
    if path is None:
        return
    p = Path(path)
    shown = printable(str(p))
    if p.is_dir():
        raise fail(f"{option} {shown}: is a folder; give a file name (e.g. {printable(str(p / 'out'))}"
                   f"{kind[0] if kind else ''})")
    if kind is not None and p.suffix.lower() != kind[0]:
        raise fail(f"{option} {shown}: {kind[1]} is written here, so the name must end in {kind[0]}"
                   + (f" (not {printable(p.suffix)})" if p.suffix else ""))
    parent = p.parent
    if not parent.exists():
        raise fail(f"{option} {shown}: the folder {printable(str(parent))} does not exist (make it first)")
    if not parent.is_dir():
        raise fail(f"{option} {shown}: {printable(str(parent))} is not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise fail(f"{option} {shown}: cannot write in the folder {printable(str(parent))} (permission denied)")


def open_out(stack: ExitStack, out: Path | None) -> IO[str]:
    return sys.stdout if out is None else stack.enter_context(OutFile(out))


def apply_manifest(st, path: Path, manifest, *, dry_run: bool = False) -> tuple[int, int]:
    """Match the manifest read from ``path`` to the trips of the open store ``st`` and
    give them their masses (unless ``dry_run``): ``manifest`` read whole
    (:func:`cevm.io.manifest.read_manifest`) or streamed
    (:func:`~cevm.io.manifest.open_manifest`, whose rows are never all held). Prints one
    warning per row not applied (file and line) as it is found, one note per mass that
    disagrees with a logged gross weight, and a summary line. Returns (rows applied, rows
    not applied)."""
    from cevm.store.masses import match_manifest, set_masses

    match = match_manifest(st, manifest, on_problem=lambda line, why: warn(f"{path}:{line}: not applied: {why}"))
    new = replaced = 0
    if match.masses and not dry_run:
        new, replaced = set_masses(st, match.masses)
    for text in match.disagreements:
        typer.echo(f"cevm: note: {path}: {one_line(text)}", err=True)
    cols = ", ".join(f"{role} {col!r}" for role, col in manifest.columns.items())
    done = (f"would give {len(match.masses)} trips their masses" if dry_run else
            f"{len(match.masses)} trips given their masses ({new} new, {replaced} replaced)")
    typer.echo(printable(f"cevm: manifest {path}: {manifest.n_rows} rows; {done}; "
                         f"{match.n_problems} rows not applied (columns: {cols}; mass in {manifest.mass_unit}, "
                         f"decimal mark {manifest.decimal!r})"), err=True)
    return len(match.masses), match.n_problems
