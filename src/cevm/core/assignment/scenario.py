"""A fleet scenario's types (vehicles, routes, legs, days and payloads) and their
validation: a :class:`Scenario` that exists is consistent."""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from cevm.core.cycle import CycleVector
from cevm.core.vehicle import Vehicle
from cevm.errors import InputError

#: Relative tolerance of the EV energy-budget checks: an assignment whose energy exceeds
#: the budget by less than this share is feasible. Far above floating-point rounding
#: (1e-13), so the same assignment is judged alike by enumeration, the MILP and the
#: final evaluation, whichever evaluation path computed its energy.
BUDGET_RTOL = 1e-9
#: Default battery reserve of an EV, as a fraction of its usable capacity: the state of
#: charge may not fall below 15 % (the issue's default; a common operator margin for
#: range uncertainty). Override per scenario or per vehicle.
EV_RESERVE_FRACTION_DEFAULT = 0.15
#: Default state of charge at the start of the day: 1.0 (charged at the depot overnight).
SOC_START_DEFAULT = 1.0

OBJECTIVES = ("fuel", "energy", "cost")
MASS_MODELS = ("carried", "paper-eq32")
LEG_KINDS = ("cycle", "trip", "route")


@dataclass(frozen=True)
class LegSource:
    """Where a leg's drive cycle comes from: a tagged value.

    ``kind`` is ``"cycle"`` (a cycle CSV file, ``ref`` is its path relative to the
    scenario file), ``"trip"`` (a stored trip ID) or ``"route"`` (a named route); the
    leg is ``repeat`` consecutive copies of it (the paper: three regional cycles).
    ``options`` say how a cycle file is read (column, units, grade file).
    """

    kind: str
    ref: str
    repeat: int = 1
    #: How a cycle file is read, as (key, value) pairs (cevm.io.cycles.CycleFormat).
    options: tuple = ()

    def describe(self) -> str:
        rep = f" x{self.repeat}" if self.repeat != 1 else ""
        opts = "".join(f", {k} = {v!r}" for k, v in self.options)
        return f"{self.kind} = {self.ref!r}{opts}{rep}"




@dataclass(frozen=True, eq=False)
class Leg:
    """One leg of a route: its drive-cycle vector (repeats included) and its source."""

    vector: CycleVector
    source: LegSource | None = None


@dataclass(frozen=True)
class FleetVehicle:
    """A vehicle of the fleet: its model parameters and its limits for planning.

    ``max_gross_kg`` is the vehicle file's unless the scenario overrides it (None: no
    limit). EV only: the day may use at most (soc_start - ev_reserve_fraction) of the
    usable battery ``vehicle.battery_j``.
    """

    id: str
    vehicle: Vehicle
    max_gross_kg: float | None = None
    ev_reserve_fraction: float = EV_RESERVE_FRACTION_DEFAULT
    soc_start: float = SOC_START_DEFAULT

    @property
    def kerb_mass_kg(self) -> float:
        if self.vehicle.kerb_mass_kg is None:
            raise ValueError(f"vehicle {self.id!r} has no kerb_mass_kg")
        return float(self.vehicle.kerb_mass_kg)

    @property
    def energy_budget_j(self) -> float | None:
        """Battery energy [J] the day may use (EV), None for an ICE vehicle."""
        if not self.vehicle.is_ev:
            return None
        if self.vehicle.battery_j is None:
            raise ValueError(f"electric vehicle {self.id!r} has no battery_j")
        return (self.soc_start - self.ev_reserve_fraction) * float(self.vehicle.battery_j)


@dataclass(frozen=True)
class Route:
    """A route: vehicle, ordered stops, and one leg per hop (depot -> stop 1 -> ... ->
    stop n, then -> depot when ``return_to_depot``): len(legs) = n + return_to_depot."""

    id: str
    vehicle_id: str
    stops: tuple[str, ...]
    legs: tuple[Leg, ...]
    depot: str = "depot"
    return_to_depot: bool = True


@dataclass(frozen=True)
class Prices:
    """Energy prices for ``objective = "cost"``: per litre of fuel and per kWh from the
    battery (currency is a label)."""

    fuel_per_l: float | None = None
    electricity_per_kwh: float | None = None
    currency: str = "cost"


@dataclass(frozen=True, eq=False)
class Scenario:
    """A fleet scenario (see :func:`load_scenario` for the file format).

    ``payload_kg[stop][d]`` is the payload [kg] for stop ``stop`` on day ``days[d]``.
    ``allowed[stop]`` restricts the vehicles that may serve a stop (default: every
    vehicle whose route lists it); ``default_vehicle[stop]`` names the vehicle of the
    default assignment the saving is measured against (default: the first route, in
    file order, that lists the stop).
    """

    name: str
    vehicles: tuple[FleetVehicle, ...]
    routes: tuple[Route, ...]
    days: tuple[str, ...]
    payload_kg: Mapping[str, tuple[float, ...]]
    allowed: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    default_vehicle: Mapping[str, str] = field(default_factory=dict)
    objective: str | None = None
    prices: Prices | None = None
    mass_model: str = "carried"
    path: str | None = None
    load_time_s: float = 0.0
    ambient_c: tuple[float | None, ...] = ()

    def ambient_of(self, d: int) -> float | None:
        """Day ``d``'s ambient temperature [degC], or None (each vehicle's default)."""
        return self.ambient_c[d] if d < len(self.ambient_c) else None

    def __post_init__(self) -> None:
        validate_scenario(self)

    @cached_property
    def vehicle_by_id(self) -> dict[str, FleetVehicle]:
        """The vehicles by id, made once (a scenario is frozen): looked up per route, a
        dict made at every call was quadratic in the fleet's size."""
        return {v.id: v for v in self.vehicles}

    @cached_property
    def _day_positions(self) -> dict[str, int]:
        """Each day's index (its first), made once: :meth:`day_index` is asked per row."""
        at: dict[str, int] = {}
        for i, d in enumerate(self.days):
            at.setdefault(d, i)
        return at

    @cached_property
    def _routes_through(self) -> dict[str, list[int]]:
        """Per stop, the indices of the routes that list it (in route order), made once:
        :meth:`options` scanned every route for every stop (quadratic: a scenario of
        4,000 routes took 17 s to validate)."""
        through: dict[str, list[int]] = {}
        for i, r in enumerate(self.routes):
            for stop in dict.fromkeys(r.stops):
                through.setdefault(stop, []).append(i)
        return through

    @property
    def objective_kind(self) -> str:
        """The objective in force: the stated one, else "fuel" for an all-ICE fleet and
        "energy" for an all-EV fleet (a mixed fleet must state "cost")."""
        if self.objective is not None:
            return self.objective
        return "energy" if all(v.vehicle.is_ev for v in self.vehicles) else "fuel"

    @property
    def unit(self) -> str:
        kind = self.objective_kind
        if kind == "fuel":
            return "l"
        if kind == "energy":
            return "J"
        return self.prices.currency if self.prices else "cost"

    def stops(self) -> list[str]:
        """All stops, in order of first appearance on the routes."""
        seen: dict[str, None] = {}
        for r in self.routes:
            for s in r.stops:
                seen.setdefault(s, None)
        return list(seen)

    def options(self, stop: str) -> list[int]:
        """Indices of the routes that may serve ``stop`` (in route order)."""
        ok = self.allowed.get(stop)
        through = self._routes_through.get(stop, [])
        return list(through) if ok is None else [i for i in through if self.routes[i].vehicle_id in ok]

    def day_index(self, day: str | int) -> int:
        """Index of ``day``: a day name, or an int index (0-based)."""
        if isinstance(day, (int, np.integer)) and not isinstance(day, bool):
            if not 0 <= day < len(self.days):
                raise InputError(self.path, f"day index {day} out of range: the scenario has {len(self.days)} days")
            return int(day)
        at = self._day_positions.get(day)  # type: ignore[arg-type]
        if at is not None:
            return at
        raise InputError(self.path, f"unknown day {day!r}; days: {', '.join(self.days)}")


def validate_scenario(sc: Scenario) -> None:
    src = sc.path or "<scenario>"

    def bad(msg: str) -> InputError:
        return InputError(src, msg)

    if not sc.vehicles:
        raise bad("no vehicles")
    if not sc.routes:
        raise bad("no routes")
    if not sc.days:
        raise bad("no days")
    ids = [v.id for v in sc.vehicles]
    if len(set(ids)) != len(ids):
        raise bad(f"duplicate vehicle id {_first_repeated(ids)!r}")
    rids = [r.id for r in sc.routes]
    if len(set(rids)) != len(rids):
        raise bad(f"duplicate route id {_first_repeated(rids)!r}")
    if sc.mass_model not in MASS_MODELS:
        raise bad(f"mass_model must be one of {', '.join(MASS_MODELS)}; got {sc.mass_model!r}")
    vids = set(ids)
    for v in sc.vehicles:
        if v.vehicle.kerb_mass_kg is None:
            raise bad(f"vehicle {v.id!r}: its vehicle file needs kerb_mass_kg (payloads are added to it)")
        if v.max_gross_kg is not None and v.max_gross_kg < v.kerb_mass_kg:
            raise bad(f"vehicle {v.id!r}: max_gross_kg {v.max_gross_kg:g} is below its kerb mass {v.kerb_mass_kg:g}")
        if v.vehicle.is_ev:
            if not 0.0 <= v.ev_reserve_fraction < 1.0:
                raise bad(f"vehicle {v.id!r}: ev_reserve_fraction must be in [0, 1), got {v.ev_reserve_fraction:g}")
            if not v.ev_reserve_fraction < v.soc_start <= 1.0:
                raise bad(f"vehicle {v.id!r}: soc_start must be in (ev_reserve_fraction, 1], got {v.soc_start:g}")
    for r in sc.routes:
        if r.vehicle_id not in vids:
            raise bad(f"route {r.id!r}: unknown vehicle {r.vehicle_id!r}; vehicles: {', '.join(ids)}")
        if len(set(r.stops)) != len(r.stops):
            raise bad(f"route {r.id!r}: a stop is listed twice")
        need = len(r.stops) + (1 if r.return_to_depot else 0)
        if len(r.legs) != need:
            raise bad(
                f"route {r.id!r}: {len(r.legs)} legs for {len(r.stops)} stops; needs {need} "
                f"({'with' if r.return_to_depot else 'without'} the return to the depot)"
            )
        cr = sc.vehicle_by_id[r.vehicle_id].vehicle.cr
        for leg in r.legs:
            if cr < leg.vector.cr0:
                raise bad(f"route {r.id!r}: vehicle Cr {cr:g} is below the leg vector's Cr0 {leg.vector.cr0:g}")
    stops = dict.fromkeys(sc.stops())  # in order, and a set: every test below is one look-up
    served = {(r.vehicle_id, s) for r in sc.routes for s in r.stops}
    for s in stops:
        if s not in sc.payload_kg:
            raise bad(f"no payload for stop {s!r} (key payload_kg.{quote_key(s)})")
    for s, vals in sc.payload_kg.items():
        if s not in stops:
            raise bad(f"payload_kg names stop {s!r}, which no route lists")
        if len(vals) != len(sc.days):
            raise bad(f"payload_kg.{quote_key(s)}: {len(vals)} values for {len(sc.days)} days")
        if any(not math.isfinite(p) or p < 0 for p in vals):
            raise bad(f"payload_kg.{quote_key(s)}: payloads must be finite and >= 0")
    for s, vs in sc.allowed.items():
        if s not in stops:
            raise bad(f"stop.{quote_key(s)}: no route lists this stop")
        for vid in vs:
            if vid not in vids:
                raise bad(f"stop.{quote_key(s)}.vehicles: unknown vehicle {vid!r}")
            if (vid, s) not in served:
                raise bad(f"stop.{quote_key(s)}.vehicles: vehicle {vid!r} has no route through this stop")
    for s in stops:
        if not sc.options(s):
            raise bad(f"stop {s!r}: no allowed vehicle drives a route through it")
    for s, vid in sc.default_vehicle.items():
        if s not in stops or vid not in {sc.routes[i].vehicle_id for i in sc.options(s)}:
            raise bad(f"stop.{quote_key(s)}.default: vehicle {vid!r} may not serve this stop")
    kind = sc.objective_kind
    if kind not in OBJECTIVES:
        raise bad(f"objective must be one of {', '.join(OBJECTIVES)}; got {kind!r}")
    evs = [v.id for v in sc.vehicles if v.vehicle.is_ev]
    ices = [v.id for v in sc.vehicles if not v.vehicle.is_ev]
    if kind == "fuel" and evs:
        raise bad(f"objective 'fuel' but {evs[0]!r} is electric: use objective = 'cost' with [prices] "
                  "for a mixed fleet")
    if kind == "energy" and ices:
        raise bad(f"objective 'energy' is for electric fleets, but {ices[0]!r} burns fuel: use 'fuel' or 'cost'")
    if kind == "cost":
        p = sc.prices
        if p is None or (ices and p.fuel_per_l is None) or (evs and p.electricity_per_kwh is None):
            raise bad("objective 'cost' needs [prices] fuel_per_l (ICE vehicles) and electricity_per_kwh (EVs)")


def _first_repeated(items: list[str]) -> str:
    """The first item that was there before (one pass: a count per item was quadratic)."""
    seen: set[str] = set()
    return next(i for i in items if i in seen or seen.add(i))  # type: ignore[func-returns-value]


def quote_key(key: str) -> str:
    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else f'"{key}"'
