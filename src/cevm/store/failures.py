"""What can go wrong with the store file, named for the person who has to act on it.

SQLite's errors are translated where they arise (every statement of a store's
connection, :class:`StoreConnection`) into three kinds of :class:`~cevm.errors.CevmError`:

- :class:`StoreDamagedError`: the database file is damaged ("database disk image is
  malformed") or is not a database at all. What to do: restore a backup, or re-ingest the
  logs into a new store; ``cevm store check`` says where the damage is.
- :class:`StoreAccessError`: the store could not be written (or read): the disk is full,
  the file, its directory or its file system is read-only, another process held the
  write lock past the busy timeout, an I/O error. A failed write transaction is rolled
  back: the store is as it was before it.
- :class:`DamagedTripError` / :class:`DamagedRouteError`: one stored trip's or route
  leg's blob fails its checksum or does not decode. Readers of many trips report it by
  id and skip that trip; a reader of that one trip stops with it.

The command line gives each kind its exit code (:mod:`cevm.cli.common`).
"""

from __future__ import annotations

import contextlib
import functools
import re
import sqlite3
from pathlib import Path
from typing import cast

from cevm.errors import CevmError

#: What to do about a damaged store (appended to every :class:`StoreDamagedError`).
DAMAGED_HINT = ("restore the store from a backup, or re-ingest the logs into a new store "
                "(cevm ingest LOGS --store NEW.sqlite); 'cevm store check' lists what is damaged")


class StoreDamagedError(CevmError):
    """The store's database file is damaged or is not an SQLite database."""


class StoreAccessError(CevmError):
    """The store could not be written (or read); a write was rolled back.

    ``reason``: ``"full"`` (disk or file-size limit), ``"readonly"`` (file, directory or
    file system), ``"locked"`` (another process's write lock, past the busy timeout),
    ``"io"`` (an I/O error) or ``"cantopen"``.
    """

    def __init__(self, message: str, reason: str):
        super().__init__(message)
        self.reason = reason


class DamagedRowError(CevmError):
    """A stored row whose blob fails its checksum or does not decode: ``kind`` ('trip' or
    'route'), ``ident`` (its id or name), ``part`` (which blob) and ``problem``."""

    def __init__(self, kind: str, ident: str, part: str, problem: str, remedy: str):
        super().__init__(f"{kind} {ident!r} is damaged in the store ({part}: {problem}); {remedy}")
        self.kind, self.ident, self.part, self.problem = kind, ident, part, problem


class DamagedTripError(DamagedRowError):
    """A stored trip whose vector or profile is damaged."""

    def __init__(self, trip_id: str, part: str, problem: str, source_file: str | None = None):
        if problem.startswith("unreadable"):  # the database file itself: nothing can be rewritten into it
            remedy = DAMAGED_HINT
        elif source_file:
            remedy = f"re-ingest its log file with --force (cevm ingest '{source_file}' --force), or restore a backup"
        else:
            remedy = "re-ingest its log file with --force, or restore a backup"
        super().__init__("trip", trip_id, part, problem, remedy)
        self.trip_id = trip_id


class DamagedRouteError(DamagedRowError):
    """A stored route whose cycle leg's vector or profile is damaged."""

    def __init__(self, route: str, part: str, problem: str):
        super().__init__("route", route, part, problem,
                         f"re-create the route (cevm route add {route} --replace ...) or restore a backup")
        self.route = route


# --------------------------------------------------------------- SQLite's errors

# primary result codes (https://sqlite.org/rescode.html)
_PERM, _BUSY, _LOCKED, _READONLY, _IOERR, _CORRUPT, _FULL, _CANTOPEN, _NOTADB = 3, 5, 6, 8, 10, 11, 13, 14, 26


def translate(exc: sqlite3.Error, path: Path, busy_timeout_s: float) -> CevmError | None:
    """The store error for SQLite's ``exc`` on the store at ``path``, or None when it is
    not about the file (a constraint, a bug: left as it is)."""
    code = getattr(exc, "sqlite_errorcode", None)
    primary = None if code is None else code & 0xFF
    text = str(exc)
    if code is None and text.startswith("Could not decode to UTF-8"):  # Python's, of damaged text in a row
        column = re.search(r"column '([^']*)'", text)
        return StoreDamagedError(f"{path}: the store is damaged (a row's text in column "
                                 f"{column.group(1) if column else '?'!r} is not UTF-8); {DAMAGED_HINT}")
    if primary == _CORRUPT:
        return StoreDamagedError(f"{path}: the store is damaged ({text}); {DAMAGED_HINT}")
    if primary == _NOTADB:
        return StoreDamagedError(f"{path}: not a usable cevm store: {text}: it is damaged, or another kind of "
                                 f"file; choose another --store, or {DAMAGED_HINT}")
    nothing = "nothing was changed"
    if primary == _FULL:
        return StoreAccessError(f"{path}: the store could not be written: the disk is full ({text}); {nothing}. "
                                "Free some space (or raise the file-size limit) and run again", "full")
    if primary in (_READONLY, _PERM):
        return StoreAccessError(f"{path}: the store could not be written: it is read-only ({text}: the file, its "
                                f"directory or the file system); {nothing}. Commands that only read it work",
                                "readonly")
    if primary in (_BUSY, _LOCKED):
        return StoreAccessError(f"{path}: the store could not be written: another process held its write lock for "
                                f"more than {busy_timeout_s:g} s ({text}; a hung cevm ingest?); {nothing}. "
                                "Run again when it is done", "locked")
    if primary == _IOERR:
        return StoreAccessError(f"{path}: the store could not be written or read: an I/O error ({text}); {nothing}. "
                                "Check the disk (and that the store is on a local file system: SQLite's WAL "
                                "journal does not work on NFS or SMB)", "io")
    if primary == _CANTOPEN:
        return StoreAccessError(f"{path}: the store could not be opened ({text}): a missing or read-only directory, "
                                f"or missing permissions; {nothing}", "cantopen")
    return None


def _translated(method, connection_of):
    """``method`` of a connection or cursor, raising the store errors of :func:`translate`."""

    @functools.wraps(method)
    def call(self, *args):
        try:
            return method(self, *args)
        except sqlite3.Error as exc:
            con = connection_of(self)
            if isinstance(self, sqlite3.Cursor):  # finalize its statement now: an exception that
                with contextlib.suppress(sqlite3.Error):  # outlives this call (a caller keeps it) must
                    self.close()  # not keep the database's files open
            err = translate(exc, con.store_path, con.busy_timeout_s)
            if err is None:
                raise
            raise err from exc

    return call


def _cursor_connection(cursor: sqlite3.Cursor) -> StoreConnection:
    # the store opens its connections with factory=StoreConnection
    return cast(StoreConnection, cursor.connection)


class _Cursor(sqlite3.Cursor):
    """A cursor whose statements and fetched rows raise the store errors."""

    execute = _translated(sqlite3.Cursor.execute, _cursor_connection)
    executemany = _translated(sqlite3.Cursor.executemany, _cursor_connection)
    executescript = _translated(sqlite3.Cursor.executescript, _cursor_connection)
    fetchone = _translated(sqlite3.Cursor.fetchone, _cursor_connection)
    fetchmany = _translated(sqlite3.Cursor.fetchmany, _cursor_connection)
    fetchall = _translated(sqlite3.Cursor.fetchall, _cursor_connection)
    __next__ = _translated(sqlite3.Cursor.__next__, _cursor_connection)


class StoreConnection(sqlite3.Connection):
    """An SQLite connection to a store whose statements raise the store errors of this
    module instead of SQLite's (``sqlite3.connect(..., factory=StoreConnection)``; set
    ``store_path`` and ``busy_timeout_s`` after connecting)."""

    store_path: Path = Path("?")
    busy_timeout_s: float = 0.0

    def cursor(self, factory=_Cursor):
        return super().cursor(factory)

    # sqlite3.Connection.execute makes its cursor in C, not through cursor(): go through it
    def execute(self, *args) -> _Cursor:
        return self.cursor().execute(*args)

    def executemany(self, *args) -> _Cursor:
        return self.cursor().executemany(*args)

    def executescript(self, *args) -> _Cursor:
        return self.cursor().executescript(*args)
