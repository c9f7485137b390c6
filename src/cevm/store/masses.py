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
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from cevm.errors import CevmError
from cevm.store.schema import in_json
from cevm.store.tripstore import TripStore

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
    return {tid: TripMass(tid, given.get(tid), _logged(gw))
            for tid, gw in zip(ids, trips["gross_weight_kg"], strict=True)}


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
    (``problems``: (line, why), sorted by line, unless they were passed on as found; their
    count ``n_problems``), and the trips whose manifest mass and logged gross weight
    disagree (``disagreements``, sentences)."""

    path: str
    masses: tuple[AssignedMass, ...]
    problems: tuple[tuple[int, str], ...]
    disagreements: tuple[str, ...]
    n_problems: int = 0  #: rows not applied (also those passed to ``on_problem`` rather than kept)


def match_manifest(store: TripStore, manifest,
                   on_problem: Callable[[int, str], None] | None = None) -> ManifestMatch:
    """Match the rows of ``manifest`` (a :class:`cevm.io.manifest.Manifest`, or a
    :class:`~cevm.io.manifest.ManifestReader` streaming one) to stored trips (see the
    module notes); its rows' own problems are passed on.

    ``on_problem(line, why)``: called for each row not applied, as it is found (a row's
    own problem or no trip, in the file's order; rows that contradict each other once all
    are read), instead of collecting them in :attr:`ManifestMatch.problems`: then only
    the rows matched are held (memory grows with the trips, not with the manifest)."""
    df = _trip_times(store)
    trip_ids = df["trip_id"].to_numpy()
    by_id = {tid: i for i, tid in enumerate(trip_ids)}
    vehicles = df["vehicle_id"].to_numpy()
    mid = (df["start_utc_s"] + 0.5 * df["duration_s"]).to_numpy(dtype=np.float64)
    # each vehicle's trips by midpoint: a window's trips by binary search, not a scan of all trips per row
    order = np.lexsort((mid, vehicles))
    mid_sorted = mid[order]
    first: dict[str, list[int]] = {}
    for k, v in enumerate(vehicles[order]):
        first.setdefault(v, [k, k])[1] = k + 1
    kept: list[tuple[int, str]] = []
    n_problems = 0

    def problem(line: int, why: str) -> None:
        nonlocal n_problems
        n_problems += 1
        if on_problem is None:
            kept.append((line, why))
        else:
            on_problem(line, why)

    hits: dict[str, tuple[set, list[int], Any]] = {}  # trip: (its masses, their lines, the last row)
    for row in manifest.items():
        if isinstance(row, tuple):
            problem(*row)
            continue
        if row.trip_id is not None:
            i = by_id.get(row.trip_id)
            if i is None:
                problem(row.line, f"trip {row.trip_id!r} is not in the store")
                continue
            if row.vehicle_id is not None and row.vehicle_id != vehicles[i]:
                problem(row.line, f"trip {row.trip_id!r} is a trip of {vehicles[i]!r}, not of {row.vehicle_id!r}")
                continue
        else:
            span = first.get(row.vehicle_id)
            if span is None:
                problem(row.line, f"no stored trips of vehicle {row.vehicle_id!r}")
                continue
            m = mid_sorted[span[0]:span[1]]  # the vehicle's midpoints, sorted (a view)
            inside = order[span[0] + np.searchsorted(m, row.start_utc_s, side="left"):
                           span[0] + np.searchsorted(m, row.end_utc_s, side="right")]
            if inside.size != 1:
                when = f"{_utc(row.start_utc_s)} to {_utc(row.end_utc_s)}"
                if inside.size == 0:
                    problem(row.line, f"no stored trip of {row.vehicle_id!r} has its midpoint in {when}")
                else:
                    ids = ", ".join(repr(trip_ids[j]) for j in inside[:4]) + (" ..." if inside.size > 4 else "")
                    problem(row.line, f"{inside.size} stored trips of {row.vehicle_id!r} have their midpoint in "
                                      f"{when} ({ids}): give trip ids, or one window each")
                continue
            i = int(inside[0])
        values, lines, _ = hits.get(trip_ids[i]) or (set(), [], None)
        values.add((row.kind, row.mass_kg))
        lines.append(row.line)
        hits[trip_ids[i]] = (values, lines, row)
    masses, disagreements = [], []
    for tid, (values, lines, r) in hits.items():
        if len(values) > 1:
            said = ", ".join(map(str, lines))
            for line in lines:
                problem(line, f"trip {tid!r} is given different masses by lines {said}: none applied")
            continue
        mass = AssignedMass(tid, r.kind, r.mass_kg, "manifest", manifest.path, r.line)
        masses.append(mass)
        text = TripMass(tid, mass, _logged(df["gross_weight_kg"].iloc[by_id[tid]])).disagreement()
        if text:
            disagreements.append(f"line {r.line}: {text}")
    return ManifestMatch(manifest.path, tuple(masses), tuple(sorted(kept)), tuple(disagreements), n_problems)


def _trip_times(store: TripStore):
    """The columns of the stored trips that matching needs (id, vehicle, start, duration,
    logged gross weight), without their quality and evidence columns."""
    import pandas as pd

    rows = store.con.execute("SELECT trip_id, vehicle_id, start_utc_s, duration_s, gross_weight_kg FROM trips "
                             "ORDER BY vehicle_id, start_utc_s, trip_id").fetchall()
    df = pd.DataFrame.from_records(rows, columns=["trip_id", "vehicle_id", "start_utc_s", "duration_s",
                                                  "gross_weight_kg"])
    for c in ("start_utc_s", "duration_s", "gross_weight_kg"):
        df[c] = df[c].astype(np.float64)
    return df


def _utc(t_s: float) -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(t_s))
