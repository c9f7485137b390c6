"""Writing an output file whole or not at all (``--out``, a calibrated vehicle file).

:class:`OutFile` writes to ``PATH.partial`` beside the file and renames it to PATH when the
block succeeds, deletes it when the block fails: a full disk, an interrupt or an error
leaves no truncated file, and an earlier PATH as it was. A write that fails is an
:class:`~cevm.errors.OutputError` naming PATH (the command line's exit 3). PATH that exists
and is not a regular file (``/dev/stdout``, a FIFO, a device such as ``/dev/full``) is
written directly: a rename would replace the device node itself (it did: an ``--out
/dev/full`` replaced ``/dev/full`` with a regular file). A symlink is followed: the file it
names is replaced, not the link.

No output may be one of the command's inputs or the trip store: :func:`output_clash`
compares an output's path with theirs (resolved real paths, and device and inode, so a
symlink, a hard link or ``./x`` for ``x`` is the same file), the store with its
``-wal``, ``-shm`` and ``-journal`` files, and the ``.partial`` file the output is
written through. The command line calls it on every command's options before any work
(:mod:`cevm.cli.paths`); :class:`OutFile` checks the same against every file read in
this process and every store opened (:func:`cevm.io.inputs.read_files`, when
:func:`cevm.io.inputs.remember_reads` is on, as under the command line), so that a file
named only inside another (a scenario's vehicle files) is not overwritten either.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path
from typing import IO, Literal

from cevm.errors import CevmError, OutputError, os_error_text
from cevm.io import inputs
from cevm.io.inputs import file_identity

#: The files SQLite keeps beside a store (its write-ahead log, shared memory, rollback
#: journal): overwriting one loses the store's last commits, or damages it.
STORE_SIDECARS = ("-wal", "-shm", "-journal")

#: What :class:`OutFile` writes through before renaming it to the output's name.
PARTIAL_SUFFIX = ".partial"


def same_file(a: tuple[str, tuple[int, int] | None], b: tuple[str, tuple[int, int] | None]) -> bool:
    """Whether two :func:`file_identity` values are the same file."""
    return a[0] == b[0] or (a[1] is not None and a[1] == b[1])


def store_files(store: str | Path) -> list[tuple[str, Path]]:
    """The store and the files SQLite keeps beside it, each with what it is."""
    return [("the trip store", Path(store))] + [(f"the trip store's {s} file", Path(f"{store}{s}"))
                                               for s in STORE_SIDECARS]


def output_clash(outputs: list[tuple[str, Path]], inputs_: list[tuple[str, Path]],
                 store: Path | None = None) -> str | None:
    """The one line refusing the first output (``(option, path)``) that names an input
    (``(option, path)``), the store or one of its files, or another output; None when
    every output is a file of its own. Each output is compared as the file it replaces
    and the ``.partial`` file it is written through."""
    theirs: list[tuple[str, Path]] = [(f"the input {opt} {p}", p) for opt, p in inputs_]
    if store is not None:
        theirs += [(f"{what} (--store) {p}", p) for what, p in store_files(store)]
    written: list[tuple[str, Path]] = []
    for opt, path in outputs:
        mine = [file_identity(path), file_identity(f"{path}{PARTIAL_SUFFIX}")]
        for what, other in theirs + written:
            ident = file_identity(other)
            if any(same_file(m, ident) for m in mine):
                return (f"{opt} {path}: is {what}; writing there would destroy it, so nothing was done "
                        "(give another output file)")
        written.append((f"the output of {opt}", path))
    return None


def _refuse_read_target(path: Path, target: Path) -> None:
    """Refuses (:class:`CevmError`: bad usage) an output onto a file this process read or a store
    it opened (:func:`cevm.io.inputs.read_files`), before anything is written."""
    known = inputs.read_files()
    if not known:
        return
    mine = [file_identity(target), file_identity(f"{target}{PARTIAL_SUFFIX}")]
    for what, (real, _) in known:
        ident = file_identity(real)  # as it is now: a file since removed leaves its inode to others
        if any(same_file(m, ident) for m in mine):
            raise CevmError(f"{path}: is {what}, read by this command; writing there would destroy it, so nothing "
                             "was written (give another output file)")


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
        _refuse_read_target(self.path, self.target)
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
