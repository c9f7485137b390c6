"""Fitting one set of terms: the posterior, its cross-validated predictions with their
intervals, and what the fit saw (pure)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from cevm.core import distribution
from cevm.core.calibration import fit_plausibility, identifiability
from cevm.core.calibration import posterior as post
from cevm.core.calibration.candidate import CandidateFit, Settings, fit_candidate
from cevm.core.calibration.data import CalibrationError, TripData, TripSet, select_trips
from cevm.core.calibration.options import Options
from cevm.core.calibration.solve import condition_number, value_covariance
from cevm.core.calibration.terms import TERMS_BY_POWERTRAIN, TermModel, neutral, normalise, with_values
from cevm.core.calibration.validation import ErrorStats, TripRow, folds, predict_one, predict_set, time_predictions
from cevm.core.uncertainty import Posterior, Priors, Scatter
from cevm.core.vehicle import FitDomain, Vehicle

#: Nominal levels at which the held-out coverage is reported.
COVERAGE_LEVELS = (0.5, 0.8, 0.9, 0.95)
#: A term whose posterior standard deviation is above this share of its prior's learnt
#: next to nothing from the trips: it is reported as kept at its prior.
PRIOR_KEPT_RATIO = 0.9


@dataclass(frozen=True)
class CalibrationResult:
    """Outcome of :func:`fit` (or the chosen model of :func:`cevm.core.calibration.select`).

    Attributes
    ----------
    vehicle
        the calibrated vehicle (fitted values replaced, the rest as given; with
        :attr:`domain` as its ``calibration`` and :attr:`posterior` as its ``posterior``)
    terms
        the model's terms' short names ("eta", "aux", ...; :mod:`cevm.core.calibration.terms`)
    fitted
        vehicle field -> (value, standard deviation), SI units (eta [-],
        aux_power_w [W], idle_fuel_lps [l/s], cda_m2 [m^2], cr [-], ...): the posterior
        mode and its standard deviation
    correlation
        (field_a, field_b) -> correlation of the two estimates
    refused
        requested term (vehicle field) -> why it was not fitted (a term without a
        prior the trips cannot identify; kept at the vehicle's value)
    prior_kept
        vehicle field -> why the trips taught the term next to nothing (it is in
        the model at its prior)
    excluded
        trip_id -> why the trip was not used
    rows
        one :class:`TripRow` per used trip, with its held-out interval
    in_sample, cv
        error statistics of in-sample and cross-validated predictions
        (cv is None when cross-validation was off or impossible)
    cv_scheme
        e.g. "5-fold", "leave-one-out", "grouped 5-fold (12 groups)", "none"
    interval
        the level of the rows' intervals (0.9: 90 %)
    coverage
        nominal level -> share of held-out trips inside their interval at it
    mean_rel_width_pct
        mean width of the rows' held-out intervals [% of measured]
    posterior
        :class:`cevm.core.uncertainty.Posterior` of the coefficients, scatter
    priors
        the :class:`cevm.core.uncertainty.Priors` used (None: none, flat)
    residual_scale
        the in-sample weighted residuals' root mean square
    condition_number
        of the column-normalised weighted Jacobian at the optimum
    time_per_prediction_s
        (mean, std) over trips of the time of one prediction from a
        cached vector [s], or None when not timed
    unit
        "l" (ICE fuel) or "J" (EV battery energy)
    warnings
        notes on the fit (parameter at a bound, failed folds, ...)
    evidence
        the fitted standstill rate against the logs' measured one
        (:func:`.fit_plausibility.evidence`), or None
    standstill_used
        whether the logs' standstill rates were observations of the fit
    domain
        what the fit saw (:class:`cevm.core.vehicle.FitDomain`)
    """

    vehicle: Vehicle
    fitted: dict
    correlation: dict
    refused: dict
    excluded: dict
    rows: tuple
    in_sample: ErrorStats
    cv: ErrorStats | None
    cv_scheme: str
    residual_scale: float
    condition_number: float
    time_per_prediction_s: tuple[float, float] | None
    unit: str
    warnings: tuple = field(default=())
    terms: tuple = field(default=())
    evidence: dict | None = None
    domain: FitDomain | None = None
    posterior: Posterior | None = None
    priors: Priors | None = None
    prior_kept: dict = field(default_factory=dict)
    interval: float = 0.9
    coverage: dict = field(default_factory=dict)
    mean_rel_width_pct: float = math.nan
    standstill_used: bool = False

    @property
    def scatter(self) -> Scatter | None:
        return None if self.posterior is None else self.posterior.scatter


def _field(model: TermModel, name: str) -> str:
    return TERMS_BY_POWERTRAIN[(model.vehicle.powertrain, name)].field


def fit_domain(data: TripSet, terms: Sequence[str], vehicle_id: str | None = None) -> FitDomain:
    """What the trips of ``data`` span (:class:`~cevm.core.vehicle.FitDomain`)."""
    def span(x):
        x = np.asarray(x, dtype=np.float64)
        x = x[np.isfinite(x)]
        return None if x.size == 0 else (float(x.min()), float(x.max()))

    starts = data.start_utc_s[np.isfinite(data.start_utc_s)]

    def iso(t):
        return str(np.datetime_as_string(np.datetime64(int(round(t)), "s"), unit="s")) + "Z"

    sources = sorted({s for s in data.mass_sources if s})
    return FitDomain(
        terms=tuple(terms), n_trips=data.n, vehicle_id=vehicle_id,
        first_utc=iso(starts.min()) if starts.size else None, last_utc=iso(starts.max()) if starts.size else None,
        ambient_c=span(data.ambient_c) if np.all(np.isfinite(data.ambient_c)) and data.n else None,
        mean_speed_mps=span(data.distance / data.duration), mass_kg=span(data.mass), distance_m=span(data.distance),
        mass_sources=", ".join(sources) if sources else None,
        idle_share=span(data.idle / data.duration) if data.n else None,
    )


def posterior_source(domain: FitDomain) -> str:
    """"calibrated on N trips of ID, DATE..DATE": the sentence a posterior carries."""
    who = f" of {domain.vehicle_id}" if domain.vehicle_id else ""
    when = (f", {domain.first_utc[:10]}..{domain.last_utc[:10]}"
            if domain.first_utc and domain.last_utc else "")
    return f"calibrated on {domain.n_trips} trips{who}{when}"


def fit(vehicle: Vehicle, trips: Sequence[TripData], params: Sequence[str] = ("eta",), options: Options | None = None,
        *, neutral_others: bool = False, standstill: bool = False, scatter: tuple[float, ...] | None = None,
        **changes) -> CalibrationResult:
    """Fit a vehicle's terms to measured trip consumption and validate the fit.

    :class:`cevm.Calibrator` (``fit_terms=params``) is the same as an estimator; this
    function stays for scripts that call it. A forced term set is held to the same
    physical bounds as a chosen one: a value the data want beyond them refuses the fit
    (:class:`CalibrationError`, with the reason).

    Parameters
    ----------
    vehicle
        the vehicle to calibrate; its values are the starting point and are kept
        for every term that is not fitted (unless ``neutral_others``)
    trips
        the trips (see :class:`TripData`); measured in litres (ICE) or joules (EV)
    params
        terms to fit, "eta" required, plus any of the powertrain's terms
        (:data:`cevm.core.calibration.terms.EXTRA_TERMS`: EV regen, aux, heat, cool,
        warm; ICE idle, run, kin, heat, cool, warm) and "cda", "cr"; old names
        ("aux_power_w", "idle_fuel_lps", "cda_m2", ...) are accepted. Default ("eta",),
        the paper's calibration.
    options
        how trips are screened, folded and reported (:class:`.options.Options`);
        ``changes`` replace single options by name (``cv_folds=0``, ``priors=...``);
        ``fit_balance`` defaults to False here (the vehicle's balance temperatures)
    neutral_others
        the terms not in ``params`` are taken out of the model (zero, or
        regeneration at eta) instead of kept at the vehicle's values (model selection)
    standstill
        use the logs' standstill rates as observations (:mod:`.posterior`)
    scatter
        (s_aux [W or l/s], s_share [-][, s_trip [J or l]]) to hold the trips' scatter
        at instead of fitting it (:class:`cevm.core.uncertainty.Scatter`; s_trip 0 where
        not given); (0, 0): the measurement uncertainties alone weigh the trips

    Raises
    ------
    CalibrationError
        when eta itself cannot be fitted (fewer than 3 usable trips), for unknown
        parameter names, duplicate trip ids, and physically implausible fits.
    """
    opts = Options.of(options, **changes)
    names = normalise(vehicle, params)
    opts.check()
    priors = vehicle.priors if opts.priors is None else opts.priors
    if neutral_others:
        vehicle = neutral(vehicle, names)
    data, excluded = select_trips(vehicle, trips, *opts.screening())
    if data.n < 3:
        why = "; ".join(f"{k}: {v}" for k, v in list(excluded.items())[:5])
        raise CalibrationError(
            f"eta needs at least 3 usable trips, {data.n} of {len(trips)} are usable"
            + (f" (excluded: {why}{' ...' if len(excluded) > 5 else ''})" if excluded else "")
        )
    model = TermModel(vehicle, data)
    settings = opts.settings(fit_balance=False)
    cf = fit_candidate(model, names, np.arange(data.n), priors, settings, standstill=standstill,
                       heldout=opts.cv_folds >= 2, scatter=scatter)
    refused = fit_plausibility.implausible(cf.model, cf.fit, np.arange(data.n), cf.prior.lb, cf.prior.ub,
                                       opts.plausible)
    if refused is not None:
        raise CalibrationError(f"{refused[0]}: {refused[1]}")
    return fit_model(cf, excluded, settings, priors=priors, interval=opts.interval, time_repeats=opts.time_repeats,
                     vehicle_id=opts.vehicle_id)


def _prior_kept(cf: CandidateFit, fields: dict) -> dict:
    """Terms whose posterior standard deviation is still above :data:`PRIOR_KEPT_RATIO`
    of their prior's: the trips could not tell (with the hint of what they would need)."""
    out = {}
    sd = cf.fit.sd
    for j, n in enumerate(cf.names):
        if n == "eta" or not cf.prior.informative(n):
            continue
        if sd[j] > PRIOR_KEPT_RATIO * cf.prior.sd[j]:
            bad = identifiability.unsupported(cf.model, ["eta", n], cf.fit.idx)
            reason = bad[1] if bad is not None else "the trips tell it apart from the other terms too little"
            out[fields[n]] = f"kept its prior: {reason}"
    return out


def cross_validated(cf: CandidateFit, settings: Settings, fold_of: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The held-out mean and variance (against the measurement) of every trip: the
    candidate's fold posteriors (:attr:`CandidateFit.heldout`), each fold's scatter from
    its own training trips' held-out residuals (nothing of the test day enters its
    interval but the balance temperatures, chosen on all trips)."""
    m, names, cp = cf.model, cf.names, cf.prior
    d = m.data
    idx = cf.fit.idx
    n = idx.size
    mean = np.full(n, math.nan)
    var = np.full(n, math.nan)
    if cf.heldout is None:
        return mean, var
    noise = cf.in_sample.noise
    for f in np.unique(fold_of[fold_of >= 0]):
        tr_pos = np.flatnonzero(fold_of != f)
        te_pos = np.flatnonzero(fold_of == f)
        tr, te = idx[tr_pos], idx[te_pos]
        if not np.all(np.isfinite(cf.heldout.mean[te_pos])):
            continue
        fn = (cf.heldout.fold_noise or {}).get(int(f), noise)
        inner = post.held_out(m, names, tr, cp, fn, huber_c=settings.huber_c,
                              fold_of=post.inner_folds(m, tr, settings.cv_folds, settings.loo_below, settings.seed),
                              theta0=cf.in_sample.theta, fit_noise=False)
        sc = fn if cf.scatter_fixed else post.heldout_scatter(m, inner, cf.scatter_prior, fn, settings.huber_c)
        mu = cf.heldout.mean[te_pos]
        ratio = post._quality_ratio(d.q, tr)[te]
        mean[te_pos] = mu
        extra = cf.heldout.extra_var
        assert extra is not None  # set by HeldOut.__post_init__
        var[te_pos] = (cf.heldout.param_var[te_pos] + extra[te_pos]
                       + (post._u_random(d)[te] * d.y[te]) ** 2
                       + ratio * sc.variance(d.duration[te], mu))
    return mean, var


def _inside(y: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    return (y >= low) & (y <= high)


def _fitted_values(cf: CandidateFit, settings: Settings, idx_all: np.ndarray
                   ) -> tuple[dict, dict, dict[str, str], list[str]]:
    """Of a fitted candidate: each field's (value, standard deviation), their correlations,
    the field of each term, and the fit's warnings (not converged, an implausible eta, a
    coefficient at its physical bound)."""
    model, result = cf.model, cf.fit
    active = list(cf.names)
    warnings: list[str] = []
    values, vcov = value_covariance(model, result)
    fields = {n: _field(model, n) for n in active}
    sd = np.sqrt(np.maximum(np.diag(vcov), 0.0))
    fitted = {fields[n]: (float(values[n]), float(sd[j])) for j, n in enumerate(active)}
    corr: dict = {}
    for a in range(len(active)):
        for b in range(a + 1, len(active)):
            dd = sd[a] * sd[b]
            corr[(fields[active[a]], fields[active[b]])] = float(vcov[a, b] / dd) if dd > 0 else math.nan
    if not result.converged:
        warnings.append("the fit did not converge to the requested tolerance")
    why = fit_plausibility.implausible(model, result, idx_all, cf.prior.lb, cf.prior.ub, settings.plausible)
    if why is not None and why[0] == "eta":
        warnings.append(f"eta: {why[1]}")
    csd = result.sd
    lb, ub = cf.prior.lb, cf.prior.ub
    for j, n in enumerate(active):
        tol = max(1e-6 * csd[j], 1e-10 * max(1.0, abs(result.theta[j])))
        if result.theta[j] <= lb[j] + tol or result.theta[j] >= ub[j] - tol:
            warnings.append(f"{fields[n]} = {values[n]:.6g} is at its physical bound: its posterior is cut there, "
                            "its standard deviation is that of the Gaussian at the bound")
    return fitted, corr, fields, warnings


def fit_model(cf: CandidateFit, excluded: dict, settings: Settings, *, priors: Priors | None, interval: float,
              time_repeats: int, vehicle_id: str | None) -> CalibrationResult:
    """The :class:`CalibrationResult` of a fitted candidate (shared by :func:`fit` and
    model selection)."""
    model, result = cf.model, cf.fit
    data = model.data
    vehicle = model.vehicle
    active = list(cf.names)
    idx_all = np.arange(data.n)
    fitted, corr, fields, warnings = _fitted_values(cf, settings, idx_all)

    fold_of, scheme = folds(data, settings.cv_folds, settings.loo_below, settings.seed)
    rho, rho_note, _ = post.day_correlation(model, active, idx_all, cf.prior, result.noise,
                                            huber_c=settings.huber_c, theta0=result.theta)
    scatter = Scatter(aux=result.noise.aux, share=result.noise.share, day_corr=rho, day_corr_note=rho_note,
                      standstill=result.noise.standstill, trip=result.noise.trip)
    domain = fit_domain(data, active, vehicle_id)
    calibrated = with_values(vehicle, model.fields_of(active, result.theta))
    pred_in = predict_set(calibrated, data)
    _, var_in = result.predictive_var(model, idx_all)
    mean_cv, var_cv = cross_validated(cf, settings, fold_of)
    sd_cv = np.sqrt(var_cv)
    # the held-out intervals in the distribution of every prediction's (cevm.core.distribution)
    low, high = distribution.interval(mean_cv, sd_cv, interval)
    seen = np.isfinite(mean_cv) & np.isfinite(sd_cv)
    coverage = {lvl: float(np.mean(_inside(data.y[seen], *distribution.interval(mean_cv[seen], sd_cv[seen], lvl))))
                for lvl in COVERAGE_LEVELS} if np.any(seen) else {}
    ok = np.isfinite(sd_cv)
    width = float(np.mean((high - low)[ok] / data.y[ok]) * 100.0) if np.any(ok) else math.nan
    warnings += [f"fold {f}: its training trips could not be fitted" for f in np.unique(fold_of[fold_of >= 0])
                 if not np.all(np.isfinite(mean_cv[fold_of == f]))]

    err_in = (pred_in - data.y) / data.y * 100.0
    err_cv = (mean_cv - data.y) / data.y * 100.0
    W = result.weights / np.maximum((data.u_random * data.y) ** 2 + result.scatter_var, 1e-300)
    share = W / W.sum()
    rows = tuple(
        TripRow(
            trip_id=data.ids[i], group=data.groups[i], mass_kg=float(data.mass[i]),
            distance_m=float(data.distance[i]), measured=float(data.y[i]), uncertainty=float(data.sigma[i]),
            rel_uncertainty=float(data.sigma[i] / data.y[i]), weight=float(share[i]),
            predicted_in_sample=float(pred_in[i]), predicted_cv=float(mean_cv[i]),
            error_pct_in_sample=float(err_in[i]), error_pct_cv=float(err_cv[i]), fold=int(fold_of[i]),
            ambient_c=float(data.ambient_c[i]), mass_source=data.mass_sources[i],
            predicted_low=float(low[i]), predicted_high=float(high[i]), sd_cv=float(sd_cv[i]),
            flags=tuple(data.flags[i]), sd_in_sample=float(math.sqrt(var_in[i])),
        )
        for i in range(data.n)
    )
    cv = ErrorStats.of(err_cv) if scheme != "none" else None
    if cv is not None:
        domain = replace(domain, cv_scheme=scheme, cv_mean_pct=cv.mean_pct, cv_std_pct=cv.std_pct)
    meter = float(np.median(data.u_sys)) if data.n and data.u_sys is not None else 0.0
    posterior = Posterior(terms=tuple(active), cov=result.cov, scatter=scatter, source=posterior_source(domain),
                          n_trips=data.n, priors=priors, meter_share=meter)
    calibrated = replace(calibrated, calibration=domain, posterior=posterior)
    balance = {}
    if any(n in ("heat", "warm") for n in active):
        balance["heating_below_c"] = (vehicle.heating_below_c, math.nan)
    if "cool" in active:
        balance["cooling_above_c"] = (vehicle.cooling_above_c, math.nan)
    f_res = (data.y - result.pred) / np.sqrt((data.u_random * data.y) ** 2 + result.scatter_var)
    return CalibrationResult(
        vehicle=calibrated,
        fitted={**fitted, **balance},
        correlation=corr,
        refused={_field(model, k): v for k, v in cf.refused.items()},
        excluded=excluded,
        rows=rows,
        in_sample=ErrorStats.of(err_in),
        cv=cv,
        cv_scheme=scheme,
        residual_scale=float(np.sqrt(np.mean(f_res * f_res))) if data.n else math.nan,
        condition_number=condition_number(result.jw),
        time_per_prediction_s=time_predictions(calibrated, data, time_repeats),
        unit="J" if vehicle.is_ev else "l",
        warnings=tuple(warnings),
        terms=tuple(active),
        evidence=fit_plausibility.evidence(model, result, idx_all),
        domain=domain,
        posterior=posterior,
        priors=priors,
        prior_kept=_prior_kept(cf, fields),
        interval=float(interval),
        coverage=coverage,
        mean_rel_width_pct=width,
        standstill_used=cf.standstill,
    )


def predict_trips(vehicle: Vehicle, trips: Sequence[TripData]) -> np.ndarray:
    """Predicted consumption of each trip [l for an ICE, J for an EV] with
    :func:`cevm.core.vehicle.predict` (the trip's mass, or the vehicle's when None; the
    trip's ambient temperature, or the vehicle's default)."""
    out = np.empty(len(trips))
    for i, t in enumerate(trips):
        out[i] = predict_one(vehicle, t.vector, vehicle.mass_kg if t.mass_kg is None else t.mass_kg,
                             math.nan if t.ambient_c is None else t.ambient_c)
    return out
