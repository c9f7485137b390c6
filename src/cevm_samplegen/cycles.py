"""Deterministic synthetic drive cycles: a micro-trip generator (pure).

A micro-trip is a stop-to-stop run: accelerate at ``accel_mps2`` to a cruise speed,
cruise (with a smooth random speed fluctuation), brake at ``decel_mps2`` to rest, then
dwell. Elevation is a smooth function of distance (a sum of sinusoids), so grades are
realistic and bounded. Everything is drawn from ``numpy.random.default_rng(seed)``:
the same arguments give the same cycle on every machine.

A cycle may be made for a vehicle class to follow (``MicroTripSpec.follow``, a
:class:`Follow`): its speeds are then lowered, step by step, where the target would ask
more wheel power than the class's design vehicle has (a truck slows on a climb and
accelerates gently when loaded, as the truck's driver does), so that the vehicle can
drive the cycle as written (``cevm predict``'s ``over_power`` stays false).

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
class Follow:
    """The design vehicle a cycle is made for: at ``mass_kg`` with ``cda_m2`` and ``cr``,
    no step asks more wheel power than ``power_w`` (the road loads of eq. 28, no rotating
    inertia: what ``cevm predict`` checks against ``max_power_kw``)."""

    power_w: float
    mass_kg: float
    cda_m2: float
    cr: float
    air_density: float = 1.2
    g_mps2: float = 9.81


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
    follow: Follow | None = None  # the vehicle the cycle is made for (module notes); None: the target as drawn


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
    lam = rng.uniform(*spec.hill_wavelength_m, size=3)
    phase = rng.uniform(0, 2 * np.pi, size=3)
    amp = spec.hill_amplitude_m * np.array([1.0, 0.5, 0.25])

    def height(d: np.ndarray) -> np.ndarray:
        return 50.0 + (amp[:, None] * np.sin(2 * np.pi * np.atleast_1d(d)[None, :] / lam[:, None]
                                             + phase[:, None])).sum(0)

    if spec.follow is not None:
        speed = _followable(speed, dt_s, height, spec.follow)
    distance = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * dt_s)])
    return DriveCycle(time_s=time, speed_mps=speed, elevation_m=height(distance), name=name)


def _followable(target: np.ndarray, dt_s: float, height, f: Follow) -> np.ndarray:
    """The speeds [m/s] nearest ``target`` (never above it) whose every step asks at most
    ``f.power_w`` of wheel power of ``f``'s vehicle on the road ``height(distance)``: each
    step's end speed, where the target's asks too much, the highest that does not (found
    by bisection: a step's power rises with its end speed). A generator's loop over the
    steps, each depending on the last (a cycle is made once)."""

    def power(v0: float, v1: float, d0: float, h0: float) -> float:
        ds = 0.5 * (v0 + v1) * dt_s
        vm = 0.5 * (v0 + v1)
        work = (0.5 * f.mass_kg * (v1 * v1 - v0 * v0) + f.mass_kg * f.g_mps2 * (float(height(d0 + ds)[0]) - h0)
                + f.mass_kg * f.g_mps2 * f.cr * ds + 0.5 * f.air_density * f.cda_m2 * vm * vm * ds)
        return work / dt_s

    out = target.astype(np.float64).copy()
    d = 0.0
    for i in range(1, out.size):
        v0, v1 = out[i - 1], out[i]
        h0 = float(height(d)[0])
        if v1 > 0 and power(v0, v1, d, h0) > f.power_w:
            lo, hi = 0.0, v1
            for _ in range(40):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if power(v0, mid, d, h0) <= f.power_w else (lo, mid)
            out[i] = lo
        d += 0.5 * (v0 + out[i]) * dt_s
    return out


#: The heavy truck the shipped regional-delivery cycle is made for: the shipped Scania
#: P320 (configs/vehicles/diesel-hgv.toml: 235 kW, CdA 6.62 m2, Cr 0.0066) at its
#: 44,000 kg gross, with 10 % of its power kept (a logged trace's noise, the de-spiked
#: 5-s windows of cevm.core.limits): the truck follows the cycle empty and loaded.
HEAVY_TRUCK = Follow(power_w=0.9 * 235e3, mass_kg=44000.0, cda_m2=6.62, cr=0.0066)


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
            follow=HEAVY_TRUCK,
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
