"""The sample buses' GTFS feed (sample_logs/gtfs) is what ``python -m cevm_samplegen
gtfs-feed`` writes, byte for byte, and reads as its README says: 23 weekday trips, blocks
1-AM, 1-PM, 2-MID by block_id and one inferred, none on Christmas Day."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cevm.core.timetable.blocks import day_blocks
from cevm.core.timetable.schedule import trip_geometry
from cevm.errors import CevmError
from cevm.io.gtfs import parse_dates, read_feed
from cevm_samplegen.gtfs import write_feed

SAMPLE = Path(__file__).resolve().parents[1] / "sample_logs" / "gtfs"


def test_regenerates_byte_for_byte(tmp_path):
    write_feed(tmp_path)
    names = sorted(p.name for p in SAMPLE.glob("*.txt"))
    assert names == sorted(p.name for p in tmp_path.glob("*.txt"))
    for n in names:
        assert (tmp_path / n).read_bytes() == (SAMPLE / n).read_bytes(), n


def test_sample_feed_blocks():
    tt = read_feed(SAMPLE, parse_dates(["2019-01-31"]))
    assert tt.n == 23 and tt.timezone == "Europe/London"
    gm = trip_geometry(tt)
    assert set(gm.placed) == {"shape_dist_traveled (m)"}
    first, last = gm.first_last(tt)
    xy = (np.zeros(tt.n), np.zeros(tt.n))
    b = day_blocks(tt.trip_id, tt.block_id, gm.departure_s[first], gm.arrival_s[last], tt.stop[first], tt.stop[last],
                   xy, xy)
    assert sorted(zip(b.names, b.source, (t.size for t in b.trips), strict=True)) == [
        ("1-AM", "feed", 7), ("1-PM", "feed", 7), ("2-MID", "feed", 3), ("inferred:2-X-01", "inferred", 6)]
    with pytest.raises(CevmError, match="no trip runs on 2019-12-25"):
        read_feed(SAMPLE, parse_dates(["2019-12-25"]))


def test_job_summary_says_the_timetable(tmp_path):
    import subprocess
    import sys

    root = SAMPLE.parents[1]
    (tmp_path / "gtfs-blocks.csv").write_text(
        "block_id,date,block_from,distance_km,energy_kwh,completes,p_complete,vehicle_key,driving_from\n"
        "1-AM,2019-01-31,feed,70,80,true,1.0,bus,\"learnt from 51 trips (390 km), shrunk\"\n"
        "X,2019-01-31,inferred,30,40,false,0.2,bus,\"learnt from 51 trips (390 km), shrunk\"\n")
    res = subprocess.run([sys.executable, str(root / "sample_logs/job_summary.py"), str(tmp_path)],
                         capture_output=True, text=True, check=True)
    flat = " ".join(res.stdout.split())
    # 120 kWh over 100 km
    assert ("bus on 2 block-days (1 inferred) of 1 date(s): 1 complete with the reserve kept, 1 at probability "
            "0.95; 40.0-80.0 kWh a block, 1.20 kWh/km; driving learnt from 51 trips (390 km)") in flat
    assert all(len(line) <= 80 for line in res.stdout.splitlines())
