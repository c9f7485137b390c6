"""What the command modules share: exit codes, common options, the one-line error.

Exit codes: 0 success; 1 some inputs of a batch failed (the rest was done); 2 bad usage
or bad input (nothing was done).
"""

from __future__ import annotations

import math
import os
import sys
from contextlib import ExitStack
from pathlib import Path
from typing import IO, Annotated, Optional

import typer

from cevm.cli.output import OutputFormat
from cevm.core.model import ICE_BRAKING_MODES
from cevm.errors import CevmError

EXIT_OK = 0
EXIT_PARTIAL = 1
EXIT_INPUT = 2


StoreOption = Annotated[
    Optional[Path],
    typer.Option("--store", envvar="CEVM_STORE", help="Trip store (SQLite). Default: $CEVM_STORE, else ~/.local/share/cevm/cevm.sqlite."),
]


def fail(message: str, code: int = EXIT_INPUT) -> typer.Exit:
    typer.echo(f"cevm: error: {message}", err=True)
    return typer.Exit(code)


def existing_store(store: Optional[Path], hint: Optional[str] = None) -> Path:
    """The store a reading command needs, or the usual one-line error (exit 2)."""
    from cevm.store import NO_STORE_HINT, existing_store_path

    try:
        return existing_store_path(store, hint or NO_STORE_HINT)
    except CevmError as exc:
        raise fail(str(exc)) from None


#: Rows printed by ``--format table``; beyond that, use csv or json.
TABLE_MAX_ROWS = 200


VehicleOption = Annotated[
    list[Path], typer.Option("--vehicle", "-v", help="Vehicle TOML file, or a directory of them. Repeatable.")
]
CycleOption = Annotated[
    Optional[list[Path]],
    typer.Option("--cycle", "-c", help="Cycle CSV (time_s, speed_kmh|speed_mps[, elevation_m]). Repeatable."),
]
TripOption = Annotated[
    Optional[list[str]], typer.Option("--trip", "-t", help="A stored trip id (see 'cevm trips'). Repeatable.")
]
VehicleIdOption = Annotated[
    Optional[list[str]], typer.Option("--vehicle-id", help="All stored trips of this vehicle id. Repeatable.")
]
RouteOption = Annotated[
    Optional[list[str]],
    typer.Option("--route", "-r", help="A stored route (see 'cevm route list'), or a glob such as 'block-*'. Repeatable."),
]
SocStartOption = Annotated[
    float, typer.Option("--soc-start", help="EV state of charge at the start [%] (default: full).")
]
ReserveOption = Annotated[
    float, typer.Option("--reserve-pct", help="EV state of charge to keep all along [%] (default 15, the paper's warning level).")
]
IceBrakingOption = Annotated[
    Optional[str],
    typer.Option(help=f"Override ICE braking mode: {' or '.join(ICE_BRAKING_MODES)}. Default: the vehicle file's."),
]
AmbientOption = Annotated[
    Optional[float],
    typer.Option("--ambient-c", help="Ambient temperature [degC] of every prediction (heating and A/C terms). "
                                     "Default: a stored trip's own logged mean, else the vehicle file's "
                                     "reference_temp_c, else 20 degC."),
]
Cr0Option = Annotated[
    float, typer.Option(help="Cr0 of the simplification criterion, for --cycle files (stored trips and routes keep theirs).")
]
OutOption = Annotated[Optional[Path], typer.Option("--out", "-o", help="Write the output to this file instead of stdout.")]
FormatOption = Annotated[OutputFormat, typer.Option("--format", "-f", help="Output format.")]


def check_common(ice_braking: Optional[str], soc_start: float, reserve_pct: float) -> None:
    if ice_braking is not None and ice_braking not in ICE_BRAKING_MODES:
        raise fail(f"--ice-braking must be one of: {', '.join(ICE_BRAKING_MODES)}")
    if not (math.isfinite(soc_start) and 0.0 < soc_start <= 100.0):
        raise fail("--soc-start must be in (0, 100] %")
    if not (math.isfinite(reserve_pct) and 0.0 <= reserve_pct < 100.0):
        raise fail("--reserve-pct must be in [0, 100) %")


class OutFile:
    """``--out`` as a context manager: written to ``PATH.partial``, renamed to PATH when
    the command succeeds, deleted when it fails (no truncated output left behind)."""

    def __init__(self, path: Path):
        self.path = Path(path)
        self.tmp = self.path.with_name(self.path.name + ".partial")

    def __enter__(self) -> IO[str]:
        try:
            self.fh = open(self.tmp, "w", encoding="utf-8", newline="")
        except OSError as exc:
            raise CevmError(f"{self.path}: cannot write: {exc.strerror or exc}") from None
        return self.fh

    def __exit__(self, exc_type, exc, tb) -> None:
        self.fh.close()
        if exc_type is None:
            os.replace(self.tmp, self.path)
        else:
            self.tmp.unlink(missing_ok=True)


def open_out(stack: ExitStack, out: Optional[Path]) -> IO[str]:
    return sys.stdout if out is None else stack.enter_context(OutFile(out))
