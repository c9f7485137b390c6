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

Read-only
    ``TripStore(path, readonly=True)`` opens with SQLite's ``mode=ro`` (nothing can be
    written; a read-only file works), falling back to ``immutable=1`` in a read-only
    directory where the WAL's ``-shm`` file cannot be made (see :meth:`_open_readonly`).
    It leaves no file behind: a store in WAL mode makes SQLite create its ``-wal`` and
    ``-shm`` files even for a reader, and a reader cannot remove them as the last writer
    does; so when they were not there before, they are removed once it closes, if no
    other connection has the store open (:func:`_remove_reader_files`, as SQLite's own
    last close does: under the database's exclusive lock, and only an empty ``-wal``).
    It never creates a store, nor writes into an empty file (0 bytes, or an SQLite
    database without tables): that is no store, as a missing file is not. (A store of an
    older schema is the one exception: it is migrated once, which needs write access.)

Writing
    A writable opening first runs SQLite's quick check (:meth:`require_intact`) and
    refuses a damaged store before anything is written into it, migrations included:
    every writer (ingest, ``trips set-mass``, ``route add``, ``route remove``) checks the
    store as ingest always did (``intact=False`` skips it, for tools that repair).

Failures
    Every statement's SQLite error is raised as the store's (:mod:`cevm.store.failures`):
    a damaged database, or a store that could not be written (full, read-only, locked
    past :data:`BUSY_TIMEOUT_S`, I/O), its transaction rolled back.

Units: SI inside (s, m, m/s, kg, J; fuel in litres, ``_l``); :func:`format_trips` is the
edge that turns rows into what a person reads (ISO 8601 times, km, kWh).
"""

from __future__ import annotations

import collections
import contextlib
import os
import sqlite3
import stat
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from cevm.errors import CevmError
from cevm.store.codec import decode_cycle_profile, decode_profile
from cevm.store.display import format_trips, format_utc
from cevm.store.failures import StoreAccessError, StoreConnection, translate
from cevm.store.location import resolve_store_path
from cevm.store.queries import FileState, TripQueries
from cevm.store.schema import (
    SCHEMA_VERSION,
    blob_crc32,
    check_layout,
    check_schema,
    ensure_schema,
    layout_problems,
    refuse_newer,
    stored_version,
    upgrade_trip_vector,
)
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


def _trip_vector_v3(vector: bytes, profile: bytes) -> bytes:
    """SQL function of migration 5 (:func:`cevm.store.schema.upgrade_trip_vector`)."""
    return upgrade_trip_vector(vector, profile, decode_profile)


def _route_vector_v3(vector: bytes, profile: bytes) -> bytes:
    """SQL function of migration 5 for a route's cycle leg (its own profile format)."""
    return upgrade_trip_vector(vector, profile, decode_cycle_profile)


class TripStore(TripWriting, TripQueries):
    """A connection to the trip store (see :mod:`cevm.store.schema` for the layout).

    ``TripStore(path)`` or ``TripStore.open(path_or_None)`` opens (and creates, with its
    parent directories) the store; use it as a context manager or call :meth:`close`.
    One instance per process/thread; many processes may open the same store at once.
    Its writes are :class:`~cevm.store.writing.TripWriting`'s, its reads
    :class:`~cevm.store.queries.TripQueries`'.
    """

    def __init__(self, path: str | Path, *, readonly: bool = False, migrate: bool = True, intact: bool = True):
        self.path = Path(path).expanduser()
        self.readonly = readonly
        self.immutable = False
        self.schema_version = SCHEMA_VERSION
        self._migrate = migrate
        self._intact = False  # the quick check passed on this connection
        self.layout_problems: list[str] = []  # tables or columns missing (read-only without migrating only)
        self._con: StoreConnection | None = None
        self._key = os.path.realpath(self.path)
        self._counted = False  # counted in _OPEN
        self._reader_files = False  # a reader found no -wal or -shm file: it removes those SQLite makes
        _remember_store(self.path)
        kind = _not_a_file(self.path)
        if kind is not None:  # a FIFO would hang the command where no signal reaches it, /dev/null swallow it
            raise CevmError(f"{self.path}: is {kind}, not a cevm store file")
        if readonly:
            self._open_readonly()
            return
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:  # a read-only file system, no permission, a full disk: the store's, exit 3
            raise StoreAccessError(f"{self.path}: the store could not be created: its directory could not be made "
                                   f"({exc.strerror or exc}: {exc.filename or self.path.parent}); nothing was "
                                   "changed. Give a --store on a writable disk", "cantopen") from None
        try:
            self._con = self._connect(str(self.path))
            if intact:
                self.require_intact()  # before the first write: WAL, migrations
                check_schema(self._con, self.path)  # version, tables, columns: before the first write too
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

    def _connect(self, database: str, uri: bool = False) -> StoreConnection:
        if not self._counted:  # before: a failed connect's close() counts it down
            _OPEN[self._key] += 1
            self._counted = True
        try:
            con = sqlite3.connect(database, timeout=BUSY_TIMEOUT_S, isolation_level=None, uri=uri,
                                  factory=StoreConnection)
        except sqlite3.Error as exc:  # the file could not be opened (or created): say why
            raise self._cannot_open(exc) from exc
        con.store_path = self.path
        con.busy_timeout_s = BUSY_TIMEOUT_S
        con.create_function("crc32", 1, blob_crc32, deterministic=True)
        con.create_function("cevm_trip_vector_v3", 2, _trip_vector_v3, deterministic=True)
        con.create_function("cevm_route_vector_v3", 2, _route_vector_v3, deterministic=True)
        return con

    def _cannot_open(self, exc: sqlite3.Error) -> CevmError:
        """The error for a store file SQLite could not open, with the reason the file
        system gives (a read-only file system, a directory without write permission)."""
        err = translate(exc, self.path, BUSY_TIMEOUT_S)
        if self.readonly or not isinstance(err, StoreAccessError) or err.reason != "cantopen":
            return err or CevmError(f"{self.path}: not a usable cevm store: {exc}")
        where = self.path if self.path.exists() else self.path.parent
        if not os.access(where, os.W_OK):
            why = ("a read-only file system" if _read_only_fs(where) else "no permission to write there")
            what = "written" if self.path.exists() else "created"
            return StoreAccessError(f"{self.path}: the store could not be {what}: {why} ({where}); nothing was "
                                    "changed. Give a --store on a writable disk", "readonly")
        return err

    def _open_readonly(self) -> None:
        """Open with ``mode=ro``: nothing can be written. A store in WAL mode needs its
        ``-shm`` file, which SQLite cannot create in a read-only directory: then, if no
        ``-wal`` file holds changes, the file is opened ``immutable=1`` (read as it is,
        with no locks: nobody can be writing it, since a writer would have made the
        ``-shm`` file); with changes in a ``-wal`` file it is refused (they would be
        missed). A store file this process cannot write, without ``-wal`` and ``-shm``
        files, is read the same way (SQLite would make them, and only a process that can
        lock the file for writing can remove them). An older schema is first migrated,
        which needs write access once."""
        if not self.path.exists():
            raise CevmError(f"{self.path}: no trip store here")
        self._reader_files = not any(Path(f"{self.path}{s}").exists() for s in _READER_FILES)
        uri = self.path.resolve().as_uri() + "?mode=ro"
        try:
            try:
                if self._reader_files and not os.access(self.path, os.W_OK):  # SQLite would make -wal and -shm
                    # files this reader could not remove (that needs the file's write lock): read immutable, as
                    # in a read-only directory (no writer is there, or it would have made them)
                    raise StoreAccessError(f"{self.path}: a read-only file", "readonly")
                self._con = self._connect(uri, uri=True)
                version = stored_version(self._con, self.path)
            except StoreAccessError as exc:
                if exc.reason not in ("cantopen", "readonly"):
                    raise
                self.close()
                wal = Path(f"{self.path}-wal")
                if wal.exists() and wal.stat().st_size > 0:
                    raise StoreAccessError(
                        f"{self.path}: the store could not be read: it has changes in its write-ahead log ({wal}) "
                        "that SQLite cannot read without creating its -shm file, and its directory is read-only; "
                        "copy the store with its -wal file to a writable directory, or open it once with write "
                        "access", "readonly") from None
                self._con = self._connect(uri + "&immutable=1", uri=True)
                self.immutable = True
                version = stored_version(self._con, self.path)
            self._con.execute("PRAGMA query_only=1")
        except BaseException:
            self.close()
            raise
        self.schema_version = version
        if version > 0 and not self._migrate:  # for SQLite's own checks (cevm store check): say what is missing
            self.layout_problems = layout_problems(self._con, min(version, SCHEMA_VERSION))
        elif 0 < version <= SCHEMA_VERSION:
            try:
                check_layout(self._con, self.path, version)
            except BaseException:
                self.close()
                raise
        if version == 0:  # an empty file: no store, and nothing is written into it
            self.close()
            raise CevmError(f"{self.path}: no trip store here: an empty file ("
                            f"{'0 bytes' if self.path.stat().st_size == 0 else 'an SQLite database without tables'}"
                            "); run 'cevm ingest' to make one there, or give another --store")
        if version < SCHEMA_VERSION and not self._migrate:
            return  # for SQLite's own checks only: the queries need the current layout
        if version < SCHEMA_VERSION:  # migrated by a writable opening, then read
            self.close()
            try:
                TripStore(self.path).close()
            except StoreAccessError as exc:
                raise StoreAccessError(
                    f"{self.path}: the store has schema version {version} and this cevm reads version "
                    f"{SCHEMA_VERSION}; migrating it needs write access once ({exc})", exc.reason) from None
            self._open_readonly()
        elif version > SCHEMA_VERSION:
            self.close()
            refuse_newer(version, self.path)

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
            except StoreAccessError as exc:
                if exc.reason != "locked" or time.monotonic() > deadline:
                    raise
                time.sleep(delay_s)
                delay_s = min(2.0 * delay_s, 0.1)

    @classmethod
    def open(cls, path: str | Path | None = None, *, readonly: bool = False) -> TripStore:
        """Open the store at ``path``, or at :func:`default_store_path` if None;
        ``readonly`` (default False) for a command that only reads: it works on a
        read-only file, directory or file system, and never creates the store."""
        return cls(resolve_store_path(path), readonly=readonly)

    def close(self) -> None:
        """Close the connection (idempotent); a reader removes the files SQLite made for it
        (see the module's notes)."""
        if self._con is not None:
            self._con.close()
            self._con = None
        if self._counted:
            self._counted = False
            _OPEN[self._key] -= 1
            if self.readonly and self._reader_files and not self.immutable and _OPEN[self._key] == 0:
                _remove_reader_files(self.path)

    def __enter__(self) -> TripStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ internals

    @property
    def con(self) -> StoreConnection:
        if self._con is None:
            raise CevmError(f"{self.path}: store is closed")
        return self._con

    @contextmanager
    def _write(self) -> Iterator[StoreConnection]:
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
                # SQLite rolled back already (disk full, I/O error): keep the first error
                with contextlib.suppress(sqlite3.Error, CevmError):
                    self._con.execute("ROLLBACK")
            raise

    def _checkpoint(self, stage: str) -> None:
        _checkpoint(stage)  # the module's hook, looked up at each call (tests replace it)


#: The files SQLite makes beside a store in WAL mode, for readers too.
_READER_FILES = ("-wal", "-shm")

#: Connections of this process open on each store (by real path): a reader's files are
#: removed only when none is (closing any descriptor of a file drops every POSIX lock
#: this process holds on it, SQLite's included).
_OPEN: collections.Counter[str] = collections.Counter()

#: SQLite's lock bytes on the database file (os_unix.c): its shared range.
_SHARED_FIRST, _SHARED_SIZE = 0x40000002, 510


def _remove_reader_files(path: Path) -> None:
    """Remove the ``-wal`` and ``-shm`` files SQLite made for a reader of the store at
    ``path``, if no connection has the store open: under a write lock on SQLite's shared
    lock range of the database (every connection holds a read lock there while open, so
    it is refused while any is, and a connection that opens meanwhile waits for it), and
    only when the ``-wal`` file is empty (it holds no commit). The lock is an open file
    description lock where there are such (Linux), which a connection of this very
    process outside :class:`TripStore` (a plain ``sqlite3`` one) also refuses; else a
    POSIX one. Its descriptor is kept open (:data:`_LOCK_FDS`): closing one would drop
    every POSIX lock this process holds on the file, SQLite's included. Anything that
    fails leaves the files as they are (harmless: SQLite uses or removes them later)."""
    try:
        import fcntl
    except ImportError:  # not POSIX: SQLite's files stay
        return
    key = os.path.realpath(path)
    try:
        fd = _LOCK_FDS.get(key)
        if fd is None:
            fd = _LOCK_FDS[key] = os.open(path, os.O_RDWR | getattr(os, "O_CLOEXEC", 0))
        if not _lock_shared_range(fcntl, fd, fcntl.F_WRLCK):
            return  # a connection has it open: its files are in use
        try:
            wal = Path(f"{path}-wal")
            if wal.exists() and wal.stat().st_size > 0:
                return
            for suffix in _READER_FILES:
                Path(f"{path}{suffix}").unlink(missing_ok=True)
        finally:
            _lock_shared_range(fcntl, fd, fcntl.F_UNLCK)
    except OSError:
        pass


#: Descriptors of the stores :func:`_remove_reader_files` locked, kept open (by real path).
_LOCK_FDS: dict[str, int] = {}


def _lock_shared_range(fcntl, fd: int, kind: int) -> bool:
    """Lock (``F_WRLCK``, without waiting) or unlock (``F_UNLCK``) SQLite's shared lock
    range of the database open on ``fd``; False when another lock holds it."""
    if hasattr(fcntl, "F_OFD_SETLK"):
        import struct

        # struct flock: l_type, l_whence (short), l_start, l_len (off_t), l_pid (0 for OFD)
        lock = struct.pack("@hhqqi4x", kind, os.SEEK_SET, _SHARED_FIRST, _SHARED_SIZE, 0)
        try:
            fcntl.fcntl(fd, fcntl.F_OFD_SETLK, lock)
        except (BlockingIOError, PermissionError):
            return False
        return True
    try:
        fcntl.lockf(fd, fcntl.LOCK_UN if kind == fcntl.F_UNLCK else fcntl.LOCK_EX | fcntl.LOCK_NB, _SHARED_SIZE,
                    _SHARED_FIRST, os.SEEK_SET)
    except (BlockingIOError, PermissionError):
        return False
    return True


def _remember_store(path: Path) -> None:
    """The store and its SQLite files among the files no output of this process may
    overwrite (:func:`cevm.io.inputs.remember_file`, on under the command line)."""
    from cevm.io.inputs import remember_file
    from cevm.io.outputs import store_files

    for what, p in store_files(path):
        remember_file(p, f"{what} {p}")


def _not_a_file(path: Path) -> str | None:
    """What ``path`` is when it exists and is not a regular file (a directory, a FIFO, a
    device), else None: SQLite would open any of them."""
    from cevm.io.inputs import file_kind

    try:
        mode = os.stat(path).st_mode
    except OSError:
        return None  # missing (a new store), or unreadable: SQLite says so
    return None if stat.S_ISREG(mode) else file_kind(mode)


def _read_only_fs(path: Path) -> bool:
    """Whether ``path`` lies on a file system mounted read-only (``statvfs``)."""
    try:
        return bool(os.statvfs(path).f_flag & os.ST_RDONLY)
    except (OSError, AttributeError):
        return False
