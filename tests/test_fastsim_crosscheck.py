"""Tests of benchmarks/crosscheck_fastsim.py: cevm's detailed model against NREL FASTSim 3.

Skipped without the optional ``fastsim`` package (cevm never needs it). Traces are made
here; FASTSim's own vehicle files and cycles come with the package.

Expected values are written out plainly from the physics both models share:

- at constant speed v on the flat, both models need the road-load power
  P = rho CdA v^3 / 2 + m g Cr v at the wheels (FASTSim's drag uses the cube of the step's
  mean speed, cevm's the mean of the cubes: the same when the speed is constant);
- FASTSim's battery power is then P / eta_tr / eff(P_m / P_max) + P_aux (its efficiency
  table read here from its vehicle file), cevm's P / eta_tr + loss(T, w) + P_aux with
  the loss map written out below; the two differ only by the motor loss model, which is
  fitted to FASTSim's curve, so they must agree within that fit's RMS residual;
- over any trace both models' net wheel energies differ by exactly the drag
  discretisation term, computed here by hand for a two-sample trace.
"""

import importlib.util
import math
import sys

import numpy as np
import pytest

from conftest import ROOT

fastsim = pytest.importorskip("fastsim")

V_CRUISE_MPS = 15.0


@pytest.fixture(scope="module")
def cf():
    spec = importlib.util.spec_from_file_location("crosscheck_fastsim", ROOT / "benchmarks" / "crosscheck_fastsim.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # dataclasses look their module up
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def ev(cf):
    return cf.matched_model("ev")


@pytest.fixture(scope="module")
def ice(cf):
    return cf.matched_model("ice")


def ramp_cruise():
    """0 -> 15 m/s at 0.5 m/s^2 (30 s), then 60 s at 15 m/s; the cruise steps' indices."""
    t = np.arange(0.0, 91.0)
    v = np.minimum(0.5 * t, V_CRUISE_MPS)
    cruise = np.flatnonzero((v[:-1] == V_CRUISE_MPS) & (v[1:] == V_CRUISE_MPS))
    return t, v, cruise


def stop_go():
    """Accelerate to 15 m/s, cruise, brake at 1 m/s^2 to a stop, stand 40 s (151 s)."""
    v = np.concatenate([np.minimum(0.5 * np.arange(91), V_CRUISE_MPS),
                        np.maximum(V_CRUISE_MPS - np.arange(1, 21), 0.0), np.zeros(40)])
    return np.arange(float(v.size)), v


def fastsim_curve(resource, component):
    """(P/P_max grid, efficiencies, P_max [W]) read plainly from FASTSim's vehicle file."""
    d = fastsim.Vehicle.from_resource(resource).to_dict(data_fmt="yaml")
    pt = next(iter(d["pt_type"].values()))
    if component == "em":
        c, key = pt["em"], "eff_interp_achieved"
    else:
        c, key = pt["fc"], "eff_interp_from_pwr_out"
    data = c[key]["data"]
    return np.asarray(data["grid"][0], float), np.asarray(data["values"], float), float(c["pwr_out_max_watts"])


def road_load_w(m, v):
    fv, ph = m.fv, m.physics
    return 0.5 * ph.rho_air_kg_m3 * fv.cda_m2 * v**3 + fv.mass_kg * ph.g_mps2 * fv.cr * v


def test_fastsim_physics_plausible(ev):
    """Measured from FASTSim, not assumed: air density near sea level, g near 9.81."""
    assert 1.10 < ev.physics.rho_air_kg_m3 < 1.30
    assert 9.78 < ev.physics.g_mps2 < 9.82


def test_drag_discretisation_by_hand(cf):
    """0 -> 10 m/s in 1 s: cevm rho CdA (0 + 1000)/4, FASTSim rho CdA 5^3 / 2."""
    got = cf.drag_discretisation_j([0.0, 1.0], [0.0, 10.0], cda_m2=2.0, rho_kg_m3=1.2)
    assert got == pytest.approx(1.2 * 2.0 * (1000.0 / 4.0 - 125.0 / 2.0), rel=1e-12)


def test_ev_constant_speed_reduces_to_road_load_over_efficiency(cf, ev):
    t, v, cruise = ramp_cruise()
    df = cf.run_fastsim_frame(ev.fv.resource, t, v)
    res = ev.simulate(t, v)
    p_road = road_load_w(ev, V_CRUISE_MPS)

    # wheels: both exactly the road load
    fs_wheel = df["veh.history.pwr_tractive_watts"].to_numpy()[1:][cruise]
    np.testing.assert_allclose(fs_wheel, p_road, rtol=1e-9)
    np.testing.assert_allclose(res.steps["wheel_power_w"][cruise], p_road, rtol=1e-9)

    # FASTSim's battery: P / eta_tr / eff(P_m / P_max) + aux, its own table
    grid, eff, p_max = fastsim_curve(cf.EV_RESOURCE, "em")
    eta_tr = ev.fv.transmission_efficiency
    p_shaft = p_road / eta_tr
    fs_batt = p_shaft / np.interp(p_shaft / p_max, grid, eff) + ev.fv.aux_power_w
    got_fs = df["veh.pt_type.BEV.res.history.pwr_out_electrical_watts"].to_numpy()[1:][cruise]
    np.testing.assert_allclose(got_fs, fs_batt, rtol=1e-9)

    # cevm's battery: P / eta_tr + k_c T^2 + k_i w + k_w w^3 + C + aux
    p = ev.params
    w = V_CRUISE_MPS / p.wheel_radius_m * p.gear_ratio * p.final_drive_ratio
    torque = p_shaft / w
    kc = p.copper_loss_frac * p.motor_peak_power_w / p.motor_peak_torque_nm**2
    ki = p.iron_loss_frac * p.motor_peak_power_w / p.motor_max_speed_rad_s
    kw = p.windage_loss_frac * p.motor_peak_power_w / p.motor_max_speed_rad_s**3
    c = p.constant_loss_frac * p.motor_peak_power_w
    ce_batt = p_shaft + kc * torque**2 + ki * w + kw * w**3 + c + p.aux_base_power_w
    np.testing.assert_allclose(res.steps["battery_power_w"][cruise], ce_batt, rtol=1e-9)

    # across models: only the loss model differs, fitted to FASTSim's curve
    assert abs(ce_batt - fs_batt) <= ev.fit.rms_w
    assert abs(ce_batt / fs_batt - 1.0) < 0.05


def test_ice_constant_speed_fastsim_is_road_load_over_efficiency(cf, ice):
    """FASTSim's engine: (P / eta_tr + aux) / eff(P_b / P_max); cevm: its Willans line
    at the engine speed of its chosen gear."""
    t, v, cruise = ramp_cruise()
    df = cf.run_fastsim_frame(ice.fv.resource, t, v)
    res = ice.simulate(t, v)
    p_road = road_load_w(ice, V_CRUISE_MPS)
    grid, eff, p_max = fastsim_curve(cf.CONV_RESOURCE, "fc")
    pb = p_road / ice.fv.transmission_efficiency + ice.fv.aux_power_w
    got_fs = df["veh.pt_type.Conv.fc.history.pwr_fuel_watts"].to_numpy()[1:][cruise]
    np.testing.assert_allclose(got_fs, pb / np.interp(pb / p_max, grid, eff), rtol=1e-9)

    p = ice.params
    w = res.steps["engine_speed_rad_s"][cruise]
    n_k = w / (1000.0 * 2.0 * math.pi / 60.0)
    fmep = p.fmep0_pa + p.fmep1_pa * n_k + p.fmep2_pa * n_k**2
    fuel = (pb + fmep * p.displacement_m3 * w / (4.0 * math.pi)) / p.indicated_efficiency_max
    np.testing.assert_allclose(res.steps["fuel_power_w"][cruise], fuel, rtol=1e-9)


@pytest.mark.parametrize("kind", ["ev", "ice"])
def test_cycle_wheel_energy_differs_by_drag_term_only(cf, ev, ice, kind):
    """Stop-go trace: the net wheel energies differ by the drag term alone, and FASTSim's
    powertrain equations on cevm's power reproduce FASTSim up to that term passing through
    the efficiencies (2e-4 of the wheel energy here, so 1e-3)."""
    m = ev if kind == "ev" else ice
    t, v = stop_go()
    r = cf.compare(m, t, v)
    assert r["trace_met"]
    assert r["drag_discretisation_j"] > 0
    assert abs(r["wheel_diff_after_drag"]) < 1e-9
    assert abs(r["via_diff"]) < 1e-3
    assert r["ce_deficit_j"] < 1e-6


def test_fits_are_physical(ev, ice):
    p = ev.params
    assert min(p.copper_loss_frac, p.iron_loss_frac, p.windage_loss_frac, p.constant_loss_frac) >= 0
    assert ev.fit.fitted_energy_j == pytest.approx(ev.fit.target_energy_j, rel=0.02)
    q = ice.params
    assert 0.2 < q.indicated_efficiency_max < 0.5
    assert min(q.fmep0_pa, q.fmep1_pa, q.fmep2_pa) >= 0
    assert ice.fit.fitted_energy_j == pytest.approx(ice.fit.target_energy_j, rel=0.02)
