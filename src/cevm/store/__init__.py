"""The embedded trip store: one SQLite file, no server.

- :mod:`~cevm.store.location`: where the store lives (``--store``, ``$CEVM_STORE``, the
  XDG data directory) and how a source file is keyed;
- :mod:`~cevm.store.codec`: the stored form of a trip's profile arrays;
- :mod:`~cevm.store.schema`: the tables of files, trips, blobs and runs, created or
  checked on open;
- :mod:`~cevm.store.writing`: a source file's trips written in one transaction, failures,
  forgotten files, ingest runs;
- :mod:`~cevm.store.queries`: files, trips, vectors, profiles and runs read back;
- :mod:`~cevm.store.tripstore`: :class:`TripStore`, the connection that composes the three
  (read-write, or read-only for the commands that only read);
- :mod:`~cevm.store.failures`: SQLite's errors as the store's (damaged, could not be
  written) and the damaged trips and routes;
- :mod:`~cevm.store.integrity`: ``cevm store check`` and ``info``;
- :mod:`~cevm.store.display`: listed trips as a person reads them;
- :mod:`~cevm.store.routes`: named routes (sequences of stored trips and cycles);
- :mod:`~cevm.store.masses`: trip masses given by manifests or by hand, and which mass a
  trip is predicted and calibrated at;
- :mod:`~cevm.store.calibration`: a vehicle's stored trips as the calibration's input;
- :mod:`~cevm.store.sources`: stored trips and routes as sweep sources and fleet legs.

Re-exported here: what callers use of location, codec and the store.
"""

from cevm.store.codec import PROFILE_DTYPES, decode_profile, encode_profile, encode_profiles, trip_profile_blob
from cevm.store.location import (
    NO_STORE_HINT,
    STORE_ENV_VAR,
    default_store_path,
    existing_store_path,
    file_key,
    resolve_store_path,
)
from cevm.store.tripstore import SCHEMA_VERSION, FileState, TripStore, WriteResult, format_trips, format_utc

__all__ = [
    "NO_STORE_HINT",
    "PROFILE_DTYPES",
    "SCHEMA_VERSION",
    "STORE_ENV_VAR",
    "FileState",
    "TripStore",
    "WriteResult",
    "decode_profile",
    "default_store_path",
    "encode_profile",
    "encode_profiles",
    "existing_store_path",
    "file_key",
    "format_trips",
    "format_utc",
    "resolve_store_path",
    "trip_profile_blob",
]
