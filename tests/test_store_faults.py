"""Fault injection against the trip store, through the command line: damaged pages and
blobs, a read-only store, a full disk, a store locked past the busy timeout. Whatever
happens: one clear line and a documented exit code (docs/reference/commands.md), never a
traceback, and the store as it was."""

from __future__ import annotations

import contextlib
import json
import os
import random
import shutil
import sqlite3
import subprocess
import sys
import time
import zlib
from pathlib import Path

import pytest
from typer.testing import CliRunner

import cevm.store.tripstore as trips_module
from fleet_store import BUS, DIESEL, URBAN, make_store

runner = CliRunner()
TESTS_DIR = Path(__file__).resolve().parent
ROOT = TESTS_DIR.parent
SAMPLE_LOG = sorted((ROOT / "sample_logs" / "srf").glob("HGV-11_*"))[0]  # a real log to ingest
EXIT_PARTIAL, EXIT_INPUT, EXIT_STORE_ACCESS, EXIT_STORE_DAMAGED = 1, 2, 3, 4


def cevm(*args: str):
    from cevm.cli import app

    res = runner.invoke(app, [str(a) for a in args])
    # an exception that escaped the command is a bug (a traceback for the user)
    assert res.exception is None or isinstance(res.exception, SystemExit), (args, res.exception, res.output)
    assert "Traceback" not in res.output + res.stderr, res.stderr
    return res


def snapshot(db: Path, runs: bool = True) -> dict:
    """Every row of every table (but the ingest runs' log unless ``runs``), read with
    plain sqlite3, read-only (it never changes the file)."""
    con = sqlite3.connect(f"{db.resolve().as_uri()}?mode=ro", uri=True)
    try:
        tables = [r[0] for r in con.execute("SELECT name FROM sqlite_master WHERE type = 'table'")
                  if runs or r[0] not in ("runs", "sqlite_sequence")]
        return {t: sorted(con.execute(f"SELECT * FROM {t}").fetchall(), key=repr) for t in tables}
    finally:
        con.close()


def last_run(db: Path) -> dict:
    con = sqlite3.connect(f"{db.resolve().as_uri()}?mode=ro", uri=True)
    try:
        row = con.execute("SELECT counts_json FROM runs ORDER BY run_id DESC LIMIT 1").fetchone()
        return json.loads(row[0]) if row and row[0] else {}
    finally:
        con.close()


@pytest.fixture
def fleet(tmp_path):
    db = tmp_path / "store" / "cevm.sqlite"
    db.parent.mkdir()
    ids = make_store(db, tmp_path / "logs")
    return db, ids


def one_error_line(res) -> str:
    lines = [ln for ln in res.stderr.splitlines() if ln.startswith("cevm: error:")]
    assert len(lines) == 1, res.stderr
    return lines[0]


# ------------------------------------------------------------------------ damaged pages


def corrupt(db: Path, seed: int, n_bytes: int = 8192) -> int:
    """Write ``n_bytes`` random bytes into the file past its 100-byte header; returns the offset."""
    size = db.stat().st_size
    rng = random.Random(seed)
    offset = rng.randrange(100, size - n_bytes)
    with open(db, "r+b") as f:
        f.seek(offset)
        f.write(rng.randbytes(n_bytes))
    return offset


READERS = [
    ("trips",),
    ("trips", "--vehicle-id", "HGV-77"),
    ("predict", "-v", BUS, "--vehicle-id", "EB-09", "-f", "csv"),
    ("predict", "-v", DIESEL, "--vehicle-id", "HGV-77", "-f", "csv"),
    ("predict", "-v", BUS, "--route", "R1", "-f", "csv"),
    ("feasibility", "-v", BUS, "--vehicle-id", "EB-09", "-f", "csv"),
    ("calibrate", "-v", DIESEL, "--vehicle-id", "HGV-77", "--ice-braking", "no-credit", "-f", "json"),
    ("route", "list", "-f", "csv"),
    ("store", "info"),
]


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(6))
def test_damaged_pages_are_named_never_a_traceback_and_never_written_into(fleet, seed):
    db, ids = fleet
    offset = corrupt(db, seed)
    check = cevm("store", "check", "--store", db, "-f", "json")
    assert check.exit_code == EXIT_STORE_DAMAGED, (offset, check.output)
    for args in READERS:
        res = cevm(*args, "--store", db)
        assert res.exit_code in (0, EXIT_PARTIAL, EXIT_STORE_DAMAGED), (offset, args, res.stderr)
        if res.exit_code == EXIT_STORE_DAMAGED:
            assert "damaged" in one_error_line(res) and "restore" in res.stderr
        if res.exit_code == EXIT_PARTIAL:  # damaged trips skipped, each named
            assert "skipped: trip '" in res.stderr
    before = db.read_bytes()
    res = cevm("ingest", SAMPLE_LOG, "--store", db, "--workers", "1", "-q")
    assert res.exit_code == EXIT_STORE_DAMAGED and "damaged" in one_error_line(res)
    assert db.read_bytes() == before  # refused before the first write


@pytest.mark.slow
def test_a_file_that_is_not_a_database_is_named_so_by_every_command(tmp_path):
    db = tmp_path / "s.sqlite"
    db.write_bytes(b"hello, not a database\n" * 400)
    before = db.read_bytes()
    for args in [("trips",), ("store", "check"), ("store", "info"), ("predict", "-v", DIESEL, "--vehicle-id", "X"),
                 ("ingest", SAMPLE_LOG, "--workers", "1", "-q"), ("route", "list")]:
        res = cevm(*args, "--store", db)
        assert res.exit_code == EXIT_STORE_DAMAGED, (args, res.stderr)
        line = one_error_line(res)
        assert "not a usable cevm store" in line and "restore the store from a backup" in line
    assert db.read_bytes() == before


# ------------------------------------------------------------------------ damaged blobs


def garble(db: Path, sql: str, *args) -> None:
    con = sqlite3.connect(db)
    with con:
        con.execute(sql, args)
    con.close()


@pytest.mark.slow
def test_damaged_blobs_are_skipped_by_batch_readers_and_refused_by_name(fleet, tmp_path):
    db, ids = fleet
    bus_a, bus_b, bus_ok = ids["EB-09"]
    hgv_a = ids["HGV-77"][3]
    # garbage in place of a vector and a profile (their checksums left as they were)
    garble(db, "UPDATE trip_blobs SET vector = randomblob(400) WHERE trip_id = ?", hgv_a)
    garble(db, "UPDATE trip_blobs SET profile = randomblob(900) WHERE trip_id = ?", bus_b)
    # and a blob replaced together with its checksum: caught by decoding
    junk = b"\x00\x11\x22\x33"
    garble(db, "UPDATE trip_blobs SET vector = ?, vector_crc32 = ? WHERE trip_id = ?", junk, zlib.crc32(junk), bus_a)
    # one flipped bit among a vector's numbers: it decodes, into a wrong prediction, but for its checksum
    hgv_b = ids["HGV-77"][5]
    con = sqlite3.connect(db)
    (vec,) = con.execute("SELECT vector FROM trip_blobs WHERE trip_id = ?", (hgv_b,)).fetchone()
    con.close()
    flipped = bytearray(vec)
    flipped[len(vec) - 20] ^= 0x10
    garble(db, "UPDATE trip_blobs SET vector = ? WHERE trip_id = ?", bytes(flipped), hgv_b)

    check = cevm("store", "check", "--store", db, "-f", "json")
    assert check.exit_code == EXIT_STORE_DAMAGED
    report = json.loads(check.stdout)
    damaged = {p["id"] for p in report["problems"]}
    assert damaged == {hgv_a, hgv_b, bus_a, bus_b, "R1"} and report["integrity"] == "ok"  # R1's first leg is bus_a
    assert report["trips_checked"] == 11

    res = cevm("predict", "-v", BUS, "--vehicle-id", "EB-09", "--store", db, "-f", "csv")
    assert res.exit_code == EXIT_PARTIAL
    rows = res.stdout.strip().splitlines()[1:]
    assert [r.split(",")[0] for r in rows] == [bus_ok]  # the damaged ones left out, the sound one predicted
    assert f"skipped: trip '{bus_a}'" in res.stderr and f"skipped: trip '{bus_b}'" in res.stderr
    assert "checksum mismatch" in res.stderr and "does not decode" in res.stderr

    for trip in (bus_a, bus_b):
        res = cevm("predict", "-v", BUS, "--trip", trip, "--store", db)
        assert res.exit_code == EXIT_STORE_DAMAGED and res.stdout == ""
        line = one_error_line(res)
        assert f"trip '{trip}' is damaged" in line and "--force" in line  # re-ingesting its log file mends it
    res = cevm("simulate", "-v", BUS, "--trip", bus_b, "--store", db)
    assert res.exit_code == EXIT_STORE_DAMAGED and f"trip '{bus_b}' is damaged" in one_error_line(res)

    res = cevm("calibrate", "-v", DIESEL, "--vehicle-id", "HGV-77", "--ice-braking", "no-credit", "--store", db,
               "-f", "json")
    assert res.exit_code == EXIT_PARTIAL, res.stderr
    fitted = {t["trip_id"] for t in json.loads(res.stdout)["trips"]}
    assert hgv_a not in fitted and hgv_b not in fitted and len(fitted) == 6
    assert f"skipped: trip '{hgv_a}'" in res.stderr and f"skipped: trip '{hgv_b}'" in res.stderr
    res = cevm("predict", "-v", DIESEL, "--trip", hgv_b, "--store", db)
    assert res.exit_code == EXIT_STORE_DAMAGED and f"trip '{hgv_b}' is damaged in the store (vector: checksum" \
        in one_error_line(res)

    before = snapshot(db)
    for trip in (hgv_a, bus_b):  # a route never refers to a damaged trip
        res = cevm("route", "add", "R2", "--trip", ids["HGV-77"][0], "--trip", trip, "--store", db)
        assert res.exit_code == EXIT_STORE_DAMAGED and f"trip '{trip}' is damaged" in one_error_line(res)
    assert snapshot(db) == before


@pytest.mark.slow
def test_a_damaged_route_leg_is_named_by_route(fleet):
    db, ids = fleet
    garble(db, "UPDATE route_legs SET profile = randomblob(300) WHERE route = 'R1' AND kind = 'cycle'")
    res = cevm("predict", "-v", BUS, "--route", "R1", "--store", db, "-f", "csv")
    assert res.exit_code == EXIT_STORE_DAMAGED and res.stdout == ""  # found before the first row
    assert "route 'R1' is damaged in the store (profile: checksum mismatch)" in one_error_line(res)
    listed = cevm("route", "list", "--store", db, "-f", "json")
    assert listed.exit_code == 0 and "damaged" in listed.stdout
    check = cevm("store", "check", "--store", db, "-f", "json")
    assert check.exit_code == EXIT_STORE_DAMAGED and '"id": "R1"' in check.stdout


# ----------------------------------------------------------------------------- read-only

IS_ROOT = os.geteuid() == 0


@contextlib.contextmanager
def read_only(db: Path, how: str, checkpoint: bool = True):
    """Make the store read-only: its file (chattr +i, chmod 444), its directory (chattr +i,
    chmod 555), or its file system (a read-only bind mount); yields the store's path then.
    ``checkpoint`` first: the store's -wal merged into it and deleted, with its -shm."""
    d = db.parent
    if checkpoint:
        con = sqlite3.connect(db)  # the last connection to close checkpoints and deletes -wal and -shm:
        con.execute("SELECT 1 FROM sqlite_master").fetchall()  # a read-only directory then holds the file alone
        con.close()
        assert not Path(f"{db}-wal").exists() and not Path(f"{db}-shm").exists()
    if how.startswith("chmod"):
        if IS_ROOT:
            pytest.skip("root ignores file permissions (the chattr and mount cases cover this)")
        target = db if how == "chmod-file" else d
        mode = target.stat().st_mode
        target.chmod(0o444 if target == db else 0o555)
        try:
            yield db
        finally:
            target.chmod(mode)
    elif how.startswith("chattr"):
        target = db if how == "chattr-file" else d
        if shutil.which("chattr") is None or subprocess.run(["chattr", "+i", str(target)],
                                                             capture_output=True).returncode != 0:
            pytest.skip("chattr +i is not available here")
        try:
            yield db
        finally:
            subprocess.run(["chattr", "-i", str(target)], check=True)
    else:
        mnt = d.parent / "ro-mount"
        mnt.mkdir()
        ok = (IS_ROOT and subprocess.run(["mount", "--bind", str(d), str(mnt)], capture_output=True).returncode == 0)
        if not ok:
            pytest.skip("cannot bind-mount here (needs root)")
        try:
            if subprocess.run(["mount", "-o", "remount,bind,ro", str(mnt)], capture_output=True).returncode != 0:
                pytest.skip("cannot remount read-only here")
            yield mnt / db.name
        finally:
            subprocess.run(["umount", str(mnt)], check=True)


READ_ONLY_READERS = [
    ("trips",),
    ("predict", "-v", BUS, "--vehicle-id", "EB-09", "-f", "csv"),
    ("predict", "-v", DIESEL, "--trip", None, "-f", "csv"),
    ("feasibility", "-v", BUS, "--route", "R1", "-f", "csv"),
    ("calibrate", "-v", DIESEL, "--vehicle-id", "HGV-77", "--ice-braking", "no-credit", "-f", "json"),
    ("route", "list"),
    ("store", "check"),
    ("store", "info"),
    ("simulate", "-v", BUS, "--trip", None),
]


def comparable(args, stdout: str, path: Path):
    """What a reader printed, without what differs from run to run (calibrate's timings)."""
    if args[0] == "calibrate":
        out = json.loads(stdout)
        return out["eta"], out["trips"]
    if args[:2] == ("store", "info"):  # says how it was opened
        return "schema version" in stdout
    return stdout.replace(str(path), "STORE")


@pytest.mark.slow
@pytest.mark.parametrize("how", ["chattr-file", "chattr-dir", "mount", "chmod-file", "chmod-dir"])
def test_read_only_store_reads_and_refuses_writes_in_one_line(fleet, how, tmp_path):
    db, ids = fleet
    before = snapshot(db)
    expected = {}
    for args in READ_ONLY_READERS:  # what they print on the writable store
        args = tuple(ids["HGV-77"][0] if a is None else a for a in args)
        expected[args] = comparable(args, cevm(*args, "--store", db).stdout, db)
    with read_only(db, how) as path:
        for args in expected:
            res = cevm(*args, "--store", path)
            assert res.exit_code == 0, (how, args, res.stderr)
            assert comparable(args, res.stdout, path) == expected[args], (how, args)
        for args in [("ingest", SAMPLE_LOG, "--workers", "1", "-q"), ("route", "add", "R9", "--cycle", URBAN),
                     ("route", "remove", "R1")]:
            res = cevm(*args, "--store", path)
            assert res.exit_code == EXIT_STORE_ACCESS, (how, args, res.stderr)
            line = one_error_line(res)
            assert "could not be" in line and "nothing was changed" in line, line
    assert snapshot(db) == before


def test_a_read_only_directory_with_changes_in_its_wal_is_refused_not_read_stale(fleet, tmp_path):
    """immutable=1 would read the store without its -wal file: the trips written last would
    be silently missing. Refused instead."""
    db, ids = fleet
    copy = tmp_path / "copy"
    copy.mkdir()
    con = sqlite3.connect(db, isolation_level=None)
    con.execute("PRAGMA wal_autocheckpoint=0")
    con.execute("DELETE FROM route_legs")
    con.execute("DELETE FROM routes")  # a change that lives in the -wal file only
    shutil.copy(db, copy / db.name)
    shutil.copy(f"{db}-wal", copy / f"{db.name}-wal")  # no -shm: as left by a copy, or a crash
    con.close()
    with read_only(copy / db.name, "chattr-dir", checkpoint=False) as path:
        res = cevm("route", "list", "--store", path)
        assert res.exit_code == EXIT_STORE_ACCESS and "write-ahead log" in one_error_line(res)
    with read_only(copy / db.name, "chattr-dir") as path:  # once merged, it reads, with the change
        res = cevm("route", "list", "--store", path, "-f", "json")
        assert res.exit_code == 0 and json.loads(res.stdout) == []


# ------------------------------------------------------------------------------ disk full


@contextlib.contextmanager
def small_tmpfs(where: Path, size: str = "4m"):
    where.mkdir()
    if not IS_ROOT or subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(where)],
                                     capture_output=True).returncode != 0:
        pytest.skip("cannot mount a tmpfs here (needs root)")
    try:
        yield where
    finally:
        subprocess.run(["umount", str(where)], check=True)


@pytest.mark.slow
def test_a_full_disk_is_one_line_and_the_store_as_it_was(fleet, tmp_path):
    db, ids = fleet
    with small_tmpfs(tmp_path / "small") as small:
        store = small / "cevm.sqlite"
        shutil.copy(db, store)
        before = snapshot(store, runs=False)
        filler = small / "filler"
        with open(filler, "wb") as f:  # fill the disk but for 8 kB
            free = shutil.disk_usage(small).free
            f.write(b"\0" * max(0, free - 8192))
        for args in [("ingest", SAMPLE_LOG, "--workers", "1", "-q"), ("route", "add", "R9", "--cycle", URBAN)]:
            res = cevm(*args, "--store", store)
            assert res.exit_code == EXIT_STORE_ACCESS, (args, res.stderr)
            assert "the disk is full" in one_error_line(res)
            assert snapshot(store, runs=False) == before
            if args[0] == "ingest":  # its run's record, if it could be written, says why it stopped
                assert "disk is full" in last_run(store).get("stopped_by", "disk is full")
        filler.unlink()
        res = cevm("route", "add", "R9", "--cycle", URBAN, "--store", store)  # and once there is room, it works
        assert res.exit_code == 0, res.stderr


FSIZE_CHILD = """
import resource, sys
limit = int(sys.argv[1])
resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
from cevm.cli import main
sys.argv = ["cevm", *sys.argv[2:]]
main()
"""


@pytest.mark.slow
def test_a_file_size_limit_is_one_line_and_the_store_as_it_was(fleet, tmp_path):
    """The same through RLIMIT_FSIZE in a subprocess (no root needed): the -wal file may not
    grow past 16 kB, so the first large write fails."""
    db, ids = fleet
    before = snapshot(db)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")]))
    for args in [("ingest", str(SAMPLE_LOG), "--workers", "1", "-q"), ("route", "add", "R9", "--cycle", str(URBAN))]:
        proc = subprocess.run([sys.executable, "-c", FSIZE_CHILD, "16384", *args, "--store", str(db)],
                              capture_output=True, text=True, env=env, timeout=120)
        assert proc.returncode == EXIT_STORE_ACCESS, proc.stderr
        assert "Traceback" not in proc.stderr
        errors = [ln for ln in proc.stderr.splitlines() if ln.startswith("cevm: error:")]
        assert len(errors) == 1 and "could not be written" in errors[0], proc.stderr
        assert snapshot(db) == before


# --------------------------------------------------------------------------------- locked


@pytest.mark.slow
def test_locked_past_the_busy_timeout_is_one_line_and_the_store_as_it_was(fleet, monkeypatch):
    db, ids = fleet
    before = snapshot(db)
    monkeypatch.setattr(trips_module, "BUSY_TIMEOUT_S", 0.3)
    holder = sqlite3.connect(db, isolation_level=None)
    holder.execute("BEGIN IMMEDIATE")  # another process's write transaction, hung
    try:
        for args in [("ingest", SAMPLE_LOG, "--workers", "1", "-q"), ("route", "add", "R9", "--cycle", URBAN),
                     ("route", "remove", "R1")]:
            t0 = time.monotonic()
            res = cevm(*args, "--store", db)
            assert res.exit_code == EXIT_STORE_ACCESS, (args, res.stderr)
            assert time.monotonic() - t0 >= 0.3  # it did wait for the lock
            line = one_error_line(res)
            assert "held its write lock for more than 0.3 s" in line and "nothing was changed" in line
        res = cevm("trips", "--store", db)  # readers are never blocked by a writer
        assert res.exit_code == 0 and ids["EB-09"][0] in res.stdout
    finally:
        holder.execute("ROLLBACK")
        holder.close()
    assert snapshot(db) == before
