"""The stored form of a trip's profile arrays: one compact BLOB per trip
(:func:`encode_profile`, :func:`decode_profile`), made by ingest's workers
(:func:`trip_profile_blob`) so that the store's single writer does not; and a route's
cycle leg (:func:`encode_cycle_profile`, :func:`decode_cycle_profile`).

Decoding is bounded before any decompression: a profile's header says how many samples
it holds, and a header above :data:`MAX_PROFILE_SAMPLES` (or, where the caller knows it,
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
from functools import lru_cache

import numpy as np

from cevm.core.cycle import CycleVector, DriveCycle
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


_PROFILE_MAGIC = b"CEVMPRF2"
_PROFILE_CODEC = "delta+shuffle+zstd"
_ZSTD_LEVEL = 1

# Format 1 (read, no longer written): every array byte-shuffled and zlib-compressed.
_PROFILE_MAGIC_V1 = b"CEVMPRF1"
_PROFILE_CODEC_V1 = "shuffle+zlib"

#: The most samples a stored profile (a trip's, a route's cycle leg's) may hold: checked
#: from its header before anything is decompressed, so that a damaged (or forged) header
#: cannot make a reader allocate gigabytes (a trip of 10 million 1-s samples lasts 16
#: weeks; a cycle file holds at most 10 million samples). A trip's profile decodes to
#: about 48 bytes a sample.
MAX_PROFILE_SAMPLES = 10_000_000


@lru_cache(maxsize=1)
def _zstd():
    """pyarrow's zstd codec (pyarrow is imported by pandas anyway)."""
    import pyarrow as pa

    return pa.Codec("zstd", compression_level=_ZSTD_LEVEL)


def encode_profile(arrays: Mapping[str, np.ndarray]) -> bytes:
    """Pack a trip's profile arrays into one compact BLOB (lossless but for the
    float32 rounding of speed and elevation).

    ``arrays`` must hold every key of :data:`PROFILE_DTYPES` with one common length.
    Each array is cast to its storage dtype (float64 for time, distance, latitude,
    longitude; float32 for speed and elevation, where values beyond +-3.4e38 become
    +-inf); the integers of its bit patterns are differenced (wrapping: exactly
    reversible, whatever the values, NaN included), which turns the slowly changing
    values of a trip into small numbers, and their bytes shuffled (all first bytes, then
    all second bytes, ...), then zstd-compressed at level 1 (pyarrow's codec). Layout:
    ``b"CEVMPRF2"``, a little-endian uint32 header length, a UTF-8 JSON header ``{"n",
    "codec", "arrays": [[name, dtype, nbytes], ...]}``, then the compressed arrays in
    header order. Measured on the sample and Twizy trips against format 1 (shuffle and
    zlib level 1): 14.1 bytes a sample instead of 18.0, in 225 ns instead of 380-445 ns.
    """
    n = int(np.asarray(arrays["time_s"]).shape[0]) if "time_s" in arrays else 0
    return encode_profiles(arrays, np.array([0, n]))[0]


def encode_profiles(arrays: Mapping[str, np.ndarray], bounds: np.ndarray) -> list[bytes]:
    """:func:`encode_profile` of several trips whose arrays lie end to end in
    ``arrays`` (trip ``i``: ``bounds[i]:bounds[i + 1]``), bit for bit: each array is
    cast and its bit patterns differenced once for all the trips (each trip's first
    difference is from 0, as its own), then each trip's bytes shuffled and
    compressed."""
    missing = [k for k in PROFILE_DTYPES if k not in arrays]
    if missing:
        raise ValueError(f"profile lacks arrays {missing}")
    bounds = np.asarray(bounds, dtype=np.int64)
    total = int(bounds[-1])
    zstd = _zstd()
    starts = bounds[:-1][np.diff(bounds) > 0]
    deltas = []
    for name, dtype in PROFILE_DTYPES.items():
        with np.errstate(over="ignore"):  # beyond float32's range is +-inf, as it should
            a = np.ascontiguousarray(arrays[name], dtype=dtype)
        if a.shape != (total,):
            raise ValueError(f"profile array {name} has shape {a.shape}, expected ({total},)")
        bits = a.view(np.uint64 if a.itemsize == 8 else np.uint32)
        delta = np.empty_like(bits)
        np.subtract(bits[1:], bits[:-1], out=delta[1:])  # unsigned: wraps, exactly reversible
        delta[starts] = bits[starts]  # each trip's first from 0
        deltas.append((name, dtype, a.itemsize, delta))
    out = []
    for a, b in zip(bounds[:-1].tolist(), bounds[1:].tolist(), strict=True):
        n = b - a
        entries, payloads = [], []
        for name, dtype, size, delta in deltas:
            shuffled = delta[a:b].view(np.uint8).reshape(n, size).T.tobytes()
            payload = zstd.compress(shuffled, asbytes=True)
            entries.append([name, dtype, len(payload)])
            payloads.append(payload)
        header = json.dumps({"n": n, "codec": _PROFILE_CODEC, "arrays": entries}).encode()
        out.append(b"".join([_PROFILE_MAGIC, struct.pack("<I", len(header)), header, *payloads]))
    return out


def trip_profile_blob(trip: Trip) -> bytes:
    """A trip's profile BLOB as the store keeps it (:func:`encode_profile` of its
    arrays); made by ingest's workers so that the single writer does not."""
    return encode_profile({name: getattr(trip, name) for name in PROFILE_DTYPES})


def decode_profile(blob: bytes, n_samples: int | None = None) -> dict[str, np.ndarray]:
    """Unpack :func:`encode_profile`'s BLOB (or one of format 1) into float64 arrays
    (speed and elevation carry the float32 rounding of their storage).

    ``n_samples``: the trip's stored sample count, if known: a header that says another
    is damage. Any header above :data:`MAX_PROFILE_SAMPLES`, an array's stream that does
    not decompress to exactly its size, raise :class:`CevmError` before more memory is
    taken (see the module notes)."""
    blob = bytes(blob)
    magic = blob[: len(_PROFILE_MAGIC)]
    if magic not in (_PROFILE_MAGIC, _PROFILE_MAGIC_V1):
        raise CevmError("corrupt profile in the store (bad magic); re-ingest the file")
    pos = len(_PROFILE_MAGIC)
    (hlen,) = struct.unpack_from("<I", blob, pos)
    pos += 4
    header = json.loads(blob[pos : pos + hlen])
    pos += hlen
    codec = header.get("codec")
    if (magic, codec) not in ((_PROFILE_MAGIC, _PROFILE_CODEC), (_PROFILE_MAGIC_V1, _PROFILE_CODEC_V1)):
        raise CevmError(f"profile codec {codec!r} unknown to this cevm")
    n = int(header["n"])
    check_samples(n, n_samples)
    out: dict[str, np.ndarray] = {}
    for name, dtype, nbytes in header["arrays"]:
        dt = np.dtype(dtype)
        if dt.kind != "f" or dt.itemsize not in (4, 8):
            raise CevmError(f"profile array {name!r} of dtype {dtype!r}: not a stored profile's")
        data, size = blob[pos : pos + int(nbytes)], n * dt.itemsize
        pos += int(nbytes)
        if magic == _PROFILE_MAGIC_V1:
            raw = inflate_exactly(data, size)
            a = np.frombuffer(raw, np.uint8).reshape(dt.itemsize, n).T.copy().view(dt).reshape(n)
        else:
            raw = _unzstd_exactly(data, size)
            delta = np.frombuffer(raw, np.uint8).reshape(dt.itemsize, n).T.copy().view(
                np.uint64 if dt.itemsize == 8 else np.uint32).reshape(n)
            a = np.cumsum(delta, dtype=delta.dtype).view(dt)
        del raw
        out[name] = a.astype(np.float64)
    return out


#: The stored form of a route's cycle leg (:mod:`cevm.store.routes`): time, speed and
#: elevation as given, not a logged trip's profile.
_CYCLE_PROFILE_MAGIC = b"CEVMRTP1"


def encode_cycle_profile(cycle: DriveCycle) -> bytes:
    """Lossless BLOB of a cycle's time [s], speed [m/s] and elevation [m]: ``b"CEVMRTP1"``,
    a little-endian uint32 sample count and uint32 flag (1: with elevation), then the
    zlib-compressed (level 6) float64 arrays one after another. A flat cycle stores no
    elevation. Raw arrays rather than an npz: decoding is a ``frombuffer``."""
    t = np.ascontiguousarray(cycle.time_s, dtype="<f8")
    parts = [t, np.ascontiguousarray(cycle.speed_mps, dtype="<f8")]
    if cycle.elevation_m is not None:
        parts.append(np.ascontiguousarray(cycle.elevation_m, dtype="<f8"))
    head = struct.pack("<II", t.size, int(cycle.elevation_m is not None))
    return _CYCLE_PROFILE_MAGIC + head + zlib.compress(b"".join(a.tobytes() for a in parts), 6)


def decode_cycle_profile(blob: bytes) -> dict[str, np.ndarray]:
    """Inverse of :func:`encode_cycle_profile`, as a profile dict (keys of
    :data:`cevm.store.PROFILE_DTYPES`): distance is the trapezoidal cumulative distance
    [m], elevation zeros for a flat cycle, latitude and longitude NaN."""
    blob = bytes(blob)
    if not blob.startswith(_CYCLE_PROFILE_MAGIC):
        raise CevmError("corrupt cycle profile in a route (bad magic); re-create the route")
    n, has_h = struct.unpack_from("<II", blob, len(_CYCLE_PROFILE_MAGIC))
    check_samples(n)  # before inflating: a bomb's header is refused
    if has_h not in (0, 1):
        raise CevmError("corrupt cycle profile in a route (bad flag); re-create the route")
    body = blob[len(_CYCLE_PROFILE_MAGIC) + 8 :]
    raw = np.frombuffer(inflate_exactly(body, 8 * n * (3 if has_h else 2)), dtype="<f8")
    t = raw[:n].astype(np.float64)
    v = raw[n : 2 * n].astype(np.float64)
    h = raw[2 * n :].astype(np.float64) if has_h else np.zeros(n)
    dist = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))])
    nan = np.broadcast_to(np.float64(np.nan), (n,))  # read-only, no memory: a cycle has no positions
    return {"time_s": t, "speed_mps": v, "distance_m": dist, "elevation_m": h, "lat_deg": nan, "lon_deg": nan}


def check_samples(n: int, expected: int | None = None) -> None:
    """Refuse (:class:`CevmError`) a stored blob's sample count ``n`` from its header:
    negative, above :data:`MAX_PROFILE_SAMPLES`, or other than ``expected`` (the trip's
    stored count) when given; before anything is inflated."""
    if n < 0 or n > MAX_PROFILE_SAMPLES:
        raise CevmError(f"its header says {n:,} samples (at most {MAX_PROFILE_SAMPLES:,} are stored): not inflated")
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


def _unzstd_exactly(data: bytes, size: int) -> bytes:
    """``data`` (a zstd frame) decompressed into exactly ``size`` bytes (pyarrow allocates
    that much and no more, and fails on a frame of another size: :class:`CevmError`)."""
    try:
        return _zstd().decompress(data, decompressed_size=size, asbytes=True)
    except (OSError, ValueError) as exc:
        raise CevmError(f"does not decompress to the {size:,} bytes of its header: {exc}") from None


#: Most bytes the arrays of a vector in the zip format of version 1 may declare.
_MAX_NPZ_BYTES = 3 * 8 * MAX_PROFILE_SAMPLES + (1 << 16)


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
