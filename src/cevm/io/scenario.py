"""Fleet scenario files (TOML) for the assignment of :mod:`cevm.core.assignment`.

:func:`load_scenario` reads and checks every key of a scenario file, loads its vehicle
files and resolves each leg's source to a CE vector with a *leg resolver*:
:func:`default_resolver` reads cycle files; :func:`cevm.store.sources.store_resolver`
also reads stored trips and routes. :func:`fleet_report` is everything
``cevm fleet plan`` shows.

**Files a scenario names are never quoted.** A scenario may name any file on the machine
as a vehicle file or a leg's cycle (or grade) file, and whoever runs ``cevm fleet plan``
on it may be able to read files its author cannot (a service, an operator's account). So
an error of such a file says which file, which key of the scenario and at which line,
and whether it could be opened (missing, unreadable, not a regular file, too large:
:class:`~cevm.errors.FileAccessError`), but never what the file holds: a cycle reader's
message quotes the header it found, a vehicle file's the key it did not know (the
``/etc/shadow`` named as a leg had its first line printed). Each such error says how to
see the details on a file one may read (``cevm predict -c FILE``, ``cevm vehicle show
FILE``). Like a VRT's sources (:mod:`cevm.ingest.dsm_sources`), the files are local
regular files only: a FIFO, a device or a directory is refused before it is read.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from cevm.core import energy
from cevm.core.assignment import (
    EV_RESERVE_FRACTION_DEFAULT,
    LEG_KINDS,
    MASS_MODELS,
    OBJECTIVES,
    SOC_START_DEFAULT,
    FleetVehicle,
    Leg,
    LegSource,
    Prices,
    Route,
    Scenario,
    calibration_warnings,
    plan,
    quote_key,
    table4_rows,
)
from cevm.core.assignment.verdict import LegDemand, reference_differences, vehicle_verdicts, verdict_warnings
from cevm.core.cycle import CycleVector, drive_cycle_vector
from cevm.core.predictive import posterior_of
from cevm.core.vehicle import Vehicle
from cevm.errors import FileAccessError, InputError
from cevm.io.cycles import CycleFormat, read_cycle_csv
from cevm.io.inputs import open_regular
from cevm.io.priors import prior_values_note
from cevm.io.toml import read_toml
from cevm.io.vehicles import load_vehicle

#: A leg resolver: (one copy of a leg source, directory of the scenario file) -> vector.
LegResolver = Callable[[LegSource, Path], CycleVector]

#: Most copies of one leg (``repeat``): a day's work of a one-minute shuttle hop. The
#: cost of a repeat does not grow with it (the vector is scaled, not concatenated).
MAX_LEG_REPEAT = 1000


def default_resolver(source: LegSource, base_dir: Path) -> CycleVector:
    """Resolve one copy of a leg source to its CE vector: cycle files only.

    ``cycle`` sources are read with :func:`cevm.io.read_cycle_csv` (path relative to
    ``base_dir``, with the source's reading options: :class:`cevm.io.cycles.CycleFormat`
    keys, a relative ``grade_file`` also relative to ``base_dir``) and turned into a
    vector with the default Cr0. ``trip`` and ``route``
    sources need the trip store: this resolver raises :class:`InputError` for them; pass
    a resolver that knows the store to :func:`load_scenario`.
    """
    if source.kind == "cycle":
        path = Path(source.ref)
        if not path.is_absolute():
            path = base_dir / path
        fmt = CycleFormat.from_mapping(dict(source.options), path, base_dir) if source.options else None
        for named in (path, *((fmt.grade_file,) if fmt is not None and fmt.grade_file is not None else ())):
            open_regular(named, "cycle file").close()  # local regular files only, refused before they are read
        cyc = read_cycle_csv(path, fmt)
        return drive_cycle_vector(cyc.time_s, cyc.speed_mps, cyc.elevation_m, validate=False)
    raise InputError(
        None, f"leg source {source.kind} = {source.ref!r} needs the trip store; this resolver reads cycle files only"
    )


def unquoted(exc: InputError, scenario: Path, where: str, what: str, how: str) -> InputError:
    """The error ``exc`` of a file the ``scenario`` names (at key ``where``), without a word
    of the file's content (see the module notes): a :class:`FileAccessError` as it is (it
    quotes nothing), any other as the file, its line and ``what`` it should be, and
    ``how`` to see what is wrong on a file one may read."""
    if isinstance(exc, FileAccessError) or exc.path is None or Path(exc.path) == scenario:
        return InputError(exc.path, f"{exc.message} (named by {where} of {scenario})", line=exc.line,
                          column=exc.column) if isinstance(exc, FileAccessError) else exc
    return InputError(exc.path, f"not a usable {what} (named by {where} of {scenario}; what is wrong is not shown, "
                                f"since a file a scenario names may be anyone's: {how} says it)", line=exc.line)


def _read_toml(path: Path) -> dict:
    return read_toml(path, "scenario file")


_TOP_KEYS = {
    "name", "description", "objective", "mass_model", "return_to_depot", "ev_reserve_fraction",
    "days", "ambient_c", "prices", "depot", "vehicle", "route", "stop", "payload_kg", "notes", "reference",
}
_VEHICLE_KEYS = {"id", "file", "max_gross_kg", "ev_reserve_fraction", "soc_start", "notes"}
_ROUTE_KEYS = {"id", "vehicle", "depot", "stops", "leg", "legs", "return_to_depot", "notes"}
_STOP_KEYS = {"vehicles", "default", "notes"}
_PRICE_KEYS = {"fuel_per_l", "electricity_per_kwh", "currency"}
_LEG_KEYS = set(LEG_KINDS) | {"repeat"} | set(CycleFormat.KEYS)


def _check_keys(src: Path, where: str, table: Any, allowed: set[str]) -> dict:
    if not isinstance(table, dict):
        raise InputError(src, f"{where} must be a table")
    for key in table:
        if key not in allowed:
            close = difflib.get_close_matches(key, sorted(allowed), n=1)
            hint = f" (did you mean '{close[0]}'?)" if close else ""
            raise InputError(src, f"{where}: unknown key '{key}'{hint}")
    return table


def _str(src: Path, where: str, value: Any) -> str:
    if not isinstance(value, str) or not value.strip():
        raise InputError(src, f"{where} must be a non-empty string, got {value!r}")
    return value


def _num(src: Path, where: str, value: Any, lo: float | None = None, hi: float | None = None) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InputError(src, f"{where} must be a finite number, got {value!r}")
    if (lo is not None and value < lo) or (hi is not None and value > hi):
        rng = f"[{lo if lo is not None else '-inf'}, {hi if hi is not None else 'inf'}]"
        raise InputError(src, f"{where} = {value:g} must be in {rng}")
    return float(value)


def _leg_source(src: Path, where: str, table: Any) -> LegSource:
    table = _check_keys(src, where, table, _LEG_KEYS)
    kinds = [k for k in LEG_KINDS if k in table]
    if len(kinds) != 1:
        raise InputError(src, f"{where} needs exactly one of {', '.join(LEG_KINDS)}; got {kinds or 'none'}")
    repeat = table.get("repeat", 1)
    if isinstance(repeat, bool) or not isinstance(repeat, int) or not 1 <= repeat <= MAX_LEG_REPEAT:
        raise InputError(src, f"{where}.repeat must be an integer from 1 to {MAX_LEG_REPEAT:,}, got {repeat!r}")
    options = tuple(sorted((k, tuple(v) if isinstance(v, list) else v) for k, v in table.items()
                           if k in CycleFormat.KEYS))
    if options and kinds[0] != "cycle":
        raise InputError(src, f"{where}: {', '.join(k for k, _ in options)} only apply to cycle files")
    if options:  # checked now, so that a mistake names the leg
        CycleFormat.from_mapping(dict(options), f"{src}: {where}", src.parent)
    return LegSource(kinds[0], _str(src, f"{where}.{kinds[0]}", table[kinds[0]]), repeat, options)


def load_scenario(path: str | Path, resolve_leg: LegResolver = default_resolver) -> Scenario:
    """Read and validate a fleet scenario file (TOML) and compute its leg vectors.

    Format (paths relative to the scenario file; masses in kg)::

        name = "..."
        objective = "fuel"         # "fuel" [l] (ICE fleet), "energy" [J] (EV fleet) or
                                   # "cost" (needs [prices]); default by fleet
        mass_model = "carried"     # or "paper-eq32" (module docstring)
        return_to_depot = true     # default for every route (figure 8: depot -> back)
        ev_reserve_fraction = 0.15 # default for every EV
        days = ["day 1", "day 2"]
        ambient_c = [4.0, 18.5]    # optional: each day's ambient temperature [degC] (or one
                                   # value for all days); default each vehicle's reference

        [prices]                   # only for objective = "cost"
        fuel_per_l = 1.50
        electricity_per_kwh = 0.25
        currency = "GBP"

        [[depot]]                  # optional; routes name theirs with depot = "..."
        id = "depot"

        [[vehicle]]
        id = "HGV1"
        file = "../vehicles/diesel-hgv.toml"   # needs kerb_mass_kg
        max_gross_kg = 44000       # optional, overrides the vehicle file's
        ev_reserve_fraction = 0.15 # EV, optional; soc_start = 1.0 likewise

        [[route]]
        id = "LH1"
        vehicle = "HGV1"
        stops = ["LH1S1/R1S2", "LH1S2"]        # in driving order
        leg = { cycle = "../cycles/long-haul-standin.csv" }   # every leg; or
        # legs = [{ cycle = "a.csv" }, { cycle = "b.csv", repeat = 3 }, ...]
        #   one per hop, n_stops + 1 with the return to the depot
        # a leg source is one of cycle = "file", trip = "ID", route = "NAME"
        # (trip and route need a resolver that knows the store); repeat: 1 to 1,000
        # a cycle leg may say how its file is read (cevm.io.cycles.CycleFormat), e.g.
        # { cycle = "vecto/driving_cycles_truck.csv", speed_column = "Long haul, 26t",
        #   speed_unit = "km/h", grade_file = "vecto/gradient_truck.csv",
        #   grade_unit = "fraction" }; keys: sep, decimal, time_column, time_step_s,
        #   speed_column, speed_unit, elevation_column, grade_column, grade_unit, grade_file

        [stop."LH1S1/R1S2"]        # optional, per stop
        vehicles = ["HGV1", "HGV3"] # who may serve it (default: every route through it)
        default = "HGV1"            # the default assignment's vehicle

        [payload_kg]               # per stop: one value per day (or one for all days)
        "LH1S1/R1S2" = [5000, 3000, 8000]

    A stop listed on several routes is shared. Every key is checked; a mistake raises
    :class:`~cevm.errors.InputError` naming the file and the key.
    """
    t0 = time.perf_counter()
    path = Path(path)
    data = _read_toml(path)
    _check_keys(path, "scenario", data, _TOP_KEYS)
    head = _header(path, data)
    prices = _prices(path, data)
    depots = _depots(path, data)
    vehicles = _fleet_vehicles(path, data, head.reserve_default)
    routes = _routes(path, data, depots, head.return_default, _LegVectors(path, resolve_leg))
    allowed, default_vehicle = _stops(path, data)
    payload = _payloads(path, data, len(head.days))
    return Scenario(
        name=head.name,
        vehicles=tuple(vehicles),
        routes=tuple(routes),
        days=tuple(head.days),
        payload_kg=payload,
        allowed=allowed,
        default_vehicle=default_vehicle,
        objective=head.objective,
        prices=prices,
        mass_model=head.mass_model,
        path=str(path),
        load_time_s=time.perf_counter() - t0,
        ambient_c=head.ambient,
    )


@dataclasses.dataclass(frozen=True)
class _Header:
    """A scenario file's top-level settings."""

    name: str
    objective: str | None
    mass_model: str
    return_default: bool
    reserve_default: float
    days: list[str]
    ambient: tuple[float | None, ...]


def _header(path: Path, data: dict) -> _Header:
    """The top-level keys: name, objective, mass model, the routes' and EVs' defaults,
    the days and their temperatures."""
    name = _str(path, "name", data.get("name", path.stem))
    objective = data.get("objective")
    if objective is not None and objective not in OBJECTIVES:
        raise InputError(path, f"objective must be one of {', '.join(OBJECTIVES)}; got {objective!r}")
    mass_model = data.get("mass_model", "carried")
    if mass_model not in MASS_MODELS:
        raise InputError(path, f"mass_model must be one of {', '.join(MASS_MODELS)}; got {mass_model!r}")
    ret_default = data.get("return_to_depot", True)
    if not isinstance(ret_default, bool):
        raise InputError(path, f"return_to_depot must be true or false, got {ret_default!r}")
    reserve_default = _num(path, "ev_reserve_fraction", data.get("ev_reserve_fraction", EV_RESERVE_FRACTION_DEFAULT),
                           0.0, 1.0)
    days = data.get("days")
    if not isinstance(days, list) or not days or not all(isinstance(d, str) and d for d in days):
        raise InputError(path, "days must be a non-empty list of day names, e.g. days = [\"day 1\"]")
    if len(set(days)) != len(days):
        raise InputError(path, "days: duplicate day name")
    ambient = _day_temperatures(path, data.get("ambient_c"), len(days))
    return _Header(name=name, objective=objective, mass_model=mass_model, return_default=ret_default,
                   reserve_default=reserve_default, days=days, ambient=ambient)


def _prices(path: Path, data: dict) -> Prices | None:
    """``[prices]``, or None without one."""
    if "prices" not in data:
        return None
    p = _check_keys(path, "prices", data["prices"], _PRICE_KEYS)
    return Prices(
        fuel_per_l=_num(path, "prices.fuel_per_l", p["fuel_per_l"], 0.0) if "fuel_per_l" in p else None,
        electricity_per_kwh=(
            _num(path, "prices.electricity_per_kwh", p["electricity_per_kwh"], 0.0)
            if "electricity_per_kwh" in p
            else None
        ),
        currency=_str(path, "prices.currency", p.get("currency", "cost")),
    )


def _depots(path: Path, data: dict) -> list[str]:
    """The ids of the ``[[depot]]`` tables, in file order."""
    depots = []
    for i, d in enumerate(_array_of_tables(path, data, "depot")):
        d = _check_keys(path, f"depot[{i}]", d, {"id", "name", "notes"})
        depots.append(_str(path, f"depot[{i}].id", d.get("id", d.get("name"))))
    return depots


def _fleet_vehicles(path: Path, data: dict, reserve_default: float) -> list[FleetVehicle]:
    """The ``[[vehicle]]`` tables, each vehicle file loaded once."""
    vehicles = []
    vehicle_cache: dict[Path, Vehicle] = {}
    for i, v in enumerate(_array_of_tables(path, data, "vehicle")):
        where = f"vehicle[{i}]"
        v = _check_keys(path, where, v, _VEHICLE_KEYS)
        vid = _str(path, f"{where}.id", v.get("id"))
        vfile = path.parent / _str(path, f"{where}.file", v.get("file"))
        if vfile not in vehicle_cache:
            try:
                vehicle_cache[vfile] = load_vehicle(vfile)
            except InputError as exc:
                raise unquoted(exc, path, f"{where}.file", "vehicle file", f"cevm vehicle show {vfile}") from None
        veh = vehicle_cache[vfile]
        maxg = v.get("max_gross_kg", veh.max_gross_kg)
        vehicles.append(
            FleetVehicle(
                id=vid,
                vehicle=veh,
                max_gross_kg=None if maxg is None else _num(path, f"{where}.max_gross_kg", maxg, 0.0),
                ev_reserve_fraction=_num(path, f"{where}.ev_reserve_fraction",
                                         v.get("ev_reserve_fraction", reserve_default), 0.0, 1.0),
                soc_start=_num(path, f"{where}.soc_start", v.get("soc_start", SOC_START_DEFAULT), 0.0, 1.0),
            )
        )
    return vehicles


class _LegVectors:
    """Legs from their sources: each source resolved once (repeats of it scaled from
    one copy), a resolver's error without a file named after the scenario's key."""

    def __init__(self, path: Path, resolve_leg: LegResolver):
        self.path = path
        self.resolve_leg = resolve_leg
        self.vectors: dict[tuple, CycleVector] = {}
        self.repeated: dict[LegSource, CycleVector] = {}

    def leg(self, source: LegSource, where: str) -> Leg:
        key = (source.kind, source.ref, source.options)
        if key not in self.vectors:
            try:
                self.vectors[key] = self.resolve_leg(dataclasses.replace(source, repeat=1), self.path.parent)
            except InputError as exc:
                if exc.path is None:
                    raise InputError(self.path, f"{where}: {exc.message}") from None
                if source.kind == "cycle":  # a file the scenario names: never quoted
                    raise unquoted(exc, self.path, where, "cycle file",
                                   "cevm predict -v VEHICLE -c FILE with the leg's reading options") from None
                raise
        if source not in self.repeated:
            self.repeated[source] = self.vectors[key].repeated(source.repeat)
        return Leg(vector=self.repeated[source], source=source)


def _routes(path: Path, data: dict, depots: list[str], ret_default: bool, legs: _LegVectors) -> list[Route]:
    """The ``[[route]]`` tables, their legs resolved."""
    return [_route(path, i, r, depots, ret_default, legs) for i, r in enumerate(_array_of_tables(path, data, "route"))]


def _route(path: Path, i: int, r: Any, depots: list[str], ret_default: bool, vectors: _LegVectors) -> Route:
    where = f"route[{i}]"
    r = _check_keys(path, where, r, _ROUTE_KEYS)
    rid = _str(path, f"{where}.id", r.get("id"))
    where = f"route {rid!r}"
    stops = r.get("stops")
    if not isinstance(stops, list) or not stops or not all(isinstance(s, str) and s for s in stops):
        raise InputError(path, f"{where}.stops must be a non-empty list of stop names")
    ret = r.get("return_to_depot", ret_default)
    if not isinstance(ret, bool):
        raise InputError(path, f"{where}.return_to_depot must be true or false")
    depot = r.get("depot", depots[0] if depots else "depot")
    if depots and depot not in depots:
        raise InputError(path, f"{where}.depot: unknown depot {depot!r}; depots: {', '.join(depots)}")
    n_legs = len(stops) + (1 if ret else 0)
    if ("leg" in r) == ("legs" in r):
        raise InputError(path, f"{where} needs either leg = {{...}} (every leg) or legs = [...] ({n_legs} legs)")
    if "leg" in r:
        leg = vectors.leg(_leg_source(path, f"{where}.leg", r["leg"]), f"{where}.leg")
        legs = (leg,) * n_legs
    else:
        if not isinstance(r["legs"], list) or len(r["legs"]) != n_legs:
            raise InputError(
                path,
                f"{where}.legs must list {n_legs} legs ({len(stops)} stops"
                f"{' + the return to the depot' if ret else ''})",
            )
        legs = tuple(vectors.leg(_leg_source(path, f"{where}.legs[{j}]", t), f"{where}.legs[{j}]")
                     for j, t in enumerate(r["legs"]))
    return Route(id=rid, vehicle_id=_str(path, f"{where}.vehicle", r.get("vehicle")), stops=tuple(stops), legs=legs,
                 depot=depot, return_to_depot=ret)


def _stops(path: Path, data: dict) -> tuple[dict[str, tuple[str, ...]], dict[str, str]]:
    """The ``[stop."NAME"]`` tables: who may serve each stop, and its default vehicle."""
    allowed: dict[str, tuple[str, ...]] = {}
    default_vehicle: dict[str, str] = {}
    stop_tables = data.get("stop", {})
    if not isinstance(stop_tables, dict):
        raise InputError(path, "stop must be a table of tables: [stop.\"NAME\"]")
    for s, t in stop_tables.items():
        where = f"stop.{quote_key(s)}"
        t = _check_keys(path, where, t, _STOP_KEYS)
        if "vehicles" in t:
            vs = t["vehicles"]
            if not isinstance(vs, list) or not vs or not all(isinstance(x, str) for x in vs):
                raise InputError(path, f"{where}.vehicles must be a non-empty list of vehicle ids")
            allowed[s] = tuple(vs)
        if "default" in t:
            default_vehicle[s] = _str(path, f"{where}.default", t["default"])
    return allowed, default_vehicle


def _payloads(path: Path, data: dict, n_days: int) -> dict[str, tuple[float, ...]]:
    """``[payload_kg]``: per stop, one payload [kg] per day (one value: every day)."""
    payload_tab = data.get("payload_kg")
    if not isinstance(payload_tab, dict):
        raise InputError(path, "missing table [payload_kg] (payload per stop, one value per day)")
    payload: dict[str, tuple[float, ...]] = {}
    for s, vals in payload_tab.items():
        where = f"payload_kg.{quote_key(s)}"
        if isinstance(vals, list):
            payload[s] = tuple(_num(path, f"{where}[{j}]", x, 0.0) for j, x in enumerate(vals))
        else:
            payload[s] = (_num(path, where, vals, 0.0),) * n_days
    return payload


def _day_temperatures(path: Path, value, n_days: int) -> tuple[float | None, ...]:
    """``ambient_c`` of a scenario: one temperature [degC] per day, or one for all."""
    if value is None:
        return ()
    lo, hi = energy.AMBIENT_RANGE_C
    vals = value if isinstance(value, list) else [value] * n_days
    if len(vals) != n_days:
        raise InputError(path, f"ambient_c has {len(vals)} values for {n_days} days")
    return tuple(_num(path, f"ambient_c[{j}]", x, lo, hi) for j, x in enumerate(vals))


def _array_of_tables(src: Path, data: dict, key: str) -> list:
    val = data.get(key, [])
    if not isinstance(val, list):
        raise InputError(src, f"{key} must be an array of tables: [[{key}]]")
    return val


def resolve_day(sc: Scenario, spec: str) -> str:
    """The day a user means by ``spec``: a day's name, else its number counted from 1
    (the paper's "day 1" to "day 3" are 1, 2, 3). 0 and numbers past the last day are
    refused with the list of days."""
    if spec in sc.days:
        return spec
    listing = ", ".join(f"{i} = {d!r}" for i, d in enumerate(sc.days, start=1))
    text = spec.strip()
    if text.isdigit():
        n = int(text)
        if 1 <= n <= len(sc.days):
            return sc.days[n - 1]
        why = ("days are numbered from 1, as the paper numbers them" if n == 0
               else f"the scenario has {len(sc.days)} days")
        raise InputError(sc.path, f"no day {n}: {why}; days: {listing}")
    raise InputError(sc.path, f"unknown day {spec!r}: give a day's name or its number from 1; days: {listing}")


def cycle_leg_demand(base_dir: Path) -> LegDemand:
    """What each cycle-file leg asks of a vehicle (:class:`cevm.core.limits.Demand`, read
    once per file; None for a stored trip or route leg, which needs the store:
    :func:`cevm.store.sources.store_leg_demand`)."""
    from cevm.core.sweep import Source

    cache: dict[tuple, object] = {}

    def demand(leg: Leg):
        src = leg.source
        if src is None or src.kind != "cycle":
            return None
        key = (src.kind, src.ref, src.options)
        if key not in cache:
            path = Path(src.ref) if Path(src.ref).is_absolute() else base_dir / src.ref
            fmt = CycleFormat.from_mapping(dict(src.options), path, base_dir) if src.options else None
            cache[key] = Source.from_cycle(read_cycle_csv(path, fmt)).demand
        return cache[key]

    return demand


#: Keys of a scenario's [reference] table: choices to compare a plan with (the paper's
#: table 4), where they come from and why a plan may differ.
_REFERENCE_KEYS = {"source", "why", "assignment"}


def read_reference(path: Path, sc: Scenario) -> dict | None:
    """A scenario's optional ``[reference]``: ``source`` (what the choices are, e.g. "the
    paper's table 4"), ``why`` (why a plan here may choose otherwise) and ``assignment``
    (day -> {stop -> vehicle id}); every day, stop and vehicle checked against the
    scenario. None without one."""
    data = _read_toml(path).get("reference")
    if data is None:
        return None
    data = _check_keys(path, "reference", data, _REFERENCE_KEYS)
    assignment = data.get("assignment", {})
    if not isinstance(assignment, dict):
        raise InputError(path, "reference.assignment must be a table: day -> {stop -> vehicle id}")
    stops, ids, days = set(sc.stops()), {v.id for v in sc.vehicles}, set(sc.days)
    for day, choice in assignment.items():
        if day not in days:
            raise InputError(path, f"reference.assignment: unknown day {day!r}; days: {', '.join(sc.days)}")
        if not isinstance(choice, dict):
            raise InputError(path, f"reference.assignment.{day!r} must be a table: stop -> vehicle id")
        for stop, vid in choice.items():
            if stop not in stops:
                raise InputError(path, f"reference.assignment.{day!r}: unknown stop {stop!r}")
            if vid not in ids:
                raise InputError(path, f"reference.assignment.{day!r}.{stop!r}: unknown vehicle {vid!r}")
    return {"source": _str(path, "reference.source", data.get("source", "a reference")),
            "why": _str(path, "reference.why", data["why"]) if "why" in data else None,
            "assignment": assignment}


def _interval_from(vehicle: Vehicle) -> str:
    """posterior, prior or none: what a vehicle's probabilities come from."""
    post = posterior_of(vehicle)
    return "none" if post is None else post.label


def fleet_report(path: str | Path, days: Sequence[str | int] | None = None, *, method: str = "auto",
                 resolve_leg: LegResolver = default_resolver, ambient_c: float | None = None,
                 leg_demand: LegDemand | None = None, min_p_complete: float | None = None) -> dict:
    """Everything ``cevm fleet SCENARIO`` shows, JSON-ready: the scenario, one plan per
    day (all days by default), the table-4 rows and a summary row per day
    (total, default, saving, method, status, time). ``ambient_c`` [degC] overrides every
    day's temperature. A day without a feasible assignment is not planned: it is listed
    in ``infeasible_days`` with why, and the other days are planned. Each vehicle of a
    plan has its ``verdict`` (:func:`cevm.core.assignment.verdict.vehicle_verdicts`: the
    flags of every command, the legs it cannot follow; ``leg_demand`` says what each leg
    asks, default :func:`cycle_leg_demand` for cycle files), warned about; ``reference``
    compares the choices with the scenario's ``[reference]`` (the paper's table 4).

    ``min_p_complete``: require every vehicle with a budget to complete its day with at
    least this probability (:func:`cevm.core.assignment.plan`).

    ``days``: names, or strings holding a day's 1-based number as the paper numbers days
    (``"3"`` is the third day; see :func:`resolve_day`), or ints (0-based indices, as
    :func:`cevm.core.assignment.plan` takes them)."""
    sc = load_scenario(path, resolve_leg)
    if ambient_c is not None:
        sc = dataclasses.replace(sc, ambient_c=_day_temperatures(Path(path), float(ambient_c), len(sc.days)))
    chosen = [resolve_day(sc, d) if isinstance(d, str) else d for d in days] if days is not None else sc.days
    plans, infeasible = [], []
    for d in chosen:  # a day without a feasible assignment is named, the others planned
        try:
            plans.append(plan(sc, d, method=method, min_p_complete=min_p_complete))
        except InputError as exc:
            if not str(exc.message).startswith("day "):
                raise
            infeasible.append({"day": sc.days[sc.day_index(d)], "why": exc.message})
    demand_of = leg_demand if leg_demand is not None else cycle_leg_demand(Path(path).parent)
    verdicts = [vehicle_verdicts(sc, p, demand_of) for p in plans]
    fleet = {v.id: v.vehicle for v in sc.vehicles}
    reference = read_reference(Path(path), sc)
    differences = reference_differences(plans, reference["assignment"]) if reference else []
    return {
        "scenario": sc.name,
        "path": str(path),
        "ambient_c": {day: sc.ambient_of(j) for j, day in enumerate(sc.days)},
        "objective": sc.objective_kind,
        "unit": sc.unit,
        "mass_model": sc.mass_model,
        "load_time_s": sc.load_time_s,
        "vehicles": [{"id": fv.id, "vehicle_key": fv.vehicle.label, "vehicle": fv.vehicle.name,
                      "powertrain": fv.vehicle.powertrain,
                      "ice_braking": None if fv.vehicle.is_ev else fv.vehicle.ice_braking,
                      "calibrated": fv.vehicle.calibration is not None,
                      "interval_from": _interval_from(fv.vehicle),
                      "uses_temperature": energy.uses_temperature(fv.vehicle),
                      "from_prior": list(fv.vehicle.from_prior),
                      "prior_note": prior_values_note(fv.vehicle)} for fv in sc.vehicles],
        "warnings": calibration_warnings(sc, plans) + [w for p, vd in zip(plans, verdicts, strict=True)
                                                         for w in verdict_warnings(p.day, vd, fleet)],
        "infeasible_days": infeasible,
        "reference": None if reference is None else {
            "source": reference["source"], "why": reference["why"], "differences": differences},
        "table": table4_rows(plans),
        "summary": sorted([
            {
                "day": p.day,
                "total": p.total,
                "default_total": p.default_total,
                "saving": p.saving,
                "saving_pct": p.saving_pct,
                "method": p.method,
                "status": p.status,
                "solve_time_s": p.solve_time_s,
                "min_p_complete": p.min_p_complete,
                "lowest_p_complete": min((x for x in (p.p_complete or {}).values() if x is not None), default=None),
            }
            for p in plans
        ] + [{"day": d["day"], "total": None, "default_total": None, "saving": None, "saving_pct": None,
              "method": None, "status": "infeasible", "solve_time_s": None, "min_p_complete": min_p_complete,
              "lowest_p_complete": None} for d in infeasible],
            key=lambda row: sc.day_index(row["day"])),
        "plans": [_with_verdicts(p.to_dict(), vd) for p, vd in zip(plans, verdicts, strict=True)],
    }


def _with_verdicts(plan_dict: dict, verdicts: dict[str, dict]) -> dict:
    """A plan's dict with each vehicle's ``verdict`` (:func:`vehicle_verdicts`)."""
    for v in plan_dict["vehicles"]:
        v["verdict"] = verdicts[v["vehicle"]]
    return plan_dict
