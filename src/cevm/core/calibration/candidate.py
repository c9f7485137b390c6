"""One candidate model, fitted as a calibration fits it: balance temperatures, posterior,
scatter from held-out residuals (pure).

A candidate is a term set (and whether the logs' standstill rates are observations). Its
fit on trips ``idx`` (:func:`fit_candidate`):

1. the balance temperatures of its temperature terms on a grid (:data:`HEATING_GRID_C`,
   :data:`COOLING_GRID_C`; coordinate search), by the log marginal likelihood at the
   class's typical scatter;
2. the posterior (:func:`.posterior.solve`) with the scatter fitted in sample (it weighs
   the trips); a term without a prior (a vehicle built without one) that the trips cannot
   identify is refused and dropped, with the reason (:mod:`.identifiability`), as a
   term with a prior never is: it keeps its prior;
3. every trip predicted by the posterior of the other days (grouped folds), and the
   scatter for predictions fitted to those held-out residuals
   (:func:`.posterior.heldout_scatter`); the held-out errors are also the candidate's
   cross-validated errors in the model selection (:mod:`.selection`).
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from cevm.core.calibration import identifiability
from cevm.core.calibration import posterior as post
from cevm.core.calibration.data import CalibrationError
from cevm.core.calibration.solve import HUBER_C
from cevm.core.calibration.terms import TERMS_BY_POWERTRAIN, TermModel
from cevm.core.uncertainty import CoefficientPrior, Priors, ScatterPrior, coefficient_prior

#: Balance temperatures tried for a candidate with heating (or warm-up) and cooling terms
#: [degC]: where a vehicle's heating and air conditioning start depends on its cabin,
#: its heater (a heat pump's power grows faster than the cold) and its climate settings;
#: a fixed 16 / 22 degC missed the sample buses' heat pumps by half their CV error.
HEATING_GRID_C = (6.0, 8.0, 10.0, 12.0, 14.0, 16.0, 18.0, 20.0)
COOLING_GRID_C = (16.0, 18.0, 20.0, 22.0, 24.0, 26.0, 28.0)


@dataclass(frozen=True)
class Settings:
    """How candidates are fitted: ``huber_c`` (None: least squares), the grouped folds
    (``cv_folds``, leave-one-day-out below ``loo_below`` days, ``seed``), whether the
    balance temperatures are searched (``fit_balance``), the identifiability limits of
    terms without a prior (``max_correlation``, ``max_rel_se``), and physical ranges that
    replace the terms' own (``plausible``: research fits only,
    :func:`cevm.core.uncertainty.plausible_range`)."""

    huber_c: float | None = HUBER_C
    cv_folds: int = 5
    loo_below: int = 10
    seed: int = 0
    fit_balance: bool = True
    max_correlation: float = 0.98
    max_rel_se: float = 0.5
    plausible: Mapping[str, tuple[float, float]] | None = None


@dataclass(frozen=True, eq=False)
class CandidateFit:
    """A fitted candidate: its ``names`` (terms kept), whether standstill rates were
    observations, the ``model`` at its balance temperatures, the coefficient ``prior``,
    the posterior with the held-out scatter (``fit``), the in-sample one
    (``in_sample``), the held-out predictions (``heldout``, None when not made) and the
    terms refused with why (``refused``: terms without a prior the trips cannot tell)."""

    names: tuple[str, ...]
    standstill: bool
    model: TermModel
    prior: CoefficientPrior
    fit: post.PosteriorFit
    in_sample: post.PosteriorFit
    heldout: post.HeldOut | None
    refused: dict = field(default_factory=dict)
    scatter_prior: ScatterPrior | None = None
    scatter_fixed: bool = False

    def cv_error_pct(self) -> np.ndarray:
        """Held-out relative errors [%] of the trips fitted (NaN where not predicted)."""
        if self.heldout is None:
            return np.full(self.fit.idx.size, math.nan)
        y = self.model.data.y[self.heldout.idx]
        return np.asarray((self.heldout.mean - y) / y * 100.0)


def prior_for(model: TermModel, names: Sequence[str], priors: Priors | None,
              plausible: Mapping[str, tuple[float, float]] | None = None) -> CoefficientPrior:
    """The coefficients' prior of ``names`` for ``model``'s vehicle (Cr bounded below by
    the trips' vectors' Cr0: their split is exact only above it)."""
    cp = coefficient_prior(model.vehicle.powertrain, names, priors, model.vehicle.eta, plausible)
    if "cr" in names:
        j = list(names).index("cr")
        cp.lb[j] = max(cp.lb[j], max((v.cr0 for v in model.data.vectors), default=0.0))
    return cp


def _has_temperature(model: TermModel, idx: np.ndarray) -> bool:
    return bool(np.all(np.isfinite(model.data.ambient_c[idx]))) and idx.size > 0


def balanced(model: TermModel, names: Sequence[str], idx: np.ndarray, priors: Priors | None,
             noise: post.Noise, settings: Settings) -> TermModel:
    """``model`` at the balance temperatures of the grids that give the candidate the
    highest log marginal likelihood on the trips ``idx`` (heating, then cooling; at the
    scatter fitted at the vehicle's balance temperatures), among
    those the trips can place (:func:`.identifiability.unsupported`: enough trips, days
    and kelvin on the side the term drives); unchanged without temperature terms or
    logged temperatures, and an axis no grid value of which the trips can place keeps
    the vehicle's balance temperature."""
    heats = any(n in ("heat", "warm") for n in names)
    cools = "cool" in names
    if not settings.fit_balance or not (heats or cools) or not _has_temperature(model, idx):
        return model
    hb, cb = model.vehicle.heating_below_c, model.vehicle.cooling_above_c
    # the scatter at the vehicle's balance temperatures, fitted once: at a scatter far
    # from the trips' (the class's typical one), the evidence hardly tells the grid
    # points apart
    centre = None if priors is None else priors.scatter
    with contextlib.suppress(np.linalg.LinAlgError):
        noise = post.solve(model, names, idx, prior_for(model, names, priors, settings.plausible), noise,
                           huber_c=settings.huber_c,
                           fit_noise=True, scatter_prior=centre, noise_rounds=2).noise
    for axis, grid in (("heat", HEATING_GRID_C if heats else ()), ("cool", COOLING_GRID_C if cools else ())):
        best = None
        for g in grid:
            h2, c2 = (g, cb) if axis == "heat" else (hb, g)
            if h2 > c2:
                continue
            m = model.with_balance(h2, c2)
            cp = prior_for(m, names, priors, settings.plausible)
            # a balance temperature the trips cannot place (too few trips on the side it
            # drives) is not chosen: the vehicle's stays (a summer-only trial keeps
            # 16 degC for heating, instead of a grid end no trip reaches)
            term = "heat" if axis == "heat" and "heat" in names else ("warm" if axis == "heat" else "cool")
            if identifiability.unsupported(m, ["eta", term], idx) is not None:
                continue
            if not np.all(np.isfinite(cp.sd)) and identifiability.unsupported(m, names, idx) is not None:
                continue
            f = post.solve(m, names, idx, cp, noise, huber_c=settings.huber_c, scatter_prior=centre)
            if best is None or f.logml > best[0]:
                best = (f.logml, h2, c2)
        if best is not None:
            _, hb, cb = best
    return model.with_balance(hb, cb)


def _flat(prior: CoefficientPrior, name: str) -> bool:
    return name != "eta" and not prior.informative(name)


def fit_candidate(model: TermModel, names: Sequence[str], idx: np.ndarray, priors: Priors | None,
                  settings: Settings, *, standstill: bool = False, heldout: bool = True,
                  balance: bool = True, scatter: tuple[float, ...] | None = None) -> CandidateFit:
    """Fit the candidate ``names`` on the trips ``idx`` (module notes); ``scatter``
    (s_aux, s_share[, s_trip]) fixes the scatter instead of fitting it (s_trip 0 where
    not given). Raises
    :class:`CalibrationError` when eta itself cannot be fitted."""
    idx = np.asarray(idx, dtype=np.intp)
    centre = None if priors is None else priors.scatter
    noise0 = post.initial_noise(model, idx, centre, standstill)
    if scatter is not None:
        noise0 = post.Noise(float(scatter[0]), float(scatter[1]), 0.0, noise0.standstill,
                            float(scatter[2]) if len(scatter) > 2 else 0.0)
    active = list(names)
    refused: dict = {}
    while True:
        m = balanced(model, active, idx, priors, noise0, settings) if balance else model
        cp = prior_for(m, active, priors, settings.plausible)
        # a term with a prior keeps it where the trips cannot tell: only the others must
        # earn their place
        bad = identifiability.unsupported(m, ["eta"] + [n for n in active if _flat(cp, n)], idx)
        if bad is None:
            fit = post.solve(m, active, idx, cp, noise0, huber_c=settings.huber_c, fit_noise=scatter is None,
                             scatter_prior=centre)
            flat = [n for n in active if _flat(cp, n)]
            if flat:
                bad = identifiability.confounded(fit.jw, active, settings.max_correlation, m)
                if bad is not None and bad[0] not in flat:
                    bad = None
                if bad is None:
                    bad = identifiability.imprecise(m, fit, idx, settings.max_rel_se)
                    if bad is not None and bad[0] not in flat:
                        bad = None
        if bad is None:
            break
        if bad[0] == "eta" or bad[0] not in active or len(active) == 1:
            raise CalibrationError(f"eta cannot be fitted: {bad[1]}")
        refused[bad[0]] = bad[1]
        active.remove(bad[0])
    ho = None
    final = fit
    if heldout:
        fold_of = post.inner_folds(m, idx, settings.cv_folds, settings.loo_below, settings.seed)
        if np.any(fold_of >= 0):
            # each fold from the same start as the whole fit: nothing of the held-out
            # trips (not even a starting point) reaches their predictions
            ho = post.held_out(m, active, idx, cp, noise0, huber_c=settings.huber_c, fold_of=fold_of,
                               fit_noise=scatter is None, scatter_prior=centre)
            noise = post.heldout_scatter(m, ho, centre, fit.noise, settings.huber_c) if scatter is None else fit.noise
            final = post.solve(m, active, idx, cp, noise, huber_c=settings.huber_c, theta0=fit.theta,
                               scatter_prior=centre)
    return CandidateFit(tuple(active), fit.noise.standstill is not None, m, cp, final, fit, ho, refused, centre,
                        scatter is not None)


def field_of(model: TermModel, name: str) -> str:
    return TERMS_BY_POWERTRAIN[(model.vehicle.powertrain, name)].field
