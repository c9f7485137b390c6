"""Fleet assignment: which vehicle serves each shared stop (paper section 6, eq. 32).

A fleet runs routes from depots. Each route is driven by one vehicle and visits an ordered
list of stops; a stop listed on several routes (the paper's LH1S1 = R1S2) is *shared*:
each day it is served by exactly one of the vehicles allowed there. :func:`plan` picks
the assignment that minimises the fleet's total fuel (or electric energy, or cost),
subject to each vehicle's gross-weight limit and, for electric vehicles, a battery
reserve, and proves it optimal.

Reading of the paper (stated, because the paper is terse here)
---------------------------------------------------------------
``mass_model = "carried"`` (the default, physical reading): the geometry of a route is
fixed. Its vehicle leaves the depot loaded with the payloads of every stop it serves,
drives every leg of its route (depot -> stop 1 -> ... -> stop n [-> depot]) whether or
not it serves each stop, and drops each served stop's payload there. So leg l carries
kerb + the payloads of the served stops at positions >= l; the return leg (on by
default, ``return_to_depot = true``, as figure 8 draws depot -> stops -> depot) is
driven empty. A shared stop served by the other vehicle moves its payload to that
vehicle: only where mass is carried changes, not which roads are driven.

``mass_model = "paper-eq32"`` (the literal reading of eq. 32,
sum_j sum_s f_j(M_s, d)): every stop served by vehicle j costs the consumption of
vehicle j over the leg that arrives at the stop, at mass kerb + M_s (that stop's payload
only); legs to stops a vehicle does not serve, and return legs, are not counted. This is
the only reading under which the paper's table 4 can vary with the payload as it does
(with a model affine in mass, "carried" gives a payload-independent choice unless a
limit binds); it is kept to compare with the paper, not as physics.

Exactness
---------
The consumption of one vehicle over one leg, as a function of the carried mass m, is
exactly ``q(m) = g * [m B0 + A0 + (1 - w) P(m)] + q0`` with ``P(m) = sum_i max(0, m c_i
+ CdA a_i)`` over the cycle's non-simplified steps (cevm.core.model): w = 1 for the paper's
ICE (q affine in m), w = 0 for an ICE with no braking credit, w = eta^2 for an EV. As
w <= 1 and each max(0, affine) is convex, q is convex and piecewise affine in m, with
one piece per interval between the step thresholds m_i = -CdA a_i / c_i. :func:`leg_curve`
builds those pieces over the leg's feasible mass range and checks them against
:func:`cevm.core.vehicle.predict` at every breakpoint and every midpoint (two piecewise-affine
functions with the same kinks that agree there agree everywhere). Then

- ``enumerate``: every combination of choices, each leg predicted with the CE model,
  vectorised over the combinations; exact, for up to ``enum_limit`` combinations.
- ``milp``: binaries x[s, r] (stop s served by route r), sum_r x[s, r] = 1. A leg whose
  q is affine over its range enters the objective linearly; any other leg gets an
  epigraph variable t >= alpha_k + beta_k m for each piece k (exact for a convex q under
  minimisation, and valid inside the battery constraint too). Gross weight: the first
  leg carries the most, kerb + payloads <= max_gross_kg. Solved with HiGHS
  (scipy.optimize.milp) with ``mip_rel_gap = 0``: proven optimal up to HiGHS's
  tolerances (absolute gap 1e-6 on an objective scaled to about 1e3, so 1e-9 relative).

The answer is always re-evaluated with the CE model (:func:`evaluate`) before it is
reported. Scenario files: see :func:`cevm.io.scenario.load_scenario`.
"""

from __future__ import annotations

import math
import re
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cevm.core import energy
from cevm.core.cycle import CycleVector
from cevm.core.model import braking_weight
from cevm.core.vehicle import Vehicle, default_ambient_c, predict
from cevm.errors import InputError
from cevm.units import J_PER_KWH

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
#: ``method="auto"`` enumerates up to this many combinations, and solves a MILP beyond:
#: enumeration is exact, needs no solver and, vectorised, costs about 1 us per
#: combination and leg, so 1,024 combinations stay well under a millisecond or two.
AUTO_ENUM_LIMIT = 1024
#: ``method="enumerate"`` refuses more combinations than this (memory: combinations x
#: legs doubles).
ENUM_LIMIT = 1 << 20
#: Relative tolerance of the check of leg pieces against the CE model.
_CURVE_RTOL = 1e-9
#: Scaled objective magnitude for the MILP (see the module docstring).
_MILP_OBJECTIVE_SCALE = 1e3

OBJECTIVES = ("fuel", "energy", "cost")
MASS_MODELS = ("carried", "paper-eq32")
LEG_KINDS = ("cycle", "trip", "route")


# --- scenario ------------------------------------------------------------------------


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
        _validate(self)

    @property
    def vehicle_by_id(self) -> dict[str, FleetVehicle]:
        return {v.id: v for v in self.vehicles}

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
        return [i for i, r in enumerate(self.routes) if stop in r.stops and (ok is None or r.vehicle_id in ok)]

    def day_index(self, day: str | int) -> int:
        """Index of ``day``: a day name, or an int index (0-based)."""
        if isinstance(day, (int, np.integer)) and not isinstance(day, bool):
            if not 0 <= day < len(self.days):
                raise InputError(self.path, f"day index {day} out of range: the scenario has {len(self.days)} days")
            return int(day)
        if day in self.days:
            return self.days.index(day)
        raise InputError(self.path, f"unknown day {day!r}; days: {', '.join(self.days)}")


def _validate(sc: Scenario) -> None:
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
        raise bad(f"duplicate vehicle id {next(i for i in ids if ids.count(i) > 1)!r}")
    rids = [r.id for r in sc.routes]
    if len(set(rids)) != len(rids):
        raise bad(f"duplicate route id {next(i for i in rids if rids.count(i) > 1)!r}")
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
    stops = sc.stops()
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
        for v in vs:
            if v not in vids:
                raise bad(f"stop.{quote_key(s)}.vehicles: unknown vehicle {v!r}")
            if not any(r.vehicle_id == v and s in r.stops for r in sc.routes):
                raise bad(f"stop.{quote_key(s)}.vehicles: vehicle {v!r} has no route through this stop")
    for s in stops:
        if not sc.options(s):
            raise bad(f"stop {s!r}: no allowed vehicle drives a route through it")
    for s, v in sc.default_vehicle.items():
        if s not in stops or v not in {sc.routes[i].vehicle_id for i in sc.options(s)}:
            raise bad(f"stop.{quote_key(s)}.default: vehicle {v!r} may not serve this stop")
    kind = sc.objective_kind
    if kind not in OBJECTIVES:
        raise bad(f"objective must be one of {', '.join(OBJECTIVES)}; got {kind!r}")
    evs = [v.id for v in sc.vehicles if v.vehicle.is_ev]
    ices = [v.id for v in sc.vehicles if not v.vehicle.is_ev]
    if kind == "fuel" and evs:
        raise bad(f"objective 'fuel' but {evs[0]!r} is electric: use objective = 'cost' with [prices] for a mixed fleet")
    if kind == "energy" and ices:
        raise bad(f"objective 'energy' is for electric fleets, but {ices[0]!r} burns fuel: use 'fuel' or 'cost'")
    if kind == "cost":
        p = sc.prices
        if p is None or (ices and p.fuel_per_l is None) or (evs and p.electricity_per_kwh is None):
            raise bad("objective 'cost' needs [prices] fuel_per_l (ICE vehicles) and electricity_per_kwh (EVs)")


def quote_key(key: str) -> str:
    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else f'"{key}"'




# --- leg consumption as a function of mass -----------------------------------------------


@dataclass(frozen=True, eq=False)
class LegCurve:
    """A vehicle's consumption over one leg as a convex piecewise-affine function of its
    gross mass m [kg] on ``[m_lo_kg, m_hi_kg]``: ``q(m) = max_k (alpha[k] + beta[k] m)``
    in litres (ICE) or joules at the battery (EV). ``affine`` when one piece remains."""

    alpha: np.ndarray
    beta: np.ndarray
    m_lo_kg: float
    m_hi_kg: float

    @property
    def affine(self) -> bool:
        return self.alpha.size == 1

    def __call__(self, mass_kg) -> np.ndarray:
        m = np.asarray(mass_kg, dtype=np.float64)
        return np.max(self.alpha[:, None] + self.beta[:, None] * m.ravel()[None, :], axis=0).reshape(m.shape)


def _negative_weight(vehicle: Vehicle) -> float:
    return energy.ev_negative_weight(vehicle) if vehicle.is_ev else braking_weight(vehicle.ice_braking)


def _to_quantity(vehicle: Vehicle, vector: CycleVector, ambient_c: float) -> tuple[float, float, float]:
    """Gain and offset of the map wheel energy [J] -> litres or battery joules, and the
    slope in mass [per kg] of the terms beyond the wheel (an ICE's kinetic term), read
    from cevm.core.energy's own functions at ``ambient_c``."""
    if vehicle.is_ev:
        def conv(e, m):
            return float(energy.ev_battery_energy_j(vehicle, e, duration_s=vector.duration_s, ambient_c=ambient_c))
    else:
        def conv(e, m):
            return float(energy.ice_fuel_l(vehicle, e, mass_kg=m, k_pos=vector.k_pos, traction_s=vector.traction_s,
                                           duration_s=vector.duration_s, idle_s=vector.idle_s, ambient_c=ambient_c))
    q0 = conv(0.0, 0.0)
    return conv(1.0, 0.0) - q0, q0, conv(0.0, 1.0) - q0


def leg_curve(vector: CycleVector, vehicle: Vehicle, m_lo_kg: float, m_hi_kg: float, *, check: bool = True,
              ambient_c: float | None = None) -> LegCurve:
    """The exact pieces of ``predict(vector, vehicle, m)`` for m in [m_lo_kg, m_hi_kg].

    Wheel energy is ``m B0 + A0 + (1 - w) P(m)`` with P the sum of the positive
    non-simplified Delta_i; on the c = CdA/m interval where the first i steps of the
    cycle's sorted threshold table are positive, P(m) = m (X_i + Cr R_i) + CdA A_i with
    the table's prefix sums. One piece per threshold inside the range, duplicates
    removed (w = 1 leaves one: affine). The terms beyond the wheel (:mod:`cevm.core.energy`,
    at ``ambient_c``, default the vehicle's) add a constant and, an ICE's kinetic term,
    a slope in m. With ``check`` (default), the pieces are compared
    with :func:`cevm.core.vehicle.predict` at every breakpoint in the range, every midpoint and
    both ends; a mismatch beyond 1e-9 relative raises RuntimeError (a bug, not input).
    """
    if not (0 < m_lo_kg <= m_hi_kg):
        raise ValueError("need 0 < m_lo_kg <= m_hi_kg")
    cda, cr = float(vehicle.cda_m2), float(vehicle.cr)
    w = _negative_weight(vehicle)
    sx, sa, sr = vector.ns_sums
    b0 = vector.s_me + cr * vector.s_r + w * (sx + cr * sr)
    a0 = cda * vector.s_a + w * cda * sa
    if vector.n_nonsimplified == 0 or w == 1.0:
        B = np.array([b0])
        A = np.array([a0])
        thr = np.empty(0)
    else:
        table = vector.threshold_table(cr)
        i_lo = int(np.searchsorted(table.threshold, cda / m_hi_kg, side="left"))
        i_hi = int(np.searchsorted(table.threshold, cda / m_lo_kg, side="left"))
        idx = np.arange(i_lo, i_hi + 1)
        B = b0 + (1.0 - w) * (table.x_cum[idx] + cr * table.r_cum[idx])
        A = a0 + (1.0 - w) * cda * table.a_cum[idx]
        thr = table.threshold[i_lo:i_hi]
    t_c = default_ambient_c(vehicle)[0] if ambient_c is None else float(ambient_c)
    gain, offset, slope = _to_quantity(vehicle, vector, t_c)
    alpha = gain * A + offset
    beta = gain * B + slope
    if alpha.size > 1:
        keep = np.ones(alpha.size, dtype=bool)
        keep[1:] = (alpha[1:] != alpha[:-1]) | (beta[1:] != beta[:-1])
        alpha, beta = alpha[keep], beta[keep]
    curve = LegCurve(alpha=alpha, beta=beta, m_lo_kg=float(m_lo_kg), m_hi_kg=float(m_hi_kg))
    if check:
        bps = np.sort(cda / thr[thr > 0]) if thr.size else np.empty(0)
        pts = np.concatenate([[m_lo_kg], bps, [m_hi_kg]])
        grid = np.concatenate([pts, 0.5 * (pts[1:] + pts[:-1])])
        grid = grid[(grid >= m_lo_kg) & (grid <= m_hi_kg)]
        truth = _quantity(predict(vector, vehicle, grid, ambient_c=t_c), vehicle)
        err = np.max(np.abs(curve(grid) - truth))
        scale = float(np.max(np.abs(truth))) + abs(offset) + 1e-300
        if err > _CURVE_RTOL * scale:
            raise RuntimeError(f"leg pieces disagree with the CE model by {err:g} (scale {scale:g}): a bug in cevm")
    return curve


def _quantity(pred, vehicle: Vehicle) -> np.ndarray:
    return pred.energy_j if vehicle.is_ev else pred.fuel_l


# --- evaluation of an assignment ---------------------------------------------------------


@dataclass(frozen=True)
class RouteUse:
    """A route under an assignment: stops served (in order), and per leg driven its
    gross mass [kg] and consumption (litres or J, the vehicle's ``unit``)."""

    route_id: str
    stops_served: tuple[str, ...]
    leg_names: tuple[str, ...]
    leg_mass_kg: tuple[float, ...]
    leg_use: tuple[float, ...]


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
        if self.energy_budget_j is not None:
            ok = ok and self.energy_j <= self.energy_budget_j * (1 + BUDGET_RTOL)
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
            if v.energy_budget_j is not None and v.energy_j > v.energy_budget_j * (1 + BUDGET_RTOL):
                out.append(f"{v.vehicle_id} uses {v.energy_j / J_PER_KWH:.1f} kWh > budget {v.energy_budget_j / J_PER_KWH:.1f} kWh")
        return out


def _weights(sc: Scenario) -> dict[str, float]:
    """Objective units per vehicle quantity (litre or battery joule)."""
    kind = sc.objective_kind
    out = {}
    for v in sc.vehicles:
        if kind in ("fuel", "energy"):
            out[v.id] = 1.0
        elif v.vehicle.is_ev:
            out[v.id] = sc.prices.electricity_per_kwh / J_PER_KWH
        else:
            out[v.id] = sc.prices.fuel_per_l
    return out


def _vector_groups(legs: Sequence[Leg]) -> list[tuple[CycleVector, list[int]]]:
    groups: dict[int, tuple[CycleVector, list[int]]] = {}
    for j, leg in enumerate(legs):
        groups.setdefault(id(leg.vector), (leg.vector, []))[1].append(j)
    return list(groups.values())


def calibration_warnings(sc: Scenario, plans: Sequence[Plan]) -> list[str]:
    """Warnings for the fleet's vehicles asked outside what their calibration saw
    (:func:`cevm.core.vehicle.domain_warnings`; none for a vehicle file that was not
    calibrated), over ``plans``: the gross masses of the legs each vehicle drives under
    the chosen assignment, the days' ambient temperatures (the vehicle's default where a
    day gives none) and the mean speeds of its routes' legs. Each line starts with the
    fleet's id of the vehicle."""
    from cevm.core.vehicle import domain_warnings

    masses: dict[str, list[float]] = {}
    temps: dict[str, list[float]] = {}
    fv = sc.vehicle_by_id
    for p in plans:
        t = sc.ambient_of(sc.day_index(p.day))
        for vu in p.evaluation.vehicles:
            masses.setdefault(vu.vehicle_id, []).extend(m for ru in vu.routes for m in ru.leg_mass_kg)
            veh = fv[vu.vehicle_id].vehicle
            temps.setdefault(vu.vehicle_id, []).append(float(default_ambient_c(veh)[0]) if t is None else float(t))
    speeds: dict[str, list[float]] = {}
    for r in sc.routes:
        speeds.setdefault(r.vehicle_id, []).extend(
            leg.vector.distance_m / leg.vector.duration_s for leg in r.legs if leg.vector.duration_s > 0)
    out = []
    for v in sc.vehicles:
        if not masses.get(v.id):
            continue
        for w in domain_warnings(v.vehicle, mass_kg=masses[v.id], ambient_c=temps[v.id],
                                 mean_speed_mps=speeds.get(v.id) or None):
            out.append(f"{v.id}: {w}")
    return out


def _leg_names(route: Route) -> list[str]:
    places = [route.depot, *route.stops] + ([route.depot] if route.return_to_depot else [])
    return [f"{a} -> {b}" for a, b in zip(places[:-1], places[1:])]


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
    weights = _weights(sc)
    fv = sc.vehicle_by_id
    per_vehicle: dict[str, list[RouteUse]] = {v.id: [] for v in sc.vehicles}
    for ri, r in enumerate(sc.routes):
        v = fv[r.vehicle_id]
        served = np.array([assign[s] == ri for s in r.stops])
        pay = np.array([sc.payload_kg[s][d] for s in r.stops]) * served
        names = _leg_names(r)
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
        for vec, cols in _vector_groups(r.legs):
            cols = np.array(cols)
            use[cols] = _quantity(predict(vec, v.vehicle, mass[cols], ambient_c=sc.ambient_of(d)), v.vehicle)
        per_vehicle[v.id].append(
            RouteUse(
                route_id=r.id,
                stops_served=tuple(s for s, ok in zip(r.stops, served) if ok),
                leg_names=tuple(names[j] for j in driven),
                leg_mass_kg=tuple(float(mass[j]) for j in driven),
                leg_use=tuple(float(use[j]) for j in driven),
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


# --- the optimisation ---------------------------------------------------------------------


@dataclass
class _Day:
    """One day's problem: free stops with their options (route indices), fixed stops."""

    d: int
    payload: dict[str, float]
    free: list[str]
    options: list[list[int]]
    fixed: dict[str, int]

    @property
    def n_combinations(self) -> int:
        return math.prod(len(o) for o in self.options)


def _day(sc: Scenario, d: int) -> _Day:
    payload = {s: sc.payload_kg[s][d] for s in sc.stops()}
    free, options, fixed = [], [], {}
    for s in sc.stops():
        opts = sc.options(s)
        if len(opts) == 1:
            fixed[s] = opts[0]
        else:
            free.append(s)
            options.append(opts)
    return _Day(d=d, payload=payload, free=free, options=options, fixed=fixed)


@dataclass(frozen=True)
class Plan:
    """The optimal assignment of one day, with its consumption and how it was found.

    ``total`` and every vehicle's ``value`` are in ``unit`` (litres, J or currency).
    ``saving`` = default_total - total (None if the default assignment is infeasible).
    ``solve_time_s`` covers :func:`plan` from the loaded scenario (vectors cached) to the
    answer: problem building, leg consumptions with the CE model, the solver, and the
    exact re-evaluation of the optimum and of the default assignment.
    """

    scenario: str
    day: str
    objective: str
    unit: str
    mass_model: str
    assignment: dict[str, str]  # stop -> route id
    evaluation: Evaluation
    total: float
    default_assignment: dict[str, str]
    default_total: float | None
    default_violations: tuple[str, ...]
    method: str
    status: str
    mip_gap: float | None
    solver_objective: float | None
    n_combinations: int
    n_variables: int
    n_constraints: int
    solve_time_s: float
    route_vehicle: dict[str, str]

    @property
    def saving(self) -> float | None:
        return None if self.default_total is None else self.default_total - self.total

    @property
    def saving_pct(self) -> float | None:
        if self.default_total is None or self.default_total == 0:
            return None
        return 100.0 * self.saving / self.default_total

    def stops_per_vehicle(self) -> dict[str, list[str]]:
        """The paper's table 4 column for this day: vehicle -> stops served, in order."""
        return {v.vehicle_id: list(v.stops) for v in self.evaluation.vehicles}

    def to_dict(self) -> dict:
        """JSON-ready dict (SI units, plus kWh for readability)."""
        vehicles = []
        for v in self.evaluation.vehicles:
            vehicles.append(
                {
                    "vehicle": v.vehicle_id,
                    "stops": list(v.stops),
                    "fuel_l": v.fuel_l,
                    "energy_j": v.energy_j,
                    "energy_kwh": None if v.energy_j is None else v.energy_j / J_PER_KWH,
                    "value": v.value,
                    "max_gross_used_kg": v.max_gross_used_kg,
                    "max_gross_kg": v.max_gross_kg,
                    "energy_budget_j": v.energy_budget_j,
                    "routes": [
                        {
                            "route": ru.route_id,
                            "stops_served": list(ru.stops_served),
                            "legs": [
                                {"leg": n, "mass_kg": m, ("energy_j" if v.energy_j is not None else "fuel_l"): u}
                                for n, m, u in zip(ru.leg_names, ru.leg_mass_kg, ru.leg_use)
                            ],
                        }
                        for ru in v.routes
                    ],
                }
            )
        return {
            "scenario": self.scenario,
            "day": self.day,
            "objective": self.objective,
            "unit": self.unit,
            "mass_model": self.mass_model,
            "assignment": {s: {"route": r, "vehicle": self.route_vehicle[r]} for s, r in self.assignment.items()},
            "stops_per_vehicle": self.stops_per_vehicle(),
            "total": self.total,
            "vehicles": vehicles,
            "default": {
                "assignment": {s: self.route_vehicle[r] for s, r in self.default_assignment.items()},
                "total": self.default_total,
                "violations": list(self.default_violations),
            },
            "saving": self.saving,
            "saving_pct": self.saving_pct,
            "method": self.method,
            "status": self.status,
            "mip_gap": self.mip_gap,
            "solver_objective": self.solver_objective,
            "n_combinations": self.n_combinations,
            "n_variables": self.n_variables,
            "n_constraints": self.n_constraints,
            "solve_time_s": self.solve_time_s,
        }


def plan(sc: Scenario, day: str | int, *, method: str = "auto", enum_limit: int = AUTO_ENUM_LIMIT,
         time_limit_s: float | None = None) -> Plan:
    """The assignment of shared stops that minimises the day's total objective.

    Parameters
    ----------
    sc : the scenario
    day : a day name, or its index (0-based)
    method : "enumerate" (every combination), "milp" (HiGHS) or "auto" (default:
        enumerate when there are at most ``enum_limit`` combinations, else MILP)
    enum_limit : "auto"'s enumeration limit, default :data:`AUTO_ENUM_LIMIT` (1,024)
    time_limit_s : MILP time limit [s]; None (default) for none. A MILP stopped by the
        limit reports status "time limit" and its gap: then the answer is not proven.

    Raises InputError when no assignment satisfies the limits (the message says why).
    """
    t0 = time.perf_counter()
    d = sc.day_index(day)
    prob = _day(sc, d)
    n_comb = prob.n_combinations
    if method == "auto":
        method = "enumerate" if n_comb <= enum_limit else "milp"
    if method == "enumerate":
        if n_comb > ENUM_LIMIT:
            raise ValueError(f"{n_comb} combinations: too many to enumerate (limit {ENUM_LIMIT}); use method='milp'")
        best, info = _solve_enumerate(sc, prob)
    elif method == "milp":
        best, info = _solve_milp(sc, prob, time_limit_s)
    else:
        raise ValueError(f"method must be 'auto', 'enumerate' or 'milp', not {method!r}")
    if best is None:
        raise InputError(sc.path, f"day {sc.days[d]!r}: {info['why']}")
    ev = evaluate(sc, d, best)
    dflt = default_assignment(sc)
    dev = evaluate(sc, d, dflt)
    route_ids = [r.id for r in sc.routes]
    return Plan(
        scenario=sc.name,
        day=sc.days[d],
        objective=sc.objective_kind,
        unit=sc.unit,
        mass_model=sc.mass_model,
        assignment={s: route_ids[i] for s, i in ev.assignment.items()},
        evaluation=ev,
        total=ev.total,
        default_assignment={s: route_ids[i] for s, i in dflt.items()},
        default_total=dev.total if dev.feasible else None,
        default_violations=tuple(dev.violations()),
        method=info["method"],
        status=info["status"],
        mip_gap=info.get("mip_gap"),
        solver_objective=info.get("objective"),
        n_combinations=n_comb,
        n_variables=info.get("n_variables", 0),
        n_constraints=info.get("n_constraints", 0),
        solve_time_s=time.perf_counter() - t0,
        route_vehicle={r.id: r.vehicle_id for r in sc.routes},
    )


def _solve_enumerate(sc: Scenario, prob: _Day) -> tuple[dict[str, int] | None, dict]:
    """Every combination of choices, vectorised: one CE prediction per (leg, unique
    vector) for all combinations at once."""
    n_comb = prob.n_combinations
    sizes = [len(o) for o in prob.options]
    choice = np.stack(np.unravel_index(np.arange(n_comb), sizes), axis=1) if sizes else np.zeros((1, 0), dtype=int)
    free_col = {s: j for j, s in enumerate(prob.free)}
    weights = _weights(sc)
    total = np.zeros(n_comb)
    vehicle_q = {v.id: np.zeros(n_comb) for v in sc.vehicles}
    feasible = np.ones(n_comb, dtype=bool)
    fv = sc.vehicle_by_id
    for ri, r in enumerate(sc.routes):
        v = fv[r.vehicle_id]
        served = np.empty((n_comb, len(r.stops)))
        for k, s in enumerate(r.stops):
            if s in prob.fixed:
                served[:, k] = 1.0 if prob.fixed[s] == ri else 0.0
            else:
                j = free_col[s]
                served[:, k] = choice[:, j] == prob.options[j].index(ri) if ri in prob.options[j] else 0.0
        pay = served * np.array([prob.payload[s] for s in r.stops])
        if sc.mass_model == "carried":
            carried = np.cumsum(pay[:, ::-1], axis=1)[:, ::-1]
            if r.return_to_depot:
                carried = np.concatenate([carried, np.zeros((n_comb, 1))], axis=1)
            driven = np.ones_like(carried)
        else:
            carried = np.concatenate([pay, np.zeros((n_comb, len(r.legs) - len(r.stops)))], axis=1)
            driven = np.concatenate([served, np.zeros((n_comb, len(r.legs) - len(r.stops)))], axis=1)
        mass = v.kerb_mass_kg + carried
        if v.max_gross_kg is not None:
            feasible &= np.max(np.where(driven > 0, mass, 0.0), axis=1) <= v.max_gross_kg
        q = np.zeros(n_comb)
        for vec, cols in _vector_groups(r.legs):
            m = mass[:, cols]
            uniq, inv = np.unique(m, return_inverse=True)
            use = _quantity(predict(vec, v.vehicle, uniq, ambient_c=sc.ambient_of(prob.d)), v.vehicle)[inv].reshape(m.shape)
            q += np.sum(use * driven[:, cols], axis=1)
        vehicle_q[v.id] += q
    for v in sc.vehicles:
        total += weights[v.id] * vehicle_q[v.id]
        if v.energy_budget_j is not None:
            feasible &= vehicle_q[v.id] <= v.energy_budget_j * (1 + BUDGET_RTOL)
    info = {"method": f"enumeration ({n_comb} combinations)", "n_variables": len(prob.free),
            "n_constraints": 0, "mip_gap": 0.0}
    if not feasible.any():
        info["why"] = "no assignment satisfies the gross-weight and battery limits" + _why(sc, prob)
        info["status"] = "infeasible"
        return None, info
    k = int(np.argmin(np.where(feasible, total, np.inf)))
    best = dict(prob.fixed)
    for j, s in enumerate(prob.free):
        best[s] = prob.options[j][choice[k, j]]
    info["status"] = "optimal"
    info["objective"] = float(total[k])
    return best, info


def _why(sc: Scenario, prob: _Day) -> str:
    """A hint at the binding limit: a route over its gross limit with its fixed stops."""
    for ri, r in enumerate(sc.routes):
        v = sc.vehicle_by_id[r.vehicle_id]
        if v.max_gross_kg is None:
            continue
        fixed = [prob.payload[s] for s in r.stops if prob.fixed.get(s) == ri]
        if sc.mass_model == "carried":
            m = v.kerb_mass_kg + sum(fixed)
        else:
            m = v.kerb_mass_kg + max(fixed, default=0.0)
        if m > v.max_gross_kg:
            return f" (route {r.id!r}: {m:g} kg with its own stops alone, over {v.id}'s {v.max_gross_kg:g} kg)"
    return ""


def _solve_milp(sc: Scenario, prob: _Day, time_limit_s: float | None) -> tuple[dict[str, int] | None, dict]:
    """The exact MILP of the module docstring, solved with HiGHS."""
    from scipy.optimize import Bounds, LinearConstraint, milp
    from scipy.sparse import csr_matrix

    t_day = sc.ambient_of(prob.d)
    weights = _weights(sc)
    fv = sc.vehicle_by_id
    # binaries: one per (free stop, option)
    opt_stop: list[int] = []
    opt_route: list[int] = []
    for j, opts in enumerate(prob.options):
        for ri in opts:
            opt_stop.append(j)
            opt_route.append(ri)
    n_x = len(opt_route)
    opt_of = {(prob.free[j], ri): k for k, (j, ri) in enumerate(zip(opt_stop, opt_route))}
    pay_x = np.array([prob.payload[prob.free[j]] for j in opt_stop])

    # Linear pieces of every leg: lists of (vehicle, q-const, {x: coef}) or epigraph legs.
    const = {v.id: 0.0 for v in sc.vehicles}  # per vehicle, quantity units
    lin_x = {v.id: np.zeros(n_x) for v in sc.vehicles}  # per vehicle, d quantity / d x
    epi: list[tuple[str, LegCurve, float, np.ndarray, np.ndarray]] = []  # (vid, curve, m0, x idx, payloads)
    x_ub = np.ones(n_x)
    gross_rows: list[tuple[np.ndarray, np.ndarray, float]] = []
    for ri, r in enumerate(sc.routes):
        v = fv[r.vehicle_id]
        kerb = v.kerb_mass_kg
        stop_x = [opt_of.get((s, ri)) for s in r.stops]
        fixed_pay = np.array([prob.payload[s] if prob.fixed.get(s) == ri else 0.0 for s in r.stops])
        if sc.mass_model == "paper-eq32":
            # each served stop: one leg at kerb + its payload
            for k, s in enumerate(r.stops):
                if stop_x[k] is None and prob.fixed.get(s) != ri:
                    continue
                m = kerb + prob.payload[s]
                q = float(_quantity(predict(r.legs[k].vector, v.vehicle, np.array([m]), ambient_c=t_day), v.vehicle)[0])
                if stop_x[k] is None:
                    if v.max_gross_kg is not None and m > v.max_gross_kg:
                        return None, {"method": "milp (HiGHS)", "status": "infeasible",
                                      "why": f"stop {s!r} alone ({m:g} kg) is over {v.id}'s {v.max_gross_kg:g} kg"}
                    const[v.id] += q
                else:
                    lin_x[v.id][stop_x[k]] += q
                    if v.max_gross_kg is not None and m > v.max_gross_kg:
                        x_ub[stop_x[k]] = 0.0
            continue
        # carried: leg l carries the served stops at positions >= l
        xs = np.array([x if x is not None else -1 for x in stop_x])
        m0 = kerb + np.cumsum(fixed_pay[::-1])[::-1]
        if v.max_gross_kg is not None:
            if m0[0] > v.max_gross_kg:
                return None, {"method": "milp (HiGHS)", "status": "infeasible",
                              "why": "no assignment satisfies the limits" + _why(sc, prob)}
            sel = xs[xs >= 0]
            if sel.size:
                gross_rows.append((sel, pay_x[sel], v.max_gross_kg - m0[0]))
        n_stop_legs = len(r.stops)
        for l, leg in enumerate(r.legs):
            if l >= n_stop_legs:  # the return leg, empty
                const[v.id] += float(_quantity(predict(leg.vector, v.vehicle, np.array([kerb]), ambient_c=t_day),
                                               v.vehicle)[0])
                continue
            sel = xs[l:][xs[l:] >= 0]
            if sel.size == 0:
                const[v.id] += float(_quantity(predict(leg.vector, v.vehicle, np.array([m0[l]]), ambient_c=t_day),
                                               v.vehicle)[0])
                continue
            m_hi = m0[l] + pay_x[sel].sum()
            if v.max_gross_kg is not None:
                m_hi = min(m_hi, v.max_gross_kg)
            curve = leg_curve(leg.vector, v.vehicle, m0[l], max(m_hi, m0[l]), ambient_c=t_day)
            if curve.affine:
                const[v.id] += float(curve.alpha[0] + curve.beta[0] * m0[l])
                lin_x[v.id][sel] += curve.beta[0] * pay_x[sel]
            else:
                epi.append((v.id, curve, float(m0[l]), sel, pay_x[sel]))

    n_t = len(epi)
    n_var = n_x + n_t
    # scale: objective about _MILP_OBJECTIVE_SCALE; masses in tonnes in the gross rows
    ref = sum(abs(const[v.id]) * weights[v.id] for v in sc.vehicles)
    ref += sum(float(np.max(np.abs(c.alpha + c.beta * m0))) * weights[vid] for vid, c, m0, _, _ in epi)
    qscale = {v.id: weights[v.id] * _MILP_OBJECTIVE_SCALE / ref if ref > 0 else 1.0 for v in sc.vehicles}
    c = np.zeros(n_var)
    for v in sc.vehicles:
        c[:n_x] += lin_x[v.id] * qscale[v.id]
    for t, (vid, curve, m0, sel, pay) in enumerate(epi):
        c[n_x + t] = qscale[vid]
    rows, cols, vals, lo, hi = [], [], [], [], []
    n_row = 0

    def add_row(idx, coef, lb, ub):
        nonlocal n_row
        rows.append(np.full(len(idx), n_row))
        cols.append(np.asarray(idx))
        vals.append(np.asarray(coef, dtype=np.float64))
        lo.append(lb)
        hi.append(ub)
        n_row += 1

    for j in range(len(prob.free)):
        add_row(np.flatnonzero(np.array(opt_stop) == j), np.ones(len(prob.options[j])), 1.0, 1.0)
    for sel, pay, cap in gross_rows:
        add_row(sel, pay / 1e3, -np.inf, cap / 1e3)
    for t, (vid, curve, m0, sel, pay) in enumerate(epi):
        s = qscale[vid] if qscale[vid] > 0 else 1.0
        for a, b in zip(curve.alpha, curve.beta):
            # t >= a + b (m0 + sum pay x)  <=>  b pay . x - t <= -(a + b m0)
            add_row(np.append(sel, n_x + t), np.append(b * pay * s, -s), -np.inf, -(a + b * m0) * s)
    for v in sc.vehicles:
        budget = v.energy_budget_j
        if budget is None:
            continue
        budget *= 1 + BUDGET_RTOL
        ts = [n_x + t for t, e in enumerate(epi) if e[0] == v.id]
        s = _MILP_OBJECTIVE_SCALE / max(budget, 1.0)
        idx = np.concatenate([np.flatnonzero(lin_x[v.id]), ts]).astype(int)
        coef = np.concatenate([lin_x[v.id][lin_x[v.id] != 0], np.ones(len(ts))]) * s
        if idx.size:
            add_row(idx, coef, -np.inf, (budget - const[v.id]) * s)
        elif const[v.id] > budget:
            return None, {"method": "milp (HiGHS)", "status": "infeasible",
                          "why": f"{v.id} needs {const[v.id] / J_PER_KWH:.1f} kWh, over its budget"}
    info: dict[str, Any] = {"method": "milp (HiGHS)", "n_variables": n_var, "n_constraints": n_row}
    if n_x == 0:
        info.update(status="optimal", mip_gap=0.0, objective=sum(const[v.id] * weights[v.id] for v in sc.vehicles))
        return dict(prob.fixed), info
    A = csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n_row, n_var))
    integrality = np.concatenate([np.ones(n_x), np.zeros(n_t)])
    bounds = Bounds(np.concatenate([np.zeros(n_x), np.full(n_t, -np.inf)]), np.concatenate([x_ub, np.full(n_t, np.inf)]))
    options: dict[str, Any] = {"mip_rel_gap": 0.0, "presolve": True}
    if time_limit_s is not None:
        options["time_limit"] = float(time_limit_s)
    res = milp(c, integrality=integrality, bounds=bounds,
               constraints=LinearConstraint(A, np.array(lo), np.array(hi)), options=options)
    status = {0: "optimal", 1: "time limit", 2: "infeasible", 3: "unbounded", 4: "error"}.get(res.status, str(res.status))
    info["status"] = status
    info["mip_gap"] = getattr(res, "mip_gap", None)
    if res.x is None:
        info["why"] = (
            "no assignment satisfies the gross-weight and battery limits" + _why(sc, prob)
            if status == "infeasible"
            else f"MILP solver stopped: {res.message}"
        )
        return None, info
    x = res.x[:n_x] > 0.5
    best = dict(prob.fixed)
    for k in np.flatnonzero(x):
        best[prob.free[opt_stop[k]]] = opt_route[k]
    # back to objective units
    scale_back = ref / _MILP_OBJECTIVE_SCALE if ref > 0 else 1.0
    info["objective"] = float(res.fun) * scale_back + sum(const[v.id] * weights[v.id] for v in sc.vehicles)
    return best, info


# --- reports --------------------------------------------------------------------------------


def table4_rows(plans: Sequence[Plan]) -> list[dict[str, str]]:
    """The paper's table 4: one row per vehicle, one column per day, the stops it
    serves (space-separated, in driving order)."""
    if not plans:
        return []
    vids = [v.vehicle_id for v in plans[0].evaluation.vehicles]
    rows = []
    for vid in vids:
        row = {"vehicle": vid}
        for p in plans:
            row[p.day] = " ".join(p.stops_per_vehicle()[vid])
        rows.append(row)
    return rows
