"""An ingest with workers, stopped from outside (SIGKILL, SIGTERM, SIGINT): no process of it
is left, the store is consistent, and after a signal it handles it says in one line what
it stored, with the documented exit code. Each run is a real ``cevm`` process in a session
of its own (tests/faults.py installs the fault-injecting task), scanned through /proc."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest

import faults
from test_ingest import write_srf
from test_parallel import run, store_content

pytestmark = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc (Linux)")

FAULTS = Path(faults.__file__)
N_FILES = 6
GONE_WITHIN_S = 15.0  # a loaded 2-core machine; the kernel's parent-death signal is immediate


@pytest.fixture
def logs(tmp_path):
    """Six small srf files; the last in input order (z_held.csv) holds its worker."""
    d = tmp_path / "logs"
    d.mkdir()
    names = [f"a{k}.csv" for k in range(N_FILES - 1)] + ["z_held.csv"]
    for k, name in enumerate(names):
        write_srf(d / name, f"EB-0{k}", 1_557_820_800 + 86_400 * k, k, n=300)
    return d


@pytest.fixture
def reference(logs, tmp_path):
    """The store a plain serial ingest of the logs makes."""
    store = tmp_path / "reference.sqlite"
    assert run("ingest", logs, "--store", store, "--workers", "1", "-q").exit_code == 0
    return store_content(store)


def start(args: list, tmp_path: Path) -> tuple[subprocess.Popen, Path, Path]:
    out, err = tmp_path / "stdout.txt", tmp_path / "stderr.txt"
    proc = subprocess.Popen([sys.executable, str(FAULTS), *map(str, args)], start_new_session=True,
                            stdout=open(out, "w"), stderr=open(err, "w"),  # noqa: SIM115 (the child holds them)
                            stdin=subprocess.DEVNULL)
    return proc, out, err


def files_ok(store: Path) -> int:
    try:
        con = sqlite3.connect(f"file:{store}?mode=ro", uri=True, timeout=1)
        try:
            return con.execute("SELECT COUNT(*) FROM files WHERE status = 'ok'").fetchone()[0]
        finally:
            con.close()
    except sqlite3.Error:
        return 0  # not created yet


def wait_for(cond, what: str, timeout_s: float = 90.0) -> None:
    t_end = time.monotonic() + timeout_s
    while not cond():
        if time.monotonic() > t_end:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.05)


def left_over(sid: int) -> list[tuple[int, str]]:
    """The session's live processes once they had ``GONE_WITHIN_S`` to end; killed
    then (they are this test's), so a failure leaves nothing running."""
    t_end = time.monotonic() + GONE_WITHIN_S
    while (procs := faults.session_processes(sid)) and time.monotonic() < t_end:
        time.sleep(0.1)
    for pid, _ in procs:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
    return procs


def held_mid_run(logs: Path, store: Path, proc: subprocess.Popen, files_before: int) -> None:
    """Wait until the held file's task runs in a worker and the files before it are
    stored; check that the workers are there to be left behind."""
    wait_for(lambda: faults.markers(logs, "z_held.csv.held-*") or proc.poll() is not None, "the held task")
    wait_for(lambda: files_ok(store) >= files_before or proc.poll() is not None, "the first files")
    assert proc.poll() is None, "the ingest ended early"
    procs = faults.session_processes(proc.pid)
    kinds = [cmd for _, cmd in procs]
    assert len(procs) >= 4, kinds  # the ingest, its forkserver, 2 workers (and the resource tracker)
    assert sum("forkserver" in c for c in kinds) >= 3, kinds


def check_consistent(store: Path, reference: dict, logs: Path, stored: int) -> None:
    """The store holds ``stored`` whole files, each exactly as the serial ingest stores
    it, and nothing of the others; a new run completes it to the serial store."""
    con = sqlite3.connect(store)
    try:
        assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    finally:
        con.close()
    got = store_content(store)
    paths = {f[0] for f in got["files"]}
    assert len(got["files"]) == stored and all(f[5] == "ok" for f in got["files"])
    assert got["files"] == [f for f in reference["files"] if f[0] in paths]
    assert got["trips"] == [t for t in reference["trips"] if t[2] in paths]
    assert got["blobs"] == [b for b in reference["blobs"] if b[0] in {t[0] for t in got["trips"]}]
    res = run("ingest", logs, "--store", store, "--workers", "2", "-q")
    assert res.exit_code == 0, res.output
    assert store_content(store) == reference


@pytest.mark.slow
def test_sigkill_of_an_ingest_leaves_no_process_and_a_consistent_store(logs, reference, tmp_path):
    store = tmp_path / "s.sqlite"
    (logs / "z_held.csv.hold").touch()
    proc, _, _ = start(["--task-s", "0", "ingest", logs, "--store", store, "--workers", "2", "-q"], tmp_path)
    try:
        held_mid_run(logs, store, proc, N_FILES - 1)
        os.kill(proc.pid, signal.SIGKILL)
        assert proc.wait(30) == -signal.SIGKILL
    finally:
        procs = left_over(proc.pid)
    assert procs == [], f"left running after kill -9 of the ingest: {procs}"
    (logs / "z_held.csv.hold").unlink()
    check_consistent(store, reference, logs, N_FILES - 1)


@pytest.mark.slow
@pytest.mark.parametrize("sig, code, to_group", [(signal.SIGTERM, 143, False), (signal.SIGINT, 130, True)],
                         ids=["kill PID", "Ctrl-C"])
def test_sigterm_and_sigint_stop_an_ingest_cleanly_and_say_what_was_stored(logs, reference, tmp_path, sig, code,
                                                                            to_group):
    """SIGTERM to the ingest alone (``kill PID``), SIGINT to its whole process group,
    workers included (Ctrl-C in a terminal): the same clean stop, and no other line."""
    store = tmp_path / "s.sqlite"
    (logs / "z_held.csv.hold").touch()
    proc, out, err = start(["--task-s", "0", "ingest", logs, "--store", store, "--workers", "2", "--log-json"],
                           tmp_path)
    try:
        held_mid_run(logs, store, proc, N_FILES - 1)
        (os.killpg if to_group else os.kill)(proc.pid, sig)
        assert proc.wait(30) == code
    finally:
        procs = left_over(proc.pid)
    assert procs == [], f"left running after {sig.name}: {procs}"
    lines = err.read_text().splitlines()
    name = sig.name
    assert lines == [f"cevm ingest: interrupted by {name}: {N_FILES - 1} of {N_FILES} files done "
                     f"({N_FILES - 1} ingested, 0 unchanged, 0 failed) and stored as reported; 1 not done, "
                     f"left as they were (run again to ingest them) -> {store}"], lines
    events = [json.loads(line) for line in out.read_text().splitlines()]
    assert [e["event"] for e in events] == ["file"] * (N_FILES - 1) + ["interrupted"]
    assert events[-1] == {"event": "interrupted", "signal": name, "store": str(store), "files": N_FILES,
                          "done": N_FILES - 1, "not_done": 1}
    (logs / "z_held.csv.hold").unlink()
    check_consistent(store, reference, logs, N_FILES - 1)


@pytest.mark.slow
def test_sigterm_in_mid_transaction_finishes_that_file_and_counts_it(logs, reference, tmp_path):
    """The signal arrives while a2.csv's trips are half inserted: its transaction is
    finished (not rolled back), it is reported, and nothing after it is written."""
    store = tmp_path / "s.sqlite"
    marker = Path(f"{store}.in-transaction")
    proc, out, err = start(["--stall-write", "a2.csv", "ingest", logs, "--store", store, "--workers", "1", "-q"],
                           tmp_path)
    try:
        wait_for(lambda: marker.exists() or proc.poll() is not None, "the stalled transaction")
        os.kill(proc.pid, signal.SIGTERM)
        assert proc.wait(30) == 143, err.read_text()
    finally:
        procs = left_over(proc.pid)
    assert procs == []
    assert err.read_text().startswith(f"cevm ingest: interrupted by SIGTERM: 3 of {N_FILES} files done "
                                      "(3 ingested, 0 unchanged, 0 failed)"), err.read_text()
    assert [Path(f[0]).name for f in store_content(store)["files"]] == ["a0.csv", "a1.csv", "a2.csv"]
    check_consistent(store, reference, logs, 3)


@pytest.fixture
def manifest(tmp_path):
    """A manifest giving the first trip of each log its payload."""
    f = tmp_path / "loads.csv"
    f.write_text("vehicle_id,start_utc,end_utc,payload_kg\n" + "".join(
        f"EB-0{k},{time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime(1_557_820_800 + 86_400 * k))},"
        f"{time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime(1_557_820_800 + 86_400 * k + 3_600))},1500\n"
        for k in range(N_FILES)))
    return f


def _trip_masses(store: Path) -> int:
    con = sqlite3.connect(f"file:{store}?mode=ro", uri=True)
    try:
        return con.execute("SELECT COUNT(*) FROM trip_masses").fetchone()[0]
    finally:
        con.close()


@pytest.mark.slow
@pytest.mark.parametrize("sig,code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)], ids=["SIGINT", "SIGTERM"])
def test_a_signal_after_the_last_file_says_the_manifest_was_not_applied(logs, manifest, tmp_path, sig, code):
    """A signal after the last file but before the manifest's masses are
    written said "6 of 6 files done ... 0 not done", and nothing of the masses. The line
    (and the JSON object) says the manifest was not applied; the exit code is the
    signal's; a new run applies it."""
    (logs / "z_held.csv").rename(logs / "a9.csv")  # no held file here
    store = tmp_path / "s.sqlite"
    proc, out, err = start(["--hold-after-ingest", "ingest", logs, "--store", store, "--workers", "1",
                            "--manifest", manifest, "--log-json"], tmp_path)
    wait_for(lambda: Path(f"{store}.ingested").exists() or proc.poll() is not None, "the files stored")
    assert proc.poll() is None, err.read_text()
    os.kill(proc.pid, sig)
    assert proc.wait(timeout=60) == code, err.read_text()
    line = [ln for ln in err.read_text().splitlines() if "interrupted by" in ln]
    assert len(line) == 1 and f"{N_FILES} of {N_FILES} files done" in line[0], err.read_text()
    assert f"the manifest {manifest} was not applied" in line[0]
    event = json.loads(out.read_text().splitlines()[-1])
    assert event["event"] == "interrupted" and event["not_done"] == 0 and event["manifest"] == "not applied"
    assert _trip_masses(store) == 0
    res = run("ingest", logs, "--store", store, "--workers", "1", "--manifest", manifest, "-q")
    assert res.exit_code == 0, res.output
    assert _trip_masses(store) == N_FILES


@pytest.mark.slow
def test_a_signal_after_the_summary_does_not_make_a_finished_run_interrupted(logs, manifest, tmp_path):
    """A SIGINT that arrives once the run is finished and its summary printed stops
    nothing: the exit code is the run's (0), the summary stands, and one line says the
    signal came too late to stop anything (no exit 130 without an 'interrupted' line)."""
    (logs / "z_held.csv").rename(logs / "a9.csv")
    store = tmp_path / "s.sqlite"
    proc, out, err = start(["--hold-after-summary", "ingest", logs, "--store", store, "--workers", "1",
                            "--manifest", manifest, "--log-json"], tmp_path)
    wait_for(lambda: Path(f"{store}.summarised").exists() or proc.poll() is not None, "the summary")
    assert proc.poll() is None, err.read_text()
    os.kill(proc.pid, signal.SIGINT)
    assert proc.wait(timeout=60) == 0, err.read_text()
    assert json.loads(out.read_text().splitlines()[-1])["event"] == "summary"
    assert "SIGINT arrived after the run had finished" in err.read_text()
    assert "interrupted" not in err.read_text() and _trip_masses(store) == N_FILES
