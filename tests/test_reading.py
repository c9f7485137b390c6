"""Tests of the streaming reader (cevm.ingest.reading, cevm.ingest.textfile): blocks,
the two parsers, limits, hostile input under a memory limit, encodings and byte order
marks, time zone notation, vehicle ids, affine temperature units, and messages that
cannot forge a line.

Expected values are hand computations (unit conversions, line numbers counted by hand)
or plain Python (csv, datetime), never the code under test.
"""

from __future__ import annotations

import gzip
import os
import subprocess
import sys
import textwrap
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import cevm.ingest.reading.blocks as reading
from cevm.errors import InputError
from cevm.ingest.profiles import load_profile, load_profiles
from cevm.ingest.reading import ReadLimits, detect_profile, read_log

DATA = Path(__file__).parent / "data"
ROOT = Path(__file__).resolve().parents[1]
UTC = UTC
SRF_HEADER = "timestamp_utc,gps_lat_deg,gps_lon_deg,gps_speed_kmh,fms_wheel_speed_kmh,fms_total_energy_used_kwh"


@pytest.fixture(scope="module")
def profiles():
    return load_profiles(include_env=False)


def srf_rows(n: int, start_s: int = 0, zone: str = "Z") -> list[str]:
    t0 = datetime(2020, 6, 1, 10, 0, 0)
    return [f"{(t0 + timedelta(seconds=start_s + i)).strftime('%Y-%m-%dT%H:%M:%S.000')}{zone},"
            f"51.5{i % 10000:04d},-0.1{i % 10000:04d},36.0,36.0,{100 + i * 0.1:.1f}" for i in range(n)]


def srf_text(rows: list[str], meta: str = "# vehicle_id=BUS-1\n", header: str = SRF_HEADER) -> str:
    return meta + header + "\n" + "\n".join(rows) + "\n"


def write(path: Path, data: str | bytes) -> Path:
    path.write_bytes(data.encode("utf-8") if isinstance(data, str) else data)
    return path


def frames_equal(a: list, b: list) -> None:
    assert [x.vehicle_id for x in a] == [y.vehicle_id for y in b]
    for x, y in zip(a, b, strict=True):
        pd.testing.assert_frame_equal(x.frame, y.frame)
        assert x.repairs == y.repairs and x.energy_sources == y.energy_sources


# ======================================================================================
# Blocks and parsers: the same result whatever the block size or the parser
# ======================================================================================
SAMPLES = sorted(p for d in ("srf", "portal")
                 for p in (ROOT / "sample_logs" / d).rglob("*.csv")) + sorted(DATA.glob("*.csv"))


@pytest.mark.slow
@pytest.mark.parametrize("path", SAMPLES[:6] + SAMPLES[-4:], ids=lambda p: p.name)
def test_pyarrow_and_pandas_parsers_and_small_blocks_give_the_same_logs(path, profiles, monkeypatch):
    ref = read_log(path, profiles=profiles, engine="pandas")
    frames_equal(read_log(path, profiles=profiles, engine="pyarrow"), ref)
    monkeypatch.setattr(reading, "BLOCK_BYTES", 5000)  # many blocks, lines cut at every border
    frames_equal(read_log(path, profiles=profiles), ref)
    frames_equal(read_log(path, profiles=profiles, engine="pandas"), ref)


def _block_with_both_engines(text: bytes, prof):
    """One block of a log's data lines parsed by each engine on the very same bytes:
    (pyarrow's ParsedBlock or None where it refuses the block, pandas' ParsedBlock)."""
    from cevm.ingest.reading.blocks import ReadRepairs
    from cevm.ingest.reading.engine_arrow import _arrow_block
    from cevm.ingest.reading.engine_pandas import _pandas_block
    from cevm.ingest.reading.gather import ColumnGatherer
    from cevm.ingest.reading.header import _find_header, _plan_columns

    hdr = _find_header(text, prof.comment_prefix, prof.separator)
    plan = _plan_columns(prof, hdr, Path("x.csv"))
    block = text[hdr.body_offset:]
    gather = ColumnGatherer(plan, prof, Path("x.csv"), ReadLimits(), ReadRepairs())
    arrow = _arrow_block(block, hdr.line + 1, plan, prof, gather.arrow_time_type(block, plan, prof))
    return arrow, _pandas_block(block, hdr.line + 1, plan, prof, Path("x.csv"))


def _times_ns(part, prof) -> np.ndarray:
    """A block's time column as ns: what the engine typed, else its text parsed."""
    from cevm.ingest.timestamps import parse_datetimes

    if part.time_ns is not None:
        return part.time_ns
    return parse_datetimes(part.text[prof.time.columns[0]], prof.time.format)


@pytest.mark.parametrize("path", [ROOT / "sample_logs/srf/EB-01_2019-01-31.csv", DATA / "srf_sample.csv",
                                  DATA / "portal_dst.csv", DATA / "twizy_excerpt.csv"], ids=lambda p: p.name)
def test_both_parse_engines_agree_on_the_same_bytes(path, profiles):
    """The pyarrow engine (typed columns, its ISO 8601 parser) and the pandas engine (C
    parser, times straight from the bytes by the byte-level path) on one block of the
    same bytes: the same lines, numbers, text, times and blank rows."""
    prof = detect_profile(path, profiles)
    raw = path.read_bytes()
    text = raw.decode(prof.encoding).encode("utf-8")
    arrow, pandas = _block_with_both_engines(text, prof)
    assert arrow is not None  # these logs are well formed: pyarrow takes them
    np.testing.assert_array_equal(arrow.lines, pandas.lines)
    np.testing.assert_array_equal(arrow.blank, pandas.blank)
    assert sorted(arrow.numbers) == sorted(pandas.numbers)
    for c in arrow.numbers:
        np.testing.assert_array_equal(arrow.numbers[c], pandas.numbers[c])  # NaN where NaN
    for c in set(arrow.text) & set(pandas.text):
        if c != prof.time.columns[0] or len(prof.time.columns) > 1:
            assert pd.Series(arrow.text[c]).equals(pd.Series(pandas.text[c])), c
    if len(prof.time.columns) == 1:
        np.testing.assert_array_equal(_times_ns(arrow, prof), _times_ns(pandas, prof))
        if arrow.time_ns is not None and pandas.time_ns is not None:
            assert arrow.time_utc == pandas.time_utc


def test_real_twizy_logs_same_with_both_parsers(profiles, twizy_logs):
    files = sorted(twizy_logs[0].glob("*.csv*"))
    assert files
    for f in files[:5]:
        frames_equal(read_log(f, profiles=profiles), read_log(f, profiles=profiles, engine="pandas"))


@pytest.mark.slow
@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(st.sampled_from(["", "36.0", "12.5", "0", "N/A", "-", "1e2"]),
                          st.sampled_from(["", "51.5", "-0.1", "x"]),
                          st.booleans()), min_size=1, max_size=40),
       st.integers(64, 400))
def test_parsers_agree_on_odd_rows(tmp_path_factory, rows, block):
    """Empty fields, NA-like text, a non-number, blank lines: both parsers, any block
    size, give the same log or the same error."""
    tmp = tmp_path_factory.mktemp("odd")
    lines = []
    for i, (v, lat, blank) in enumerate(rows):
        lines.append("" if blank else f"2020-06-01T10:{i // 60:02d}:{i % 60:02d}.000Z,{lat},{lat},{v},{v},")
    f = write(tmp / "o.csv", srf_text(lines))
    profs = load_profiles(include_env=False)
    out = []
    for engine, bb in (("pandas", 1 << 24), ("pyarrow", 1 << 24), ("pyarrow", block)):
        old = reading.BLOCK_BYTES
        reading.BLOCK_BYTES = bb
        try:
            out.append(read_log(f, profs["srf"], engine=engine))
        except InputError as exc:
            out.append((str(exc).split(" (and ")[0], exc.line, exc.column))
        finally:
            reading.BLOCK_BYTES = old
    for o in out[1:]:
        if isinstance(out[0], tuple) or isinstance(o, tuple):
            if isinstance(out[0], tuple) and isinstance(o, tuple):
                assert o == out[0]
            else:
                assert isinstance(o, tuple) and isinstance(out[0], tuple), (o, out[0])
        else:
            frames_equal(o, out[0])


def test_columns_of_float32_values_are_float32_with_the_values_written(tmp_path, profiles, monkeypatch):
    """A column in SI as logged whose every value is a float32 (engine speed in 1/8 rpm,
    a 0/1 switch) is float32 and holds exactly the values written; one other value
    (1234.56), in a later block, makes it float64 again; a converted column (km/h) is
    float64 whatever its values."""
    monkeypatch.setattr(reading, "BLOCK_BYTES", 2000)  # many blocks
    head = "timestamp_utc,fms_wheel_speed_kmh,fms_engine_speed_rpm,fms_brake_switch"
    t0 = datetime(2020, 6, 1, 10, 0, 0)
    rpm = [f"{600 + i / 8:g}" for i in range(300)]
    rows = [f"{(t0 + timedelta(seconds=i)).strftime('%Y-%m-%dT%H:%M:%S')}Z,{i % 40},{rpm[i]},{i % 2}"
            for i in range(300)]
    [log] = read_log(write(tmp_path / "a.csv", srf_text(rows, header=head)), profiles=profiles)
    fr = log.frame
    assert fr["engine_speed_rpm"].dtype == np.float32 and fr["brake_switch"].dtype == np.float32
    assert fr["engine_speed_rpm"].to_numpy(dtype=float).tolist() == [float(x) for x in rpm]
    assert fr["brake_switch"].tolist() == [float(i % 2) for i in range(300)]
    assert fr["wheel_speed_mps"].dtype == np.float64  # 36 km/h = 10 m/s, but converted
    rows[250] = rows[250].replace(f",{rpm[250]},", ",1234.56,")
    [log] = read_log(write(tmp_path / "b.csv", srf_text(rows, header=head)), profiles=profiles)
    got = log.frame["engine_speed_rpm"]
    assert got.dtype == np.float64
    assert got.tolist() == [float(x) for x in rpm[:250]] + [1234.56] + [float(x) for x in rpm[251:]]


def test_errors_in_a_later_block_name_their_line(tmp_path, profiles, monkeypatch):
    monkeypatch.setattr(reading, "BLOCK_BYTES", 2000)
    rows = srf_rows(300)
    rows[250] = rows[250].rsplit(",", 1)[0] + ",abc"  # line 2 + 251 = 253
    rows[260] = rows[260].rsplit(",", 1)[0] + ",abc"
    from dataclasses import replace

    prof = profiles["srf"]
    required = replace(prof, columns=tuple(replace(m, required=m.source == "fms_total_energy_used_kwh")
                                           for m in prof.columns))
    with pytest.raises(InputError, match="not a number: 'abc'") as ei:
        read_log(write(tmp_path / "b.csv", srf_text(rows)), required)
    assert (ei.value.line, ei.value.column) == (253, "fms_total_energy_used_kwh")
    # in a measured column: missing values, and one note naming both lines
    [log] = read_log(write(tmp_path / "b.csv", srf_text(rows)), profiles=profiles)
    assert next(r for r in log.repairs if "not numbers" in r).endswith("lines 253, 263")


# ======================================================================================
# Limits
# ======================================================================================
def test_row_limit_names_the_first_row_over_it(tmp_path, profiles):
    f = write(tmp_path / "r.csv", srf_text(srf_rows(50)))
    assert len(read_log(f, profiles=profiles, limits=ReadLimits(max_rows=50))[0].frame) == 50
    with pytest.raises(InputError, match=r"more than 49 data rows.*--max-rows") as ei:
        read_log(f, profiles=profiles, limits=ReadLimits(max_rows=49))
    assert ei.value.line == 2 + 50  # header on line 2, row 50 on line 52


def test_value_limit_bounds_a_wide_file_by_its_rows_times_columns(tmp_path, profiles, monkeypatch):
    # SRF_HEADER's 6 columns are all read by the srf profile: 120 values are 20 rows
    f = write(tmp_path / "r.csv", srf_text(srf_rows(50)))
    assert ReadLimits(max_values=120).row_limit(6) == 20 and ReadLimits(max_values=None).row_limit(6) == 2_500_000
    with pytest.raises(InputError, match=r"more than 20 data rows of 6 columns \(120 values\)") as ei:
        read_log(f, profiles=profiles, limits=ReadLimits(max_values=120))
    assert ei.value.line == 2 + 21
    assert len(read_log(f, profiles=profiles, limits=ReadLimits(max_values=300))[0].frame) == 50
    # the command line: the default holds the values bound; --max-rows given sets the rows alone
    from typer.testing import CliRunner

    import cevm.cli.ingest as cli_ingest
    from cevm.cli import app

    real = cli_ingest.ReadLimits
    monkeypatch.setattr(cli_ingest, "ReadLimits", lambda **kw: real(**{"max_values": 120, **kw}))
    store = str(tmp_path / "s.sqlite")
    res = CliRunner().invoke(app, ["ingest", str(f), "--store", store, "-q"])
    assert res.exit_code == 1 and "more than 20 data rows of 6 columns" in res.output, res.output
    res = CliRunner().invoke(app, ["ingest", str(f), "--store", store, "-q", "--max-rows", "40"])
    assert res.exit_code == 1 and "more than 40 data rows: over" in res.output, res.output
    res = CliRunner().invoke(app, ["ingest", str(f), "--store", store, "-q", "--max-rows", "100"])
    assert res.exit_code == 0, res.output

def test_size_limit_plain_before_reading_and_gzip_while_decompressing(tmp_path, profiles):
    text = srf_text(srf_rows(2000))  # about 140 kB
    f = write(tmp_path / "s.csv", text)
    with pytest.raises(InputError, match=r"file of 0.1\d+ MB: more than the limit of 0.1 MB.*--max-file-mb"):
        read_log(f, profiles=profiles, limits=ReadLimits(max_file_mb=0.1))
    g = write(tmp_path / "s.csv.gz", gzip.compress(text.encode()))
    with pytest.raises(InputError, match=r"decompresses to more than the limit of 0.1 MB"):
        read_log(g, profiles=profiles, limits=ReadLimits(max_file_mb=0.1))
    assert len(read_log(g, profiles=profiles)[0].frame) == 2000


def make_bomb(path: Path, mib_out: int) -> Path:
    """Concatenated gzip members of one valid srf row repeated: ``mib_out`` MiB of rows."""
    row = srf_rows(1)[0].encode() + b"\n"
    block = row * ((1 << 20) // len(row))
    member = gzip.compress(block, compresslevel=9)
    with open(path, "wb") as fh:
        fh.write(gzip.compress(srf_text([]).encode()[:-1]))
        for _ in range(mib_out):
            fh.write(member)
    return path


def test_gzip_bomb_is_refused_once_past_the_floor(tmp_path, profiles):
    bomb = make_bomb(tmp_path / "bomb.csv.gz", 48)  # 48 MiB from ~0.1 MB
    assert bomb.stat().st_size < 200_000
    with pytest.raises(InputError, match=r"expands more than 100 times.*zip bomb.*--max-expansion"):
        read_log(bomb, profiles=profiles)
    # allowed to expand, the same file is bounded by the row limit instead
    with pytest.raises(InputError, match="more than 100,000 data rows"):
        read_log(bomb, profiles=profiles, limits=ReadLimits(max_expansion=1e9, max_rows=100_000))


def test_multi_member_gzip_and_zero_padding(tmp_path, profiles):
    rows = srf_rows(10)
    text = srf_text(rows).encode()
    cut = text.index(rows[5].encode())
    f = write(tmp_path / "m.csv.gz", gzip.compress(text[:cut]) + gzip.compress(text[cut:]) + b"\x00" * 64)
    [log] = read_log(f, profiles=profiles)
    assert log.frame["source_line"].tolist() == list(range(3, 13))
    bad = write(tmp_path / "junk.csv.gz", gzip.compress(text) + b"junk")
    with pytest.raises(InputError, match="corrupt gzip data: trailing bytes"):
        read_log(bad, profiles=profiles)


def test_line_less_text_fails_from_its_first_megabytes(tmp_path, profiles):
    f = tmp_path / "l.csv"
    with open(f, "wb") as fh:
        fh.write(b"timestamp_utc,")
        fh.write(b"1234567890" * 800_000)  # 8 MB, no line break
    with pytest.raises(InputError, match="no line break in 1 MiB of text from line 1") as ei:
        read_log(f, profiles=profiles)
    assert ei.value.line == 1
    # a line too long later in the file
    g = tmp_path / "g.csv"
    g.write_bytes(srf_text(srf_rows(3)).encode() + b"9" * (3 << 20) + b"\n")
    with pytest.raises(InputError, match="no line break in 1 MiB of text from line 6") as ei:
        read_log(g, profiles=profiles)
    assert ei.value.line == 6


def test_sparse_nul_file_fails_from_its_first_bytes(tmp_path, profiles):
    f = tmp_path / "n.csv"
    with open(f, "wb") as fh:
        fh.truncate(3 << 30)  # 3 GiB of NUL bytes, sparse: reading it whole would take seconds
    with pytest.raises(InputError, match="binary data"):
        read_log(f, profiles=profiles, limits=ReadLimits(max_file_mb=1e5))
    with pytest.raises(InputError, match="binary data"):
        read_log(f, "srf", profiles, limits=ReadLimits(max_file_mb=1e5))  # forced profile: first chunk


_CHILD = textwrap.dedent("""
    import re, resource, sys
    from cevm.errors import InputError
    from cevm.ingest.reading import read_log
    read_log(sys.argv[2], "srf")  # imports and first allocations done before the limit
    peak = int(re.search(r"VmPeak:\\s+(\\d+)", open("/proc/self/status").read()).group(1)) * 1024
    limit = peak + int(sys.argv[3]) * 2**20
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    try:
        read_log(sys.argv[1], "srf")
    except InputError as exc:
        print("REFUSED", exc)
    except MemoryError:
        print("MEMORY ERROR")
        sys.exit(3)
""")


def run_limited(path: Path, headroom_mb: int = 400) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"), OMP_NUM_THREADS="1")
    return subprocess.run([sys.executable, "-c", _CHILD, str(path), str(DATA / "srf_sample.csv"), str(headroom_mb)],
                          capture_output=True, text=True, env=env, timeout=300)


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="RLIMIT_AS and /proc: Linux")
def test_gzip_bomb_under_a_memory_limit(tmp_path):
    """1 GiB of valid rows from a 2 MB gzip, in a process allowed 400 MB more than it
    had: refused with the expansion limit (reading it whole would need > 1 GiB)."""
    bomb = make_bomb(tmp_path / "bomb.csv.gz", 1024)
    p = run_limited(bomb)
    assert p.returncode == 0 and "REFUSED" in p.stdout and "zip bomb" in p.stdout, p.stdout + p.stderr


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="RLIMIT_AS and /proc: Linux")
def test_line_less_file_under_a_memory_limit(tmp_path):
    """420 MB without a line break after a header-like start, 400 MB of headroom:
    refused from the first megabytes (reading it whole needs more than the limit)."""
    f = tmp_path / "l.csv"
    chunk = b"0123456789" * (1 << 20)
    with open(f, "wb") as fh:
        fh.write(b"timestamp_utc,")
        for _ in range(40):
            fh.write(chunk)
    p = run_limited(f)
    assert p.returncode == 0 and "REFUSED" in p.stdout and "no line break" in p.stdout, p.stdout + p.stderr


# ======================================================================================
# Encodings and byte order marks
# ======================================================================================
def test_utf8_bom_on_a_cp1252_portal_export(tmp_path, profiles):
    raw = (DATA / "portal_dst.csv").read_bytes()
    text = raw.decode("cp1252")
    f = write(tmp_path / "bom.csv", b"\xef\xbb\xbf" + text.encode("utf-8"))  # what a spreadsheet saves
    assert detect_profile(f, profiles).name == "portal"
    got = read_log(f, profiles=profiles)
    frames_equal(got, read_log(DATA / "portal_dst.csv", profiles=profiles))


@pytest.mark.parametrize("enc,bom", [("utf-16-le", b"\xff\xfe"), ("utf-16-be", b"\xfe\xff"),
                                     ("utf-32-le", b"\xff\xfe\x00\x00")])
def test_unicode_with_bom_is_decoded_not_called_binary(tmp_path, profiles, enc, bom):
    text = srf_text(srf_rows(20))
    f = write(tmp_path / "u.csv", bom + text.replace("\n", "\r\n").encode(enc))
    assert detect_profile(f, profiles).name == "srf"
    [log] = read_log(f, profiles=profiles)
    [ref] = read_log(write(tmp_path / "ref.csv", text), profiles=profiles)
    pd.testing.assert_frame_equal(log.frame, ref.frame)


def test_utf16_without_bom_is_named(tmp_path, profiles):
    f = write(tmp_path / "u.csv", srf_text(srf_rows(20)).encode("utf-16-le"))
    with pytest.raises(InputError, match=r"binary data.*looks like UTF-16-LE text without a byte order mark"):
        read_log(f, profiles=profiles)


def test_bad_byte_in_a_later_chunk_names_line_and_column(tmp_path, profiles, monkeypatch):
    monkeypatch.setattr("cevm.ingest.textfile.CHUNK_BYTES", 1000)
    rows = srf_rows(200)
    data = srf_text(rows).encode().replace(rows[150].encode(), rows[150].replace("36.0", "3\xe9.0", 1).encode("cp1252"))
    with pytest.raises(InputError, match="byte 0xe9 is not valid utf-8") as ei:
        read_log(write(tmp_path / "e.csv", data), profiles=profiles)
    assert (ei.value.line, ei.value.column) == (2 + 151, "gps_speed_kmh")


# ======================================================================================
# Time zone notation
# ======================================================================================
@pytest.mark.parametrize("first,other", [("Z", ""), ("", "Z"), ("+01:00", "")])
def test_mixed_zone_notation_is_an_error_with_line_and_column(tmp_path, first, other):
    prof = load_profile({"name": "iso", "detect": {"required_columns": ["timestamp_utc"]},
                         "time": {"columns": ["timestamp_utc"], "format": "ISO8601", "timezone": "Europe/Paris"},
                         "columns": {"wheel_speed_mps": {"source": "fms_wheel_speed_kmh", "unit": "km/h"}}})
    rows = srf_rows(10, zone=first)
    rows[6] = srf_rows(10, zone=other)[6]  # line 2 + 7
    f = write(tmp_path / "z.csv", srf_text(rows, meta=""))
    for engine in ("pyarrow", "pandas"):
        with pytest.raises(InputError, match="time zone notation mixed in one file") as ei:
            read_log(f, prof, engine=engine)
        assert (ei.value.line, ei.value.column) == (8, "timestamp_utc")


# ======================================================================================
# Vehicle ids and messages
# ======================================================================================
def test_vehicle_id_with_a_control_character_is_refused(tmp_path, profiles):
    raw = (DATA / "portal_dst.csv").read_bytes()
    lines = raw.split(b"\r\n")
    first = lines[1].split(b";")
    first[0] = b'"AB\r12"'
    lines[1] = b";".join(first)
    with pytest.raises(InputError, match=r"vehicle id 'AB\\r12' holds a control character") as ei:
        read_log(write(tmp_path / "cr.csv", b"\r\n".join(lines)), profiles=profiles)
    assert (ei.value.line, ei.value.column) == (2, "Registration")
    f = write(tmp_path / "m.csv", srf_text(srf_rows(3), meta="# logger=x\n# vehicle_id=EB\x1b[2J07\n"))
    with pytest.raises(InputError, match="metadata key 'vehicle_id' holds a control character") as ei:
        read_log(f, profiles=profiles)
    assert ei.value.line == 2


def test_file_name_with_a_line_break_cannot_forge_a_line(tmp_path, profiles):
    d = tmp_path / "d"
    d.mkdir()
    f = write(d / "a\ncevm: failed: other.csv", b"\x89PNG\x00\x00")
    with pytest.raises(InputError) as ei:
        read_log(f, profiles=profiles)
    msg = str(ei.value)
    assert "\n" not in msg and "a\\ncevm: failed: other.csv" in msg
    # the command prints one line for the failed file
    from typer.testing import CliRunner

    from cevm.cli import app

    res = CliRunner().invoke(app, ["ingest", str(d), "--store", str(tmp_path / "s.sqlite"), "-q", "--workers", "1"])
    failed = [ln for ln in res.output.splitlines() if ln.startswith("cevm: failed:")]
    assert len(failed) == 1 and "other.csv" in failed[0], res.output


# ======================================================================================
# Temperatures (affine units) and HVAC power
# ======================================================================================
def temp_profile(unit: str, **extra) -> dict:
    return {"name": "t", "detect": {"required_columns": ["t"]},
            "time": {"columns": ["t"], "format": "ISO8601"},
            "columns": {"wheel_speed_mps": {"source": "v", "unit": "km/h"},
                        "ambient_temp_c": {"source": "T", "unit": unit, **extra},
                        "hvac_power_w": {"source": "P", "unit": "kW"}}}


@pytest.mark.parametrize("unit,values,want_c", [
    ("degC", ["-12.5", "20", "35"], [-12.5, 20.0, 35.0]),
    ("K", ["260.65", "293.15", "308.15"], [-12.5, 20.0, 35.0]),
    ("degF", ["9.5", "68", "95"], [-12.5, 20.0, 35.0]),
])
def test_ambient_temperature_in_affine_units(tmp_path, unit, values, want_c):
    prof = load_profile(temp_profile(unit))
    body = "".join(f"2020-06-01T10:00:0{i}Z,36,{v},{p}\n"
                   for i, (v, p) in enumerate(zip(values, ["0", "2.5", "12"], strict=True)))
    [log] = read_log(write(tmp_path / "t.csv", "t,v,T,P\n" + body), prof)
    assert log.frame["ambient_temp_c"].tolist() == pytest.approx(want_c, abs=1e-9)
    assert log.frame["hvac_power_w"].tolist() == pytest.approx([0.0, 2500.0, 12000.0])


def test_absurd_temperature_is_repaired_and_shown_in_the_loggers_unit(tmp_path):
    prof = load_profile(temp_profile("K"))
    rows = [f"2020-06-01T10:00:{i:02d}Z,36,{'2048' if i == 3 else '293.15'},1" for i in range(10)]
    [log] = read_log(write(tmp_path / "t.csv", "t,v,T,P\n" + "\n".join(rows) + "\n"), prof)
    assert np.isnan(log.frame["ambient_temp_c"].iloc[3])
    assert any("ambient_temp_c" in r and "2048 K" in r and "line 5" in r for r in log.repairs), log.repairs


def test_negate_on_an_offset_scale_is_refused_and_wrong_dimension_named():
    with pytest.raises(InputError, match="negate does not apply"):
        load_profile(temp_profile("K", negate=True))
    with pytest.raises(InputError, match="unit 'kW' is a power, expected a temperature"):
        load_profile(temp_profile("kW"))


def test_shipped_profiles_map_the_ambient_temperature(tmp_path, profiles):
    assert {m.source for m in profiles["srf"].columns if m.canonical == "ambient_temp_c"} == {"fms_ambient_air_temp_c"}
    rows = [r + f",{t}" for r, t in zip(srf_rows(3), ["-3.25", "-3.21875", ""], strict=True)]
    f = write(tmp_path / "a.csv", srf_text(rows, header=SRF_HEADER + ",fms_ambient_air_temp_c"))
    [log] = read_log(f, profiles=profiles)
    ambient = log.frame["ambient_temp_c"]
    assert ambient.tolist()[:2] == [-3.25, -3.21875] and np.isnan(ambient.iloc[2])
    twizy = DATA / "twizy_excerpt.csv"
    [tw] = read_log(twizy, profiles=profiles)
    first = twizy.read_text().splitlines()
    col = first[0].split(",").index("Temperature")
    assert tw.frame["ambient_temp_c"].iloc[0] == float(first[1].split(",")[col])


def test_ingest_flags_set_the_limits_and_an_oversized_file_is_refused_unhashed(tmp_path, monkeypatch):
    from typer.testing import CliRunner

    import cevm.ingest.pipeline as pipeline
    from cevm.cli import app

    f = write(tmp_path / "r.csv", srf_text(srf_rows(50)))
    store = str(tmp_path / "s.sqlite")
    res = CliRunner().invoke(app, ["ingest", str(f), "--store", store, "-q", "--max-rows", "20"])
    assert res.exit_code == 1 and "more than 20 data rows" in res.output and ":23:" in res.output, res.output
    hashed = []
    monkeypatch.setattr(pipeline, "file_sha256", lambda p: hashed.append(p) or "0" * 64)
    res = CliRunner().invoke(app, ["ingest", str(f), "--store", store, "-q", "--max-file-mb", "0.001"])
    assert res.exit_code == 1 and "more than the limit of 0.001 MB per file (--max-file-mb)" in res.output, res.output
    assert hashed == []
    res = CliRunner().invoke(app, ["ingest", str(f), "--store", store, "-q", "--max-expansion", "0.5"])
    assert res.exit_code == 2  # below the allowed range: bad usage


@pytest.mark.parametrize("engine", ["pyarrow", "pandas"])
def test_mixed_zone_notation_across_blocks(tmp_path, monkeypatch, profiles, engine):
    monkeypatch.setattr(reading, "BLOCK_BYTES", 300)
    rows = srf_rows(40)
    rows[20:] = srf_rows(40, zone="")[20:]  # from line 2 + 21 on, no zone designator
    f = write(tmp_path / "z.csv", srf_text(rows, meta="# vehicle_id=A\n"))
    with pytest.raises(InputError, match="time zone notation mixed in one file") as ei:
        read_log(f, profiles=profiles, engine=engine)
    assert (ei.value.line, ei.value.column) == (3 + 20, "timestamp_utc")


def test_last_line_with_a_stray_carriage_return_is_an_input_error_not_a_crash(tmp_path, profiles):
    f = write(tmp_path / "cr.csv", srf_text([]).rstrip("\n") + "\n\r0")
    with pytest.raises(InputError):  # before: csv.Error from the truncated-line check
        read_log(f, profiles=profiles)


# ======================================================================================
# Times as numbers since the Unix epoch (CAN and OBD loggers)
# ======================================================================================
def epoch_profile(fmt: str, **time) -> dict:
    return {"name": "can", "detect": {"required_columns": ["ts"]},
            "time": {"columns": ["ts"], "format": fmt, **time},
            "columns": {"wheel_speed_mps": {"source": "v", "unit": "m/s"}}}


@pytest.mark.parametrize("engine", ["pyarrow", "pandas"])
@pytest.mark.parametrize("fmt, scale", [("unix_s", 1), ("unix_ms", 1000)])
def test_epoch_times_are_utc_whatever_the_engine(tmp_path, engine, fmt, scale):
    # 2021-03-28 00:59:59 .. 01:00:02 UTC crosses the start of British summer time: an
    # epoch time is UTC, so no zone (and no DST step) may touch it
    t0 = int(datetime(2021, 3, 28, 0, 59, 59, tzinfo=UTC).timestamp())
    times = [t0 + i * 0.5 for i in range(8)]
    cells = [f"{t * scale:.0f}" if scale > 1 else f"{t:.1f}" for t in times]
    f = write(tmp_path / "can.csv", "ts,v\n" + "".join(f"{c},{3 + i}\n" for i, c in enumerate(cells)))
    (log,) = read_log(f, load_profile(epoch_profile(fmt)), vehicle_id="CAN-1", engine=engine)
    np.testing.assert_allclose(log.frame["time_s"].to_numpy(), times, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(log.frame["wheel_speed_mps"].to_numpy(), 3.0 + np.arange(8))


def test_epoch_times_in_the_wrong_unit_are_named_with_line_and_column(tmp_path):
    ms = int(datetime(2021, 6, 1, tzinfo=UTC).timestamp()) * 1000  # milliseconds read as seconds: year 53,000
    f = write(tmp_path / "can.csv", "ts,v\n" + "".join(f"{ms + 1000 * i},3\n" for i in range(5)))
    for engine in ("pyarrow", "pandas"):
        with pytest.raises(InputError, match="unreadable or impossible time") as ei:
            read_log(f, load_profile(epoch_profile("unix_s")), vehicle_id="CAN-1", engine=engine)
        assert (ei.value.line, ei.value.column) == (2, "ts")


def test_an_epoch_profile_with_a_zone_is_refused():
    with pytest.raises(InputError, match="no zone applies") as ei:
        load_profile(epoch_profile("unix_ms", timezone="Europe/London"))
    assert "time.timezone" in str(ei.value)


# ======================================================================================
# Fuel by mass (PEMS, gravimetric flow meters)
# ======================================================================================
def pems_profile(**fuel) -> dict:
    return {"name": "pems", "detect": {"required_columns": ["ts"]},
            "time": {"columns": ["ts"], "format": "unix_s"},
            "columns": {"wheel_speed_mps": {"source": "v", "unit": "km/h"},
                        "flowmeter_fuel_lps": {"source": "fuel", **fuel}},
            "energy": [{"column": "flowmeter_fuel_lps", "kind": "rate", "priority": 1,
                        "resolution": 0.01, "resolution_unit": fuel.get("unit", "l/h")}]}


def test_fuel_by_mass_is_converted_to_litres_with_its_density(tmp_path):
    t0 = int(datetime(2021, 6, 1, 8, tzinfo=UTC).timestamp())
    grams_per_s = [0.5, 2.0, 8.35, 0.0]
    f = write(tmp_path / "pems.csv", "ts,v,fuel\n" + "".join(f"{t0 + i},50,{g}\n" for i, g in enumerate(grams_per_s)))
    prof = load_profile(pems_profile(unit="g/s", density_kg_per_l=0.835))
    (log,) = read_log(f, prof, vehicle_id="HGV-P")
    # 8.35 g/s of a 0.835 kg/l diesel is 10 ml/s
    np.testing.assert_allclose(log.frame["flowmeter_fuel_lps"].to_numpy(), np.array(grams_per_s) / 835.0, rtol=1e-12)
    # the resolution, given in the column's mass unit: 0.01 g/s -> 0.01 / 835 l/s
    (spec,) = prof.energy
    assert spec.resolution == pytest.approx(0.01 / 835.0, rel=1e-12)
    kg_h = load_profile(pems_profile(unit="kg/h", density_kg_per_l=0.82))
    assert kg_h.columns[1].factor == pytest.approx(1.0 / 3600.0 / 0.82, rel=1e-12)


@pytest.mark.parametrize("fuel, match", [
    ({"unit": "g/s"}, "give the fuel's density_kg_per_l"),
    ({"unit": "l/h", "density_kg_per_l": 0.835}, "applies to a fuel column given in a mass unit"),
    ({"unit": "g/s", "density_kg_per_l": 835.0}, "must be within 0.6-1.0 kg/l"),
])
def test_fuel_by_mass_needs_a_plausible_density_and_nothing_else_takes_one(fuel, match):
    with pytest.raises(InputError, match=match) as ei:
        load_profile(pems_profile(**fuel))
    assert "columns.flowmeter_fuel_lps.density_kg_per_l" in str(ei.value)
