"""Stored trips as a person reads them: the edge that turns the store's SI rows into ISO
8601 times, km and kWh (:func:`format_trips`, :func:`format_utc`)."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from cevm.lazy import pd
from cevm.units import J_PER_KWH


def format_utc(t_s: np.ndarray | pd.Series | float) -> pd.Series | str:
    """ISO 8601 UTC strings with ``Z`` (rounded to the second) for seconds since the
    Unix epoch; a scalar gives a str."""
    scalar = np.ndim(t_s) == 0
    ts = pd.to_datetime(pd.Series(np.atleast_1d(np.asarray(t_s, dtype=np.float64))), unit="s", utc=True)
    out = ts.dt.round("s").dt.strftime("%Y-%m-%dT%H:%M:%SZ")
    return str(out.iloc[0]) if scalar else out


def format_trips(df: pd.DataFrame, masses: Mapping | None = None) -> pd.DataFrame:
    """The display table of :meth:`~cevm.store.TripStore.list_trips` rows: trip_id, vehicle_id,
    start_utc (ISO 8601, ``Z``), duration_s, distance_km, measured_fuel_l,
    start_soc_pct (logged at the start), standstill_before_s (since the vehicle's previous
    trip), measured_energy_kwh (from joules, :data:`cevm.units.J_PER_KWH`), dsm_coverage_pct,
    elevation_source, source_file; with ``masses`` (:func:`cevm.store.masses.trip_masses`)
    also each trip's mass: mass_kg (the gross mass it is predicted at, as far as known
    without a vehicle file: given, else logged), payload_kg (a payload given to it),
    mass_source (``manifest tms.csv:12``, ``by hand``, ``logged``, ``vehicle file``),
    logged_gross_kg and mass_vs_logged_pct (a given gross mass against the logged one).
    Unknown values are NaN."""
    kind = df["measured_kind"]
    value = df["measured_value"].astype(np.float64)
    out = pd.DataFrame(
        {
            "trip_id": df["trip_id"],
            "vehicle_id": df["vehicle_id"],
            "start_utc": np.asarray(format_utc(df["start_utc_s"])),  # a Series in, a Series out
            "duration_s": df["duration_s"].astype(np.float64),
            "distance_km": df["distance_m"].astype(np.float64) / 1000.0,
            "start_soc_pct": df["start_soc_pct"].astype(np.float64),
            "standstill_before_s": df["standstill_before_s"].astype(np.float64),
            "measured_fuel_l": value.where(kind == "fuel_l"),
            "measured_energy_kwh": value.where(kind == "energy_j") / J_PER_KWH,
            "dsm_coverage_pct": df["dsm_coverage_pct"].astype(np.float64),
            "elevation_source": df["elevation_source"],
            "source_file": df["source_file"],
        },
        index=df.index,
    )
    if masses is not None:
        nan = float("nan")
        ms = [masses[t] for t in df["trip_id"]]
        gross = [m.assigned.mass_kg if m.assigned is not None and m.assigned.kind == "gross" else
                 (m.logged_gross_kg if m.assigned is None and m.logged_gross_kg is not None else nan) for m in ms]
        out["mass_kg"] = np.array(gross, dtype=np.float64)
        out["payload_kg"] = np.array([m.assigned.mass_kg if m.assigned is not None and m.assigned.kind == "payload"
                                      else nan for m in ms], dtype=np.float64)
        out["mass_source"] = [m.describe() + (" (payload)" if m.assigned is not None and m.assigned.kind == "payload"
                                              else "") for m in ms]
        logged = np.array([nan if m.logged_gross_kg is None else m.logged_gross_kg for m in ms], dtype=np.float64)
        out["logged_gross_kg"] = logged
        with np.errstate(invalid="ignore"):
            given = np.array([m.assigned.mass_kg if m.assigned is not None and m.assigned.kind == "gross" else nan
                              for m in ms], dtype=np.float64)
            out["mass_vs_logged_pct"] = 100.0 * (given - logged) / logged
    return out
