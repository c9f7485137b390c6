"""Benchmark of `cevm ingest` on one core: generated srf logs and tiled DSM -> store.

    python benchmarks/bench_ingest.py [--quick] [--vehicles N] [--days D]

Generates a fleet of srf logs on the sample routes (cevm_samplegen.fleet_for_benchmark,
the stand-in consumption: the benchmark measures ingest, not the detailed model) with
the sample DSM tiles, then ingests it serially into a fresh store and prints samples/s
end to end (CSV bytes to stored vector, DSM lookup included) and each stage's share.
Baselines in the same run: the bare cost of reading the same files with pandas.read_csv,
the floor of any CSV-based pipeline; and the read stage alone (``read_log`` of every
file) with each parser, pyarrow (what ingest uses) and pandas (the parser before,
still the fallback for blocks pyarrow refuses), best of two, CPU seconds. Target
(issue 4): >= 1 million samples/s.

The process runs with :func:`cevm.runtime.tune_allocator` applied, as the ``cevm``
command does (``CEVM_TUNE_ALLOCATOR=0`` to measure glibc's defaults: ~7 % slower,
from page faults).
"""

from __future__ import annotations

import argparse
import os
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a small fleet (a few seconds)")
    ap.add_argument("--vehicles", type=int, default=None)
    ap.add_argument("--days", type=int, default=None)
    args = ap.parse_args()
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


if __name__ == "__main__":
    main()
