"""A source's step terms compressed for the lowest state of charge (:class:`SourceSteps`).

SoC_j = SoC_start - 100 E_j / E_batt [%], with E_j the battery energy drawn from the
start to sample j. Over a step, the battery gives g_i = W(Delta_i) / eta + P_aux dt_i
with W(D) = D if D > 0 else eta^2 D (eq. 27-31); E_j = sum_{i<=j} g_i; the final E_n is
the CE model's total. The lowest SoC is SoC_start - 100 max(0, max_j E_j) / E_batt.

Per source, once (:func:`build_steps`): the per-step terms x = k + e, a, r, dt of every
leg, in time order (the source's :class:`~cevm.core.sweep.steptable.StepTable`). Steps that draw energy for every
admissible vehicle (simplified steps, eq. 8, and standstill on flat ground) have
g_i >= 0, so a run of them never holds a maximum inside: each maximal run is merged into
one element (exact). The other steps stay single elements. Elements are cut into blocks
of about :data:`BLOCK_ELEMENTS`, whose sums bound E_j inside them
(:mod:`cevm.core.sweep.peak` uses the bounds to sum only the blocks that may hold the
maximum).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from cevm.core.cycle import CR0_DEFAULT, PAPER_PHYSICS, Physics
from cevm.core.sweep.steptable import LegProfile, StepTable, build_step_table

#: Target number of elements (merged steps) per block of :class:`SourceSteps`. Smaller
#: blocks prune more precisely but cost one more bound per block and prediction; 48 and
#: 64 were the fastest on the benchmark's routes (benchmarks/bench_sweep.py), 32 about
#: 10 % slower, 128 about 15 %.
BLOCK_ELEMENTS = 48


@dataclass(frozen=True, eq=False)
class SourceSteps:
    """A source's time-ordered step terms, compressed for the lowest state of charge.

    Elements (``n_elements``): ``x`` = sum of k + e [J/kg], ``a`` [J/m^2], ``r`` [J/kg
    per unit Cr], ``dt`` [s]; ``ns`` marks a single non-simplified step (its sign
    depends on the vehicle), else the element is a merged run of steps that draw energy
    for every vehicle with Cr >= cr0. ``block_start`` (K+1) cuts elements into K blocks;
    ``blocks`` (4, K, L) holds each block's x, r, a and dt padded with zeros to the
    longest block, L. Per block (K,): ``fp_x, fp_a, fp_r`` sums over merged
    elements, ``ns_x, ns_a, ns_r`` over non-simplified ones, ``t_s`` the duration.
    ``nsel`` the indices of the non-simplified elements, ``nsel_block`` their block,
    ``nsel_block_start`` (K+1) where each block starts among them.
    """

    x: np.ndarray
    a: np.ndarray
    r: np.ndarray
    dt: np.ndarray
    ns: np.ndarray
    n_steps: int
    block_start: np.ndarray
    blocks: np.ndarray
    fp_x: np.ndarray
    fp_a: np.ndarray
    fp_r: np.ndarray
    ns_x: np.ndarray
    ns_a: np.ndarray
    ns_r: np.ndarray
    t_s: np.ndarray
    nsel: np.ndarray
    nsel_block: np.ndarray
    nsel_block_start: np.ndarray
    cr0: float

    @property
    def n_elements(self) -> int:
        return int(self.x.size)

    @property
    def n_blocks(self) -> int:
        return int(self.block_start.size - 1)


def _block_sums(values: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    """Sums of ``values`` between consecutive ``bounds`` (empty blocks give 0)."""
    cum = np.concatenate([[0.0], np.cumsum(values)])
    return cum[bounds[1:]] - cum[bounds[:-1]]


def build_steps(
    legs: Sequence[LegProfile],
    *,
    cr0: float = CR0_DEFAULT,
    physics: Physics = PAPER_PHYSICS,
    block_elements: int = BLOCK_ELEMENTS,
) -> SourceSteps:
    """Compress the legs' step terms for :func:`peak_energy_j` (see the module notes).

    Parameters
    ----------
    legs : the source's legs in driving order
    cr0 : Cr0 of criterion (8) [-]; use the source vector's, default 0.004
    physics : air density and gravity (the paper's by default)
    block_elements : target elements per block, default :data:`BLOCK_ELEMENTS`
    """
    return steps_of_table(build_step_table(legs, cr0=cr0, physics=physics), cr0=cr0, block_elements=block_elements)


def steps_of_table(st: StepTable, *, cr0: float = CR0_DEFAULT, block_elements: int = BLOCK_ELEMENTS) -> SourceSteps:
    """:func:`build_steps` from a source's :class:`~cevm.core.sweep.steptable.StepTable`
    (its step terms, computed once for the source)."""
    x, a, r, dt = st.x, st.a, st.r, st.dt
    n = x.size
    simplified = (x + cr0 * r) > 0
    moving = a > 0
    # Steps with g >= 0 for every vehicle with Cr >= cr0 and aux >= 0: simplified steps
    # (Delta > 0) and standstill on flat ground (Delta = 0, only auxiliary power).
    fp = simplified | (~moving & (x == 0.0))
    start = np.ones(n, dtype=bool)
    if n > 1:
        start[1:] = ~(fp[1:] & fp[:-1])
    starts = np.flatnonzero(start)
    if n:
        ex, ea, er, edt = (np.add.reduceat(v, starts) for v in (x, a, r, dt))
        ens = ~fp[starts]
    else:
        ex = ea = er = edt = np.zeros(0)
        ens = np.zeros(0, dtype=bool)
    nc = int(starts.size)
    k = max(1, int(round(nc / max(1, block_elements))))
    bounds = (np.arange(k + 1, dtype=np.int64) * nc) // k
    lens = np.diff(bounds)
    lmax = max(1, int(lens.max()))
    fpm = ~ens
    nsel = np.flatnonzero(ens)
    idx = bounds[:-1, None] + np.arange(lmax)[None, :]
    inside = np.arange(lmax)[None, :] < lens[:, None]
    idx = np.where(inside, idx, 0)
    blocks = np.stack([np.where(inside, v[idx], 0.0) if nc else np.zeros((k, lmax))
                       for v in (ex, er, ea, edt)])
    return SourceSteps(
        x=ex,
        a=ea,
        r=er,
        dt=edt,
        ns=ens,
        n_steps=int(n),
        block_start=bounds,
        blocks=blocks,
        fp_x=_block_sums(np.where(fpm, ex, 0.0), bounds),
        fp_a=_block_sums(np.where(fpm, ea, 0.0), bounds),
        fp_r=_block_sums(np.where(fpm, er, 0.0), bounds),
        ns_x=_block_sums(np.where(ens, ex, 0.0), bounds),
        ns_a=_block_sums(np.where(ens, ea, 0.0), bounds),
        ns_r=_block_sums(np.where(ens, er, 0.0), bounds),
        t_s=_block_sums(edt, bounds),
        nsel=nsel,
        nsel_block=np.searchsorted(bounds, nsel, side="right") - 1,
        nsel_block_start=np.searchsorted(nsel, bounds),
        cr0=float(cr0),
    )

