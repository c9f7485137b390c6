"""Fleet assignment: which vehicle serves each shared stop (paper section 6, eq. 32).

A fleet runs routes from depots. Each route is driven by one vehicle and visits an ordered
list of stops; a stop listed on several routes (the paper's LH1S1 = R1S2) is *shared*:
each day it is served by exactly one of the vehicles allowed there. :func:`plan` picks
the assignment that minimises the fleet's total fuel (or electric energy, or cost),
subject to each vehicle's gross-weight limit and, for electric vehicles, a battery
reserve, and proves it optimal.

Reading of the paper (stated, because the paper is terse here)
---------------------------------------------------------------
``mass_model = "carried"`` (the default, physical reading): the geometry of a route is
fixed. Its vehicle leaves the depot loaded with the payloads of every stop it serves,
drives every leg of its route (depot -> stop 1 -> ... -> stop n [-> depot]) whether or
not it serves each stop, and drops each served stop's payload there. So leg l carries
kerb + the payloads of the served stops at positions >= l; the return leg (on by
default, ``return_to_depot = true``, as figure 8 draws depot -> stops -> depot) is
driven empty. A shared stop served by the other vehicle moves its payload to that
vehicle: only where mass is carried changes, not which roads are driven.

``mass_model = "paper-eq32"`` (the literal reading of eq. 32,
sum_j sum_s f_j(M_s, d)): every stop served by vehicle j costs the consumption of
vehicle j over the leg that arrives at the stop, at mass kerb + M_s (that stop's payload
only); legs to stops a vehicle does not serve, and return legs, are not counted. This is
the only reading under which the paper's table 4 can vary with the payload as it does
(with a model affine in mass, "carried" gives a payload-independent choice unless a
limit binds); it is kept to compare with the paper, not as physics.

Exactness
---------
The consumption of one vehicle over one leg, as a function of the carried mass m, is
exactly ``q(m) = g * [m B0 + A0 + (1 - w) P(m)] + q0`` with ``P(m) = sum_i max(0, m c_i
+ CdA a_i)`` over the cycle's non-simplified steps (cevm.core.model): w = 1 for the paper's
ICE (q affine in m), w = 0 for an ICE with no braking credit, w = eta^2 for an EV. As
w <= 1 and each max(0, affine) is convex, q is convex and piecewise affine in m, with
one piece per interval between the step thresholds m_i = -CdA a_i / c_i. :func:`leg_curve`
builds those pieces over the leg's feasible mass range and checks them against
:func:`cevm.core.vehicle.predict` at every breakpoint and every midpoint (two piecewise-affine
functions with the same kinks that agree there agree everywhere). Then

- ``enumerate``: every combination of choices, each leg predicted with the CE model,
  vectorised over the combinations; exact, for up to ``enum_limit`` combinations.
- ``milp``: binaries x[s, r] (stop s served by route r), sum_r x[s, r] = 1. A leg whose
  q is affine over its range enters the objective linearly; any other leg gets an
  epigraph variable t >= alpha_k + beta_k m for each piece k (exact for a convex q under
  minimisation, and valid inside the battery constraint too). Gross weight: the first
  leg carries the most, kerb + payloads <= max_gross_kg. Solved with HiGHS
  (scipy.optimize.milp) with ``mip_rel_gap = 0``: proven optimal up to HiGHS's
  tolerances (absolute gap 1e-6 on an objective scaled to about 1e3, so 1e-9 relative).

The answer is always re-evaluated with the CE model (:func:`evaluate`) before it is
reported. Scenario files: see :func:`cevm.io.scenario.load_scenario`.

Modules
-------
- :mod:`~cevm.core.assignment.scenario`: the scenario's types and their validation;
- :mod:`~cevm.core.assignment.curves`: a leg's consumption as a function of mass;
- :mod:`~cevm.core.assignment.evaluation`: the exact evaluation of one assignment;
- :mod:`~cevm.core.assignment.problem`: one day's problem (free and fixed stops);
- :mod:`~cevm.core.assignment.enumeration` and :mod:`~cevm.core.assignment.milp`: the
  two solvers;
- :mod:`~cevm.core.assignment.planning`: :func:`plan`, the optimum of one day;
- :mod:`~cevm.core.assignment.reports`: the paper's table 4.
"""

from __future__ import annotations

from cevm.core.assignment.curves import LegCurve, leg_curve
from cevm.core.assignment.evaluation import (
    Evaluation,
    RouteUse,
    VehicleUse,
    default_assignment,
    evaluate,
)
from cevm.core.assignment.planning import AUTO_ENUM_LIMIT, ENUM_LIMIT, Plan, plan
from cevm.core.assignment.reports import calibration_warnings, table4_rows
from cevm.core.assignment.scenario import (
    BUDGET_RTOL,
    EV_RESERVE_FRACTION_DEFAULT,
    LEG_KINDS,
    MASS_MODELS,
    OBJECTIVES,
    SOC_START_DEFAULT,
    FleetVehicle,
    Leg,
    LegSource,
    Prices,
    Route,
    Scenario,
    quote_key,
)

__all__ = [
    "AUTO_ENUM_LIMIT",
    "BUDGET_RTOL",
    "ENUM_LIMIT",
    "EV_RESERVE_FRACTION_DEFAULT",
    "LEG_KINDS",
    "MASS_MODELS",
    "OBJECTIVES",
    "SOC_START_DEFAULT",
    "Evaluation",
    "FleetVehicle",
    "Leg",
    "LegCurve",
    "LegSource",
    "Plan",
    "Prices",
    "Route",
    "RouteUse",
    "Scenario",
    "VehicleUse",
    "calibration_warnings",
    "default_assignment",
    "evaluate",
    "leg_curve",
    "plan",
    "quote_key",
    "table4_rows",
]
