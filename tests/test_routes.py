"""Named routes in the trip store: storage, a route equals the sum of its parts, the CLI."""

import hashlib
import json
import shutil

import numpy as np
import pytest
from typer.testing import CliRunner

from cevm.cli import app
from cevm.core.cycle import CycleVector, drive_cycle_vector
from cevm.core.trip import Trip
from cevm.errors import CevmError, InputError
from cevm.io import read_cycle_csv
from cevm.store import TripStore
from cevm.store.routes import (
    CycleLeg,
    TripLeg,
    add_route,
    check_route_name,
    list_routes,
    load_route_legs,
    load_route_profiles,
    load_route_vector,
    remove_route,
    route_names,
)
from cevm_samplegen.cycles import MicroTripSpec, micro_trip_cycle

runner = CliRunner()


def make_trip(vehicle_id: str, seed: int, start_utc_s: float, path: str) -> Trip:
    cyc = micro_trip_cycle(MicroTripSpec(n_trips=6, hill_amplitude_m=15.0), seed=seed)
    v = cyc.speed_mps
    dist = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(cyc.time_s))])
    nan = np.full(v.size, np.nan)
    return Trip(vehicle_id=vehicle_id, source_file=path, source_sha256=hashlib.sha256(path.encode()).hexdigest(),
                trip_index=0, start_utc_s=start_utc_s, time_s=cyc.time_s, speed_mps=v, distance_m=dist,
                lat_deg=nan, lon_deg=nan, elevation_m=cyc.elevation_m, elevation_source="synthetic",
                dsm_coverage_pct=0.0, measured=None, gross_weight_kg=None)


@pytest.fixture
def store(tmp_path):
    """A store with two trips of vehicle EB-01 (from two 'files')."""
    path = tmp_path / "s.sqlite"
    with TripStore.open(path) as st:
        for i, seed in enumerate((11, 12)):
            src = str(tmp_path / f"log{i}.csv")
            trip = make_trip("EB-01", seed, 1_557_820_800 + 86400 * i, src)
            vec = drive_cycle_vector(trip.time_s, trip.speed_mps, trip.elevation_m)
            st.replace_file_trips(src, [trip], [vec.to_bytes()], sha256=trip.source_sha256, size_bytes=1,
                                  mtime_s=0.0, profile="test")
        ids = list(st.load_vectors().keys())
    return path, ids


@pytest.fixture
def cycles(tmp_path, root):
    """Copies of two shipped cycles (so the test can delete them)."""
    out = []
    for name in ("urban-bus", "regional-delivery"):
        dst = tmp_path / f"{name}.csv"
        shutil.copy(root / "configs/cycles" / f"{name}.csv", dst)
        out.append(dst)
    return out


def vectors_equal(a: CycleVector, b: CycleVector) -> bool:
    return (np.allclose(a.delta, b.delta, rtol=1e-13) and np.array_equal(a.ns_x, b.ns_x)
            and np.array_equal(a.ns_a, b.ns_a) and np.array_equal(a.ns_r, b.ns_r)
            and a.duration_s == pytest.approx(b.duration_s) and a.distance_m == pytest.approx(b.distance_m)
            and a.idle_s == pytest.approx(b.idle_s) and a.n_samples == b.n_samples)


def test_a_route_vector_is_the_sum_of_its_legs(store, cycles):
    path, ids = store
    c0, c1 = (read_cycle_csv(c) for c in cycles)
    with TripStore.open(path) as st:
        info = add_route(st, "block-1", [TripLeg(ids[0]), CycleLeg.from_file(cycles[0]), TripLeg(ids[1]),
                                         CycleLeg.from_file(cycles[1])], note="morning block")
        assert [(x.kind, x.label) for x in info.legs] == [("trip", ids[0]), ("cycle", "urban-bus"),
                                                          ("trip", ids[1]), ("cycle", "regional-delivery")]
        want = (CycleVector.from_bytes(st.load_vector_bytes(ids[0])) + drive_cycle_vector(c0.time_s, c0.speed_mps,
                                                                                          c0.elevation_m)
                + CycleVector.from_bytes(st.load_vector_bytes(ids[1])) + drive_cycle_vector(c1.time_s, c1.speed_mps,
                                                                                            c1.elevation_m))
        assert vectors_equal(load_route_vector(st, "block-1"), want)
        profiles = load_route_profiles(st, "block-1")
        assert len(profiles) == 4
        assert np.array_equal(profiles[0]["speed_mps"], st.load_profile(ids[0])["speed_mps"])
        # cycle legs are stored losslessly (float64): the vector can be recomputed exactly
        assert np.array_equal(profiles[1]["speed_mps"], c0.speed_mps)
        assert np.array_equal(profiles[3]["elevation_m"], c1.elevation_m)
        assert np.all(np.isnan(profiles[1]["lat_deg"])) and profiles[1]["distance_m"][-1] == pytest.approx(
            drive_cycle_vector(c0.time_s, c0.speed_mps).distance_m)
        assert [r.name for r in list_routes(st)] == ["block-1"] and list_routes(st)[0].note == "morning block"
        meta = dict(st.con.execute("SELECT key, value FROM meta").fetchall())
        # the route tables are part of the store's schema (version 3 on)
        assert "routes_schema_version" not in meta and int(meta["schema_version"]) >= 3


def test_routes_replace_remove_and_bad_names(store, cycles):
    path, ids = store
    with TripStore.open(path) as st:
        add_route(st, "R1", [TripLeg(ids[0])])
        with pytest.raises(CevmError, match="already exists"):
            add_route(st, "R1", [TripLeg(ids[1])])
        add_route(st, "R1", [TripLeg(ids[1]), TripLeg(ids[0])], replace=True)
        assert [leg.info.ref for leg in load_route_legs(st, "R1", profiles=False)] == [ids[1], ids[0]]
        with pytest.raises(CevmError, match="unknown trip id"):
            add_route(st, "R2", [TripLeg("nope")])
        assert route_names(st) == ["R1"]  # nothing half-written
        with pytest.raises(CevmError, match="unknown route 'R9'"):
            load_route_vector(st, "R9")
        assert remove_route(st, "R1") and not remove_route(st, "R1") and route_names(st) == []
    for bad in ("", "has space", "x*", "-lead", "a" * 101):
        with pytest.raises(InputError):
            check_route_name(bad)


def test_a_route_whose_trip_was_replaced_says_so(store):
    path, ids = store
    with TripStore.open(path) as st:
        add_route(st, "R1", [TripLeg(ids[0]), TripLeg(ids[1])])
        st.forget_file(st.list_trips(trip_ids=[ids[1]])["source_file"].iloc[0])
        with pytest.raises(CevmError, match=r"no longer in the store.*--replace"):
            load_route_vector(st, "R1")


def test_cycle_legs_do_not_need_the_file_afterwards(tmp_path, cycles, root):
    path = tmp_path / "routes.sqlite"
    res = runner.invoke(app,
                        ["route", "add", "round", "-c", str(cycles[0]), "-c", str(cycles[1]), "--store", str(path)])
    assert res.exit_code == 0, res.output
    assert "copied into the store" in res.stdout
    bus = str(root / "configs/vehicles/electric-bus.toml")
    before = json.loads(runner.invoke(app,
                                      ["predict", "-v", bus, "-r", "round", "--store", str(path), "-f", "json"]).stdout)
    for c in cycles:
        c.unlink()
    after = runner.invoke(app, ["predict", "-v", bus, "-r", "round", "--store", str(path), "-f", "json"])
    assert after.exit_code == 0 and json.loads(after.stdout) == before


@pytest.mark.slow
def test_cli_route_equals_the_sum_of_its_parts(store, cycles, root):
    path, ids = store
    s = str(path)
    res = runner.invoke(app, ["route", "add", "mixed", "--leg", f"trip:{ids[0]}", "--leg", f"cycle:{cycles[0]}",
                              "--leg", f"trip:{ids[1]}", "--store", s])
    assert res.exit_code == 0, res.output
    listed = json.loads(runner.invoke(app, ["route", "list", "--store", s, "-f", "json"]).stdout)
    assert listed[0]["route"] == "mixed" and listed[0]["legs"] == 3 and listed[0]["status"] == "ok"
    vehicles = ["-v", str(root / "configs/vehicles/electric-bus.toml"), "-v",
                str(root / "configs/vehicles/diesel-hgv.toml")]
    common = [*vehicles, "--store", s, "-p", "0:10000:5000", "-f", "json"]
    route = json.loads(runner.invoke(app, ["predict", "-r", "mix*", *common]).stdout)
    parts = json.loads(runner.invoke(app,
                                     ["predict", "-t", ids[0], "-c", str(cycles[0]), "-t", ids[1], *common]).stdout)
    assert len(route) == 6 and len(parts) == 18
    assert {r["cycle"] for r in route} == {"mixed"} and {r["source_kind"] for r in route} == {"route"}
    assert listed[0]["distance_km"] == pytest.approx(route[0]["distance_km"], rel=1e-12)
    for i, r in enumerate(route):
        legs = parts[i::6]  # the same vehicle and payload on each part (parts are source-major)
        assert all(p["vehicle"] == r["vehicle"] and p["mass_kg"] == r["mass_kg"] for p in legs)
        for key in ("distance_km", "duration_s", "wheel_energy_kwh", "energy_kwh", "fuel_l"):
            if key in r:
                assert r[key] == pytest.approx(sum(p[key] for p in legs), rel=1e-12)
        if "soc_end_pct" in r:
            assert 100.0 - r["soc_end_pct"] == pytest.approx(sum(100.0 - p["soc_end_pct"] for p in legs), rel=1e-12)
            assert r["soc_min_pct"] <= r["soc_end_pct"]
    feas = runner.invoke(app, ["feasibility", *vehicles, "-r", "mixed", "--store", s, "-f", "json"])
    assert feas.exit_code == 0, feas.output
    assert {r["vehicle"] for r in json.loads(feas.stdout)} == {"Optare Metrocity EV", "Scania P320 diesel HGV"}


@pytest.mark.slow
def test_cli_route_errors(store, cycles, root):
    path, ids = store
    bus = str(root / "configs/vehicles/electric-bus.toml")
    s = str(path)
    for args, msg in ((["route", "add", "x", "--store", s], "give the legs"),
                      (["route", "add", "x", "-t", ids[0], "-c", str(cycles[0]), "--store", s], "cannot be combined"),
                      (["route", "add", "x", "--leg", "bus:1", "--store", s], "expected trip:ID or cycle:PATH"),
                      (["route", "add", "bad name", "-t", ids[0], "--store", s], "not a valid route name"),
                      (["route", "remove", "ghost", "--store", s], "no route 'ghost'"),
                      (["predict", "-v", bus, "-r", "ghost", "--store", s], "unknown route 'ghost'"),
                      (["predict", "-v", bus, "-r", "gh*", "--store", s], "no stored route matches 'gh*'")):
        res = runner.invoke(app, args)
        assert res.exit_code == 2 and msg in res.output, (args, res.output)


def _store_trips(st, tmp_path, seeds, temps, step_s: float) -> None:
    """One stored trip of EB-01 per seed, ``step_s`` apart, each at its temperature."""
    import dataclasses

    for i, seed in enumerate(seeds):
        src = str(tmp_path / f"log{i}.csv")
        trip = dataclasses.replace(make_trip("EB-01", seed, 1_557_820_800 + step_s * i, src), ambient_temp_c=temps[i])
        vec = drive_cycle_vector(trip.time_s, trip.speed_mps, trip.elevation_m)
        st.replace_file_trips(src, [trip], [vec.to_bytes()], sha256=trip.source_sha256, size_bytes=1,
                              mtime_s=0.0, profile="test")


def test_a_route_of_trips_is_predicted_at_its_legs_mean_temperature(tmp_path, cycles):
    """A route's ambient temperature is the duration-weighted mean of its trip legs' logged
    temperatures (computed here by hand); a route with a cycle leg, or with a trip that
    logged none, has none (the prediction then says it used the vehicle's reference)."""
    from contextlib import ExitStack

    from cevm.store.sources import load_sources

    path = tmp_path / "s.sqlite"
    temps = {0: -4.0, 1: 12.0, 2: None}
    with TripStore.open(path) as st:
        _store_trips(st, tmp_path, (11, 12, 13), temps, 86400)
        rows = st.list_trips().sort_values("start_utc_s")
        ids = list(rows.trip_id)
        durations = list(rows.duration_s)
        add_route(st, "warm-and-cold", [TripLeg(ids[0]), TripLeg(ids[1])])
        add_route(st, "with-cycle", [TripLeg(ids[0]), CycleLeg.from_file(cycles[0])])
        add_route(st, "one-unlogged", [TripLeg(ids[0]), TripLeg(ids[2])])
    with ExitStack() as stack:
        got = {s.name: s.ambient_c for s in load_sources(stack, path, [], [], [], ["*"], 0.0)}
    expected = (-4.0 * durations[0] + 12.0 * durations[1]) / (durations[0] + durations[1])
    assert got["warm-and-cold"] == pytest.approx(expected, rel=1e-9)
    assert durations[0] != durations[1]  # so that the weighting is tested, not a plain mean
    assert got["with-cycle"] is None
    assert got["one-unlogged"] is None


def test_a_route_of_legs_at_different_temperatures_is_the_sum_of_its_legs(tmp_path):
    """A day stored as a route: each leg heated or cooled at its own logged temperature and
    warmed up at its own start, so the route's energy (fuel) and its distribution are the
    sums of its legs predicted one by one (an EV with heating, A/C and warm-up terms on
    both sides of the balance temperatures; a diesel with heating and cold-start fuel); the
    legs' mean temperature alone would heat the cold leg too little."""
    from contextlib import ExitStack

    from cevm.core.predictive import Features, predictive, total
    from cevm.core.sweep import PredictionSet, sweep
    from cevm.core.vehicle import predict
    from cevm.io.vehicles import vehicle_from_mapping
    from cevm.store.sources import load_sources

    path = tmp_path / "s.sqlite"
    temps = [-8.0, 14.0, 31.0]
    with TripStore.open(path) as st:
        _store_trips(st, tmp_path, (21, 22, 23), temps, 3600)
        ids = list(st.list_trips().sort_values("start_utc_s").trip_id)
        add_route(st, "day", [TripLeg(t) for t in ids])
        vectors = st.load_cycle_vectors(trip_ids=ids)
    common = {"class": "bus", "mass_kg": 12000.0, "cda_m2": 4.0, "cr": 0.007, "eta": 0.8}
    ev = vehicle_from_mapping({**common, "name": "ev", "powertrain": "ev", "battery_kwh": 300.0,
                               "aux_power_kw": 3.0, "aux_heating_kw_per_k": 0.5, "aux_cooling_kw_per_k": 0.4,
                               "warmup_kwh_per_k": 0.1})
    ice = vehicle_from_mapping({**common, "name": "ice", "powertrain": "ice", "eta": 0.35, "fuel_lhv_mj_per_l": 35.8,
                                "idle_fuel_lph": 2.0, "heating_fuel_lph_per_k": 0.05,
                                "cooling_fuel_lph_per_k": 0.1, "warmup_fuel_l_per_k": 0.02})
    with ExitStack() as stack:
        (route,) = load_sources(stack, path, [], [], [], ["day"], 0.0)
        blocks = list(sweep([route], PredictionSet.build([ev, ice]), ranges=True))
    (block,) = blocks
    legs = [vectors[t] for t in ids]
    want_e = sum(float(predict(v, ev, ambient_c=t).energy_j) for v, t in zip(legs, temps, strict=True))
    want_f = sum(float(predict(v, ice, ambient_c=t).fuel_l) for v, t in zip(legs, temps, strict=True))
    # (to rounding: the route's CE vector sums its legs' steps in another order)
    assert float(block.energy_j[0]) == pytest.approx(want_e, rel=1e-8)
    assert float(block.fuel_l[1]) == pytest.approx(want_f, rel=1e-8)
    mean_t = predict(route.vector, ev, ambient_c=route.ambient_c).energy_j
    assert abs(float(mean_t) - want_e) > 1e-3 * want_e  # the mean temperature alone would differ
    # the interval: the legs' sum as one day (cevm.core.predictive.total)
    from cevm.core.intervals import block_ranges

    f = [Features.of(v, ev, ambient_c=t) for v, t in zip(legs, temps, strict=True)]
    day = total(ev, Features.concat(f))
    assert float(block_ranges(block).sd[0]) == pytest.approx(float(day.sd[0]), rel=1e-9)
    assert float(day.mean[0]) == pytest.approx(want_e, rel=1e-8)
    assert float(predictive(ev, f[0]).mean) > 0
