"""Report rows of a fleet plan, and the calibration-domain warnings of its plans."""

from __future__ import annotations

from collections.abc import Sequence

from cevm.core.assignment.planning import Plan
from cevm.core.assignment.scenario import Scenario
from cevm.core.vehicle import default_ambient_c, domain_warnings


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


def calibration_warnings(sc: Scenario, plans: Sequence[Plan]) -> list[str]:
    """Warnings for the fleet's vehicles asked outside what their calibration saw
    (:func:`cevm.core.vehicle.domain_warnings`; none for a vehicle file that was not
    calibrated), over ``plans``: the gross masses of the legs each vehicle drives under
    the chosen assignment, the days' ambient temperatures (the vehicle's default where a
    day gives none) and the mean speeds of its routes' legs. Each line starts with the
    fleet's id of the vehicle."""
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
    out: list[str] = []
    for v in sc.vehicles:
        if not masses.get(v.id):
            continue
        out.extend(f"{v.id}: {w}" for w in domain_warnings(v.vehicle, mass_kg=masses[v.id], ambient_c=temps[v.id],
                                                            mean_speed_mps=speeds.get(v.id) or None))
    return out
