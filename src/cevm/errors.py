"""Errors that describe a user's mistake (bad file, bad key, bad value).

The CLI prints these as one line, without a traceback, and exits non-zero. Anything
else that escapes is a bug in cevm and keeps its traceback.
"""

from __future__ import annotations

import errno
import re
from dataclasses import dataclass
from pathlib import Path

from cevm.text import one_line

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
        forge a second line of output), bounded (:func:`cevm.text.one_line`: a message
        quoting megabytes of a user's text stays one readable line)."""
        where = str(self.path) if self.path is not None else "<input>"
        if self.line is not None:
            where += f":{self.line}"
        if self.column is not None:
            where += f": column '{self.column}'"
        return one_line(f"{where}: {self.message}")


class FileAccessError(InputError):
    """A file that could not be opened as the kind of file asked for: missing, unreadable,
    not a regular file (a FIFO, a device), over its size bound. Its message never quotes
    the file's content (:mod:`cevm.io.inputs`)."""


class OutputError(CevmError):
    """An output (stdout, an ``--out`` or ``--plot`` file) that could not be written: a
    full disk, a read-only file system, an I/O error. The command line exits 3 for it, as
    for a store that could not be written."""


#: errno values that say a write found no room or no write access.
_NO_ROOM = {errno.ENOSPC: "the disk is full", errno.EDQUOT: "the disk quota is exhausted",
            errno.EFBIG: "the file-size limit is reached", errno.EROFS: "a read-only file system"}


def os_error_text(exc: OSError, what: str | None = None) -> str:
    """One line for an OSError of writing (or reading) ``what`` (default: its file name,
    or "the output"): ``FILE: could not be written: the disk is full (No space left on
    device)``."""
    where = what or (str(exc.filename) if exc.filename else "the output")
    reason = exc.strerror or str(exc)
    if exc.errno in _NO_ROOM:
        return f"{where}: could not be written: {_NO_ROOM[exc.errno]} ({reason})"
    return f"{where}: could not be written or read: {reason} (an I/O error)"
