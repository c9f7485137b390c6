"""Cycle files as users have them (cevm.io.cycles, cevm.io.numeric_csv): layouts,
detection, VECTO's layout (a stand-in in tests/data/cycles, and the public files when
../shared is there), gzip, decimal commas, plausibility bounds, and errors
that name file, line and column. Expected values come from plain Python parsing and
loops here, never from the reader under test."""

import csv
import gzip
import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from cevm.cli import app
from cevm.errors import InputError
from cevm.io.cycles import (
    MAX_ACCEL_MPS2,
    MAX_GRADE,
    MAX_SPEED_KMH,
    CycleFormat,
    read_cycle_csv,
    read_cycles,
)
from cevm.io.numeric_csv import read_numeric_columns, sniff_csv
from conftest import DATA, SHARED, shared_or_skip

runner = CliRunner()
VECTO_STANDIN = DATA / "cycles" / "vecto-standin"
VECTO = SHARED / "cycles" / "vecto-carculator"


def vecto_facts(splice_line: int, missions_read: int, regional_rows: int, bus_time_stop_line: int,
                bus_rows: int) -> dict:
    """What a folder of VECTO-layout files holds, counted with the csv module (the stand-in's
    by construction, see tests/data/cycles/README.md): the truck file's mission columns that
    read, those refused (line, column, words of the message), the rows of 'Regional
    delivery, 7.5t', the line where the bus file's Time column has stopped, the bus rows."""
    return {
        "missions_read": missions_read,
        "refusals": {
            # 0 -> 59.9 km/h in one second, spliced into the trace
            "Long haul, 7.5t": (splice_line, "Long haul, 7.5t", "acceleration 16.6 m/s^2"),
            # the gradient file names this column 'Regional delivery, 8.5t'
            "Regional delivery, 7.5t": (1, None, "did you mean 'Regional delivery, 8.5t'"),
        },
        "regional_rows": regional_rows, "bus_time_stop_line": bus_time_stop_line, "bus_rows": bus_rows,
    }


VECTO_FACTS = {
    VECTO_STANDIN: vecto_facts(splice_line=122, missions_read=3, regional_rows=290, bus_time_stop_line=122,
                               bus_rows=483),
    VECTO: vecto_facts(splice_line=5202, missions_read=19, regional_rows=1676, bus_time_stop_line=5827,
                       bus_rows=17918),
}


@pytest.fixture(params=["standin", "public"])
def vecto(request) -> Path:
    """A folder of VECTO-layout files: the stand-in always, the public files when there."""
    if request.param == "public":
        return shared_or_skip("cycles", "vecto-carculator")
    return VECTO_STANDIN


def plain_columns(path: Path, sep: str = ";") -> tuple[list[str], list[list[str]]]:
    with open(path, newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh, delimiter=sep))
    return rows[0], rows[1:]


def plain_elevation(t, v, g):
    """The documented formula, one step at a time."""
    h = [0.0]
    for i in range(len(t) - 1):
        d = 0.5 * (v[i] + v[i + 1]) * (t[i + 1] - t[i])
        s = 0.5 * (g[i] + g[i + 1])
        h.append(h[-1] + d * s / math.sqrt(1.0 + s * s))
    return h


def truck(vecto: Path) -> CycleFormat:
    return CycleFormat(speed_columns=("Long haul, 26t",), speed_unit="km/h", grade_file=vecto / "gradient_truck.csv",
                       grade_unit="fraction")


# ------------------------------------------------------------------------- VECTO files


def test_vecto_truck_mission_with_its_gradient(vecto):
    cyc = read_cycle_csv(vecto / "driving_cycles_truck.csv", truck(vecto))
    header, rows = plain_columns(vecto / "driving_cycles_truck.csv")
    gheader, grows = plain_columns(vecto / "gradient_truck.csv")
    j, gj = header.index("Long haul, 26t"), gheader.index("Long haul, 26t")
    t = [float(r[0]) for r in rows]
    v = [float(r[j]) / 3.6 for r in rows]
    g = [float(r[gj]) for r in grows]
    assert cyc.name == "driving_cycles_truck[Long haul, 26t]"
    np.testing.assert_array_equal(cyc.time_s, t)
    np.testing.assert_allclose(cyc.speed_mps, v, rtol=1e-15)
    np.testing.assert_allclose(cyc.elevation_m, plain_elevation(t, v, g), rtol=1e-12, atol=1e-9)


def test_vecto_truck_file_reads_as_one_cycle_per_mission_column(vecto):
    """Every mission column is a cycle as long as its own values (missions end with
    trailing empty cells), with its gradient; the two columns the public files get wrong
    are refused with their line and column."""
    header, rows = plain_columns(vecto / "driving_cycles_truck.csv")
    expected_refusals = VECTO_FACTS[vecto]["refusals"]
    read = 0
    for j, name in enumerate(header[1:], start=1):
        fmt = CycleFormat(speed_columns=(name,), speed_unit="km/h", grade_file=vecto / "gradient_truck.csv",
                          grade_unit="fraction")
        if name in expected_refusals:
            line, column, words = expected_refusals[name]
            with pytest.raises(InputError) as err:
                read_cycle_csv(vecto / "driving_cycles_truck.csv", fmt)
            assert (err.value.line, err.value.column) == (line, column) and words in str(err.value)
            continue
        cyc = read_cycle_csv(vecto / "driving_cycles_truck.csv", fmt)
        n = sum(1 for r in rows if r[j].strip())
        assert cyc.time_s.size == n and cyc.name == f"driving_cycles_truck[{name}]"
        assert cyc.elevation_m is not None and cyc.elevation_m[0] == 0.0
        read += 1
    assert read == len(header) - 1 - len(expected_refusals) == VECTO_FACTS[vecto]["missions_read"]
    # a glob selects several missions at once, one cycle each, in the file's order
    cycles = read_cycles(vecto / "driving_cycles_truck.csv",
                         CycleFormat(speed_columns=("Urban delivery*",), speed_unit="km/h"))
    assert [c.name for c in cycles] == [f"driving_cycles_truck[{h}]" for h in header if h.startswith("Urban delivery")]


def test_grade_column_of_another_name_and_a_fixed_time_step(vecto):
    fmt = CycleFormat(speed_columns=("Regional delivery, 7.5t",), speed_unit="kmh",
                      grade_file=vecto / "gradient_truck.csv", grade_column="Regional delivery, 8.5t",
                      grade_unit="fraction")
    facts = VECTO_FACTS[vecto]
    assert read_cycle_csv(vecto / "driving_cycles_truck.csv", fmt).time_s.size == facts["regional_rows"]
    # the bus file's Time column stops long before its missions (public: 5825 and 17918)
    bus = CycleFormat(speed_columns=("Urban, 9m",), speed_unit="km/h")
    with pytest.raises(InputError) as err:
        read_cycle_csv(vecto / "driving_cycles_bus.csv", bus)
    assert (err.value.line, err.value.column) == (facts["bus_time_stop_line"], "Time")
    assert "--time-step-s" in str(err.value)
    cyc = read_cycle_csv(vecto / "driving_cycles_bus.csv", CycleFormat(
        speed_columns=("Urban, 9m",), speed_unit="km/h", time_step_s=1.0, grade_file=vecto / "gradient_bus.csv",
        grade_unit="fraction"))
    n = facts["bus_rows"]
    assert cyc.time_s.size == n and cyc.time_s[0] == 0.0 and cyc.time_s[-1] == n - 1.0


def test_a_grade_file_with_other_rows_is_refused(tmp_path):
    (tmp_path / "s.csv").write_text("Time;m\n1;10\n2;10\n3;10\n")
    (tmp_path / "g.csv").write_text("Time;m\n1;0.01\n3;0.01\n4;0.01\n")
    fmt = CycleFormat(speed_columns=("m",), speed_unit="m/s", grade_file=tmp_path / "g.csv", grade_unit="fraction")
    with pytest.raises(InputError) as err:
        read_cycle_csv(tmp_path / "s.csv", fmt)
    assert (err.value.line, err.value.column) == (3, "Time") and "g.csv" in str(err.value)
    assert "the grade file's rows must be the cycle's" in str(err.value)
    (tmp_path / "g.csv").write_text("Time;m\n1;0.01\n2;0.01\n")  # shorter than the cycle
    with pytest.raises(InputError) as err:
        read_cycle_csv(tmp_path / "s.csv", fmt)
    assert err.value.line == 4 and "g.csv" in str(err.value) and "2 data lines, but the cycle has 3" in str(err.value)


def test_a_unitless_speed_column_needs_its_unit(vecto):
    with pytest.raises(InputError) as err:
        read_cycle_csv(vecto / "driving_cycles_truck.csv", CycleFormat(speed_columns=("Long haul, 26t",)))
    assert (err.value.line, err.value.column) == (1, "Long haul, 26t") and "--speed-unit" in str(err.value)
    with pytest.raises(InputError) as err:  # the VECTO gradient file says nothing of its unit either
        read_cycle_csv(vecto / "driving_cycles_truck.csv", CycleFormat(
            speed_columns=("Long haul, 26t",), speed_unit="km/h", grade_file=vecto / "gradient_truck.csv"))
    assert "--grade-unit" in str(err.value) and "gradient_truck.csv" in str(err.value)


# ------------------------------------------------------------------ layouts, detection

PLAIN = "time_s,speed_kmh,elevation_m\n0,0,10.5\n1,3.6,10.75\n2,7.2,11\n3,10.8,11.25\n"


def test_gzip_reads_like_the_plain_file(tmp_path):
    plain = tmp_path / "c.csv"
    plain.write_text(PLAIN)
    gz = tmp_path / "c.csv.gz"
    gz.write_bytes(gzip.compress(PLAIN.encode()))
    odd = tmp_path / "odd.csv"  # gzip by its magic bytes, whatever the name
    odd.write_bytes(gzip.compress(PLAIN.encode()))
    a, b, c = read_cycle_csv(plain), read_cycle_csv(gz), read_cycle_csv(odd)
    assert b.name == "c" and sniff_csv(gz).compression == "gzip"
    for x in (b, c):
        np.testing.assert_array_equal(x.speed_mps, a.speed_mps)
        np.testing.assert_array_equal(x.elevation_m, a.elevation_m)
    np.testing.assert_allclose(a.speed_mps, [0, 1, 2, 3], rtol=1e-15)
    np.testing.assert_array_equal(a.elevation_m, [10.5, 10.75, 11, 11.25])


@pytest.mark.parametrize("sep", [";", "\t", "|"])
def test_decimal_comma_and_separators_detected(tmp_path, sep):
    body = PLAIN.replace(",", sep).replace(".", ",") if sep != "|" else PLAIN.replace(",", "|")
    p = tmp_path / "c.csv"
    p.write_text(body)
    layout = sniff_csv(p)
    assert layout.sep == sep and layout.decimal == ("," if sep != "|" else ".")
    cyc = read_cycle_csv(p)
    np.testing.assert_array_equal(cyc.elevation_m, [10.5, 10.75, 11, 11.25])


def test_decimal_comma_after_integer_lines_is_detected_from_the_first_mib(tmp_path):
    lines = ["time_s;speed_kmh"] + [f"{i};0" for i in range(200)] + ["200;1,5", "201;3,25"]
    p = tmp_path / "c.csv"
    p.write_text("\n".join(lines) + "\n")
    cyc = read_cycle_csv(p)
    assert cyc.speed_mps[-1] == pytest.approx(3.25 / 3.6, rel=1e-15)


@pytest.mark.parametrize(
    "header, to_mps",
    [("Time [s];Speed [km/h]", 1 / 3.6), ("t;v (m/s)", 1.0), ("time;Vehicle Speed (mph)", 0.44704),
     ("TIME_S;SPEED_MPS", 1.0), ("time (s);velocity [kph]", 1 / 3.6)],
)
def test_columns_detected_by_name_with_the_unit_in_the_name(tmp_path, header, to_mps):
    p = tmp_path / "c.csv"
    p.write_text(header + "\n0;0\n1;2\n2;4\n")
    cyc = read_cycle_csv(p)
    np.testing.assert_allclose(cyc.speed_mps, np.array([0, 2, 4]) * to_mps, rtol=1e-15)
    assert cyc.elevation_m is None


def test_elevation_in_feet_and_time_in_milliseconds(tmp_path):
    p = tmp_path / "c.csv"
    p.write_text("time_ms,speed_mps,altitude (ft)\n0,1,100\n1000,1,101\n2000,1,102\n")
    cyc = read_cycle_csv(p)
    np.testing.assert_array_equal(cyc.time_s, [0, 1, 2])
    np.testing.assert_allclose(cyc.elevation_m, [30.48, 30.7848, 31.0896], rtol=1e-15)


def test_grade_in_percent_integrates_to_the_analytic_rise(tmp_path):
    """10 m/s on a constant 5 % grade for 100 s: 1,000 m of road, a rise of
    1000 * 0.05 / sqrt(1 + 0.05^2) m."""
    p = tmp_path / "c.csv"
    p.write_text("time_s,speed_mps,grade_pct\n" + "".join(f"{i},10,5\n" for i in range(101)))
    cyc = read_cycle_csv(p)
    assert cyc.elevation_m[-1] == pytest.approx(1000 * 0.05 / math.sqrt(1.0025), rel=1e-12)
    frac = tmp_path / "f.csv"
    frac.write_text("time_s,speed_mps,slope\n" + "".join(f"{i},10,0.05\n" for i in range(101)))
    np.testing.assert_allclose(read_cycle_csv(frac, CycleFormat(grade_unit="fraction")).elevation_m, cyc.elevation_m,
                               rtol=1e-15)


def test_options_choose_columns_separator_and_decimal(tmp_path):
    p = tmp_path / "c.txt"
    p.write_text("a;b;c;d\n0;5;1,5;7\n2;6;2,5;8\n4;7;3,5;9\n")
    fmt = CycleFormat(sep=";", decimal=",", time_column="b", speed_columns=("c",), speed_unit="m/s",
                      elevation_column="d")
    cyc = read_cycle_csv(p, fmt)
    np.testing.assert_array_equal(cyc.time_s, [5, 6, 7])
    np.testing.assert_array_equal(cyc.speed_mps, [1.5, 2.5, 3.5])
    np.testing.assert_array_equal(cyc.elevation_m, [7, 8, 9])
    assert cyc.name == "c[c]"


def test_the_old_layout_reads_as_before(root):
    """The shipped cycles: time_s, speed_kmh, elevation_m, parsed here by hand."""
    for path in sorted((root / "configs" / "cycles").glob("*.csv")):
        with open(path, newline="") as fh:
            rows = list(csv.DictReader(fh))
        cyc = read_cycle_csv(path)
        assert cyc.name == path.stem
        np.testing.assert_array_equal(cyc.time_s, [float(r["time_s"]) for r in rows])
        np.testing.assert_allclose(cyc.speed_mps, [float(r["speed_kmh"]) / 3.6 for r in rows], rtol=1e-15)
        np.testing.assert_array_equal(cyc.elevation_m, [float(r["elevation_m"]) for r in rows])


@settings(max_examples=40, deadline=None)
@given(
    values=st.lists(st.tuples(st.floats(0, 1e4, allow_nan=False), st.floats(-1e6, 1e6, allow_nan=False),
                              st.integers(-10**9, 10**9)), min_size=1, max_size=40),
    sep=st.sampled_from([",", ";", "\t", "|"]),
    comma=st.booleans(),
    digits=st.integers(0, 9),
)
def test_fast_path_reads_the_numbers_python_reads(tmp_path_factory, values, sep, comma, digits):
    """Any table of numbers, in any separator and decimal mark, reads to the values
    Python's float() gives for its cells (or within one unit in the last place)."""
    decimal = "," if comma and sep != "," else "."
    cells = [[f"{a:.{digits}f}", f"{b:.{digits}e}", str(c)] for a, b, c in values]
    text = sep.join(["x", "y", "z"]) + "\n" + "".join(sep.join(c.replace(".", decimal) for c in r) + "\n"
                                                      for r in cells)
    d = tmp_path_factory.mktemp("t")
    (d / "n.csv").write_text(text)
    # a text column: read by the other fast path (pandas instead of numpy), the same numbers
    (d / "s.csv").write_text("".join(line + sep + ("name" if i == 0 else f"r{i}") + "\n"
                                     for i, line in enumerate(text.splitlines())))
    for name in ("n.csv", "s.csv"):
        layout = sniff_csv(d / name, decimal=decimal)
        got = read_numeric_columns(layout, [0, 1, 2])
        for j in range(3):
            want = np.array([float(r[j]) for r in cells])
            np.testing.assert_array_max_ulp(got[j], want, maxulp=1)


# --------------------------------------------------------------------------- errors


def _error(tmp_path, body, fmt=None, name="bad.csv"):
    p = tmp_path / name
    p.write_bytes(body) if isinstance(body, bytes) else p.write_text(body)
    with pytest.raises(InputError) as err:
        read_cycle_csv(p, fmt)
    assert str(p) in str(err.value) and "\n" not in str(err.value)
    return err.value


BIG = "time_s,speed_kmh,elevation_m\n" + "".join(f"{i},31,{100 + 0.01 * i:.2f}\n" for i in range(5000))


@pytest.mark.parametrize(
    "edit, line, column, words",
    [
        (lambda b: b.replace("\n4000,", "\n4000x,", 1), 4002, "time_s", "not a number: '4000x'"),
        (lambda b: b.replace("\n4000,", "\n4000,,", 1), 4002, None, "4 fields, but the header has 3"),
        (lambda b: b.replace("\n4000,31,140.00", "\n4000,31,1e999", 1), 4002, "elevation_m", "not a finite number"),
        (lambda b: b.replace("\n4000,31,", "\n4000,,", 1), 4002, "speed_kmh", "empty cell"),
        (lambda b: b.replace("\n4000,31,140.00\n", "\n4000\n", 1), 4002, "speed_kmh", "only 1 field"),
        (lambda b: b.replace("\n4000,31,", "\n4000,99999,", 1), 4002, "speed_kmh", "beyond 300 km/h"),
        (lambda b: b.replace("\n4000,31,", "\n3999,31,", 1), 4002, "time_s", "time does not increase"),
        (lambda b: b.replace("\n4000,31,140.00", "\n4000,31,9.5e7", 1), 4002, "elevation_m", "beyond +-10000 m"),
        (lambda b: b.replace("\n4000,31,140.00", "\n4000,31,150", 1), 4002, "elevation_m", "steeper than 40%"),
        (lambda b: b.replace("\n4000,31,", "\n4000,-1,", 1), 4002, "speed_kmh", "negative speed"),
    ],
)
def test_each_error_names_its_line_and_column(tmp_path, edit, line, column, words):
    assert "\n4000,31,140.00\n" in BIG
    e = _error(tmp_path, edit(BIG))
    assert (e.line, e.column) == (line, column), str(e)
    assert words in str(e), str(e)


def test_acceleration_and_grade_beyond_their_bounds(tmp_path):
    # 0 to 60 km/h in 1 s: 16.7 m/s^2
    e = _error(tmp_path, "time_s,speed_kmh\n0,0\n1,0\n2,60\n3,60\n")
    assert (e.line, e.column) == (4, "speed_kmh") and f"beyond {MAX_ACCEL_MPS2:g} m/s^2" in str(e)
    # the same over 2 s (8.3 m/s^2) is allowed
    assert read_cycle_csv(_write(tmp_path, "ok.csv", "time_s,speed_kmh\n0,0\n2,60\n3,60\n")).time_s.size == 3
    e = _error(tmp_path, "time_s,speed_mps,grade_pct\n0,10,1\n1,10,45\n2,10,1\n")
    assert (e.line, e.column) == (3, "grade_pct") and "steeper than 40%" in str(e)
    # a grade in % read as a fraction is refused, not integrated into a 500 m climb
    e = _error(tmp_path, "time_s,speed_mps,grade\n0,10,5\n1,10,5\n", CycleFormat(grade_unit="fraction"))
    assert (e.line, e.column) == (2, "grade") and "wrong unit" in str(e)
    assert MAX_GRADE == 0.40 and MAX_SPEED_KMH == 300.0


def test_elevation_rounded_to_whole_metres_is_not_a_cliff(tmp_path):
    """A profile in whole metres steps by 1 m at walking pace: within the allowance."""
    body = "time_s,speed_kmh,elevation_m\n" + "".join(f"{i},3.6,{100 + i // 3}\n" for i in range(30))
    assert read_cycle_csv(_write(tmp_path, "r.csv", body)).time_s.size == 30


def _write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.mark.parametrize(
    "body, fmt, line, column, words",
    [
        ("time_s,speed_kmh,speed_mps2\n0,1,1\n1,1,1\n", CycleFormat(speed_columns=("sped_kmh",)), 1, None,
         "did you mean 'speed_kmh'"),
        ("time,speed,speed\n0,1,1\n1,1,1\n", None, 1, None, "several speed columns"),
        ("time_s,speed_kmh\n0,1\n1,1\n", CycleFormat(speed_unit="m/s"), 1, "speed_kmh",
         "the column name says km/h"),
        ("time_s,speed_kmh\n0,1\n1,1\n", CycleFormat(speed_columns=("speed*",), time_step_s=1.0,
                                                      time_column="time_s"), None, None, "not both"),
        ("time_s,a,b\n0,1,1\n1,1,\n2,1,1\n", CycleFormat(speed_columns=("a", "b"), speed_unit="km/h"), 3, "b",
         "empty cell"),
        ("time_s,speed_kmh\n0,1\n1,1\n", CycleFormat(sep=":"), None, None, "separator ':' not supported"),
        (b"time_s,speed_kmh\n0,1\n1,2\xe9\n", None, 3, None, "not UTF-8 text"),
        ("x" * (1 << 21), None, 1, None, "no line break"),
    ],
)
def test_layout_and_option_errors(tmp_path, body, fmt, line, column, words):
    p = tmp_path / "bad.csv"
    p.write_bytes(body) if isinstance(body, bytes) else p.write_text(body)
    with pytest.raises(InputError) as err:
        read_cycle_csv(p, fmt)
    assert (err.value.line, err.value.column) == (line, column), str(err.value)
    assert words in str(err.value), str(err.value)


def test_a_mission_ends_with_its_trailing_empty_cells_but_one_cycle_does_not(tmp_path):
    body = "t;a;b\n0;1;1\n1;2;2\n2;;3\n3;;4\n"
    cycles = read_cycles(_write(tmp_path, "m.csv", body), CycleFormat(speed_columns=("a", "b"), speed_unit="m/s"))
    assert [c.time_s.size for c in cycles] == [2, 4]
    # a file of one cycle: a time without a speed is an error, not the end
    e = _error(tmp_path, "time_s,speed_kmh\n0,1\n1,2\n2,\n")
    assert (e.line, e.column) == (4, "speed_kmh") and "empty cell" in str(e)
    # blank lines at the end are nothing
    assert read_cycle_csv(_write(tmp_path, "b.csv", "time_s,speed_kmh\n0,1\n1,2\n\n\n")).time_s.size == 2


# ------------------------------------------------------------------------ commands


def test_the_cycle_at_99999_kmh_is_refused_by_predict(tmp_path, root):
    p = _write(tmp_path, "fast.csv", "time_s,speed_kmh\n0,99999\n1,99999\n2,99999\n")
    res = runner.invoke(app, ["predict", "-v", str(root / "configs/vehicles/electric-bus.toml"), "-c", str(p)])
    assert res.exit_code == 2
    assert f"{p}:2: column 'speed_kmh': speed 99999 km/h" in res.output and "Traceback" not in res.output


def test_every_command_that_reads_cycles_takes_the_options(vecto, root, tmp_path):
    opts = ["--speed-col", "Long haul, 26t", "--speed-unit", "km/h", "--grade-file", str(vecto / "gradient_truck.csv"),
            "--grade-unit", "fraction"]
    hgv = str(root / "configs/vehicles/diesel-hgv.toml")
    cyc_file = str(vecto / "driving_cycles_truck.csv")
    res = runner.invoke(app, ["predict", "-v", hgv, "-c", cyc_file, *opts, "-m", "30000", "-f", "json"])
    assert res.exit_code == 0, res.output
    (row,) = json.loads(res.stdout)
    cyc = read_cycle_csv(vecto / "driving_cycles_truck.csv", truck(vecto))
    from cevm.io import load_vehicle
    from reference import reference_wheel_energy_j

    veh = load_vehicle(hgv)
    e = reference_wheel_energy_j(cyc.time_s, cyc.speed_mps, cyc.elevation_m, 30000.0, veh.cda_m2, veh.cr,
                                 veh.ice_braking)
    assert row["cycle"] == "driving_cycles_truck[Long haul, 26t]"
    assert row["wheel_energy_kwh"] == pytest.approx(e / 3.6e6, rel=1e-9)
    res = runner.invoke(app, ["feasibility", "-v", hgv, "-c", cyc_file, *opts, "-f", "json"])
    assert res.exit_code == 0 and json.loads(res.stdout)[0]["cycle"] == row["cycle"]
    res = runner.invoke(app, ["simulate", "-v", hgv, "-c", cyc_file, *opts, "-f", "json"])
    assert res.exit_code == 0 and json.loads(res.stdout)[0]["cycle"] == row["cycle"]
    store = tmp_path / "s.sqlite"
    res = runner.invoke(app, ["route", "add", "lh", "--store", str(store), "-c", cyc_file, "--speed-col",
                              "Long haul, 26t", "--speed-col", "Long haul, 40t", "--speed-unit", "km/h"])
    assert res.exit_code == 0 and "2 legs (0 trips, 2 cycles)" in res.output, res.output
    res = runner.invoke(app, ["predict", "-v", hgv, "-c", cyc_file, "--speed-unit", "parsec/s"])
    assert res.exit_code == 2 and "unknown speed unit 'parsec/s'" in res.output



_RANDOM = np.random.default_rng(5).normal(0, 1e3, 500).tolist()


@pytest.mark.parametrize("body, by_arrow", [
    ("".join(f"{i},{x!r},{x * 1e-7:.25f}\n" for i, x in enumerate(_RANDOM)), True),
    ("0, 1.5,2\n1 ,+2.25,3\n", True),  # spaces around a number, a plus sign
    ("0,1.5,2\n1,2.25,3\n2,-,4\n", False),  # a cell that is no number: pandas explains it
    ('"0","1.5",2\r\n\r\n1,2.25,3e2\r\n', True),
])
def test_pyarrow_and_numpy_readers_give_the_same_doubles(tmp_path, monkeypatch, body, by_arrow):
    """Numbers are parsed by pyarrow where it can and by numpy.loadtxt where it refuses a
    cell: both to the nearest double, so a file reads the same by either."""
    import cevm.io.numeric_csv as nc

    path = tmp_path / "c.csv"
    path.write_text("a,b,c\n" + body)
    layout = nc.sniff_csv(path)
    assert (nc._read_arrow(layout, [0, 1, 2], None) is not None) == by_arrow

    def read():
        try:
            return [a.tobytes() for a in nc.read_numeric_columns(layout, [0, 1, 2])]
        except InputError as exc:
            return str(exc)

    fast = read()
    monkeypatch.setattr(nc, "_read_arrow", lambda *args: None)
    assert fast == read()
    if not by_arrow:
        assert "line 4" in fast or ":4:" in fast
        return
    fast = nc.read_numeric_columns(layout, [0, 1, 2])
    assert all(a.flags.writeable and a.dtype == np.float64 for a in fast)
    want_first = [float(x) for x in body.splitlines()[0].replace('"', "").split(",")]
    assert [a[0] for a in fast] == want_first
