"""The detailed model beside the CE model on the same trace (pure): what each gives and
the terms in which they differ, so that ``cevm simulate`` says why its figure is not
``cevm predict``'s.

The two models share the road loads (the vehicle file's mass, CdA, Cr; the trace's
speeds and grades) and the auxiliaries (an EV's ``aux_power_kw``, the detailed table's
``aux_base_power_kw``), and differ in what lies between the wheel and the battery or
tank:

- the CE model (eq. 22-31): one efficiency ``eta`` for every loss in traction, the
  negative steps credited at ``eta eta_r`` without limit (EV; an ICE per its braking
  mode), no rotating inertia, heating and cooling from the ambient temperature where
  the file has their coefficients;
- the detailed model: the motor and inverter's loss map (or the engine's fuel map and
  gearbox), the transmission's efficiency, regeneration limited in power and torque and
  faded out at low speed, the battery's internal resistance, the wheels' and motor's
  rotating inertia, a fixed HVAC power.

For an EV, :func:`compare` returns the traction efficiency the detailed model ends up
with over the trace (wheel work in traction over the electric energy it took) beside the
CE model's ``eta``, and the energy each returns to the battery.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cevm.core.cycle import DriveCycle, cycle_vector
from cevm.core.detailed.results import SimulationResult
from cevm.core.vehicle import Vehicle


@dataclass(frozen=True)
class ModelComparison:
    """The CE model's figure on a simulated trace and the terms the two differ in.

    ``ce`` the CE model's battery energy [J] (EV) or fuel [l] (ICE) at the simulation's
    mass and ``ambient_c`` [degC]; ``difference`` (CE - detailed) / detailed [-]. EV only
    (NaN otherwise): ``ce_traction_j`` the CE model's battery energy in traction (positive
    wheel work / eta) [J], ``detailed_traction_j`` the detailed model's electric energy
    into the motor in traction [J], ``detailed_efficiency`` its wheel work in traction over
    that [-], ``ce_regen_j`` and ``detailed_regen_j`` the energy each returns to the battery
    [J], ``aux_j`` the auxiliaries' energy of each (the CE model's, the detailed model's)."""

    ce: float
    difference: float
    ambient_c: float
    ce_traction_j: float = float("nan")
    detailed_traction_j: float = float("nan")
    detailed_efficiency: float = float("nan")
    ce_regen_j: float = float("nan")
    detailed_regen_j: float = float("nan")
    ce_aux_j: float = float("nan")
    detailed_aux_j: float = float("nan")


def compare(vehicle: Vehicle, res: SimulationResult, ambient_c: float = float("nan")) -> ModelComparison:
    """The CE model of ``vehicle`` on the trace of ``res`` at its mass (``ambient_c``:
    NaN, the vehicle's reference or the default, as for a stored trip without a logged
    temperature) beside the detailed model's result (module notes)."""
    from cevm.core import energy
    from cevm.core.replay.trip_energies import trip_energies

    vec = cycle_vector(DriveCycle(time_s=res.time_s, speed_mps=res.speed_mps, elevation_m=res.elevation_m))
    te = trip_energies([vec], vehicle, [res.mass_kg], [ambient_c])
    ce = float(te.energy[0])
    t = float(te.ambient_c[0])
    detailed = res.energy_j if vehicle.is_ev else res.fuel_l
    diff = (ce - detailed) / detailed if detailed else float("nan")
    if not vehicle.is_ev:
        return ModelComparison(ce=ce, difference=diff, ambient_c=t)
    s = res.steps
    dt = s["dt_s"]
    p_el = s["motor_electric_power_w"]
    wheel = s["wheel_power_w"]
    traction_el = float(np.sum(np.where(p_el > 0, p_el, 0.0) * dt))
    traction_wheel = float(np.sum(np.where(wheel > 0, wheel - s["traction_deficit_w"], 0.0) * dt))
    regen = float(-np.sum(np.where(p_el < 0, p_el, 0.0) * dt))
    aux_ce = float(energy.ev_aux_power_w(vehicle, t) * res.duration_s)
    return ModelComparison(
        ce=ce, difference=diff, ambient_c=t, ce_traction_j=float(te.positive_j[0]) / vehicle.eta,
        detailed_traction_j=traction_el, detailed_efficiency=traction_wheel / traction_el if traction_el else np.nan,
        ce_regen_j=float(-energy.ev_negative_weight(vehicle) * te.negative_j[0] / vehicle.eta),
        detailed_regen_j=regen, ce_aux_j=aux_ce, detailed_aux_j=float(np.sum(s["aux_power_w"] * dt)))
