"""The detailed (baseline) simulation: physical sanity against hand computations, the CE
engine's road loads, and plain per-step reference loops written here."""

import math
import time
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cevm.core.cycle import drive_cycle_vector
from cevm.core.detailed import DieselParams, EvParams, decimate_indices, simulate
from cevm.core.model import wheel_energy_j
from cevm.errors import InputError
from cevm.io import load_vehicle, read_cycle_csv
from cevm.io.detailed import diesel_params_from_vehicle, ev_params_from_vehicle
from cevm.io.vehicles import vehicle_from_mapping

RHO, G = 1.225, 9.81
RPM = 2 * math.pi / 60
BIG = 1e12


def bus_vehicle(detailed=None):
    d = dict(name="bus", powertrain="ev", mass_kg=9825.0, cda_m2=3.99, cr=0.0066, eta=0.78, battery_kwh=124.0)
    if detailed is not None:
        d["detailed"] = detailed
    return vehicle_from_mapping(d, "bus.toml")


def hgv_vehicle(detailed=None):
    d = dict(name="hgv", powertrain="ice", mass_kg=30000.0, cda_m2=6.62, cr=0.0066, eta=0.45, fuel_lhv_mj_per_l=35.8)
    if detailed is not None:
        d["detailed"] = detailed
    return vehicle_from_mapping(d, "hgv.toml")


# Lossless, unlimited electric powertrain: battery energy must equal wheel energy.
IDEAL_EV = EvParams(
    transmission_efficiency=1.0,
    motor_peak_power_w=BIG,
    motor_peak_torque_nm=BIG,
    copper_loss_frac=0.0,
    iron_loss_frac=0.0,
    windage_loss_frac=0.0,
    constant_loss_frac=0.0,
    regen_max_power_w=BIG,
    regen_fade_low_mps=0.0,
    regen_fade_high_mps=0.0,
    ocv_cell_v=(3.7,) * 11,
    internal_resistance_ohm=0.0,
    aux_base_power_w=0.0,
    wheel_inertia_kgm2=0.0,
    motor_inertia_kgm2=0.0,
)


def random_trace(seed, n=400, hills=True, irregular=True):
    """Speed with stops, irregular time steps, elevation changing only while moving."""
    rng = np.random.default_rng(seed)
    dt = rng.uniform(0.3, 2.5, n - 1) if irregular else np.ones(n - 1)
    t = np.concatenate([[0.0], np.cumsum(dt)])
    v = np.clip(np.cumsum(rng.normal(0, 1.2, n)), 0, 25)
    v[rng.random(n) < 0.1] = 0.0
    v[:3] = 0.0
    v[-3:] = 0.0
    ds = 0.5 * (v[1:] + v[:-1]) * dt
    grade = 0.06 * np.sin(np.arange(n - 1) / 37.0) if hills else np.zeros(n - 1)
    h = 50.0 + np.concatenate([[0.0], np.cumsum(grade * ds)])
    return t, v, h


# --- road loads: the wheel energy is the CE model's ---------------------------------------


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), mass=st.floats(2000, 40000))
def test_lossless_ev_battery_energy_equals_ce_wheel_energy(seed, mass):
    t, v, h = random_trace(seed)
    veh = bus_vehicle()
    res = simulate(veh, t, v, h, mass_kg=mass, params=IDEAL_EV, time_step_s=None)
    vec = drive_cycle_vector(t, v, h)
    ce = float(wheel_energy_j(vec, mass, veh.cda_m2, veh.cr, negative_weight=1.0))
    assert res.wheel_energy_j == pytest.approx(ce, rel=1e-9, abs=1e-3)
    assert res.energy_j == pytest.approx(ce, rel=1e-9, abs=1e-3)
    assert res.friction_brake_energy_j == pytest.approx(0.0, abs=1e-6)
    assert res.traction_deficit_j == pytest.approx(0.0, abs=1e-6)


def test_diesel_wheel_energy_equals_ce_wheel_energy():
    t, v, h = random_trace(3)
    veh = hgv_vehicle()
    res = simulate(veh, t, v, h, params=DieselParams(wheel_inertia_kgm2=0.0), time_step_s=None)
    ce = float(wheel_energy_j(drive_cycle_vector(t, v, h), veh.mass_kg, veh.cda_m2, veh.cr, 1.0))
    assert res.wheel_energy_j == pytest.approx(ce, rel=1e-9)


def test_wheel_force_by_hand_on_a_grade_with_rotating_mass():
    # 10 m/s -> 12 m/s in 2 s, climbing 3 m over the 22 m travelled.
    p = EvParams(wheel_inertia_kgm2=50.0, motor_inertia_kgm2=0.4)
    t, v, h = np.array([0.0, 2.0]), np.array([10.0, 12.0]), np.array([0.0, 3.0])
    m, cda, cr = 9825.0, 3.99, 0.0066
    res = simulate(bus_vehicle(), t, v, h, params=p, time_step_s=None)
    m_rot = (50.0 + 0.4 * (1.4 * 5.74) ** 2) / 0.466**2
    energy = (m + m_rot) * 0.5 * (144 - 100) + m * G * 3 + cda * 0.25 * RHO * (1000 + 1728) * 2 + cr * m * G * 11 * 2
    assert res.steps["wheel_power_w"][0] == pytest.approx(energy / 2.0, rel=1e-12)
    assert res.steps["wheel_force_n"][0] == pytest.approx(energy / 22.0, rel=1e-12)


# --- electric bus ---------------------------------------------------------------------


def test_constant_speed_battery_power_by_hand():
    p = EvParams()
    v, m, cda, cr = 50 / 3.6, 9825.0, 3.99, 0.0066
    t = np.arange(0.0, 101.0)
    res = simulate(bus_vehicle(), t, np.full(t.size, v), None, params=p, soc_start=0.8)
    force = 0.5 * RHO * cda * v**2 + cr * m * G
    ratio, r = 1.40 * 5.74, 0.466
    torque = force * r / (ratio * 0.95)
    w = v * ratio / r
    kc, ki = 0.06 * 180e3 / 1100**2, 0.015 * 180e3 / (4500 * RPM)
    kw, c = 0.005 * 180e3 / (4500 * RPM) ** 3, 0.003 * 180e3
    p_el = force * v / 0.95 + kc * torque**2 + ki * w + kw * w**3 + c
    assert 0.85 < force * v / 0.95 / p_el < 0.92  # a light-load motor+inverter efficiency
    np.testing.assert_allclose(res.steps["motor_torque_nm"], torque, rtol=1e-12)
    np.testing.assert_allclose(res.steps["motor_electric_power_w"], p_el, rtol=1e-12)
    p_batt = p_el + 4000.0
    np.testing.assert_allclose(res.steps["battery_power_w"], p_batt, rtol=1e-12)
    # Current at SoC 0.8: OCV 3.94 V per cell x 180, R = 0.08 ohm: P = V I - R I^2.
    vo = 180 * 3.94
    i0 = (vo - math.sqrt(vo**2 - 4 * 0.08 * p_batt)) / (2 * 0.08)
    assert res.steps["battery_current_a"][0] == pytest.approx(i0, rel=1e-12)
    assert res.energy_j == pytest.approx(p_batt * 100.0, rel=1e-12)


def test_efficiency_varies_with_operating_point():
    p = EvParams()
    w = np.array([100.0, 300.0])
    tq = np.array([100.0, 900.0])
    eff = tq[:, None] * w[None, :] / (tq[:, None] * w[None, :] + p.motor_loss_w(tq[:, None], w[None, :]))
    assert eff.max() - eff.min() > 0.05
    assert eff.max() < 0.97


def test_hard_stop_regeneration_is_limited():
    # 80 km/h to 0 at 3 m/s^2 (7.4 s), 0.1 s steps; no auxiliaries.
    p = replace(EvParams(), aux_base_power_w=0.0, regen_max_power_w=60e3)
    v0 = 80 / 3.6
    t = np.arange(0.0, v0 / 3.0 + 0.1, 0.1)
    v = np.maximum(v0 - 3.0 * t, 0.0)
    res = simulate(bus_vehicle(), t, v, None, params=p, time_step_s=None)
    duration = t[-1] - t[0]
    recovered = -res.energy_j
    assert 0 < recovered <= 60e3 * duration
    kinetic = 0.5 * (9825 + p.rotating_mass_kg()) * v0**2
    assert recovered < 0.5 * kinetic
    # What the motor does not take, the friction brakes do; none below the fade speed.
    s = res.steps
    assert np.all(s["motor_power_w"] >= -60e3 - 1e-6)
    assert np.all(s["motor_torque_nm"][s["speed_mean_mps"] < 4 / 3.6] == 0.0)
    wheel_motor = s["motor_power_w"] / 0.95
    np.testing.assert_allclose(s["friction_brake_power_w"] - wheel_motor, -s["wheel_power_w"], rtol=1e-9, atol=1e-6)


def test_gentle_braking_regenerates_through_the_transmission_losses():
    # 50 -> 30 km/h at 0.5 m/s^2: below every regeneration limit, above the fade speed.
    p = EvParams()
    t = np.arange(0.0, 12.0)
    v = 50 / 3.6 - 0.5 * t
    res = simulate(bus_vehicle(), t, v, None, params=p)
    s = res.steps
    assert np.all(s["wheel_power_w"] < 0)
    np.testing.assert_allclose(s["motor_power_w"], s["wheel_power_w"] * 0.95, rtol=1e-12)
    tq = s["motor_torque_nm"]
    w = s["motor_speed_rad_s"]
    kc, ki, kw, c = p.loss_coefficients
    np.testing.assert_allclose(s["motor_electric_power_w"], tq * w + kc * tq**2 + ki * w + kw * w**3 + c, rtol=1e-12)
    assert np.all(s["motor_electric_power_w"] < 0)
    assert res.friction_brake_energy_j == pytest.approx(0.0, abs=1e-6)


def test_soc_falls_by_energy_over_capacity_with_constant_ocv_and_no_resistance():
    p = replace(IDEAL_EV, aux_base_power_w=5e3)
    t, v, h = random_trace(11)
    veh = bus_vehicle()
    res = simulate(veh, t, v, h, params=p, soc_start=0.9, time_step_s=None)
    assert res.soc[0] == 0.9
    assert 0.9 - res.soc[-1] == pytest.approx(res.energy_j / (124 * 3.6e6), rel=1e-12)
    # With resistance the SoC falls further than the terminal energy alone.
    res_r = simulate(veh, t, v, h, params=replace(p, internal_resistance_ohm=0.2), soc_start=0.9, time_step_s=None)
    assert res_r.soc[-1] < res.soc[-1]


def test_vectorised_soc_matches_a_plain_per_step_loop():
    # Drain most of a small battery so that the OCV changes a lot along the way.
    p = EvParams()
    t, v, h = random_trace(5, n=2000, irregular=True)
    veh = vehicle_from_mapping(
        dict(name="b", powertrain="ev", mass_kg=9825.0, cda_m2=3.99, cr=0.0066, eta=0.8, battery_kwh=3.0), "b"
    )
    res = simulate(veh, t, v, h, params=p, soc_start=0.95, time_step_s=None)
    assert res.soc[0] - res.soc[-1] > 0.5
    soc_grid = np.linspace(0, 1, 11)
    ocv = 180 * np.array([3.40, 3.55, 3.61, 3.65, 3.69, 3.74, 3.80, 3.87, 3.94, 4.02, 4.10])
    mean_ocv = sum(0.05 * (ocv[i] + ocv[i + 1]) for i in range(10))
    q = 3.0 * 3.6e6 / mean_ocv
    soc = 0.95
    socs = [soc]
    for pw, dt in zip(res.steps["battery_power_w"], np.diff(t), strict=True):
        vo = float(np.interp(soc, soc_grid, ocv))
        i = (vo - math.sqrt(vo * vo - 4 * 0.08 * pw)) / (2 * 0.08)
        soc -= i * dt / q
        socs.append(soc)
    np.testing.assert_allclose(res.soc, socs, rtol=0, atol=1e-10)


# --- diesel ---------------------------------------------------------------------------


def test_idle_fuel_rate_by_hand():
    t = np.arange(0.0, 601.0)
    res = simulate(hgv_vehicle(), t, np.zeros(t.size), None)
    w = 600 * RPM
    p_fric = (0.97e5 + 0.15e5 * 0.6 + 0.05e5 * 0.36) * 9.29e-3 * w / (4 * math.pi)
    torque = 3000.0 / w
    e = (0.47 - 0.04 * 0.65**2) * (1 - 0.04 * (torque / 800.0) ** 2)
    rate_lph = (3000.0 + p_fric) / e / 35.8e6 * 3600
    assert 1.5 <= rate_lph <= 2.0
    assert res.fuel_l == pytest.approx(rate_lph * 600 / 3600, rel=1e-12)
    assert np.all(res.steps["gear"] == 0)


def test_fuel_cut_coasting_down_a_steep_hill():
    # 60 km/h down an 8 % slope: gravity gives far more than the road loads take.
    t = np.arange(0.0, 61.0)
    v = np.full(t.size, 60 / 3.6)
    h = 500.0 - 0.08 * v * t
    res = simulate(hgv_vehicle(), t, v, h)
    assert res.fuel_l == 0.0
    assert np.all(res.steps["gear"] > 0)
    assert res.friction_brake_energy_j > 0


def test_willans_line_by_hand_at_constant_speed():
    # A pure Willans line: constant indicated efficiency, constant FMEP.
    p = DieselParams(indicated_efficiency_speed_drop=0.0, indicated_efficiency_load_drop=0.0, fmep1_pa=0.0,
                     fmep2_pa=0.0)
    v, m, cda, cr = 80 / 3.6, 30000.0, 6.62, 0.0066
    t = np.arange(0.0, 201.0)
    res = simulate(hgv_vehicle(), t, np.full(t.size, v), None, params=p)
    gears = res.steps["gear"]
    assert np.all(gears == 12)  # 1,173 rpm: above 950 + 400 x (88 kW / 229 kW) = 1,104 rpm
    w = v / 0.49 * 2.71
    p_wheel = 0.5 * RHO * cda * v**3 + cr * m * G * v
    p_eng = p_wheel / (0.985 * 0.965) + 3000.0
    fuel_power = (p_eng + 0.97e5 * 9.29e-3 * w / (4 * math.pi)) / 0.47
    assert res.fuel_l == pytest.approx(fuel_power * 200 / 35.8e6, rel=1e-12)
    np.testing.assert_allclose(res.steps["engine_speed_rad_s"], w, rtol=1e-12)


def test_fuel_increases_with_mass_and_ev_energy_too():
    t, v, h = random_trace(8, n=600, irregular=False)
    fuels = [simulate(hgv_vehicle(), t, v, h, mass_kg=m).fuel_l for m in (18000, 26000, 34000, 44000)]
    assert np.all(np.diff(fuels) > 0)
    energies = [simulate(bus_vehicle(), t, v, h, mass_kg=m).energy_j for m in (8000, 9825, 12000)]
    assert np.all(np.diff(energies) > 0)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 10_000), mass=st.floats(15000, 44000))
def test_gear_choice_keeps_engine_speed_within_limits(seed, mass):
    t, v, h = random_trace(seed, irregular=False)
    p = DieselParams()
    res = simulate(hgv_vehicle(), t, v, h, mass_kg=mass, params=p)
    s = res.steps
    n_rpm = s["engine_speed_rad_s"] / RPM
    assert np.all(n_rpm >= 600 - 1e-9) and np.all(n_rpm <= 2100 + 1e-9)
    assert np.all((s["gear"] >= 0) & (s["gear"] <= 12))
    # Engaged and not short of power: at least the shift rule's lowest speed.
    in_gear = (s["gear"] > 0) & (s["traction_deficit_w"] == 0)
    assert np.all(n_rpm[in_gear] >= 950 - 1e-6)
    # Torque never above the full-load curve; no fuel without positive indicated power.
    assert np.all(s["engine_torque_nm"] <= p.full_load_torque(s["engine_speed_rad_s"]) + 1e-6)
    assert np.all(s["fuel_rate_lps"] >= 0)
    assert np.all(np.diff(res.fuel_cum_l) >= 0)


# --- parameters from vehicle files ------------------------------------------------------


def test_shipped_vehicle_tables_parse(root):
    bus = load_vehicle(root / "configs/vehicles/electric-bus.toml")
    hgv = load_vehicle(root / "configs/vehicles/diesel-hgv.toml")
    assert ev_params_from_vehicle(bus).motor_peak_power_w == 180e3
    dp = diesel_params_from_vehicle(hgv)
    assert dp.n_gears == 12 and dp.full_load_speed_rad_s[-1] == pytest.approx(2100 * RPM)
    assert 230e3 < dp.rated_power_w() < 240e3


@pytest.mark.parametrize(
    "table, needle",
    [
        ({"motor_peak_powr_kw": 100},
         "unknown key 'motor_peak_powr_kw' in [detailed] (did you mean 'motor_peak_power_kw'?)"),
        ({"motor_peak_power_kw": -5}, "key 'motor_peak_power_kw' = -5 must be > 0"),
        ({"transmission_efficiency": 1.2}, "key 'transmission_efficiency' = 1.2 must be <= 1"),
        ({"internal_resistance_ohm": "low"}, "key 'internal_resistance_ohm' must be a finite number"),
        ({"ocv_cell_v": [3.5, 3.9]}, "key 'ocv_cell_v' must have as many values as ocv_soc"),
        ({"ocv_soc": [0.0, 0.5, 0.4, 1.0], "ocv_cell_v": [3, 3, 3, 3]}, "key 'ocv_soc' must be strictly increasing"),
        ({"regen_fade_low_kmh": 12.0}, "key 'regen_fade_high_kmh' must be >= regen_fade_low_kmh"),
    ],
)
def test_bad_ev_table_names_the_key(table, needle):
    """Refused where the file is read (every command, predict as simulate), naming the
    file; and by the table's reader itself, naming the vehicle."""
    with pytest.raises(InputError) as exc:
        bus_vehicle(table)
    assert needle in str(exc.value)
    assert str(exc.value).startswith("bus.toml:")
    v = bus_vehicle()
    with pytest.raises(InputError) as exc:
        ev_params_from_vehicle(type(v)(**{**v.__dict__, "extra": {"detailed": table}}))
    assert needle in str(exc.value)
    assert str(exc.value).startswith("bus:")


@pytest.mark.parametrize(
    "table, needle",
    [
        ({"gear_ratios": [3.0, 5.0]}, "key 'gear_ratios' must be strictly decreasing"),
        ({"gear_efficiencies": [0.9, 0.9]}, "key 'gear_efficiencies' must have one value per gear ratio"),
        ({"idle_speed_rpm": 2500}, "key 'max_speed_rpm' must be > idle_speed_rpm"),
        ({"motor_peak_power_kw": 100}, "unknown key 'motor_peak_power_kw'"),
    ],
)
def test_bad_diesel_table_names_the_key(table, needle):
    with pytest.raises(InputError) as exc:
        hgv_vehicle(table)  # refused where the file is read, in every command
    assert needle in str(exc.value) and str(exc.value).startswith("hgv.toml:")


def test_table_values_are_converted_to_si():
    p = ev_params_from_vehicle(bus_vehicle({"motor_max_speed_rpm": 6000, "regen_fade_low_kmh": 3.6,
                                            "aux_base_power_kw": 2}))
    assert p.motor_max_speed_rad_s == pytest.approx(200 * math.pi)
    assert p.regen_fade_low_mps == pytest.approx(1.0)
    assert p.aux_base_power_w == pytest.approx(2000.0)
    d = diesel_params_from_vehicle(hgv_vehicle({"displacement_l": 12.7, "full_load_speed_rpm": [600, 2000],
                                                "full_load_torque_nm": [1000, 1000]}))
    assert d.displacement_m3 == pytest.approx(0.0127)
    assert d.full_load_speed_rad_s[1] == pytest.approx(2000 * RPM)


# --- output, time steps, speed ----------------------------------------------------------


def test_to_frame_per_sample_with_units(tmp_path):
    t, v, h = random_trace(2, n=50, irregular=False)
    for veh, cols in ((bus_vehicle(), ["soc_pct", "battery_power_kw", "motor_speed_rpm", "energy_cum_kwh"]),
                      (hgv_vehicle(), ["gear", "engine_speed_rpm", "fuel_rate_lph", "fuel_cum_l"])):
        res = simulate(veh, t, v, h)
        df = res.to_frame()
        assert len(df) == t.size and set(cols) <= set(df.columns)
        assert {"time_s", "speed_kmh", "elevation_m", "wheel_power_kw"} <= set(df.columns)
        assert np.isnan(df["wheel_power_kw"].iloc[-1])
        path = tmp_path / f"{res.powertrain}.csv"
        df.to_csv(path, index=False)
        assert path.read_text().splitlines()[0].startswith("time_s,speed_kmh,elevation_m")
    assert df["fuel_cum_l"].iloc[-1] == pytest.approx(res.fuel_l)


def test_fast_sampled_trace_is_simulated_on_a_one_second_grid():
    t10 = np.round(np.arange(0.0, 120.05, 0.1), 1)
    v10 = 10 + 5 * np.sin(t10 / 10.0)
    idx = decimate_indices(t10, 1.0)
    np.testing.assert_array_equal(t10[idx], np.arange(0.0, 121.0))
    assert decimate_indices(np.arange(0.0, 50.0), 1.0).size == 50
    a = simulate(hgv_vehicle(), t10, v10)
    b = simulate(hgv_vehicle(), t10[::10], v10[::10], time_step_s=None)
    assert a.fuel_l == b.fuel_l and a.time_s.size == 121


def test_invalid_trace_is_refused():
    with pytest.raises(ValueError):
        simulate(bus_vehicle(), [0.0, 1.0, 1.0], [0.0, 1.0, 2.0])
    with pytest.raises(ValueError):
        simulate(bus_vehicle(), [0.0, 1.0], [0.0, -1.0])


def test_a_3600_sample_cycle_simulates_in_milliseconds():
    t, v, h = random_trace(1, n=3600, irregular=False)
    for veh in (bus_vehicle(), hgv_vehicle()):
        simulate(veh, t, v, h)
        best = min(_timed(lambda veh=veh: simulate(veh, t, v, h)) for _ in range(5))
        assert best < 0.02  # typically 1 ms; generous for a loaded machine


def _timed(f):
    t0 = time.perf_counter()
    f()
    return time.perf_counter() - t0


# --- realism over public cycles -----------------------------------------------------------


def test_consumption_is_realistic_on_public_cycles(shared_cycles):
    bus = bus_vehicle()
    for name in ("CYC_UKBUS6", "CYC_MANHATTAN"):
        c = read_cycle_csv(shared_cycles / f"{name}.csv")
        res = simulate(bus, c.time_s, c.speed_mps, None)
        kwh_per_km = res.energy_j / 3.6e6 / (res.distance_m / 1000)
        assert 0.6 < kwh_per_km < 1.5, name
    hgv = hgv_vehicle()
    c = read_cycle_csv(shared_cycles / "CYC_HHDDT65.csv")
    res = simulate(hgv, c.time_s, c.speed_mps, None)
    assert 25 < res.fuel_l / (res.distance_m / 1e5) < 45
    c = read_cycle_csv(shared_cycles / "CYC_CBDTRUCK.csv")
    res_town = simulate(hgv, c.time_s, c.speed_mps, None)
    assert res_town.fuel_l / (res_town.distance_m / 1e5) > 45


def test_a_table_is_read_by_io_and_a_vehicle_whose_table_was_not_read_is_refused():
    """The core reads no vehicle file: a vehicle with a [detailed] table needs its
    parameters passed (cevm.io.detailed), else it is refused, not simulated with the
    defaults; an empty table is the defaults."""
    from cevm.io.detailed import detailed_params

    t, v, h = random_trace(2, n=50, irregular=False)
    weak = bus_vehicle({"motor_peak_power_kw": 20})
    with pytest.raises(TypeError, match="detailed_params"):
        simulate(weak, t, v, h)
    assert detailed_params(weak) == ev_params_from_vehicle(weak)
    hgv = hgv_vehicle({"axle_ratio": 3.0})
    assert detailed_params(hgv) == diesel_params_from_vehicle(hgv)
    assert detailed_params(weak).motor_peak_power_w == 20e3
    assert simulate(bus_vehicle({}), t, v, h).energy_j == simulate(bus_vehicle(), t, v, h).energy_j
