"""The CE engine against analytic cases, the plain per-step reference, and properties."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from cevm.core.cycle import CR0_DEFAULT, CycleVector, drive_cycle_vector
from cevm.core.model import (
    battery_energy_from_wheel_j,
    ev_energy_j,
    ice_fuel_l,
    nonsimplified_positive_j,
    wheel_energy_j,
)
from conftest import DATA, shared_or_skip
from reference import RHO, G, reference_wheel_energy_j

MODES = {"paper": lambda eta: 1.0, "no-credit": lambda eta: 0.0, "ev": lambda eta: eta * eta}


def energy(vec, m, cda, cr, mode, eta=0.8):
    return float(wheel_energy_j(vec, m, cda, cr, MODES[mode](eta)))


# --- analytic cases -----------------------------------------------------------------

@pytest.mark.parametrize("mode", MODES)
def test_constant_speed_flat_is_aero_plus_rolling(mode):
    v, T, m, cda, cr = 15.0, 600.0, 12000.0, 4.0, 0.007
    t = np.arange(0.0, T + 0.5, 1.0)
    vec = drive_cycle_vector(t, np.full(t.size, v))
    expected = 0.5 * RHO * cda * v**3 * T + cr * m * G * v * T
    assert energy(vec, m, cda, cr, mode) == pytest.approx(expected, rel=1e-12)
    assert vec.distance_m == pytest.approx(v * T, rel=1e-12)


@pytest.mark.parametrize("mode", MODES)
def test_steady_climb_adds_m_g_dh(mode):
    v, T, m, cda, cr, grade = 10.0, 300.0, 20000.0, 6.0, 0.006, 0.04
    t = np.arange(0.0, T + 0.5, 1.0)
    h = 100.0 + grade * v * t
    vec = drive_cycle_vector(t, np.full(t.size, v), h)
    dh = grade * v * T
    expected = 0.5 * RHO * cda * v**3 * T + cr * m * G * v * T + m * G * dh
    assert energy(vec, m, cda, cr, mode) == pytest.approx(expected, rel=1e-12)


def test_stop_from_speed_per_mode():
    # Linear braking from v0 to rest at 1 m/s^2, CdA = 0 so only kinetic and rolling.
    v0, dec, m, cr, eta = 12.0, 1.0, 15000.0, 0.006, 0.8
    t = np.arange(0.0, v0 / dec + 0.5, 1.0)
    v = np.maximum(v0 - dec * t, 0.0)
    vec = drive_cycle_vector(t, v)
    T = v0 / dec
    net = -0.5 * m * v0**2 + cr * m * G * (v0 * T / 2)  # trapezoid distance is exact here
    assert net < 0
    # every step brakes harder than rolling resistance: all non-simplified, all negative
    assert vec.n_nonsimplified == t.size - 1
    assert energy(vec, m, 0.0, cr, "paper") == pytest.approx(net, rel=1e-12)
    assert energy(vec, m, 0.0, cr, "no-credit") == 0.0
    assert energy(vec, m, 0.0, cr, "ev", eta) == pytest.approx(eta**2 * net, rel=1e-12)


@pytest.mark.parametrize("mode", MODES)
def test_standstill_costs_nothing(mode):
    t = np.arange(0.0, 100.0)
    vec = drive_cycle_vector(t, np.zeros(t.size))
    assert energy(vec, 10000.0, 4.0, 0.007, mode) == 0.0
    assert vec.idle_s == 99.0 and vec.distance_m == 0.0


def test_fuel_and_battery_conversions():
    t = np.arange(0.0, 601.0)
    vec = drive_cycle_vector(t, np.full(t.size, 20.0))
    e = energy(vec, 30000.0, 6.62, 0.0066, "paper")
    lhv = 35.8e6
    assert float(ice_fuel_l(vec, 30000.0, 6.62, 0.0066, 0.45, lhv)) == pytest.approx(e / (lhv * 0.45), rel=1e-12)
    # EV: eq. 31 plus an auxiliary load over the whole duration
    ev = float(ev_energy_j(vec, 30000.0, 6.62, 0.0066, 0.78, aux_power_w=5000.0))
    assert ev == pytest.approx(e / 0.78 + 5000.0 * 600.0, rel=1e-12)


def test_idle_fuel_counts_standstill_time_only():
    t = np.arange(0.0, 201.0)
    v = np.where(t < 100, 0.0, 10.0)
    vec = drive_cycle_vector(t, v)
    base = float(ice_fuel_l(vec, 20000.0, 6.0, 0.006, 0.4, 36e6))
    with_idle = float(ice_fuel_l(vec, 20000.0, 6.0, 0.006, 0.4, 36e6, idle_fuel_lps=2.0 / 3600))
    assert with_idle - base == pytest.approx(99.0 * 2.0 / 3600, rel=1e-12)


# --- against the per-step reference --------------------------------------------------

def random_cycle(rng, n, hilly=True):
    dt = rng.uniform(0.2, 2.0, n - 1)
    t = np.concatenate([[0.0], np.cumsum(dt)])
    v = np.abs(np.cumsum(rng.normal(0, 1.2, n)))
    v[rng.random(n) < 0.1] = 0.0
    h = np.cumsum(rng.normal(0, 0.4, n)) if hilly else None
    return t, v, h


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(6))
def test_vector_predictions_equal_reference(seed):
    rng = np.random.default_rng(seed)
    t, v, h = random_cycle(rng, 400, hilly=seed % 2 == 0)
    vec = drive_cycle_vector(t, v, h)
    masses = rng.uniform(1000, 45000, 30)
    for mode in MODES:
        for cda, cr, eta in [(3.99, 0.0066, 0.78), (6.62, 0.008, 0.45), (0.6, 0.004, 0.95)]:
            got = wheel_energy_j(vec, masses, cda, cr, MODES[mode](eta))
            want = [reference_wheel_energy_j(t, v, h, m, cda, cr, mode, eta) for m in masses]
            scale = np.abs(want).max() + 1.0
            np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-10 * scale)


def test_table_and_direct_paths_agree():
    rng = np.random.default_rng(7)
    t, v, h = random_cycle(rng, 3000)
    vec = drive_cycle_vector(t, v, h)
    m = rng.uniform(2000, 40000, 500)
    cda = rng.uniform(0.5, 8, 500)
    from cevm.core.model import _positive_direct

    fast = nonsimplified_positive_j(vec, m, cda, 0.0066)  # one Cr, many: sorted table
    slow = _positive_direct(vec, m, cda, 0.0066)
    np.testing.assert_allclose(fast, slow, rtol=1e-10, atol=1e-6)
    # many distinct Cr values mixed in one call, broadcast over a 2-D grid
    crs = rng.uniform(0.004, 0.012, 500)
    grid = nonsimplified_positive_j(vec, m[:, None], cda[:, None], np.stack([crs, np.full(500, 0.0066)], 1))
    np.testing.assert_allclose(grid[:, 0], [_positive_direct(vec, m[i:i+1], cda[i:i+1], crs[i])[0] for i in range(500)],
                               rtol=1e-10, atol=1e-6)
    np.testing.assert_allclose(grid[:, 1], fast, rtol=1e-10, atol=1e-6)


def test_scalar_calls_repeated_switch_to_the_table_and_stay_exact():
    rng = np.random.default_rng(11)
    t, v, h = random_cycle(rng, 800)
    vec = drive_cycle_vector(t, v, h)
    want = reference_wheel_energy_j(t, v, h, 18000.0, 5.0, 0.007, "ev", 0.8)
    got = [float(wheel_energy_j(vec, 18000.0, 5.0, 0.007, 0.64)) for _ in range(6)]
    assert 0.007 in vec._tables  # built after a few direct sums
    np.testing.assert_allclose(got, want, rtol=1e-10)
    arr = wheel_energy_j(vec, np.array([18000.0, 18000.0]), 5.0, 0.007, 0.64)
    np.testing.assert_allclose(arr, want, rtol=1e-10)


ADVISOR_STANDINS = ["CYC_STANDIN_BUS.csv", "CYC_STANDIN_TOWNTRUCK.csv", "CYC_STANDIN_10HZ.csv"]
ADVISOR_PUBLIC = ["CYC_UKBUS6.csv", "CYC_NYCTRUCK.csv", "CYC_HHDDT65.csv"]


@pytest.mark.parametrize("source", ["standin", "public"])
def test_public_cycles_against_reference(source):
    """ADVISOR-layout cycles (a 10 Hz one among them): the stand-ins of tests/data/cycles,
    and the public cycles when ../shared is there."""
    import pandas as pd

    if source == "public":
        folder, names = shared_or_skip("cycles", "advisor"), ADVISOR_PUBLIC
    else:
        folder, names = DATA / "cycles" / "advisor-standin", ADVISOR_STANDINS
    for name in names:
        df = pd.read_csv(folder / name)
        t = df["time_s"].to_numpy(float)
        v = df["speed_kmh"].to_numpy(float) / 3.6
        vec = drive_cycle_vector(t, v)
        for mode in MODES:
            for m in (9825.0, 44000.0):
                got = energy(vec, m, 3.99, 0.0066, mode, 0.78)
                want = reference_wheel_energy_j(t, v, None, m, 3.99, 0.0066, mode, 0.78)
                assert got == pytest.approx(want, rel=1e-10), (name, mode, m)


def test_cr_below_cr0_is_refused():
    t = np.arange(0.0, 10.0)
    vec = drive_cycle_vector(t, np.full(10, 5.0), cr0=0.005)
    with pytest.raises(ValueError, match="Cr0"):
        wheel_energy_j(vec, 1000.0, 1.0, 0.004, 0.5)


def test_serialisation_round_trip():
    rng = np.random.default_rng(3)
    t, v, h = random_cycle(rng, 500)
    vec = drive_cycle_vector(t, v, h, cr0=0.005)
    back = CycleVector.from_bytes(vec.to_bytes())
    for name in ("s_me", "s_a", "s_r", "stand_x", "cr0", "duration_s", "distance_m", "idle_s", "n_samples", "physics"):
        assert getattr(back, name) == getattr(vec, name)
    for name in ("ns_x", "ns_a", "ns_r"):
        np.testing.assert_array_equal(getattr(back, name), getattr(vec, name))



def test_vectors_stored_as_npz_by_earlier_versions_still_read():
    # version 1 stored an npz archive (written here as it did): stores made then stay usable
    import io

    rng = np.random.default_rng(4)
    t, v, h = random_cycle(rng, 300)
    vec = drive_cycle_vector(t, v, h)
    buf = io.BytesIO()
    scalars = np.array([vec.s_me, vec.s_a, vec.s_r, vec.stand_x, vec.cr0, vec.duration_s, vec.distance_m,
                        vec.idle_s, float(vec.n_samples), vec.physics.rho_air_kg_m3, vec.physics.g_mps2])
    np.savez(buf, version=np.array([1]), scalars=scalars, ns=np.stack([vec.ns_x, vec.ns_a, vec.ns_r]))
    old = CycleVector.from_bytes(buf.getvalue())
    assert old.delta.tolist() == vec.delta.tolist() and old.n_samples == vec.n_samples
    np.testing.assert_array_equal(old.ns_a, vec.ns_a)
    assert wheel_energy_j(old, 12000.0, 5.0, 0.006, 0.5) == wheel_energy_j(vec, 12000.0, 5.0, 0.006, 0.5)


def test_corrupt_vector_bytes_are_refused():
    data = drive_cycle_vector(np.arange(50.0), np.full(50, 8.0)).to_bytes()
    with pytest.raises(ValueError, match="truncated"):
        CycleVector.from_bytes(data[:-8])
    with pytest.raises(ValueError, match="magic"):
        CycleVector.from_bytes(b"XXXXXXXX" + data[8:])


# --- properties -----------------------------------------------------------------------

@st.composite
def cycles(draw, min_n=3, max_n=60):
    n = draw(st.integers(min_n, max_n))
    dt = draw(hnp.arrays(np.float64, n - 1, elements=st.floats(0.1, 5.0)))
    v = draw(hnp.arrays(np.float64, n, elements=st.one_of(st.just(0.0), st.floats(0.0, 35.0))))
    h = draw(hnp.arrays(np.float64, n, elements=st.floats(-50.0, 50.0)))
    t = np.concatenate([[0.0], np.cumsum(dt)])
    return t, v, h


def magnitude(t, v, h, m, cda, cr):
    """Sum of |terms| over steps: the scale of floating-point rounding in E_DC [J]."""
    dt = np.diff(t)
    k = np.abs(np.diff(v**2)) / 2
    e = G * np.abs(np.diff(h))
    a = 0.25 * RHO * (v[:-1] ** 3 + v[1:] ** 3) * dt
    r = 0.5 * G * (v[:-1] + v[1:]) * dt
    return float(np.sum(m * (k + e) + cda * a + cr * m * r)) + 1.0


vehicle_params = st.tuples(
    st.floats(500.0, 60000.0),  # mass
    st.floats(0.0, 10.0),  # CdA
    st.floats(CR0_DEFAULT, 0.02),  # Cr
    st.floats(0.2, 1.0),  # eta
)


@pytest.mark.slow
@settings(max_examples=200, deadline=None)
@given(cycles(), vehicle_params, st.sampled_from(list(MODES)))
def test_property_equals_reference(cyc, params, mode):
    t, v, h = cyc
    m, cda, cr, eta = params
    vec = drive_cycle_vector(t, v, h)
    got = energy(vec, m, cda, cr, mode, eta)
    want = reference_wheel_energy_j(t, v, h, m, cda, cr, mode, eta)
    assert got == pytest.approx(want, rel=1e-9, abs=1e-12 * magnitude(t, v, h, m, cda, cr))


@pytest.mark.slow
@settings(max_examples=100, deadline=None)
@given(cycles(min_n=4), st.data(), vehicle_params, st.sampled_from(list(MODES)))
def test_property_split_anywhere_sums_to_whole(cyc, data, params, mode):
    t, v, h = cyc
    j = data.draw(st.integers(1, len(t) - 2))
    m, cda, cr, eta = params
    whole = drive_cycle_vector(t, v, h)
    halves = drive_cycle_vector(t[: j + 1], v[: j + 1], h[: j + 1]) + drive_cycle_vector(t[j:], v[j:], h[j:])
    assert halves.duration_s == pytest.approx(whole.duration_s)
    assert halves.distance_m == pytest.approx(whole.distance_m)
    w, s = energy(whole, m, cda, cr, mode, eta), energy(halves, m, cda, cr, mode, eta)
    assert s == pytest.approx(w, rel=1e-9, abs=1e-12 * magnitude(t, v, h, m, cda, cr))


@pytest.mark.slow
@settings(max_examples=100, deadline=None)
@given(cycles(), vehicle_params, st.floats(1.0, 10.0))
def test_property_paper_ice_is_affine_in_mass(cyc, params, k):
    t, v, h = cyc
    m, cda, cr, _ = params
    vec = drive_cycle_vector(t, v, h)
    e0 = energy(vec, m, cda, cr, "paper")
    e1 = energy(vec, k * m, cda, cr, "paper")
    e2 = energy(vec, 2 * k * m - m, cda, cr, "paper")  # equally spaced masses
    assert e2 - e1 == pytest.approx(e1 - e0, abs=1e-12 * magnitude(t, v, h, 2 * k * m, cda, cr))


@pytest.mark.slow
@settings(max_examples=100, deadline=None)
@given(cycles(), vehicle_params)
def test_property_braking_modes_are_ordered(cyc, params):
    # no credit >= EV (credit eta^2) >= paper (full credit); EV battery energy falls with eta
    t, v, h = cyc
    m, cda, cr, eta = params
    vec = drive_cycle_vector(t, v, h)
    nc, ev, paper = (energy(vec, m, cda, cr, mode, eta) for mode in ("no-credit", "ev", "paper"))
    tol = 1e-12 * magnitude(t, v, h, m, cda, cr)
    assert nc >= ev - tol and ev >= paper - tol
    assert ev >= eta * eta * paper - tol  # never below the full-regeneration bound x eta^2
    etas = np.array([0.3, 0.5, 0.7, 0.9])
    batt = battery_energy_from_wheel_j(wheel_energy_j(vec, m, cda, cr, etas**2), etas)
    if nc > tol:  # a cycle that needs traction at all
        assert np.all(np.diff(batt) <= 1e-11 * magnitude(t, v, h, m, cda, cr))


@pytest.mark.slow
@settings(max_examples=100, deadline=None)
@given(cycles(), vehicle_params, st.floats(-1e4, 1e4), st.floats(-500.0, 500.0))
def test_property_invariant_to_time_and_elevation_offsets(cyc, params, dt0, dh0):
    t, v, h = cyc
    m, cda, cr, eta = params
    a = drive_cycle_vector(t, v, h)
    b = drive_cycle_vector(t + dt0, v, h + dh0)
    for mode in MODES:
        ea, eb = energy(a, m, cda, cr, mode, eta), energy(b, m, cda, cr, mode, eta)
        scale = magnitude(t, v, h, m, cda, cr) + m * G * abs(dh0) + (abs(dt0) + 1.0) * 1e-9
        assert eb == pytest.approx(ea, rel=1e-9, abs=1e-11 * scale)


@pytest.mark.slow
@settings(max_examples=100, deadline=None)
@given(cycles(), st.floats(500.0, 60000.0), st.floats(CR0_DEFAULT, 0.02))
def test_property_linear_resampling_keeps_kinetic_potential_rolling(cyc, m, cr):
    # Inserting linearly interpolated midpoints leaves the trapezoidal distance exact and
    # the kinetic and potential sums telescoping: paper-mode energy with CdA = 0 is unchanged.
    t, v, h = cyc

    def refine(x):
        out = np.empty(2 * len(x) - 1)
        out[0::2] = x
        out[1::2] = (x[:-1] + x[1:]) / 2
        return out

    t2, v2, h2 = refine(t), refine(v), refine(h)
    a = drive_cycle_vector(t, v, h)
    b = drive_cycle_vector(t2, v2, h2)
    assert b.distance_m == pytest.approx(a.distance_m, rel=1e-9, abs=1e-9)
    ea, eb = energy(a, m, 0.0, cr, "paper"), energy(b, m, 0.0, cr, "paper")
    assert eb == pytest.approx(ea, rel=1e-9, abs=1e-12 * magnitude(t, v, h, m, 0.0, cr))
    # aerodynamic work: v^3 is convex, so the trapezoid rule over-estimates it on each
    # linear piece and refining can only lower it
    assert b.s_a + b.ns_a.sum() <= a.s_a + a.ns_a.sum() + 1e-9 * (a.s_a + a.ns_a.sum() + 1.0)
