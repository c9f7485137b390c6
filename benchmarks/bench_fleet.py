"""Benchmark of the fleet assignment (cevm.core.assignment, paper section 6).

    python benchmarks/bench_fleet.py [--quick]

1. The paper's case study (configs/fleet/paper-case-study.toml), per day:
   - plan() with the scenario loaded (leg vectors cached): problem building, CE
     predictions of every leg, enumeration of the 4 combinations, exact re-evaluation
     of the optimum and of the default assignment;
   - the same including the drive-cycle vectors (computed from the cycles' samples in
     memory, as the paper's 0.30 s included its eq. 21 coefficients), and including
     the whole scenario load from files;
   - baseline in the same run: the same enumeration with every leg's fuel computed by a
     straightforward per-sample loop (no cached vector), as a plain implementation of
     the paper's equations runs. Both must pick the same assignment.
   Paper: 0.30-0.34 s per day with its CE model, 13.7 s with its detailed model.
   Target: under 5 ms per day with vectors cached.
2. A generated fleet: 100 vehicles, 1,000 stops, 200 of them shareable between two
   routes, gross-weight limits that bind. MILP (HiGHS): time, status, gap, size.
   Twice: ICE as in the paper (leg fuel affine in mass) and ICE without braking credit
   (convex piecewise-affine legs, epigraph pieces). Target: proven optimum under 10 s.
3. Baseline for the MILP in the same run: a smaller generated fleet whose combinations
   can all be enumerated (vectorised); both methods must reach the same optimum.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import random
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from cevm.core.assignment import FleetVehicle, Leg, Route, Scenario, plan  # noqa: E402
from cevm.core.cycle import drive_cycle_vector  # noqa: E402
from cevm.io import load_vehicle, read_cycle_csv  # noqa: E402
from cevm.io.scenario import load_scenario  # noqa: E402
from cevm_samplegen.cycles import MicroTripSpec, micro_trip_cycle  # noqa: E402

RHO, G = 1.225, 9.81
PAPER = ROOT / "configs" / "fleet" / "paper-case-study.toml"


def best_of(fn, repeat=7):
    times = []
    out = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), float(np.median(times)), out


def loop_fuel_l(t, v, h, m, veh, cr0=0.004):
    """Per-sample fuel over a cycle (Python loop), the paper's ICE equations as printed."""
    total = 0.0
    for i in range(len(t) - 1):
        dt = t[i + 1] - t[i]
        k = 0.5 * (v[i + 1] ** 2 - v[i] ** 2)
        a = 0.25 * RHO * (v[i] ** 3 + v[i + 1] ** 3) * dt
        r = 0.5 * G * (v[i] + v[i + 1]) * dt
        e = G * (h[i + 1] - h[i])
        total += m * (k + e) + veh.cda_m2 * a + veh.cr * m * r
    return total / (veh.fuel_lhv_j_per_l * veh.eta)


def baseline_paper_day(sc: Scenario, cycles, d: int):
    """Enumerate the 4 combinations with per-sample loops; returns (assignment, total)."""
    shared = [s for s in sc.stops() if len(sc.options(s)) > 1]
    best = (None, float("inf"))
    import itertools

    for combo in itertools.product(*[sc.options(s) for s in shared]):
        who = {s: sc.options(s)[0] for s in sc.stops()} | dict(zip(shared, combo, strict=True))
        total = 0.0
        for ri, r in enumerate(sc.routes):
            veh = sc.vehicle_by_id[r.vehicle_id].vehicle
            for li, leg in enumerate(r.legs):
                load = sum(sc.payload_kg[s][d] for k, s in enumerate(r.stops) if k >= li and who[s] == ri)
                t, v, h = cycles[leg.source.ref]
                total += leg.source.repeat * loop_fuel_l(t, v, h, veh.kerb_mass_kg + load, veh)
        if total < best[1]:
            best = (who, total)
    return best


def bench_paper(quick: bool) -> None:
    print("== paper case study (3 HGVs, 2 shared stops, 4 combinations per day) ==")
    sc = load_scenario(PAPER)
    t_load, med_load, _ = best_of(lambda: load_scenario(PAPER), 3 if quick else 7)
    cycles = {}
    for r in sc.routes:
        for leg in r.legs:
            c = read_cycle_csv(PAPER.parent / leg.source.ref)
            cycles[leg.source.ref] = (c.time_s.tolist(), c.speed_mps.tolist(), c.elevation_m.tolist())
    arrays = {ref: tuple(np.asarray(x) for x in tv) for ref, tv in cycles.items()}

    def with_vectors(d):
        vec = {ref: drive_cycle_vector(*arr) for ref, arr in arrays.items()}
        summed = {}
        routes = []
        for r in sc.routes:
            legs = []
            for leg in r.legs:
                key = (leg.source.ref, leg.source.repeat)
                if key not in summed:
                    total = vec[leg.source.ref]
                    for _ in range(leg.source.repeat - 1):
                        total = total + vec[leg.source.ref]
                    summed[key] = total
                legs.append(Leg(summed[key], leg.source))
            routes.append(dataclasses.replace(r, legs=tuple(legs)))
        return plan(dataclasses.replace(sc, routes=tuple(routes)), d)

    print(f"load_scenario (2 cycle files, vectors, vehicles): best {t_load * 1e3:.2f} ms, median {med_load * 1e3:.2f} "
          f"ms")
    print(f"{'day':6} {'plan (cached)':>16} {'+ vectors':>12} {'load + plan':>12} {'MILP':>10} "
          f"{'baseline':>10} {'speed-up':>9}  choice (LH1S1/R1S2, LH2S1/R1S4)  same")
    for d, day in enumerate(sc.days):
        n = 5 if quick else 50
        t_plan, med_plan, p = best_of(lambda: plan(sc, d), n)
        t_vec, _, pv = best_of(lambda: with_vectors(d), 5 if quick else 20)
        t_all, _, _ = best_of(lambda: plan(load_scenario(PAPER), d), 3 if quick else 10)
        t_milp, _, pm = best_of(lambda: plan(sc, d, method="milp"), 3 if quick else 10)
        t0 = time.perf_counter()
        who, base_total = baseline_paper_day(sc, cycles, d)
        t_base = time.perf_counter() - t0
        route_ids = [r.id for r in sc.routes]
        same = (
            all(route_ids[who[s]] == p.assignment[s] for s in p.assignment)
            and pv.assignment == p.assignment == pm.assignment
            and abs(base_total - p.total) < 1e-9 * p.total
        )
        choice = (p.assignment["LH1S1/R1S2"], p.assignment["LH2S1/R1S4"])
        print(f"{day:6} {t_plan * 1e3:9.2f} ms (med {med_plan * 1e3:.2f}) {t_vec * 1e3:9.2f} ms {t_all * 1e3:9.2f} ms "
              f"{t_milp * 1e3:7.2f} ms {t_base:8.2f} s {t_base / t_plan:8.0f}x  {choice}  {same}")
        print(f"       total {p.total:.4f} l, default {p.default_total:.4f} l, saving {p.saving:.4f} l")


def generated_fleet(n_vehicles=100, n_exclusive=800, n_shared=200, seed=7, braking="paper") -> Scenario:
    """A random fleet: one route per vehicle, exclusive stops spread over the routes,
    each shared stop inserted into two random routes; legs from a pool of synthetic
    cycles (1-3 repeats). Payloads are drawn so that a route taking all its shared
    stops would be near or over its gross limit: the limits bind. The default
    assignment gives each shared stop, in turn, to the vehicle with more room left."""
    rng = random.Random(seed)
    specs = [
        (MicroTripSpec(n_trips=6), 101),
        (MicroTripSpec(n_trips=4, cruise_kmh=(40, 70), cruise_s=(60, 200), hill_amplitude_m=25.0), 102),
        (MicroTripSpec(n_trips=2, cruise_kmh=(70, 88), cruise_s=(300, 600), accel_mps2=(0.2, 0.4)), 103),
        (MicroTripSpec(n_trips=10, cruise_kmh=(20, 40)), 104),
        (MicroTripSpec(n_trips=3, cruise_kmh=(50, 80), hill_amplitude_m=40.0), 105),
    ]
    base = []
    for spec, s in specs:
        c = micro_trip_cycle(spec, s)
        base.append(drive_cycle_vector(c.time_s, c.speed_mps, c.elevation_m))
    pool = []
    for v in base:
        pool.extend([v, v + v, v + v + v])
    hgv = load_vehicle(ROOT / "configs" / "vehicles" / "diesel-hgv.toml")
    hgv = dataclasses.replace(hgv, ice_braking=braking)
    rigid = dataclasses.replace(hgv, name="rigid", kerb_mass_kg=9000.0, mass_kg=9000.0, max_gross_kg=26000.0,
                                cda_m2=5.5)
    vehicles = []
    stops: dict[str, list[str]] = {}
    for i in range(n_vehicles):
        veh = hgv if i % 3 else rigid
        vehicles.append(FleetVehicle(f"V{i:03d}", veh, veh.max_gross_kg))
        stops[f"V{i:03d}"] = []
    ids = list(stops)
    payload = {}
    for j in range(n_exclusive):
        vid = ids[j % n_vehicles]
        s = f"E{j:04d}"
        stops[vid].append(s)
    default = {}
    for j in range(n_shared):
        s = f"S{j:03d}"
        pair = rng.sample(ids, 2)
        for vid in pair:
            stops[vid].insert(rng.randrange(len(stops[vid]) + 1), s)
        default[s] = pair
    for v in vehicles:
        cap = v.max_gross_kg - v.vehicle.kerb_mass_kg
        own = [s for s in stops[v.id] if s.startswith("E")]
        for s in own:
            payload[s] = (round(rng.uniform(0.03, 0.08) * cap, -1),)
    for j in range(n_shared):
        payload[f"S{j:03d}"] = (round(rng.uniform(500, 5000), -1),)
    # The default assignment, an operator's rule of thumb: each shared stop (in turn) to
    # the one of its two vehicles with more spare payload capacity left.
    room = {v.id: v.max_gross_kg - v.vehicle.kerb_mass_kg
            - sum(payload[s][0] for s in stops[v.id] if s.startswith("E")) for v in vehicles}
    for s, pair in default.items():
        vid = max(pair, key=lambda x: room[x])
        room[vid] -= payload[s][0]
        default[s] = vid
    routes = []
    for v in vehicles:
        ss = stops[v.id]
        legs = tuple(Leg(rng.choice(pool)) for _ in range(len(ss) + 1))
        routes.append(Route(id=f"R{v.id}", vehicle_id=v.id, stops=tuple(ss), legs=legs))
    return Scenario(name=f"generated {n_vehicles} vehicles", vehicles=tuple(vehicles), routes=tuple(routes),
                    days=("day",), payload_kg=payload, default_vehicle=default)


def report_plan(label: str, p, t: float) -> None:
    moved = sum(1 for s, r in p.assignment.items() if s.startswith("S") and r != p.default_assignment[s])
    gross_tight = sum(1 for v in p.evaluation.vehicles if v.max_gross_kg and v.max_gross_used_kg > v.max_gross_kg - 500)
    default = ("infeasible" if p.default_total is None
               else f"{p.default_total:.3f} l (saving {p.saving:.3f} l, {p.saving_pct:.2f} %)")
    print(f"{label}: {t:.2f} s  status {p.status}, MIP gap {p.mip_gap}, {p.n_variables} variables, "
          f"{p.n_constraints} constraints")
    print(f"   total {p.total:.3f} l (solver {p.solver_objective:.3f}), default {default}")
    print(f"   {moved} shared stops off their default vehicle; {gross_tight} vehicles within 500 kg of their limit")


def bench_generated(quick: bool) -> None:
    print("\n== generated fleet: 100 vehicles, 1,000 stops, 200 shareable ==")
    for braking in ("paper", "no-credit"):
        t0 = time.perf_counter()
        sc = generated_fleet(braking=braking)
        t_gen = time.perf_counter() - t0
        t0 = time.perf_counter()
        p = plan(sc, 0, method="milp")
        t = time.perf_counter() - t0
        print(f"[ICE braking = {braking!r}] (scenario generation {t_gen:.2f} s, not counted)")
        report_plan("   MILP", p, t)
        loose = dataclasses.replace(sc, vehicles=tuple(dataclasses.replace(v, max_gross_kg=None) for v in sc.vehicles))
        pl = plan(loose, 0, method="milp")
        print(f"   without gross limits: {pl.total:.3f} l ({pl.status}): the limits cost {p.total - pl.total:.3f} l")

    print("\n== baseline in the same run: enumeration vs MILP on a fleet small enough to enumerate ==")
    sizes = [(10, 60, 12)] if quick else [(10, 60, 12), (12, 80, 16)]
    for braking in ("paper", "no-credit"):
        for nv, ne, ns in sizes:
            sc = generated_fleet(nv, ne, ns, seed=11, braking=braking)
            t0 = time.perf_counter()
            pe = plan(sc, 0, method="enumerate")
            te = time.perf_counter() - t0
            t0 = time.perf_counter()
            pm = plan(sc, 0, method="milp")
            tm = time.perf_counter() - t0
            same = abs(pe.total - pm.total) <= 1e-9 * pe.total
            print(f"[{braking}] {nv} vehicles, {ne + ns} stops, {ns} shared ({pe.n_combinations} combinations): "
                  f"enumeration {te:.3f} s, MILP {tm:.3f} s, same optimum: {same} "
                  f"({pe.total:.6f} vs {pm.total:.6f} l)")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="fewer repeats")
    args = ap.parse_args()
    bench_paper(args.quick)
    bench_generated(args.quick)


if __name__ == "__main__":
    main()
