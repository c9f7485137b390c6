"""Predictions with their intervals: the cost of the range beside the number.

    python benchmarks/bench_intervals.py [--n 1000000] [--repeats 5]

Two measurements, each against its baseline in the same run (best of ``--repeats``):

1. Batched from features (:class:`cevm.core.predictive.Features`, n predictions of a
   calibrated bus with five terms in its posterior: P, N, duration, temperatures ...):
   the mean alone (:func:`cevm.core.predictive.mean`, what predict computes) against the
   mean with its standard deviation and a 90 % interval
   (:func:`cevm.core.predictive.predictive` + :meth:`Predictive.interval`). Goals (issue
   22): at most 2x, and above a million predictions a second with intervals.
2. From a cycle vector, the way predict and feasibility use it (one cycle, n masses and
   temperatures): :func:`cevm.core.vehicle.predict` against :meth:`Features.of` +
   :func:`predictive` + interval.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from cevm.core.cycle import drive_cycle_vector  # noqa: E402
from cevm.core.predictive import Features, mean, predictive  # noqa: E402
from cevm.core.uncertainty import Posterior, Scatter  # noqa: E402
from cevm.core.vehicle import Vehicle, predict  # noqa: E402


def calibrated_bus() -> Vehicle:
    bus = Vehicle(name="bus", powertrain="ev", mass_kg=11000.0, cda_m2=4.0, cr=0.007, eta=0.8, battery_j=4.3e8,
                  aux_power_w=4000.0, aux_heating_w_per_k=400.0, aux_cooling_w_per_k=300.0, warmup_j_per_k=1e5,
                  heating_below_c=10.0)
    terms = ("eta", "aux", "heat", "cool", "warm")
    rng = np.random.default_rng(0)
    a = rng.normal(size=(5, 5)) * np.array([0.03, 400.0, 40.0, 30.0, 1e4])
    return dataclasses.replace(bus, posterior=Posterior(terms, a.T @ a, Scatter(500.0, 0.03, 0.6), "bench", 30))


def best(fn, repeats: int) -> float:
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return min(out)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=1_000_000)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args(argv)
    n = args.n
    v = calibrated_bus()
    rng = np.random.default_rng(1)
    f = Features(positive_j=rng.uniform(1e7, 6e7, n), negative_j=-rng.uniform(0, 1e7, n),
                 duration_s=rng.uniform(600, 3600, n), idle_s=rng.uniform(0, 600, n),
                 traction_s=rng.uniform(300, 3000, n), kinetic_j=rng.uniform(1e7, 1e8, n),
                 ambient_c=rng.uniform(-10, 35, n), starts=1.0)
    t_mean = best(lambda: mean(v, f), args.repeats)
    t_int = best(lambda: predictive(v, f).interval(0.9), args.repeats)
    print(f"1. from features, n = {n:,}:")
    print(f"   mean only                  {t_mean * 1e3:8.1f} ms  {n / t_mean / 1e6:6.2f} M/s")
    print(f"   mean, sd and 90 % interval {t_int * 1e3:8.1f} ms  {n / t_int / 1e6:6.2f} M/s   "
          f"ratio {t_int / t_mean:.2f}x (goal <= 2x, >= 1 M/s)")

    t = np.arange(0.0, 1801.0)
    speed = np.clip(12 + 6 * np.sin(t / 60.0) + 3 * np.sin(t / 7.0), 0, None)
    vec = drive_cycle_vector(t, speed, 5 * np.sin(t / 300.0))
    m = rng.uniform(9000, 14000, n)
    temps = rng.uniform(-10, 35, n)
    t_pred = best(lambda: predict(vec, v, m, ambient_c=temps), args.repeats)
    t_both = best(lambda: predictive(v, Features.of(vec, v, m, temps)).interval(0.9), args.repeats)
    print(f"2. from a cycle vector, n = {n:,} masses and temperatures:")
    print(f"   predict (the number)       {t_pred * 1e3:8.1f} ms  {n / t_pred / 1e6:6.2f} M/s")
    print(f"   features + interval        {t_both * 1e3:8.1f} ms  {n / t_both / 1e6:6.2f} M/s   "
          f"ratio {t_both / t_pred:.2f}x")


if __name__ == "__main__":
    main()
