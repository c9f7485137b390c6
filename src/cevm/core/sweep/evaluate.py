"""Every prediction of a set on a few sources at once: totals by the CE model, the state
of charge at the end and at its lowest (EV), the fuel against the tank (ICE), then where
each row crosses its reserve or runs empty (:mod:`~cevm.core.sweep.ranges`) and whether
it can follow the source (:mod:`~cevm.core.sweep.power`).

ICE rows get the fuel needed (the total) against ``tank_l``: fuel burnt never falls along
a route (the paper's braking credit lowers the *estimate* of the total, not the tank).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from cevm.core import limits
from cevm.core.sweep.block import DEFAULT_RESERVE_PCT, DEFAULT_SOC_START_PCT, SweepBlock
from cevm.core.sweep.peak import StepsBatch, peak_many
from cevm.core.sweep.power import follow_flags
from cevm.core.sweep.predictions import PredictionSet, row_terms
from cevm.core.sweep.ranges import source_ranges
from cevm.core.sweep.sources import Source
from cevm.core.sweep.wheel import ce_wheel_batch_j, group_ids
from cevm.errors import CevmError


def check_cr(source: Source, pset: PredictionSet) -> None:
    bad = pset.cr < source.vector.cr0
    if bad.any():
        v = pset.vehicles[int(pset.vehicle_index[np.argmax(bad)])]
        raise CevmError(f"vehicle {v.name!r}: cr {v.cr:g} is below the Cr0 {source.vector.cr0:g} of source "
                        f"{source.name!r}; the CE split is only exact for Cr >= Cr0 (use a lower --cr0)")


def predict_source(
    source: Source,
    pset: PredictionSet,
    *,
    soc_start_pct: float = DEFAULT_SOC_START_PCT,
    reserve_pct: float = DEFAULT_RESERVE_PCT,
    lowest_soc: bool = True,
    source_index: int = 0,
    ranges: bool = False,
) -> SweepBlock:
    """Every prediction of ``pset`` on ``source``: totals by the CE model, and for EVs
    the state of charge at the end and at its lowest along the way (``lowest_soc``,
    default True; False skips the profile and leaves ``soc_min_pct`` NaN).

    ``soc_start_pct`` [%] (default 100: leaving the depot charged) and ``reserve_pct``
    [%] (default 15, the paper's warning level) are percentages of ``battery_kwh``.
    The SoC is not capped at 100 %: a full battery cannot take regenerated energy, so on
    a route that starts downhill from full the model's SoC is optimistic. Nor does it go
    below 0: where a row runs empty, and where it crosses the reserve, the block says
    (:func:`source_ranges`); ``ranges`` (default False) adds each row's range, the source
    driven again and again (one step-by-step sum per row). Vehicles with
    ``max_power_kw`` or ``max_speed_kmh`` get :func:`follow_flags`.
    """
    return predict_sources([source], pset, soc_start_pct=soc_start_pct, reserve_pct=reserve_pct,
                           lowest_soc=lowest_soc, first_index=source_index, ranges=ranges)[0]


def predict_sources(
    sources: Sequence[Source],
    pset: PredictionSet,
    *,
    soc_start_pct: float = DEFAULT_SOC_START_PCT,
    reserve_pct: float = DEFAULT_RESERVE_PCT,
    lowest_soc: bool = True,
    first_index: int = 0,
    ranges: bool = False,
) -> list[SweepBlock]:
    """:func:`predict_source` for several sources at once (one vectorised evaluation,
    faster than one source at a time); one block per source, in order."""
    if not sources:
        return []
    arrays = predict_arrays(sources, pset, soc_start_pct, reserve_pct, lowest_soc)
    return finish_blocks(as_blocks(sources, pset, arrays, first_index), soc_start_pct, reserve_pct, ranges)


def predict_arrays(sources: Sequence[Source], pset: PredictionSet, soc_start_pct: float, reserve_pct: float,
                    lowest_soc: bool) -> tuple[np.ndarray, ...]:
    """The (P, n_sources) arrays of :func:`predict_sources`, in :data:`BLOCK_ARRAYS`
    order. Also the task of a parallel :func:`sweep` (the sources and the set stay with
    the caller; only these arrays come back)."""
    for src in sources:
        check_cr(src, pset)
    vecs = [src.vector for src in sources]
    n_src = len(sources)
    duration = np.array([v.duration_s for v in vecs])
    ev = pset.is_ev
    shape = (pset.n, n_src)
    wheel = np.empty(shape)
    energy_j = np.full(shape, np.nan)
    fuel = np.full(shape, np.nan)
    soc_end = np.full(shape, np.nan)
    soc_min = np.full(shape, np.nan)
    terms = row_terms(pset, sources)
    # EV rows with the lowest SoC: the step terms give the total and the peak in one
    # pass; every other row: the CE vector
    by_steps = ev if lowest_soc else np.zeros_like(ev)
    by_vector = ~by_steps
    if by_vector.any():
        wheel[by_vector] = ce_wheel_batch_j(vecs, pset.mass_kg[by_vector], pset.cda_m2[by_vector], pset.cr[by_vector],
                                     pset.negative_weight[by_vector],
                                     group_ids(pset.cda_m2[by_vector], pset.cr[by_vector],
                                             pset.vehicle_index[by_vector]))  # (P, R)
    peak = None
    if by_steps.any():
        bt = StepsBatch.of([src.steps for src in sources])
        aux = terms.aux_w[ev]
        if np.all(aux == aux[:, :1]):
            aux = aux[:, 0].copy()  # the same for every source: the cheaper per-row form
        wheel[ev], peak = peak_many(bt, pset.mass_kg[ev], pset.cda_m2[ev], pset.cr[ev], pset.eta[ev],
                                     pset.negative_weight[ev], aux, pset.vehicle_index[ev], None)
    if ev.any():
        # battery energy E_e = W / eta + P_aux(T) D + warm-up (eq. 31, cevm.core.energy)
        start = terms.start_j[ev]
        e = wheel[ev] / pset.eta[ev][:, None] + terms.aux_w[ev] * duration + start
        energy_j[ev] = e
        cap = pset.battery_j[ev][:, None]
        soc_end[ev] = soc_start_pct - 100.0 * e / cap
        if peak is not None:
            peak += start  # drawn at the start, before the first step: every E_j includes it
            np.maximum(peak, e, out=peak)  # E_n is one of the E_j: SoC_min <= SoC_end exactly
            soc_min[ev] = soc_start_pct - 100.0 * peak / cap
    ice = ~ev
    if ice.any():
        # fuel L_f = W / (U_f eta) (eq. 26) + the terms of cevm.core.energy.ice_fuel_l
        fuel[ice] = wheel[ice] / (pset.lhv_j_per_l[ice] * pset.eta[ice])[:, None] + terms.fuel_extra_l[ice]
    tank_ok = limits.tank_ok(fuel, pset.tank_l[:, None], ice[:, None])
    reserve_ok = ev[:, None] & (limits.reserve_ok(soc_min, reserve_pct) == 1.0)
    return (wheel, energy_j, fuel, soc_end, soc_min, reserve_ok, tank_ok, terms.ambient_c,
            terms.ambient_from.astype(np.float64))


#: The arrays of a :class:`SweepBlock`, in the order :func:`predict_arrays` returns them.
BLOCK_ARRAYS = ("wheel_energy_j", "energy_j", "fuel_l", "soc_end_pct", "soc_min_pct", "reserve_ok", "tank_ok",
                 "ambient_c", "ambient_from")


def as_blocks(sources: Sequence[Source], pset: PredictionSet, arrays: tuple[np.ndarray, ...],
               first_index: int) -> list[SweepBlock]:
    """One :class:`SweepBlock` per source from the (P, n_sources) arrays of
    :func:`predict_arrays`."""
    def columns(i: int) -> dict[str, Any]:  # SweepBlock's array fields
        return {name: a[:, i].copy() for name, a in zip(BLOCK_ARRAYS, arrays, strict=True)}

    return [SweepBlock(src, first_index + i, pset, **columns(i)) for i, src in enumerate(sources)]


def finish_blocks(blocks: list[SweepBlock], soc_start_pct: float, reserve_pct: float, ranges: bool) -> list[SweepBlock]:
    """The blocks with :func:`source_ranges`, :func:`follow_flags` and the verdict
    (:func:`cevm.core.limits.verdict`; in this process: the step tables stay with the
    sources)."""
    out = []
    for b in blocks:
        b = follow_flags(source_ranges(b, soc_start_pct=soc_start_pct, reserve_pct=reserve_pct, repeat=ranges))
        ps = b.pset
        flags = limits.verdict(is_ev=ps.is_ev, over_max_gross=ps.over_max_gross,
                               over_power=np.full(ps.n, np.nan) if b.over_power is None else b.over_power,
                               over_speed=np.full(ps.n, np.nan) if b.over_speed is None else b.over_speed,
                               soc_min_pct=b.soc_min_pct, reserve_pct=reserve_pct, fuel_l=b.fuel_l,
                               tank_l=ps.tank_l)
        out.append(replace(b, feasible=flags["feasible"], soc_start_pct=soc_start_pct, reserve_pct=reserve_pct))
    return out

