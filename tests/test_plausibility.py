"""Plausibility bounds at ingest's inputs: DSM heights,
elevations and grades, speeds and accelerations, and a DSM tile that cannot be read."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from cevm.core.cycle import CycleVector
from cevm.ingest.cleaning import CleanParams, clean_log
from cevm.ingest.dsm import DsmSampler
from cevm.ingest.elevation import ElevationParams, combine_elevation
from cevm.ingest.task import IngestOptions, process_file
from test_ingest import ORIGIN_BNG, plane, write_srf

T0 = 1_600_000_000.0


# ------------------------------------------------------------------ speed, acceleration


def _frame(v, tau=None, **cols) -> pd.DataFrame:
    v = np.asarray(v, dtype=float)
    tau = np.arange(v.size, dtype=float) if tau is None else np.asarray(tau, float)
    return pd.DataFrame({"time_s": T0 + tau, "source_line": np.arange(2, v.size + 2), "wheel_speed_mps": v, **cols})


def test_a_speed_spike_is_rejected_and_bridged():
    """20 m/s with a one-reading spike to 60 m/s (40 m/s in a second: 4 g) and a
    two-reading spike to 0: both rejected, the trip runs at 20 m/s throughout."""
    v = np.full(601, 20.0)
    v[200] = 60.0
    v[400:402] = 0.0
    res = clean_log(_frame(v))
    (trip,) = res.trips
    assert np.allclose(trip.speed_mps, 20.0)
    assert trip.distance_m[-1] == pytest.approx(20.0 * 600)
    assert res.quality["speed_spikes_rejected"] == 3 and res.quality["speed_unresolved_jumps"] == 0
    assert trip.quality["speed_spikes_rejected"] == 3


def test_hard_but_possible_braking_is_kept():
    """An emergency stop at 10 m/s^2 (1 g) from 30 m/s is physics, not a spike."""
    v = np.concatenate([np.full(100, 30.0), 30.0 - 10.0 * np.arange(1, 4), np.zeros(100)])
    v = np.concatenate([v, np.full(200, 10.0)])
    res = clean_log(_frame(v))
    assert res.quality["speed_spikes_rejected"] == 0 and res.quality["speed_unresolved_jumps"] == 0
    assert sum(t.distance_m[-1] for t in res.trips) == pytest.approx(np.sum(0.5 * (v[1:] + v[:-1])), rel=1e-9)


def test_a_lasting_jump_is_reported_not_guessed():
    """A speed that jumps from 10 to 40 m/s and stays (a unit change mid-file?) cannot be
    told from a spike of the first part: nothing is rejected, the jump is reported."""
    v = np.concatenate([np.full(300, 10.0), np.full(300, 40.0)])
    res = clean_log(_frame(v))
    assert res.quality["speed_unresolved_jumps"] == 1 and res.quality["speed_spikes_rejected"] == 0


def test_a_spliced_recording_is_reported_with_its_time_and_size_and_kept_in_the_trip_quality(tmp_path):
    """A 1-s jump of 119 km/h that lasts (two recordings spliced) is kept as
    logged (it cannot be told from a spike of the other part), but no longer silently:
    the trip's stored quality lists it under 'speed_jumps' (UTC time, time step, speeds
    before and after, in SI) for calibrate, and the file's repairs say it with its time
    and size."""
    v = np.concatenate([np.full(300, 5.0), np.full(300, 5.0 + 119 / 3.6), np.full(300, 5.0)])
    res = clean_log(_frame(v))
    (trip,) = res.trips
    jumps = trip.quality["speed_jumps"]
    assert len(jumps) == 2 and trip.quality["speed_unresolved_jumps"] == 2
    up = next(j for j in jumps if j["to_mps"] > j["from_mps"])
    assert up["utc_s"] == T0 + 300 and up["dt_s"] == 1.0 and up["source"] == "wheel_speed_mps"
    assert (up["from_mps"], up["to_mps"]) == (5.0, pytest.approx(5.0 + 119 / 3.6))
    # through a file: the note in the file's repairs, the list in the stored quality
    f = tmp_path / "splice.csv"
    write_srf(f, "EB-01", 1_557_820_800, 0, n=900)
    lines = f.read_text().splitlines()
    head = next(i for i, ln in enumerate(lines) if ln.startswith("timestamp_utc"))
    col = lines[head].split(",").index("fms_wheel_speed_kmh")
    for i in range(head + 400, head + 700):
        cells = lines[i].split(",")
        cells[col] = f"{float(cells[col]) + 119:.1f}"
        lines[i] = ",".join(cells)
    f.write_text("\n".join(lines) + "\n")
    out = process_file(f, IngestOptions())
    assert out.error is None
    notes = [r for r in out.repairs if "lasting speed jump" in r]
    assert len(notes) == 1 and ("+119 km/h in 1 s at 2019-05-14" in notes[0]
                                or "-119 km/h in 1 s at 2019-05-14" in notes[0])
    assert sum(len(t.quality.get("speed_jumps", ())) for t in out.trips) == 2


def test_the_acceleration_bound_is_a_parameter():
    v = np.full(601, 20.0)
    v[300] = 26.0  # 6 m/s in a second and back: possible for the default bound
    assert clean_log(_frame(v)).quality["speed_spikes_rejected"] == 0
    strict = CleanParams(max_accel_mps2=3.0)
    assert clean_log(_frame(v), params=strict).quality["speed_spikes_rejected"] == 1


# ------------------------------------------------------------------------ DSM heights


def _dsm(path, scale=1.0, offset_m=0.0, scale_tag=None):
    """A 2 m DSM (EPSG:27700) of the tilted plane of test_ingest over the trips of
    write_srf, heights times ``scale`` plus ``offset_m`` (or a scale factor in the
    raster's metadata: ``scale_tag``)."""
    import rasterio
    from rasterio.transform import from_origin

    res, n = 2.0, 3000
    x0, y1 = ORIGIN_BNG[0] - 1000.0, ORIGIN_BNG[1] + 5000.0
    xs = x0 + res * (np.arange(n) + 0.5)
    ys = y1 - res * (np.arange(n) + 0.5)
    z = (plane(xs[None, :], ys[:, None]) * scale + offset_m).astype(np.float64)
    with rasterio.open(path, "w", driver="GTiff", width=n, height=n, count=1, dtype="float64", crs="EPSG:27700",
                       transform=from_origin(x0, y1, res, res), nodata=-9999.0, tiled=True, blockxsize=256,
                       blockysize=256, compress="deflate") as ds:
        ds.write(z, 1)
        if scale_tag is not None:
            ds.scales = (scale_tag,)
    return path


@pytest.mark.slow
@pytest.mark.parametrize("how", ["values", "scale_tag"])
def test_dsm_scaled_by_1e6_is_refused_and_gps_used(tmp_path, how):
    """Heights near 1.2e8 m (the plane's 120 m times 1e6, in the values or in the
    raster's scale factor): refused with a warning naming the tile; the trip takes the
    GPS altitude, exactly as without a DSM, and says so."""
    write_srf(tmp_path / "ev.csv", "EB-9", 1_557_820_800, 1)
    bad = _dsm(tmp_path / "bad.tif", **({"scale": 1e6} if how == "values" else {"scale_tag": 1e6}))
    out = process_file(tmp_path / "ev.csv", IngestOptions(dsm=str(bad)))
    ref = process_file(tmp_path / "ev.csv", IngestOptions())
    assert out.ok and ref.ok
    (trip,), (_no_dsm,) = out.trips, ref.trips
    assert trip.elevation_source == "gps" and trip.dsm_coverage_pct == 0.0
    q = trip.quality["elevation"]
    assert q["dsm_refused_samples"] == trip.n_samples
    assert any("refused" in w and "-500..9000 m" in w for w in q["elevation_warnings"])
    assert any("bad.tif" in w for w in q["elevation_warnings"])
    assert any("refused" in r and trip.trip_id in r for r in out.repairs)
    vec, want = CycleVector.from_bytes(out.vectors[0]), CycleVector.from_bytes(ref.vectors[0])
    assert vec.s_me == pytest.approx(want.s_me, rel=1e-12)  # the GPS profile, as without a DSM
    assert abs(vec.s_me) < 1e5  # J/kg: a few hundred metres of climb at most, not 1e8 m


@pytest.mark.slow
def test_dsm_right_but_offset_from_gps_is_warned(tmp_path):
    """A DSM 1000 m above the GPS altitude (a wrong datum or unit): kept (plausible
    heights) but warned about."""
    write_srf(tmp_path / "ev.csv", "EB-9", 1_557_820_800, 1)
    out = process_file(tmp_path / "ev.csv", IngestOptions(dsm=str(_dsm(tmp_path / "up.tif", offset_m=1000.0))))
    (trip,) = out.trips
    assert trip.elevation_source == "dsm"
    assert any("differ from GPS altitude by" in w for w in trip.quality["elevation"]["elevation_warnings"])
    good = process_file(tmp_path / "ev.csv", IngestOptions(dsm=str(_dsm(tmp_path / "ok.tif"))))
    assert good.trips[0].quality["elevation"]["elevation_warnings"] == []


def test_refused_heights_are_counted_in_the_pure_profile():
    d = np.arange(0.0, 2001.0, 10.0)
    raw = 50.0 + 0.01 * d
    raw[50:60] = 9.5e7  # ten samples of a mis-scaled tile
    res = combine_elevation(d, raw, None)
    assert res.dsm_refused == 10 and res.source == "dsm"
    assert res.filled_short_m == pytest.approx(110.0)  # bridged as a DSM gap (d 490..600)
    assert np.abs(res.elevation_m - (50.0 + 0.01 * d)).max() < 1e-6
    strict = combine_elevation(d, raw, None, ElevationParams(dsm_range_m=(0.0, 55.0)))
    assert strict.dsm_refused == int(np.sum(raw > 55.0))


def test_grades_are_bounded_and_a_cliff_profile_is_warned():
    """A staircase of 20 m cliffs every 200 m (DSM walls): every grade ends up within
    15 %, and the profile is called implausibly steep."""
    d = np.arange(0.0, 4001.0, 5.0)
    raw = 20.0 * np.floor(d / 200.0)
    res = combine_elevation(d, raw, None)
    grade = np.diff(res.elevation_m) / np.diff(d)
    assert np.abs(grade).max() <= 0.15 + 1e-9
    assert res.grade_bounded_m > 0.1 * 4000
    assert any("implausibly steep" in w for w in res.warnings)
    gentle = combine_elevation(d, 0.05 * d, None)
    assert gentle.warnings == () and gentle.grade_bounded_m == 0.0


# -------------------------------------------------------------------- unreadable tiles


def _two_tiles(tmp_path):
    """Two DSM tiles of 1 x 2 km side by side (west, east) over the trips of write_srf."""
    import rasterio
    from rasterio.transform import from_origin

    d = tmp_path / "tiles"
    d.mkdir()
    res, w, h = 2.0, 500, 1000
    paths = []
    for k in range(2):
        x0, y1 = ORIGIN_BNG[0] - 200.0 + 1000.0 * k, ORIGIN_BNG[1] + 1800.0
        xs = x0 + res * (np.arange(w) + 0.5)
        ys = y1 - res * (np.arange(h) + 0.5)
        z = plane(xs[None, :], ys[:, None]).astype(np.float32)
        p = d / f"t{k}.tif"
        with rasterio.open(p, "w", driver="GTiff", width=w, height=h, count=1, dtype="float32", crs="EPSG:27700",
                           transform=from_origin(x0, y1, res, res), nodata=-9999.0, tiled=True, blockxsize=256,
                           blockysize=256, compress="deflate") as ds:
            ds.write(z, 1)
        paths.append(p)
    return d, paths


def _corrupt_blocks(path):
    """Overwrite every compressed block of a tiled GeoTIFF with junk (the header
    stays readable)."""
    import rasterio

    with rasterio.open(path) as ds:
        spans = [(int(ds.get_tag_item(f"BLOCK_OFFSET_{j}_{i}", "TIFF", bidx=1)),
                  int(ds.get_tag_item(f"BLOCK_SIZE_{j}_{i}", "TIFF", bidx=1))) for (i, j), _ in ds.block_windows(1)]
    data = bytearray(path.read_bytes())
    for off, size in spans:
        data[off:off + size] = b"\xff" * size
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("damage", ["corrupt", "deleted"])
def test_an_unreadable_tile_costs_only_its_points(tmp_path, damage):
    """The trip runs across both tiles; the east tile's data cannot be read (corrupt
    blocks, or the file gone after the headers were read). The file still ingests; the
    west part has DSM elevation, the east part falls back, and the tile is named."""
    write_srf(tmp_path / "ev.csv", "EB-9", 1_557_820_800, 1, n=400)
    tdir, (west, east) = _two_tiles(tmp_path)
    whole = process_file(tmp_path / "ev.csv", IngestOptions(dsm=str(tdir)))
    with DsmSampler.open(tdir) as sampler:
        if damage == "corrupt":
            _corrupt_blocks(east)
        else:
            east.unlink()
        out = process_file(tmp_path / "ev.csv", IngestOptions(dsm=str(tdir)), sampler=sampler)
        assert set(sampler.unreadable) == {str(east)}
    assert out.ok, out.error
    (trip,), (ref,) = out.trips, whole.trips
    assert ref.elevation_source == "dsm" and ref.dsm_coverage_pct > 99.0
    assert trip.elevation_source.startswith("dsm+") and 20.0 < trip.dsm_coverage_pct < 90.0
    warnings = trip.quality["elevation"]["elevation_warnings"]
    assert any("t1.tif unreadable" in w for w in warnings)
    assert any("t1.tif unreadable" in r for r in out.repairs)
