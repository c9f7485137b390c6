"""The bounds and edges a hostile campaign found, kept as the project's own fault tests:
each failure a user or an attacker met (a traceback, a hang, a line of 64 kB, a
quadratic reader, a trip too long for a worker's memory) has a test named by what it
protects. Fast: small inputs, or the cheap part at the size that mattered (a header of
100,000 names). Speed and memory themselves are measured in ``benchmarks/``
(``bench_memory.py --cases "one trip 2.2M"``, ``bench_ingest.py``), never timed here."""

from __future__ import annotations

import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

import test_cli_failures as cli_failures
from cevm.errors import InputError

ROOT = Path(__file__).resolve().parents[1]
BUS = ROOT / "configs" / "vehicles" / "electric-bus.toml"
URBAN = ROOT / "configs" / "cycles" / "urban-bus.csv"
EB01 = ROOT / "sample_logs" / "srf" / "EB-01_2019-01-31.csv"


def run_main(capsys, monkeypatch, tmp_path, args) -> tuple[int, str]:
    """``cevm ARGS`` through :func:`cevm.cli.main` in this process: (exit code, stderr)."""
    return cli_failures.run_main(capsys, monkeypatch, args, stdout_path=tmp_path / "stdout.txt")


def one_error_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("cevm: error:") and "Traceback" not in err, err
    return lines[0]


# ------------------------------------------------------------------------------ bounds
def test_a_header_of_100000_names_is_planned_with_its_duplicates_told():
    """The column plan of a header 100,000 names wide (a count per name made it 100 s):
    the used columns found, the unused duplicates made unique by their index."""
    from cevm.ingest.profiles import load_profiles
    from cevm.ingest.reading.header import Header, _plan_columns

    prof = load_profiles()["srf"]
    names = ("timestamp_utc", "gps_speed_kmh", *(f"x{i % 50_000}" for i in range(100_000)))
    plan = _plan_columns(prof, Header(names, 5, 0, ()), Path("wide.csv"))
    assert plan.used == ["timestamp_utc", "gps_speed_kmh"]
    assert plan.unique_names[2] == "x0\x002" and plan.unique_names[50_002] == "x0\x0050002"
    assert len(set(plan.unique_names)) == len(names)


def test_a_used_column_named_twice_in_a_wide_header_is_refused():
    from cevm.ingest.profiles import load_profiles
    from cevm.ingest.reading.header import Header, _plan_columns

    prof = load_profiles()["srf"]
    names = ("timestamp_utc", *(f"x{i}" for i in range(100_000)), "timestamp_utc")
    with pytest.raises(InputError, match=r"\['timestamp_utc'\] appear more than once"):
        _plan_columns(prof, Header(names, 1, 0, ()), Path("wide.csv"))


class _Pieces:
    """A text stream (:class:`cevm.ingest.textfile.Utf8Stream`'s ``read``) that hands out
    ``data`` in pieces of ``size`` bytes."""

    def __init__(self, data: bytes, size: int) -> None:
        self.data, self.size, self.pos = data, size, 0

    def read(self) -> bytes:
        out = self.data[self.pos:self.pos + self.size]
        self.pos += len(out)
        return out


def test_the_lines_before_a_header_are_scanned_once_whatever_the_pieces(monkeypatch):
    """5,000 comment lines handed out 100 bytes at a time: the header, its line and the
    metadata found, and the bytes scanned at most the text's own plus one cut line per
    piece (the scan from the start with every piece was quadratic: 17 MB of comments
    took 5 s)."""
    from cevm.ingest.profiles import load_profiles
    from cevm.ingest.reading import header as hdr_mod

    comments = b"".join(b"# note%d=value %d\n" % (i, i) for i in range(5_000))
    text = b"# vehicle_id=EB-01\n" + comments + b"timestamp_utc,gps_speed_kmh\n2019-01-31T07:33:34Z,0\n"
    scanned = []
    scan = hdr_mod._HeaderScan.scan

    def counting(self, data):
        scanned.append(len(data))
        return scan(self, data)

    monkeypatch.setattr(hdr_mod._HeaderScan, "scan", counting)
    hdr, meta, rest = hdr_mod._read_header(_Pieces(text, 100), load_profiles()["srf"], Path("log.csv"))
    assert hdr.names == ("timestamp_utc", "gps_speed_kmh") and hdr.line == 5_002
    assert meta["vehicle_id"] == "EB-01" and meta["note4999"] == "value 4999"
    assert rest == b"2019-01-31T07:33:34Z,0\n"
    assert sum(scanned) <= len(text)  # each piece's whole lines once, a cut line carried


def test_a_header_field_over_the_csv_limit_is_one_line_with_its_line():
    from cevm.ingest.profiles import load_profiles
    from cevm.ingest.reading.header import _read_header

    text = b"# vehicle_id=EB-01\ntimestamp_utc,\"" + b"x" * 200_000 + b"\"\n1,2\n"
    with pytest.raises(InputError) as exc:
        _read_header(_Pieces(text, 1 << 16), load_profiles()["srf"], Path("log.csv"))
    assert exc.value.line == 2 and "unreadable header line" in str(exc.value)


def test_a_trip_over_max_trip_s_is_cut_at_whole_days_from_its_start():
    """Hand computed: 1 Hz rows over 200,000 s with a gap split at row 100,000; pieces
    start 86,400 s after their trip's start (rows 86,400 and 186,400), and a split that
    is there already stays what it is."""
    from cevm.ingest.cleaning.splitting import _SPLIT_REASONS, _split_long_trips

    t = np.arange(200_000, dtype=float)
    reason = np.zeros(t.size, dtype=np.int8)
    reason[100_000] = _SPLIT_REASONS.index("gap")
    cut = _split_long_trips(t, reason, 86_400.0)
    assert cut.tolist() == [86_400, 186_400]
    assert np.flatnonzero(reason).tolist() == [86_400, 100_000, 186_400]
    assert [_SPLIT_REASONS[r] for r in reason[[86_400, 100_000, 186_400]]] == ["max_duration", "gap", "max_duration"]


def test_a_log_that_never_stops_becomes_trips_of_a_day_and_says_so():
    """49 hours of driving at 10 m/s without a stop: trips of 24 h, 24 h and 1 h (each
    its first to its last sample: 86,399 s), split 'max_duration', and a stop note."""
    from cevm.ingest.cleaning import clean_log

    t0, n = 1.6e9, 2 * 86_400 + 3_600
    result = clean_log({"time_s": t0 + np.arange(n, dtype=float), "wheel_speed_mps": np.full(n, 10.0)})
    assert [tr.start_utc_s - t0 for tr in result.trips] == [0.0, 86_400.0, 172_800.0]
    assert [float(tr.time_s[-1]) for tr in result.trips] == [86_399.0, 86_399.0, 3_599.0]
    assert [tr.quality["split_before"] for tr in result.trips] == ["start", "max_duration", "max_duration"]
    assert result.quality["splits"]["max_duration"] == 2
    assert result.quality["stop_notes"] == [{"kind": "max_duration", "t0_s": t0 + 86_400, "splits": 2,
                                             "max_trip_s": 86_400.0}]


def test_the_repair_note_of_cut_trips_names_the_rule():
    from cevm.ingest.task import stop_note_warnings

    (line,) = stop_note_warnings([{"kind": "max_duration", "t0_s": 1.6e9, "splits": 2, "max_trip_s": 86_400.0}])
    assert line.startswith("trips: 2 cut(s) of trips longer than 24 h") and "2020-09-13 12:26:40 UTC" in line


def test_a_scenario_of_thousands_of_routes_loads_with_each_stops_routes(tmp_path):
    """2,000 vehicles, each with a route of two stops (validation scanned every route for
    every stop and made the vehicles' dict per route: 4,000 routes took 19 s): each
    stop's options are its own route, looked up by index."""
    import importlib.util

    from cevm.io.scenario import load_scenario

    spec = importlib.util.spec_from_file_location("bench_readers", ROOT / "benchmarks" / "bench_readers.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)  # the benchmark's scenario, the same file it times
    write_scenario = bench.write_scenario

    sc = load_scenario(write_scenario(tmp_path / "many.toml", 2_000))
    assert len(sc.routes) == 2_000 and sc.options("S1999b") == [1999] and sc.options("S0a") == [0]
    assert sc.vehicle_by_id["V7"].id == "V7" and sc.day_index("d1") == 0


def test_the_paper_scenarios_options_are_the_routes_through_each_stop_in_order():
    """By hand from configs/fleet/paper-case-study.toml: the shared stop LH1S1/R1S2 is on
    LH1 (route 0) and R1 (route 2), both allowed; LH1S2 on LH1 alone."""
    from cevm.io.scenario import load_scenario

    sc = load_scenario(ROOT / "configs" / "fleet" / "paper-case-study.toml")
    assert sc.options("LH1S1/R1S2") == [0, 2] and sc.options("LH2S1/R1S4") == [1, 2]
    assert sc.options("LH1S2") == [0] and sc.options("R1S5") == [2]
    assert sc.day_index("day 3") == 2 and sc.vehicle_by_id is sc.vehicle_by_id


def test_a_profile_mapping_a_source_twice_is_refused_in_one_pass():
    from cevm.ingest.profiles import ColumnMap, _check_column_set

    class Keys:
        def fail(self, message, key):
            return InputError("p.toml", f"{key}: {message}")

    maps = tuple(ColumnMap(canonical=f"c{i}", source=f"s{i % 30_000}", unit=None, factor=1.0) for i in range(40_000))
    with pytest.raises(InputError, match=r"source column\(s\) \['s0', 's1',"):
        _check_column_set(maps, Keys())


# --------------------------------------------------------------------------- the DSM
@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
def test_a_dsm_naming_a_fifo_is_refused_without_opening_it(tmp_path):
    from cevm.ingest.dsm import DsmSampler

    fifo = tmp_path / "dsm.tif"
    os.mkfifo(fifo)
    with pytest.raises(InputError, match=r"is a FIFO \(named pipe\), not a DSM"):
        DsmSampler.open(fifo)
    with pytest.raises(InputError, match="is a FIFO"):
        DsmSampler.open(fifo, allow_remote=True)  # GDAL never gets it either


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
def test_a_vrt_whose_source_is_a_fifo_is_refused(tmp_path):
    from cevm.ingest.dsm import DsmSampler

    os.mkfifo(tmp_path / "tile.tif")
    vrt = tmp_path / "dsm.vrt"
    vrt.write_text('<VRTDataset rasterXSize="2" rasterYSize="2"><VRTRasterBand dataType="Float32" band="1">'
                   '<SimpleSource><SourceFilename relativeToVRT="1">tile.tif</SourceFilename></SimpleSource>'
                   "</VRTRasterBand></VRTDataset>")
    with pytest.raises(InputError, match="is a FIFO"):
        DsmSampler.open(vrt)


def _raster(path: Path, crs, data: np.ndarray) -> Path:
    import rasterio
    from rasterio.transform import from_origin

    with rasterio.open(path, "w", driver="GTiff", width=data.shape[1], height=data.shape[0], count=1,
                       dtype="float32", crs=crs, transform=from_origin(480_000, 240_000, 2, 2)) as ds:
        ds.write(data.astype(np.float32), 1)
    return path


def test_a_dsm_in_a_crs_proj_cannot_transform_to_is_an_unusable_dsm(tmp_path):
    from rasterio.crs import CRS

    from cevm.ingest.dsm import DsmSampler

    local = _raster(tmp_path / "local.tif", CRS.from_wkt('LOCAL_CS["site grid",UNIT["metre",1]]'),
                    np.full((4, 4), 50.0))
    with pytest.raises(InputError) as exc:
        DsmSampler.open(local)
    assert str(exc.value).startswith(f"{local}: unusable DSM: PROJ cannot transform GPS positions")


def test_an_unusable_dsm_ends_ingest_with_one_line_and_exit_2(tmp_path, capsys, monkeypatch):
    from rasterio.crs import CRS

    local = _raster(tmp_path / "local.tif", CRS.from_wkt('LOCAL_CS["site grid",UNIT["metre",1]]'),
                    np.full((4, 4), 50.0))
    code, err = run_main(capsys, monkeypatch, tmp_path, ["ingest", EB01, "--store", tmp_path / "s.sqlite", "--dsm",
                                                         local, "-q", "--workers", "1"])
    assert code == 2 and "unusable DSM" in one_error_line(err) and "cevm bug" not in err


def test_infinite_dsm_pixels_are_no_height_without_a_warning(tmp_path):
    """A pixel of +-Inf is no data, as a nodata one: NaN where it counts, the finite
    pixels' bilinear value elsewhere, and no RuntimeWarning from the arithmetic."""
    from cevm.ingest.dsm import DsmSampler

    z = np.full((8, 8), 50.0)
    z[2, 2], z[5, 5] = np.inf, -np.inf
    path = _raster(tmp_path / "inf.tif", "EPSG:27700", z)
    # pixel centres: x = 480,000 + 2 (col + 0.5), y = 240,000 - 2 (row + 0.5)
    x = np.array([480_005.0, 480_011.0, 480_003.0])  # by (2, 2), by (5, 5), at finite pixels only
    y = np.array([239_995.0, 239_989.0, 239_999.0])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with DsmSampler.open(path) as s:
            got = s.sample_xy(x, y, "EPSG:27700")
    assert np.isnan(got[0]) and np.isnan(got[1]) and got[2] == 50.0


# ------------------------------------------------------------------- the other inputs
def test_a_cycle_header_field_over_the_csv_limit_is_one_line_with_file_and_line(tmp_path):
    from cevm.io.cycles import read_cycle_csv

    header = tmp_path / "header.csv"
    header.write_text("time_s,speed_kmh," + "x" * 200_000 + "\n0,1,2\n1,2,3\n")
    cell = tmp_path / "cell.csv"
    cell.write_text("time_s,speed_kmh\n0,1\n1,\"" + "x" * 200_000 + "\"\n2,3\n")
    for path, line in ((header, 1), (cell, 3)):
        with pytest.raises(InputError) as exc:
            read_cycle_csv(path)
        assert exc.value.line == line and "a field longer than 128 KiB" in str(exc.value)
        assert len(str(exc.value)) < 300


def test_an_unknown_detailed_key_is_refused_by_predict_as_by_simulate(tmp_path, capsys, monkeypatch):
    vehicle = tmp_path / "bus.toml"
    vehicle.write_text(BUS.read_text().replace("[detailed]\n", "[detailed]\nbogus_key = 3\n"))
    for command in ("predict", "simulate", "feasibility"):
        code, err = run_main(capsys, monkeypatch, tmp_path, [command, "-v", vehicle, "-c", URBAN])
        assert code == 2 and "unknown key 'bogus_key' in [detailed]" in one_error_line(err), command


def test_a_metadata_comment_of_2_mb_gives_a_short_error_line(tmp_path, capsys, monkeypatch):
    """The header a profile was looked for in, quoted whole, made a 64 kB line."""
    log = tmp_path / "big-meta.csv"
    log.write_bytes(b"# vehicle_id=EB-" + b"x" * 2_000_000 + b"\n" + EB01.read_bytes().split(b"\n", 1)[1])
    code, err = run_main(capsys, monkeypatch, tmp_path, ["ingest", log, "--store", tmp_path / "s.sqlite", "-q",
                                                         "--workers", "1"])
    failed = [ln for ln in err.splitlines() if ln.startswith("cevm: failed:")]
    assert code == 1 and len(failed) == 1 and len(failed[0]) < 600, err[:2000]


def test_a_log_vehicle_id_longer_than_a_vehicle_files_is_refused(tmp_path):
    """A 900 kB metadata comment was stored as the vehicle id, printed in every row."""
    from cevm.ingest.reading import read_log

    log = tmp_path / "long-id.csv"
    log.write_bytes(b"# vehicle_id=EB-" + b"x" * 900_000 + b"\n" + EB01.read_bytes().split(b"\n", 1)[1])
    with pytest.raises(InputError) as exc:
        read_log(log, "srf")
    assert "is 900,003 characters long, more than 80" in str(exc.value) and len(str(exc.value)) < 300


def test_infinite_values_are_counted_among_the_values_they_are_impossible_of(tmp_path):
    """Every latitude 'inf': the line said '6125 of 0 values are impossible' (the count
    of values left the infinite ones out)."""
    from cevm.ingest.reading import read_log

    lines = EB01.read_text().split("\n")
    header = lines[4].split(",")
    lat = header.index("gps_lat_deg")
    rows = [ln.split(",") for ln in lines[5:205] if ln]
    for r in rows:
        r[lat] = "inf"
    log = tmp_path / "lat-inf.csv"
    log.write_text("\n".join(lines[:5] + [",".join(r) for r in rows]) + "\n")
    with pytest.raises(InputError, match="200 of 200 values are impossible for lat_deg"):
        read_log(log, "srf")


def test_any_error_line_is_bounded_with_its_start_and_end_kept():
    exc = InputError("f.csv", "a" * 1_000_000 + " the end", line=3)
    text = str(exc)
    assert len(text) < 2_100 and text.startswith("f.csv:3: aaa") and text.endswith("the end")
    assert "characters left out" in text


# ------------------------------------------------------------------- option values
@pytest.mark.parametrize("args", [["predict", "-v", BUS, "-c", URBAN, "--cr0", "-1"],
                                  ["feasibility", "-v", BUS, "-c", URBAN, "--cr0", "nan"],
                                  ["predict", "-v", BUS, "-c", URBAN, "--cr0", "inf"]])
def test_cr0_out_of_range_is_one_line_and_exit_2(tmp_path, capsys, monkeypatch, args):
    code, err = run_main(capsys, monkeypatch, tmp_path, args)
    assert code == 2 and "--cr0" in one_error_line(err) and "at least 0" in err


@pytest.mark.parametrize("args, needle", [
    (["ingest", EB01, "--max-file-mb", "inf"], "--max-file-mb"),
    (["predict", "-v", BUS, "-c", URBAN, "--cr0", "abc"], "--cr0"),
    (["predict", "-v", BUS, "-c", URBAN, "--no-such-option"], "--no-such-option"),
    (["predict", "-c", URBAN], "--vehicle"),
])
def test_a_usage_error_is_one_line_and_exit_2(tmp_path, capsys, monkeypatch, args, needle):
    code, err = run_main(capsys, monkeypatch, tmp_path, args)
    assert code == 2 and needle in one_error_line(err)


# ------------------------------------------------------------------- the terminal
def test_a_non_ascii_id_on_an_ascii_stdout_is_escaped_not_a_traceback(tmp_path):
    vehicle = tmp_path / "bus.toml"
    vehicle.write_text('id = "Λεωφορείο-1"\n' + BUS.read_text())
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"), PYTHONIOENCODING="ascii")
    p = subprocess.run([sys.executable, "-m", "cevm", "predict", "-v", str(vehicle), "-c", str(URBAN), "-f", "csv"],
                       capture_output=True, env=env, timeout=120)
    assert p.returncode == 0 and b"Traceback" not in p.stderr, p.stderr.decode(errors="replace")
    assert b"\\u039b\\u03b5" in p.stdout  # the id's first letters, escaped


def test_a_warning_is_one_line_without_a_source_line():
    """In a process of its own (as the command and its pool's workers are: no host
    recording warnings), numpy's RuntimeWarning is one line naming its category."""
    code = ("import numpy as np\nfrom cevm.runtime import warnings_as_lines\nwarnings_as_lines()\n"
            "np.subtract(np.array([np.inf]), np.array([np.inf]))\n")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                       env=dict(os.environ, PYTHONPATH=str(ROOT / "src")))
    assert p.returncode == 0 and p.stderr == "cevm: warning: invalid value encountered in subtract (RuntimeWarning)\n"


def test_a_hosts_warning_recorder_still_gets_the_warnings():
    """Under a recorder (pytest's, catch_warnings(record=True)) the warnings go to it."""
    from cevm.runtime import warnings_as_lines

    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        warnings_as_lines()
        warnings.warn("from the library", RuntimeWarning, stacklevel=1)
    assert [str(w.message) for w in seen] == ["from the library"]
