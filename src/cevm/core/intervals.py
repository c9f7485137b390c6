"""Ranges and probabilities of a sweep's rows (pure): each row's predictive distribution
(:mod:`cevm.core.predictive`), the probability that it completes its source with the
reserve kept (EV) or within its tank (ICE), and what of it lies outside what its
vehicle's calibration saw.

The probability of keeping the reserve: the energy the vehicle may draw before its
state of charge reaches the reserve is B = (SoC_start - reserve) x battery; the energy it
needs to its lowest state of charge along the source is E_min (the whole source's when
that is its end, less when it regains charge after it: a descent), and
P(reserve kept) = P(E_min <= B), E_min taken as Gaussian with the source's relative
uncertainty (sd_min = sd x E_min / E: the uncertainty of a part of the source in
proportion to its energy). Where the row runs empty on the way, E_min is the whole
source's energy. An ICE completes its source within its tank with P(fuel <= tank_l).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy.special import ndtr, ndtri

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
        z = float(ndtri(0.5 + 0.5 * level))
        return self.mean - z * self.sd, self.mean + z * self.sd

    def prob_at_most(self, budget: np.ndarray) -> np.ndarray:
        """P(consumption <= budget) per row (the budget in the rows' unit)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            z = (budget - self.mean) / self.sd
        return np.where(self.sd > 0, ndtr(z), np.where(budget >= self.mean, 1.0, 0.0))


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
        f = Features.of(vec, veh, pset.mass_kg[rows], block.ambient_c[rows])
        braking = pset.braking[int(v)] or None
        p = predictive(veh, f, ice_braking=braking)
        sd[rows] = np.broadcast_to(p.sd, (rows.size,))
        code[rows] = INTERVAL_SOURCES.index(p.source)
        mask[rows] = extrapolation_mask(veh.calibration, mass_kg=pset.mass_kg[rows], ambient_c=block.ambient_c[rows],
                                        mean_speed_mps=speed, idle_share=idle)
    return RowRanges(mean, sd, code, mask)


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
        z = (budget - e_min) / sd_min
    p = np.where(sd_min > 0, ndtr(z), np.where(budget >= e_min, 1.0, 0.0))
    return np.where(pset.is_ev, p, np.nan)


def p_tank_ok(block: SweepBlock, ranges: RowRanges) -> np.ndarray:
    """P(an ICE row's fuel fits its tank); NaN for EV rows and tanks not known."""
    pset = block.pset
    p = ranges.prob_at_most(pset.tank_l)
    return np.where(~pset.is_ev & np.isfinite(pset.tank_l), p, np.nan)
