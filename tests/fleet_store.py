"""A small trip store for the store's command-line tests: real vectors and profiles of
synthetic trips whose measured consumption is the plain per-step model (tests/reference.py).

- ``HGV-77``: 8 diesel trips over 4 days, fuel measured at eta 0.38 (no-credit braking),
  gross weight logged on odd trips (alternately 30 t and 40 t), none on even ones;
- ``EB-09``: 3 electric-bus trips, battery energy measured at eta 0.7;
- route ``R1``: the first bus trip, then the shipped urban-bus cycle.

:func:`make_fleet` adds a vehicle file of the plain CE model the diesel trips were
measured with (:data:`HGV_FILE`); :func:`write_manifest` a manifest of their true masses.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cevm.core.cycle import drive_cycle_vector
from cevm.core.trip import Measurement, Trip
from cevm.io import load_vehicle
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


# A diesel truck as the trips were measured: the plain CE model (no idle or other terms:
# stated as zeros, since a term a file leaves out takes its class's prior).
HGV_FILE = """name = "Test HGV"
powertrain = "ice"
idle_fuel_lph = 0.0
heating_fuel_lph_per_k = 0.0
cooling_fuel_lph_per_k = 0.0
kerb_mass_kg = 18000.0
max_gross_kg = 44000.0
cda_m2 = 6.62
cr = 0.0066
eta = {eta}
fuel_lhv_mj_per_l = 35.8
ice_braking = "no-credit"
tank_l = 400.0
[detailed]
"""


def make_fleet(tmp_path: Path):
    """The store of :func:`make_store` in ``tmp_path``, a vehicle file of the plain CE
    model at the diesel trips' eta, and each diesel trip's (start, duration)."""
    db = tmp_path / "cevm.sqlite"
    ids = make_store(db, tmp_path / "logs")
    hgv = tmp_path / "hgv.toml"  # the plain CE model at the eta the trips were measured with
    hgv.write_text(HGV_FILE.format(eta=HGV_ETA))
    with TripStore(db) as st:
        df = st.list_trips(vehicle_id="HGV-77")
    starts = dict(zip(df["trip_id"], zip(df["start_utc_s"], df["duration_s"], strict=True), strict=True))
    return db, ids, hgv, starts


def unlogged(ids):
    """The diesel trips without a logged gross weight (trip_index 0 of each file)."""
    return ids["HGV-77"][0::2]


def iso_local(t_s: float, zone: str) -> str:
    import datetime as dt
    from zoneinfo import ZoneInfo

    return dt.datetime.fromtimestamp(t_s, ZoneInfo(zone)).strftime("%Y-%m-%d %H:%M:%S")


def write_manifest(path: Path, ids, starts, zone="Europe/London") -> Path:
    """A TMS export, as a German office writes it: ';', decimal comma, tonnes, local times;
    one window per unlogged trip (around its midpoint), plus rows that cannot apply."""
    lines = ["Kennzeichen;Abfahrt;Ankunft;Gesamtgewicht (t)"]
    for tid in unlogged(ids):
        t0, dur = starts[tid]
        lines.append(f"HGV-77;{iso_local(t0 - 600, zone)};{iso_local(t0 + dur + 600, zone)};"
                     f"{ids['hgv_mass_kg'][tid] / 1000:.3f}".replace(".", ","))
    day0 = starts[ids["HGV-77"][0]][0]
    lines.append(f"HGV-77;{iso_local(day0 - 86400, zone)};{iso_local(day0 - 80000, zone)};35,0")  # no trip
    lines.append(f"HGV-77;{iso_local(day0 - 3600, zone)};{iso_local(day0 + 86400, zone)};35,0")  # both of day 0
    lines.append(f"XX-01;{iso_local(day0, zone)};{iso_local(day0 + 60, zone)};35,0")  # unknown vehicle
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path
