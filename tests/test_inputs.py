"""Every input that is not a log has a bound checked before the work (memory stays
bounded whatever a file holds): TOML files
(vehicle files, scenarios) and manifests are read only when they are regular files within
their size, TOML nests within the parser's depth, a manifest is streamed and bounded in
rows and line length. Each refusal is one line and exit 2, never a traceback, a hang or
memory without end. The hostile inputs run in a process of their own, under a 2 GB address
space limit and a timeout, so that a regression fails the test instead of the machine."""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from fleet_store import BUS, URBAN, make_fleet

ROOT = Path(__file__).resolve().parents[1]
runner = CliRunner()


def cevm(*args):
    from cevm.cli import app

    res = runner.invoke(app, [str(a) for a in args])
    assert res.exception is None or isinstance(res.exception, SystemExit), (args, res.exception, res.output)
    assert "Traceback" not in res.output + res.stderr, res.stderr
    return res


def _limited() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (2 << 30, 2 << 30))


def cevm_process(*args, timeout_s: float = 60.0) -> subprocess.CompletedProcess:
    """``cevm ARGS`` in a process of its own, within 2 GB of address space and a timeout
    (a hang or an endless read fails the test, not the machine)."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")]))
    return subprocess.run([sys.executable, "-m", "cevm", *map(str, args)], capture_output=True, text=True, env=env,
                          timeout=timeout_s, preexec_fn=_limited, stdin=subprocess.DEVNULL)


def one_error(proc) -> str:
    """The one error line of a finished command (a process, or the runner's result)."""
    code = getattr(proc, "returncode", getattr(proc, "exit_code", None))
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert code == 2 and len(lines) == 1 and lines[0].startswith("cevm: error: "), proc.stderr
    assert "Traceback" not in proc.stderr
    return lines[0]


@pytest.fixture
def fifo(tmp_path):
    if not hasattr(os, "mkfifo"):
        pytest.skip("no FIFOs here")
    path = tmp_path / "pipe.toml"
    os.mkfifo(path)
    return path


# ------------------------------------------------------------------------------- TOML


@pytest.mark.slow
def test_a_vehicle_file_that_is_a_device_or_a_fifo_is_refused_before_it_is_read(fifo, tmp_path):
    for args in (("vehicle", "show", "/dev/zero"), ("predict", "-v", fifo, "-c", URBAN)):
        if not Path(args[2]).exists():
            continue
        line = one_error(cevm_process(*args, timeout_s=30))
        assert str(args[2]) in line and ("character device, not a vehicle file" in line or "FIFO" in line), line
    scenario = one_error(cevm_process("fleet", "plan", fifo, timeout_s=30))
    assert "FIFO (named pipe), not a scenario file" in scenario


def test_toml_nested_without_end_or_too_large_is_refused_in_one_line(tmp_path):
    deep = tmp_path / "deep.toml"
    deep.write_text("name = " + "[" * 50_000 + "]" * 50_000 + "\n")
    assert "nest too deeply" in one_error(cevm("vehicle", "show", deep))
    deep_tables = tmp_path / "tables.toml"
    deep_tables.write_text("x = " + "{a = " * 5_000 + "1" + "}" * 5_000 + "\n")
    assert "nest too deeply" in one_error(cevm("fleet", "plan", deep_tables))
    big = tmp_path / "big.toml"
    big.write_text(f'name = "{"x" * (1 << 20)}"\n')
    line = one_error(cevm("predict", "-v", big, "-c", URBAN))
    assert "larger than a vehicle file may be (1 MiB)" in line and "1,048,5" in line


def test_a_vehicle_file_within_the_bound_reads_as_before(tmp_path):
    padded = tmp_path / "padded.toml"
    padded.write_text(BUS.read_text() + "# " + "x" * ((1 << 20) - BUS.stat().st_size - 100) + "\n")
    assert padded.stat().st_size <= 1 << 20
    a = cevm("predict", "-v", BUS, "-c", URBAN, "-f", "csv")
    b = cevm("predict", "-v", padded, "-c", URBAN, "-f", "csv")
    assert a.exit_code == b.exit_code == 0 and a.stdout.replace("electric-bus", "padded") == b.stdout


# --------------------------------------------------------------------------- manifests


@pytest.fixture
def fleet(tmp_path):
    return make_fleet(tmp_path)


@pytest.mark.slow
def test_a_manifest_that_is_a_device_a_fifo_or_too_large_is_refused(fleet, fifo, tmp_path, monkeypatch):
    db, ids, hgv, starts = fleet
    for source, said in ((Path("/dev/zero"), "character device"), (fifo, "FIFO")):
        if source.exists():
            line = one_error(cevm_process("trips", "set-mass", "--manifest", source, "--store", db, timeout_s=30))
            assert said in line and "not a manifest" in line
    import cevm.io.manifest as manifest

    big = tmp_path / "big.csv"
    big.write_text("trip_id,gross_kg\n" + f"{ids['HGV-77'][0]},30000\n" * 100)
    monkeypatch.setattr(manifest, "MAX_MANIFEST_BYTES", 1000)
    res = cevm("trips", "set-mass", "--manifest", big, "--store", db)
    assert res.exit_code == 2 and "larger than a manifest may be (1,000 bytes): give it in parts" in res.stderr


def test_a_manifest_line_over_128_kib_is_one_line_naming_it(fleet, tmp_path):
    db, ids, hgv, starts = fleet
    long_line = tmp_path / "long.csv"
    long_line.write_text(f"trip_id,gross_kg\n{ids['HGV-77'][0]},30000\n{'x' * 200_000},30000\n")
    res = cevm("trips", "set-mass", "--manifest", long_line, "--store", db)
    assert res.exit_code == 2 and "long.csv:3: not a CSV line: a field longer than 128 KiB" in res.stderr
    res = cevm("ingest", ROOT / "sample_logs" / "srf" / "EB-01_2019-01-31.csv", "--store", tmp_path / "n.sqlite",
               "--manifest", long_line)
    assert res.exit_code == 2 and "a field longer than 128 KiB" in res.stderr
    header = tmp_path / "header.csv"
    header.write_text("trip_id," + "y" * 200_000 + "\n")
    res = cevm("trips", "set-mass", "--manifest", header, "--store", db)
    assert res.exit_code == 2 and "header line longer than 128 KiB" in res.stderr
    nul = tmp_path / "nul.csv"  # a NUL byte is a character like another: that row's trip is unknown
    nul.write_bytes(b"trip_id,gross_kg\nA\x00B,30000\n")
    res = cevm("trips", "set-mass", "--manifest", nul, "--store", db)
    assert res.exit_code == 1 and "nul.csv:2: not applied: trip 'A\\x00B' is not in the store" in res.stderr


def test_manifest_rows_past_the_bound_are_refused_before_anything_is_stored(fleet, tmp_path, monkeypatch):
    db, ids, hgv, starts = fleet
    import cevm.io.manifest as manifest

    p = tmp_path / "m.csv"
    p.write_text("trip_id,gross_kg\n" + "".join(f"{t},31000\n" for t in ids["HGV-77"]))
    monkeypatch.setattr(manifest, "MAX_MANIFEST_ROWS", 7)
    res = cevm("trips", "set-mass", "--manifest", p, "--store", db)
    assert res.exit_code == 2 and "m.csv:9: more than 7 rows: give the manifest in parts" in res.stderr
    assert "not applied" not in res.stderr
    listed = json.loads(cevm("trips", "--store", db, "-f", "json").stdout)
    assert not any(r["mass_source"].startswith("manifest") for r in listed)  # nothing was stored
    monkeypatch.setattr(manifest, "MAX_MANIFEST_ROWS", 8)
    res = cevm("trips", "set-mass", "--manifest", p, "--store", db)
    assert res.exit_code == 0 and "8 trips given their masses" in res.stderr


def test_a_manifest_with_cr_line_ends_reads_as_with_lf(fleet, tmp_path):
    db, ids, hgv, starts = fleet
    rows = ["trip_id,gross_kg"] + [f"{t},{31000 + k}" for k, t in enumerate(ids["HGV-77"][:3])]
    for name, end in (("lf.csv", "\n"), ("cr.csv", "\r"), ("crlf.csv", "\r\n")):
        (tmp_path / name).write_text(end.join(rows) + end, newline="")
    from cevm.io.manifest import read_manifest

    lf, cr, crlf = (read_manifest(tmp_path / n) for n in ("lf.csv", "cr.csv", "crlf.csv"))
    assert lf.rows == cr.rows == crlf.rows and len(lf.rows) == 3 and lf.rows[-1].line == 4


@pytest.mark.slow
def test_a_streamed_manifest_holds_no_rows(fleet, tmp_path):
    """20,000 rows that match no trip, matched as set-mass does (streamed, each problem
    passed on as found): the memory taken does not grow with the rows, against the same
    manifest read whole (as before: every row and every problem held, 1.67 GB at 3
    million rows)."""
    from cevm.io.manifest import open_manifest, read_manifest
    from cevm.store import TripStore
    from cevm.store.masses import match_manifest

    db, ids, hgv, starts = fleet
    p = tmp_path / "m.csv"
    with open(p, "w") as fh:
        fh.write("vehicle_id,start,end,gross_kg\n")
        for k in range(20_000):
            fh.write(f"HGV-{k % 500:03d},2020-01-01T{k % 24:02d}:00:00Z,2020-01-01T{k % 24:02d}:30:00Z,30000\n")
    seen = []
    with TripStore(db, readonly=True) as st:
        tracemalloc.start()
        try:
            with open_manifest(p) as reader:
                match = match_manifest(st, reader, on_problem=lambda line, why: seen.append(line))
            _, streamed = tracemalloc.get_traced_memory()
            tracemalloc.reset_peak()
            whole = match_manifest(st, read_manifest(p))
            _, held = tracemalloc.get_traced_memory()
        finally:
            tracemalloc.stop()
    assert match.n_problems == whole.n_problems == len(whole.problems) == 20_000 and match.problems == ()
    assert seen == [line for line, _ in whole.problems] == list(range(2, 20_002))
    seen_bytes = 20_000 * 36  # the list of line numbers this test keeps
    assert streamed - seen_bytes < 1.5e6 and held > 5e6, (streamed, held)


@pytest.mark.slow
def test_a_logger_profile_that_is_a_device_or_nested_without_end_is_refused(tmp_path):
    """``--profiles-dir`` (or $CEVM_PROFILES) holding a profile that is /dev/zero (a link
    to it), or one nested 50,000 levels deep: one line, exit 2 (before: memory without end,
    a RecursionError)."""
    log = ROOT / "sample_logs" / "srf" / "EB-01_2019-01-31.csv"
    profiles = tmp_path / "profiles"
    profiles.mkdir()
    (profiles / "deep.toml").write_text("x = " + "[" * 50_000 + "]" * 50_000 + "\n")
    line = one_error(cevm("ingest", log, "--profiles-dir", profiles, "--store", tmp_path / "s.sqlite", "-q"))
    assert "deep.toml: not a valid TOML profile: its arrays or tables nest too deeply" in line
    (profiles / "deep.toml").unlink()
    if Path("/dev/zero").exists():
        (profiles / "zero.toml").symlink_to("/dev/zero")
        line = one_error(cevm_process("ingest", log, "--profiles-dir", profiles, "--store", tmp_path / "s.sqlite",
                                      "-q", timeout_s=30))
        assert "zero.toml: is a character device, not a logger profile" in line
    assert not (tmp_path / "s.sqlite").exists()



def test_profiles_dir_adds_to_the_shipped_profiles(tmp_path):
    """``--profiles-dir`` adds its profiles to the shipped ones (its help says "extra"):
    an srf log still ingests beside a directory holding only a user's own profile (it
    was read instead of the shipped ones: "no logger profile matches")."""
    log = ROOT / "sample_logs" / "srf" / "EB-01_2019-01-31.csv"
    profiles = tmp_path / "profiles"
    profiles.mkdir()
    (profiles / "mine.toml").write_text(
        'name = "mine"\n[detect]\nrequired_columns = ["when", "kmh"]\n[time]\ncolumns = ["when"]\n'
        'format = "%Y/%m/%d %H:%M:%S"\ntimezone = "UTC"\n[vehicle]\nsource = "parent_dir"\n'
        '[columns]\nwheel_speed_mps = { source = "kmh", unit = "km/h" }\n')
    res = cevm("ingest", log, "--profiles-dir", profiles, "--store", tmp_path / "s.sqlite", "-q", "--workers", "1")
    assert res.exit_code == 0, res.stderr
    listed = cevm("trips", "--store", tmp_path / "s.sqlite", "-f", "csv")
    assert listed.exit_code == 0 and "EB-01" in listed.stdout

# ---------------------------------------------------------------------------- scenarios

SCENARIO = """name = "probe"
days = ["d1"]
[[depot]]
id = "depot"
[[vehicle]]
id = "V1"
file = "{vehicle}"
[[route]]
id = "R1"
vehicle = "V1"
stops = ["S1"]
leg = {{ cycle = "{cycle}" }}
[payload_kg]
"S1" = [1000]
"""


@pytest.mark.slow
def test_a_scenario_never_quotes_a_file_it_names(tmp_path):
    """A scenario naming someone's secrets as its leg or its vehicle file (the
    /etc/shadow of the trial, here files of the test's own) gets one line naming the file,
    the key and the line, and not a word of what the file holds (before: "the header has:"
    and the file's first line); a FIFO or a device is refused before it is read."""
    secret = tmp_path / "shadow"
    secret.write_text("xuserx:$6$SECRETHASH:19000:0:99999:7:::\n")
    secret_toml = tmp_path / "credentials"
    secret_toml.write_text('API_TOKEN = "SECRETTOKEN"\n')
    DIESEL_PAPER = ROOT / "configs" / "vehicles" / "diesel-hgv-paper.toml"
    scenario = tmp_path / "s.toml"
    cases = [(DIESEL_PAPER, secret, "shadow:1: not a usable cycle file (named by route 'R1'.leg of"),
             (secret_toml, URBAN, "credentials: not a usable vehicle file (named by vehicle[0].file of")]
    for vehicle, cycle, said in cases:
        scenario.write_text(SCENARIO.format(vehicle=vehicle, cycle=cycle))
        line = one_error(cevm("fleet", "plan", scenario))
        assert said in line and "SECRET" not in line and "API_TOKEN" not in line and "xuserx" not in line, line
    fifo = tmp_path / "pipe.csv"
    if hasattr(os, "mkfifo"):
        os.mkfifo(fifo)
        for cycle, said in ((fifo, "is a FIFO (named pipe), not a cycle file"),
                            (Path("/dev/zero"), "is a character device, not a cycle file")):
            if cycle.exists():
                scenario.write_text(SCENARIO.format(vehicle=DIESEL_PAPER, cycle=cycle))
                line = one_error(cevm_process("fleet", "plan", scenario, timeout_s=30))
                assert said in line and "(named by route 'R1'.leg of" in line, line
    scenario.write_text(SCENARIO.format(vehicle=DIESEL_PAPER, cycle=tmp_path / "missing.csv"))
    assert "missing.csv: cycle file not found (named by route 'R1'.leg" in one_error(cevm("fleet", "plan", scenario))


def test_a_vehicle_file_with_a_byte_order_mark_reads_as_without(tmp_path):
    """A Windows editor's UTF-8 byte order mark is not TOML: dropped, not 'Invalid statement'."""
    bom = tmp_path / "bom.toml"
    bom.write_bytes(b"\xef\xbb\xbf" + BUS.read_bytes())
    a = cevm("predict", "-v", BUS, "-c", URBAN, "-f", "csv")
    b = cevm("predict", "-v", bom, "-c", URBAN, "-f", "csv")
    assert a.exit_code == b.exit_code == 0 and a.stdout.replace("electric-bus", "bom") == b.stdout


# ------------------------------------------------------------------------------ cycles


def test_a_cycle_file_with_cr_line_ends_reads_as_with_lf_everywhere(tmp_path):
    """A classic Mac export (CR alone ends each line) was a _csv.Error traceback in
    predict, route add and a fleet leg; it reads as the same file with LF."""
    lf = URBAN.read_bytes().replace(b"\r\n", b"\n")
    cr = tmp_path / "urban-cr.csv"
    cr.write_bytes(lf.replace(b"\n", b"\r"))
    same = tmp_path / "urban-lf.csv"
    same.write_bytes(lf)
    a = cevm("predict", "-v", BUS, "-c", same, "-f", "csv")
    b = cevm("predict", "-v", BUS, "-c", cr, "-f", "csv")
    assert a.exit_code == b.exit_code == 0 and a.stdout.replace("urban-lf", "urban-cr") == b.stdout
    res = cevm("route", "add", "R1", "--cycle", cr, "--store", tmp_path / "s.sqlite")
    assert res.exit_code == 0, res.stderr
    DIESEL_PAPER = ROOT / "configs" / "vehicles" / "diesel-hgv-paper.toml"
    scenario = tmp_path / "s.toml"
    outputs = []
    for cycle in (same, cr):
        scenario.write_text(SCENARIO.format(vehicle=DIESEL_PAPER, cycle=cycle))
        res = cevm("fleet", "plan", scenario, "-f", "json")
        assert res.exit_code == 0, res.stderr
        outputs.append([(d["day"], d["total"]) for d in json.loads(res.stdout)["summary"]])
    assert outputs[0] == outputs[1]


@pytest.mark.slow
def test_a_cycle_or_grade_file_that_is_a_fifo_or_a_device_is_refused(tmp_path):
    fifo = tmp_path / "pipe.csv"
    if not hasattr(os, "mkfifo"):
        pytest.skip("no FIFOs here")
    os.mkfifo(fifo)
    for args, said in ((("predict", "-v", BUS, "-c", fifo), f"{fifo}: is a FIFO (named pipe), not a cycle file"),
                       (("predict", "-v", BUS, "-c", URBAN, "--grade-file", fifo),
                        f"{fifo}: is a FIFO (named pipe), not a grade file"),
                       (("route", "add", "R1", "--cycle", "/dev/zero", "--store", tmp_path / "s.sqlite"),
                        "/dev/zero: is a character device, not a cycle file")):
        assert one_error(cevm_process(*args, timeout_s=30)).endswith(said)


def _cycle(path: Path, n: int, columns: int = 1) -> Path:
    """A plausible 1 Hz cycle of ``n`` samples in ``columns`` speed columns."""
    t = np.arange(n)
    v = 20.0 + 10.0 * np.sin(t / 30.0)
    head = "time_s," + ",".join(f"speed_kmh_{k}" if columns > 1 else "speed_kmh" for k in range(columns))
    path.write_text(head + "\n" + "".join(f"{ti}," + ",".join([f"{vi:.3f}"] * columns) + "\n"
                                          for ti, vi in zip(t, v, strict=True)))
    return path


@pytest.mark.slow
def test_cycle_samples_are_bounded_per_file_per_command_per_route_and_per_stored_trip(tmp_path, monkeypatch):
    """The bounds that keep a command under 500 MB (README of the bounds in
    docs/reference/commands.md), each refused in one line naming the file and line, before
    the rest is read: a file's samples over its cycles, the files of one command together,
    a route's legs, a stored trip (as a source). The bounds are lowered here to a few
    hundred samples; bench_memory.py measures them at their real values."""
    import cevm.io.cycles as cycles
    import cevm.store.routes as routes
    import cevm.store.sources as sources

    db, ids, hgv, starts = make_fleet(tmp_path / "fleet")  # at the real bounds (its route's cycle is longer)
    monkeypatch.setattr(cycles, "MAX_CYCLE_SAMPLES", 300)
    monkeypatch.setattr(cycles, "MAX_COMMAND_CYCLE_SAMPLES", 500)
    ok, long_, wide = _cycle(tmp_path / "ok.csv", 300), _cycle(tmp_path / "long.csv", 301), \
        _cycle(tmp_path / "wide.csv", 200, columns=2)
    assert cevm("predict", "-v", BUS, "-c", ok, "-f", "csv").exit_code == 0
    line = one_error(cevm("predict", "-v", BUS, "-c", long_))
    assert line.startswith(f"cevm: error: {long_}:302: more than 300 samples: the most a cycle file may hold")
    line = one_error(cevm("predict", "-v", BUS, "-c", wide, "--speed-col", "speed_kmh_*", "--speed-unit", "km/h"))
    assert f"{wide}:152: more than 300 samples (2 speed columns: 150 lines each)" in line
    line = one_error(cevm("predict", "-v", BUS, "-c", ok, "-c", ok))
    assert f"{ok}:202: more than the 200 samples left: the cycle files of one command hold at most 500" in line

    monkeypatch.setattr(routes, "MAX_ROUTE_SAMPLES", 400)
    store = tmp_path / "s.sqlite"
    line = one_error(cevm("route", "add", "R1", "--cycle", ok, "--cycle", ok, "--store", store))
    assert f"{ok}:102: more than the 100 samples left: a route holds at most 400 samples" in line
    assert cevm("route", "add", "R1", "--cycle", ok, "--store", store).exit_code == 0

    monkeypatch.setattr(sources, "MAX_SOURCE_SAMPLES", 500)
    import sqlite3

    con = sqlite3.connect(db)
    n = dict(con.execute("SELECT trip_id, n_samples FROM trips").fetchall())
    con.close()
    long_trip = next(t for t in ids["EB-09"] if n[t] > 500)
    short = [t for t in ids["EB-09"] if n[t] <= 500]
    said = f"trip '{long_trip}' holds {n[long_trip]:,} samples, more than the 500 one source may"
    assert said in one_error(cevm("predict", "-v", BUS, "--trip", long_trip, "--store", db))
    assert said in one_error(cevm("simulate", "-v", BUS, "--trip", long_trip, "--store", db))
    res = cevm("predict", "-v", BUS, "--vehicle-id", "EB-09", "--store", db, "-f", "csv")
    assert res.exit_code == 1 and f"skipped: {said}" in res.stderr
    assert [r.split(",")[0] for r in res.stdout.splitlines()[1:]] == short
