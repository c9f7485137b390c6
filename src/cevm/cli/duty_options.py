"""The candidate vehicle and its charging, as the commands that run duties read them
from their options (``cevm replay`` on logged days, ``cevm gtfs`` on a timetable's
blocks): one reading for both, so that the same options mean the same in each."""

from __future__ import annotations

import dataclasses
import math
from types import SimpleNamespace

from cevm.core.replay import DEFAULT_PLACE_RADIUS_M, Charging, Place, ReplaySettings
from cevm.core.vehicle import Vehicle
from cevm.errors import CevmError
from cevm.units import J_PER_KWH


def parse_place(text: str, option: str) -> Place | str:
    """``LAT,LON,RADIUS_M`` (or ``LAT,LON``: the default radius) as a :class:`Place`, or
    ``depot``."""
    if text.strip().lower() == "depot":
        return "depot"
    parts = [p.strip() for p in text.split(",")]
    try:
        nums = [float(p) for p in parts]
    except ValueError:
        nums = []
    if len(nums) not in (2, 3) or not all(math.isfinite(x) for x in nums):
        raise CevmError(f"{option} {text!r}: give LAT,LON,RADIUS_M in degrees and metres (e.g. 52.06,-0.70,500), "
                        "or 'depot'")
    try:
        return Place(nums[0], nums[1], nums[2] if len(nums) == 3 else DEFAULT_PLACE_RADIUS_M)
    except ValueError as exc:
        raise CevmError(f"{option} {text!r}: {exc}") from None


def build_charging(vehicle, charger_kw, min_dwell_min, efficiency, charge_at, refuel_at, depot_radius_m,
                   overnight, overnight_kw) -> Charging:
    """The :class:`Charging` of the options, refused where they do not fit the candidate."""
    places = [parse_place(t, "--charge-at") for t in charge_at or []]
    places += [parse_place(t, "--refuel-at") for t in refuel_at or []]
    if vehicle.is_ev and refuel_at:
        raise CevmError("--refuel-at is for a diesel candidate; an electric one charges (--charge-at)")
    if not vehicle.is_ev and (charge_at or charger_kw or overnight_kw):
        raise CevmError("--charge-at, --charger-kw and --overnight-kw are for an electric candidate; a diesel one "
                        "refuels to full at --refuel-at places and overnight (--overnight full|none)")
    if overnight_kw is not None and overnight is not None:
        raise CevmError("give --overnight full|none or --overnight-kw, not both")
    mode = "power" if overnight_kw is not None else (overnight or "full")
    if mode not in ("full", "none", "power"):
        raise CevmError(f"--overnight {overnight!r}: give full or none (or --overnight-kw P)")
    try:
        return Charging(power_w=1e3 * (charger_kw or 0.0), min_dwell_s=60.0 * min_dwell_min, efficiency=efficiency,
                        places=tuple(p for p in places if isinstance(p, Place)), depot="depot" in places,
                        depot_radius_m=depot_radius_m, overnight=mode,
                        overnight_w=1e3 * (overnight_kw or 0.0))
    except ValueError as exc:
        raise CevmError(str(exc)) from None


def describe_run(vehicle, settings: ReplaySettings, tz_name: str) -> dict[str, str]:
    """The run's assumptions as the rows say them."""
    ch = settings.charging
    where = [p.describe() for p in ch.places] + (["the vehicle's depot"] if ch.depot else [])
    places = "anywhere" if ch.anywhere else "; ".join(where)
    if not vehicle.is_ev and ch.anywhere:
        places = "nowhere (no --refuel-at)"
    overnight = {"full": "full", "none": "none"}.get(ch.overnight, f"{ch.overnight_w / 1e3:g} kW")
    rule = (f"a stop of at least {settings.gap_s / 3600:g} h ends a duty" if settings.rule == "gap"
            else f"calendar day in {tz_name}")
    lowest = "inside the trips" if settings.within_trips else "at the trips' ends"
    return {"charge_places": places, "overnight": overnight, "duty_rule": rule, "lowest_at": lowest}


def candidate_vehicle(o: SimpleNamespace) -> Vehicle:
    """The one candidate vehicle (``-v``), with ``--battery-kwh`` applied to an electric one."""
    from cevm.io import load_vehicles

    vehicles = load_vehicles(o.vehicle)
    if len(vehicles) != 1:
        raise CevmError(f"give one candidate vehicle file (-v), not {len(vehicles)}")
    v = vehicles[0]
    if o.battery_kwh is not None:
        if not v.is_ev:
            raise CevmError("--battery-kwh is for an electric candidate")
        v = dataclasses.replace(v, battery_j=o.battery_kwh * J_PER_KWH)
    return v
