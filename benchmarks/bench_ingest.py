"""Benchmark of `cevm ingest` on one core: generated srf logs and tiled DSM -> store.

    python benchmarks/bench_ingest.py [--quick] [--vehicles N] [--days D]
                                      [--baseline-src DIR] [--repeat N]
    python benchmarks/bench_ingest.py --sizes [--baseline-src DIR] [--repeat N]
    python benchmarks/bench_ingest.py --held-out [--held-out-rows N] [--baseline-src DIR] [--repeat N]

Every time is CPU time (the machine is shared: wall time measures the neighbours).

Generates a fleet of srf logs on the sample routes (cevm_samplegen.fleet_for_benchmark,
the stand-in consumption: the benchmark measures ingest, not the detailed model) with
the sample DSM tiles, then ingests it serially into a fresh store and prints samples per
CPU second end to end (CSV bytes to stored vector, DSM lookup included) and each stage's
CPU seconds. Baselines in the same run: the bare cost of reading the same files with
pandas.read_csv, and with a bare typed pyarrow parse (the floor of any reader of these
bytes); and the read stage alone (``read_log`` of every file) with each parser, pyarrow
(what ingest uses) and pandas (the parser before, still the fallback for blocks pyarrow
refuses), best of two. Target: >= 1 million samples/s.

``--baseline-src DIR`` also ingests the same files with another checkout's ``src`` (its
``configs`` beside it: e.g. ``git archive COMMIT src configs | tar -x -C /tmp/before``
and ``--baseline-src /tmp/before/src``), in a subprocess of the same run, alternating
``--repeat`` times, and prints each stage's CPU seconds and share for both (the minimum
of the repeats), the range of the repeats and the ratio of each pair of runs made one
after the other: before and after a change, measured side by side.

``--sizes`` measures one file at a time instead: srf logs of 1,000, 100,000, 1 M and 5 M
rows (a long-haul truck's working days of the benchmark fleet, repeated on consecutive
days, as ``benchmarks/bench_memory.py`` makes them), each ingested with the sample DSM by a
fresh ``cevm ingest --workers 1`` process of this checkout (and of ``--baseline-src``,
alternating, ``--repeat`` times): the process's CPU seconds, the cost per trip sample
[us] and its peak memory (VmHWM), for a linear cost and a bounded memory whatever the
file's size (the 5 M-row file with ``--max-rows`` and ``--max-samples`` lifted).

``--held-out`` is the held-out check: one core's CPU on real logs against a bare
typed pyarrow parse of the same bytes (goal: within 4x for many small files, 3x for a
large one). Many small files: the Twizy logs of ``../shared/real-logs/twizy`` (no DSM
covers them); one large file: the sample srf days of the long-haul truck HGV-21, each in
turn on consecutive dates, to ``--held-out-rows`` rows, with the sample DSM. Each is
measured as the ingest call in a process that has ingested one of the files before (so
that the modules such a file needs are imported; the DSM's headers are read again)
against the parse in this process, and as a whole ``cevm ingest`` process against the
parse in a process of its own.

The process runs with :func:`cevm.runtime.tune_allocator` applied, as the ``cevm``
command does (``CEVM_TUNE_ALLOCATOR=0`` to measure glibc's defaults: ~7 % slower,
from page faults).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("GDAL_NUM_THREADS", "1")

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

import pandas as pd  # noqa: E402

from cevm.ingest import IngestOptions, ingest  # noqa: E402
from cevm.runtime import tune_allocator  # noqa: E402
from cevm.store import TripStore  # noqa: E402
from cevm_samplegen import fleet_for_benchmark, generate_sample_logs  # noqa: E402

# Ingests ``fleet`` with the DSM into a new store with whatever cevm is first on the path
# (the baseline checkout's src), one core, and prints the report as JSON.
_RUN_INGEST = r"""
import json, os, sys, tempfile, time, types
os.environ.setdefault("OMP_NUM_THREADS", "1"); os.environ.setdefault("GDAL_NUM_THREADS", "1")
from cevm.ingest import IngestOptions, ingest
import cevm.ingest.pipeline as pipeline, cevm.ingest.task as task
from cevm.runtime import tune_allocator
from cevm.store import TripStore
# stages timed in this thread's CPU time, not wall time (the machine is shared)
cpu_clock = types.SimpleNamespace(perf_counter=time.thread_time, time=time.time)
task.time = pipeline.time = cpu_clock
tune_allocator()
fleet, dsm = sys.argv[1], sys.argv[2]
with tempfile.TemporaryDirectory() as d, TripStore.open(os.path.join(d, "b.sqlite")) as st:
    t0 = time.process_time()
    rep = ingest([fleet], st, IngestOptions(dsm=dsm))
    dt = time.process_time() - t0
assert rep.failed == 0, [f.error for f in rep.files if f.error][:3]
print(json.dumps({"seconds": dt, "samples": rep.summary()["samples"], "stage_s": rep.stage_s}))
"""


# One file by ``cevm ingest`` (the command, as a user runs it) in this process: prints its
# CPU seconds, the samples stored and the process's peak memory (VmHWM) as JSON.
_RUN_ONE = r"""
import json, os, re, resource, sqlite3, sys, time
os.environ.setdefault("OMP_NUM_THREADS", "1"); os.environ.setdefault("GDAL_NUM_THREADS", "1")
from cevm.cli import main
store = sys.argv[sys.argv.index("--store") + 1]
sys.argv = ["cevm", "ingest", *sys.argv[1:]]
t0 = time.process_time()
try:
    main()
except SystemExit as exc:
    assert not exc.code, exc.code
cpu = time.process_time() - t0
hwm = float(re.search(r"VmHWM:\s+(\d+)", open("/proc/self/status").read()).group(1)) / 1024
con = sqlite3.connect(store)
samples = con.execute("SELECT COALESCE(SUM(n_samples), 0) FROM trips").fetchone()[0]
print("\n@@" + json.dumps({"cpu_s": cpu, "samples": samples, "peak_mb": hwm}))
"""


def _ingest_one(src: str, path: Path, dsm: Path, tmp: Path) -> dict:
    store = tmp / "one.sqlite"
    for p in tmp.glob("one.sqlite*"):
        p.unlink()
    env = {**os.environ, "PYTHONPATH": src}
    lift = ["--max-rows", "6000000"]
    if "max_samples" in (Path(src) / "cevm" / "cli" / "ingest.py").read_text():  # a checkout from before it: none
        lift += ["--max-samples", "50000000"]
    out = subprocess.run([sys.executable, "-c", _RUN_ONE, str(path), "--dsm", str(dsm), "--store", str(store),
                          "--workers", "1", "-q", *lift], env=env, check=True, capture_output=True, text=True).stdout
    return json.loads(out.split("@@")[-1])


def _sizes(args, tmp: Path) -> None:
    """Cost per sample and peak memory of one file of each size (module docstring)."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_memory import make_large_srf

    sizes = (1_000, 100_000, 1_000_000, 5_000_000)
    files = {sizes[-1]: make_large_srf(tmp / f"srf-{sizes[-1]}.csv", sizes[-1], tmp)}
    for n in sizes[:-1]:  # the first rows of the largest
        with open(files[sizes[-1]], "rb") as src, open(tmp / f"srf-{n}.csv", "wb") as out:
            k = 0
            for line in src:
                out.write(line)
                k += not line.startswith((b"#", b"timestamp_utc"))
                if k == n:
                    break
        files[n] = tmp / f"srf-{n}.csv"
    dsm = tmp / "sample" / "dsm"
    this_src = str(Path(__file__).resolve().parents[1] / "src")
    srcs = {"this": this_src, **({"baseline": args.baseline_src} if args.baseline_src else {})}
    print(f"{'rows':>10s} {'code':>9s} {'samples':>10s} {'CPU s':>8s} {'us/sample':>10s} {'peak MB':>8s}")
    for n in sizes:
        best: dict[str, dict] = {}
        for _ in range(max(1, args.repeat)):
            for name, src in srcs.items():
                r = _ingest_one(src, files[n], dsm, tmp)
                if name not in best or r["cpu_s"] < best[name]["cpu_s"]:
                    best[name] = r
        for name, r in best.items():
            print(f"{n:>10,d} {name:>9s} {r['samples']:>10,d} {r['cpu_s']:>8.2f} "
                  f"{1e6 * r['cpu_s'] / max(r['samples'], 1):>10.2f} {r['peak_mb']:>8.0f}")
        if len(best) == 2:
            print(f"{'':>10s} {'ratio':>9s} {'':>10s} {best['baseline']['cpu_s'] / best['this']['cpu_s']:>7.2f}x "
                  "(baseline CPU / this CPU, same run)")


def _ingest_with(src: str, fleet: Path, dsm: Path) -> dict:
    env = {**os.environ, "PYTHONPATH": src}
    out = subprocess.run([sys.executable, "-c", _RUN_INGEST, str(fleet), str(dsm)], env=env, check=True,
                         capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def _print_side_by_side(runs: dict[str, list[dict]]) -> None:
    """Each stage's CPU seconds and share of the run, minimum over repeats, per source;
    the range of the repeats and the ratio of each repeat pair (run one after the other)."""
    best = {name: min(r, key=lambda x: x["seconds"]) for name, r in runs.items()}
    stages = sorted({k for b in best.values() for k in b["stage_s"]}, key=lambda k: -best["this"]["stage_s"].get(k, 0))
    names = list(best)
    print("  side by side, CPU seconds (fastest of the repeats; other = hashing, discovery, bookkeeping):")
    print("    " + f"{'stage':10s}" + "".join(f"{n:>22s}" for n in names))
    for k in [*stages, "other", "total"]:
        cells = []
        for n in names:
            b = best[n]
            v = b["seconds"] - sum(b["stage_s"].values()) if k == "other" else (
                b["seconds"] if k == "total" else b["stage_s"].get(k, 0.0))
            cells.append(f"{v:8.2f} s {100 * v / b['seconds']:5.1f} %   ")
        print("    " + f"{k:10s}" + "".join(f"{c:>22s}" for c in cells))
    for n in names:
        b = best[n]
        secs = [r["seconds"] for r in runs[n]]
        print(f"    {n}: {b['samples'] / b['seconds'] / 1e6:.3f} M samples/s per CPU second "
              f"(repeats {min(secs):.2f}-{max(secs):.2f} s CPU: " + ", ".join(f"{x:.2f}" for x in secs) + ")")
    if "baseline" in runs and len(runs["baseline"]) == len(runs["this"]):
        ratios = [b["seconds"] / t["seconds"] for b, t in zip(runs["baseline"], runs["this"], strict=True)]
        print(f"    baseline CPU / this CPU: {best['baseline']['seconds'] / best['this']['seconds']:.2f}x (fastest of "
              f"each); per repeat pair {min(ratios):.2f}-{max(ratios):.2f}x: " + ", ".join(f"{r:.2f}" for r in ratios))


def _sample_days(vehicle: str) -> tuple[list[bytes], bytes, list[list[bytes]]]:
    """The comment lines, header and each day's data lines (after their date) of one
    vehicle's sample srf logs (``sample_logs/srf``), in date order."""
    import gzip

    head: list[bytes] = []
    header = b""
    days = []
    for f in sorted((ROOT / "sample_logs" / "srf").glob(f"{vehicle}_*.csv*")):
        data = f.read_bytes()
        if data[:2] == b"\x1f\x8b":
            data = gzip.decompress(data)
        lines = data.split(b"\n")
        k = next(i for i, ln in enumerate(lines) if not ln.startswith(b"#"))
        head, header = lines[:k], lines[k]
        days.append([ln[10:] for ln in lines[k + 1:] if ln])
    return head, header, days


def make_held_out_large(out: Path, rows: int, vehicle: str = "HGV-21") -> Path:
    """A large real-world-shaped log: one vehicle's sample srf days (each a day of its
    own, in turn) on consecutive dates from 2020-01-01 until ``rows`` data rows."""
    import datetime as dt

    head, header, days = _sample_days(vehicle)
    with open(out, "wb") as fh:
        fh.write(b"\n".join([*head, header]) + b"\n")
        n = k = 0
        while n < rows:
            date = (dt.date(2020, 1, 1) + dt.timedelta(days=k)).isoformat().encode()
            take = days[k % len(days)][: rows - n]
            fh.write(b"".join(date + t + b"\n" for t in take))
            n += len(take)
            k += 1
    return out


_RUN_HELD_OUT = r"""
import json, os, sys, tempfile, time
os.environ.setdefault("OMP_NUM_THREADS", "1"); os.environ.setdefault("GDAL_NUM_THREADS", "1")
from cevm.ingest import IngestOptions, ingest
from cevm.ingest.textfile import ReadLimits
from cevm.runtime import tune_allocator
from cevm.store import TripStore
tune_allocator()
inputs, dsm = sys.argv[1].split(os.pathsep), sys.argv[2] or None
with tempfile.TemporaryDirectory() as d, TripStore.open(os.path.join(d, "w.sqlite")) as st:
    ingest(inputs[:1], st, IngestOptions(dsm=dsm))  # warm: the modules a file of these needs imported
with tempfile.TemporaryDirectory() as d, TripStore.open(os.path.join(d, "h.sqlite")) as st:
    t0 = time.process_time()
    rep = ingest(inputs, st, IngestOptions(dsm=dsm, limits=ReadLimits(max_rows=6_000_000)))
    dt = time.process_time() - t0
assert rep.failed == 0, [f.error for f in rep.files if f.error][:3]
print(json.dumps({"cpu_s": dt, "samples": rep.summary()["samples"]}))
"""

_RUN_BARE = r"""
import sys, gzip
import pyarrow as pa, pyarrow.csv as pacsv
for f in sys.argv[1:]:
    data = open(f, "rb").read()
    if data[:2] == b"\x1f\x8b":
        data = gzip.decompress(data)
    k = 0
    while data[k:k + 1] == b"#":
        k = data.index(b"\n", k) + 1
    pacsv.read_csv(pa.py_buffer(data[k:]), read_options=pacsv.ReadOptions(use_threads=False),
                   convert_options=pacsv.ConvertOptions(timestamp_parsers=[pacsv.ISO8601]))
"""


def _child_cpu(cmd: list[str], env: dict) -> float:
    """CPU seconds (user + system) of a child process running ``cmd``."""
    import resource

    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run(cmd, env=env, check=True, capture_output=True)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def _held_out(args, tmp: Path) -> None:
    """The held-out check: one core's CPU on real logs against a bare typed
    pyarrow parse of the same bytes (module docstring)."""
    shared = next((p for p in (ROOT.parent / "shared", ROOT.parent.parent / "shared") if p.is_dir()), None)
    twizy = shared / "real-logs" / "twizy" if shared else None
    cases = []
    if twizy is not None and twizy.is_dir():
        cases.append(("many small (Twizy logs, no DSM)", sorted(twizy.glob("*.csv")), None, 4.0))
    else:
        print("many small: skipped (../shared/real-logs/twizy not found)")
    generate_sample_logs(tmp / "sample", small=False)
    large = make_held_out_large(tmp / "held-out-large.csv", args.held_out_rows)
    cases.append((f"one large ({args.held_out_rows:,} rows of sample srf days, sample DSM)", [large],
                  tmp / "sample" / "dsm", 3.0))
    this_src = str(ROOT / "src")
    srcs = {"this": this_src, **({"baseline": args.baseline_src} if args.baseline_src else {})}
    for title, files, dsm, goal in cases:
        env = {**os.environ, "PYTHONPATH": ""}
        bare_in = min(bare_parse_s(files) for _ in range(max(2, args.repeat)))
        bare_proc = min(_child_cpu([sys.executable, "-c", _RUN_BARE, *map(str, files)], env)
                        for _ in range(max(2, args.repeat)))
        print(f"{title}: {len(files)} files, {sum(f.stat().st_size for f in files) / 1e6:.1f} MB")
        print(f"  bare typed pyarrow parse: {bare_in:.3f} s CPU in process, {bare_proc:.3f} s as a process of its own")
        for name, src in srcs.items():
            envs = {**os.environ, "PYTHONPATH": src}
            inproc, proc = [], []
            for _ in range(max(1, args.repeat)):
                out = subprocess.run([sys.executable, "-c", _RUN_HELD_OUT, os.pathsep.join(map(str, files)),
                                      str(dsm or "")], env=envs, check=True, capture_output=True, text=True).stdout
                r = json.loads(out.strip().splitlines()[-1])
                inproc.append(r["cpu_s"])
                store = tmp / "held-out.sqlite"
                for q in tmp.glob("held-out.sqlite*"):
                    q.unlink()
                cmd = [sys.executable, "-m", "cevm", "ingest", *map(str, files), "--store", str(store), "--workers",
                       "1", "-q", "--max-rows", "6000000", *(["--dsm", str(dsm)] if dsm else [])]
                proc.append(_child_cpu(cmd, envs))
            print(f"  {name:>8s}: ingest {min(inproc):.3f} s CPU in process = {min(inproc) / bare_in:.1f}x the bare "
                  f"parse (goal {goal:g}x; {r['samples'] / min(inproc) / 1e6:.2f} M samples/s); whole `cevm ingest` "
                  f"process {min(proc):.3f} s = {min(proc) / bare_proc:.1f}x the bare parse's process "
                  f"(repeats {', '.join(f'{x:.2f}' for x in inproc)} / {', '.join(f'{x:.2f}' for x in proc)} s)")


def cpu_stages() -> None:
    """Time the ingest's stages in this thread's CPU time (not wall time: the machine is
    shared), as the side-by-side runs do."""
    import types

    import cevm.ingest.pipeline as pipeline
    import cevm.ingest.task as task

    clock = types.SimpleNamespace(perf_counter=time.thread_time, time=time.time)
    task.time = pipeline.time = clock  # type: ignore[assignment]


def bare_parse_s(files: list[Path]) -> float:
    """CPU seconds of a bare typed parse of ``files`` by pyarrow's CSV reader (one
    thread, numbers and ISO 8601 times typed, the comment lines before the header
    skipped, gzip inflated first): the floor of any reader of these bytes."""
    import gzip

    import pyarrow as pa
    import pyarrow.csv as pacsv

    t0 = time.process_time()
    for f in files:
        data = f.read_bytes()
        if data[:2] == b"\x1f\x8b":
            data = gzip.decompress(data)
        k = 0
        while data[k:k + 1] == b"#":
            k = data.index(b"\n", k) + 1
        pacsv.read_csv(pa.py_buffer(data[k:]), read_options=pacsv.ReadOptions(use_threads=False),
                       convert_options=pacsv.ConvertOptions(timestamp_parsers=[pacsv.ISO8601]))
    return time.process_time() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a small fleet (a few seconds)")
    ap.add_argument("--vehicles", type=int, default=None)
    ap.add_argument("--days", type=int, default=None)
    ap.add_argument("--baseline-src", default=None, help="another checkout's src/ to ingest the same files with")
    ap.add_argument("--repeat", type=int, default=1,
                    help="alternating runs of this and the baseline (with --baseline-src)")
    ap.add_argument("--sizes", action="store_true", help="one file of 1k, 100k, 1M and 5M rows each: cost and memory")
    ap.add_argument("--held-out", action="store_true",
                    help="real logs against a bare typed pyarrow parse of the same bytes (the held-out check)")
    ap.add_argument("--held-out-rows", type=int, default=1_000_000, help="rows of --held-out's large file")
    args = ap.parse_args()
    if args.held_out:
        with tempfile.TemporaryDirectory(prefix="cevm-bench-") as tmp:
            _held_out(args, Path(tmp))
        return
    if args.sizes:
        with tempfile.TemporaryDirectory(prefix="cevm-bench-") as tmp:
            _sizes(args, Path(tmp))
        return
    n_veh = args.vehicles or (8 if args.quick else 40)
    n_days = args.days or (2 if args.quick else 5)
    print(f"allocator tuned as the CLI runs: {tune_allocator()}")

    with tempfile.TemporaryDirectory(prefix="cevm-bench-") as tmp:
        tmp = Path(tmp)
        t0 = time.perf_counter()
        generate_sample_logs(tmp / "sample", small=False)  # for the DSM tiles
        fleet_for_benchmark(n_veh, n_days, tmp / "fleet", dsm_dir=tmp / "sample" / "dsm")
        files = sorted((tmp / "fleet").rglob("*.csv*"))
        size_mb = sum(f.stat().st_size for f in files) / 1e6
        print(f"generated {len(files)} srf files ({size_mb:.0f} MB) for {n_veh} vehicles x {n_days} days "
              f"in {time.perf_counter() - t0:.1f} s")

        # baselines: the floors of reading the bytes, nothing else (CPU time: this machine is shared)
        t0 = time.process_time()
        rows = sum(len(pd.read_csv(f, comment="#")) for f in files)
        dt_read = time.process_time() - t0
        print(f"baseline pandas.read_csv only: {rows:,} rows in {dt_read:.2f} s CPU = {rows / dt_read / 1e6:.2f} M "
              f"rows/s")
        dt_bare = min(bare_parse_s(files) for _ in range(2))
        print(f"baseline bare typed pyarrow parse (read_csv, ISO 8601 times, one thread): {dt_bare:.2f} s CPU "
              f"= {rows / dt_bare / 1e6:.2f} M rows/s")

        # the read stage alone, with each parser
        from cevm.ingest.profiles import load_profiles
        from cevm.ingest.reading import read_log

        profs = load_profiles()
        best = {"pandas": float("inf"), "pyarrow": float("inf")}
        for _ in range(2):
            for engine in best:
                t0 = time.process_time()
                for f in files:
                    read_log(f, profs["srf"], profs, engine=engine)
                best[engine] = min(best[engine], time.process_time() - t0)
        print(f"read stage alone (read_log, CPU s, best of 2): pandas parser (before) {best['pandas']:.2f} s "
              f"= {rows / best['pandas'] / 1e6:.2f} M rows/s; pyarrow parser (now) {best['pyarrow']:.2f} s "
              f"= {rows / best['pyarrow'] / 1e6:.2f} M rows/s: {best['pandas'] / best['pyarrow']:.2f}x")

        cpu_stages()
        with TripStore.open(tmp / "bench.sqlite") as st:
            t0 = time.process_time()
            rep = ingest([tmp / "fleet"], st, IngestOptions(dsm=str(tmp / "sample" / "dsm")))
            dt = time.process_time() - t0
        s = rep.summary()
        assert s["failed"] == 0, s
        print(f"cevm ingest (1 core): {s['files']} files, {s['trips']} trips, {s['rows']:,} rows -> "
              f"{s['samples']:,} trip samples, {s['km']:,.0f} km in {dt:.2f} s CPU")
        print(f"  throughput: {s['rows'] / dt / 1e6:.2f} M rows/s, {s['samples'] / dt / 1e6:.2f} M trip samples/s "
              f"({dt / dt_read:.1f}x the bare read_csv CPU, {dt / dt_bare:.1f}x the bare pyarrow parse)")
        total = sum(rep.stage_s.values())
        print("  stages (CPU seconds, share of the run):")
        for k, v in sorted(rep.stage_s.items(), key=lambda kv: -kv[1]):
            print(f"    {k:10s} {v:7.2f} s  {100 * v / dt:5.1f} %")
        print(f"    {'other':10s} {dt - total:7.2f} s  {100 * (dt - total) / dt:5.1f} %  (hashing, discovery, "
              f"bookkeeping)")
        print("  target: >= 1,000,000 samples/s")
        if args.baseline_src:
            this_src = str(Path(__file__).resolve().parents[1] / "src")
            runs: dict[str, list[dict]] = {"baseline": [], "this": []}
            for _ in range(max(1, args.repeat)):
                runs["baseline"].append(_ingest_with(args.baseline_src, tmp / "fleet", tmp / "sample" / "dsm"))
                runs["this"].append(_ingest_with(this_src, tmp / "fleet", tmp / "sample" / "dsm"))
            print(f"baseline: {args.baseline_src}")
            _print_side_by_side(runs)


if __name__ == "__main__":
    main()
