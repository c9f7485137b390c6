"""What a vehicle's model knows and how sure it is: priors and posteriors of its
coefficients, and the scatter of its trips (pure, frozen dataclasses).

Every term of :mod:`cevm.core.energy` is linear in a *coefficient* once CdA, Cr, the
balance temperatures and the braking mode are fixed (:mod:`cevm.core.calibration.terms`)::

    term    coefficient                     term    coefficient
    eta     1 / eta                         kin     1 / eta_k - 1 / eta      (ICE)
    regen   eta_r (EV; None: tied to eta)   aux, heat, cool, warm, idle, run: the value

A :class:`Priors` holds, per term, a range [low, high] of the *value* (the vehicle
field: eta, W, W/K, l/s ...) that holds it with about 95 % probability, and where the
range comes from (the vehicle class's published figures, or the vehicle file's
``[prior]`` table); :func:`coefficient_prior` turns it into a Gaussian on the
coefficient (mean the middle of the coefficient's range, standard deviation a quarter of
its width / 0.98), truncated to the term's physical range (:data:`cevm.core.terms`
``plausible``): what physics refuses has no prior probability.

A :class:`Posterior` is what a calibration learnt (or, for a file never calibrated, the
prior itself): the covariance of the coefficients of its terms (their means are the
vehicle's own values) and the :class:`Scatter` of trips around the model. The
predictive distribution of a trip or a day is :mod:`cevm.core.predictive`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from cevm.core.terms import TERMS_BY_POWERTRAIN

#: z of a two-sided 95 % range: a prior range [low, high] is mean +- Z95 standard deviations.
Z95 = 1.959963984540054

#: Vehicle classes with shipped prior defaults (``configs/priors/classes.toml``).
VEHICLE_CLASSES = ("bus", "truck", "van", "car", "quadricycle")


@dataclass(frozen=True)
class TermPrior:
    """A prior range of one term's value (the vehicle field, SI), holding it with about
    95 % probability, and where it comes from."""

    term: str
    low: float
    high: float
    source: str = ""

    @property
    def mean(self) -> float:
        return 0.5 * (self.low + self.high)


@dataclass(frozen=True)
class ScatterPrior:
    """Typical trip-to-trip scatter of a vehicle class (:class:`Scatter`'s ``aux``,
    ``share`` and ``trip``), for predictions before any calibration and as the weak
    centre of the scatter a calibration fits; ``aux`` in W (EV) or l/s (ICE), ``trip`` in
    J (EV) or l (ICE)."""

    aux: float
    share: float
    source: str = ""
    trip: float = 0.0


@dataclass(frozen=True)
class Priors:
    """A vehicle's priors: its class, how the class was decided (``class_from``: "vehicle
    file" or "inferred from ..."), one :class:`TermPrior` per term, and its scatter."""

    vehicle_class: str
    class_from: str
    terms: tuple[TermPrior, ...]
    scatter: ScatterPrior
    sources: str = ""  # where the class defaults come from (file), for messages
    #: the 95 % range of a stated spec-sheet value as factors of it: (("cda", 0.9, 1.1),
    #: ("cr", 0.8, 1.2)); a file never calibrated predicts with that spread of its CdA, Cr
    spec: tuple[tuple[str, float, float], ...] = ()

    def spec_sd(self, name: str) -> float:
        """The relative standard deviation of a stated ``name`` ("cda", "cr"): a quarter
        of its 95 % range's width in factors (0 where the class gives none)."""
        for n, lo, hi in self.spec:
            if n == name:
                return (hi - lo) / (2.0 * Z95)
        return 0.0

    def get(self, term: str) -> TermPrior | None:
        for t in self.terms:
            if t.term == term:
                return t
        return None

    def describe(self) -> str:
        return f"class {self.vehicle_class} ({self.class_from})"


@dataclass(frozen=True)
class Scatter:
    """The scatter of a trip's consumption around the model [J or l]:

        Var(y_i) = (aux D_i)^2 + (share mu_i)^2 + trip^2 + sigma_meas,i^2

    ``aux`` the trip-to-trip scatter of the auxiliary power [W] (EV) or of the fuel rate
    [l/s] (ICE) beyond what the model's terms explain (A/C on or off, the set-point, a
    cabin warm after a short park), times the trip's duration D_i [s]; ``share`` the part
    that scales with the energy mu_i (driving style, traffic, wind, tyres) [-];
    ``trip`` the part that does not grow with the trip [J or l]: how warm the engine,
    cabin or battery was at the start, the first and last minutes of a trip, a detour
    (without it a short trip's interval shrinks with its duration and energy while the
    model misses short trips most); sigma_meas the measurement's own uncertainty (for a
    comparison with a measurement).

    ``day_corr`` rho in [0, 1]: the share of both parts common to the trips of one day
    (one weather, one driver): over a day's trips the sum's variance is
    rho [(aux sum D)^2 + (share sum mu)^2] + (1 - rho) sum [(aux D_i)^2 + (share mu_i)^2];
    ``day_corr_note`` how it was decided. ``standstill`` the scatter of the logs' mean
    standstill rate around the model's when those were used as observations, else None.
    """

    aux: float
    share: float
    day_corr: float = 1.0
    day_corr_note: str = "assumed 1 (fully correlated within a day): no estimate"
    standstill: float | None = None
    trip: float = 0.0

    def trip_variance(self, duration_s: ArrayLike, mean: ArrayLike) -> np.ndarray:
        """(aux D)^2 + (share max(mu, 0))^2 + trip^2 per trip (an energy given back on a
        descent has no share scatter of its own)."""
        d = np.asarray(duration_s, dtype=np.float64)
        m = np.maximum(np.asarray(mean, dtype=np.float64), 0.0)
        return (self.aux * d) ** 2 + (self.share * m) ** 2 + self.trip ** 2

    def sum_variance(self, duration_s: ArrayLike, drawn: ArrayLike, trips: ArrayLike, own: ArrayLike) -> np.ndarray:
        """The scatter's variance of a sum of trips (a day, a duty): ``duration_s`` their
        summed durations, ``drawn`` their summed max(mu, 0), ``trips`` how many, ``own``
        the sum of their :meth:`trip_variance`; the share ``day_corr`` of every part is
        common to the trips, the rest their own."""
        shared = ((self.aux * np.asarray(duration_s, dtype=np.float64)) ** 2
                  + (self.share * np.asarray(drawn, dtype=np.float64)) ** 2
                  + (self.trip * np.asarray(trips, dtype=np.float64)) ** 2)
        return np.asarray(self.day_corr * shared + (1.0 - self.day_corr) * np.asarray(own, dtype=np.float64))


@dataclass(frozen=True, eq=False)
class Posterior:
    """What a vehicle's model knows about its coefficients.

    ``terms`` the model's terms (coefficient order); ``cov`` their coefficients'
    covariance (coefficient units, see the module notes; their means are the vehicle's
    own values); ``scatter`` the trips' :class:`Scatter`; ``source`` a sentence for
    rows and legends ("calibrated on 26 trips of EB-01, 2019-01-31..2019-08-27" or
    "prior only: class defaults (bus, inferred from mass)"); ``n_trips`` how many trips
    it learnt from (0: prior only); ``priors`` the priors it started from;
    ``meter_share`` the relative systematic (calibration) uncertainty of the meter the
    trips were measured with: the coefficients absorb it, so every prediction of the
    true consumption shares it.
    """

    terms: tuple[str, ...]
    cov: np.ndarray
    scatter: Scatter
    source: str
    n_trips: int = 0
    priors: Priors | None = field(default=None)
    meter_share: float = 0.0

    @property
    def prior_only(self) -> bool:
        return self.n_trips == 0

    @property
    def label(self) -> str:
        """"prior" or "posterior": what a row's interval comes from."""
        return "prior" if self.prior_only else "posterior"

    def std(self) -> np.ndarray:
        return np.sqrt(np.maximum(np.diag(self.cov), 0.0))


# ----------------------------------------------------------------- coefficients


def value_jacobian(terms: Sequence[str], coef: np.ndarray) -> np.ndarray:
    """d value / d coefficient for the coefficients ``coef`` of ``terms`` (eta = 1/c_eta,
    eta_k = 1 / (c_kin + c_eta); the others are their own values)."""
    k = len(terms)
    G = np.eye(k)
    pos = {n: j for j, n in enumerate(terms)}
    if "eta" in pos:
        c = coef[pos["eta"]]
        G[pos["eta"], pos["eta"]] = -1.0 / (c * c)
    if "kin" in pos:
        s = coef[pos["kin"]] + (coef[pos["eta"]] if "eta" in pos else 0.0)
        G[pos["kin"], :] = 0.0
        G[pos["kin"], pos["kin"]] = -1.0 / (s * s)
        if "eta" in pos:
            G[pos["kin"], pos["eta"]] = -1.0 / (s * s)
    return G


def value_covariance(terms: Sequence[str], coef: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """The covariance of the terms' values (vehicle-field meaning) from the coefficients'
    by the delta method (:func:`value_jacobian`)."""
    G = value_jacobian(terms, coef)
    return np.asarray(G @ cov @ G.T, dtype=np.float64)


def coefficient_covariance(terms: Sequence[str], coef: np.ndarray, value_cov: np.ndarray) -> np.ndarray:
    """The inverse of :func:`value_covariance` (a vehicle file stores values' standard
    deviations and correlations)."""
    Gi = np.linalg.inv(value_jacobian(terms, coef))
    return np.asarray(Gi @ value_cov @ Gi.T, dtype=np.float64)


# ----------------------------------------------------------------- priors as Gaussians


@dataclass(frozen=True, eq=False)
class CoefficientPrior:
    """A Gaussian prior on coefficients, truncated to [lb, ub]; ``sd`` inf: flat (no
    prior: the term is what the data say, or refused when they cannot say)."""

    terms: tuple[str, ...]
    mean: np.ndarray
    sd: np.ndarray
    lb: np.ndarray
    ub: np.ndarray

    @property
    def precision(self) -> np.ndarray:
        with np.errstate(divide="ignore"):
            return np.where(np.isfinite(self.sd), 1.0 / (self.sd * self.sd), 0.0)

    def informative(self, term: str) -> bool:
        return bool(np.isfinite(self.sd[self.terms.index(term)]))


def _coefficient_range(term: str, low: float, high: float, eta_mid: float) -> tuple[float, float]:
    """A value range as a coefficient range (monotone transforms of the ends)."""
    if term == "eta":
        return 1.0 / high, 1.0 / low
    if term == "kin":
        return 1.0 / high - 1.0 / eta_mid, 1.0 / low - 1.0 / eta_mid
    return low, high


def plausible_range(powertrain: str, term: str,
                    plausible: Mapping[str, tuple[float, float]] | None = None) -> tuple[float, float]:
    """The physical range of a term's value (SI): ``plausible[term]`` where given (a
    research fit on a model that is no real vehicle, e.g. a lossless drive), else the
    term's own (:data:`cevm.core.terms` ``plausible``)."""
    if plausible is not None and term in plausible:
        lo, hi = plausible[term]
        return float(lo), float(hi)
    return TERMS_BY_POWERTRAIN[(powertrain, term)].plausible


def coefficient_bounds(powertrain: str, term: str, eta_mid: float = math.nan,
                       plausible: Mapping[str, tuple[float, float]] | None = None) -> tuple[float, float]:
    """The physical range of the term's value (:func:`plausible_range`) as a coefficient
    range."""
    lo, hi = plausible_range(powertrain, term, plausible)
    if term == "eta":
        return 1.0 / hi, 1.0 / lo
    if term == "kin":
        if not math.isfinite(eta_mid):
            return -math.inf, math.inf
        return 1.0 / hi - 1.0 / eta_mid, 1.0 / lo - 1.0 / eta_mid
    return lo, hi


def coefficient_prior(powertrain: str, terms: Sequence[str], priors: Priors | None,
                      eta_ref: float, plausible: Mapping[str, tuple[float, float]] | None = None
                      ) -> CoefficientPrior:
    """The Gaussian (truncated) prior of the coefficients of ``terms`` from ``priors``
    (None, or a term without a range: flat within its physical range); ``eta_ref`` the
    eta that the kinetic coefficient is taken relative to when eta has no prior;
    ``plausible`` physical ranges that replace the terms' own (:func:`plausible_range`)."""
    eta_p = priors.get("eta") if priors is not None else None
    eta_mid = eta_p.mean if eta_p is not None else eta_ref
    mean, sd, lb, ub = [], [], [], []
    for term in terms:
        lo, hi = coefficient_bounds(powertrain, term, eta_mid, plausible)
        p = priors.get(term) if priors is not None else None
        if p is None or term in ("cda", "cr"):
            m, s = math.nan, math.inf
        else:
            a, b = _coefficient_range(term, p.low, p.high, eta_mid)
            m, s = 0.5 * (a + b), max((b - a) / (2.0 * Z95), 1e-12 * max(abs(a), abs(b), 1e-300))
        mean.append(m)
        sd.append(s)
        lb.append(lo)
        ub.append(hi)
    return CoefficientPrior(tuple(terms), np.array(mean), np.array(sd), np.array(lb), np.array(ub))


# ----------------------------------------------------------------- extrapolation


def extrapolation_variance(slope_sd: dict, ambient_range: tuple[float, float] | None, heating_below_c: float,
                           cooling_above_c: float, ambient_c: ArrayLike, duration_s: ArrayLike,
                           starts: ArrayLike = 1.0) -> np.ndarray:
    """The variance a prediction gains beyond the temperatures a calibration saw [J^2 or
    l^2]: a straight heating (cooling) line fitted between the trips' temperatures says
    nothing of how it bends beyond them (a heat pump's power grows faster than the
    cold), so below the coldest trip (above the warmest) the slope may change by as
    much as the prior allows::

        Var = (s_heat D dh)^2 + (s_warm starts dh)^2 + (s_cool D dc)^2
        dh = max(0, min(T_lo, T_heat) - T) where T_lo < T_heat, else 0
        dc = max(0, T - max(T_hi, T_cool)) where T_hi > T_cool, else 0

    ``slope_sd`` the prior standard deviations of the "heat", "cool", "warm"
    coefficients (those present); ``ambient_range`` (T_lo, T_hi) the calibration's
    trips' temperatures (None: nothing is added). Where the trips never reached the
    side a term drives (T_lo >= T_heat) its posterior is its prior already: nothing is
    added there.
    """
    t = np.asarray(ambient_c, dtype=np.float64)
    d = np.asarray(duration_s, dtype=np.float64)
    if ambient_range is None or not slope_sd:
        return np.zeros(np.broadcast(t, d).shape)
    lo, hi = ambient_range
    dh = np.maximum(0.0, min(lo, heating_below_c) - t) if lo < heating_below_c else np.zeros_like(t)
    dc = np.maximum(0.0, t - max(hi, cooling_above_c)) if hi > cooling_above_c else np.zeros_like(t)
    var = np.zeros(np.broadcast(t, d).shape)
    if "heat" in slope_sd:
        var = var + (slope_sd["heat"] * d * dh) ** 2
    if "warm" in slope_sd:
        var = var + (slope_sd["warm"] * np.asarray(starts, dtype=np.float64) * dh) ** 2
    if "cool" in slope_sd:
        var = var + (slope_sd["cool"] * d * dc) ** 2
    return var


def slope_prior_sd(powertrain: str, terms: Sequence[str], priors: Priors | None) -> dict:
    """The prior standard deviations of the temperature terms among ``terms`` (for
    :func:`extrapolation_variance`); empty without priors."""
    if priors is None:
        return {}
    names = [t for t in ("heat", "cool", "warm") if t in terms and priors.get(t) is not None]
    cp = coefficient_prior(powertrain, names, priors, math.nan)
    return {n: float(s) for n, s in zip(names, cp.sd, strict=True) if math.isfinite(s)}
