"""The MILP solver (HiGHS through :func:`scipy.optimize.milp`): the model of the package
docstring, built part by part.

Variables: binaries x[s, r] (free stop s served by route r, :class:`Binaries`), then one
epigraph variable t per leg whose consumption is not affine over its mass range
(:func:`leg_terms`). Objective (:func:`objective`): each vehicle's quantity times its
objective weight, scaled to about :data:`_MILP_OBJECTIVE_SCALE`. Constraints
(:func:`constraints`): one route per free stop, gross weight, the epigraph pieces and
the EV energy budgets. :func:`solve_milp` solves and decodes the answer.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cevm.core.assignment.chance import MAX_CUTS, p_complete
from cevm.core.assignment.curves import LegCurve, leg_curve, quantity
from cevm.core.assignment.evaluation import evaluate, objective_weights
from cevm.core.assignment.problem import DayProblem, over_budget, why_infeasible
from cevm.core.assignment.scenario import BUDGET_RTOL, Route, Scenario
from cevm.core.vehicle import predict

#: Scaled objective magnitude for the MILP (see the package docstring).
_MILP_OBJECTIVE_SCALE = 1e3

_METHOD = "milp (HiGHS)"
_HIGHS_STATUS = {0: "optimal", 1: "time limit", 2: "infeasible", 3: "unbounded", 4: "error"}


class _Infeasible(Exception):
    """No assignment can satisfy the limits, known before solving: ``why``."""

    def __init__(self, why: str):
        super().__init__(why)
        self.why = why


@dataclass
class Binaries:
    """The binary variables: one per (free stop, route that may serve it)."""

    stop: list[int]  # index of the free stop (into prob.free) of each binary
    route: list[int]  # route index of each binary
    of: dict[tuple[str, int], int]  # (stop, route index) -> binary
    payload_kg: np.ndarray  # payload of each binary's stop

    @property
    def n(self) -> int:
        return len(self.route)


def binaries(prob: DayProblem) -> Binaries:
    opt_stop: list[int] = []
    opt_route: list[int] = []
    for j, opts in enumerate(prob.options):
        for ri in opts:
            opt_stop.append(j)
            opt_route.append(ri)
    opt_of = {(prob.free[j], ri): k for k, (j, ri) in enumerate(zip(opt_stop, opt_route, strict=True))}
    pay_x = np.array([prob.payload[prob.free[j]] for j in opt_stop])
    return Binaries(stop=opt_stop, route=opt_route, of=opt_of, payload_kg=pay_x)


@dataclass
class LegTerms:
    """Every leg's consumption as terms of the model, per vehicle in its quantity
    (litres or battery joules): a constant, a linear term in the binaries, and the legs
    that need an epigraph variable; and the limits on the binaries."""

    const: dict[str, float]  # per vehicle
    lin_x: dict[str, np.ndarray]  # per vehicle, d quantity / d x
    epi: list[tuple[str, LegCurve, float, np.ndarray, np.ndarray]] = field(default_factory=list)
    # (vehicle id, curve, mass without the free stops [kg], binaries carried, their payloads)
    x_ub: np.ndarray = field(default_factory=lambda: np.ones(0))  # upper bound of each binary
    gross_rows: list[tuple[np.ndarray, np.ndarray, float]] = field(default_factory=list)
    # (binaries, payloads, room [kg]): sum payload x <= room

    @property
    def n_t(self) -> int:
        return len(self.epi)


def _use(vector, fleet_vehicle, mass_kg: float, t_day) -> float:
    """The CE model's consumption of a vehicle over one leg at one mass."""
    return float(quantity(predict(vector, fleet_vehicle.vehicle, np.array([mass_kg]), ambient_c=t_day),
                          fleet_vehicle.vehicle)[0])


def _eq32_route_terms(sc: Scenario, prob: DayProblem, xb: Binaries, ri: int, r: Route, terms: LegTerms,
                      t_day) -> None:
    """``mass_model = "paper-eq32"``: each served stop costs one leg at kerb + its payload."""
    v = sc.vehicle_by_id[r.vehicle_id]
    kerb = v.kerb_mass_kg
    stop_x = [xb.of.get((s, ri)) for s in r.stops]
    for k, s in enumerate(r.stops):
        if stop_x[k] is None and prob.fixed.get(s) != ri:
            continue
        m = kerb + prob.payload[s]
        q = _use(r.legs[k].vector, v, m, t_day)
        if stop_x[k] is None:
            if v.max_gross_kg is not None and m > v.max_gross_kg:
                raise _Infeasible(f"stop {s!r} alone ({m:g} kg) is over {v.id}'s {v.max_gross_kg:g} kg")
            terms.const[v.id] += q
        else:
            terms.lin_x[v.id][stop_x[k]] += q
            if v.max_gross_kg is not None and m > v.max_gross_kg:
                terms.x_ub[stop_x[k]] = 0.0


def _carried_route_terms(sc: Scenario, prob: DayProblem, xb: Binaries, ri: int, r: Route, terms: LegTerms,
                         t_day) -> None:
    """``mass_model = "carried"``: leg l carries the served stops at positions >= l."""
    v = sc.vehicle_by_id[r.vehicle_id]
    kerb = v.kerb_mass_kg
    pay_x = xb.payload_kg
    stop_x = [xb.of.get((s, ri)) for s in r.stops]
    fixed_pay = np.array([prob.payload[s] if prob.fixed.get(s) == ri else 0.0 for s in r.stops])
    xs = np.array([x if x is not None else -1 for x in stop_x])
    m0 = kerb + np.cumsum(fixed_pay[::-1])[::-1]
    if v.max_gross_kg is not None:
        if m0[0] > v.max_gross_kg:
            raise _Infeasible("no assignment satisfies the limits" + why_infeasible(sc, prob))
        sel = xs[xs >= 0]
        if sel.size:
            terms.gross_rows.append((sel, pay_x[sel], v.max_gross_kg - m0[0]))
    n_stop_legs = len(r.stops)
    for j, leg in enumerate(r.legs):
        if j >= n_stop_legs:  # the return leg, empty
            terms.const[v.id] += _use(leg.vector, v, kerb, t_day)
            continue
        sel = xs[j:][xs[j:] >= 0]
        if sel.size == 0:
            terms.const[v.id] += _use(leg.vector, v, m0[j], t_day)
            continue
        m_hi = m0[j] + pay_x[sel].sum()
        if v.max_gross_kg is not None:
            m_hi = min(m_hi, v.max_gross_kg)
        curve = leg_curve(leg.vector, v.vehicle, m0[j], max(m_hi, m0[j]), ambient_c=t_day)
        if curve.affine:
            terms.const[v.id] += float(curve.alpha[0] + curve.beta[0] * m0[j])
            terms.lin_x[v.id][sel] += curve.beta[0] * pay_x[sel]
        else:
            terms.epi.append((v.id, curve, float(m0[j]), sel, pay_x[sel]))


def leg_terms(sc: Scenario, prob: DayProblem, xb: Binaries) -> LegTerms:
    """Every route's legs as model terms (:class:`LegTerms`), route by route in file
    order; raises :class:`_Infeasible` for a limit no assignment can meet."""
    terms = LegTerms(const={v.id: 0.0 for v in sc.vehicles}, lin_x={v.id: np.zeros(xb.n) for v in sc.vehicles},
                     x_ub=np.ones(xb.n))
    t_day = sc.ambient_of(prob.d)
    route_terms = _eq32_route_terms if sc.mass_model == "paper-eq32" else _carried_route_terms
    for ri, r in enumerate(sc.routes):
        route_terms(sc, prob, xb, ri, r, terms, t_day)
    return terms


@dataclass
class Objective:
    """The scaled objective vector ``c``, the scale ``ref`` of the objective (objective
    units) and each vehicle's factor from its quantity to the scaled objective."""

    c: np.ndarray
    ref: float
    qscale: dict[str, float]


def objective(sc: Scenario, weights: dict[str, float], xb: Binaries, terms: LegTerms) -> Objective:
    """The objective, scaled to about :data:`_MILP_OBJECTIVE_SCALE`: each vehicle's
    linear terms on the binaries, and its epigraph variables at weight one each."""
    ref = sum(abs(terms.const[v.id]) * weights[v.id] for v in sc.vehicles)
    ref += sum(float(np.max(np.abs(c.alpha + c.beta * m0))) * weights[vid] for vid, c, m0, _, _ in terms.epi)
    qscale = {v.id: weights[v.id] * _MILP_OBJECTIVE_SCALE / ref if ref > 0 else 1.0 for v in sc.vehicles}
    c = np.zeros(xb.n + terms.n_t)
    for v in sc.vehicles:
        c[:xb.n] += terms.lin_x[v.id] * qscale[v.id]
    for t, (vid, *_) in enumerate(terms.epi):
        c[xb.n + t] = qscale[vid]
    return Objective(c=c, ref=ref, qscale=qscale)


class _Rows:
    """Sparse constraint rows ``lo <= A x <= hi``, added one by one."""

    def __init__(self) -> None:
        self.rows: list[np.ndarray] = []
        self.cols: list[np.ndarray] = []
        self.vals: list[np.ndarray] = []
        self.lo: list[float] = []
        self.hi: list[float] = []

    @property
    def n(self) -> int:
        return len(self.lo)

    def add(self, idx, coef, lb: float, ub: float) -> None:
        self.rows.append(np.full(len(idx), self.n))
        self.cols.append(np.asarray(idx))
        self.vals.append(np.asarray(coef, dtype=np.float64))
        self.lo.append(lb)
        self.hi.append(ub)

    def constraint(self, n_var: int):
        # SciPy's optimize and sparse are imported when a MILP is solved: 0.2-0.3 s that
        # enumeration (most plans) and importing the package never pay
        from scipy.optimize import LinearConstraint
        from scipy.sparse import csr_matrix

        A = csr_matrix((np.concatenate(self.vals), (np.concatenate(self.rows), np.concatenate(self.cols))),
                       shape=(self.n, n_var))
        return LinearConstraint(A, np.array(self.lo), np.array(self.hi))


def constraints(sc: Scenario, prob: DayProblem, xb: Binaries, terms: LegTerms, obj: Objective) -> _Rows:
    """The rows: each free stop served by one route; each vehicle's gross weight (in
    tonnes); each epigraph leg's pieces, t >= a + b m; each EV's energy budget. Raises
    :class:`_Infeasible` for an EV whose fixed legs alone exceed its budget."""
    n_x = xb.n
    rows = _Rows()
    opt_stop = np.array(xb.stop)
    for j in range(len(prob.free)):
        rows.add(np.flatnonzero(opt_stop == j), np.ones(len(prob.options[j])), 1.0, 1.0)
    for sel, pay, cap in terms.gross_rows:
        rows.add(sel, pay / 1e3, -np.inf, cap / 1e3)
    for t, (vid, curve, m0, sel, pay) in enumerate(terms.epi):
        s = obj.qscale[vid] if obj.qscale[vid] > 0 else 1.0
        for a, b in zip(curve.alpha, curve.beta, strict=True):
            # t >= a + b (m0 + sum pay x)  <=>  b pay . x - t <= -(a + b m0)
            rows.add(np.append(sel, n_x + t), np.append(b * pay * s, -s), -np.inf, -(a + b * m0) * s)
    for v in sc.vehicles:
        budget = v.energy_budget_j
        if budget is None:
            continue
        budget *= 1 + BUDGET_RTOL
        lin = terms.lin_x[v.id]
        ts = [n_x + t for t, e in enumerate(terms.epi) if e[0] == v.id]
        s = _MILP_OBJECTIVE_SCALE / max(budget, 1.0)
        idx = np.concatenate([np.flatnonzero(lin), ts]).astype(int)
        coef = np.concatenate([lin[lin != 0], np.ones(len(ts))]) * s
        if idx.size:
            rows.add(idx, coef, -np.inf, (budget - terms.const[v.id]) * s)
        elif terms.const[v.id] > budget:
            raise _Infeasible("no assignment satisfies the battery limits" + over_budget(sc, {v.id: terms.const[v.id]}))
    return rows


def _highs(obj: Objective, rows: _Rows, terms: LegTerms, n_x: int, time_limit_s: float | None):
    """HiGHS on the model: binaries in [0, x_ub], epigraph variables free; a relative
    gap of 0 (proven optimal)."""
    from scipy.optimize import Bounds, milp  # when solved: see _Rows.constraint

    n_t = terms.n_t
    integrality = np.concatenate([np.ones(n_x), np.zeros(n_t)])
    bounds = Bounds(np.concatenate([np.zeros(n_x), np.full(n_t, -np.inf)]),
                    np.concatenate([terms.x_ub, np.full(n_t, np.inf)]))
    options: dict[str, Any] = {"mip_rel_gap": 0.0, "presolve": True}
    if time_limit_s is not None:
        options["time_limit"] = float(time_limit_s)
    return milp(obj.c, integrality=integrality, bounds=bounds, constraints=rows.constraint(n_x + n_t),
                options=options)


def _least_use(terms: LegTerms) -> dict[str, float]:
    """A lower bound of each vehicle's use of the day: its constant legs, and each leg of
    an epigraph at its mass without the free stops (the linear terms are >= 0)."""
    least = dict(terms.const)
    for vid, curve, m_wo, _, _ in terms.epi:
        least[vid] += float(curve(m_wo))
    return least


def _decode(res, sc: Scenario, prob: DayProblem, xb: Binaries, terms: LegTerms, obj: Objective,
            weights: dict[str, float], info: dict[str, Any]) -> dict[str, int] | None:
    """The assignment HiGHS found (None if none), and its status, gap and objective (in
    objective units, the constant terms included) in ``info``."""
    status = _HIGHS_STATUS.get(res.status, str(res.status))
    info["status"] = status
    info["mip_gap"] = getattr(res, "mip_gap", None)
    if res.x is None:
        info["why"] = (
            "no assignment satisfies the gross-weight and battery limits"
            + (why_infeasible(sc, prob) or over_budget(sc, _least_use(terms)))
            if status == "infeasible"
            else f"MILP solver stopped: {res.message}"
        )
        return None
    x = res.x[:xb.n] > 0.5
    best = dict(prob.fixed)
    for k in np.flatnonzero(x):
        best[prob.free[xb.stop[k]]] = xb.route[k]
    # back to objective units
    scale_back = obj.ref / _MILP_OBJECTIVE_SCALE if obj.ref > 0 else 1.0
    info["objective"] = float(res.fun) * scale_back + sum(terms.const[v.id] * weights[v.id] for v in sc.vehicles)
    return best


def solve_milp(sc: Scenario, prob: DayProblem, time_limit_s: float | None,
               min_p_complete: float | None = None) -> tuple[dict[str, int] | None, dict]:
    """The exact MILP of the package docstring, solved with HiGHS: the assignment (None
    if there is none) and what the solver said (``method``, ``status``, ``why`` when
    infeasible, ``mip_gap``, ``objective``, the model's size); with ``min_p_complete``,
    re-solved with a no-good cut for each assignment that breaks the chance constraint
    (:mod:`.chance`)."""
    weights = objective_weights(sc)
    xb = binaries(prob)
    try:
        terms = leg_terms(sc, prob, xb)
        obj = objective(sc, weights, xb, terms)
        rows = constraints(sc, prob, xb, terms, obj)
    except _Infeasible as exc:
        return None, {"method": _METHOD, "status": "infeasible", "why": exc.why}
    info: dict[str, Any] = {"method": _METHOD, "n_variables": xb.n + terms.n_t, "n_constraints": rows.n}
    if xb.n == 0:
        info.update(status="optimal", mip_gap=0.0,
                    objective=sum(terms.const[v.id] * weights[v.id] for v in sc.vehicles))
        return dict(prob.fixed), info
    res = _highs(obj, rows, terms, xb.n, time_limit_s)
    best = _decode(res, sc, prob, xb, terms, obj, weights, info)
    if min_p_complete is None or best is None:
        return best, info
    return _chance_cuts(sc, prob, xb, terms, obj, rows, weights, info, best, min_p_complete, time_limit_s)


def _chance_cuts(sc, prob, xb, terms, obj, rows, weights, info, best, p_min, time_limit_s):
    """The no-good cut loop of :mod:`.chance`: until HiGHS's assignment completes every
    budgeted day with probability ``p_min`` (or none is left)."""
    cuts = 0
    while True:
        ps = p_complete(sc, prob.d, evaluate(sc, prob.d, best))
        if all(p is None or p >= p_min for p in ps.values()):
            info["chance_cuts"] = cuts
            info["method"] = f"{_METHOD}, {cuts} no-good cut{'s' if cuts != 1 else ''} for the chance constraint"
            return best, info
        if cuts >= MAX_CUTS:
            info.update(status="not proven", chance_cuts=cuts,
                        why=f"the chance constraint still fails after {cuts} no-good cuts")
            return None, info
        chosen = [xb.of[(s, best[s])] for s in prob.free]
        rows.add(np.array(chosen), np.ones(len(chosen)), -np.inf, len(chosen) - 1.0)
        cuts += 1
        res = _highs(obj, rows, terms, xb.n, time_limit_s)
        info["n_constraints"] = rows.n
        best = _decode(res, sc, prob, xb, terms, obj, weights, info)
        if best is None:
            info["chance_cuts"] = cuts
            info["why"] = (f"no assignment completes every day with probability {p_min:g} "
                           f"({cuts} assignment{'s' if cuts != 1 else ''} tried and cut)")
            return None, info
