"""Trip masses: what a trip weighed, from a manifest or given by hand, stored with where it
came from (table ``trip_masses``), and which mass a trip is predicted and calibrated at.

Precedence (:meth:`TripMass.gross_kg`), for each trip:

1. a mass given to the trip (:func:`set_masses`: a manifest's row, or by hand), the
   latest given: a gross mass as it is, a payload on the kerb mass (``kerb_mass_kg``) of
   the vehicle file the command is given (a file without one refuses such a trip);
2. else the gross weight the logger recorded for the trip;
3. else the vehicle file's ``mass_kg``.

A given mass that differs from the logged gross weight by more than
:data:`DISAGREEMENT_FRACTION` is reported (:meth:`TripMass.disagreement`); the given one
is used, since the logger's weighing (an axle-load estimate) is the less direct of the two.

A manifest row (:class:`~cevm.io.manifest.ManifestRow`) is matched (:func:`match_manifest`)
by trip id, or by vehicle and time window: the trip of that vehicle whose midpoint (start
plus half its duration) lies in the window. A row that matches no trip, or several, or a
trip another row also gives a different mass, is reported with its file and line and not
applied. Masses are keyed on the trip id with no foreign key: a mass outlives the trip's
re-ingest (a changed log file's trips that keep their vehicle and start keep their mass,
see :mod:`cevm.store.writing`), and comes back with the trip after ``forget``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cevm.errors import CevmError
from cevm.store.schema import in_json
from cevm.store.trips import TripStore

#: A given mass and the logged gross weight of a trip that differ by more than this
#: fraction of the logged one are reported.
DISAGREEMENT_FRACTION = 0.05

#: What ``mass_source`` says for each origin of the mass a prediction used.
MASS_SOURCES = ("manifest", "by hand", "manifest payload", "by hand payload", "logged", "vehicle file",
                "--mass-kg", "--payload-kg")


@dataclass(frozen=True)
class AssignedMass:
    """A mass given to a trip: ``kind`` 'gross' or 'payload', ``mass_kg`` [kg], ``source``
    'manifest' (with ``source_file`` and 1-based ``source_line``) or 'hand', and when it
    was given (``set_utc_s``, s since the Unix epoch)."""

    trip_id: str
    kind: str
    mass_kg: float
    source: str
    source_file: str | None = None
    source_line: int | None = None
    set_utc_s: float = 0.0

    @property
    def origin(self) -> str:
        """'manifest' or 'by hand', and 'payload' after it for a payload."""
        who = "manifest" if self.source == "manifest" else "by hand"
        return who if self.kind == "gross" else f"{who} payload"

    def describe(self) -> str:
        """Where it came from, for a person: ``manifest tms.csv:12`` or ``by hand``."""
        if self.source == "manifest":
            return f"manifest {Path(self.source_file or '?').name}:{self.source_line}"
        return "by hand"


@dataclass(frozen=True)
class TripMass:
    """What the store knows of a trip's mass: the mass given to it (or None) and the
    gross weight its logger recorded (or None)."""

    trip_id: str
    assigned: AssignedMass | None
    logged_gross_kg: float | None

    @property
    def known(self) -> bool:
        """Whether the trip has a mass of its own (given or logged)."""
        return self.assigned is not None or self.logged_gross_kg is not None

    def sweep_key(self) -> tuple[str, float] | None:
        """The mass a prediction set needs for this trip: ('gross', kg), ('payload', kg)
        or None for each vehicle's own mass."""
        if self.assigned is not None:
            return self.assigned.kind, self.assigned.mass_kg
        if self.logged_gross_kg is not None:
            return "gross", self.logged_gross_kg
        return None

    def describe(self) -> str:
        """Where its mass comes from, for a person: ``manifest tms.csv:12``, ``by hand``,
        ``logged``, ``vehicle file``."""
        return self.assigned.describe() if self.assigned is not None else self.origin

    @property
    def origin(self) -> str:
        """The ``mass_source`` of a prediction at this trip's mass (:data:`MASS_SOURCES`)."""
        if self.assigned is not None:
            return self.assigned.origin
        return "logged" if self.logged_gross_kg is not None else "vehicle file"

    def gross_kg(self, vehicle) -> float:
        """The gross mass [kg] to predict or calibrate this trip at with ``vehicle`` (the
        module's precedence); :class:`CevmError` for a payload on a vehicle without a
        kerb mass."""
        a = self.assigned
        if a is not None and a.kind == "payload":
            if vehicle.kerb_mass_kg is None:
                raise CevmError(f"trip {self.trip_id!r} has a payload of {a.mass_kg:,.0f} kg ({a.describe()}), but "
                                f"vehicle {vehicle.name!r} has no kerb_mass_kg to add it to: add kerb_mass_kg to the "
                                "vehicle file, or give the trip a gross mass")
            return float(vehicle.kerb_mass_kg) + a.mass_kg
        if a is not None:
            return a.mass_kg
        if self.logged_gross_kg is not None:
            return self.logged_gross_kg
        return float(vehicle.mass_kg)

    def disagreement(self, vehicle=None) -> str | None:
        """A sentence when the given mass and the logged gross weight differ by more than
        :data:`DISAGREEMENT_FRACTION` (a payload is compared on ``vehicle``'s kerb mass,
        and not at all without one), else None."""
        a, logged = self.assigned, self.logged_gross_kg
        if a is None or logged is None:
            return None
        if a.kind == "payload":
            if vehicle is None or vehicle.kerb_mass_kg is None:
                return None
            given = float(vehicle.kerb_mass_kg) + a.mass_kg
            what = f"a payload of {a.mass_kg:,.0f} kg on the {vehicle.kerb_mass_kg:,.0f} kg kerb mass"
        else:
            given, what = a.mass_kg, f"{a.mass_kg:,.0f} kg"
        rel = (given - logged) / logged
        if abs(rel) <= DISAGREEMENT_FRACTION:
            return None
        return (f"trip {self.trip_id!r}: {a.describe()} gives {what}, its logger {logged:,.0f} kg "
                f"({100 * rel:+.1f} %); the {'manifest' if a.source == 'manifest' else 'given'} mass is used")


# ---------------------------------------------------------------------------- reading


def _logged(x) -> float | None:
    return None if x is None or not math.isfinite(x) or x <= 0 else float(x)


def assigned_masses(store: TripStore, trip_ids: Sequence[str] | None = None) -> dict[str, AssignedMass]:
    """The masses given to trips: all, or those of ``trip_ids`` (ids without one are
    left out)."""
    sql = "SELECT trip_id, kind, mass_kg, source, source_file, source_line, set_utc_s FROM trip_masses"
    args: tuple = ()
    if trip_ids is not None:
        sql += " WHERE trip_id IN (SELECT value FROM json_each(?))"
        args = (in_json(trip_ids),)
    return {r[0]: AssignedMass(*r) for r in store.con.execute(sql, args)}


def trip_masses(store: TripStore, trips) -> dict[str, TripMass]:
    """:class:`TripMass` of each trip of ``trips`` (a :meth:`TripStore.list_trips` frame),
    by trip id."""
    ids = list(trips["trip_id"])
    given = assigned_masses(store, ids)
    return {tid: TripMass(tid, given.get(tid), _logged(gw)) for tid, gw in zip(ids, trips["gross_weight_kg"])}


# ---------------------------------------------------------------------------- writing


def set_masses(store: TripStore, masses: Sequence[AssignedMass]) -> tuple[int, int]:
    """Give each trip its mass, replacing any it had, in one transaction; returns
    (new, replaced). Every trip must be stored (:class:`CevmError` otherwise)."""
    ids = [m.trip_id for m in masses]
    if not ids:
        return 0, 0
    store.list_trips(trip_ids=ids)  # unknown ids raise
    now = time.time()
    with store._write() as con:
        (had,) = con.execute("SELECT COUNT(*) FROM trip_masses WHERE trip_id IN (SELECT value FROM json_each(?))",
                             (in_json(ids),)).fetchone()
        con.executemany(
            "INSERT INTO trip_masses (trip_id, kind, mass_kg, source, source_file, source_line, set_utc_s) "
            "VALUES (?, ?, ?, ?, ?, ?, ?) ON CONFLICT (trip_id) DO UPDATE SET kind = excluded.kind, "
            "mass_kg = excluded.mass_kg, source = excluded.source, source_file = excluded.source_file, "
            "source_line = excluded.source_line, set_utc_s = excluded.set_utc_s",
            [(m.trip_id, m.kind, float(m.mass_kg), m.source, m.source_file, m.source_line, m.set_utc_s or now)
             for m in masses])
    return len(set(ids)) - int(had), int(had)


def clear_masses(store: TripStore, trip_ids: Sequence[str]) -> int:
    """Forget the masses given to ``trip_ids`` (they fall back to the logged gross weight,
    else the vehicle file's mass); returns how many there were."""
    with store._write() as con:
        return con.execute("DELETE FROM trip_masses WHERE trip_id IN (SELECT value FROM json_each(?))",
                           (in_json(trip_ids),)).rowcount


# ------------------------------------------------------------------------ manifests


@dataclass(frozen=True)
class ManifestMatch:
    """A manifest against the store: the masses to give (``masses``), the rows not applied
    (``problems``: (line, why)), and the trips whose manifest mass and logged gross weight
    disagree (``disagreements``, sentences)."""

    path: str
    masses: tuple[AssignedMass, ...]
    problems: tuple[tuple[int, str], ...]
    disagreements: tuple[str, ...]


def match_manifest(store: TripStore, manifest) -> ManifestMatch:
    """Match the rows of ``manifest`` (:class:`cevm.io.manifest.Manifest`) to stored trips
    (see the module notes); its rows' own problems are passed on."""
    df = store.list_trips()
    by_id = {tid: i for i, tid in enumerate(df["trip_id"])}
    vehicles = df["vehicle_id"].to_numpy()
    mid = (df["start_utc_s"] + 0.5 * df["duration_s"]).to_numpy(dtype=np.float64)
    problems = list(manifest.problems)
    hits: dict[str, list] = {}
    for row in manifest.rows:
        if row.trip_id is not None:
            i = by_id.get(row.trip_id)
            if i is None:
                problems.append((row.line, f"trip {row.trip_id!r} is not in the store"))
                continue
            if row.vehicle_id is not None and row.vehicle_id != vehicles[i]:
                problems.append((row.line, f"trip {row.trip_id!r} is a trip of {vehicles[i]!r}, not of "
                                           f"{row.vehicle_id!r}"))
                continue
        else:
            mine = vehicles == row.vehicle_id
            if not mine.any():
                problems.append((row.line, f"no stored trips of vehicle {row.vehicle_id!r}"))
                continue
            inside = np.flatnonzero(mine & (mid >= row.start_utc_s) & (mid <= row.end_utc_s))
            if inside.size != 1:
                span = f"{_utc(row.start_utc_s)} to {_utc(row.end_utc_s)}"
                if inside.size == 0:
                    problems.append((row.line, f"no stored trip of {row.vehicle_id!r} has its midpoint in {span}"))
                else:
                    ids = ", ".join(repr(df["trip_id"].iloc[j]) for j in inside[:4]) + (" ..." if inside.size > 4
                                                                                        else "")
                    problems.append((row.line, f"{inside.size} stored trips of {row.vehicle_id!r} have their "
                                               f"midpoint in {span} ({ids}): give trip ids, or one window each"))
                continue
            i = int(inside[0])
        hits.setdefault(df["trip_id"].iloc[i], []).append(row)
    masses, disagreements = [], []
    for tid, rows in hits.items():
        if len({(r.kind, r.mass_kg) for r in rows}) > 1:
            lines = ", ".join(str(r.line) for r in rows)
            for r in rows:
                problems.append((r.line, f"trip {tid!r} is given different masses by lines {lines}: none applied"))
            continue
        r = rows[-1]
        mass = AssignedMass(tid, r.kind, r.mass_kg, "manifest", manifest.path, r.line)
        masses.append(mass)
        text = TripMass(tid, mass, _logged(df["gross_weight_kg"].iloc[by_id[tid]])).disagreement()
        if text:
            disagreements.append(f"line {r.line}: {text}")
    return ManifestMatch(manifest.path, tuple(masses), tuple(sorted(problems)), tuple(disagreements))


def _utc(t_s: float) -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(t_s))
