"""The probability that a duty completes with its reserve kept, by Monte Carlo (pure).

Charging stops capped at full make the lowest level of a duty a non-linear function of
its trips' energies, so its probability is not the Gaussian's of a sum: the duty is
run again with N draws of its trips' energies (:mod:`cevm.core.replay.spread`: the
coefficients' and the meter's parts drawn once per duty (once per vehicle when the level
carries across duties), the scatter's shared part once per duty and its own part once per
trip), all draws at once along a last axis (:func:`cevm.core.replay.chain.run_chains`).
p_complete is the share of draws whose lowest level stays at or above the reserve; its
Monte Carlo standard error is sqrt(p (1 - p) / N) (a share of 0 or 1 out of N draws
holds the truth below 3 / N, or above 1 - 3 / N, at 95 %: the rule of three).

Draws are reproducible and do not depend on how the work is split: each vehicle draws
from its own generator, seeded from the run's seed and the vehicle id
(:func:`vehicle_generator`), so its duties' probabilities are the same in a serial run, on
any number of workers, and whichever other vehicles are replayed with it.
"""

from __future__ import annotations

import dataclasses
import hashlib
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from cevm.core.replay.chain import Lanes, Stops, duty_minima, stop_potential
from cevm.core.replay.spread import TripSpread

#: Default number of draws: a probability of 0.5 to +-0.011 (one standard error), 0.95 to
#: +-0.005; cost grows linearly (benchmarks/bench_replay.py).
DEFAULT_DRAWS = 2000
#: Default seed of the run's draws.
DEFAULT_SEED = 23
#: Draws evaluated together (bounds the work arrays: slots x lanes x this many floats).
DRAW_CHUNK_CELLS = 1 << 19


def vehicle_generator(seed: int, key: str) -> np.random.Generator:
    """The generator of one vehicle's draws: from the run's ``seed`` and the vehicle id
    ``key``."""
    digest = hashlib.blake2b(key.encode(), digest_size=16).digest()
    words = np.frombuffer(digest, dtype=np.uint32)
    return np.random.default_rng([int(seed) & 0xFFFFFFFF, *words.tolist()])


@dataclass(frozen=True, eq=False)
class DrawPlan:
    """What the draws of one vehicle's duties need: per trip (n,) ``mean`` and ``excess``
    [J or l], ``spread`` (:class:`TripSpread`), ``stops``; duties ``bounds`` (D+1);
    ``chained`` whether the level carries across duties (else each duty starts at
    ``start``); ``capacity``, ``start``, ``reserve`` levels [J or l]; ``efficiency`` of
    charging; ``key`` (the vehicle id: its generator) and ``duty_start_s`` (D,)."""

    mean: np.ndarray
    excess: np.ndarray
    spread: TripSpread
    stops: Stops
    bounds: np.ndarray
    chained: bool
    capacity: float
    start: float
    reserve: float
    efficiency: float
    key: str
    duty_start_s: np.ndarray


#: A duty whose reserve holds by more than this many standard deviations of its energy
#: even without any charge is given p = 1 without drawing: its chance to fail is below
#: 1e-9 (:func:`sure_duties`).
SURE_SD = 6.0


def sure_duties(plan: DrawPlan) -> np.ndarray:
    """The duties (D,) that keep their reserve with a probability above 1 - 1e-9 whatever
    the draws of their charges: with every trip's mean at least :data:`SURE_SD` standard
    deviations above 0 (so that no trip gives energy back), the level never falls below
    start - (sum of the trips' energies) - (largest excess), a Gaussian with the duty's
    total's standard deviation (:meth:`~cevm.core.replay.spread.TripSpread.duty_sd`), and it
    keeps the reserve by :data:`SURE_SD` of them."""
    bounds = plan.bounds
    first = bounds[:-1]
    if first.size == 0:
        return np.zeros(0, dtype=bool)
    sp = plan.spread
    positive = np.minimum.reduceat(plan.mean - SURE_SD * sp.trip_sd(plan.mean), first) > 0
    total = np.add.reduceat(plan.mean, first) + np.maximum.reduceat(plan.excess, first)
    if plan.chained:  # a duty's start depends on the ones before: only the first is known
        positive[1:] = False
    return positive & (plan.start - total - plan.reserve >= SURE_SD * sp.duty_sd(plan.mean, bounds))


def _draw_energies(plan: DrawPlan, z_duty: np.ndarray, z_trip: np.ndarray) -> np.ndarray:
    """(n, count) trip energies from standard normals: ``z_duty`` (groups x (k + 2) + 2 D,
    count), per duty (per vehicle when chained: one group) the coefficients', the meter's
    and the extrapolation's, then per duty the scatter's two shared parts; ``z_trip`` (n,
    count) the trips' own scatter (its two parts are independent: one normal of their
    combined variance, with the trip's own spread beyond the model's). Module notes of
    :mod:`cevm.core.replay.spread`."""
    sp = plan.spread
    k = sp.k
    sizes = np.diff(plan.bounds)
    d_count = sizes.size
    n = plan.mean.size
    groups = 1 if plan.chained else d_count
    common = z_duty[:groups * (k + 2)].reshape(groups, k + 2, -1)
    day = z_duty[groups * (k + 2):].reshape(d_count, 2, -1)

    def per_trip(z: np.ndarray, by_duty: bool = True) -> np.ndarray:  # (groups or D, count) -> (n, count)
        return np.broadcast_to(z, (n, z.shape[1])) if (plan.chained and not by_duty) else np.repeat(z, sizes, axis=0)

    mu = plan.mean[:, None]
    cp = sp.coef_part
    e = mu + sp.meter_share * mu * per_trip(common[:, k], False) + sp.extra_sd[:, None] * per_trip(common[:, k + 1],
                                                                                                  False)
    for j in range(k):
        e += cp[:, j:j + 1] * per_trip(common[:, j], False)
    rho = sp.day_corr
    e += np.sqrt(rho) * (sp.aux_sd[:, None] * per_trip(day[:, 0]) + sp.share_sd[:, None] * per_trip(day[:, 1]))
    e += np.sqrt((1.0 - rho) * (sp.aux_sd ** 2 + sp.share_sd ** 2) + sp.own ** 2)[:, None] * z_trip
    return np.asarray(e, dtype=np.float64)


def _weights(plan: DrawPlan) -> tuple[np.ndarray, np.ndarray]:
    """Per trip, the weights of its duty's k + 4 shared normals (the coefficients', the
    meter's, the extrapolation's, the scatter's two shared parts) and of its own one
    (the scatter's own part and the trip's spread beyond the model's, independent)."""
    sp = plan.spread
    rho = sp.day_corr
    w = np.column_stack([sp.coef_part, sp.meter_share * plan.mean, sp.extra_sd, np.sqrt(rho) * sp.aux_sd,
                         np.sqrt(rho) * sp.share_sd])
    return w, np.sqrt((1.0 - rho) * (sp.aux_sd ** 2 + sp.share_sd ** 2) + sp.own ** 2)


def _independent_ok(plan: DrawPlan, gen: np.random.Generator, draws: int) -> np.ndarray:
    """Draws keeping the reserve, per duty (D,), duties starting at the same level: one
    lane per duty, each slot's energies drawn as the slot comes (no per-trip array of
    draws), chunks of draws of :data:`DRAW_CHUNK_CELLS`."""
    bounds = plan.bounds
    d_count = bounds.size - 1
    lanes = Lanes.of(bounds[:-1], bounds[1:])
    t_count = lanes.shape[0]
    w, own = _weights(plan)
    cols = w.shape[1]
    w_s, own_s = lanes.take(w), lanes.take(own)
    mu_s, x_s = lanes.take(plan.mean), lanes.take(plan.excess)
    pot_s = lanes.take(stop_potential(plan.stops.power_w, plan.stops.dwell_s, plan.efficiency))
    charges = [bool(np.any(pot_s[t] > 0)) for t in range(t_count)]
    trip_of = np.maximum(lanes.index, 0)
    n = plan.mean.size
    chunk = max(1, DRAW_CHUNK_CELLS // max(1, d_count * (cols + t_count)))
    ok = np.zeros(d_count)
    cap = plan.capacity
    done = 0
    while done < draws:
        count = min(chunk, draws - done)
        z = np.ascontiguousarray(gen.standard_normal((count, d_count * cols + n)).T)  # a draw: one row of the stream
        shared = z[:d_count * cols].reshape(d_count, cols, count)
        z_own = z[d_count * cols:]
        level = np.full((d_count, count), plan.start)
        lowest = np.full((d_count, count), np.inf)
        for t in range(t_count):
            e = np.einsum("lj,ljc->lc", w_s[t], shared)
            e += mu_s[t][:, None]
            e += own_s[t][:, None] * z_own[trip_of[t]]
            np.minimum(lowest, level - e - x_s[t][:, None], out=lowest)
            level -= e
            np.minimum(level, cap, out=level)
            if charges[t]:
                level += np.minimum(pot_s[t][:, None], cap - level)
        ok += np.count_nonzero(lowest >= plan.reserve, axis=1)
        done += count
    return ok


def _chained_ok(plan: DrawPlan, gen: np.random.Generator, draws: int) -> np.ndarray:
    """Draws keeping the reserve, per duty (D,), the level carried across duties: the
    vehicle's trips in one lane, the energies of a chunk of draws drawn first."""
    bounds = plan.bounds
    d_count = bounds.size - 1
    n = plan.mean.size
    k = plan.spread.k
    n_duty_cols = (k + 2) + 2 * d_count
    lanes = Lanes.of([0], [n])
    duty = np.repeat(np.arange(d_count), np.diff(bounds))
    last = np.zeros(n, dtype=bool)
    last[bounds[1:] - 1] = True
    slot_duty, slot_last = lanes.take(duty, fill=0), lanes.take(last, fill=False)
    chunk = max(1, DRAW_CHUNK_CELLS // max(1, n, n_duty_cols + n))
    ok = np.zeros(d_count)
    done = 0
    while done < draws:
        count = min(chunk, draws - done)
        z = np.ascontiguousarray(gen.standard_normal((count, n_duty_cols + n)).T)  # a draw: one row of the stream
        e = _draw_energies(plan, z[:n_duty_cols], z[n_duty_cols:])
        low = duty_minima(lanes, slot_duty, slot_last, d_count, e, plan.excess[:, None], plan.stops,
                          capacity=plan.capacity, start=plan.start, efficiency=plan.efficiency)
        ok += np.count_nonzero(low >= plan.reserve, axis=1)
        done += count
    return ok


def _duties_of(plan: DrawPlan, keep: np.ndarray) -> DrawPlan:
    """The plan of the duties ``keep`` only (their trips, their stops)."""
    bounds = plan.bounds
    trips = np.concatenate([np.arange(bounds[d], bounds[d + 1]) for d in np.flatnonzero(keep)])
    sizes = np.diff(bounds)[keep]
    st = plan.stops
    stops = Stops(st.dwell_s[trips], st.power_w[trips], st.sizable[trips], st.duty_end[trips])
    return dataclasses.replace(plan, mean=plan.mean[trips], excess=plan.excess[trips], spread=plan.spread.take(trips),
                               stops=stops, bounds=np.concatenate([[0], np.cumsum(sizes)]),
                               duty_start_s=plan.duty_start_s[keep])


def p_complete(plan: DrawPlan, draws: int = DEFAULT_DRAWS, seed: int = DEFAULT_SEED) -> np.ndarray:
    """Each duty's probability of keeping its reserve (D,), from ``draws`` draws (module
    notes); 1 without drawing for the duties :func:`sure_duties` finds."""
    d_count = plan.bounds.size - 1
    if d_count == 0:
        return np.zeros(0)
    sure = sure_duties(plan)
    if sure.all():
        return np.ones(d_count)
    gen = vehicle_generator(seed, plan.key)
    if plan.chained:
        return np.where(sure, 1.0, _chained_ok(plan, gen, draws) / draws)
    out = np.ones(d_count)
    out[~sure] = _independent_ok(_duties_of(plan, ~sure), gen, draws) / draws
    return out


def standard_error(p: ArrayLike, draws: int) -> np.ndarray:
    """The Monte Carlo standard error of shares ``p`` of ``draws`` draws."""
    p = np.asarray(p, dtype=np.float64)
    return np.asarray(np.sqrt(p * (1.0 - p) / draws), dtype=np.float64)
