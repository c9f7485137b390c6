"""Reading vehicle files (TOML; keys: see :mod:`cevm.core.vehicle`)."""

from __future__ import annotations

from pathlib import Path

from cevm.core.vehicle import Vehicle, vehicle_from_mapping
from cevm.errors import InputError
from cevm.io.toml import read_toml


def load_vehicle(path: str | Path) -> Vehicle:
    """Read and validate a vehicle TOML file (keys: see :mod:`cevm.core.vehicle`)."""
    return vehicle_from_mapping(read_toml(path, "vehicle file"), str(path))


def load_vehicles(paths: list[str | Path]) -> list[Vehicle]:
    """Load vehicle files; a directory contributes its ``*.toml`` files, sorted."""
    out: list[Vehicle] = []
    for p in paths:
        p = Path(p)
        if p.is_dir():
            files = sorted(p.glob("*.toml"))
            if not files:
                raise InputError(p, "directory holds no vehicle files (*.toml)")
            out.extend(load_vehicle(f) for f in files)
        else:
            out.append(load_vehicle(p))
    return out
