"""Model selection by grouped cross-validation (pure).

The candidates are eta with every subset of the powertrain's extra terms
(:data:`~.terms.EXTRA_TERMS`) that the trips can support. Each candidate is fitted to all
usable trips and cross-validated on the same grouped folds. A candidate is *refused*,
with the reason, when a term is not identifiable (:func:`.identifiability.unsupported`, confounded,
imprecise) or its value is physically implausible (:func:`.plausibility.implausible`): such a
candidate is shown, never chosen.

Choice (the one-standard-error rule, on paired errors): let b be the candidate with the
lowest cross-validated mean loss of its relative errors (MSE; with ``robust``, Huber's
loss: squared up to 3 scales, linear beyond, :data:`SELECTION_HUBER_K`). A candidate c is as good as b
when MSE_c - MSE_b <= SE, the standard error of that difference estimated from the
per-group sums of the paired squared-error differences (the folds' unit of
independence). The chosen model is the simplest candidate as good as b (fewest terms;
then the lower MSE): a term must buy more than noise to be kept.

Honesty: choosing among candidates by their cross-validated error makes the winner's
error optimistic. :func:`select` therefore also runs the whole selection inside each
outer fold (nested cross-validation): the trips of a fold are predicted by the model the
selection picks on the other folds alone. Its error is the one to quote for "cevm
calibrate, as a procedure" on unseen trips.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np

from cevm.core.calibration import identifiability, plausibility
from cevm.core.calibration.data import CalibrationError, TripData, select_trips
from cevm.core.calibration.fitting import CalibrationResult, fit_model
from cevm.core.calibration.solve import HUBER_C, fit_terms, value_covariance
from cevm.core.calibration.terms import EXTRA_TERMS, TERMS_BY_POWERTRAIN, TermModel, neutral
from cevm.core.calibration.validation import ErrorStats, folds
from cevm.core.vehicle import Vehicle


@dataclass(frozen=True)
class Candidate:
    """One candidate term set: its cross-validated errors, fitted values (field ->
    (value, standard error), SI) and status: "ok", "chosen", or "refused: why"; ``mse``
    the mean selection loss of its cross-validated errors (:data:`SELECTION_HUBER_K`)."""

    terms: tuple[str, ...]
    status: str
    cv: ErrorStats | None
    in_sample: ErrorStats | None
    fitted: dict
    mse: float
    se_vs_best: float = math.nan

    @property
    def ok(self) -> bool:
        return not self.status.startswith("refused")


@dataclass(frozen=True)
class Selection:
    """Outcome of :func:`select`: every candidate, the chosen model's full
    :class:`~.fitting.CalibrationResult`, and the nested cross-validated error of the
    selection as a procedure (None when it could not be run)."""

    candidates: tuple[Candidate, ...]
    chosen: tuple[str, ...]
    best: tuple[str, ...]
    result: CalibrationResult
    nested_cv: ErrorStats | None
    cv_scheme: str
    rule: str
    notes: tuple[str, ...] = ()


def candidate_sets(vehicle: Vehicle, terms: Sequence[str] | None = None) -> list[tuple[str, ...]]:
    """("eta", ...) for every subset of the extra terms (all of the powertrain's by
    default), fewest terms first."""
    extras = EXTRA_TERMS[vehicle.powertrain] if terms is None else tuple(terms)
    out = []
    for k in range(len(extras) + 1):
        for comb in itertools.combinations(extras, k):
            out.append(("eta", *comb))
    return out


@dataclass(frozen=True)
class _Options:
    tau: float | None
    max_correlation: float
    max_rel_se: float
    huber_c: float | None
    folds: int
    loo_below: int
    seed: int
    fit_balance: bool = True


#: Balance temperatures tried for a candidate with heating (or warm-up) and cooling terms
#: [degC]: where a vehicle's heating and air conditioning start depends on its cabin,
#: its heater (a heat pump's power grows faster than the cold) and its climate settings;
#: a fixed 16 / 22 degC missed the sample buses' heat pumps by half their CV error. The
#: one whose fit leaves the least model error (tau) wins, on the trips the candidate is
#: fitted to (inside each outer fold of the nested cross-validation too).
HEATING_GRID_C = (6.0, 8.0, 10.0, 12.0, 14.0, 16.0, 18.0, 20.0)
COOLING_GRID_C = (16.0, 18.0, 20.0, 22.0, 24.0, 26.0, 28.0)


def _balanced(model: TermModel, names, idx, opt: _Options) -> TermModel:
    """``model`` with the balance temperatures that fit the candidate ``names`` best on
    the trips ``idx`` (coordinate search over :data:`HEATING_GRID_C` then
    :data:`COOLING_GRID_C`); ``model`` itself without temperature terms."""
    heats = any(n in ("heat", "warm") for n in names)
    cools = "cool" in names
    if not opt.fit_balance or not (heats or cools):
        return model
    hb, cb = model.vehicle.heating_below_c, model.vehicle.cooling_above_c
    for axis, grid in (("heat", HEATING_GRID_C if heats else ()), ("cool", COOLING_GRID_C if cools else ())):
        trial = []
        for g in grid:
            h2, c2 = (g, cb) if axis == "heat" else (hb, g)
            if h2 > c2:
                continue
            m = model.with_balance(h2, c2)
            if identifiability.unsupported(m, names, idx) is not None:
                continue
            f = fit_terms(m, names, idx, opt.tau, huber_c=opt.huber_c)
            trial.append((f.tau, f.s2 if math.isfinite(f.s2) else math.inf, h2, c2))
        if trial:
            _, _, hb, cb = min(trial)
    return model.with_balance(hb, cb)


def _cv_errors(model: TermModel, names, fold_of, idx, opt: _Options) -> np.ndarray:
    """Cross-validated relative errors [%] of the trips ``idx`` with folds ``fold_of``
    (NaN where a fold could not be fitted); the model's own vectorised predictions."""
    err = np.full(len(idx), math.nan)
    y = model.data.y[idx]
    for f in np.unique(fold_of[fold_of >= 0]):
        tr = idx[fold_of != f]
        te_pos = np.flatnonzero(fold_of == f)
        if tr.size < len(names) + 1:
            continue
        ff = fit_terms(model, names, tr, opt.tau, huber_c=opt.huber_c)
        p = model.predict(names, ff.theta, idx[te_pos])
        err[te_pos] = (p - y[te_pos]) / y[te_pos] * 100.0
    return err


def _status(model: TermModel, names, idx, opt: _Options):
    """(the model with its balance temperatures, fit or None, refusal reason or None) of a
    candidate on the trips ``idx``."""
    model = _balanced(model, names, idx, opt)
    bad = identifiability.unsupported(model, names, idx)
    if bad is not None:
        return model, None, bad
    f = fit_terms(model, names, idx, opt.tau, huber_c=opt.huber_c)
    bad = (identifiability.confounded(f.jw, names, opt.max_correlation, model)
           or identifiability.imprecise(model, f, idx, opt.max_rel_se) or plausibility.implausible(model, f, idx))
    return model, f, bad


#: The selection's loss on a cross-validated error e [%]: e^2 up to K scales, linear
#: beyond (Huber's), the scale being the smallest median absolute error among the
#: candidates (x 1.4826: the standard deviation for normal errors). A trip no candidate
#: can predict (a broken measurement) then weighs like a trip K scales off, not like its
#: square: it cannot decide which terms are kept.
SELECTION_HUBER_K = 3.0


def _losses(errs: dict, robust: bool) -> dict:
    if not robust:
        return {c: e * e for c, e in errs.items()}
    scale = min(1.4826 * float(np.nanmedian(np.abs(e))) for e in errs.values())
    k = SELECTION_HUBER_K * max(scale, 1e-9)
    out = {}
    for c, e in errs.items():
        a = np.abs(e)
        out[c] = np.where(a <= k, e * e, 2.0 * k * a - k * k)
    return out


def _choose(errs: dict, groups: np.ndarray, robust: bool) -> tuple[tuple, tuple, dict, dict]:
    """(best, chosen, loss, se_vs_best) by the paired one-standard-error rule over groups."""
    losses = _losses(errs, robust)
    mean = {c: float(np.nanmean(v)) for c, v in losses.items()}
    best = min(mean, key=lambda c: (mean[c], len(c)))
    se = {}
    ug = np.unique(groups)
    for c, v in losses.items():
        d = v - losses[best]
        per_group = np.array([np.nansum(d[groups == g]) for g in ug])
        n = np.sum(np.isfinite(d))
        se[c] = float(math.sqrt(len(ug)) * per_group.std(ddof=1) / n) if len(ug) > 1 and n else math.inf
    ok = [c for c in errs if mean[c] - mean[best] <= se[c]]
    chosen = min(ok, key=lambda c: (len(c), mean[c]))
    return best, chosen, mean, se


def _select_on(model: TermModel, sets, idx, opt: _Options) -> tuple[tuple, tuple, dict, dict, dict, dict, dict]:
    """The selection on the trips ``idx``: (best, chosen, errors, (model, fit) per
    candidate, reasons, loss, se)."""
    data = model.data
    sub = data.subset(idx)
    fold_of, _ = folds(sub, opt.folds, opt.loo_below, opt.seed)
    groups = np.array([g if g is not None else f"\0{t}" for g, t in zip(sub.groups, sub.ids)], dtype=object)
    errs, fits, reasons = {}, {}, {}
    for names in sets:
        m, f, bad = _status(model, list(names), idx, opt)
        if bad is not None:
            reasons[names] = bad
            continue
        fits[names] = (m, f)
        errs[names] = _cv_errors(m, list(names), fold_of, idx, opt) if np.any(fold_of >= 0) else \
            (f.pred - data.y[idx]) / data.y[idx] * 100.0
    if not errs:
        raise CalibrationError("no candidate model could be fitted: "
                               + "; ".join(f"{'+'.join(c)}: {r[1]}" for c, r in list(reasons.items())[:3]))
    best, chosen, loss, se = _choose(errs, groups, opt.huber_c is not None)
    return best, chosen, errs, fits, reasons, loss, se


def select(
    vehicle: Vehicle,
    trips: Sequence[TripData],
    *,
    terms: Sequence[str] | None = None,
    cv_folds: int = 5,
    loo_below: int = 10,
    max_rel_uncertainty: float = 0.10,
    min_distance_m: float = 1000.0,
    rel_uncertainty_floor: float = 0.001,
    model_rel_sigma: float | None = None,
    max_correlation: float = 0.98,
    max_rel_se: float = 0.5,
    time_repeats: int = 20,
    seed: int = 0,
    nested: bool = True,
    vehicle_id: str | None = None,
    robust: bool = True,
    fit_balance: bool = True,
) -> Selection:
    """Choose the vehicle's terms by grouped cross-validation (module docstring) and fit
    the chosen model (:func:`~.fitting.fit`'s parameters; ``terms`` restricts the extra
    terms tried; ``nested`` runs the nested cross-validation of the procedure; ``robust``
    (default) fits Huber M-estimates and compares candidates with a Huber loss on their
    cross-validated errors, so a few broken measurements decide nothing); ``fit_balance``
    (default) chooses the balance temperatures of temperature terms on a grid
    (:data:`HEATING_GRID_C`), False keeps the vehicle's.

    Every candidate starts from ``vehicle`` with the terms it does not hold taken out of
    the model (no auxiliary power, regeneration at eta, ...); CdA and Cr stay as given.
    """
    base = neutral(vehicle)
    data, excluded = select_trips(base, trips, max_rel_uncertainty, min_distance_m, rel_uncertainty_floor)
    data, excluded, t_note = _trips_with_temperature(base, data, excluded, terms)
    if data.n < 3:
        why = "; ".join(f"{k}: {v}" for k, v in list(excluded.items())[:5])
        raise CalibrationError(f"eta needs at least 3 usable trips, {data.n} of {len(trips)} are usable"
                               + (f" (excluded: {why}{' ...' if len(excluded) > 5 else ''})" if excluded else ""))
    model = TermModel(base, data)
    extras, notes = _possible_terms(model, EXTRA_TERMS[base.powertrain] if terms is None else tuple(terms))
    notes = ([t_note] if t_note else []) + notes
    sets = candidate_sets(base, extras)
    idx = np.arange(data.n)
    fold_of, scheme = folds(data, cv_folds, loo_below, seed)
    opt = _Options(model_rel_sigma, max_correlation, max_rel_se, HUBER_C if robust else None, cv_folds, loo_below,
                   seed, fit_balance)
    best, chosen, errs, fits, reasons, loss, se = _select_on(model, sets, idx, opt)
    cands = []
    for names in sets:
        if names in reasons:
            term, why = reasons[names]
            cands.append(Candidate(names, f"refused: {term}: {why}", None, None, {}, math.nan))
            continue
        m, f = fits[names]
        vals, vcov = value_covariance(m, f)
        sd = np.sqrt(np.maximum(np.diag(vcov), 0.0))
        fitted = {TERMS_BY_POWERTRAIN[(base.powertrain, n)].field: (float(vals[n]), float(sd[j]))
                  for j, n in enumerate(names)}
        fitted.update(_balance_fields(m, names))
        e = errs[names]
        ins = ErrorStats.of((f.pred - data.y) / data.y * 100.0)
        cands.append(Candidate(names, "chosen" if names == chosen else "ok", ErrorStats.of(e), ins, fitted,
                               loss[names], se[names]))
    result = fit_model(fits[chosen][0], chosen, excluded, cv_folds=cv_folds, loo_below=loo_below, tau=model_rel_sigma,
                       max_correlation=max_correlation, max_rel_se=max_rel_se, time_repeats=time_repeats, seed=seed,
                       vehicle_id=vehicle_id, huber_c=opt.huber_c)
    balance = _balance_fields(fits[chosen][0], chosen) if opt.fit_balance else {}
    if balance:
        result = replace(result, fitted={**result.fitted, **balance})
    nested_cv = None
    if nested and np.any(fold_of >= 0):
        err = np.full(data.n, math.nan)
        for f in np.unique(fold_of[fold_of >= 0]):
            train = np.flatnonzero(fold_of != f)
            test = np.flatnonzero(fold_of == f)
            try:
                _, ch, _, fits_f, *_ = _select_on(model, sets, train, opt)
            except CalibrationError:
                continue
            mf = fits_f[ch][0]
            ff = fit_terms(mf, list(ch), train, model_rel_sigma, huber_c=opt.huber_c)
            p = mf.predict(list(ch), ff.theta, test)
            err[test] = (p - data.y[test]) / data.y[test] * 100.0
        nested_cv = ErrorStats.of(err)
    rule = ("the simplest candidate whose cross-validated mean squared error is within one standard error "
            "(paired, over groups) of the best")
    return Selection(tuple(cands), tuple(chosen), tuple(best), result, nested_cv, scheme, rule, tuple(notes))


#: When at least this share of the usable trips logged a temperature, the others are left
#: out (and said so) so that the temperature terms can be tried: every candidate is
#: compared on the same trips, and a temperature term needs one on every trip.
TEMPERATURE_QUORUM = 0.5


def _trips_with_temperature(vehicle: Vehicle, data, excluded: dict, terms) -> tuple:
    """``data`` without its trips that logged no temperature, when most did (a sensor
    that dropped out on some days); else unchanged. Returns (data, excluded, note)."""
    wanted = EXTRA_TERMS[vehicle.powertrain] if terms is None else tuple(terms)
    if not any(TERMS_BY_POWERTRAIN[(vehicle.powertrain, n)].temperature for n in wanted):
        return data, excluded, None
    has_t = np.isfinite(data.ambient_c)
    if has_t.all() or not has_t.any() or has_t.mean() < TEMPERATURE_QUORUM:
        return data, excluded, None
    excluded = dict(excluded)
    for i in np.flatnonzero(~has_t):
        excluded[data.ids[i]] = (f"no ambient temperature logged, while {int(has_t.sum())} of the {data.n} usable "
                                 "trips have one: left out so that the temperature terms can be compared")
    note = (f"{int((~has_t).sum())} of {data.n} usable trips logged no ambient temperature and were left out "
            "(the temperature terms need one on every trip)")
    return data.subset(np.flatnonzero(has_t)), excluded, note


def _balance_fields(model: TermModel, names) -> dict:
    """The balance temperatures a candidate with temperature terms was fitted with, as
    fitted fields (value, standard error NaN: chosen on a grid)."""
    out = {}
    if any(n in ("heat", "warm") for n in names):
        out["heating_below_c"] = (model.vehicle.heating_below_c, math.nan)
    if "cool" in names:
        out["cooling_above_c"] = (model.vehicle.cooling_above_c, math.nan)
    return out


def _possible_terms(model: TermModel, extras: Sequence[str]) -> tuple[tuple[str, ...], list[str]]:
    """The extra terms worth trying at all, and a note for each left out: temperature
    terms when no trip logged a temperature, a term whose feature is zero on every trip."""
    data = model.data
    keep, notes = [], []
    vals = model.vehicle_values()
    no_temp = [n for n in extras if TERMS_BY_POWERTRAIN[(model.vehicle.powertrain, n)].temperature]
    if no_temp and not np.any(np.isfinite(data.ambient_c)):
        notes.append(f"{', '.join(no_temp)} not tried: no trip has a logged ambient temperature (map the logger's "
                     "temperature column in its profile, then re-ingest)")
        extras = [n for n in extras if n not in no_temp]
    for n in extras:
        t = TERMS_BY_POWERTRAIN[(model.vehicle.powertrain, n)]
        if t.linear and not t.temperature:
            col = model.feature(n, vals["cda"], vals["cr"])
            if not np.any(np.abs(np.nan_to_num(col)) > 0):
                notes.append(f"{n} not tried: it has no effect on any trip ({t.hint})")
                continue
        keep.append(n)
    return tuple(keep), notes
