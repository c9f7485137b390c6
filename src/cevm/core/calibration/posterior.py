"""The posterior of a set of terms: Gaussian priors, a model of the trips' scatter, the
mode under the physical bounds and its Laplace covariance (pure).

Model of trip i's measured consumption y_i [J or l] (:mod:`cevm.core.calibration.terms`: x_i the features,
theta the coefficients, f_i the terms held fixed)::

    y_i = x_i theta + f_i + sqrt(r_i) (D_i b_g(i) + mu_i a_g(i)) + e_i
    e_i ~ N(0, sigma_i^2 + (1 - rho) r_i ((s_aux D_i)^2 + (s_share mu_i)^2))
    b_g ~ N(0, rho s_aux^2),  a_g ~ N(0, rho s_share^2)     (one pair per day g)
    theta_j ~ N(m_j, s_j^2) truncated to the term's physical range

sigma_i is the measurement's own uncertainty, D_i the duration, mu_i the modelled
consumption, r_i = q_ref / q_i the trip's road-profile quality relative to the trips'
median (:mod:`cevm.store.calibration`: DSM coverage), s_aux the trip-to-trip scatter of
the auxiliary power (or fuel rate), s_share the scatter proportional to the energy, and
rho the share of both common to a day's trips (:class:`cevm.core.uncertainty.Scatter`).
With the logs' standstill evidence (:attr:`Noise.standstill`), each trip that measured
its mean battery power (fuel rate) while standing still adds an observation of the
model's standstill rate (EV: P_aux(T) = p0 + p_heat h(T) + p_cool c(T); ICE: r_idle +
r_heat h(T) + r_cool c(T)) with its own scatter s_stand.

Solution: the day effects are unknowns with their Gaussian priors beside theta, so the
posterior mode is one bounded linear least-squares problem (numpy's lstsq, scipy's BVLS
where a physical bound binds; Gauss-Newton steps for an EV's regeneration tied to eta,
the model's one non-linearity), and its covariance the inverse of the normal matrix
(Laplace at the mode; the day effects marginalised). Robustness as before
(:data:`.solve.HUBER_C`): a trip whose standardised residual exceeds c has its variance
inflated by abs(z) / c (Huber's M-estimate, by iterative reweighting).

The scatter is fitted in two steps. In sample, (s_aux, s_share, s_stand) maximise the
log marginal likelihood (the Laplace evidence, the coefficients integrated out: a
REML-like estimate) plus a weak log-normal prior centred on the vehicle class's typical
scatter (a factor e either side at one standard deviation), so that a handful of trips
cannot claim a zero scatter: this weighs the trips. Then, for predictions, (s_aux,
s_share) maximise the likelihood of the trips' *held-out* residuals (grouped folds over
days): the model's error on a day it has not seen, which a model that is not the truth
(a heat pump that is not a hinge) or trips that share a day's error make larger than in
sample (:func:`heldout_scatter`).

Legs of one day share weather and driver: rho comes from the profile likelihood of the
day effects over :data:`RHO_GRID` (:func:`day_correlation`), the largest rho the data do
not reject at 95 % (conservative: a day's total is then not claimed more certain than the
data show; with no day of two trips the data cannot tell, and rho = 1 is assumed). The
coefficients themselves are fitted with rho = 0 (each trip its own information): rho
serves the variance of sums (:mod:`cevm.core.predictive`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy.linalg import cho_factor, cho_solve
from scipy.optimize import lsq_linear, minimize

from cevm.core.calibration.data import TripSet
from cevm.core.calibration.terms import TermModel
from cevm.core.uncertainty import CoefficientPrior, ScatterPrior, extrapolation_variance

#: Day-correlation values of the profile likelihood (:func:`fit`).
RHO_GRID = (0.0, 0.2, 0.4, 0.6, 0.8, 0.95)
#: 95 % point of chi-square with one degree of freedom (the profile-likelihood interval).
CHI2_95_1 = 3.841458820694124
#: Standard deviation of the log-normal prior of the scatter parameters around the class's
#: typical values: a factor e either way at one standard deviation (weak: it matters only
#: when a few trips cannot tell).
SCATTER_LOG_SD = 1.0
#: The in-sample scatter is refitted until it moves by less than this (relative): the
#: weights it gives the trips change by twice that at most.
NOISE_TOL = 0.01
#: The standstill observations' scatter is at least this share of their median: a
#: meter's accuracy (:data:`cevm.ingest.consumption.DEFAULT_ACCURACY_PCT`, 2 %); without a
#: floor, identical rates would weigh infinitely.
STANDSTILL_FLOOR = 0.02
#: A standstill mean over less than this is not an observation [s].
STANDSTILL_MIN_S = 60.0


@dataclass(frozen=True)
class Noise:
    """Scatter parameters of a fit (module notes): ``aux`` [W or l/s], ``share`` [-],
    ``rho`` [0, 1], ``standstill`` [W or l/s] or None (standstill evidence not used),
    ``trip`` [J or l] the part of a trip's scatter that does not grow with it (fitted on
    the held-out residuals only, :func:`heldout_scatter`; held in the in-sample fit)."""

    aux: float
    share: float
    rho: float = 0.0
    standstill: float | None = None
    trip: float = 0.0

    def variance(self, duration_s: np.ndarray, mean: np.ndarray) -> np.ndarray:
        """(s_aux D)^2 + (s_share max(mu, 0))^2 + s_trip^2 per trip."""
        return (self.aux * duration_s) ** 2 + (self.share * np.maximum(mean, 0.0)) ** 2 + self.trip ** 2


@dataclass(frozen=True, eq=False)
class PosteriorFit:
    """A posterior of ``names`` on the trips ``idx``: the mode ``theta``, its covariance
    ``cov`` (coefficients), the ``noise``, the log marginal likelihood ``logml``, per trip
    the Huber weight ``weights``, the prediction ``pred`` and the scatter variance
    ``scatter_var`` ((s_aux D)^2 + (s_share mu)^2, relative quality applied); ``free`` the
    mode without the physical bounds (for messages), ``jw`` the weighted Jacobian of the
    data rows, ``rho_profile`` (rho, log-likelihood) pairs when rho was estimated."""

    names: tuple[str, ...]
    idx: np.ndarray
    theta: np.ndarray
    cov: np.ndarray
    noise: Noise
    logml: float
    weights: np.ndarray
    pred: np.ndarray
    scatter_var: np.ndarray
    free: np.ndarray
    jw: np.ndarray
    converged: bool
    prior: CoefficientPrior
    rho_profile: tuple = ()
    rho_note: str = ""

    @property
    def sd(self) -> np.ndarray:
        return np.sqrt(np.maximum(np.diag(self.cov), 0.0))

    def predictive_var(self, model: TermModel, idx: ArrayLike,
                       measurement: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """(mean, variance) of trips ``idx`` of ``model`` under this posterior: the
        parameters' part, the scatter (a new day: both its parts), and the measurement's
        own uncertainty when ``measurement``."""
        idx = np.asarray(idx)
        mu = model.predict(self.names, self.theta, idx)
        J = model.jacobian(self.names, self.theta, idx)
        var = np.einsum("ij,jk,ik->i", J, self.cov, J)
        d = model.data
        r = _quality_ratio(d.q, self.idx)[idx]
        var = var + r * self.noise.variance(d.duration[idx], mu)
        if measurement:
            var = var + (_u_random(d)[idx] * d.y[idx]) ** 2
        return mu, var


def _u_random(d: TripSet) -> np.ndarray:
    """The measurement's random relative uncertainty (its total where not split)."""
    return d.u if d.u_random is None else d.u_random


def _quality_ratio(q: np.ndarray, ref_idx: np.ndarray) -> np.ndarray:
    """r_i = q_ref / q_i, q_ref the median quality of the trips ``ref_idx``."""
    ref = float(np.median(q[ref_idx])) if len(ref_idx) else 1.0
    return ref / q


def _groups(model: TermModel, idx: np.ndarray) -> tuple[np.ndarray, int]:
    keys = [g if g is not None else f"\0{t}" for g, t in zip(model.data.groups, model.data.ids, strict=True)]
    sub = [keys[i] for i in idx]
    uniq = {k: j for j, k in enumerate(dict.fromkeys(sub))}
    return np.array([uniq[k] for k in sub], dtype=np.intp), len(uniq)


#: The standstill observations of a fit: (positions in idx, rates, design rows, offset).
StandstillRows = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]
#: A built system: (A, b, block sizes (data, standstill, prior, day effects), the
#: trips' independent variances, rho).
Parts = tuple[np.ndarray, np.ndarray, tuple[int, int, int, int], np.ndarray, float]


def _standstill_design(model: TermModel, names: Sequence[str], theta: np.ndarray,
                      idx: np.ndarray) -> StandstillRows:
    """Rows of the standstill observations among trips ``idx``: (positions in idx, the
    observed rates, A (rows x k), offset of the fixed terms)."""
    d = model.data
    s = d.standstill_s[idx]
    z = d.standstill_rate[idx]
    ok = np.isfinite(s) & np.isfinite(z) & (s >= STANDSTILL_MIN_S)
    pos = np.flatnonzero(ok)
    h = np.nan_to_num(model.h[idx][pos])
    c = np.nan_to_num(model.c[idx][pos])
    base = "aux" if model.ev else "idle"
    cols = {base: np.ones(pos.size), "heat": h, "cool": c}
    A = np.zeros((pos.size, len(names)))
    for j, n in enumerate(names):
        if n in cols:
            A[:, j] = cols[n]
    vals = model.vehicle_values()
    off = np.zeros(pos.size)
    for n, col in cols.items():
        if n not in names:
            x = vals.get(n, 0.0)
            if math.isfinite(x) and x:
                off = off + x * col
    return pos, z[pos], A, off


def _lstsq(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """min ||A x - b||: the normal equations of the column-scaled system by Cholesky (a
    few times faster than an SVD on these tall, narrow systems), numpy's lstsq where
    they are singular."""
    norms = np.sqrt(np.einsum("ij,ij->j", A, A))
    norms = np.where(norms > 0, norms, 1.0)
    As = A / norms
    try:
        c = cho_factor(As.T @ As)
        x = cho_solve(c, As.T @ b)
        if np.all(np.isfinite(x)) and float(np.min(np.abs(np.diag(c[0])))) > 1e-7:
            return np.asarray(x / norms)
    except np.linalg.LinAlgError:
        pass
    return np.asarray(np.linalg.lstsq(A, b, rcond=None)[0])


class _System:
    """The weighted least-squares system of one linearisation (theta, day effects)."""

    def __init__(self, model: TermModel, names: tuple[str, ...], idx: np.ndarray, prior: CoefficientPrior,
                 x: np.ndarray,
                 mu: np.ndarray, h: np.ndarray, h_ss: np.ndarray, groups: np.ndarray, n_groups: int,
                 ratio: np.ndarray, standstill: StandstillRows | None):
        d = model.data
        self.k = len(names)
        self.n = idx.size
        self.y = d.y[idx]
        self.sig2 = (_u_random(d)[idx] * self.y) ** 2
        self.D = d.duration[idx]
        self.mu = np.maximum(mu, 0.0)
        self.ratio = ratio
        self.h = h
        self.J = model.jacobian(names, x, idx)
        p = model.predict(names, x, idx)
        self.target = self.y - p + self.J @ x
        self.groups = groups
        self.G = n_groups
        self.prior = prior
        self.inf = np.isfinite(prior.sd)
        self.ss = standstill  # (pos, z, A, off) or None
        self.h_ss = h_ss

    def build(self, noise: Noise) -> Parts:
        """(A, b, blocks) for ``noise``: blocks = (data rows, standstill rows, prior rows)."""
        k, n, G = self.k, self.n, self.G
        rho = noise.rho if G and n > G and noise.aux > 0 and noise.share > 0 else 0.0
        ind = (self.sig2 + (1.0 - rho) * self.ratio * ((noise.aux * self.D) ** 2 + (noise.share * self.mu) ** 2)
               + self.ratio * noise.trip ** 2)
        sw = np.sqrt(self.h / ind)
        ncol = k + (2 * G if rho > 0 else 0)
        rows = [np.hstack([self.J, np.zeros((n, ncol - k))])]
        if rho > 0:
            sq = np.sqrt(self.ratio)
            rows[0][np.arange(n), k + self.groups] = sq * self.D
            rows[0][np.arange(n), k + G + self.groups] = sq * self.mu
        A_data = sw[:, None] * rows[0]
        b_data = sw * self.target
        blocks_A, blocks_b = [A_data], [b_data]
        n_ss = 0
        if self.ss is not None and noise.standstill is not None:
            pos, z, A_ss, off = self.ss
            w = np.sqrt(self.h_ss) / noise.standstill
            blocks_A.append(np.hstack([w[:, None] * A_ss, np.zeros((pos.size, ncol - k))]))
            blocks_b.append(w * (z - off))
            n_ss = pos.size
        inf = np.flatnonzero(self.inf)
        P = np.zeros((inf.size, ncol))
        P[np.arange(inf.size), inf] = 1.0 / self.prior.sd[inf]
        blocks_A.append(P)
        blocks_b.append(self.prior.mean[inf] / self.prior.sd[inf])
        n_re = 0
        if rho > 0:
            R = np.zeros((2 * G, ncol))
            R[np.arange(G), k + np.arange(G)] = 1.0 / (math.sqrt(rho) * noise.aux)
            R[G + np.arange(G), k + G + np.arange(G)] = 1.0 / (math.sqrt(rho) * noise.share)
            blocks_A.append(R)
            blocks_b.append(np.zeros(2 * G))
            n_re = 2 * G
        A = np.vstack(blocks_A)
        b = np.concatenate(blocks_b)
        return A, b, (n, n_ss, inf.size, n_re), ind, rho

    def solve(self, noise: Noise, lb: np.ndarray, ub: np.ndarray) -> tuple[np.ndarray, np.ndarray, Parts]:
        """The mode (bounded on theta), the unbounded one, and what :meth:`logml` needs."""
        A, b, blocks, ind, rho = self.build(noise)
        ncol = A.shape[1]
        free = _lstsq(A, b)
        th = free[: self.k]
        if np.all(th >= lb) and np.all(th <= ub):
            w = free
        else:
            lo = np.concatenate([lb, np.full(ncol - self.k, -np.inf)])
            hi = np.concatenate([ub, np.full(ncol - self.k, np.inf)])
            w = lsq_linear(A, b, bounds=(lo, hi), method="bvls").x
            w[: self.k] = np.clip(w[: self.k], lb, ub)
        return w, free, (A, b, blocks, ind, rho)

    def logml(self, noise: Noise, w: np.ndarray, parts: Parts) -> float:
        """Laplace log marginal likelihood at the mode ``w`` (Huber weights as fixed)."""
        A, b, (_n, n_ss, _n_pr, n_re), ind, rho = parts
        r = A @ w - b
        quad = float(r @ r)
        out = -0.5 * quad
        out -= 0.5 * float(np.sum(np.log(2.0 * math.pi * ind / self.h)))
        if n_ss and noise.standstill is not None:
            out -= 0.5 * float(np.sum(np.log(2.0 * math.pi * noise.standstill ** 2 / self.h_ss)))
        inf = np.flatnonzero(self.inf)
        out -= 0.5 * float(np.sum(np.log(2.0 * math.pi * self.prior.sd[inf] ** 2)))
        if n_re:
            out -= 0.5 * self.G * (math.log(2.0 * math.pi * rho * noise.aux ** 2)
                                   + math.log(2.0 * math.pi * rho * noise.share ** 2))
        H = A.T @ A
        try:
            c, _ = cho_factor(H)
            logdet = 2.0 * float(np.sum(np.log(np.diag(c))))
        except np.linalg.LinAlgError:
            sign, ld = np.linalg.slogdet(H)
            logdet = float(ld)
            if sign <= 0:
                return -math.inf
        out += 0.5 * H.shape[0] * math.log(2.0 * math.pi) - 0.5 * logdet
        return float(out)

    def covariance(self, parts: Parts) -> np.ndarray:
        """The theta block of the inverse normal matrix (day effects marginalised)."""
        A = parts[0]
        H = A.T @ A
        try:
            inv = cho_solve(cho_factor(H), np.eye(H.shape[0]))
        except np.linalg.LinAlgError:
            inv = np.linalg.pinv(H)
        return np.asarray(inv[: self.k, : self.k])



    def logml_grad(self, noise: Noise, fisher: bool = False) -> tuple[Any, ...]:
        """The log marginal likelihood without the bounds and without day effects
        (``noise.rho`` ignored), its gradient in (log s_aux, log s_share[, log
        s_stand]): d/dV_i = ((w r)_i^2 - P_ii) / 2 with P = W - W X H^-1 X^T W, the
        REML-type identities of a linear Gaussian model; with ``fisher`` also the
        expected information F_ab = tr(P dV_a P dV_b) / 2."""
        n = self.n
        v = self.sig2 + self.ratio * noise.variance(self.D, self.mu)
        V = v / self.h
        X, t = self.J, self.target
        dV = [2.0 * self.ratio * (noise.aux * self.D) ** 2 / self.h,
              2.0 * self.ratio * (noise.share * self.mu) ** 2 / self.h]
        if self.ss is not None and noise.standstill is not None:
            pos, z, A_ss, off = self.ss
            Vs = noise.standstill ** 2 / self.h_ss
            X = np.vstack([X, A_ss])
            t = np.concatenate([t, z - off])
            V = np.concatenate([V, Vs])
            dV = [np.concatenate([g, np.zeros(pos.size)]) for g in dV]
            dV.append(np.concatenate([np.zeros(n), 2.0 * Vs]))
        w = 1.0 / V
        inf = self.inf
        P0 = np.where(inf, self.prior.precision, 0.0)
        H = (X.T * w) @ X + np.diag(P0)
        rhs = (X.T * w) @ t + P0 * np.where(inf, self.prior.mean, 0.0)
        try:
            cf = cho_factor(H)
        except np.linalg.LinAlgError:
            return (-math.inf, np.zeros(len(dV))) + ((np.eye(len(dV)),) if fisher else ())
        th = cho_solve(cf, rhs)
        r = t - X @ th
        dm = np.where(inf, th - np.nan_to_num(self.prior.mean), 0.0)
        logdet = 2.0 * float(np.sum(np.log(np.diag(cf[0]))))
        val = (-0.5 * float(np.sum(w * r * r)) - 0.5 * float(np.sum(P0 * dm * dm))
               - 0.5 * float(np.sum(np.log(2.0 * math.pi * V)))
               - 0.5 * float(np.sum(np.log(2.0 * math.pi * self.prior.sd[inf] ** 2)))
               + 0.5 * X.shape[1] * math.log(2.0 * math.pi) - 0.5 * logdet)
        Hi_Xt = cho_solve(cf, X.T)
        lev = np.einsum("ij,ji->i", X, Hi_Xt)
        Pdiag = w - w * w * lev
        g = 0.5 * ((w * r) ** 2 - Pdiag)
        grad = np.array([float(g @ d) for d in dV])
        if not fisher:
            return val, grad
        B = X * w[:, None]
        P = -(B @ cho_solve(cf, B.T))
        P[np.diag_indices_from(P)] += w
        P2 = P * P
        D = np.array(dV)
        F = 0.5 * (D @ P2 @ D.T)
        return val, grad, F


def _scatter_logprior(noise: Noise, centre: ScatterPrior | None) -> tuple[float, np.ndarray]:
    """The weak log-normal prior of the scatter parameters and its gradient in their logs."""
    use_ss = noise.standstill is not None
    if centre is None:
        return 0.0, np.zeros(3 if use_ss else 2)
    pairs = [(noise.aux, centre.aux, SCATTER_LOG_SD), (noise.share, centre.share, SCATTER_LOG_SD)]
    if noise.standstill is not None:
        pairs.append((noise.standstill, centre.aux, 1.5 * SCATTER_LOG_SD))
    val, grad = 0.0, []
    for x, c, sd in pairs:
        if not x > 0:
            grad.append(0.0)
            continue
        z = math.log(x / c) / sd
        val -= 0.5 * z * z
        grad.append(-z / sd)
    return val, np.array(grad)


def _start(model: TermModel, names: Sequence[str], prior: CoefficientPrior) -> np.ndarray:
    """The prior means where given, else the vehicle's values (neutral for unset terms),
    inside the bounds."""
    from cevm.core.calibration.solve import start

    x0 = start(model, names)
    x0 = np.where(np.isfinite(prior.sd), prior.mean, x0)
    return np.asarray(np.clip(x0, prior.lb, prior.ub))


class _State:
    """The iteration state of :func:`solve`: coefficients, prediction, Huber weights."""

    def __init__(self, model: TermModel, names: tuple[str, ...], idx: np.ndarray, prior: CoefficientPrior,
                 ss: StandstillRows | None, huber_c: float | None, x: np.ndarray):
        self.model, self.names, self.idx, self.prior, self.ss, self.huber_c = model, names, idx, prior, ss, huber_c
        self.groups, self.G = _groups(model, idx)
        self.ratio = _quality_ratio(model.data.q, idx)[idx]
        self.x = x
        self.mu = model.predict(names, x, idx)
        self.h = np.ones(idx.size)
        self.h_ss = np.ones(0 if ss is None else ss[0].size)

    def system(self) -> _System:
        return _System(self.model, self.names, self.idx, self.prior, self.x, self.mu, self.h, self.h_ss, self.groups,
                       self.G, self.ratio, self.ss)

    def iterate(self, noise: Noise, max_iter: int) -> bool:
        """Mode, prediction and Huber weights to convergence for ``noise`` (Gauss-Newton
        for the tied regeneration and CdA / Cr, iteratively reweighted for Huber)."""
        d = self.model.data
        y = d.y[self.idx]
        sig2 = (_u_random(d)[self.idx] * y) ** 2
        D = d.duration[self.idx]
        for _ in range(max_iter):
            w, _, _ = self.system().solve(noise, self.prior.lb, self.prior.ub)
            new = w[: len(self.names)]
            mu = self.model.predict(self.names, new, self.idx)
            h, h_ss = self.h, self.h_ss
            if self.huber_c is not None:
                total = sig2 + self.ratio * noise.variance(D, mu)
                z = np.abs(y - mu) / np.sqrt(total)
                h = np.minimum(1.0, self.huber_c / np.maximum(z, 1e-300))
                if self.ss is not None and noise.standstill is not None:
                    zs = np.abs(self.ss[1] - self.ss[2] @ new - self.ss[3]) / noise.standstill
                    h_ss = np.minimum(1.0, self.huber_c / np.maximum(zs, 1e-300))
            step = float(np.max(np.abs(new - self.x) / np.maximum(np.abs(new), 1e-12))) if new.size else 0.0
            dmu = float(np.max(np.abs(mu - self.mu) / np.maximum(np.abs(mu), 1e-300))) if mu.size else 0.0
            dh = float(np.max(np.abs(h - self.h))) if h.size else 0.0
            dhs = float(np.max(np.abs(h_ss - self.h_ss))) if h_ss.size else 0.0
            self.x, self.mu, self.h, self.h_ss = new, mu, h, h_ss
            if max(step, dmu) < 1e-8 and dh < 1e-5 and dhs < 1e-5:
                return True
        return False


def solve(model: TermModel, names: Sequence[str], idx: np.ndarray, prior: CoefficientPrior, noise: Noise, *,
          huber_c: float | None, theta0: np.ndarray | None = None, max_iter: int = 60,
          fit_noise: bool = False, scatter_prior: ScatterPrior | None = None, noise_rounds: int = 4) -> PosteriorFit:
    """The posterior mode and covariance of ``names`` on trips ``idx`` for ``noise``
    (module notes); ``fit_noise`` also fits the scatter in sample (``rho`` kept for the
    day effects of the mode): alternately the mode (Huber weights and the
    energy-proportional scatter at the current prediction) and the scatter, until the
    scatter moves by less than :data:`NOISE_TOL` (``noise_rounds`` at most)."""
    names = tuple(names)
    idx = np.asarray(idx, dtype=np.intp)
    lb, ub = prior.lb, prior.ub
    x = _start(model, names, prior) if theta0 is None else np.clip(theta0, lb, ub)
    ss = _standstill_design(model, names, x, idx) if noise.standstill is not None else None
    if ss is not None and ss[0].size == 0:
        ss, noise = None, replace(noise, standstill=None)
    state = _State(model, names, idx, prior, ss, huber_c, x)
    converged = state.iterate(noise, max_iter)
    if fit_noise:
        for _ in range(noise_rounds):
            new = fit_noise_in_sample(state.system(), noise, scatter_prior)
            moved = max(abs(math.log(new.aux / noise.aux)), abs(math.log(new.share / noise.share)),
                        abs(math.log(new.standstill / noise.standstill))
                        if new.standstill is not None and noise.standstill is not None else 0.0)
            noise = new
            converged = state.iterate(noise, max_iter)
            if moved < NOISE_TOL:
                break
    return _result(state, noise, scatter_prior, converged)


def _result(state: _State, noise: Noise, scatter_prior: ScatterPrior | None, converged: bool) -> PosteriorFit:
    sysm = state.system()
    prior = state.prior
    w, free_w, parts = sysm.solve(noise, prior.lb, prior.ub)
    x = w[: sysm.k]
    logml = sysm.logml(noise, w, parts) + _scatter_logprior(noise, scatter_prior)[0]
    cov = sysm.covariance(parts)
    pred = state.model.predict(state.names, x, state.idx)
    svar = state.ratio * noise.variance(sysm.D, pred)
    jw = parts[0][: state.idx.size, : sysm.k]
    return PosteriorFit(names=state.names, idx=state.idx, theta=x, cov=cov, noise=noise, logml=logml,
                        weights=state.h, pred=pred, scatter_var=svar, free=free_w[: sysm.k], jw=jw,
                        converged=converged, prior=prior)


def fit_noise_in_sample(sysm: _System, noise: Noise, centre: ScatterPrior | None) -> Noise:
    """The scatter that maximises the log marginal likelihood plus its weak prior for this
    linearisation (Fisher scoring on the logs, halving a step that does not climb; day
    effects not modelled)."""
    use_ss = noise.standstill is not None and sysm.ss is not None
    logs = [math.log(noise.aux), math.log(noise.share)]
    if noise.standstill is not None and sysm.ss is not None:
        logs.append(math.log(noise.standstill))
    x0 = np.array(logs)

    floor = STANDSTILL_FLOOR * float(np.median(np.abs(sysm.ss[1]))) if sysm.ss is not None and use_ss else 0.0

    def make(v: np.ndarray) -> Noise:
        v = np.clip(v, x0 - 25.0, x0 + 25.0)
        return Noise(math.exp(v[0]), math.exp(v[1]), noise.rho, max(math.exp(v[2]), floor) if use_ss else None,
                     noise.trip)

    def evaluate(v: np.ndarray, fisher: bool) -> tuple[Any, ...]:
        nz = make(v)
        out = sysm.logml_grad(nz, fisher=fisher)
        pv, pg = _scatter_logprior(nz, centre)
        return (out[0] + pv, out[1] + pg) + ((out[2],) if fisher else ())

    prec = np.zeros(x0.size)
    if centre is not None:
        prec[:2] = 1.0 / SCATTER_LOG_SD ** 2
        if use_ss:
            prec[2] = 1.0 / (1.5 * SCATTER_LOG_SD) ** 2
    x = x0
    val, g, F = evaluate(x, True)
    if not math.isfinite(val):
        return noise
    for _ in range(50):
        A = F + np.diag(prec) + 1e-9 * np.eye(x.size)
        try:
            step = np.clip(np.linalg.solve(A, g), -3.0, 3.0)
        except np.linalg.LinAlgError:
            break
        t = 1.0
        while True:
            new = x + t * step
            nv, ng, nF = evaluate(new, True)
            if math.isfinite(nv) and nv >= val - 1e-12:
                break
            t *= 0.5
            if t < 1e-4:
                return make(x)
        gain = nv - val
        x, val, g, F = new, nv, ng, nF
        if float(np.max(np.abs(t * step))) < 1e-3 or gain < 1e-4:
            break  # the scatter moves by < 0.1 %, or the log-likelihood no longer does
    return make(x)


def inner_folds(model: TermModel, idx: np.ndarray, n_folds: int = 5, loo_below: int = 10, seed: int = 0) -> np.ndarray:
    """Grouped folds of the trips ``idx`` (positions: fold per element of ``idx``):
    leave-one-day-out below ``loo_below`` days, else ``n_folds`` grouped folds."""
    from cevm.core.calibration.validation import folds

    fold_of, _ = folds(model.data.subset(idx), n_folds, loo_below, seed)
    return fold_of


@dataclass(frozen=True, eq=False)
class HeldOut:
    """Held-out predictions of trips ``idx`` (grouped folds): ``mean``, the parameters'
    variance ``param_var`` under the fold's posterior, ``extra_var`` what a trip colder
    (warmer) than the fold's training trips gains (:func:`cevm.core.uncertainty.
    extrapolation_variance`), and the fold of each trip (-1: not predicted)."""

    idx: np.ndarray
    mean: np.ndarray
    param_var: np.ndarray
    fold: np.ndarray
    extra_var: np.ndarray | None = None
    fold_noise: dict | None = None  # fold -> the Noise its training trips fitted

    def __post_init__(self) -> None:
        if self.extra_var is None:
            object.__setattr__(self, "extra_var", np.zeros_like(self.param_var))


def held_out(model: TermModel, names: Sequence[str], idx: np.ndarray, prior: CoefficientPrior, noise: Noise, *,
             huber_c: float | None, fold_of: np.ndarray | None = None, theta0: np.ndarray | None = None,
             fit_noise: bool = True,
             scatter_prior: ScatterPrior | None = None) -> HeldOut:
    """Every trip of ``idx`` predicted by the posterior of the other folds; each fold
    fits its own scatter in sample from ``noise`` (``fit_noise``, so that no trip's
    measurement reaches its own prediction through the weights), else ``noise`` is
    used as it is."""
    idx = np.asarray(idx, dtype=np.intp)
    fold_of = inner_folds(model, idx) if fold_of is None else fold_of
    mean = np.full(idx.size, math.nan)
    pvar = np.full(idx.size, math.nan)
    xvar = np.zeros(idx.size)
    fnoise = {}
    for f in np.unique(fold_of[fold_of >= 0]):
        tr = idx[fold_of != f]
        te_pos = np.flatnonzero(fold_of == f)
        if tr.size < 2:
            continue
        pf = solve(model, names, tr, prior, noise, huber_c=huber_c, theta0=theta0, fit_noise=fit_noise,
                   scatter_prior=scatter_prior, noise_rounds=2)
        fnoise[int(f)] = pf.noise
        te = idx[te_pos]
        J = model.jacobian(names, pf.theta, te)
        mean[te_pos] = model.predict(names, pf.theta, te)
        pvar[te_pos] = np.einsum("ij,jk,ik->i", J, pf.cov, J)
        xvar[te_pos] = extrapolation_var(model, names, prior, tr, te)
    return HeldOut(idx, mean, pvar, fold_of, xvar, fnoise)


def extrapolation_var(model: TermModel, names: Sequence[str], prior: CoefficientPrior, train: np.ndarray,
                      test: np.ndarray) -> np.ndarray:
    """:func:`cevm.core.uncertainty.extrapolation_variance` of the trips ``test`` for a
    fit on the trips ``train`` (the priors' slopes of the model's temperature terms)."""
    d = model.data
    t_tr = d.ambient_c[train]
    if not np.all(np.isfinite(t_tr)) or not np.all(np.isfinite(d.ambient_c[test])):
        return np.zeros(len(test))
    sd = {n: float(prior.sd[j]) for j, n in enumerate(names)
          if n in ("heat", "cool", "warm") and math.isfinite(prior.sd[j])}
    v = model.vehicle
    return extrapolation_variance(sd, (float(t_tr.min()), float(t_tr.max())), v.heating_below_c, v.cooling_above_c,
                                  d.ambient_c[test], d.duration[test])


def heldout_scatter(model: TermModel, ho: HeldOut, centre: ScatterPrior | None, start: Noise,
                    huber_c: float | None, with_param_var: bool = False) -> Noise:
    """(s_aux, s_share, s_trip) that maximise the likelihood of the held-out residuals
    y_i - mu_i ~ N(0, sigma_i^2 + r_i ((s_aux D_i)^2 + (s_share mu_i)^2 + s_trip^2))
    (plus the scatter's weak prior, each a factor e either side of the class's typical
    value at one standard deviation; Huber-weighted so that a broken measurement does
    not widen every interval); ``start``'s rho and standstill kept.

    The part s_trip that does not grow with a trip is what a short trip needs: with
    only s_aux D and s_share mu, a trip's interval shrinks with its duration and energy,
    while the model misses short trips most (a cold start, the first and last minutes);
    the sample trucks' held-out intervals were narrowest where the error was largest (a
    rank correlation of width and error of -0.77 and -0.49 on the portal trucks before,
    docs/benchmarks.md). Where the held-out residuals do not want it the likelihood
    takes it down to what its weak prior allows.

    The held-out residual's whole variance is taken as scatter (``with_param_var``
    False): a prediction then adds the full fit's parameter variance on top, which
    counts it twice when the model is right (slightly wide) but carries the fold fits'
    error on a day unlike the others when it is not, and when a day's trips share their
    error (the parameter variance of trips taken as independent is then too small).
    Measured on trips simulated with day-correlated scatter (8 days of 4 trips) and on
    the sample logs: 90 % intervals held 88 % and 93 % of held-out trips this way,
    81 % and 86 % with the parameter variance taken out.
    """
    d = model.data
    ok = np.isfinite(ho.mean)
    idx = ho.idx[ok]
    if idx.size < 3:
        return start
    r = d.y[idx] - ho.mean[ok]
    extra = np.zeros(idx.size) if ho.extra_var is None else ho.extra_var[ok]
    base = (ho.param_var[ok] if with_param_var else 0.0) + extra + (_u_random(d)[idx] * d.y[idx]) ** 2
    ratio = _quality_ratio(d.q, ho.idx)[idx]
    A = ratio * d.duration[idx] ** 2
    M = ratio * np.maximum(ho.mean[ok], 0.0) ** 2
    T = ratio
    h = np.ones(idx.size)
    trip_centre = centre.trip if centre is not None and centre.trip > 0 else None
    t0 = start.trip if start.trip > 0 else trip_centre or 0.01 * float(np.median(np.abs(d.y[idx])))
    x0 = np.array([math.log(start.aux), math.log(start.share), math.log(max(t0, 1e-300))])

    def obj(v: np.ndarray) -> tuple[float, np.ndarray]:
        v = np.clip(v, x0 - 25.0, x0 + 25.0)
        a2, s2, t2 = math.exp(2 * v[0]), math.exp(2 * v[1]), math.exp(2 * v[2])
        V = base + a2 * A + s2 * M + t2 * T
        val = -0.5 * float(np.sum(h * (np.log(2 * math.pi * V) + r * r / V)))
        dv = 0.5 * h * (r * r / V - 1.0) / V
        g = np.array([float(np.sum(dv * 2 * a2 * A)), float(np.sum(dv * 2 * s2 * M)), float(np.sum(dv * 2 * t2 * T))])
        pv, pg = _scatter_logprior(Noise(math.sqrt(a2), math.sqrt(s2)), centre)
        if trip_centre is not None:  # the same weak log-normal prior as the others'
            z = (v[2] - math.log(trip_centre)) / SCATTER_LOG_SD
            pv, pg = pv - 0.5 * z * z, np.append(pg, -z / SCATTER_LOG_SD)
        else:
            pg = np.append(pg, 0.0)
        return -(val + pv), -(g + pg)

    x = x0
    for _ in range(10):
        res = minimize(obj, x, jac=True, method="BFGS", options={"maxiter": 100, "gtol": 1e-8})
        x = np.clip(res.x, x0 - 25.0, x0 + 25.0)
        if huber_c is None:
            break
        V = base + math.exp(2 * x[0]) * A + math.exp(2 * x[1]) * M + math.exp(2 * x[2]) * T
        new_h = np.minimum(1.0, huber_c / np.maximum(np.abs(r) / np.sqrt(V), 1e-300))
        if np.max(np.abs(new_h - h)) < 1e-4:
            break
        h = new_h
    return replace(start, aux=math.exp(x[0]), share=math.exp(x[1]), trip=math.exp(x[2]))


def day_correlation(model: TermModel, names: Sequence[str], idx: np.ndarray, prior: CoefficientPrior, noise: Noise,
                    *, huber_c: float | None, theta0: np.ndarray | None = None) -> tuple[float, str, tuple]:
    """rho for the variance of a day's total (module notes): (rho, how it was decided,
    the profile ((rho, log-likelihood), ...)). The trip scatter's total is kept at
    ``noise`` (its split between days and trips is what is estimated)."""
    idx = np.asarray(idx, dtype=np.intp)
    groups, G = _groups(model, idx)
    counts = np.bincount(groups, minlength=G) if G else np.zeros(0)
    if not (noise.aux > 0 and noise.share > 0):
        return 1.0, "assumed 1 (fully correlated within a day): the scatter was held, not fitted", ()
    if G == 0 or not np.any(counts >= 2):
        return 1.0, "assumed 1 (fully correlated within a day): no day holds two trips, so the data cannot tell", ()
    if G < 3:
        return 1.0, f"assumed 1 (fully correlated within a day): {G} days cannot tell", ()
    prof = []
    for r in RHO_GRID:
        pf = solve(model, names, idx, prior, replace(noise, rho=r), huber_c=huber_c, theta0=theta0)
        prof.append((r, pf.logml))
    best = max(prof, key=lambda t: t[1])
    ok = [r for r, ll in prof if 2.0 * (best[1] - ll) <= CHI2_95_1]
    r_use = max(ok)
    if r_use >= RHO_GRID[-1]:
        r_use = 1.0
        note = (f"1 (fully correlated within a day): the trips' {G} days do not reject it at 95 % "
                f"(profile likelihood, most likely {best[0]:g})")
    else:
        note = (f"{r_use:g}: the largest the trips' {G} days do not reject at 95 % (profile likelihood over "
                f"{', '.join(f'{r:g}' for r in RHO_GRID)}; most likely {best[0]:g})")
    return r_use, note, tuple(prof)


def initial_noise(model: TermModel, idx: np.ndarray, scatter_prior: ScatterPrior | None, standstill: bool) -> Noise:
    """A starting point of the scatter: the class's typical values, else 5 % of the
    median consumption rate and 5 %; no part that does not grow with a trip (the
    in-sample fit does not estimate it: held at the class's value, it would weigh the
    trips of a vehicle whose trips are small against it less than their priors;
    :func:`heldout_scatter` fits it)."""
    d = model.data
    rate = float(np.median(d.y[idx] / d.duration[idx])) if len(idx) else 1.0
    aux = scatter_prior.aux if scatter_prior is not None else 0.05 * rate
    share = scatter_prior.share if scatter_prior is not None else 0.05
    return Noise(aux=max(aux, 1e-9), share=max(share, 1e-6), rho=0.0,
                 standstill=(max(aux, 1e-9) if standstill else None))
