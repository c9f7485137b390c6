"""One day's optimisation problem: the stops with a choice and their options, the
stops without, and a hint at the binding limit when nothing is feasible."""

from __future__ import annotations

import math
from dataclasses import dataclass

from cevm.core.assignment.scenario import Scenario


@dataclass
class DayProblem:
    """One day's problem: free stops with their options (route indices), fixed stops."""

    d: int
    payload: dict[str, float]
    free: list[str]
    options: list[list[int]]
    fixed: dict[str, int]

    @property
    def n_combinations(self) -> int:
        return math.prod(len(o) for o in self.options)


def day_problem(sc: Scenario, d: int) -> DayProblem:
    """Day ``d``'s problem: a stop with one allowed route is fixed, the others free."""
    payload = {s: sc.payload_kg[s][d] for s in sc.stops()}
    free, options, fixed = [], [], {}
    for s in sc.stops():
        opts = sc.options(s)
        if len(opts) == 1:
            fixed[s] = opts[0]
        else:
            free.append(s)
            options.append(opts)
    return DayProblem(d=d, payload=payload, free=free, options=options, fixed=fixed)


def why_infeasible(sc: Scenario, prob: DayProblem) -> str:
    """A hint at the binding limit: a route over its gross limit with its fixed stops."""
    for ri, r in enumerate(sc.routes):
        v = sc.vehicle_by_id[r.vehicle_id]
        if v.max_gross_kg is None:
            continue
        fixed = [prob.payload[s] for s in r.stops if prob.fixed.get(s) == ri]
        if sc.mass_model == "carried":
            m = v.kerb_mass_kg + sum(fixed)
        else:
            m = v.kerb_mass_kg + max(fixed, default=0.0)
        if m > v.max_gross_kg:
            return f" (route {r.id!r}: {m:g} kg with its own stops alone, over {v.id}'s {v.max_gross_kg:g} kg)"
    return ""


def over_budget(sc: Scenario, least: dict[str, float]) -> str:
    """A hint at the binding energy limit: the first vehicle whose ``least`` use of the
    day (per vehicle id, in its quantity: battery J; a lower bound where not exact) is
    over its budget (an EV's battery above its reserve), with its routes and both figures
    in kWh; "" when none is."""
    from cevm.core.assignment.scenario import BUDGET_RTOL
    from cevm.units import J_PER_KWH

    for v in sc.vehicles:
        budget = v.energy_budget_j
        q = least.get(v.id)
        if budget is None or q is None or not q > budget * (1 + BUDGET_RTOL):
            continue
        routes = ", ".join(repr(r.id) for r in sc.routes if r.vehicle_id == v.id)
        return (f" ({v.id} on route {routes}: at least {q / J_PER_KWH:,.1f} kWh, over the {budget / J_PER_KWH:,.1f} "
                "kWh of its battery above the reserve)")
    return ""
