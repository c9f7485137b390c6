"""The detailed (baseline) vehicle model: a backward-facing time-step simulation.

This is cevm's stand-in for the paper's Simulink baseline models (section 4): it turns a
speed and elevation trace into per-step operating points of the powertrain and, from
efficiency maps, limits and a battery or fuel model, into electric energy or fuel. It is
*not* the CE model: its efficiencies vary with the operating point, regeneration is
limited, auxiliaries draw power all the time and a diesel burns fuel at idle, so the CE
model's single eta matches it only on average (the spread is the CE model's error).

Backward-facing means the trace is followed exactly: the model asks what force the wheels
need for the measured speed change, and what the powertrain must do to supply it. Where a
limit binds (motor or engine torque), the unmet part is reported (``traction_deficit_j``)
instead of slowing the vehicle down.

Step convention (as in :mod:`cevm.core.cycle` and PAPER-NOTES.md): step i joins sample i to
i+1, dt_i = T_{i+1} - T_i, mean speed v_i = (v_i + v_{i+1}) / 2, acceleration
(v_{i+1} - v_i) / dt_i. The road load of a step is the paper's eq. (28),

    Delta_i = m (k_i + e_i) + CdA a_i + Cr m r_i          [J]

(eq. 1-4 integrated over the step, rho_air = 1.225 kg/m^3, g = 9.81 m/s^2), plus the
kinetic energy of the rotating parts m_rot k_i (wheels, motor or engine). The wheel
power of the step is that energy over dt_i and the wheel force that energy over the
step's distance v_i dt_i. Steps at standstill (v_i = 0) need no wheel work: the brakes
hold the vehicle, so elevation noise at standstill costs nothing.

Electric vehicle (:class:`EvParams`)
    wheel -> fixed reduction x final drive (one efficiency) -> motor+inverter (loss map)
    -> battery (open-circuit voltage curve, internal resistance, coulomb counting).
    Motor and inverter losses, the standard loss model used to generate scalable maps::

        P_loss(T, w) = k_c T^2 + k_i w + k_w w^3 + C        [W]

    (copper, iron, windage and friction, constant inverter/control losses), with the
    coefficients given as fractions of the peak power so the map scales with the motor.
    Drive is limited by the peak torque below base speed and the peak power above it;
    regeneration by its own torque and power limits and a fade-out at low speed; what
    regeneration cannot take goes to the friction brakes. A regenerating step whose
    losses exceed the recovered power is left to the friction brakes (no battery drain).
    Above the maximum motor speed there is no drive torque. Battery terminal power =
    motor electric power + auxiliaries (always on, standstill included).

Diesel vehicle (:class:`DieselParams`)
    wheel -> axle -> N-speed gearbox (per-gear efficiency) -> engine with a full-load
    torque curve and a Willans-line fuel model. Gear choice, vectorised over all gears
    at once (arrays of shape (n_gears, n_steps)): the highest gear whose engine speed is
    at least a minimum that rises with the power demand (from 950 rpm at no load to
    1,350 rpm at rated power by default), at most the maximum speed, and whose
    full-load torque covers the demand. Fuel power::

        P_fuel = (P_eng + P_fric(w)) / e_ind(w, T)      if P_eng + P_fric > 0, else 0

    P_eng the brake power (traction + engine inertia + auxiliaries), P_fric the friction
    power from a friction mean effective pressure quadratic in speed, e_ind the indicated
    efficiency, mildly dependent on speed and load. Fuel cut: when the indicated power
    needed is negative (the wheels drive the engine harder than its friction brakes it)
    no fuel is injected, and the service brakes take the rest; a brake torque between
    zero and the friction torque needs some fuel (the driver holds a little throttle).
    Launch (slower than first gear at the preferred engine speed): the clutch slips, the
    engine turns at the preferred speed and passes the wheels' torque. At standstill,
    and when the vehicle is too slow for first gear while not driving, the clutch is
    open and the engine idles: idle fuel = (P_aux + P_fric(idle)) / e_ind(idle).

Time step: :func:`simulate` decimates traces sampled faster than 1 s to about 1 s
(``time_step_s``), as quantisation noise of fast logs otherwise makes spurious power
spikes; any strictly increasing time is accepted.

Default parameters are plausible values for the paper's vehicles (Optare Metrocity EV,
Scania P320 with a 9.3 l DC09 engine), from public data-sheet figures and textbook
values, not from measurements. A vehicle file can override any of them in its
``[detailed]`` table (keys in :data:`cevm.io.detailed.EV_KEYS` /
:data:`cevm.io.detailed.DIESEL_KEYS`), read by :func:`cevm.io.detailed.detailed_params`
and passed to :func:`simulate` as ``params``.

Battery SoC: SoC_{i+1} = SoC_i - I_i dt_i / Q, and I_i depends on V_oc(SoC_i). This is
solved vectorised by fixed-point passes: each pass evaluates V_oc at the previous pass's
SoC, solves P = V_oc I - R I^2 for every step and integrates with one cumulative sum;
passes repeat until the SoC changes by less than 1e-12. The error shrinks like
(L x SoC drop)^k / k!: for a 1 h bus cycle (6 % SoC) 4-5 passes reach 1e-11, a full
discharge 10 passes reach 1e-14 (measured against a plain per-step loop; the tests do
the same). SoC is not clipped: below 0 the trace needs more than the usable capacity
(the OCV curve is held at its end values).

Modules: :mod:`~cevm.core.detailed.params` (the parameters and their limits),
:mod:`~cevm.core.detailed.road` (road loads), :mod:`~cevm.core.detailed.ev` (motor and
battery), :mod:`~cevm.core.detailed.diesel` (gearbox and engine),
:mod:`~cevm.core.detailed.results` (:class:`SimulationResult`) and
:mod:`~cevm.core.detailed.simulation` (:func:`simulate`).
"""

from __future__ import annotations

from cevm.core.detailed.diesel import simulate_diesel
from cevm.core.detailed.ev import battery_current_a, integrate_soc, simulate_ev
from cevm.core.detailed.params import (
    DIESEL_LIMITS,
    EV_LIMITS,
    GEAR_RATIOS_12,
    RPM,
    DieselParams,
    EvParams,
    param_problem,
)
from cevm.core.detailed.results import SimulationResult
from cevm.core.detailed.simulation import decimate_indices, simulate

__all__ = [
    "DIESEL_LIMITS",
    "EV_LIMITS",
    "GEAR_RATIOS_12",
    "RPM",
    "DieselParams",
    "EvParams",
    "SimulationResult",
    "battery_current_a",
    "decimate_indices",
    "integrate_soc",
    "param_problem",
    "simulate",
    "simulate_diesel",
    "simulate_ev",
]
