"""The shape of every predictive distribution of a consumption (pure): its quantiles,
central intervals and the probability of staying within a budget, from its mean and
standard deviation. Every command's intervals and probabilities (predict's
``*_low``/``*_high`` and ``p_reserve_ok``/``p_tank_ok``, feasibility's verdict, replay's
intervals and battery sizes, fleet plan's ``p_complete``, calibrate's held-out intervals)
come from here, so that an interval and a probability made of the same mean and
standard deviation say the same thing.

Fuel burnt, and the energy a vehicle draws over a trip that is not a net descent, cannot
be negative, and its errors are multiplicative (an efficiency, a share of the energy): a
Gaussian's lower end goes below zero where the standard deviation is large against the
mean (a short truck trip, a file never calibrated). So where the mean is positive the
distribution is the **log-normal** with that mean m and standard deviation s::

    sigma^2 = ln(1 + (s / m)^2),   mu = ln m - sigma^2 / 2,   X = exp(mu + sigma Z)

(the same mean and variance as before: only the shape changes, and it never crosses
zero). Where the mean is zero or negative (an electric vehicle on a long descent regains
charge: its energy takes either sign) it is the Gaussian N(m, s^2); a standard deviation
of zero is the mean itself. For s << m the two agree (the held-out log-likelihoods and
coverages of the sample logs' calibrations: docs/benchmarks.md).
"""

from __future__ import annotations

import math
import statistics

import numpy as np
from numpy.typing import ArrayLike


def normal_quantile(p: float) -> float:
    """The standard normal quantile of ``p`` in (0, 1) (an interval's z): Python's
    :class:`statistics.NormalDist` (Wichura's AS241, within 1e-15 of
    ``scipy.special.ndtri``), so that a command printing intervals need not import
    ``scipy.special`` (about 0.1-0.3 s of a short command: its array-API layer imports
    numpy.testing and numpy.f2py)."""
    return _STANDARD_NORMAL.inv_cdf(float(p))


_STANDARD_NORMAL = statistics.NormalDist()


def _quantile_or_edge(p: float) -> float:
    if 0.0 < p < 1.0:
        return _STANDARD_NORMAL.inv_cdf(p)
    return -math.inf if p == 0.0 else math.inf if p == 1.0 else math.nan


_QUANTILES = np.frompyfunc(_quantile_or_edge, 1, 1)


def normal_quantiles(p: ArrayLike) -> np.ndarray:
    """:func:`normal_quantile` of each ``p`` (float64, broadcast; 0 and 1 give -inf
    and +inf, anything outside [0, 1] or NaN gives NaN, as ``scipy.special.ndtri``)."""
    return np.asarray(_QUANTILES(np.asarray(p, dtype=np.float64)), dtype=np.float64)


def normal_cdf(z: ArrayLike) -> np.ndarray:
    """The standard normal distribution function of each ``z`` (float64; NaN stays
    NaN): erfc(-z / sqrt 2) / 2, the formula of ``scipy.special.ndtr``, with C's
    ``erfc`` (:func:`math.erfc`) per element (within 2.3e-16 of ``ndtr``, 1e-13 of it
    relative in the far tail below 1e-300): about 60 ns an element, where importing
    ``scipy.special`` costs a command about 0.16 s of CPU (2.5 M elements' worth)
    before its first row."""
    x = np.asarray(z, dtype=np.float64) * -_SQRT_HALF
    return np.asarray(_ERFC(x), dtype=np.float64) * 0.5


_SQRT_HALF = math.sqrt(0.5)
_ERFC = np.frompyfunc(math.erfc, 1, 1)


def _params(mean: ArrayLike, sd: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(m, s, log-normal's mu, its sigma) broadcast; mu and sigma are NaN where the
    Gaussian applies (m <= 0, or s = 0)."""
    m, s = np.broadcast_arrays(np.asarray(mean, dtype=np.float64), np.asarray(sd, dtype=np.float64))
    with np.errstate(divide="ignore", invalid="ignore", under="ignore", over="ignore"):
        s2 = np.log1p(np.square(s / m))
        # an sd below the mean's last digit (s2 = 0): the Gaussian, as good as the mean
        s2 = np.where((m > 0) & (s2 > 0) & np.isfinite(s2), s2, np.nan)
        mu = np.log(m) - 0.5 * s2
    return m, s, mu, np.sqrt(s2)


def lognormal(mean: ArrayLike, sd: ArrayLike) -> np.ndarray:
    """Where the log-normal applies (mean > 0 and sd > 0)."""
    m, s = np.broadcast_arrays(np.asarray(mean, dtype=np.float64), np.asarray(sd, dtype=np.float64))
    return np.asarray((m > 0) & (s > 0))


def _quantile(params: tuple[np.ndarray, ...], z: ArrayLike) -> np.ndarray:
    m, s, mu, sig = params
    with np.errstate(invalid="ignore", over="ignore"):
        out = np.where(np.isfinite(mu), np.exp(mu + sig * z), m + s * z)
    return np.asarray(out, dtype=np.float64)


def quantile(mean: ArrayLike, sd: ArrayLike, q: ArrayLike) -> np.ndarray:
    """The q-quantile(s), q in (0, 1) (broadcast)."""
    return _quantile(_params(mean, sd), normal_quantiles(q))


def interval(mean: ArrayLike, sd: ArrayLike, level: float) -> tuple[np.ndarray, np.ndarray]:
    """The central interval that holds the consumption with probability ``level``."""
    params = _params(mean, sd)
    z = normal_quantile(0.5 + 0.5 * level)
    return _quantile(params, -z), _quantile(params, z)


def prob_at_most(mean: ArrayLike, sd: ArrayLike, budget: ArrayLike) -> np.ndarray:
    """P(consumption <= budget) (broadcast); a budget of NaN gives NaN."""
    b = np.asarray(budget, dtype=np.float64)
    m, s, mu, sig = _params(mean, sd)
    m, s, mu, sig, b = np.broadcast_arrays(m, s, mu, sig, b)
    with np.errstate(divide="ignore", invalid="ignore"):
        z_ln = (np.log(np.where(b > 0, b, 1.0)) - mu) / sig
        z_ln = np.where(b > 0, z_ln, -np.inf)
        z_n = (b - m) / s
    p = np.where(np.isfinite(mu), normal_cdf(z_ln),
                 np.where(s > 0, normal_cdf(z_n), np.where(b >= m, 1.0, 0.0)))
    return np.asarray(np.where(np.isnan(b) | np.isnan(m), np.nan, p), dtype=np.float64)
