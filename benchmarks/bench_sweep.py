"""Benchmark of fleet sweeps (cevm.core.sweep, ``cevm predict``): predictions per second.

    python benchmarks/bench_sweep.py [--quick]

A realistic fleet decision: 50 heavy vehicles (25 battery-electric trucks, 25 diesel
trucks; kerb 8-20 t, max gross 44 t) x 500 delivery rounds (synthetic 1 Hz micro-trip
cycles of 30 to 110 min, median 59, with hills, cevm_samplegen.cycles) x 14 payloads
(0:26000:2000 kg) = 350,000 predictions. Every EV row has its final and lowest state of charge along the way, every
ICE row whether the fuel fits the tank.

Rolling coefficients are drawn from four EU tyre-label classes of heavy (C3) tyres
(B to E: 0.0045, 0.0055, 0.0065, 0.0075), as vehicle files of a real fleet share tyre
specifications; a second run gives every vehicle its own Cr (its class value +- 0.0005,
as after fitting Cr vehicle by vehicle), the fleet otherwise the same.

Timed, on one core (OMP/BLAS threads set to 1):
1. precompute, once per route: the CE vector from the samples and the compressed step
   terms for the state of charge (SourceSteps);
2. the library sweep (cevm.core.sweep.sweep over all routes, every row with its
   totals, and its SoC or tank check). Target: < 1 s. Measured with the default
   allocator, then again after cevm.runtime.tune_allocator() (what the CLI runs with:
   freed memory kept for reuse, no page faults per new array); then, tuned, the totals
   alone, the sweep with every vehicle its own Cr, and a feasibility matrix;
3. baseline in the same run: a per-prediction loop (cevm.core.vehicle.predict for the total,
   and a numpy cumulative sum over the route's steps for the lowest SoC), on a random
   sample of predictions, extrapolated;
4. the CLI as a subprocess: ``cevm predict -v DIR -r 'bench-*' --store S
   --payload-kg 0:26000:2000 -f csv -o FILE`` (process start, store reads, CSV write).

The sweep's lowest SoC is checked against the baseline's plain cumulative sums on the
sample (largest difference printed).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from cevm.cli.values import parse_values  # noqa: E402
from cevm.core.cycle import step_terms  # noqa: E402
from cevm.core.feasibility import feasibility  # noqa: E402
from cevm.core.sweep import PredictionSet, Source, predict_source, sweep  # noqa: E402
from cevm.core.vehicle import Vehicle, predict  # noqa: E402
from cevm.executors import ProcessExecutor  # noqa: E402
from cevm.runtime import tune_allocator  # noqa: E402
from cevm_samplegen.cycles import MicroTripSpec, micro_trip_cycle  # noqa: E402

TYRE_CR = (0.0045, 0.0055, 0.0065, 0.0075)


def make_routes(n: int, seed: int = 7):
    rng = np.random.default_rng(seed)
    routes = []
    for i in range(n):
        kind = rng.integers(3)
        if kind == 0:  # urban multi-drop
            spec = MicroTripSpec(n_trips=int(rng.integers(25, 60)), cruise_kmh=(20.0, 50.0), cruise_s=(10.0, 60.0),
                                 dwell_s=(20.0, 90.0), hill_amplitude_m=float(rng.uniform(3, 25)))
        elif kind == 1:  # regional
            spec = MicroTripSpec(n_trips=int(rng.integers(8, 16)), cruise_kmh=(50.0, 85.0), cruise_s=(60.0, 300.0),
                                 dwell_s=(10.0, 60.0), accel_mps2=(0.3, 0.6), decel_mps2=(0.5, 0.9),
                                 hill_amplitude_m=float(rng.uniform(10, 40)), hill_wavelength_m=(2000.0, 8000.0))
        else:  # mixed
            spec = MicroTripSpec(n_trips=int(rng.integers(15, 30)), cruise_kmh=(30.0, 70.0), cruise_s=(20.0, 150.0),
                                 dwell_s=(10.0, 60.0), hill_amplitude_m=float(rng.uniform(5, 30)))
        routes.append(micro_trip_cycle(spec, seed=1000 + i, name=f"bench-{i:03d}"))
    return routes


def make_vehicles(n: int, seed: int = 11, *, distinct_cr: bool = False) -> list[Vehicle]:
    rng = np.random.default_rng(seed)
    rng_cr = np.random.default_rng(seed + 1)  # the same fleet but for Cr, either way
    out = []
    for i in range(n):
        ev = i % 2 == 0
        kerb = float(rng.uniform(9000, 20000) if ev else rng.uniform(8000, 18000))
        tyre = rng_cr.integers(len(TYRE_CR))
        cr = float(TYRE_CR[tyre] + rng_cr.uniform(-0.0005, 0.0005) * distinct_cr)
        common = dict(name=f"{'EV' if ev else 'DI'}-{i:02d}", mass_kg=kerb, kerb_mass_kg=kerb, max_gross_kg=44000.0,
                      cda_m2=float(rng.uniform(4.5, 7.0)), cr=cr)
        if ev:
            out.append(Vehicle(powertrain="ev", eta=float(rng.uniform(0.75, 0.88)),
                               battery_j=float(rng.uniform(300, 600)) * 3.6e6,
                               aux_power_w=float(rng.choice([0.0, 2000.0, 5000.0])), **common))
        else:
            out.append(Vehicle(powertrain="ice", eta=float(rng.uniform(0.40, 0.46)), fuel_lhv_j_per_l=35.8e6,
                               tank_l=float(rng.choice([300.0, 400.0, 600.0])),
                               ice_braking=str(rng.choice(["paper", "no-credit"])), **common))
    return out


def write_vehicle_toml(v: Vehicle, path: Path) -> None:
    lines = [f'name = "{v.name}"', f'powertrain = "{v.powertrain}"', f"kerb_mass_kg = {v.kerb_mass_kg!r}",
             f"max_gross_kg = {v.max_gross_kg!r}", f"cda_m2 = {v.cda_m2!r}", f"cr = {v.cr!r}", f"eta = {v.eta!r}"]
    if v.is_ev:
        lines += [f"battery_kwh = {v.battery_j / 3.6e6!r}", f"aux_power_kw = {v.aux_power_w / 1e3!r}"]
    else:
        lines += [f"fuel_lhv_mj_per_l = {v.fuel_lhv_j_per_l / 1e6!r}", f'ice_braking = "{v.ice_braking}"',
                  f"tank_l = {v.tank_l!r}"]
    path.write_text("\n".join(lines) + "\n")


def library_sweep(sources, pset, executor=None):
    n = 0
    worst = np.inf
    for b in sweep(sources, pset, executor=executor):
        n += b.n
        worst = min(worst, float(np.nanmin(b.soc_min_pct)))
    return n, worst


def plain_prediction(cyc, veh, m):
    """Baseline: the CE total by cevm.core.vehicle.predict, the lowest SoC by a cumulative sum
    over every step of the route."""
    vec = cyc["vector"]
    pred = predict(vec, veh, m)
    st = cyc["terms"]
    x = st.k + st.e
    d = m * (x + veh.cr * st.r) + veh.cda_m2 * st.a
    if veh.is_ev:
        d = np.where(cyc["ns"] & (d <= 0), veh.eta**2 * d, d)
        e = np.cumsum(d / veh.eta + veh.aux_power_w * st.dt)
        return float(pred.energy_j), 100.0 - 100.0 * max(0.0, float(e.max())) / veh.battery_j
    return float(pred.fuel_l), np.nan


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="100 routes and 10 vehicles (a smoke run)")
    ap.add_argument("--no-cli", action="store_true", help="skip the CLI subprocess")
    args = ap.parse_args()
    n_routes, n_veh = (100, 10) if args.quick else (500, 50)
    payloads = parse_values("0:26000:2000", "--payload-kg")

    t0 = time.perf_counter()
    cycles = make_routes(n_routes)
    t_gen = time.perf_counter() - t0
    n_samples = sum(c.time_s.size for c in cycles)
    vehicles = make_vehicles(n_veh)
    pset = PredictionSet.build(vehicles, payload_kg=payloads)
    n_pred = n_routes * pset.n
    print(f"fleet sweep: {n_veh} vehicles x {n_routes} routes x {payloads.size} payloads = {n_pred:,} predictions")
    print(f"routes: {n_samples:,} samples at 1 Hz ({n_samples / n_routes / 60:.0f} min per route on average), "
          f"generated in {t_gen:.1f} s")

    t0 = time.perf_counter()
    sources = [Source.from_cycle(c) for c in cycles]
    t_vec = time.perf_counter() - t0
    t0 = time.perf_counter()
    for s in sources:
        s.steps  # noqa: B018  (build and cache)
    t_steps = time.perf_counter() - t0
    nel = sum(s.steps.n_elements for s in sources)
    print(f"precompute once per route: CE vectors {t_vec:.3f} s, step terms for the SoC {t_steps:.3f} s "
          f"({n_samples / (t_vec + t_steps) / 1e6:.1f} M samples/s; {nel / n_samples:.2f} elements per step)")

    times, cpu = [], []
    for _ in range(5):
        t0, c0 = time.perf_counter(), time.process_time()
        n, worst = library_sweep(sources, pset)
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    assert n == n_pred
    t_lib = min(times)
    print(f"library sweep (best of 5): {t_lib:.3f} s = {n_pred / t_lib:,.0f} predictions/s [target < 1 s]  "
          f"(CPU time {min(cpu):.3f} s; median wall {float(np.median(times)):.3f} s; lowest SoC seen {worst:.1f} %)")
    # the same with the allocator settings the CLI applies (cevm.runtime); the lines
    # below are measured with them too
    tuned = tune_allocator()
    times = []
    for _ in range(5):
        t0 = time.perf_counter()
        library_sweep(sources, pset)
        times.append(time.perf_counter() - t0)
    t_tuned = min(times)
    print(f"  with cevm.runtime.tune_allocator() (as the CLI runs; applied: {tuned}): {t_tuned:.3f} s = "
          f"{n_pred / t_tuned:,.0f} predictions/s ({t_lib / t_tuned:.2f}x)")
    t0 = time.perf_counter()
    for _ in sweep(sources, pset, lowest_soc=False):
        pass
    t_tot = time.perf_counter() - t0
    print(f"  of which CE totals alone (lowest_soc=False): {t_tot:.3f} s")
    # the batches on 2 worker processes (cevm predict --workers 2), warm; the step terms
    # are built here anyway (above), so this is the evaluation alone
    with ProcessExecutor(2) as ex:
        library_sweep(sources[:10], pset, ex)  # start the workers
        times = []
        for _ in range(3):
            t0 = time.perf_counter()
            library_sweep(sources, pset, ex)
            times.append(time.perf_counter() - t0)
    t_pool = min(times)
    print(f"  on 2 worker processes (best of 3): {t_pool:.3f} s = {n_pred / t_pool:,.0f} predictions/s "
          f"({t_tuned / t_pool:.2f}x one process)")

    veh_d = make_vehicles(n_veh, distinct_cr=True)
    pset_d = PredictionSet.build(veh_d, payload_kg=payloads)
    t0 = time.perf_counter()
    library_sweep(sources, pset_d)
    t_d = time.perf_counter() - t0
    print(f"library sweep, every vehicle its own Cr: {t_d:.3f} s = {n_pred / t_d:,.0f} predictions/s")

    # feasibility from 40 % state of charge (so that the reserve binds often) and with a
    # 30 l tank for the diesel trucks: the largest payload is searched, to the kg
    n_feas = 50 if not args.quick else 10
    lean = [dataclasses.replace(v, tank_l=30.0) if not v.is_ev else v for v in vehicles]
    t0 = time.perf_counter()
    limits: dict[str, int] = {}
    for s in sources[:n_feas]:
        for why in feasibility(s, lean, soc_start_pct=40.0).limited_by:
            limits[why] = limits.get(why, 0) + 1
    t_f = time.perf_counter() - t0
    print(f"feasibility matrix ({n_veh} vehicles x {n_feas} routes, from 40 % SoC, largest payload to the kg): "
          f"{t_f:.2f} s = {t_f / n_feas * 1e3:.0f} ms per route; limited by {limits}")

    # baseline: per-prediction loop on a sample
    rng = np.random.default_rng(3)
    k = 3000 if not args.quick else 600
    picks = rng.integers(0, n_routes, k), rng.integers(0, pset.n, k)
    cache = {}
    for r in set(picks[0].tolist()):
        c = cycles[r]
        st = step_terms(c.time_s, c.speed_mps, c.elevation_m)
        cache[r] = {"vector": sources[r].vector, "terms": st,
                    "ns": (st.k + st.e + sources[r].vector.cr0 * st.r) <= 0}
    t0 = time.perf_counter()
    base = [plain_prediction(cache[r], vehicles[pset.vehicle_index[p]], float(pset.mass_kg[p]))
            for r, p in zip(*picks, strict=True)]
    t_base = time.perf_counter() - t0
    rate_base = k / t_base
    print(f"baseline per-prediction loop: {rate_base:,.0f} predictions/s "
          f"(would take {n_pred / rate_base:.1f} s for the sweep; sweep is {n_pred / t_lib / rate_base:.0f}x faster)")
    # check against the baseline
    blocks = {}
    for r in set(picks[0].tolist()):
        blocks[r] = predict_source(sources[r], pset)
    diffs_e, diffs_soc = [], []
    for (r, p), (val, soc) in zip(zip(*picks, strict=True), base, strict=True):
        b = blocks[r]
        got = b.energy_j[p] if pset.is_ev[p] else b.fuel_l[p]
        diffs_e.append(abs(got - val) / abs(val))
        if pset.is_ev[p]:
            diffs_soc.append(abs(b.soc_min_pct[p] - soc))
    print(f"check on the sample: largest relative difference of totals {max(diffs_e):.1e}, "
          f"largest difference of the lowest SoC {max(diffs_soc):.1e} percentage points")

    if args.no_cli:
        return
    from cevm.store import TripStore
    from cevm.store.routes import CycleLeg, add_route

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        vdir = tmp / "vehicles"
        vdir.mkdir()
        for v in vehicles:
            write_vehicle_toml(v, vdir / f"{v.name}.toml")
        store = tmp / "bench.sqlite"
        t0 = time.perf_counter()
        with TripStore.open(store) as st:
            for c in cycles:
                add_route(st, c.name, [CycleLeg(c, ref=f"<synthetic {c.name}>")])
        t_store = time.perf_counter() - t0
        out = tmp / "sweep.csv"
        cmd = [sys.executable, "-m", "cevm", "predict", "-v", str(vdir), "-r", "bench-*", "--store", str(store),
               "--payload-kg", "0:26000:2000", "-f", "csv", "-o", str(out)]
        env = dict(os.environ, PYTHONPATH=str(ROOT / "src"))
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
        t_cli = time.perf_counter() - t0
        if proc.returncode != 0:
            print(proc.stderr)
            raise SystemExit("CLI failed")
        with open(out, "rb") as fh:
            rows = sum(1 for _ in fh) - 1
        assert rows == n_pred, (rows, n_pred)
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", "import cevm.cli"], env=env, check=True)
        t_import = time.perf_counter() - t0
        print(f"CLI to CSV (subprocess, {out.stat().st_size / 1e6:.1f} MB, {rows:,} rows): {t_cli:.2f} s = "
              f"{n_pred / t_cli:,.0f} predictions/s (of which Python start + imports {t_import:.2f} s; "
              f"storing the {n_routes} routes beforehand took {t_store:.1f} s)")


if __name__ == "__main__":
    main()
