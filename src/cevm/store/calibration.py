"""Stored trips for calibration: a vehicle's trips in the store -> the pure fit's
:class:`~cevm.core.calibration.TripData`.

The fitting itself is pure (:mod:`cevm.core.calibration`); this module reads the store
and decides each trip's mass, quality factor and group. Writing the calibrated vehicle
file is :mod:`cevm.io.calibrated`, the paper's figures 5 and 7 :mod:`cevm.io.plots`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cevm.core.calibration import TripData
from cevm.core.trip import Measurement
from cevm.core.vehicle import Vehicle
from cevm.errors import CevmError
from cevm.store.failures import DamagedTripError
from cevm.store.trips import TripStore


@dataclass(frozen=True)
class TripSelection:
    """A vehicle's stored trips for a fit: ``trips``; ``notes`` for the report (the
    masses used, ...); ``damaged``: the trips left out because their blobs are damaged
    (:class:`~cevm.store.failures.DamagedTripError`, each naming its trip)."""

    trips: tuple[TripData, ...]
    notes: tuple[str, ...]
    damaged: tuple[DamagedTripError, ...] = ()


def elevation_quality(elevation_source: str | None, dsm_coverage_pct: float | None) -> float:
    """Quality factor q in (0, 1] of a trip's road profile, for the calibration weights.

    q = 0.5 + 0.5 x DSM coverage for DSM-based profiles; 0.5 for GPS altitude or a flat
    road (a climb the model cannot see is an error the measurement cannot show). Equal
    factors cancel: only differences between trips move the fit.
    """
    cov = 0.0 if dsm_coverage_pct is None or not np.isfinite(dsm_coverage_pct) else float(dsm_coverage_pct)
    if elevation_source and elevation_source.startswith("dsm"):
        return 0.5 + 0.5 * min(max(cov, 0.0), 100.0) / 100.0
    return 0.5


def _opt(x) -> float | None:
    """A stored REAL (NaN for NULL) as the fit's optional float."""
    return None if x is None or not np.isfinite(x) else float(x)


def trips_for_calibration(store: TripStore, vehicle_id: str, vehicle: Vehicle) -> TripSelection:
    """The stored trips of ``vehicle_id`` as :class:`TripData`.

    Mass: the trip's measured gross weight where the logger reported one, else the
    vehicle file's mass. Group: the trip's UTC day, so trips of one day (one driver, one
    load, one weather) are held out together in cross-validation. Evidence: the trip's
    logged mean ambient temperature, its start, its time at standstill and the rate
    measured then (battery power for an EV, fuel rate for an ICE). Trips whose vector is
    damaged are left out and listed in :attr:`TripSelection.damaged`.
    """
    df = store.list_trips(vehicle_id=vehicle_id)
    if df.empty:
        known = ", ".join(store.vehicle_ids()[:10]) or "none"
        raise CevmError(f"vehicle id {vehicle_id!r} has no stored trips (stored vehicle ids: {known}); see 'cevm trips'")
    damaged: list[DamagedTripError] = []
    vectors = store.load_cycle_vectors(vehicle_id=vehicle_id, on_damaged=damaged.append)
    rate_column = "standstill_power_w" if vehicle.is_ev else "standstill_fuel_lps"
    out: list[TripData] = []
    n_weight = 0
    for r in df.itertuples(index=False):
        if r.trip_id not in vectors:
            continue  # damaged
        meas = None
        if isinstance(r.measured_kind, str) and np.isfinite(r.measured_value):
            meas = Measurement(r.measured_kind, float(r.measured_value), str(r.measured_source),
                               float(r.measured_resolution), float(r.measured_uncertainty))
        gw = r.gross_weight_kg
        has_weight = gw is not None and np.isfinite(gw) and gw > 0
        n_weight += has_weight
        day = np.datetime_as_string(np.datetime64(int(r.start_utc_s), "s"), unit="D")
        out.append(TripData.from_measurement(
            r.trip_id, vectors[r.trip_id], meas,
            mass_kg=float(gw) if has_weight else vehicle.mass_kg,
            quality=elevation_quality(r.elevation_source, r.dsm_coverage_pct),
            group=day,
            mass_source="logged" if has_weight else "vehicle file",
            ambient_c=_opt(r.ambient_temp_c),
            start_utc_s=float(r.start_utc_s),
            standstill_s=_opt(r.standstill_s),
            standstill_rate=_opt(getattr(r, rate_column)),
        ))
    if not out:
        raise CevmError(f"vehicle id {vehicle_id!r}: every stored trip is damaged ({damaged[0]}); "
                        "'cevm store check' lists them")
    if n_weight == len(out):
        notes = [f"mass: the measured gross weight of each of the {len(out)} trips"]
    else:
        notes = [f"mass: measured gross weight on {n_weight} of {len(out)} trips, the vehicle file's "
                 f"{vehicle.mass_kg:,.0f} kg on the other {len(out) - n_weight} (give trips a gross weight for a better fit)"]
    if damaged:
        notes.append(f"{len(damaged)} damaged trip(s) left out: " + ", ".join(e.trip_id for e in damaged[:10])
                     + (" ..." if len(damaged) > 10 else ""))
    return TripSelection(tuple(out), tuple(notes), tuple(damaged))
