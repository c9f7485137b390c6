"""What an ingest imports: a `cevm ingest` of srf logs (pyarrow reads them) never imports
pandas (0.8 s of CPU and 80 MB a process: each worker of a parallel ingest would pay it);
pandas comes in only where a path needs it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

_PROBE = r"""
import sys, tempfile, os
from cevm.ingest import IngestOptions, ingest
from cevm.store import TripStore
with tempfile.TemporaryDirectory() as d, TripStore.open(os.path.join(d, "s.sqlite")) as st:
    rep = ingest([sys.argv[1]], st, IngestOptions(dsm=sys.argv[2]))
    assert rep.failed == 0, [f.error for f in rep.files]
    assert rep.summary()["trips"] > 0
print("pandas" in sys.modules)
"""


@pytest.mark.slow
def test_ingest_of_srf_logs_does_not_import_pandas():
    srf = ROOT / "sample_logs" / "srf" / "EB-01_2019-01-31.csv"
    out = subprocess.run([sys.executable, "-c", _PROBE, str(srf), str(ROOT / "sample_logs" / "dsm")],
                         capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"
