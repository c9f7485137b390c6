"""Errors that describe a user's mistake (bad file, bad key, bad value).

The CLI prints these as one line, without a traceback, and exits non-zero. Anything
else that escapes is a bug in cevm and keeps its traceback.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path


class CevmError(Exception):
    """Base class for errors caused by input, not by a bug."""


@dataclass
class InputError(CevmError):
    """Bad input, located as precisely as we can: file, line (1-based, as an editor
    shows it), column or key."""

    path: str | Path | None
    message: str
    line: int | None = None
    column: str | None = None

    def __post_init__(self) -> None:
        super().__init__(str(self))

    def __str__(self) -> str:
        where = str(self.path) if self.path is not None else "<input>"
        if self.line is not None:
            where += f":{self.line}"
        if self.column is not None:
            where += f": column '{self.column}'"
        return f"{where}: {self.message}"
