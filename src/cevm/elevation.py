"""Road elevation for GPS fixes: DSM lookup and road-profile smoothing.

Two parts:

* :class:`DsmSampler` (I/O edge) looks up a digital surface model (DSM) at WGS84 fixes
  with bilinear interpolation. The DSM is a GeoTIFF, a directory of GeoTIFF tiles, a VRT,
  or any GDAL name rasterio opens (``/vsicurl/...``, ``https://...`` to a COG or VRT).
  Tiles may be in any CRS. Only the windows that hold points are read, each once per
  call, and kept in a small LRU cache across calls.
* :func:`road_profile_m`, :func:`combine_elevation` (pure) turn raw, spiky DSM samples
  (roofs, trees, bridges, vehicles) into a plausible road profile along distance, with a
  fallback to GPS altitude or a flat profile where the DSM has long gaps;
  :func:`trip_elevation` does both for a trip.

All elevations are metres, distances metres, grades dimensionless (rise / run).
"""

from __future__ import annotations

import math
import os
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from functools import lru_cache
from pathlib import Path

import numpy as np
from scipy import ndimage

from cevm.errors import InputError

__all__ = [
    "DsmSampler",
    "ElevationParams",
    "ElevationResult",
    "SamplerStats",
    "bound_grade",
    "combine_elevation",
    "road_profile_m",
    "trip_elevation",
]

WGS84 = "EPSG:4326"


# --------------------------------------------------------------------------------------
# Parameters and results
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ElevationParams:
    """Parameters of the road-profile smoothing and fallbacks.

    Attributes
    ----------
    grid_step_m : float, default 5.0
        Spacing of the uniform distance grid the profile is built on [m]. 5 m is finer
        than any road feature that matters for energy, and coarse enough to keep the
        filters cheap (a 1 Hz trip at 10 m/s gives two grid points per sample).
    max_gap_m : float, default 200.0
        Longest stretch of road [m] without a valid DSM sample that is bridged by linear
        interpolation along distance. Measured between the valid samples on either side
        of a run of invalid ones (or from the trip's end). Longer gaps fall back to GPS
        altitude or to a flat/linear fill. 200 m keeps bridges, tunnels' mouths and
        small DSM holes in the DSM profile, where a straight line is a good road.
    median_window_m : float, default 100.0
        Length [m] of the running median that serves as reference ground to detect
        surface objects. A median ignores an object shorter than about half its window
        whatever its height; 100 m covers roofs, trees, vehicles and bridge decks up to
        about 40 m long as seen by the fixes (a single 1 Hz fix on an object at 20 m/s
        spans 2 x 20 m after resampling), and a median follows ramps exactly.
    spike_threshold_m : float, default 1.0
        Grid cells more than this above or below the running median are surface objects
        (or DSM voids) and are replaced by straight lines between their neighbours. DSM
        noise on tarmac is about 0.1-0.3 m and a median's error on vertical curves of
        roads a few tenths of a metre, while vehicles, hedges, roofs and trees stand
        metres high. Lower objects are left to the low-pass.
    lowpass_sigma_m : float, default 15.0
        Standard deviation [m] of the Gaussian low-pass applied after the median, to
        remove the DSM's roughness (about 0.1-0.3 m on tarmac) and the staircase of the
        median. Linear ramps pass unchanged (ends are padded by odd reflection).
    max_grade : float, default 0.15
        Largest road grade magnitude allowed (0.15 = 15 %), see :func:`bound_grade`.
        Public roads rarely exceed 10-12 % over more than 100 m; 15 % leaves room for
        the steep urban streets that do exist while rejecting DSM cliffs.
    gps_lowpass_sigma_m : float, default 300.0
        Gaussian low-pass [m] for GPS altitude (the fallback where the DSM has nothing).
        A phone's vertical error is 10-30 m and correlated over minutes, so the DSM's
        15 m filter would keep it as false hills: their climbs cost energy the vehicle
        never spent (a model without braking credit counts every one). 300 m keeps the
        hills that matter for energy over a trip and removes most of the noise.
    gps_median_window_m : float, default 500.0
        Running-median window [m] of the GPS-altitude profile, whose spike threshold is
        ``gps_spike_threshold_m``.
    gps_spike_threshold_m : float, default 30.0
        GPS altitudes further than this from their running median are dropped as
        outliers (a lost fix, a multipath jump) before the low-pass.
    gps_min_valid_pct : float, default 50.0
        GPS altitude is used only when at least this share of samples carries a finite
        value inside ``gps_alt_range_m``.
    gps_alt_range_m : tuple[float, float], default (-500.0, 9000.0)
        Plausible GPS altitudes [m]; values outside are treated as missing (loggers write
        0, -1000 or 99999 as "no fix"). A trip whose GPS altitude is constant is rejected
        too (a placeholder, not a measurement).
    """

    grid_step_m: float = 5.0
    max_gap_m: float = 200.0
    median_window_m: float = 100.0
    spike_threshold_m: float = 1.0
    lowpass_sigma_m: float = 15.0
    max_grade: float = 0.15
    gps_lowpass_sigma_m: float = 300.0
    gps_median_window_m: float = 500.0
    gps_spike_threshold_m: float = 30.0
    gps_min_valid_pct: float = 50.0
    gps_alt_range_m: tuple[float, float] = (-500.0, 9000.0)

    def for_gps(self) -> ElevationParams:
        """These parameters with the GPS-altitude smoothing in place of the DSM's."""
        return replace(self, lowpass_sigma_m=self.gps_lowpass_sigma_m, median_window_m=self.gps_median_window_m,
                       spike_threshold_m=self.gps_spike_threshold_m)

    def __post_init__(self) -> None:
        checks = {
            "grid_step_m": self.grid_step_m > 0,
            "max_gap_m": self.max_gap_m >= 0,
            "median_window_m": self.median_window_m >= 0,
            "spike_threshold_m": self.spike_threshold_m >= 0,
            "lowpass_sigma_m": self.lowpass_sigma_m >= 0,
            "max_grade": self.max_grade > 0,
            "gps_min_valid_pct": 0 <= self.gps_min_valid_pct <= 100,
            "gps_lowpass_sigma_m": self.gps_lowpass_sigma_m >= 0,
            "gps_median_window_m": self.gps_median_window_m >= 0,
            "gps_spike_threshold_m": self.gps_spike_threshold_m >= 0,
        }
        for name, ok in checks.items():
            value = getattr(self, name)
            if not ok or (isinstance(value, float) and math.isnan(value)):
                raise ValueError(f"ElevationParams.{name} = {value!r} is out of range")
        lo, hi = self.gps_alt_range_m
        if not lo < hi:
            raise ValueError(f"ElevationParams.gps_alt_range_m = {self.gps_alt_range_m!r}: need low < high")


@dataclass(frozen=True, eq=False)
class ElevationResult:
    """Elevation of a trip's samples and how it was obtained.

    Attributes
    ----------
    elevation_m : ndarray of float64
        Road elevation per sample [m]; finite everywhere. Samples that share a distance
        (standstill) share an elevation.
    source : str
        ``"dsm"`` (DSM everywhere, short gaps interpolated), ``"dsm+gps"`` (long DSM gaps
        filled from GPS altitude offset to join the DSM), ``"dsm+flat"`` (long DSM gaps
        bridged linearly / held level, no usable GPS), ``"dsm+gps+flat"`` (both kinds
        of fill: GPS altitude missing in some long DSM gaps), ``"gps"`` (no DSM value at
        all, smoothed GPS altitude) or ``"flat"`` (nothing usable: 0 m everywhere).
    dsm_coverage_pct : float
        Share of samples with a valid raw DSM value [%] (0 without a DSM).
    filled_short_m : float
        Road length [m] of DSM gaps up to ``max_gap_m`` bridged by interpolation.
    filled_gps_m : float
        Road length [m] filled from GPS altitude.
    filled_flat_m : float
        Road length [m] filled by a straight line between DSM ends or held level.
    notes : tuple of str
        Human-readable remarks (why a fallback was taken, ...).
    """

    elevation_m: np.ndarray
    source: str
    dsm_coverage_pct: float
    filled_short_m: float = 0.0
    filled_gps_m: float = 0.0
    filled_flat_m: float = 0.0
    notes: tuple[str, ...] = ()

    def quality(self) -> dict:
        """JSON-serialisable summary for ``Trip.quality``."""
        return {
            "elevation_source": self.source,
            "dsm_coverage_pct": round(float(self.dsm_coverage_pct), 3),
            "elevation_filled_short_m": round(float(self.filled_short_m), 1),
            "elevation_filled_gps_m": round(float(self.filled_gps_m), 1),
            "elevation_filled_flat_m": round(float(self.filled_flat_m), 1),
            "elevation_notes": list(self.notes),
        }


# --------------------------------------------------------------------------------------
# DSM sampler (I/O edge)
# --------------------------------------------------------------------------------------


@dataclass
class SamplerStats:
    """Counters of a :class:`DsmSampler`, to check and tune its I/O.

    ``windows_read`` and ``pixels_read`` count raster windows read from GDAL (cache
    misses); ``cache_hits`` counts windows served from the sampler's cache;
    ``points`` counts points asked for.
    """

    windows_read: int = 0
    pixels_read: int = 0
    cache_hits: int = 0
    points: int = 0


@dataclass(frozen=True)
class _Tile:
    """Header of one raster: where it is and how pixels map to its CRS.

    x = x0 + a * col, y = y0 + e * row, with (col, row) at a pixel's top-left corner
    (axis-aligned transform; e < 0 for the usual north-up raster).
    """

    name: str
    crs_key: str  # pyproj-usable CRS string ("EPSG:27700" or WKT)
    width: int
    height: int
    x0: float
    y0: float
    a: float
    e: float
    nodata: float | None
    scale: float
    offset: float
    block: int = 0  # side of the file's square internal tiles [px], 0 if not square-tiled

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        xs = (self.x0, self.x0 + self.a * self.width)
        ys = (self.y0, self.y0 + self.e * self.height)
        return min(xs), min(ys), max(xs), max(ys)


@dataclass(frozen=True)
class DsmHeaders:
    """What :meth:`DsmSampler.open` read from a DSM's rasters (their headers) and its
    label: enough to make an equal sampler elsewhere (:meth:`DsmSampler.from_headers`,
    e.g. in a worker process) without reading the headers again. Picklable and
    hashable."""

    tiles: tuple[_Tile, ...]
    label: str


def _is_gdal_name(source: str) -> bool:
    """True for names GDAL resolves itself (URLs, /vsi paths): never checked on disk."""
    return source.startswith("/vsi") or "://" in source


@lru_cache(maxsize=256)
def _crs_key_from_wkt(wkt: str) -> str:
    """A pyproj-usable CRS string: ``EPSG:n`` when the WKT matches an EPSG code (so
    that pyproj picks the EPSG datum transformation, e.g. OSGB36 Helmert), else the WKT."""
    import pyproj

    crs = pyproj.CRS.from_wkt(wkt)
    epsg = crs.to_epsg(min_confidence=90)
    return f"EPSG:{epsg}" if epsg is not None else wkt


@lru_cache(maxsize=64)
def _transformer(src: str, dst: str):
    """Cached ``pyproj.Transformer.from_crs(src, dst, always_xy=True)``."""
    import pyproj

    return pyproj.Transformer.from_crs(src, dst, always_xy=True)


def _read_header(name: str, shown: str) -> _Tile:
    import rasterio
    from rasterio.errors import RasterioError

    try:
        with rasterio.open(name) as ds:
            if ds.count < 1:
                raise InputError(shown, "raster has no band")
            if ds.crs is None:
                raise InputError(shown, "raster has no CRS (georeferencing) to place GPS fixes in")
            t = ds.transform
            if t.b != 0 or t.d != 0:
                raise InputError(shown, "rotated or sheared rasters are not supported")
            if t.a == 0 or t.e == 0:
                raise InputError(shown, "raster has a degenerate geotransform")
            bh, bw = ds.block_shapes[0]
            block = bw if bh == bw and bh < ds.height else 0
            scale = ds.scales[0] if ds.scales and ds.scales[0] is not None else 1.0
            offset = ds.offsets[0] if ds.offsets and ds.offsets[0] is not None else 0.0
            return _Tile(
                name=name,
                crs_key=_crs_key_from_wkt(ds.crs.to_wkt()),
                width=ds.width,
                height=ds.height,
                x0=float(t.c),
                y0=float(t.f),
                a=float(t.a),
                e=float(t.e),
                nodata=None if ds.nodata is None else float(ds.nodata),
                scale=float(scale),
                offset=float(offset),
                block=int(block),
            )
    except RasterioError as exc:
        raise InputError(shown, f"cannot open as a raster: {exc}") from None


def _list_sources(source: str | os.PathLike | Sequence[str | os.PathLike]) -> list[str]:
    """Resolve a DSM argument to raster names GDAL can open (see :meth:`DsmSampler.open`)."""
    if isinstance(source, (list, tuple)):
        names: list[str] = []
        for s in source:
            names.extend(_list_sources(s))
        return names
    text = os.fspath(source)
    if _is_gdal_name(text):
        return [text]
    path = Path(text)
    if path.is_dir():
        names = sorted(
            str(p)
            for p in path.rglob("*")
            if p.is_file() and p.suffix.lower() in (".tif", ".tiff")
        )
        if not names:
            raise InputError(text, "directory holds no GeoTIFF tile (*.tif, *.tiff)")
        return names
    if not path.exists():
        raise InputError(text, "DSM not found (expected a GeoTIFF, a VRT, a directory of tiles or a URL)")
    return [text]


def _unique_inverse(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(keys, return_inverse=True)``, cheap for spatially coherent keys:
    only the keys at the starts of runs of equal keys are sorted."""
    n = keys.size
    starts = np.flatnonzero(keys[1:] != keys[:-1]) + 1
    if starts.size == 0:
        return keys[:1], np.zeros(n, dtype=np.intp)
    starts = np.concatenate(([0], starts))
    if starts.size <= 64:  # a few runs: sorting in Python costs less than np.unique's setup
        run_keys = keys[starts].tolist()
        uniq_list = sorted(set(run_keys))
        index = {k: i for i, k in enumerate(uniq_list)}
        uniq = np.array(uniq_list, dtype=keys.dtype)
        inv = np.array([index[k] for k in run_keys], dtype=np.intp)
    else:
        uniq, inv = np.unique(keys[starts], return_inverse=True)
    return uniq, np.repeat(inv, np.diff(np.append(starts, n)))


class _CrsGroup:
    """Tiles sharing a CRS, with a bucket index to find the tile containing a point."""

    def __init__(self, crs_key: str, tile_ids: list[int], tiles: list[_Tile]):
        self.crs_key = crs_key
        self.tile_ids = np.asarray(tile_ids, dtype=np.int64)
        b = np.array([tiles[i].bounds for i in tile_ids], dtype=np.float64).reshape(-1, 4)
        self.xmin, self.ymin, self.xmax, self.ymax = b.T
        self.bbox = (b[:, 0].min(), b[:, 1].min(), b[:, 2].max(), b[:, 3].max())
        # Bucket grid: cells of the median tile size; each cell lists the tiles
        # overlapping it, in index order (the first tile containing a point wins).
        size = float(np.median(np.maximum(b[:, 2] - b[:, 0], b[:, 3] - b[:, 1])))
        self.cell = size if size > 0 else 1.0
        # As sorted bucket keys with CSR lists of candidates (ascending tile index).
        self._bkeys: np.ndarray | None = None
        if len(tile_ids) > 8:
            keys: list[int] = []
            cands: list[int] = []
            for k in range(len(tile_ids)):
                cx0, cy0 = self._cell(b[k, 0], b[k, 1])
                cx1, cy1 = self._cell(b[k, 2], b[k, 3])
                for cx in range(int(cx0), int(cx1) + 1):
                    for cy in range(int(cy0), int(cy1) + 1):
                        keys.append(int(self._key(cx, cy)))
                        cands.append(k)
            ka, ca = np.array(keys, dtype=np.int64), np.array(cands, dtype=np.int64)
            order = np.lexsort((ca, ka))
            ka, ca = ka[order], ca[order]
            first = np.concatenate(([True], ka[1:] != ka[:-1]))
            self._bkeys = ka[first]
            self._bptr = np.append(np.flatnonzero(first), ka.size).astype(np.int64)
            self._bcand = ca
        self.lonlat_bbox: dict[str, tuple[float, float, float, float] | None] = {}

    def _cell(self, x, y):
        return np.floor((x - self.bbox[0]) / self.cell), np.floor((y - self.bbox[1]) / self.cell)

    @staticmethod
    def _key(cx, cy):
        return (np.asarray(cx, dtype=np.int64) + (1 << 30)) * (1 << 31) + (np.asarray(cy, dtype=np.int64) + (1 << 30))

    def locate(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Index (into the sampler's tiles) of the first tile whose footprint holds each
        point (x in [xmin, xmax), y in (ymin, ymax]), -1 for none."""
        out = np.full(x.shape, -1, dtype=np.int64)
        if x.size == 0:
            return out
        if self._bkeys is None:  # few tiles: test each
            for k in range(self.tile_ids.size):
                m = (out < 0) & (x >= self.xmin[k]) & (x < self.xmax[k]) & (y > self.ymin[k]) & (y <= self.ymax[k])
                out[m] = self.tile_ids[k]
            return out
        cx, cy = self._cell(x, y)
        ok = np.isfinite(cx) & np.isfinite(cy)
        keys = np.where(ok, self._key(np.where(ok, cx, 0), np.where(ok, cy, 0)), -1)
        pos = np.minimum(np.searchsorted(self._bkeys, keys), self._bkeys.size - 1)
        idx = np.flatnonzero(ok & (self._bkeys[pos] == keys))
        if idx.size == 0:
            return out
        b = pos[idx]
        first, count = self._bptr[b], self._bptr[b + 1] - self._bptr[b]
        xs, ys = x[idx], y[idx]
        got = np.full(idx.size, -1, dtype=np.int64)
        for r in range(int(count.max())):  # candidates of a bucket in order: the first hit wins
            live = (got < 0) & (count > r)
            k = self._bcand[np.where(live, first + r, 0)]
            m = live & (xs >= self.xmin[k]) & (xs < self.xmax[k]) & (ys > self.ymin[k]) & (ys <= self.ymax[k])
            got[m] = self.tile_ids[k[m]]
        out[idx] = got
        return out


class _Pool:
    """Cached raster blocks of one shape and dtype: row ``slot`` of ``data`` holds one
    block, C order, ``shape[1]`` pixels per row (blocks at a tile's right or bottom edge
    fill only the top-left part of their slot). Room for ``max_slots`` blocks (the
    cache budget's worth) is allocated at once, uninitialised: the operating system
    commits pages only as blocks are written, and no block is ever copied to grow the
    pool (it grows by doubling only when one lookup needs more blocks than the budget).
    Freed slots are reused."""

    def __init__(self, shape: tuple[int, int], dtype: np.dtype, max_slots: int):
        self.shape = shape
        self.size = shape[0] * shape[1]
        self.data = np.empty((0, self.size), dtype=dtype)
        self.free: list[int] = []
        self.used = 0
        self.max_slots = max(1, max_slots)

    def put(self, arr: np.ndarray) -> int:
        """Store a block (at most ``shape``) in a free slot; return the slot."""
        if self.free:
            slot = self.free.pop()
        else:
            if self.used == self.data.shape[0]:
                cap = self.max_slots if self.used < self.max_slots else 2 * self.used
                grown = np.empty((cap, self.size), dtype=self.data.dtype)
                grown[: self.used] = self.data[: self.used]
                self.data = grown
            slot = self.used
            self.used += 1
        h, w = arr.shape
        self.data[slot].reshape(self.shape)[:h, :w] = arr
        return slot


class DsmSampler:
    """Bilinear lookup of a DSM (one raster, a VRT, or many tiles in any CRSs).

    Open with :meth:`open`; use as a context manager (or call :meth:`close`). Not
    thread-safe: use one sampler per thread.

    How a lookup works: fixes are transformed with pyproj into each tile CRS (one
    cached transformer per CRS); a tile index (bounds from the headers, read once when
    the sampler opens) finds the tile holding each point; points are grouped by square blocks of their tile
    (``block_px``), and each block is read once (with a one-pixel margin for the
    bilinear neighbours) and interpolated with numpy. Blocks stay in an LRU cache of
    ``cache_mb`` megabytes across calls (the blocks of one call stay until it is done),
    so nothing bigger than a block is ever read for a point and a national mosaic is
    never loaded. Cached blocks of one shape share one array, so a call gathers its
    pixels with one fancy index whatever the number of blocks (Python loops run over
    the distinct blocks of a call, one cache lookup each, never over points).

    Bilinear interpolation is between pixel centres. If any of the four neighbours is
    nodata or NaN, the point is NaN. Points within half a pixel of a tile's edge take
    their missing neighbours from the adjacent tile of the same CRS (the pixel whose
    area holds the neighbour's centre), so seams of a tiled grid interpolate exactly as
    the mosaic would; with no adjacent tile, or beyond every tile, the point is NaN.
    Where tiles overlap, the first in sorted path order wins.
    """

    def __init__(self, tiles: Sequence[_Tile], *, block_px: int | None = None, cache_mb: float = 256.0, max_open: int = 32, label: str = "DSM"):
        if block_px is not None and not 2 <= block_px < (1 << 20):
            raise ValueError("block_px must be in [2, 2**20)")
        self.tiles: list[_Tile] = list(tiles)
        self.label = label
        self.cache_bytes = int(cache_mb * 1e6)
        self.max_open = int(max_open)
        self.stats = SamplerStats()
        # Block cache: key (tile << 42 | brow << 21 | bcol) -> (pool, slot, nbytes), LRU
        # order. A block lives in a slot of a pool: one 2-D array per (slot height,
        # width, dtype), one row per slot, so that a lookup gathers from every cached
        # block with one fancy index.
        self._blocks: OrderedDict[int, tuple[int, int, int]] = OrderedDict()
        self._cached_bytes = 0
        self._pools: list[_Pool] = []
        self._pool_index: dict[tuple[int, int, str], int] = {}
        self._open: OrderedDict[int, object] = OrderedDict()
        by_crs: dict[str, list[int]] = {}
        for i, t in enumerate(self.tiles):
            by_crs.setdefault(t.crs_key, []).append(i)
        self._groups = [_CrsGroup(k, ids, self.tiles) for k, ids in by_crs.items()]
        self._group_of_tile = np.empty(len(self.tiles), dtype=np.int64)
        for gi, grp in enumerate(self._groups):
            self._group_of_tile[grp.tile_ids] = gi
        # Per-tile arrays for vectorised pixel arithmetic.
        f = lambda attr: np.array([getattr(t, attr) for t in self.tiles], dtype=np.float64)  # noqa: E731
        self._x0, self._y0, self._a, self._e = f("x0"), f("y0"), f("a"), f("e")
        self._w = np.array([t.width for t in self.tiles], dtype=np.int64)
        self._h = np.array([t.height for t in self.tiles], dtype=np.int64)
        self._blk = np.array([block_px or (t.block if 128 <= t.block <= 1024 else 512) for t in self.tiles], dtype=np.int64)

    # ---- construction ----------------------------------------------------------------

    @classmethod
    def open(cls, source: str | os.PathLike | Sequence[str | os.PathLike], *, block_px: int | None = None, cache_mb: float = 256.0) -> DsmSampler:
        """Open a DSM.

        Parameters
        ----------
        source : path, URL or sequence of them
            A GeoTIFF, a VRT, a directory searched recursively for ``*.tif`` /
            ``*.tiff`` tiles, or a GDAL name that rasterio opens without it being a
            local file: ``/vsicurl/https://...``, ``https://...`` (a COG or a VRT),
            ``/vsizip/...``. Such names are not checked on disk.
        block_px : int or None, default None
            Side of the square windows read from a raster [px]. None: the raster's own
            square internal tile size if it has one between 128 and 1024 px (a COG's
            256 or 512: a window then decompresses one internal tile, plus the one-pixel
            margin from the neighbours, which GDAL's block cache keeps), else 512.
        cache_mb : float, default 256
            Budget of the block cache [MB]: about 240 float32 (120 float64) windows
            of 513 x 513 px, i.e. 60 km² of a 1 m DSM, or 200+ km of road.

        Raises
        ------
        InputError
            Missing path, empty directory, unreadable raster, raster without CRS.
        """
        names = _list_sources(source)
        shown = os.fspath(source) if not isinstance(source, (list, tuple)) else None
        tiles = [_read_header(n, n) for n in names]
        return cls(tiles, block_px=block_px, cache_mb=cache_mb, label=shown or f"{len(names)} rasters")

    @property
    def headers(self) -> DsmHeaders:
        """The rasters' headers (see :class:`DsmHeaders`)."""
        return DsmHeaders(tuple(self.tiles), self.label)

    @classmethod
    def from_headers(cls, headers: DsmHeaders, *, block_px: int | None = None, cache_mb: float = 256.0) -> DsmSampler:
        """A sampler from headers read elsewhere (:attr:`headers`); rasters are opened
        when first read, so a raster that vanished since is an error then."""
        return cls(headers.tiles, block_px=block_px, cache_mb=cache_mb, label=headers.label)

    def close(self) -> None:
        """Close open datasets and drop the block cache."""
        for ds in self._open.values():
            ds.close()
        self._open.clear()
        self._blocks.clear()
        self._cached_bytes = 0
        self._pools.clear()
        self._pool_index.clear()

    def __enter__(self) -> DsmSampler:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        crss = ", ".join(g.crs_key[:40] for g in self._groups)
        return f"DsmSampler({self.label!r}, {len(self.tiles)} tiles, CRS {crss})"

    # ---- raster access -----------------------------------------------------------------

    def _dataset(self, tile: int):
        ds = self._open.get(tile)
        if ds is not None:
            self._open.move_to_end(tile)
            return ds
        import rasterio
        from rasterio.errors import RasterioError

        try:
            ds = rasterio.open(self.tiles[tile].name)
        except RasterioError as exc:
            raise InputError(self.tiles[tile].name, f"cannot open as a raster: {exc}") from None
        self._open[tile] = ds
        while len(self._open) > self.max_open:
            _, old = self._open.popitem(last=False)
            old.close()
        return ds

    def _read_block(self, tile: int, brow: int, bcol: int) -> np.ndarray:
        """Pixels of block (brow, bcol) of a tile plus a one-pixel margin right and
        below, as float (float32 for float32 rasters) with NaN for nodata."""
        from rasterio.errors import RasterioError
        from rasterio.windows import Window

        t = self.tiles[tile]
        b = int(self._blk[tile])
        r0, c0 = brow * b, bcol * b
        h, w = min(b + 1, t.height - r0), min(b + 1, t.width - c0)
        try:
            raw = self._dataset(tile).read(1, window=Window(c0, r0, w, h))
        except RasterioError as exc:
            raise InputError(t.name, f"cannot read window {w}x{h} at col {c0}, row {r0}: {exc}") from None
        plain = t.scale == 1.0 and t.offset == 0.0
        # float32 rasters stay float32 in the cache (half the memory; exact in float64
        # arithmetic later); anything else becomes float64.
        arr = raw.astype(np.float32 if plain and raw.dtype == np.float32 else np.float64)
        if t.nodata is not None and not math.isnan(t.nodata):
            arr[_nodata_mask(raw, t.nodata)] = np.nan
        if not plain:
            arr = arr * t.scale + t.offset
        self.stats.windows_read += 1
        self.stats.pixels_read += arr.size
        return arr

    def _block_slot(self, key: int) -> tuple[int, int]:
        """(pool, slot) of the cached block ``key`` (tile << 42 | brow << 21 | bcol),
        read on a miss. The cache is trimmed to its budget by :meth:`_trim`, after each
        lookup, so the blocks of one lookup stay while it gathers."""
        hit = self._blocks.get(key)
        if hit is not None:
            self._blocks.move_to_end(key)
            self.stats.cache_hits += 1
            return hit[0], hit[1]
        tile, brow, bcol = key >> 42, (key >> 21) & ((1 << 21) - 1), key & ((1 << 21) - 1)
        arr = self._read_block(tile, brow, bcol)
        t, b = self.tiles[tile], int(self._blk[tile])
        shape = (min(b + 1, t.height), min(b + 1, t.width))  # every block of the tile fits
        pk = (shape[0], shape[1], arr.dtype.str)
        pi = self._pool_index.get(pk)
        if pi is None:
            pi = self._pool_index[pk] = len(self._pools)
            slot_bytes = shape[0] * shape[1] * arr.dtype.itemsize
            self._pools.append(_Pool(shape, arr.dtype, self.cache_bytes // slot_bytes + 1))
        slot = self._pools[pi].put(arr)
        self._blocks[key] = (pi, slot, arr.nbytes)
        self._cached_bytes += arr.nbytes
        return pi, slot

    def _trim(self) -> None:
        """Evict least recently used blocks beyond the cache budget (keeping one)."""
        while self._cached_bytes > self.cache_bytes and len(self._blocks) > 1:
            _, (pi, slot, nbytes) = self._blocks.popitem(last=False)
            self._pools[pi].free.append(slot)
            self._cached_bytes -= nbytes

    def _gather(self, tile: np.ndarray, row: np.ndarray, col: np.ndarray, quad: bool) -> np.ndarray:
        """Pixel values at (tile, row, col); with ``quad`` also the right, lower and
        lower-right neighbours (requires row <= height-2, col <= width-2). Returns shape
        (n,) or (4, n): [z(r,c), z(r,c+1), z(r+1,c), z(r+1,c+1)]."""
        n = tile.size
        out = np.empty((4, n) if quad else (n,), dtype=np.float64)
        if n == 0:
            return out
        blk = self._blk[tile]
        brow, bcol = row // blk, col // blk
        uniq, inv = _unique_inverse((tile << 42) | (brow << 21) | bcol)
        pool_of = np.empty(uniq.size, dtype=np.int64)
        slot_of = np.empty(uniq.size, dtype=np.int64)
        try:
            for i, key in enumerate(uniq.tolist()):
                pool_of[i], slot_of[i] = self._block_slot(key)
        finally:
            self._trim()
        pools = [int(pool_of[0])] if (pool_of == pool_of[0]).all() else np.unique(pool_of).tolist()
        for pi in pools:
            pool = self._pools[pi]
            stride = pool.shape[1]
            sel = slice(None) if len(pools) == 1 else np.flatnonzero(pool_of[inv] == pi)
            ii = inv[sel]
            flat = slot_of[ii] * pool.size + (row[sel] - brow[sel] * blk[sel]) * stride + (col[sel] - bcol[sel] * blk[sel])
            data = pool.data.reshape(-1)
            if quad:
                out[0, sel] = data[flat]
                out[1, sel] = data[flat + 1]
                out[2, sel] = data[flat + stride]
                out[3, sel] = data[flat + stride + 1]
            else:
                out[sel] = data[flat]
        return out

    # ---- lookup --------------------------------------------------------------------------

    def sample(self, lon_deg, lat_deg) -> np.ndarray:
        """DSM elevation [m] at WGS84 longitudes and latitudes [deg] (same shape),
        bilinear between pixel centres, NaN where invalid (nodata neighbour, outside
        every tile, non-finite input)."""
        return self.sample_xy(lon_deg, lat_deg, WGS84)

    def sample_xy(self, x, y, crs: str = WGS84) -> np.ndarray:
        """DSM elevation [m] at coordinates ``x``, ``y`` in ``crs`` (any pyproj CRS
        string; x is easting or longitude). See :meth:`sample`."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        if x.shape != y.shape:
            raise ValueError(f"x and y differ in shape: {x.shape} vs {y.shape}")
        shape = x.shape
        x, y = x.ravel(), y.ravel()
        self.stats.points += x.size
        # Standstill fixes repeat: sample each run of equal consecutive points once.
        if x.size > 1:
            change = np.flatnonzero((x[1:] != x[:-1]) | (y[1:] != y[:-1])) + 1
            if change.size < 0.9 * (x.size - 1):
                starts = np.concatenate(([0], change))
                vals = self._sample_unique(x[starts], y[starts], crs)
                return np.repeat(vals, np.diff(np.append(starts, x.size))).reshape(shape)
        return self._sample_unique(x, y, crs).reshape(shape)

    def _sample_unique(self, x: np.ndarray, y: np.ndarray, crs: str) -> np.ndarray:
        out = np.full(x.size, np.nan)
        if x.size == 0 or not self.tiles:
            return out
        finite = np.isfinite(x) & np.isfinite(y)
        all_live = bool(finite.all())
        if len(self._groups) == 1 and all_live:
            # Common case, no index arrays: one CRS, every fix finite.
            grp = self._groups[0]
            px, py = self._to_crs(x, y, crs, grp.crs_key)
            t = grp.locate(px, py)
            pts = None
            if not (t >= 0).all():
                pts = np.flatnonzero(t >= 0)
                t, px, py = t[pts], px[pts], py[pts]
        else:
            live = np.flatnonzero(finite)
            tile = np.full(x.size, -1, dtype=np.int64)
            tx = np.full(x.size, np.nan)
            ty = np.full(x.size, np.nan)
            for grp in self._groups:
                todo = live[tile[live] < 0]
                if todo.size == 0:
                    break
                if len(self._groups) > 1:
                    todo = todo[self._in_group_bbox(grp, x[todo], y[todo], crs)]
                gx, gy = self._to_crs(x[todo], y[todo], crs, grp.crs_key)
                found = grp.locate(gx, gy)
                hit = found >= 0
                sel = todo[hit]
                tile[sel], tx[sel], ty[sel] = found[hit], gx[hit], gy[hit]
            pts = np.flatnonzero(tile >= 0)
            t, px, py = tile[pts], tx[pts], ty[pts]
        if t.size == 0:
            return out
        w, h = self._w[t], self._h[t]
        # Continuous pixel coordinates with pixel centres at integers.
        colf = (px - self._x0[t]) / self._a[t] - 0.5
        rowf = (py - self._y0[t]) / self._e[t] - 0.5
        c0 = np.floor(colf).astype(np.int64)
        r0 = np.floor(rowf).astype(np.int64)
        # Exactly on the last centre row/column: use the cell before it (weight 1).
        c0 -= (colf == w - 1) & (c0 > 0)
        r0 -= (rowf == h - 1) & (r0 > 0)
        inner = (c0 >= 0) & (c0 <= w - 2) & (r0 >= 0) & (r0 <= h - 2)
        res = np.empty(t.size)
        if inner.all():
            z = self._gather(t, r0, c0, quad=True)
            res[:] = _bilinear(z, colf - c0, rowf - r0)
        else:
            ii = np.flatnonzero(inner)
            z = self._gather(t[ii], r0[ii], c0[ii], quad=True)
            res[ii] = _bilinear(z, colf[ii] - c0[ii], rowf[ii] - r0[ii])
            ee = np.flatnonzero(~inner)
            res[ee] = self._sample_edge(t[ee], colf[ee], rowf[ee])
        if pts is None:
            return res
        out[pts] = res
        return out

    @staticmethod
    def _to_crs(x: np.ndarray, y: np.ndarray, src: str, dst: str) -> tuple[np.ndarray, np.ndarray]:
        if src == dst:
            return x, y
        gx, gy = _transformer(src, dst).transform(x, y)
        return np.asarray(gx, dtype=np.float64), np.asarray(gy, dtype=np.float64)

    def _sample_edge(self, t, colf, rowf) -> np.ndarray:
        """Bilinear for points within half a pixel of their tile's edge: each of the four
        neighbour pixel centres (on the point's tile grid) is looked up in whatever tile
        of the same CRS holds it."""
        c0 = np.floor(colf)
        r0 = np.floor(rowf)
        m = t.size
        # the four neighbours (0, 0), (0, 1), (1, 0), (1, 1) of every point, one batch
        dr = np.repeat(np.array([0, 0, 1, 1]), m)
        dc = np.repeat(np.array([0, 1, 0, 1]), m)
        tt = np.tile(t, 4)
        cx = self._x0[tt] + self._a[tt] * (np.tile(c0, 4) + dc + 0.5)
        cy = self._y0[tt] + self._e[tt] * (np.tile(r0, 4) + dr + 0.5)
        z = np.full(4 * m, np.nan)
        grp = self._group_of_tile[tt]
        for gi in np.unique(grp).tolist():
            sel = np.flatnonzero(grp == gi)
            nt = self._groups[gi].locate(cx[sel], cy[sel])
            ok = nt >= 0
            sel, nt = sel[ok], nt[ok]
            col = np.floor((cx[sel] - self._x0[nt]) / self._a[nt]).astype(np.int64)
            row = np.floor((cy[sel] - self._y0[nt]) / self._e[nt]).astype(np.int64)
            col = np.clip(col, 0, self._w[nt] - 1)
            row = np.clip(row, 0, self._h[nt] - 1)
            z[sel] = self._gather(nt, row, col, quad=False)
        return _bilinear(z.reshape(4, m), colf - c0, rowf - r0)

    def _in_group_bbox(self, grp: _CrsGroup, x: np.ndarray, y: np.ndarray, crs: str) -> np.ndarray:
        """Cheap pre-filter: points inside the group's bounding box seen in ``crs``
        (with a 1 % margin). Everything passes if the box cannot be computed."""
        if crs not in grp.lonlat_bbox:
            try:
                tr = _transformer(grp.crs_key, crs)
                xmin, ymin, xmax, ymax = tr.transform_bounds(*grp.bbox, densify_pts=21)
                mx, my = 0.01 * (xmax - xmin), 0.01 * (ymax - ymin)
                box = (xmin - mx, ymin - my, xmax + mx, ymax + my)
                grp.lonlat_bbox[crs] = box if all(map(math.isfinite, box)) and xmin <= xmax else None
            except Exception:  # noqa: BLE001 - a pre-filter only
                grp.lonlat_bbox[crs] = None
        box = grp.lonlat_bbox[crs]
        if box is None:
            return np.ones(x.size, dtype=bool)
        return (x >= box[0]) & (x <= box[2]) & (y >= box[1]) & (y <= box[3])


def _nodata_mask(raw: np.ndarray, nodata: float) -> np.ndarray:
    """Pixels equal to ``nodata`` compared in the raster's own dtype (as GDAL does)."""
    if np.issubdtype(raw.dtype, np.floating):
        return raw == raw.dtype.type(nodata)
    info = np.iinfo(raw.dtype)
    if nodata != math.floor(nodata) or not info.min <= nodata <= info.max:
        return np.zeros(raw.shape, dtype=bool)
    return raw == int(nodata)


def _bilinear(z: np.ndarray, fx: np.ndarray, fy: np.ndarray) -> np.ndarray:
    """Bilinear interpolation of z = [z00, z01, z10, z11] (row, col offsets) at
    fractional offsets fx (along columns) and fy (along rows) in [0, 1]. Any NaN
    neighbour gives NaN, whatever its weight."""
    top = z[0] + fx * (z[1] - z[0])
    bottom = z[2] + fx * (z[3] - z[2])
    return top + fy * (bottom - top)


# --------------------------------------------------------------------------------------
# Road profile (pure)
# --------------------------------------------------------------------------------------


def _grid(d0: float, d1: float, step: float) -> np.ndarray:
    """Uniform grid from d0 to d1 inclusive with spacing <= step."""
    if not d1 > d0:
        return np.array([d0], dtype=np.float64)
    n = int(math.ceil((d1 - d0) / step - 1e-9)) + 1
    return np.linspace(d0, d1, max(n, 2))


def _check_distance(distance_m: np.ndarray) -> None:
    if not np.all(np.isfinite(distance_m)):
        raise ValueError("distance_m must be finite")
    if distance_m.size > 1 and np.any(np.diff(distance_m) < 0):
        raise ValueError("distance_m must be non-decreasing")


@dataclass(frozen=True)
class _Gaps:
    """Runs of invalid samples, classified by the road length they span: from the last
    valid sample before to the first valid one after (or the trip's end)."""

    short_m: float  # total span of the runs bridged by interpolation [m]
    long: list[tuple[float, float, str]] = field(default_factory=list)  # (a, b, "lead"|"inner"|"trail")


def _find_gaps(d: np.ndarray, valid: np.ndarray, max_gap_m: float) -> _Gaps:
    """Classify runs of invalid samples by the road length they span."""
    n = d.size
    vi = np.flatnonzero(valid)
    if vi.size == 0:
        return _Gaps(0.0, [(float(d[0]), float(d[-1]), "all")] if n else [])
    spans: list[tuple[float, float, str]] = []
    if vi[0] > 0:
        spans.append((float(d[0]), float(d[vi[0]]), "lead"))
    inner = np.flatnonzero(np.diff(vi) > 1)
    spans.extend(zip(d[vi[inner]].tolist(), d[vi[inner + 1]].tolist(), ["inner"] * inner.size))
    if vi[-1] < n - 1:
        spans.append((float(d[vi[-1]]), float(d[-1]), "trail"))
    short = sum(b - a for a, b, _ in spans if b - a <= max_gap_m)
    return _Gaps(float(short), [s for s in spans if s[1] - s[0] > max_gap_m])


def _resample(d: np.ndarray, z: np.ndarray, valid: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """Valid samples onto the grid: samples are averaged per grid cell (standstill
    repeats and dense logging), then cells are joined by linear interpolation along
    distance; held level beyond the first/last valid sample."""
    dv, zv = d[valid], z[valid]
    if grid.size == 1:
        return np.array([zv.mean()])
    step = grid[1] - grid[0]
    cell = np.rint((dv - grid[0]) / step).astype(np.int64)
    before, after = cell < 0, cell >= grid.size  # samples beyond a partial grid: anchors only
    if before.any() or after.any():
        keep = ~(before | after)
        d_lo, z_lo, d_hi, z_hi = dv[before], zv[before], dv[after], zv[after]
        dv, zv, cell = dv[keep], zv[keep], cell[keep]
    else:
        d_lo = z_lo = d_hi = z_hi = dv[:0]
    cnt = np.bincount(cell, minlength=grid.size)
    has = cnt > 0
    zc = np.bincount(cell, weights=zv, minlength=grid.size)[has] / cnt[has]
    dc = np.bincount(cell, weights=dv, minlength=grid.size)[has] / cnt[has]
    if d_lo.size or d_hi.size:
        dc = np.concatenate((d_lo, dc, d_hi))
        zc = np.concatenate((z_lo, zc, z_hi))
    out = np.interp(grid, dc, zc)
    if dc.size > 1:
        # A cell mean sits up to half a step inside its cell: continue the line of the
        # first (last) two cells over that half step, not level (keeps ramps exact).
        for k, (i, j) in ((0, (0, 1)), (-1, (-2, -1))):
            if 0 < abs(grid[k] - dc[k]) <= 0.5 * step * (1 + 1e-9) and dc[j] > dc[i]:
                out[k] = zc[i] + (grid[k] - dc[i]) * (zc[j] - zc[i]) / (dc[j] - dc[i])
    return out


def _odd_pad(x: np.ndarray, r: int) -> np.ndarray:
    """Pad by point reflection about each end value (x[0] - (x[k] - x[0])), which
    continues a straight line: symmetric filters then keep ramps up to the ends."""
    if r <= 0:
        return x
    if x.size == 1:
        return np.full(2 * r + 1, x[0])
    if r >= x.size:  # reflected more than once
        return np.pad(x, r, mode="reflect", reflect_type="odd")
    out = np.empty(x.size + 2 * r)
    out[r : r + x.size] = x
    out[:r] = 2 * x[0] - x[r:0:-1]  # as np.pad(x, r, mode="reflect", reflect_type="odd")
    out[r + x.size :] = 2 * x[-1] - x[-2 : -r - 2 : -1]
    return out


def _smooth(h: np.ndarray, step: float, params: ElevationParams) -> np.ndarray:
    """Robust smoothing of a gap-free uniform profile with spacing ``step`` [m].

    A running median of ``median_window_m`` is the reference ground; cells further than
    ``spike_threshold_m`` from it are surface objects: they are dropped and bridged by
    straight lines between the remaining cells (a Hampel filter). Then a Gaussian
    low-pass of ``lowpass_sigma_m``. Ends are padded by odd reflection, so a straight
    ramp comes out unchanged, ends included. (Taking the median itself as the profile
    would shift a ramp near an object by half the object's length times the grade.)
    """
    k = 2 * int(params.median_window_m / (2 * step)) + 1
    if k > 1 and h.size > 2:
        r = k // 2
        ground = ndimage.median_filter(_odd_pad(h, r), size=k, mode="nearest")[r:-r]
        spike = np.abs(h - ground) > params.spike_threshold_m
        if spike.all():
            h = ground
        elif spike.any():
            idx = np.arange(h.size, dtype=np.float64)
            h = h.copy()
            h[spike] = np.interp(idx[spike], idx[~spike], h[~spike])
    sigma = params.lowpass_sigma_m / step
    if sigma > 0 and h.size > 1:
        r = int(4.0 * sigma + 0.5)
        h = _gaussian_valid(_odd_pad(h, r), sigma, r)
    return h


#: Kernels longer than this [taps] are applied by FFT (same result within rounding).
_FFT_MIN_TAPS = 96


def _gaussian_valid(x: np.ndarray, sigma: float, r: int) -> np.ndarray:
    """Gaussian low-pass (standard deviation ``sigma`` cells, radius ``r`` cells) of
    ``x`` at the cells ``r .. len(x) - r - 1``, whose windows lie inside ``x``: what
    ``ndimage.gaussian_filter1d(x, sigma, truncate=4.0)[r:-r]`` gives for
    ``r = int(4 * sigma + 0.5)``, whatever its boundary mode. Long kernels (the GPS
    profile's, 481 taps) go through an FFT, O(n log n) instead of O(n r); the result
    differs only by floating-point rounding (about 1e-12 m)."""
    if 2 * r + 1 < _FFT_MIN_TAPS:
        return ndimage.gaussian_filter1d(x, sigma, mode="nearest", truncate=4.0)[r:-r]
    k = np.exp(-0.5 / (sigma * sigma) * np.arange(-r, r + 1, dtype=np.float64) ** 2)
    k /= k.sum()
    nfft = _fft_size(x.size + k.size - 1)
    y = np.fft.irfft(np.fft.rfft(x, nfft) * np.fft.rfft(k, nfft), nfft)
    return y[2 * r : x.size]


@lru_cache(maxsize=1)
def _smooth_sizes() -> np.ndarray:
    """Sorted numbers 2^a 3^b 5^c up to 2**26: lengths the FFT handles fastest."""
    limit, out, a = 1 << 26, [], 1
    while a <= limit:
        b = a
        while b <= limit:
            c = b
            while c <= limit:
                out.append(c)
                c *= 5
            b *= 3
        a *= 2
    return np.array(sorted(out), dtype=np.int64)


def _fft_size(n: int) -> int:
    """The smallest 5-smooth length >= n (n itself beyond 2**26)."""
    sizes = _smooth_sizes()
    i = int(np.searchsorted(sizes, n))
    return int(sizes[i]) if i < sizes.size else n


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) index ranges of True runs."""
    m = np.concatenate(([False], mask, [False]))
    edges = np.flatnonzero(m[1:] != m[:-1])
    return list(zip(edges[::2].tolist(), edges[1::2].tolist()))


def bound_grade(h: np.ndarray, step: float, max_grade: float) -> np.ndarray:
    """Bound the grade of a uniform profile (spacing ``step`` [m]) to ``max_grade``.

    Returns the mean of the two Lipschitz envelopes of ``h``: the largest profile below
    ``h`` and the smallest profile above ``h`` whose grade never exceeds ``max_grade``
    (``min_j h_j + G |i - j| step`` and ``max_j h_j - G |i - j| step``, computed with
    running minima/maxima, O(n)). Both envelopes obey the bound, so their mean does.
    Where ``h`` already obeys it both equal ``h``: the profile changes only around a
    violation, which becomes a ramp centred on it, and total rise and fall far from it
    are kept. So there is no drift, unlike clipping the grade and integrating.
    """
    if h.size < 2 or np.all(np.abs(np.diff(h)) <= max_grade * step):
        return h.copy()
    s = max_grade * step * np.arange(h.size)
    up_fwd = s + np.minimum.accumulate(h - s)  # min over j <= i of h_j + G (i - j) step
    up_bwd = (np.minimum.accumulate((h + s)[::-1]))[::-1] - s  # j >= i
    lo_fwd = np.maximum.accumulate(h + s) - s
    lo_bwd = (np.maximum.accumulate((h - s)[::-1]))[::-1] + s
    lower_env = np.minimum(up_fwd, up_bwd)
    upper_env = np.maximum(lo_fwd, lo_bwd)
    return 0.5 * (lower_env + upper_env)


def _profile_grid(d: np.ndarray, z: np.ndarray, params: ElevationParams, grid: np.ndarray, max_gap_m: float) -> tuple[np.ndarray, _Gaps]:
    """Smoothed (not yet grade-bounded) profile on ``grid``, NaN inside long gaps."""
    valid = np.isfinite(z)
    gaps = _find_gaps(d, valid, max_gap_m)
    if not valid.any():
        return np.full(grid.size, np.nan), gaps
    h = _resample(d, z, valid, grid)
    # Blank long gaps, keeping the first grid point past the valid sample on each side
    # so that the samples next to the gap still interpolate between finite points.
    for a, b, kind in gaps.long:
        lo = 0 if kind == "lead" else np.searchsorted(grid, a, side="right") + 1
        hi = grid.size if kind == "trail" else np.searchsorted(grid, b, side="left") - 1
        if hi > lo:
            h[lo:hi] = np.nan
    step = grid[1] - grid[0] if grid.size > 1 else params.grid_step_m
    for lo, hi in _runs(np.isfinite(h)):
        h[lo:hi] = _smooth(h[lo:hi], step, params)
    return h, gaps


def road_profile_m(distance_m, raw_elevation_m, params: ElevationParams = ElevationParams()) -> np.ndarray:
    """Road elevation profile [m] from raw (spiky, gappy) elevation samples.

    Steps: (1) resample onto a uniform grid of ``grid_step_m`` along distance (means
    per cell, linear between cells); (2) bridge runs of NaN samples spanning up to
    ``max_gap_m`` by linear interpolation along distance, leave longer gaps NaN;
    (3) running median of ``median_window_m`` (removes roofs, trees, vehicles, bridge
    decks), repeated on its residuals to cancel the median's bias on slopes, then Gaussian low-pass of ``lowpass_sigma_m``, each covered stretch apart;
    (4) bound the grade to ``max_grade`` with :func:`bound_grade` (no drift);
    (5) interpolate back to the samples by distance, so samples that share a distance
    (standstill) get the same elevation.

    Parameters
    ----------
    distance_m : array_like
        Cumulative distance of the samples [m], finite and non-decreasing.
    raw_elevation_m : array_like
        Raw elevation per sample [m], NaN where unknown.
    params : ElevationParams

    Returns
    -------
    ndarray of float64
        Elevation per sample [m]; NaN only inside gaps longer than ``max_gap_m`` (and
        everywhere if no sample is valid).
    """
    d = np.asarray(distance_m, dtype=np.float64)
    z = np.asarray(raw_elevation_m, dtype=np.float64)
    if d.shape != z.shape or d.ndim != 1:
        raise ValueError("distance_m and raw_elevation_m must be 1-D arrays of one length")
    if d.size == 0:
        return np.empty(0)
    _check_distance(d)
    grid = _grid(d[0], d[-1], params.grid_step_m)
    h, _ = _profile_grid(d, z, params, grid, params.max_gap_m)
    step = grid[1] - grid[0] if grid.size > 1 else params.grid_step_m
    for lo, hi in _runs(np.isfinite(h)):
        h[lo:hi] = bound_grade(h[lo:hi], step, params.max_grade)
    return _to_samples(d, grid, h)


def _to_samples(d: np.ndarray, grid: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Profile on the grid back to the samples, linear along distance; a sample with a
    NaN grid neighbour of non-zero weight is NaN."""
    if grid.size == 1:
        return np.full(d.size, h[0])
    out = np.interp(d, grid, h)
    if np.isnan(h).any():
        k = np.clip(np.searchsorted(grid, d, side="right") - 1, 0, grid.size - 2)
        w = (d - grid[k]) / (grid[k + 1] - grid[k])
        bad = (np.isnan(h[k]) & (w < 1)) | (np.isnan(h[k + 1]) & (w > 0))
        out[bad] = np.nan
    return out


def _mean_finite(x: np.ndarray) -> float | None:
    x = x[np.isfinite(x)]
    return float(x.mean()) if x.size else None


def _gps_usable(gps: np.ndarray | None, params: ElevationParams) -> tuple[np.ndarray | None, str]:
    """Plausible GPS altitudes (implausible ones as NaN), or None with the reason."""
    if gps is None:
        return None, "no GPS altitude"
    g = np.asarray(gps, dtype=np.float64).copy()
    lo, hi = params.gps_alt_range_m
    g[~((g >= lo) & (g <= hi))] = np.nan
    n_ok = int(np.isfinite(g).sum())
    if g.size == 0 or 100.0 * n_ok / g.size < params.gps_min_valid_pct:
        return None, f"GPS altitude valid on {100.0 * n_ok / max(g.size, 1):.0f}% of samples only"
    if np.nanmax(g) == np.nanmin(g) and n_ok > 1:
        return None, "GPS altitude is constant (a placeholder)"
    return g, ""


def combine_elevation(distance_m, raw_dsm_m, gps_alt_m=None, params: ElevationParams = ElevationParams(), *, have_dsm: bool = True) -> ElevationResult:
    """Road elevation of a trip from raw DSM samples, with GPS altitude or a flat fill
    as fallback (pure).

    The DSM profile is built as in :func:`road_profile_m`. Gaps longer than
    ``max_gap_m`` are filled from GPS altitude, smoothed the same way (its own gaps
    bridged whatever their length), plus an offset that varies linearly across the gap
    from the mean (DSM - GPS) over up to ``median_window_m`` of DSM profile before it
    to the same mean after it, so the fill joins the DSM profile on both sides (a
    constant offset at the trip's ends; the grade bound absorbs the small residual
    step). Without usable GPS (over the whole trip, or in that gap), a long gap is
    bridged by a straight line between the DSM values at its ends, or held level at the
    trip's ends. Without any DSM value the profile is the smoothed GPS
    altitude, or 0 m everywhere ("flat"). The grade bound is applied last, to the whole
    profile.

    Parameters
    ----------
    distance_m : array_like
        Cumulative distance [m], finite, non-decreasing.
    raw_dsm_m : array_like or None
        Raw DSM elevation per sample [m], NaN where invalid; None if there is no DSM.
    gps_alt_m : array_like or None
        GPS altitude per sample [m], NaN where missing.
    params : ElevationParams
    have_dsm : bool
        False when no DSM was given at all (changes only the notes).
    """
    d = np.asarray(distance_m, dtype=np.float64)
    n = d.size
    if raw_dsm_m is None:
        have_dsm = False
        z = np.full(n, np.nan)
    else:
        z = np.asarray(raw_dsm_m, dtype=np.float64)
    if z.shape != d.shape or d.ndim != 1:
        raise ValueError("distance_m and raw_dsm_m must be 1-D arrays of one length")
    if gps_alt_m is not None and np.shape(gps_alt_m) != d.shape:
        raise ValueError("gps_alt_m must have the length of distance_m")
    if n == 0:
        return ElevationResult(np.empty(0), "flat", 0.0, notes=("empty trip",))
    _check_distance(d)
    valid = np.isfinite(z)
    coverage = 100.0 * valid.sum() / n if have_dsm else 0.0
    notes: list[str] = []
    grid = _grid(d[0], d[-1], params.grid_step_m)
    step = grid[1] - grid[0] if grid.size > 1 else params.grid_step_m
    h, gaps = _profile_grid(d, z, params, grid, params.max_gap_m)
    gps, why_not_gps = _gps_usable(gps_alt_m, params)
    filled_gps = filled_flat = 0.0

    if not valid.any():
        notes.append("no DSM given" if not have_dsm else "no valid DSM value on this trip")
        if gps is not None:
            g, _ = _profile_grid(d, gps, _gps_params(params), grid, math.inf)
            h, source, filled_gps = g, "gps", float(d[-1] - d[0])
            notes.append("smoothed GPS altitude used")
        else:
            h, source, filled_flat = np.zeros(grid.size), "flat", float(d[-1] - d[0])
            notes.append(f"{why_not_gps}: flat profile at 0 m")
        short = 0.0
    else:
        short = gaps.short_m
        source = "dsm"
        holes = np.isnan(h)
        if holes.any():
            gap_a = np.array([g[0] for g in gaps.long])
            gap_m = np.array([g[1] - g[0] for g in gaps.long])
            by_gps = np.zeros(gap_m.size, dtype=bool)
            if gps is not None:
                span = max(1, int(round(params.median_window_m / step)))
                for lo, hi in _runs(holes):
                    g = _gps_around(d, gps, params, grid, lo, hi, span)
                    # DSM - GPS offset at each side, averaged over the DSM stretch (up to
                    # median_window_m) next to the gap, to average out GPS noise.
                    off_l = _mean_finite(h[max(0, lo - span) : lo] - g[max(0, lo - span) : lo])
                    off_r = _mean_finite(h[hi : hi + span] - g[hi : hi + span])
                    inside = (d >= grid[lo]) & (d <= grid[hi - 1])
                    gps_inside = np.isfinite(gps[inside]).mean() if inside.any() else 0.0
                    if gps_inside < 0.5 or not np.isfinite(g[lo:hi]).all() or (off_l is None and off_r is None):
                        continue  # no GPS here (fixes in under half the gap): left to the straight line below
                    if off_l is None or off_r is None:
                        off = np.full(hi - lo, off_r if off_l is None else off_l)
                    else:
                        w = (grid[lo:hi] - grid[lo - 1]) / (grid[hi] - grid[lo - 1])
                        off = off_l + w * (off_r - off_l)
                    h[lo:hi] = g[lo:hi] + off
                    by_gps[max(0, np.searchsorted(gap_a, grid[lo], side="right") - 1)] = True
            filled_gps = float(gap_m[by_gps].sum())
            filled_flat = float(gap_m[~by_gps].sum())
            holes = np.isnan(h)
            if holes.any():
                ok = ~holes
                h[holes] = np.interp(grid[holes], grid[ok], h[ok])
            if filled_gps > 0:
                source = "dsm+gps"
                notes.append(f"{int(by_gps.sum())} DSM gap(s) over {_gap_str(params)} ({filled_gps:.0f} m) filled from GPS altitude joined to the DSM")
            if filled_flat > 0:
                source = "dsm+gps+flat" if filled_gps > 0 else "dsm+flat"
                why = why_not_gps if gps is None else "no GPS altitude there"
                notes.append(f"{int((~by_gps).sum())} DSM gap(s) over {_gap_str(params)} ({filled_flat:.0f} m) bridged by straight lines ({why})")
        if short > 0:
            notes.append(f"DSM gaps up to {_gap_str(params)} ({short:.0f} m) interpolated along distance")
    h = bound_grade(h, step, params.max_grade)
    return ElevationResult(
        elevation_m=_to_samples(d, grid, h),
        source=source,
        dsm_coverage_pct=float(coverage),
        filled_short_m=float(short),
        filled_gps_m=float(filled_gps),
        filled_flat_m=float(filled_flat),
        notes=tuple(notes),
    )


def _gps_around(d, gps, params: ElevationParams, grid, lo: int, hi: int, span: int) -> np.ndarray:
    """Smoothed GPS profile on ``grid``, computed only over grid[lo:hi] widened by
    ``span`` cells (for the offsets) and the filters' reach (so that the values there
    are practically those of a whole-trip computation); NaN elsewhere."""
    step = grid[1] - grid[0]
    params = _gps_params(params)
    reach = span + int(params.median_window_m / step) + int(4 * params.lowpass_sigma_m / step) + 2
    a, b = max(0, lo - reach), min(grid.size, hi + reach)
    i, j = np.searchsorted(d, grid[a], side="left"), np.searchsorted(d, grid[b - 1], side="right")
    i, j = max(0, i - 1), min(d.size, j + 1)  # one sample beyond, for the interpolation
    g = np.full(grid.size, np.nan)
    g[a:b], _ = _profile_grid(d[i:j], gps[i:j], params, grid[a:b], math.inf)
    return g


@lru_cache(maxsize=16)
def _gps_params(params: ElevationParams) -> ElevationParams:
    """``params.for_gps()``, made once per parameter set."""
    return params.for_gps()


def _gap_str(params: ElevationParams) -> str:
    return f"{params.max_gap_m:g} m"


def trip_elevation(distance_m, lon_deg, lat_deg, gps_alt_m=None, sampler: DsmSampler | None = None, params: ElevationParams = ElevationParams()) -> ElevationResult:
    """Road elevation of a trip: DSM lookup at the fixes (if ``sampler``), then
    :func:`combine_elevation`.

    Parameters
    ----------
    distance_m : array_like
        Cumulative distance [m], finite, non-decreasing.
    lon_deg, lat_deg : array_like
        WGS84 fixes [deg], NaN where there is no fix.
    gps_alt_m : array_like or None
        GPS altitude [m], NaN where missing; None if the logger has none.
    sampler : DsmSampler or None
        The DSM; None gives GPS altitude (if plausible) or a flat profile.
    params : ElevationParams
    """
    if sampler is None:
        return combine_elevation(distance_m, None, gps_alt_m, params, have_dsm=False)
    raw = sampler.sample(lon_deg, lat_deg)
    return combine_elevation(distance_m, raw, gps_alt_m, params)
