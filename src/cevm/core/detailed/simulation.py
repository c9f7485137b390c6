"""The detailed model's entry point: :func:`simulate` a vehicle over a trace, decimated
to the simulation step."""

from __future__ import annotations

import numpy as np

from cevm.core.cycle import PAPER_PHYSICS, Physics, validate_cycle
from cevm.core.detailed.diesel import simulate_diesel
from cevm.core.detailed.ev import simulate_ev
from cevm.core.detailed.params import DieselParams, EvParams
from cevm.core.detailed.results import SimulationResult


def _check_series(name: str, values, n: int, low: float, low_open: bool) -> np.ndarray:
    """A per-sample series as a float array of ``n`` finite values above ``low``, or
    ValueError naming it."""
    x = np.asarray(values, dtype=np.float64)
    if x.shape != (n,):
        raise ValueError(f"{name} must have one value per sample ({n}), got shape {x.shape}")
    bad = ~np.isfinite(x) | ((x <= low) if low_open else (x < low))
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"{name} must be finite and {'>' if low_open else '>='} {low:g}; sample {i} is {x[i]!r}")
    return x


def decimate_indices(time_s, time_step_s: float) -> np.ndarray:
    """Indices of the samples kept on a grid of at least ``time_step_s`` [s]: the first
    sample in each interval [t0 + k step, t0 + (k+1) step), and the last sample.

    A trace sampled at ``time_step_s`` or slower keeps every sample.
    """
    t = np.asarray(time_s, dtype=np.float64)
    if t.size <= 2:
        return np.arange(t.size)
    b = np.floor((t - t[0]) / time_step_s + 1e-9)
    keep = np.empty(t.size, dtype=bool)
    keep[0] = True
    keep[1:] = b[1:] != b[:-1]
    keep[-1] = True
    return np.flatnonzero(keep)


def _default_params(vehicle) -> EvParams | DieselParams:
    """The default powertrain of a vehicle without a ``[detailed]`` table (or with an
    empty one); TypeError for a vehicle whose table was not read."""
    if vehicle.extra.get("detailed"):
        raise TypeError(f"vehicle {vehicle.name!r} has a [detailed] table: read it with "
                        "cevm.io.detailed.detailed_params(vehicle) and pass it as params=")
    return EvParams() if vehicle.is_ev else DieselParams()


def simulate(vehicle, time_s, speed_mps, elevation_m=None, mass_kg: float | None = None,
             soc_start: float = 1.0, *, params: EvParams | DieselParams | None = None,
             time_step_s: float | None = 1.0, physics: Physics = PAPER_PHYSICS, aux_power_w=None,
             friction_scale=None) -> SimulationResult:
    """Simulate ``vehicle`` (a :class:`~cevm.core.vehicle.Vehicle`) over a trace.

    Parameters
    ----------
    vehicle
        road-load parameters (mass, CdA, Cr), battery capacity (EV) or fuel
        heating value (ICE). The CE-model terms ``eta``, ``aux_power_kw`` and
        ``idle_fuel_lph`` are not used.
    time_s
        (N,) time [s], strictly increasing (any step)
    speed_mps
        (N,) speed [m/s], >= 0
    elevation_m
        (N,) road elevation [m], or None for a flat road
    mass_kg
        gross mass [kg]; default the vehicle's ``mass_kg``
    soc_start
        EV state of charge at the first sample [0..1], default 1.0 (full)
    params
        :class:`EvParams` / :class:`DieselParams`: the powertrain (auxiliaries
        included). A vehicle file's ``[detailed]`` table is read into these by
        :func:`cevm.io.detailed.detailed_params`. None: the defaults, for a vehicle
        without such a table (one with a non-empty table is refused, TypeError: the
        core reads no configuration, and leaving it out would quietly simulate another
        powertrain).
    time_step_s
        simulation step [s], default 1.0: a trace sampled faster is decimated
        to one sample per ``time_step_s`` (:func:`decimate_indices`) before simulating,
        as backward models usually run at 1 s. Speed logged at 10 Hz with 0.1 mph
        resolution gives +-0.45 m/s^2 acceleration spikes from quantisation alone, which
        no powertrain follows (a forward model's driver and the vehicle's inertia filter
        them). Kinetic and potential energy telescope, so the decimated trace needs the
        same net energy. None: simulate every sample. The result's arrays are on the
        simulated samples.
    physics
        air density and gravity (the paper's by default)
    aux_power_w
        (N,) auxiliary power [W] per sample beyond the ``[detailed]`` table's
        (>= 0): EV, from the battery (heating and air conditioning that follow the
        weather); diesel, mechanical at the engine (an A/C compressor). None: none.
    friction_scale
        (N,) diesel only: factor (> 0) on the engine friction per sample,
        e.g. above 1 while a cold engine warms up. None: 1.

    Raises
    ------
    ValueError
        for an invalid trace (see :func:`cevm.core.cycle.validate_cycle`) or series.
    """
    validate_cycle(time_s, speed_mps, elevation_m)
    n_samples = np.size(time_s)
    if aux_power_w is not None:
        aux_power_w = _check_series("aux_power_w", aux_power_w, n_samples, 0.0, False)
    if friction_scale is not None:
        if vehicle.is_ev:
            raise ValueError("friction_scale applies to a diesel engine, not to an EV")
        friction_scale = _check_series("friction_scale", friction_scale, n_samples, 0.0, True)
    if time_step_s is not None:
        if not time_step_s > 0:
            raise ValueError("time_step_s must be > 0")
        idx = decimate_indices(time_s, time_step_s)
        if idx.size < np.size(time_s):
            time_s = np.asarray(time_s, dtype=np.float64)[idx]
            speed_mps = np.asarray(speed_mps, dtype=np.float64)[idx]
            if elevation_m is not None:
                elevation_m = np.asarray(elevation_m, dtype=np.float64)[idx]
            aux_power_w = None if aux_power_w is None else aux_power_w[idx]
            friction_scale = None if friction_scale is None else friction_scale[idx]
    m = float(vehicle.mass_kg if mass_kg is None else mass_kg)
    if not m > 0:
        raise ValueError("mass_kg must be > 0")
    if not 0.0 <= soc_start <= 1.0:
        raise ValueError("soc_start must be in [0, 1]")
    if params is None:
        params = _default_params(vehicle)
    if vehicle.is_ev:
        ev = params
        if not isinstance(ev, EvParams):
            raise TypeError("an EV needs EvParams")
        return simulate_ev(ev, time_s, speed_mps, elevation_m, mass_kg=m, cda_m2=vehicle.cda_m2, cr=vehicle.cr,
                           battery_j=vehicle.battery_j, soc_start=soc_start,
                           physics=physics, aux_power_w=aux_power_w)
    ice = params
    if not isinstance(ice, DieselParams):
        raise TypeError("an ICE vehicle needs DieselParams")
    return simulate_diesel(ice, time_s, speed_mps, elevation_m, mass_kg=m, cda_m2=vehicle.cda_m2, cr=vehicle.cr,
                           fuel_lhv_j_per_l=vehicle.fuel_lhv_j_per_l, physics=physics,
                           aux_power_w=aux_power_w, friction_scale=friction_scale)
