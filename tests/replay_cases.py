"""Synthetic logged trips for the replay tests: real cycles (micro-trips with hills), their
vectors and step tables, vehicles written as files, and the plain per-step reference
(tests/reference.py) of each trip's energy and of where it crosses a level."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cevm.core.cycle import drive_cycle_vector
from cevm.core.replay import LoggedTrips
from cevm.core.sweep import LegProfile, build_step_table
from cevm.io import load_vehicle
from cevm_samplegen.cycles import MicroTripSpec, micro_trip_cycle
from reference import reference_consumption, reference_crossing

EV_FILE = """name = "Test e-truck"
powertrain = "ev"
kerb_mass_kg = 18000.0
payload_kg = 10000.0
cda_m2 = 5.0
cr = 0.005
eta = 0.88
battery_kwh = {battery}
aux_power_kw = 3.0
aux_heating_kw_per_k = 0.2
heating_below_c = 12.0
warmup_kwh_per_k = 0.05
"""

ICE_FILE = """name = "Test diesel"
powertrain = "ice"
kerb_mass_kg = 18000.0
cda_m2 = 6.0
cr = 0.006
eta = 0.38
fuel_lhv_mj_per_l = 35.8
idle_fuel_lph = 1.8
running_fuel_lph = 2.0
kinetic_eta = 0.3
heating_fuel_lph_per_k = 0.02
warmup_fuel_l_per_k = 0.01
heating_below_c = 14.0
ice_braking = "no-credit"
tank_l = {tank}
"""


def vehicle(tmp_path: Path, text: str, name: str):
    p = tmp_path / f"{name}.toml"
    p.write_text(text)
    return load_vehicle(p)


def ev(tmp_path: Path, battery_kwh: float = 300.0):
    return vehicle(tmp_path, EV_FILE.format(battery=battery_kwh), f"ev{battery_kwh:g}")


def ice(tmp_path: Path, tank_l: float = 400.0):
    return vehicle(tmp_path, ICE_FILE.format(tank=tank_l), f"ice{tank_l:g}")


def cycle(seed: int, n_trips: int = 6, descent_m: float = 0.0):
    """A micro-trip cycle; ``descent_m``: a road that falls this much over its last third."""
    c = micro_trip_cycle(MicroTripSpec(n_trips=n_trips, cruise_kmh=(30.0, 70.0), hill_amplitude_m=8.0), seed=seed)
    h = c.elevation_m.copy()
    if descent_m:
        n = h.size
        ramp = np.clip((np.arange(n) - 2 * n / 3) / (n / 3), 0.0, 1.0)
        h = h - descent_m * ramp
    return c.time_s, c.speed_mps, h


def logged(cycles, starts, *, masses=None, temps=None, positions=None, vid="T-1", day=None) -> LoggedTrips:
    """A vehicle's trips of ``cycles`` (t, v, h) starting at ``starts`` [s]."""
    n = len(cycles)
    vecs = tuple(drive_cycle_vector(t, v, h) for t, v, h in cycles)
    dur = np.array([t[-1] - t[0] for t, _, _ in cycles])
    start = np.asarray(starts, dtype=np.float64)
    pos = positions if positions is not None else (None,) * 4
    return LoggedTrips(vehicle_id=vid, trip_ids=tuple(f"{vid}:{i}" for i in range(n)), start_s=start, end_s=start + dur,
                       distance_m=np.array([v.distance_m for v in vecs]), vectors=vecs,
                       gross_kg=np.full(n, np.nan) if masses is None else np.asarray(masses, dtype=np.float64),
                       payload_kg=np.full(n, np.nan), mass_source=tuple(["logged"] * n),
                       ambient_c=np.full(n, np.nan) if temps is None else np.asarray(temps, dtype=np.float64),
                       start_lat=pos[0], start_lon=pos[1], end_lat=pos[2], end_lon=pos[3],
                       day=None if day is None else np.asarray(day))


def tables(cycles, trips: LoggedTrips):
    """A ``step_table(i)`` callable over the trips' cycles, counting its calls."""
    calls = []

    def read(i: int):
        calls.append(i)
        t, v, h = cycles[i]
        vec = trips.vectors[i]
        return build_step_table([LegProfile(t, v, h)], cr0=vec.cr0, physics=vec.physics)

    read.calls = calls
    return read


def fields(veh) -> dict:
    """The vehicle's fields as tests/reference.py takes them (inputs, not the model)."""
    keys = ("eta", "cda_m2", "cr", "powertrain", "regen_eta", "aux_power_w", "aux_heating_w_per_k",
            "aux_cooling_w_per_k", "warmup_j_per_k", "fuel_lhv_j_per_l", "ice_braking", "kinetic_eta",
            "running_fuel_lps", "idle_fuel_lps", "heating_fuel_lps_per_k", "cooling_fuel_lps_per_k",
            "warmup_fuel_l_per_k", "heating_below_c", "cooling_above_c")
    return {k: getattr(veh, k) for k in keys}


def reference_energy(cyc, mass_kg: float, veh, ambient_c: float) -> float:
    t, v, h = cyc
    return reference_consumption(t, v, h, mass_kg, fields(veh), ambient_c)


def reference_ev_crossing(cyc, mass_kg: float, veh, ambient_c: float, level: float):
    """(time, distance) where an EV's energy drawn inside the trip first reaches ``level``."""
    f = fields(veh)
    heat = max(0.0, f["heating_below_c"] - ambient_c)
    aux = f["aux_power_w"] + f["aux_heating_w_per_k"] * heat
    regen = f["eta"] if f["regen_eta"] is None else f["regen_eta"]
    return reference_crossing([cyc], level, lump=f["warmup_j_per_k"] * heat, m=mass_kg, cda=f["cda_m2"], cr=f["cr"],
                              eta=f["eta"], w=f["eta"] * regen, aux=aux)


def reference_ev_peak(cyc, mass_kg: float, veh, ambient_c: float) -> tuple[float, float]:
    """(largest energy drawn inside the trip, energy at its end) [J], a plain loop."""
    from reference import reference_step_energy

    f = fields(veh)
    heat = max(0.0, f["heating_below_c"] - ambient_c)
    aux = f["aux_power_w"] + f["aux_heating_w_per_k"] * heat
    regen = f["eta"] if f["regen_eta"] is None else f["regen_eta"]
    t, v, h = cyc
    e = f["warmup_j_per_k"] * heat
    peak = e
    for i in range(len(t) - 1):
        g, _, _ = reference_step_energy(t, v, h, i, mass_kg, f["cda_m2"], f["cr"], eta=f["eta"],
                                        w=f["eta"] * regen, aux=aux)
        e += g
        peak = max(peak, e)
    return peak, e


# ------------------------------------------------------------------------ a store

DEPOT = (52.0600, -0.7040)
CUSTOMER = (52.2000, -0.9000)


def _stored_trip(vehicle_id, sha, k, start, cyc, gross_kg, temp_c, frm, to, source):
    from cevm.core.trip import Trip

    t, v, h = cyc
    dist = np.concatenate([[0.0], np.cumsum((v[1:] + v[:-1]) / 2 * np.diff(t))])
    frac = dist / dist[-1]
    lat = frm[0] + (to[0] - frm[0]) * frac
    lon = frm[1] + (to[1] - frm[1]) * frac
    return Trip(vehicle_id=vehicle_id, source_file=str(source), source_sha256=sha, trip_index=k, start_utc_s=start,
                time_s=t, speed_mps=v, distance_m=dist, lat_deg=lat, lon_deg=lon, elevation_m=h,
                elevation_source="dsm", dsm_coverage_pct=100.0, measured=None, gross_weight_kg=gross_kg,
                ambient_temp_c=temp_c)


def make_replay_store(path: Path, logs_dir: Path) -> dict:
    """A store of two logged trucks: ``TRK-1`` works three days 07:00 to about 13:00 from
    its depot (out to a customer, a 45 min stop there, back, a 40 min stop at the depot,
    a last round trip), ``TRK-2`` a night shift from 23:30 across midnight on two nights.
    Returns each vehicle's trips' (cycle, start, gross mass, temperature) in order."""
    from cevm.store import TripStore

    plan = {"TRK-1": [], "TRK-2": []}
    day0 = 1.6e9 - (1.6e9 % 86400)  # a midnight, UTC
    with TripStore(path) as st:
        for vid, days, first_h, legs in (("TRK-1", 3, 7.0, [(DEPOT, CUSTOMER, 45), (CUSTOMER, DEPOT, 40),
                                                             (DEPOT, DEPOT, 0)]),
                                         ("TRK-2", 2, 23.5, [(DEPOT, CUSTOMER, 35), (CUSTOMER, DEPOT, 0)])):
            for d in range(days):
                sha = f"{(d + 1) * (2 if vid == 'TRK-2' else 1):02x}" * 32
                t = day0 + d * 86400 + first_h * 3600
                trips, vectors = [], []
                for k, (frm, to, stop_min) in enumerate(legs):
                    cyc = cycle(200 + 10 * d + k + (50 if vid == "TRK-2" else 0), n_trips=12)
                    mass, temp = 30e3 + 4e3 * k, 4.0 + 3 * d
                    trip = _stored_trip(vid, sha, k, t, cyc, mass, temp, frm, to, logs_dir / f"{vid}-{d}.csv")
                    trips.append(trip)
                    vectors.append(drive_cycle_vector(*cyc).to_bytes())
                    plan[vid].append((cyc, t, mass, temp))
                    t += cyc[0][-1] + stop_min * 60
                st.replace_file_trips(logs_dir / f"{vid}-{d}.csv", trips, vectors, sha256=sha, size_bytes=1,
                                      mtime_s=0.0, profile="test")
    return plan
