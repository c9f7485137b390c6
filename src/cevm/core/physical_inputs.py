"""Checks of physical inputs, one wording for every command (pure).

A gross mass, a payload, a state of charge, an efficiency or a temperature that no
vehicle can have is refused here, with one message, whichever command or function it
came through (``cevm predict``, ``feasibility``, ``simulate``,
:class:`cevm.core.sweep.PredictionSet`, :func:`cevm.core.feasibility.feasibility`). Each
check raises :class:`PhysicalInputError` (an :class:`~cevm.errors.InputError`, so the
command line prints it as one line and exits 2) naming the quantity, the value and the
range it must lie in.

What stays a flag, not an error: a gross mass above the vehicle's ``max_gross_kg`` (an
overloaded vehicle is a real question: ``over_max_gross``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from cevm.core import energy
from cevm.errors import InputError

#: Heaviest gross mass accepted [kg]: beyond the heaviest road trains (about 200 t). The
#: same bound as the vehicle files' (:data:`cevm.core.vehicle.PLAUSIBLE`).
MAX_GROSS_MASS_KG = 200_000.0


class PhysicalInputError(InputError):
    """A physical input outside what a vehicle can have (see the module notes)."""

    def __init__(self, message: str):
        super().__init__(None, message)

    def __str__(self) -> str:
        return self.message


def _first_bad(values: np.ndarray, bad: np.ndarray) -> float:
    return float(values[bad].flat[0]) if values.ndim else float(values)


def gross_masses_kg(values, what: str = "gross mass") -> np.ndarray:
    """Gross masses [kg] as a float array: finite, > 0 and at most
    :data:`MAX_GROSS_MASS_KG`, else :class:`PhysicalInputError`."""
    m = np.asarray(values, dtype=np.float64)
    bad = ~np.isfinite(m)
    if np.any(bad):
        raise PhysicalInputError(f"{what} {_first_bad(m, bad)!r} kg is not a finite number")
    bad = m <= 0
    if np.any(bad):
        raise PhysicalInputError(f"{what} {_first_bad(m, bad):g} kg is not positive")
    bad = m > MAX_GROSS_MASS_KG
    if np.any(bad):
        raise PhysicalInputError(f"{what} {_first_bad(m, bad):,g} kg is beyond {MAX_GROSS_MASS_KG:,g} kg, more "
                                 "than the heaviest road vehicle (a unit mistake?)")
    return m


def payloads_kg(values) -> np.ndarray:
    """Payloads [kg] as a float array: finite, >= 0 and at most
    :data:`MAX_GROSS_MASS_KG`, else :class:`PhysicalInputError`."""
    p = np.asarray(values, dtype=np.float64)
    bad = ~np.isfinite(p)
    if np.any(bad):
        raise PhysicalInputError(f"payload {_first_bad(p, bad)!r} kg is not a finite number")
    bad = p < 0
    if np.any(bad):
        raise PhysicalInputError(f"payload {_first_bad(p, bad):g} kg is negative: a payload is what the vehicle "
                                 "carries, 0 kg or more")
    bad = p > MAX_GROSS_MASS_KG
    if np.any(bad):
        raise PhysicalInputError(f"payload {_first_bad(p, bad):,g} kg is beyond {MAX_GROSS_MASS_KG:,g} kg, more "
                                 "than the heaviest road vehicle (a unit mistake?)")
    return p


def not_below_kerb(vehicle, masses_kg) -> None:
    """Refuse a gross mass below the vehicle's kerb mass (:class:`PhysicalInputError`);
    a vehicle without ``kerb_mass_kg`` is not checked."""
    kerb = getattr(vehicle, "kerb_mass_kg", None)
    if kerb is None:
        return
    m = np.asarray(masses_kg, dtype=np.float64)
    bad = m < kerb
    if np.any(bad):
        label = getattr(vehicle, "label", vehicle.name)
        raise PhysicalInputError(f"gross mass {_first_bad(m, bad):,g} kg is below the kerb mass {kerb:,g} kg of "
                                 f"vehicle {label!r}: a gross mass is the vehicle itself plus its payload "
                                 "(for a load on the vehicle, give a payload)")


def masses_for(vehicles: Sequence, masses_kg) -> np.ndarray:
    """:func:`gross_masses_kg` and :func:`not_below_kerb` for each of ``vehicles``."""
    m = gross_masses_kg(masses_kg)
    for v in vehicles:
        not_below_kerb(v, m)
    return m


def soc_pct(soc_start_pct: float, reserve_pct: float | None = None) -> None:
    """The state of charge at the start must be in (0, 100] %, the reserve in
    [0, 100) % (:class:`PhysicalInputError`)."""
    if not (isinstance(soc_start_pct, (int, float)) and math.isfinite(soc_start_pct)
            and 0.0 < soc_start_pct <= 100.0):
        raise PhysicalInputError(f"state of charge at the start {soc_start_pct!r} % is outside (0, 100] %")
    if reserve_pct is not None and not (isinstance(reserve_pct, (int, float)) and math.isfinite(reserve_pct)
                                        and 0.0 <= reserve_pct < 100.0):
        raise PhysicalInputError(f"reserve state of charge {reserve_pct!r} % is outside [0, 100) %")


def efficiency(value: float, what: str = "efficiency") -> float:
    """An efficiency in (0, 1] (:class:`PhysicalInputError`)."""
    if not (isinstance(value, (int, float)) and math.isfinite(value) and 0.0 < value <= 1.0):
        raise PhysicalInputError(f"{what} {value!r} is outside (0, 1]: an efficiency is a fraction")
    return float(value)


def ambient_c(values) -> np.ndarray:
    """Ambient temperatures [degC] within :data:`cevm.core.energy.AMBIENT_RANGE_C`
    (:class:`PhysicalInputError`, with :func:`cevm.core.energy.check_ambient_c`'s words)."""
    try:
        return energy.check_ambient_c(values)
    except ValueError as exc:
        raise PhysicalInputError(str(exc)) from None
