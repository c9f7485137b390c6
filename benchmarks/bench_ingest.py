"""Benchmark of `cevm ingest` on one core: generated srf logs and tiled DSM -> store.

    python benchmarks/bench_ingest.py [--quick] [--vehicles N] [--days D]
                                      [--baseline-src DIR] [--repeat N]
    python benchmarks/bench_ingest.py --sizes [--baseline-src DIR] [--repeat N]

Generates a fleet of srf logs on the sample routes (cevm_samplegen.fleet_for_benchmark,
the stand-in consumption: the benchmark measures ingest, not the detailed model) with
the sample DSM tiles, then ingests it serially into a fresh store and prints samples/s
end to end (CSV bytes to stored vector, DSM lookup included) and each stage's share.
Baselines in the same run: the bare cost of reading the same files with pandas.read_csv,
the floor of any CSV-based pipeline; and the read stage alone (``read_log`` of every
file) with each parser, pyarrow (what ingest uses) and pandas (the parser before,
still the fallback for blocks pyarrow refuses), best of two, CPU seconds. Target
(issue 4): >= 1 million samples/s.

``--baseline-src DIR`` also ingests the same files with another checkout's ``src`` (its
``configs`` beside it: e.g. ``git archive COMMIT src configs | tar -x -C /tmp/before``
and ``--baseline-src /tmp/before/src``),
in a subprocess of the same run, alternating ``--repeat`` times, and prints each
stage's seconds and share for both (the minimum of the repeats): before and after a
change, measured side by side.

``--sizes`` measures one file at a time instead: srf logs of 1,000, 100,000, 1 M and 5 M
rows (a long-haul truck's working days of the benchmark fleet, repeated on consecutive
days, as ``benchmarks/bench_memory.py`` makes them), each ingested with the sample DSM by a
fresh ``cevm ingest --workers 1`` process of this checkout (and of ``--baseline-src``,
alternating, ``--repeat`` times): the process's CPU seconds, the cost per trip sample
[us] and its peak memory (VmHWM), for a linear cost and a bounded memory whatever the
file's size (the 5 M-row file with ``--max-rows`` and ``--max-samples`` lifted).

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

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

import pandas as pd  # noqa: E402

from cevm.ingest import IngestOptions, ingest  # noqa: E402
from cevm.runtime import tune_allocator  # noqa: E402
from cevm_samplegen import fleet_for_benchmark, generate_sample_logs  # noqa: E402
from cevm.store import TripStore  # noqa: E402


# Ingests ``fleet`` with the DSM into a new store with whatever cevm is first on the path
# (the baseline checkout's src), one core, and prints the report as JSON.
_RUN_INGEST = r"""
import json, os, sys, tempfile, time
os.environ.setdefault("OMP_NUM_THREADS", "1"); os.environ.setdefault("GDAL_NUM_THREADS", "1")
from cevm.ingest import IngestOptions, ingest
from cevm.runtime import tune_allocator
from cevm.store import TripStore
tune_allocator()
fleet, dsm = sys.argv[1], sys.argv[2]
with tempfile.TemporaryDirectory() as d, TripStore.open(os.path.join(d, "b.sqlite")) as st:
    t0 = time.perf_counter()
    rep = ingest([fleet], st, IngestOptions(dsm=dsm))
    dt = time.perf_counter() - t0
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
    """Each stage's seconds and share of the run, minimum over repeats, per source."""
    best = {name: min(r, key=lambda x: x["seconds"]) for name, r in runs.items()}
    stages = sorted({k for b in best.values() for k in b["stage_s"]}, key=lambda k: -best["this"]["stage_s"].get(k, 0))
    names = list(best)
    print("  side by side (fastest of the repeats; other = hashing, discovery, bookkeeping):")
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
        print(f"    {n}: {b['samples'] / b['seconds'] / 1e6:.3f} M samples/s "
              "(all repeats: " + ", ".join(f"{r['seconds']:.2f}" for r in runs[n]) + " s)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a small fleet (a few seconds)")
    ap.add_argument("--vehicles", type=int, default=None)
    ap.add_argument("--days", type=int, default=None)
    ap.add_argument("--baseline-src", default=None, help="another checkout's src/ to ingest the same files with")
    ap.add_argument("--repeat", type=int, default=1, help="alternating runs of this and the baseline (with --baseline-src)")
    ap.add_argument("--sizes", action="store_true", help="one file of 1k, 100k, 1M and 5M rows each: cost and memory")
    args = ap.parse_args()
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

        # baseline: the floor of reading the bytes into a frame, nothing else
        t0 = time.perf_counter()
        rows = sum(len(pd.read_csv(f, comment="#")) for f in files)
        dt_read = time.perf_counter() - t0
        print(f"baseline pandas.read_csv only: {rows:,} rows in {dt_read:.2f} s = {rows / dt_read / 1e6:.2f} M rows/s")

        # the read stage alone, with each parser (CPU time: this machine is shared)
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

        with TripStore.open(tmp / "bench.sqlite") as st:
            t0 = time.perf_counter()
            rep = ingest([tmp / "fleet"], st, IngestOptions(dsm=str(tmp / "sample" / "dsm")))
            dt = time.perf_counter() - t0
        s = rep.summary()
        assert s["failed"] == 0, s
        print(f"cevm ingest (1 core): {s['files']} files, {s['trips']} trips, {s['rows']:,} rows -> "
              f"{s['samples']:,} trip samples, {s['km']:,.0f} km in {dt:.2f} s")
        print(f"  throughput: {s['rows'] / dt / 1e6:.2f} M rows/s, {s['samples'] / dt / 1e6:.2f} M trip samples/s "
              f"({dt / dt_read:.1f}x the bare read_csv time)")
        total = sum(rep.stage_s.values())
        print("  stages (share of the run):")
        for k, v in sorted(rep.stage_s.items(), key=lambda kv: -kv[1]):
            print(f"    {k:10s} {v:7.2f} s  {100 * v / dt:5.1f} %")
        print(f"    {'other':10s} {dt - total:7.2f} s  {100 * (dt - total) / dt:5.1f} %  (hashing, discovery, bookkeeping)")
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
