"""Calibration of a vehicle's CE parameters against measured trip consumption (pure).

The paper fits one number, the average efficiency eta, "using data from a few drive
cycles" (section 2.3) and judges the model by the per-cycle relative error
e = (modelled - measured) / measured (tables 1 and 2). This module does that fit, and
optionally a few more parameters, with honest uncertainties and a validation that does
not flatter.

Model, per trip i with cached vector, gross mass m_i, duration D_i and idle time I_i::

    E_i(CdA, Cr; w) = P_i + w N_i        wheel energy [J] (cevm.core.model.wheel_energy_j):
                                         P_i = E_DC1 + positive non-simplified steps,
                                         N_i <= 0 the negative non-simplified steps
    ICE fuel [l]    = E_i(w_ice) / (LHV eta) + idle_fuel_lps * I_i      (eq. 26 + idle)
    EV energy [J]   = E_i(eta^2) / eta + aux_power_w * D_i              (eq. 31 + aux)
                    = P_i / eta + eta N_i + aux_power_w * D_i

w_ice is 1 for the paper's eq. (24), 0 for "no-credit" (the vehicle's ``ice_braking``).

Error metric and weights
------------------------
Residuals are relative, r_i = (p_i - y_i) / y_i, the quantity the paper's tables judge.
Trip i weighs W_i = q_i / (u_i^2 + tau^2), with u_i = uncertainty_i / y_i the relative
1-sigma measurement error (floored), q_i in (0, 1] a caller's quality factor (DSM
coverage, gaps) and tau the model's own relative error (what remains when measurement
error is accounted for). With tau = 0, sum W_i r_i^2 is exactly the chi-square of the
absolute residuals, sum (p_i - y_i)^2 / sigma_i^2. By default tau is estimated from the
residuals (Paule-Mandel: the tau >= 0 that makes chi-square equal n - k), so a trip
measured 100 times better than the model can predict does not take over the fit.

The fit minimises sum W_i r_i^2 with scipy.optimize.least_squares under bounds
(eta in [0.05, 1], aux power and idle rate >= 0, CdA > 0, Cr >= the vectors' Cr0).
Covariance = (J_w^T J_w)^-1 s^2, J_w the weighted Jacobian, s^2 = chi-square / (n - k).

Identifiability
---------------
eta is always fitted (at least 3 usable trips, else :class:`CalibrationError`). An extra
parameter is refused, with the reason, and the rest are fitted when:

- there are fewer than k + 2 usable trips for k parameters;
- it has no effect on any trip (e.g. idle fuel when no trip stands still);
- its effect on the trips is confounded with the others': the multiple correlation of
  its weighted Jacobian column with the other columns exceeds ``max_correlation``
  (0.98; for two parameters this is |correlation of the estimates|). Example: aux power
  and 1/eta when every trip has the same speed profile and mass (aux energy ~ duration
  ~ distance / speed, traction energy ~ distance);
- after the fit its standard error exceeds ``max_rel_se`` (50 %) of max(|value|,
  reference), the reference being 10 % of the median consumption rate y_i / D_i for
  aux power and idle fuel (so a well-measured zero is accepted), |value| otherwise.

Validation
----------
Every trip is also predicted by a fit that did not see it: K-fold (default 5) over groups
(a group key such as day or route keeps near-duplicate trips on one side), leave-one-out
(over groups) when there are fewer than 10 groups. tau is re-estimated in each fold. The
errors in-sample and cross-validated are reported as the paper's mean and std in %,
together with the time of one prediction from a cached vector.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np
from scipy.optimize import brentq, least_squares

from cevm.core.cycle import CycleVector
from cevm.core.model import braking_weight, wheel_energy_j
from cevm.core.trip import Measurement
from cevm.core.vehicle import Vehicle, predict
from cevm.errors import CevmError
from cevm.units import J_PER_KWH

#: Parameters that can be fitted, per powertrain, in the order of their priority.
PARAMS_EV: tuple[str, ...] = ("eta", "aux_power_w", "cda_m2", "cr")
PARAMS_ICE: tuple[str, ...] = ("eta", "idle_fuel_lps", "cda_m2", "cr")
#: Accepted aliases of parameter names (as a user may type them).
PARAM_ALIASES = {"aux_power": "aux_power_w", "aux": "aux_power_w", "idle_fuel": "idle_fuel_lps",
                 "idle": "idle_fuel_lps", "cda": "cda_m2"}
#: Bounds of eta in the fit [-]: 0.05 is far below any real powertrain, 1 is physics.
ETA_BOUNDS = (0.05, 1.0)
#: Lower bound of CdA in the fit [m^2] (CdA must stay > 0).
CDA_MIN_M2 = 1e-6

_HINTS = {
    "aux_power_w": "trips must differ in average speed or mass (aux energy grows with duration)",
    "idle_fuel_lps": "trips must differ in their share of time at standstill",
    "cda_m2": "trips must differ in speed (drag energy grows with v^2 per metre)",
    "cr": "trips must differ in mass and speed mix (rolling energy grows with m per metre)",
}


class CalibrationError(CevmError):
    """The data cannot calibrate the vehicle at all (e.g. too few usable trips)."""


@dataclass(frozen=True)
class TripData:
    """One trip as the fit sees it.

    trip_id : unique id (e.g. :attr:`cevm.core.trip.Trip.trip_id`)
    vector : the trip's cached :class:`~cevm.core.cycle.CycleVector`
    mass_kg : gross mass of the trip [kg]; None: the vehicle's ``mass_kg``
    measured : measured consumption: litres of fuel (ICE) or joules at the battery (EV);
        None or NaN when the trip has no measurement
    uncertainty : 1-sigma error of ``measured``, same unit
    quality : extra weight factor in (0, 1] (DSM coverage, gaps...), default 1
    group : key of trips that must stay together in cross-validation (day, route), or None
    kind : "fuel_l" or "energy_j" when known; checked against the powertrain
    """

    trip_id: str
    vector: CycleVector
    mass_kg: float | None
    measured: float | None
    uncertainty: float | None
    quality: float = 1.0
    group: str | None = None
    kind: str | None = None

    @classmethod
    def from_measurement(cls, trip_id: str, vector: CycleVector, measurement: Measurement | None, *,
                         mass_kg: float | None = None, quality: float = 1.0,
                         group: str | None = None) -> TripData:
        """A :class:`TripData` from a :class:`cevm.core.trip.Measurement` (None: unmeasured)."""
        if measurement is None:
            return cls(trip_id, vector, mass_kg, None, None, quality, group)
        return cls(trip_id, vector, mass_kg, measurement.value, measurement.uncertainty, quality, group,
                   measurement.kind)


@dataclass(frozen=True)
class TripRow:
    """Per-trip outcome of a calibration (consumption in litres or joules).

    weight is the trip's share of the fit's total weight (weights of used trips sum to 1);
    fold is the cross-validation fold that held the trip out (-1 without CV).
    """

    trip_id: str
    group: str | None
    mass_kg: float
    distance_m: float
    measured: float
    uncertainty: float
    rel_uncertainty: float
    weight: float
    predicted_in_sample: float
    predicted_cv: float
    error_pct_in_sample: float
    error_pct_cv: float
    fold: int


@dataclass(frozen=True)
class ErrorStats:
    """Statistics of the per-trip error e = (predicted - measured) / measured [%].

    std_pct uses ddof = 1 (sample standard deviation); NaN for fewer than 2 trips.
    """

    n: int
    mean_pct: float
    std_pct: float
    rms_pct: float
    max_abs_pct: float

    @classmethod
    def of(cls, error_pct: np.ndarray) -> ErrorStats:
        e = np.asarray(error_pct, dtype=np.float64)
        e = e[np.isfinite(e)]
        if e.size == 0:
            return cls(0, math.nan, math.nan, math.nan, math.nan)
        return cls(
            n=int(e.size),
            mean_pct=float(e.mean()),
            std_pct=float(e.std(ddof=1)) if e.size > 1 else math.nan,
            rms_pct=float(np.sqrt(np.mean(e * e))),
            max_abs_pct=float(np.abs(e).max()),
        )


@dataclass(frozen=True)
class CalibrationResult:
    """Outcome of :func:`fit`.

    vehicle : the calibrated vehicle (fitted values replaced, the rest as given)
    fitted : name -> (value, standard error), SI units (eta [-], aux_power_w [W],
        idle_fuel_lps [l/s], cda_m2 [m^2], cr [-])
    correlation : (name_a, name_b) -> correlation of the two estimates
    refused : requested parameter -> why it was not fitted (kept at the vehicle's value)
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


# --- the data actually used ------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class _Data:
    ids: tuple
    groups: tuple
    vectors: tuple
    mass: np.ndarray
    y: np.ndarray
    sigma: np.ndarray  # absolute uncertainty as given
    u: np.ndarray  # relative uncertainty, floored
    q: np.ndarray
    duration: np.ndarray
    idle: np.ndarray

    @property
    def n(self) -> int:
        return int(self.y.size)


def _finite(x) -> bool:
    return x is not None and isinstance(x, (int, float, np.floating, np.integer)) and math.isfinite(x)


def _select_trips(vehicle: Vehicle, trips: Sequence[TripData], max_rel_uncertainty: float,
                  min_distance_m: float, rel_uncertainty_floor: float) -> tuple[_Data, dict]:
    """Screen the trips: the usable ones as arrays, the others with a reason."""
    want_kind = "energy_j" if vehicle.is_ev else "fuel_l"
    w_prior = vehicle.eta**2 if vehicle.is_ev else braking_weight(vehicle.ice_braking)
    seen: set = set()
    excluded: dict = {}
    keep: list = []
    for t in trips:
        if t.trip_id in seen:
            raise CalibrationError(f"trip id {t.trip_id!r} appears twice")
        seen.add(t.trip_id)
        mass = vehicle.mass_kg if t.mass_kg is None else t.mass_kg
        y, s = t.measured, t.uncertainty
        reason = None
        if t.kind is not None and t.kind != want_kind:
            reason = (f"measurement kind {t.kind!r} does not fit an {'EV' if vehicle.is_ev else 'ICE'} "
                      f"(needs {want_kind!r})")
        elif not _finite(y):
            reason = "no measured consumption"
        elif y <= 0:
            reason = f"measured consumption {y:g} <= 0"
        elif not _finite(s) or s < 0:
            reason = "no valid measurement uncertainty" if not _finite(s) else f"uncertainty {s:g} < 0"
        elif not (_finite(t.quality) and 0 < t.quality <= 1):
            reason = f"quality {t.quality!r} is not in (0, 1]"
        elif not (_finite(mass) and mass > 0):
            reason = f"mass {mass!r} kg is not > 0"
        elif t.vector.distance_m < min_distance_m:
            reason = f"distance {t.vector.distance_m:.0f} m < {min_distance_m:.0f} m"
        elif s / y > max_rel_uncertainty:
            reason = (f"relative uncertainty {100 * s / y:.1f} % > {100 * max_rel_uncertainty:.1f} % "
                      f"({s:g} on {y:g})")
        elif vehicle.cr < t.vector.cr0:
            reason = (f"the vector's Cr0 = {t.vector.cr0:g} is above the vehicle's Cr = {vehicle.cr:g}: "
                      "recompute the vector with a lower cr0")
        else:
            e = float(wheel_energy_j(t.vector, float(mass), float(vehicle.cda_m2), float(vehicle.cr),
                                     float(w_prior)))
            if e <= 0:
                reason = f"predicted wheel energy {e:.3g} J <= 0 (a descent): consumption is not driven by it"
        if reason is None:
            keep.append((t, float(mass)))
        else:
            excluded[t.trip_id] = reason
    y = np.array([t.measured for t, _ in keep], dtype=np.float64)
    sigma = np.array([t.uncertainty for t, _ in keep], dtype=np.float64)
    data = _Data(
        ids=tuple(t.trip_id for t, _ in keep),
        groups=tuple(t.group for t, _ in keep),
        vectors=tuple(t.vector for t, _ in keep),
        mass=np.array([m for _, m in keep], dtype=np.float64),
        y=y,
        sigma=sigma,
        u=np.maximum(sigma / y, rel_uncertainty_floor) if y.size else y,
        q=np.array([t.quality for t, _ in keep], dtype=np.float64),
        duration=np.array([t.vector.duration_s for t, _ in keep], dtype=np.float64),
        idle=np.array([t.vector.idle_s for t, _ in keep], dtype=np.float64),
    )
    return data, excluded


# --- the model as a function of the parameters ------------------------------------------

_W01 = np.array([0.0, 1.0])


class _Model:
    """Predictions p(theta) and their Jacobian for the used trips."""

    def __init__(self, vehicle: Vehicle, data: _Data):
        self.vehicle = vehicle
        self.data = data
        self.ev = vehicle.is_ev
        if not self.ev:
            if vehicle.fuel_lhv_j_per_l is None:
                raise CalibrationError(f"ICE vehicle {vehicle.name!r} has no fuel lower heating value")
            self.w_ice = braking_weight(vehicle.ice_braking)
            self.lhv = float(vehicle.fuel_lhv_j_per_l)
        self._cache: dict = {}

    def components(self, cda: float, cr: float) -> tuple[np.ndarray, np.ndarray]:
        """P_i (E_DC1 + positive non-simplified) and N_i (negative non-simplified) [J]."""
        key = (float(cda), float(cr))
        hit = self._cache.get(key)
        if hit is None:
            e = np.array([wheel_energy_j(v, np.float64(m), key[0], key[1], _W01)
                          for v, m in zip(self.data.vectors, self.data.mass)])
            e = e.reshape(self.data.n, 2)
            hit = (e[:, 0], e[:, 1] - e[:, 0])
            if len(self._cache) > 256:
                self._cache.clear()
            self._cache[key] = hit
        return hit

    def values(self, names: Sequence[str], theta: np.ndarray) -> dict:
        v = {n: float(getattr(self.vehicle, n)) for n in ("eta", "aux_power_w", "idle_fuel_lps", "cda_m2", "cr")}
        v.update({n: float(x) for n, x in zip(names, theta)})
        return v

    def predict(self, names, theta, idx) -> np.ndarray:
        v = self.values(names, theta)
        P, N = self.components(v["cda_m2"], v["cr"])
        P, N = P[idx], N[idx]
        eta = v["eta"]
        if self.ev:
            return P / eta + eta * N + v["aux_power_w"] * self.data.duration[idx]
        return (P + self.w_ice * N) / (self.lhv * eta) + v["idle_fuel_lps"] * self.data.idle[idx]

    def jacobian(self, names, theta, idx) -> np.ndarray:
        v = self.values(names, theta)
        P, N = self.components(v["cda_m2"], v["cr"])
        P, N = P[idx], N[idx]
        eta = v["eta"]
        J = np.empty((P.size, len(names)))
        base = None
        for j, name in enumerate(names):
            if name == "eta":
                J[:, j] = (-P / eta**2 + N) if self.ev else -(P + self.w_ice * N) / (self.lhv * eta**2)
            elif name == "aux_power_w":
                J[:, j] = self.data.duration[idx]
            elif name == "idle_fuel_lps":
                J[:, j] = self.data.idle[idx]
            else:  # cda_m2, cr: piecewise linear in each, so a forward difference is exact
                # within a linear piece (a kink inside the step shifts it by a tiny amount)
                if base is None:
                    base = self.predict(names, theta, idx)
                h = 1e-7 * max(abs(v[name]), 1e-3)
                th = np.array(theta, dtype=np.float64)
                th[j] += h
                J[:, j] = (self.predict(names, th, idx) - base) / h
        return J


# --- the weighted fit ---------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class _Fit:
    theta: np.ndarray
    cov: np.ndarray
    tau: float
    s2: float
    jw: np.ndarray  # weighted Jacobian at theta
    weights: np.ndarray  # W_i
    pred: np.ndarray
    converged: bool


def _bounds(names, data: _Data):
    cr_min = max(v.cr0 for v in data.vectors)
    lo = {"eta": ETA_BOUNDS[0], "aux_power_w": 0.0, "idle_fuel_lps": 0.0, "cda_m2": CDA_MIN_M2, "cr": cr_min}
    hi = {"eta": ETA_BOUNDS[1], "cr": 0.1}
    return (np.array([lo[n] for n in names]), np.array([hi.get(n, np.inf) for n in names]))


def _start(model: _Model, names) -> np.ndarray:
    lb, ub = _bounds(names, model.data)
    x0 = np.array([getattr(model.vehicle, n) for n in names], dtype=np.float64)
    return np.clip(x0, lb, ub)


def _solve_tau(r: np.ndarray, u: np.ndarray, q: np.ndarray, dof: int) -> float:
    """Paule-Mandel: tau >= 0 with sum q r^2 / (u^2 + tau^2) = dof (0 if already below)."""
    if dof <= 0:
        return 0.0
    qr2 = q * r * r
    if float(np.sum(qr2 / (u * u))) <= dof:
        return 0.0
    hi = math.sqrt(float(qr2.sum()) / dof)
    return float(brentq(lambda t: float(np.sum(qr2 / (u * u + t * t))) - dof, 0.0, hi, xtol=1e-12, rtol=1e-10))


def _fit(model: _Model, names, idx, tau_fixed: float | None, theta0=None) -> _Fit:
    data = model.data
    y, u, q = data.y[idx], data.u[idx], data.q[idx]
    n, k = y.size, len(names)
    lb, ub = _bounds(names, data)
    x = _start(model, names) if theta0 is None else np.clip(theta0, lb, ub)
    tau = 0.0 if tau_fixed is None else float(tau_fixed)
    converged = False
    for _ in range(50):
        W = q / (u * u + tau * tau)
        sw = np.sqrt(W) / y

        def fun(th):
            return sw * (model.predict(names, th, idx) - y)

        def jac(th):
            return sw[:, None] * model.jacobian(names, th, idx)

        res = least_squares(fun, x, jac=jac, bounds=(lb, ub), method="trf", x_scale="jac",
                            ftol=1e-12, xtol=1e-12, gtol=1e-12, max_nfev=200 * k)
        x = res.x
        converged = bool(res.success)
        if tau_fixed is not None:
            break
        pred = model.predict(names, x, idx)
        new = _solve_tau((pred - y) / y, u, q, n - k)
        if abs(new - tau) <= 1e-9 + 1e-6 * tau:
            break
        converged = False
        tau = new
    W = q / (u * u + tau * tau)
    sw = np.sqrt(W) / y
    pred = model.predict(names, x, idx)
    f = sw * (pred - y)
    jw = sw[:, None] * model.jacobian(names, x, idx)
    s2 = float(f @ f) / (n - k) if n > k else math.nan
    _, sv, vt = np.linalg.svd(jw, full_matrices=False)
    with np.errstate(divide="ignore"):
        inv = np.where(sv > sv[0] * 1e-14, 1.0 / (sv * sv), np.inf) if sv.size else sv
    cov = (vt.T * inv) @ vt * (s2 if math.isfinite(s2) else math.nan)
    return _Fit(theta=x, cov=cov, tau=tau, s2=s2, jw=jw, weights=W, pred=pred, converged=converged)


# --- identifiability ----------------------------------------------------------------------


def _confounded(jw: np.ndarray, names: Sequence[str], max_correlation: float) -> tuple[str, str] | None:
    """The extra parameter (never eta) to refuse for a weak or confounded Jacobian column."""
    norms = np.linalg.norm(jw, axis=0)
    for j in reversed(range(len(names))):
        if names[j] != "eta" and not norms[j] > 0:
            return names[j], f"has no effect on any used trip ({_HINTS.get(names[j], '')})"
    if len(names) < 2:
        return None
    jn = jw / norms
    cos = jn.T @ jn
    mult = np.zeros(len(names))
    for j in range(len(names)):
        others = np.delete(jn, j, axis=1)
        coef, *_ = np.linalg.lstsq(others, jn[:, j], rcond=None)
        resid = jn[:, j] - others @ coef
        mult[j] = math.sqrt(max(0.0, 1.0 - float(resid @ resid)))
    worst, worst_r = None, -1.0
    for j, name in enumerate(names):
        if name != "eta" and mult[j] > max_correlation and mult[j] >= worst_r - 1e-9:
            worst, worst_r = j, mult[j]
    if worst is None:
        return None
    c = np.abs(cos[worst]).copy()
    c[worst] = -1
    partner = names[int(np.argmax(c))]
    with_ = partner if len(names) == 2 else f"{', '.join(n for n in names if n != names[worst])} (mostly {partner})"
    return names[worst], (
        f"not identifiable: its effect on the trips is confounded with {with_} "
        f"(correlation {worst_r:.4f} > {max_correlation:g}); {_HINTS.get(names[worst], '')}"
    )


def _imprecise(fit: _Fit, names, data: _Data, idx, max_rel_se: float) -> tuple[str, str] | None:
    """The extra parameter whose standard error is too large for it to mean anything."""
    sd = np.sqrt(np.maximum(np.diag(fit.cov), 0.0))
    rate = float(np.median(data.y[idx] / data.duration[idx]))
    worst, worst_ratio, worst_ref = None, max_rel_se, 0.0
    for j, name in enumerate(names):
        if name == "eta":
            continue
        ref = 0.1 * rate if name in ("aux_power_w", "idle_fuel_lps") else 0.0
        scale = max(abs(float(fit.theta[j])), ref)
        ratio = sd[j] / scale if scale > 0 and math.isfinite(sd[j]) else math.inf
        if ratio > worst_ratio:
            worst, worst_ratio, worst_ref = j, ratio, ref
    if worst is None:
        return None
    name, value = names[worst], float(fit.theta[worst])
    of = f"its value {value:.3g}" if abs(value) >= worst_ref else f"the reference {worst_ref:.3g} (10 % of the median consumption rate)"
    return name, (
        f"not identifiable: {value:.3g} +- {sd[worst]:.3g}, a standard error of {100 * worst_ratio:.0f} % of "
        f"{of} (limit {100 * max_rel_se:.0f} %); {_HINTS.get(name, '')}"
    )


def _normalise_params(params: Sequence[str], vehicle: Vehicle) -> list[str]:
    allowed = PARAMS_EV if vehicle.is_ev else PARAMS_ICE
    out: list[str] = []
    for p in params:
        name = PARAM_ALIASES.get(p, p)
        if name not in allowed:
            raise CalibrationError(
                f"cannot fit {p!r} for an {'EV' if vehicle.is_ev else 'ICE'} vehicle; choose from {', '.join(allowed)}"
            )
        if name not in out:
            out.append(name)
    if "eta" not in out:
        raise CalibrationError("'eta' must be among the fitted parameters")
    out.remove("eta")
    return ["eta", *out]


# --- cross-validation ----------------------------------------------------------------------


def _folds(data: _Data, cv_folds: int, loo_below: int, seed: int) -> tuple[np.ndarray, str]:
    """Fold index per trip (-1: no CV) and a description; groups never straddle folds."""
    keys = [g if g is not None else f"\0{tid}" for g, tid in zip(data.groups, data.ids)]
    uniq = list(dict.fromkeys(keys))
    grouped = any(g is not None for g in data.groups)
    G = len(uniq)
    if cv_folds < 2 or G < 2:
        return np.full(data.n, -1), "none"
    if G < loo_below or cv_folds >= G:
        fold_of = {g: i for i, g in enumerate(uniq)}
        scheme = f"leave-one-group-out ({G} groups)" if grouped else "leave-one-out"
    else:
        rng = np.random.default_rng(seed)
        order = [uniq[i] for i in rng.permutation(G)]
        size = {g: 0 for g in uniq}
        for k in keys:
            size[k] += 1
        order.sort(key=lambda g: -size[g])  # stable: shuffled order among equal sizes
        load = np.zeros(cv_folds)
        fold_of = {}
        for g in order:
            f = int(np.argmin(load))
            fold_of[g] = f
            load[f] += size[g]
        scheme = f"grouped {cv_folds}-fold ({G} groups)" if grouped else f"{cv_folds}-fold"
    return np.array([fold_of[k] for k in keys]), scheme


# --- predictions and timing ----------------------------------------------------------------


def predict_trips(vehicle: Vehicle, trips: Sequence[TripData]) -> np.ndarray:
    """Predicted consumption of each trip [l for an ICE, J for an EV] with
    :func:`cevm.core.vehicle.predict` (the trip's mass, or the vehicle's when None)."""
    out = np.empty(len(trips))
    for i, t in enumerate(trips):
        out[i] = _predict_one(vehicle, t.vector, vehicle.mass_kg if t.mass_kg is None else t.mass_kg)
    return out


def _predict_one(vehicle: Vehicle, vector: CycleVector, mass_kg: float) -> float:
    p = predict(vector, vehicle, float(mass_kg))
    return float(p.energy_j if vehicle.is_ev else p.fuel_l)


def _time_predictions(vehicle: Vehicle, data: _Data, repeats: int) -> tuple[float, float] | None:
    if repeats <= 0 or data.n == 0:
        return None
    per_trip = np.empty(data.n)
    for i, (v, m) in enumerate(zip(data.vectors, data.mass)):
        _predict_one(vehicle, v, m)  # warm any per-vector cache first
        t0 = time.perf_counter()
        for _ in range(repeats):
            _predict_one(vehicle, v, m)
        per_trip[i] = (time.perf_counter() - t0) / repeats
    return float(per_trip.mean()), float(per_trip.std(ddof=1)) if data.n > 1 else 0.0


# --- the public entry point ----------------------------------------------------------------


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
) -> CalibrationResult:
    """Fit a vehicle's CE parameters to measured trip consumption and validate the fit.

    Parameters
    ----------
    vehicle : the vehicle to calibrate; its values are the starting point and are kept
        for every parameter that is not fitted
    trips : the trips (see :class:`TripData`); measured in litres (ICE) or joules (EV)
    params : parameters to fit, "eta" required, plus any of "aux_power_w" (EV),
        "idle_fuel_lps" (ICE), "cda_m2", "cr" (aliases: aux_power, idle_fuel, cda).
        Default ("eta",), the paper's calibration.
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
    max_correlation : refuse an extra parameter whose effect has a multiple correlation
        above this with the others', default 0.98 (the standard error is then inflated
        at least 5-fold by the confounding)
    max_rel_se : refuse an extra parameter whose standard error exceeds this share of
        max(|value|, reference), default 0.5 (an estimate of 1 +- 0.5 says little)
    time_repeats : predictions timed per trip, default 20; 0 skips the timing
    seed : seed of the fold assignment, default 0 (results are reproducible)

    Returns
    -------
    CalibrationResult

    Raises
    ------
    CalibrationError
        when eta itself cannot be fitted (fewer than 3 usable trips), for unknown
        parameter names and duplicate trip ids.
    """
    names = _normalise_params(params, vehicle)
    if model_rel_sigma is not None and not (math.isfinite(model_rel_sigma) and model_rel_sigma >= 0):
        raise CalibrationError(f"model_rel_sigma must be None or >= 0, got {model_rel_sigma!r}")
    data, excluded = _select_trips(vehicle, trips, max_rel_uncertainty, min_distance_m, rel_uncertainty_floor)
    if data.n < 3:
        why = "; ".join(f"{k}: {v}" for k, v in list(excluded.items())[:5])
        raise CalibrationError(
            f"eta needs at least 3 usable trips, {data.n} of {len(trips)} are usable"
            + (f" (excluded: {why}{' ...' if len(excluded) > 5 else ''})" if excluded else "")
        )
    model = _Model(vehicle, data)
    idx_all = np.arange(data.n)
    refused: dict = {}
    warnings: list = []
    active = list(names)
    while True:
        k = len(active)
        if data.n < k + 2:
            name = active.pop()
            refused[name] = f"needs at least {k + 2} usable trips to fit {k} parameters, {data.n} are usable"
            continue
        x0 = _start(model, active)
        tau0 = 0.0 if model_rel_sigma is None else model_rel_sigma
        w0 = data.q / (data.u**2 + tau0**2)
        jw0 = (np.sqrt(w0) / data.y)[:, None] * model.jacobian(active, x0, idx_all)
        bad = _confounded(jw0, active, max_correlation)
        if bad is None:
            result = _fit(model, active, idx_all, model_rel_sigma)
            bad = _confounded(result.jw, active, max_correlation) or _imprecise(
                result, active, data, idx_all, max_rel_se)
        if bad is None:
            break
        refused[bad[0]] = bad[1]
        active.remove(bad[0])

    values = model.values(active, result.theta)
    calibrated = replace(vehicle, **{n: values[n] for n in active})
    sd = np.sqrt(np.maximum(np.diag(result.cov), 0.0))
    fitted = {n: (float(result.theta[j]), float(sd[j])) for j, n in enumerate(active)}
    corr: dict = {}
    for a in range(len(active)):
        for b in range(a + 1, len(active)):
            d = sd[a] * sd[b]
            corr[(active[a], active[b])] = float(result.cov[a, b] / d) if d > 0 else math.nan
    if not result.converged:
        warnings.append("the fit did not converge to the requested tolerance")
    lb, ub = _bounds(active, data)
    for j, n in enumerate(active):
        tol = max(1e-6 * sd[j], 1e-10 * max(1.0, abs(result.theta[j])))  # trf stays inside by a hair
        if result.theta[j] <= lb[j] + tol or result.theta[j] >= ub[j] - tol:
            warnings.append(f"{n} = {result.theta[j]:.6g} is at its bound: its standard error assumes it is not")

    pred_in = np.array([_predict_one(calibrated, v, m) for v, m in zip(data.vectors, data.mass)])

    folds, scheme = _folds(data, cv_folds, loo_below, seed)
    pred_cv = np.full(data.n, math.nan)
    for f in np.unique(folds[folds >= 0]):
        train = np.flatnonzero(folds != f)
        test = np.flatnonzero(folds == f)
        if train.size < len(active):
            warnings.append(f"fold {f}: {train.size} training trips cannot fit {len(active)} parameters")
            continue
        ff = _fit(model, active, train, model_rel_sigma)
        if not ff.converged:
            warnings.append(f"fold {f}: the fit did not converge to the requested tolerance")
        vf = replace(vehicle, **{n: model.values(active, ff.theta)[n] for n in active})
        for i in test:
            pred_cv[i] = _predict_one(vf, data.vectors[i], data.mass[i])

    err_in = (pred_in - data.y) / data.y * 100.0
    err_cv = (pred_cv - data.y) / data.y * 100.0
    share = result.weights / result.weights.sum()
    rows = tuple(
        TripRow(
            trip_id=data.ids[i],
            group=data.groups[i],
            mass_kg=float(data.mass[i]),
            distance_m=float(data.vectors[i].distance_m),
            measured=float(data.y[i]),
            uncertainty=float(data.sigma[i]),
            rel_uncertainty=float(data.sigma[i] / data.y[i]),
            weight=float(share[i]),
            predicted_in_sample=float(pred_in[i]),
            predicted_cv=float(pred_cv[i]),
            error_pct_in_sample=float(err_in[i]),
            error_pct_cv=float(err_cv[i]),
            fold=int(folds[i]),
        )
        for i in range(data.n)
    )
    cond = _condition_number(result.jw)
    return CalibrationResult(
        vehicle=calibrated,
        fitted=fitted,
        correlation=corr,
        refused=refused,
        excluded=excluded,
        rows=rows,
        in_sample=ErrorStats.of(err_in),
        cv=ErrorStats.of(err_cv) if scheme != "none" else None,
        cv_scheme=scheme,
        model_rel_sigma=float(result.tau),
        residual_scale=math.sqrt(result.s2) if math.isfinite(result.s2) else math.nan,
        condition_number=cond,
        time_per_prediction_s=_time_predictions(calibrated, data, time_repeats),
        unit="J" if vehicle.is_ev else "l",
        warnings=tuple(warnings),
    )


def _condition_number(jw: np.ndarray) -> float:
    norms = np.linalg.norm(jw, axis=0)
    if not np.all(norms > 0):
        return math.inf
    sv = np.linalg.svd(jw / norms, compute_uv=False)
    return float(sv[0] / sv[-1]) if sv[-1] > 0 else math.inf


def display_value(result: CalibrationResult, value: float) -> float:
    """Consumption in display units: litres, or kWh for joules."""
    return value / J_PER_KWH if result.unit == "J" else value
