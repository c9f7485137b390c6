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
from cevm.core.cycle import CycleVector
from cevm.core.trip import Measurement
from cevm.core.vehicle import Vehicle
from cevm.errors import CevmError
from cevm.store.trips import TripStore


@dataclass(frozen=True)
class TripSelection:
    trips: tuple[TripData, ...]
    notes: tuple[str, ...]


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


def trips_for_calibration(store: TripStore, vehicle_id: str, vehicle: Vehicle) -> TripSelection:
    """The stored trips of ``vehicle_id`` as :class:`TripData`.

    Mass: the trip's measured gross weight where the logger reported one, else the
    vehicle file's mass. Group: the trip's UTC day, so trips of one day (one driver, one
    load, one weather) are held out together in cross-validation.
    """
    df = store.list_trips(vehicle_id=vehicle_id)
    if df.empty:
        known = ", ".join(store.vehicle_ids()[:10]) or "none"
        raise CevmError(f"vehicle id {vehicle_id!r} has no stored trips (stored vehicle ids: {known}); see 'cevm trips'")
    vectors = store.load_vectors(vehicle_id=vehicle_id)
    out: list[TripData] = []
    n_weight = 0
    for r in df.itertuples(index=False):
        meas = None
        if isinstance(r.measured_kind, str) and np.isfinite(r.measured_value):
            meas = Measurement(r.measured_kind, float(r.measured_value), str(r.measured_source),
                               float(r.measured_resolution), float(r.measured_uncertainty))
        gw = r.gross_weight_kg
        has_weight = gw is not None and np.isfinite(gw) and gw > 0
        n_weight += has_weight
        day = np.datetime_as_string(np.datetime64(int(r.start_utc_s), "s"), unit="D")
        out.append(TripData.from_measurement(
            r.trip_id, CycleVector.from_bytes(vectors[r.trip_id]), meas,
            mass_kg=float(gw) if has_weight else vehicle.mass_kg,
            quality=elevation_quality(r.elevation_source, r.dsm_coverage_pct),
            group=day,
        ))
    if n_weight == len(out):
        notes = [f"mass: the measured gross weight of each of the {len(out)} trips"]
    else:
        notes = [f"mass: measured gross weight on {n_weight} of {len(out)} trips, the vehicle file's "
                 f"{vehicle.mass_kg:,.0f} kg on the other {len(out) - n_weight} (give trips a gross weight for a better fit)"]
    return TripSelection(tuple(out), tuple(notes))

