"""The sample fleet's trip manifests: what an operator's systems know of each trip's load,
written from the truth, as :mod:`cevm.io.manifest` reads them.

- ``manifests/bus-loads.csv``: the buses' automatic passenger counters, one row per trip
  (UTC, ``,``-separated): the vehicle, the trip's window and the payload in kg (the
  counted passengers times 75 kg, the paper's figure), the mass the srf logs lack.
- ``manifests/portal-tms.csv``: the transport management system of the portal trucks
  (which record no gross weight): ``;``-separated with decimal commas, UK local time with
  its offset (``2019-10-27T01:30+01:00``: the night of the clock change has an hour twice,
  which a time without its offset could not tell apart), windows to the minute around
  each trip, the gross weight in tonnes to 0.1 t.

Deterministic: the same truth gives the same bytes.
"""

from __future__ import annotations

import math
from datetime import UTC, datetime
from pathlib import Path
from zoneinfo import ZoneInfo

#: Mass per counted passenger [kg] (the paper's 75 kg).
PASSENGER_KG = 75.0

_LONDON = ZoneInfo("Europe/London")


def _iso_utc(t_s: float) -> str:
    return datetime.fromtimestamp(t_s, UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


def _local_minute(t_s: float) -> str:
    local = datetime.fromtimestamp(t_s, UTC).astimezone(_LONDON)
    return local.strftime("%Y-%m-%dT%H:%M") + local.strftime("%z")[:3] + ":" + local.strftime("%z")[3:]


def write_manifests(outdir: Path, records: list[dict]) -> list[Path]:
    """Write the manifests of ``records`` (truth.json's trips) under ``outdir/manifests``;
    returns the paths written (none for a fleet without buses or portal trucks)."""
    out = []
    bus = [r for r in records if r["dialect"] == "srf" and r["load_unit"] == "passengers"]
    if bus:
        lines = ["vehicle_id,start_utc,end_utc,payload_kg"]
        lines.extend(f"{r['vehicle_id']},{_iso_utc(math.floor(r['start_utc_s']))},"
                     f"{_iso_utc(math.ceil(r['end_utc_s']))},{r['load'] * PASSENGER_KG:.0f}"
                     for r in sorted(bus, key=lambda r: (r["vehicle_id"], r["start_utc_s"])))
        out.append(_write(outdir / "manifests" / "bus-loads.csv", "\n".join(lines) + "\n"))
    portal = [r for r in records if r["dialect"] == "portal"]
    if portal:
        lines = ["Registration;Departure;Arrival;Gross weight (t)"]
        for r in sorted(portal, key=lambda r: (r["vehicle_id"], r["start_utc_s"])):
            start = math.floor(r["start_utc_s"] / 60.0) * 60.0
            end = math.ceil(r["end_utc_s"] / 60.0) * 60.0
            gross = f"{r['mass_kg'] / 1000.0:.1f}".replace(".", ",")
            lines.append(f"{r['vehicle_id']};{_local_minute(start)};{_local_minute(end)};{gross}")
        out.append(_write(outdir / "manifests" / "portal-tms.csv", "\r\n".join(lines) + "\r\n"))
    return out


def _write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(text.encode("utf-8"))
    return path
