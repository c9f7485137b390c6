"""Where a vehicle first crosses its reserve or runs empty along a source, and its range.

Computed from the plain per-step terms (:class:`~cevm.core.sweep.profiles.StepTable`),
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

from dataclasses import replace

import numpy as np

from cevm.core.model import braking_weight
from cevm.core.sweep.block import DEFAULT_RESERVE_PCT, DEFAULT_SOC_START_PCT, SweepBlock
from cevm.core.sweep.profiles import StepTable
from cevm.core.sweep.stepenergy import StepCoefficients, step_coefficients, step_energies


def _crossing_point(st: StepTable, cum: np.ndarray, before: np.ndarray, target: np.ndarray,
                    rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each row r of ``rows``: the first step j with ``cum[r, j] >= target[r]``
    (``before[r]`` the sum before the first step), and the time [s] and distance [m]
    at which it is reached, interpolated inside the step. Returns (found, t, d)."""
    hit = cum[rows] >= target[:, None]
    found = hit.any(axis=1)
    j = np.argmax(hit, axis=1)
    prev = np.where(j > 0, cum[rows, np.maximum(j - 1, 0)], before)
    step = cum[rows, j] - prev
    with np.errstate(invalid="ignore", divide="ignore"):
        frac = np.clip(np.where(step > 0, (target - prev) / step, 1.0), 0.0, 1.0)
    return found, st.t0[j] + frac * st.dt[j], st.d0[j] + frac * st.dd[j]


#: Rows x steps of one chunk of :func:`crossings` (8 MB of float64).
_RANGE_CHUNK_CELLS = 1 << 20


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
    n = st.n
    at_start = c.lump[:, None] >= levels
    t_out[at_start] = 0.0
    d_out[at_start] = 0.0
    within |= at_start
    if n == 0:
        return t_out, d_out, within
    step = max(1, _RANGE_CHUNK_CELLS // n)
    for lo in range(0, r_count, step):
        sl = slice(lo, lo + step)
        cc = c.take(np.arange(r_count)[sl])
        cum = np.cumsum(step_energies(st, cc), axis=1)  # C_j, one pass, without the lump
        per_pass = cum[:, -1]
        peak = cum.max(axis=1)
        lump = cc.lump
        for jl in range(n_levels):
            todo = ~at_start[sl, jl]
            if not todo.any():
                continue
            rows = np.flatnonzero(todo)
            target = levels[sl, jl][rows] - lump[rows]  # C_j must reach this
            found, t, d = _crossing_point(st, cum, np.zeros(rows.size), target, rows)
            r_found = lo + rows[found]
            t_out[r_found, jl], d_out[r_found, jl], within[r_found, jl] = t[found], d[found], True
            if not repeat:
                continue
            rest = rows[~found]
            target = target[~found]
            gains = per_pass[rest] > 0
            t_out[lo + rest[~gains], jl] = np.inf
            d_out[lo + rest[~gains], jl] = np.inf
            rest, target = rest[gains], target[gains]
            if not rest.size:
                continue
            s = per_pass[rest]
            k = np.maximum(1.0, np.ceil((target - peak[rest]) / s))
            k = np.where(target - k * s > peak[rest], k + 1.0, k)  # rounding
            found, t, d = _crossing_point(st, cum, np.zeros(rest.size), target - k * s, rest)
            t_out[lo + rest, jl] = np.where(found, k * st.duration_s + t, np.nan)
            d_out[lo + rest, jl] = np.where(found, k * st.distance_m + d, np.nan)
    return t_out, d_out, within


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
    out = {f: np.full(n, np.nan) for f in RANGE_FIELDS}
    if rows.size:
        coef = step_coefficients(ps, block.ambient_c)
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
