"""Model selection (cevm.core.calibration.select): on synthetic trips made with a known
term set it picks that set, and it refuses what physics refuses.

The trips are made with the CE model itself plus measurement noise (the truth is then
known exactly); tests of the CE model against a *different* model are the sample logs
and benchmarks/bench_accuracy.py.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from cevm.core.calibration import CalibrationError, TripData, fit, select
from cevm.core.cycle import drive_cycle_vector
from cevm.core.vehicle import Vehicle, predict
from cevm_samplegen.cycles import MicroTripSpec, micro_trip_cycle

BUS = Vehicle(name="bus", powertrain="ev", mass_kg=11000.0, cda_m2=4.0, cr=0.007, eta=0.8, kerb_mass_kg=9000.0,
              battery_j=120 * 3.6e6)
TRUCK = Vehicle(name="truck", powertrain="ice", mass_kg=30000.0, cda_m2=6.0, cr=0.006, eta=0.4, kerb_mass_kg=18000.0,
                fuel_lhv_j_per_l=35.8e6, ice_braking="no-credit")

URBAN = MicroTripSpec(n_trips=12, cruise_kmh=(15.0, 40.0), cruise_s=(10.0, 60.0), dwell_s=(10.0, 60.0))
SUBURBAN = MicroTripSpec(n_trips=8, cruise_kmh=(35.0, 60.0), cruise_s=(40.0, 150.0), dwell_s=(5.0, 30.0))
RURAL = MicroTripSpec(n_trips=4, cruise_kmh=(60.0, 85.0), cruise_s=(200.0, 600.0), dwell_s=(2.0, 20.0),
                      accel_mps2=(0.3, 0.6), decel_mps2=(0.4, 0.8))


def _vectors(n, seed):
    specs = [URBAN, SUBURBAN, RURAL]
    out = []
    for i in range(n):
        c = micro_trip_cycle(specs[i % 3], seed * 1000 + i)
        out.append(drive_cycle_vector(c.time_s, c.speed_mps, c.elevation_m))
    return out


def _trips(truth: Vehicle, n=60, seed=1, noise=0.01, temps=None, masses=None, standstill=None):
    rng = np.random.default_rng(seed)
    vecs = _vectors(n, seed)
    temps = rng.uniform(-8.0, 32.0, n) if temps is None else np.asarray(temps, dtype=float)
    masses = rng.uniform(0.8, 1.2, n) * truth.mass_kg if masses is None else masses
    out = []
    for i, vec in enumerate(vecs):
        p = predict(vec, truth, float(masses[i]), ambient_c=float(temps[i]))
        y = float(p.energy_j if truth.is_ev else p.fuel_l) * (1.0 + noise * rng.standard_normal())
        ss = {} if standstill is None else {"standstill_s": vec.idle_s, "standstill_rate": standstill(temps[i])}
        out.append(TripData(f"t{i}", vec, float(masses[i]), y, noise * y, group=f"day{i // 3}",
                            ambient_c=float(temps[i]), **ss))
    return out


def _chosen(sel):
    return set(sel.chosen)


@pytest.mark.slow
def test_ev_selection_finds_the_temperature_dependent_auxiliaries():
    truth = dataclasses.replace(BUS, aux_power_w=4000.0, aux_heating_w_per_k=300.0, aux_cooling_w_per_k=200.0)
    sel = select(BUS, _trips(truth), time_repeats=0)
    assert _chosen(sel) == {"eta", "aux", "heat", "cool"}
    r = sel.result
    for field, want in (("eta", 0.8), ("aux_power_w", 4000.0), ("aux_heating_w_per_k", 300.0),
                        ("aux_cooling_w_per_k", 200.0)):
        value, sd = r.fitted[field]
        assert abs(value - want) < 4 * sd + 0.02 * want, (field, value, sd)
    eta_only = next(c for c in sel.candidates if c.terms == ("eta",))
    assert r.cv.std_pct < 0.5 * eta_only.cv.std_pct
    assert sel.nested_cv is not None and sel.nested_cv.std_pct < 3.0
    # the calibrated vehicle predicts what the table says, through the public predict path
    assert r.vehicle.aux_heating_w_per_k == r.fitted["aux_heating_w_per_k"][0]
    assert r.domain.terms == sel.chosen and r.vehicle.calibration is r.domain


@pytest.mark.slow
def test_ev_selection_keeps_the_paper_model_when_nothing_else_is_there():
    """Trips made with eta alone: every extra term is either refused or not worth it."""
    sel = select(BUS, _trips(BUS, noise=0.02), time_repeats=0, nested=False)
    assert sel.chosen == ("eta",)


@pytest.mark.slow
def test_ice_selection_finds_the_willans_running_fuel():
    truth = dataclasses.replace(TRUCK, running_fuel_lps=6.0 / 3600, idle_fuel_lps=2.0 / 3600)
    sel = select(TRUCK, _trips(truth, temps=np.full(60, 15.0)), time_repeats=0, nested=False)
    assert {"eta", "run"} <= _chosen(sel)
    value, sd = sel.result.fitted["running_fuel_lps"]
    assert abs(value * 3600 - 6.0) < 4 * sd * 3600 + 0.3
    # no temperature spread: the temperature terms are refused, with the reason
    heat = [c for c in sel.candidates if "heat" in c.terms]
    assert heat and all(not c.ok and "colder than" in c.status for c in heat)


def test_regeneration_is_fitted_where_the_data_identify_it():
    """Trips that differ in their braking share (urban vs rural) identify regen_eta."""
    truth = dataclasses.replace(BUS, regen_eta=0.45)
    trips = _trips(truth, n=90, noise=0.003, temps=np.full(90, 19.0))
    r = fit(BUS, trips, ("eta", "regen"), time_repeats=0)
    assert not r.refused
    value, sd = r.fitted["regen_eta"]
    assert abs(value - 0.45) < 4 * sd + 0.01


def test_negative_auxiliary_power_is_refused_as_implausible():
    """Measurements that want a negative auxiliary load (the traction part over-predicts)
    must not produce a calibrated aux power: the candidate is refused, with why."""
    truth = dataclasses.replace(BUS, eta=0.7)
    trips = _trips(truth, temps=np.full(60, 19.0), noise=0.005)
    # shift every trip down by 1.5 kW x duration: what a negative aux would describe
    shifted = [dataclasses.replace(t, measured=t.measured - 1500.0 * t.vector.duration_s,
                                   uncertainty=0.005 * (t.measured - 1500.0 * t.vector.duration_s)) for t in trips]
    sel = select(BUS, shifted, terms=("aux",), time_repeats=0, nested=False)
    aux = next(c for c in sel.candidates if c.terms == ("eta", "aux"))
    assert not aux.ok and "implausible" in aux.status and "aux" in aux.status
    assert sel.chosen == ("eta",)


@pytest.mark.slow
def test_efficiency_above_one_is_refused():
    """Measured consumption below the wheel energy (masses far too high, or kWh read as
    MWh): eta > 1 is not a calibration, chosen or forced (a forced term set is
    held to the same physical bounds)."""
    trips = _trips(dataclasses.replace(BUS, eta=0.8), temps=np.full(60, 19.0))
    low = [dataclasses.replace(t, measured=t.measured * 0.5, uncertainty=t.uncertainty * 0.5) for t in trips]
    with pytest.raises(CalibrationError, match="implausible"):
        select(BUS, low, time_repeats=0, nested=False)
    with pytest.raises(CalibrationError,
                       match=r"eta: implausible: the data want a drive efficiency of .*, above the 0\.89"):
        fit(BUS, low, time_repeats=0)


@pytest.mark.slow
def test_an_idle_rate_several_times_the_measured_standstill_flow_is_refused():
    """The logs' standstill fuel flow refuses a model whose standstill rate is 3 times
    off it, whether or not the model has an idle term (without one it draws
    nothing standing still); a model that takes the flow as observations of its idle
    rate is held to it."""
    truth = dataclasses.replace(TRUCK, idle_fuel_lps=6.0 / 3600)
    sel = select(TRUCK, _trips(truth, temps=np.full(60, 15.0), standstill=lambda t: 1.0 / 3600), terms=("idle",),
                 time_repeats=0, nested=False)
    status = {c.label: c.status for c in sel.candidates}
    assert "it has no idle term" in status["eta"]
    assert "5.9 times the fuel flow the logs measured" in status["eta+idle"]
    assert sel.chosen == ("eta", "idle") and sel.chosen_standstill
    assert sel.result.fitted["idle_fuel_lps"][0] * 3600 == pytest.approx(1.0, rel=0.05)
    ok = select(TRUCK, _trips(truth, temps=np.full(60, 15.0), standstill=lambda t: 5.5 / 3600),
                terms=("idle",), time_repeats=0, nested=False)
    assert "idle" in ok.chosen
    eta_only = next(c for c in ok.candidates if c.terms == ("eta",) and not c.standstill)
    assert not eta_only.ok and "it has no idle term" in eta_only.status
    assert ok.result.evidence is not None and ok.result.evidence["ratio"] == pytest.approx(6.0 / 5.5, rel=0.1)


@pytest.mark.slow
def test_temperature_terms_need_logged_temperatures():
    truth = dataclasses.replace(BUS, aux_power_w=3000.0, aux_heating_w_per_k=300.0)
    trips = _trips(truth)
    # none logged: the temperature terms are not tried, and the notes say why
    sel = select(BUS, [dataclasses.replace(t, ambient_c=None) for t in trips], time_repeats=0, nested=False)
    assert not any("heat" in c.terms for c in sel.candidates)
    assert any("no trip has a logged ambient temperature" in n for n in sel.notes)
    # most logged (a sensor that dropped out on some days): the others are left out, said
    # so, and the temperature terms are tried on the rest
    some = [dataclasses.replace(t, ambient_c=None) if i % 4 == 0 else t for i, t in enumerate(trips)]
    sel = select(BUS, some, time_repeats=0, nested=False)
    assert "heat" in sel.chosen and len(sel.result.rows) == 45
    assert sum("no ambient temperature logged" in why for why in sel.result.excluded.values()) == 15
    assert any("15 of 60 usable trips logged no ambient temperature" in n for n in sel.notes)
    # a few logged: a candidate with them is refused, naming how many trips lack one
    few = [t if i % 4 == 0 else dataclasses.replace(t, ambient_c=None) for i, t in enumerate(trips)]
    sel = select(BUS, few, time_repeats=0, nested=False)
    heat = next(c for c in sel.candidates if c.terms == ("eta", "heat"))
    assert not heat.ok and "45 of 60 trips have no ambient temperature" in heat.status
    assert "heat" not in sel.chosen


@pytest.mark.slow
def test_selected_table_agrees_with_the_result():
    """The chosen candidate's cross-validated errors (the model's own vectorised
    predictions) equal the result's (through cevm.core.vehicle.predict)."""
    truth = dataclasses.replace(BUS, aux_power_w=4000.0, aux_heating_w_per_k=300.0)
    sel = select(BUS, _trips(truth), time_repeats=0, nested=False)
    chosen = next(c for c in sel.candidates if c.status == "chosen")
    assert chosen.cv.mean_pct == pytest.approx(sel.result.cv.mean_pct, abs=1e-9)
    assert chosen.cv.std_pct == pytest.approx(sel.result.cv.std_pct, abs=1e-9)
    assert sel.nested_cv is None


@pytest.mark.slow
def test_the_calibrated_vehicle_file_holds_the_model_and_what_it_saw(tmp_path):
    """select() -> the vehicle file: fitted keys in file units, the left-out terms zeroed,
    a reference temperature, and a [calibration] table that loads back as the domain."""
    from cevm.io import load_vehicle
    from cevm.io.calibrated import calibration_table, write_calibrated_vehicle

    truth = dataclasses.replace(BUS, aux_power_w=4000.0, aux_heating_w_per_k=300.0, aux_cooling_w_per_k=200.0)
    trips = [dataclasses.replace(t, start_utc_s=1.55e9 + 86400.0 * i) for i, t in enumerate(_trips(truth))]
    src = tmp_path / "bus.toml"
    src.write_text('name = "bus"\npowertrain = "ev"\nkerb_mass_kg = 9000\npayload_kg = 2000\ncda_m2 = 4.0\n'
                   'cr = 0.007\neta = 0.8\nbattery_kwh = 120\nregen_eta = 0.5  # a guess\nwarmup_kwh_per_k = 0.1\n'
                   '\n[sources]\ncda_m2 = "somewhere"\n')
    sel = select(load_vehicle(src), trips, time_repeats=0, vehicle_id="B-1")
    out = tmp_path / "cal.toml"
    write_calibrated_vehicle(src, out, sel.result, force=False, note="test",
                             calibration=calibration_table(sel.result, selected_from=len(sel.candidates)))
    back = load_vehicle(out)
    r = sel.result
    assert back.eta == pytest.approx(r.vehicle.eta, rel=1e-5)
    assert back.aux_heating_w_per_k == pytest.approx(r.fitted["aux_heating_w_per_k"][0], rel=1e-5)
    assert back.regen_eta is None and back.warmup_j_per_k == 0.0  # not in the chosen model
    temps = [t.ambient_c for t in trips]
    assert back.reference_temp_c == pytest.approx(float(np.median(temps)), abs=0.05)
    d = back.calibration
    assert d.terms == sel.chosen and d.n_trips == 60 and d.vehicle_id == "B-1"
    assert d.ambient_c == pytest.approx((min(temps), max(temps)), abs=0.05)
    assert d.cv_std_pct == pytest.approx(r.cv.std_pct, abs=1e-3)
    assert d.first_utc.startswith("2019-02-") and d.mass_kg[0] > 8000
    assert 'cda_m2 = "somewhere"' in out.read_text()  # the rest of the file is kept


@pytest.mark.slow
def test_the_heating_balance_temperature_is_fitted():
    """Trips made with heating below 10 degC (not the default 16): the selection's grid
    finds 10, and its fit is better than one held at 16."""
    truth = dataclasses.replace(BUS, aux_power_w=3000.0, aux_heating_w_per_k=500.0, heating_below_c=10.0)
    trips = _trips(truth)
    sel = select(BUS, trips, time_repeats=0, nested=False)
    assert "heat" in sel.chosen
    assert sel.result.fitted["heating_below_c"][0] == 10.0
    assert sel.result.vehicle.heating_below_c == 10.0
    held = select(BUS, trips, time_repeats=0, nested=False, fit_balance=False)
    assert sel.result.cv.std_pct < held.result.cv.std_pct


def test_a_research_fit_may_widen_the_physical_ranges():
    """A model that is no real vehicle (a lossless drive behind a 0.95 transmission, as
    benchmarks/bench_tables.py's detailed variant with every loss off) is refused under
    the real-vehicle bound 0.89 and fitted, to its true eta, with ``plausible`` widened."""
    trips = _trips(dataclasses.replace(BUS, eta=0.95, regen_eta=None), temps=np.full(60, 19.0), noise=0.002)
    with pytest.raises(CalibrationError, match=r"above the 0\.89"):
        fit(BUS, trips, time_repeats=0)
    res = fit(dataclasses.replace(BUS, priors=None), trips, time_repeats=0, plausible={"eta": (0.05, 1.0)})
    assert res.vehicle.eta == pytest.approx(0.95, abs=0.005)
