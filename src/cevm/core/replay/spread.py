"""How far a trip's energy may be from its mean, in parts that say which trips share
them (pure): the candidate's predictive distribution (:mod:`cevm.core.predictive`)
taken apart so that a duty's trips can be drawn together.

For trip i of a duty, with mean mu_i [J or l] (:mod:`cevm.core.replay.trip_energies`)::

    y_i = mu_i + g_i . (L z_par)              the model's coefficients: common to all trips
              + meter mu_i z_m                the calibration meter's systematic share: common
              + sqrt(rho) (a_i z_A + s_i z_S)  the scatter's share common to the duty's trips
              + sqrt(1 - rho) (a_i z_a,i + s_i z_s,i)   and the trip's own
              + x_i z_x                       the extrapolation beyond the calibration's
                                              temperatures: taken as common (the unknown
                                              slope is one for every trip)
              + o_i z_o,i                     a spread of the trip's own beyond the model
                                              (``own_sd``: a timetable's synthesised cycle,
                                              the spread between its draws), independent

z standard normal, g_i the gradient of the mean in the coefficients, L L^T their
covariance, a_i = s_aux D_i and s_i = s_share mu_i the scatter of the auxiliary power
over the trip's duration and of its energy, rho the within-day correlation of the
scatter (the ranges model: a duty is the "day"), x_i the extrapolation's standard
deviation. Each trip's variance is that of :func:`cevm.core.predictive.predictive`; a
duty's total has the variance of :func:`cevm.core.predictive.total` (plus the
extrapolation's, which that function leaves out, taken as fully correlated).

:func:`trip_spread` is the one place that reads that API; for a vehicle without priors
(built without a class) every part is zero and the source is "none": a duty then
completes with probability 0 or 1, as its mean says.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from cevm.core import distribution
from cevm.core import predictive as pr
from cevm.core.replay.trip_energies import TripEnergies
from cevm.core.vehicle import Vehicle


@dataclass(frozen=True, eq=False)
class TripSpread:
    """The parts of n trips' predictive spread (module notes), [J or l]: ``grad`` (n, k)
    and ``chol`` (k, k) (grad @ chol: the coefficients' part per standard normal),
    ``meter_share`` [-], ``aux_sd`` and ``share_sd`` (n,) the scatter's two parts,
    ``extra_sd`` (n,) the extrapolation's, ``day_corr`` rho; ``source`` "posterior",
    "prior" or "none" and ``note`` the sentence behind it."""

    grad: np.ndarray
    chol: np.ndarray
    meter_share: float
    aux_sd: np.ndarray
    share_sd: np.ndarray
    extra_sd: np.ndarray
    day_corr: float
    source: str = "none"
    note: str = ""
    own_sd: np.ndarray | None = None

    @property
    def own(self) -> np.ndarray:
        """(n,) a spread of each trip's own beyond the model's, independent from trip to
        trip [J or l] (a timetable's synthesised drive cycles: the spread between their
        draws); zeros for logged trips."""
        return self.own_sd if self.own_sd is not None else np.zeros(self.n)

    def with_own(self, own_sd: ArrayLike) -> TripSpread:
        """This spread with an independent per-trip term ``own_sd`` (n,) added."""
        own = np.broadcast_to(np.asarray(own_sd, dtype=np.float64), (self.n,)).copy()
        return dataclasses.replace(self, own_sd=own)

    @classmethod
    def none(cls, n: int, note: str = "") -> TripSpread:
        z = np.zeros(n)
        return cls(np.zeros((n, 0)), np.zeros((0, 0)), 0.0, z, z, z, 1.0, "none", note)

    @property
    def n(self) -> int:
        return int(self.aux_sd.size)

    @property
    def k(self) -> int:
        return int(self.chol.shape[1])

    @property
    def coef_part(self) -> np.ndarray:
        """(n, k): each trip's energy per standard normal of the coefficients."""
        return self.grad @ self.chol if self.k else np.zeros((self.n, 0))

    def take(self, rows: np.ndarray) -> TripSpread:
        """The spread of the trips ``rows``."""
        return TripSpread(self.grad[rows], self.chol, self.meter_share, self.aux_sd[rows], self.share_sd[rows],
                          self.extra_sd[rows], self.day_corr, self.source, self.note,
                          None if self.own_sd is None else self.own_sd[rows])

    def trip_sd(self, mean: ArrayLike) -> np.ndarray:
        """Each trip's standard deviation [J or l]."""
        cp = self.coef_part
        var = np.einsum("ij,ij->i", cp, cp) + (self.meter_share * np.asarray(mean)) ** 2
        var = var + self.aux_sd ** 2 + self.share_sd ** 2 + self.extra_sd ** 2 + self.own ** 2
        return np.asarray(np.sqrt(var), dtype=np.float64)

    def duty_sd(self, mean: ArrayLike, bounds: np.ndarray) -> np.ndarray:
        """The standard deviation of each duty's total (duties ``bounds`` over the trips):
        coefficients, meter and extrapolation common to its trips, the scatter shared at
        rho (module notes)."""
        first = bounds[:-1]
        if first.size == 0:
            return np.zeros(0)
        mu = np.asarray(mean, dtype=np.float64)
        cp = np.add.reduceat(self.coef_part, first, axis=0) if self.k else np.zeros((first.size, 0))
        var = np.einsum("ij,ij->i", cp, cp) + (self.meter_share * np.add.reduceat(mu, first)) ** 2
        rho = self.day_corr
        a, s = self.aux_sd, self.share_sd
        shared = np.add.reduceat(a, first) ** 2 + np.add.reduceat(s, first) ** 2
        own = np.add.reduceat(a * a + s * s, first)
        var = var + rho * shared + (1.0 - rho) * own + np.add.reduceat(self.extra_sd, first) ** 2
        var = var + np.add.reduceat(self.own ** 2, first)
        return np.asarray(np.sqrt(var), dtype=np.float64)


def energy_at_confidence(mean: ArrayLike, duty_sd: ArrayLike, bounds: np.ndarray, confidence: float) -> np.ndarray:
    """Each trip's energy [J or l] with its duty's total at the duty's one-sided
    ``confidence`` quantile (:mod:`cevm.core.distribution`, of the total's mean and
    ``duty_sd``), what that adds to the mean shared over the duty's trips in proportion to the energy each draws
    (``max(mean, 0)``; equally where none draws). Sizing a battery on these energies gives
    the one that runs the duty, with its reserve kept, when the duty takes that much: with
    a probability of at least ``confidence`` (the spread's placement within the duty aside).
    ``bounds``: the duties' first trips and the end (:attr:`Duties.bounds`)."""
    mu = np.asarray(mean, dtype=np.float64)
    sd = np.asarray(duty_sd, dtype=np.float64)
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence {confidence!r} must be in (0, 1)")
    counts = np.diff(bounds)
    if mu.size == 0 or counts.size == 0:
        return mu.copy()
    duty_of = np.repeat(np.arange(counts.size), counts)
    draws = np.maximum(mu, 0.0)
    total = np.bincount(duty_of, weights=draws, minlength=counts.size)
    share = np.where(total[duty_of] > 0.0, draws / np.where(total > 0.0, total, 1.0)[duty_of],
                     1.0 / np.maximum(counts, 1)[duty_of])
    duty_mean = np.bincount(duty_of, weights=mu, minlength=counts.size)
    add = distribution.quantile(duty_mean, sd, confidence) - duty_mean
    return np.asarray(mu + add[duty_of] * share, dtype=np.float64)


def central_interval(mean: ArrayLike, sd: ArrayLike, level: float) -> tuple[np.ndarray, np.ndarray]:
    """The central interval holding the consumption with probability ``level``
    (:mod:`cevm.core.distribution`)."""
    return distribution.interval(mean, sd, level)


def trip_spread(vehicle: Vehicle, trips: TripEnergies, *, ice_braking: str | None = None) -> TripSpread:
    """The spread of ``vehicle`` on the trips of ``trips`` (a
    :class:`~cevm.core.replay.trip_energies.TripEnergies`), from the predictive distribution of
    the commands' (:mod:`cevm.core.predictive`: the vehicle's posterior, else its class's
    prior); :meth:`TripSpread.none` where there is none (module notes)."""
    n = trips.n
    post = pr.posterior_of(vehicle)
    if post is None:
        return TripSpread.none(n, "no priors: the vehicle was built without a class")
    f = pr.Features(positive_j=trips.positive_j, negative_j=trips.negative_j, duration_s=trips.duration_s,
                    idle_s=trips.idle_s, traction_s=trips.traction_s, kinetic_j=trips.kinetic_j,
                    ambient_c=trips.ambient_c, starts=np.ones(n), spec=trips.spec)
    p = pr.predictive(vehicle, f, ice_braking=ice_braking)
    mu = np.maximum(np.asarray(p.mean, dtype=np.float64), 0.0)
    G = pr.gradient(vehicle, f, post.terms, ice_braking) if post.terms else np.zeros((n, 0))
    w, V = np.linalg.eigh(post.cov) if post.terms else (np.zeros(0), np.zeros((0, 0)))
    chol = V * np.sqrt(np.maximum(w, 0.0))
    sc = post.scatter
    # the scatter's part that does not grow with a trip joins its auxiliary part: exact
    # for a trip, a little wide for a duty's sum (a sum of square roots)
    aux, share = np.hypot(sc.aux * trips.duration_s, sc.trip), sc.share * mu
    base = TripSpread(G, chol, float(post.meter_share), aux, share, np.zeros(n), float(sc.day_corr), p.source,
                      p.note or post.source)
    rest = np.asarray(p.sd, dtype=np.float64) ** 2 - base.trip_sd(np.asarray(p.mean)) ** 2
    # what predictive adds beyond the others: the extrapolation's part and a spec sheet's CdA
    # and Cr, each common to every trip (one slope, one CdA): drawn together
    extra = np.sqrt(np.maximum(rest, 0.0))
    return TripSpread(G, chol, base.meter_share, aux, share, extra, base.day_corr, base.source, base.note)
