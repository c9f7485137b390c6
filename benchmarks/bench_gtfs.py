"""Benchmark of ``cevm gtfs``'s feed reader (cevm.io.gtfs) on a city-sized synthetic feed,
and of the whole command on a real city's weekday.

    python benchmarks/bench_gtfs.py [--rows N] [--keep DIR]

1. A synthetic feed of N stop_times rows (default 10,000,000: a large city's feed; 400,000
   trips of 25 stops, 5,000 stops, half the trips on a weekday service and half on a
   weekend one) is written to a temporary folder (not committed; ``--keep DIR`` keeps it).
   ``read_feed`` reads it for one weekday (the weekday service's trips kept: 5 M rows), in
   a child process, so that its peak resident memory is its own (``ru_maxrss``): rows per
   second and the peak, against cevm's memory bound (500 MB).
   Baseline in the same run: pyarrow's plain ``read_csv`` of the same stop_times.txt with
   its columns typed (trip and stop ids as text, times as text, the rest numbers), all
   rows kept, in a child process of its own: what a reader that loads the file whole costs.
2. Ann Arbor's weekday (../shared/gtfs/ann-arbor-umich-2022.zip, Tuesday 2022-01-11: 83
   blocks, 1,428 trips): the whole ``cevm gtfs`` command with the shipped electric bus
   (class prior driving, flat), its wall time and peak memory, in a child process; skipped
   without the shared folder.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("CEVM_TEST_SHARED") or ROOT.parent / "shared")


def write_feed(folder: Path, rows: int, stops_per_trip: int = 25, n_stops: int = 5000) -> None:
    """A synthetic feed with ``rows`` stop_times rows (module notes)."""
    import pyarrow as pa
    import pyarrow.csv as pacsv

    folder.mkdir(parents=True, exist_ok=True)
    n_trips = rows // stops_per_trip
    rng = np.random.default_rng(1)
    (folder / "agency.txt").write_text("agency_id,agency_name,agency_url,agency_timezone\n"
                                       "X,Bench,https://example.org,Europe/London\n")
    (folder / "calendar.txt").write_text(
        "service_id,monday,tuesday,wednesday,thursday,friday,saturday,sunday,start_date,end_date\n"
        "WK,1,1,1,1,1,0,0,20260101,20261231\nWE,0,0,0,0,0,1,1,20260101,20261231\n")
    lat = 51.5 + rng.uniform(-0.2, 0.2, n_stops)
    lon = -0.1 + rng.uniform(-0.3, 0.3, n_stops)
    pacsv.write_csv(pa.table({"stop_id": [f"S{i}" for i in range(n_stops)], "stop_lat": lat, "stop_lon": lon}),
                    folder / "stops.txt")
    trips = pa.table({"route_id": [f"R{i % 300}" for i in range(n_trips)],
                      "service_id": ["WK" if i % 2 == 0 else "WE" for i in range(n_trips)],
                      "trip_id": [f"T{i}" for i in range(n_trips)],
                      "block_id": [f"B{i // 20}" for i in range(n_trips)]})
    pacsv.write_csv(trips, folder / "trips.txt")
    opts = pacsv.WriteOptions(include_header=False, quoting_style="none")
    with open(folder / "stop_times.txt", "wb") as fh:
        fh.write(b"trip_id,arrival_time,departure_time,stop_id,stop_sequence,shape_dist_traveled\n")
        chunk = 20_000
        for a in range(0, n_trips, chunk):
            t = np.arange(a, min(a + chunk, n_trips))
            k = np.tile(np.arange(stops_per_trip), t.size)
            tr = np.repeat(t, stops_per_trip)
            secs = 5 * 3600 + (tr % 1000) * 60 + k * 90
            hms = np.char.add(np.char.add(np.char.zfill((secs // 3600).astype(str), 2), ":"),
                              np.char.add(np.char.add(np.char.zfill((secs % 3600 // 60).astype(str), 2), ":"),
                                          np.char.zfill((secs % 60).astype(str), 2)))
            stop = (tr * 7 + k) % n_stops
            tbl = pa.table({"trip_id": np.char.add("T", tr.astype(str)), "a": hms, "d": hms,
                            "stop_id": np.char.add("S", stop.astype(str)), "seq": k + 1, "dist": k * 412.5})
            pacsv.write_csv(tbl, fh, write_options=opts)


def _child(code: str) -> tuple[float, float, str]:
    """Run ``code`` in a child Python; (its wall time [s], its own peak RSS [MB] from
    ``os.wait4``'s resource usage, its stdout)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"))
    t = time.perf_counter()
    with tempfile.TemporaryFile("w+") as out:
        proc = subprocess.Popen([sys.executable, "-c", code], env=env, stdout=out)
        _, status, usage = os.wait4(proc.pid, 0)
        proc.returncode = os.waitstatus_to_exitcode(status)
        if proc.returncode:
            raise SystemExit(f"the child failed ({proc.returncode})")
        out.seek(0)
        text = out.read()
    return time.perf_counter() - t, usage.ru_maxrss / 1024.0, text


def bench_reader(folder: Path, rows: int) -> None:
    code = ("import time; from cevm.io.gtfs import read_feed, parse_dates; t = time.perf_counter(); "
            f"tt = read_feed({str(folder)!r}, parse_dates(['2026-03-03'])); "
            "print(time.perf_counter() - t, tt.n, tt.stop.size, tt.stop_times_rows)")
    wall, peak, out = _child(code)
    secs, trips, kept, total = out.split()
    print(f"read_feed, one weekday: {int(total):,} stop_times rows read, {int(kept):,} kept ({int(trips):,} trips) in "
          f"{float(secs):.1f} s: {int(total) / float(secs):,.0f} rows/s; peak RSS {peak:,.0f} MB "
          f"(bound 500 MB; child's wall {wall:.1f} s with start-up)")
    base = ("import time, pyarrow as pa, pyarrow.csv as c; t = time.perf_counter(); "
            f"x = c.read_csv({str(folder / 'stop_times.txt')!r}, convert_options=c.ConvertOptions(column_types="
            "{'trip_id': pa.string(), 'arrival_time': pa.string(), 'departure_time': pa.string(), "
            "'stop_id': pa.string(), 'stop_sequence': pa.int32(), 'shape_dist_traveled': pa.float64()})); "
            "print(time.perf_counter() - t, x.num_rows)")
    _, peak_b, out_b = _child(base)
    secs_b, n_b = out_b.split()
    print(f"baseline, pyarrow read_csv of the whole file, typed, all rows kept: {int(n_b) / float(secs_b):,.0f} "
          f"rows/s; peak RSS {peak_b:,.0f} MB. read_feed/baseline: speed {float(secs_b) / float(secs):.2f}x, "
          f"memory {peak / peak_b:.2f}x")


def bench_ann_arbor() -> None:
    z = SHARED / "gtfs" / "ann-arbor-umich-2022.zip"
    if not z.exists():
        print(f"Ann Arbor: skipped ({z} not found)")
        return
    bus = ROOT / "configs" / "vehicles" / "electric-bus.toml"
    code = ("import sys, time; from cevm.cli import main; t = time.perf_counter(); "
            f"sys.argv = ['cevm', 'gtfs', {str(z)!r}, '-v', {str(bus)!r}, '--date', '2022-01-11', '-f', 'csv', "
            "'-o', '/dev/null']\n"
            "try:\n    main()\nexcept SystemExit:\n    pass\n"
            "print(time.perf_counter() - t, file=sys.stdout)")
    wall, peak, out = _child(code)
    print(f"Ann Arbor, Tuesday 2022-01-11 (83 blocks, 1,428 trips), the whole cevm gtfs: "
          f"{float(out.split()[-1]):.1f} s in the command, {wall:.1f} s with start-up; peak RSS {peak:,.0f} MB")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--rows", type=int, default=10_000_000)
    ap.add_argument("--keep", type=Path, default=None)
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = a.keep or Path(tmp) / "feed"
        t = time.perf_counter()
        if not (folder / "stop_times.txt").exists():
            write_feed(folder, a.rows)
        print(f"synthetic feed of {a.rows:,} stop_times rows in {folder} ({time.perf_counter() - t:.0f} s to write, "
              f"{(folder / 'stop_times.txt').stat().st_size / 1e6:,.0f} MB)")
        bench_reader(folder, a.rows)
        bench_ann_arbor()


if __name__ == "__main__":
    main()
