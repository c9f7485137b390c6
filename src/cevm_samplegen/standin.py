"""Stand-in drive cycles for the paper's fleet case study (section 6).

The LowCVP long-haul and regional delivery cycles the paper uses are not public. These
are deterministic stand-ins of the same lengths: micro-trips (:mod:`cevm_samplegen.cycles`)
with one cruise shortened to the target distance and the elevation closed.
``configs/cycles/long-haul-standin.csv`` and ``regional-standin.csv`` are written by

    python -m cevm_samplegen standin-cycles configs/cycles
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cevm.core.cycle import DriveCycle
from cevm_samplegen.cycles import MicroTripSpec, micro_trip_cycle, write_cycle_csv


@dataclass(frozen=True)
class StandinCycle:
    """A deterministic stand-in for a non-public cycle: micro-trips from ``spec`` and
    ``seed``, one cruise shortened to ``target_m`` (:func:`trim_cruise`), and the
    elevation closed (:func:`close_elevation`)."""

    spec: MicroTripSpec
    seed: int
    target_m: float
    about: str


#: Stand-ins for the LowCVP cycles of the paper's section 6 (not public): same lengths.
STANDIN_CYCLES: dict[str, StandinCycle] = {
    "long-haul-standin": StandinCycle(
        MicroTripSpec(
            n_trips=2,
            cruise_kmh=(72.0, 86.0),  # HGV motorway/trunk-road speeds (limiter 90 km/h)
            cruise_s=(420.0, 620.0),
            dwell_s=(10.0, 40.0),
            accel_mps2=(0.15, 0.3),
            decel_mps2=(0.25, 0.45),
            fluctuation_kmh=3.0,
            hill_amplitude_m=20.0,
            hill_wavelength_m=(3000.0, 12000.0),
        ),
        seed=1,
        target_m=22600.0,
        about="stand-in for the LowCVP long-haul cycle (22.6 km)",
    ),
    "regional-standin": StandinCycle(
        MicroTripSpec(
            n_trips=8,
            cruise_kmh=(30.0, 60.0),  # regional roads and towns
            cruise_s=(30.0, 110.0),
            dwell_s=(10.0, 45.0),
            accel_mps2=(0.3, 0.6),
            decel_mps2=(0.4, 0.8),
            fluctuation_kmh=3.0,
            hill_amplitude_m=12.0,
            hill_wavelength_m=(1000.0, 5000.0),
        ),
        seed=1,
        target_m=7900.0,
        about="stand-in for the LowCVP regional delivery cycle (7.9 km)",
    ),
}


def trim_cruise(cycle: DriveCycle, target_m: float) -> DriveCycle:
    """Shorten ``cycle`` to ``target_m`` by cutting samples out of one cruise.

    The cut removes samples i..j-1 (joining sample i-1 to j, one sample period apart)
    inside a single moving stretch, choosing, among the cuts that remove the excess
    distance, the one with the smallest speed jump at the join (ties: the earliest).
    The road stays the same: elevation is re-read from the original elevation-vs-
    distance profile at the new distances. Needs uniform sampling and a cycle longer
    than the target; the result is within one sample's distance of it.
    """
    t, v = cycle.time_s, cycle.speed_mps
    dt = float(t[1] - t[0])
    if not np.allclose(np.diff(t), dt):
        raise ValueError("trim_cruise needs uniformly sampled cycles")
    dist = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * dt)])
    excess = dist[-1] - target_m
    if excess < 0:
        raise ValueError(f"cycle is {dist[-1]:.0f} m, shorter than the target {target_m:.0f} m")
    if excess == 0:
        return cycle
    stretch = np.cumsum(v == 0)  # constant along a moving stretch
    start = np.arange(1, v.size)  # candidate i (cut starts at sample i, keeps i-1)
    # j such that removed distance = dist[j] - dist[i-1] - join step ~= excess
    goal = dist[start - 1] + excess + 0.5 * (v[start - 1] + v[start - 1]) * dt
    j = np.searchsorted(dist, goal, side="left")
    ok = j < v.size
    start, j = start[ok], j[ok]
    ok = (v[start - 1] > 0) & (v[j] > 0) & (stretch[start - 1] == stretch[j])
    if not ok.any():
        raise ValueError("no cruise long enough to trim; use more or longer micro-trips")
    start, j = start[ok], j[ok]
    k = int(np.argmin(np.abs(v[j] - v[start - 1])))
    i, j = int(start[k]), int(j[k])
    keep = np.concatenate([np.arange(0, i), np.arange(j, v.size)])
    v_new = v[keep]
    d_new = np.concatenate([[0.0], np.cumsum(0.5 * (v_new[1:] + v_new[:-1]) * dt)])
    h_new = None if cycle.elevation_m is None else np.interp(d_new, dist, cycle.elevation_m)
    return DriveCycle(time_s=t[0] + np.arange(v_new.size) * dt, speed_mps=v_new, elevation_m=h_new, name=cycle.name)


def close_elevation(cycle: DriveCycle) -> DriveCycle:
    """The cycle with a linear-in-distance correction so that it ends at the elevation it
    starts at: a leg built from ``repeat`` copies, or a route of such legs, then gains
    no net height (a net descent would credit every leg with potential energy)."""
    if cycle.elevation_m is None:
        return cycle
    v, t, h = cycle.speed_mps, cycle.time_s, cycle.elevation_m
    dist = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))])
    frac = dist / dist[-1] if dist[-1] > 0 else np.zeros_like(dist)
    return DriveCycle(time_s=t, speed_mps=v, elevation_m=h - (h[-1] - h[0]) * frac, name=cycle.name)


def standin_cycle(name: str) -> DriveCycle:
    """The stand-in cycle ``name`` (a key of :data:`STANDIN_CYCLES`): generated, trimmed
    to its target distance (:func:`trim_cruise`), elevation closed (:func:`close_elevation`)."""
    s = STANDIN_CYCLES[name]
    return close_elevation(trim_cruise(micro_trip_cycle(s.spec, s.seed, name), s.target_m))


def write_standin_cycles(outdir: str | Path) -> list[Path]:
    """Write every stand-in cycle to ``outdir/NAME.csv``; returns the paths."""
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    out = []
    for name in STANDIN_CYCLES:
        p = outdir / f"{name}.csv"
        write_cycle_csv(standin_cycle(name), p)
        out.append(p)
    return out


def main(argv: list[str] | None = None) -> None:
    """``python -m cevm_samplegen standin-cycles OUTDIR``: write the stand-in cycles."""
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 1:
        print("usage: python -m cevm_samplegen standin-cycles OUTDIR", file=sys.stderr)
        raise SystemExit(2)
    for p in write_standin_cycles(argv[0]):
        print(p)


if __name__ == "__main__":
    main()
