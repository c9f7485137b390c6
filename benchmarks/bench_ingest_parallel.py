"""Benchmark of parallel ingest: serial vs a local process pool vs a Dask LocalCluster.

    python benchmarks/bench_ingest_parallel.py [--quick] [--vehicles N] [--days D]
                                               [--workers W] [--repeat R] [--no-dask]
                                               [--short-days] [--days-per-file K]
                                               [--small-repeat R]

Generates a fleet of srf logs with ``cevm_samplegen.fleet_for_benchmark`` (default 40
vehicles x 5 working days, one file per vehicle-day of 4-6 h of driving, ~17,000
samples: 3.4e6 samples, with its DSM tiles; ``--quick``: 8 x 2), then ingests it into a
fresh store with :func:`cevm.ingest.ingest`, DSM lookup included:

- ``serial``: one process (:class:`~cevm.executors.SerialExecutor`, ``--workers 1``),
  single-threaded BLAS like the workers (set before numpy loads);
- ``pool``: ``W`` worker processes (:class:`~cevm.executors.ProcessExecutor`), default 2,
  with small files grouped into tasks of about :data:`~cevm.executors.TASK_S` of work
  (estimated from their sizes, as ``cevm ingest`` does); ``pool 1/file``: one file per
  task (``task_s=0``), the baseline before grouping; ``pool warm``: the grouped pool's
  workers again (DSM samplers open, imports done: the steady state of a long run);
- ``dask``: a LocalCluster of ``W`` worker processes x 1 thread on 127.0.0.1
  (:class:`~cevm.executors.DaskExecutor`), started before the clock starts, grouped;
  ``dask 1/file`` one file per task; ``dask warm``: the same workers again;
- ``2 x serial``: the fleet split in two halves ingested by two independent serial
  processes at once, into two stores: what this machine gives two processes running
  this workload with no executor, no single writer and no pickling at all. It is the
  ceiling against which the pool's overhead is judged;
- the small batch (``--small-repeat``): whole ``cevm ingest`` commands on 16 files of
  ~1.4 h (~80,000 samples), the default number of workers against ``--workers 1`` and
  ``--workers 2`` (the old default here), interleaved.

Task size matters (the per-task cost of a Dask cluster is fixed, ~5-10 ms of CPU here,
and so is each new worker's start: transformer, DSM blocks): ``--short-days`` makes
the vehicle-days the sample fleet's (2-3 trips, ~1.4 h of driving, ~5,000 samples,
~20 ms of work per file: 1e6 samples in all), ``--days-per-file K`` merges K days of a
vehicle into one file, for tasks K times bigger. The issue's own fleet logs 16 h a day
at 1 Hz: 57,600 samples per bus-day.

Every process runs with :func:`cevm.runtime.tune_allocator` applied, as under the
``cevm`` command (this one and the ``2 x serial`` children at start, workers on their
first task), so the serial baseline is the command's own.

Every run starts cold (DSM blocks not yet read), as a ``cevm ingest`` command does: a
new pool each time (the pool's start-up, ~30 ms once the forkserver runs, is counted;
the forkserver's own start, ~0.5 s once per command, is printed apart), and a new Dask
LocalCluster before each cold run (not counted: a cluster outlives the runs). Each mode runs
``R`` times interleaved (default 2, ``--quick``: 1); the best wall time
is shown, and the medians. Samples/s, the speed-up and the efficiency (speed-up / W) are against the
serial run of the same invocation. Also printed: the CPU seconds used by this process
tree (psutil, if installed) and by the whole machine, with the hypervisor's steal time
(/proc/stat): other programs on a shared machine show up there. The stores of the
three modes are compared (trips, vectors and profiles must be identical).

Targets (issues 9 and 18): pool >= 1.7x the serial throughput on 2 cores on working
days; Dask overhead under 15 % against the pool on ``--short-days``; the default never
slower than ``--workers 1`` on the small batch.
"""

from __future__ import annotations

import argparse
import json
import os
import sqlite3
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

# One BLAS thread everywhere, as the pool and Dask workers have (cevm.executors.WORKER_ENV):
# the serial baseline is then one core, and the "2 x serial" children do not spin
# OpenBLAS threads against each other.
for _k in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_k, "1")

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from cevm.executors import TASK_S, DaskExecutor, ProcessExecutor, SerialExecutor, Task, local_dask_cluster  # noqa: E402
from cevm.ingest import IngestOptions, ingest  # noqa: E402
from cevm.runtime import tune_allocator  # noqa: E402
from cevm.store import TripStore  # noqa: E402

try:
    import psutil
except ImportError:  # CPU accounting is optional
    psutil = None


# ------------------------------------------------------------------------ accounting


def machine_ticks() -> dict:
    """Cumulative CPU time of the whole machine [s] from /proc/stat (Linux)."""
    try:
        fields = [int(x) for x in Path("/proc/stat").read_text().splitlines()[0].split()[1:]]
    except OSError:
        return {}
    hz = os.sysconf("SC_CLK_TCK")
    user, nice, system, idle, iowait, irq, softirq, steal = (fields + [0] * 8)[:8]
    return {"busy": (user + nice + system + irq + softirq) / hz, "idle": (idle + iowait) / hz, "steal": steal / hz}


def tree_cpu_s() -> dict[int, float]:
    """CPU seconds of this process and of each live descendant (pool and Dask
    workers), by pid."""
    if psutil is None:
        return {}
    me = psutil.Process()
    out = {}
    for p in [me, *me.children(recursive=True)]:
        try:
            t = p.cpu_times()
            out[p.pid] = t.user + t.system
        except psutil.Error:
            pass
    return out


class Meter:
    def __enter__(self):
        self.t0, self.cpu0, self.m0 = time.perf_counter(), tree_cpu_s(), machine_ticks()
        return self

    def stop(self) -> None:  # before the workers exit: their CPU time is read from them
        self.wall = time.perf_counter() - self.t0
        cpu1 = tree_cpu_s()
        self.main_cpu = cpu1.get(os.getpid(), float("nan")) - self.cpu0.get(os.getpid(), float("nan"))
        self.cpu = sum(v - self.cpu0.get(k, 0.0) for k, v in cpu1.items()) if cpu1 else float("nan")
        m1 = machine_ticks()
        self.machine = {k: m1[k] - self.m0[k] for k in m1}

    def __exit__(self, *exc):
        if not hasattr(self, "wall"):
            self.stop()


# --------------------------------------------------------------------------- the runs


def run_ingest(files, store: Path, dsm: str, executor) -> tuple[dict, Meter]:
    with TripStore(store) as st, Meter() as m:
        report = ingest(files, st, IngestOptions(dsm=dsm), executor=executor)
        m.stop()
    return report.summary(), m


def run_two_serial(files, stores: list[Path], dsm: str) -> tuple[int, Meter]:
    """Two independent serial ingest processes on the two halves of ``files``, started
    together once both have imported cevm; their CPU time is what they report."""
    halves = [files[0::2], files[1::2]]
    procs = [subprocess.Popen([sys.executable, __file__, "--child", str(s), dsm, *map(str, h)],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
             for s, h in zip(stores, halves, strict=True)]
    for p in procs:
        assert p.stdout.readline().strip() == "ready"
    with Meter() as m:
        for p in procs:
            p.stdin.write("go\n")
            p.stdin.flush()
        outs = [json.loads(p.communicate()[0]) for p in procs]
        m.stop()
    if any(p.returncode for p in procs):
        raise SystemExit("a serial child failed")
    m.cpu = sum(o["cpu_s"] for o in outs)
    m.main_cpu = float("nan")
    return sum(o["samples"] for o in outs), m


def child(argv: list[str]) -> None:
    store, dsm, *files = argv
    tune_allocator()  # as the cevm command does
    print("ready", flush=True)
    sys.stdin.readline()
    cpu0 = time.process_time()
    with TripStore(store) as st:
        report = ingest(files, st, IngestOptions(dsm=dsm), executor=SerialExecutor())
    print(json.dumps({**report.summary(), "cpu_s": time.process_time() - cpu0}))


def store_content(path: Path) -> tuple:
    con = sqlite3.connect(path)
    try:
        return (con.execute("SELECT * FROM trips ORDER BY trip_id").fetchall(),
                con.execute("SELECT * FROM trip_blobs ORDER BY trip_id").fetchall())
    finally:
        con.close()


def generate(outdir: Path, n_vehicles: int, n_days: int, full_days: bool) -> tuple[list[Path], str]:
    try:
        from cevm_samplegen import fleet_for_benchmark
    except ImportError:
        raise SystemExit("cevm_samplegen.fleet_for_benchmark is needed to generate the fleet") from None
    t0 = time.perf_counter()
    truth = fleet_for_benchmark(n_vehicles, n_days, outdir / "fleet", dsm_dir=outdir / "dsm", full_days=full_days)
    files = sorted((outdir / "fleet").rglob("*.csv"))
    print(f"fleet: {n_vehicles} vehicles x {n_days} {'working' if full_days else 'short'} days = "
          f"{len(files)} srf files, {truth['rows']:,} rows, "
          f"{truth['bytes'] / 1e6:.0f} MB; {len(truth['dsm_tiles'])} DSM tiles "
          f"(generated in {time.perf_counter() - t0:.1f} s)")
    return files, str(outdir / "dsm")


def merge_days(files: list[Path], per_file: int, outdir: Path) -> list[Path]:
    """Bigger tasks: ``per_file`` consecutive days of a vehicle in one srf file (the
    first day's header, then every day's rows), as a logger that uploads weekly makes."""
    outdir.mkdir()
    by_vehicle: dict[str, list[Path]] = {}
    for f in files:
        by_vehicle.setdefault(f.name.split("_")[0], []).append(f)
    merged = []
    for vid, days in by_vehicle.items():
        for k in range(0, len(days), per_file):
            group = days[k : k + per_file]
            parts = []
            for j, f in enumerate(group):
                lines = f.read_text().splitlines(keepends=True)
                head = next(i for i, ln in enumerate(lines) if not ln.startswith("#")) + 1  # comments + column names
                parts.extend(lines if j == 0 else lines[head:])
            out = outdir / f"{vid}_{k // per_file:03d}.csv"
            out.write_text("".join(parts))
            merged.append(out)
    print(f"merged into {len(merged)} files of {per_file} days each")
    return sorted(merged)


def line(name: str, samples: int, m: Meter, serial_rate: float | None, workers: int) -> float:
    rate = samples / m.wall
    extra = ""
    if serial_rate:
        speedup = rate / serial_rate
        extra = f"  x{speedup:4.2f}  eff {100 * speedup / workers:3.0f} %"
    mach = m.machine
    others = mach.get("busy", float("nan")) - m.cpu
    print(f"  {name:<11} {m.wall:7.2f} s  {rate / 1e3:7.0f} k samples/s{extra:<22}"
          f" cpu ours {m.cpu:5.2f} s (this process {m.main_cpu:4.2f}), machine busy "
          f"{mach.get('busy', float('nan')):6.2f} s "
          f"(others ~{others:5.2f}), steal {mach.get('steal', float('nan')):4.2f} s")
    return rate


def small_batch(tmp: Path, repeat: int) -> None:
    """Whole ``cevm ingest`` commands on 16 files of ~1.4 h (8 vehicles x 2 days,
    ~80,000 samples, DSM included): the default number of workers against
    ``--workers 1`` and ``--workers 2`` (the old default on this machine: every core),
    interleaved, each into a fresh store."""
    files, dsm = generate(tmp / "small", 8, 2, full_days=False)
    logs = files[0].parent
    modes = {"default": [], "--workers 1": ["--workers", "1"], "--workers 2": ["--workers", "2"]}
    walls: dict[str, list[float]] = {m: [] for m in modes}
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src") + os.pathsep + os.environ.get("PYTHONPATH", "")}
    for rep in range(repeat):
        for name, opt in modes.items():
            store = tmp / "small" / f"{name.strip('-').replace(' ', '')}-{rep}.sqlite"
            t0 = time.perf_counter()
            subprocess.run([sys.executable, "-m", "cevm", "ingest", str(logs), "--dsm", dsm, "--store", str(store),
                            "-q", *opt], check=True, env=env, stdout=subprocess.DEVNULL)
            walls[name].append(time.perf_counter() - t0)
    print(f"\nsmall batch, whole commands ({len(files)} files, {repeat} runs each, interleaved; min-max, median):")
    med = {m: statistics.median(v) for m, v in walls.items()}
    for name, v in walls.items():
        print(f"  cevm ingest {name:<12} {min(v):5.2f}-{max(v):5.2f} s, median {med[name]:5.2f} s")
    print(f"  default / --workers 1: x{med['default'] / med['--workers 1']:.2f} (median; target <= 1), "
          f"old default (--workers 2) / --workers 1: x{med['--workers 2'] / med['--workers 1']:.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="8 vehicles x 2 days, one repeat")
    ap.add_argument("--vehicles", type=int, default=None)
    ap.add_argument("--days", type=int, default=None)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=None)
    ap.add_argument("--no-dask", action="store_true")
    ap.add_argument("--short-days", action="store_true",
                    help="the sample fleet's ~1.4 h vehicle-days (5,000 samples a file) instead of working days")
    ap.add_argument("--days-per-file", type=int, default=1,
                    help="merge this many days of a vehicle into one file: bigger tasks (default 1)")
    ap.add_argument("--small-repeat", type=int, default=None,
                    help="runs of each command of the small-batch case (default 5, --quick 1; 0: skip it)")
    ap.add_argument("--child", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child is not None:
        return child(args.child)
    # The serial run and the writer run as under the cevm command, which tunes the
    # allocator at start (pool and Dask workers do it on their first task); without it
    # the serial baseline pays ~7 % in page faults that the workers do not.
    print(f"allocator tuned as the CLI runs: {tune_allocator()}")
    n_veh = args.vehicles or (8 if args.quick else 40)
    n_days = args.days or (2 if args.quick else 5)
    repeat = args.repeat or (1 if args.quick else 2)
    small_repeat = args.small_repeat if args.small_repeat is not None else (1 if args.quick else 5)
    w = args.workers
    dask_ok = not args.no_dask
    if dask_ok:
        try:
            import distributed  # noqa: F401
        except ImportError:
            print("(distributed not installed: no Dask run; pip install 'cevm[dask]')")
            dask_ok = False
    print(f"machine: {os.cpu_count()} CPUs; load average before: {os.getloadavg()[0]:.2f}")

    with tempfile.TemporaryDirectory(prefix="cevm-bench-par-") as tmp:
        tmp = Path(tmp)
        files, dsm = generate(tmp, n_veh, n_days, full_days=not args.short_days)
        if args.days_per_file > 1:
            files = merge_days(files, args.days_per_file, tmp / "merged")
        pool = ProcessExecutor(w)
        t0 = time.perf_counter()
        list(pool.run(abs, [Task(str(i), (i,)) for i in range(w)]))  # forkserver + preload
        print(f"process pool start-up (forkserver importing cevm, first use in a process): "
              f"{time.perf_counter() - t0:.2f} s, not counted below")
        cluster = client_ex = None
        if dask_ok:
            t0 = time.perf_counter()
            cluster = local_dask_cluster(w, 1, processes=True)
            client_ex = DaskExecutor(cluster.scheduler_address)
            list(client_ex.run(abs, [Task(str(i), (i,)) for i in range(w)]))
            print(f"Dask LocalCluster start-up ({w} workers x 1 thread): {time.perf_counter() - t0:.2f} s, not counted")

        best: dict[str, tuple] = {}
        walls: dict[str, list[float]] = {}
        stage = {}
        stores = {}
        for rep in range(repeat):
            modes = ["serial", "pool 1/file", "pool", "pool warm"] + (
                ["dask 1/file", "dask", "dask warm"] if dask_ok else [])
            for name in modes:
                # every run starts cold, as a cevm ingest command does: a new pool (the
                # forkserver stays: its start-up is printed above) and a new Dask
                # cluster, so no worker keeps a DSM sampler warm from the previous run.
                # "1/file": one file per task (task_s = 0), the old baseline; the others
                # group small files into tasks of cevm.executors.TASK_S of work.
                if name.startswith("pool") and name != "pool warm":
                    pool.close()
                    ex = pool = ProcessExecutor(w, task_s=0.0 if name == "pool 1/file" else TASK_S)
                elif name in ("dask", "dask 1/file"):
                    # a new cluster, not client.restart(): here a restart after a local
                    # pool has run sometimes never gets its workers back (seen with the
                    # executors of main too), and the benchmark then hangs
                    client_ex.close()
                    cluster.close()
                    cluster = local_dask_cluster(w, 1, processes=True)
                    ex = client_ex = DaskExecutor(cluster.scheduler_address,
                                                  task_s=0.0 if name == "dask 1/file" else TASK_S)
                    list(ex.run(abs, [Task(str(i), (i,)) for i in range(w)]))  # workers up
                elif name == "pool warm":  # the same workers again: their DSM samplers are open
                    ex = pool
                elif name == "dask warm":
                    ex = client_ex
                else:
                    ex = SerialExecutor()
                store = tmp / f"{name.replace(' ', '-').replace('/', '-')}-{rep}.sqlite"
                submitted0 = ex.submitted
                summary, m = run_ingest(files, store, dsm, ex)
                if name == "pool":
                    n_groups = ex.submitted - submitted0
                if summary["failed"]:
                    raise SystemExit(f"{name}: {summary['failed']} files failed")
                stores[name] = store
                if name == "serial":
                    stage = summary["stage_s"]
                walls.setdefault(name, []).append(m.wall)
                if name not in best or m.wall < best[name][1].wall:
                    best[name] = (summary["samples"], m)
            samples2, m2 = run_two_serial(files, [tmp / f"half{k}-{rep}.sqlite" for k in range(2)], dsm)
            walls.setdefault("2 x serial", []).append(m2.wall)
            if "2 x serial" not in best or m2.wall < best["2 x serial"][1].wall:
                best["2 x serial"] = (samples2, m2)

        print(f"\ningest of {best['serial'][0]:,} samples in {len(files)} files ({n_groups} tasks of about "
              f"{TASK_S * 1e3:.0f} ms of estimated work or more, when grouped), best of {repeat} "
              f"(wall; throughput; vs serial):")
        serial_rate = line("serial", *best["serial"], None, 1)
        rates = {}
        for name in ("pool 1/file", "pool", "pool warm", "dask 1/file", "dask", "dask warm", "2 x serial"):
            if name in best:
                rates[name] = line(name.replace("pool", f"pool x{w}"), *best[name], serial_rate, w)
        total_stage = sum(stage.values())
        print("\nserial stages [s]: " + ", ".join(f"{k} {v:.2f}" for k, v in stage.items())
              + f"; the writer's share (store) {100 * stage.get('store', 0) / max(total_stage, 1e-9):.0f} %")
        ceiling = rates.get("2 x serial", float("nan")) / serial_rate
        print(f"pool: x{rates['pool'] / serial_rate:.2f} vs serial (one file per task: "
              f"x{rates['pool 1/file'] / serial_rate:.2f}), x{rates['pool warm'] / serial_rate:.2f} with warm "
              f"workers (target >= 1.7 on 2 cores); two independent serial processes reach x{ceiling:.2f} "
              f"on this machine now")
        if len(files) > n_groups:
            saved = best["pool 1/file"][1].cpu - best["pool"][1].cpu
            print(f"pool CPU (this process and workers) one file per task minus grouped: {saved:+.2f} s, "
                  f"{1e3 * saved / (len(files) - n_groups):+.1f} ms per task saved")
        if repeat > 1:
            med = {k: statistics.median(v) for k, v in walls.items()}
            print("median walls [s]: " + ", ".join(f"{k} {v:.2f}" for k, v in med.items())
                  + f"; pool x{med['serial'] / med['pool']:.2f} (1/file x{med['serial'] / med['pool 1/file']:.2f}), "
                    f"warm x{med['serial'] / med['pool warm']:.2f}"
                  + (f"; dask overhead vs pool {100 * (med['dask'] / med['pool'] - 1):+.0f} % (1/file vs 1/file "
                     f"{100 * (med['dask 1/file'] / med['pool 1/file'] - 1):+.0f} %), warm "
                     f"{100 * (med['dask warm'] / med['pool warm'] - 1):+.0f} %" if "dask" in med else ""))
        if "dask" in rates:
            cpu_ms = 1e3 * (best["dask"][1].cpu - best["pool"][1].cpu) / n_groups
            cpu_ms_1 = 1e3 * (best["dask 1/file"][1].cpu - best["pool 1/file"][1].cpu) / len(files)
            print(f"dask overhead vs the pool: {100 * (rates['pool'] / rates['dask'] - 1):+.0f} % cold, "
                  f"{100 * (rates['pool warm'] / rates['dask warm'] - 1):+.0f} % warm (target < 15 %); one file "
                  f"per task: {100 * (rates['pool 1/file'] / rates['dask 1/file'] - 1):+.0f} % cold; extra CPU "
                  f"{cpu_ms:.1f} ms per grouped task, {cpu_ms_1:.1f} ms per file-task of "
                  f"{best['serial'][0] / len(files):,.0f} samples ({1e3 * best['serial'][1].wall / len(files):.0f} ms "
                  f"serial)")
        print(f"per-core throughput (serial): {serial_rate / 1e3:.0f} k samples/s")
        compared = [n for n in ("pool 1/file", "pool", "dask 1/file", "dask") if n in stores]
        same = [n for n in compared if store_content(stores[n]) == store_content(stores["serial"])]
        print(f"stores identical to the serial one: {', '.join(same) or 'none'}"
              f"{'' if len(same) == len(compared) else '  <-- MISMATCH'}")
        pool.close()
        if client_ex is not None:
            client_ex.close()
            cluster.close()
        if small_repeat:
            small_batch(tmp, small_repeat)
        print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
