"""Benchmark of the CE engine: vector computation and predictions from a cached vector.

    python benchmarks/bench_core.py [--quick]

Prints throughputs and their ratios against baselines measured in the same run:
- the straightforward per-sample computation (a Python loop over samples, as a plain
  implementation of the paper's equations would run), and
- a numpy per-prediction recomputation over all samples (vectorised over samples, one
  prediction at a time).
It also checks that the fast predictions equal the baselines' (max relative difference).
Targets on one core: vector >= 20 M samples/s; predictions >= 1 M/s, exact.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from cevm.core.cycle import CR0_DEFAULT, drive_cycle_vector
from cevm.core.model import wheel_energy_j
from cevm_samplegen.cycles import DEMO_CYCLES, micro_trip_cycle

RHO, G = 1.225, 9.81


def best_of(fn, repeat=5):
    best = float("inf")
    out = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def loop_vector(t, v, h, cr0=CR0_DEFAULT):
    """The straightforward per-sample vector computation (Python loop)."""
    s_me = s_a = s_r = 0.0
    ns = []
    for i in range(len(t) - 1):
        dt = t[i + 1] - t[i]
        k = 0.5 * (v[i + 1] ** 2 - v[i] ** 2)
        a = 0.25 * RHO * (v[i] ** 3 + v[i + 1] ** 3) * dt
        r = 0.5 * G * (v[i] + v[i + 1]) * dt
        e = G * (h[i + 1] - h[i])
        if k + e + cr0 * r > 0:
            s_me += k + e
            s_a += a
            s_r += r
        else:
            ns.append((k + e, a, r))
    return s_me, s_a, s_r, ns


def loop_prediction(t, v, h, m, cda, cr, w, cr0=CR0_DEFAULT):
    """The straightforward per-sample prediction (Python loop over samples)."""
    total = 0.0
    for i in range(len(t) - 1):
        dt = t[i + 1] - t[i]
        k = 0.5 * (v[i + 1] ** 2 - v[i] ** 2)
        a = 0.25 * RHO * (v[i] ** 3 + v[i + 1] ** 3) * dt
        r = 0.5 * G * (v[i] + v[i + 1]) * dt
        e = G * (h[i + 1] - h[i])
        d = m * (k + e) + cda * a + cr * m * r
        total += d if (k + e + cr0 * r > 0 or d > 0) else w * d
    return total


def numpy_prediction(t, v, h, m, cda, cr, w, cr0=CR0_DEFAULT):
    """Per-prediction recomputation over all samples, vectorised over samples."""
    dt = np.diff(t)
    k = 0.5 * np.diff(v * v)
    a = 0.25 * RHO * (v[:-1] ** 3 + v[1:] ** 3) * dt
    r = 0.5 * G * (v[:-1] + v[1:]) * dt
    e = G * np.diff(h)
    d = m * (k + e) + cda * a + cr * m * r
    simp = k + e + cr0 * r > 0
    return float(np.where(simp | (d > 0), d, w * d).sum())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="smaller sizes (a few seconds)")
    args = ap.parse_args()
    rng = np.random.default_rng(0)

    spec, seed = DEMO_CYCLES["urban-bus"]
    cyc = micro_trip_cycle(spec, seed)
    t, v, h = cyc.time_s, cyc.speed_mps, cyc.elevation_m
    n = t.size
    print(f"cycle: synthetic urban bus, {n} samples at 1 Hz, {cyc.distance_m / 1e3:.1f} km")
    print()

    # --- vector computation -------------------------------------------------------
    print("== drive-cycle vector computation ==")
    reps = 50 if args.quick else 300
    dt_small, _ = best_of(lambda: [drive_cycle_vector(t, v, h) for _ in range(reps)], 3)
    small_rate = reps * n / dt_small
    big_n = 2_000_000 if args.quick else 10_000_000
    tb = np.arange(big_n, dtype=np.float64)
    vb = np.abs(np.cumsum(rng.normal(0, 0.5, big_n)))
    vb = np.minimum(vb % 30.0, 25.0)
    hb = np.cumsum(rng.normal(0, 0.05, big_n))
    dt_big, _ = best_of(lambda: drive_cycle_vector(tb, vb, hb, validate=False), 3)
    dt_big_val, _ = best_of(lambda: drive_cycle_vector(tb, vb, hb), 3)
    loop_n = 20_000 if args.quick else 100_000
    tl, vl, hl = tb[:loop_n].tolist(), vb[:loop_n].tolist(), hb[:loop_n].tolist()
    dt_loop, ref = best_of(lambda: loop_vector(tl, vl, hl), 1)
    loop_rate = loop_n / dt_loop
    fast = drive_cycle_vector(tb[:loop_n], vb[:loop_n], hb[:loop_n])
    rel_vec = max(abs(x - y) / (abs(y) + 1e-300) for x, y in zip(fast.delta, ref[:3], strict=True))
    print(f"  baseline, Python loop per sample : {loop_rate / 1e6:10.2f} M samples/s")
    print(f"  cevm, {reps} cycles of {n} samples  : {small_rate / 1e6:10.2f} M samples/s  "
          f"({small_rate / loop_rate:,.0f}x)")
    print(f"  cevm, one array of {big_n / 1e6:.0f} M samples : {big_n / dt_big / 1e6:10.2f} M samples/s  "
          f"({big_n / dt_big / loop_rate:,.0f}x)"
          f"   with input validation: {big_n / dt_big_val / 1e6:.2f} M samples/s")
    print(f"  max relative difference of the vector vs the loop: {rel_vec:.1e}")
    print("  target: >= 20 M samples/s")
    print()

    # --- predictions ------------------------------------------------------------------
    print("== predictions from a cached vector (50 vehicles x 1,000 masses) ==")
    n_veh = 50
    n_mass = 200 if args.quick else 1000
    cda = rng.uniform(3.0, 7.0, n_veh)
    cr = rng.choice([0.0055, 0.0066, 0.0075, 0.008, 0.01], n_veh)  # 5 tyre types
    eta = rng.uniform(0.7, 0.9, n_veh)
    masses = np.linspace(8000.0, 44000.0, n_mass)
    M = masses[None, :]
    C = cda[:, None]
    R = cr[:, None]
    vec = drive_cycle_vector(t, v, h)
    n_pred = n_veh * n_mass
    modes = {
        "EV (regen eta^2)": (eta[:, None] ** 2),
        "ICE paper (eq. 24)": 1.0,
        "ICE no-credit": 0.0,
    }
    sample_idx = [(i, j) for i, j in zip(rng.integers(0, n_veh, 30), rng.integers(0, n_mass, 30), strict=True)]
    loop_args = (t.tolist(), v.tolist(), h.tolist())
    for label, w in modes.items():
        def run(w=w):
            return wheel_energy_j(vec, M, C, R, w)

        vec._tables.clear()
        t0 = time.perf_counter()
        cold = run()
        dt_cold = time.perf_counter() - t0
        dt_warm, out = best_of(run, 5)
        wv = np.broadcast_to(np.asarray(w, dtype=float), (n_veh, n_mass)) if np.ndim(w) else np.full((n_veh, n_mass), w)
        # baselines on a sample of the same predictions
        dt_loop, loop_vals = best_of(
            lambda: [loop_prediction(*loop_args, masses[j], cda[i], cr[i], wv[i, j]) for i, j in sample_idx[:10]], 1
        )
        dt_np, np_vals = best_of(
            lambda: [numpy_prediction(t, v, h, masses[j], cda[i], cr[i], wv[i, j]) for i, j in sample_idx], 3
        )
        loop_rate = 10 / dt_loop
        np_rate = len(sample_idx) / dt_np
        rel = max(
            abs(out[i, j] - ref) / abs(ref) for (i, j), ref in zip(sample_idx, np_vals, strict=True)
        )
        rel_loop = max(abs(out[i, j] - ref) / abs(ref) for (i, j), ref in zip(sample_idx[:10], loop_vals, strict=True))
        assert np.array_equal(cold, out)
        rate_warm = n_pred / dt_warm
        rate_cold = n_pred / dt_cold
        print(f"  {label}:")
        print(f"    baseline, Python loop per sample  : {loop_rate:14,.0f} predictions/s")
        print(f"    baseline, numpy recompute per pred: {np_rate:14,.0f} predictions/s")
        print(f"    cevm, cached vector (warm)        : {rate_warm:14,.0f} predictions/s"
              f"  ({rate_warm / loop_rate:,.0f}x loop, {rate_warm / np_rate:,.0f}x numpy)"
              f"  = {1e6 / rate_warm:.3f} us each")
        print(f"    cevm, incl. sorting per Cr (cold) : {rate_cold:14,.0f} predictions/s")
        print(f"    max relative difference vs baselines: {max(rel, rel_loop):.1e}")
    print("  target: >= 1,000,000 predictions/s, exact (the paper: 19 ms per prediction)")

    # one prediction at a time (latency inside an optimisation loop)
    reps = 2000 if args.quick else 20000
    vec._tables.clear()
    wheel_energy_j(vec, 20000.0, 4.0, 0.0066, 0.6)
    dt1, _ = best_of(lambda: [wheel_energy_j(vec, 20000.0, 4.0, 0.0066, 0.6) for _ in range(reps)], 3)
    print()
    print(f"== single prediction latency (EV, scalar call) == {dt1 / reps * 1e6:.1f} us per call")


if __name__ == "__main__":
    main()
