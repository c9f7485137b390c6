"""The verdict of a plan (pure): each vehicle's day held to the same flags as every
other command (:mod:`cevm.core.limits`), and how a plan's choices compare with a
reference (the paper's table 4).

The optimiser keeps each vehicle within its gross-weight limit and its EV energy budget
(or the tank); whether the vehicle can follow each leg it drives at the mass it carries
(``max_power_kw``, ``max_speed_kmh``) is checked here, leg by leg, and said: in the
plan's JSON (each vehicle's ``verdict``), in its warnings and in the table.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np

from cevm.core import limits
from cevm.core.assignment.evaluation import leg_names
from cevm.core.assignment.scenario import BUDGET_RTOL, Leg, Scenario

if TYPE_CHECKING:
    from cevm.core.assignment.planning import Plan
    from cevm.core.limits import Demand
    from cevm.core.vehicle import Vehicle

#: What a plan asks of its legs: the :class:`~cevm.core.limits.Demand` of a leg (None:
#: its profile is not known, so power and speed are not checked).
LegDemand = Callable[[Leg], "Demand | None"]


def vehicle_verdicts(sc: Scenario, plan: Plan, demand_of: LegDemand | None) -> dict[str, dict]:
    """Each vehicle's verdict on the day of ``plan``, by fleet id: ``feasible`` (the one
    verdict of :func:`cevm.core.limits.verdict`: within max_gross_kg, max_power_kw and
    max_speed_kmh on every leg it drives, and the energy budget (EV) or the tank (ICE)),
    ``over_max_gross``, ``energy_ok``, and the legs it cannot follow (``over_power``,
    ``over_speed``: a list of {route, leg, mass_kg, power_demand_kw} each)."""
    routes = {r.id: r for r in sc.routes}
    fleet = sc.vehicle_by_id
    out = {}
    for vu in plan.evaluation.vehicles:
        veh = fleet[vu.vehicle_id].vehicle
        over_p: list[dict] = []
        over_v: list[dict] = []
        checked_p = checked_v = False
        for ru in vu.routes:
            route = routes[ru.route_id]
            names = leg_names(route)
            for name, mass in zip(ru.leg_names, ru.leg_mass_kg, strict=True):
                demand = None if demand_of is None else demand_of(route.legs[names.index(name)])
                if demand is None or (veh.max_power_w is None and veh.max_speed_mps is None):
                    continue
                p, v, need_w = limits.follow_flags(demand, veh, mass)
                entry = {"route": ru.route_id, "leg": name, "mass_kg": mass, "power_demand_kw": float(need_w[0]) / 1e3}
                checked_p |= veh.max_power_w is not None
                checked_v |= veh.max_speed_mps is not None
                if p[0] == 1.0:
                    over_p.append(entry)
                if v[0] == 1.0:
                    over_v.append(entry)
        gross = vu.max_gross_kg is not None and vu.max_gross_used_kg > vu.max_gross_kg * (1 + 1e-12)
        energy_ok: bool | None = None  # the day's energy against the budget (EV) or the tank (ICE)
        if veh.is_ev and vu.energy_budget_j is not None and vu.energy_j is not None:
            energy_ok = vu.energy_j <= vu.energy_budget_j * (1 + BUDGET_RTOL)
        elif not veh.is_ev and veh.tank_l is not None and vu.fuel_l is not None:
            energy_ok = vu.fuel_l <= veh.tank_l
        flags = limits.verdict(is_ev=veh.is_ev, over_max_gross=float(gross),
                               over_power=float(bool(over_p)) if checked_p else np.nan,
                               over_speed=float(bool(over_v)) if checked_v else np.nan,
                               energy_ok=np.nan if energy_ok is None else float(energy_ok))
        feasible = float(flags["feasible"])
        out[vu.vehicle_id] = {
            "feasible": None if feasible != feasible else feasible == 1.0,
            "over_max_gross": gross,
            "energy_ok": energy_ok,
            "over_power": over_p if checked_p else None,
            "over_speed": over_v if checked_v else None,
        }
    return out


def verdict_warnings(day: str, verdicts: Mapping[str, dict], vehicles: Mapping[str, Vehicle]) -> list[str]:
    """One warning per vehicle of a day that cannot follow a leg it is planned on."""
    out = []
    for vid, vd in verdicts.items():
        veh = vehicles[vid]
        for key, what, limit in (("over_power", "wheel power", "max_power_kw"),
                                 ("over_speed", "speed", "max_speed_kmh")):
            legs = vd.get(key) or []
            if legs:
                worst = max(legs, key=lambda e: e["mass_kg"])
                value = (f"{(veh.max_power_w or 0.0) / 1e3:g} kW" if key == "over_power"
                         else f"{(veh.max_speed_mps or 0.0) * 3.6:g} km/h")
                out.append(f"{day}: {vid} is planned on {len(legs)} leg(s) asking more {what} than its {limit} "
                           f"({value}), e.g. {worst['route']} '{worst['leg']}' at {worst['mass_kg']:,.0f} kg "
                           f"(asks {worst['power_demand_kw']:,.0f} kW over 5 s); the plan keeps the gross and energy "
                           "limits only")
    return out


def reference_differences(plans: Sequence[Plan], reference: Mapping[str, Mapping[str, str]]
                          ) -> list[dict[str, str | None]]:
    """Where the plans' choices differ from a reference (day -> stop -> vehicle id, e.g.
    the paper's table 4): one {day, stop, planned, reference} per difference, in order."""
    out = []
    for p in plans:
        want = reference.get(p.day)
        if not want:
            continue
        for stop, vid in want.items():
            route = p.assignment.get(stop)
            planned = None if route is None else p.route_vehicle[route]
            if planned != vid:
                out.append({"day": p.day, "stop": stop, "planned": planned, "reference": vid})
    return out
