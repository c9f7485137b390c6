"""The former name of :mod:`cevm.core.physical_inputs`, kept only for
:mod:`cevm.core.sweep`, which another branch is splitting into a package: once that
lands, its ``from cevm.core import checks`` becomes ``physical_inputs`` and this module
goes. Import :mod:`cevm.core.physical_inputs`."""

from cevm.core.physical_inputs import (
    MAX_GROSS_MASS_KG,
    PhysicalInputError,
    ambient_c,
    efficiency,
    gross_masses_kg,
    masses_for,
    not_below_kerb,
    payloads_kg,
    soc_pct,
)

__all__ = ["MAX_GROSS_MASS_KG", "PhysicalInputError", "ambient_c", "efficiency", "gross_masses_kg", "masses_for",
           "not_below_kerb", "payloads_kg", "soc_pct"]
