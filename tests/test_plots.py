"""The figures are drawn without pyplot: a program (or notebook) that calls the plot
functions keeps its matplotlib backend, and no figure stays open."""

from __future__ import annotations

import subprocess
import sys

import pytest

SCRIPT = r"""
import struct, sys
import matplotlib
matplotlib.use("svg")  # the caller's choice, which drawing a PNG must not change
import numpy as np
from cevm.core.detailed import simulate
from cevm.io.vehicles import vehicle_from_mapping
from cevm.io.plots import plot_simulation

veh = vehicle_from_mapping(dict(name="bus", powertrain="ev", mass_kg=9825.0, cda_m2=3.99, cr=0.0066, eta=0.78,
                                battery_kwh=124.0), "bus.toml")
t = np.arange(0.0, 301.0)
v = np.clip(10 * np.sin(t / 40.0), 0, None)
res = simulate(veh, t, v, 50 + np.sin(t / 30.0))
plot_simulation(res.to_frame(), res, sys.argv[1], "bus")
head = open(sys.argv[1], "rb").read(24)
assert head[:8] == b"\x89PNG\r\n\x1a\n", head
print(matplotlib.get_backend(), "matplotlib.pyplot" in sys.modules, struct.unpack(">II", head[16:24]))
"""


@pytest.mark.slow
def test_plotting_keeps_the_callers_backend_and_leaves_pyplot_alone(tmp_path):
    out = subprocess.run([sys.executable, "-c", SCRIPT, str(tmp_path / "sim.png")], capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    backend, pyplot_imported, size = out.stdout.strip().split(maxsplit=2)
    assert backend == "svg" and pyplot_imported == "False"
    assert size == "(1200, 540)"  # figsize 10 x 4.5 in at 120 dpi
