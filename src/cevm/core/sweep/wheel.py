"""Wheel energy by the CE model for any mix of vehicles and masses, in one pass.

:func:`ce_wheel_energy_j` is the formula of :func:`cevm.core.model.wheel_energy_j`
(eq. 22-30) with the positive non-simplified steps summed by :func:`positive_parts` for
any mix of rolling coefficients at once (the model groups predictions by Cr); the two
agree to rounding (tested). :func:`positive_parts` also gives the lowest state of charge
its per-block sums (:mod:`cevm.core.sweep.peak`).

The sum of the positive Delta_i of a set of non-simplified steps, per prediction: the
sign of each step is decided once for all masses of a vehicle where they agree (most
steps), and by one comparison per (vehicle, step) where they differ, then binned by the
first mass at which the step turns positive. No work per (prediction, step) pair.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from cevm.core.cycle import CycleVector


def _segment_sums(values: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    """Sums of ``values`` (..., N) over the last axis between consecutive ``bounds``
    (K+1, non-decreasing, from 0 to N): (..., K), empty segments 0."""
    k = bounds.size - 1
    out = np.zeros(values.shape[:-1] + (k,))
    nonempty = np.flatnonzero(bounds[1:] > bounds[:-1])
    if nonempty.size:
        out[..., nonempty] = np.add.reduceat(values, bounds[nonempty], axis=-1)
    return out


def positive_parts(xs, as_, rs, nsel_block, bs, k, m, cda, cr, group, n_groups) -> np.ndarray:
    """(P, K): sum of max(Delta_i, 0) = max(m (x_i + Cr r_i) + CdA a_i, 0) [J] over the
    elements i of each block (``nsel_block``: block of each element, in order;
    ``bs``: (K+1) where each block starts), exactly, for every prediction. Predictions of
    one ``group`` (ids 0..n_groups-1) share CdA and Cr."""
    p_count = m.size
    if xs.size == 0:
        return np.zeros((p_count, k))
    c = cda / m
    order = np.lexsort((c, group))  # by group, then c ascending
    counts = np.bincount(group, minlength=n_groups)
    gstart = np.concatenate([[0], np.cumsum(counts)[:-1]])
    gsorted = group[order]
    cda_g = np.empty(n_groups)
    cda_g[group] = cda
    cr_g = np.empty(n_groups)
    cr_g[group] = cr
    c_lo = c[order][gstart]  # smallest c = CdA / m of each group (its largest mass)
    c_hi = c[order][gstart + counts - 1]
    # Delta_i = m (x_i + Cr r_i + c a_i) with r_i, a_i >= 0: positive for every prediction
    # if positive at the smallest Cr and c, for none if not at the largest. Only the
    # elements in between are classified group by group.
    never = (xs + cr_g.max() * rs + c_hi.max() * as_) <= 0
    always = (xs + cr_g.min() * rs + c_lo.min() * as_) > 0
    # group-level sums (G, K) of y = x + Cr r and of a over the positive elements
    yp = np.zeros((n_groups, k))
    ap = np.zeros((n_groups, k))
    if always.any():
        sx, sr, sa = (_segment_sums(np.where(always, v, 0.0), bs) for v in (xs, rs, as_))
        yp += sx + cr_g[:, None] * sr
        ap += sa
    sel = np.flatnonzero(~(never | always))
    sy = None
    if sel.size:
        xs, as_, rs = xs[sel], as_[sel], rs[sel]
        nblock = nsel_block[sel]
        bsel = np.searchsorted(sel, bs)
        y = xs[None, :] + cr_g[:, None] * rs[None, :]  # (G, N) Delta / m without the CdA part
        # per group: positive for every mass if positive at c_lo, never if not at c_hi
        pos_all = (y + c_lo[:, None] * as_[None, :]) > 0
        neg_all = (y + c_hi[:, None] * as_[None, :]) <= 0
        yp += _segment_sums(np.where(pos_all, y, 0.0), bsel)
        ap += _segment_sums(np.where(pos_all, as_[None, :], 0.0), bsel)
        unc = ~(pos_all | neg_all)
        if unc.any():
            # Elements whose sign differs between a group's masses. With the group's
            # predictions sorted by c, element i is positive for those of rank >= j_i,
            # j_i = #{c_p <= thr_i}, thr_i = -y_i / a_i. Bin y_i and a_i by (group, j_i,
            # block) and sum over j: each prediction reads its (group, rank) row.
            gi, ni = np.nonzero(unc)
            yv = y[gi, ni]
            av = as_[ni]
            kk = int(counts.max()) + 1
            j = _count_not_positive(yv, av, gi, c[order], gsorted, gstart)
            idx = (gi * kk + j) * k + nblock[ni]
            sy = np.bincount(idx, weights=yv, minlength=n_groups * kk * k).reshape(n_groups, kk, k)
            sa = np.bincount(idx, weights=av, minlength=n_groups * kk * k).reshape(n_groups, kk, k)
            sy[:, 0] += yp
            sa[:, 0] += ap
            np.cumsum(sy, axis=1, out=sy)
            np.cumsum(sa, axis=1, out=sa)
    if sy is None:
        return m[:, None] * yp[group] + cda[:, None] * ap[group]
    row = np.empty(p_count, dtype=np.int64)
    row[order] = gsorted * kk + (np.arange(p_count) - gstart[gsorted])  # (group, rank) row
    out = np.take(sy.reshape(-1, k), row, axis=0)  # np.take: faster than fancy indexing
    out *= m[:, None]
    sa = np.take(sa.reshape(-1, k), row, axis=0)
    sa *= cda[:, None]
    out += sa
    return out


#: Largest (groups x predictions) table of prefix counts :func:`_count_not_positive` builds
#: (8 MB); past it, a binary search on complex keys (1.5x slower, no table).
_COUNT_TABLE_CELLS = 1 << 20


def _count_not_positive(yv, av, gi, c_sorted, gsorted, gstart) -> np.ndarray:
    """For each (group g_i, element) pair with a_i > 0: j_i = #{c_p of group g_i :
    y_i + c_p a_i <= 0} = #{c_p <= -y_i / a_i}, with ``c_sorted`` ascending within each
    group (``gsorted`` the group of each, ``gstart`` where each group starts).

    One binary search among all the c values and a table of prefix counts per group
    (``table[g, r]``: how many of the r smallest c are group g's), or, for a table larger
    than :data:`_COUNT_TABLE_CELLS`, one binary search on complex keys g + i c, which
    numpy orders by group and then by c."""
    thr = -yv / av
    n_groups, n = gstart.size, c_sorted.size
    if n_groups * (n + 1) > _COUNT_TABLE_CELLS:
        keys = gsorted + 1j * c_sorted
        return np.searchsorted(keys, gi + 1j * thr, side="right") - gstart[gi]
    order = np.argsort(c_sorted, kind="stable")
    table = np.zeros((n_groups, n + 1), dtype=np.int64)
    table[gsorted[order], np.arange(1, n + 1)] = 1
    np.cumsum(table, axis=1, out=table)
    return table[gi, np.searchsorted(c_sorted[order], thr, side="right")]


def ce_wheel_energy_j(vector: CycleVector, mass_kg, cda_m2, cr, negative_weight, *, group=None) -> np.ndarray:
    """Wheel energy E_DC over the cycle [J]: the CE model of :func:`cevm.core.model.wheel_energy_j`
    (eq. 22-30, same formula), with the positive non-simplified steps summed by
    :func:`positive_parts`: one pass for any mix of Cr values (the model groups by Cr).

    Parameters: arrays of P predictions (broadcast): mass_kg [kg] (> 0), cda_m2 [m^2],
    cr [-] (>= vector.cr0), negative_weight w; ``group`` as for :func:`peak_energy_j`
    (predictions of a group share CdA and Cr; default: grouped by (CdA, Cr)).
    """
    m = np.asarray(mass_kg, dtype=np.float64).ravel()
    cda, crs, w = (np.broadcast_to(np.asarray(v, dtype=np.float64), m.shape).ravel()
                   for v in (cda_m2, cr, negative_weight))
    if np.any(m <= 0):
        raise ValueError("mass_kg must be > 0")
    if np.any(crs < vector.cr0):
        raise ValueError(f"rolling coefficient below the vector's Cr0 {vector.cr0:g}")
    if m.size == 0:
        return np.zeros(0)
    return ce_wheel_batch_j([vector], m, cda, crs, w, group_ids(cda, crs, group))[:, 0]


def ce_wheel_batch_j(vectors: Sequence[CycleVector], m, cda, cr, w, group) -> np.ndarray:
    """(P, R) wheel energy [J] of P predictions on R vectors (see :func:`ce_wheel_energy_j`)."""
    sc = np.array([[v.s_me, v.s_a, v.s_r, *v.ns_sums] for v in vectors])  # (R, 6)
    mm = m[:, None]
    e1 = mm * (sc[:, 0] + cr[:, None] * sc[:, 2]) + cda[:, None] * sc[:, 1]
    net = mm * (sc[:, 3] + cr[:, None] * sc[:, 5]) + cda[:, None] * sc[:, 4]
    out = e1 + net  # braking credited (w = 1): affine, no sign to decide
    need = np.flatnonzero(w != 1.0)
    if need.size:
        sizes = np.array([v.ns_x.size for v in vectors])
        _, grp = np.unique(group[need], return_inverse=True)
        pos = positive_parts(
            np.concatenate([v.ns_x for v in vectors]), np.concatenate([v.ns_a for v in vectors]),
            np.concatenate([v.ns_r for v in vectors]), np.repeat(np.arange(len(vectors)), sizes),
            np.concatenate([[0], np.cumsum(sizes)]), len(vectors), m[need], cda[need], cr[need], grp,
            int(grp.max()) + 1)
        out[need] = e1[need] + pos + w[need][:, None] * (net[need] - pos)
    return out


def group_ids(cda: np.ndarray, cr: np.ndarray, group) -> np.ndarray:
    """Compact group ids (0..G-1): of ``group`` if given, else of the (CdA, Cr) pairs."""
    if group is None:
        _, inv = np.unique(np.stack([cda, cr], axis=1), axis=0, return_inverse=True)
        return inv.ravel()
    _, inv = np.unique(np.asarray(group).ravel(), return_inverse=True)
    return inv

