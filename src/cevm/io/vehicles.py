"""Reading vehicle files (TOML; keys: see :mod:`cevm.core.vehicle`).

A vehicle's id (what rows and legends call it) is the file's ``id`` key, else the
file's stem (``configs/vehicles/diesel-hgv.toml`` -> ``diesel-hgv``). Vehicles loaded
together must have different ids: two calibrations of one vehicle are told apart by them.
"""

from __future__ import annotations

from pathlib import Path

from cevm.core.vehicle import Vehicle, vehicle_from_mapping
from cevm.errors import InputError
from cevm.io.toml import read_toml


def stem_id(path: str | Path) -> str:
    """The id a vehicle file without an ``id`` key gets: its stem, with any control
    character escaped (a file name cannot forge output)."""
    from cevm.text import printable

    return printable(Path(path).stem)


def load_vehicle(path: str | Path) -> Vehicle:
    """Read and validate a vehicle TOML file (keys: see :mod:`cevm.core.vehicle`)."""
    return vehicle_from_mapping(read_toml(path, "vehicle file"), str(path), default_id=stem_id(path))


def load_vehicles(paths: list[str | Path]) -> list[Vehicle]:
    """Load vehicle files; a directory contributes its ``*.toml`` files, sorted. Raises
    :class:`InputError` when two of them have the same id."""
    out: list[Vehicle] = []
    where: dict[str, Path] = {}
    for p in paths:
        p = Path(p)
        if p.is_dir():
            files = sorted(p.glob("*.toml"))
            if not files:
                raise InputError(p, "directory holds no vehicle files (*.toml)")
        else:
            files = [p]
        for f in files:
            v = load_vehicle(f)
            if v.id in where:
                raise InputError(f, f"vehicle id {v.id!r} is also the id of {where[v.id]}: give one of them "
                                    "another 'id' key (rows and legends tell vehicles apart by it)")
            where[v.id] = f
            out.append(v)
    return out
