"""The stored form of a trip's profile arrays: one compact BLOB per trip
(:func:`encode_profile`, :func:`decode_profile`), made by ingest's workers
(:func:`trip_profile_blob`) so that the store's single writer does not.

Decoding is bounded before any decompression: a profile's header says how many samples
it holds, and a header above :data:`MAX_STORED_SAMPLES` (or, where the caller knows it,
other than the trip's stored ``n_samples``) is damage, refused before anything is
inflated; each array is then inflated to exactly the size its header gives and no more
(a compressed stream that would grow further is damage too), so a blob whose checksum is
valid but whose content is a zip bomb costs at most the memory of the trip it claims to
be. A vector in the zip format of version 1 (:func:`decode_vector`) is bounded by the
sizes its zip directory declares.
"""

from __future__ import annotations

import io
import json
import struct
import zipfile
import zlib
from collections.abc import Mapping

import numpy as np

from cevm.core.cycle import CycleVector
from cevm.core.trip import Trip
from cevm.errors import CevmError

#: Most samples a stored profile (a trip's, a route's cycle leg's) may decode to: 10
#: million, 116 days at 1 Hz (a trip ends at any stop over 30 minutes; a cycle file holds
#: at most 10 million samples). A trip's profile decodes to about 48 bytes a sample.
MAX_STORED_SAMPLES = 10_000_000

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


def decode_profile(blob: bytes, n_samples: int | None = None) -> dict[str, np.ndarray]:
    """Unpack :func:`encode_profile`'s BLOB into float64 arrays (speed and elevation
    carry the float32 rounding of their storage).

    ``n_samples``: the trip's stored sample count, if known: a header that says another
    is damage. Any header above :data:`MAX_STORED_SAMPLES`, an array's stream that does
    not inflate to exactly its size, raise :class:`CevmError` before more memory is
    taken (see the module notes)."""
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
    check_samples(n, n_samples)
    out: dict[str, np.ndarray] = {}
    for name, dtype, nbytes in header["arrays"]:
        dt = np.dtype(dtype)
        if dt.kind != "f" or dt.itemsize > 8:
            raise CevmError(f"profile array {name!r} of dtype {dtype!r}: not a stored profile's")
        raw = inflate_exactly(blob[pos : pos + int(nbytes)], n * dt.itemsize)
        pos += int(nbytes)
        a = np.frombuffer(raw, np.uint8).reshape(dt.itemsize, n).T.copy().view(dt).reshape(n)
        del raw
        out[name] = a.astype(np.float64)
    return out


def check_samples(n: int, expected: int | None = None) -> None:
    """Refuse (:class:`CevmError`) a stored blob's sample count ``n`` from its header:
    negative, above :data:`MAX_STORED_SAMPLES`, or other than ``expected`` (the trip's
    stored count) when given; before anything is inflated."""
    if n < 0 or n > MAX_STORED_SAMPLES:
        raise CevmError(f"its header says {n:,} samples (at most {MAX_STORED_SAMPLES:,} are stored): not inflated")
    if expected is not None and n != int(expected):
        raise CevmError(f"its header says {n:,} samples, the trip {int(expected):,}: not inflated")


def inflate_exactly(data: bytes, size: int) -> bytes:
    """``data`` (a zlib stream) inflated to exactly ``size`` bytes: never more (a stream
    that would grow past it is refused once ``size`` bytes are out), and refused if it
    ends short (:class:`CevmError`)."""
    d = zlib.decompressobj()
    try:
        out = d.decompress(data, max(size, 1))  # (a max_length of 0 would be no limit)
        more = len(out) > size or bool(d.unconsumed_tail) or (not d.eof and bool(d.decompress(b"", 1)))
    except zlib.error as exc:
        raise CevmError(f"does not inflate: {exc}") from None
    if len(out) != size or more:
        raise CevmError(f"inflates to {'more' if more else len(out)} bytes, not the {size:,} of its header")
    return out


#: Most bytes the arrays of a vector in the zip format of version 1 may declare.
_MAX_NPZ_BYTES = 3 * 8 * MAX_STORED_SAMPLES + (1 << 16)


def decode_vector(blob: bytes) -> CycleVector:
    """A stored vector blob as a :class:`~cevm.core.cycle.CycleVector`. The current
    layout is read as it is (its size is the blob's); one in the zip format of version 1
    only if its zip directory declares at most :data:`_MAX_NPZ_BYTES` of arrays (else
    :class:`CevmError`, before anything is inflated; the zip reader inflates no member
    past its declared size)."""
    blob = bytes(blob)
    if blob[:2] == b"PK":
        try:
            with zipfile.ZipFile(io.BytesIO(blob)) as z:
                declared = sum(i.file_size for i in z.infolist())
        except (zipfile.BadZipFile, ValueError, OSError) as exc:
            raise CevmError(f"not a readable zip: {exc}") from None
        if declared > _MAX_NPZ_BYTES:
            raise CevmError(f"its zip directory declares {declared:,} bytes of arrays (at most "
                            f"{_MAX_NPZ_BYTES:,}): not inflated")
    return CycleVector.from_bytes(blob)
