"""The detailed model's per-sample series: auxiliary power that changes along a trace
(heating, air conditioning) and a diesel's engine friction scaled while it warms up.

Checked against the constant parameters they generalise and against hand computations."""

import math

import numpy as np
import pytest

from cevm.core.detailed import DieselParams, EvParams, simulate
from cevm.io.vehicles import vehicle_from_mapping

RPM = 2 * math.pi / 60


def bus():
    return vehicle_from_mapping(dict(name="bus", powertrain="ev", mass_kg=9825.0, cda_m2=3.99, cr=0.0066,
                                     eta=0.78, battery_kwh=124.0), "bus.toml")


def hgv():
    return vehicle_from_mapping(dict(name="hgv", powertrain="ice", mass_kg=30000.0, cda_m2=6.62, cr=0.0066,
                                     eta=0.45, fuel_lhv_mj_per_l=35.8), "hgv.toml")


def trace(n=900, seed=4):
    rng = np.random.default_rng(seed)
    t = np.arange(float(n))
    v = np.clip(np.cumsum(rng.normal(0, 0.8, n)), 0, 22)
    v[rng.random(n) < 0.08] = 0.0
    v[:5] = v[-5:] = 0.0
    h = 80.0 + 4.0 * np.sin(t / 90.0)
    return t, v, h


def test_constant_aux_series_equals_the_hvac_parameter():
    t, v, h = trace()
    a = simulate(bus(), t, v, h, params=EvParams(hvac_power_w=7000.0), time_step_s=None)
    b = simulate(bus(), t, v, h, params=EvParams(), aux_power_w=np.full(t.size, 7000.0), time_step_s=None)
    assert b.energy_j == pytest.approx(a.energy_j, rel=1e-12)
    np.testing.assert_allclose(b.samples["soc"], a.samples["soc"], rtol=0, atol=1e-14)


def test_ev_aux_series_adds_its_trapezoid_integral_without_battery_resistance():
    t, v, h = trace()
    p = EvParams(internal_resistance_ohm=0.0)
    aux = 3000.0 + 9000.0 * (t > 300) * (t < 500) + 2.0 * t  # a heater switched on, a ramp
    base = simulate(bus(), t, v, h, params=p, time_step_s=None)
    res = simulate(bus(), t, v, h, params=p, aux_power_w=aux, time_step_s=None)
    integral = float(np.sum(0.5 * (aux[1:] + aux[:-1]) * np.diff(t)))
    assert res.energy_j - base.energy_j == pytest.approx(integral, rel=1e-9)
    np.testing.assert_allclose(res.steps["aux_power_w"] - base.steps["aux_power_w"], 0.5 * (aux[1:] + aux[:-1]))


def test_constant_diesel_aux_series_equals_the_aux_parameter():
    t, v, h = trace()
    a = simulate(hgv(), t, v, h, params=DieselParams(aux_power_w=3000.0 + 2500.0), time_step_s=None)
    b = simulate(hgv(), t, v, h, params=DieselParams(), aux_power_w=np.full(t.size, 2500.0), time_step_s=None)
    assert b.fuel_l == pytest.approx(a.fuel_l, rel=1e-12)
    np.testing.assert_array_equal(b.steps["gear"], a.steps["gear"])


def test_unit_friction_scale_changes_nothing():
    t, v, h = trace()
    a = simulate(hgv(), t, v, h, time_step_s=None)
    b = simulate(hgv(), t, v, h, friction_scale=np.ones(t.size), time_step_s=None)
    assert b.fuel_l == a.fuel_l
    np.testing.assert_array_equal(b.steps["friction_brake_power_w"], a.steps["friction_brake_power_w"])


def test_cold_engine_idle_fuel_by_hand():
    """Idling 600 s with friction twice the hot engine's at first, falling to it after
    300 s: the detailed model's idle rate (P_aux + s P_fric) / e_ind, step by step with
    s the mean of the step's two samples."""
    t = np.arange(0.0, 601.0)
    scale = 1.0 + np.clip((300.0 - t) / 300.0, 0.0, 1.0)
    res = simulate(hgv(), t, np.zeros(t.size), None, friction_scale=scale, time_step_s=None)
    w = 600 * RPM
    p_fric = (0.97e5 + 0.15e5 * 0.6 + 0.05e5 * 0.36) * 9.29e-3 * w / (4 * math.pi)
    e = (0.47 - 0.04 * 0.65**2) * (1 - 0.04 * (3000.0 / w / 800.0) ** 2)
    step_scale = 0.5 * (scale[1:] + scale[:-1])
    fuel = float(np.sum((3000.0 + step_scale * p_fric) / e / 35.8e6))
    assert res.fuel_l == pytest.approx(fuel, rel=1e-12)
    hot = simulate(hgv(), t, np.zeros(t.size), None, time_step_s=None)
    extra = float(np.sum((step_scale - 1.0) * p_fric / e / 35.8e6))
    assert res.fuel_l - hot.fuel_l == pytest.approx(extra, rel=1e-9) and extra > 0.03  # litres


def test_cold_friction_costs_fuel_while_driving_but_not_on_overrun():
    # Down an 8 % slope at 60 km/h the fuel is cut however high the friction.
    t = np.arange(0.0, 61.0)
    v = np.full(t.size, 60 / 3.6)
    res = simulate(hgv(), t, v, 500.0 - 0.08 * v * t, friction_scale=np.full(t.size, 2.5))
    assert res.fuel_l == 0.0
    t, v, h = trace()
    hot = simulate(hgv(), t, v, h, time_step_s=None)
    cold = simulate(hgv(), t, v, h, friction_scale=np.full(t.size, 1.5), time_step_s=None)
    assert cold.fuel_l > hot.fuel_l


def test_series_are_decimated_with_the_trace():
    t = np.arange(0.0, 300.01, 0.1)
    v = np.full(t.size, 10.0)
    aux = np.where(t < 150.0, 0.0, 5000.0)
    fine = simulate(bus(), t, v, None, aux_power_w=aux)  # decimated to 1 s
    coarse_t = t[::10]
    coarse = simulate(bus(), coarse_t, v[::10], None, aux_power_w=aux[::10])
    assert fine.energy_j == pytest.approx(coarse.energy_j, rel=1e-9)


@pytest.mark.parametrize("kwargs, needle", [
    (dict(aux_power_w=np.zeros(5)), "one value per sample"),
    (dict(aux_power_w=np.full(10, -1.0)), ">= 0"),
    (dict(aux_power_w=np.full(10, np.nan)), "finite"),
    (dict(friction_scale=np.zeros(10)), "> 0"),
])
def test_bad_series_are_refused(kwargs, needle):
    t = np.arange(10.0)
    with pytest.raises(ValueError, match=needle):
        simulate(hgv(), t, np.full(10, 5.0), None, **kwargs)


def test_friction_scale_is_refused_for_an_ev():
    t = np.arange(10.0)
    with pytest.raises(ValueError, match="diesel"):
        simulate(bus(), t, np.full(10, 5.0), None, friction_scale=np.ones(10))
