"""Road elevation along a timetable's shapes from a DSM (``cevm gtfs --dsm``): the shape's
resampled points looked up in the DSM and smoothed as ingest smooths a trip's
(:func:`cevm.ingest.elevation.trip_elevation`: the same median, low-pass and grade bound),
once per shape."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cevm.core.timetable.geometry import Shape


class ShapeElevation:
    """The :data:`cevm.core.timetable.schedule.Elevation` of a DSM (None: flat)."""

    def __init__(self, dsm: str | Path | None):
        self.sampler = None
        if dsm is not None:
            from cevm.ingest.dsm import DsmSampler

            self.sampler = DsmSampler.open(dsm)

    def close(self) -> None:
        if self.sampler is not None:
            self.sampler.close()

    def __call__(self, key: str, shape: Shape) -> tuple[np.ndarray, np.ndarray, str] | None:
        if self.sampler is None or shape.dist_m.size < 2:
            return None
        from cevm.ingest.elevation import trip_elevation

        res = trip_elevation(shape.dist_m, shape.lon, shape.lat, None, self.sampler)
        z = np.asarray(res.elevation_m, dtype=np.float64)
        if not np.isfinite(z).any():
            return None
        z = np.where(np.isfinite(z), z, np.nanmean(z))
        return shape.dist_m, z, f"DSM ({res.dsm_coverage_pct:.0f} % of the shape covered; {res.source})"
