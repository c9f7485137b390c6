"""Feasibility (pure): can each vehicle run a source, with what margin, and the largest
payload that keeps the reserve (EV) or fits the tank (ICE).

Built on the fleet predictions of :mod:`cevm.core.sweep` (sources, the CE totals and the
exact peak of the energy drawn along the way).

Feasibility and the largest payload
-----------------------------------
For a fixed vehicle, every E_j is convex in the mass m: W(D) = w D + (1 - w)
max(D, 0) with D affine in m, and w = eta eta_r <= 1 (the same holds for ICE fuel, w = 1
or 0); the terms beyond the wheel (:mod:`cevm.core.energy`) are constant or, the ICE's
kinetic term, linear in m, so convexity is kept.
The maximum over j of convex functions is convex. So the payloads that keep the reserve
form one interval, even on routes where energy *falls* with mass (a long descent: a
heavier vehicle regenerates more). :func:`feasibility` does not assume monotonicity: it
tests the empty payload, and if that fails it finds the minimum of the convex function
(binary search on the sign of its discrete slope) before bisecting each side, all on
whole kilograms with the exact model: the answer is the largest whole-kg payload that
keeps the reserve (EV) or fits the tank (ICE) and respects ``max_gross_kg``.

At a confidence c (:func:`feasibility`'s ``confidence``), "keeps the reserve" means that
it does so with probability at least c under the vehicle's predictive distribution
(:mod:`cevm.core.predictive`: its calibration's posterior, or its class's priors): the
load's (the peak energy drawn, or the fuel) c-quantile must fit the budget, in the
distribution of every interval (:mod:`cevm.core.distribution`: log-normal of the load's
mean and standard deviation, the peak's taken as the source total's relative one), so
that the verdict and predict's p_reserve_ok agree. The quantile grows with the load's
mean and standard deviation, both increasing in the mass where the load is (for c >=
0.5): the search stands; c = 0.5 is the point estimate (the mean, as predict's).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from cevm.core import distribution, limits, physical_inputs
from cevm.core.predictive import Features, posterior_of, predictive
from cevm.core.sweep import (
    AMBIENT_ORIGINS,
    DEFAULT_RESERVE_PCT,
    DEFAULT_SOC_START_PCT,
    RANGE_FIELDS,
    PredictionSet,
    RowTerms,
    Source,
    ce_wheel_energy_j,
    check_cr,
    peak_energy_j,
    predict_source,
    row_terms,
)
from cevm.core.vehicle import Vehicle
from cevm.errors import CevmError


@dataclass(frozen=True, eq=False)
class Feasibility:
    """Can each vehicle run one source, with what margin, and with what payload.

    Arrays (V,), one per vehicle, at the evaluated load (``mass_kg``, ``payload_kg``):
    ``over_max_gross``; EV: ``soc_end_pct``, ``soc_min_pct``, ``reserve_margin_pct``
    (SoC_min - reserve, percentage points); ICE: ``fuel_l``, ``tank_margin_l`` (tank -
    fuel, NaN without ``tank_l``); ``feasible`` 1.0 / 0.0 (NaN: ICE without tank_l), the
    one verdict of every command (:func:`cevm.core.limits.verdict`: the reserve or the
    tank, max_gross_kg, max_power_kw and max_speed_kmh), with its flags ``over_power``,
    ``over_speed``, ``reserve_ok``, ``tank_ok``.
    Payload search: ``max_payload_kg`` (largest whole-kg payload keeping the reserve /
    fitting the tank, within max_gross_kg or the search cap, and at masses the vehicle
    can follow the source at (max_power_kw, max_speed_kmh); NaN when none does),
    ``min_payload_kg`` (0 unless the empty vehicle fails and a heavier one passes,
    which convexity allows on descents), ``limited_by``: ``"reserve"``, ``"tank"``,
    ``"max_gross_kg"``, ``"payload_cap"``, ``"max_power_kw"``, ``"max_speed_kmh"`` or
    ``"infeasible"``. Payloads count from
    ``kerb_mass_kg`` (from ``mass_kg`` for a vehicle without one). ``ambient_c`` the
    temperature each vehicle was evaluated at [degC], ``ambient_from`` its origin. The
    state of charge never goes below 0: an EV that runs empty on the way has
    ``soc_end_pct`` NaN and ``soc_min_pct`` 0, and ``empty_at_m`` says where (see the
    range fields below).
    """

    source: Source
    vehicles: tuple[Vehicle, ...]
    mass_kg: np.ndarray
    payload_kg: np.ndarray
    over_max_gross: np.ndarray
    energy_j: np.ndarray
    fuel_l: np.ndarray
    soc_end_pct: np.ndarray
    soc_min_pct: np.ndarray
    reserve_margin_pct: np.ndarray
    tank_margin_l: np.ndarray
    feasible: np.ndarray
    max_payload_kg: np.ndarray
    min_payload_kg: np.ndarray
    limited_by: tuple[str, ...]
    ambient_c: np.ndarray | None = None
    ambient_from: tuple[str, ...] = ()
    # at the evaluated load (:func:`cevm.core.sweep.source_ranges`): where the reserve is
    # first crossed (EV) and the battery or tank runs empty along the source [m], [s]
    # (NaN if not), and the range [m] to empty and to the reserve with the source
    # driven again and again (inf: a source that gives back what it takes)
    reserve_at_m: np.ndarray | None = None
    reserve_at_s: np.ndarray | None = None
    empty_at_m: np.ndarray | None = None
    empty_at_s: np.ndarray | None = None
    range_m: np.ndarray | None = None
    range_reserve_m: np.ndarray | None = None
    # at the evaluated load (cevm.core.limits): can it follow the source (1.0 / 0.0, NaN:
    # the vehicle file has no max_power_kw / max_speed_kmh), the power the source asks [W],
    # and the reserve and the tank at the confidence (1.0 / 0.0, NaN for the other
    # powertrain or unknown)
    over_power: np.ndarray | None = None
    over_speed: np.ndarray | None = None
    power_demand_w: np.ndarray | None = None
    reserve_ok: np.ndarray | None = None
    tank_ok: np.ndarray | None = None
    # what it assumed of the battery [%]
    soc_start_pct: float = DEFAULT_SOC_START_PCT
    reserve_pct: float = DEFAULT_RESERVE_PCT
    # the verdict's and the payload's confidence, and at the evaluated load: the energy's
    # (EV, J) or fuel's (ICE, l) standard deviation, P(reserve kept / tank enough), and
    # where the uncertainty comes from (:data:`cevm.core.intervals.INTERVAL_SOURCES`)
    confidence: float = 0.5
    sd: np.ndarray | None = None
    p_ok: np.ndarray | None = None
    interval_from: tuple[str, ...] = ()


class _LoadFunction:
    """f(vehicle, payload): peak battery energy [J] (EV) or fuel [l] (ICE), vectorised
    over (vehicle index, payload) pairs, and each vehicle's budget (usable energy above
    the reserve, or the tank)."""

    def __init__(self, source: Source, vehicles: Sequence[Vehicle], base_kg: np.ndarray, soc_start_pct: float,
                 reserve_pct: float, ice_braking: str | None, ambient_c: float | None = None,
                 confidence: float | None = None):
        self.source = source
        self.vehicles = tuple(vehicles)
        self.confidence = confidence
        self.pset = PredictionSet.build(vehicles, ice_braking=ice_braking, ambient_c=ambient_c)  # one row per vehicle
        check_cr(source, self.pset)
        self.base_kg = base_kg
        ps = self.pset
        self.budget = np.where(ps.is_ev, (soc_start_pct - reserve_pct) / 100.0 * ps.battery_j, ps.tank_l)

    def __call__(self, vi: np.ndarray, payload_kg: np.ndarray) -> np.ndarray:
        """The load at the confidence: the peak energy's or fuel's quantile at it
        (:mod:`cevm.core.distribution`; the mean without a confidence)."""
        load, total, terms = self.evaluate(vi, payload_kg)
        if self.confidence is None:
            return load
        sd = self.sd(vi, self.base_kg[vi] + payload_kg, terms)
        ev = self.pset.is_ev[vi]
        with np.errstate(invalid="ignore", divide="ignore"):
            rel = np.where(ev, sd / np.abs(total), 0.0)
        return distribution.quantile(load, np.where(ev, rel * np.abs(load), sd), self.confidence)

    def sd(self, vi: np.ndarray, mass_kg: np.ndarray, terms: RowTerms) -> np.ndarray:
        """The standard deviation of the source's total energy [J] or fuel [l] of (vehicle
        index, mass) pairs (:func:`cevm.core.predictive.predictive`)."""
        out = np.zeros(vi.size)
        for v in np.unique(vi):
            sel = vi == v
            veh = self.vehicles[int(v)]
            f = Features.of(self.source.vector, veh, mass_kg[sel], terms.ambient_c[sel, 0])
            out[sel] = predictive(veh, f, ice_braking=self.pset.braking[int(v)] or None).sd
        return out

    def source_of(self, v: int) -> str:
        """Where vehicle ``v``'s uncertainty comes from (posterior, prior, none)."""
        post = posterior_of(self.vehicles[v])
        return "none" if post is None else post.label

    def evaluate(self, vi: np.ndarray, payload_kg: np.ndarray) -> tuple[np.ndarray, np.ndarray, RowTerms]:
        """(peak battery energy [J] (EV) or fuel [l] (ICE), total battery energy [J] (NaN
        for ICE), the row terms) of (vehicle index, payload) pairs."""
        ps = self.pset
        vec = self.source.vector
        m = self.base_kg[vi] + payload_kg
        terms = row_terms(ps, [self.source], rows=vi, mass_kg=m)
        wheel = ce_wheel_energy_j(vec, m, ps.cda_m2[vi], ps.cr[vi], ps.negative_weight[vi], group=vi)
        out = np.empty(vi.size)
        total = np.full(vi.size, np.nan)
        ev = ps.is_ev[vi]
        if ev.any():
            v = vi[ev]
            aux = terms.aux_w[ev, 0]
            start = terms.start_j[ev, 0]
            e = wheel[ev] / ps.eta[v] + aux * vec.duration_s
            out[ev] = start + peak_energy_j(self.source.steps, m[ev], ps.cda_m2[v], ps.cr[v], ps.eta[v],
                                            ps.negative_weight[v], aux, group=v, end_energy_j=e)
            total[ev] = e + start
        if (~ev).any():
            v = vi[~ev]
            out[~ev] = wheel[~ev] / (ps.lhv_j_per_l[v] * ps.eta[v]) + terms.fuel_extra_l[~ev, 0]
        return out, total, terms

    def ok(self, vi: np.ndarray, payload_kg: np.ndarray) -> np.ndarray:
        return self(vi, payload_kg) <= self.budget[vi]


def _last_true(pred, vi: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Largest integer p in [lo, hi] with pred True, given pred(lo) True and pred(hi)
    False and pred True-then-False on [lo, hi] (vectorised bisection)."""
    lo = lo.copy()
    hi = hi.copy()
    while True:
        act = np.flatnonzero(hi - lo > 1)
        if act.size == 0:
            return lo
        mid = (lo[act] + hi[act]) // 2
        ok = pred(vi[act], mid.astype(np.float64))
        lo[act] = np.where(ok, mid, lo[act])
        hi[act] = np.where(ok, hi[act], mid)


def _first_true(pred, vi: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Smallest integer p in [lo, hi] with pred True, given pred(hi) True and pred
    False-then-True on [lo, hi]."""
    lo = lo.copy()
    hi = hi.copy()
    first = pred(vi, lo.astype(np.float64))
    res = hi.copy()
    res[first] = lo[first]
    act0 = ~first  # pred(lo) False, pred(hi) True
    while True:
        act = np.flatnonzero(act0 & (hi - lo > 1))
        if act.size == 0:
            res[act0] = hi[act0]
            return res
        mid = (lo[act] + hi[act]) // 2
        ok = pred(vi[act], mid.astype(np.float64))
        hi[act] = np.where(ok, mid, hi[act])
        lo[act] = np.where(ok, lo[act], mid)


def feasibility(
    source: Source,
    vehicles: Sequence[Vehicle],
    *,
    soc_start_pct: float = DEFAULT_SOC_START_PCT,
    reserve_pct: float = DEFAULT_RESERVE_PCT,
    payload_kg: float | None = None,
    mass_kg: float | None = None,
    payload_cap_kg: float | None = None,
    ice_braking: str | None = None,
    ambient_c: float | None = None,
    confidence: float = 0.5,
) -> Feasibility:
    """Feasibility of ``source`` for each vehicle, and the largest payload.

    Parameters
    ----------
    source : the route (or cycle, trip)
    vehicles : the vehicles
    soc_start_pct : SoC at the start [%], default 100
    reserve_pct : the SoC that must be kept all along [%], default 15 (the paper's
        warning level)
    payload_kg, mass_kg : the load at which margins are reported (at most one): a payload
        [kg] on each vehicle's kerb mass, or a gross mass [kg]; default each vehicle's
        default ``mass_kg``
    payload_cap_kg : where the payload search stops for a vehicle without
        ``max_gross_kg`` [kg]; default None: its kerb (or base) mass, i.e. at most
        doubling the vehicle's mass (``limited_by`` says ``"payload_cap"`` then)
    ice_braking : override of the ICE braking mode
    ambient_c : the ambient temperature [degC]; default the source's own, else each
        vehicle's default (:data:`cevm.core.sweep.AMBIENT_ORIGINS`)
    confidence : the probability with which the verdict and the largest payload keep the
        reserve (fit the tank), in [0.5, 1); default 0.5: the point estimate (module notes)

    The payload search is exact on whole kilograms: see the module notes (convexity).
    An ICE vehicle without ``tank_l`` has no fuel limit: its payload is limited by
    ``max_gross_kg`` (or the cap) only and ``feasible`` is NaN (unknown).
    """
    vehicles = tuple(vehicles)
    nv = len(vehicles)
    base = np.array([v.kerb_mass_kg if v.kerb_mass_kg is not None else v.mass_kg for v in vehicles])
    if payload_kg is not None and mass_kg is not None:
        raise CevmError("give a payload or a gross mass, not both")
    physical_inputs.soc_pct(soc_start_pct, reserve_pct)
    if payload_kg is not None:
        mass = base + float(physical_inputs.payloads_kg(payload_kg))
    elif mass_kg is not None:
        mass = np.full(nv, float(physical_inputs.masses_for(vehicles, mass_kg)))
    else:
        mass = np.array([v.mass_kg for v in vehicles], dtype=np.float64)
    if not (isinstance(confidence, (int, float)) and 0.5 <= confidence < 1.0):
        raise CevmError(f"the confidence must be at least 0.5 and below 1, got {confidence!r}")
    f = _LoadFunction(source, vehicles, base, soc_start_pct, reserve_pct, ice_braking, ambient_c,
                      confidence=None if confidence == 0.5 else confidence)  # 0.5: the mean, as predict
    ps = f.pset
    vi = np.arange(nv)
    at, total, terms = f.evaluate(vi, mass - base)
    sd_at = f.sd(vi, mass, terms)
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = np.where(ps.is_ev, sd_at / np.abs(total), 0.0)
        sd_load = np.where(ps.is_ev, rel * np.abs(at), sd_at)
    p_ok = distribution.prob_at_most(at, sd_load, f.budget)
    p_ok = np.where(ps.is_ev | np.isfinite(ps.tank_l), p_ok, np.nan)
    max_gross = np.array([np.inf if v.max_gross_kg is None else v.max_gross_kg for v in vehicles])
    over = mass > max_gross
    # totals at the evaluated load
    energy = total
    fuel = np.full(nv, np.nan)
    soc_end = np.full(nv, np.nan)
    soc_min = np.full(nv, np.nan)
    ev = ps.is_ev
    if ev.any():
        soc_end[ev] = soc_start_pct - 100.0 * energy[ev] / ps.battery_j[ev]
        soc_min[ev] = soc_start_pct - 100.0 * at[ev] / ps.battery_j[ev]
    fuel[~ev] = at[~ev]
    with np.errstate(invalid="ignore"):
        tank_margin = ps.tank_l - fuel
        ok_load = (np.where(ev, soc_min >= reserve_pct, tank_margin >= 0) if confidence == 0.5
                   else p_ok >= confidence)
    known = ev | np.isfinite(ps.tank_l)

    max_p, min_p, limited = _payload_range(f, known, max_gross, base, payload_cap_kg)
    follow = _follow(source, vehicles, mass)
    max_p, min_p, limited = _within_follow_limits(source, vehicles, base, max_p, min_p, limited)
    # the reserve or the tank at the confidence (the point estimate at 0.5), then every flag
    flags = limits.verdict(is_ev=ev, over_max_gross=over, over_power=follow[0], over_speed=follow[1],
                           energy_ok=np.where(known, ok_load.astype(float), np.nan))
    feasible = flags["feasible"]
    ranges = load_ranges(source, vehicles, mass, soc_start_pct=soc_start_pct, reserve_pct=reserve_pct,
                     ice_braking=ice_braking, ambient_c=ambient_c)
    empty = np.isfinite(ranges["empty_at_m"]) & ev
    with np.errstate(invalid="ignore"):
        soc_end[empty | (soc_end < 0)] = np.nan  # it does not reach the end: no charge below 0
        soc_min[empty | (soc_min < 0)] = 0.0
    return Feasibility(
        **ranges,
        over_power=follow[0],
        over_speed=follow[1],
        power_demand_w=follow[2],
        reserve_ok=flags["reserve_ok"],
        tank_ok=flags["tank_ok"],
        soc_start_pct=soc_start_pct,
        reserve_pct=reserve_pct,
        source=source,
        vehicles=vehicles,
        mass_kg=mass,
        payload_kg=mass - base,
        over_max_gross=over,
        energy_j=energy,
        fuel_l=fuel,
        soc_end_pct=soc_end,
        soc_min_pct=soc_min,
        reserve_margin_pct=soc_min - reserve_pct,
        tank_margin_l=tank_margin,
        feasible=feasible,
        max_payload_kg=max_p,
        min_payload_kg=min_p,
        limited_by=tuple(str(s) for s in limited),
        ambient_c=terms.ambient_c[:, 0],
        ambient_from=tuple(AMBIENT_ORIGINS[int(c)] for c in terms.ambient_from[:, 0]),
        confidence=float(confidence),
        sd=sd_at,
        p_ok=p_ok,
        interval_from=tuple(f.source_of(i) for i in range(nv)),
    )


def _payload_range(f: _LoadFunction, known: np.ndarray, max_gross: np.ndarray, base: np.ndarray,
                   payload_cap_kg: float | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The feasible payloads of each vehicle, searched on whole kg in [0, the gross limit
    or the cap]: (largest, smallest, what limits the largest: "max_gross_kg",
    "payload_cap", "reserve", "tank" or "infeasible"). ``known``: whether a vehicle has
    a limit besides its gross mass (an EV's reserve, an ICE's tank)."""
    ps = f.pset
    nv = base.size
    if payload_cap_kg is not None and not (math.isfinite(payload_cap_kg) and payload_cap_kg >= 0):
        raise CevmError("the payload cap must be finite and >= 0 kg")
    cap = np.where(np.isfinite(max_gross), max_gross - base, base if payload_cap_kg is None else payload_cap_kg)
    plim = np.floor(np.maximum(cap, 0.0) + 1e-9).astype(np.int64)
    capped_by = np.where(np.isfinite(max_gross), "max_gross_kg", "payload_cap")
    max_p = np.full(nv, np.nan)
    min_p = np.full(nv, np.nan)
    limited = np.array(["infeasible"] * nv, dtype=object)
    unlimited = ~known  # ICE without tank: only the gross limit / cap
    max_p[unlimited] = plim[unlimited]
    min_p[unlimited] = 0.0
    limited[unlimited] = capped_by[unlimited]
    idx = np.flatnonzero(known)
    if idx.size:
        zero = np.zeros(idx.size, dtype=np.int64)
        ok0 = f.ok(idx, zero.astype(np.float64))
        oklim = f.ok(idx, plim[idx].astype(np.float64))
        kind = np.where(ps.is_ev[idx], "reserve", "tank")
        # (a) the empty vehicle passes: feasible payloads are [0, p_max] (convexity)
        a = ok0 & oklim
        max_p[idx[a]] = plim[idx[a]]
        limited[idx[a]] = capped_by[idx[a]]
        b = np.flatnonzero(ok0 & ~oklim)
        if b.size:
            max_p[idx[b]] = _last_true(f.ok, idx[b], zero[b], plim[idx[b]])
            limited[idx[b]] = kind[b]
        min_p[idx[ok0]] = 0.0
        # (b) the empty vehicle fails: find the minimum of the convex load function
        c = np.flatnonzero(~ok0)
        if c.size:
            vc = idx[c]

            def rising(v, p):  # f(p + 1) >= f(p): False then True for a convex f
                return f(v, p + 1.0) >= f(v, p)

            pl = plim[vc]
            pstar = _first_true(lambda v, p: np.where(p >= plim[v], True, rising(v, np.minimum(p, plim[v]))),
                                vc, np.zeros(c.size, dtype=np.int64), pl)
            okstar = f.ok(vc, pstar.astype(np.float64))
            d = np.flatnonzero(okstar)
            if d.size:
                vd = vc[d]
                min_p[vd] = _first_true(f.ok, vd, np.zeros(d.size, dtype=np.int64), pstar[d])
                okl = f.ok(vd, plim[vd].astype(np.float64))
                hi_ok = np.flatnonzero(okl)
                max_p[vd[hi_ok]] = plim[vd[hi_ok]]
                limited[vd[hi_ok]] = capped_by[vd[hi_ok]]
                lo_ok = np.flatnonzero(~okl)
                if lo_ok.size:
                    vl = vd[lo_ok]
                    max_p[vl] = _last_true(f.ok, vl, pstar[d][lo_ok], plim[vl])
                    limited[vl] = kind[c][d][lo_ok]
    return max_p, min_p, limited


def _follow(source: Source, vehicles: Sequence[Vehicle], mass_kg: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(over_power, over_speed, power_demand_w) of each vehicle at its mass (arrays (V,):
    :func:`cevm.core.limits.follow_flags`)."""
    out = np.full((3, len(vehicles)), np.nan)
    for i, v in enumerate(vehicles):
        if v.max_power_w is not None or v.max_speed_mps is not None:
            out[:, i] = [a[0] for a in limits.follow_flags(source.demand, v, mass_kg[i])]
    return out[0], out[1], out[2]


def _within_follow_limits(source: Source, vehicles: Sequence[Vehicle], base: np.ndarray, max_p: np.ndarray,
                          min_p: np.ndarray, limited: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The payload range [min_p, max_p] of each vehicle narrowed to the masses at which it
    can follow the source: within ``max_power_kw`` (an interval of masses,
    :meth:`cevm.core.limits.Demand.power_mass_window`) and, at any mass, within
    ``max_speed_kmh``; ``limited`` says ``"max_power_kw"`` or ``"max_speed_kmh"`` where
    that is what limits the largest payload."""
    max_p, min_p, limited = max_p.copy(), min_p.copy(), np.array(limited, dtype=object)
    for i, v in enumerate(vehicles):
        if not np.isfinite(max_p[i]):
            continue
        if v.max_speed_mps is not None and source.demand.over_speed(v.max_speed_mps):
            max_p[i], min_p[i], limited[i] = np.nan, np.nan, "max_speed_kmh"
            continue
        if v.max_power_w is None:
            continue
        lo, hi = source.demand.power_mass_window(v.max_power_w, v.cda_m2, v.cr)
        top = math.floor(hi - base[i] + 1e-9) if math.isfinite(hi) else math.inf
        bottom = max(0.0, math.ceil(lo - base[i] - 1e-9)) if math.isfinite(lo) else math.inf
        if math.isnan(lo) or top < max(min_p[i], bottom):
            max_p[i], min_p[i], limited[i] = np.nan, np.nan, "max_power_kw"
            continue
        if top < max_p[i]:
            max_p[i], limited[i] = top, "max_power_kw"
        min_p[i] = max(min_p[i], bottom)
    return max_p, min_p, limited


def load_ranges(source: Source, vehicles: Sequence[Vehicle], mass_kg: np.ndarray, *,
                soc_start_pct: float = DEFAULT_SOC_START_PCT, reserve_pct: float = DEFAULT_RESERVE_PCT,
                ice_braking: str | None = None, ambient_c: float | None = None) -> dict[str, np.ndarray]:
    """Each vehicle at its own gross mass ``mass_kg`` (V,) on ``source``: where it first
    crosses its reserve and runs empty, and its range (:func:`cevm.core.sweep.source_ranges`,
    the source repeated), as the ``Feasibility`` fields of those names (arrays (V,), SI)."""
    out = {k: np.full(len(vehicles), np.nan) for k in RANGE_FIELDS}
    for i, v in enumerate(vehicles):
        ps = PredictionSet.build([v], mass_kg=[float(mass_kg[i])], ice_braking=ice_braking, ambient_c=ambient_c)
        b = predict_source(source, ps, soc_start_pct=soc_start_pct, reserve_pct=reserve_pct, ranges=True)
        for k in RANGE_FIELDS:
            out[k][i] = getattr(b, k)[0]
    return out
