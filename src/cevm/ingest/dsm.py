"""DSM access for the ingest pipeline (I/O edge): look up a digital surface model at
WGS84 fixes.

:class:`DsmSampler` samples a DSM with bilinear interpolation. The DSM is a GeoTIFF, a
directory of GeoTIFF tiles, a VRT, or any GDAL name rasterio opens (``/vsicurl/...``,
``https://...`` to a COG or VRT). Tiles may be in any CRS. It is made of three parts:

- the :class:`TileIndex`: the rasters' headers (:class:`DsmHeaders`, read once and
  handed to workers), grouped by CRS, and where each point falls;
- the :class:`WindowReader`: the windows of the rasters that hold points, read once per
  call and kept in a small LRU cache across calls;
- the sampling itself (:meth:`DsmSampler.sample`): the transform of the fixes, and
  bilinear interpolation between pixel centres, exact across tile seams.

Turning the samples into a road profile is :mod:`cevm.ingest.elevation`.
"""

from __future__ import annotations

import math
import os
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from cevm.errors import InputError
from cevm.ingest.dsm_sources import check_local, remote_allowed

__all__ = ["DsmHeaders", "DsmSampler", "SamplerStats", "TileIndex", "WindowReader"]

WGS84 = "EPSG:4326"

#: Points looked up at a time by :meth:`DsmSampler.sample_xy` (its temporaries take
#: about 150 bytes a point).
POINTS_AT_A_TIME = 1 << 16


@dataclass
class SamplerStats:
    """Counters of a :class:`DsmSampler`, to check and tune its I/O.

    ``windows_read`` and ``pixels_read`` count raster windows read from GDAL (cache
    misses); ``cache_hits`` counts windows served from the sampler's cache;
    ``points`` counts points asked for; ``windows_failed`` windows that could not be
    read (their tile is then unreadable: :attr:`DsmSampler.unreadable`).
    """

    windows_read: int = 0
    pixels_read: int = 0
    cache_hits: int = 0
    points: int = 0
    windows_failed: int = 0


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
    driver: str = ""  # the only GDAL driver to open it with ("": any; see cevm.ingest.dsm_sources)

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


def _read_header(name: str, shown: str, driver: str = "") -> _Tile:
    import rasterio
    from rasterio.errors import RasterioError

    try:
        with rasterio.open(name, driver=driver or None) as ds:
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
                driver=driver,
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
        self._grid = self._regular_grid(b) if len(tile_ids) > 8 else None

    #: Largest table of a regular tile grid [cells] (4 bytes each).
    MAX_GRID_CELLS = 4_000_000

    def _regular_grid(self, b: np.ndarray) -> np.ndarray | None:
        """The tiles as a table (row from the top, column from the left) of tile
        indices, -1 for no tile, when they form a regular grid: one size, edges on
        multiples of it from the bounding box's corner, no two in one cell (the usual
        national DSM, e.g. 1 km tiles on the grid's kilometres). None otherwise."""
        w, h = b[:, 2] - b[:, 0], b[:, 3] - b[:, 1]
        tw, th = float(w[0]), float(h[0])
        if not (tw > 0 and th > 0) or np.abs(w - tw).max() > 1e-9 * tw or np.abs(h - th).max() > 1e-9 * th:
            return None
        fc = (b[:, 0] - self.bbox[0]) / tw
        fr = (self.bbox[3] - b[:, 3]) / th
        col, row = np.rint(fc), np.rint(fr)
        if np.abs(fc - col).max() > 1e-6 or np.abs(fr - row).max() > 1e-6:
            return None
        nx, ny = int(col.max()) + 1, int(row.max()) + 1
        if nx * ny > self.MAX_GRID_CELLS:
            return None
        grid = np.full((ny, nx), -1, dtype=np.int32)
        flat = row.astype(np.int64) * nx + col.astype(np.int64)
        if np.unique(flat).size != flat.size:
            return None  # overlapping tiles: the bucket index keeps "first wins"
        grid.reshape(-1)[flat] = np.arange(flat.size, dtype=np.int32)
        self._tw, self._th = tw, th
        return grid

    def _locate_regular(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(tile, undecided): each point's tile on the regular grid, checked against the
        tile's exact bounds; ``undecided`` marks points within rounding of a cell edge
        (or failing the check), which the general index decides."""
        grid = self._grid
        ny, nx = grid.shape
        fc = (x - self.bbox[0]) / self._tw
        fr = (self.bbox[3] - y) / self._th
        with np.errstate(invalid="ignore"):
            inside = (fc >= 0) & (fc < nx) & (fr >= 0) & (fr < ny)
        ci = np.where(inside, fc, 0).astype(np.int64)
        ri = np.where(inside, fr, 0).astype(np.int64)
        k = np.where(inside, grid[ri, ci], -1).astype(np.int64)
        kk = np.maximum(k, 0)
        ok = (k >= 0) & (x >= self.xmin[kk]) & (x < self.xmax[kk]) & (y > self.ymin[kk]) & (y <= self.ymax[kk])
        eps = 1e-7
        near = (np.abs(fc - np.rint(fc)) < eps) | (np.abs(fr - np.rint(fr)) < eps)
        undecided = (k >= 0) & ~ok | (near & np.isfinite(fc) & np.isfinite(fr))
        return np.where(ok, self.tile_ids[kk], -1), undecided

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
        if self._grid is not None:
            out, undecided = self._locate_regular(x, y)
            if undecided.any():
                u = np.flatnonzero(undecided)
                out[u] = self._locate_buckets(x[u], y[u])
            return out
        return self._locate_buckets(x, y)

    def _locate_buckets(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """:meth:`locate` through the bucket index (any layout of tiles)."""
        out = np.full(x.shape, -1, dtype=np.int64)
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


class TileIndex:
    """Where the DSM's rasters are: their headers grouped by CRS, each group with a
    bucket index that finds the tile holding a point (the first, in sorted path order,
    where tiles overlap), and per-tile arrays for vectorised pixel arithmetic. Built
    from the headers alone; reads nothing."""

    def __init__(self, tiles: Sequence[_Tile]):
        self.tiles: list[_Tile] = list(tiles)
        by_crs: dict[str, list[int]] = {}
        for i, t in enumerate(self.tiles):
            by_crs.setdefault(t.crs_key, []).append(i)
        self.groups = [_CrsGroup(k, ids, self.tiles) for k, ids in by_crs.items()]
        self.group_of_tile = np.empty(len(self.tiles), dtype=np.int64)
        for gi, grp in enumerate(self.groups):
            self.group_of_tile[grp.tile_ids] = gi
        f = lambda attr: np.array([getattr(t, attr) for t in self.tiles], dtype=np.float64)  # noqa: E731
        self.x0, self.y0, self.a, self.e = f("x0"), f("y0"), f("a"), f("e")
        self.w = np.array([t.width for t in self.tiles], dtype=np.int64)
        self.h = np.array([t.height for t in self.tiles], dtype=np.int64)

    def locate(self, x: np.ndarray, y: np.ndarray, crs: str):
        """The tile holding each point (``x``, ``y`` in ``crs``) and the point in that
        tile's CRS: ``(tile, px, py, pts)``, for the points ``pts`` inside a tile
        (``pts`` None: every point, in order). Non-finite points are in no tile."""
        finite = np.isfinite(x) & np.isfinite(y)
        if len(self.groups) == 1 and bool(finite.all()):
            # Common case, no index arrays: one CRS, every fix finite.
            grp = self.groups[0]
            px, py = _to_crs(x, y, crs, grp.crs_key)
            t = grp.locate(px, py)
            pts = None
            if not (t >= 0).all():
                pts = np.flatnonzero(t >= 0)
                t, px, py = t[pts], px[pts], py[pts]
            return t, px, py, pts
        live = np.flatnonzero(finite)
        tile = np.full(x.size, -1, dtype=np.int64)
        tx = np.full(x.size, np.nan)
        ty = np.full(x.size, np.nan)
        for grp in self.groups:
            todo = live[tile[live] < 0]
            if todo.size == 0:
                break
            if len(self.groups) > 1:
                todo = todo[self._in_group_bbox(grp, x[todo], y[todo], crs)]
            gx, gy = _to_crs(x[todo], y[todo], crs, grp.crs_key)
            found = grp.locate(gx, gy)
            hit = found >= 0
            sel = todo[hit]
            tile[sel], tx[sel], ty[sel] = found[hit], gx[hit], gy[hit]
        pts = np.flatnonzero(tile >= 0)
        return tile[pts], tx[pts], ty[pts], pts

    def pixels_holding(self, tile: np.ndarray, cx: np.ndarray, cy: np.ndarray):
        """For points (``cx``, ``cy``) in the CRS of ``tile`` (one per point): the tile
        of that CRS whose pixel area holds each, and the pixel's row and column
        (``(sel, tile, row, col)`` for the points ``sel`` that some tile holds)."""
        sels, tiles, rows, cols = [], [], [], []
        grp = self.group_of_tile[tile]
        for gi in np.unique(grp).tolist():
            sel = np.flatnonzero(grp == gi)
            nt = self.groups[gi].locate(cx[sel], cy[sel])
            ok = nt >= 0
            sel, nt = sel[ok], nt[ok]
            col = np.floor((cx[sel] - self.x0[nt]) / self.a[nt]).astype(np.int64)
            row = np.floor((cy[sel] - self.y0[nt]) / self.e[nt]).astype(np.int64)
            sels.append(sel)
            tiles.append(nt)
            rows.append(np.clip(row, 0, self.h[nt] - 1))
            cols.append(np.clip(col, 0, self.w[nt] - 1))
        if len(sels) == 1:
            return sels[0], tiles[0], rows[0], cols[0]
        return tuple(np.concatenate(a) if a else np.empty(0, dtype=np.int64) for a in (sels, tiles, rows, cols))

    @staticmethod
    def _in_group_bbox(grp: _CrsGroup, x: np.ndarray, y: np.ndarray, crs: str) -> np.ndarray:
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


def _to_crs(x: np.ndarray, y: np.ndarray, src: str, dst: str) -> tuple[np.ndarray, np.ndarray]:
    if src == dst:
        return x, y
    gx, gy = _transformer(src, dst).transform(x, y)
    return np.asarray(gx, dtype=np.float64), np.asarray(gy, dtype=np.float64)


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


class WindowReader:
    """Pixels of the DSM's rasters, read in square windows and cached.

    A raster is read in blocks of ``block_px`` (per tile: the given size, else the
    raster's own square internal tile size between 128 and 1024 px, else 512), each
    with a one-pixel margin right and below for the bilinear neighbours, as float
    (float32 for plain float32 rasters) with NaN for nodata and the raster's scale and
    offset applied. Blocks stay in an LRU cache of ``cache_bytes`` across calls (the
    blocks of one :meth:`gather` stay until it is done; a gather that needs more than
    the budget is done a budget's worth of blocks at a time); cached blocks of one shape
    share one array (:class:`_Pool`), so a gather fetches its pixels with one fancy
    index whatever the number of blocks. At most ``max_open`` datasets stay open.
    """

    def __init__(self, tiles: Sequence[_Tile], *, block_px: int | None, cache_mb: float, max_open: int,
                 stats: SamplerStats):
        self.tiles = list(tiles)
        self.cache_bytes = int(cache_mb * 1e6)
        self.max_open = int(max_open)
        self.stats = stats
        # Block cache: key (tile << 42 | brow << 21 | bcol) -> (pool, slot, nbytes), LRU
        # order. A block lives in a slot of a pool: one 2-D array per (slot height,
        # width, dtype), one row per slot, so that a lookup gathers from every cached
        # block with one fancy index.
        self._blocks: OrderedDict[int, tuple[int, int, int]] = OrderedDict()
        self._cached_bytes = 0
        self._pools: list[_Pool] = []
        self._pool_index: dict[tuple[int, int, str], int] = {}
        self._open: OrderedDict[int, object] = OrderedDict()
        self.failed: dict[int, str] = {}  # tile -> why it cannot be read
        self._blk = np.array([block_px or (t.block if 128 <= t.block <= 1024 else 512) for t in self.tiles], dtype=np.int64)
        self._h = np.array([t.height for t in self.tiles], dtype=np.int64)
        self._w = np.array([t.width for t in self.tiles], dtype=np.int64)

    def close(self) -> None:
        """Close open datasets and drop the block cache."""
        for ds in self._open.values():
            ds.close()
        self._open.clear()
        self._blocks.clear()
        self._cached_bytes = 0
        self._pools.clear()
        self._pool_index.clear()

    def _dataset(self, tile: int):
        ds = self._open.get(tile)
        if ds is not None:
            self._open.move_to_end(tile)
            return ds
        import rasterio

        ds = rasterio.open(self.tiles[tile].name, driver=self.tiles[tile].driver or None)
        self._open[tile] = ds
        while len(self._open) > self.max_open:
            _, old = self._open.popitem(last=False)
            old.close()
        return ds

    def _read_block(self, tile: int, brow: int, bcol: int) -> np.ndarray:
        """Pixels of block (brow, bcol) of a tile plus a one-pixel margin right and
        below, as float (float32 for float32 rasters) with NaN for nodata. A tile that
        cannot be opened or read gives NaN from then on (:attr:`failed` says why): it
        costs only the points it covers."""
        from rasterio.errors import RasterioError
        from rasterio.windows import Window

        t = self.tiles[tile]
        b = int(self._blk[tile])
        r0, c0 = brow * b, bcol * b
        h, w = min(b + 1, t.height - r0), min(b + 1, t.width - c0)
        if tile in self.failed:
            return np.full((h, w), np.nan)
        try:
            raw = self._dataset(tile).read(1, window=Window(c0, r0, w, h))
        except (RasterioError, OSError) as exc:
            self.failed[tile] = f"cannot read window {w}x{h} at col {c0}, row {r0}: {exc}"
            self.stats.windows_failed += 1
            return np.full((h, w), np.nan)
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

    def _block_slot(self, key: int, keep: int = 0) -> tuple[int, int]:
        """(pool, slot) of the cached block ``key`` (tile << 42 | brow << 21 | bcol),
        read on a miss, after older blocks are evicted to make room for it (never the
        ``keep`` most recently used: the lookup's own). The cache is trimmed to its
        budget by :meth:`_trim` after each lookup too, so the blocks of one lookup stay
        while it gathers."""
        hit = self._blocks.get(key)
        if hit is not None:
            self._blocks.move_to_end(key)
            self.stats.cache_hits += 1
            return hit[0], hit[1]
        tile, brow, bcol = key >> 42, (key >> 21) & ((1 << 21) - 1), key & ((1 << 21) - 1)
        arr = self._read_block(tile, brow, bcol)
        self._trim(arr.nbytes, keep)
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

    def _trim(self, extra: int = 0, keep: int = 1) -> None:
        """Evict least recently used blocks until ``extra`` bytes more fit the cache
        budget, keeping the ``keep`` most recently used."""
        while self._cached_bytes + extra > self.cache_bytes and len(self._blocks) > keep:
            _, (pi, slot, nbytes) = self._blocks.popitem(last=False)
            self._pools[pi].free.append(slot)
            self._cached_bytes -= nbytes

    def gather(self, tile: np.ndarray, row: np.ndarray, col: np.ndarray, quad: bool) -> np.ndarray:
        """Pixel values at (tile, row, col); with ``quad`` also the right, lower and
        lower-right neighbours (requires row <= height-2, col <= width-2). Returns shape
        (n,) or (4, n): [z(r,c), z(r,c+1), z(r+1,c), z(r+1,c+1)]. Points whose blocks
        are more than the cache budget are done a budget's worth of blocks at a time
        (a long track on a fine DSM would otherwise hold all its blocks at once)."""
        n = tile.size
        out = np.empty((4, n) if quad else (n,), dtype=np.float64)
        if n == 0:
            return out
        blk = self._blk[tile]
        brow, bcol = row // blk, col // blk
        uniq, inv = _unique_inverse((tile << 42) | (brow << 21) | bcol)
        # the blocks in groups of at most the budget (sizes as float64, margin included)
        t_u = uniq >> 42
        b_u = self._blk[t_u] + 1
        nbytes = np.minimum(b_u, self._h[t_u]) * np.minimum(b_u, self._w[t_u]) * 8
        if int(nbytes.sum()) <= self.cache_bytes:
            self._gather_blocks(uniq, inv, tile, row, col, brow, bcol, blk, quad, out)
            return out
        bounds, acc = [0], 0
        for i, nb in enumerate(nbytes.tolist()):  # over blocks, not points
            if acc + nb > self.cache_bytes and i > bounds[-1]:
                bounds.append(i)
                acc = 0
            acc += nb
        bounds.append(uniq.size)
        order = np.argsort(inv, kind="stable")  # points by block, so by group
        starts = np.searchsorted(inv[order], bounds)
        for g in range(len(bounds) - 1):
            lo, hi = bounds[g], bounds[g + 1]
            pts = order[starts[g]:starts[g + 1]]
            part = np.empty((4, pts.size) if quad else (pts.size,), dtype=np.float64)
            self._gather_blocks(uniq[lo:hi], inv[pts] - lo, tile[pts], row[pts], col[pts], brow[pts], bcol[pts],
                                blk[pts], quad, part)
            out[..., pts] = part
        return out

    def _gather_blocks(self, uniq, inv, tile, row, col, brow, bcol, blk, quad: bool, out: np.ndarray) -> None:
        """:meth:`gather` of points whose blocks are ``uniq`` (``inv``: each point's)."""
        pool_of = np.empty(uniq.size, dtype=np.int64)
        slot_of = np.empty(uniq.size, dtype=np.int64)
        try:
            for i, key in enumerate(uniq.tolist()):
                pool_of[i], slot_of[i] = self._block_slot(key, keep=i)
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


class DsmSampler:
    """Bilinear lookup of a DSM (one raster, a VRT, or many tiles in any CRSs).

    Open with :meth:`open`; use as a context manager (or call :meth:`close`). Not
    thread-safe: use one sampler per thread.

    How a lookup works: fixes are transformed with pyproj into each tile CRS (one
    cached transformer per CRS); the :class:`TileIndex` (bounds from the headers, read
    once when the sampler opens) finds the tile holding each point; the
    :class:`WindowReader` fetches the four neighbour pixels of every point from its
    cached windows, and they are interpolated with numpy. Nothing bigger than a window
    is ever read for a point and a national mosaic is never loaded; Python loops run
    over the distinct windows of a call, one cache lookup each, never over points.

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
        self.label = label
        self.stats = SamplerStats()
        self.index = TileIndex(tiles)
        self.windows = WindowReader(self.index.tiles, block_px=block_px, cache_mb=cache_mb, max_open=max_open,
                                    stats=self.stats)

    @property
    def tiles(self) -> list[_Tile]:
        """The rasters' headers, in sorted path order."""
        return self.index.tiles

    @property
    def unreadable(self) -> dict[str, str]:
        """Tiles found unreadable while sampling (name -> why); their points are NaN."""
        return {self.tiles[i].name: why for i, why in self.windows.failed.items()}

    def tiles_at(self, lon_deg, lat_deg) -> np.ndarray:
        """Index (into :attr:`tiles`) of the tile holding each WGS84 point, -1 for none."""
        x = np.asarray(lon_deg, dtype=np.float64).ravel()
        y = np.asarray(lat_deg, dtype=np.float64).ravel()
        out = np.full(x.size, -1, dtype=np.int64)
        if x.size and self.tiles:
            t, _, _, pts = self.index.locate(x, y, WGS84)
            if pts is None:
                out[:] = t
            else:
                out[pts] = t
        return out

    @property
    def max_open(self) -> int:
        """Datasets kept open at most (least recently used closed first)."""
        return self.windows.max_open

    @max_open.setter
    def max_open(self, value: int) -> None:
        self.windows.max_open = int(value)

    # ---- construction ----------------------------------------------------------------

    @classmethod
    def open(cls, source: str | os.PathLike | Sequence[str | os.PathLike], *, block_px: int | None = None,
             cache_mb: float = 256.0, allow_remote: bool | None = None) -> DsmSampler:
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
        allow_remote : bool or None, default None
            Allow names and VRT sources that make GDAL fetch over a network; None: as
            the environment's ``CEVM_ALLOW_REMOTE_DSM`` says (off unless set to 1).
            Without it only local GeoTIFFs and VRTs of them are opened
            (:mod:`cevm.ingest.dsm_sources`).

        Raises
        ------
        InputError
            Missing path, empty directory, unreadable raster, raster without CRS, a
            remote source without ``allow_remote``.
        """
        names = _list_sources(source)
        shown = os.fspath(source) if not isinstance(source, (list, tuple)) else None
        local = not remote_allowed(allow_remote)
        tiles = [_read_header(n, n, check_local(n) if local else "") for n in names]
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
        self.windows.close()

    def __enter__(self) -> DsmSampler:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        crss = ", ".join(g.crs_key[:40] for g in self.index.groups)
        return f"DsmSampler({self.label!r}, {len(self.tiles)} tiles, CRS {crss})"

    # ---- lookup --------------------------------------------------------------------------

    def sample(self, lon_deg, lat_deg) -> np.ndarray:
        """DSM elevation [m] at WGS84 longitudes and latitudes [deg] (same shape),
        bilinear between pixel centres, NaN where invalid (nodata neighbour, outside
        every tile, non-finite input)."""
        return self.sample_xy(lon_deg, lat_deg, WGS84)

    def sample_xy(self, x, y, crs: str = WGS84) -> np.ndarray:
        """DSM elevation [m] at coordinates ``x``, ``y`` in ``crs`` (any pyproj CRS
        string; x is easting or longitude). See :meth:`sample`. Many points are looked
        up :data:`POINTS_AT_A_TIME` at a time (bounded temporaries; the same values)."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        if x.shape != y.shape:
            raise ValueError(f"x and y differ in shape: {x.shape} vs {y.shape}")
        shape = x.shape
        x, y = x.ravel(), y.ravel()
        if x.size > POINTS_AT_A_TIME:  # bounded temporaries (the values do not depend on it)
            out = np.empty(x.size)
            for a in range(0, x.size, POINTS_AT_A_TIME):
                out[a:a + POINTS_AT_A_TIME] = self.sample_xy(x[a:a + POINTS_AT_A_TIME], y[a:a + POINTS_AT_A_TIME], crs)
            return out.reshape(shape)
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
        t, px, py, pts = self.index.locate(x, y, crs)
        if t.size == 0:
            return out
        ix = self.index
        w, h = ix.w[t], ix.h[t]
        # Continuous pixel coordinates with pixel centres at integers.
        colf = (px - ix.x0[t]) / ix.a[t] - 0.5
        rowf = (py - ix.y0[t]) / ix.e[t] - 0.5
        c0 = np.floor(colf).astype(np.int64)
        r0 = np.floor(rowf).astype(np.int64)
        # Exactly on the last centre row/column: use the cell before it (weight 1).
        c0 -= (colf == w - 1) & (c0 > 0)
        r0 -= (rowf == h - 1) & (r0 > 0)
        inner = (c0 >= 0) & (c0 <= w - 2) & (r0 >= 0) & (r0 <= h - 2)
        res = np.empty(t.size)
        if inner.all():
            z = self.windows.gather(t, r0, c0, quad=True)
            res[:] = _bilinear(z, colf - c0, rowf - r0)
        else:
            ii = np.flatnonzero(inner)
            z = self.windows.gather(t[ii], r0[ii], c0[ii], quad=True)
            res[ii] = _bilinear(z, colf[ii] - c0[ii], rowf[ii] - r0[ii])
            ee = np.flatnonzero(~inner)
            res[ee] = self._sample_edge(t[ee], colf[ee], rowf[ee])
        if pts is None:
            return res
        out[pts] = res
        return out

    def _sample_edge(self, t, colf, rowf) -> np.ndarray:
        """Bilinear for points within half a pixel of their tile's edge: each of the four
        neighbour pixel centres (on the point's tile grid) is looked up in whatever tile
        of the same CRS holds it."""
        ix = self.index
        c0 = np.floor(colf)
        r0 = np.floor(rowf)
        m = t.size
        # the four neighbours (0, 0), (0, 1), (1, 0), (1, 1) of every point, one batch
        dr = np.repeat(np.array([0, 0, 1, 1]), m)
        dc = np.repeat(np.array([0, 1, 0, 1]), m)
        tt = np.tile(t, 4)
        cx = ix.x0[tt] + ix.a[tt] * (np.tile(c0, 4) + dc + 0.5)
        cy = ix.y0[tt] + ix.e[tt] * (np.tile(r0, 4) + dr + 0.5)
        z = np.full(4 * m, np.nan)
        sel, nt, row, col = ix.pixels_holding(tt, cx, cy)
        z[sel] = self.windows.gather(nt, row, col, quad=False)
        return _bilinear(z.reshape(4, m), colf - c0, rowf - r0)


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
