"""The predictive distribution of a vehicle's consumption: mean, standard deviation,
quantiles, and the probability of staying within a budget (pure, vectorised).

A prediction's features (:class:`Features`, one element per prediction) are what the CE
model multiplies its coefficients by (:mod:`cevm.core.calibration.terms`): the wheel
energy's parts P >= 0 and N <= 0 [J], the duration, time at standstill and traction
time [s], the positive kinetic energy m k_pos [J], the ambient temperature [degC] and the
trip starts. The mean is :func:`cevm.core.vehicle.predict`'s, to the last bit; the
variance, for a prediction of the true consumption [J^2 or l^2]::

    Var = g Sigma g^T  +  (s_aux D)^2 + (s_share mu)^2 + s_trip^2  +  (meter mu)^2
          + extrapolation   [+ sigma_meas^2]

g the gradient of the mean in the coefficients, Sigma their covariance
(:class:`cevm.core.uncertainty.Posterior`), s_aux, s_share and s_trip the trips' scatter
(:class:`cevm.core.uncertainty.Scatter`), meter the calibration meter's systematic share
(every prediction shares it), the extrapolation what a prediction colder or warmer than
the calibration's trips gains (:func:`extrapolation_var`), and sigma_meas a
measurement's own uncertainty when the prediction is compared with one. The
distribution of that mean and variance is :mod:`cevm.core.distribution`'s (log-normal
where the mean is positive: never below zero): :meth:`Predictive.quantile`,
:meth:`Predictive.interval`, :meth:`Predictive.prob_at_most`.

A vehicle file never calibrated predicts with its priors (:func:`posterior_of`): its
coefficients at the file's values, their uncertainty the vehicle class's prior ranges,
its scatter the class's typical one; the rows say "prior". A day's or a route's total
(:func:`total`) adds its legs' means and gets the variance of a sum: the parameters'
part and the meter's are common to every leg, the scatter's is shared within a group
(a day) at the posterior's day correlation rho and independent across groups.

Interface for commands (predict, feasibility, fleet plan, replay)::

    f = Features.of(vector, vehicle, mass_kg, ambient_c)     # or Features(...) from arrays
    p = predictive(vehicle, f)                                # .mean, .sd, .source
    low, high = p.interval(0.9)
    p_ok = p.prob_at_most(budget)                             # P(consumption <= budget)
    day = total(vehicle, f, groups)                          # one Predictive per group
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import cast

import numpy as np
from numpy.typing import ArrayLike

from cevm.core import distribution, energy
from cevm.core.cycle import CycleVector
from cevm.core.model import IceBraking, braking_weight, wheel_energy_parts_j
from cevm.core.uncertainty import Posterior, Scatter, coefficient_prior, extrapolation_variance, slope_prior_sd
from cevm.core.vehicle import Vehicle, default_ambient_c

#: The relative step of the CdA and Cr derivatives of :meth:`Features.of` (and of
#: :func:`cevm.core.replay.trip_energies.trip_energies`).
SPEC_STEP = 1e-6


def spec_spread(vehicle: Vehicle) -> bool:
    """Whether ``vehicle``'s stated CdA and Cr carry a spread in its predictions: a file
    never calibrated whose class (or [prior]) gives them one (a calibration's eta absorbs
    them)."""
    pr = vehicle.priors
    return vehicle.posterior is None and pr is not None and (pr.spec_sd("cda") > 0 or pr.spec_sd("cr") > 0)

#: The terms a never-calibrated vehicle's prior interval spans: every vehicle's physical
#: terms (the others only where its file sets them: they change what eta means).
PRIOR_TERMS = {"ev": ("eta", "aux", "heat", "cool"), "ice": ("eta", "idle", "heat", "cool")}


@dataclass(frozen=True, eq=False)
class Features:
    """What the CE model needs of n predictions (arrays of one length, or scalars):
    ``positive_j`` P and ``negative_j`` N (<= 0) of the wheel energy [J], ``duration_s``,
    ``idle_s`` (standstill), ``traction_s`` [s], ``kinetic_j`` the positive kinetic
    energy m k_pos [J], ``ambient_c`` [degC], ``starts`` (trip starts, 1 per trip);
    ``spec`` the derivatives of (P, N) in the vehicle's CdA and Cr, relative (d/d ln x)
    [J]: ((dP, dN) for CdA, (dP, dN) for Cr), or None (:meth:`of` gives them to a file
    never calibrated, whose stated CdA and Cr carry its class's spread)."""

    positive_j: np.ndarray
    negative_j: np.ndarray
    duration_s: np.ndarray
    idle_s: np.ndarray
    traction_s: np.ndarray
    kinetic_j: np.ndarray
    ambient_c: np.ndarray
    starts: np.ndarray | float = 1.0
    spec: tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]] | None = None

    @classmethod
    def of(cls, vector: CycleVector, vehicle: Vehicle, mass_kg: ArrayLike | None = None,
           ambient_c: ArrayLike | None = None, *, starts: np.ndarray | float = 1.0) -> Features:
        """The features of ``vector`` driven by ``vehicle`` at ``mass_kg`` (default its
        own) and ``ambient_c`` (default :func:`cevm.core.vehicle.default_ambient_c`),
        which broadcast together."""
        m = vehicle.mass_kg if mass_kg is None else mass_kg
        t = default_ambient_c(vehicle)[0] if ambient_c is None else ambient_c
        t = energy.check_ambient_c(t)
        m, t = np.broadcast_arrays(np.asarray(m, dtype=np.float64), np.asarray(t, dtype=np.float64))
        P, N = wheel_energy_parts_j(vector, m, vehicle.cda_m2, vehicle.cr)
        kin = m * vector.k_pos if math.isfinite(vector.k_pos) else np.zeros_like(m)
        trac = vector.traction_s if math.isfinite(vector.traction_s) else 0.0
        full = np.ones_like(m)
        spec = None
        if spec_spread(vehicle):
            # (P, N) are piecewise linear in CdA and Cr: a forward difference within the piece
            # (upwards: Cr may not fall below the vector's cr0) is the derivative
            parts = []
            up = 1.0 + SPEC_STEP
            for cda, cr in ((vehicle.cda_m2 * up, vehicle.cr), (vehicle.cda_m2, vehicle.cr * up)):
                P2, N2 = wheel_energy_parts_j(vector, m, cda, cr)
                parts.append(((P2 - P) / SPEC_STEP, (N2 - N) / SPEC_STEP))
            spec = (parts[0], parts[1])
        return cls(P, N, vector.duration_s * full, vector.idle_s * full, trac * full, kin, t, starts, spec)

    @property
    def n(self) -> int:
        return int(np.broadcast(self.positive_j, self.duration_s, self.ambient_c).size)

    @classmethod
    def concat(cls, parts: Sequence[Features]) -> Features:
        """The predictions of ``parts`` one after another (a day's legs, a route's), each
        part's arrays broadcast to its length; the CdA and Cr derivatives where every
        part has them."""
        ns = [p.n for p in parts]

        def cat(get) -> np.ndarray:
            return np.concatenate([np.broadcast_to(np.asarray(get(p), dtype=np.float64), (n,))
                                   for p, n in zip(parts, ns, strict=True)])

        def col(k: str) -> np.ndarray:
            return cat(lambda p: getattr(p, k))

        spec = None
        if parts and all(p.spec is not None for p in parts):
            def d(i: int, j: int) -> np.ndarray:
                return cat(lambda p: p.spec[i][j])

            spec = ((d(0, 0), d(0, 1)), (d(1, 0), d(1, 1)))
        return cls(col("positive_j"), col("negative_j"), col("duration_s"), col("idle_s"), col("traction_s"),
                   col("kinetic_j"), col("ambient_c"), col("starts"), spec)


@dataclass(frozen=True, eq=False)
class Predictive:
    """Predictive distributions (:mod:`cevm.core.distribution`): ``mean`` and ``sd`` [J (EV) or l (ICE)] per
    prediction, ``source`` "posterior" (a calibration's) or "prior" (the class's: a file
    never calibrated) or "none" (a vehicle without priors: no interval), and ``note``
    the sentence behind it."""

    mean: np.ndarray
    sd: np.ndarray
    source: str = "posterior"
    note: str = ""

    def quantile(self, q: ArrayLike) -> np.ndarray:
        """The q-quantile(s), q in (0, 1)."""
        return distribution.quantile(self.mean, self.sd, q)

    def interval(self, level: float = 0.9) -> tuple[np.ndarray, np.ndarray]:
        """The central interval holding the consumption with probability ``level``."""
        return distribution.interval(self.mean, self.sd, level)

    def prob_at_most(self, budget: ArrayLike) -> np.ndarray:
        """P(consumption <= budget), budget in the unit of ``mean`` (broadcast)."""
        return distribution.prob_at_most(self.mean, self.sd, budget)


def _prior_posterior(vehicle: Vehicle) -> Posterior | None:
    """A never-calibrated vehicle's Posterior: its file's values, the class's prior
    spread of their coefficients, the class's scatter, rho = 1."""
    pr = vehicle.priors
    if pr is None:
        return None
    pt = vehicle.powertrain
    terms = list(PRIOR_TERMS[pt])
    if pt == "ev" and vehicle.regen_eta is not None:
        terms.insert(1, "regen")
    if pt == "ev" and vehicle.warmup_j_per_k:
        terms.append("warm")
    if pt == "ice":
        for name, on in (("kin", vehicle.kinetic_eta is not None), ("run", bool(vehicle.running_fuel_lps)),
                         ("warm", bool(vehicle.warmup_fuel_l_per_k))):
            if on:
                terms.append(name)
    terms = [t for t in terms if pr.get(t) is not None]
    cp = coefficient_prior(pt, terms, pr, vehicle.eta)
    sd = np.where(np.isfinite(cp.sd), cp.sd, 0.0)
    scatter = Scatter(pr.scatter.aux, pr.scatter.share, 1.0,
                      "assumed 1 (fully correlated within a day): never calibrated", trip=pr.scatter.trip)
    return Posterior(terms=tuple(terms), cov=np.diag(sd * sd), scatter=scatter,
                     source=f"prior only: class defaults ({pr.vehicle_class}, {pr.class_from})", n_trips=0,
                     priors=pr)


def posterior_of(vehicle: Vehicle) -> Posterior | None:
    """The vehicle's posterior (a calibrated file's), else its prior (module notes),
    else None (a vehicle built without priors: no interval). A calibrated file that
    leaves out a term every vehicle has (``vehicle.from_prior``, e.g. written by a
    calibration forced to eta alone) has that term at its prior's centre: its prior
    spread joins the posterior's, independent of the fitted terms."""
    post = vehicle.posterior
    if post is None:
        return _prior_posterior(vehicle)
    pr = vehicle.priors
    extra = [t for t in vehicle.from_prior if t not in post.terms and pr is not None and pr.get(t) is not None]
    if not extra:
        return post
    cp = coefficient_prior(vehicle.powertrain, extra, pr, vehicle.eta)
    sd = np.where(np.isfinite(cp.sd), cp.sd, 0.0)
    k = len(post.terms)
    cov = np.zeros((k + len(extra), k + len(extra)))
    cov[:k, :k] = post.cov
    cov[k:, k:] = np.diag(sd * sd)
    return replace(post, terms=(*post.terms, *extra), cov=cov)


def mean(vehicle: Vehicle, f: Features, ice_braking: str | None = None) -> np.ndarray:
    """The predicted consumption [J or l], exactly as :func:`cevm.core.vehicle.predict`."""
    if vehicle.is_ev:
        w = energy.ev_negative_weight(vehicle)
        return energy.ev_battery_energy_j(vehicle, f.positive_j + w * f.negative_j, duration_s=f.duration_s,
                                          ambient_c=f.ambient_c, starts=f.starts)
    w = braking_weight(cast(IceBraking, ice_braking or vehicle.ice_braking))
    return energy.ice_fuel_l(vehicle, f.positive_j + w * f.negative_j, mass_kg=1.0, k_pos=f.kinetic_j,
                             traction_s=f.traction_s, duration_s=f.duration_s, idle_s=f.idle_s,
                             ambient_c=f.ambient_c, starts=f.starts)


def gradient(vehicle: Vehicle, f: Features, terms: Sequence[str], ice_braking: str | None = None) -> np.ndarray:
    """d mean / d coefficient of ``terms`` (n x k; :mod:`cevm.core.uncertainty`)."""
    return gradient_rows(vehicle, f, terms, ice_braking).T


def gradient_rows(vehicle: Vehicle, f: Features, terms: Sequence[str], ice_braking: str | None = None,
                  extra: int = 0) -> np.ndarray:
    """The gradient as k rows of n (+ ``extra`` rows left for the caller): the layout
    whose products with a k x k matrix and row-wise sums of squares numpy does fast (a
    tall n x k matrix times k x k is an order of magnitude slower)."""
    n = f.n
    k = len(terms)
    out = np.empty((k + extra, n))
    needs_h = any(t in ("heat", "warm") for t in terms)
    h = energy.heating_k(f.ambient_c, vehicle.heating_below_c) if needs_h else None
    c = energy.cooling_k(f.ambient_c, vehicle.cooling_above_c) if "cool" in terms else None
    ev = vehicle.is_ev
    for j, t in enumerate(terms):
        row = out[j]
        if t == "eta":
            if ev:
                if vehicle.regen_eta is None:
                    np.multiply(f.negative_j, -vehicle.eta ** 2, out=row)
                    row += f.positive_j
                else:
                    row[:] = f.positive_j
            else:
                w = braking_weight(cast(IceBraking, ice_braking or vehicle.ice_braking))
                np.multiply(f.negative_j, w, out=row)
                row += f.positive_j
                row /= vehicle.fuel_lhv_j_per_l
                if "kin" not in terms and vehicle.kinetic_eta is not None:
                    row -= np.asarray(f.kinetic_j) / vehicle.fuel_lhv_j_per_l  # a fixed eta_k moves with eta
        elif t == "regen":
            row[:] = f.negative_j
        elif t == "kin":
            np.divide(f.kinetic_j, float(vehicle.fuel_lhv_j_per_l or math.nan), out=row)
        elif t == "aux":
            row[:] = f.duration_s
        elif t == "idle":
            row[:] = f.idle_s
        elif t == "run":
            row[:] = f.traction_s
        elif t == "heat":
            np.multiply(f.duration_s, cast(np.ndarray, h), out=row)
        elif t == "cool":
            np.multiply(f.duration_s, cast(np.ndarray, c), out=row)
        elif t == "warm":
            np.multiply(f.starts, cast(np.ndarray, h), out=row)
        else:
            raise KeyError(t)
    return out


def extrapolation_var(vehicle: Vehicle, post: Posterior, f: Features) -> np.ndarray | None:
    """What a prediction gains beyond the temperatures the calibration saw
    (:func:`cevm.core.uncertainty.extrapolation_variance`); nothing for a file never
    calibrated (its prior is all it knows anyway): None."""
    d = vehicle.calibration
    if post.prior_only or d is None or d.ambient_c is None:
        return None
    sd = slope_prior_sd(vehicle.powertrain, post.terms, post.priors)
    if not sd:
        return None
    return extrapolation_variance(sd, d.ambient_c, vehicle.heating_below_c, vehicle.cooling_above_c, f.ambient_c,
                                  f.duration_s, f.starts)


def spec_parts(vehicle: Vehicle, f: Features, ice_braking: str | None = None) -> list[np.ndarray]:
    """The consumption's standard deviations [J or l] from the spread of a file's stated
    CdA and Cr (its class's, :attr:`cevm.core.uncertainty.Priors.spec`), one array per
    quantity, for a file never calibrated (a calibration's eta absorbs them: none then).
    The consumption is affine in (P, N) with the other features fixed, so its derivative
    is the mean of (dP, dN) with every other feature zero."""
    pr = vehicle.priors
    if f.spec is None or pr is None or vehicle.posterior is not None:
        return []
    zero = np.zeros_like(np.asarray(f.positive_j, dtype=np.float64))
    out = []
    for (dp, dn), name in zip(f.spec, ("cda", "cr"), strict=True):
        s = pr.spec_sd(name)
        if s > 0:
            d = Features(dp, dn, zero, zero, zero, zero, f.ambient_c, 0.0)
            out.append(np.asarray(mean(vehicle, d, ice_braking), dtype=np.float64) * s)
    return out


def sqrt_cov(cov: np.ndarray) -> np.ndarray:
    """A square root R of a covariance, R^T R = cov (eigen-decomposition: semi-definite
    covariances too)."""
    w, V = np.linalg.eigh(cov)
    return np.asarray((V * np.sqrt(np.maximum(w, 0.0))).T)


def _variance(post: Posterior, rows: np.ndarray, k: int) -> np.ndarray:
    """Sum of squares over the rows of [R G ; the rest]: the parameters' variance
    g Sigma g^T (G the first k rows) plus the squares of the rows after them."""
    var = np.zeros(rows.shape[1])
    if k:
        A = np.empty((k, rows.shape[1]))
        np.matmul(sqrt_cov(post.cov), rows[:k], out=A)
        var = np.einsum("ij,ij->j", A, A)
    if rows.shape[0] > k:
        var += np.einsum("ij,ij->j", rows[k:], rows[k:])
    return var


def predictive(vehicle: Vehicle, f: Features, *, measurement_sd: ArrayLike | None = None,
               ice_braking: str | None = None) -> Predictive:
    """The predictive distribution of each prediction of ``f`` (module notes);
    ``measurement_sd`` [J or l] a measurement's own random uncertainty, added when the
    prediction is compared with one."""
    mu = np.asarray(mean(vehicle, f, ice_braking), dtype=np.float64)
    post = posterior_of(vehicle)
    if post is None:
        return Predictive(mu, np.zeros_like(mu), "none", "no priors: the vehicle was built without a class")
    k = len(post.terms)
    rows = gradient_rows(vehicle, f, post.terms, ice_braking, extra=3)
    sc = post.scatter
    np.multiply(f.duration_s, sc.aux, out=rows[k])
    # the energy-proportional scatter and the meter's share, at the prediction
    np.maximum(np.broadcast_to(mu, (f.n,)), 0.0, out=rows[k + 1])
    rows[k + 1] *= math.hypot(sc.share, post.meter_share)
    rows[k + 2] = sc.trip  # the part that does not grow with the trip
    var = _variance(post, rows, k)
    extra = extrapolation_var(vehicle, post, f)
    if extra is not None:
        var += extra
    for part in spec_parts(vehicle, f, ice_braking):
        var = var + part ** 2
    if measurement_sd is not None:
        var = var + np.asarray(measurement_sd, dtype=np.float64) ** 2
    var = var.reshape(mu.shape) if var.size == mu.size else var
    shape = np.broadcast(mu, var).shape
    return Predictive(np.broadcast_to(mu, shape), np.sqrt(np.broadcast_to(var, shape)), post.label, post.source)


def total(vehicle: Vehicle, f: Features, groups: ArrayLike | None = None, *,
          ice_braking: str | None = None) -> Predictive:
    """The predictive distribution of the sum of all predictions of ``f`` (one
    element), or of each group's sum (``groups``: a label per prediction, e.g. its
    day; the result in the order of ``np.unique(groups)``). Within a group the scatter
    is shared at the posterior's day correlation rho; across groups it is independent;
    the parameters' and the meter's parts are common to all, and so is what a colder
    (warmer) day than the calibration's gains (one unknown slope for every leg: the
    legs' standard deviations add), so that a day's probability widens beyond the
    calibration's temperatures as each leg's interval does."""
    mu = np.asarray(mean(vehicle, f, ice_braking), dtype=np.float64)
    mu = np.broadcast_to(mu, (f.n,))
    if groups is None:
        codes, k = np.zeros(f.n, dtype=np.intp), 1
    else:
        _, codes = np.unique(np.asarray(groups), return_inverse=True)
        k = int(codes.max()) + 1 if codes.size else 0
    sums = np.bincount(codes, weights=mu, minlength=k)
    post = posterior_of(vehicle)
    if post is None:
        return Predictive(sums, np.zeros(k), "none", "no priors: the vehicle was built without a class")
    G = gradient_rows(vehicle, f, post.terms, ice_braking)
    Gs = np.stack([np.bincount(codes, weights=G[j], minlength=k) for j in range(G.shape[0])]) \
        if G.shape[0] else np.zeros((0, k))
    var = _variance(post, Gs, Gs.shape[0]) + (post.meter_share * sums) ** 2
    sc = post.scatter
    d = np.broadcast_to(np.asarray(f.duration_s, dtype=np.float64), (f.n,))
    m = np.maximum(mu, 0.0)
    own = np.bincount(codes, weights=sc.trip_variance(d, m), minlength=k)
    var = var + sc.sum_variance(np.bincount(codes, weights=d, minlength=k),
                                np.bincount(codes, weights=m, minlength=k), np.bincount(codes, minlength=k), own)
    extra = extrapolation_var(vehicle, post, f)
    if extra is not None:
        var = var + np.bincount(codes, weights=np.sqrt(np.broadcast_to(extra, (f.n,))), minlength=k) ** 2
    for part in spec_parts(vehicle, f, ice_braking):  # one CdA, one Cr for every leg
        var = var + np.bincount(codes, weights=np.broadcast_to(part, (f.n,)), minlength=k) ** 2
    return Predictive(sums, np.sqrt(var), post.label, post.source)
