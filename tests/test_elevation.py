"""Tests of cevm.ingest.dsm and cevm.ingest.elevation: DSM sampling on synthetic rasters, and the road profile.

Rasters are written in tmp_path with rasterio. Expected values come from planes
(reproduced exactly by bilinear interpolation), hand computations, a plain-loop reference
bilinear written below, or a single-raster mosaic of the same pixels.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import rasterio
from hypothesis import given, settings
from hypothesis import strategies as st
from pyproj import Transformer
from rasterio.io import MemoryFile
from rasterio.transform import from_origin

from cevm.errors import InputError
from cevm.ingest.dsm import DsmSampler
from cevm.ingest.elevation import (
    ElevationParams,
    bound_grade,
    combine_elevation,
    road_profile_m,
    trip_elevation,
)

# ---------------------------------------------------------------------------- helpers


def write_tif(path, data, x0, y0, dx, dy, crs, nodata=None, **kw):
    """Write a one-band GeoTIFF whose top-left corner is (x0, y0), pixels dx by dy."""
    data = np.asarray(data)
    with rasterio.open(
        path, "w", driver="GTiff", width=data.shape[1], height=data.shape[0], count=1,
        dtype=data.dtype, crs=crs, transform=from_origin(x0, y0, dx, dy), nodata=nodata, **kw,
    ) as ds:
        ds.write(data, 1)
    return path


def plane_grid(x0, y0, dx, dy, w, h, a, b, c):
    """z = a x + b y + c at the pixel centres of a north-up grid."""
    xc = x0 + dx * (np.arange(w) + 0.5)
    yc = y0 - dy * (np.arange(h) + 0.5)
    return a * xc[None, :] + b * yc[:, None] + c


def ref_bilinear(grid, x0, y0, dx, dy, x, y):
    """Plain-loop bilinear between pixel centres of one north-up grid (NaN outside the
    centres' hull or next to NaN), written independently of the code under test."""
    h, w = grid.shape
    out = []
    for xi, yi in zip(x, y, strict=True):
        cf = (xi - x0) / dx - 0.5
        rf = (y0 - yi) / dy - 0.5
        if not (0 <= cf <= w - 1 and 0 <= rf <= h - 1):
            out.append(math.nan)
            continue
        c = min(int(math.floor(cf)), w - 2)
        r = min(int(math.floor(rf)), h - 2)
        fx, fy = cf - c, rf - r
        v = ((1 - fx) * (1 - fy) * grid[r, c] + fx * (1 - fy) * grid[r, c + 1]
             + (1 - fx) * fy * grid[r + 1, c] + fx * fy * grid[r + 1, c + 1])
        out.append(v)
    return np.array(out)


def to_lonlat(crs, x, y):
    return Transformer.from_crs(crs, "EPSG:4326", always_xy=True).transform(x, y)


def from_lonlat(crs, lon, lat):
    return Transformer.from_crs("EPSG:4326", crs, always_xy=True).transform(lon, lat)


BNG = "EPSG:27700"
X0, Y0 = 431000.0, 287000.0  # top-left corner of the test DSMs in British National Grid


# ---------------------------------------------------------------------------- sampling


@pytest.mark.parametrize(
    "crs, x0, y0, dx, dy",
    [(BNG, X0, Y0, 1.0, 1.0), ("EPSG:32630", 600000.0, 5800000.0, 2.0, 3.0),
     ("EPSG:3857", -160000.0, 6900000.0, 1.5, 1.5)],
)
def test_plane_is_reproduced_exactly(tmp_path, crs, x0, y0, dx, dy):
    w, h = 120, 90
    a, b, c = 0.0123, -0.0071, 87.5
    write_tif(tmp_path / "p.tif", plane_grid(x0, y0, dx, dy, w, h, a, b, c), x0, y0, dx, dy, crs)
    rng = np.random.default_rng(1)
    # Anywhere between the outermost pixel centres, including exactly on them.
    x = rng.uniform(x0 + dx / 2, x0 + dx * (w - 0.5), 2000)
    y = rng.uniform(y0 - dy * (h - 0.5), y0 - dy / 2, 2000)
    x[:2], y[:2] = [x0 + dx / 2, x0 + dx * (w - 0.5)], [y0 - dy / 2, y0 - dy * (h - 0.5)]
    with DsmSampler.open(tmp_path / "p.tif") as s:
        np.testing.assert_allclose(s.sample_xy(x, y, crs), a * x + b * y + c, rtol=0, atol=1e-9)
        lon, lat = to_lonlat(crs, x, y)
        xb, yb = from_lonlat(crs, lon, lat)  # where the fixes land in the tile CRS
        inside = (xb >= x0 + dx / 2) & (xb <= x0 + dx * (w - 0.5)) & (yb <= y0 - dy / 2) & (yb >= y0 - dy * (h - 0.5))
        z = s.sample(lon, lat)
        np.testing.assert_allclose(z[inside], a * xb[inside] + b * yb[inside] + c, rtol=0, atol=1e-9)
        assert inside.sum() > 1900


def test_bilinear_hand_computation(tmp_path):
    grid = np.array([[1.0, 2.0, 4.0], [3.0, 5.0, 9.0], [0.0, -2.0, 7.0]])
    write_tif(tmp_path / "g.tif", grid, X0, Y0, 1.0, 1.0, BNG)
    with DsmSampler.open(tmp_path / "g.tif") as s:
        # Centre of pixel (row 0, col 0) is (X0 + 0.5, Y0 - 0.5). A quarter pixel east of
        # it and half a pixel south: 0.75*0.5*1 + 0.25*0.5*2 + 0.75*0.5*3 + 0.25*0.5*5.
        assert s.sample_xy([X0 + 0.75], [Y0 - 1.0], BNG)[0] == pytest.approx(2.375, abs=1e-12)
        # Between the lower-right four centres: fx = 0.5, fy = 0.25:
        # 0.5*0.75*5 + 0.5*0.75*9 + 0.5*0.25*(-2) + 0.5*0.25*7 = 5.875
        assert s.sample_xy([X0 + 2.0], [Y0 - 1.75], BNG)[0] == pytest.approx(5.875, abs=1e-12)
        # On pixel centres: the pixel's value, including the last row and column.
        assert s.sample_xy([X0 + 2.5, X0 + 1.5], [Y0 - 2.5, Y0 - 1.5], BNG).tolist() == [7.0, 5.0]


def test_nodata_and_nan_neighbours_give_nan(tmp_path):
    grid = np.arange(36, dtype=np.float32).reshape(6, 6)
    grid[2, 3] = -9999.0
    grid[4, 1] = np.nan
    write_tif(tmp_path / "n.tif", grid, X0, Y0, 1.0, 1.0, BNG, nodata=-9999.0)
    with DsmSampler.open(tmp_path / "n.tif") as s:
        # Points whose four neighbours include pixel (2, 3): cells between centres rows
        # 1-2 / 2-3 and cols 2-3 / 3-4.
        xs = X0 + np.array([3.0, 4.0, 3.0, 4.0])
        ys = Y0 - np.array([2.0, 2.0, 3.0, 3.0])
        assert np.isnan(s.sample_xy(xs, ys, BNG)).all()
        # Neighbours include the NaN pixel (4, 1).
        assert np.isnan(s.sample_xy([X0 + 1.2], [Y0 - 4.2], BNG)).all()
        # Clear of both: finite and equal to the plain computation (the grid is a plane
        # z = 6 row + col there).
        z = s.sample_xy([X0 + 1.25], [Y0 - 1.75], BNG)[0]
        assert z == pytest.approx(6 * 1.25 + 0.75, abs=1e-6)


def test_outside_and_non_finite_give_nan(tmp_path):
    write_tif(tmp_path / "o.tif", np.ones((10, 10)), X0, Y0, 1.0, 1.0, BNG)
    with DsmSampler.open(tmp_path / "o.tif") as s:
        z = s.sample_xy(
            [X0 - 5, X0 + 15, X0 + 5, X0 + 5, X0 + 0.2, X0 + 5, np.nan, X0 + 5],
            [Y0 - 5, Y0 - 5, Y0 + 1, Y0 - 11, Y0 - 5, Y0 - 9.8, Y0 - 5, Y0 - 5],
            BNG,
        )
        # outside, outside, outside, outside, within half a pixel of the outer edge
        # (no neighbour centre on that side), idem, NaN input, inside.
        assert np.isnan(z[:7]).all() and z[7] == 1.0
        assert np.isnan(s.sample([10.0, np.nan], [45.0, 52.0])).all()  # Italy, NaN fix


def _mosaic_and_tiles(tmp_path, nx, ny, tw, th, rng, subdirs=False):
    """A random DSM written as one raster and as nx * ny tiles of tw x th pixels."""
    big = rng.normal(100, 20, (ny * th, nx * tw))
    write_tif(tmp_path / "mosaic.tif", big, X0, Y0, 1.0, 1.0, BNG)
    tdir = tmp_path / "tiles"
    names = []
    for j in range(ny):
        for i in range(nx):
            d = tdir / f"row{j}" if subdirs else tdir
            d.mkdir(parents=True, exist_ok=True)
            name = d / f"t_{j}_{i}.{'tiff' if (i + j) % 2 else 'tif'}"
            write_tif(name, big[j * th:(j + 1) * th, i * tw:(i + 1) * tw], X0 + i * tw, Y0 - j * th, 1.0, 1.0, BNG)
            names.append(name)
    return big, tdir, names


def _seam_points(nx, ny, tw, th, rng):
    """Points everywhere, plus on and across every seam and on the corners."""
    W, H = nx * tw, ny * th
    x = list(rng.uniform(0.5, W - 0.5, 3000))
    y = list(rng.uniform(0.5, H - 0.5, 3000))
    for i in range(1, nx):  # vertical seams: on the seam, between last/first centres
        for off in (0.0, -0.5, 0.5, -0.25, 0.3, -0.5000001):
            x += [i * tw + off] * 20
            y += list(rng.uniform(0.5, H - 0.5, 20))
    for j in range(1, ny):
        for off in (0.0, -0.5, 0.5, 0.25, -0.3):
            y += [j * th + off] * 20
            x += list(rng.uniform(0.5, W - 0.5, 20))
    for i in range(1, nx):
        for j in range(1, ny):
            for ox, oy in ((0, 0), (0.2, -0.3), (-0.4, 0.1), (0.5, 0.5)):
                x.append(i * tw + ox)
                y.append(j * th + oy)
    # Pixel offsets from the top-left corner -> map coordinates.
    return X0 + np.array(x), Y0 - np.array(y)


def test_four_tiles_of_a_plane_exact_across_seams(tmp_path):
    a, b, c = 0.031, 0.017, -12.0
    tw, th = 40, 30
    for j in range(2):
        for i in range(2):
            xs, ys = X0 + i * tw, Y0 - j * th
            write_tif(tmp_path / f"p{j}{i}.tif", plane_grid(xs, ys, 1.0, 1.0, tw, th, a, b, c), xs, ys, 1.0, 1.0, BNG)
    x, y = _seam_points(2, 2, tw, th, np.random.default_rng(2))
    with DsmSampler.open(tmp_path) as s:
        assert len(s.tiles) == 4
        z = s.sample_xy(x, y, BNG)
    np.testing.assert_allclose(z, a * x + b * y + c, rtol=0, atol=1e-9)


def test_two_tiles_seam_matches_reference(tmp_path):
    rng = np.random.default_rng(3)
    big, tdir, _ = _mosaic_and_tiles(tmp_path, 2, 1, 25, 20, rng)
    x, y = _seam_points(2, 1, 25, 20, rng)
    with DsmSampler.open(tdir) as s:
        z = s.sample_xy(x, y, BNG)
    np.testing.assert_allclose(z, ref_bilinear(big, X0, Y0, 1.0, 1.0, x, y), rtol=0, atol=1e-9)


def test_directory_of_many_tiles_recursive_equals_mosaic(tmp_path):
    """12 tiles in sub-directories (uses the bucket index) give the mosaic's values."""
    rng = np.random.default_rng(4)
    big, tdir, _ = _mosaic_and_tiles(tmp_path, 4, 3, 16, 12, rng, subdirs=True)
    (tdir / "readme.txt").write_text("not a raster")
    x, y = _seam_points(4, 3, 16, 12, rng)
    with DsmSampler.open(tdir) as tiled, DsmSampler.open(tmp_path / "mosaic.tif") as single:
        assert len(tiled.tiles) == 12
        z = tiled.sample_xy(x, y, BNG)
        np.testing.assert_allclose(z, single.sample_xy(x, y, BNG), rtol=0, atol=1e-9)
        lon, lat = to_lonlat(BNG, x, y)
        np.testing.assert_allclose(tiled.sample(lon, lat), single.sample(lon, lat), rtol=0, atol=1e-9)
    np.testing.assert_allclose(z, ref_bilinear(big, X0, Y0, 1.0, 1.0, x, y), rtol=0, atol=1e-9)


def test_vrt_mosaic(tmp_path):
    rng = np.random.default_rng(5)
    tw, th = 20, 15
    big, _, names = _mosaic_and_tiles(tmp_path, 2, 2, tw, th, rng)
    sources = ""
    for k, name in enumerate(names):
        j, i = divmod(k, 2)
        sources += f"""
    <SimpleSource>
      <SourceFilename relativeToVRT="0">{name}</SourceFilename>
      <SourceBand>1</SourceBand>
      <SrcRect xOff="0" yOff="0" xSize="{tw}" ySize="{th}"/>
      <DstRect xOff="{i * tw}" yOff="{j * th}" xSize="{tw}" ySize="{th}"/>
    </SimpleSource>"""
    from rasterio.crs import CRS

    vrt = f"""<VRTDataset rasterXSize="{2 * tw}" rasterYSize="{2 * th}">
  <SRS>{CRS.from_epsg(27700).to_wkt()}</SRS>
  <GeoTransform>{X0}, 1.0, 0.0, {Y0}, 0.0, -1.0</GeoTransform>
  <VRTRasterBand dataType="Float64" band="1">{sources}
  </VRTRasterBand>
</VRTDataset>"""
    (tmp_path / "dsm.vrt").write_text(vrt)
    x, y = _seam_points(2, 2, tw, th, rng)
    with DsmSampler.open(tmp_path / "dsm.vrt") as s:
        assert len(s.tiles) == 1
        z = s.sample_xy(x, y, BNG)
    np.testing.assert_allclose(z, ref_bilinear(big, X0, Y0, 1.0, 1.0, x, y), rtol=0, atol=1e-9)


def test_tiles_in_two_crs(tmp_path):
    """A directory mixing British National Grid and UTM tiles: each point is taken from
    the tile holding it, in that tile's CRS."""
    pb = (0.01, 0.02, 5.0)
    pu = (-0.02, 0.01, 900.0)
    write_tif(tmp_path / "bng.tif", plane_grid(X0, Y0, 1, 1, 50, 50, *pb), X0, Y0, 1, 1, BNG)
    lon_u, lat_u = -3.0, 53.0  # elsewhere, in UTM zone 30
    xu0, yu0 = from_lonlat("EPSG:32630", lon_u, lat_u)
    write_tif(tmp_path / "utm.tif", plane_grid(xu0, yu0, 2, 2, 30, 30, *pu), xu0, yu0, 2, 2, "EPSG:32630")
    xb = np.array([X0 + 10.3, X0 + 40.9])
    yb = np.array([Y0 - 20.1, Y0 - 3.3])
    xu = np.array([xu0 + 11.0, xu0 + 50.2])
    yu = np.array([yu0 - 7.7, yu0 - 33.0])
    lon = np.concatenate((to_lonlat(BNG, xb, yb)[0], to_lonlat("EPSG:32630", xu, yu)[0]))
    lat = np.concatenate((to_lonlat(BNG, xb, yb)[1], to_lonlat("EPSG:32630", xu, yu)[1]))
    with DsmSampler.open(tmp_path) as s:
        z = s.sample(lon, lat)
    xb2, yb2 = from_lonlat(BNG, lon[:2], lat[:2])
    xu2, yu2 = from_lonlat("EPSG:32630", lon[2:], lat[2:])
    expect = np.concatenate((pb[0] * xb2 + pb[1] * yb2 + pb[2], pu[0] * xu2 + pu[1] * yu2 + pu[2]))
    np.testing.assert_allclose(z, expect, rtol=0, atol=1e-9)


def test_sampler_from_headers_read_elsewhere_equals_the_opened_one(tmp_path):
    """A worker's sampler made from the writer's headers (pickled, as they travel to a
    worker) samples exactly as the sampler that read them, and opens no raster until a
    window of it is needed."""
    import pickle

    rng = np.random.default_rng(5)
    big, tdir, _ = _mosaic_and_tiles(tmp_path, 3, 2, 16, 12, rng)
    x, y = _seam_points(3, 2, 16, 12, rng)
    with DsmSampler.open(tdir) as opened:
        headers = pickle.loads(pickle.dumps(opened.headers))
        assert headers == opened.headers and hash(headers) == hash(opened.headers)
        want = opened.sample_xy(x, y, BNG)
    with DsmSampler.from_headers(headers) as made:
        assert made.label == headers.label and made.stats.windows_read == 0
        np.testing.assert_array_equal(made.sample_xy(x, y, BNG), want)
    np.testing.assert_allclose(want, ref_bilinear(big, X0, Y0, 1.0, 1.0, x, y), rtol=0, atol=1e-9)


def test_reads_only_windows_and_caches_them(tmp_path):
    n = 2048
    data = np.arange(n * n, dtype=np.float32).reshape(n, n) % 1000
    write_tif(tmp_path / "big.tif", data, X0, Y0, 1.0, 1.0, BNG, tiled=True, blockxsize=256, blockysize=256,
              compress="deflate")
    # A 300 m drive across two 256-px blocks near the top-left corner.
    t = np.linspace(0, 1, 5000)
    x, y = X0 + 100 + 300 * t, Y0 - 100 - 20 * t
    with DsmSampler.open(tmp_path / "big.tif") as s:  # windows follow the 256-px internal tiles
        z = s.sample_xy(x, y, BNG)
        assert np.isfinite(z).all()
        first = s.stats.windows_read
        assert first == 2  # blocks (0, 0) and (0, 1): each read once
        assert s.stats.pixels_read <= 2 * 257 * 257 < n * n / 30
        s.sample_xy(x, y, BNG)
        assert s.stats.windows_read == first and s.stats.cache_hits >= 2
    np.testing.assert_allclose(z, ref_bilinear(data.astype(float), X0, Y0, 1.0, 1.0, x, y), atol=1e-9)


def test_small_caches_evict_and_stay_correct(tmp_path):
    """With room for one cached window and two open files, a trip over 12 tiles still
    gives the mosaic's values (windows are re-read, files re-opened)."""
    rng = np.random.default_rng(6)
    big, tdir, _ = _mosaic_and_tiles(tmp_path, 4, 3, 16, 12, rng)
    x, y = _seam_points(4, 3, 16, 12, rng)
    with DsmSampler.open(tdir, cache_mb=0.001) as s:
        s.max_open = 2
        z = s.sample_xy(x, y, BNG)
        z2 = s.sample_xy(x, y, BNG)
        assert s.stats.windows_read > 2 * 12 and len(s.windows._open) <= 2
    np.testing.assert_allclose(z, ref_bilinear(big, X0, Y0, 1.0, 1.0, x, y), rtol=0, atol=1e-9)
    np.testing.assert_array_equal(z, z2)


def test_a_lookup_of_more_blocks_than_the_cache_holds_stays_within_it(tmp_path):
    """A long track over a fine DSM touches more blocks than the cache budget: they are
    looked up a budget's worth at a time (the cache never holds more than about its
    budget, instead of every block of the track at once), with the same values."""
    n = 2048
    data = np.arange(n * n, dtype=np.float32).reshape(n, n) % 997
    write_tif(tmp_path / "big.tif", data, X0, Y0, 1.0, 1.0, BNG, tiled=True, blockxsize=256, blockysize=256)
    t = np.linspace(0, 1, 20000)  # a zigzag over all 64 blocks of 256 px
    x, y = X0 + 10 + 2020 * t, Y0 - 10 - 2020 * np.abs(np.sin(25 * t))
    slot = 257 * 257 * 4  # a float32 block with its margin
    with DsmSampler.open(tmp_path / "big.tif", cache_mb=4.5 * slot / 1e6) as s:
        z = s.sample_xy(x, y, BNG)
        assert s.stats.windows_read >= 40
        assert sum(p.data.shape[0] for p in s.windows._pools) <= 5  # slots for 4.5 blocks, never more
    np.testing.assert_allclose(z, ref_bilinear(data.astype(float), X0, Y0, 1.0, 1.0, x, y), rtol=0, atol=1e-9)


def test_scaled_integer_raster(tmp_path):
    """An int16 DSM in centimetres (scale 0.01) with nodata -32768."""
    cm = np.array([[1000, 1010, 1030], [1005, 1011, 1020], [-32768, 1002, 1003]], dtype=np.int16)
    with rasterio.open(tmp_path / "cm.tif", "w", driver="GTiff", width=3, height=3, count=1, dtype="int16",
                       crs=BNG, transform=from_origin(X0, Y0, 1, 1), nodata=-32768) as ds:
        ds.write(cm, 1)
        ds.scales = (0.01,)
    with DsmSampler.open(tmp_path / "cm.tif") as s:
        # Centre of pixel (0, 1): 10.10 m; any point next to the nodata pixel: NaN.
        z = s.sample_xy([X0 + 1.5, X0 + 1.0], [Y0 - 0.5, Y0 - 2.0], BNG)
    assert z[0] == pytest.approx(10.10, abs=1e-9) and np.isnan(z[1])


def test_standstill_repeats_and_shapes(tmp_path):
    write_tif(tmp_path / "p.tif", plane_grid(X0, Y0, 1, 1, 30, 30, 0.1, 0.2, 0), X0, Y0, 1, 1, BNG)
    x = np.repeat(X0 + np.array([3.3, 7.1, 12.8]), [5, 1, 4])
    y = np.repeat(Y0 - np.array([4.4, 9.0, 20.2]), [5, 1, 4])
    with DsmSampler.open(tmp_path / "p.tif") as s:
        z = s.sample_xy(x, y, BNG)
        np.testing.assert_allclose(z, 0.1 * x + 0.2 * y, atol=1e-9)
        assert s.sample_xy(x.reshape(2, 5), y.reshape(2, 5), BNG).shape == (2, 5)
        assert s.sample([], []).shape == (0,)


def test_gdal_names_are_not_checked_on_disk(tmp_path):
    data = plane_grid(X0, Y0, 1, 1, 20, 20, 0.5, 0.25, 3.0)
    with MemoryFile() as mem:
        with mem.open(driver="GTiff", width=20, height=20, count=1, dtype="float64", crs=BNG,
                      transform=from_origin(X0, Y0, 1, 1)) as ds:
            ds.write(data, 1)
        assert mem.name.startswith("/vsimem/")
        with DsmSampler.open(mem.name) as s:
            want = 0.5 * (X0 + 5.5) + 0.25 * (Y0 - 5.5) + 3
            assert s.sample_xy([X0 + 5.5], [Y0 - 5.5], BNG)[0] == pytest.approx(want, abs=1e-9)


def test_bad_dsm_inputs(tmp_path):
    with pytest.raises(InputError, match="not found"):
        DsmSampler.open(tmp_path / "missing.tif")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="no GeoTIFF"):
        DsmSampler.open(tmp_path / "empty")
    (tmp_path / "junk.tif").write_text("hello")
    with pytest.raises(InputError, match=r"junk.tif: cannot open"):
        DsmSampler.open(tmp_path / "junk.tif")
    (tmp_path / "nocrs").mkdir()
    write_tif(tmp_path / "nocrs" / "a.tif", np.ones((4, 4)), 0, 4, 1, 1, None)
    with pytest.raises(InputError, match="no CRS"):
        DsmSampler.open(tmp_path / "nocrs")


# ---------------------------------------------------------------------------- profile


def _ramp_trip(length_m=3000.0, spacing_m=10.0, grade=0.04, z0=50.0):
    d = np.arange(0.0, length_m + spacing_m / 2, spacing_m)
    return d, z0 + grade * d


@pytest.mark.parametrize("spacing_m", [1.0, 4.0, 12.0])
def test_ramp_is_preserved(spacing_m):
    d, z = _ramp_trip(spacing_m=spacing_m)
    np.testing.assert_allclose(road_profile_m(d, z), z, atol=1e-6)


@pytest.mark.parametrize("spacing_m", [1.0, 5.0, 10.0])
def test_roof_spike_is_removed(spacing_m):
    d, ramp = _ramp_trip(spacing_m=spacing_m, grade=0.02)
    z = ramp.copy()
    roof = (d >= 1500) & (d < 1515)  # 10 m high over 15 m of road
    z[roof] += 10.0
    assert roof.sum() >= 1
    out = road_profile_m(d, z)
    assert np.max(np.abs(out - ramp)) < 0.01  # of a 10 m spike


def test_grade_bound_holds_and_does_not_drift():
    d = np.arange(0.0, 2000.0, 2.0)
    z = np.where(d < 1000, 10.0, 40.0)  # a 30 m cliff in the DSM
    out = road_profile_m(d, z)
    assert np.all(np.abs(np.diff(out)) <= 0.15 * np.diff(d) + 1e-9)
    far = np.abs(d - 1000) > 300  # 30 m / 0.15 = 200 m of ramp, centred, plus smoothing
    np.testing.assert_allclose(out[far], z[far], atol=1e-9)


def _bound_reference(h, step, g):
    """O(n^2) Lipschitz envelopes, plainly."""
    n = len(h)
    lower = [min(h[j] + g * step * abs(i - j) for j in range(n)) for i in range(n)]
    upper = [max(h[j] - g * step * abs(i - j) for j in range(n)) for i in range(n)]
    return (np.array(lower) + np.array(upper)) / 2


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-50, 50, allow_nan=False), min_size=1, max_size=40), st.floats(0.5, 10), st.floats(0.01, 0.5))
def test_bound_grade_matches_envelopes(h, step, g):
    h = np.array(h)
    out = bound_grade(h, step, g)
    np.testing.assert_allclose(out, _bound_reference(h, step, g), atol=1e-9)
    assert np.all(np.abs(np.diff(out)) <= g * step + 1e-9)
    if np.all(np.abs(np.diff(h)) <= g * step):
        np.testing.assert_allclose(out, h, atol=1e-9)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.floats(0.05, 0.3))
def test_profile_properties(seed, max_grade):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 400))
    step = rng.exponential(8.0, n - 1) * (rng.random(n - 1) > 0.3)  # standstills
    d = np.concatenate(([0.0], np.cumsum(step)))
    z = 100 + np.cumsum(rng.normal(0, 3, n)) + 15 * (rng.random(n) < 0.05)
    z[rng.random(n) < 0.1] = np.nan
    z[0] = 100.0
    res = combine_elevation(d, z, None, ElevationParams(max_grade=max_grade))
    e = res.elevation_m
    assert np.isfinite(e).all()
    assert np.all(np.abs(np.diff(e)) <= max_grade * np.diff(d) + 1e-9)
    same = np.diff(d) == 0
    assert np.all(np.diff(e)[same] == 0)


def test_standstill_samples_share_elevation():
    d = np.array([0, 10, 20, 20, 20, 20, 30, 40, 40, 50, 60], dtype=float)
    z = np.array([5, 5.2, 5.1, 8, 4, 5.3, 5.5, 5.4, 5.6, 5.8, 6.0])
    out = road_profile_m(d, z)
    assert out[2] == out[3] == out[4] == out[5]
    assert out[7] == out[8]


def test_short_gap_filled_long_gap_left_nan():
    d, z = _ramp_trip(length_m=4000, spacing_m=5.0, grade=0.03)
    raw = z.copy()
    raw[(d > 1000) & (d < 1150)] = np.nan  # 155 m between valid samples: short
    raw[(d > 2500) & (d < 3000)] = np.nan  # 505 m: long
    out = road_profile_m(d, raw)
    short = (d > 1000) & (d < 1150)
    np.testing.assert_allclose(out[short], z[short], atol=1e-6)
    inner_long = (d > 2510) & (d < 2990)
    assert np.isnan(out[inner_long]).all()
    assert np.isfinite(out[~((d > 2500) & (d < 3000))]).all()  # neighbours of the gap too
    np.testing.assert_allclose(out[d < 2400], z[d < 2400], atol=1e-6)


def _hill_in_gap():
    """A 2 % ramp with a 6 m hill between 2000 and 3000 m; the DSM misses 1900-3100 m.
    GPS altitude sees the hill, 47 m higher (geoid vs ellipsoid), noisy."""
    d = np.arange(0.0, 5000.0, 5.0)
    true = 20 + 0.02 * d + 6 * np.sin(np.pi * np.clip((d - 2000) / 1000, 0, 1)) ** 2
    raw = true.copy()
    gap = (d > 1900) & (d < 3100)
    raw[gap] = np.nan
    gps = true + 47 + np.random.default_rng(0).normal(0, 1.0, d.size)
    return d, true, raw, gap, gps


def test_long_gap_falls_back_to_gps_joined_to_dsm():
    # the joining mechanism, with GPS filtered like the DSM (this GPS has white 1 m noise)
    d, true, raw, gap, gps = _hill_in_gap()
    res = combine_elevation(d, raw, gps, ElevationParams(gps_lowpass_sigma_m=15.0, gps_median_window_m=100.0))
    assert res.source == "dsm+gps"
    assert res.dsm_coverage_pct == pytest.approx(100 * (1 - gap.mean()))
    assert res.filled_gps_m == pytest.approx(1200.0) and res.filled_flat_m == 0
    # Follows the hill (within GPS noise after smoothing), joined without a step.
    assert np.max(np.abs(res.elevation_m - true)) < 1.0
    np.testing.assert_allclose(res.elevation_m[~gap][(d[~gap] < 1800) | (d[~gap] > 3200)],
                               true[~gap][(d[~gap] < 1800) | (d[~gap] > 3200)], atol=1e-6)
    assert res.notes


def test_realistic_gps_altitude_noise_adds_little_false_climb():
    # A phone's vertical error: 12 m, correlated over about a minute (600 m at 10 m/s).
    # Climb is what costs energy in a model without braking credit; the GPS default
    # (300 m low-pass) must add far less false climb than the DSM's 15 m filter would.
    rng = np.random.default_rng(3)
    d = np.arange(0.0, 20000.0, 10.0)
    true = 50 + 15 * np.sin(2 * np.pi * d / 6000.0)
    phi = np.exp(-10.0 / 600.0)
    noise = np.zeros(d.size)
    for i in range(1, d.size):  # an AR(1) series, written plainly
        noise[i] = phi * noise[i - 1] + rng.normal(0, 12.0 * np.sqrt(1 - phi**2))
    gps = true + 47 + noise

    def climb(h):
        return float(np.sum(np.maximum(np.diff(h), 0.0)))

    default = combine_elevation(d, None, gps, have_dsm=False).elevation_m
    narrow = combine_elevation(d, None, gps, ElevationParams(gps_lowpass_sigma_m=15.0, gps_median_window_m=100.0),
                               have_dsm=False).elevation_m
    excess_default = climb(default) - climb(true)
    excess_narrow = climb(narrow) - climb(true)
    assert excess_narrow > 2 * excess_default
    assert abs(excess_default) < 0.5 * climb(true)


def test_long_gap_without_gps_is_bridged_straight():
    d, true, raw, gap, _ = _hill_in_gap()
    res = combine_elevation(d, raw, None)
    assert res.source == "dsm+flat" and res.filled_flat_m == pytest.approx(1200.0)
    line = 20 + 0.02 * d  # straight line between the gap's ends: the ramp itself
    np.testing.assert_allclose(res.elevation_m, line, atol=1e-6)


def test_gps_missing_in_one_long_gap():
    d = np.arange(0.0, 8000.0, 5.0)
    true = 10 + 0.01 * d
    raw = true.copy()
    raw[(d > 1000) & (d < 1600)] = np.nan  # 600 m, GPS there
    raw[(d > 5000) & (d < 5900)] = np.nan  # 900 m, no GPS anywhere near
    gps = true - 12.0
    gps[(d > 4000) & (d < 7000)] = np.nan
    res = combine_elevation(d, raw, gps)
    assert res.source == "dsm+gps+flat"
    assert res.filled_gps_m == pytest.approx(600.0) and res.filled_flat_m == pytest.approx(900.0)
    np.testing.assert_allclose(res.elevation_m, true, atol=1e-6)  # both fills follow the ramp here
    assert len(res.notes) == 2


def test_short_gaps_keep_source_dsm_and_are_reported():
    d, z = _ramp_trip(spacing_m=10.0)
    raw = z.copy()
    raw[50:55] = np.nan  # 60 m between valid samples
    res = combine_elevation(d, raw, None)
    assert res.source == "dsm" and res.filled_short_m == pytest.approx(60.0)
    assert res.dsm_coverage_pct == pytest.approx(100 * (1 - 5 / d.size))
    np.testing.assert_allclose(res.elevation_m, z, atol=1e-6)


def test_without_dsm_gps_or_flat():
    d, z = _ramp_trip(spacing_m=10.0, grade=0.05)
    lon = np.full(d.size, -1.5)
    lat = np.full(d.size, 52.5)
    res = trip_elevation(d, lon, lat, z + 3.0, None)
    assert res.source == "gps" and res.dsm_coverage_pct == 0.0
    np.testing.assert_allclose(res.elevation_m, z + 3.0, atol=1e-6)
    flat = trip_elevation(d, lon, lat, None, None)
    assert flat.source == "flat" and np.all(flat.elevation_m == 0.0)
    placeholder = trip_elevation(d, lon, lat, np.zeros(d.size), None)
    assert placeholder.source == "flat" and "constant" in " ".join(placeholder.notes)
    junk = trip_elevation(d, lon, lat, np.where(np.arange(d.size) % 3, 99999.0, 10.0), None)
    assert junk.source == "flat"
    assert flat.quality()["elevation_source"] == "flat"


def test_trip_elevation_with_sampler(tmp_path):
    a, b, c = 0.01, -0.02, 6000.0
    write_tif(tmp_path / "p.tif", plane_grid(X0, Y0, 1, 1, 400, 400, a, b, c), X0, Y0, 1, 1, BNG)
    # A straight drive south-east across the tile and 200 m beyond it.
    x = X0 + 20 + np.arange(0, 500, 2.0)
    y = Y0 - 20 - 0.5 * np.arange(0, 500, 2.0)
    lon, lat = to_lonlat(BNG, x, y)
    xs, ys = from_lonlat(BNG, lon, lat)
    d = np.concatenate(([0.0], np.cumsum(np.hypot(np.diff(xs), np.diff(ys)))))
    with DsmSampler.open(tmp_path / "p.tif") as s:
        res = trip_elevation(d, lon, lat, None, s)
    inside = xs < X0 + 399.5
    assert res.dsm_coverage_pct == pytest.approx(100 * inside.mean())
    assert res.source == "dsm"  # the uncovered end is shorter than 200 m: held level
    assert res.filled_short_m == pytest.approx(d[-1] - d[inside][-1])
    expect = a * xs + b * ys + c
    clear = xs < X0 + 300  # the level hold at the end bends the ramp within ~100 m
    np.testing.assert_allclose(res.elevation_m[clear], expect[clear], atol=1e-6)


def test_params_are_validated():
    with pytest.raises(ValueError, match="max_grade"):
        ElevationParams(max_grade=0.0)
    with pytest.raises(ValueError, match="grid_step_m"):
        ElevationParams(grid_step_m=float("nan"))
    with pytest.raises(ValueError, match="non-decreasing"):
        road_profile_m([0.0, 2.0, 1.0], [1.0, 1.0, 1.0])


def test_degenerate_trips():
    assert road_profile_m([], []).size == 0
    assert road_profile_m([0.0], [7.0]).tolist() == [7.0]
    assert road_profile_m([3.0, 3.0, 3.0], [1.0, 2.0, 6.0]).tolist() == [3.0, 3.0, 3.0]
    assert np.isnan(road_profile_m([0.0, 10.0], [np.nan, np.nan])).all()
    assert combine_elevation([], [], None).elevation_m.size == 0
    still = combine_elevation([5.0, 5.0, 5.0], [np.nan] * 3, [101.0, 103.0, 102.0])
    assert still.source == "gps" and still.elevation_m.tolist() == [102.0] * 3


# ------------------------------------------------------- sampler internals, references


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n_tiles=st.integers(9, 40))
def test_tile_index_finds_the_first_tile_holding_each_point(seed, n_tiles):
    """The bucket index (more than 8 tiles) against a loop over the tiles in order:
    x in [xmin, xmax), y in (ymin, ymax], overlapping tiles of mixed sizes."""
    from cevm.ingest.dsm.headers import TileHeader as _Tile
    from cevm.ingest.dsm.tiles import CrsTileGroup as _CrsGroup

    rng = np.random.default_rng(seed)
    tiles = []
    for k in range(n_tiles):
        w, h = int(rng.integers(1, 40)), int(rng.integers(1, 40))
        x0, y0 = float(rng.integers(0, 100)), float(rng.integers(0, 100))
        tiles.append(_Tile(f"t{k}", BNG, w, h, x0, y0 + h, 1.0, -1.0, None, 1.0, 0.0))
    grp = _CrsGroup(BNG, list(range(n_tiles)), tiles)
    corners = np.array([(t.x0, t.y0) for t in tiles] + [(t.x0 + t.width, t.y0 - t.height) for t in tiles])
    x = np.concatenate((rng.uniform(-10, 150, 500), corners[:, 0], [np.nan, 5.0]))
    y = np.concatenate((rng.uniform(-10, 150, 500), corners[:, 1], [5.0, np.inf]))
    want = []
    for xi, yi in zip(x, y, strict=True):
        hit = -1
        for k, t in enumerate(tiles):
            xmin, xmax = t.x0, t.x0 + t.width
            ymin, ymax = t.y0 - t.height, t.y0
            if xmin <= xi < xmax and ymin < yi <= ymax:
                hit = k
                break
        want.append(hit)
    np.testing.assert_array_equal(grp.locate(x, y), want)


def test_tiles_of_mixed_shapes_and_dtypes_equal_the_mosaic(tmp_path):
    """Tiles of different sizes, float32 and float64 and small blocks (several block
    pools, blocks cut at tile edges) give the bilinear values of the mosaic."""
    rng = np.random.default_rng(11)
    widths, heights = [7, 19, 12, 30], [9, 14, 21]
    big = rng.normal(100, 20, (sum(heights), sum(widths)))
    for j, (r0, h) in enumerate(zip(np.cumsum([0] + heights[:-1]), heights, strict=True)):
        for i, (c0, w) in enumerate(zip(np.cumsum([0] + widths[:-1]), widths, strict=True)):
            part = big[r0:r0 + h, c0:c0 + w]
            if (i + j) % 2:
                part = part.astype(np.float32)
                big[r0:r0 + h, c0:c0 + w] = part  # the values as stored
            write_tif(tmp_path / f"t{j}{i}.tif", part, X0 + c0, Y0 - r0, 1.0, 1.0, BNG)
    x = X0 + rng.uniform(0.5, sum(widths) - 0.5, 4000)
    y = Y0 - rng.uniform(0.5, sum(heights) - 0.5, 4000)
    with DsmSampler.open(tmp_path, block_px=8, cache_mb=0.002) as s:
        z = s.sample_xy(x, y, BNG)
        z2 = s.sample_xy(x[::-1], y[::-1], BNG)  # other order, blocks evicted and re-read
        assert s.stats.windows_read > 12
    want = ref_bilinear(big, X0, Y0, 1.0, 1.0, x, y)
    np.testing.assert_allclose(z, want, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(z2, z[::-1])


@pytest.mark.parametrize("sigma", [3.0, 60.0])
@pytest.mark.parametrize("n", [1, 7, 300, 2000])
def test_lowpass_equals_the_direct_gaussian_filter(sigma, n):
    from scipy import ndimage

    from cevm.ingest.road_filters import gaussian_valid as _gaussian_valid
    from cevm.ingest.road_filters import odd_pad as _odd_pad

    x = np.cumsum(np.random.default_rng(n).normal(0, 1, n))
    r = int(4.0 * sigma + 0.5)
    padded = _odd_pad(x, r)
    want = ndimage.gaussian_filter1d(padded, sigma, mode="nearest", truncate=4.0)[r:-r]
    np.testing.assert_allclose(_gaussian_valid(padded, sigma, r), want, rtol=0, atol=1e-9)


@settings(max_examples=80, deadline=None)
@given(n=st.integers(1, 30), r=st.integers(0, 40), seed=st.integers(0, 2**32 - 1))
def test_odd_pad_is_point_reflection(n, r, seed):
    from cevm.ingest.road_filters import odd_pad as _odd_pad

    x = np.random.default_rng(seed).normal(size=n)
    got = _odd_pad(x, r)
    if r == 0:
        want = x
    elif n == 1:
        want = np.full(2 * r + 1, x[0])
    else:
        want = np.pad(x, r, mode="reflect", reflect_type="odd")
    np.testing.assert_array_equal(got, want)


@settings(max_examples=60, deadline=None)
@given(keys=st.lists(st.integers(0, 2**50), min_size=1, max_size=300), runs=st.integers(1, 5))
def test_unique_inverse_equals_numpy_unique(keys, runs):
    from cevm.ingest.dsm.tiles import _unique_inverse

    k = np.repeat(np.array(keys, dtype=np.int64), runs)  # runs of equal keys, and not
    uniq, inv = _unique_inverse(k)
    want_u, want_inv = np.unique(k, return_inverse=True)
    np.testing.assert_array_equal(uniq, want_u)
    np.testing.assert_array_equal(inv, want_inv)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(3, 6), st.integers(3, 5), st.floats(0.3, 1.0))
def test_regular_tile_grid_locates_as_the_bucket_index(seed, nx, ny, keep):
    """A regular grid of tiles (some missing) finds the same tile as the general bucket
    index for every point: random ones, points exactly on edges and corners, and points
    one ulp either side of them."""
    from cevm.ingest.dsm import TileHeader as _Tile
    from cevm.ingest.dsm import TileIndex

    rng = np.random.default_rng(seed)
    tw, th = 1000.0, 500.0
    cells = [(i, j) for i in range(nx) for j in range(ny)]
    chosen = rng.permutation(len(cells))[: max(9, int(keep * len(cells)))]  # over 8: the indexed case
    tiles = [_Tile(f"t{i}_{j}", BNG, 500, 250, X0 + i * tw, Y0 - j * th, 2.0, -2.0, None, 1.0, 0.0)
             for i, j in (cells[k] for k in sorted(chosen))]
    grp = TileIndex(tiles).groups[0]
    xs = X0 + tw * np.arange(nx + 1)
    ys = Y0 - th * np.arange(ny + 1)
    ex, ey = np.meshgrid(np.concatenate([xs, np.nextafter(xs, -np.inf), np.nextafter(xs, np.inf)]),
                         np.concatenate([ys, np.nextafter(ys, -np.inf), np.nextafter(ys, np.inf)]))
    x = np.concatenate([rng.uniform(X0 - 500, X0 + nx * tw + 500, 2000), ex.ravel(), [np.nan]])
    y = np.concatenate([rng.uniform(Y0 - ny * th - 500, Y0 + 500, 2000), ey.ravel(), [Y0]])
    assert grp._grid is not None  # the fast path is taken
    np.testing.assert_array_equal(grp.locate(x, y), grp._locate_buckets(x, y))
    assert (grp.locate(x, y) >= 0).sum() > 100  # many points do lie in a tile (9+ of 0.5 km2 in < 25 km2)
