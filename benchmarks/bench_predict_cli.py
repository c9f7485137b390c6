"""Benchmark of ``cevm predict`` on one large cycle file: the whole command against its floor.

    python benchmarks/bench_predict_cli.py [--samples 1000000] [--repeat 3] [--keep DIR]

Writes a cycle CSV of ``--samples`` 1 Hz samples (default 1 M, 11.6 days of driving, the
most a cycle file may hold: ``cevm.io.cycles.MAX_CYCLE_SAMPLES``;
``time_s,speed_kmh,elevation_m`` with 1, 2 and 2 decimals, about 21 MB) to a temporary
directory, then times, alternately and ``--repeat`` times each, two fresh processes:

1. the floor: one Python process that reads the same file with pyarrow's typed CSV
   reader (one thread, as cevm's reader) and takes the columns as numpy arrays with
   ``np.frombuffer`` (no pandas: cevm's reader never imports it, and importing pandas
   alone costs about 0.3 s, which made an earlier pandas floor flatter the command),
   then computes the CE per-step sums with numpy (k, a, r, e, the simplified split and
   its three sums; what any program reading this file and reducing it must do),
   importing nothing of cevm;
2. the command ``cevm predict -v configs/vehicles/diesel-hgv.toml --cycle BIG.csv
   --mass-kg 20000`` (interpreter start, imports, the reader with its checks, the CE
   vector, the sweep, the table).

Prints each run, the best and the median of each, and the ratio command / floor (the
goal of issues 18 and 25: 1.5x or less). Also, in-process: the cycle reader alone
(``cevm.io.read_cycle_csv``) against a bare typed pyarrow read of the file, to show the
reader's own share. Wall-clock times on a shared 2-core machine: compare within a run.

Both processes run with Python's bytecode cache on, in a directory of the run
(``PYTHONPYCACHEPREFIX``), whatever ``PYTHONDONTWRITEBYTECODE`` says: cevm is run from
its source tree, and without the cache every run would compile cevm's modules again
(about 0.17 s), which an installed cevm (whose modules pip compiles at install) never
does; the floor's pyarrow and numpy come with their bytecode. The warm-up runs write it.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
VEHICLE = ROOT / "configs" / "vehicles" / "diesel-hgv.toml"

FLOOR = r"""
import sys
import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv

names = ("time_s", "speed_kmh", "elevation_m")
table = pacsv.read_csv(sys.argv[1], read_options=pacsv.ReadOptions(use_threads=False),
                       convert_options=pacsv.ConvertOptions(column_types=dict.fromkeys(names, pa.float64())))

def column(name):
    a = table.column(name).combine_chunks()
    return np.frombuffer(a.buffers()[1], np.float64, len(a), a.offset * 8)

t, v, h = column("time_s"), column("speed_kmh") / 3.6, column("elevation_m")
dt = np.diff(t)
v0, v1 = v[:-1], v[1:]
k = 0.5 * (v1 * v1 - v0 * v0)
a = 0.30625 * (v0 ** 3 + v1 ** 3) * dt
r = 4.905 * (v0 + v1) * dt
e = 9.81 * np.diff(h)
x = k + e
simple = x + 0.004 * r > 0
print(x[simple].sum(), a[simple].sum(), r[simple].sum(), x[~simple].sum())
"""


def write_cycle(path: Path, n: int, seed: int = 18) -> None:
    """A 1 Hz cycle of ``n`` samples: stop-and-go trips with hills, speed in km/h."""
    rng = np.random.default_rng(seed)
    # a smooth speed: a random walk of accelerations, clipped to 0-90 km/h, with stops
    acc = rng.normal(0.0, 0.35, n)
    v = np.empty(n)
    cur = 0.0
    for start in range(0, n, 100_000):  # blocks keep this fast without a per-sample loop
        block = np.cumsum(acc[start:start + 100_000]) + cur
        v[start:start + block.size] = block
        cur = block[-1]
    v = np.abs((v + 45.0) % 180.0 - 90.0)  # fold into 0-90 km/h
    phase = np.arange(n) % 900.0  # a 40 s stop every 15 min, 30 s ramps to and from it
    v *= np.clip((phase - 40.0) / 30.0, 0.0, 1.0) * np.clip((900.0 - phase) / 30.0, 0.0, 1.0)
    h = 50.0 + 30.0 * np.sin(np.arange(n) * 2.0 * np.pi / 3000.0)
    t = np.arange(n, dtype=np.float64)
    with open(path, "w") as fh:
        fh.write("time_s,speed_kmh,elevation_m\n")
        block = 200_000
        for lo in range(0, n, block):
            sl = slice(lo, lo + block)
            lines = np.char.add(np.char.add(np.char.add(np.char.add(
                np.char.mod("%.1f", t[sl]), ","), np.char.mod("%.2f", v[sl])), ","), np.char.mod("%.2f", h[sl]))
            fh.write("\n".join(lines.tolist()))
            fh.write("\n")


def timed(cmd: list[str], env: dict) -> tuple[float, float]:
    """(wall-clock, CPU) seconds of one run of ``cmd``; the CPU time (user + system of the
    child) is steadier than the wall clock on a shared machine."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    dt = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        sys.exit(f"failed ({proc.returncode}): {' '.join(cmd)}\n{proc.stderr}")
    return dt, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--samples", type=int, default=1_000_000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--keep", type=Path, help="write the cycle here and keep it")
    args = ap.parse_args()

    with tempfile.TemporaryDirectory(prefix="cevm-bench-predict-") as tmp:
        env = dict(os.environ, PYTHONPATH=str(ROOT / "src"), OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1",
                   PYTHONPYCACHEPREFIX=str(Path(tmp) / "pycache"))
        env.pop("PYTHONDONTWRITEBYTECODE", None)
        d = args.keep or Path(tmp)
        d.mkdir(parents=True, exist_ok=True)
        big = d / "BIG.csv"
        t0 = time.perf_counter()
        write_cycle(big, args.samples)
        print(f"cycle: {args.samples:,} samples, {big.stat().st_size / 1e6:.1f} MB, written in "
              f"{time.perf_counter() - t0:.1f} s ({big})")
        floor_cmd = [sys.executable, "-c", FLOOR, str(big)]
        cli_cmd = [sys.executable, "-m", "cevm", "predict", "-v", str(VEHICLE), "--cycle", str(big),
                   "--mass-kg", "20000"]
        timed(floor_cmd, env)  # warm the page cache and the interpreter's files; write the bytecode
        timed(cli_cmd, env)
        floor, cli = [], []
        for i in range(args.repeat):
            floor.append(timed(floor_cmd, env))
            cli.append(timed(cli_cmd, env))
            print(f"  run {i + 1}: floor {floor[-1][0]:.3f} s ({floor[-1][1]:.3f} s CPU), cevm predict "
                  f"{cli[-1][0]:.3f} s ({cli[-1][1]:.3f} s CPU): {cli[-1][0] / floor[-1][0]:.2f}x "
                  f"({cli[-1][1] / floor[-1][1]:.2f}x CPU)")
        for k, label in ((0, "wall clock"), (1, "CPU time")):
            f = [x[k] for x in floor]
            c = [x[k] for x in cli]
            print(f"{label}: floor (python + pyarrow typed read + numpy sums) best {min(f):.3f} s, median "
                  f"{statistics.median(f):.3f} s; cevm predict best {min(c):.3f} s, median {statistics.median(c):.3f} "
                  f"s;"
                  f" ratio best {min(c) / min(f):.2f}x, median {statistics.median(c) / statistics.median(f):.2f}x "
                  "(goal: 1.5x or less)")

        sys.path.insert(0, str(ROOT / "src"))
        import pyarrow as pa
        import pyarrow.csv as pacsv

        from cevm.io import read_cycle_csv

        types = pacsv.ConvertOptions(column_types=dict.fromkeys(("time_s", "speed_kmh", "elevation_m"), pa.float64()))
        bare, reader = [], []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            pacsv.read_csv(big, read_options=pacsv.ReadOptions(use_threads=False), convert_options=types)
            bare.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            read_cycle_csv(big)
            reader.append(time.perf_counter() - t0)
        print(f"in process: pyarrow typed read_csv {min(bare):.3f} s, cevm.io.read_cycle_csv {min(reader):.3f} s "
              f"({min(reader) / min(bare):.2f}x, best of {args.repeat})")


if __name__ == "__main__":
    main()
