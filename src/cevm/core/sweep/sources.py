"""Sources: what a vehicle drives (a cycle file, a stored trip, a named route of legs).

A :class:`Source` carries its CE drive-cycle vector (:class:`~cevm.core.cycle.CycleVector`,
for totals) and its legs' profiles (time, speed, elevation: for the state of charge along
the way, the range and the power it asks), from which it builds, on first use and once,
its compressed step terms (:class:`~cevm.core.sweep.compressed.SourceSteps`) and its
plain step table (:class:`~cevm.core.sweep.steptable.StepTable`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cached_property

from cevm.core.cycle import CR0_DEFAULT, PAPER_PHYSICS, CycleVector, DriveCycle, Physics, cycle_vector
from cevm.core.limits import Demand, source_demand
from cevm.core.sweep.compressed import BLOCK_ELEMENTS, SourceSteps, steps_of_table
from cevm.core.sweep.steptable import LegProfile, StepTable, build_step_table


@dataclass(frozen=True, eq=False)
class Source:
    """Something to drive: its name, kind (``"cycle"``, ``"trip"`` or ``"route"``), CE
    vector, and its legs' profiles (a sequence, or a callable returning one, called at
    most once and only when the state of charge along the way is needed).
    ``ambient_c``: the source's own ambient temperature [degC] (a stored trip's logged
    mean), or None (see :data:`AMBIENT_ORIGINS` for what a prediction uses then).
    ``logged``: a measured trace (a stored trip, a route of them), held to a vehicle's
    limits with its measurement's tolerance, and ``elevation_sd_m`` its elevation's
    uncertainty [m] (:mod:`cevm.core.limits`); a cycle file is a target, held exactly.
    ``leg_vectors`` and ``leg_ambient_c``: a route's legs, each with its own logged
    temperature, so that the terms that depend on the temperature are taken leg by leg
    (:func:`cevm.core.sweep.predictions.row_terms`): a day stored as a route is then the
    sum of its trips, each heated at its own temperature and warmed up at its own start
    (``ambient_c`` stays the duration-weighted mean, for the rows)."""

    name: str
    kind: str
    vector: CycleVector
    legs: Sequence[LegProfile] | Callable[[], Sequence[LegProfile]]
    block_elements: int = BLOCK_ELEMENTS
    ambient_c: float | None = None
    logged: bool = False
    elevation_sd_m: float = 0.0
    leg_vectors: tuple[CycleVector, ...] | None = None
    leg_ambient_c: tuple[float, ...] | None = None

    @classmethod
    def from_cycle(cls, cycle: DriveCycle, name: str | None = None, *, cr0: float = CR0_DEFAULT,
                   physics: Physics = PAPER_PHYSICS) -> Source:
        """A cycle as a source: its vector (with ``cr0``) and its one leg."""
        return cls(name=name if name is not None else (cycle.name or "cycle"), kind="cycle",
                   vector=cycle_vector(cycle, cr0=cr0, physics=physics),
                   legs=(LegProfile(cycle.time_s, cycle.speed_mps, cycle.elevation_m),))

    @cached_property
    def leg_profiles(self) -> tuple[LegProfile, ...]:
        return tuple(self.legs() if callable(self.legs) else self.legs)

    @cached_property
    def steps(self) -> SourceSteps:
        """The compressed step terms (built on first use, then kept)."""
        return steps_of_table(self.step_table, cr0=self.vector.cr0, block_elements=self.block_elements)

    @cached_property
    def step_table(self) -> StepTable:
        """The plain per-step terms in driving order (built on first use, then kept):
        for the range (:func:`source_ranges`) and the power a cycle asks
        (:func:`follow_flags`)."""
        return build_step_table(self.leg_profiles, cr0=self.vector.cr0, physics=self.vector.physics)

    @cached_property
    def demand(self) -> Demand:
        """What the source asks of a vehicle: its held top speed and the power of each
        window (:func:`cevm.core.limits.source_demand`; built on first use, then kept)."""
        return source_demand(self.step_table, self.leg_profiles, logged=self.logged,
                             elevation_sd=self.elevation_sd_m)

    def release(self) -> None:
        """Forget the cached profiles and step terms (their memory): for a sweep that is
        done with this source. They are rebuilt if asked for again."""
        self.__dict__.pop("steps", None)
        self.__dict__.pop("step_table", None)
        self.__dict__.pop("leg_profiles", None)
        self.__dict__.pop("demand", None)

    @property
    def distance_m(self) -> float:
        return self.vector.distance_m

    @property
    def duration_s(self) -> float:
        return self.vector.duration_s

