"""A source's samples and its plain per-step terms in driving order.

A :class:`LegProfile` is one leg's samples (time, speed, elevation); a source (a cycle,
a stored trip, a route of legs) drives its legs one after another. :class:`StepTable`
holds the per-step terms of :func:`cevm.core.cycle.step_terms` of all its legs in driving
order, with the time and distance at each step's start: what the range
(:mod:`~cevm.core.sweep.ranges`), the power a source asks (:mod:`~cevm.core.sweep.power`)
and the energy along the way (:mod:`~cevm.core.sweep.stepenergy`) are computed from.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from cevm.core.cycle import CR0_DEFAULT, PAPER_PHYSICS, Physics, step_terms


@dataclass(frozen=True, eq=False)
class LegProfile:
    """One leg's samples: time [s] (strictly increasing), speed [m/s], road elevation [m]
    (None for a flat road). Consecutive legs are *not* joined by a step: a route's
    vector is the sum of its legs' vectors, and its profile is the legs one after
    another."""

    time_s: np.ndarray
    speed_mps: np.ndarray
    elevation_m: np.ndarray | None = None

    @classmethod
    def from_profile(cls, profile: Mapping[str, np.ndarray]) -> LegProfile:
        """From a stored profile dict (:meth:`cevm.store.TripStore.load_profile`)."""
        h = profile.get("elevation_m")
        return cls(np.asarray(profile["time_s"], np.float64), np.asarray(profile["speed_mps"], np.float64),
                   None if h is None else np.asarray(h, np.float64))



def edges(values: np.ndarray) -> np.ndarray:
    """[0, cumsum(values)]: the running sum at each step's start and, last, the total
    (n + 1 values; a sequential sum, so any of its values equals the sum of the steps
    before it, added in order)."""
    out = np.empty(values.size + 1)
    out[0] = 0.0
    np.cumsum(values, out=out[1:])
    return out


@dataclass(frozen=True, eq=False)
class StepTable:
    """A source's per-step terms in driving order (legs one after another), SI: ``k``
    (kinetic, J/kg), ``x`` = k + e (J/kg), ``a`` (J/m^2), ``r`` (J/kg per unit Cr),
    ``dt`` [s], ``simplified`` (criterion 8 with the source's Cr0), ``moving`` (a > 0);
    ``v_max_mps`` the source's top speed, ``g_mps2`` the gravity r was made with. Built
    on first use and kept: ``dd`` (distance of the step [m]), ``t_edges`` and
    ``d_edges`` (time [s] and distance [m] at each step's start, then at the end), ``t0``
    and ``d0`` (at each step's start)."""

    k: np.ndarray
    x: np.ndarray
    a: np.ndarray
    r: np.ndarray
    dt: np.ndarray
    simplified: np.ndarray
    moving: np.ndarray
    v_max_mps: float
    g_mps2: float = PAPER_PHYSICS.g_mps2

    @property
    def n(self) -> int:
        return int(self.dt.size)

    @cached_property
    def dd(self) -> np.ndarray:
        return self.r / self.g_mps2

    @cached_property
    def t_edges(self) -> np.ndarray:
        return edges(self.dt)

    @cached_property
    def d_edges(self) -> np.ndarray:
        return edges(self.dd)

    @property
    def t0(self) -> np.ndarray:
        return self.t_edges[:-1]

    @property
    def d0(self) -> np.ndarray:
        return self.d_edges[:-1]

    def d0_at(self, j: np.ndarray) -> np.ndarray:
        """``d0[j]``, the distance [m] at the start of steps ``j``, without the running
        distance of the whole source unless it was made already: the running sum of the
        steps up to the last of ``j``, the same sum in the same order, so the same values
        (a crossing a tenth of the way along a long source sums a tenth of it)."""
        j = np.asarray(j)
        if "d_edges" in self.__dict__ or j.size == 0:
            return np.asarray(self.d0[j])
        return np.asarray(edges(self.r[: int(j.max())] / self.g_mps2)[j])

    @property
    def duration_s(self) -> float:
        return float(self.t_edges[-1]) if self.n else 0.0

    @property
    def distance_m(self) -> float:
        return float(self.d_edges[-1]) if self.n else 0.0


def build_step_table(legs: Sequence[LegProfile], *, cr0: float = CR0_DEFAULT,
                     physics: Physics = PAPER_PHYSICS) -> StepTable:
    """The :class:`StepTable` of a source's legs: :func:`cevm.core.cycle.step_terms` of
    each leg, once."""
    ks, xs, as_, rs, dts = [], [], [], [], []
    vmax = 0.0
    for leg in legs:
        st = step_terms(leg.time_s, leg.speed_mps, leg.elevation_m, physics)
        ks.append(st.k)
        xs.append(st.k + st.e)
        as_.append(st.a)
        rs.append(st.r)
        dts.append(st.dt)
        if leg.speed_mps.size:
            vmax = max(vmax, float(np.max(leg.speed_mps)))
    z = np.zeros(0)
    k, x, a, r, dt = (v[0] if len(v) == 1 else np.concatenate(v) if v else z  # one leg: no copy
                      for v in (ks, xs, as_, rs, dts))
    return StepTable(k=k, x=x, a=a, r=r, dt=dt, simplified=(x + cr0 * r) > 0, moving=a > 0, v_max_mps=vmax,
                     g_mps2=physics.g_mps2)
