"""The probability that each vehicle completes its day, and the plans that require one
(a chance constraint), still proven optimal.

A vehicle's day is the sum of the legs it drives: its predictive distribution
(:func:`cevm.core.predictive.total`, the day's legs as one group: the parameters' and the
meter's uncertainty common to all legs, the trip scatter shared at the posterior's day
correlation) gives P(day <= budget), the budget an EV's usable battery above its reserve
(:attr:`FleetVehicle.energy_budget_j`) or an ICE's tank (``tank_l``, where the file
gives one).

Requiring P >= p (``min_p_complete``) for every vehicle with a budget is the constraint
that the day's p-quantile fits the budget, in the distribution of every interval
(:mod:`cevm.core.distribution`: log-normal of the day's mean and standard deviation, as
each leg's interval in predict; the legs' extrapolation beyond the calibration's
temperatures widens it as it widens theirs). Its sd depends on the assignment (the masses
move the legs' energies and their gradients), so it is not a linear row of the MILP; it
is handled exactly:

- enumeration evaluates it for every combination, vectorised (:func:`day_moments`);
- the MILP keeps its deterministic rows (mean <= budget, implied by the chance
  constraint for p >= Phi(sigma / 2), the probability of staying below the mean, which
  is below 0.6 unless the day's standard deviation is more than half its mean: no
  assignment that satisfies it is lost) and, each time
  HiGHS returns an assignment that breaks the chance constraint (checked exactly with the
  CE model), adds the no-good cut that removes that one assignment (sum of its binaries
  <= their number - 1) and solves again. Each cut removes only an assignment proven
  infeasible, so the first assignment that satisfies the constraint is optimal among all
  that do; the loop ends, as there are finitely many assignments
  (:data:`MAX_CUTS` bounds it: beyond, the plan says it is not proven).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from cevm.core.assignment.scenario import FleetVehicle, Scenario
from cevm.core.cycle import CycleVector
from cevm.core.distribution import normal_quantile
from cevm.core.predictive import (
    Features,
    extrapolation_var,
    gradient_rows,
    mean,
    posterior_of,
    spec_parts,
    sqrt_cov,
    total,
)

if TYPE_CHECKING:
    from cevm.core.assignment.evaluation import Evaluation

#: The MILP's no-good cuts at most before a chance-constrained plan is given up as not
#: proven (each is one more solve).
MAX_CUTS = 200


def budget_of(v: FleetVehicle) -> float | None:
    """What a vehicle's day may use: an EV's usable battery above its reserve [J], an
    ICE's tank [l] (None without tank_l)."""
    if v.vehicle.is_ev:
        return v.energy_budget_j
    return None if v.vehicle.tank_l is None else float(v.vehicle.tank_l)


def _leg_features(sc: Scenario, d: int, v: FleetVehicle, legs: Sequence[tuple[int, int, float]]) -> Features | None:
    """The features of a vehicle's driven legs ((route index, leg index, mass) each)."""
    if not legs:
        return None
    t = sc.ambient_of(d)
    parts = []
    for ri, j, m in legs:
        vec = sc.routes[ri].legs[j].vector
        parts.append(Features.of(vec, v.vehicle, [m], None if t is None else [t]))
    return Features.concat(parts)


def p_complete(sc: Scenario, d: int, evaluation: Evaluation) -> dict[str, float | None]:
    """Each vehicle's probability of completing its day under ``evaluation`` (a
    :class:`cevm.core.assignment.Evaluation`) within its budget (:func:`budget_of`);
    None where it has no budget, or no uncertainty is known (no priors)."""
    rid = {r.id: i for i, r in enumerate(sc.routes)}
    out: dict[str, float | None] = {}
    for vu in evaluation.vehicles:
        v = sc.vehicle_by_id[vu.vehicle_id]
        budget = budget_of(v)
        legs = [(rid[ru.route_id], j, m) for ru in vu.routes for j, m in zip(ru.leg_index, ru.leg_mass_kg, strict=True)]
        f = _leg_features(sc, d, v, legs)
        if budget is None or f is None or posterior_of(v.vehicle) is None:
            out[vu.vehicle_id] = None
            continue
        p = total(v.vehicle, f)
        out[vu.vehicle_id] = float(p.prob_at_most(budget)[0])
    return out


class DayMoments:
    """Accumulates, per combination of an enumeration, one vehicle's day: the sum of its
    legs' means, of their gradients in the coefficients, of their durations and of their
    own scatter variances; :meth:`sd` is the day's standard deviation per combination."""

    def __init__(self, v: FleetVehicle, n_comb: int):
        self.v = v
        self.post = posterior_of(v.vehicle)
        k = 0 if self.post is None else len(self.post.terms)
        self.G = np.zeros((k, n_comb))
        self.mu = np.zeros(n_comb)
        self.dur = np.zeros(n_comb)
        self.own = np.zeros(n_comb)
        self.drawn = np.zeros(n_comb)  # the sum of the legs' max(mean, 0): the scatter's share part
        self.trips = np.zeros(n_comb)  # how many legs: the scatter's part that does not grow with a leg
        self.extra = np.zeros(n_comb)  # the sum of the legs' extrapolation standard deviations
        self.spec = np.zeros((2, n_comb))  # the sums of the legs' parts from a spec sheet's CdA and Cr

    def add(self, vec: CycleVector, masses: np.ndarray, driven: np.ndarray, t_day: float | None) -> None:
        """Legs of one vector at ``masses`` (n_comb x legs), counted where ``driven``."""
        if self.post is None:
            return
        uniq, inv = np.unique(masses, return_inverse=True)
        f = Features.of(vec, self.v.vehicle, uniq, None if t_day is None else np.full(uniq.size, t_day))
        mu_u = np.broadcast_to(mean(self.v.vehicle, f), uniq.shape)
        g_u = gradient_rows(self.v.vehicle, f, self.post.terms)
        inv = inv.reshape(masses.shape)
        sc_ = self.post.scatter
        self.G += np.einsum("kcl,cl->kc", g_u[:, inv], driven)
        mu = mu_u[inv]
        self.mu += np.sum(mu * driven, axis=1)
        self.dur += vec.duration_s * np.sum(driven, axis=1)
        self.own += np.sum(driven * sc_.trip_variance(vec.duration_s, mu), axis=1)
        self.drawn += np.sum(driven * np.maximum(mu, 0.0), axis=1)
        self.trips += np.sum(driven, axis=1)
        x = extrapolation_var(self.v.vehicle, self.post, f)
        if x is not None:  # one unknown slope for every leg: their standard deviations add
            self.extra += np.sum(driven * np.sqrt(np.broadcast_to(x, uniq.shape))[inv], axis=1)
        for j, part in enumerate(spec_parts(self.v.vehicle, f)):  # one CdA, one Cr for every leg
            self.spec[j] += np.sum(driven * np.broadcast_to(part, uniq.shape)[inv], axis=1)

    def sd(self) -> np.ndarray:
        if self.post is None:
            return np.zeros_like(self.mu)
        sc_ = self.post.scatter
        A = sqrt_cov(self.post.cov) @ self.G
        var = np.einsum("kc,kc->c", A, A) + (self.post.meter_share * self.mu) ** 2
        # the shared scatter's share part is of each leg's energy drawn (max(mean, 0) per leg, as
        # cevm.core.predictive.total has it), not of the day's net: a leg that gives energy back
        # does not cancel another's scatter
        var += sc_.sum_variance(self.dur, self.drawn, self.trips, self.own) + self.extra ** 2
        var += np.sum(self.spec ** 2, axis=0)
        return np.asarray(np.sqrt(var))


def z_of(p: float) -> float:
    return normal_quantile(p)


def check_level(p: float | None) -> None:
    if p is not None and not (isinstance(p, (int, float)) and 0.5 <= p < 1.0 and math.isfinite(p)):
        raise ValueError(f"the required probability of completing a day must be at least 0.5 and below 1, got {p!r}")


def prob(mean: np.ndarray, sd: np.ndarray, budget: float) -> np.ndarray:
    """P(the day's total <= budget): the distribution of every interval
    (:mod:`cevm.core.distribution`)."""
    from cevm.core import distribution

    return distribution.prob_at_most(mean, sd, budget)
