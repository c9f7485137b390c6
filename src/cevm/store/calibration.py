"""Stored trips for calibration: a vehicle's trips in the store -> the pure fit's
:class:`~cevm.core.calibration.TripData`.

The fitting itself is pure (:mod:`cevm.core.calibration`); this module reads the store
and decides each trip's mass, quality factor and group. Writing the calibrated vehicle
file is :mod:`cevm.io.calibrated`, the paper's figures 5 and 7 :mod:`cevm.io.plots`.
"""

from __future__ import annotations

import json
import math
from collections import Counter
from dataclasses import dataclass

import numpy as np

from cevm.core.calibration import TripData
from cevm.core.replay.duties import logged_twice
from cevm.core.vehicle import Vehicle
from cevm.errors import CevmError
from cevm.store.failures import DamagedTripError
from cevm.store.masses import trip_masses
from cevm.store.queries import row_measurement
from cevm.store.tripstore import TripStore


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


#: A trip whose recording the cleaner found spliced (a lasting speed jump it could not
#: repair, :mod:`cevm.ingest.cleaning`: its quality's ``speed_jumps``) weighs this share
#: of its road-profile quality: its model error counts twice (the distance and the energy
#: of the join are unknown, the rest of the trip is sound).
SPLICED_WEIGHT = 0.5


def _quality(quality_json: str | None) -> dict:
    if not quality_json:
        return {}
    try:
        q = json.loads(quality_json)
    except ValueError:
        return {}
    return q if isinstance(q, dict) else {}


def systematic_uncertainty(quality: dict | str | None) -> float | None:
    """The chosen consumption source's systematic (meter calibration) uncertainty, from a
    trip's stored quality (:mod:`cevm.ingest.consumption`); None when it does not say."""
    q = _quality(quality) if not isinstance(quality, dict) else quality
    cons = q.get("consumption") or {}
    if not isinstance(cons, dict):
        return None
    chosen = cons.get("source")
    for src in cons.get("sources") or ():
        if isinstance(src, dict) and src.get("source") == chosen:
            v = src.get("systematic_uncertainty")
            return float(v) if isinstance(v, (int, float)) and math.isfinite(v) and v >= 0 else None
    return None


def splice_flags(quality: dict) -> tuple[str, ...]:
    """The note a calibration shows beside a trip whose recording was spliced (its
    quality's ``speed_jumps``), or none."""
    jumps = quality.get("speed_jumps") or []
    if not isinstance(jumps, list) or not jumps:
        return ()
    big = jumps[0] if isinstance(jumps[0], dict) else {}
    try:
        step = abs(float(big["to_mps"]) - float(big["from_mps"])) * 3.6
        when = np.datetime_as_string(np.datetime64(int(big["utc_s"]), "s"), unit="s")
        dt = float(big.get("dt_s", 1.0))
        largest = f", the largest {step:.0f} km/h in {dt:g} s at {when}Z"
    except (KeyError, TypeError, ValueError):
        largest = ""
    n = int(quality.get("speed_unresolved_jumps") or len(jumps))
    return (f"spliced recording: {n} lasting speed jump{'s' if n != 1 else ''}{largest} (the cleaner could not "
            f"repair it): weighted {SPLICED_WEIGHT:g}",)


def trips_for_calibration(store: TripStore, vehicle_id: str, vehicle: Vehicle) -> TripSelection:
    """The stored trips of ``vehicle_id`` as :class:`TripData`.

    Mass (:mod:`cevm.store.masses`): a mass given to the trip (a manifest, by hand; a
    payload on the vehicle file's kerb mass), else the gross weight its logger recorded,
    else the vehicle file's mass; each trip's ``mass_source`` says which, the notes count
    them and name the trips whose given and logged masses disagree by more than 5 %.
    Group: the trip's UTC day, so trips of one day (one driver, one load, one weather)
    are held out together in cross-validation. A trip lying mostly inside an earlier one
    (:func:`~cevm.core.replay.duties.logged_twice`: the same driving logged twice) is
    left out and named in the notes. Evidence: the trip's logged mean ambient
    temperature, its start, its time at standstill and the rate measured then (battery
    power for an EV, fuel rate for an ICE). Trips whose vector is damaged are left out
    and listed in :attr:`TripSelection.damaged`.
    """
    df = store.list_trips(vehicle_id=vehicle_id)
    if df.empty:
        known = ", ".join(store.vehicle_ids()[:10]) or "none"
        raise CevmError(f"vehicle id {vehicle_id!r} has no stored trips (stored vehicle ids: {known}); "
                        "see 'cevm trips'")
    df = df.sort_values(["start_utc_s", "trip_id"], kind="stable")
    twice = logged_twice(df["start_utc_s"].to_numpy(dtype=np.float64),
                         (df["start_utc_s"] + df["duration_s"]).to_numpy(dtype=np.float64))
    twice_ids = list(df["trip_id"][twice])
    df = df[~twice]
    damaged: list[DamagedTripError] = []
    vectors = store.load_cycle_vectors(vehicle_id=vehicle_id, on_damaged=damaged.append)
    masses = trip_masses(store, df)
    rate_column = "standstill_power_w" if vehicle.is_ev else "standstill_fuel_lps"
    out: list[TripData] = []
    origins: Counter = Counter()
    disagreements = []
    for r in df.itertuples(index=False):
        if r.trip_id not in vectors:
            continue  # damaged
        mass = masses[r.trip_id]
        origins[mass.origin] += 1
        text = mass.disagreement(vehicle)
        if text:
            disagreements.append(text)
        day = np.datetime_as_string(np.datetime64(int(r.start_utc_s), "s"), unit="D")
        quality = _quality(r.quality_json)
        flags = splice_flags(quality)
        q = elevation_quality(r.elevation_source, r.dsm_coverage_pct) * (SPLICED_WEIGHT if flags else 1.0)
        out.append(TripData.from_measurement(
            r.trip_id, vectors[r.trip_id],
            row_measurement(r.measured_kind, r.measured_value, r.measured_source, r.measured_resolution,
                            r.measured_uncertainty),
            mass_kg=mass.gross_kg(vehicle),
            quality=q,
            group=day,
            mass_source=mass.origin,
            ambient_c=_opt(r.ambient_temp_c),
            start_utc_s=float(r.start_utc_s),
            standstill_s=_opt(r.standstill_s),
            standstill_rate=_opt(getattr(r, rate_column)),
            systematic_uncertainty=systematic_uncertainty(quality),
            flags=flags,
        ))
    if not out:
        raise CevmError(f"vehicle id {vehicle_id!r}: every stored trip is damaged ({damaged[0]}); "
                        "'cevm store check' lists them")
    own = len(out) - origins["vehicle file"]
    counts = ", ".join(f"{n} {what}" for what, n in sorted(origins.items(), key=lambda kv: (-kv[1], kv[0])))
    if not origins["vehicle file"]:
        notes = [f"mass: each of the {len(out)} trips at its own ({counts})"]
    else:
        notes = [f"mass: {own} of {len(out)} trips at their own, the other {origins['vehicle file']} at the vehicle "
                 f"file's {vehicle.mass_kg:,.0f} kg ({counts}; give trips their masses with 'cevm trips set-mass' "
                 "for a better fit)"]
    if twice_ids:
        notes.append(f"{len(twice_ids)} trip(s) lie mostly inside an earlier trip of the vehicle, the same driving "
                     "logged twice (two loggers, or one log under two names): each fitted once, left out: "
                     + ", ".join(twice_ids[:10]) + (" ..." if len(twice_ids) > 10 else ""))
    spliced = [t.trip_id for t in out if t.flags]
    if spliced:
        notes.append(f"{len(spliced)} trip(s) with a spliced recording weighted {SPLICED_WEIGHT:g} (column flags): "
                     + ", ".join(spliced[:10]) + (" ..." if len(spliced) > 10 else ""))
    notes += [f"mass disagreement: {text}" for text in disagreements[:10]]
    if len(disagreements) > 10:
        notes.append(f"mass disagreement: ... and {len(disagreements) - 10} more trips ('cevm trips' shows them)")
    if damaged:
        notes.append(f"{len(damaged)} damaged trip(s) left out: " + ", ".join(e.trip_id for e in damaged[:10])
                     + (" ..." if len(damaged) > 10 else ""))
    return TripSelection(tuple(out), tuple(notes), tuple(damaged))
