"""Stored trips as a person reads them: the edge that turns the store's SI rows into ISO
8601 times, km and kWh (:func:`format_trips`, :func:`format_utc`)."""

from __future__ import annotations

import numpy as np
import pandas as pd

from cevm.units import J_PER_KWH


def format_utc(t_s: np.ndarray | pd.Series | float) -> pd.Series | str:
    """ISO 8601 UTC strings with ``Z`` (rounded to the second) for seconds since the
    Unix epoch; a scalar gives a str."""
    scalar = np.ndim(t_s) == 0
    ts = pd.to_datetime(pd.Series(np.atleast_1d(np.asarray(t_s, dtype=np.float64))), unit="s", utc=True)
    out = ts.dt.round("s").dt.strftime("%Y-%m-%dT%H:%M:%SZ")
    return str(out.iloc[0]) if scalar else out


def format_trips(df: pd.DataFrame) -> pd.DataFrame:
    """The display table of :meth:`~cevm.store.TripStore.list_trips` rows: trip_id, vehicle_id,
    start_utc (ISO 8601, ``Z``), duration_s, distance_km, measured_fuel_l,
    measured_energy_kwh (from joules, 1 kWh = 3.6e6 J), dsm_coverage_pct,
    elevation_source, source_file. Unmeasured values are NaN."""
    kind = df["measured_kind"]
    value = df["measured_value"].astype(np.float64)
    return pd.DataFrame(
        {
            "trip_id": df["trip_id"],
            "vehicle_id": df["vehicle_id"],
            "start_utc": format_utc(df["start_utc_s"]).to_numpy(),
            "duration_s": df["duration_s"].astype(np.float64),
            "distance_km": df["distance_m"].astype(np.float64) / 1000.0,
            "measured_fuel_l": value.where(kind == "fuel_l"),
            "measured_energy_kwh": value.where(kind == "energy_j") / J_PER_KWH,
            "dsm_coverage_pct": df["dsm_coverage_pct"].astype(np.float64),
            "elevation_source": df["elevation_source"],
            "source_file": df["source_file"],
        },
        index=df.index,
    )
