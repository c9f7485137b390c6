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
