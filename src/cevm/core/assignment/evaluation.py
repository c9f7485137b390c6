"""The exact CE evaluation of one assignment: every leg predicted at the mass it
carries (:func:`evaluate`) and the default assignment savings are measured against."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from itertools import pairwise

import numpy as np

from cevm.core.assignment.curves import quantity
from cevm.core.assignment.scenario import BUDGET_RTOL, Leg, Route, Scenario
from cevm.core.cycle import CycleVector
from cevm.core.vehicle import predict
from cevm.units import J_PER_KWH


@dataclass(frozen=True)
class RouteUse:
    """A route under an assignment: stops served (in order), and per leg driven its
    gross mass [kg] and consumption (litres or J, the vehicle's ``unit``)."""

    route_id: str
    stops_served: tuple[str, ...]
    leg_names: tuple[str, ...]
    leg_mass_kg: tuple[float, ...]
    leg_use: tuple[float, ...]
    leg_index: tuple[int, ...] = ()  # the driven legs' positions in the route


@dataclass(frozen=True)
class VehicleUse:
    """A vehicle's day: stops served, consumption and limits.

    ``fuel_l`` (ICE) or ``energy_j`` (EV, at the battery) is the day's total; ``value``
    the same in the objective's unit; ``max_gross_used_kg`` the heaviest leg's mass.
    """

    vehicle_id: str
    stops: tuple[str, ...]
    fuel_l: float | None
    energy_j: float | None
    value: float
    max_gross_used_kg: float
    max_gross_kg: float | None
    energy_budget_j: float | None
    routes: tuple[RouteUse, ...]

    @property
    def feasible(self) -> bool:
        ok = self.max_gross_kg is None or self.max_gross_used_kg <= self.max_gross_kg * (1 + 1e-12)
        if self.energy_budget_j is not None:  # an EV: energy_j is its day's total
            ok = ok and self.energy_j is not None and self.energy_j <= self.energy_budget_j * (1 + BUDGET_RTOL)
        return ok


@dataclass(frozen=True)
class Evaluation:
    """Exact CE evaluation of one assignment (stop -> route index) on one day."""

    assignment: dict[str, int]
    vehicles: tuple[VehicleUse, ...]
    total: float

    @property
    def feasible(self) -> bool:
        return all(v.feasible for v in self.vehicles)

    def violations(self) -> list[str]:
        out = []
        for v in self.vehicles:
            if v.max_gross_kg is not None and v.max_gross_used_kg > v.max_gross_kg * (1 + 1e-12):
                out.append(f"{v.vehicle_id} gross {v.max_gross_used_kg:g} kg > {v.max_gross_kg:g} kg")
            if v.energy_budget_j is not None and v.energy_j is not None \
                    and v.energy_j > v.energy_budget_j * (1 + BUDGET_RTOL):
                out.append(f"{v.vehicle_id} uses {v.energy_j / J_PER_KWH:.1f} kWh > budget "
                           f"{v.energy_budget_j / J_PER_KWH:.1f} kWh")
        return out


def objective_weights(sc: Scenario) -> dict[str, float]:
    """Objective units per vehicle quantity (litre or battery joule)."""
    kind = sc.objective_kind
    out = {}
    for v in sc.vehicles:
        if kind in ("fuel", "energy"):
            out[v.id] = 1.0
        elif v.vehicle.is_ev:
            out[v.id] = _price(sc, "electricity_per_kwh") / J_PER_KWH
        else:
            out[v.id] = _price(sc, "fuel_per_l")
    return out


def _price(sc: Scenario, name: str) -> float:
    """A price of the cost objective (the scenario's loading refuses a cost objective without it)."""
    value = None if sc.prices is None else getattr(sc.prices, name)
    if value is None:
        raise ValueError(f"objective 'cost' needs [prices] {name}")
    return float(value)


def vector_groups(legs: Sequence[Leg]) -> list[tuple[CycleVector, list[int]]]:
    groups: dict[int, tuple[CycleVector, list[int]]] = {}
    for j, leg in enumerate(legs):
        groups.setdefault(id(leg.vector), (leg.vector, []))[1].append(j)
    return list(groups.values())


def leg_names(route: Route) -> list[str]:
    places = [route.depot, *route.stops] + ([route.depot] if route.return_to_depot else [])
    return [f"{a} -> {b}" for a, b in pairwise(places)]


def evaluate(sc: Scenario, day: str | int, assignment: Mapping[str, int | str]) -> Evaluation:
    """Consumption of every vehicle under ``assignment`` (stop -> route index or route
    id; a stop with a single option may be left out), predicted leg by leg with the CE
    model at the mass carried on each leg (see the module docstring for the mass
    models)."""
    d = sc.day_index(day)
    rid = {r.id: i for i, r in enumerate(sc.routes)}
    assign: dict[str, int] = {}
    for s in sc.stops():
        opts = sc.options(s)
        a = assignment.get(s, opts[0] if len(opts) == 1 else None)
        if a is None:
            raise ValueError(f"assignment misses stop {s!r}")
        a = rid[a] if isinstance(a, str) else int(a)
        if a not in opts:
            raise ValueError(f"stop {s!r} cannot be served by route {sc.routes[a].id!r}")
        assign[s] = a
    weights = objective_weights(sc)
    fv = sc.vehicle_by_id
    per_vehicle: dict[str, list[RouteUse]] = {v.id: [] for v in sc.vehicles}
    for ri, r in enumerate(sc.routes):
        v = fv[r.vehicle_id]
        served = np.array([assign[s] == ri for s in r.stops])
        pay = np.array([sc.payload_kg[s][d] for s in r.stops]) * served
        names = leg_names(r)
        if sc.mass_model == "carried":
            carried = np.cumsum(pay[::-1])[::-1]
            if r.return_to_depot:
                carried = np.append(carried, 0.0)
            driven = np.arange(len(r.legs))
        else:
            carried = np.concatenate([pay, np.zeros(len(r.legs) - len(r.stops))])
            driven = np.flatnonzero(served)
        mass = v.kerb_mass_kg + carried
        use = np.zeros(len(r.legs))
        for vec, cols in vector_groups(r.legs):
            at = np.array(cols)
            use[at] = quantity(predict(vec, v.vehicle, mass[at], ambient_c=sc.ambient_of(d)), v.vehicle)
        per_vehicle[v.id].append(
            RouteUse(
                route_id=r.id,
                stops_served=tuple(s for s, ok in zip(r.stops, served, strict=True) if ok),
                leg_names=tuple(names[j] for j in driven),
                leg_mass_kg=tuple(float(mass[j]) for j in driven),
                leg_use=tuple(float(use[j]) for j in driven),
                leg_index=tuple(int(j) for j in driven),
            )
        )
    vehicles = []
    total = 0.0
    for v in sc.vehicles:
        routes = tuple(per_vehicle[v.id])
        q = float(sum(sum(ru.leg_use) for ru in routes))
        value = q * weights[v.id]
        total += value
        vehicles.append(
            VehicleUse(
                vehicle_id=v.id,
                stops=tuple(s for ru in routes for s in ru.stops_served),
                fuel_l=None if v.vehicle.is_ev else q,
                energy_j=q if v.vehicle.is_ev else None,
                value=value,
                max_gross_used_kg=max([v.kerb_mass_kg, *(m for ru in routes for m in ru.leg_mass_kg)]),
                max_gross_kg=v.max_gross_kg,
                energy_budget_j=v.energy_budget_j,
                routes=routes,
            )
        )
    return Evaluation(assignment=assign, vehicles=tuple(vehicles), total=total)


def default_assignment(sc: Scenario) -> dict[str, int]:
    """The assignment savings are measured against: each stop's ``default`` vehicle if
    the scenario names one, else the first route (in file order) allowed to serve it."""
    out = {}
    for s in sc.stops():
        opts = sc.options(s)
        want = sc.default_vehicle.get(s)
        out[s] = next(i for i in opts if sc.routes[i].vehicle_id == want) if want else opts[0]
    return out
