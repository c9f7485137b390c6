"""Constants and the seeded random streams every part of the generator shares."""

from __future__ import annotations

import zlib

import numpy as np

DEFAULT_SEED = 7
G_MPS2 = 9.81
RHO_AIR_KG_M3 = 1.225
#: Geoid undulation near Milton Keynes [m]: GPS reports heights above the WGS84
#: ellipsoid, about 47 m above mean sea level there (OSGM15).
GEOID_UNDULATION_M = 47.0
#: Origin of the terrain phases (BNG, m): keeps the cosine arguments small.
WORLD_ORIGIN_EN = (485000.0, 238000.0)
BNG = "EPSG:27700"
WGS84 = "EPSG:4326"


def seeded_rng(seed: int, *keys: object) -> np.random.Generator:
    """An independent, reproducible generator for ``(seed, *keys)`` (strings hashed with
    CRC-32, never Python's salted ``hash``)."""
    ints = [int(seed)] + [k if isinstance(k, int) else zlib.crc32(str(k).encode()) for k in keys]
    return np.random.default_rng(np.random.SeedSequence(ints))

