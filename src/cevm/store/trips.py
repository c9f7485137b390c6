"""The trip store's :class:`TripStore`: one SQLite file, no server, one connection.

It composes the store's pieces: the table layout (:mod:`cevm.store.schema`, created or
checked on open), the writes (:mod:`cevm.store.writing`: a file's trips, failures,
runs) and the reads (:mod:`cevm.store.queries`). Where the file is:
:mod:`cevm.store.location`; how a trip's profile is packed: :mod:`cevm.store.codec`;
listed trips as a person reads them: :mod:`cevm.store.display`.

Concurrency and crashes
    WAL journal, a 60 s busy timeout and ``BEGIN IMMEDIATE`` for every write
    transaction: two ``cevm ingest`` processes serialise their writes file by file, and
    readers are never blocked. One file = one transaction, so a crash (even SIGKILL)
    mid-file leaves the store as it was before that file. Primary keys and UNIQUE
    constraints are the last line of defence against duplicates. WAL needs a local
    file system (not NFS/SMB), as SQLite documents.

Units: SI inside (s, m, m/s, kg, J; fuel in litres, ``_l``); :func:`format_trips` is the
edge that turns rows into what a person reads (ISO 8601 times, km, kWh).
"""

from __future__ import annotations

import sqlite3
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from cevm.errors import CevmError
from cevm.store.display import format_trips, format_utc
from cevm.store.location import resolve_store_path
from cevm.store.queries import FileState, TripQueries
from cevm.store.schema import SCHEMA_VERSION, ensure_schema
from cevm.store.writing import TripWriting, WriteResult

BUSY_TIMEOUT_S = 60.0
"""How long a writer waits for another process's write transaction [s]. One file's
transaction lasts milliseconds to a second, so 60 s only runs out if a process hangs."""

__all__ = ["BUSY_TIMEOUT_S", "SCHEMA_VERSION", "FileState", "TripStore", "WriteResult", "format_trips",
           "format_utc"]


def _checkpoint(stage: str) -> None:
    """Called between the statements of a write transaction; does nothing.

    Tests replace it to raise or to stall (and be killed) in mid-transaction.
    """


class TripStore(TripWriting, TripQueries):
    """A connection to the trip store (see :mod:`cevm.store.schema` for the layout).

    ``TripStore(path)`` or ``TripStore.open(path_or_None)`` opens (and creates, with its
    parent directories) the store; use it as a context manager or call :meth:`close`.
    One instance per process/thread; many processes may open the same store at once.
    Its writes are :class:`~cevm.store.writing.TripWriting`'s, its reads
    :class:`~cevm.store.queries.TripQueries`'.
    """

    def __init__(self, path: str | Path):
        self.path = Path(path).expanduser()
        self._con: sqlite3.Connection | None = None
        if self.path.is_dir():
            raise CevmError(f"{self.path}: is a directory, not a cevm store file")
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise CevmError(f"{self.path}: cannot create the store's directory: {exc}") from exc
        try:
            self._con = sqlite3.connect(
                str(self.path), timeout=BUSY_TIMEOUT_S, isolation_level=None
            )
            self._enable_wal()
            # NORMAL in WAL mode: a power cut may lose the last commits, never corrupts.
            self._con.execute("PRAGMA synchronous=NORMAL")
            self._con.execute("PRAGMA foreign_keys=ON")
            ensure_schema(self)
        except sqlite3.DatabaseError as exc:
            self.close()
            raise CevmError(f"{self.path}: not a usable cevm store: {exc}") from exc
        except BaseException:
            self.close()
            raise

    def _enable_wal(self) -> str:
        """Switch to the WAL journal (persistent in the file; a no-op once done).

        SQLite does not call the busy handler for this switch, so when several
        processes create a store at once it can fail with "database is locked": retry
        with growing sleeps (1 ms to 0.1 s) for up to :data:`BUSY_TIMEOUT_S`. Returns
        the journal mode in force (not 'wal' on file systems without shared memory).
        """
        deadline = time.monotonic() + BUSY_TIMEOUT_S
        delay_s = 0.001
        while True:
            try:
                return str(self.con.execute("PRAGMA journal_mode=WAL").fetchone()[0])
            except sqlite3.OperationalError as exc:
                msg = str(exc).lower()
                if ("locked" not in msg and "busy" not in msg) or time.monotonic() > deadline:
                    raise
                time.sleep(delay_s)
                delay_s = min(2.0 * delay_s, 0.1)

    @classmethod
    def open(cls, path: str | Path | None = None) -> TripStore:
        """Open the store at ``path``, or at :func:`default_store_path` if None."""
        return cls(resolve_store_path(path))

    def close(self) -> None:
        """Close the connection (idempotent)."""
        if self._con is not None:
            self._con.close()
            self._con = None

    def __enter__(self) -> TripStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ internals

    @property
    def con(self) -> sqlite3.Connection:
        if self._con is None:
            raise CevmError(f"{self.path}: store is closed")
        return self._con

    @contextmanager
    def _write(self) -> Iterator[sqlite3.Connection]:
        """One write transaction (``BEGIN IMMEDIATE``: the write lock, waiting up to
        :data:`BUSY_TIMEOUT_S` for it): committed when the block ends, rolled back if it
        raises anything (even KeyboardInterrupt)."""
        con = self.con
        con.execute("BEGIN IMMEDIATE")
        try:
            yield con
            con.execute("COMMIT")
        except BaseException:
            if self._con is not None and self._con.in_transaction:
                self._con.execute("ROLLBACK")
            raise

    def _checkpoint(self, stage: str) -> None:
        _checkpoint(stage)  # the module's hook, looked up at each call (tests replace it)
