"""The fault campaign's categories as the project's own tests, for every command of the app:
an output onto the store, its ``-wal`` or ``-shm`` file, or an input; a damaged schema; a
read-only store; a stop signal early and late. Each case asserts one line on stderr
(never a traceback), the documented exit code (docs/reference/commands.md), and that the
store's trips are intact afterwards.

The commands are not listed here: they are walked from the app itself
(:func:`commands`), with a generic invocation built from each command's signature
(:func:`invocation`), so that a command added later is tried the same way without a line
of its own here. Where a command needs a value no signature tells (a vehicle id, a trip),
:data:`VALUES` gives one by the parameter's name.
"""

from __future__ import annotations

import inspect
import os
import shutil
import sqlite3
import typing
from pathlib import Path

import pytest
from typer.testing import CliRunner

import faults
from cevm.cli import make_app
from cevm.cli.paths import is_output, option_names
from fleet_store import DIESEL, URBAN, make_store

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = ROOT / "configs" / "fleet" / "paper-case-study.toml"
EXIT_INPUT, EXIT_STORE_ACCESS, EXIT_STORE_DAMAGED = 2, 3, 4
runner = CliRunner()


def _walk(app, prefix: tuple[str, ...] = ()):
    for info in app.registered_commands:
        yield (*prefix, info.name or info.callback.__name__), info.callback
    if prefix and app.registered_callback is not None and app.registered_callback.callback is not None:
        yield prefix, app.registered_callback.callback  # a group that is a command itself (cevm trips)
    for group in app.registered_groups:
        yield from _walk(group.typer_instance, (*prefix, group.name))


def commands() -> list[tuple[tuple[str, ...], object]]:
    """Every command of the app: (its words, its function)."""
    return sorted(_walk(make_app()), key=lambda c: c[0])


def _base(annotation):
    if typing.get_origin(annotation) is typing.Annotated:
        annotation = typing.get_args(annotation)[0]
    return annotation


def _is_path(annotation) -> bool:
    return "Path" in str(_base(annotation))


def _is_list(annotation) -> bool:
    return "list[" in str(_base(annotation))


def parameters(function) -> list[inspect.Parameter]:
    return [p for p in inspect.signature(function, eval_str=True).parameters.values()
            if "Context" not in str(_base(p.annotation))]


def output_params(function) -> list[str]:
    return [p.name for p in parameters(function) if is_output(p.name)]


def has_store(function) -> bool:
    return any(p.name == "store" for p in parameters(function))


#: Values of required parameters by name (what the fleet store of tests/fleet_store.py holds).
VALUES = {"vehicle": DIESEL, "file": DIESEL, "scenario": SCENARIO, "vehicle_id": "HGV-77", "name": "R-campaign",
          "paths": str(URBAN), "trip_ids": None}


def invocation(words: tuple[str, ...], function, **given) -> list[str]:
    """The command line of ``words`` with every required parameter given a value
    (:data:`VALUES`, else by type) and the parameters in ``given`` (by name; a list for
    a repeatable one)."""
    names = option_names(function)
    args: list[str] = [*words]
    positional: list[str] = []
    for p in parameters(function):
        if p.name in given:
            value = given[p.name]
        elif p.default is inspect.Parameter.empty:
            value = VALUES.get(p.name, URBAN if _is_path(p.annotation) else "x")
        else:
            continue
        if value is None:
            continue
        values = value if isinstance(value, list) else [value]
        flag = names[p.name]
        for v in values:
            if flag.startswith("--"):
                args += [flag, str(v)]
            else:
                positional.append(str(v))
    return args + positional


def cevm(args: list[str]):
    res = runner.invoke(make_app(), [str(a) for a in args])
    assert res.exception is None or isinstance(res.exception, SystemExit), (args, res.exception, res.output)
    assert "Traceback" not in res.output + res.stderr, res.stderr
    return res


def error_lines(res) -> list[str]:
    return [ln for ln in res.stderr.splitlines() if ln.strip()]


def trips_of(db: Path) -> list:
    """The store's trips and their blobs, read with plain sqlite3 without changing the file."""
    con = sqlite3.connect(f"{db.resolve().as_uri()}?mode=ro&immutable=1", uri=True)
    try:
        return [con.execute("SELECT * FROM trips ORDER BY trip_id").fetchall(),
                con.execute("SELECT trip_id, vector, profile FROM trip_blobs ORDER BY trip_id").fetchall()]
    finally:
        con.close()


@pytest.fixture(scope="module")
def pristine(tmp_path_factory) -> tuple[Path, dict]:
    d = tmp_path_factory.mktemp("pristine")
    db = d / "cevm.sqlite"
    ids = make_store(db, d / "logs")
    return db, ids


@pytest.fixture
def store(pristine, tmp_path) -> tuple[Path, dict, list]:
    """A copy of the fleet store of tests/fleet_store.py (its own directory), its trip
    ids, and its trips as they are."""
    src, ids = pristine
    db = tmp_path / "store" / "cevm.sqlite"
    db.parent.mkdir()
    shutil.copy(src, db)
    return db, ids, trips_of(db)


# ------------------------------------------------------------- --out onto what is read

OUTPUT_COMMANDS = [(w, f, o) for w, f in commands() for o in output_params(f)]


def test_every_command_with_an_output_is_tried():
    """The walk finds the commands known to write files: the cases below cover them."""
    found = {(" ".join(w), o) for w, _, o in OUTPUT_COMMANDS}
    assert {("predict", "out"), ("predict", "plot"), ("feasibility", "out"), ("replay", "out"), ("replay", "summary"),
            ("simulate", "out"), ("fleet plan", "out"), ("calibrate", "out"), ("calibrate", "plot")} <= found


@pytest.mark.parametrize("target", ["store", "store-wal", "store-shm", "store-journal", "store-hardlink",
                                    "store-symlink", "store-dotted"])
@pytest.mark.parametrize("words, function, output", OUTPUT_COMMANDS,
                         ids=[f"{' '.join(w)}--{o}" for w, _, o in OUTPUT_COMMANDS])
def test_an_output_onto_the_store_is_refused_before_any_work(words, function, output, target, store, tmp_path):
    db, _, before = store
    path = {"store": db, "store-wal": Path(f"{db}-wal"), "store-shm": Path(f"{db}-shm"),
            "store-journal": Path(f"{db}-journal"), "store-hardlink": tmp_path / "linked.sqlite",
            "store-symlink": tmp_path / "soft.sqlite",
            "store-dotted": Path(os.path.relpath(db.parent / ".." / "store" / db.name))}[target]
    if target == "store-hardlink":
        os.link(db, path)
    elif target == "store-symlink":
        path.symlink_to(db)
    listing = sorted(os.listdir(db.parent))
    res = cevm(invocation(words, function, store=db, **{output: path}))
    assert res.exit_code == EXIT_INPUT, res.stderr
    lines = error_lines(res)
    assert len(lines) == 1 and lines[0].startswith("cevm: error: "), res.stderr
    assert str(path) in lines[0] and "trip store" in lines[0], lines[0]
    assert sorted(os.listdir(db.parent)) == listing  # nothing written beside it (no .partial, no -wal)
    assert trips_of(db) == before


INPUT_COMMANDS = [(w, f, o, p.name) for w, f, o in OUTPUT_COMMANDS for p in parameters(f)
                  if _is_path(p.annotation) and not is_output(p.name) and p.name != "store"]


@pytest.mark.parametrize("how", ["same", "hardlink"])
@pytest.mark.parametrize("words, function, output, param", INPUT_COMMANDS,
                         ids=[f"{' '.join(w)}--{o}-onto-{p}" for w, _, o, p in INPUT_COMMANDS])
def test_an_output_onto_an_input_is_refused_and_the_input_kept(words, function, output, param, how, store, tmp_path):
    db, _, before = store
    source = {"vehicle": DIESEL, "file": DIESEL, "scenario": SCENARIO}.get(param, URBAN)
    mine = tmp_path / f"input{source.suffix}"
    shutil.copy(source, mine)
    content = mine.read_bytes()
    value = [mine] if _is_list(next(p.annotation for p in parameters(function) if p.name == param)) else mine
    target = mine
    if how == "hardlink":
        target = tmp_path / f"other{source.suffix}"
        os.link(mine, target)
    res = cevm(invocation(words, function, store=db, **{param: value, output: target}))
    assert res.exit_code == EXIT_INPUT, res.stderr
    lines = error_lines(res)
    assert len(lines) == 1 and lines[0].startswith("cevm: error: ") and str(mine) in lines[0], res.stderr
    assert mine.read_bytes() == content
    assert trips_of(db) == before


def test_an_output_onto_another_output_is_refused(tmp_path):
    both = [(w, f) for w, f in commands() if len(output_params(f)) > 1]
    assert both
    same = tmp_path / "same.png"
    for words, function in both:
        first, second = output_params(function)[:2]
        res = cevm(invocation(words, function, **{first: same, second: same}))
        assert res.exit_code == EXIT_INPUT and str(same) in res.stderr, (words, res.stderr)
        assert not same.exists()


def test_a_file_named_inside_a_scenario_is_not_overwritten(tmp_path):
    """fleet plan reads the vehicle files and cycles its scenario names: an --out onto one
    is refused where the output is opened, after the plan, before anything is written."""
    cfg = tmp_path / "configs"
    shutil.copytree(ROOT / "configs" / "fleet", cfg / "fleet")
    shutil.copytree(ROOT / "configs" / "vehicles", cfg / "vehicles")
    shutil.copytree(ROOT / "configs" / "cycles", cfg / "cycles")
    vehicle = cfg / "vehicles" / "diesel-hgv-paper.toml"
    content = vehicle.read_bytes()
    res = cevm(["fleet", "plan", str(cfg / "fleet" / SCENARIO.name), "--store", str(tmp_path / "none.sqlite"),
                "--out", str(vehicle)])
    assert res.exit_code == EXIT_INPUT, res.stderr
    assert len(error_lines(res)) == 1 and "vehicle file" in res.stderr, res.stderr
    assert vehicle.read_bytes() == content
    assert not list(cfg.rglob("*.partial"))


# ------------------------------------------------------------------ the store's schema

#: What makes a command open the store, by its words (a trip id stands for "the first
#: HGV-77 trip"): the command's required parameters alone may not. A command with a
#: --store option that is not here is tried with its required parameters only; it must
#: then open the store (else add it here).
STORE_USE: dict[str, dict] = {
    "predict": {"vehicle_id": ["HGV-77"]},
    "feasibility": {"vehicle_id": ["HGV-77"]},
    "simulate": {"trip": "TRIP"},
    "trips set-mass": {"trip_ids": ["TRIP"], "gross_kg": 30000},
    "route add": {"cycle": [URBAN]},
    "route remove": {"name": "R1"},
    "ingest": {"paths": str(sorted((ROOT / "sample_logs" / "srf").glob("HGV-11_*"))[0])},
    "gtfs": {"feed": str(ROOT / "tests" / "data" / "gtfs" / "small"), "vehicle_id": ["HGV-77"]},
}

#: Commands with a --store option that need not open it, and why.
STORE_UNUSED = {
    "fleet plan": "opens the store only for legs that name stored trips or routes (the shipped scenario names cycles)",
}

#: Commands that write into the store: they refuse a damaged one before writing anything.
WRITERS = {"ingest", "trips set-mass", "route add", "route remove"}

STORE_COMMANDS = [(w, f) for w, f in commands() if has_store(f) and " ".join(w) not in STORE_UNUSED]


def store_invocation(words, function, db: Path, ids: dict, **extra) -> list[str]:
    given = {k: ([ids["HGV-77"][0] if x == "TRIP" else x for x in v] if isinstance(v, list)
                 else ids["HGV-77"][0] if v == "TRIP" else v)
             for k, v in STORE_USE.get(" ".join(words), {}).items()}
    return invocation(words, function, store=db, **given, **extra)


#: Each kind of schema damage: the SQL that does it, and the word the error must name.
SCHEMA_DAMAGE = {
    "version-text": ("UPDATE meta SET value = 'abc' WHERE key = 'schema_version'", "schema_version"),
    "version-gone": ("DELETE FROM meta WHERE key = 'schema_version'", "schema_version"),
    "meta-gone": ("DROP TABLE meta", "meta"),
    "blobs-gone": ("DROP TABLE trip_blobs", "trip_blobs"),
    "column-gone": ("ALTER TABLE trips DROP COLUMN standstill_before_s", "standstill_before_s"),
    "masses-gone": ("DROP TABLE trip_masses", "trip_masses"),
}


def _damage(db: Path, kind: str) -> str:
    """Damage the schema of the store at ``db``; returns the words the error must name."""
    sql, named = SCHEMA_DAMAGE[kind]
    con = sqlite3.connect(db, isolation_level=None)
    try:
        con.execute(sql)
        return named
    finally:
        con.close()  # the last connection: -wal merged and removed


def test_every_command_that_names_a_store_is_tried():
    for words, function in commands():
        name = " ".join(words)
        if has_store(function) and name not in STORE_UNUSED:
            assert name in STORE_USE or all(p.default is not inspect.Parameter.empty or p.name in VALUES
                                             for p in parameters(function)), name


DAMAGE_KINDS = tuple(SCHEMA_DAMAGE)


def _damage_cases():
    """Every command with every kind of damage; in the fast loop each command with one
    kind, in turn, so that every kind and every command is tried there."""
    for i, (words, function) in enumerate(STORE_COMMANDS):
        for j, kind in enumerate(DAMAGE_KINDS):
            marks = () if j == i % len(DAMAGE_KINDS) else (pytest.mark.slow,)
            yield pytest.param(words, function, kind, marks=marks, id=f"{' '.join(words)}-{kind}")


@pytest.mark.parametrize("words, function, kind", list(_damage_cases()))
def test_a_damaged_schema_is_exit_4_naming_it_and_nothing_is_written(words, function, kind, store, tmp_path):
    db, ids, _ = store
    what = _damage(db, kind)
    content, listing = db.read_bytes(), sorted(os.listdir(db.parent))
    res = cevm(store_invocation(words, function, db, ids))
    assert res.exit_code == EXIT_STORE_DAMAGED, (kind, res.exit_code, res.stdout, res.stderr)
    errors = [ln for ln in error_lines(res) if ln.startswith("cevm: error:")]
    if words == ("store", "check") and not errors:  # its report says what is damaged, on stdout
        assert what in res.stdout and "DAMAGED" in res.stdout, res.stdout
    else:
        assert len(errors) == 1 and what in errors[0] and "damaged" in errors[0], res.stderr
    assert db.read_bytes() == content  # a writer wrote nothing: no run row, no migration
    assert sorted(os.listdir(db.parent)) == listing


# ---------------------------------------------------------------- a read-only opening

READERS = [(w, f) for w, f in STORE_COMMANDS if " ".join(w) not in WRITERS]

#: Readers that take seconds (a calibration): in the slow loop only.
SLOW_READERS = {("calibrate",)}


@pytest.mark.parametrize("words, function", [
    pytest.param(w, f, marks=(pytest.mark.slow,) if w in SLOW_READERS else (), id=" ".join(w)) for w, f in READERS])
def test_a_reader_leaves_no_file_beside_the_store(words, function, store):
    """SQLite makes -wal and -shm files for a reader of a store in WAL mode: a command
    that only reads leaves none behind, and the store's file as it was."""
    db, ids, before = store
    content, listing = db.read_bytes(), sorted(os.listdir(db.parent))
    res = cevm(store_invocation(words, function, db, ids))
    assert res.exit_code in (0, 1), (words, res.stderr)
    assert sorted(os.listdir(db.parent)) == listing
    assert db.read_bytes() == content


def test_a_reader_beside_an_open_connection_keeps_its_files(store):
    """Another connection has the store open (a long ingest): its -wal and -shm are in
    use, and a reader that ends meanwhile leaves them."""
    db, ids, _ = store
    con = sqlite3.connect(db, isolation_level=None)
    con.execute("SELECT COUNT(*) FROM trips").fetchone()
    try:
        assert Path(f"{db}-shm").exists()
        res = cevm(["trips", "--store", str(db), "-f", "csv"])
        assert res.exit_code == 0 and Path(f"{db}-shm").exists() and Path(f"{db}-wal").exists()
        con.execute("UPDATE meta SET value = value WHERE key = 'cevm_version'")  # still usable
    finally:
        con.close()


@pytest.mark.parametrize("every", [False, pytest.param(True, marks=pytest.mark.slow)], ids=["trips", "every-reader"])
@pytest.mark.parametrize("how", ["chattr-file", "chattr-dir"])
def test_readers_work_on_a_read_only_store_and_add_no_file(how, every, store):
    from test_store_faults import read_only

    db, ids, before = store
    with read_only(db, how) as path:
        listing = sorted(os.listdir(path.parent))
        for words, function in READERS if every else [(w, f) for w, f in READERS if w == ("trips",)]:
            res = cevm(store_invocation(words, function, path, ids))
            assert res.exit_code in (0, 1), (how, words, res.stderr)
            assert sorted(os.listdir(path.parent)) == listing, (how, words)
    assert trips_of(db) == before


# ------------------------------------------------------------------- stop signals

LATE = Path(__file__).resolve().parent / "late.py"
SIGNALS = {"SIGTERM": (15, 143), "SIGINT": (2, 130)}


def _caught(pid: int, signum: int) -> bool:
    """Whether process ``pid`` has a handler of its own for ``signum`` (/proc: SigCgt)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("SigCgt:"):
                return bool(int(line.split()[1], 16) >> (signum - 1) & 1)
    except OSError:
        pass
    return False


def _env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT / "src"), str(ROOT / "tests"), env.get("PYTHONPATH", "")])
    return env


def _finish(proc, timeout: float = 60.0) -> tuple[int, str, str]:
    import subprocess

    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        raise AssertionError(f"still running after {timeout} s: {err[-2000:]}") from None
    return proc.returncode, out, err


SIGNAL_COMMANDS = [(w, f) for w, f in commands()]


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs /proc (Linux)")
@pytest.mark.parametrize("name", list(SIGNALS))
@pytest.mark.parametrize("words, function", SIGNAL_COMMANDS, ids=[" ".join(w) for w, _ in SIGNAL_COMMANDS])
def test_a_signal_at_the_first_instant_is_one_line_and_its_code(words, function, name, store):
    """The signal as soon as cevm's handler is in place (the process catches SIGTERM:
    the entry point's first act, before typer, numpy or pandas are imported): one line,
    130 or 143, nothing changed. Before that only the interpreter's own start runs."""
    import subprocess
    import sys
    import time

    db, ids, before = store
    signum, code = SIGNALS[name]
    args = store_invocation(words, function, db, ids) if has_store(function) else invocation(words, function)
    proc = subprocess.Popen([sys.executable, "-m", "cevm", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=_env())
    t0 = time.monotonic()
    while not _caught(proc.pid, 15) and proc.poll() is None and time.monotonic() - t0 < 30:
        time.sleep(0.0005)
    proc.send_signal(signum)
    rc, _, err = _finish(proc)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert rc == code, (rc, err)
    assert "Traceback" not in err and len(lines) == 1 and name in lines[0], err
    assert lines[0].startswith(f"cevm {' '.join(words)}:"), lines[0]
    assert trips_of(db) == before


#: The one case of the late signal in the fast loop (each runs a whole command: seconds).
LATE_FAST = (("trips",), "SIGTERM")


def _late_cases():
    for words, function in SIGNAL_COMMANDS:
        for name in SIGNALS:
            marks = () if (words, name) == LATE_FAST else (pytest.mark.slow,)
            yield pytest.param(words, function, name, marks=marks, id=f"{' '.join(words)}-{name}")


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs /proc (Linux)")
@pytest.mark.parametrize("words, function, name", list(_late_cases()))
def test_a_signal_after_the_command_ended_is_one_line_and_its_code(words, function, name, store, tmp_path):
    """The signal once the command has returned, as the process exits (tests/late.py
    holds it there): the command's own output stands, one more line says the signal came,
    the code is 130 or 143, never a traceback."""
    import subprocess
    import sys
    import time

    db, ids, before = store
    signum, code = SIGNALS[name]
    marker = tmp_path / "ended"
    args = store_invocation(words, function, db, ids) if has_store(function) else invocation(words, function)
    proc = subprocess.Popen([sys.executable, str(LATE), str(marker), *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=_env())
    t0 = time.monotonic()
    while not marker.exists() and proc.poll() is None and time.monotonic() - t0 < 120:
        time.sleep(0.01)
    assert marker.exists(), proc.communicate()
    proc.send_signal(signum)
    rc, _, err = _finish(proc)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert rc == code and "Traceback" not in err, (rc, err)
    assert lines[-1].startswith(f"cevm {' '.join(words)}: interrupted by {name} as it exited"), err
    assert not any(name in ln for ln in lines[:-1]), err


# ---------------------------------------------------------------- damaged pages

def _flip_pages(db: Path, seed: int, pages: int = 3) -> None:
    """Flip bits in a few random pages of the store (not the first: its header)."""
    import random

    data = bytearray(db.read_bytes())
    rng = random.Random(seed)
    n = len(data) // 4096
    for _ in range(pages):
        page = rng.randrange(1, n)
        for _ in range(rng.randrange(1, 200)):
            data[page * 4096 + rng.randrange(4096)] ^= 1 << rng.randrange(8)
    db.write_bytes(bytes(data))


PAGE_CASES = [(w, f, vid, seed) for w, f in STORE_COMMANDS if w in (("predict",), ("feasibility",))
              for vid in ("EB-09", "HGV-77") for seed in (5, 17, 49, 55)]


@pytest.mark.parametrize("words, function, vehicle_id, seed", PAGE_CASES,
                         ids=[f"{' '.join(w)}-{v}-{s}" for w, _, v, s in PAGE_CASES])
def test_damaged_pages_are_the_stores_damage_not_bad_input(words, function, vehicle_id, seed, store):
    """Pages of the store damaged on disk (bits flipped): the command reads what it can,
    skips damaged trips (exit 1) or stops on the damage (exit 4) with one line saying so,
    never exit 2 (the user's input was fine) nor a traceback. (These seeds once gave exit
    2: a damaged profile found while predicting, every trip damaged, an index that lost
    trips.)"""
    db, ids, _ = store
    _flip_pages(db, seed)
    vehicle = ROOT / "configs" / "vehicles" / ("electric-bus.toml" if vehicle_id == "EB-09" else "diesel-hgv.toml")
    res = cevm(invocation(words, function, store=db, vehicle=[vehicle], vehicle_id=[vehicle_id]))
    errors = [ln for ln in error_lines(res) if ln.startswith("cevm: error:")]
    assert res.exit_code in (0, 1, EXIT_STORE_DAMAGED), (res.exit_code, res.stderr)
    assert len(errors) == (res.exit_code == EXIT_STORE_DAMAGED), res.stderr
    if errors:
        assert "damaged" in errors[0] or "malformed" in errors[0], errors[0]


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs /proc (Linux)")
@pytest.mark.parametrize("name", list(SIGNALS))
def test_a_signal_at_random_moments_of_a_pool_is_one_line(name, store):
    """A Ctrl-C (SIGINT to the process group, as a terminal sends it) or a SIGTERM to the
    whole group (systemd's stop) at seeded random moments of a command with worker
    processes, its forkserver's start included: the command's one line and code (or its
    normal end), nothing from the workers, the forkserver or the resource tracker (no
    traceback, no "leaked semaphore"), no process left."""
    import contextlib
    import random
    import signal
    import subprocess
    import sys
    import time

    db, ids, before = store
    signum, code = SIGNALS[name]
    rng = random.Random(32 + signum)
    args = ["predict", "-v", str(ROOT / "configs" / "vehicles" / "electric-bus.toml"), "--vehicle-id", "EB-09",
            "--workers", "2", "-f", "csv", "--store", str(db)]
    for delay in sorted(rng.uniform(0.05, 4.0) for _ in range(4)):
        proc = subprocess.Popen([sys.executable, "-m", "cevm", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True, env=_env(), start_new_session=True)
        time.sleep(delay)
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signum)
        rc, _, err = _finish(proc)
        lines = [ln for ln in err.splitlines() if ln.strip() and not ln.startswith("cevm: note:")]
        assert "Traceback" not in err and "leaked" not in err, (delay, err)
        assert rc == code or rc == 0, (delay, rc, err)
        if rc == code:
            assert len(lines) == 1 and name in lines[0], (delay, err)
        t_end = time.monotonic() + 15.0  # the session's processes (forkserver, workers, tracker) end with it
        while (left := faults.session_processes(proc.pid)) and time.monotonic() < t_end:
            time.sleep(0.1)
        for pid, _ in left:  # this test's: killed, so a failure leaves nothing running
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        assert not left, (delay, left)
    assert trips_of(db) == before


def test_a_reader_keeps_the_files_another_process_uses(store, tmp_path):
    """The files a reader made are removed only if no other process has the store open: a
    process that opened it meanwhile (a reader, or a writer about to write) keeps them,
    and its commits are all there once it ends."""
    import subprocess
    import sys

    from cevm.store import TripStore

    db, ids, before = store
    ready, go = tmp_path / "ready", tmp_path / "go"
    code = (f"import sqlite3, time, pathlib\n"
            f"con = sqlite3.connect({str(db)!r}, isolation_level=None)\n"
            f"con.execute('SELECT COUNT(*) FROM trips').fetchone()\n"
            f"pathlib.Path({str(ready)!r}).touch()\n"
            f"while not pathlib.Path({str(go)!r}).exists(): time.sleep(0.01)\n"
            f"con.execute(\"UPDATE meta SET value = 'x' WHERE key = 'cevm_version'\")\n"
            f"con.close()\n")
    reader = TripStore(db, readonly=True)
    assert reader.count_trips() == len(before[0])
    assert Path(f"{db}-shm").exists()  # SQLite made it for the reader
    other = subprocess.Popen([sys.executable, "-c", code])
    try:
        while not ready.exists():
            assert other.poll() is None
        reader.close()
        assert Path(f"{db}-shm").exists() and Path(f"{db}-wal").exists()  # in use: kept
        go.touch()
        assert other.wait(timeout=60) == 0
    finally:
        go.touch()
        other.wait(timeout=60)
    con = sqlite3.connect(f"{db.resolve().as_uri()}?mode=ro", uri=True)
    try:
        assert con.execute("SELECT value FROM meta WHERE key = 'cevm_version'").fetchone()[0] == "x"
    finally:
        con.close()
    assert trips_of(db) == before


def test_a_reader_keeps_the_files_a_plain_connection_of_this_process_uses(store):
    """A connection of the same process outside TripStore (a notebook's plain sqlite3
    one) has the store open: the reader that made the files leaves them (an open file
    description lock conflicts with that connection's lock, where a POSIX one would not),
    and that connection's locks and writes are intact."""
    from cevm.store import TripStore

    db, ids, before = store
    reader = TripStore(db, readonly=True)
    assert reader.count_trips() == len(before[0]) and Path(f"{db}-shm").exists()
    con = sqlite3.connect(db, isolation_level=None)
    try:
        con.execute("SELECT COUNT(*) FROM trips").fetchone()
        reader.close()
        assert Path(f"{db}-shm").exists() and Path(f"{db}-wal").exists()
        con.execute("UPDATE meta SET value = 'y' WHERE key = 'cevm_version'")
    finally:
        con.close()
    assert not Path(f"{db}-wal").exists()  # its last close merged and removed them, as SQLite does
    assert trips_of(db) == before
