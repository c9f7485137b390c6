"""The DSM's pixels read block by block from its tiles (:class:`WindowReader`), within a
cache of blocks (:class:`BlockPool`) and a bound on open datasets."""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from cevm.ingest.dsm.headers import TileHeader, gdal_cache_bounded
from cevm.ingest.dsm.tiles import _unique_inverse


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


class BlockPool:
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
    share one array (:class:`BlockPool`), so a gather fetches its pixels with one fancy
    index whatever the number of blocks. At most ``max_open`` datasets stay open.
    """

    def __init__(self, tiles: Sequence[TileHeader], *, block_px: int | None, cache_mb: float, max_open: int,
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
        self._pools: list[BlockPool] = []
        self._pool_index: dict[tuple[int, int, str], int] = {}
        self._open: OrderedDict[int, Any] = OrderedDict()  # rasterio datasets (untyped library)
        self.failed: dict[int, str] = {}  # tile -> why it cannot be read
        self._blk = np.array([block_px or (t.block if 128 <= t.block <= 1024 else 512) for t in self.tiles],
                             dtype=np.int64)
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

    def trim_open(self) -> None:
        """Close the least recently used datasets beyond :attr:`max_open`."""
        while len(self._open) > self.max_open:
            _, old = self._open.popitem(last=False)
            old.close()

    def _dataset(self, tile: int):
        ds = self._open.get(tile)
        if ds is not None:
            self._open.move_to_end(tile)
            return ds
        import rasterio

        gdal_cache_bounded()  # in a worker too, which has only the headers
        ds = rasterio.open(self.tiles[tile].name, driver=self.tiles[tile].driver or None)
        self._open[tile] = ds
        self.trim_open()
        return ds

    def _read_block(self, tile: int, brow: int, bcol: int) -> np.ndarray:
        """Pixels of block (brow, bcol) of a tile plus a one-pixel margin right and
        below, as float (float32 for float32 rasters) with NaN for nodata and for
        infinite values (no height, and no arithmetic warnings downstream). A tile that
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
        if np.isinf(arr).any():  # an infinite height is no height: no data, as a nodata pixel
            arr[np.isinf(arr)] = np.nan
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
            self._pools.append(BlockPool(shape, arr.dtype, self.cache_bytes // slot_bytes + 1))
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
            flat = (slot_of[ii] * pool.size + (row[sel] - brow[sel] * blk[sel]) * stride
                    + (col[sel] - bcol[sel] * blk[sel]))
            data = pool.data.reshape(-1)
            if quad:
                out[0, sel] = data[flat]
                out[1, sel] = data[flat + 1]
                out[2, sel] = data[flat + stride]
                out[3, sel] = data[flat + stride + 1]
            else:
                out[sel] = data[flat]

def _nodata_mask(raw: np.ndarray, nodata: float) -> np.ndarray:
    """Pixels equal to ``nodata`` compared in the raster's own dtype (as GDAL does)."""
    if np.issubdtype(raw.dtype, np.floating):
        return raw == raw.dtype.type(nodata)
    info = np.iinfo(raw.dtype)
    if nodata != math.floor(nodata) or not info.min <= nodata <= info.max:
        return np.zeros(raw.shape, dtype=bool)
    return raw == int(nodata)
