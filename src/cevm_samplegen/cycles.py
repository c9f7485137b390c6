"""Deterministic synthetic drive cycles: a micro-trip generator (pure).

A micro-trip is a stop-to-stop run: accelerate at ``accel_mps2`` to a cruise speed,
cruise (with a smooth random speed fluctuation), brake at ``decel_mps2`` to rest, then
dwell. Elevation is a smooth function of distance (a sum of sinusoids), so grades are
realistic and bounded. Everything is drawn from ``numpy.random.default_rng(seed)``:
the same arguments give the same cycle on every machine.

``python -m cevm_samplegen demo-cycles OUTDIR`` writes the project's demo cycles (see :data:`DEMO_CYCLES`).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cevm.core.cycle import DriveCycle
from cevm.units import MPS_TO_KMH


@dataclass(frozen=True)
class MicroTripSpec:
    """Ranges a micro-trip generator draws from (uniformly)."""

    n_trips: int = 20
    cruise_kmh: tuple[float, float] = (20.0, 45.0)
    cruise_s: tuple[float, float] = (10.0, 60.0)
    dwell_s: tuple[float, float] = (10.0, 40.0)
    accel_mps2: tuple[float, float] = (0.6, 1.1)
    decel_mps2: tuple[float, float] = (0.8, 1.4)
    fluctuation_kmh: float = 2.0  # std of the smooth speed fluctuation while cruising
    hill_amplitude_m: float = 10.0  # amplitude of the elevation profile
    hill_wavelength_m: tuple[float, float] = (800.0, 4000.0)


def micro_trip_cycle(spec: MicroTripSpec, seed: int, name: str = "", dt_s: float = 1.0) -> DriveCycle:
    """Generate a cycle of ``spec.n_trips`` micro-trips sampled every ``dt_s`` seconds."""
    rng = np.random.default_rng(seed)
    pieces = [np.zeros(int(rng.uniform(*spec.dwell_s) / dt_s))]
    for _ in range(spec.n_trips):
        v = rng.uniform(*spec.cruise_kmh) / MPS_TO_KMH
        acc = rng.uniform(*spec.accel_mps2)
        dec = rng.uniform(*spec.decel_mps2)
        n_acc = max(1, int(np.ceil(v / acc / dt_s)))
        n_dec = max(1, int(np.ceil(v / dec / dt_s)))
        n_cruise = max(1, int(rng.uniform(*spec.cruise_s) / dt_s))
        up = v * np.minimum(1.0, np.arange(1, n_acc + 1) * dt_s * acc / v)
        # smooth fluctuation: a random walk, low-passed, pinned to 0 at both ends
        walk = np.cumsum(rng.normal(0.0, 1.0, n_cruise))
        walk -= np.linspace(walk[0], walk[-1], n_cruise)
        kernel = np.hanning(min(15, n_cruise) + 2)[1:-1]
        smooth = np.convolve(walk, kernel / kernel.sum(), mode="same")
        scale = spec.fluctuation_kmh / MPS_TO_KMH / max(1e-9, float(np.std(smooth)) if n_cruise > 2 else 1.0)
        cruise = np.clip(v + smooth * scale, 0.3 * v, None)
        down = cruise[-1] * np.maximum(0.0, 1.0 - np.arange(1, n_dec + 1) * dt_s * dec / max(cruise[-1], 1e-9))
        dwell = np.zeros(max(1, int(rng.uniform(*spec.dwell_s) / dt_s)))
        pieces.extend([up, cruise, down, dwell])
    speed = np.concatenate(pieces)
    time = np.arange(speed.size) * dt_s
    distance = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * dt_s)])
    lam = rng.uniform(*spec.hill_wavelength_m, size=3)
    phase = rng.uniform(0, 2 * np.pi, size=3)
    amp = spec.hill_amplitude_m * np.array([1.0, 0.5, 0.25])
    elevation = 50.0 + (amp[:, None] * np.sin(2 * np.pi * distance[None, :] / lam[:, None] + phase[:, None])).sum(0)
    return DriveCycle(time_s=time, speed_mps=speed, elevation_m=elevation, name=name)


#: The project's demo cycles: name -> (spec, seed).
DEMO_CYCLES: dict[str, tuple[MicroTripSpec, int]] = {
    "urban-bus": (MicroTripSpec(n_trips=40), 1),
    "regional-delivery": (
        MicroTripSpec(
            n_trips=8,
            cruise_kmh=(50.0, 80.0),
            cruise_s=(60.0, 240.0),
            dwell_s=(5.0, 30.0),
            accel_mps2=(0.3, 0.6),
            decel_mps2=(0.5, 0.9),
            hill_amplitude_m=25.0,
            hill_wavelength_m=(2000.0, 8000.0),
        ),
        2,
    ),
}


def write_cycle_csv(cycle: DriveCycle, path: Path) -> None:
    """Write a cycle as CSV: time_s, speed_kmh, elevation_m."""
    elev = cycle.elevation_m if cycle.elevation_m is not None else np.zeros_like(cycle.time_s)
    data = np.column_stack([cycle.time_s, cycle.speed_mps * MPS_TO_KMH, elev])
    np.savetxt(path, data, delimiter=",", header="time_s,speed_kmh,elevation_m", comments="",
               fmt=["%.1f", "%.3f", "%.2f"])


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    out = Path(argv[0] if argv else ".")
    out.mkdir(parents=True, exist_ok=True)
    for name, (spec, seed) in DEMO_CYCLES.items():
        write_cycle_csv(micro_trip_cycle(spec, seed, name), out / f"{name}.csv")
        print(out / f"{name}.csv")


if __name__ == "__main__":
    main()
