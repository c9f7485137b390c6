"""Benchmark of ``cevm replay`` (cevm.core.replay): a fleet-year of duties, from cached
vectors, on one core.

    python benchmarks/bench_replay.py [--quick]

A fleet-year: 100 logged trucks x 250 working days x 3-7 trips a day (about 125,000
trips, 25,000 duties), each trip one of a pool of 60 synthetic 1 Hz micro-trip cycles with
hills (cevm_samplegen.cycles; 20-70 min), at its own gross mass (20-44 t) and temperature
(a seasonal -5 to 25 degC); stops of 10-90 min between trips. The candidate: the shipped
battery-electric tractor (configs/vehicles/electric-truck.toml) with a 200 kWh battery (so
that some duties fail) and a 50 kW charger at stops of 30 min or more; its spread a
stated one (eta and aux uncertain, 0.8 kW of auxiliary scatter, 5 % of the energy,
within-day correlation 0.5), as a calibrated file would give it.

"From cached vectors": the pool's CE vectors and step tables are built once, beforehand
(a store holds the vectors; a replay reads step tables only for the few trips whose
lowest point could decide anything: counted below).

Timed, on one core (OMP/BLAS threads 1):
1. the duties run (cevm.core.replay.plan_vehicle, vehicle by vehicle): the trips'
   energies from their vectors, the levels carried with charging, the lowest points exact,
   where failing duties cross the reserve, and every duty's battery and charger needs to
   1 kWh / 1 kW (the battery-size sweep); the same with the lowest level at the trips'
   ends only (``--within-trips ends``: no step table); then the battery-size sweep again
   on its own (sizing.battery_needed over all duties), in microseconds per duty;
2. the Monte Carlo of p_complete, 2000 draws per duty (--quick: 500);
3. baselines in the same run: (a) today's cevm path, each trip predicted alone at its own
   mass (cevm.core.sweep.predict_source with a one-row prediction set, as ``cevm predict
   --vehicle-id`` does) and the duty's levels summed in a Python loop, on a sample of
   vehicles, extrapolated; (b) the battery-size sweep by brute force, every size from 1
   kWh to the largest need, each a run of all duties' chains, on a sample of duties;
4. the Monte Carlo on 2 worker processes (cevm.executors), checked identical to the
   serial run.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from cevm.core.cycle import drive_cycle_vector  # noqa: E402
from cevm.core.replay import (  # noqa: E402
    Charging,
    LoggedTrips,
    ReplaySettings,
    TripSpread,
    battery_needed,
    p_complete,
    plan_vehicle,
)
from cevm.core.sweep import LegProfile, PredictionSet, Source, build_step_table, predict_source  # noqa: E402
from cevm.executors import ProcessExecutor, Task  # noqa: E402
from cevm.io import load_vehicle  # noqa: E402
from cevm_samplegen.cycles import MicroTripSpec, micro_trip_cycle  # noqa: E402

KWH = 3.6e6


def make_pool(n: int, seed: int = 3):
    rng = np.random.default_rng(seed)
    cycles, vectors, tables = [], [], []
    for k in range(n):
        c = micro_trip_cycle(MicroTripSpec(n_trips=int(rng.integers(8, 30)), cruise_kmh=(25.0, 80.0),
                                           cruise_s=(20.0, 180.0), hill_amplitude_m=12.0), seed=100 + k)
        v = drive_cycle_vector(c.time_s, c.speed_mps, c.elevation_m)
        cycles.append(c)
        vectors.append(v)
        tables.append(build_step_table([LegProfile(c.time_s, c.speed_mps, c.elevation_m)], cr0=v.cr0,
                                       physics=v.physics))
    return cycles, vectors, tables


def make_fleet(n_vehicles: int, n_days: int, pool_size: int, seed: int = 5):
    """Per vehicle: (LoggedTrips, pool index of each trip)."""
    rng = np.random.default_rng(seed)
    _, vectors, _ = POOL
    fleet = []
    for v in range(n_vehicles):
        starts, ends, which, mass, temp = [], [], [], [], []
        for d in range(n_days):
            t = 1.5e9 + d * 86400.0 + rng.uniform(5, 8) * 3600
            season = 10.0 - 12.0 * np.cos(2 * np.pi * d / n_days)
            for _ in range(int(rng.integers(3, 8))):
                k = int(rng.integers(pool_size))
                dur = vectors[k].duration_s
                starts.append(t)
                ends.append(t + dur)
                which.append(k)
                mass.append(rng.uniform(20e3, 44e3))
                temp.append(season + rng.normal(0, 3))
                t += dur + rng.uniform(10, 90) * 60
        n = len(starts)
        trips = LoggedTrips(vehicle_id=f"TRK-{v:03d}", trip_ids=tuple(f"TRK-{v:03d}:{i}" for i in range(n)),
                            start_s=np.array(starts), end_s=np.array(ends),
                            distance_m=np.array([vectors[k].distance_m for k in which]),
                            vectors=tuple(vectors[k] for k in which), gross_kg=np.array(mass),
                            payload_kg=np.full(n, np.nan), mass_source=("logged",) * n, ambient_c=np.array(temp))
        fleet.append((trips, np.array(which)))
    return fleet


def spread_of(plan) -> TripSpread:
    """A stated spread, as a calibration would give: eta and aux uncertain (2 coefficients),
    0.8 kW of auxiliary scatter, 5 % of the energy, rho 0.5."""
    e = plan.energies
    n = e.n
    grad = np.stack([e.positive_j - plan.vehicle.eta ** 2 * e.negative_j, e.duration_s], axis=1)
    chol = np.diag([0.02, 300.0])  # sd of 1/eta and of the aux power [W]
    return TripSpread(grad, chol, 0.01, 800.0 * e.duration_s, 0.05 * np.maximum(e.energy, 0), np.zeros(n), 0.5,
                      "posterior", "stated for the benchmark")


def run_plans(fleet, veh, settings):
    _, _, tables = POOL
    plans, reads = [], 0
    for trips, which in fleet:
        calls = []

        def read(i, which=which, calls=calls):
            calls.append(i)
            return tables[int(which[i])]

        plans.append(plan_vehicle(trips, veh, settings, read))
        reads += len(set(calls))
    return plans, reads


def baseline_today(fleet_sample, veh, settings):
    """Each trip predicted alone at its own mass (predict's per-trip path), levels summed
    in Python; returns seconds and duties."""
    cycles, _, _ = POOL
    cap = veh.battery_j
    t0 = time.perf_counter()
    duties = 0
    for trips, which in fleet_sample:
        level, last_day = cap, None
        for i in range(trips.n):
            c = cycles[int(which[i])]
            src = Source(name=trips.trip_ids[i], kind="trip", vector=trips.vectors[i],
                         legs=(LegProfile(c.time_s, c.speed_mps, c.elevation_m),), ambient_c=float(trips.ambient_c[i]))
            b = predict_source(src, PredictionSet.build([veh], mass_kg=[float(trips.gross_kg[i])]))
            day = int(trips.start_s[i] // 86400)
            if day != last_day:
                level, last_day, duties = cap, day, duties + 1
            level = min(cap, level - float(b.energy_j[0]))
            if i + 1 < trips.n and trips.start_s[i + 1] - trips.end_s[i] >= settings.charging.min_dwell_s:
                level = min(cap, level + 0.9 * settings.charging.power_w * (trips.start_s[i + 1] - trips.end_s[i]))
    return time.perf_counter() - t0, duties


def brute_sizes(plans, s, r, eff):
    """Every battery size from 1 kWh up to the largest need, each a run of the duties'
    chains: the smallest that completes each duty."""
    out = []
    for plan in plans:
        lanes = plan.lanes()
        top = int(np.nanmax(plan.battery_needed) / KWH) + 1
        need = np.full(lanes.shape[1], np.nan)
        for k in range(1, top + 1):
            c = k * KWH
            from cevm.core.replay.sizing import lane_lows
            ok = lane_lows(lanes, plan.energies.energy, plan.excess.bound, plan.stops, capacity=c, start=s * c,
                           efficiency=eff) >= r * c
            need = np.where(np.isnan(need) & ok, c, need)
        out.append(need)
    return out


def main() -> None:
    global POOL
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="20 vehicles, 500 draws")
    a = ap.parse_args()
    n_veh, n_days, draws = (20, 250, 500) if a.quick else (100, 250, 2000)
    t = time.perf_counter()
    POOL = make_pool(60)
    fleet = make_fleet(n_veh, n_days, 60)
    n_trips = sum(tr.n for tr, _ in fleet)
    print(f"fleet-year: {n_veh} vehicles x {n_days} days, {n_trips:,} trips from a pool of 60 cached cycles "
          f"(pool and fleet made in {time.perf_counter() - t:.1f} s, not timed)")
    veh = dataclasses.replace(load_vehicle(ROOT / "configs/vehicles/electric-truck.toml"), battery_j=200 * KWH)
    settings = ReplaySettings(charging=Charging(power_w=50e3), draws=draws)
    t = time.perf_counter()
    plans, reads = run_plans(fleet, veh, settings)
    t_plan = time.perf_counter() - t
    n_duties = sum(p.duties.n for p in plans)
    fails = sum(int(np.count_nonzero(p.levels.low < p.reserve)) for p in plans)
    print(f"duties run and sized: {n_duties:,} duties ({fails:,} below the reserve at the mean) in {t_plan:.2f} s = "
          f"{n_duties / t_plan:,.0f} duties/s, {1e6 * t_plan / n_duties:.0f} us a duty; step tables read for "
          f"{reads:,} of {n_trips:,} trips ({100 * reads / n_trips:.1f} %)")
    t = time.perf_counter()
    ends, _ = run_plans(fleet, veh, dataclasses.replace(settings, within_trips=False))
    t_ends = time.perf_counter() - t
    print(f"  the same at the trips' ends only (--within-trips ends, no step table): {t_ends:.2f} s = "
          f"{n_duties / t_ends:,.0f} duties/s; duties below the reserve: "
          f"{sum(int(np.count_nonzero(p.levels.low < p.reserve)) for p in ends):,}")
    s, r = settings.soc_start_pct / 100, settings.reserve_pct / 100
    t = time.perf_counter()
    for p in plans:
        battery_needed(p.lanes(), p.energies.energy, p.excess.bound, p.stops, soc_start=s, reserve=r,
                       efficiency=0.9, step=KWH)
    t_size = time.perf_counter() - t
    print(f"battery-size sweep alone (to 1 kWh, every duty): {t_size:.3f} s = {1e6 * t_size / n_duties:.1f} us a duty")
    plans = [dataclasses.replace(p, spread=spread_of(p)) for p in plans]
    t = time.perf_counter()
    p_serial = [p_complete(p.draw_plan(), draws=draws, seed=23) for p in plans]
    t_mc = time.perf_counter() - t
    draw_trips = draws * n_trips
    print(f"Monte Carlo of p_complete ({draws} draws a duty): {t_mc:.2f} s = {n_duties / t_mc:,.0f} duties/s "
          f"({draw_trips / t_mc / 1e6:.1f} M trip draws/s)")
    print(f"fleet-year on one core: {t_plan + t_mc:.1f} s ({n_duties:,} duties with sizes and p_complete), "
          f"{t_ends + t_mc:.1f} s at the trips' ends only")

    sample = fleet[:2]
    t_base, _ = baseline_today(sample, veh, settings)
    n_sample_trips = sum(tr.n for tr, _ in sample)
    base_per_trip = t_base / n_sample_trips
    print(f"baseline (a): each trip predicted alone, levels in a Python loop: {n_sample_trips:,} trips in "
          f"{t_base:.2f} s, {1e3 * base_per_trip:.2f} ms a trip -> the fleet-year in {base_per_trip * n_trips:.0f} s "
          f"(extrapolated; without sizes nor p): the replay's duties run "
          f"{base_per_trip * n_trips / t_plan:.1f}x faster")
    sample_plans = plans[:2]
    t = time.perf_counter()
    brute = brute_sizes(sample_plans, s, r, 0.9)
    t_brute = time.perf_counter() - t
    d_s = sum(p.duties.n for p in sample_plans)
    t = time.perf_counter()
    bis = [battery_needed(p.lanes(), p.energies.energy, p.excess.bound, p.stops, soc_start=s, reserve=r,
                          efficiency=0.9, step=KWH) for p in sample_plans]
    t_bis = time.perf_counter() - t
    same = all(np.array_equal(a, b) for a, b in zip(brute, bis, strict=True))
    print(f"baseline (b): battery sizes by brute force over every kWh: {1e6 * t_brute / d_s:.0f} us a duty vs "
          f"bisection {1e6 * t_bis / d_s:.1f} us a duty ({t_brute / t_bis:.0f}x); same sizes: {same}")

    with ProcessExecutor(2) as ex:
        t = time.perf_counter()
        tasks = (Task(p.trips.vehicle_id, (p.draw_plan(), draws, 23), cost_s=2e-7 * draws * p.trips.n) for p in plans)
        p_par = [res.value for res in ex.run(p_complete, tasks)]
        t_par = time.perf_counter() - t
    same = all(np.array_equal(a, b) for a, b in zip(p_serial, p_par, strict=True))
    print(f"Monte Carlo on 2 worker processes: {t_par:.2f} s ({t_mc / t_par:.2f}x the serial run); identical to "
          f"serial: {same}")


POOL = None

if __name__ == "__main__":
    main()
