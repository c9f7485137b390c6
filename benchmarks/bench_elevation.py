"""Benchmark of the elevation stage: DSM sampling and road-profile smoothing.

    python benchmarks/bench_elevation.py [--quick] [--striped]

Writes a synthetic 1 m DSM in British National Grid (EPSG:27700) to a temporary
directory: 4 tiles of 2000 x 2000 float32, deflate-compressed, internally tiled 256 x 256
like a COG (``--striped``: GDAL's default strips instead). Then measures, on one core:

- ``DsmSampler.sample`` on 1e6 WGS84 fixes along a winding route over the 4 tiles
  (spatially coherent), from a fresh sampler (cold: reads and decompresses the windows)
  and again (warm: windows in the sampler's cache); the pyproj transform alone;
- a 1 Hz-like trip (a fix every 10 m over ~100 km of road on the same DSM): cold cost
  per km of road, which is what a fleet's first pass over a national DSM pays;
- 1e5 random (incoherent) fixes over the 4 tiles, warm;
- ``combine_elevation`` (grid, outlier removal, low-pass, grade bound) on 1e6 samples
  10 m apart.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
import rasterio
from pyproj import Transformer
from rasterio.transform import from_origin

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from cevm.ingest.dsm import DsmSampler
from cevm.ingest.elevation import combine_elevation

X0, Y0, TILE = 430000.0, 290000.0, 2000  # top-left corner of the mosaic [m], tile side [px]


def write_dsm(folder: Path, striped: bool) -> None:
    rng = np.random.default_rng(0)
    opts = {} if striped else {"tiled": True, "blockxsize": 256, "blockysize": 256}
    for j in range(2):
        for i in range(2):
            xs = X0 + i * TILE + np.arange(TILE) + 0.5
            ys = Y0 - j * TILE - np.arange(TILE) - 0.5
            z = 80 + 20 * np.sin(xs / 700.0)[None, :] + 15 * np.cos(ys / 900.0)[:, None]
            z = (z + rng.normal(0, 0.2, z.shape)).astype(np.float32)
            with rasterio.open(
                folder / f"dsm_{j}_{i}.tif", "w", driver="GTiff", width=TILE, height=TILE, count=1,
                dtype="float32", crs="EPSG:27700", transform=from_origin(X0 + i * TILE, Y0 - j * TILE, 1, 1),
                nodata=-9999.0, compress="deflate", **opts,
            ) as ds:
                ds.write(z, 1)


def route(n: int, length_m: float) -> tuple[np.ndarray, np.ndarray]:
    """n points evenly along a winding closed curve inside the mosaic (British National
    Grid), of about ``length_m``; returned as WGS84 lon, lat."""
    t = np.linspace(0, 1, 200_001)
    loops = max(1.0, length_m / 12_000.0)
    x = X0 + 2000 + 1900 * np.sin(2 * np.pi * loops * t) * np.cos(2 * np.pi * 3.1 * t)
    y = Y0 - 2000 + 1900 * np.sin(2 * np.pi * 1.7 * loops * t + 0.3)
    s = np.concatenate(([0.0], np.cumsum(np.hypot(np.diff(x), np.diff(y)))))
    si = np.linspace(0, s[-1], n)
    xi, yi = np.interp(si, s, x), np.interp(si, s, y)
    lon, lat = Transformer.from_crs("EPSG:27700", "EPSG:4326", always_xy=True).transform(xi, yi)
    return np.asarray(lon), np.asarray(lat), s[-1]


def timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return time.perf_counter() - t0, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="1e5 points instead of 1e6")
    ap.add_argument("--striped", action="store_true", help="strip-organised GeoTIFFs instead of 256-px tiles")
    args = ap.parse_args()
    n = 100_000 if args.quick else 1_000_000
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        dt, _ = timed(lambda: write_dsm(folder, args.striped))
        layout = "striped" if args.striped else "tiled 256"
        print(f"DSM: 4 tiles of {TILE}x{TILE} float32 deflate ({layout}), written in {dt:.1f} s")

        lon, lat, length = route(n, 60_000.0)
        tr = Transformer.from_crs("EPSG:4326", "EPSG:27700", always_xy=True)
        dt, _ = timed(lambda: tr.transform(lon, lat))
        print(f"pyproj 4326->27700 alone:        {n / dt / 1e6:6.2f} M points/s")
        with DsmSampler.open(folder) as s:
            dt_cold, z = timed(lambda: s.sample(lon, lat))
            st = s.stats
            print(f"sample, route, cold:             {n / dt_cold / 1e6:6.2f} M points/s "
                  f"({n} points over {length / 1000:.0f} km; {st.windows_read} windows, "
                  f"{st.pixels_read / 1e6:.1f} M px read; {np.isfinite(z).mean():.1%} valid)")
            dt_warm, _ = timed(lambda: s.sample(lon, lat))
            print(f"sample, route, warm:             {n / dt_warm / 1e6:6.2f} M points/s")
            rng = np.random.default_rng(1)
            m = n // 10
            xr = rng.uniform(X0 + 1, X0 + 2 * TILE - 1, m)
            yr = rng.uniform(Y0 - 2 * TILE + 1, Y0 - 1, m)
            lr, br = Transformer.from_crs("EPSG:27700", "EPSG:4326", always_xy=True).transform(xr, yr)
            s.sample(lr, br)  # fill the cache with every window
            dt, _ = timed(lambda: s.sample(lr, br))
            print(f"sample, random points, warm:     {m / dt / 1e6:6.2f} M points/s")

        # A 1 Hz-like trip: a fix every 10 m. Cold cost per km of road.
        km = 100.0
        lon1, lat1, length1 = route(int(km * 100), km * 1000)
        with DsmSampler.open(folder) as s:
            dt, _ = timed(lambda: s.sample(lon1, lat1))
            print(f"sample, fix every 10 m, cold:    {dt / (length1 / 1000) * 1000:6.2f} ms per km "
                  f"({lon1.size / dt / 1e3:.0f} k points/s; {s.stats.windows_read} windows for "
                  f"{length1 / 1000:.0f} km, {dt / s.stats.windows_read * 1000:.2f} ms per window; "
                  f"the route loops over 16 km², fresh road costs more per km)")

        d = np.arange(n) * 10.0
        rng = np.random.default_rng(2)
        raw = 50 + 30 * np.sin(d / 3000) + rng.normal(0, 0.2, n)
        raw[rng.random(n) < 0.02] += 8.0  # objects
        raw[(d % 100_000) < 300] = np.nan  # long gaps
        gps = raw + 40 + rng.normal(0, 3, n)
        dt, res = timed(lambda: combine_elevation(d, raw, gps))
        print(f"combine_elevation (10 m apart):  {n / dt / 1e6:6.2f} M samples/s (source {res.source})")


if __name__ == "__main__":
    main()
