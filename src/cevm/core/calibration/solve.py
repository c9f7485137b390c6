"""The weighted fit of a set of terms (pure).

Residuals are relative, r_i = (p_i - y_i) / y_i, the quantity the paper's tables judge.
Trip i weighs W_i = q_i / (u_i^2 + tau^2), with u_i the relative 1-sigma measurement
error (floored), q_i in (0, 1] a quality factor (DSM coverage, gaps) and tau the model's
own relative error. With tau = 0, sum W_i r_i^2 is exactly the chi-square of the absolute
residuals, sum (p_i - y_i)^2 / sigma_i^2. By default tau is estimated from the residuals
(Paule-Mandel: the tau >= 0 that makes chi-square equal n - k), so a trip measured 100
times better than the model can predict does not take over the fit.

Robustness: a real fleet's logs hold a few trips whose measurement is wrong (a counter
glitch, a gap the logger bridged badly). With ``huber_c`` (default :data:`HUBER_C`) the
fit is a Huber M-estimate by iteratively reweighted least squares: a trip whose
standardised residual r_i / sqrt(u_i^2 + tau^2) exceeds c keeps the weight c / abs(z_i) of
it, so it cannot pull the fit more than a trip c standard deviations away; trips within
c count fully (for normal errors, 99 % of them at c = 2.5), so on clean data the fit is
the least-squares one.

The model is linear in the terms' coefficients (:mod:`cevm.core.calibration.terms`)
except for an EV's regeneration tied to eta and for CdA and Cr. Without CdA and Cr each
fit is a bounded linear least-squares problem (numpy's lstsq, scipy's BVLS where a bound
binds), with Gauss-Newton steps for the tied regeneration: tens of microseconds, so model
selection can afford nested cross-validation. With CdA or Cr, scipy's trust-region
least squares under bounds. Covariance = (J_w^T J_w)^-1 s^2, J_w the weighted Jacobian,
s^2 = chi-square / (n - k).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from scipy.optimize import brentq, least_squares, lsq_linear

from cevm.core.calibration.terms import TERMS_BY_POWERTRAIN, TermModel

#: Huber's threshold on standardised residuals (:func:`fit_terms`): 2.5 standard
#: deviations, the usual choice between efficiency on clean data and robustness.
HUBER_C = 2.5


@dataclass(frozen=True, eq=False)
class Fit:
    """A fit of the coefficients ``theta`` of ``names`` to the trips ``idx``."""

    names: tuple[str, ...]
    theta: np.ndarray
    cov: np.ndarray
    tau: float
    s2: float
    jw: np.ndarray  # weighted Jacobian at theta
    weights: np.ndarray  # W_i
    pred: np.ndarray
    converged: bool
    free: np.ndarray  # the coefficients without bounds (for messages): same as theta when no bound binds


class FitLike(Protocol):
    """What the checks read of a fit (a :class:`Fit` or a posterior's mode,
    :class:`cevm.core.calibration.posterior.PosteriorFit`)."""

    @property
    def names(self) -> tuple[str, ...]: ...
    @property
    def theta(self) -> np.ndarray: ...
    @property
    def cov(self) -> np.ndarray: ...
    @property
    def free(self) -> np.ndarray: ...


def bounds(model: TermModel, names: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of the coefficients of ``names`` in the fit."""
    pt = model.vehicle.powertrain
    lo, hi = [], []
    for n in names:
        b = TERMS_BY_POWERTRAIN[(pt, n)].bounds
        if n == "cr":
            b = (max(b[0], max((v.cr0 for v in model.data.vectors), default=0.0)), b[1])
        lo.append(b[0])
        hi.append(b[1])
    return np.array(lo, dtype=np.float64), np.array(hi, dtype=np.float64)


def start(model: TermModel, names: Sequence[str]) -> np.ndarray:
    """Starting coefficients: the vehicle's values (a neutral value for unset terms),
    inside the bounds."""
    vals = model.vehicle_values()
    coef = model.coefficients({k: v for k, v in vals.items() if k not in ("cda", "cr")})
    x0 = []
    for n in names:
        if n in ("cda", "cr"):
            x0.append(vals[n])
        elif n == "regen":
            x0.append(vals["eta"] if not math.isfinite(vals["regen"]) else vals["regen"])
        else:
            c = coef.get(n, 0.0)
            x0.append(0.0 if not math.isfinite(c) else c)
    lb, ub = bounds(model, names)
    return np.clip(np.array(x0, dtype=np.float64), lb, ub)


def solve_tau(r: np.ndarray, u: np.ndarray, q: np.ndarray, dof: int) -> float:
    """Paule-Mandel: tau >= 0 with sum q r^2 / (u^2 + tau^2) = dof (0 if already below)."""
    if dof <= 0:
        return 0.0
    qr2 = q * r * r
    if float(np.sum(qr2 / (u * u))) <= dof:
        return 0.0
    hi = math.sqrt(float(qr2.sum()) / dof)
    return float(brentq(lambda t: float(np.sum(qr2 / (u * u + t * t))) - dof, 0.0, hi, xtol=1e-12, rtol=1e-10))


def _linear_step(model, names, idx, sw, y, theta, lb, ub) -> tuple[np.ndarray, np.ndarray, bool]:
    """One Gauss-Newton step (exact for a linear model): the bounded weighted least-squares
    solution of the model linearised at ``theta``; also the unbounded one."""
    J = model.jacobian(names, theta, idx)
    p = model.predict(names, theta, idx)
    A = sw[:, None] * J
    b = sw * (y - p + J @ theta)
    free, *_ = np.linalg.lstsq(A, b, rcond=None)
    if np.all(free >= lb) and np.all(free <= ub):
        return free, free, True
    res = lsq_linear(A, b, bounds=(lb, ub), method="bvls")
    return res.x, free, bool(res.success)


def fit_terms(model: TermModel, names: Sequence[str], idx: np.ndarray, tau_fixed: float | None,
              theta0: np.ndarray | None = None, huber_c: float | None = HUBER_C) -> Fit:
    """Fit the coefficients of ``names`` to the trips ``idx`` (weights and tau as in the
    module docstring; ``tau_fixed`` None estimates tau; ``huber_c`` None: plain least
    squares)."""
    names = tuple(names)
    data = model.data
    y, u, q = data.y[idx], data.u[idx], data.q[idx]
    n, k = y.size, len(names)
    lb, ub = bounds(model, names)
    x = start(model, names) if theta0 is None else np.clip(theta0, lb, ub)
    nonlinear = any(not TERMS_BY_POWERTRAIN[(model.vehicle.powertrain, nm)].linear for nm in names)
    tied = model.ev and "regen" not in names and model.vehicle.regen_eta is None
    tau = 0.0 if tau_fixed is None else float(tau_fixed)
    converged = False
    free = x
    h = np.ones(n)  # Huber weights
    for _ in range(100):
        W = q * h / (u * u + tau * tau)
        sw = np.sqrt(W) / y
        if nonlinear:
            def fun(th):
                return sw * (model.predict(names, th, idx) - y)  # noqa: B023 (called only in this iteration)

            def jac(th):
                return sw[:, None] * model.jacobian(names, th, idx)  # noqa: B023 (called only in this iteration)

            res = least_squares(fun, x, jac=jac, bounds=(lb, ub), method="trf", x_scale="jac",
                                ftol=1e-12, xtol=1e-12, gtol=1e-12, max_nfev=200 * k)
            x, free, converged = res.x, res.x, bool(res.success)
        else:
            for _gn in range(30):
                new, free, converged = _linear_step(model, names, idx, sw, y, x, lb, ub)
                step = np.max(np.abs(new - x) / np.maximum(np.abs(new), 1e-12)) if new.size else 0.0
                x = new
                if not tied or step < 1e-12:
                    break
            else:
                converged = False
        pred = model.predict(names, x, idx)
        r = (pred - y) / y
        new_tau = tau if tau_fixed is not None else solve_tau(r, u, q * h, n - k)
        new_h = h
        if huber_c is not None:
            z = np.abs(r) * np.sqrt(q) / np.sqrt(u * u + new_tau * new_tau)
            new_h = np.minimum(1.0, huber_c / np.maximum(z, 1e-300))
        if abs(new_tau - tau) <= 1e-9 + 1e-6 * tau and np.max(np.abs(new_h - h)) <= 1e-6:
            break
        converged = False
        tau, h = new_tau, new_h
    W = q * h / (u * u + tau * tau)
    sw = np.sqrt(W) / y
    if not nonlinear and (np.any(x <= lb) or np.any(x >= ub)):
        # a bound binds: the unbounded optimum (for messages), by Gauss-Newton to convergence
        free = x
        inf = np.full(k, np.inf)
        for _gn in range(50):
            new, _, _ = _linear_step(model, names, idx, sw, y, free, -inf, inf)
            if not np.all(np.isfinite(new)) or np.any(new[names.index("eta")] <= 0 if "eta" in names else False):
                break
            step = np.max(np.abs(new - free) / np.maximum(np.abs(new), 1e-12))
            free = new
            if not tied or step < 1e-12:
                break
    pred = model.predict(names, x, idx)
    f = sw * (pred - y)
    jw = sw[:, None] * model.jacobian(names, x, idx)
    s2 = float(f @ f) / (n - k) if n > k else math.nan
    _, sv, vt = np.linalg.svd(jw, full_matrices=False)
    with np.errstate(divide="ignore"):
        inv = np.where(sv > sv[0] * 1e-14, 1.0 / (sv * sv), np.inf) if sv.size else sv
    cov = (vt.T * inv) @ vt * (s2 if math.isfinite(s2) else math.nan)
    return Fit(names=names, theta=x, cov=cov, tau=tau, s2=s2, jw=jw, weights=W, pred=pred, converged=converged,
               free=free)


def value_covariance(model: TermModel, fit: FitLike) -> tuple[dict[str, float], np.ndarray]:
    """The fitted terms' values (vehicle-field meaning, SI) and their covariance, by the
    delta method from the coefficients' (eta = 1/c, eta_k = 1/(c_kin + c_eta))."""
    names = fit.names
    vals = model.values_of(names, fit.theta)
    k = len(names)
    G = np.eye(k)
    pos = {n: j for j, n in enumerate(names)}
    if "eta" in pos:
        c = fit.theta[pos["eta"]]
        G[pos["eta"], pos["eta"]] = -1.0 / (c * c)
    if "kin" in pos:
        v = vals["kin"]
        G[pos["kin"], :] = 0.0
        G[pos["kin"], pos["kin"]] = -v * v
        if "eta" in pos:
            G[pos["kin"], pos["eta"]] = -v * v
    return {n: vals[n] for n in names}, G @ fit.cov @ G.T


def condition_number(jw: np.ndarray) -> float:
    """Of the column-normalised weighted Jacobian (inf for a column of zeros)."""
    norms = np.linalg.norm(jw, axis=0)
    if not np.all(norms > 0):
        return math.inf
    sv = np.linalg.svd(jw / norms, compute_uv=False)
    return float(sv[0] / sv[-1]) if sv[-1] > 0 else math.inf
