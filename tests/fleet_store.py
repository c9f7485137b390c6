"""A small trip store for the store's command-line tests: real vectors and profiles of
synthetic trips whose measured consumption is the plain per-step model (tests/reference.py).

- ``HGV-77``: 8 diesel trips over 4 days, fuel measured at eta 0.38 (no-credit braking),
  gross weight logged on odd trips (alternately 30 t and 40 t), none on even ones;
- ``EB-09``: 3 electric-bus trips, battery energy measured at eta 0.7;
- route ``R1``: the first bus trip, then the shipped urban-bus cycle.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cevm.core.cycle import drive_cycle_vector
from cevm.core.trip import Measurement, Trip
from cevm.io import load_vehicle, read_cycle_csv
from cevm.store import TripStore
from cevm.store.routes import CycleLeg, TripLeg, add_route
from cevm_samplegen.cycles import MicroTripSpec, micro_trip_cycle
from reference import reference_wheel_energy_j

ROOT = Path(__file__).resolve().parents[1]
DIESEL = ROOT / "configs/vehicles/diesel-hgv.toml"
BUS = ROOT / "configs/vehicles/electric-bus.toml"
URBAN = ROOT / "configs/cycles/urban-bus.csv"
HGV_ETA, BUS_ETA = 0.38, 0.7


def _trip(vehicle_id: str, sha: str, k: int, start: float, cycle, measured: Measurement, gross_kg: float | None,
          source: Path) -> Trip:
    t, v, h = cycle.time_s, cycle.speed_mps, cycle.elevation_m
    dist = np.concatenate([[0.0], np.cumsum((v[1:] + v[:-1]) / 2 * np.diff(t))])
    return Trip(vehicle_id=vehicle_id, source_file=str(source), source_sha256=sha, trip_index=k, start_utc_s=start,
                time_s=t, speed_mps=v, distance_m=dist, lat_deg=np.full(t.size, 52.0), lon_deg=np.full(t.size, -0.7),
                elevation_m=h, elevation_source="dsm", dsm_coverage_pct=100.0, measured=measured,
                gross_weight_kg=gross_kg)


def make_store(path: Path, logs_dir: Path) -> dict:
    """Write the store at ``path`` (its trips "come from" files in ``logs_dir``); returns
    the trip ids by vehicle and the true masses of the diesel trips."""
    hgv = load_vehicle(DIESEL)
    bus = load_vehicle(BUS)
    out = {"HGV-77": [], "EB-09": [], "hgv_mass_kg": {}}
    with TripStore(path) as st:
        for day in range(4):
            sha = f"{day + 1:02x}" * 32
            trips, vectors = [], []
            for k in range(2):
                c = micro_trip_cycle(MicroTripSpec(n_trips=6 + day, cruise_kmh=(30.0, 70.0 + 5 * k)), seed=10 * day + k)
                mass = 30_000.0 if (day + k) % 2 else 40_000.0
                wheel = reference_wheel_energy_j(c.time_s, c.speed_mps, c.elevation_m, mass, hgv.cda_m2, hgv.cr,
                                                 "no-credit")
                fuel = wheel / (hgv.fuel_lhv_j_per_l * HGV_ETA)
                logged = mass if k == 1 else None
                trip = _trip("HGV-77", sha, k, 1.6e9 + day * 86400 + k * 7200, c,
                             Measurement("fuel_l", fuel, "fms_total_fuel", 0.01, 0.005 * fuel), logged,
                             logs_dir / f"hgv-{day}.csv")
                trips.append(trip)
                vectors.append(drive_cycle_vector(c.time_s, c.speed_mps, c.elevation_m).to_bytes())
                out["HGV-77"].append(trip.trip_id)
                out["hgv_mass_kg"][trip.trip_id] = mass
            st.replace_file_trips(logs_dir / f"hgv-{day}.csv", trips, vectors, sha256=sha, size_bytes=1, mtime_s=0.0,
                                  profile="test")
        sha = "bb" * 32
        trips, vectors = [], []
        for k in range(3):
            c = micro_trip_cycle(MicroTripSpec(n_trips=10, cruise_kmh=(20.0, 45.0)), seed=100 + k)
            wheel = reference_wheel_energy_j(c.time_s, c.speed_mps, c.elevation_m, bus.mass_kg, bus.cda_m2, bus.cr,
                                             "ev", BUS_ETA)
            energy = wheel / BUS_ETA
            trip = _trip("EB-09", sha, k, 1.61e9 + k * 3600, c,
                         Measurement("energy_j", energy, "counter", 3.6e4, 1e4), None, logs_dir / "bus.csv")
            trips.append(trip)
            vectors.append(drive_cycle_vector(c.time_s, c.speed_mps, c.elevation_m).to_bytes())
            out["EB-09"].append(trip.trip_id)
        st.replace_file_trips(logs_dir / "bus.csv", trips, vectors, sha256=sha, size_bytes=1, mtime_s=0.0,
                              profile="test")
        add_route(st, "R1", [TripLeg(out["EB-09"][0]), CycleLeg.from_file(URBAN)])
    return out


def urban_cycle():
    return read_cycle_csv(URBAN)
