"""A DSM's rasters by their headers: which files a source names, each tile's grid, CRS,
nodata and scale (:class:`TileHeader`), and the headers sent to workers once
(:class:`DsmHeaders`)."""

from __future__ import annotations

import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

from cevm.errors import InputError
from cevm.text import shorten


@dataclass(frozen=True)
class TileHeader:
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

    tiles: tuple[TileHeader, ...]
    label: str


#: The most memory one internal block of a raster (a tile, or a strip of rows) may take
#: decoded [bytes]: GDAL decodes a whole block to read any pixel of it, so a raster of
#: larger blocks is refused when its header is read, before any pixel is (one 40,000 x
#: 40,000 float32 strip is 6.4 GB decoded, a 16,384-pixel tile 1.07 GB; GeoTIFFs
#: written for reading in windows use 256-1,024 pixel tiles, 0.25-4 MB).
MAX_BLOCK_BYTES = 64 << 20

#: GDAL's own cache of decoded blocks [MB] (``GDAL_CACHEMAX``) in a process that reads a
#: DSM, unless the user set it: its default, 5 % of the machine's memory, would be 1.2 GB
#: on a 24 GB machine, beside :class:`~cevm.ingest.dsm.windows.WindowReader`'s own
#: cache. A DSM lookup then holds at most this plus that cache plus one block
#: (:data:`MAX_BLOCK_BYTES`) of decoded pixels.
GDAL_CACHE_MB = 64


def gdal_cache_bounded() -> None:
    """Bound GDAL's block cache to :data:`GDAL_CACHE_MB` unless ``GDAL_CACHEMAX`` is set
    (before GDAL's first read in this process, which takes it then)."""
    os.environ.setdefault("GDAL_CACHEMAX", str(GDAL_CACHE_MB))


def _check_block_size(ds, shown: str) -> None:
    """Refuse a raster whose internal blocks decode to more than :data:`MAX_BLOCK_BYTES`
    each (all bands of a pixel-interleaved one)."""
    import numpy as np

    bh, bw = ds.block_shapes[0]
    bands = ds.count if str(getattr(ds.interleaving, "value", ds.interleaving)).upper() == "PIXEL" else 1
    nbytes = int(bh) * int(bw) * np.dtype(ds.dtypes[0]).itemsize * bands
    if nbytes > MAX_BLOCK_BYTES:
        kind = "strip" if bw == ds.width else "tile"
        raise InputError(shown, f"its internal blocks ({kind}s of {bw:,} x {bh:,} pixels, {ds.dtypes[0]}) take "
                                f"{nbytes / 1e6:,.0f} MB each decoded, over the {MAX_BLOCK_BYTES >> 20} MB a DSM block "
                                "may take (GDAL decodes a whole block to read one pixel); write it in tiles, e.g. "
                                "gdal_translate -co TILED=YES -co BLOCKXSIZE=512 -co BLOCKYSIZE=512 -co "
                                "COMPRESS=DEFLATE")


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


def _usable_crs(wkt: str, shown: str) -> str:
    """The raster's CRS as :func:`_crs_key_from_wkt` gives it, once PROJ has shown it can
    transform GPS fixes (WGS84) into it; else an :class:`InputError` naming the raster:
    a CRS that PROJ cannot transform to (an engineering CRS without a datum, a
    projection it does not know) or PROJ's own data missing (``proj.db``) make the DSM
    unusable, which is the user's to fix, not a failure of cevm."""
    import pyproj.exceptions

    try:
        key = _crs_key_from_wkt(wkt)
        _transformer("EPSG:4326", key)
    except (pyproj.exceptions.ProjError, pyproj.exceptions.DataDirError) as exc:
        raise InputError(shown, f"unusable DSM: PROJ cannot transform GPS positions (WGS84) into its CRS "
                                f"({shorten(' '.join(wkt.split()), 120)}): {shorten(str(exc))}; reproject it, e.g. "
                                "gdalwarp -t_srs EPSG:3857 (or check PROJ's data: PROJ_DATA)") from None
    return key


def _read_header(name: str, shown: str, driver: str = "") -> TileHeader:
    import rasterio
    from rasterio.errors import RasterioError

    gdal_cache_bounded()
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
            _check_block_size(ds, shown)
            bh, bw = ds.block_shapes[0]
            block = bw if bh == bw and bh < ds.height else 0
            scale = ds.scales[0] if ds.scales and ds.scales[0] is not None else 1.0
            offset = ds.offsets[0] if ds.offsets and ds.offsets[0] is not None else 0.0
            return TileHeader(
                name=name,
                crs_key=_usable_crs(ds.crs.to_wkt(), shown),
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
        raise InputError(shown, f"cannot open as a raster: {shorten(str(exc))}") from None
    except (UnicodeDecodeError, ValueError) as exc:  # GDAL's text of a damaged header (its CRS, its tags)
        raise InputError(shown, f"cannot open as a raster: a damaged header ({shorten(str(exc))})") from None


def _list_sources(source: str | os.PathLike | list[str | os.PathLike] | tuple[str | os.PathLike, ...]) -> list[str]:
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
    refuse_irregular(path, text)
    return [text]


def refuse_irregular(path: Path, shown: str) -> None:
    """Refuse a DSM file that is not a regular file (a FIFO would hang GDAL's opening, a
    device would be read without end), as every other input is
    (:func:`cevm.io.inputs.file_kind`)."""
    from cevm.io.inputs import file_kind

    try:
        kind = file_kind(os.stat(path).st_mode)
    except OSError as exc:
        raise InputError(shown, f"cannot read the DSM: {exc.strerror or exc}") from None
    if kind is not None:
        raise InputError(shown, f"is {kind}, not a DSM (a GeoTIFF, a VRT or a directory of tiles)")
