"""The stored form of a trip's profile arrays: one compact BLOB per trip
(:func:`encode_profile`, :func:`decode_profile`), made by ingest's workers
(:func:`trip_profile_blob`) so that the store's single writer does not."""

from __future__ import annotations

import json
import struct
import zlib
from collections.abc import Mapping

import numpy as np

from cevm.core.trip import Trip
from cevm.errors import CevmError

# Profile arrays and the dtype each is stored with. Degrees need float64 (float32 steps
# are ~1e-6 deg = 0.1 m at 45 deg, and worse in the sums of a cumulated track), time and
# cumulative distance need float64 (float32 at 1e5 s or 1e6 m steps by 8 ms or 6 cm, a
# large error on a 0.1 s or 1 m step); speed and elevation are fine as float32 (relative
# step 6e-8: 1e-6 m/s at 20 m/s, 0.5 mm at 8848 m).
PROFILE_DTYPES: dict[str, str] = {
    "time_s": "<f8",
    "speed_mps": "<f4",
    "distance_m": "<f8",
    "elevation_m": "<f4",
    "lat_deg": "<f8",
    "lon_deg": "<f8",
}


_PROFILE_MAGIC = b"CEVMPRF1"


_PROFILE_CODEC = "shuffle+zlib"


# zlib level 1: on 1 Hz trips the byte-shuffled arrays compress to ~0.3 of raw at every
# level, and level 1 runs at ~4 million samples/s (level 6: ~3, np.savez_compressed:
# ~0.6, too slow for the ingest's budget of 1 million samples/s for everything).
_PROFILE_ZLIB_LEVEL = 1


def encode_profile(arrays: Mapping[str, np.ndarray]) -> bytes:
    """Pack a trip's profile arrays into one compact BLOB (lossless but for the
    float32 rounding of speed and elevation).

    ``arrays`` must hold every key of :data:`PROFILE_DTYPES` with one common length.
    Each array is cast to its storage dtype (float64 for time, distance, latitude,
    longitude; float32 for speed and elevation, where values beyond +-3.4e38 become
    +-inf), its bytes are shuffled (all first
    bytes, then all second bytes, ..., which groups the slowly varying exponent bytes)
    and zlib-compressed at level 1. Layout: ``b"CEVMPRF1"``, a little-endian uint32
    header length, a UTF-8 JSON header ``{"n", "codec", "arrays": [[name, dtype,
    nbytes], ...]}``, then the compressed arrays in header order.
    """
    missing = [k for k in PROFILE_DTYPES if k not in arrays]
    if missing:
        raise ValueError(f"profile lacks arrays {missing}")
    n = int(np.asarray(arrays["time_s"]).shape[0])
    entries, payloads = [], []
    for name, dtype in PROFILE_DTYPES.items():
        with np.errstate(over="ignore"):  # beyond float32's range is +-inf, as it should
            a = np.ascontiguousarray(arrays[name], dtype=dtype)
        if a.shape != (n,):
            raise ValueError(f"profile array {name} has shape {a.shape}, expected ({n},)")
        shuffled = a.view(np.uint8).reshape(n, a.itemsize).T.tobytes()
        payload = zlib.compress(shuffled, _PROFILE_ZLIB_LEVEL)
        entries.append([name, dtype, len(payload)])
        payloads.append(payload)
    header = json.dumps({"n": n, "codec": _PROFILE_CODEC, "arrays": entries}).encode()
    return b"".join([_PROFILE_MAGIC, struct.pack("<I", len(header)), header, *payloads])


def trip_profile_blob(trip: Trip) -> bytes:
    """A trip's profile BLOB as the store keeps it (:func:`encode_profile` of its
    arrays); made by ingest's workers so that the single writer does not."""
    return encode_profile({name: getattr(trip, name) for name in PROFILE_DTYPES})


def decode_profile(blob: bytes) -> dict[str, np.ndarray]:
    """Unpack :func:`encode_profile`'s BLOB into float64 arrays (speed and elevation
    carry the float32 rounding of their storage)."""
    blob = bytes(blob)
    if blob[: len(_PROFILE_MAGIC)] != _PROFILE_MAGIC:
        raise CevmError("corrupt profile in the store (bad magic); re-ingest the file")
    pos = len(_PROFILE_MAGIC)
    (hlen,) = struct.unpack_from("<I", blob, pos)
    pos += 4
    header = json.loads(blob[pos : pos + hlen])
    pos += hlen
    if header.get("codec") != _PROFILE_CODEC:
        raise CevmError(f"profile codec {header.get('codec')!r} unknown to this cevm")
    n = int(header["n"])
    out: dict[str, np.ndarray] = {}
    for name, dtype, nbytes in header["arrays"]:
        dt = np.dtype(dtype)
        raw = zlib.decompress(blob[pos : pos + nbytes])
        pos += nbytes
        a = np.frombuffer(raw, np.uint8).reshape(dt.itemsize, n).T.copy().view(dt).reshape(n)
        out[name] = a.astype(np.float64)
    return out
