"""SIGTERM and SIGINT stop every long-running command the same way: exit 143 or
130, one line that says so, no traceback, no process of the command left, the store as it
was. Each command is a real ``cevm`` process in a session of its own, stopped with a real
signal while it is certainly in the middle of its work (tests/stall.py holds it there:
store open, workers started, output begun). Ingest, which also says what it stored, has
its own tests (tests/test_shutdown.py)."""

from __future__ import annotations

import contextlib
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest

import faults
from fleet_store import BUS, DIESEL, URBAN, make_store

pytestmark = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc (Linux)")

ROOT = Path(__file__).resolve().parents[1]
STALL = Path(__file__).resolve().parent / "stall.py"
SCENARIO = ROOT / "configs" / "fleet" / "paper-case-study.toml"

# (command, where it is held, whether worker processes run beside it)
COMMANDS = [
    (("calibrate", "-v", DIESEL, "--vehicle-id", "HGV-77", "--out", "{tmp}/out.toml"),
     "cevm.core.calibration.estimator:select", False),
    (("predict", "-v", BUS, "--vehicle-id", "EB-09", "-f", "csv"), "cevm.cli.predict:PredictWriter.add", False),
    (("predict", "-v", BUS, "--vehicle-id", "EB-09", "--workers", "2", "-f", "csv"),
     "cevm.cli.predict:PredictWriter.add", True),
    (("feasibility", "-v", BUS, "--vehicle-id", "EB-09"), "cevm.cli.feasibility:feasibility", False),
    (("simulate", "-v", BUS, "--trip", "{bus}", "--out", "{tmp}/sim.csv"), "cevm.core.detailed:simulate", False),
    (("store", "check"), "cevm.store.integrity:_trip_problems", False),
    (("fleet", "plan", SCENARIO), "cevm.io.scenario:fleet_report", False),
    (("replay", "-v", BUS, "--vehicle-id", "EB-09", "--out", "{tmp}/replay.csv"), "cevm.cli.replay:plan_vehicle",
     False),
    (("trips", "set-mass", "{hgv}", "--gross-kg", "31000"), "cevm.store.masses:set_masses", False),
    (("route", "add", "R7", "--cycle", URBAN), "cevm.store.routes:add_route", False),
]


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    d = tmp_path_factory.mktemp("fleet")
    db = d / "cevm.sqlite"
    ids = make_store(db, d / "logs")
    return db, ids


def snapshot(db: Path) -> dict:
    con = sqlite3.connect(f"{db.resolve().as_uri()}?mode=ro", uri=True)
    try:
        tables = [r[0] for r in con.execute("SELECT name FROM sqlite_master WHERE type = 'table'")]
        return {t: sorted(con.execute(f"SELECT * FROM {t}").fetchall(), key=repr) for t in tables}
    finally:
        con.close()


def left_over(sid: int, within_s: float = 15.0) -> list:
    t_end = time.monotonic() + within_s
    while (procs := faults.session_processes(sid)) and time.monotonic() < t_end:
        time.sleep(0.1)
    for pid, _ in procs:  # this test's: killed, so a failure leaves nothing running
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
    return procs


# SIGTERM to every command; SIGINT (the same path in cevm) to a few, pool workers included
CASES = [(*c, signal.SIGTERM) for c in COMMANDS] + [(*c, signal.SIGINT) for c in COMMANDS
                                                    if c[0][0] in ("calibrate", "store", "trips") or c[2]]


@pytest.mark.slow
@pytest.mark.parametrize("args, where, workers, sig", CASES,
                         ids=[" ".join(map(str, c[0][:2])) + (" --workers 2" if c[2] else "") + f" {c[3].name}"
                              for c in CASES])
def test_a_signal_stops_every_command_with_its_code_and_one_line(fleet, tmp_path, args, where, workers, sig):
    db, ids = fleet
    args = [str(a).format(tmp=tmp_path, bus=ids["EB-09"][0], hgv=ids["HGV-77"][0]) for a in args]
    before = snapshot(db)
    marker = tmp_path / "held"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT / "src"), str(STALL.parent),
                                                       os.environ.get("PYTHONPATH", "")]))
    err = tmp_path / "stderr.txt"
    with open(err, "w") as err_file:
        proc = subprocess.Popen([sys.executable, str(STALL), where, str(marker), *args, "--store", str(db)],
                                start_new_session=True, stdout=subprocess.DEVNULL, stderr=err_file,
                                stdin=subprocess.DEVNULL, env=env)
    try:
        t_end = time.monotonic() + 120
        while not marker.exists() and proc.poll() is None and time.monotonic() < t_end:
            time.sleep(0.05)
        assert marker.exists(), f"never reached {where}: {err.read_text()}"
        if workers:  # the pool's processes are there to be left behind
            assert len(faults.session_processes(proc.pid)) >= 3, faults.session_processes(proc.pid)
        if sig == signal.SIGINT:
            os.killpg(proc.pid, sig)  # Ctrl-C: the terminal signals the whole process group
        else:
            os.kill(proc.pid, sig)  # kill PID, a timeout, systemd: the command alone
        code = proc.wait(60)
    finally:
        procs = left_over(proc.pid)
    assert procs == [], f"left running after {sig.name}: {procs}"
    assert code == 128 + sig, (code, err.read_text())
    lines = err.read_text().splitlines()
    command = " ".join(args[:2]) if args[0] in ("trips", "route", "store", "fleet") else args[0]
    assert lines[-1].startswith(f"cevm {command}: interrupted by {sig.name}: stopped before the end"), lines
    assert sum("interrupted" in ln for ln in lines) == 1 and not any("Traceback" in ln for ln in lines), lines
    assert not any(p.name.endswith((".partial", ".tmp")) for p in tmp_path.iterdir())  # no half-written --out
    assert not any((tmp_path / name).exists() for name in ("out.toml", "sim.csv", "replay.csv"))
    assert snapshot(db) == before
