"""The lowest state of charge along a source: the largest energy drawn, max_j E_j,
exactly, without a cumulative sum over every step of every prediction.

Computing max_j E_j per (vehicle, mass) by a plain cumulative sum costs O(steps). This
module gets the same maximum, exactly, at a fraction of that, from a source's compressed
step terms (:class:`~cevm.core.sweep.compressed.SourceSteps`):

1. Per block and prediction, exactly: the block's energy S_b and two upper bounds of
   E_j inside it, C_b + (positive part) and C_{b+1} - (regenerated part), where C_b is
   the energy drawn before block b. These need the sum of the positive Delta_i of the
   block's non-simplified steps for that vehicle and mass
   (:func:`cevm.core.sweep.wheel.positive_parts`).
2. Blocks whose upper bound cannot beat the best value known (0, E_n, the block ends)
   are skipped; the others are summed step by step. Typically one or two blocks per
   prediction are summed, near the end of the route or after a descent.

The result equals a plain per-step loop to floating-point rounding (tested). Several
sources are evaluated together (:class:`StepsBatch`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from cevm.core.sweep.compressed import SourceSteps
from cevm.core.sweep.wheel import group_ids, positive_parts

#: Work arrays are cut into chunks of about this many float64 elements (8 MB).
_CHUNK_ELEMENTS = 1 << 20
#: Step-by-step sums of the blocks that may hold the maximum are done in chunks of this
#: many elements (64 kB arrays, which stay in the processor's cache: 4x larger chunks
#: were 10 % slower on the benchmark).
_SCAN_CHUNK_ELEMENTS = 1 << 13


@dataclass(frozen=True, eq=False)
class StepsBatch:
    """The :class:`SourceSteps` of R sources side by side: K blocks in all (``kstart``
    (R+1) the first block of each source, ``source_of_block`` (K,)), block sums and the
    (4, K, L) block matrix; the non-simplified elements with their global block."""

    kstart: np.ndarray
    source_of_block: np.ndarray
    fp_x: np.ndarray
    fp_a: np.ndarray
    fp_r: np.ndarray
    ns_x: np.ndarray
    ns_a: np.ndarray
    ns_r: np.ndarray
    t_s: np.ndarray
    blocks: np.ndarray
    el_x: np.ndarray
    el_a: np.ndarray
    el_r: np.ndarray
    el_block: np.ndarray
    el_bs: np.ndarray

    @classmethod
    def of(cls, steps: Sequence[SourceSteps]) -> StepsBatch:
        ks = np.array([st.n_blocks for st in steps])
        kstart = np.concatenate([[0], np.cumsum(ks)])
        lmax = max(st.blocks.shape[2] for st in steps)
        if all(st.blocks.shape[2] == lmax for st in steps):
            blocks = np.concatenate([st.blocks for st in steps], axis=1)
        else:
            blocks = np.zeros((4, int(kstart[-1]), lmax))
            for st, k0 in zip(steps, kstart[:-1], strict=True):
                blocks[:, k0 : k0 + st.n_blocks, : st.blocks.shape[2]] = st.blocks
        nel = np.array([st.nsel.size for st in steps])
        offs = np.concatenate([[0], np.cumsum(nel)[:-1]])
        el_bs = np.concatenate([[0]] + [st.nsel_block_start[1:] + off for st, off in zip(steps, offs, strict=True)])

        def cat(name):
            return np.concatenate([getattr(st, name) for st in steps])

        return cls(
            kstart=kstart,
            source_of_block=np.repeat(np.arange(len(steps)), ks),
            fp_x=cat("fp_x"), fp_a=cat("fp_a"), fp_r=cat("fp_r"),
            ns_x=cat("ns_x"), ns_a=cat("ns_a"), ns_r=cat("ns_r"), t_s=cat("t_s"),
            blocks=blocks,
            el_x=np.concatenate([st.x[st.nsel] for st in steps]),
            el_a=np.concatenate([st.a[st.nsel] for st in steps]),
            el_r=np.concatenate([st.r[st.nsel] for st in steps]),
            el_block=np.concatenate([st.nsel_block + k0 for st, k0 in zip(steps, kstart[:-1], strict=True)]),
            el_bs=el_bs,
        )

    @property
    def n_blocks(self) -> int:
        return int(self.kstart[-1])


def _peak_batch(bt: StepsBatch, m, cda, cr, eta, w, aux, group, end) -> tuple[np.ndarray, np.ndarray]:
    """``(wheel, peak)``, both (P, R): the wheel energy E_DC [J] (the CE model's, summed
    block by block: one positive-part pass serves the total and the peak) and
    :func:`peak_energy_j` of P predictions on each of the batch's R sources. ``end``
    (P, R) or None: a known E_n to include in the peak."""
    k = bt.n_blocks
    n_src = bt.kstart.size - 1
    n_groups = int(group.max()) + 1
    cr_g = np.empty(n_groups)
    cr_g[group] = cr
    mm = m[:, None]
    cc = cda[:, None]
    # (P, K) arithmetic in place, in a few buffers: fresh arrays of this size cost page
    # faults (glibc returns freed memory to the system), as much as the arithmetic
    pos = positive_parts(bt.el_x, bt.el_a, bt.el_r, bt.el_block, bt.el_bs, k, m, cda, cr, group, n_groups)
    tmp = np.empty_like(pos)
    # wheel energy of the merged (always positive) elements, and of the others' negatives
    up = (bt.fp_x + cr_g[:, None] * bt.fp_r)[group]
    up *= mm
    up += np.multiply(cc, bt.fp_a, out=tmp)
    neg = (bt.ns_x + cr_g[:, None] * bt.ns_r)[group]
    neg *= mm
    neg += np.multiply(cc, bt.ns_a, out=tmp)
    neg -= pos  # sum of the non-positive Delta_i of each block (<= 0)
    up += pos  # positive wheel energy of each block
    np.multiply(w[:, None], neg, out=tmp)
    tmp += up
    wheel = np.add.reduceat(tmp, bt.kstart[:-1], axis=1)
    up *= (1.0 / eta)[:, None]
    any_aux = bool(np.any(aux != 0))
    # auxiliary power per prediction (P,) or per prediction and source (P, R)
    aux_b = aux[:, bt.source_of_block] if aux.ndim == 2 else aux[:, None]
    if any_aux:
        up += np.multiply(aux_b, bt.t_s, out=tmp)  # >= sum of the positive g_i of the block
    regen = neg
    regen *= (w / eta)[:, None]  # <= sum of the negative g_i of the block (<= 0)
    s = np.add(up, regen, out=pos)  # battery energy of each block
    c_end = np.cumsum(s, axis=1)
    for j in range(n_src - 1, 0, -1):  # restart the sum at each source (last first: the
        lo, hi = bt.kstart[j], bt.kstart[j + 1]  # column before it is still the running sum)
        c_end[:, lo:hi] -= c_end[:, lo - 1 : lo]
    c_start = np.subtract(c_end, s, out=tmp)
    best = np.maximum.reduceat(c_end, bt.kstart[:-1], axis=1)
    np.maximum(best, 0.0, out=best)
    if end is not None:
        np.maximum(best, end, out=best)
    # bounds of E_j inside each block: min(C_b + up, C_{b+1} - regen)
    ub = np.minimum(np.add(c_start, up, out=up), np.subtract(c_end, regen, out=regen), out=up)
    # scan more, never less, where rounding blurs a bound (1e-9 of the energy, or 1 mJ)
    lim = best - (1e-9 * np.abs(best) + 1e-3)
    cand = np.empty(ub.shape, dtype=bool)
    for j in range(n_src):
        lo, hi = bt.kstart[j], bt.kstart[j + 1]
        np.greater(ub[:, lo:hi], lim[:, j : j + 1], out=cand[:, lo:hi])
    pi, bi = np.nonzero(cand)
    if pi.size:
        flat = best.reshape(-1)
        lmax = bt.blocks.shape[2]
        step = max(1, _SCAN_CHUNK_ELEMENTS // lmax)
        # g_i = W(Delta_i) / eta + P_aux dt_i with Delta_i / eta = (m / eta) x_i +
        # (m Cr / eta) r_i + (CdA / eta) a_i, and W(D) = D + (w - 1) min(D, 0): merged
        # elements have Delta > 0, so only single non-simplified steps are weighted
        k_x, k_r, k_a, k_w = m / eta, m * cr / eta, cda / eta, w - 1.0
        for lo in range(0, pi.size, step):
            pp = pi[lo : lo + step]
            bb = bi[lo : lo + step]
            x, r, a, dt = bt.blocks[:, bb]
            g = k_x[pp][:, None] * x
            g += k_r[pp][:, None] * r
            g += k_a[pp][:, None] * a
            neg = np.minimum(g, 0.0)
            neg *= k_w[pp][:, None]
            g += neg
            if any_aux:
                dt *= (aux[pp, bt.source_of_block[bb]] if aux.ndim == 2 else aux[pp])[:, None]
                g += dt
            np.cumsum(g, axis=1, out=g)
            np.maximum.at(flat, pp * n_src + bt.source_of_block[bb], g.max(axis=1) + c_start[pp, bb])
    return wheel, best


def peak_energy_j(
    steps: SourceSteps,
    mass_kg,
    cda_m2,
    cr,
    eta,
    negative_weight,
    aux_power_w=0.0,
    *,
    group=None,
    end_energy_j=None,
) -> np.ndarray:
    """Largest cumulative energy drawn along the source, max(0, max_j E_j) [J].

    E_j = sum_{i<=j} (W_i(Delta_i) / eta + P_aux dt_i), with W = 1 for Delta > 0 and
    ``negative_weight`` otherwise on non-simplified steps (eta^2 for an EV: then E_j is
    the battery energy and SoC_min = SoC_start - 100 peak / E_batt).

    The parameters: arrays of P predictions, broadcast together.

    Parameters
    ----------
    steps
        the source's :class:`SourceSteps`
    mass_kg
        gross mass [kg]; cda_m2 [m^2]; cr [-] (>= steps.cr0); eta (0, 1]
    negative_weight
        w in [0, 1]; aux_power_w : auxiliary power [W], >= 0 (default 0)
    group
        optional (P,) ints; predictions with the same group must share CdA and Cr
        (e.g. the vehicle index). Default: grouped by (CdA, Cr).
    end_energy_j
        optional (P,) E_n from the CE model, used as a known lower bound of the
        maximum (and included in it, so SoC_min <= SoC_end holds exactly).
    """
    m = np.asarray(mass_kg, dtype=np.float64).ravel()
    cda, crs, et, w, aux = (np.broadcast_to(np.asarray(v, dtype=np.float64), m.shape).ravel()
                            for v in (cda_m2, cr, eta, negative_weight, aux_power_w))
    if m.size == 0:
        return np.zeros(0)
    if np.any(crs < steps.cr0):
        raise ValueError(f"rolling coefficient below the source's Cr0 {steps.cr0:g}")
    end = None
    if end_energy_j is not None:
        end = np.broadcast_to(np.asarray(end_energy_j, np.float64), m.shape)[:, None]
    return peak_many(StepsBatch.of([steps]), m, cda, crs, et, w, aux, group, end)[1][:, 0]


def peak_many(bt: StepsBatch, m, cda, cr, eta, w, aux, group, end) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_peak_batch` in chunks of predictions (bounded work arrays): ``(wheel,
    peak)``, (P, R) each."""
    step = max(1, _CHUNK_ELEMENTS // (4 * bt.n_blocks))
    grp = None if group is None else np.asarray(group).ravel()
    if m.size <= step:
        return _peak_batch(bt, m, cda, cr, eta, w, aux, group_ids(cda, cr, grp), end)
    wheel = np.empty((m.size, bt.kstart.size - 1))
    peak = np.empty_like(wheel)
    for lo in range(0, m.size, step):
        sl = slice(lo, lo + step)
        wheel[sl], peak[sl] = _peak_batch(bt, m[sl], cda[sl], cr[sl], eta[sl], w[sl], aux[sl],
                                          group_ids(cda[sl], cr[sl], None if grp is None else grp[sl]),
                                          None if end is None else end[sl])
    return wheel, peak

