"""Bilinear DSM heights at points in any CRS (:class:`DsmSampler`)."""

from __future__ import annotations

import os
from collections.abc import Sequence

import numpy as np

from cevm.ingest.dsm.headers import DsmHeaders, TileHeader, _list_sources, _read_header
from cevm.ingest.dsm.tiles import TileIndex
from cevm.ingest.dsm.windows import SamplerStats, WindowReader
from cevm.ingest.dsm_sources import check_local, remote_allowed

WGS84 = "EPSG:4326"


#: Points looked up at a time by :meth:`DsmSampler.sample_xy` (its temporaries take
#: about 150 bytes a point).
POINTS_AT_A_TIME = 1 << 16

#: Datasets a sampler keeps open at most (the least recently used closed first): a DSM
#: of up to this many tiles opens each once per process (an open GeoTIFF costs about
#: 1 ms, and a fleet's trips revisit tiles: with 32, the benchmark fleet's 58 tiles
#: were opened 117 times in all).
MAX_OPEN = 128


def _gdal_env():
    """A rasterio (GDAL) environment to open many rasters in (else each open makes and
    tears down its own)."""
    import rasterio

    return rasterio.Env()


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

    def __init__(self, tiles: Sequence[TileHeader], *, block_px: int | None = None, cache_mb: float = 256.0,
                 max_open: int | None = None, label: str = "DSM"):
        if block_px is not None and not 2 <= block_px < (1 << 20):
            raise ValueError("block_px must be in [2, 2**20)")
        self.label = label
        self.stats = SamplerStats()
        self.index = TileIndex(tiles)
        self.windows = WindowReader(self.index.tiles, block_px=block_px, cache_mb=cache_mb,
                                    max_open=MAX_OPEN if max_open is None else max_open,
                                    stats=self.stats)

    @property
    def tiles(self) -> list[TileHeader]:
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
        self.windows.trim_open()

    # ---- construction ----------------------------------------------------------------

    @classmethod
    def open(cls, source: str | os.PathLike | list[str | os.PathLike] | tuple[str | os.PathLike, ...], *,
             block_px: int | None = None,
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
        with _gdal_env():  # one GDAL environment for all the headers, not one per raster
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




def _bilinear(z: np.ndarray, fx: np.ndarray, fy: np.ndarray) -> np.ndarray:
    """Bilinear interpolation of z = [z00, z01, z10, z11] (row, col offsets) at
    fractional offsets fx (along columns) and fy (along rows) in [0, 1]. Any NaN
    neighbour gives NaN, whatever its weight."""
    top = z[0] + fx * (z[1] - z[0])
    bottom = z[2] + fx * (z[3] - z[2])
    return top + fy * (bottom - top)
