"""What a simulation gives: :class:`SimulationResult`, its per-step and per-sample
channels and totals."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

import numpy as np

from cevm.core.cycle import trapezoid_distance_m
from cevm.core.detailed.params import RPM
from cevm.units import J_PER_KWH, MPS_TO_KMH, S_PER_H


@dataclass(frozen=True, eq=False)
class SimulationResult:
    """Per-step and per-sample output of :func:`simulate`, and totals.

    ``steps`` maps channel names (SI, unit in the name) to arrays of the N-1 steps;
    ``samples`` maps names to arrays of the N samples. EV step channels: ``dt_s``,
    ``speed_mean_mps``, ``accel_mps2``, ``wheel_force_n``, ``wheel_power_w``,
    ``motor_speed_rad_s``, ``motor_torque_nm``, ``motor_power_w`` (shaft),
    ``motor_loss_w``, ``motor_electric_power_w``, ``aux_power_w``, ``battery_power_w``
    (terminals, + = discharge), ``battery_ocv_v``, ``battery_current_a``,
    ``friction_brake_power_w``, ``traction_deficit_w``; samples ``soc``,
    ``energy_cum_j``. Diesel step channels: the common ones, ``gear`` (0 = clutch open,
    engine idling), ``engine_speed_rad_s``, ``engine_torque_nm``, ``engine_power_w``
    (brake, auxiliaries included), ``fuel_power_w``, ``fuel_rate_lps``,
    ``friction_brake_power_w``, ``traction_deficit_w``; samples ``fuel_cum_l``.

    Totals: ``wheel_energy_j`` (sum of wheel work, braking negative),
    ``energy_j`` (EV: net electric energy at the battery terminals, regeneration
    subtracted, auxiliaries included), ``fuel_l`` (diesel), ``friction_brake_energy_j``,
    ``traction_deficit_j`` (wheel work the powertrain could not deliver: > 0 means the
    trace asks more than the vehicle can do).
    """

    powertrain: str
    mass_kg: float
    time_s: np.ndarray
    speed_mps: np.ndarray
    elevation_m: np.ndarray | None
    steps: Mapping[str, np.ndarray]
    samples: Mapping[str, np.ndarray]
    wheel_energy_j: float
    friction_brake_energy_j: float
    traction_deficit_j: float
    energy_j: float | None = None
    fuel_l: float | None = None

    @property
    def duration_s(self) -> float:
        return float(self.time_s[-1] - self.time_s[0])

    @property
    def distance_m(self) -> float:
        """Trapezoidal distance [m]."""
        return trapezoid_distance_m(self.time_s, self.speed_mps)

    @property
    def soc(self) -> np.ndarray | None:
        """EV state of charge per sample [0..1], None for a diesel."""
        return self.samples.get("soc")

    @property
    def fuel_cum_l(self) -> np.ndarray | None:
        """Diesel cumulative fuel per sample [l], None for an EV."""
        return self.samples.get("fuel_cum_l")

    def to_frame(self, rows: slice | None = None):
        """A pandas DataFrame, one row per sample, user units in the column names.

        Step quantities are on the row of the step's first sample (the last row has
        none: NaN); cumulative quantities and SoC are at the sample. ``rows``: only these
        samples (a slice: a block of them to write, every k-th to plot), so that the
        frame of a long trace need not be held whole beside the result.
        """
        import pandas as pd  # here: the core imports pandas only for this frame, on request

        n = self.time_s.size
        sel = slice(None) if rows is None else rows

        def per_sample(x, scale=1.0):
            out = np.full(n, np.nan)
            out[:-1] = x * scale
            return out if rows is None else out[sel].copy()

        def at(x, scale=None):
            x = x if rows is None else x[sel]
            return x if scale is None else x * scale

        cols: dict[str, Any] = {
            "time_s": self.time_s if rows is None else self.time_s[sel].copy(),
            "speed_kmh": at(self.speed_mps, MPS_TO_KMH),
        }
        if self.elevation_m is not None:
            cols["elevation_m"] = self.elevation_m if rows is None else self.elevation_m[sel].copy()
        s = self.steps
        cols["accel_mps2"] = per_sample(s["accel_mps2"])
        cols["wheel_force_kn"] = per_sample(s["wheel_force_n"], 1e-3)
        cols["wheel_power_kw"] = per_sample(s["wheel_power_w"], 1e-3)
        if self.powertrain == "ev":
            cols["motor_speed_rpm"] = per_sample(s["motor_speed_rad_s"], 1 / RPM)
            cols["motor_torque_nm"] = per_sample(s["motor_torque_nm"])
            cols["motor_power_kw"] = per_sample(s["motor_power_w"], 1e-3)
            cols["motor_electric_power_kw"] = per_sample(s["motor_electric_power_w"], 1e-3)
            cols["aux_power_kw"] = per_sample(s["aux_power_w"], 1e-3)
            cols["battery_power_kw"] = per_sample(s["battery_power_w"], 1e-3)
            cols["battery_current_a"] = per_sample(s["battery_current_a"])
            cols["battery_ocv_v"] = per_sample(s["battery_ocv_v"])
            cols["friction_brake_power_kw"] = per_sample(s["friction_brake_power_w"], 1e-3)
            cols["soc_pct"] = at(self.samples["soc"], 100.0)
            cols["energy_cum_kwh"] = at(self.samples["energy_cum_j"]) / J_PER_KWH
        else:
            gear = pd.array(np.zeros(n, dtype=np.int64), dtype="Int64")
            gear[:-1] = s["gear"]
            gear[-1] = pd.NA
            cols["gear"] = gear if rows is None else gear[sel]
            cols["engine_speed_rpm"] = per_sample(s["engine_speed_rad_s"], 1 / RPM)
            cols["engine_torque_nm"] = per_sample(s["engine_torque_nm"])
            cols["engine_power_kw"] = per_sample(s["engine_power_w"], 1e-3)
            cols["fuel_rate_lph"] = per_sample(s["fuel_rate_lps"], S_PER_H)
            cols["friction_brake_power_kw"] = per_sample(s["friction_brake_power_w"], 1e-3)
            cols["fuel_cum_l"] = self.samples["fuel_cum_l"] if rows is None else self.samples["fuel_cum_l"][sel].copy()
        cols["traction_deficit_kw"] = per_sample(s["traction_deficit_w"], 1e-3)
        return pd.DataFrame(cols)


def make_result(powertrain: str, mass_kg, t, speed_mps, elevation_m, steps: dict, samples: dict,
            **totals) -> SimulationResult:
    """A :class:`SimulationResult` from the step channels (``wheel_power_w``, ``dt_s``,
    ``friction_brake_power_w``, ``traction_deficit_w`` among them) and the sample ones."""
    dt = steps["dt_s"]
    return SimulationResult(
        powertrain=powertrain,
        mass_kg=float(mass_kg),
        time_s=t,
        speed_mps=np.asarray(speed_mps, dtype=np.float64),
        elevation_m=None if elevation_m is None else np.asarray(elevation_m, dtype=np.float64),
        steps=MappingProxyType(steps),
        samples=MappingProxyType(samples),
        wheel_energy_j=float(np.dot(steps["wheel_power_w"], dt)),
        friction_brake_energy_j=float(np.dot(steps["friction_brake_power_w"], dt)),
        traction_deficit_j=float(np.dot(steps["traction_deficit_w"], dt)),
        **totals,
    )
