"""Benchmark of peak memory of cevm on every kind of input: `cevm ingest` on one file (a large
valid log and hostile ones), and the inputs that are not logs (vehicle files, scenarios,
manifests, cycle files, stored blobs).

    python benchmarks/bench_memory.py [--rows N] [--bomb-gib G] [--keep DIR] [--cases NAME|KIND...]

Each log case runs `cevm ingest FILE --workers 1 -q` (the command as a user runs it, with
its default limits and allocator settings) in a fresh subprocess, and prints that
process's peak resident memory (``VmHWM`` of ``/proc/self/status``: not ``ru_maxrss``,
which Linux carries over an ``exec`` from the parent, so that a child reports at least
the benchmark's own size), the exit code, the wall time and the first line of its output,
and whether the peak meets the goal. The cases:

- ``2M rows``: a valid srf log of ``--rows`` rows (default 2,000,000, about 191 MB: one
  long-haul truck's working day of the benchmark fleet, 15 mapped columns, repeated on
  consecutive days, as one file), ingested with the sample DSM (and ``--max-rows`` at
  least ``--rows``; ``--cases big`` runs this case alone). The peak of each stage of the
  ingest of this file (read, cleaning, the DSM samples, elevation, the trip evidence,
  the vectors, the stored profiles, the store) is printed too, from the process's
  high-water mark reset before each stage (``/proc/self/clear_refs``, Linux).
- ``wide``: the sample's bus day with every srf column (20, a hybrid's fuel columns
  added), at the most rows the default values bound allows it (ingested) and at 2.5 M
  rows (refused by that bound, at the row past it).
- ``portal 2.5M``, ``portal 1.2M``: the sample portal log's first day (``;``, decimal
  commas, cp1252, local times) repeated on consecutive days from 1 November 2019 to 2.5
  million rows (the default row limit: 12 M trip samples on the 1 s grid, a row every
  5 s; refused by the samples bound, ``--max-samples``) and to 1.2 million (5.8 M
  samples, under it: ingested).
- ``DSM one strip``, ``DSM 16k tiles``: a sample srf log with a DSM of one 40,000 x
  40,000 float32 deflate strip (sparse: kilobytes on disk, 6.4 GB decoded), or of
  16,384-pixel tiles (1.07 GB each decoded): refused from the raster's header.
- ``one trip 2.2M``: a log of 2.2 million rows at 1 Hz (12 srf columns, under the default
  row and values bounds) that forms one trip: a battery bus driving laps of a 2 km circle
  over the sample DSM for 25 days without a stop, a gap or a charge (the cleaning, the
  elevation, the vector and the stored profile of one trip of 2.2 M samples); the peak
  of each stage is printed as for the large log.
- ``gzip bomb``: about 10 MB of gzip expanding to ``--bomb-gib`` GiB (default 3) of
  valid, identical srf rows: it must fail fast with a clear message.
- ``no line breaks``: 415 MB of text without a line break: must fail from its first
  bytes.
- ``all NUL``: a 2 GB sparse file of NUL bytes: must fail without being read whole.

The inputs that are not logs, each as the command a user runs, at its
default limit or refused before the work:

- ``vehicle``: a vehicle file of 1 MiB (its bound) of small keys, the most work for the
  TOML parser per byte (``cevm predict -v``), and ``/dev/zero`` as a vehicle file;
- ``scenario``: the same for a fleet scenario (``cevm fleet plan``);
- ``manifest``: a manifest at its row bound (1,000,000 window rows, none matching a trip,
  so each is reported) given to ``cevm trips set-mass``, and ``/dev/zero``;
- ``cycle``: a cycle file at its sample bound, predicted (two vehicles, two masses,
  ``--range``) and simulated (``--out`` and ``--plot``), and the files of one command at
  their bound (``cevm feasibility``);
- ``blob``: a stored trip whose profile has a valid checksum but is a zip bomb (12
  million samples, 576 MB inflated; 4 MB stored), read by ``cevm store check`` and
  ``cevm simulate --trip``.

Baseline in the same run: the peak of a Python process that has imported cevm's ingest
pipeline and done nothing else (``import only``), and the size of the 2M-row file
itself. The default limits are printed first. The goal: under 500 MB per
worker for any input on the default settings. ``--cases`` takes case names or kinds
(``logs``, ``vehicle``, ``scenario``, ``manifest``, ``cycle``, ``blob``; ``big``: the
large log alone).
"""

from __future__ import annotations

import argparse
import gzip
import json
import os
import re
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

GOAL_MB = 500.0


# ------------------------------------------------------------------------ the cases
def make_large_srf(out: Path, rows: int, workdir: Path) -> Path:
    """A valid srf log of about ``rows`` rows: one long-haul truck's working day of the
    benchmark fleet (cevm_samplegen), repeated on consecutive days (dates shifted), as
    one file; the DSM that covers it is ``workdir/sample/dsm``."""
    from cevm_samplegen import fleet_for_benchmark, generate_sample_logs

    sample = workdir / "sample"
    generate_sample_logs(sample, small=False)
    fleet_for_benchmark(4, 1, workdir / "day", full_days=True, dsm_dir=sample / "dsm")
    day = (workdir / "day" / "srf" / "BM-004_2019-05-13.csv").read_bytes()
    lines = day.split(b"\n")
    head = [ln for ln in lines if ln.startswith(b"#")]
    header = lines[len(head)]
    body = [ln for ln in lines[len(head) + 1:] if ln]
    assert all(ln[:10] == b"2019-05-13" for ln in body), "a day that crosses midnight"
    tails = [ln[10:] for ln in body]
    import datetime as dt

    return _write_days(out, head, header, tails, dt.date(2019, 5, 13), rows)


def _write_days(out: Path, head: list[bytes], header: bytes, tails: list[bytes], d0, rows: int) -> Path:
    """``rows`` data rows of one day's rows (``tails``: each row after its date) repeated
    on consecutive days from ``d0``, under the comment lines and the header."""
    import datetime as dt

    with open(out, "wb") as fh:
        fh.write(b"\n".join(head + [header]) + b"\n")
        k = n = 0
        while n < rows:
            date = (d0 + dt.timedelta(days=k)).isoformat().encode()
            take = tails[: rows - n]
            fh.write(b"".join(date + t + b"\n" for t in take))
            n += len(take)
            k += 1
    return out


def make_wide_srf(out: Path, rows: int, sample: Path) -> Path:
    """A valid srf log of ``rows`` rows with every srf column (20, time included): the
    sample's bus day with a hybrid's fuel columns added (fuel counter, fuel rate, flow
    meter, gross weight), repeated on consecutive days. At the default limits the values
    bound (rows x columns) decides how many rows it may hold."""
    import datetime as dt

    lines = (sample / "srf" / "EB-01_2019-01-31.csv").read_bytes().split(b"\n")
    head = [ln for ln in lines if ln.startswith(b"#")]
    header = lines[len(head)] + b",fms_total_fuel_used_l,fms_fuel_rate_lph,flowmeter_fuel_lph,fms_gross_weight_kg"
    body = [ln for ln in lines[len(head) + 1:] if ln]
    assert all(ln[:10] == b"2019-01-31" for ln in body), "a day that crosses midnight"
    tails = [ln[10:] + b",1000.0,1.50,1.45,12000" for ln in body]
    return _write_days(out, head, header, tails, dt.date(2019, 1, 31), rows)


def make_portal(out: Path, rows: int, sample: Path) -> Path:
    """A portal export of ``rows`` rows: the sample portal log's first day repeated on
    consecutive days from 2019-11-01 (no clock change), in the export's own bytes."""
    import datetime as dt

    src = next((sample / "portal").glob("*.csv")).read_bytes().split(b"\n")
    header, body = src[0], [ln for ln in src[1:] if ln.strip()]
    first = body[0].split(b";")[1][:10]
    day = [ln for ln in body if ln.split(b";")[1][:10] == first]
    with open(out, "wb") as fh:
        fh.write(header + b"\n")
        n, d = 0, dt.date(2019, 11, 1)
        while n < rows:
            stamp = d.strftime("%d/%m/%Y").encode()
            chunk = day[: rows - n]
            fh.write(b"\n".join(ln.replace(first, stamp, 1) for ln in chunk) + b"\n")
            n += len(chunk)
            d += dt.timedelta(days=1)
    return out


def make_long_trip(out: Path, rows: int) -> Path:
    """A valid srf log of ``rows`` rows at 1 Hz that forms one trip: a battery bus driving
    laps of a 2 km circle over the sample DSM without a stop of 30 min, a gap of 5 min or a
    charge (25 days for 2.2 M rows), with GPS, wheel speed, battery and energy counter."""
    import numpy as np
    import pyarrow as pa
    import pyarrow.csv as pacsv

    t = np.arange(rows, dtype=np.float64)
    speed = 9.0 + 7.0 * np.sin(t / 97.0) + 2.0 * np.sin(t / 13.0)  # 0-18 m/s, never long at rest
    speed = np.clip(speed, 0.0, None)
    dist = np.cumsum(speed)
    r = 2000.0
    ang = dist / r
    lat0, lon0 = 52.04, -0.76
    lat = lat0 + np.degrees(r * np.sin(ang) / 6_371_000.0)
    lon = lon0 + np.degrees(r * (1 - np.cos(ang)) / (6_371_000.0 * np.cos(np.radians(lat0))))
    power_w = 20_000.0 + 1_500.0 * speed * np.maximum(np.gradient(speed), 0) * 12.0 + 150.0 * speed
    energy_kwh = 48_000.0 + np.round(np.cumsum(power_w) / 3.6e6, 1)
    volt = np.full(rows, 680.0)
    amp = np.round(power_w / volt, 1)
    soc = np.round(95.0 - 60.0 * (t / rows), 1)  # a pack swapped out of sight: only drifts
    stamps = np.datetime64("2019-05-13T00:00:00", "ms") + (t * 1000).astype("timedelta64[ms]")
    ts = np.char.add(np.datetime_as_string(stamps, unit="ms"), "Z")
    table = pa.table({
        "timestamp_utc": pa.array(ts), "gps_lat_deg": np.round(lat, 6), "gps_lon_deg": np.round(lon, 6),
        "gps_alt_m": np.round(100.0 + 5 * np.sin(ang), 1), "gps_speed_kmh": np.round(speed * 3.6, 1),
        "gps_hdop": np.full(rows, 0.9), "fms_wheel_speed_kmh": np.round(speed * 3.6, 1),
        "fms_battery_soc_pct": soc, "fms_battery_voltage_v": volt, "fms_battery_current_a": amp,
        "fms_total_energy_used_kwh": energy_kwh, "fms_ambient_air_temp_c": np.full(rows, 12.5),
    })
    with open(out, "wb") as fh:
        fh.write(b"# vehicle_id=LT-01\n")
        pacsv.write_csv(table, fh, pacsv.WriteOptions(quoting_style="none"))
    return out


def make_huge_block_dsm(out: Path, **layout) -> Path:
    """A 40,000 x 40,000 float32 GeoTIFF (over the sample's area) with ``layout``'s
    blocks, written sparse (no block written: kilobytes on disk)."""
    import rasterio
    from rasterio.transform import from_origin

    with rasterio.open(out, "w", driver="GTiff", width=40_000, height=40_000, count=1, dtype="float32",
                       crs="EPSG:27700", transform=from_origin(470_000, 250_000, 2.0, 2.0), compress="deflate",
                       sparse_ok=True, **layout):
        pass
    return out


def make_bomb(out: Path, gib: float) -> Path:
    """gzip of ``gib`` GiB of one valid srf row repeated (a zip bomb of valid data)."""
    row = b"2020-06-01T10:00:00.000Z,51.5,-0.1,36.0,36.0,100.0\n"
    block = row * ((8 << 20) // len(row))
    member = gzip.compress(block, compresslevel=9)
    with open(out, "wb") as fh:
        fh.write(gzip.compress(b"# vehicle_id=BOMB-1\ntimestamp_utc,gps_lat_deg,gps_lon_deg,gps_speed_kmh,"
                               b"fms_wheel_speed_kmh,fms_total_energy_used_kwh\n"))
        for _ in range(int(gib * (1 << 30) / len(block))):
            fh.write(member)  # concatenated gzip members decompress to the concatenation
    return out


def make_lineless(out: Path, mb: int = 415) -> Path:
    chunk = b"timestamp_utc,abc,def,ghi,jkl;" * (1 << 15)
    with open(out, "wb") as fh:
        for _ in range(mb * (1 << 20) // len(chunk)):
            fh.write(chunk)
    return out


def make_nul(out: Path, gb: float = 2.0) -> Path:
    with open(out, "wb") as fh:
        fh.truncate(int(gb * 1e9))  # sparse: reads as NUL bytes
    return out


# ------------------------------------------------------------------------ the child
def _hwm_mb() -> float:
    with open("/proc/self/status") as fh:
        return int(re.search(r"VmHWM:\s+(\d+)", fh.read()).group(1)) / 1024


def _peak_mb() -> float:
    """This process's peak resident memory [MB]: VmHWM (since its exec, or since the last
    reset), else ru_maxrss (which may include the parent's peak before the exec)."""
    try:
        return _hwm_mb()
    except (OSError, AttributeError):
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _reset_hwm() -> bool:
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
        return True
    except OSError:
        return False


def child(argv: list[str], stages: bool) -> None:
    """Run ``cevm ARGV`` in this process; print a JSON line with the peak."""
    peaks: dict[str, float] = {}
    if stages and _reset_hwm():
        import contextlib

        import cevm.ingest.task as task
        from cevm.store import TripStore

        @contextlib.contextmanager
        def stage(name):
            # a reset lowers the high-water mark: keep the peak so far first
            peaks["_overall"] = max(peaks.get("_overall", 0.0), _hwm_mb())
            _reset_hwm()
            try:
                yield
            finally:
                peaks[name] = max(peaks.get(name, 0.0), _hwm_mb())

        def wrap(owner, name, label):
            fn = getattr(owner, name)

            def timed(*a, **k):
                with stage(label):
                    return fn(*a, **k)

            setattr(owner, name, timed)

        class Stream(task.CleanStream):  # the cleaning: made, then a batch of trips at a time
            def __init__(self, *a, **k):
                with stage("clean"):
                    super().__init__(*a, **k)

            def batches(self, *a, **k):
                made = super().batches(*a, **k)
                while True:
                    with stage("clean"):
                        batch = next(made, None)
                    if batch is None:
                        return
                    yield batch

        from cevm.ingest.dsm import DsmSampler

        task.CleanStream = Stream
        wrap(task, "read_log", "read")
        wrap(DsmSampler, "sample", "dsm")
        wrap(task, "trip_elevation", "elevation")
        wrap(task, "batch_evidence", "evidence")
        wrap(task, "drive_cycle_vector", "vector")
        wrap(task, "encode_profiles", "profile")
        wrap(TripStore, "replace_file_trips", "store")
    from cevm.cli import main as cevm_main

    sys.argv = ["cevm", *argv]
    code = 0
    t0 = time.perf_counter()
    try:
        cevm_main()  # applies the allocator settings, as the command does
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else 1
    dt = time.perf_counter() - t0
    rss = max(_peak_mb(), peaks.pop("_overall", 0.0))
    sys.stdout.flush()
    print("\n@@" + json.dumps({"peak_mb": rss, "code": code, "seconds": dt, "stages": peaks}))


def run_case(name: str, path: Path | None, store: Path, extra: list[str] = (), stages: bool = False,
             timeout_s: float = 600.0) -> dict:
    """``cevm ingest PATH --store STORE --workers 1 -q EXTRA`` (None: the import-only
    baseline) in a fresh process: its peak, exit code, wall time and first line."""
    if path is None:
        return run_command(name, None, timeout_s=timeout_s)
    return run_command(name, ["ingest", str(path), "--store", str(store), "--workers", "1", "-q", *extra],
                       stages=stages, timeout_s=timeout_s)


def run_command(name: str, args: list[str] | None, stages: bool = False, timeout_s: float = 600.0) -> dict:
    """``cevm ARGS`` (None: the import-only baseline) in a fresh process: its peak
    resident memory, exit code, wall time and first line of output."""
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"), OMP_NUM_THREADS="1", GDAL_NUM_THREADS="1")
    if args is None:
        cmd = [sys.executable, __file__, "--child", "--import-only"]
    else:
        cmd = [sys.executable, __file__, "--child", *(["--stages"] if stages else []), "--", *map(str, args)]
    t0 = time.perf_counter()
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=timeout_s)
    except subprocess.TimeoutExpired:
        return dict(name=name, wall=time.perf_counter() - t0, peak_mb=float("nan"), code=-1, stages={},
                    message=f"TIMEOUT: killed after {timeout_s:.0f} s")
    wall = time.perf_counter() - t0
    m = re.search(r"^@@(\{.*\})$", p.stdout, re.M)
    if not m:
        tail = (p.stdout + p.stderr).strip().splitlines()[-1:] or [""]
        return dict(name=name, wall=wall, peak_mb=float("nan"), code=p.returncode, stages={},
                    message=f"the process died (exit {p.returncode}): {tail[0]}")
    res = json.loads(m.group(1))
    text = [ln for ln in (p.stderr + p.stdout[: m.start()]).splitlines() if ln.strip()]  # failures first
    res.update(name=name, wall=wall, message=text[0] if text else "")
    return res


def print_case(c: dict) -> None:
    msg = c["message"] if len(c["message"]) < 130 else c["message"][:127] + "..."
    goal = "met" if c["peak_mb"] < GOAL_MB else "NOT met"
    print(f"{c['name']:20s} {c['peak_mb']:8.0f} {goal:>8s} {c['code']:4d} {c['wall']:7.2f}  {msg}", flush=True)
    if c["stages"]:
        print("  peak during each stage [MB]: " + ", ".join(f"{k} {v:.0f}" for k, v in c["stages"].items()),
              flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=2_000_000)
    ap.add_argument("--bomb-gib", type=float, default=3.0)
    ap.add_argument("--keep", type=Path, default=None, help="make the inputs in this directory and keep them")
    ap.add_argument("--cases", nargs="*", default=None, help="run only these cases (by name)")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--stages", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--import-only", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("rest", nargs="*", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child and args.import_only:  # the baseline: what the ingest's imports cost
        import cevm.cli
        import cevm.ingest.pipeline  # noqa: F401

        print("\n@@" + json.dumps({"peak_mb": _peak_mb(), "code": 0, "seconds": 0, "stages": {}}))
        return
    if args.child:
        child(args.rest, args.stages)
        return

    from cevm.ingest.textfile import ReadLimits

    lim = ReadLimits()
    wide_rows = lim.row_limit(20)  # the wide log's 20 columns at the default values bound
    print(f"default limits (cevm ingest): --max-rows {lim.max_rows:,} and at most {lim.max_values:,} values (rows x "
          f"columns read: {lim.row_limit(16):,} rows of the 16-column log, {wide_rows:,} of the 20-column one), "
          f"--max-file-mb {lim.max_file_mb:g}, "
          f"--max-expansion {lim.max_expansion:g}; goal: peak < {GOAL_MB:.0f} MB per worker")
    print(other_limits())
    with tempfile.TemporaryDirectory(prefix="cevm-mem-") as tmp:
        work = args.keep or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        big_name = f"{args.rows / 1e6:g}M rows"
        todo = log_cases(args, work, lim, wide_rows, big_name) + other_cases(work)
        cases = []
        print(f"{'case':20s} {'peak MB':>8s} {'< ' + format(GOAL_MB, '.0f'):>8s} {'exit':>4s} {'wall s':>7s}  output")
        for name, kind, run in todo:
            if args.cases and not ({name, kind} & set(args.cases)) and not (name == big_name and "big" in args.cases):
                continue
            cases.append(run())
            print_case(cases[-1])
        worst = max(c["peak_mb"] for c in cases)
        bad = [c["name"] for c in cases if not c["peak_mb"] < GOAL_MB]
        print(f"worst peak {worst:.0f} MB: goal < {GOAL_MB:.0f} MB per worker "
              f"{'met' if not bad else 'NOT met (' + ', '.join(bad) + ')'}")


def log_cases(args, work: Path, lim, wide_rows: int, big_name: str) -> list:
    """The logs' cases (kind ``logs``): (name, kind, run), their inputs made when first
    run (``--keep``: made once, reused)."""
    made: dict[str, Path] = {}

    def made_logs() -> dict[str, Path]:
        if made:
            return made
        t0 = time.perf_counter()
        big, dsm = work / f"big-{args.rows}.csv", work / "sample" / "dsm"
        if not (args.keep and big.exists() and dsm.is_dir()):
            make_large_srf(big, args.rows, work)
        wide, wide_over = work / f"wide-{wide_rows}.csv", work / "wide-2500000.csv"
        for path, n in ((wide, wide_rows), (wide_over, 2_500_000)):
            if not (args.keep and path.exists()):
                make_wide_srf(path, n, work / "sample")
        portal, portal_half = work / "portal-2500000.csv", work / "portal-1200000.csv"
        for path, n in ((portal, 2_500_000), (portal_half, 1_200_000)):
            if not (args.keep and path.exists()):
                make_portal(path, n, work / "sample")
        strip_dsm, tiles_dsm = work / "dsm-strip.tif", work / "dsm-16k.tif"
        make_huge_block_dsm(strip_dsm, tiled=False, blockysize=40_000)
        make_huge_block_dsm(tiles_dsm, tiled=True, blockxsize=16_384, blockysize=16_384)
        bus_day = work / "sample" / "srf" / "EB-01_2019-01-31.csv"
        bomb, lineless, nul = work / "bomb.csv.gz", work / "lineless.csv", work / "nul.csv"
        if not (args.keep and bomb.exists()):
            make_bomb(bomb, args.bomb_gib)
        if not (args.keep and lineless.exists()):
            make_lineless(lineless)
        if not (args.keep and nul.exists()):
            make_nul(nul)
        print(f"log inputs made in {time.perf_counter() - t0:.1f} s: {big.name} {big.stat().st_size / 1e6:.0f} MB "
              f"({args.rows:,} rows), {bomb.name} {bomb.stat().st_size / 1e6:.1f} MB -> {args.bomb_gib:g} GiB, "
              f"{lineless.name} {lineless.stat().st_size / 1e6:.0f} MB, {nul.name} {nul.stat().st_size / 1e9:.1f} GB",
              flush=True)
        made.update(big=big, dsm=dsm, wide=wide, wide_over=wide_over, portal=portal, portal_half=portal_half,
                    strip_dsm=strip_dsm,
                    tiles_dsm=tiles_dsm, bus_day=bus_day, bomb=bomb, lineless=lineless, nul=nul)
        return made

    def ingest(k: int, name: str, key: str | None, extra=lambda m: [], stages: bool = False):
        def run():
            if key is None:
                return run_case(name, None, work)
            m = made_logs()
            store = work / f"s{k}.sqlite"
            for p in store.parent.glob(store.name + "*"):
                p.unlink()
            return run_case(name, m[key], store, extra(m), stages=stages)
        return name, "logs", run

    def dsm(key: str = "dsm"):
        return lambda m: ["--dsm", str(m[key])]

    def long_trip():  # made alone: ``--cases "one trip 2.2M"`` does not make the others
        m = {"dsm": ROOT / "sample_logs" / "dsm", "long": work / "long-trip-2200000.csv"}
        if not (args.keep and m["long"].exists()):
            make_long_trip(m["long"], 2_200_000)
        store = work / "s11.sqlite"
        for p in store.parent.glob(store.name + "*"):
            p.unlink()
        return run_case("one trip 2.2M", m["long"], store, ["--dsm", str(m["dsm"])], stages=True)

    return [ingest(0, "import only", None),
            ingest(1, big_name, "big", lambda m: ["--dsm", str(m["dsm"]), "--max-rows", str(max(args.rows,
                                                                                                 lim.max_rows))],
                   stages=True),
            ingest(2, f"wide {wide_rows / 1e6:g}M", "wide", dsm()),
            ingest(3, "wide 2.5M", "wide_over", dsm()),
            ingest(4, "portal 2.5M", "portal", dsm()),
            ingest(5, "portal 1.2M", "portal_half", dsm()),
            ingest(6, "DSM one strip", "bus_day", dsm("strip_dsm")),
            ingest(7, "DSM 16k tiles", "bus_day", dsm("tiles_dsm")),
            ingest(8, "gzip bomb", "bomb"), ingest(9, "no line breaks", "lineless"), ingest(10, "all NUL", "nul"),
            ("one trip 2.2M", "logs", long_trip)]


# ------------------------------------------------------------ inputs that are not logs
def other_limits() -> str:
    from cevm.io.cycles import MAX_COMMAND_CYCLE_SAMPLES, MAX_CYCLE_SAMPLES
    from cevm.io.inputs import MAX_TOML_BYTES
    from cevm.io.manifest import MAX_MANIFEST_BYTES, MAX_MANIFEST_ROWS
    from cevm.store.codec import MAX_PROFILE_SAMPLES

    return (f"default limits (other inputs): TOML {MAX_TOML_BYTES / 2**20:g} MiB; manifest {MAX_MANIFEST_ROWS:,} rows "
            f"and {MAX_MANIFEST_BYTES / 2**20:g} MiB; cycle file {MAX_CYCLE_SAMPLES:,} samples, "
            f"{MAX_COMMAND_CYCLE_SAMPLES:,} over a command's files; stored profile "
            f"{MAX_PROFILE_SAMPLES:,} samples (and its trip's own count)")


def make_toml_of_keys(out: Path, nbytes: int, head: str = "") -> Path:
    """A TOML file of just under ``nbytes``: ``head``, then a table of many small keys
    (the most work and memory for the parser per byte)."""
    lines, size = [head, "[padding]"], len(head) + 10
    k = 0
    while size < nbytes - 64:
        line = f"k{k} = [1.5, 2]"
        lines.append(line)
        size += len(line) + 1
        k += 1
    out.write_text("\n".join(lines) + "\n")
    return out


def make_manifest(out: Path, rows: int, vehicle: str) -> Path:
    """A manifest of ``rows`` window rows of ``vehicle`` (one an hour, none of them
    matching a stored trip: every row is a problem, reported as it is read)."""
    import datetime as dt

    t0 = dt.datetime(2030, 1, 1, tzinfo=dt.UTC)
    with open(out, "w") as fh:
        fh.write("vehicle_id,start,end,gross_kg\n")
        for i in range(rows):
            a = t0 + dt.timedelta(hours=i)
            fh.write(f"{vehicle},{a:%Y-%m-%dT%H:%M:%SZ},{a + dt.timedelta(minutes=30):%Y-%m-%dT%H:%M:%SZ},30000\n")
    return out


def make_cycle(out: Path, samples: int) -> Path:
    """A plausible cycle file of ``samples`` 1 Hz samples (time_s, speed_kmh): a smooth
    stop-and-go, written a million rows at a time."""
    import numpy as np

    with open(out, "w") as fh:
        fh.write("time_s,speed_kmh\n")
        for a in range(0, samples, 1_000_000):
            t = np.arange(a, min(samples, a + 1_000_000))
            v = 40.0 * (1.0 - np.cos(2 * np.pi * t / 600.0)) / 2.0
            fh.write("".join(f"{ti},{vi:.2f}\n" for ti, vi in zip(t.tolist(), v.tolist(), strict=True)))
    return out


def make_blob_store(work: Path) -> tuple[Path, str]:
    """A store of one sample log's trips, the first trip's profile replaced by a bomb with a
    valid checksum: its header and streams say 12 million samples (576 MB once inflated),
    and the trip's row says so too."""
    import sqlite3
    import struct
    import zlib

    import numpy as np

    from cevm.store.codec import PROFILE_DTYPES

    store = work / "blob.sqlite"
    for p in store.parent.glob(store.name + "*"):
        p.unlink()
    log = ROOT / "sample_logs" / "srf" / "EB-01_2019-01-31.csv"
    subprocess.run([sys.executable, "-m", "cevm", "ingest", str(log), "--store", str(store), "--workers", "1", "-q"],
                   check=True, capture_output=True, env=dict(os.environ, PYTHONPATH=str(ROOT / "src")))
    n = 12_000_000
    entries, payloads = [], []
    for name, dtype in PROFILE_DTYPES.items():
        z, left, chunk = zlib.compressobj(9), n * np.dtype(dtype).itemsize, bytes(8 << 20)
        parts = []
        while left > 0:
            parts.append(z.compress(chunk[:min(left, len(chunk))]))
            left -= len(chunk)
        parts.append(z.flush())
        entries.append([name, dtype, sum(map(len, parts))])
        payloads.append(b"".join(parts))
    header = json.dumps({"n": n, "codec": "shuffle+zlib", "arrays": entries}).encode()
    bomb = b"".join([b"CEVMPRF1", struct.pack("<I", len(header)), header, *payloads])
    con = sqlite3.connect(store)
    with con:
        (trip,) = con.execute("SELECT trip_id FROM trips ORDER BY trip_id LIMIT 1").fetchone()
        con.execute("UPDATE trip_blobs SET profile = ?, profile_crc32 = ? WHERE trip_id = ?",
                    (bomb, zlib.crc32(bomb), trip))
        con.execute("UPDATE trips SET n_samples = ? WHERE trip_id = ?", (n, trip))
    con.close()
    return store, trip


def other_cases(work: Path) -> list:
    """The cases of the inputs that are not logs (kinds ``vehicle``, ``scenario``,
    ``manifest``, ``cycle``, ``blob``): each at its default limit, or refused before the
    work (a device, a bomb), as the command a user runs."""
    from cevm.io.cycles import MAX_COMMAND_CYCLE_SAMPLES, MAX_CYCLE_SAMPLES
    from cevm.io.inputs import MAX_TOML_BYTES
    from cevm.io.manifest import MAX_MANIFEST_ROWS

    bus = ROOT / "configs" / "vehicles" / "electric-bus.toml"
    hgv = ROOT / "configs" / "vehicles" / "diesel-hgv.toml"
    urban = ROOT / "configs" / "cycles" / "urban-bus.csv"
    scenario = ROOT / "configs" / "fleet" / "paper-case-study.toml"
    state: dict = {}

    def cycle():
        if "cycle" not in state:
            state["cycle"] = make_cycle(work / "cycle.csv", MAX_CYCLE_SAMPLES)
        return state["cycle"]

    def blob_store():
        if "blob" not in state:
            state["blob"] = make_blob_store(work)
        return state["blob"]

    def case(name, kind, args):
        return name, kind, lambda: run_command(name, args() if callable(args) else args)

    return [
        case("vehicle 1 MiB", "vehicle", lambda: ["predict", "-v", make_toml_of_keys(
            work / "vehicle.toml", MAX_TOML_BYTES, bus.read_text()), "-c", urban]),
        case("vehicle /dev/zero", "vehicle", ["predict", "-v", "/dev/zero", "-c", urban]),
        case("scenario 1 MiB", "scenario", lambda: ["fleet", "plan", make_toml_of_keys(
            work / "scenario.toml", MAX_TOML_BYTES, scenario.read_text())]),
        case("scenario /dev/zero", "scenario", ["fleet", "plan", "/dev/zero"]),
        case(f"manifest {MAX_MANIFEST_ROWS / 1e6:g}M", "manifest", lambda: [
            "trips", "set-mass", "--manifest", make_manifest(work / "manifest.csv", MAX_MANIFEST_ROWS, "EB-01"),
            "--store", blob_store()[0]]),
        case("manifest /dev/zero", "manifest", lambda: ["trips", "set-mass", "--manifest", "/dev/zero", "--store",
                                                        blob_store()[0]]),
        case(f"cycle {MAX_CYCLE_SAMPLES / 1e6:g}M predict", "cycle", lambda: [
            "predict", "-v", bus, "-v", hgv, "-c", cycle(), "--range", "-p", "0,1000", "-f", "csv"]),
        case(f"cycle {MAX_CYCLE_SAMPLES / 1e6:g}M simulate", "cycle", lambda: [
            "simulate", "-v", bus, "-c", cycle(), "--out", work / "sim.csv", "--plot", work / "sim.png"]),
        case(f"cycles {MAX_COMMAND_CYCLE_SAMPLES / 1e6:g}M feasib.", "cycle", lambda: [
            "feasibility", "-v", bus, "-v", hgv, *[a for _ in range(MAX_COMMAND_CYCLE_SAMPLES // MAX_CYCLE_SAMPLES)
                                                  for a in ("-c", cycle())], "-f", "csv"]),
        case("blob: store check", "blob", lambda: ["store", "check", "--store", blob_store()[0]]),
        case("blob: simulate", "blob", lambda: ["simulate", "-v", bus, "--trip", blob_store()[1], "--store",
                                                blob_store()[0]]),
    ]


if __name__ == "__main__":
    main()
