"""No silent fallbacks: a percent option given as a fraction is warned about (one line
per option, saying how it reads), in every command that takes one."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from cevm.cli import app

runner = CliRunner()
ROOT = Path(__file__).resolve().parents[1]
BUS = str(ROOT / "configs/vehicles/electric-bus.toml")
URBAN = str(ROOT / "configs/cycles/urban-bus.csv")


@pytest.mark.parametrize("command", [["predict", "-c", URBAN], ["feasibility", "-c", URBAN],
                                     ["simulate", "-c", URBAN]])
def test_a_percent_given_as_a_fraction_is_warned_about(command):
    res = runner.invoke(app, [command[0], "-v", BUS, *command[1:], "--soc-start", "0.8", "--reserve-pct", "0.15"])
    lines = [line for line in res.stderr.splitlines() if "reads as" in line]
    assert lines == ["cevm: warning: --soc-start 0.8 reads as 0.8 % (a percentage, not a fraction); for 80 % give "
                     "--soc-start 80",
                     "cevm: warning: --reserve-pct 0.15 reads as 0.15 % (a percentage, not a fraction); for 15 % "
                     "give --reserve-pct 15"]
    res = runner.invoke(app, [command[0], "-v", BUS, *command[1:], "--soc-start", "80", "--reserve-pct", "0"])
    assert "reads as" not in res.stderr
