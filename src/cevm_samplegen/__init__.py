"""Deterministic synthetic logger exports and DSM tiles: the project's ``sample_logs/``.

``python -m cevm_samplegen OUTDIR [--small] [--seed N] [--consumption MODULE:FUNC]``
writes, from a seed alone (no wall clock, no network; same bytes on every run)::

    OUTDIR/srf/<vehicle>_<yyyy-mm-dd>.csv[.gz]   one file per vehicle and logging day
    OUTDIR/portal/portal_export_<first>_<last>.csv  two vehicles, several days, one DST jump
    OUTDIR/dsm/<OS tile>_DSM_<r>M.tif              DSM tiles, EPSG:27700
    OUTDIR/manifests/bus-loads.csv, portal-tms.csv the operator's trip loads
                                                   (cevm_samplegen.manifests)
    OUTDIR/truth.json                              what really happened (see below)

**Truth first, then sensors.** For every trip the generator draws a speed trace (the
micro-trip generator of :mod:`cevm_samplegen.cycles`: stop-to-stop runs; long haul adds motorway
cruise blocks), lays it along a smooth road polyline in British National Grid (BNG,
EPSG:27700) around Milton Keynes (position = the route point at the cumulative distance),
takes the TRUE road elevation from a smooth terrain function (the road surface: no
buildings), the day's weather (:mod:`cevm_samplegen.weather`: air temperature and
sunshine over Milton Keynes, a seasonal mean, the day's anomaly, a diurnal cycle and
noise; the cold and hot days of :data:`~cevm_samplegen.fleet.SAMPLE_WEATHER` forced),
and gets the consumption from an injected function::

    consumption_fn(kind, time_s, speed_mps, elevation_m, mass_kg, *, conditions)
        -> Consumption | cumulative array

``kind`` is the vehicle type, the stem of a ``configs/vehicles`` file: ``"electric-bus"``
(result in joules at the battery, net of regeneration) or ``"diesel-hgv"`` (litres of
diesel). Arrays are the 1 Hz truth samples of one trip (time from 0 s), ``mass_kg`` the
trip's constant gross mass, ``conditions`` a :class:`TripConditions` (the air
temperature and sunshine at each sample, the ignition-off time before the trip, the
people on board); the result has one value per sample, starting at 0 (a
:class:`Consumption` adds named parts for ``truth.json``). A function that does not take
``conditions`` is refused with a clear message. The default,
:func:`standin_consumption`, is a STAND-IN (a longitudinal-dynamics formula with
load-dependent efficiency, written here) for tests and trial runs; the project's sample
logs are generated with the detailed simulator (:func:`logged_consumption`). Both take
the weather's loads from :mod:`cevm_samplegen.auxiliaries`: a cabin heat balance with a
heat pump (COP falling with the cold), a resistive backup and A/C (EER falling with the
heat), a warm-up after each layover; a diesel's cab A/C and a cold engine's extra
friction. The CE model (:mod:`cevm.core.model`) is never used for measured values.

Sensors are then derived from the truth:

* ``srf`` (LOGGERS.md dialect 1): ~1 Hz ticks with a random phase, +-12 ms jitter, 1 %
  missed ticks (plus short bursts), 0.3 % repeated ticks (identical duplicate lines); no
  rows while the ignition is off between trips (the FMS dongle is unpowered and the app
  pauses: layovers are gaps of 12-45 min). GPS: correlated position noise (AR(1),
  tau 40 s, about 2.5 m x HDOP/0.9, plus 0.7 m white; it keeps wandering at standstill),
  HDOP, cold start (8-25 s without fix) and re-acquisition (2-6 s) after each layover,
  dropouts of 10-45 s, 2 % single missing fixes, GPS altitude = road + geoid undulation
  47 m (ellipsoidal heights near Milton Keynes) + session bias + drift of about 12 m.
  FMS fields arrive asynchronously (a field is empty in a tick that got no new value):
  wheel speed (per-vehicle calibration factor, 1/256 km/h steps), pedal (0.4 %), brake
  switch, engine/motor speed (0.125 rpm) and torque (1 %, from a plausible gear model),
  every tick but 0.5 %; fuel counter (0.5 l, floor, every 5-10 s; per-vehicle ECU bias),
  fuel rate (0.05 l/h, 2 % noise, same ECU bias), flow meter (mean rate over each 2 s
  interval, 1.5 % noise: the trusted truck source), gross weight (10 kg, every ~10 s once
  the vehicle has moved for 30 s); bus: total energy (0.1 kWh floor, net of regeneration,
  every 4-6 s: the trusted bus source), SoC (0.4 %), pack voltage and current from an
  open-circuit-voltage + resistance model, consistent with the energy (V I = battery
  power); ambient air temperature (``fms_ambient_air_temp_c``, 0.03125 degC steps, every
  4-6 s): the air plus a per-vehicle sensor bias, up to 2 K warm in full sun at
  standstill (fading with speed), through a 60 s sensor lag. Comment metadata
  ``# vehicle_id=``, ``# logger=``, ``# started=``.
* ``portal`` (dialect 2): ``;``, decimal comma, cp1252 (``£``, ``é``, an en dash in
  Event texts), CRLF, Europe/London local time ``dd/mm/yyyy HH:MM:SS`` (the autumn DST
  jump makes one hour repeat), rows every 1-10 s while moving, every 30-120 s when
  stopped with the ignition on, a row where the vehicle comes to rest and where it moves
  off, ``Ignition`` On/Off rows at trip ends, heartbeats every 15-30 min while off; GPS
  speed in mph, CAN odometer in miles (0.1 mi, floor), fuel used (0.5 l, floor), rare
  no-fix rows written as 0;0; Events: harsh braking etc., a depot exit on each day's
  first row and a fuel-card purchase on its last. Rows grouped by ``Registration``. No
  temperature column (the dialect has none).

**Fleet** (:data:`SAMPLE_FLEET`): srf, six days from winter to summer 2019 (31 January
and 1 February in a cold snap, -5.5 and -4 degC at dawn; 10 April and 15 May drawn from
the climate; 25 July and 27 August hot, 31 and 29 degC in the afternoon): electric
buses EB-01 and EB-02 on two urban loops (4-5 trips a day from a random morning hour,
0-60 passengers x 75 kg per trip); diesel HGV-11 on regional deliveries (3 trips a day,
payload 14-26 t falling at each drop) and urban multi-drop (4 rounds in town, 6-12 t)
on alternate days; HGV-21 on long haul (a trunk road out and back: the return leg is
drawn to end at the depot; heavy out, light back) and, two days, regional deliveries;
an 18,000 kg tractor. Portal, 25-28 October 2019:
KX19 LMR on the regional loop by day, KX19 LMT on the trunk road by night (its night of
26-27 October spans 01:00 UTC, when the clocks went back). :func:`fleet_for_benchmark`
writes a larger srf fleet on the same routes.

**File-level faults** (all listed in ``truth.json``): a backward clock correction of
4.25 s in one srf file (EB-02, day 2, mid trip 2: the phone clock ran ahead), a
fuel-counter reset in one file (HGV-21, day 2, mid trip 2: the new counter starts at
12.5 l), HGV-21's counter starting near 1.84 million litres, gzipped files (every srf
file but each vehicle's first day, ``.csv.gz``, to keep the repository small),
HGV-11's wheel speed reading 1.5 % high and its ECU fuel figures 3 % high (its flow
meter shows the truth), ambient sensors reading 0.2-0.7 K off.

**DSM.** Float32 GeoTIFFs, 1 km tiles named by OS grid reference (``SP8538_DSM_2M.tif``),
2 m pixels (5 m in ``--small``), deflate + floating-point predictor, values rounded to
1/128 m (exact in binary, half the size of 0.01 m rounding), nodata -9999. Surface =
terrain + flat-roofed buildings beside the roads (at least 8 m clear of every road
centreline) + trees (dome canopies) beside the roads and a few over them + bridge decks
across the roads + nodata holes (LIDAR voids, some on the roads). Tiles exist only for
the 1 km cells the routes touch inside a survey box (E 480-492 km, N 233-245 km), so
these route sections lie outside every tile ON PURPOSE: (1) the trunk road north of
N 245 km, i.e. all but the first ~5 km of each long-haul trip; (2) the cell SP8139 on the
west side of the regional loop (a survey hole, about 1 km of road). Exact intervals:
``truth.json`` -> ``routes.<name>.dsm_gaps_m``; the road intervals with trees, bridges or
holes over them: ``routes.<name>.surface_objects``.

**truth.json**: per trip the vehicle, file, first and last file line, true UTC start and
end (first and last logged tick, true clock), true distance, gross mass and load, true
consumption (``consumption`` in ``consumption_unit``), the duty, the route and where on
it the trip starts (``route_from_m``: the true positions are ``Route.xy(route_from_m +
distance)``), the share inside DSM tiles, the true air temperature (time-weighted mean,
min, max), mean sunshine, ignition-off time before the trip, occupants, and the
consumption function's parts: bus ``hvac_energy_j`` (heating, ventilation and A/C from
the battery), ``warmup_energy_j`` (its share that made up the layover's cabin
deficit), ``cabin_start_c``; truck ``hvac_fuel_l`` (cab HVAC), ``cold_start_fuel_l``
(a cold engine's extra friction), ``engine_start_c``, ``cabin_start_c``; per day its
weather (min, max, cloud, forced or drawn, sunrise); per file its faults; per vehicle
the sensor biases and duty schedule; the consumption function's qualified name.

**Not simulated**: lane offsets (all traffic drives on the centreline), traffic and
signals as such (stops are random micro-trip dwells), load changes within a trip,
charging and depot pre-conditioning (a day's first trip starts with the cabin and the
engine at the night's air temperature), battery temperature (its resistance and usable
capacity do not change with the cold), wind, rain, wrap-around of counters, OSTN15-grade datum detail (pyproj's default
BNG->WGS84 transformation is used both ways), DSM noise on the road surface (the road is
the terrain, to 1/128 m), embankments, cuttings and bridge ramps, vehicles in the DSM.

Public API: :func:`generate_sample_logs`, :func:`fleet_for_benchmark`,
:func:`simulate_fleet`, :func:`build_world`, :func:`standin_consumption`,
:func:`logged_consumption`, :class:`TripConditions`, :class:`Consumption`,
:class:`FleetSpec`, :data:`SAMPLE_FLEET`, :data:`SMALL_FLEET`.

Modules: :mod:`~cevm_samplegen.world` (terrain, roads, DSM), :mod:`~cevm_samplegen.weather`
(air temperature, sunshine), :mod:`~cevm_samplegen.fleet` (duties, vehicles, truth trips),
:mod:`~cevm_samplegen.consumption` (the consumption functions) with
:mod:`~cevm_samplegen.auxiliaries` (cabin HVAC, engine warm-up),
:mod:`~cevm_samplegen.writers` (sensors, srf and portal files) with
:mod:`~cevm_samplegen.csvfmt` (number formatting), :mod:`~cevm_samplegen.cycles` (micro-trips);
this module ties them together.

This package is the project's developer tool, apart from the runtime package ``cevm``:
``cevm`` never imports it. Demo cycles: ``python -m cevm_samplegen demo-cycles OUTDIR``; the
fleet case study's stand-in cycles: ``python -m cevm_samplegen standin-cycles OUTDIR``.
"""

from __future__ import annotations

import dataclasses
import gzip
import hashlib
import importlib
import json
from collections.abc import Callable, Sequence
from datetime import UTC, datetime
from pathlib import Path

from cevm_samplegen.common import BNG, DEFAULT_SEED, GEOID_UNDULATION_M
from cevm_samplegen.consumption import (
    MEASUREMENT_KIND,
    STANDIN,
    Consumption,
    StandInParams,
    TripConditions,
    logged_consumption,
    standin_consumption,
)
from cevm_samplegen.fleet import (
    BUS_KERB_KG,
    HGV_KERB_KG,
    SAMPLE_FLEET,
    SMALL_FLEET,
    ConsumptionFn,
    DutySpec,
    FleetSpec,
    TruthTrip,
    VehicleSpec,
    check_consumption_fn,
    simulate_fleet,
)
from cevm_samplegen.manifests import write_manifests
from cevm_samplegen.world import (
    DsmSpec,
    Route,
    Terrain,
    World,
    build_world,
    dsm_tile,
    os_tile_name,
    route_dsm_summary,
    write_dsm_tiles,
)
from cevm_samplegen.writers import Counters, bng_to_wgs84, portal_file, srf_file

__all__ = [
    "SAMPLE_FLEET",
    "SMALL_FLEET",
    "STANDIN",
    "Consumption",
    "ConsumptionFn",
    "DsmSpec",
    "DutySpec",
    "FleetSpec",
    "Route",
    "StandInParams",
    "Terrain",
    "TripConditions",
    "TruthTrip",
    "VehicleSpec",
    "World",
    "build_world",
    "dsm_tile",
    "fleet_for_benchmark",
    "generate_sample_logs",
    "logged_consumption",
    "main",
    "simulate_fleet",
    "standin_consumption",
]


def _qualname(fn: Callable) -> str:
    return f"{getattr(fn, '__module__', '?')}:{getattr(fn, '__qualname__', repr(fn))}"


def _iso(t: float) -> str:
    ms = int(round(t * 1000.0))
    return datetime.fromtimestamp(ms // 1000, UTC).strftime("%Y-%m-%dT%H:%M:%S") + f".{ms % 1000:03d}Z"


def _finish_records(records: list[dict]) -> None:
    for r in records:
        kind = MEASUREMENT_KIND[r["vehicle_type"]]
        r["consumption_unit"] = "J" if kind == "energy_j" else "l"
        r["consumption"] = round(r["consumption"], 1 if kind == "energy_j" else 5)
        r["load_unit"] = "passengers" if r["vehicle_type"] == "electric-bus" else "kg payload"
        r["start_utc"], r["end_utc"] = _iso(r["start_utc_s"]), _iso(r["end_utc_s"])


def _write(path: Path, data: bytes, gz: bool) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    if gz:
        path = path.with_name(path.name + ".gz")
        data = gzip.compress(data, compresslevel=9, mtime=0)
    path.write_bytes(data)
    return path


def _write_srf(outdir: Path, world: World, fleet: FleetSpec, truth, seed: int) -> tuple[list[dict], list[dict]]:
    transformer = bng_to_wgs84()
    files, records = [], []
    for veh in fleet.srf_vehicles:
        state = Counters()
        for day_index, date in enumerate(fleet.srf_dates):
            trips = truth[veh.vehicle_id][day_index]
            data, recs, info = srf_file(world, veh, trips, date, state, fleet, seed, transformer)
            gz = (veh.vehicle_id, day_index) in fleet.gzip_files
            path = _write(outdir / "srf" / f"{veh.vehicle_id}_{date}.csv", data, gz)
            rel = path.relative_to(outdir).as_posix()
            info = {"path": rel, "sha256": hashlib.sha256(path.read_bytes()).hexdigest(),
                    "bytes": path.stat().st_size, **info}
            for r in recs:
                r["file"] = rel
            files.append(info)
            records.extend(recs)
    return files, records


def _vehicles_json(vehicles: Sequence[VehicleSpec]) -> dict:
    return {v.vehicle_id: {k: (round(x, 3) if isinstance(x, float) else x)
                           for k, x in sorted(dataclasses.asdict(v).items()) if k != "vehicle_id"}
            for v in vehicles}


def _dump_json(obj, path: Path) -> None:
    path.write_text(json.dumps(obj, indent=1, sort_keys=True, ensure_ascii=False) + "\n", encoding="utf-8")


NOTES = (
    "Times are the true UTC of the first and last logged tick of each trip; distance and consumption are the "
    "truth between them. ambient_c is the time-weighted mean true air temperature over that span (min, max: "
    "on the 1 s truth grid), solar_w_m2 the mean global horizontal irradiance, soak_s the ignition-off time "
    "before the trip (12 h before a day's first), occupants the people on board. The consumption function's "
    "parts are over the whole truth trip (within a second of the logged span): hvac_energy_j (bus: heating, "
    "ventilation and A/C from the battery, warm-up included), warmup_energy_j (its excess while making up the "
    "layover's cabin deficit), hvac_fuel_l (truck: cab HVAC on the engine), cold_start_fuel_l (a cold engine's "
    "extra friction), cabin_start_c and engine_start_c (at ignition on)."
)


def _weather_json(truth: dict[str, list[list[TruthTrip]]]) -> dict:
    days = {tr.weather.date: tr.weather for days in truth.values() for day in days for tr in day}
    return {d: {"min_c": round(w.min_c, 3), "max_c": round(w.max_c, 3), "cloud": round(w.cloud, 3),
                "forced": w.forced, "sunrise_utc_h": round(w.sunrise_utc_h, 3)} for d, w in sorted(days.items())}


def generate_sample_logs(outdir: str | Path, consumption_fn: ConsumptionFn = standin_consumption, *,
                         seed: int = DEFAULT_SEED, small: bool = False, fleet: FleetSpec | None = None,
                         write_dsm: bool = True) -> dict:
    """Generate the sample logs, DSM tiles and ``truth.json`` into ``outdir``.

    ``small=True`` uses :data:`SMALL_FLEET` (a few minutes of driving, four 5 m tiles:
    well under a second); ``fleet`` overrides both. Returns the truth dictionary written
    to ``outdir/truth.json``. Same arguments -> same bytes.
    """
    outdir = Path(outdir)
    fleet = fleet if fleet is not None else (SMALL_FLEET if small else SAMPLE_FLEET)
    world, truth = simulate_fleet(fleet, consumption_fn, seed)
    files, records = _write_srf(outdir, world, fleet, truth, seed)
    if fleet.portal_vehicles:
        data, precs, pinfo = portal_file(world, fleet, truth, seed, bng_to_wgs84())
        dates = sorted({d for ds in fleet.portal_dates.values() for d in ds})
        # the night duty's first trip starts the evening before its first date
        first = min(datetime.fromtimestamp(r["start_utc_s"], UTC).date().isoformat() for r in precs)
        path = _write(outdir / "portal" / f"portal_export_{first}_{dates[-1]}.csv", data, False)
        rel = path.relative_to(outdir).as_posix()
        for r in precs:
            r["file"] = rel
        files.append({"path": rel, "sha256": hashlib.sha256(data).hexdigest(), "bytes": len(data), **pinfo})
        records.extend(precs)
    _finish_records(records)
    manifests = [p.relative_to(outdir).as_posix() for p in write_manifests(outdir, records)]
    tiles = []
    if write_dsm:
        tiles = [p.relative_to(outdir).as_posix() for p in write_dsm_tiles(world, outdir / "dsm")]
    doc = {
        "generator": "cevm_samplegen",
        "format_version": 2,
        "seed": seed,
        "small": bool(small),
        "consumption_fn": _qualname(consumption_fn),
        "consumption_units": {"electric-bus": "J at the battery, net of regeneration", "diesel-hgv": "l of diesel"},
        "notes": NOTES,
        "weather": _weather_json(truth),
        "vehicles": _vehicles_json(fleet.srf_vehicles + fleet.portal_vehicles),
        "files": files,
        "manifests": manifests,
        "trips": records,
        "routes": {name: route_dsm_summary(world, r) for name, r in sorted(world.routes.items())},
        "dsm": {
            "crs": BNG, "tile_m": fleet.dsm.tile_m, "resolution_m": fleet.dsm.resolution_m,
            "quantum_m": fleet.dsm.quantum_m,
            "nodata": fleet.dsm.nodata, "survey_box": list(fleet.dsm.survey_box),
            "omitted_tiles": [os_tile_name(*c) for c in fleet.dsm.omitted_cells], "tiles": tiles,
            "geoid_undulation_m": GEOID_UNDULATION_M,
        },
    }
    outdir.mkdir(parents=True, exist_ok=True)
    _dump_json(doc, outdir / "truth.json")
    return doc


_BENCH_TEMPLATES = (
    ("electric-bus", "bus", "bus-1"),
    ("electric-bus", "bus", "bus-2"),
    ("diesel-hgv", "regional", "regional"),
    ("diesel-hgv", "longhaul", "trunk"),
)


def fleet_for_benchmark(n_vehicles: int, n_days: int, outdir: str | Path, *, seed: int = DEFAULT_SEED,
                        consumption_fn: ConsumptionFn = standin_consumption, first_date: str = "2019-05-13",
                        dsm_dir: str | Path | None = None, full_days: bool = False) -> dict:
    """A larger srf fleet for the ingest benchmark: ``n_vehicles`` (cycling through two
    buses, a regional and a long-haul truck, ids ``BM-001``...) x ``n_days`` consecutive
    days from ``first_date``, on the same routes as the sample logs (so the sample's DSM
    tiles cover them; pass ``dsm_dir`` to write the tiles too). A vehicle-day has the
    sample fleet's 2-3 trips (~1.4 h of driving, ~5,000 samples), or with
    ``full_days`` a working day of 6-12 trips (4-6 h, 15,000-22,000 samples). Writes
    ``outdir/srf/*.csv`` and ``outdir/truth.json``; returns the truth dictionary (with
    ``rows`` and ``bytes`` totals)."""
    outdir = Path(outdir)
    vehicles = []
    for i in range(n_vehicles):
        vt, duty, route = _BENCH_TEMPLATES[i % len(_BENCH_TEMPLATES)]
        if full_days:
            duty = f"{duty}-day"
        vid = f"BM-{i + 1:03d}"
        vehicles.append(VehicleSpec(vid, vt, duty, route, BUS_KERB_KG if vt == "electric-bus" else HGV_KERB_KG,
                                    flowmeter=(i % 8 == 2), fuel_counter_start_l=1000.0 * (i + 1),
                                    energy_counter_start_kwh=500.0 * (i + 1)))
    d0 = datetime.fromisoformat(first_date)
    dates = tuple((d0.fromordinal(d0.toordinal() + k)).date().isoformat() for k in range(n_days))
    fleet = FleetSpec(tuple(vehicles), dates, (), {})
    world, truth = simulate_fleet(fleet, consumption_fn, seed, world=build_world(seed, SAMPLE_FLEET.dsm))
    files, records = _write_srf(outdir, world, fleet, truth, seed)
    _finish_records(records)
    tiles = []
    if dsm_dir is not None:
        tiles = [p.as_posix() for p in write_dsm_tiles(world, Path(dsm_dir))]
    doc = {
        "generator": "cevm_samplegen.fleet_for_benchmark", "format_version": 1, "seed": seed,
        "consumption_fn": _qualname(consumption_fn), "vehicles": _vehicles_json(fleet.srf_vehicles),
        "files": files, "trips": records, "rows": int(sum(f["rows"] for f in files)),
        "bytes": int(sum(f["bytes"] for f in files)), "dsm_tiles": tiles,
    }
    _dump_json(doc, outdir / "truth.json")
    return doc


def _load_fn(spec: str) -> ConsumptionFn:
    mod, _, name = spec.partition(":")
    if not name:
        raise SystemExit(f"--consumption expects MODULE:FUNCTION, got {spec!r}")
    fn = importlib.import_module(mod)
    for part in name.split("."):
        fn = getattr(fn, part)
    return fn  # type: ignore[return-value]


def main(argv: list[str] | None = None) -> int:
    """``python -m cevm_samplegen OUTDIR [--small] [--seed N] [--consumption MODULE:FUNC]
    [--benchmark N_VEHICLES N_DAYS]``."""
    import argparse

    ap = argparse.ArgumentParser(prog="python -m cevm_samplegen",
                                 description="Generate synthetic logger exports, DSM tiles and truth.json.")
    ap.add_argument("outdir", type=Path)
    ap.add_argument("--small", action="store_true", help="tiny fleet for tests (well under a second)")
    ap.add_argument("--seed", type=int, default=DEFAULT_SEED)
    ap.add_argument("--consumption", default="cevm_samplegen:standin_consumption",
                    help="MODULE:FUNCTION giving the measured consumption (default: the stand-in)")
    ap.add_argument("--benchmark", nargs=2, type=int, metavar=("N_VEHICLES", "N_DAYS"),
                    help="write a benchmark srf fleet instead")
    a = ap.parse_args(argv)
    fn = _load_fn(a.consumption)
    try:
        check_consumption_fn(fn)
    except TypeError as e:
        raise SystemExit(f"--consumption {a.consumption}: {e}") from None
    if a.benchmark:
        doc = fleet_for_benchmark(a.benchmark[0], a.benchmark[1], a.outdir, seed=a.seed, consumption_fn=fn)
        print(f"{len(doc['files'])} files, {doc['rows']} rows, {doc['bytes']} bytes in {a.outdir}")
        return 0
    doc = generate_sample_logs(a.outdir, fn, seed=a.seed, small=a.small)
    print(f"{len(doc['files'])} log files, {len(doc['trips'])} trips, {len(doc['dsm']['tiles'])} DSM tiles "
          f"in {a.outdir}")
    return 0

