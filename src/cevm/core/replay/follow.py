"""Whether the candidate can follow each logged trip (pure): its power, speed and gross
mass limits judged trip by trip by the one verdict of every command
(:mod:`cevm.core.limits`), exactly as ``cevm predict -v CANDIDATE --vehicle-id ID``
judges the same stored trips.

A duty with a trip the candidate cannot follow does not complete, whatever its energy:
the candidate would not have driven that trip as logged (too slow to keep the logged
speed, too weak to climb or accelerate as logged, or too heavy to carry the load). Each
such duty names its first such trip and the limit, with the figures
(``speed on trip T (124 km/h > 80)``).

The power and speed a trip asks (:class:`cevm.core.limits.Demand`) come from its stored
samples, read one trip at a time through a callable (None: unreadable, the flags
unknown, NaN) and dropped once judged, so a large fleet's profiles are never held
together; a candidate without ``max_power_kw`` and ``max_speed_kmh`` reads none.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from cevm.core import limits
from cevm.core.limits import Demand
from cevm.core.vehicle import Vehicle
from cevm.units import KMH_TO_MPS


@dataclass(frozen=True, eq=False)
class TripFollow:
    """Per trip (arrays (n,)): ``over_power``, ``over_speed``, ``over_max_gross`` (1.0 /
    0.0, NaN: not checked, the vehicle lacks the limit or the trip's samples are
    unreadable), ``power_demand_w`` (the peak 5-s wheel power at the trip's mass [W],
    NaN: not read) and ``top_speed_mps`` (its held top speed [m/s], NaN: not read);
    ``read`` the trips whose samples were read."""

    over_power: np.ndarray
    over_speed: np.ndarray
    over_max_gross: np.ndarray
    power_demand_w: np.ndarray
    top_speed_mps: np.ndarray
    read: int = 0

    @property
    def fails(self) -> np.ndarray:
        """Per trip: the candidate cannot follow it (a flag is 1.0)."""
        return (self.over_power == 1.0) | (self.over_speed == 1.0) | (self.over_max_gross == 1.0)

    def duty_follows(self, first: np.ndarray) -> np.ndarray:
        """Per duty (``first``: its first trip): every trip of it is followed (or not
        known not to be)."""
        if not first.size:
            return np.ones(0, dtype=bool)
        return ~np.logical_or.reduceat(self.fails, first)

    def duty_flag(self, name: str, first: np.ndarray) -> np.ndarray:
        """Per duty, flag ``name`` over its trips: 1.0 if any trip fails it, 0.0 if every
        trip was checked and passes, NaN if it was not checked on some trip and none fails."""
        x = getattr(self, name)
        if not first.size:
            return np.zeros(0)
        fails = np.logical_or.reduceat(x == 1.0, first)
        unknown = np.logical_or.reduceat(np.isnan(x), first)
        return np.where(fails, 1.0, np.where(unknown, np.nan, 0.0))


def trip_follow(vehicle: Vehicle, mass_kg: np.ndarray, demand: Callable[[int], Demand | None] | None
                ) -> TripFollow:
    """The flags of ``vehicle`` on each trip at its gross mass ``mass_kg[i]`` [kg]
    (:func:`cevm.core.limits.follow_flags`, the gross mass against ``max_gross_kg`` as
    :class:`cevm.core.sweep.PredictionSet` does); ``demand(i)`` gives trip i's demand (None:
    unreadable; None: power and speed not checked). Trips are read one at a time, only
    when the vehicle has ``max_power_kw`` or ``max_speed_kmh``."""
    m = np.asarray(mass_kg, dtype=np.float64)
    n = m.size
    over_p, over_v = np.full(n, np.nan), np.full(n, np.nan)
    peak, top = np.full(n, np.nan), np.full(n, np.nan)
    gross = np.zeros(n) if vehicle.max_gross_kg is None else (m > vehicle.max_gross_kg).astype(np.float64)
    read = 0
    if demand is not None and (vehicle.max_power_w is not None or vehicle.max_speed_mps is not None):
        for i in range(n):  # one trip's samples at a time (module notes), not a loop over samples
            d = demand(i)
            read += 1
            if d is None:
                continue
            p, v, w = limits.follow_flags(d, vehicle, m[i])
            over_p[i], over_v[i], peak[i] = p[0], v[0], w[0]
            top[i] = d.top_speed_mps
    return TripFollow(over_power=over_p, over_speed=over_v, over_max_gross=gross, power_demand_w=peak,
                      top_speed_mps=top, read=read)


def duty_reasons(follow: TripFollow, first: np.ndarray, last: np.ndarray, trip_ids: Sequence[str],
                 vehicle: Vehicle, mass_kg: np.ndarray) -> list[str]:
    """Per duty, why the candidate cannot drive it as logged ("" where it can): its first
    trip that fails a limit, each limit it fails with the figures, e.g. ``speed on trip T
    (124 km/h > 80)``, ``power on trip T (412 kW > 235)``, ``gross mass on trip T
    (45,100 kg > 44,000)``; and how many more of its trips fail."""
    out = []
    fails = follow.fails
    for a, b in zip(first.tolist(), last.tolist(), strict=True):
        bad = np.flatnonzero(fails[a:b + 1]) + a
        if not bad.size:
            out.append("")
            continue
        i = int(bad[0])
        what = []
        if follow.over_speed[i] == 1.0 and vehicle.max_speed_mps is not None:
            what.append(f"speed on trip {trip_ids[i]} ({follow.top_speed_mps[i] / KMH_TO_MPS:,.0f} km/h > "
                        f"{vehicle.max_speed_mps / KMH_TO_MPS:,.0f})")
        if follow.over_power[i] == 1.0 and vehicle.max_power_w is not None:
            what.append(f"power on trip {trip_ids[i]} ({follow.power_demand_w[i] / 1e3:,.0f} kW > "
                        f"{vehicle.max_power_w / 1e3:,.0f})")
        if follow.over_max_gross[i] == 1.0 and vehicle.max_gross_kg is not None:
            what.append(f"gross mass on trip {trip_ids[i]} ({mass_kg[i]:,.0f} kg > {vehicle.max_gross_kg:,.0f})")
        more = bad.size - 1
        out.append("; ".join(what) + (f"; {more} more trip(s) of the duty" if more else ""))
    return out
