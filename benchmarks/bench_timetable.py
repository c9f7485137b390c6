"""The held-out check of timetables: logged trips turned into timetables (their stops and
times only: no speed, no energy) and predicted from the timetable, against the same trips
predicted from their own logs with the same calibration; and the synthesis' speed.

    python benchmarks/bench_timetable.py                       # the sample logs' buses
    python benchmarks/bench_timetable.py --twizy ../shared/real-logs/twizy
    python benchmarks/bench_timetable.py --store S -v VEHICLE.toml --vehicle-id ID [...]

For each vehicle: its calibration (``cevm calibrate`` on all its trips, ``--no-nested``;
or the ``-v`` file as given with ``--store``); for each trip the timetable of
:func:`cevm.core.timetable.synthesis.timetable_from_log` (with its terminals' standing,
so that it lasts what the measurement covers) and the road's elevation along the trip
from its stored profile (what a feed's shape over the DSM gives), predicted by
:func:`cevm.core.timetable.energy.scheduled_trip_energy` with the driving learnt from the
vehicle's trips of the OTHER days (leave one day out); and the same trip predicted from
its own stored vector. Both against the measured energy: error e = (predicted -
measured) / measured, its mean and sd, and the share of trips inside their 90 %
intervals (the measurement's own uncertainty added, as calibrate's held-out check does).
Targets: the timetable's mean error within 5 points of the logs' and its sd within 1.5x;
90 % intervals holding 85-97 % of the trips.

Speed, as stop_times rows a second, on the held-out trips and on a feed-like set
(``--feed-trips`` timetables of 30 stops 250-600 m apart, times rounded to the minute
with arrival = departure, as most GTFS feeds give them; the bus prior): through
synthesise_trip (one cycle) and through scheduled_trip_energy (``--draws`` cycles, their
energies and spread), against the baseline in the same run of one CE vector per trip
(drive_cycle_vector of one cycle of the same length: the least any method that reduces
a cycle pays).
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from cevm.core.cycle import drive_cycle_vector  # noqa: E402
from cevm.core.predictive import Features, predictive  # noqa: E402
from cevm.core.timetable.driving import driving_prior  # noqa: E402
from cevm.core.timetable.energy import scheduled_trip_energy  # noqa: E402
from cevm.core.timetable.learning import learn_driving  # noqa: E402
from cevm.core.timetable.synthesis import synthesise_trip, timetable_from_log  # noqa: E402
from cevm.io.vehicles import load_vehicle  # noqa: E402
from cevm.store import TripStore  # noqa: E402
from cevm.store.calibration import trips_for_calibration  # noqa: E402

Z90 = 1.6448536269514722


def cevm(*args: str) -> None:
    res = subprocess.run([sys.executable, "-m", "cevm", *args], capture_output=True, text=True,
                         env={"PYTHONPATH": str(ROOT / "src"), "PATH": "/usr/bin:/bin"})
    if res.returncode not in (0, 3):
        raise SystemExit(f"cevm {' '.join(args)} failed ({res.returncode}):\n{res.stdout}\n{res.stderr}")


def sample_store(tmp: Path) -> tuple[Path, list[tuple[str, Path]]]:
    """The sample logs' buses ingested (with their passenger loads) and calibrated."""
    store = tmp / "buses.sqlite"
    logs = sorted(str(p) for p in (ROOT / "sample_logs/srf").iterdir() if p.name.startswith("EB-"))
    cevm("ingest", *logs, "--dsm", str(ROOT / "sample_logs/dsm"), "--manifest",
         str(ROOT / "sample_logs/manifests/bus-loads.csv"), "--store", str(store), "-q")
    out = []
    for vid in ("EB-01", "EB-02"):
        f = tmp / f"{vid}.toml"
        cevm("calibrate", "-v", str(ROOT / "configs/vehicles/electric-bus.toml"), "--vehicle-id", vid, "--store",
             str(store), "--no-nested", "--out", str(f), "--force")
        out.append((vid, f))
    return store, out


def twizy_store(tmp: Path, folder: Path) -> tuple[Path, list[tuple[str, Path]]]:
    store = tmp / "twizy.sqlite"
    cevm("ingest", str(folder), "--store", str(store), "-q")
    with TripStore.open(store, readonly=True) as st:
        ids = st.vehicle_ids()
    out = []
    for vid in ids:
        f = tmp / f"{vid}.toml"
        cevm("calibrate", "-v", str(ROOT / "configs/vehicles/renault-twizy.toml"), "--vehicle-id", vid, "--store",
             str(store), "--no-nested", "--out", str(f), "--force")
        out.append((vid, f))
    return store, out


def held_out(store: Path, vehicles: list[tuple[str, Path]], draws: int) -> dict:
    rows = []
    timing = {"rows": 0, "synth_s": 0.0, "energy_s": 0.0, "vector_s": 0.0}
    with TripStore.open(store, readonly=True) as st:
        for vid, vfile in vehicles:
            veh = load_vehicle(vfile)
            sel = trips_for_calibration(st, vid, veh)
            trips = [t for t in sel.trips if t.measured is not None and math.isfinite(t.measured) and t.measured > 0]
            profiles = {t.trip_id: st.load_profile(t.trip_id) for t in trips}
            days = sorted({t.group for t in trips})
            series = {t.trip_id: (profiles[t.trip_id]["time_s"], profiles[t.trip_id]["speed_mps"]) for t in trips}
            prior = driving_prior(veh.vehicle_class)
            for day in days:
                others = [series[t.trip_id] for t in trips if t.group != day]
                params = learn_driving(others, prior=prior, label=vid)
                for t in (t for t in trips if t.group == day):
                    p = profiles[t.trip_id]
                    mass = t.mass_kg if t.mass_kg is not None else veh.mass_kg
                    amb = t.ambient_c if t.ambient_c is not None else 10.0
                    msd = t.uncertainty if t.uncertainty is not None and math.isfinite(t.uncertainty) else 0.0
                    own = predictive(veh, Features.of(t.vector, veh, mass, amb), measurement_sd=msd)
                    stops, arr, dep = timetable_from_log(p["time_s"], p["speed_mps"])
                    prof_d = p["distance_m"] - p["distance_m"][0]
                    ok = np.isfinite(p["elevation_m"])
                    t0 = time.perf_counter()
                    synthesise_trip(stops, arr, dep, params, np.random.default_rng(0), with_terminals=True)
                    t1 = time.perf_counter()
                    e = scheduled_trip_energy(veh, stops, arr, dep, profile_dist_m=prof_d[ok] if ok.any() else None,
                                              profile_elev_m=p["elevation_m"][ok] if ok.any() else None,
                                              mass_kg=mass, ambient_c=amb, params=params, draws=draws, seed=1,
                                              with_terminals=True)
                    t2 = time.perf_counter()
                    drive_cycle_vector(p["time_s"], p["speed_mps"], np.where(ok, p["elevation_m"], 0.0))
                    t3 = time.perf_counter()
                    timing["rows"] += int(stops.size)
                    timing["synth_s"] += t1 - t0
                    timing["energy_s"] += t2 - t1
                    timing["vector_s"] += t3 - t2
                    scale = 1.0 if veh.is_ev else float(veh.fuel_lhv_j_per_l)
                    tt_mean, tt_sd = e.energy_j / scale, math.hypot(e.sd_j / scale, msd)
                    rows.append({
                        "vehicle": vid, "trip_id": t.trip_id, "day": day, "measured": t.measured,
                        "own": float(own.mean), "own_sd": float(own.sd),
                        "timetable": tt_mean, "timetable_sd": tt_sd,
                        "sd_synthesis": e.sd_synthesis_j / scale, "stops": int(stops.size),
                        "late_s": e.late_s, "km": e.distance_m / 1000.0,
                        "k_pos_own": t.vector.k_pos, "k_pos_tt": e.vector.k_pos})
    return {"rows": rows, "timing": timing}


def feed_speed(trips: int, draws: int, vehicle_file: Path) -> dict:
    """The feed-like speed measurement (module notes)."""
    rng = np.random.default_rng(0)
    tables = []
    for _ in range(trips):
        gaps = rng.uniform(250.0, 600.0, 29)
        times = np.round(np.concatenate(([0.0], np.cumsum(gaps / rng.uniform(5.0, 8.0, 29) + 25.0))) / 60.0) * 60.0
        tables.append((np.concatenate(([0.0], np.cumsum(gaps))), times + 8 * 3600.0))
    veh = load_vehicle(vehicle_file)
    p = driving_prior("bus")
    t0 = time.perf_counter()
    cycles = [synthesise_trip(d, t, t, p, np.random.default_rng(i)) for i, (d, t) in enumerate(tables)]
    t1 = time.perf_counter()
    late = sum(c.late_s > 0 for c in cycles)
    for i, (d, t) in enumerate(tables):
        scheduled_trip_energy(veh, d, t, t, profile_dist_m=None, profile_elev_m=None, mass_kg=12_000.0,
                              ambient_c=10.0, params=p, draws=draws, seed=i)
    t2 = time.perf_counter()
    for c in cycles:
        drive_cycle_vector(c.time_s, c.speed_mps)
    t3 = time.perf_counter()
    rows = 30 * trips
    return {"trips": trips, "stop_times_rows": rows, "synthesis_rows_per_s": rows / (t1 - t0),
            "energy_rows_per_s": rows / (t2 - t1), "draws": draws,
            "baseline_vector_per_trip_rows_per_s": rows / (t3 - t2),
            "synthesis_over_baseline": (t1 - t0) / (t3 - t2), "energy_over_baseline": (t2 - t1) / (t3 - t2),
            "energy_ms_per_trip": (t2 - t1) / trips * 1e3, "trips_late": int(late),
            "samples_per_trip": float(np.mean([c.time_s.size for c in cycles]))}


def summary(rows: list[dict]) -> dict:
    m = np.array([r["measured"] for r in rows])
    out: dict = {"trips": len(rows)}
    for key in ("own", "timetable"):
        p = np.array([r[key] for r in rows])
        sd = np.array([r[f"{key}_sd"] for r in rows])
        e = (p - m) / m * 100.0
        inside = np.abs(p - m) <= Z90 * sd
        out[key] = {"mean_error_pct": float(e.mean()), "sd_error_pct": float(e.std(ddof=1)),
                    "inside_90_pct": float(100.0 * inside.mean()),
                    "mean_interval_halfwidth_pct": float(np.mean(Z90 * sd / m) * 100.0)}
    o, t = out["own"], out["timetable"]
    out["targets"] = {
        "mean_within_5_points": abs(t["mean_error_pct"] - o["mean_error_pct"]) <= 5.0,
        "sd_within_1.5x": t["sd_error_pct"] <= 1.5 * o["sd_error_pct"],
        "coverage_85_97": 85.0 <= t["inside_90_pct"] <= 97.0}
    kp = np.array([r["k_pos_tt"] / r["k_pos_own"] for r in rows if r["k_pos_own"] > 0])
    out["k_pos_ratio_timetable_over_log"] = {"median": float(np.median(kp)), "p10": float(np.percentile(kp, 10)),
                                             "p90": float(np.percentile(kp, 90))}
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--store", type=Path, help="a trip store (with -v and --vehicle-id)")
    ap.add_argument("-v", "--vehicle", type=Path, help="the calibrated vehicle file for --store's vehicles")
    ap.add_argument("--vehicle-id", action="append", default=[])
    ap.add_argument("--twizy", type=Path, help="a folder of Twizy logs (ingested and calibrated per vehicle)")
    ap.add_argument("--draws", type=int, default=8)
    ap.add_argument("--feed-trips", type=int, default=200, help="feed-like timetables timed (0: none)")
    ap.add_argument("--json", type=Path, help="write every row and the summary here")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        if args.store is not None:
            if args.vehicle is None or not args.vehicle_id:
                ap.error("--store needs -v and --vehicle-id")
            store, vehicles = args.store, [(v, args.vehicle) for v in args.vehicle_id]
        elif args.twizy is not None:
            store, vehicles = twizy_store(Path(tmp), args.twizy)
        else:
            store, vehicles = sample_store(Path(tmp))
        t0 = time.perf_counter()
        res = held_out(store, vehicles, args.draws)
        wall = time.perf_counter() - t0
    s = summary(res["rows"])
    tm = res["timing"]
    s["speed"] = {
        "stop_times_rows": tm["rows"],
        "synthesis_rows_per_s": tm["rows"] / tm["synth_s"],
        "energy_rows_per_s": tm["rows"] / tm["energy_s"], "draws": args.draws,
        "baseline_vector_per_trip_rows_per_s": tm["rows"] / tm["vector_s"],
        "energy_over_baseline": tm["energy_s"] / tm["vector_s"], "wall_s": wall}
    if args.feed_trips:
        s["feed_like_speed"] = feed_speed(args.feed_trips, args.draws, ROOT / "configs/vehicles/electric-bus.toml")
    print(json.dumps(s, indent=2))
    if args.json:
        args.json.write_text(json.dumps({"summary": s, "rows": res["rows"]}, indent=1))


if __name__ == "__main__":
    main()
