"""Writing an output file whole or not at all (``--out``, a calibrated vehicle file).

:class:`OutFile` writes to ``PATH.partial`` beside the file and renames it to PATH when the
block succeeds, deletes it when the block fails: a full disk, an interrupt or an error
leaves no truncated file, and an earlier PATH as it was. A write that fails is an
:class:`~cevm.errors.OutputError` naming PATH (the command line's exit 3). PATH that exists
and is not a regular file (``/dev/stdout``, a FIFO, a device such as ``/dev/full``) is
written directly: a rename would replace the device node itself (it did: an ``--out
/dev/full`` replaced ``/dev/full`` with a regular file). A symlink is followed: the file it
names is replaced, not the link.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path
from typing import IO, Literal

from cevm.errors import CevmError, OutputError, os_error_text


class OutFile:
    """The context manager of the module notes: ``with OutFile(path) as fh: fh.write(...)``
    (text, UTF-8, ``\\n`` line ends as written)."""

    def __init__(self, path: str | Path, *, binary: bool = False):
        self.path = Path(path)
        self.binary = binary  # bytes (a figure), not text
        target = Path(os.path.realpath(self.path))
        self.direct = target.exists() and not target.is_file()
        self.target = target
        self.tmp = target if self.direct else target.with_name(target.name + ".partial")

    def __enter__(self) -> IO:
        try:
            self.fh = open(self.tmp, "wb") if self.binary else open(self.tmp, "w", encoding="utf-8", newline="")
        except OSError as exc:
            raise CevmError(f"{self.path}: cannot write: {exc.strerror or exc}") from None
        return self.fh

    def __exit__(self, exc_type, exc, tb) -> Literal[False]:
        if self.direct:
            try:
                self.fh.close()
            except OSError as err:
                if exc_type is None or issubclass(exc_type, OSError):
                    raise OutputError(os_error_text(err, str(self.path))) from None
            if exc_type is not None and issubclass(exc_type, OSError):
                raise OutputError(os_error_text(exc, str(self.path))) from None
            return False
        try:
            self.fh.close()  # the last buffered bytes are written here
            if exc_type is None:
                os.replace(self.tmp, self.target)
        except OSError as err:
            _unlink_quietly(self.tmp)
            if exc_type is None or issubclass(exc_type, OSError):
                raise OutputError(os_error_text(err, str(self.path))) from None
            return False
        if exc_type is not None:
            _unlink_quietly(self.tmp)
            if issubclass(exc_type, OSError):  # a write in the block failed: named as this file's
                raise OutputError(os_error_text(exc, str(self.path))) from None
        return False


def write_text(path: str | Path, text: str) -> None:
    """``text`` written to ``path`` whole or not at all (:class:`OutFile`)."""
    with OutFile(path) as fh:
        fh.write(text)


def _unlink_quietly(path: Path) -> None:
    with contextlib.suppress(OSError):
        path.unlink(missing_ok=True)
