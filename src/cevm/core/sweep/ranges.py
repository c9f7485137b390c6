"""Where a vehicle first crosses its reserve or runs empty along a source, and its range.

Computed from the plain per-step terms (:class:`~cevm.core.sweep.steptable.StepTable`),
for the rows that need them: the energy drawn is summed step by step as the CE model's
terms give it (:mod:`cevm.core.sweep.stepenergy`), so the total at the end equals the
model's.

A level L (the energy above the reserve, or the whole usable battery or tank) is first
crossed in the step where the running sum E_j reaches L; the point is interpolated
linearly inside that step (the step's energy spread evenly over its time and distance).

Beyond the source's end, the range counts the source driven again and again, without a
stop to recharge or refuel and without another cold start: the repetition k and step j
of the first crossing of lump + k S + C_j >= L, S the energy of one pass (without the
start's), C_j the running sum inside a pass. A source that gives back at least what it
takes (S <= 0, a descent) has no range limit: infinite.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from cevm.core.model import braking_weight
from cevm.core.sweep.block import DEFAULT_RESERVE_PCT, DEFAULT_SOC_START_PCT, SweepBlock
from cevm.core.sweep.stepenergy import StepCoefficients, step_coefficients, step_energies
from cevm.core.sweep.steptable import StepTable

#: Cells (rows x steps) of one chunk of :func:`crossings` (8 MB of float64).
_RANGE_CHUNK_CELLS = 1 << 20
#: Rows evaluated together by :func:`crossings`.
_RANGE_CHUNK_ROWS = 1 << 12
#: Fewest and most steps of one chunk of :func:`crossings`: the running sums are made a
#: chunk at a time and stop at the chunk where every level is crossed (a row that runs
#: empty early in a long source costs that early part only).
_RANGE_CHUNK_STEPS = (1 << 10, 1 << 16)


@dataclass(frozen=True, eq=False)
class _Crossings:
    """Where each (row, level) target is first reached by the running sum C_j of one
    pass: ``found`` (R, J), the step ``j`` and the fraction ``frac`` of it at which C
    reaches the target (linear inside the step); ``per_pass`` C at the end of the pass
    and ``peak`` its largest value (R,), when asked for (else None)."""

    found: np.ndarray
    j: np.ndarray
    frac: np.ndarray
    per_pass: np.ndarray | None
    peak: np.ndarray | None


def _first_crossings(st: StepTable, c: StepCoefficients, targets: np.ndarray, totals: bool) -> _Crossings:
    """For each row r and level l with a target (NaN: none, never reached), the first
    step j with C_j = sum_{i<=j} g_i >= targets[r, l] (g: :func:`step_energies`), and
    with ``totals`` the pass's end value and peak of C. C is summed in order, a chunk of
    steps at a time (each chunk's sums continue the last one's: the values are those of
    one running sum over the whole source), and the scan stops at the chunk where every
    target is reached unless ``totals`` asks for the whole pass."""
    r_count, n_levels = targets.shape
    found = np.zeros((r_count, n_levels), dtype=bool)
    j_at = np.zeros((r_count, n_levels), dtype=np.int64)
    frac = np.zeros((r_count, n_levels))
    search = ~np.isnan(targets)
    carry = np.zeros(r_count)  # C before the chunk
    peak = np.full(r_count, -np.inf) if totals else None
    n = st.n
    lo_steps, hi_steps = _RANGE_CHUNK_STEPS
    chunk = min(hi_steps, max(lo_steps, _RANGE_CHUNK_CELLS // max(1, r_count)))
    for lo in range(0, n, chunk):
        if not totals and not search.any():
            break
        cum = step_energies(st, c, lo, min(n, lo + chunk))
        if lo:
            cum[:, 0] += carry
        np.cumsum(cum, axis=1, out=cum)
        for jl in range(n_levels):
            rows = np.flatnonzero(search[:, jl])
            if not rows.size:
                continue
            target = targets[rows, jl]
            hit = cum[rows] >= target[:, None]
            now = hit.any(axis=1)
            if not now.any():
                continue
            rows, target = rows[now], target[now]
            j = np.argmax(hit[now], axis=1)
            prev = np.where(j > 0, cum[rows, np.maximum(j - 1, 0)], carry[rows])
            step = cum[rows, j] - prev
            with np.errstate(invalid="ignore", divide="ignore"):
                frac[rows, jl] = np.clip(np.where(step > 0, (target - prev) / step, 1.0), 0.0, 1.0)
            found[rows, jl] = True
            j_at[rows, jl] = lo + j
            search[rows, jl] = False
        if peak is not None:
            np.maximum(peak, cum.max(axis=1), out=peak)
        carry = cum[:, -1].copy()
    return _Crossings(found, j_at, frac, carry if totals else None, peak)


def crossings(st: StepTable, c: StepCoefficients, levels: np.ndarray, *, repeat: bool
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where the running energy of each row first reaches each of its ``levels``
    (R, J), along the source and, with ``repeat``, with the source driven again and
    again after its end (see the notes above).

    Returns ``(time_s, distance_m, within)``, each (R, J): NaN where never reached (a
    level above what the source takes, without ``repeat``; infinite with ``repeat`` when
    one pass gives back what it takes), ``within`` True where reached in the first pass.
    """
    levels = np.atleast_2d(np.asarray(levels, dtype=np.float64))
    r_count, n_levels = levels.shape
    t_out = np.full((r_count, n_levels), np.nan)
    d_out = np.full((r_count, n_levels), np.nan)
    within = np.zeros((r_count, n_levels), dtype=bool)
    if r_count == 0:
        return t_out, d_out, within
    at_start = c.lump[:, None] >= levels
    t_out[at_start] = 0.0
    d_out[at_start] = 0.0
    within |= at_start
    if st.n == 0:
        return t_out, d_out, within
    for lo in range(0, r_count, _RANGE_CHUNK_ROWS):
        sl = slice(lo, lo + _RANGE_CHUNK_ROWS)
        cc = c.take(np.arange(r_count)[sl])
        todo = ~at_start[sl]
        target = levels[sl] - cc.lump[:, None]  # C_j must reach this (without the lump)
        first = _first_crossings(st, cc, np.where(todo, target, np.nan), totals=repeat and bool(todo.any()))
        t, d = _point(st, first)
        hit = first.found
        t_out[sl][hit], d_out[sl][hit] = t[hit], d[hit]
        within[sl] |= hit
        if not repeat:
            continue
        rest = todo & ~hit  # beyond the first pass: lump + k S + C_j >= level
        s = first.per_pass[:, None] if first.per_pass is not None else np.zeros((cc.lump.size, 1))
        gives_back = rest & ~(s > 0)
        t_out[sl][gives_back] = np.inf
        d_out[sl][gives_back] = np.inf
        rest &= s > 0
        if not rest.any():
            continue
        assert first.peak is not None  # made whole: the pass was summed to its end (repeat)
        peak = first.peak[:, None]
        with np.errstate(invalid="ignore", divide="ignore"):
            k = np.maximum(1.0, np.ceil((target - peak) / s))
            k = np.where(target - k * s > peak, k + 1.0, k)  # rounding
            again = _first_crossings(st, cc, np.where(rest, target - k * s, np.nan), totals=False)
        t, d = _point(st, again)
        t_out[sl][rest] = np.where(again.found, k * st.duration_s + t, np.nan)[rest]
        d_out[sl][rest] = np.where(again.found, k * st.distance_m + d, np.nan)[rest]
    return t_out, d_out, within


def _point(st: StepTable, cr: _Crossings) -> tuple[np.ndarray, np.ndarray]:
    """The time [s] and distance [m] of each crossing found (else NaN), interpolated
    inside its step."""
    t = np.full(cr.found.shape, np.nan)
    d = np.full(cr.found.shape, np.nan)
    if cr.found.any():
        j, f = cr.j[cr.found], cr.frac[cr.found]
        t[cr.found] = st.t0[j] + f * st.dt[j]
        d[cr.found] = st.d0_at(j) + f * (st.r[j] / st.g_mps2)  # st.dd[j], without the whole dd
    return t, d


#: The fields :func:`source_ranges` fills (of :class:`SweepBlock`, and of
#: :class:`cevm.core.feasibility.Feasibility`).
RANGE_FIELDS = ("reserve_at_m", "reserve_at_s", "empty_at_m", "empty_at_s", "range_m", "range_reserve_m")


def source_ranges(block: SweepBlock, *, soc_start_pct: float = DEFAULT_SOC_START_PCT,
                  reserve_pct: float = DEFAULT_RESERVE_PCT, repeat: bool = True) -> SweepBlock:
    """``block`` with where each row first crosses its reserve (EV) and runs empty
    (EV battery, ICE tank) along the source, its range (``repeat``: the source driven
    again and again; see the notes above), and no state of charge below zero: a row
    that runs empty on the way has ``soc_min_pct`` 0 and ``soc_end_pct`` NaN (it does
    not reach the end).

    Rows that cannot cross inside the source (EV: lowest SoC above the reserve; ICE:
    fuel within the tank and never falling along the way) are not summed step by step
    unless ``repeat`` asks for their range. EV rows without a lowest SoC (a sweep with
    ``lowest_soc=False``) get NaN. SI fields: ``reserve_at_m``, ``reserve_at_s``,
    ``empty_at_m``, ``empty_at_s``, ``range_m`` (to empty), ``range_reserve_m`` (to the
    reserve; EV only).
    """
    ps = block.pset
    n = ps.n
    ev = ps.is_ev
    cap = np.where(ev, ps.battery_j, np.nan)
    l_empty = np.where(ev, soc_start_pct / 100.0 * cap, ps.tank_l)
    l_res = np.where(ev, (soc_start_pct - reserve_pct) / 100.0 * cap, np.nan)
    has_level = np.isfinite(l_empty)
    if ev.any() and np.all(np.isnan(block.soc_min_pct[ev])):
        has_level &= ~ev  # no lowest SoC: the EV rows are not evaluated
    if repeat:
        need = has_level
    else:
        # an ICE's running fuel can fall along the way only with braking credited (w > 0)
        # or a kinetic efficiency above eta (a negative kinetic term)
        with np.errstate(invalid="ignore"):
            need = ev & (block.soc_min_pct < reserve_pct)
            if not ev.all():
                falls = np.array([not v.is_ev and (braking_weight(ps.braking[j] or v.ice_braking) > 0
                                                   or (v.kinetic_eta is not None and v.kinetic_eta > v.eta))
                                  for j, v in enumerate(ps.vehicles)])[ps.vehicle_index]
                need |= ~ev & ((block.fuel_l >= ps.tank_l) | falls)
        need &= has_level
    rows = np.flatnonzero(need)
    with np.errstate(invalid="ignore"):
        clean = not (np.any(block.soc_end_pct < 0) or np.any(block.soc_min_pct < 0))
    if not rows.size and not repeat and clean:
        return block  # nothing crosses anything: the common case costs no copy
    out: dict[str, Any] = {f: np.full(n, np.nan) for f in RANGE_FIELDS}  # SweepBlock fields (None: not asked)
    if rows.size:
        coef = step_coefficients(ps, block.ambient_c)
        if block.source.leg_vectors is not None:  # a route leg by leg: an EV's auxiliary power, starts as its total
            from cevm.core.sweep.predictions import row_terms

            terms = row_terms(ps, [block.source])
            coef = replace(coef, aux=np.where(ps.is_ev, terms.aux_w[:, 0], coef.aux),
                           lump=np.where(ps.is_ev, terms.start_j[:, 0], coef.lump))
        levels = np.stack([l_res[rows], l_empty[rows]], axis=1)
        t, d, inside = crossings(block.source.step_table, coef.take(rows), levels, repeat=repeat)
        res = ev[rows]
        out["reserve_at_s"][rows] = np.where(inside[:, 0] & res, t[:, 0], np.nan)
        out["reserve_at_m"][rows] = np.where(inside[:, 0] & res, d[:, 0], np.nan)
        out["empty_at_s"][rows] = np.where(inside[:, 1], t[:, 1], np.nan)
        out["empty_at_m"][rows] = np.where(inside[:, 1], d[:, 1], np.nan)
        if repeat:
            out["range_m"][rows] = d[:, 1]
            out["range_reserve_m"][rows] = np.where(res, d[:, 0], np.nan)
    if not repeat:
        out["range_m"] = out["range_reserve_m"] = None
    soc_end = block.soc_end_pct.copy()
    soc_min = block.soc_min_pct.copy()
    empty = np.isfinite(out["empty_at_m"]) & ev
    with np.errstate(invalid="ignore"):
        soc_end[empty | (soc_end < 0)] = np.nan
        soc_min[empty | (soc_min < 0)] = 0.0
    return replace(block, soc_end_pct=soc_end, soc_min_pct=soc_min, **out)
