"""Opening the user's files that are not logs, within bounds checked before the work.

A vehicle file, a logger profile, a scenario, a manifest or a cycle file is opened only
when it is a regular file (:func:`open_regular`): a FIFO would hang the command, a
device such as ``/dev/zero`` would be read without end, a directory is not a file. The
check is made on the open file itself (``fstat``; the file is opened without blocking,
so a FIFO without a writer cannot hang the opening), so a symlink or a file swapped in
between cannot slip past it. :func:`read_bounded` then reads at most the size the kind of
file is allowed (:data:`MAX_TOML_BYTES` for TOML, the readers' own limits for the
others), refusing a larger file from its size, before reading it, and a file that grows
past the limit while it is read at the limit.

Every refusal is a :class:`~cevm.errors.FileAccessError` (an InputError) naming the file
and the bound, and never quotes the file's content (a scenario may name any file on the
machine: :mod:`cevm.io.scenario` passes these on and no other error of such a file).
"""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import BinaryIO

from cevm.errors import FileAccessError

#: Largest TOML file read (vehicle files, logger profiles, fleet scenarios) [bytes]. The
#: shipped ones are 1-6 kB; Python's TOML parser takes about 2 s per MiB, and its nesting
#: is bounded too (:func:`cevm.io.toml.read_toml`).
MAX_TOML_BYTES = 1 << 20

_KINDS = ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISCHR, "a character device"),
          (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


def file_kind(mode: int) -> str | None:
    """What a non-regular file is, or None for a regular file."""
    if stat.S_ISREG(mode):
        return None
    return next((name for test, name in _KINDS if test(mode)), "not a regular file")


def _os_error(path: Path, what: str, exc: OSError) -> FileAccessError:
    if isinstance(exc, FileNotFoundError):
        return FileAccessError(path, f"{what} not found")
    if isinstance(exc, PermissionError):
        return FileAccessError(path, f"cannot read the {what}: permission denied")
    return FileAccessError(path, f"cannot read the {what}: {exc.strerror or exc}")


def open_regular(path: str | Path, what: str = "file") -> BinaryIO:
    """``path`` opened for reading in binary mode, if it is a regular file; else an
    :class:`InputError` saying what it is (a directory, a FIFO, a device, ...). ``what``
    names the kind of file in the messages ("vehicle file")."""
    path = Path(path)
    try:
        kind = file_kind(os.stat(path).st_mode)  # refused before it is opened, where possible
        if kind is not None:
            raise FileAccessError(path, f"is {kind}, not a {what}")
        flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_BINARY", 0)
        fd = os.open(path, flags)
    except OSError as exc:
        raise _os_error(path, what, exc) from None
    try:
        kind = file_kind(os.fstat(fd).st_mode)  # the file opened, whatever the path now names
        if kind is not None:
            raise FileAccessError(path, f"is {kind}, not a {what}")
        if hasattr(os, "set_blocking"):
            os.set_blocking(fd, True)
        return open(fd, "rb", closefd=True)
    except BaseException:
        os.close(fd)
        raise


def check_size(path: Path, fh: BinaryIO, max_bytes: int, what: str, hint: str = "") -> int:
    """The size of the open file ``fh``, refused (:class:`InputError`) above ``max_bytes``."""
    size = os.fstat(fh.fileno()).st_size
    if size > max_bytes:
        raise FileAccessError(path, f"{size:,} bytes: larger than a {what} may be ({_size(max_bytes)}){hint}")
    return size


def read_bounded(path: str | Path, max_bytes: int, what: str = "file", hint: str = "") -> bytes:
    """The bytes of the regular file ``path`` (:func:`open_regular`), at most
    ``max_bytes``: a larger file is refused from its size before it is read, and one that
    grows past the limit while read (or that reports no size, as ``/proc`` files) when
    the limit is reached. ``hint`` is appended to the refusal (what to do)."""
    path = Path(path)
    with open_regular(path, what) as fh:
        check_size(path, fh, max_bytes, what, hint)
        try:
            data = fh.read(max_bytes + 1)
        except OSError as exc:
            raise _os_error(path, what, exc) from None
    if len(data) > max_bytes:
        raise FileAccessError(path, f"more than {_size(max_bytes)}: larger than a {what} may be{hint}")
    return data


def _size(n: int) -> str:
    for unit, scale in (("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)):
        if n >= scale and n % scale == 0:
            return f"{n // scale} {unit}"
    return f"{n:,} bytes"


#: The longest field Python's csv module reads (its default ``field_size_limit``): a
#: longer one is refused with its file and line (:func:`csv_reason`).
CSV_FIELD_BYTES = 128 << 10


def csv_reason(exc: Exception) -> str:
    """What a ``csv.Error`` of a user's file means, in words for its one line: a field
    over :data:`CSV_FIELD_BYTES`, a NUL byte, else the module's own text."""
    text = str(exc)
    if "field larger than field limit" in text:
        return f"a field longer than {CSV_FIELD_BYTES // 1024} KiB (not a CSV file of this kind?)"
    if "NUL" in text:
        return "a NUL byte (a binary file?)"
    return text
