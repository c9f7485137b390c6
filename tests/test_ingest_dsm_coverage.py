"""A --dsm that covers none or few of the logs is said, with the share covered overall
and per file (it fell back to GPS altitude or a flat road in silence)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from cevm.cli import app
from test_ingest import ORIGIN_BNG, write_srf

runner = CliRunner()


def _plane_dsm(path: Path, shift_m: float) -> Path:
    """A flat 6 km x 6 km DSM tile at the logs' origin shifted east by ``shift_m``."""
    import rasterio
    from rasterio.transform import from_origin

    n, res = 600, 10.0
    x0, y1 = ORIGIN_BNG[0] - 1000.0 + shift_m, ORIGIN_BNG[1] + 5000.0
    with rasterio.open(path, "w", driver="GTiff", width=n, height=n, count=1, dtype="float32", crs="EPSG:27700",
                       transform=from_origin(x0, y1, res, res), nodata=-9999.0) as ds:
        ds.write(np.full((n, n), 100.0, dtype=np.float32), 1)
    return path


@pytest.mark.parametrize("shift_m, said", [(0.0, None), (100_000.0, "covers none")])
def test_a_dsm_that_misses_the_logs_is_said(tmp_path, shift_m, said):
    logs = tmp_path / "logs"
    logs.mkdir()
    write_srf(logs / "a.csv", "EB-01", 1_557_820_800, 1)
    write_srf(logs / "b.csv", "EB-02", 1_557_820_800, 2)
    dsm = _plane_dsm(tmp_path / "dsm.tif", shift_m)
    res = runner.invoke(app, ["ingest", str(logs), "--store", str(tmp_path / "s.sqlite"), "--dsm", str(dsm),
                              "--log-json"])
    assert res.exit_code == 0, res.output
    summary = json.loads(res.stdout.splitlines()[-1])
    warning = [line for line in res.stderr.splitlines() if "--dsm" in line]
    if said is None:
        assert summary["dsm_coverage_pct"] > 95 and not warning
    else:
        assert summary["dsm_coverage_pct"] == 0.0
        (line,) = warning
        assert said in line and "of the 2 log(s) ingested" in line and "a.csv 0 %" in line and "b.csv 0 %" in line
