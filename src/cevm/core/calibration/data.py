"""The trips a calibration sees: one :class:`TripData` per trip, screened into a
:class:`TripSet` of arrays (pure).

Screening excludes, with the reason, trips that cannot inform a fit: no or a non-positive
measurement, no uncertainty, a measurement worse than ``max_rel_uncertainty``, trips
shorter than ``min_distance_m``, a measurement of the wrong kind for the powertrain,
masses that are not positive, vectors whose Cr0 is above the vehicle's Cr, and trips
whose wheel energy is not positive (a descent: consumption is not driven by it).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TypeGuard

import numpy as np

from cevm.core.cycle import CycleVector
from cevm.core.energy import AMBIENT_RANGE_C
from cevm.core.model import braking_weight, wheel_energy_j
from cevm.core.trip import Measurement
from cevm.core.vehicle import Vehicle
from cevm.errors import CevmError


class CalibrationError(CevmError):
    """The data cannot calibrate the vehicle at all (e.g. too few usable trips)."""


@dataclass(frozen=True)
class TripData:
    """One trip as the fit sees it.

    Attributes
    ----------
    trip_id
        unique id (e.g. :attr:`cevm.core.trip.Trip.trip_id`)
    vector
        the trip's cached :class:`~cevm.core.cycle.CycleVector`
    mass_kg
        gross mass of the trip [kg]; None: the vehicle's ``mass_kg``
    measured
        measured consumption: litres of fuel (ICE) or joules at the battery (EV);
        None or NaN when the trip has no measurement
    uncertainty
        1-sigma error of ``measured``, same unit
    quality
        extra weight factor in (0, 1] (DSM coverage, gaps...), default 1
    group
        key of trips that must stay together in cross-validation (day, route), or None
    kind
        "fuel_l" or "energy_j" when known; checked against the powertrain
    ambient_c
        the trip's mean ambient temperature [degC], None when not logged
    start_utc_s
        start [s since the Unix epoch], None when unknown (ranges only)
    standstill_s
        time at standstill with a measured rate [s] (evidence), None
    standstill_rate
        the measured mean battery power [W] (EV) or fuel rate [l/s] (ICE)
        while standing still: evidence that fitted auxiliary and idle terms are checked
        against, never an input of the model
    mass_source
        where ``mass_kg`` comes from ("logged", "manifest", "vehicle file"...)
    systematic_uncertainty
        the part of ``uncertainty`` that is the meter's calibration
        error, common to every trip it measured (same unit; None: unknown, the whole
        uncertainty is taken as the trip's own); a calibration absorbs it into its
        coefficients, so it is no trip-to-trip scatter but an uncertainty of them all
    flags
        notes on the trip that a calibration reports beside it (e.g. a splice the
        cleaner could not repair)
    """

    trip_id: str
    vector: CycleVector
    mass_kg: float | None
    measured: float | None
    uncertainty: float | None
    quality: float = 1.0
    group: str | None = None
    kind: str | None = None
    ambient_c: float | None = None
    start_utc_s: float | None = None
    standstill_s: float | None = None
    standstill_rate: float | None = None
    mass_source: str | None = None
    systematic_uncertainty: float | None = None
    flags: tuple[str, ...] = ()

    @classmethod
    def from_measurement(cls, trip_id: str, vector: CycleVector, measurement: Measurement | None, *,
                         mass_kg: float | None = None, quality: float = 1.0, group: str | None = None,
                         **more) -> TripData:
        """A :class:`TripData` from a :class:`cevm.core.trip.Measurement` (None: unmeasured);
        ``more``: the optional fields (ambient_c, start_utc_s, ...)."""
        if measurement is None:
            return cls(trip_id, vector, mass_kg, None, None, quality, group, **more)
        return cls(trip_id, vector, mass_kg, measurement.value, measurement.uncertainty, quality, group,
                   measurement.kind, **more)


@dataclass(frozen=True, eq=False)
class TripSet:
    """The usable trips as arrays (one element per trip), SI units.

    ``u`` is the relative 1-sigma measurement error, floored; ``u_random`` its part that
    is the trip's own (the meter's systematic part ``u_sys`` taken out, floored);
    ``ambient_c`` NaN where not logged; ``traction`` the vectors' traction time [s];
    ``standstill_rate`` NaN where not measured; ``flags`` per trip (:class:`TripData`).
    """

    ids: tuple
    groups: tuple
    vectors: tuple
    mass: np.ndarray
    y: np.ndarray
    sigma: np.ndarray
    u: np.ndarray
    q: np.ndarray
    duration: np.ndarray
    idle: np.ndarray
    k_pos: np.ndarray
    traction: np.ndarray
    distance: np.ndarray
    ambient_c: np.ndarray
    start_utc_s: np.ndarray
    standstill_s: np.ndarray
    standstill_rate: np.ndarray
    mass_sources: tuple
    u_random: np.ndarray | None = None
    u_sys: np.ndarray | None = None
    flags: tuple = ()

    def __post_init__(self):
        if self.u_random is None:
            object.__setattr__(self, "u_random", self.u)
        if self.u_sys is None:
            object.__setattr__(self, "u_sys", np.zeros_like(self.u))
        if not self.flags:
            object.__setattr__(self, "flags", tuple(() for _ in range(self.y.size)))

    @property
    def n(self) -> int:
        return int(self.y.size)

    @property
    def has_temperature(self) -> np.ndarray:
        return np.isfinite(self.ambient_c)

    def subset(self, idx: np.ndarray) -> TripSet:
        """The trips at positions ``idx``."""
        idx = np.asarray(idx)
        pick = [int(i) for i in idx]
        assert self.u_random is not None and self.u_sys is not None  # set by __post_init__

        def tup(t: tuple) -> tuple:
            return tuple(t[i] for i in pick)

        return TripSet(
            ids=tup(self.ids), groups=tup(self.groups), vectors=tup(self.vectors), mass=self.mass[idx],
            y=self.y[idx], sigma=self.sigma[idx], u=self.u[idx], q=self.q[idx], duration=self.duration[idx],
            idle=self.idle[idx], k_pos=self.k_pos[idx], traction=self.traction[idx], distance=self.distance[idx],
            ambient_c=self.ambient_c[idx], start_utc_s=self.start_utc_s[idx],
            standstill_s=self.standstill_s[idx], standstill_rate=self.standstill_rate[idx],
            mass_sources=tup(self.mass_sources), u_random=self.u_random[idx], u_sys=self.u_sys[idx],
            flags=tup(self.flags),
        )


def _finite(x: object) -> TypeGuard[float]:
    return x is not None and isinstance(x, (int, float, np.floating, np.integer)) and math.isfinite(x)


def _opt(x: object) -> float:
    return float(x) if _finite(x) else math.nan


def select_trips(vehicle: Vehicle, trips: Sequence[TripData], max_rel_uncertainty: float,
                 min_distance_m: float, rel_uncertainty_floor: float) -> tuple[TripSet, dict]:
    """Screen the trips: the usable ones as a :class:`TripSet`, the others with a reason."""
    want_kind = "energy_j" if vehicle.is_ev else "fuel_l"
    w_prior = vehicle.eta**2 if vehicle.is_ev else braking_weight(vehicle.ice_braking)
    t_lo, t_hi = AMBIENT_RANGE_C
    seen: set = set()
    excluded: dict = {}
    keep: list = []
    for t in trips:
        if t.trip_id in seen:
            raise CalibrationError(f"trip id {t.trip_id!r} appears twice")
        seen.add(t.trip_id)
        mass = vehicle.mass_kg if t.mass_kg is None else t.mass_kg
        meas, s = _opt(t.measured), _opt(t.uncertainty)  # NaN where missing
        reason = None
        if t.kind is not None and t.kind != want_kind:
            reason = (f"measurement kind {t.kind!r} does not fit an {'EV' if vehicle.is_ev else 'ICE'} "
                      f"(needs {want_kind!r})")
        elif not _finite(meas):
            reason = "no measured consumption"
        elif meas <= 0:
            reason = f"measured consumption {meas:g} <= 0"
        elif not _finite(s) or s < 0:
            reason = "no valid measurement uncertainty" if not _finite(s) else f"uncertainty {s:g} < 0"
        elif not (_finite(t.quality) and 0 < t.quality <= 1):
            reason = f"quality {t.quality!r} is not in (0, 1]"
        elif not (_finite(mass) and mass > 0):
            reason = f"mass {mass!r} kg is not > 0"
        elif t.vector.distance_m < min_distance_m:
            reason = f"distance {t.vector.distance_m:.0f} m < {min_distance_m:.0f} m"
        elif s / meas > max_rel_uncertainty:
            reason = (f"relative uncertainty {100 * s / meas:.1f} % > {100 * max_rel_uncertainty:.1f} % "
                      f"({s:g} on {meas:g})")
        elif vehicle.cr < t.vector.cr0:
            reason = (f"the vector's Cr0 = {t.vector.cr0:g} is above the vehicle's Cr = {vehicle.cr:g}: "
                      "recompute the vector with a lower cr0")
        elif _finite(t.ambient_c) and not t_lo <= t.ambient_c <= t_hi:
            reason = f"ambient temperature {t.ambient_c:g} degC is outside {t_lo:g}..{t_hi:g} degC"
        else:
            e = float(wheel_energy_j(t.vector, float(mass), float(vehicle.cda_m2), float(vehicle.cr),
                                     float(w_prior)))
            if e <= 0:
                reason = f"predicted wheel energy {e:.3g} J <= 0 (a descent): consumption is not driven by it"
        if reason is None:
            keep.append((t, float(mass)))
        else:
            excluded[t.trip_id] = reason
    y = np.array([t.measured for t, _ in keep], dtype=np.float64)
    sigma = np.array([t.uncertainty for t, _ in keep], dtype=np.float64)
    sys_ = np.array([min(t.systematic_uncertainty, t.uncertainty) if _finite(t.systematic_uncertainty) else 0.0
                     for t, _ in keep], dtype=np.float64)
    u = np.maximum(sigma / y, rel_uncertainty_floor) if y.size else y
    u_sys = sys_ / y if y.size else y
    data = TripSet(
        ids=tuple(t.trip_id for t, _ in keep),
        groups=tuple(t.group for t, _ in keep),
        vectors=tuple(t.vector for t, _ in keep),
        mass=np.array([m for _, m in keep], dtype=np.float64),
        y=y,
        sigma=sigma,
        u=u,
        q=np.array([t.quality for t, _ in keep], dtype=np.float64),
        duration=np.array([t.vector.duration_s for t, _ in keep], dtype=np.float64),
        idle=np.array([t.vector.idle_s for t, _ in keep], dtype=np.float64),
        k_pos=np.array([t.vector.k_pos for t, _ in keep], dtype=np.float64),
        traction=np.array([t.vector.traction_s for t, _ in keep], dtype=np.float64),
        distance=np.array([t.vector.distance_m for t, _ in keep], dtype=np.float64),
        ambient_c=np.array([_opt(t.ambient_c) for t, _ in keep], dtype=np.float64),
        start_utc_s=np.array([_opt(t.start_utc_s) for t, _ in keep], dtype=np.float64),
        standstill_s=np.array([_opt(t.standstill_s) for t, _ in keep], dtype=np.float64),
        standstill_rate=np.array([_opt(t.standstill_rate) for t, _ in keep], dtype=np.float64),
        mass_sources=tuple(t.mass_source for t, _ in keep),
        u_random=np.maximum(np.sqrt(np.maximum(u * u - u_sys * u_sys, 0.0)), rel_uncertainty_floor) if y.size else y,
        u_sys=u_sys,
        flags=tuple(tuple(t.flags) for t, _ in keep),
    )
    return data, excluded
