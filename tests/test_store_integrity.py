"""The store's integrity against what an operator's trial found: every writer
checks the store as ingest does; read-only commands never create or change a file; a blob
without a checksum is damage; a blob whose checksum is valid but whose content is a zip
bomb costs no more memory than the trip it claims to be; text that is not UTF-8 in a row
is damage named in one line. Each through the command line, as an operator meets it."""

from __future__ import annotations

import json
import os
import random
import re
import sqlite3
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest

from fleet_store import BUS, DIESEL, URBAN, make_store
from test_store_faults import EXIT_INPUT, EXIT_PARTIAL, EXIT_STORE_DAMAGED, cevm, garble, one_error_line, read_only

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def fleet(tmp_path):
    db = tmp_path / "store" / "cevm.sqlite"
    db.parent.mkdir()
    ids = make_store(db, tmp_path / "logs")
    con = sqlite3.connect(db)  # the last connection checkpoints: the store is one file, as it is at rest
    con.execute("SELECT 1").fetchall()
    con.close()
    return db, ids


def state(path: Path) -> tuple:
    """A file's bytes and modification time (ns), and the names beside it."""
    st = path.stat()
    return path.read_bytes(), st.st_mtime_ns, sorted(p.name for p in path.parent.iterdir())


# ------------------------------------------------------------------- writers check it


def damage(db: Path, seed: int) -> None:
    size = db.stat().st_size
    rng = random.Random(seed)
    offset = rng.randrange(100, size - 8192)
    with open(db, "r+b") as f:
        f.seek(offset)
        f.write(rng.randbytes(8192))


WRITERS = [
    ("trips", "set-mass", None, "--gross-kg", "30000"),
    ("route", "add", "R5", "--cycle", URBAN),
    ("route", "remove", "R1"),
]


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1, 2, 5, 8])  # seeds whose damage the writers wrote into before
def test_every_writer_refuses_a_store_that_ingest_refuses(fleet, seed):
    db, ids = fleet
    damage(db, seed)
    ingest = cevm("ingest", ROOT / "sample_logs" / "srf" / "EB-01_2019-01-31.csv", "--store", db, "--workers", "1",
                  "-q")
    assert ingest.exit_code == EXIT_STORE_DAMAGED  # the reference: ingest refuses it
    before = state(db)
    for args in WRITERS:
        args = tuple(ids["HGV-77"][0] if a is None else a for a in args)
        res = cevm(*args, "--store", db)
        assert res.exit_code == EXIT_STORE_DAMAGED, (seed, args, res.stderr)
        assert "damaged" in one_error_line(res) and "nothing was written" in res.stderr
        assert state(db) == before, (seed, args)


# ------------------------------------------------ read-only commands never write a file

READERS = [
    ("trips",),
    ("trips", "--vehicle-id", "HGV-77"),
    ("predict", "-v", BUS, "--vehicle-id", "EB-09"),
    ("predict", "-v", BUS, "--trip", "EB-09:1610000000:bbbbbbbb"),
    ("predict", "-v", BUS, "--route", "R1"),
    ("feasibility", "-v", BUS, "--vehicle-id", "EB-09"),
    ("calibrate", "-v", DIESEL, "--vehicle-id", "HGV-77"),
    ("simulate", "-v", BUS, "--trip", "EB-09:1610000000:bbbbbbbb"),
    ("route", "list"),
    ("store", "check"),
    ("store", "info"),
    ("replay", "-v", BUS, "--vehicle-id", "EB-09"),
]


@pytest.mark.slow
@pytest.mark.parametrize("args", READERS, ids=[" ".join(map(str, a[:2])) for a in READERS])
def test_a_reader_on_an_empty_file_says_no_store_and_writes_nothing(tmp_path, args):
    db = tmp_path / "d" / "empty.sqlite"
    db.parent.mkdir()
    db.touch()
    os.utime(db, ns=(1_000_000_000, 1_000_000_000))
    before = state(db)
    res = cevm(*args, "--store", db)
    assert res.exit_code == EXIT_INPUT, (args, res.stderr)
    assert "no trip store here: an empty file" in one_error_line(res) and res.stdout == ""
    assert state(db) == before  # no schema written, no -wal or -shm made


@pytest.mark.slow
@pytest.mark.parametrize("args", READERS, ids=[" ".join(map(str, a[:2])) for a in READERS])
def test_a_reader_on_a_missing_store_creates_nothing(tmp_path, args):
    missing = tmp_path / "nowhere" / "deeper" / "s.sqlite"
    res = cevm(*args, "--store", missing)
    assert res.exit_code == EXIT_INPUT and "no trip store here" in one_error_line(res)
    assert not (tmp_path / "nowhere").exists()
    beside = tmp_path / "d"
    beside.mkdir()
    res = cevm(*args, "--store", beside / "s.sqlite")
    assert res.exit_code == EXIT_INPUT and list(beside.iterdir()) == []


@pytest.mark.slow
@pytest.mark.parametrize("how", ["chattr-dir", "mount"])
def test_readers_in_a_read_only_directory_read_a_store_and_refuse_an_empty_file(fleet, how, tmp_path):
    db, ids = fleet
    empty = db.parent / "empty.sqlite"
    empty.touch()
    with read_only(db, how) as path:
        before = state(path), state(path.parent / "empty.sqlite")
        for args in READERS:
            res = cevm(*args, "--store", path, "-f", "json") if args[0] in ("trips", "route", "store") else \
                cevm(*args, "--store", path)
            assert res.exit_code in (0, EXIT_PARTIAL), (how, args, res.stderr)
            res = cevm(*args, "--store", path.parent / "empty.sqlite")
            assert res.exit_code == EXIT_INPUT, (how, args, res.stderr)
            res = cevm(*args, "--store", path.parent / "missing.sqlite")
            assert res.exit_code == EXIT_INPUT, (how, args, res.stderr)
        assert (state(path), state(path.parent / "empty.sqlite")) == before


# ------------------------------------------------------------------- NULL checksums


@pytest.mark.parametrize("column", ["vector_crc32", "profile_crc32"])
def test_a_blob_without_its_checksum_is_damage(fleet, column):
    db, ids = fleet
    bus_a, bus_b, bus_ok = ids["EB-09"]
    garble(db, f"UPDATE trip_blobs SET {column} = NULL WHERE trip_id = ?", bus_b)
    check = cevm("store", "check", "--store", db, "-f", "json")
    assert check.exit_code == EXIT_STORE_DAMAGED, check.stdout
    problems = json.loads(check.stdout)["problems"]
    assert [p["id"] for p in problems] == [bus_b] and "checksum is missing" in problems[0]["problem"]
    res = cevm("predict", "-v", BUS, "--trip", bus_b, "--store", db)
    assert res.exit_code == EXIT_STORE_DAMAGED and f"trip '{bus_b}' is damaged" in one_error_line(res)
    res = cevm("predict", "-v", BUS, "--vehicle-id", "EB-09", "--store", db, "-f", "csv")
    assert res.exit_code == EXIT_PARTIAL and f"skipped: trip '{bus_b}'" in res.stderr
    assert [r.split(",")[0] for r in res.stdout.strip().splitlines()[1:]] == [bus_a, bus_ok]
    res = cevm("route", "add", "R2", "--trip", bus_b, "--store", db)
    assert res.exit_code == EXIT_STORE_DAMAGED


@pytest.mark.parametrize("column", ["vector_crc32", "profile_crc32"])
def test_a_route_leg_without_its_checksum_is_damage(fleet, column):
    db, ids = fleet
    garble(db, f"UPDATE route_legs SET {column} = NULL WHERE route = 'R1' AND kind = 'cycle'")
    res = cevm("predict", "-v", BUS, "--route", "R1", "--store", db, "-f", "csv")
    assert res.exit_code == EXIT_STORE_DAMAGED and res.stdout == ""
    assert "route 'R1' is damaged in the store" in one_error_line(res) and "checksum is missing" in res.stderr
    check = cevm("store", "check", "--store", db, "-f", "json")
    assert check.exit_code == EXIT_STORE_DAMAGED and [p["id"] for p in json.loads(check.stdout)["problems"]] == ["R1"]
    listed = cevm("route", "list", "--store", db, "-f", "json")
    assert listed.exit_code == 0 and json.loads(listed.stdout)[0]["status"].startswith("broken")


# ------------------------------------------------------------------- text not UTF-8


def test_text_that_is_not_utf8_is_damage_in_one_line(fleet):
    db, ids = fleet
    garble(db, "UPDATE trips SET quality_json = CAST(x'7b22ff22' AS TEXT) WHERE trip_id = ?", ids["HGV-77"][2])
    for args in [("trips",), ("trips", "--vehicle-id", "HGV-77", "-f", "csv"),
                 ("calibrate", "-v", DIESEL, "--vehicle-id", "HGV-77"), ("store", "info")]:
        res = cevm(*args, "--store", db)
        if args[0] == "store":
            assert res.exit_code == 0
            continue
        assert res.exit_code == EXIT_STORE_DAMAGED, (args, res.stderr)
        line = one_error_line(res)
        assert "column 'quality_json' is not UTF-8" in line and "restore" in line


# ------------------------------------------------------------------------ blob bombs

BOMB_SAMPLES = 12_000_000  # above the 10 M samples any stored profile may decode to


def _zeros_stream(nbytes: int) -> bytes:
    """A zlib stream of ``nbytes`` zero bytes, made in chunks (a few MB at a time)."""
    z = zlib.compressobj(9)
    chunk = bytes(8 << 20)
    parts = [z.compress(chunk) for _ in range(nbytes // len(chunk))]
    parts.append(z.compress(bytes(nbytes % len(chunk))))
    parts.append(z.flush())
    return b"".join(parts)


def trip_profile_bomb(n: int) -> bytes:
    """A trip profile blob in the stored layout whose header and streams say ``n``
    samples: valid, decodable, and about 48 n bytes once inflated."""
    from cevm.store.codec import PROFILE_DTYPES

    entries, payloads = [], []
    for name, dtype in PROFILE_DTYPES.items():
        payload = _zeros_stream(n * np.dtype(dtype).itemsize)
        entries.append([name, dtype, len(payload)])
        payloads.append(payload)
    header = json.dumps({"n": n, "codec": "shuffle+zlib", "arrays": entries}).encode()
    return b"".join([b"CEVMPRF1", struct.pack("<I", len(header)), header, *payloads])


def route_profile_bomb(n: int) -> bytes:
    return b"CEVMRTP1" + struct.pack("<II", n, 1) + _zeros_stream(3 * 8 * n)


PEAK_CHILD = """
import re, sys
from cevm.cli import main
sys.argv = ["cevm", *sys.argv[1:]]
try:
    main()
except SystemExit as exc:
    code = exc.code
with open("/proc/self/status") as fh:
    peak = int(re.search(r"VmHWM:\\s+(\\d+)", fh.read()).group(1)) / 1024
sys.stderr.write(f"@@peak_mb {peak:.0f}\\n")
sys.exit(code)
"""


def run_measured(*args) -> tuple[subprocess.CompletedProcess, float]:
    """``cevm ARGS`` in a process of its own, and its peak resident memory [MB]."""
    # a wide terminal: store check's table must not wrap the message the test reads (a
    # pytest-xdist worker has no terminal, and COLUMNS of the caller's would apply)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")]),
               COLUMNS="400")
    proc = subprocess.run([sys.executable, "-c", PEAK_CHILD, *map(str, args)], capture_output=True, text=True,
                          env=env, timeout=300)
    peak = float(proc.stderr.rsplit("@@peak_mb ", 1)[1])
    return proc, peak


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs /proc (Linux)")
def test_a_bomb_with_a_valid_checksum_is_refused_within_the_trips_own_memory(fleet):
    db, ids = fleet
    bomb = trip_profile_bomb(BOMB_SAMPLES)  # 4 MB here, 576 MB once inflated
    trip = ids["EB-09"][1]
    garble(db, "UPDATE trip_blobs SET profile = ?, profile_crc32 = ? WHERE trip_id = ?", bomb, zlib.crc32(bomb), trip)
    garble(db, "UPDATE trips SET n_samples = ? WHERE trip_id = ?", BOMB_SAMPLES, trip)  # its row says so too
    for args in (("store", "check"), ("simulate", "-v", BUS, "--trip", trip), ("predict", "-v", BUS, "--trip", trip,
                                                                                  "--range")):
        proc, peak = run_measured(*args, "--store", db)
        said = proc.stdout + proc.stderr  # store check's table is its output
        # the table folds a cell where the store's path (longer under pytest -n) ends a line
        flat = re.sub(r"[\s│┃]+", " ", said)
        assert proc.returncode == EXIT_STORE_DAMAGED, (args, said)
        # the blob's header (store check, simulate) or the trip's row (predict reads it first) names the count
        assert "Traceback" not in said and re.search(f"its (header|row) says {BOMB_SAMPLES:,} samples", flat), said
        assert peak < 250, (args, peak)  # the command's own size: nothing inflated


def test_a_header_other_than_the_trips_sample_count_is_damage(fleet):
    db, ids = fleet
    trip = ids["EB-09"][1]
    con = sqlite3.connect(db)
    (n,) = con.execute("SELECT n_samples FROM trips WHERE trip_id = ?", (trip,)).fetchone()
    con.close()
    bomb = trip_profile_bomb(n + 1000)
    garble(db, "UPDATE trip_blobs SET profile = ?, profile_crc32 = ? WHERE trip_id = ?", bomb, zlib.crc32(bomb), trip)
    res = cevm("simulate", "-v", BUS, "--trip", trip, "--store", db)
    assert res.exit_code == EXIT_STORE_DAMAGED
    assert f"its header says {n + 1000:,} samples, the trip {n:,}" in one_error_line(res)


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs /proc (Linux)")
def test_a_route_leg_bomb_is_refused_before_it_is_inflated(fleet):
    db, ids = fleet
    bomb = route_profile_bomb(BOMB_SAMPLES)
    garble(db, "UPDATE route_legs SET profile = ?, profile_crc32 = ? WHERE route = 'R1' AND kind = 'cycle'", bomb,
           zlib.crc32(bomb))
    for args in (("store", "check"), ("predict", "-v", BUS, "--route", "R1")):
        proc, peak = run_measured(*args, "--store", db)
        said = proc.stdout + proc.stderr
        assert proc.returncode == EXIT_STORE_DAMAGED, (args, said)
        assert "R1" in said and f"its header says {BOMB_SAMPLES:,} samples" in said and "Traceback" not in said, said
        assert peak < 250, (args, peak)


def test_decoding_inflates_no_stream_past_its_header():
    """The codec alone: a stream longer than its header says, or shorter, is refused; a
    zero-sample header with a non-empty stream too (zlib's max_length 0 means no limit)."""
    from cevm.errors import CevmError
    from cevm.store.codec import MAX_PROFILE_SAMPLES, decode_profile, encode_profile, inflate_exactly

    prof = {k: np.arange(5.0) for k in ("time_s", "speed_mps", "distance_m", "elevation_m", "lat_deg", "lon_deg")}
    blob = encode_profile(prof)
    assert decode_profile(blob, 5)["time_s"].tolist() == [0, 1, 2, 3, 4]
    with pytest.raises(CevmError, match="the trip 6"):
        decode_profile(blob, 6)
    hlen = struct.unpack_from("<I", blob, 8)[0]  # the current format (zstd): a header of 6 over streams of 5
    head = json.loads(blob[12:12 + hlen])
    head["n"] = 6
    forged = json.dumps(head).encode()
    with pytest.raises(CevmError, match="does not decompress to the 48 bytes of its header"):
        decode_profile(blob[:8] + struct.pack("<I", len(forged)) + forged + blob[12 + hlen:])
    stream = zlib.compress(bytes(1000))
    for size in (0, 999, 1001):
        with pytest.raises(CevmError, match="inflates to"):
            inflate_exactly(stream, size)
    assert inflate_exactly(stream, 1000) == bytes(1000)
    header = json.dumps({"n": MAX_PROFILE_SAMPLES + 1, "codec": "shuffle+zlib", "arrays": []}).encode()
    with pytest.raises(CevmError, match="at most"):
        decode_profile(b"CEVMPRF1" + struct.pack("<I", len(header)) + header)


def test_store_check_reads_every_trips_row(fleet):
    """A row whose text is not UTF-8, or whose quality summary is not JSON, is named by
    `store check` (it said "sound" while `cevm trips` stopped on the row)."""
    db, ids = fleet
    a, b = ids["HGV-77"][2], ids["EB-09"][1]
    garble(db, "UPDATE trips SET quality_json = CAST(x'7b22ff22' AS TEXT) WHERE trip_id = ?", a)
    garble(db, "UPDATE trips SET quality_json = '{\"cut' WHERE trip_id = ?", b)
    check = cevm("store", "check", "--store", db, "-f", "json")
    assert check.exit_code == EXIT_STORE_DAMAGED
    problems = {p["id"]: p["problem"] for p in json.loads(check.stdout)["problems"]}
    assert set(problems) == {a, b}
    assert "its row cannot be read" in problems[a] and "quality_json" in problems[a]
    assert problems[b].startswith("its quality summary is not JSON")
    from cevm.store import TripStore
    from cevm.store.failures import DamagedTripError

    with TripStore(db, readonly=True) as st, pytest.raises(DamagedTripError, match="quality: not JSON"):
        st.load_trip(b)


@pytest.mark.slow
@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs here")
def test_a_store_that_is_a_fifo_a_device_or_a_directory_is_refused(tmp_path):
    """SQLite opens whatever it is given: on a FIFO every command hung where no signal
    reaches it (SIGTERM could not stop it), /dev/null took writes into nothing and left
    -wal and -shm files in /dev. Refused in one line (exit 2) before SQLite sees it."""
    fifo = tmp_path / "store.sqlite"
    os.mkfifo(fifo)
    # a wide terminal: store check's table must not wrap the message the test reads (a
    # pytest-xdist worker has no terminal, and COLUMNS of the caller's would apply)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")]),
               COLUMNS="400")
    for args in (("trips",), ("store", "check"), ("route", "add", "R1", "--cycle", URBAN)):
        proc = subprocess.run([sys.executable, "-m", "cevm", *map(str, args), "--store", str(fifo)],
                              capture_output=True, text=True, env=env, timeout=60)
        assert proc.returncode == EXIT_INPUT, (args, proc.stderr)
        assert proc.stderr.splitlines() == [f"cevm: error: {fifo}: is a FIFO (named pipe), not a cevm store file"]
    for store, kind in ((Path("/dev/null"), "a character device"), (tmp_path, "a directory")):
        if not store.exists():
            continue
        before = sorted(p.name for p in store.parent.iterdir())
        for args in (("store", "info"), ("route", "add", "R1", "--cycle", URBAN)):
            res = cevm(*args, "--store", store)
            assert res.exit_code == EXIT_INPUT and f"{store}: is {kind}, not a cevm store file" in one_error_line(res)
        assert sorted(p.name for p in store.parent.iterdir()) == before  # no -wal, no -shm beside it
