"""Ranges and probabilities of a sweep's rows (pure): each row's predictive distribution
(:mod:`cevm.core.predictive`), the probability that it completes its source with the
reserve kept (EV) or within its tank (ICE), and what of it lies outside what its
vehicle's calibration saw.

The probability of keeping the reserve: the energy the vehicle may draw before its
state of charge reaches the reserve is B = (SoC_start - reserve) x battery; the energy it
needs to its lowest state of charge along the source is E_min (the whole source's when
that is its end, less when it regains charge after it: a descent), and
P(reserve kept) = P(E_min <= B), E_min with the source's relative uncertainty (sd_min =
sd x E_min / E: the uncertainty of a part of the source in proportion to its energy) and
the distribution of every interval (:mod:`cevm.core.distribution`), so that a row whose
high end keeps the reserve has p_reserve_ok at least the interval's upper level. Where
the row runs empty on the way, E_min is the whole source's energy. An ICE completes its
source within its tank with P(fuel <= tank_l).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from cevm.core import distribution
from cevm.core.predictive import Features, predictive
from cevm.core.vehicle import EXTRAPOLATION_AXES, extrapolation_mask, extrapolation_text

if TYPE_CHECKING:
    from cevm.core.sweep.block import SweepBlock

#: Where a row's interval comes from: a calibration's posterior, the vehicle class's
#: priors (a file never calibrated), or nothing (a vehicle built without priors).
INTERVAL_SOURCES = ("posterior", "prior", "none")
#: The texts of every extrapolation mask (:func:`cevm.core.vehicle.extrapolation_mask`).
EXTRAPOLATION_TEXTS = tuple(extrapolation_text(m) for m in range(1 << len(EXTRAPOLATION_AXES)))


@dataclass(frozen=True, eq=False)
class RowRanges:
    """Per row of a sweep block: ``mean`` (the block's energy [J] or fuel [l]), its
    standard deviation ``sd``, ``source`` (codes into :data:`INTERVAL_SOURCES`) and
    ``extrapolation`` (masks, texts in :data:`EXTRAPOLATION_TEXTS`)."""

    mean: np.ndarray
    sd: np.ndarray
    source: np.ndarray
    extrapolation: np.ndarray

    def bounds(self, level: float) -> tuple[np.ndarray, np.ndarray]:
        """The central interval at ``level`` of every row."""
        return distribution.interval(self.mean, self.sd, level)

    def prob_at_most(self, budget: np.ndarray) -> np.ndarray:
        """P(consumption <= budget) per row (the budget in the rows' unit)."""
        return distribution.prob_at_most(self.mean, self.sd, budget)


def block_ranges(block: SweepBlock) -> RowRanges:
    """The :class:`RowRanges` of a :class:`cevm.core.sweep.SweepBlock`: its rows' vehicles
    at their masses and temperatures on its source."""
    pset, src = block.pset, block.source
    n = pset.n
    mean = np.where(pset.is_ev, block.energy_j, block.fuel_l)
    sd = np.zeros(n)
    code = np.full(n, INTERVAL_SOURCES.index("none"), dtype=np.int64)
    vec = src.vector
    speed = vec.distance_m / vec.duration_s if vec.duration_s > 0 else 0.0
    idle = vec.idle_s / vec.duration_s if vec.duration_s > 0 else 0.0
    mask = np.zeros(n, dtype=np.int64)
    for v in np.unique(pset.vehicle_index):
        rows = np.flatnonzero(pset.vehicle_index == v)
        veh = pset.vehicles[int(v)]
        braking = pset.braking[int(v)] or None
        if src.leg_vectors is not None:  # a route taken leg by leg: the sum of its legs' distributions
            p = _route_total(veh, src, pset.mass_kg[rows], block.ambient_c[rows], block.ambient_from[rows] == 0,
                             braking)
        else:
            f = Features.of(vec, veh, pset.mass_kg[rows], block.ambient_c[rows])
            p = predictive(veh, f, ice_braking=braking)
        sd[rows] = np.broadcast_to(p.sd, (rows.size,))
        code[rows] = INTERVAL_SOURCES.index(p.source)
        mask[rows] = extrapolation_mask(veh.calibration, mass_kg=pset.mass_kg[rows], ambient_c=block.ambient_c[rows],
                                        mean_speed_mps=speed, idle_share=idle)
    return RowRanges(mean, sd, code, mask)


def _route_total(veh, src, mass_kg: np.ndarray, ambient_c: np.ndarray, given: np.ndarray, braking: str | None):
    """The predictive distribution of each row's route as the sum of its legs
    (:func:`cevm.core.predictive.total`), each leg at its own temperature (a row whose
    temperature was ``given``, the run's --ambient-c, at that one) and the row's mass."""
    from cevm.core.predictive import total

    legs = src.leg_vectors
    own = np.asarray(src.leg_ambient_c, dtype=np.float64)
    f = Features.concat([Features.of(vec, veh, mass_kg, np.where(given, ambient_c, own[i]))
                         for i, vec in enumerate(legs)])
    groups = np.tile(np.arange(mass_kg.size), len(legs))
    return total(veh, f, groups, ice_braking=braking)


def p_reserve_ok(block: SweepBlock, ranges: RowRanges, soc_start_pct: float, reserve_pct: float) -> np.ndarray:
    """P(an EV row completes its source with its lowest state of charge at or above the
    reserve) (module notes); NaN for ICE rows."""
    pset = block.pset
    battery = pset.battery_j
    e = block.energy_j
    with np.errstate(invalid="ignore"):
        e_min = np.where(np.isfinite(block.soc_min_pct) & (block.soc_min_pct > 0),
                         (soc_start_pct - block.soc_min_pct) / 100.0 * battery, e)
        e_min = np.where(np.isfinite(e_min), e_min, e)
        rel = np.where(np.abs(e) > 0, ranges.sd / np.abs(e), 0.0)
        sd_min = rel * np.abs(e_min)
        budget = (soc_start_pct - reserve_pct) / 100.0 * battery
    p = distribution.prob_at_most(e_min, sd_min, budget)
    return np.where(pset.is_ev, p, np.nan)


def p_tank_ok(block: SweepBlock, ranges: RowRanges) -> np.ndarray:
    """P(an ICE row's fuel fits its tank); NaN for EV rows and tanks not known."""
    pset = block.pset
    p = ranges.prob_at_most(pset.tank_l)
    return np.where(~pset.is_ev & np.isfinite(pset.tank_l), p, np.nan)
