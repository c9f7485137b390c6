"""The optimum of one day (:func:`plan`): the problem, a solver, and the exact
re-evaluation of the answer and of the default assignment."""

from __future__ import annotations

import time
from dataclasses import dataclass

from cevm.core.assignment.chance import check_level, p_complete
from cevm.core.assignment.enumeration import solve_enumerate
from cevm.core.assignment.evaluation import Evaluation, default_assignment, evaluate
from cevm.core.assignment.milp import solve_milp
from cevm.core.assignment.problem import day_problem
from cevm.core.assignment.scenario import Scenario
from cevm.errors import InputError
from cevm.units import J_PER_KWH

#: ``method="auto"`` enumerates up to this many combinations, and solves a MILP beyond:
#: enumeration is exact, needs no solver and, vectorised, costs about 1 us per
#: combination and leg, so 1,024 combinations stay well under a millisecond or two.
AUTO_ENUM_LIMIT = 1024
#: ``method="enumerate"`` refuses more combinations than this (memory: combinations x
#: legs doubles).
ENUM_LIMIT = 1 << 20


@dataclass(frozen=True)
class Plan:
    """The optimal assignment of one day, with its consumption and how it was found.

    ``total`` and every vehicle's ``value`` are in ``unit`` (litres, J or currency).
    ``saving`` = default_total - total (None if the default assignment is infeasible).
    ``solve_time_s`` covers :func:`plan` from the loaded scenario (vectors cached) to the
    answer: problem building, leg consumptions with the CE model, the solver, and the
    exact re-evaluation of the optimum and of the default assignment.
    """

    scenario: str
    day: str
    objective: str
    unit: str
    mass_model: str
    assignment: dict[str, str]  # stop -> route id
    evaluation: Evaluation
    total: float
    default_assignment: dict[str, str]
    default_total: float | None
    default_violations: tuple[str, ...]
    method: str
    status: str
    mip_gap: float | None
    solver_objective: float | None
    n_combinations: int
    n_variables: int
    n_constraints: int
    solve_time_s: float
    route_vehicle: dict[str, str]
    p_complete: dict | None = None  # vehicle -> P(completing the day within its budget) or None
    min_p_complete: float | None = None

    @property
    def saving(self) -> float | None:
        return None if self.default_total is None else self.default_total - self.total

    @property
    def saving_pct(self) -> float | None:
        if self.default_total is None or self.default_total == 0:
            return None
        return 100.0 * (self.default_total - self.total) / self.default_total

    def stops_per_vehicle(self) -> dict[str, list[str]]:
        """The paper's table 4 column for this day: vehicle -> stops served, in order."""
        return {v.vehicle_id: list(v.stops) for v in self.evaluation.vehicles}

    def to_dict(self) -> dict:
        """JSON-ready dict (SI units, plus kWh for readability)."""
        vehicles = [
            {
                "vehicle": v.vehicle_id,
                "stops": list(v.stops),
                "fuel_l": v.fuel_l,
                "energy_j": v.energy_j,
                "energy_kwh": None if v.energy_j is None else v.energy_j / J_PER_KWH,
                "value": v.value,
                "max_gross_used_kg": v.max_gross_used_kg,
                "max_gross_kg": v.max_gross_kg,
                "energy_budget_j": v.energy_budget_j,
                "p_complete": (self.p_complete or {}).get(v.vehicle_id),
                "routes": [
                    {
                        "route": ru.route_id,
                        "stops_served": list(ru.stops_served),
                        "legs": [
                            {"leg": n, "mass_kg": m, ("energy_j" if v.energy_j is not None else "fuel_l"): u}
                            for n, m, u in zip(ru.leg_names, ru.leg_mass_kg, ru.leg_use, strict=True)
                        ],
                    }
                    for ru in v.routes
                ],
            }
            for v in self.evaluation.vehicles
        ]
        return {
            "scenario": self.scenario,
            "day": self.day,
            "objective": self.objective,
            "unit": self.unit,
            "mass_model": self.mass_model,
            "assignment": {s: {"route": r, "vehicle": self.route_vehicle[r]} for s, r in self.assignment.items()},
            "stops_per_vehicle": self.stops_per_vehicle(),
            "total": self.total,
            "vehicles": vehicles,
            "default": {
                "assignment": {s: self.route_vehicle[r] for s, r in self.default_assignment.items()},
                "total": self.default_total,
                "violations": list(self.default_violations),
            },
            "saving": self.saving,
            "saving_pct": self.saving_pct,
            "method": self.method,
            "status": self.status,
            "mip_gap": self.mip_gap,
            "solver_objective": self.solver_objective,
            "n_combinations": self.n_combinations,
            "n_variables": self.n_variables,
            "n_constraints": self.n_constraints,
            "solve_time_s": self.solve_time_s,
            "min_p_complete": self.min_p_complete,
        }


def plan(sc: Scenario, day: str | int, *, method: str = "auto", enum_limit: int = AUTO_ENUM_LIMIT,
         time_limit_s: float | None = None, min_p_complete: float | None = None) -> Plan:
    """The assignment of shared stops that minimises the day's total objective.

    Parameters
    ----------
    sc : the scenario
    day : a day name, or its index (0-based)
    method : "enumerate" (every combination), "milp" (HiGHS) or "auto" (default:
        enumerate when there are at most ``enum_limit`` combinations, else MILP)
    enum_limit : "auto"'s enumeration limit, default :data:`AUTO_ENUM_LIMIT` (1,024)
    time_limit_s : MILP time limit [s]; None (default) for none. A MILP stopped by the
        limit reports status "time limit" and its gap: then the answer is not proven.
    min_p_complete : require every vehicle with a budget (an EV's battery above its
        reserve, an ICE's tank) to complete its day with at least this probability
        (:mod:`cevm.core.assignment.chance`; in [0.5, 1)); None: no such requirement.
        Every plan reports each vehicle's probability (``p_complete``).

    Raises InputError when no assignment satisfies the limits (the message says why).
    """
    check_level(min_p_complete)
    t0 = time.perf_counter()
    d = sc.day_index(day)
    prob = day_problem(sc, d)
    n_comb = prob.n_combinations
    if method == "auto":
        method = "enumerate" if n_comb <= enum_limit else "milp"
    if method == "enumerate":
        if n_comb > ENUM_LIMIT:
            raise ValueError(f"{n_comb} combinations: too many to enumerate (limit {ENUM_LIMIT}); use method='milp'")
        best, info = solve_enumerate(sc, prob, min_p_complete)
    elif method == "milp":
        best, info = solve_milp(sc, prob, time_limit_s, min_p_complete)
    else:
        raise ValueError(f"method must be 'auto', 'enumerate' or 'milp', not {method!r}")
    if best is None:
        raise InputError(sc.path, f"day {sc.days[d]!r}: {info['why']}")
    ev = evaluate(sc, d, best)
    dflt = default_assignment(sc)
    dev = evaluate(sc, d, dflt)
    route_ids = [r.id for r in sc.routes]
    return Plan(
        scenario=sc.name,
        day=sc.days[d],
        objective=sc.objective_kind,
        unit=sc.unit,
        mass_model=sc.mass_model,
        assignment={s: route_ids[i] for s, i in ev.assignment.items()},
        evaluation=ev,
        total=ev.total,
        default_assignment={s: route_ids[i] for s, i in dflt.items()},
        default_total=dev.total if dev.feasible else None,
        default_violations=tuple(dev.violations()),
        method=info["method"],
        status=info["status"],
        mip_gap=info.get("mip_gap"),
        solver_objective=info.get("objective"),
        n_combinations=n_comb,
        n_variables=info.get("n_variables", 0),
        n_constraints=info.get("n_constraints", 0),
        solve_time_s=time.perf_counter() - t0,
        route_vehicle={r.id: r.vehicle_id for r in sc.routes},
        p_complete=p_complete(sc, d, ev),
        min_p_complete=min_p_complete,
    )
