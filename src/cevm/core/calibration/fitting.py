"""Fitting one set of terms, with honest uncertainties and cross-validation (pure)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np

from cevm.core.calibration import identifiability, plausibility
from cevm.core.calibration.data import CalibrationError, TripData, TripSet, select_trips
from cevm.core.calibration.solve import HUBER_C, Fit, bounds, condition_number, fit_terms, start, value_covariance
from cevm.core.calibration.terms import TERMS_BY_POWERTRAIN, TermModel, neutral, normalise
from cevm.core.calibration.validation import ErrorStats, TripRow, folds, predict_set, time_predictions
from cevm.core.vehicle import FitDomain, Vehicle


@dataclass(frozen=True)
class CalibrationResult:
    """Outcome of :func:`fit` (or the chosen model of :func:`cevm.core.calibration.select`).

    vehicle : the calibrated vehicle (fitted values replaced, the rest as given; with
        :attr:`domain` as its ``calibration``)
    terms : the fitted terms' short names ("eta", "aux", ...; :mod:`.terms`)
    fitted : vehicle field -> (value, standard error), SI units (eta [-],
        aux_power_w [W], idle_fuel_lps [l/s], cda_m2 [m^2], cr [-], ...)
    correlation : (field_a, field_b) -> correlation of the two estimates
    refused : requested term (vehicle field) -> why it was not fitted (kept at the
        vehicle's value)
    excluded : trip_id -> why the trip was not used
    rows : one :class:`TripRow` per used trip
    in_sample, cv : error statistics of in-sample and cross-validated predictions
        (cv is None when cross-validation was off or impossible)
    cv_scheme : e.g. "5-fold", "leave-one-out", "grouped 5-fold (12 groups)", "none"
    model_rel_sigma : tau, the relative model error used in the weights [-]
    residual_scale : s = sqrt(chi-square / (n - k)), the factor applied to the errors
    condition_number : of the column-normalised weighted Jacobian at the optimum
    time_per_prediction_s : (mean, std) over trips of the time of one prediction from a
        cached vector [s], or None when not timed
    unit : "l" (ICE fuel) or "J" (EV battery energy)
    warnings : notes on the fit (parameter at a bound, failed folds, ...)
    evidence : the fitted standstill rate against the logs' measured one
        (:func:`.plausibility.evidence`), or None
    domain : what the fit saw (:class:`cevm.core.vehicle.FitDomain`)
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
    model_rel_sigma: float
    residual_scale: float
    condition_number: float
    time_per_prediction_s: tuple[float, float] | None
    unit: str
    warnings: tuple = field(default=())
    terms: tuple = field(default=())
    evidence: dict | None = None
    domain: FitDomain | None = None


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
    )


def _prune(model: TermModel, names: list[str], idx: np.ndarray, tau: float | None, max_correlation: float,
           max_rel_se: float, *, refuse_implausible: bool, huber_c: float | None) -> tuple[Fit, list[str], dict, list[str]]:
    """Fit ``names``, refusing (and dropping) terms the data cannot support, one at a
    time. Returns the fit, the terms kept, the refused ones with reasons, warnings."""
    data = model.data
    refused: dict = {}
    warnings: list[str] = []
    active = list(names)
    while True:
        bad = identifiability.unsupported(model, active, idx)
        if bad is None:
            x0 = start(model, active)
            tau0 = 0.0 if tau is None else tau
            w0 = data.q[idx] / (data.u[idx] ** 2 + tau0**2)
            jw0 = (np.sqrt(w0) / data.y[idx])[:, None] * model.jacobian(active, x0, idx)
            bad = identifiability.confounded(jw0, active, max_correlation, model)
        if bad is None:
            result = fit_terms(model, active, idx, tau, huber_c=huber_c)
            bad = (identifiability.confounded(result.jw, active, max_correlation, model)
                   or identifiability.imprecise(model, result, idx, max_rel_se))
            if bad is None:
                why = plausibility.implausible(model, result, idx)
                if why is not None and why[0] == "eta":
                    warnings.append(f"eta: {why[1]}")
                elif why is not None and refuse_implausible:
                    bad = why
        if bad is None:
            return result, active, refused, warnings
        if bad[0] == "eta":
            raise CalibrationError(f"eta cannot be fitted: {bad[1]}")
        refused[bad[0]] = bad[1]
        active.remove(bad[0])


def fit(
    vehicle: Vehicle,
    trips: Sequence[TripData],
    params: Sequence[str] = ("eta",),
    *,
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
    neutral_others: bool = False,
    vehicle_id: str | None = None,
    robust: bool = True,
) -> CalibrationResult:
    """Fit a vehicle's terms to measured trip consumption and validate the fit.

    Parameters
    ----------
    vehicle : the vehicle to calibrate; its values are the starting point and are kept
        for every term that is not fitted (unless ``neutral_others``)
    trips : the trips (see :class:`TripData`); measured in litres (ICE) or joules (EV)
    params : terms to fit, "eta" required, plus any of the powertrain's terms
        (:data:`cevm.core.calibration.terms.EXTRA_TERMS`: EV regen, aux, heat, cool,
        warm; ICE idle, run, kin, heat, cool, warm) and "cda", "cr"; old names
        ("aux_power_w", "idle_fuel_lps", "cda_m2", ...) are accepted. Default ("eta",),
        the paper's calibration.
    cv_folds : folds of the cross-validation, default 5 (the common choice: 80 % of the
        trips train each fit); 0 or 1 turns cross-validation off
    loo_below : with fewer groups (trips without a group are their own group) than this,
        default 10, cross-validation is leave-one-(group-)out: 5 folds of so few trips
        would remove too much of the training data
    max_rel_uncertainty : trips whose uncertainty / measured exceeds this are excluded,
        default 0.10: beyond 10 % a trip says less about eta than the model's own error
        (the paper's CE model scatters by about 4 %)
    min_distance_m : shorter trips are excluded [m], default 1000 m: below that, counter
        resolution and the energy of the start (battery or engine warm-up) dominate
    rel_uncertainty_floor : lower bound of the relative uncertainty [-], default 0.001:
        no on-board counter is better than 0.1 %, and a zero would be an infinite weight
    model_rel_sigma : the model's own relative error tau [-] added to each trip's
        uncertainty in the weights; default None estimates it from the residuals
        (Paule-Mandel); 0 weighs by measurement uncertainty alone
    max_correlation : refuse an extra term whose effect has a multiple correlation above
        this with the others', default 0.98 (the standard error is then inflated at
        least 5-fold by the confounding)
    max_rel_se : refuse an extra term whose standard error exceeds this share of
        max(|value|, reference), default 0.5 (an estimate of 1 +- 0.5 says little)
    time_repeats : predictions timed per trip, default 20; 0 skips the timing
    seed : seed of the fold assignment, default 0 (results are reproducible)
    neutral_others : the terms not in ``params`` are taken out of the model (zero, or
        regeneration at eta) instead of kept at the vehicle's values (model selection)
    vehicle_id : recorded in the result's :attr:`~CalibrationResult.domain`
    robust : default True, a Huber M-estimate (:func:`.solve.fit_terms`): a trip whose
        measurement is far off cannot pull the fit more than one 2.5 sigma away; False:
        weighted least squares

    Extra terms the data cannot identify or whose value physics refuses
    (:mod:`.identifiability`, :mod:`.plausibility`) are refused with the reason, and the rest are fitted.

    Raises
    ------
    CalibrationError
        when eta itself cannot be fitted (fewer than 3 usable trips), for unknown
        parameter names and duplicate trip ids.
    """
    names = normalise(vehicle, params)
    if model_rel_sigma is not None and not (math.isfinite(model_rel_sigma) and model_rel_sigma >= 0):
        raise CalibrationError(f"model_rel_sigma must be None or >= 0, got {model_rel_sigma!r}")
    if neutral_others:
        vehicle = neutral(vehicle, names)
    data, excluded = select_trips(vehicle, trips, max_rel_uncertainty, min_distance_m, rel_uncertainty_floor)
    if data.n < 3:
        why = "; ".join(f"{k}: {v}" for k, v in list(excluded.items())[:5])
        raise CalibrationError(
            f"eta needs at least 3 usable trips, {data.n} of {len(trips)} are usable"
            + (f" (excluded: {why}{' ...' if len(excluded) > 5 else ''})" if excluded else "")
        )
    model = TermModel(vehicle, data)
    return fit_model(model, names, excluded, cv_folds=cv_folds, loo_below=loo_below, tau=model_rel_sigma,
                     max_correlation=max_correlation, max_rel_se=max_rel_se, time_repeats=time_repeats, seed=seed,
                     vehicle_id=vehicle_id, huber_c=HUBER_C if robust else None)


def fit_model(model: TermModel, names: Sequence[str], excluded: dict, *, cv_folds: int, loo_below: int,
              tau: float | None, max_correlation: float, max_rel_se: float, time_repeats: int, seed: int,
              vehicle_id: str | None, refuse_implausible: bool = True,
              huber_c: float | None = HUBER_C) -> CalibrationResult:
    """:func:`fit` on a prepared :class:`~.terms.TermModel` (shared by model selection)."""
    data = model.data
    vehicle = model.vehicle
    idx_all = np.arange(data.n)
    result, active, refused_terms, warnings = _prune(model, list(names), idx_all, tau, max_correlation, max_rel_se,
                                                     refuse_implausible=refuse_implausible, huber_c=huber_c)
    values, vcov = value_covariance(model, result)
    fields = {_field(model, n): values[n] for n in active}
    calibrated = replace(vehicle, **fields)
    sd = np.sqrt(np.maximum(np.diag(vcov), 0.0))
    fitted = {_field(model, n): (float(values[n]), float(sd[j])) for j, n in enumerate(active)}
    corr: dict = {}
    for a in range(len(active)):
        for b in range(a + 1, len(active)):
            d = sd[a] * sd[b]
            corr[(_field(model, active[a]), _field(model, active[b]))] = float(vcov[a, b] / d) if d > 0 else math.nan
    if not result.converged:
        warnings.append("the fit did not converge to the requested tolerance")
    lb, ub = bounds(model, active)
    csd = np.sqrt(np.maximum(np.diag(result.cov), 0.0))
    for j, n in enumerate(active):
        tol = max(1e-6 * csd[j], 1e-10 * max(1.0, abs(result.theta[j])))
        if result.theta[j] <= lb[j] + tol or result.theta[j] >= ub[j] - tol:
            warnings.append(f"{_field(model, n)} = {values[n]:.6g} is at its bound: its standard error assumes it is not")

    pred_in = predict_set(calibrated, data)
    fold_of, scheme = folds(data, cv_folds, loo_below, seed)
    pred_cv = np.full(data.n, math.nan)
    for f in np.unique(fold_of[fold_of >= 0]):
        train = np.flatnonzero(fold_of != f)
        test = np.flatnonzero(fold_of == f)
        if train.size < len(active):
            warnings.append(f"fold {f}: {train.size} training trips cannot fit {len(active)} parameters")
            continue
        ff = fit_terms(model, active, train, tau, huber_c=huber_c)
        if not ff.converged:
            warnings.append(f"fold {f}: the fit did not converge to the requested tolerance")
        vf = replace(vehicle, **model.fields_of(active, ff.theta))
        pred_cv[test] = predict_set(vf, data, test)

    err_in = (pred_in - data.y) / data.y * 100.0
    err_cv = (pred_cv - data.y) / data.y * 100.0
    share = result.weights / result.weights.sum()
    rows = tuple(
        TripRow(
            trip_id=data.ids[i], group=data.groups[i], mass_kg=float(data.mass[i]),
            distance_m=float(data.distance[i]), measured=float(data.y[i]), uncertainty=float(data.sigma[i]),
            rel_uncertainty=float(data.sigma[i] / data.y[i]), weight=float(share[i]),
            predicted_in_sample=float(pred_in[i]), predicted_cv=float(pred_cv[i]),
            error_pct_in_sample=float(err_in[i]), error_pct_cv=float(err_cv[i]), fold=int(fold_of[i]),
            ambient_c=float(data.ambient_c[i]), mass_source=data.mass_sources[i],
        )
        for i in range(data.n)
    )
    cv = ErrorStats.of(err_cv) if scheme != "none" else None
    domain = fit_domain(data, active, vehicle_id)
    if cv is not None:
        domain = replace(domain, cv_scheme=scheme, cv_mean_pct=cv.mean_pct, cv_std_pct=cv.std_pct)
    calibrated = replace(calibrated, calibration=domain)
    return CalibrationResult(
        vehicle=calibrated,
        fitted=fitted,
        correlation=corr,
        refused={_field(model, k): v for k, v in refused_terms.items()},
        excluded=excluded,
        rows=rows,
        in_sample=ErrorStats.of(err_in),
        cv=cv,
        cv_scheme=scheme,
        model_rel_sigma=float(result.tau),
        residual_scale=math.sqrt(result.s2) if math.isfinite(result.s2) else math.nan,
        condition_number=condition_number(result.jw),
        time_per_prediction_s=time_predictions(calibrated, data, time_repeats),
        unit="J" if vehicle.is_ev else "l",
        warnings=tuple(warnings),
        terms=tuple(active),
        evidence=plausibility.evidence(model, result, idx_all),
        domain=domain,
    )


def predict_trips(vehicle: Vehicle, trips: Sequence[TripData]) -> np.ndarray:
    """Predicted consumption of each trip [l for an ICE, J for an EV] with
    :func:`cevm.core.vehicle.predict` (the trip's mass, or the vehicle's when None; the
    trip's ambient temperature, or the vehicle's default)."""
    from cevm.core.calibration.validation import predict_one

    out = np.empty(len(trips))
    for i, t in enumerate(trips):
        out[i] = predict_one(vehicle, t.vector, vehicle.mass_kg if t.mass_kg is None else t.mass_kg,
                             math.nan if t.ambient_c is None else t.ambient_c)
    return out
