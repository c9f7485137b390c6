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

Draws are reproducible and do not depend on how the work is split: each duty draws from
its own generator, seeded from the run's seed, the vehicle id and the duty's start
(:func:`duty_generator`), so a duty's probability is the same in a serial run, on any
number of workers, and whichever other duties or vehicles are replayed with it (when
duties are independent).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np

from cevm.core.replay.chain import Lanes, Stops, run_chains
from cevm.core.replay.spread import TripSpread

#: Default number of draws: a probability of 0.5 to +-0.011 (one standard error), 0.95 to
#: +-0.005; cost grows linearly (benchmarks/bench_replay.py).
DEFAULT_DRAWS = 2000
#: Default seed of the run's draws.
DEFAULT_SEED = 23
#: Draws evaluated together (bounds the work arrays: slots x lanes x this many floats).
DRAW_CHUNK_CELLS = 1 << 19


def duty_generator(seed: int, key: str, start_s: float) -> np.random.Generator:
    """The generator of one duty's draws: from the run's ``seed``, the vehicle ``key`` and
    the duty's start [s since the epoch]."""
    digest = hashlib.blake2b(f"{key}\x00{float(start_s)!r}".encode(), digest_size=16).digest()
    words = np.frombuffer(digest, dtype=np.uint32)
    return np.random.default_rng([int(seed) & 0xFFFFFFFF, *words.tolist()])


@dataclass(frozen=True, eq=False)
class DrawPlan:
    """What the draws of one vehicle's duties need: per trip (n,) ``mean`` and ``excess``
    [J or l], ``spread`` (:class:`TripSpread`), ``stops``; duties ``bounds`` (D+1);
    ``chained`` whether the level carries across duties (else each duty starts at
    ``start``); ``capacity``, ``start``, ``reserve`` levels [J or l]; ``efficiency`` of
    charging; ``key`` (vehicle id) and ``duty_start_s`` (D,) for the generators."""

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


def _draw_energies(plan: DrawPlan, gens: list[np.random.Generator], common: np.random.Generator | None,
                   count: int) -> np.ndarray:
    """(n, count) trip energies drawn (module notes of :mod:`cevm.core.replay.spread`)."""
    sp = plan.spread
    k = sp.k
    bounds = plan.bounds
    n = plan.mean.size
    cp = sp.coef_part
    rho = sp.day_corr
    out = np.empty((n, count))
    shared = None
    if common is not None:  # chained: coefficients, meter and extrapolation once per vehicle
        shared = common.standard_normal((count, k + 2))
    for d, g in enumerate(gens):
        lo, hi = int(bounds[d]), int(bounds[d + 1])
        m = hi - lo
        z = g.standard_normal((count, k + 4 + 2 * m))
        zc = shared if shared is not None else z[:, :k + 2]
        z_par, z_meter, z_extra = zc[:, :k], zc[:, k], zc[:, k + 1]
        z_day_a, z_day_s = z[:, k + 2], z[:, k + 3]
        z_own = z[:, k + 4:].reshape(count, 2, m)
        mu = plan.mean[lo:hi, None]
        e = mu + cp[lo:hi] @ z_par.T if k else np.broadcast_to(mu, (m, count)).copy()
        e += sp.meter_share * mu * z_meter[None, :]
        a, s = sp.aux_sd[lo:hi, None], sp.share_sd[lo:hi, None]
        e += np.sqrt(rho) * (a * z_day_a[None, :] + s * z_day_s[None, :])
        e += np.sqrt(1.0 - rho) * (a * z_own[:, 0, :].T + s * z_own[:, 1, :].T)
        e += sp.extra_sd[lo:hi, None] * z_extra[None, :]
        out[lo:hi] = e
    return out


def p_complete(plan: DrawPlan, draws: int = DEFAULT_DRAWS, seed: int = DEFAULT_SEED) -> np.ndarray:
    """Each duty's probability of keeping its reserve (D,), from ``draws`` draws (module
    notes)."""
    bounds = plan.bounds
    d_count = bounds.size - 1
    n = plan.mean.size
    if d_count == 0:
        return np.zeros(0)
    gens = [duty_generator(seed, plan.key, s) for s in plan.duty_start_s]
    common = duty_generator(seed, plan.key + "\x00vehicle", float(plan.duty_start_s[0])) if plan.chained else None
    lanes = Lanes.of([0], [n]) if plan.chained else Lanes.of(bounds[:-1], bounds[1:])
    t_count, l_count = lanes.shape
    chunk = max(1, DRAW_CHUNK_CELLS // max(1, t_count * l_count))
    ok = np.zeros(d_count)
    first = bounds[:-1]
    done = 0
    while done < draws:
        count = min(chunk, draws - done)
        e = _draw_energies(plan, gens, common, count)
        run = run_chains(lanes, e, plan.excess[:, None], plan.stops, capacity=plan.capacity, start=plan.start,
                         efficiency=plan.efficiency)
        low = lanes.put(run.low, n)  # (n, count)
        ok += np.count_nonzero(np.minimum.reduceat(low, first, axis=0) >= plan.reserve, axis=1)
        done += count
    return ok / draws


def standard_error(p, draws: int) -> np.ndarray:
    """The Monte Carlo standard error of shares ``p`` of ``draws`` draws."""
    p = np.asarray(p, dtype=np.float64)
    return np.sqrt(p * (1.0 - p) / draws)
