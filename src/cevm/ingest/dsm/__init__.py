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

A package of those parts: :mod:`.headers`, :mod:`.tiles`, :mod:`.windows`,
:mod:`.sampler`.

Turning the samples into a road profile is :mod:`cevm.ingest.elevation`.
"""

from cevm.ingest.dsm.headers import DsmHeaders, TileHeader
from cevm.ingest.dsm.sampler import WGS84, DsmSampler
from cevm.ingest.dsm.tiles import TileIndex
from cevm.ingest.dsm.windows import SamplerStats, WindowReader

__all__ = ["WGS84", "DsmHeaders", "DsmSampler", "SamplerStats", "TileHeader", "TileIndex", "WindowReader"]
