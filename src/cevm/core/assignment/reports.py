"""Report rows of a fleet plan."""

from __future__ import annotations

from collections.abc import Sequence

from cevm.core.assignment.planning import Plan


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
