"""The power a source asks (cevm.core.sweep.power): the largest mean wheel power over any
window of POWER_WINDOW_S, against a plain loop over the windows, on uniform and
irregular time grids; and the masses at which a vehicle can follow."""

from __future__ import annotations

import numpy as np
import pytest

from cevm.core.sweep.power import POWER_WINDOW_S, peak_wheel_power_w, power_mass_window
from cevm.core.sweep.steptable import LegProfile, build_step_table

RHO, G = 1.225, 9.81


def plain_peak_power(t, v, h, m, cda, cr, window_s=POWER_WINDOW_S):
    """The largest mean wheel power [W] of the windows that start at each moving step and
    end at the first sample at least window_s later (or at the end), plainly."""
    best = 0.0
    n = len(t) - 1
    for i in range(n):
        if v[i] == 0 and v[i + 1] == 0:
            continue  # standstill: no window starts here
        work = 0.0
        j = i
        while True:
            dt = t[j + 1] - t[j]
            moving = not (v[j] == 0 and v[j + 1] == 0)
            if moving:
                k = 0.5 * (v[j + 1] ** 2 - v[j] ** 2)
                a = 0.25 * RHO * (v[j] ** 3 + v[j + 1] ** 3) * dt
                r = 0.5 * G * (v[j] + v[j + 1]) * dt
                work += m * (k + G * (h[j + 1] - h[j])) + cda * a + cr * m * r
            j += 1
            if t[j] - t[i] >= window_s * (1 - 1e-9) or j == n:
                break
        best = max(best, work / (t[j] - t[i]))
    return best


def _trace(kind: str, n: int = 400, seed: int = 0):
    rng = np.random.default_rng(seed)
    if kind == "1 s":
        dt = np.ones(n - 1)
    elif kind == "0.1 s":  # times that do not add up exactly
        dt = np.full(n - 1, 0.1)
    elif kind == "irregular":
        dt = rng.uniform(0.2, 2.5, n - 1)
    else:  # 1 s with gaps
        dt = np.where(rng.random(n - 1) < 0.05, 7.0, 1.0)
    t = 1000.0 + np.concatenate([[0.0], np.cumsum(dt)])
    v = np.clip(10 + 6 * np.sin(np.arange(n) / 17.0) + rng.normal(0, 1.0, n), 0, None)
    v[50:70] = 0.0
    h = 20 * np.sin(np.arange(n) / 40.0) + rng.normal(0, 0.2, n)
    return t, v, h


@pytest.mark.parametrize("kind", ["1 s", "0.1 s", "irregular", "gaps"])
def test_peak_wheel_power_is_the_largest_window_mean_of_the_plain_loop(kind):
    t, v, h = _trace(kind)
    st = build_step_table([LegProfile(t, v, h)])
    masses = np.array([5000.0, 20000.0, 44000.0])
    got = peak_wheel_power_w(st, masses, 6.0, 0.006)
    want = [plain_peak_power(t, v, h, m, 6.0, 0.006) for m in masses]
    assert got == pytest.approx(want, rel=1e-9)


@pytest.mark.parametrize("kind", ["1 s", "irregular"])
def test_a_vehicle_follows_exactly_between_the_masses_of_its_power_window(kind):
    t, v, h = _trace(kind, seed=3)
    st = build_step_table([LegProfile(t, v, h)])
    peak_at = peak_wheel_power_w(st, np.array([30000.0]), 6.0, 0.006)[0]
    lo, hi = power_mass_window(st, peak_at, 6.0, 0.006)
    assert lo <= 30000.0 <= hi * (1 + 1e-12)
    inside = np.linspace(max(lo, 1.0), hi, 7)
    assert np.all(peak_wheel_power_w(st, inside, 6.0, 0.006) <= peak_at * (1 + 1e-9))
    assert peak_wheel_power_w(st, np.array([hi * 1.01]), 6.0, 0.006)[0] > peak_at
