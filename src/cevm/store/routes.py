"""Named routes in the trip store: a bus block or a delivery round as a sequence of legs.

A route is an ordered list of legs; each leg is a stored trip (by trip id) or a drive
cycle. A route's CE vector is the sum of its legs' vectors (vectors of consecutive pieces
add), and its profile is the legs' profiles one after another (no step joins two legs).

Storage (tables of the trip store's schema, :mod:`cevm.store.schema`, since version 3;
before, they were made on first use under ``meta`` key ``routes_schema_version``)::

    routes      name (primary key), created_utc_s, n_legs, note
    route_legs  (route, position) primary key, kind ('trip' | 'cycle'), ref (trip id, or
                the cycle file's resolved path when added), label (trip id or file
                stem), sha256 (of the cycle file), vector, profile (BLOBs, cycle legs)
                and their CRC-32s, checked whenever they are read

Cycle legs keep their own copy of the cycle: the CE vector (computed in float64 when the
route is added, with the Cr0 given) and the profile (time, speed and elevation in
float64, lossless), so a route does not depend on the file staying where it was, or
staying the same. Trip legs refer to the trip by id only (no foreign key: re-ingesting a
changed log file replaces its trips, which a foreign key would forbid); a route whose
trip has gone is reported when loaded, with the way out (re-create the route). A route
is stored only from sound legs: a trip leg whose vector or profile is damaged is refused
(:class:`~cevm.store.failures.DamagedTripError`), never referred to.
"""

from __future__ import annotations

import fnmatch
import hashlib
import json
import re
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cevm.core.cycle import CR0_DEFAULT, CycleVector, DriveCycle, cycle_vector
from cevm.errors import CevmError, InputError
from cevm.store import TripStore
from cevm.store.codec import decode_cycle_profile, decode_vector, encode_cycle_profile
from cevm.store.failures import DamagedRouteError
from cevm.store.schema import blob_crc32

_NAME_RE = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,99}\Z")

# ------------------------------------------------------------------------ leg inputs


@dataclass(frozen=True)
class TripLeg:
    """A leg that is a stored trip."""

    trip_id: str


@dataclass(frozen=True, eq=False)
class CycleLeg:
    """A leg that is a drive cycle (read from ``ref``, a file path, by the caller)."""

    cycle: DriveCycle
    ref: str
    sha256: str | None = None

    @classmethod
    def from_file(cls, path: str | Path, fmt=None) -> CycleLeg:
        """Read a cycle file's one cycle (:func:`cevm.io.read_cycle_csv`) and hash its bytes."""
        (leg,) = cls.all_from_file(path, fmt, one=True)
        return leg

    @classmethod
    def all_from_file(cls, path: str | Path, fmt=None, *, one: bool = False,
                      max_samples: int | None = None) -> list[CycleLeg]:
        """The legs of a cycle file, one per cycle it holds (:func:`cevm.io.cycles.read_cycles`
        with the :class:`~cevm.io.cycles.CycleFormat` ``fmt``, at most ``max_samples``
        samples; ``one``: exactly one), each with the file's hash."""
        from cevm.io.cycles import read_cycle_csv, read_cycles  # here: the cycle reader only when a route is added

        cycles = [read_cycle_csv(path, fmt)] if one else read_cycles(path, fmt, max_samples=max_samples)
        p = Path(path)
        ref, sha = str(p.expanduser().resolve()), _sha256(p)
        return [cls(cycle=cyc, ref=ref, sha256=sha) for cyc in cycles]


LegInput = TripLeg | CycleLeg


def _sha256(path: Path) -> str:
    """The SHA-256 of a file's bytes, read 1 MiB at a time (a cycle file is read whole
    into arrays already: its bytes need not be held too)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


@dataclass(frozen=True)
class RouteLegInfo:
    """One stored leg: position (0-based), kind, ref (trip id or cycle path), label."""

    position: int
    kind: str
    ref: str
    label: str


@dataclass(frozen=True)
class RouteInfo:
    """A stored route: name, when it was added [s since the epoch, UTC], legs, note."""

    name: str
    created_utc_s: float
    legs: tuple[RouteLegInfo, ...]
    note: str | None = None


@dataclass(frozen=True, eq=False)
class StoredLeg:
    """A leg as loaded: its info, CE vector, and profile (arrays keyed as
    :data:`cevm.store.PROFILE_DTYPES`; a cycle leg has NaN latitude and longitude)."""

    info: RouteLegInfo
    vector: CycleVector
    profile: dict[str, np.ndarray]


# --------------------------------------------------------------------------- helpers


def check_route_name(name: str) -> str:
    """Return ``name`` if valid, else raise :class:`~cevm.errors.InputError`: 1 to 100
    characters, letters, digits, ``.``, ``_`` and ``-``, starting with a letter or
    digit (no glob characters, so ``--route 'block-*'`` can select routes)."""
    if not isinstance(name, str) or not _NAME_RE.match(name):
        raise InputError("route name", f"{name!r} is not a valid route name: use 1-100 letters, digits, '.', '_' "
                                       "or '-', starting with a letter or digit")
    return name


def _checked_blob(route: str, part: str, blob: bytes, crc: int | None) -> bytes:
    """A cycle leg's ``blob`` if it matches its checksum, else :class:`DamagedRouteError`
    (also for a missing blob or checksum: every cycle leg is stored with both)."""
    if blob is None:
        raise DamagedRouteError(route, part, "missing")
    if crc is None:
        raise DamagedRouteError(route, part, "its checksum is missing (NULL)")
    blob = bytes(blob)
    if blob_crc32(blob) != crc:
        raise DamagedRouteError(route, part, "checksum mismatch")
    return blob


# ---------------------------------------------------------------------------- writing


def add_route(
    store: TripStore,
    name: str,
    legs: Sequence[LegInput],
    *,
    replace: bool = False,
    cr0: float = CR0_DEFAULT,
    note: str | None = None,
) -> RouteInfo:
    """Store the route ``name`` as ``legs`` in order, in one transaction.

    Trip legs must be stored trips (unknown ids raise :class:`CevmError`); cycle legs
    are stored with their vector (computed with ``cr0``, default 0.004 as at ingest) and
    lossless profile. All legs' vectors must share Cr0 and physics (they are summed).
    An existing route of that name is an error unless ``replace`` (default False).
    """
    check_route_name(name)
    if not legs:
        raise CevmError(f"route {name!r}: give at least one leg (--trip or --cycle)")
    _check_route_samples(store, name, legs)
    trip_ids = [leg.trip_id for leg in legs if isinstance(leg, TripLeg)]
    vectors: dict[str, CycleVector] = {}
    if trip_ids:
        vectors = store.load_cycle_vectors(trip_ids=trip_ids)  # a damaged one raises
        damaged = store.damaged_profiles(trip_ids)
        if damaged:
            raise damaged[0]
    rows: list[tuple] = []
    total: CycleVector | None = None
    for pos, leg in enumerate(legs):
        if isinstance(leg, TripLeg):
            vec = vectors[leg.trip_id]
            rows.append((name, pos, "trip", leg.trip_id, leg.trip_id, None, None, None, None, None))
        elif isinstance(leg, CycleLeg):
            vec = cycle_vector(leg.cycle, cr0=cr0)
            label = leg.cycle.name or Path(leg.ref).stem
            vblob, pblob = vec.to_bytes(), encode_cycle_profile(leg.cycle)
            rows.append((name, pos, "cycle", leg.ref, label, leg.sha256, vblob, pblob, blob_crc32(vblob),
                         blob_crc32(pblob)))
        else:
            raise TypeError(f"a leg is a TripLeg or a CycleLeg, not {type(leg).__name__}")
        try:
            total = vec if total is None else total + vec
        except ValueError as exc:
            raise CevmError(f"route {name!r}: leg {pos + 1} cannot follow the others: {exc} "
                            f"(trips were ingested with another --cr0?)") from None
    with store._write() as con:
        exists = con.execute("SELECT 1 FROM routes WHERE name = ?", (name,)).fetchone() is not None
        if exists and not replace:
            raise CevmError(f"route {name!r} already exists; add --replace to overwrite it, "
                            f"or 'cevm route remove {name}'")
        if exists:
            con.execute("DELETE FROM route_legs WHERE route = ?", (name,))
            con.execute("DELETE FROM routes WHERE name = ?", (name,))
        created = time.time()
        con.execute("INSERT INTO routes (name, created_utc_s, n_legs, note) VALUES (?, ?, ?, ?)",
                    (name, created, len(rows), note))
        con.executemany("INSERT INTO route_legs (route, position, kind, ref, label, sha256, vector, profile, "
                        "vector_crc32, profile_crc32) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?)", rows)
    return RouteInfo(name, created, tuple(RouteLegInfo(r[1], r[2], r[3], r[4]) for r in rows), note)


#: Most samples a route may hold over its legs (trips' and cycles'): it is predicted as one
#: source, so it is bounded as one cycle file is (:data:`cevm.io.cycles.MAX_CYCLE_SAMPLES`:
#: at twice that, ``predict --route`` of two vehicles with ``--range`` peaked at 515 MB).
MAX_ROUTE_SAMPLES = 1_000_000


def _check_route_samples(store: TripStore, name: str, legs: Sequence[LegInput]) -> None:
    """Refuse (:class:`CevmError`) a route of more than :data:`MAX_ROUTE_SAMPLES` samples."""
    trip_ids = [leg.trip_id for leg in legs if isinstance(leg, TripLeg)]
    n_trip = dict(store.con.execute("SELECT trip_id, n_samples FROM trips WHERE trip_id IN (SELECT value FROM "
                                    "json_each(?))", (json.dumps(trip_ids),)).fetchall()) if trip_ids else {}
    total = sum(int(n_trip.get(leg.trip_id, 0)) if isinstance(leg, TripLeg) else leg.cycle.time_s.size
                for leg in legs)
    if total > MAX_ROUTE_SAMPLES:
        raise CevmError(f"route {name!r}: its legs hold {total:,} samples, more than the {MAX_ROUTE_SAMPLES:,} a route "
                        "may hold (its profiles are read together when it is predicted): split it into routes")


def remove_route(store: TripStore, name: str) -> bool:
    """Delete the route ``name`` (one transaction); False if there was none."""
    with store._write() as con:
        con.execute("DELETE FROM route_legs WHERE route = ?", (name,))
        n = con.execute("DELETE FROM routes WHERE name = ?", (name,)).rowcount
    return n > 0


# ---------------------------------------------------------------------------- reading


def list_routes(store: TripStore) -> list[RouteInfo]:
    """All stored routes, by name."""
    legs: dict[str, list[RouteLegInfo]] = {}
    for route, pos, kind, ref, label in store.con.execute(
        "SELECT route, position, kind, ref, label FROM route_legs ORDER BY route, position"
    ):
        legs.setdefault(route, []).append(RouteLegInfo(int(pos), kind, ref, label))
    return [RouteInfo(name, float(created), tuple(legs.get(name, ())), note)
            for name, created, note in store.con.execute("SELECT name, created_utc_s, note FROM routes ORDER BY name")]


def route_names(store: TripStore, pattern: str | None = None) -> list[str]:
    """Names of the stored routes, sorted; only those matching the glob ``pattern``
    (``fnmatch``, case-sensitive) if given."""
    names = [r[0] for r in store.con.execute("SELECT name FROM routes ORDER BY name")]
    return names if pattern is None else [n for n in names if fnmatch.fnmatchcase(n, pattern)]


def resolve_route_patterns(store: TripStore, patterns: Sequence[str]) -> list[str]:
    """Route names for ``--route`` values: exact names, or glob patterns (``*?[``) that
    must match at least one route. Order of the patterns, duplicates dropped. Unknown
    names raise :class:`CevmError` listing what is stored."""
    names = route_names(store)
    known = set(names)
    out: dict[str, None] = {}
    for pat in patterns:
        if any(c in pat for c in "*?["):
            hits = [n for n in names if fnmatch.fnmatchcase(n, pat)]
            if not hits:
                raise CevmError(f"no stored route matches {pat!r}; {_routes_hint(names, store)}")
            out.update(dict.fromkeys(hits))
        elif pat in known:
            out[pat] = None
        else:
            raise CevmError(f"unknown route {pat!r}; {_routes_hint(names, store)}")
    return list(out)


def _routes_hint(names: list[str], store: TripStore) -> str:
    if not names:
        return f"the store {store.path} holds no routes ('cevm route add' creates one)"
    shown = ", ".join(names[:10]) + (", ..." if len(names) > 10 else "")
    return f"the store {store.path} holds {len(names)} route(s): {shown} ('cevm route list')"


def _leg_rows(store: TripStore, name: str, columns: str) -> list[tuple]:
    """Rows (position, kind, ref, label, *columns) of route ``name``'s legs, checked:
    unknown routes and trips no longer stored raise :class:`CevmError`."""
    rows = store.con.execute(
        f"SELECT position, kind, ref, label{columns} FROM route_legs WHERE route = ? ORDER BY position", (name,)
    ).fetchall()
    if not rows:
        raise CevmError(f"unknown route {name!r}; {_routes_hint(route_names(store), store)}")
    trip_ids = [r[2] for r in rows if r[1] == "trip"]
    if trip_ids:
        present = {r[0] for r in store.con.execute(
            "SELECT trip_id FROM trips WHERE trip_id IN (SELECT value FROM json_each(?))", (json.dumps(trip_ids),))}
        for pos, kind, ref, *_ in rows:
            if kind == "trip" and ref not in present:
                raise CevmError(
                    f"route {name!r}: leg {pos + 1} is trip {ref!r}, which is no longer in the store (its log file "
                    f"was re-ingested with new content, or forgotten); re-create the route with "
                    f"'cevm route add {name} --replace ...'")
    return rows


def load_route_legs(store: TripStore, name: str, *, profiles: bool = True) -> list[StoredLeg]:
    """The legs of route ``name`` with vectors and (if ``profiles``, default True)
    profiles; an empty dict as profile otherwise. Raises :class:`CevmError` for an
    unknown route or a trip that is no longer stored, :class:`DamagedRouteError` or
    :class:`~cevm.store.failures.DamagedTripError` for a leg whose blobs are damaged."""
    out = []
    columns = ", vector, vector_crc32, profile, profile_crc32" if profiles else ", vector, vector_crc32, NULL, NULL"
    for pos, kind, ref, label, vblob, vcrc, pblob, pcrc in _leg_rows(store, name, columns):
        info = RouteLegInfo(int(pos), kind, ref, label)
        if kind == "trip":
            vec = store.load_cycle_vectors(trip_ids=[ref])[ref]
            prof = store.load_profile(ref) if profiles else {}
        else:
            vec = _decoded(name, "vector", decode_vector, _checked_blob(name, "vector", vblob, vcrc))
            prof = _cycle_profile(name, pblob, pcrc) if profiles else {}
        out.append(StoredLeg(info, vec, prof))
    return out


def _decoded(route: str, part: str, decode, blob: bytes):
    try:
        return decode(blob)
    except Exception as exc:  # whatever a damaged blob makes the decoder raise
        raise DamagedRouteError(route, part, f"does not decode: {exc}") from None


def _cycle_profile(route: str, blob: bytes, crc: int | None) -> dict[str, np.ndarray]:
    return _decoded(route, "profile", decode_cycle_profile, _checked_blob(route, "profile", blob, crc))


def check_route_profiles(store: TripStore, name: str) -> None:
    """Raise :class:`DamagedRouteError` (or :class:`~cevm.store.failures.DamagedTripError`)
    if a profile of route ``name``'s legs fails its checksum; reads the blobs one at a
    time and keeps none (for a reader that will load them later and must not fail
    half-way)."""
    rows = _leg_rows(store, name, ", profile_crc32 IS NULL, crc32(profile) IS NOT profile_crc32")
    for _, kind, _, _, no_crc, bad in rows:
        if kind == "cycle" and (no_crc or bad):
            why = "its checksum is missing (NULL)" if no_crc else "checksum mismatch"
            raise DamagedRouteError(name, "profile", why)
    trip_ids = [ref for _, kind, ref, *_ in rows if kind == "trip"]
    for exc in store.damaged_profiles(trip_ids) if trip_ids else []:
        raise exc


def load_route_vector(store: TripStore, name: str) -> CycleVector:
    """The CE vector of route ``name``: the sum of its legs' vectors."""
    legs = load_route_legs(store, name, profiles=False)
    total = legs[0].vector
    for leg in legs[1:]:
        total = total + leg.vector
    return total


def load_route_profiles(store: TripStore, name: str) -> list[dict[str, np.ndarray]]:
    """The profiles of route ``name``'s legs, in order (one dict per leg, keys of
    :data:`cevm.store.PROFILE_DTYPES`, float64; trip legs as stored, so speed and
    elevation carry float32 rounding; cycle legs lossless). Reads no vectors."""
    return [store.load_profile(ref) if kind == "trip" else _cycle_profile(name, pblob, pcrc)
            for _, kind, ref, _, pblob, pcrc in _leg_rows(store, name, ", profile, profile_crc32")]
