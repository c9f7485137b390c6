"""The enumeration solver: every combination of choices, vectorised."""

from __future__ import annotations

import numpy as np

from cevm.core.assignment.chance import DayMoments, budget_of
from cevm.core.assignment.chance import prob as p_within
from cevm.core.assignment.curves import quantity
from cevm.core.assignment.evaluation import objective_weights, vector_groups
from cevm.core.assignment.problem import DayProblem, over_budget, why_infeasible
from cevm.core.assignment.scenario import BUDGET_RTOL, Scenario
from cevm.core.vehicle import predict


def solve_enumerate(sc: Scenario, prob: DayProblem, min_p_complete: float | None = None
                    ) -> tuple[dict[str, int] | None, dict]:
    """Every combination of choices, vectorised: one CE prediction per (leg, unique
    vector) for all combinations at once; with ``min_p_complete``, only the combinations
    whose every vehicle with a budget completes its day with at least that probability
    (:mod:`.chance`)."""
    n_comb = prob.n_combinations
    sizes = [len(o) for o in prob.options]
    choice = np.stack(np.unravel_index(np.arange(n_comb), sizes), axis=1) if sizes else np.zeros((1, 0), dtype=int)
    free_col = {s: j for j, s in enumerate(prob.free)}
    weights = objective_weights(sc)
    total = np.zeros(n_comb)
    vehicle_q = {v.id: np.zeros(n_comb) for v in sc.vehicles}
    feasible = np.ones(n_comb, dtype=bool)
    fv = sc.vehicle_by_id
    moments = {}
    if min_p_complete is not None:
        moments = {v.id: DayMoments(v, n_comb) for v in sc.vehicles if budget_of(v) is not None}
    for ri, r in enumerate(sc.routes):
        v = fv[r.vehicle_id]
        served = np.empty((n_comb, len(r.stops)))
        for k, s in enumerate(r.stops):
            if s in prob.fixed:
                served[:, k] = 1.0 if prob.fixed[s] == ri else 0.0
            else:
                j = free_col[s]
                served[:, k] = choice[:, j] == prob.options[j].index(ri) if ri in prob.options[j] else 0.0
        pay = served * np.array([prob.payload[s] for s in r.stops])
        if sc.mass_model == "carried":
            carried = np.cumsum(pay[:, ::-1], axis=1)[:, ::-1]
            if r.return_to_depot:
                carried = np.concatenate([carried, np.zeros((n_comb, 1))], axis=1)
            driven = np.ones_like(carried)
        else:
            carried = np.concatenate([pay, np.zeros((n_comb, len(r.legs) - len(r.stops)))], axis=1)
            driven = np.concatenate([served, np.zeros((n_comb, len(r.legs) - len(r.stops)))], axis=1)
        mass = v.kerb_mass_kg + carried
        if v.max_gross_kg is not None:
            feasible &= np.max(np.where(driven > 0, mass, 0.0), axis=1) <= v.max_gross_kg
        q = np.zeros(n_comb)
        for vec, cols in vector_groups(r.legs):
            m = mass[:, cols]
            uniq, inv = np.unique(m, return_inverse=True)
            pred = predict(vec, v.vehicle, uniq, ambient_c=sc.ambient_of(prob.d))
            use = quantity(pred, v.vehicle)[inv].reshape(m.shape)
            q += np.sum(use * driven[:, cols], axis=1)
            if v.id in moments:
                moments[v.id].add(vec, m, driven[:, cols], sc.ambient_of(prob.d))
        vehicle_q[v.id] += q
    for v in sc.vehicles:
        total += weights[v.id] * vehicle_q[v.id]
        if v.energy_budget_j is not None:
            feasible &= vehicle_q[v.id] <= v.energy_budget_j * (1 + BUDGET_RTOL)
        if v.id in moments:
            budget = budget_of(v)
            if budget is not None:
                feasible &= p_within(vehicle_q[v.id], moments[v.id].sd(), budget) >= min_p_complete
    info = {"method": f"enumeration ({n_comb} combinations)", "n_variables": len(prob.free),
            "n_constraints": 0, "mip_gap": 0.0}
    if not feasible.any():
        info["why"] = ("no assignment satisfies the gross-weight and battery limits"
                       + (f" with every day completed with probability {min_p_complete:g}" if moments else "")
                       + (why_infeasible(sc, prob)
                          or over_budget(sc, {k: float(np.min(q)) for k, q in vehicle_q.items() if q.size})))
        info["status"] = "infeasible"
        return None, info
    k = int(np.argmin(np.where(feasible, total, np.inf)))
    best = dict(prob.fixed)
    for j, s in enumerate(prob.free):
        best[s] = prob.options[j][choice[k, j]]
    info["status"] = "optimal"
    info["objective"] = float(total[k])
    return best, info

