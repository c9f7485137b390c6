"""Errors that describe a user's mistake (bad file, bad key, bad value).

The CLI prints these as one line, without a traceback, and exits non-zero. Anything
else that escapes is a bug in cevm and keeps its traceback.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from cevm.text import printable

#: Control characters: C0 (line feed, carriage return, tab, escape, ...), DEL, C1, and
#: the Unicode line and paragraph separators.
_CONTROL = re.compile("[\x00-\x1f\x7f-\x9f\u2028\u2029]")


def has_control(text: str) -> bool:
    """Whether ``text`` holds a control character (a vehicle id must not: it would
    break a CSV record or forge a line)."""
    return _CONTROL.search(text) is not None


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
        """``file:line: column 'c': message``, non-printable characters escaped
        (:func:`cevm.text.printable`: a file name or value holding a line break cannot
        forge a second line of output)."""
        where = str(self.path) if self.path is not None else "<input>"
        if self.line is not None:
            where += f":{self.line}"
        if self.column is not None:
            where += f": column '{self.column}'"
        return printable(f"{where}: {self.message}")
