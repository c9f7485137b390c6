"""Road loads of the detailed model: wheel force and power per step (the paper's eq. 28
plus the kinetic energy of the rotating parts)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cevm.core.cycle import step_terms


@dataclass(frozen=True, eq=False)
class RoadLoads:
    """Per step of a trace: what the wheels must do to follow it."""

    dt: np.ndarray  # s
    v: np.ndarray  # mean speed, m/s
    accel: np.ndarray  # m/s^2
    k_per_dt: np.ndarray  # (v1^2 - v0^2) / (2 dt) = v * accel, W/kg
    moving: np.ndarray  # bool
    force: np.ndarray  # N, wheel force incl. rotating inertia (0 at standstill)
    power: np.ndarray  # W, wheel power (0 at standstill)


def road_loads(time_s, speed_mps, elevation_m, mass_kg, cda_m2, cr, rot_mass_kg, physics) -> RoadLoads:
    """Wheel force and power per step: the paper's eq. (28) plus rotating inertia."""
    st = step_terms(time_s, speed_mps, elevation_m, physics)
    v = np.asarray(speed_mps, dtype=np.float64)
    dt = st.dt
    vm = 0.5 * (v[:-1] + v[1:])
    moving = vm > 0.0
    energy = mass_kg * (st.k + st.e) + cda_m2 * st.a + (cr * mass_kg) * st.r + rot_mass_kg * st.k
    energy = np.where(moving, energy, 0.0)
    ds = vm * dt
    force = np.divide(energy, ds, out=np.zeros_like(energy), where=moving)
    return RoadLoads(
        dt=dt,
        v=vm,
        accel=(v[1:] - v[:-1]) / dt,
        k_per_dt=st.k / dt,
        moving=moving,
        force=force,
        power=energy / dt,
    )


def step_mean(per_sample) -> np.ndarray:
    """Per-step values from a per-sample series: the mean of each step's two samples."""
    x = np.asarray(per_sample, dtype=np.float64)
    return 0.5 * (x[:-1] + x[1:])
