"""Every command turns a write error into one line and exit 3: its output on a
full device (``> /dev/full``), an ``--out`` or ``--plot`` file on a full disk, a new store
on a read-only file system. Never a traceback, never Python's "Exception ignored" at exit,
never a half-written file left behind. The full disk is a 64 kB tmpfs (root only: skipped
elsewhere); /dev/full needs Linux."""

from __future__ import annotations

import contextlib
import os
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from fleet_store import BUS, DIESEL, URBAN, make_store

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = ROOT / "configs" / "fleet" / "paper-case-study.toml"
EXIT_STORE_ACCESS = 3
IS_ROOT = hasattr(os, "geteuid") and os.geteuid() == 0
FULL = Path("/dev/full")

pytestmark = pytest.mark.skipif(not (FULL.exists() and stat.S_ISCHR(FULL.stat().st_mode)),
                                reason="needs /dev/full (Linux)")


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    d = tmp_path_factory.mktemp("fleet")
    db = d / "cevm.sqlite"
    ids = make_store(db, d / "logs")
    return db, ids


def run_main(capsys, monkeypatch, args, stdout_path: Path = FULL) -> tuple[int, str]:
    """``cevm ARGS`` through :func:`cevm.cli.main` (the console entry point, as a user runs
    it) in this process, its stdout a file opened on ``stdout_path``: (exit code, stderr)."""
    from cevm.cli import main

    capsys.readouterr()
    monkeypatch.setattr(sys, "argv", ["cevm", *map(str, args)])
    with open(stdout_path, "w") as fh:
        monkeypatch.setattr(sys, "stdout", fh)
        try:
            main()
            code = 0
        except SystemExit as exc:
            code = exc.code
        finally:
            monkeypatch.undo()
    return code, capsys.readouterr().err


def one_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.startswith("cevm: error:")]
    assert len(lines) == 1 and "Traceback" not in err and "Exception ignored" not in err, err
    return lines[0]


READERS = [
    ("trips", "-f", "csv"), ("trips", "-f", "json"), ("trips",),
    ("predict", "-v", BUS, "-c", URBAN, "-f", "csv"),
    ("predict", "-v", BUS, "-c", URBAN, "--payload-kg", "0:4000:1", "-f", "csv"),  # fails in the middle of writing
    ("predict", "-v", BUS, "--vehicle-id", "EB-09"),
    ("feasibility", "-v", BUS, "-c", URBAN),
    ("calibrate", "-v", DIESEL, "--vehicle-id", "HGV-77", "-f", "json"),
    ("simulate", "-v", BUS, "-c", URBAN, "-f", "csv"),
    ("store", "check", "-f", "json"), ("store", "info"), ("route", "list"),
    ("vehicle", "show", BUS), ("fleet", "plan", SCENARIO),
    ("replay", "-v", BUS, "--vehicle-id", "EB-09", "-f", "csv"),
]


def _id(args) -> str:
    return " ".join(Path(a).stem if isinstance(a, Path) else str(a) for a in args)


@pytest.mark.slow
@pytest.mark.parametrize("args", READERS, ids=[_id(a) for a in READERS])
def test_output_on_a_full_device_is_one_line_and_exit_3(fleet, capsys, monkeypatch, args):
    db, ids = fleet
    store = ("--store", db) if args[0] not in ("vehicle", "simulate") or "--trip" in args else ()
    code, err = run_main(capsys, monkeypatch, (*args, *store))
    assert code == EXIT_STORE_ACCESS, err
    line = one_line(err)  # stdout is named when cevm can tell (a write that failed may leave nothing to flush)
    assert "the output (stdout): could not be written: the disk is full" in line or \
        "the output: could not be written: the disk is full" in line, line


@pytest.mark.slow
def test_a_shell_redirect_to_dev_full_and_a_closed_pipe(fleet):
    """As an operator types them: ``cevm trips -f csv > /dev/full`` (exit 3, one line), and
    ``cevm predict ... | head -1`` (the reader went away: nothing said, exit 141)."""
    db, ids = fleet
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")]))
    with open(FULL, "w") as full:
        proc = subprocess.run([sys.executable, "-m", "cevm", "trips", "-f", "csv", "--store", str(db)], stdout=full,
                              stderr=subprocess.PIPE, text=True, env=env, timeout=120)
    assert proc.returncode == EXIT_STORE_ACCESS and "the disk is full" in one_line(proc.stderr)
    proc = subprocess.Popen([sys.executable, "-m", "cevm", "predict", "-v", str(BUS), "-c", str(URBAN),
                             "--payload-kg", "0:20000:1", "-f", "csv"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, env=env)
    assert proc.stdout.readline().startswith(b"cycle,")
    proc.stdout.close()  # as head does after its line
    err = proc.stderr.read().decode()
    assert proc.wait(120) == 141 and "Traceback" not in err and "Exception ignored" not in err, err
    assert "error" not in err


@contextlib.contextmanager
def mounted(where: Path, options: str):
    where.mkdir()
    if not IS_ROOT or subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(where)],
                                     capture_output=True).returncode != 0:
        pytest.skip("cannot mount a tmpfs here (needs root)")
    try:
        yield where
    finally:
        subprocess.run(["umount", str(where)], check=True)


def fill(path: Path) -> None:
    """Fill the file system of ``path`` to its last byte."""
    with open(path, "wb", buffering=0) as f:
        for size in (1 << 16, 1 << 12, 1):
            try:
                while True:
                    f.write(b"\0" * size)
            except OSError:
                pass


OUTS = [
    ("simulate", "-v", BUS, "-c", URBAN, "--out", "{d}/sim.csv"),
    ("predict", "-v", BUS, "-c", URBAN, "--payload-kg", "0:4000:1", "-f", "csv", "--out", "{d}/p.csv"),
    ("feasibility", "-v", BUS, "-c", URBAN, "-f", "csv", "--out", "{d}/f.csv"),
    ("predict", "-v", BUS, "-v", DIESEL, "-c", URBAN, "--payload-kg", "0:4000:500", "--plot", "{d}/p.png"),
    ("simulate", "-v", BUS, "-c", URBAN, "--plot", "{d}/sim.png"),
    ("calibrate", "-v", DIESEL, "--vehicle-id", "HGV-77", "--out", "{d}/hgv.toml"),
    ("calibrate", "-v", DIESEL, "--vehicle-id", "HGV-77", "--plot", "{d}/cal.png"),
    ("replay", "-v", BUS, "--vehicle-id", "EB-09", "--plot", "{d}/replay.png"),
    ("replay", "-v", BUS, "--vehicle-id", "EB-09", "--summary", "{d}/summary.json"),
]


@pytest.mark.slow
@pytest.mark.parametrize("args", OUTS, ids=["simulate --out", "predict --out", "feasibility --out", "predict --plot",
                                            "simulate --plot", "calibrate --out", "calibrate --plot", "replay --plot",
                                            "replay --summary"])
def test_an_out_file_on_a_full_disk_is_one_line_and_leaves_nothing(fleet, capsys, monkeypatch, tmp_path, args):
    db, ids = fleet
    with mounted(tmp_path / "small", "size=64k") as small:
        fill(small / "filler")
        args = [str(a).format(d=small) for a in args]
        if args[0] in ("calibrate", "replay"):
            args += ["--store", str(db)]
        code, err = run_main(capsys, monkeypatch, args, stdout_path=Path(os.devnull))
        assert code == EXIT_STORE_ACCESS, err
        out = next(a for a in args if a.startswith(str(small)))
        assert f"{out}: could not be written: the disk is full" in one_line(err)
        assert sorted(p.name for p in small.iterdir()) == ["filler"]  # nothing half-written left


@pytest.mark.slow
def test_an_out_path_that_is_a_device_is_written_not_replaced(fleet, capsys, monkeypatch, tmp_path):
    """``--out`` naming a device (here copies of /dev/full, named with the ending each
    option asks for) is written to, not replaced by a file renamed over it (as --out's
    atomic rename did: it replaced /dev/full itself)."""
    nodes = {ending: tmp_path / f"full{ending}" for ending in ("", ".png", ".toml", ".json")}
    try:
        for node in nodes.values():
            os.mknod(node, 0o666 | stat.S_IFCHR, os.makedev(1, 7))
    except (PermissionError, OSError):
        pytest.skip("cannot make a device node here (needs root)")
    db, ids = fleet
    for args in (("simulate", "-v", BUS, "-c", URBAN, "--out", nodes[""]),
                 ("predict", "-v", BUS, "-c", URBAN, "-f", "csv", "--out", nodes[""]),
                 ("simulate", "-v", BUS, "-c", URBAN, "--plot", nodes[".png"]),  # nor removed after a failed plot
                 ("calibrate", "-v", DIESEL, "--vehicle-id", "HGV-77", "--store", db, "--out", nodes[".toml"],
                  "--force"),
                 ("replay", "-v", BUS, "--vehicle-id", "EB-09", "--store", db, "--summary", nodes[".json"])):
        node = args[-2] if args[-1] == "--force" else args[-1]
        code, err = run_main(capsys, monkeypatch, args, stdout_path=Path(os.devnull))
        assert code == EXIT_STORE_ACCESS and f"{node}: could not be written: the disk is full" in one_line(err), (
            args, err)
        assert stat.S_ISCHR(node.stat().st_mode)  # still the device
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(n.name for n in nodes.values())


def test_a_new_store_on_a_read_only_file_system_is_one_line_and_exit_3(capsys, monkeypatch, tmp_path):
    log = ROOT / "sample_logs" / "srf" / "EB-01_2019-01-31.csv"
    with mounted(tmp_path / "ro", "size=64k,ro") as ro:
        for args in (("ingest", log, "--workers", "1", "-q"), ("route", "add", "R1", "--cycle", URBAN)):
            for store in (ro / "new.sqlite", ro / "sub" / "new.sqlite"):
                code, err = run_main(capsys, monkeypatch, (*args, "--store", store), stdout_path=Path(os.devnull))
                assert code == EXIT_STORE_ACCESS, (args, err)
                line = one_line(err)
                assert str(store) in line and "read-only file system" in line.lower(), line
        assert list(ro.iterdir()) == []


@pytest.mark.parametrize("command", ["predict", "ingest"])
def test_a_bad_scheduler_address_is_one_line_and_ends_there(tmp_path, command):
    """The one line, exit 2, and the process ends: the half-made Dask client no longer
    waits 40 s at exit and prints a TimeoutError traceback after the line."""
    pytest.importorskip("distributed")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")]))
    log = ROOT / "sample_logs" / "srf" / "EB-01_2019-01-31.csv"
    args = (["predict", "-v", str(BUS), "-c", str(URBAN)] if command == "predict" else
            ["ingest", str(log), "--store", str(tmp_path / "s.sqlite")])
    proc = subprocess.run([sys.executable, "-m", "cevm", *args, "--scheduler", "nonsense://10.0.0.5:8786"],
                          capture_output=True, text=True, env=env, timeout=35)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.splitlines()
    assert len(lines) == 1, lines
    assert lines[0].startswith("cevm: error: cannot reach the Dask scheduler at nonsense://10.0.0.5:8786: "
                               "ValueError: unknown address scheme"), lines
    assert not (tmp_path / "s.sqlite").exists()
