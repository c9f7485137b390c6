"""``cevm trips``: what is stored."""

from __future__ import annotations

from typing import Annotated, Optional

import typer

from cevm.cli.common import StoreOption, existing_store, fail
from cevm.cli.output import OutputFormat, write_rows
from cevm.errors import CevmError


def trips(
    store: StoreOption = None,
    vehicle_id: Annotated[Optional[str], typer.Option("--vehicle-id", help="Only this vehicle's trips.")] = None,
    fmt: Annotated[OutputFormat, typer.Option("--format", "-f", help="Output format.")] = OutputFormat.table,
) -> None:
    """List the stored trips."""
    from cevm.store import TripStore, format_trips

    path = existing_store(store)
    try:
        with TripStore.open(path, readonly=True) as st:
            df = format_trips(st.list_trips(vehicle_id=vehicle_id))
    except CevmError as exc:
        raise fail(exc) from None
    rows = [{k: (None if isinstance(v, float) and v != v else v) for k, v in r.items()} for r in df.to_dict("records")]
    columns = ["trip_id", "vehicle_id", "start_utc", "distance_km", "duration_s", "measured_fuel_l",
               "measured_energy_kwh", "dsm_coverage_pct", "elevation_source"]
    if fmt == OutputFormat.table:
        columns = [c for c in columns if any(r.get(c) is not None for r in rows)] or columns[:5]
        write_rows(rows, fmt, columns=columns, title=f"cevm trips ({len(rows)})", headers=TRIPS_HEADERS,
                   digits={"duration_s": 0, "dsm_coverage_pct": 1, "distance_km": 2})
    else:
        write_rows(rows, fmt)


TRIPS_HEADERS = {"vehicle_id": "vehicle", "start_utc": "start (UTC)", "distance_km": "km", "duration_s": "s",
                 "measured_fuel_l": "fuel l", "measured_energy_kwh": "kWh", "dsm_coverage_pct": "DSM %",
                 "elevation_source": "elevation"}
