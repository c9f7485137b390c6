"""Parallel and cluster ingest: same store as a serial run, faults retried without
duplicates, the DSM read over HTTP range requests, one task function everywhere."""

from __future__ import annotations

import json
import os
import sqlite3
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from pyproj import Transformer
from typer.testing import CliRunner

import faults
from cevm.cli import app
from cevm.executors import (
    DaskExecutor,
    ProcessExecutor,
    SerialExecutor,
    Task,
    make_executor,
    worker_cache,
)
from test_ingest import ORIGIN_BNG, plane, write_srf

runner = CliRunner()


def run(*args, env=None):
    res = runner.invoke(app, [str(a) for a in args], env=env)
    if res.exception is not None and not isinstance(res.exception, SystemExit):
        raise res.exception  # a crash, not an exit code (CliRunner reports both as 1)
    return res


# ------------------------------------------------------------------------- fixtures

DSM_RES_M = 2.0
DSM_X0, DSM_Y1 = ORIGIN_BNG[0] - 100.0, ORIGIN_BNG[1] + 1900.0  # top-left corner [m]
TILE_PX = 500  # 2 x 2 tiles of 1 km


def _tile_array(row: int, col: int) -> tuple[np.ndarray, float, float]:
    x0 = DSM_X0 + col * TILE_PX * DSM_RES_M
    y1 = DSM_Y1 - row * TILE_PX * DSM_RES_M
    xs = x0 + DSM_RES_M * (np.arange(TILE_PX) + 0.5)
    ys = y1 - DSM_RES_M * (np.arange(TILE_PX) + 0.5)
    return plane(xs[None, :], ys[:, None]).astype(np.float32), x0, y1


@pytest.fixture(scope="module")
def cog_dir(tmp_path_factory):
    """2 x 2 cloud-optimised GeoTIFF tiles of a tilted plane (EPSG:27700) and a VRT of
    them (sources relative to the VRT, so it works from a directory or a URL)."""
    import rasterio
    from rasterio.io import MemoryFile
    from rasterio.shutil import copy as rio_copy
    from rasterio.transform import from_origin

    d = tmp_path_factory.mktemp("cog")
    sources = []
    for row in range(2):
        for col in range(2):
            z, x0, y1 = _tile_array(row, col)
            name = f"tile_{row}_{col}.tif"
            profile = dict(driver="GTiff", width=TILE_PX, height=TILE_PX, count=1, dtype="float32",
                           crs="EPSG:27700", transform=from_origin(x0, y1, DSM_RES_M, DSM_RES_M), nodata=-9999.0)
            with MemoryFile() as mem:
                with mem.open(**profile) as ds:
                    ds.write(z, 1)
                with mem.open() as src:
                    rio_copy(src, d / name, driver="COG", blocksize=256, compress="DEFLATE")
            sources.append((name, row, col))
    with rasterio.open(d / "tile_0_0.tif") as ds:
        assert ds.block_shapes[0] == (256, 256)  # really a tiled COG
        wkt = ds.crs.to_wkt()
    n = 2 * TILE_PX
    simple = "".join(
        f"""<SimpleSource><SourceFilename relativeToVRT="1">{name}</SourceFilename><SourceBand>1</SourceBand>
        <SrcRect xOff="0" yOff="0" xSize="{TILE_PX}" ySize="{TILE_PX}"/>
        <DstRect xOff="{col * TILE_PX}" yOff="{row * TILE_PX}" xSize="{TILE_PX}" ySize="{TILE_PX}"/></SimpleSource>"""
        for name, row, col in sources
    )
    (d / "dsm.vrt").write_text(
        f"""<VRTDataset rasterXSize="{n}" rasterYSize="{n}"><SRS>{wkt}</SRS>
  <GeoTransform>{DSM_X0}, {DSM_RES_M}, 0, {DSM_Y1}, 0, {-DSM_RES_M}</GeoTransform>
  <VRTRasterBand dataType="Float32" band="1"><NoDataValue>-9999</NoDataValue>{simple}</VRTRasterBand>
</VRTDataset>"""
    )
    return d


# A static file server with HTTP range requests (206 Partial Content), which GDAL's
# /vsicurl/ needs and http.server.SimpleHTTPRequestHandler lacks. It runs in a child
# process, not a thread of the test: rasterio holds the GIL while GDAL opens a URL, so a
# server thread of this process could never answer (a deadlock). It logs each request
# as a JSON line: [method, file name, Range header].
RANGE_SERVER = r"""
import http.server, json, re, sys
from pathlib import Path
from urllib.parse import unquote, urlsplit

ROOT, LOG = Path(sys.argv[1]).resolve(), sys.argv[2]

class Handler(http.server.BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"
    timeout = 10  # a stuck client cannot hold a handler thread longer [s]

    def do_HEAD(self):
        self.serve(body=False)

    def do_GET(self):
        self.serve(body=True)

    def reply(self, status, headers, chunk=b""):
        self.send_response(status)
        for k, v in headers.items():
            self.send_header(k, v)
        self.send_header("Content-Length", str(len(chunk)))
        self.end_headers()
        self.wfile.write(chunk)

    def serve(self, body):
        path = (ROOT / unquote(urlsplit(self.path).path).lstrip("/")).resolve()
        rng = self.headers.get("Range")
        with open(LOG, "a") as f:
            f.write(json.dumps([self.command, path.name, rng]) + "\n")
        if ROOT not in path.parents or not path.is_file():
            return self.reply(404, {})
        data = path.read_bytes()
        size = len(data)
        if rng is None:
            status, chunk, headers = 200, data, {}
        else:
            m = re.fullmatch(r"bytes=(\d+)-(\d*)", rng.strip())
            if m is None or int(m[1]) >= size:
                return self.reply(416, {"Content-Range": f"bytes */{size}"})
            start, end = int(m[1]), min(int(m[2]) if m[2] else size - 1, size - 1)
            status, chunk, headers = 206, data[start:end + 1], {"Content-Range": f"bytes {start}-{end}/{size}"}
        headers["Accept-Ranges"] = "bytes"
        if body:
            self.reply(status, headers, chunk)
        else:
            self.send_response(status)
            for k, v in headers.items():
                self.send_header(k, v)
            self.send_header("Content-Length", str(len(chunk)))
            self.end_headers()

    def log_message(self, *args):
        pass

server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
server.daemon_threads = True
print(server.server_address[1], flush=True)
server.serve_forever()
"""


@pytest.fixture(scope="module")
def http_root(cog_dir, tmp_path_factory):
    """``(base URL, request log path)`` of an HTTP server on 127.0.0.1 (a free port)
    serving ``cog_dir``; stopped after the module's tests."""
    log = tmp_path_factory.mktemp("http") / "requests.jsonl"
    log.touch()
    proc = subprocess.Popen([sys.executable, "-c", RANGE_SERVER, str(cog_dir), str(log)],
                            stdout=subprocess.PIPE, text=True)
    try:
        port = int(proc.stdout.readline())
        yield f"http://127.0.0.1:{port}", log
    finally:
        proc.terminate()
        proc.wait(10)


@pytest.fixture
def logs(tmp_path):
    """Six srf days of three vehicles, a junk file, and a copy of one day at another
    path (its trips are duplicates: the first path in input order keeps them)."""
    d = tmp_path / "logs"
    (d / "b").mkdir(parents=True)
    for k, vid in enumerate(["EB-01", "EB-02", "EB-03"]):
        for day in range(2):
            write_srf(d / f"v{k}_d{day}.csv", vid, 1_557_820_800 + 86_400 * day + 600 * k, 10 * k + day, n=360)
    (d / "b" / "copy.csv").write_bytes((d / "v1_d0.csv").read_bytes())
    (d / "junk.csv").write_bytes(np.random.default_rng(5).bytes(1500))
    return d


def store_content(path: Path) -> dict:
    """Everything a store holds that does not depend on timing: all trips columns, the
    vector and profile blobs, and the files table without its timestamp."""
    con = sqlite3.connect(path)
    try:
        return {
            "files": con.execute(
                "SELECT path, sha256, size_bytes, mtime_s, profile, status, error, trips_sha256, n_trips, "
                "n_duplicates FROM files ORDER BY path").fetchall(),
            "trips": con.execute("SELECT * FROM trips ORDER BY trip_id").fetchall(),
            "blobs": con.execute("SELECT trip_id, vector, profile FROM trip_blobs ORDER BY trip_id").fetchall(),
        }
    finally:
        con.close()


def ingest_json(*args, env=None):
    res = run("ingest", *args, "--log-json", env=env)
    lines = [json.loads(line) for line in res.stdout.splitlines() if line.startswith("{")]
    return res, [e for e in lines if e["event"] == "file"], lines[-1] if lines else None


@pytest.fixture(scope="module")
def dask_cluster():
    pytest.importorskip("distributed")
    from cevm.executors import local_dask_cluster

    cluster = local_dask_cluster(2, 1, processes=True)  # processes: a task may kill its worker
    try:
        yield cluster
    finally:
        cluster.close()


# -------------------------------------------------------------------------- driver


@pytest.mark.slow
def test_driver_yields_in_input_order_passes_items_through_and_reports_errors():
    items = [Task("a", (2, 10)), "unchanged", Task("b", (3, 3)), Task("bad", (2, -1, 0)), Task("c", (5, 2))]
    for ex in (SerialExecutor(), ProcessExecutor(2)):
        with ex:
            res = list(ex.run(pow, items))
        assert [r.index for r in res] == [0, 1, 2, 3, 4]
        assert [r.value for r in res] == [1024, "unchanged", 27, None, 25]
        assert res[1].task is None and res[1].attempts == 0
        assert [r.attempts for r in res if r.task is not None] == [1, 1, 1, 1]
        assert res[3].error.startswith("ValueError") and not res[3].ok  # pow(2, -1, 0): not invertible


def test_process_pool_results_come_in_input_order_whatever_the_completion_order():
    # the first tasks sleep longest, so they finish last (when the two workers overlap;
    # no wall-time bound: a loaded machine stretches a pool's start to seconds, and a
    # timed assertion failed for that alone)
    items = [Task(f"t{i}", (0.2 - 0.04 * i,)) for i in range(5)]
    with ProcessExecutor(2) as ex:
        res = list(ex.run(time.sleep, items))
    assert [r.task.key for r in res] == [f"t{i}" for i in range(5)]
    assert all(r.ok for r in res)
    assert res[0].seconds >= 0.2


def test_pool_workers_run_single_threaded_blas():
    from cevm.executors import WORKER_ENV

    keys = sorted(WORKER_ENV)
    before = {k: os.environ.get(k) for k in keys}
    with ProcessExecutor(2) as ex:
        got = [r.value for r in ex.run(os.getenv, [Task(k, (k,)) for k in keys])]
    assert got == [before[k] or "1" for k in keys]  # a user's setting wins
    assert {k: os.environ.get(k) for k in keys} == before  # this process's environment is untouched


def test_worker_cache_makes_each_object_once_per_thread():
    made = []
    key = ("test", object())

    def factory():
        made.append(threading.get_ident())
        return len(made)

    assert worker_cache(key, factory) == worker_cache(key, factory) == 1
    other = []
    t = threading.Thread(target=lambda: other.append(worker_cache(key, factory)))
    t.start()
    t.join()
    assert other == [2] and len(made) == 2

    class Res:
        closed = False

        def close(self):
            self.closed = True

    from cevm.executors import WORKER_CACHE_SIZE

    objs = [worker_cache(("lru", k), Res) for k in range(WORKER_CACHE_SIZE)]
    assert worker_cache(("lru", 0), Res) is objs[0]  # used again: now the most recent
    worker_cache(("lru", "new"), Res)  # one too many: the least recently used goes
    assert [o.closed for o in objs] == [False, True] + [False] * (WORKER_CACHE_SIZE - 2)
    assert worker_cache(("lru", 1), Res) is not objs[1]  # made again


def test_process_file_opens_the_workers_dsm_once_not_per_file(tmp_path, cog_dir, monkeypatch):
    import cevm.ingest.task as ing

    opened = []
    real = ing.open_sampler
    monkeypatch.setattr(ing, "open_sampler", lambda dsm, *a: opened.append(dsm) or real(dsm, *a))
    dsm = f"{cog_dir}/./dsm.vrt"  # a name of its own: nothing cached by other tests
    opts = ing.IngestOptions(dsm=dsm)
    outs = []
    for k in range(3):
        write_srf(tmp_path / f"{k}.csv", "EB-01", 1_557_820_800 + 3600 * k, k, n=200)
        outs.append(ing.process_file(tmp_path / f"{k}.csv", opts))
    assert all(o.ok for o in outs)
    assert opened == [dsm]
    assert all(t.elevation_source == "dsm" for o in outs for t in o.trips)


def test_make_executor_and_the_cli_options(logs, tmp_path):
    assert isinstance(make_executor(1), SerialExecutor)
    ex = make_executor(3)
    assert isinstance(ex, ProcessExecutor) and ex.slots == 3
    default = make_executor()
    assert default.slots == (os.cpu_count() or 1)
    with pytest.raises(ValueError):
        make_executor(0)
    with pytest.raises(ValueError):
        make_executor(2, "tcp://127.0.0.1:1")
    store = tmp_path / "s.sqlite"
    assert run("ingest", logs, "--store", store, "--workers", "0").exit_code == 2
    res = run("ingest", logs, "--store", store, "--workers", "2", "--scheduler", "tcp://127.0.0.1:1")
    assert res.exit_code == 2 and "not both" in res.output


def test_the_default_number_of_workers_follows_the_work():
    from cevm.executors import POOL_START_S, workers_for

    # a pool pays for its start once the work saved exceeds it: work (1 - 1 / (n e)) > start
    assert workers_for(0.5, 16, 2, start_s=1.0, efficiency=1.0) == 1  # 0.25 s saved < 1 s
    assert workers_for(1.9, 16, 2, start_s=1.0, efficiency=1.0) == 1
    assert workers_for(2.1, 16, 2, start_s=1.0, efficiency=1.0) == 2
    assert workers_for(2.1, 16, 8, start_s=1.0, efficiency=1.0) == 8  # more cores, more saved
    assert workers_for(1.1, 16, 8, start_s=1.0, efficiency=1.0) == 1  # 1 s + 1.1 s / 8: still slower
    assert workers_for(1000.0, 3, 8) == 3  # never more workers than tasks, nor than cores
    assert workers_for(1000.0, 1, 8) == workers_for(1000.0, 50, 1) == 1
    ex = make_executor()
    if ex.slots > 1:  # a 1-core machine gets the serial executor whatever the work
        small = ex.sized_for(POOL_START_S, 16)
        assert isinstance(small, SerialExecutor)
        assert ex.sized_for(1000.0, 2) is ex and ex.slots == 2
    explicit = make_executor(2)
    assert explicit.sized_for(0.001, 2) is explicit  # a number the user gave is kept


def test_estimated_work_follows_the_uncompressed_size(tmp_path):
    import gzip

    from cevm.ingest.pipeline import INGEST_FILE_S, INGEST_S_PER_BYTE, estimated_work_s

    text = "".join(f"2019-05-14T08:00:{i % 60:02d}Z,{i},{i * 0.5}\n" for i in range(20_000)).encode()
    plain, packed = tmp_path / "a.csv", tmp_path / "a.csv.gz"
    plain.write_bytes(text)
    packed.write_bytes(gzip.compress(text))
    want = INGEST_FILE_S + INGEST_S_PER_BYTE * len(text)
    assert estimated_work_s(plain, plain.stat().st_size) == pytest.approx(want, rel=1e-12)
    assert packed.stat().st_size < len(text) / 3  # the trailer is read, not the compressed size
    assert estimated_work_s(packed, packed.stat().st_size) == pytest.approx(want, rel=1e-12)


@pytest.mark.slow
def test_a_small_batch_runs_in_this_process_and_a_big_one_on_a_pool(logs, tmp_path, monkeypatch):
    """The default executor starts no pool for the 7 small files (their estimated work
    is far below a pool's start), does for the same files when each is thought to take
    seconds, and stores the same either way; files stored already at their size and
    modification time are not counted as work."""
    import cevm.ingest.pipeline as pipeline
    from cevm.ingest import IngestOptions, ingest
    from cevm.store import TripStore

    stores = {}
    for name, s_per_byte in (("small", pipeline.INGEST_S_PER_BYTE), ("big", 1e-4)):
        monkeypatch.setattr(pipeline, "INGEST_S_PER_BYTE", s_per_byte)
        ex = ProcessExecutor(2, auto=True)
        with ex, TripStore(tmp_path / f"{name}.sqlite") as st:
            report = ingest([logs], st, IngestOptions(), executor=ex)
            started = ex._pool is not None
            assert pipeline._work_to_do(sorted(logs.rglob("*.csv")), st, IngestOptions()) == \
                {str(logs / "junk.csv"): pytest.approx(pipeline.estimated_work_s(logs / "junk.csv", 1500))}
        assert started == (name == "big"), name
        assert report.count("ingested") == 7 and report.failed == 1  # (the copy: ingested, its trip a duplicate)
        stores[name] = store_content(tmp_path / f"{name}.sqlite")
    assert stores["small"]["trips"] == stores["big"]["trips"] and stores["small"]["blobs"] == stores["big"]["blobs"]


# --------------------------------------------------------------- same store content


def test_serial_process_pool_and_dask_cluster_store_exactly_the_same(logs, tmp_path, cog_dir, dask_cluster):
    dsm = cog_dir / "dsm.vrt"
    results = {}
    for name, opt in [("serial", ["--workers", "1"]), ("pool", ["--workers", "2"]),
                      ("dask", ["--scheduler", dask_cluster.scheduler_address])]:
        store = tmp_path / f"{name}.sqlite"
        res, files, summary = ingest_json(logs, "--store", store, "--dsm", dsm, *opt)
        assert res.exit_code == 1, res.output  # the junk file fails, in every run
        results[name] = (store_content(store), [(Path(f["path"]).name, f["status"], f["trips"], f["duplicates"],
                                                 f["samples"], f["error"]) for f in files], summary)
    serial_content, serial_files, serial_summary = results["serial"]
    # the content is non-trivial: 6 trips on the DSM, one failure, one copy's duplicate
    assert len(serial_content["trips"]) == 6 and len(serial_content["blobs"]) == 6
    assert [f[1] for f in serial_files].count("failed") == 1
    by_name = {f[0]: f for f in serial_files}
    assert by_name["copy.csv"][:4] == ("copy.csv", "ingested", 1, 0)  # '.../b/copy.csv' sorts first: it owns
    assert by_name["v1_d0.csv"][:4] == ("v1_d0.csv", "ingested", 1, 1)  # the trip; the original's is a duplicate
    for name in ("pool", "dask"):
        content, files, summary = results[name]
        assert content == serial_content, name
        assert files == serial_files, name  # same reports, same (input) order of on_file calls
        for k in ("files", "ingested", "unchanged", "failed", "trips", "samples", "rows"):
            assert summary[k] == serial_summary[k], (name, k)


def test_a_tls_scheduler_without_client_certificates_is_one_clear_error(logs, tmp_path):
    dask = pytest.importorskip("dask")
    pytest.importorskip("distributed")
    with dask.config.set({"distributed.comm.tls.ca-file": None, "distributed.comm.tls.client.cert": None}):
        res = run("ingest", logs, "--store", tmp_path / "s.sqlite", "--scheduler", "tls://127.0.0.1:1")
    assert res.exit_code == 2
    assert "tls:// scheduler needs this client's certificates" in res.output
    assert "DASK_DISTRIBUTED__COMM__TLS__CLIENT__CERT" in res.output and "Traceback" not in res.output


def _weigh(table: dict, key: str) -> float:
    return table[key] * len(table)


def test_dask_sends_a_recurring_argument_once_and_again_after_a_restart(dask_cluster):
    """The same object in every task travels as one shared future (made again when
    the cluster restarted); the tasks' own arguments go by value; results are exact."""
    from distributed import Client

    table = {f"k{i}": float(i) for i in range(500)}
    with Client(dask_cluster.scheduler_address, set_as_default=False) as client:
        ex = DaskExecutor(client=client)
        tasks = [Task(f"k{i}", (table, f"k{i}")) for i in range(40)]
        got = [r.value for r in ex.run(_weigh, tasks)]
        assert got == [500.0 * i for i in range(40)]
        assert len(ex._shared) == 1 and next(iter(ex._shared.values()))[0] is table
        client.restart()
        got = [r.value for r in ex.run(_weigh, tasks[:5])]
        assert got == [500.0 * i for i in range(5)] and len(ex._shared) == 1
        ex.close()
        assert ex._shared == {}


# ----------------------------------------------------------- predictions on workers


ROOT = Path(__file__).resolve().parents[1]


def _sweep_case():
    from cevm.cli.values import parse_values
    from cevm.core.sweep import PredictionSet, Source
    from cevm.io import load_vehicles
    from cevm_samplegen.cycles import MicroTripSpec, micro_trip_cycle

    vehicles = load_vehicles([ROOT / "configs/vehicles/electric-bus.toml", ROOT / "configs/vehicles/diesel-hgv.toml"])
    pset = PredictionSet.build(vehicles, payload_kg=parse_values("0:10000:2500", "--payload-kg"))
    cycles = [micro_trip_cycle(MicroTripSpec(n_trips=3 + k % 4), seed=k, name=f"r{k}") for k in range(14)]
    return pset, [Source.from_cycle(c) for c in cycles]


def _sweep_arrays(blocks):
    from cevm.core.sweep.evaluate import BLOCK_ARRAYS

    return [(b.source_index, b.source.name, *(getattr(b, f).tobytes() for f in BLOCK_ARRAYS)) for b in blocks]


def _check_sweep_on(executor, monkeypatch):
    import cevm.core.sweep.driver as fp

    monkeypatch.setattr(fp, "SWEEP_BATCH_CELLS", 12)  # several batches of a few sources
    pset, sources = _sweep_case()
    want = _sweep_arrays(fp.sweep(sources, pset))
    assert len({len(r) for r in want}) == 1 and [r[0] for r in want] == list(range(len(sources)))
    pset, sources = _sweep_case()  # fresh sources: nothing cached by the serial sweep
    blocks = list(fp.sweep(sources, pset, executor=executor))
    assert [b.source for b in blocks] == sources  # the caller's sources, in order
    assert _sweep_arrays(blocks) == want  # bit for bit: the same batches
    assert len(list(fp._batches(sources, pset, True))) > 3


def test_sweep_on_worker_processes_equals_the_serial_sweep_bit_for_bit(monkeypatch):
    with ProcessExecutor(2) as ex:
        _check_sweep_on(ex, monkeypatch)


def test_sweep_on_a_dask_cluster_equals_the_serial_sweep_bit_for_bit(monkeypatch, dask_cluster):
    with DaskExecutor(dask_cluster.scheduler_address) as ex:
        _check_sweep_on(ex, monkeypatch)


@pytest.mark.slow
def test_predict_cli_with_workers_writes_what_a_serial_run_writes(monkeypatch):
    import cevm.core.sweep.driver as fp

    monkeypatch.setattr(fp, "SWEEP_BATCH_CELLS", 1)
    args = ["predict", "-v", ROOT / "configs/vehicles/electric-bus.toml", "-v",
            ROOT / "configs/vehicles/diesel-hgv.toml",
            "-c", ROOT / "configs/cycles/urban-bus.csv", "-c", ROOT / "configs/cycles/regional-delivery.csv",
            "-p", "0:10000:2500", "-f", "csv"]
    serial = run(*args)
    assert serial.exit_code == 0, serial.output
    pool = run(*args, "--workers", "2")
    assert pool.exit_code == 0, pool.output
    assert pool.stdout == serial.stdout and serial.stdout.count("\n") == 1 + 2 * 2 * 5
    both = run(*args, "--workers", "2", "--scheduler", "tcp://127.0.0.1:1")
    assert both.exit_code == 2 and "not both" in both.output


# ------------------------------------------------------------------------- faults


@pytest.mark.slow
def test_a_worker_killed_mid_file_is_retried_and_a_file_that_kills_twice_fails(logs, tmp_path, monkeypatch):
    import cevm.ingest.pipeline as pipeline

    serial = tmp_path / "serial.sqlite"
    run("ingest", logs, "--store", serial, "--workers", "1", "-q")
    (logs / "v0_d1.csv.kill-0").touch()  # kills one worker once: retried elsewhere
    (logs / "v2_d0.csv.kill-0").touch()
    for k in range(3):  # kills every worker that tries it: failed after two deaths
        (logs / f"v1_d1.csv.kill-{k}").touch()
    monkeypatch.setattr(pipeline, "process_file", faults.process_file_or_die)
    store = tmp_path / "pool.sqlite"
    # the seven small files are one group of tasks (cevm.executors.TASK_S): a death in it
    # is charged to none of them, and each of its files then runs alone
    res, files, summary = ingest_json(logs, "--store", store, "--workers", "2")
    assert res.exit_code == 1
    left = faults.markers(logs, "*.kill-*")
    # once, once, and twice alone (three times if its first death was in the group or
    # beside another task: that one is charged to no file)
    assert left in (["v1_d1.csv.kill-2"], [])
    assert faults.markers(logs, "v0_d1.csv.killed-*") and faults.markers(logs, "v2_d0.csv.killed-*")
    status = {Path(f["path"]).name: f for f in files}
    assert status["v0_d1.csv"]["status"] == status["v2_d0.csv"]["status"] == "ingested"
    assert status["v1_d1.csv"]["status"] == "failed" and "died 2 times" in status["v1_d1.csv"]["error"]
    assert summary["failed"] == 2  # v1_d1 and the junk file
    # nothing stored twice or half: the store is the serial one but for the failed file
    got, want = store_content(store), store_content(serial)
    assert got["trips"] == [t for t in want["trips"] if not t[2].endswith("v1_d1.csv")]
    assert {b[0] for b in got["blobs"]} == {t[0] for t in got["trips"]}
    # the next run (no fault) ingests it and leaves the rest alone
    res, files, summary = ingest_json(logs, "--store", store, "--workers", "2")
    assert (summary["ingested"], summary["unchanged"]) == (1, 6)
    assert store_content(store)["trips"] == want["trips"]


def _sleepers(marker_dir: str, *specs: tuple[str, float], cost_s: float | None = None) -> list[Task]:
    return [Task(name, (marker_dir, name, seconds), cost_s=cost_s) for name, seconds in specs]


def test_a_task_running_beside_a_killer_is_not_blamed(tmp_path):
    """Two tasks running when the pool breaks: both are suspects; each is re-run alone,
    so the innocent one succeeds and the killer fails after two deaths of its own."""
    crash = str(tmp_path)
    for k in range(3):
        Path(crash, f"{k}.killer").touch()
    with ProcessExecutor(2) as ex:
        res = list(ex.run(faults.sleep_or_die, _sleepers(crash, ("innocent", 0.3), ("killer", 0.0), ("later", 0.0))))
    left = [p for p in os.listdir(crash) if not p.startswith("done-")]
    assert res[0].ok and res[2].ok
    assert not res[1].ok and "died" in res[1].error
    # the killer was charged two deaths alone; a first death beside the innocent task
    # (if it had started by then) was charged to neither, and cost one more worker
    assert ex.restarts in (2, 3) and len(left) == 3 - ex.restarts
    assert "died 2 times" in res[1].error


def test_a_task_that_killed_once_beside_a_killer_is_not_failed(tmp_path):
    """A task that kills its worker once (then runs clean) started beside one that
    kills every worker: it succeeds on its retry, and only the killer fails, charged
    with two deaths."""
    crash = str(tmp_path)
    Path(crash, "0.once").touch()
    for k in range(3):
        Path(crash, f"{k}.killer").touch()
    with ProcessExecutor(2) as ex:
        res = list(ex.run(faults.sleep_or_die, _sleepers(crash, ("once", 0.0), ("killer", 0.0))))
    assert res[0].ok, res[0].error
    assert not res[1].ok and "died 2 times" in res[1].error


def _count_submissions(ex, monkeypatch) -> list[int]:
    """The number of tasks in each submission ``ex`` makes (a group counts its tasks)."""
    sizes = []
    real = ex._submit

    def submit(fn, entry):
        sizes.append(len(entry.items))
        return real(fn, entry)

    monkeypatch.setattr(ex, "_submit", submit)
    return sizes


def test_tasks_with_a_cost_are_grouped_up_to_the_task_size_and_come_back_one_by_one(tmp_path, monkeypatch):
    crash = str(tmp_path)
    items = _sleepers(crash, *[(f"t{i}", 0.001 * i) for i in range(12)], cost_s=0.125)
    items[5:5] = ["unchanged"]  # a pass-through item amid a group
    items.append(Task("big", (crash, "big", 0.0), cost_s=0.5))  # worth a task of its own
    items.append(Task("no cost", (crash, "no cost", 0.0)))  # never grouped
    with ProcessExecutor(2, task_s=0.5) as ex:
        sizes = _count_submissions(ex, monkeypatch)
        res = list(ex.run(faults.sleep_or_die, items))
    assert sizes == [4, 4, 4, 1, 1]  # 0.5 s of work each, and the two that go alone
    assert [r.index for r in res] == list(range(len(items)))
    assert [r.value for r in res] == [0.001 * i for i in range(5)] + ["unchanged"] + \
        [0.001 * i for i in range(5, 12)] + [0.0, 0.0]
    assert all(r.ok and r.attempts == (0 if r.task is None else 1) for r in res)
    assert res[3].seconds == pytest.approx(0.003, abs=0.05)  # each task's own time, not its group's
    # without costs (or on a serial executor) nothing is grouped
    with ProcessExecutor(2, task_s=0.0) as ex:
        sizes = _count_submissions(ex, monkeypatch)
        list(ex.run(faults.sleep_or_die, items))
    assert sizes == [1] * 14


def test_a_task_that_raises_in_a_group_fails_alone_with_its_own_error(tmp_path, monkeypatch):
    items = [Task(f"t{i}", (2, i), cost_s=0.01) for i in range(4)] + [Task("bad", (2, -1, 0), cost_s=0.01)]
    items += [Task(f"u{i}", (3, i), cost_s=0.01) for i in range(3)]
    with ProcessExecutor(2, task_s=1.0) as ex:
        sizes = _count_submissions(ex, monkeypatch)
        res = list(ex.run(pow, items))
    assert sizes == [8, 1]  # one group; then the task that raised, alone
    assert [r.value for r in res] == [1, 2, 4, 8, None, 1, 3, 9]
    assert res[4].error.startswith("ValueError") and res[4].attempts == 1  # as if it had run alone
    assert all(r.ok for k, r in enumerate(res) if k != 4)


def test_a_group_whose_worker_dies_is_split_and_only_the_killer_fails(tmp_path, monkeypatch):
    crash = str(tmp_path)
    for k in range(3):
        Path(crash, f"{k}.killer").touch()
    Path(crash, "0.t1").touch()  # kills once: fine when run again
    items = _sleepers(crash, ("t0", 0.0), ("t1", 0.0), ("killer", 0.0), ("t3", 0.0), cost_s=0.01)
    with ProcessExecutor(2, task_s=1.0) as ex:
        sizes = _count_submissions(ex, monkeypatch)
        res = list(ex.run(faults.sleep_or_die, items))
    assert [r.ok for r in res] == [True, True, False, True]
    assert "died 2 times" in res[2].error and res[2].attempts == 2
    assert [r.attempts for r in res if r.ok] == [1, 1, 1]  # the group's runs are charged to none
    # the group died (at t1), then each task alone: t0, t1, the killer twice, t3
    assert sizes == [4, 1, 1, 1, 1, 1] and ex.restarts == 3
    assert sorted(p.partition("-")[2].partition("-")[2] for p in os.listdir(crash) if p.startswith("done-")) \
        == ["0.killer", "0.t1", "1.killer"]


def test_the_window_counts_work_not_items(tmp_path):
    """Cheap tasks are taken ahead by their share of a task's work: 40 tasks of a
    quarter task each fill a window of 10 tasks; without a cost, 10 fill it."""
    pulled = []

    def items(n, cost_s):
        for i in range(n):
            pulled.append(i)
            yield Task(str(i), (1.0, 1), cost_s=cost_s)

    with ProcessExecutor(2, task_s=0.5) as ex:
        for cost_s, ahead in ((0.125, 40), (None, 10)):
            pulled.clear()
            gen = ex.run(pow, items(200, cost_s), window=10)
            next(gen)
            assert len(pulled) in (ahead, ahead + 1), cost_s  # (+1: the one pulled after the first yield)
            gen.close()


def test_dask_reschedules_a_killed_workers_file_without_duplicates(logs, tmp_path, dask_cluster, monkeypatch):
    import cevm.ingest.pipeline as pipeline

    serial = tmp_path / "serial.sqlite"
    run("ingest", logs, "--store", serial, "--workers", "1", "-q")
    (logs / "v2_d1.csv.kill-0").touch()
    monkeypatch.setattr(pipeline, "process_file", faults.process_file_or_die)
    store = tmp_path / "dask.sqlite"
    res, files, summary = ingest_json(logs, "--store", store, "--scheduler", dask_cluster.scheduler_address)
    assert res.exit_code == 1 and summary["failed"] == 1  # the junk file only
    assert faults.markers(logs, "*.kill-*") == [] and faults.markers(logs, "v2_d1.csv.killed-0-*")  # it did die
    assert store_content(store) == store_content(serial)


def test_dask_splits_a_group_that_kills_its_workers_and_fails_only_the_killer(tmp_path, dask_cluster):
    crash = str(tmp_path)
    for k in range(5):
        Path(crash, f"{k}.killer").touch()
    items = _sleepers(crash, ("t0", 0.0), ("killer", 0.0), ("t2", 0.0), cost_s=0.01)
    with DaskExecutor(dask_cluster.scheduler_address, task_s=1.0) as ex:
        res = list(ex.run(faults.sleep_or_die, items))
    assert [r.ok for r in res] == [True, False, True]
    assert "KilledWorker" in res[1].error
    # the group died on two workers (allowed-failures = 1), then the killer alone on two more
    assert len([p for p in os.listdir(crash) if p.startswith("done-")]) == 4


# ---------------------------------------------------------------------- DSM over HTTP


@pytest.mark.slow
def test_dsm_over_http_range_requests_gives_the_local_elevations(cog_dir, http_root, logs, tmp_path):
    from cevm.ingest.dsm import DsmSampler

    base, log = http_root
    rng = np.random.default_rng(3)
    # points over the 4 tiles, some within a pixel of the seams, some outside the DSM
    x = np.concatenate([rng.uniform(DSM_X0 - 50, DSM_X0 + 2050, 400), DSM_X0 + 1000 + rng.uniform(-2, 2, 50)])
    y = np.concatenate([rng.uniform(DSM_Y1 - 2050, DSM_Y1 + 50, 400), DSM_Y1 - 1000 + rng.uniform(-2, 2, 50)])
    lon, lat = Transformer.from_crs("EPSG:27700", "EPSG:4326", always_xy=True).transform(x, y)
    with DsmSampler.open(cog_dir) as local:
        want = local.sample(lon, lat)
    inside = (x > DSM_X0 + 1) & (x < DSM_X0 + 1999) & (y < DSM_Y1 - 1) & (y > DSM_Y1 - 1999)
    assert np.isfinite(want[inside]).all() and np.isnan(want[~inside & ((x < DSM_X0) | (y > DSM_Y1))]).all()
    assert want[inside] == pytest.approx(plane(x, y)[inside], abs=1e-3)  # a plane is bilinear-exact
    for url in (f"{base}/dsm.vrt", f"/vsicurl/{base}/dsm.vrt"):
        with DsmSampler.open(url, allow_remote=True) as remote:
            got = remote.sample(lon, lat)
        np.testing.assert_array_equal(got, want)
    with DsmSampler.open(f"{base}/tile_1_1.tif", allow_remote=True) as one:  # a single COG by URL
        got = one.sample(lon, lat)
    in11 = (x > DSM_X0 + 1001) & (x < DSM_X0 + 1999) & (y < DSM_Y1 - 1001) & (y > DSM_Y1 - 1999)
    np.testing.assert_array_equal(got[in11], want[in11])
    requests = [json.loads(line) for line in log.read_text().splitlines()]
    tif_gets = [r for r in requests if r[0] == "GET" and r[1].endswith(".tif")]
    assert tif_gets and all(r[2] is not None for r in tif_gets)  # window by window, never whole files

    # an ingest whose workers read the DSM over HTTP stores what the local DSM gives
    local_store, http_store = tmp_path / "local.sqlite", tmp_path / "http.sqlite"
    run("ingest", logs, "--store", local_store, "--dsm", cog_dir / "dsm.vrt", "--workers", "1", "-q")
    res = run("ingest", logs, "--store", http_store, "--dsm", f"{base}/dsm.vrt", "--workers", "2", "-q",
              "--allow-remote-dsm")
    assert res.exit_code == 1, res.output  # the junk file
    got, want = store_content(http_store), store_content(local_store)
    assert got == want and len(want["trips"]) == 6
    assert all(t[9] == "dsm" for t in want["trips"])  # elevation_source: the DSM everywhere
