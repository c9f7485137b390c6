"""Fleet predictions (pure): vehicles x sources x masses, state of charge along the way.

A *source* is what a vehicle drives: a cycle file, a stored trip or a named route (a
sequence of legs). It carries its CE drive-cycle vector (:class:`~cevm.core.cycle.CycleVector`,
for totals) and its legs' profiles (time, speed, elevation; for the state of charge along
the way). A :class:`PredictionSet` is the flat list of (vehicle, mass) predictions of a
sweep; :func:`predict_source` evaluates all of them on one source in numpy arrays, and
:func:`sweep` yields one such block per source, so a million rows never need a million
Python objects.

Totals (wheel energy, battery energy, fuel) are the CE model on the source's vector
(eq. 22-31): :func:`ce_wheel_energy_j` is the formula of :func:`cevm.core.model.wheel_energy_j`
with the positive non-simplified steps summed in one pass for any mix of rolling
coefficients (the model groups predictions by Cr); the two agree to rounding (tested).

State of charge along the way
-----------------------------
SoC_j = SoC_start - 100 E_j / E_batt [%], with E_j the battery energy drawn from the
start to sample j. Over a step, the battery gives g_i = W(Delta_i) / eta + P_aux dt_i
with W(D) = D if D > 0 else eta^2 D (eq. 27-31); E_j = sum_{i<=j} g_i; the final E_n is
the CE model's total. The lowest SoC is SoC_start - 100 max(0, max_j E_j) / E_batt.

Computing max_j E_j per (vehicle, mass) by a plain cumulative sum costs O(steps). This
module gets the same maximum, exactly, at a fraction of that:

1. Per source, once (:class:`SourceSteps`): the per-step terms x = k + e, a, r, dt of
   every leg (:func:`cevm.core.cycle.step_terms`), in time order. Steps that draw energy for
   every admissible vehicle (simplified steps, eq. 8, and standstill on flat ground)
   have g_i >= 0, so a run of them never holds a maximum inside: each maximal run is
   merged into one element (exact). The other steps stay single elements. Elements are
   cut into blocks of about :data:`BLOCK_ELEMENTS`.
2. Per block and prediction, exactly: the block's energy S_b and two upper bounds of
   E_j inside it, C_b + (positive part) and C_{b+1} - (regenerated part), where C_b is
   the energy drawn before block b. These need the sum of the positive Delta_i of the
   block's non-simplified steps for that vehicle and mass: the sign of each step is
   decided once for all masses of a vehicle where they agree (most steps), and by one
   comparison per (vehicle, step) where they differ, then binned by the first mass at
   which the step turns positive (:func:`_positive_parts`). No work per (prediction,
   step) pair.
3. Blocks whose upper bound cannot beat the best value known (0, E_n, the block ends)
   are skipped; the others are summed step by step. Typically one or two blocks per
   prediction are summed, near the end of the route or after a descent.

The result equals a plain per-step loop to floating-point rounding (tested). Several
sources are evaluated together (:func:`sweep`, :data:`SWEEP_BATCH_CELLS`).

ICE rows get the fuel needed (the total) against ``tank_l``: fuel burnt never falls along
a route (the paper's braking credit lowers the *estimate* of the total, not the tank).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from cevm.core import checks, energy
from cevm.core.cycle import (
    CR0_DEFAULT,
    PAPER_PHYSICS,
    CycleVector,
    DriveCycle,
    Physics,
    cycle_vector,
    step_terms,
)
from cevm.core.model import braking_weight
from cevm.core.vehicle import Vehicle
from cevm.errors import CevmError, InputError
from cevm.executors import Executor, Task

#: Default state of charge at the start [%]: a vehicle leaving the depot fully charged.
DEFAULT_SOC_START_PCT = 100.0
#: Default reserve [%]: the paper's example of the level at which commercial EVs warn the
#: driver, "e.g., 15%" (section 3.2, figure 4).
DEFAULT_RESERVE_PCT = 15.0
#: Target number of elements (merged steps) per block of :class:`SourceSteps`. Smaller
#: blocks prune more precisely but cost one more bound per block and prediction; 48 and
#: 64 were the fastest on the benchmark's routes (benchmarks/bench_sweep.py), 32 about
#: 10 % slower, 128 about 15 %.
BLOCK_ELEMENTS = 48
#: Largest number of values a range option may expand to (a typo guard).
MAX_RANGE_VALUES = 10_000_000
#: Work arrays are cut into chunks of about this many float64 elements (8 MB).
_CHUNK_ELEMENTS = 1 << 20
#: Step-by-step sums of the blocks that may hold the maximum are done in chunks of this
#: many elements (64 kB arrays, which stay in the processor's cache: 4x larger chunks
#: were 10 % slower on the benchmark).
_SCAN_CHUNK_ELEMENTS = 1 << 13


# ----------------------------------------------------------------------- value ranges


def parse_values(spec: str, option: str = "value") -> np.ndarray:
    """The numbers of one option value [whatever unit the option has].

    ``spec`` is a number (``"12000"``), a comma-separated list (``"12000,20000"``), or a
    range ``start:stop:step`` whose ``stop`` is *included* when it lies on the grid:
    ``"0:26000:2000"`` gives the 14 values 0, 2000, ..., 26000; ``"0:25000:2000"`` gives
    0 ... 24000 (13 values). Values are ``start + k step`` (no accumulated rounding);
    the last is snapped to ``stop`` when within 1e-9 steps of it. Items of a list may
    themselves be ranges. Raises :class:`~cevm.errors.InputError` naming ``option``.
    """
    out: list[np.ndarray] = []
    for item in str(spec).split(","):
        item = item.strip()
        if not item:
            raise InputError(option, f"empty value in {spec!r}")
        parts = item.split(":")
        try:
            nums = [float(p) for p in parts]
        except ValueError:
            raise InputError(option, f"not a number or a start:stop:step range: {item!r}") from None
        if not all(math.isfinite(v) for v in nums):
            raise InputError(option, f"values must be finite: {item!r}")
        if len(nums) == 1:
            out.append(np.array(nums))
            continue
        if len(nums) != 3:
            raise InputError(option, f"a range is start:stop:step (three numbers), got {item!r}")
        start, stop, step = nums
        if step <= 0:
            raise InputError(option, f"range {item!r}: step must be > 0")
        if stop < start:
            raise InputError(option, f"range {item!r}: stop is below start")
        n = int(math.floor((stop - start) / step + 1e-9)) + 1
        if n > MAX_RANGE_VALUES:
            raise InputError(option, f"range {item!r} has {n} values, more than {MAX_RANGE_VALUES}")
        vals = start + step * np.arange(n, dtype=np.float64)
        if abs(vals[-1] - stop) <= 1e-9 * step:
            vals[-1] = stop
        out.append(vals)
    return np.concatenate(out)


# -------------------------------------------------------------------------- sources


@dataclass(frozen=True, eq=False)
class LegProfile:
    """One leg's samples: time [s] (strictly increasing), speed [m/s], road elevation [m]
    (None for a flat road). Consecutive legs are *not* joined by a step: a route's
    vector is the sum of its legs' vectors, and its profile is the legs one after
    another."""

    time_s: np.ndarray
    speed_mps: np.ndarray
    elevation_m: np.ndarray | None = None

    @classmethod
    def from_profile(cls, profile: Mapping[str, np.ndarray]) -> LegProfile:
        """From a stored profile dict (:meth:`cevm.store.TripStore.load_profile`)."""
        h = profile.get("elevation_m")
        return cls(np.asarray(profile["time_s"], np.float64), np.asarray(profile["speed_mps"], np.float64),
                   None if h is None else np.asarray(h, np.float64))


@dataclass(frozen=True, eq=False)
class SourceSteps:
    """A source's time-ordered step terms, compressed for the lowest state of charge.

    Elements (``n_elements``): ``x`` = sum of k + e [J/kg], ``a`` [J/m^2], ``r`` [J/kg
    per unit Cr], ``dt`` [s]; ``ns`` marks a single non-simplified step (its sign
    depends on the vehicle), else the element is a merged run of steps that draw energy
    for every vehicle with Cr >= cr0. ``block_start`` (K+1) cuts elements into K blocks;
    ``blocks`` (4, K, L) holds each block's x, r, a and dt padded with zeros to the
    longest block, L. Per block (K,): ``fp_x, fp_a, fp_r`` sums over merged
    elements, ``ns_x, ns_a, ns_r`` over non-simplified ones, ``t_s`` the duration.
    ``nsel`` the indices of the non-simplified elements, ``nsel_block`` their block,
    ``nsel_block_start`` (K+1) where each block starts among them.
    """

    x: np.ndarray
    a: np.ndarray
    r: np.ndarray
    dt: np.ndarray
    ns: np.ndarray
    n_steps: int
    block_start: np.ndarray
    blocks: np.ndarray
    fp_x: np.ndarray
    fp_a: np.ndarray
    fp_r: np.ndarray
    ns_x: np.ndarray
    ns_a: np.ndarray
    ns_r: np.ndarray
    t_s: np.ndarray
    nsel: np.ndarray
    nsel_block: np.ndarray
    nsel_block_start: np.ndarray
    cr0: float

    @property
    def n_elements(self) -> int:
        return int(self.x.size)

    @property
    def n_blocks(self) -> int:
        return int(self.block_start.size - 1)


def _leg_terms(legs: Sequence[LegProfile], physics: Physics) -> tuple[np.ndarray, ...]:
    xs, as_, rs, dts = [], [], [], []
    for leg in legs:
        st = step_terms(leg.time_s, leg.speed_mps, leg.elevation_m, physics)
        xs.append(st.k + st.e)
        as_.append(st.a)
        rs.append(st.r)
        dts.append(st.dt)
    if not xs:
        z = np.zeros(0)
        return z, z, z, z
    return np.concatenate(xs), np.concatenate(as_), np.concatenate(rs), np.concatenate(dts)


def _block_sums(values: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    """Sums of ``values`` between consecutive ``bounds`` (empty blocks give 0)."""
    cum = np.concatenate([[0.0], np.cumsum(values)])
    return cum[bounds[1:]] - cum[bounds[:-1]]


def build_steps(
    legs: Sequence[LegProfile],
    *,
    cr0: float = CR0_DEFAULT,
    physics: Physics = PAPER_PHYSICS,
    block_elements: int = BLOCK_ELEMENTS,
) -> SourceSteps:
    """Compress the legs' step terms for :func:`peak_energy_j` (see the module notes).

    Parameters
    ----------
    legs : the source's legs in driving order
    cr0 : Cr0 of criterion (8) [-]; use the source vector's, default 0.004
    physics : air density and gravity (the paper's by default)
    block_elements : target elements per block, default :data:`BLOCK_ELEMENTS`
    """
    x, a, r, dt = _leg_terms(legs, physics)
    n = x.size
    simplified = (x + cr0 * r) > 0
    moving = a > 0
    # Steps with g >= 0 for every vehicle with Cr >= cr0 and aux >= 0: simplified steps
    # (Delta > 0) and standstill on flat ground (Delta = 0, only auxiliary power).
    fp = simplified | (~moving & (x == 0.0))
    start = np.ones(n, dtype=bool)
    if n > 1:
        start[1:] = ~(fp[1:] & fp[:-1])
    starts = np.flatnonzero(start)
    if n:
        ex, ea, er, edt = (np.add.reduceat(v, starts) for v in (x, a, r, dt))
        ens = ~fp[starts]
    else:
        ex = ea = er = edt = np.zeros(0)
        ens = np.zeros(0, dtype=bool)
    nc = int(starts.size)
    k = max(1, int(round(nc / max(1, block_elements))))
    bounds = (np.arange(k + 1, dtype=np.int64) * nc) // k
    lens = np.diff(bounds)
    lmax = max(1, int(lens.max()))
    fpm = ~ens
    nsel = np.flatnonzero(ens)
    idx = bounds[:-1, None] + np.arange(lmax)[None, :]
    inside = np.arange(lmax)[None, :] < lens[:, None]
    idx = np.where(inside, idx, 0)
    blocks = np.stack([np.where(inside, v[idx], 0.0) if nc else np.zeros((k, lmax))
                       for v in (ex, er, ea, edt)])
    return SourceSteps(
        x=ex,
        a=ea,
        r=er,
        dt=edt,
        ns=ens,
        n_steps=int(n),
        block_start=bounds,
        blocks=blocks,
        fp_x=_block_sums(np.where(fpm, ex, 0.0), bounds),
        fp_a=_block_sums(np.where(fpm, ea, 0.0), bounds),
        fp_r=_block_sums(np.where(fpm, er, 0.0), bounds),
        ns_x=_block_sums(np.where(ens, ex, 0.0), bounds),
        ns_a=_block_sums(np.where(ens, ea, 0.0), bounds),
        ns_r=_block_sums(np.where(ens, er, 0.0), bounds),
        t_s=_block_sums(edt, bounds),
        nsel=nsel,
        nsel_block=np.searchsorted(bounds, nsel, side="right") - 1,
        nsel_block_start=np.searchsorted(nsel, bounds),
        cr0=float(cr0),
    )


@dataclass(frozen=True, eq=False)
class Source:
    """Something to drive: its name, kind (``"cycle"``, ``"trip"`` or ``"route"``), CE
    vector, and its legs' profiles (a sequence, or a callable returning one, called at
    most once and only when the state of charge along the way is needed).
    ``ambient_c``: the source's own ambient temperature [degC] (a stored trip's logged
    mean), or None (see :data:`AMBIENT_ORIGINS` for what a prediction uses then)."""

    name: str
    kind: str
    vector: CycleVector
    legs: Sequence[LegProfile] | Callable[[], Sequence[LegProfile]]
    block_elements: int = BLOCK_ELEMENTS
    ambient_c: float | None = None

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
        return build_steps(self.leg_profiles, cr0=self.vector.cr0, physics=self.vector.physics,
                           block_elements=self.block_elements)

    @cached_property
    def step_table(self) -> StepTable:
        """The plain per-step terms in driving order (built on first use, then kept):
        for the range (:func:`source_ranges`) and the power a cycle asks
        (:func:`follow_flags`)."""
        return build_step_table(self.leg_profiles, cr0=self.vector.cr0, physics=self.vector.physics)

    def release(self) -> None:
        """Forget the cached profiles and step terms (their memory): for a sweep that is
        done with this source. They are rebuilt if asked for again."""
        self.__dict__.pop("steps", None)
        self.__dict__.pop("step_table", None)
        self.__dict__.pop("leg_profiles", None)

    @property
    def distance_m(self) -> float:
        return self.vector.distance_m

    @property
    def duration_s(self) -> float:
        return self.vector.duration_s


# ------------------------------------------------------------------------ predictions


@dataclass(frozen=True, eq=False)
class PredictionSet:
    """The (vehicle, mass) predictions of a sweep, flat, vehicle by vehicle.

    Arrays (P,): ``vehicle_index``, ``mass_kg``, ``payload_kg`` (mass minus kerb mass;
    NaN without ``kerb_mass_kg``), ``over_max_gross``, and each vehicle's parameters
    broadcast to its rows: ``cda_m2``, ``cr``, ``eta``, ``negative_weight`` (eta eta_r
    for an EV, :func:`cevm.core.energy.ev_negative_weight`; 1 or 0 for an ICE by braking
    mode), ``aux_power_w`` (an EV's base auxiliary power p0 only: the terms that depend
    on the temperature and the trip are in :func:`row_terms`), ``battery_j`` (NaN for
    ICE), ``lhv_j_per_l`` (NaN for EV), ``idle_fuel_lps``, ``tank_l`` (NaN if unknown),
    ``is_ev``. ``braking`` holds each vehicle's ICE braking mode in force ("" for EV).
    ``ambient_c``: the ambient temperature of every prediction [degC], or None: each
    source's own, else each vehicle's default (:data:`AMBIENT_ORIGINS`).
    """

    vehicles: tuple[Vehicle, ...]
    vehicle_index: np.ndarray
    mass_kg: np.ndarray
    payload_kg: np.ndarray
    over_max_gross: np.ndarray
    cda_m2: np.ndarray
    cr: np.ndarray
    eta: np.ndarray
    negative_weight: np.ndarray
    aux_power_w: np.ndarray
    battery_j: np.ndarray
    lhv_j_per_l: np.ndarray
    idle_fuel_lps: np.ndarray
    tank_l: np.ndarray
    is_ev: np.ndarray
    braking: tuple[str, ...]
    ambient_c: float | None = None

    @property
    def n(self) -> int:
        return int(self.mass_kg.size)

    @classmethod
    def build(
        cls,
        vehicles: Sequence[Vehicle],
        *,
        mass_kg: Sequence[float] | np.ndarray | None = None,
        payload_kg: Sequence[float] | np.ndarray | None = None,
        ice_braking: str | None = None,
        ambient_c: float | None = None,
    ) -> PredictionSet:
        """Every vehicle at every mass: ``mass_kg`` (gross masses [kg], the same for all
        vehicles), or ``payload_kg`` (each vehicle's kerb mass + payload [kg]; needs
        ``kerb_mass_kg``), or neither (each vehicle's default ``mass_kg``).
        ``ice_braking`` overrides the ICE braking mode of every ICE vehicle; ``ambient_c``
        [degC] is the temperature of every prediction (None: see :data:`AMBIENT_ORIGINS`)."""
        if ambient_c is not None:
            try:
                ambient_c = float(energy.check_ambient_c(ambient_c))
            except ValueError as exc:
                raise CevmError(str(exc)) from None
        if mass_kg is not None and payload_kg is not None:
            raise CevmError("give gross masses or payloads, not both")
        vehicles = tuple(vehicles)
        if not vehicles:
            raise CevmError("no vehicles")
        masses: list[np.ndarray] = []
        if mass_kg is not None:
            m = checks.masses_for(vehicles, np.asarray(mass_kg, dtype=np.float64).ravel())
            if m.size == 0:
                raise CevmError("no gross masses given")
            masses = [m] * len(vehicles)
        elif payload_kg is not None:
            p = checks.payloads_kg(np.asarray(payload_kg, dtype=np.float64).ravel())
            if p.size == 0:
                raise CevmError("no payloads given")
            for v in vehicles:
                if v.kerb_mass_kg is None:
                    raise CevmError(f"vehicle {v.name!r} has no kerb_mass_kg, so a payload cannot be added; "
                                    "give gross masses (--mass-kg) instead")
                masses.append(v.kerb_mass_kg + p)
        else:
            masses = [np.array([v.mass_kg]) for v in vehicles]
        counts = np.array([m.size for m in masses])
        vi = np.repeat(np.arange(len(vehicles)), counts)
        mass = np.concatenate(masses)

        def per_vehicle(fn) -> np.ndarray:
            return np.array([fn(v) for v in vehicles], dtype=np.float64)[vi]

        braking = []
        for v in vehicles:
            if v.is_ev:
                braking.append("")
            else:
                mode = ice_braking or v.ice_braking
                braking_weight(mode)  # validates
                braking.append(mode)
        kerb = per_vehicle(lambda v: np.nan if v.kerb_mass_kg is None else v.kerb_mass_kg)
        max_gross = per_vehicle(lambda v: np.inf if v.max_gross_kg is None else v.max_gross_kg)
        is_ev = np.array([v.is_ev for v in vehicles], dtype=bool)[vi]
        eta = per_vehicle(lambda v: v.eta)
        w_ice = np.array([0.0 if v.is_ev else braking_weight(b) for v, b in zip(vehicles, braking)])[vi]
        return cls(
            vehicles=vehicles,
            vehicle_index=vi,
            mass_kg=mass,
            payload_kg=mass - kerb,
            over_max_gross=mass > max_gross,
            cda_m2=per_vehicle(lambda v: v.cda_m2),
            cr=per_vehicle(lambda v: v.cr),
            eta=eta,
            negative_weight=np.where(is_ev, per_vehicle(lambda v: energy.ev_negative_weight(v) if v.is_ev else 0.0),
                                     w_ice),
            aux_power_w=per_vehicle(lambda v: v.aux_power_w if v.is_ev else 0.0),
            battery_j=per_vehicle(lambda v: v.battery_j if v.is_ev and v.battery_j else np.nan),
            lhv_j_per_l=per_vehicle(lambda v: np.nan if v.is_ev else v.fuel_lhv_j_per_l),
            idle_fuel_lps=per_vehicle(lambda v: 0.0 if v.is_ev else v.idle_fuel_lps),
            tank_l=per_vehicle(lambda v: np.nan if v.is_ev or v.tank_l is None else v.tank_l),
            is_ev=is_ev,
            braking=tuple(braking),
            ambient_c=ambient_c,
        )


# ------------------------------------------------------- terms beyond the wheel energy

#: Where a prediction's ambient temperature comes from, in order: the run's (given for
#: every prediction), the source's own (a stored trip's logged mean), the vehicle file's
#: ``reference_temp_c``, or :data:`cevm.core.energy.AMBIENT_DEFAULT_C`.
AMBIENT_ORIGINS = ("given", "source", "vehicle reference_temp_c", f"default {energy.AMBIENT_DEFAULT_C:g} degC")


@dataclass(frozen=True, eq=False)
class RowTerms:
    """The terms of :mod:`cevm.core.energy` that do not depend on the sign of a step, per
    (prediction, source): arrays (n, R).

    ``ambient_c`` the temperature used [degC] and ``ambient_from`` its origin (index into
    :data:`AMBIENT_ORIGINS`); EV rows: ``aux_w`` the auxiliary power P_aux(T) [W] and
    ``start_j`` the warm-up energy of the start [J]; ICE rows: ``fuel_extra_l`` the fuel
    beyond W / (U eta) (kinetic, running, idle, temperature and cold-start terms) [l].
    Zero where a row's powertrain has no such term.
    """

    ambient_c: np.ndarray
    ambient_from: np.ndarray
    aux_w: np.ndarray
    start_j: np.ndarray
    fuel_extra_l: np.ndarray


def row_terms(pset: PredictionSet, sources: Sequence[Source], rows: np.ndarray | None = None,
              mass_kg: np.ndarray | None = None) -> RowTerms:
    """:class:`RowTerms` of the predictions ``rows`` of ``pset`` (all by default; their
    masses ``mass_kg``, default the set's) on ``sources``."""
    rows = np.arange(pset.n) if rows is None else np.asarray(rows)
    mass = pset.mass_kg[rows] if mass_kg is None else np.asarray(mass_kg, dtype=np.float64)
    n, r = rows.size, len(sources)
    vecs = [src.vector for src in sources]
    dur = np.array([v.duration_s for v in vecs])
    idle = np.array([v.idle_s for v in vecs])
    kpos = np.array([v.k_pos for v in vecs])
    trac = np.array([v.traction_s for v in vecs])
    own = np.array([np.nan if src.ambient_c is None else float(src.ambient_c) for src in sources])
    t_all = np.empty((n, r))
    origin = np.empty((n, r), dtype=np.int8)
    aux = np.zeros((n, r))
    start = np.zeros((n, r))
    extra = np.zeros((n, r))
    vi = pset.vehicle_index[rows]
    for v in np.unique(vi):
        sel = vi == v
        veh = pset.vehicles[int(v)]
        if pset.ambient_c is not None:
            t, code = np.full(r, pset.ambient_c), np.zeros(r, dtype=np.int8)
        else:
            default = veh.reference_temp_c if veh.reference_temp_c is not None else energy.AMBIENT_DEFAULT_C
            code_default = 2 if veh.reference_temp_c is not None else 3
            t = np.where(np.isfinite(own), own, default)
            code = np.where(np.isfinite(own), 1, code_default).astype(np.int8)
        t_all[sel] = t
        origin[sel] = code
        if veh.is_ev:
            aux[sel] = energy.ev_aux_power_w(veh, t)
            start[sel] = energy.ev_start_energy_j(veh, t)
        else:
            try:
                extra[sel] = energy.ice_fuel_l(veh, 0.0, mass_kg=mass[sel][:, None], k_pos=kpos, traction_s=trac,
                                               duration_s=dur, idle_s=idle, ambient_c=t)
            except ValueError as exc:
                raise CevmError(f"vehicle {veh.name!r}: {exc}") from None
    return RowTerms(t_all, origin, aux, start, extra)


# -------------------------------------------------------------- lowest state of charge


def _segment_sums(values: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    """Sums of ``values`` (..., N) over the last axis between consecutive ``bounds``
    (K+1, non-decreasing, from 0 to N): (..., K), empty segments 0."""
    k = bounds.size - 1
    out = np.zeros(values.shape[:-1] + (k,))
    nonempty = np.flatnonzero(bounds[1:] > bounds[:-1])
    if nonempty.size:
        out[..., nonempty] = np.add.reduceat(values, bounds[nonempty], axis=-1)
    return out


def _positive_parts(xs, as_, rs, nsel_block, bs, k, m, cda, cr, group, n_groups) -> np.ndarray:
    """(P, K): sum of max(Delta_i, 0) = max(m (x_i + Cr r_i) + CdA a_i, 0) [J] over the
    elements i of each block (``nsel_block``: block of each element, in order;
    ``bs``: (K+1) where each block starts), exactly, for every prediction. Predictions of
    one ``group`` (ids 0..n_groups-1) share CdA and Cr."""
    p_count = m.size
    if xs.size == 0:
        return np.zeros((p_count, k))
    c = cda / m
    order = np.lexsort((c, group))  # by group, then c ascending
    counts = np.bincount(group, minlength=n_groups)
    gstart = np.concatenate([[0], np.cumsum(counts)[:-1]])
    gsorted = group[order]
    cda_g = np.empty(n_groups)
    cda_g[group] = cda
    cr_g = np.empty(n_groups)
    cr_g[group] = cr
    c_lo = c[order][gstart]  # smallest c = CdA / m of each group (its largest mass)
    c_hi = c[order][gstart + counts - 1]
    # Delta_i = m (x_i + Cr r_i + c a_i) with r_i, a_i >= 0: positive for every prediction
    # if positive at the smallest Cr and c, for none if not at the largest. Only the
    # elements in between are classified group by group.
    never = (xs + cr_g.max() * rs + c_hi.max() * as_) <= 0
    always = (xs + cr_g.min() * rs + c_lo.min() * as_) > 0
    # group-level sums (G, K) of y = x + Cr r and of a over the positive elements
    yp = np.zeros((n_groups, k))
    ap = np.zeros((n_groups, k))
    if always.any():
        sx, sr, sa = (_segment_sums(np.where(always, v, 0.0), bs) for v in (xs, rs, as_))
        yp += sx + cr_g[:, None] * sr
        ap += sa
    sel = np.flatnonzero(~(never | always))
    sy = None
    if sel.size:
        xs, as_, rs = xs[sel], as_[sel], rs[sel]
        nblock = nsel_block[sel]
        bsel = np.searchsorted(sel, bs)
        y = xs[None, :] + cr_g[:, None] * rs[None, :]  # (G, N) Delta / m without the CdA part
        # per group: positive for every mass if positive at c_lo, never if not at c_hi
        pos_all = (y + c_lo[:, None] * as_[None, :]) > 0
        neg_all = (y + c_hi[:, None] * as_[None, :]) <= 0
        yp += _segment_sums(np.where(pos_all, y, 0.0), bsel)
        ap += _segment_sums(np.where(pos_all, as_[None, :], 0.0), bsel)
        unc = ~(pos_all | neg_all)
        if unc.any():
            # Elements whose sign differs between a group's masses. With the group's
            # predictions sorted by c, element i is positive for those of rank >= j_i,
            # j_i = #{c_p <= thr_i}, thr_i = -y_i / a_i. Bin y_i and a_i by (group, j_i,
            # block) and sum over j: each prediction reads its (group, rank) row.
            gi, ni = np.nonzero(unc)
            yv = y[gi, ni]
            av = as_[ni]
            kk = int(counts.max()) + 1
            j = _count_not_positive(yv, av, gi, c[order], gsorted, gstart)
            idx = (gi * kk + j) * k + nblock[ni]
            sy = np.bincount(idx, weights=yv, minlength=n_groups * kk * k).reshape(n_groups, kk, k)
            sa = np.bincount(idx, weights=av, minlength=n_groups * kk * k).reshape(n_groups, kk, k)
            sy[:, 0] += yp
            sa[:, 0] += ap
            np.cumsum(sy, axis=1, out=sy)
            np.cumsum(sa, axis=1, out=sa)
    if sy is None:
        return m[:, None] * yp[group] + cda[:, None] * ap[group]
    row = np.empty(p_count, dtype=np.int64)
    row[order] = gsorted * kk + (np.arange(p_count) - gstart[gsorted])  # (group, rank) row
    out = np.take(sy.reshape(-1, k), row, axis=0)  # np.take: faster than fancy indexing
    out *= m[:, None]
    sa = np.take(sa.reshape(-1, k), row, axis=0)
    sa *= cda[:, None]
    out += sa
    return out


#: Largest (groups x predictions) table of prefix counts :func:`_count_not_positive` builds
#: (8 MB); past it, a binary search on complex keys (1.5x slower, no table).
_COUNT_TABLE_CELLS = 1 << 20


def _count_not_positive(yv, av, gi, c_sorted, gsorted, gstart) -> np.ndarray:
    """For each (group g_i, element) pair with a_i > 0: j_i = #{c_p of group g_i :
    y_i + c_p a_i <= 0} = #{c_p <= -y_i / a_i}, with ``c_sorted`` ascending within each
    group (``gsorted`` the group of each, ``gstart`` where each group starts).

    One binary search among all the c values and a table of prefix counts per group
    (``table[g, r]``: how many of the r smallest c are group g's), or, for a table larger
    than :data:`_COUNT_TABLE_CELLS`, one binary search on complex keys g + i c, which
    numpy orders by group and then by c."""
    thr = -yv / av
    n_groups, n = gstart.size, c_sorted.size
    if n_groups * (n + 1) > _COUNT_TABLE_CELLS:
        keys = gsorted + 1j * c_sorted
        return np.searchsorted(keys, gi + 1j * thr, side="right") - gstart[gi]
    order = np.argsort(c_sorted, kind="stable")
    table = np.zeros((n_groups, n + 1), dtype=np.int64)
    table[gsorted[order], np.arange(1, n + 1)] = 1
    np.cumsum(table, axis=1, out=table)
    return table[gi, np.searchsorted(c_sorted[order], thr, side="right")]


def ce_wheel_energy_j(vector: CycleVector, mass_kg, cda_m2, cr, negative_weight, *, group=None) -> np.ndarray:
    """Wheel energy E_DC over the cycle [J]: the CE model of :func:`cevm.core.model.wheel_energy_j`
    (eq. 22-30, same formula), with the positive non-simplified steps summed by
    :func:`_positive_parts`: one pass for any mix of Cr values (the model groups by Cr).

    Parameters: arrays of P predictions (broadcast): mass_kg [kg] (> 0), cda_m2 [m^2],
    cr [-] (>= vector.cr0), negative_weight w; ``group`` as for :func:`peak_energy_j`
    (predictions of a group share CdA and Cr; default: grouped by (CdA, Cr)).
    """
    m = np.asarray(mass_kg, dtype=np.float64).ravel()
    cda, crs, w = (np.broadcast_to(np.asarray(v, dtype=np.float64), m.shape).ravel()
                   for v in (cda_m2, cr, negative_weight))
    if np.any(m <= 0):
        raise ValueError("mass_kg must be > 0")
    if np.any(crs < vector.cr0):
        raise ValueError(f"rolling coefficient below the vector's Cr0 {vector.cr0:g}")
    if m.size == 0:
        return np.zeros(0)
    return _ce_batch([vector], m, cda, crs, w, _groups(cda, crs, group))[:, 0]


def _ce_batch(vectors: Sequence[CycleVector], m, cda, cr, w, group) -> np.ndarray:
    """(P, R) wheel energy [J] of P predictions on R vectors (see :func:`ce_wheel_energy_j`)."""
    sc = np.array([[v.s_me, v.s_a, v.s_r, *v.ns_sums] for v in vectors])  # (R, 6)
    mm = m[:, None]
    e1 = mm * (sc[:, 0] + cr[:, None] * sc[:, 2]) + cda[:, None] * sc[:, 1]
    net = mm * (sc[:, 3] + cr[:, None] * sc[:, 5]) + cda[:, None] * sc[:, 4]
    out = e1 + net  # braking credited (w = 1): affine, no sign to decide
    need = np.flatnonzero(w != 1.0)
    if need.size:
        sizes = np.array([v.ns_x.size for v in vectors])
        _, grp = np.unique(group[need], return_inverse=True)
        pos = _positive_parts(
            np.concatenate([v.ns_x for v in vectors]), np.concatenate([v.ns_a for v in vectors]),
            np.concatenate([v.ns_r for v in vectors]), np.repeat(np.arange(len(vectors)), sizes),
            np.concatenate([[0], np.cumsum(sizes)]), len(vectors), m[need], cda[need], cr[need], grp,
            int(grp.max()) + 1)
        out[need] = e1[need] + pos + w[need][:, None] * (net[need] - pos)
    return out


def _groups(cda: np.ndarray, cr: np.ndarray, group) -> np.ndarray:
    """Compact group ids (0..G-1): of ``group`` if given, else of the (CdA, Cr) pairs."""
    if group is None:
        _, inv = np.unique(np.stack([cda, cr], axis=1), axis=0, return_inverse=True)
        return inv.ravel()
    _, inv = np.unique(np.asarray(group).ravel(), return_inverse=True)
    return inv


@dataclass(frozen=True, eq=False)
class _StepsBatch:
    """The :class:`SourceSteps` of R sources side by side: K blocks in all (``kstart``
    (R+1) the first block of each source, ``source_of_block`` (K,)), block sums and the
    (4, K, L) block matrix; the non-simplified elements with their global block."""

    kstart: np.ndarray
    source_of_block: np.ndarray
    fp_x: np.ndarray
    fp_a: np.ndarray
    fp_r: np.ndarray
    ns_x: np.ndarray
    ns_a: np.ndarray
    ns_r: np.ndarray
    t_s: np.ndarray
    blocks: np.ndarray
    el_x: np.ndarray
    el_a: np.ndarray
    el_r: np.ndarray
    el_block: np.ndarray
    el_bs: np.ndarray

    @classmethod
    def of(cls, steps: Sequence[SourceSteps]) -> _StepsBatch:
        ks = np.array([st.n_blocks for st in steps])
        kstart = np.concatenate([[0], np.cumsum(ks)])
        lmax = max(st.blocks.shape[2] for st in steps)
        if all(st.blocks.shape[2] == lmax for st in steps):
            blocks = np.concatenate([st.blocks for st in steps], axis=1)
        else:
            blocks = np.zeros((4, int(kstart[-1]), lmax))
            for st, k0 in zip(steps, kstart[:-1]):
                blocks[:, k0 : k0 + st.n_blocks, : st.blocks.shape[2]] = st.blocks
        nel = np.array([st.nsel.size for st in steps])
        offs = np.concatenate([[0], np.cumsum(nel)[:-1]])
        el_bs = np.concatenate([[0]] + [st.nsel_block_start[1:] + off for st, off in zip(steps, offs)])

        def cat(name):
            return np.concatenate([getattr(st, name) for st in steps])

        return cls(
            kstart=kstart,
            source_of_block=np.repeat(np.arange(len(steps)), ks),
            fp_x=cat("fp_x"), fp_a=cat("fp_a"), fp_r=cat("fp_r"),
            ns_x=cat("ns_x"), ns_a=cat("ns_a"), ns_r=cat("ns_r"), t_s=cat("t_s"),
            blocks=blocks,
            el_x=np.concatenate([st.x[st.nsel] for st in steps]),
            el_a=np.concatenate([st.a[st.nsel] for st in steps]),
            el_r=np.concatenate([st.r[st.nsel] for st in steps]),
            el_block=np.concatenate([st.nsel_block + k0 for st, k0 in zip(steps, kstart[:-1])]),
            el_bs=el_bs,
        )

    @property
    def n_blocks(self) -> int:
        return int(self.kstart[-1])


def _peak_batch(bt: _StepsBatch, m, cda, cr, eta, w, aux, group, end) -> tuple[np.ndarray, np.ndarray]:
    """``(wheel, peak)``, both (P, R): the wheel energy E_DC [J] (the CE model's, summed
    block by block: one positive-part pass serves the total and the peak) and
    :func:`peak_energy_j` of P predictions on each of the batch's R sources. ``end``
    (P, R) or None: a known E_n to include in the peak."""
    k = bt.n_blocks
    n_src = bt.kstart.size - 1
    n_groups = int(group.max()) + 1
    cr_g = np.empty(n_groups)
    cr_g[group] = cr
    mm = m[:, None]
    cc = cda[:, None]
    # (P, K) arithmetic in place, in a few buffers: fresh arrays of this size cost page
    # faults (glibc returns freed memory to the system), as much as the arithmetic
    pos = _positive_parts(bt.el_x, bt.el_a, bt.el_r, bt.el_block, bt.el_bs, k, m, cda, cr, group, n_groups)
    tmp = np.empty_like(pos)
    # wheel energy of the merged (always positive) elements, and of the others' negatives
    up = (bt.fp_x + cr_g[:, None] * bt.fp_r)[group]
    up *= mm
    up += np.multiply(cc, bt.fp_a, out=tmp)
    neg = (bt.ns_x + cr_g[:, None] * bt.ns_r)[group]
    neg *= mm
    neg += np.multiply(cc, bt.ns_a, out=tmp)
    neg -= pos  # sum of the non-positive Delta_i of each block (<= 0)
    up += pos  # positive wheel energy of each block
    np.multiply(w[:, None], neg, out=tmp)
    tmp += up
    wheel = np.add.reduceat(tmp, bt.kstart[:-1], axis=1)
    up *= (1.0 / eta)[:, None]
    any_aux = bool(np.any(aux != 0))
    # auxiliary power per prediction (P,) or per prediction and source (P, R)
    aux_b = aux[:, bt.source_of_block] if aux.ndim == 2 else aux[:, None]
    if any_aux:
        up += np.multiply(aux_b, bt.t_s, out=tmp)  # >= sum of the positive g_i of the block
    regen = neg
    regen *= (w / eta)[:, None]  # <= sum of the negative g_i of the block (<= 0)
    s = np.add(up, regen, out=pos)  # battery energy of each block
    c_end = np.cumsum(s, axis=1)
    for j in range(n_src - 1, 0, -1):  # restart the sum at each source (last first: the
        lo, hi = bt.kstart[j], bt.kstart[j + 1]  # column before it is still the running sum)
        c_end[:, lo:hi] -= c_end[:, lo - 1 : lo]
    c_start = np.subtract(c_end, s, out=tmp)
    best = np.maximum.reduceat(c_end, bt.kstart[:-1], axis=1)
    np.maximum(best, 0.0, out=best)
    if end is not None:
        np.maximum(best, end, out=best)
    # bounds of E_j inside each block: min(C_b + up, C_{b+1} - regen)
    ub = np.minimum(np.add(c_start, up, out=up), np.subtract(c_end, regen, out=regen), out=up)
    # scan more, never less, where rounding blurs a bound (1e-9 of the energy, or 1 mJ)
    lim = best - (1e-9 * np.abs(best) + 1e-3)
    cand = np.empty(ub.shape, dtype=bool)
    for j in range(n_src):
        lo, hi = bt.kstart[j], bt.kstart[j + 1]
        np.greater(ub[:, lo:hi], lim[:, j : j + 1], out=cand[:, lo:hi])
    pi, bi = np.nonzero(cand)
    if pi.size:
        flat = best.reshape(-1)
        lmax = bt.blocks.shape[2]
        step = max(1, _SCAN_CHUNK_ELEMENTS // lmax)
        # g_i = W(Delta_i) / eta + P_aux dt_i with Delta_i / eta = (m / eta) x_i +
        # (m Cr / eta) r_i + (CdA / eta) a_i, and W(D) = D + (w - 1) min(D, 0): merged
        # elements have Delta > 0, so only single non-simplified steps are weighted
        k_x, k_r, k_a, k_w = m / eta, m * cr / eta, cda / eta, w - 1.0
        for lo in range(0, pi.size, step):
            pp = pi[lo : lo + step]
            bb = bi[lo : lo + step]
            x, r, a, dt = bt.blocks[:, bb]
            g = k_x[pp][:, None] * x
            g += k_r[pp][:, None] * r
            g += k_a[pp][:, None] * a
            neg = np.minimum(g, 0.0)
            neg *= k_w[pp][:, None]
            g += neg
            if any_aux:
                dt *= (aux[pp, bt.source_of_block[bb]] if aux.ndim == 2 else aux[pp])[:, None]
                g += dt
            np.cumsum(g, axis=1, out=g)
            np.maximum.at(flat, pp * n_src + bt.source_of_block[bb], g.max(axis=1) + c_start[pp, bb])
    return wheel, best


def peak_energy_j(
    steps: SourceSteps,
    mass_kg,
    cda_m2,
    cr,
    eta,
    negative_weight,
    aux_power_w=0.0,
    *,
    group=None,
    end_energy_j=None,
) -> np.ndarray:
    """Largest cumulative energy drawn along the source, max(0, max_j E_j) [J].

    E_j = sum_{i<=j} (W_i(Delta_i) / eta + P_aux dt_i), with W = 1 for Delta > 0 and
    ``negative_weight`` otherwise on non-simplified steps (eta^2 for an EV: then E_j is
    the battery energy and SoC_min = SoC_start - 100 peak / E_batt).

    Parameters (arrays of P predictions, broadcast together)
    ----------
    steps : the source's :class:`SourceSteps`
    mass_kg : gross mass [kg]; cda_m2 [m^2]; cr [-] (>= steps.cr0); eta (0, 1]
    negative_weight : w in [0, 1]; aux_power_w : auxiliary power [W], >= 0 (default 0)
    group : optional (P,) ints; predictions with the same group must share CdA and Cr
        (e.g. the vehicle index). Default: grouped by (CdA, Cr).
    end_energy_j : optional (P,) E_n from the CE model, used as a known lower bound of the
        maximum (and included in it, so SoC_min <= SoC_end holds exactly).
    """
    m = np.asarray(mass_kg, dtype=np.float64).ravel()
    cda, crs, et, w, aux = (np.broadcast_to(np.asarray(v, dtype=np.float64), m.shape).ravel()
                            for v in (cda_m2, cr, eta, negative_weight, aux_power_w))
    if m.size == 0:
        return np.zeros(0)
    if np.any(crs < steps.cr0):
        raise ValueError(f"rolling coefficient below the source's Cr0 {steps.cr0:g}")
    end = None
    if end_energy_j is not None:
        end = np.broadcast_to(np.asarray(end_energy_j, np.float64), m.shape)[:, None]
    return _peak_many(_StepsBatch.of([steps]), m, cda, crs, et, w, aux, group, end)[1][:, 0]


def _peak_many(bt: _StepsBatch, m, cda, cr, eta, w, aux, group, end) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_peak_batch` in chunks of predictions (bounded work arrays): ``(wheel,
    peak)``, (P, R) each."""
    step = max(1, _CHUNK_ELEMENTS // (4 * bt.n_blocks))
    grp = None if group is None else np.asarray(group).ravel()
    if m.size <= step:
        return _peak_batch(bt, m, cda, cr, eta, w, aux, _groups(cda, cr, grp), end)
    wheel = np.empty((m.size, bt.kstart.size - 1))
    peak = np.empty_like(wheel)
    for lo in range(0, m.size, step):
        sl = slice(lo, lo + step)
        wheel[sl], peak[sl] = _peak_batch(bt, m[sl], cda[sl], cr[sl], eta[sl], w[sl], aux[sl],
                                          _groups(cda[sl], cr[sl], None if grp is None else grp[sl]),
                                          None if end is None else end[sl])
    return wheel, peak


def energy_trajectory(
    source: Source, vehicle: Vehicle, mass_kg: float, *, ice_braking: str | None = None,
    ambient_c: float | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cumulative energy along a source for one vehicle and mass, sample by sample.

    Returns ``(time_s, distance_m, energy)``: time [s] and distance [m] from the start of
    the first leg (legs follow each other), and the battery energy drawn [J] for an EV,
    the fuel burnt [l] for an ICE, with every term of :mod:`cevm.core.energy` (the
    start's warm-up at the first sample; an ICE's running fuel on simplified steps, idle
    fuel on standstill steps, its kinetic term on the steps that gain speed).
    ``ambient_c`` [degC]: default the source's own, else the vehicle's default. Plain
    per-step arithmetic (no compression): for plots and tests.
    """
    if ambient_c is None:
        ambient_c = source.ambient_c if source.ambient_c is not None else (
            vehicle.reference_temp_c if vehicle.reference_temp_c is not None else energy.AMBIENT_DEFAULT_C)
    t_c = float(ambient_c)
    phys = source.vector.physics
    if vehicle.is_ev:
        w = energy.ev_negative_weight(vehicle)
        e0 = float(energy.ev_start_energy_j(vehicle, t_c))
        aux = float(energy.ev_aux_power_w(vehicle, t_c))
    else:
        w = braking_weight(ice_braking or vehicle.ice_braking)
        e0 = float(energy.ice_start_fuel_l(vehicle, t_c))
        rate_t = float(energy.ice_time_fuel_lps(vehicle, t_c))
        c_kin = energy.ice_kinetic_coefficient(vehicle)
    ts, ds, es = [np.zeros(1)], [np.zeros(1)], [np.full(1, e0)]
    t0 = d0 = 0.0
    for leg in source.leg_profiles:
        st = step_terms(leg.time_s, leg.speed_mps, leg.elevation_m, phys)
        d = mass_kg * (st.k + st.e + vehicle.cr * st.r) + vehicle.cda_m2 * st.a
        simplified = (st.k + st.e + source.vector.cr0 * st.r) > 0
        d = np.where(~simplified & (d <= 0), w * d, d)
        if vehicle.is_ev:
            g = d / vehicle.eta + aux * st.dt
        else:
            lhv = vehicle.fuel_lhv_j_per_l
            g = (d / (lhv * vehicle.eta) + c_kin * mass_kg * np.maximum(st.k, 0.0) / lhv
                 + vehicle.running_fuel_lps * st.dt * simplified + vehicle.idle_fuel_lps * st.dt * (st.a <= 0)
                 + rate_t * st.dt)
        ts.append(t0 + np.cumsum(st.dt))
        ds.append(d0 + np.cumsum(st.r) / phys.g_mps2)
        es.append(es[-1][-1] + np.cumsum(g))
        t0, d0 = float(ts[-1][-1]), float(ds[-1][-1])
    return np.concatenate(ts), np.concatenate(ds), np.concatenate(es)


# ---------------------------------------------------------------------------- sweeps


@dataclass(frozen=True, eq=False)
class SweepBlock:
    """The predictions of one :class:`PredictionSet` on one source (arrays of P rows).

    ``wheel_energy_j`` [J]; ``energy_j`` battery energy [J] (NaN for ICE rows);
    ``fuel_l`` [l] (NaN for EV rows); ``soc_end_pct``, ``soc_min_pct`` [%] (NaN for ICE
    rows, and for EVs when not computed); ``reserve_ok`` (EV rows: lowest SoC >=
    reserve); ``tank_ok`` 1.0 / 0.0 for ICE rows with a known tank, else NaN;
    ``ambient_c`` the ambient temperature each row assumed [degC] and ``ambient_from``
    where it came from (index into :data:`AMBIENT_ORIGINS`, as float).
    """

    source: Source
    source_index: int
    pset: PredictionSet
    wheel_energy_j: np.ndarray
    energy_j: np.ndarray
    fuel_l: np.ndarray
    soc_end_pct: np.ndarray
    soc_min_pct: np.ndarray
    reserve_ok: np.ndarray
    tank_ok: np.ndarray
    ambient_c: np.ndarray
    ambient_from: np.ndarray
    # where the reserve / the battery or tank is first crossed, and the range
    # (:func:`source_ranges`); None when not computed or when no row of the block crosses
    reserve_at_m: np.ndarray | None = None
    reserve_at_s: np.ndarray | None = None
    empty_at_m: np.ndarray | None = None
    empty_at_s: np.ndarray | None = None
    range_m: np.ndarray | None = None
    range_reserve_m: np.ndarray | None = None
    # whether the vehicle can follow the source (:func:`follow_flags`); None: not known
    over_power: np.ndarray | None = None
    over_speed: np.ndarray | None = None

    @property
    def n(self) -> int:
        return self.pset.n


def check_cr(source: Source, pset: PredictionSet) -> None:
    bad = pset.cr < source.vector.cr0
    if bad.any():
        v = pset.vehicles[int(pset.vehicle_index[np.argmax(bad)])]
        raise CevmError(f"vehicle {v.name!r}: cr {v.cr:g} is below the Cr0 {source.vector.cr0:g} of source "
                        f"{source.name!r}; the CE split is only exact for Cr >= Cr0 (use a lower --cr0)")


def predict_source(
    source: Source,
    pset: PredictionSet,
    *,
    soc_start_pct: float = DEFAULT_SOC_START_PCT,
    reserve_pct: float = DEFAULT_RESERVE_PCT,
    lowest_soc: bool = True,
    source_index: int = 0,
    ranges: bool = False,
) -> SweepBlock:
    """Every prediction of ``pset`` on ``source``: totals by the CE model, and for EVs
    the state of charge at the end and at its lowest along the way (``lowest_soc``,
    default True; False skips the profile and leaves ``soc_min_pct`` NaN).

    ``soc_start_pct`` [%] (default 100: leaving the depot charged) and ``reserve_pct``
    [%] (default 15, the paper's warning level) are percentages of ``battery_kwh``.
    The SoC is not capped at 100 %: a full battery cannot take regenerated energy, so on
    a route that starts downhill from full the model's SoC is optimistic. Nor does it go
    below 0: where a row runs empty, and where it crosses the reserve, the block says
    (:func:`source_ranges`); ``ranges`` (default False) adds each row's range, the source
    driven again and again (one step-by-step sum per row). Vehicles with
    ``max_power_kw`` or ``max_speed_kmh`` get :func:`follow_flags`.
    """
    return predict_sources([source], pset, soc_start_pct=soc_start_pct, reserve_pct=reserve_pct,
                           lowest_soc=lowest_soc, first_index=source_index, ranges=ranges)[0]


def predict_sources(
    sources: Sequence[Source],
    pset: PredictionSet,
    *,
    soc_start_pct: float = DEFAULT_SOC_START_PCT,
    reserve_pct: float = DEFAULT_RESERVE_PCT,
    lowest_soc: bool = True,
    first_index: int = 0,
    ranges: bool = False,
) -> list[SweepBlock]:
    """:func:`predict_source` for several sources at once (one vectorised evaluation,
    faster than one source at a time); one block per source, in order."""
    if not sources:
        return []
    arrays = _predict_arrays(sources, pset, soc_start_pct, reserve_pct, lowest_soc)
    return _finish(_as_blocks(sources, pset, arrays, first_index), soc_start_pct, reserve_pct, ranges)


def _predict_arrays(sources: Sequence[Source], pset: PredictionSet, soc_start_pct: float, reserve_pct: float,
                    lowest_soc: bool) -> tuple[np.ndarray, ...]:
    """The (P, n_sources) arrays of :func:`predict_sources`, in :data:`_BLOCK_ARRAYS`
    order. Also the task of a parallel :func:`sweep` (the sources and the set stay with
    the caller; only these arrays come back)."""
    for src in sources:
        check_cr(src, pset)
    vecs = [src.vector for src in sources]
    n_src = len(sources)
    duration = np.array([v.duration_s for v in vecs])
    ev = pset.is_ev
    shape = (pset.n, n_src)
    wheel = np.empty(shape)
    energy_j = np.full(shape, np.nan)
    fuel = np.full(shape, np.nan)
    soc_end = np.full(shape, np.nan)
    soc_min = np.full(shape, np.nan)
    terms = row_terms(pset, sources)
    # EV rows with the lowest SoC: the step terms give the total and the peak in one
    # pass; every other row: the CE vector
    by_steps = ev if lowest_soc else np.zeros_like(ev)
    by_vector = ~by_steps
    if by_vector.any():
        wheel[by_vector] = _ce_batch(vecs, pset.mass_kg[by_vector], pset.cda_m2[by_vector], pset.cr[by_vector],
                                     pset.negative_weight[by_vector],
                                     _groups(pset.cda_m2[by_vector], pset.cr[by_vector],
                                             pset.vehicle_index[by_vector]))  # (P, R)
    peak = None
    if by_steps.any():
        bt = _StepsBatch.of([src.steps for src in sources])
        aux = terms.aux_w[ev]
        if np.all(aux == aux[:, :1]):
            aux = aux[:, 0].copy()  # the same for every source: the cheaper per-row form
        wheel[ev], peak = _peak_many(bt, pset.mass_kg[ev], pset.cda_m2[ev], pset.cr[ev], pset.eta[ev],
                                     pset.negative_weight[ev], aux, pset.vehicle_index[ev], None)
    if ev.any():
        # battery energy E_e = W / eta + P_aux(T) D + warm-up (eq. 31, cevm.core.energy)
        start = terms.start_j[ev]
        e = wheel[ev] / pset.eta[ev][:, None] + terms.aux_w[ev] * duration + start
        energy_j[ev] = e
        cap = pset.battery_j[ev][:, None]
        soc_end[ev] = soc_start_pct - 100.0 * e / cap
        if peak is not None:
            peak += start  # drawn at the start, before the first step: every E_j includes it
            np.maximum(peak, e, out=peak)  # E_n is one of the E_j: SoC_min <= SoC_end exactly
            soc_min[ev] = soc_start_pct - 100.0 * peak / cap
    ice = ~ev
    if ice.any():
        # fuel L_f = W / (U_f eta) (eq. 26) + the terms of cevm.core.energy.ice_fuel_l
        fuel[ice] = wheel[ice] / (pset.lhv_j_per_l[ice] * pset.eta[ice])[:, None] + terms.fuel_extra_l[ice]
    tank = pset.tank_l[:, None]
    with np.errstate(invalid="ignore"):
        tank_ok = np.where(ice[:, None] & np.isfinite(tank), (fuel <= tank).astype(float), np.nan)
        reserve_ok = ev[:, None] & (soc_min >= reserve_pct)
    return (wheel, energy_j, fuel, soc_end, soc_min, reserve_ok, tank_ok, terms.ambient_c,
            terms.ambient_from.astype(np.float64))


#: The arrays of a :class:`SweepBlock`, in the order :func:`_predict_arrays` returns them.
_BLOCK_ARRAYS = ("wheel_energy_j", "energy_j", "fuel_l", "soc_end_pct", "soc_min_pct", "reserve_ok", "tank_ok",
                 "ambient_c", "ambient_from")


def _as_blocks(sources: Sequence[Source], pset: PredictionSet, arrays: tuple[np.ndarray, ...],
               first_index: int) -> list[SweepBlock]:
    """One :class:`SweepBlock` per source from the (P, n_sources) arrays of
    :func:`_predict_arrays`."""
    return [SweepBlock(src, first_index + i, pset, **{name: a[:, i].copy() for name, a in zip(_BLOCK_ARRAYS, arrays)})
            for i, src in enumerate(sources)]


def _finish(blocks: list[SweepBlock], soc_start_pct: float, reserve_pct: float, ranges: bool) -> list[SweepBlock]:
    """The blocks with :func:`source_ranges` and :func:`follow_flags` (in this process:
    the step tables stay with the sources)."""
    return [follow_flags(source_ranges(b, soc_start_pct=soc_start_pct, reserve_pct=reserve_pct, repeat=ranges))
            for b in blocks]


def _portable(source: Source, lowest_soc: bool) -> Source:
    """What a worker needs of ``source``: its vector, and its step terms when the lowest
    state of charge is asked for (the legs' profiles, and any store access behind them,
    stay here)."""
    out = Source(source.name, source.kind, source.vector, legs=(), block_elements=source.block_elements,
                 ambient_c=source.ambient_c)
    if lowest_soc:
        out.__dict__["steps"] = source.steps  # the cached_property's slot: set, not recomputed
    return out


#: Sources evaluated together by :func:`sweep`: as many as keep about this many
#: (EV prediction x block) cells in one evaluation (512 kB per work array; measured
#: with benchmarks/bench_sweep.py: 2x smaller or larger batches were 10-50 % slower).
SWEEP_BATCH_CELLS = 1 << 16


def _batches(sources: Sequence[Source], pset: PredictionSet, lowest_soc: bool) -> Iterator[tuple[int, int]]:
    """The (start, stop) source ranges :func:`sweep` evaluates together, in order."""
    n_rows = max(1, int(pset.is_ev.sum()) if lowest_soc else pset.n)
    use_steps = lowest_soc and bool(pset.is_ev.any())
    i = 0
    while i < len(sources):
        cells = 0
        j = i
        while j < len(sources) and (j == i or cells < SWEEP_BATCH_CELLS):
            cells += n_rows * (sources[j].steps.n_blocks if use_steps else 1)
            j += 1
        yield i, j
        i = j


def sweep(
    sources: Sequence[Source],
    pset: PredictionSet,
    *,
    soc_start_pct: float = DEFAULT_SOC_START_PCT,
    reserve_pct: float = DEFAULT_RESERVE_PCT,
    lowest_soc: bool = True,
    executor: Executor | None = None,
    ranges: bool = False,
) -> Iterator[SweepBlock]:
    """Every prediction of ``pset`` on every source: one block of ``pset.n`` rows per
    source, source-major (then vehicle, then mass), computed when asked for, a few
    sources at a time (:data:`SWEEP_BATCH_CELLS`).

    ``executor`` (:func:`cevm.executors.make_executor`: worker processes or a Dask
    cluster) evaluates the batches in parallel: each task gets a batch's vectors and
    step terms (built here, with any profile reading) and the set, and returns the
    arrays; blocks still come in source order, and equal a serial sweep's bit for bit
    (the batches are the same). Raises :class:`CevmError` if a task fails."""
    if executor is None or executor.inline:
        for i, j in _batches(sources, pset, lowest_soc):
            yield from predict_sources(sources[i:j], pset, soc_start_pct=soc_start_pct, reserve_pct=reserve_pct,
                                       lowest_soc=lowest_soc, first_index=i, ranges=ranges)
        return
    use_steps = lowest_soc and bool(pset.is_ev.any())
    spans: list[tuple[int, int]] = []

    def tasks() -> Iterator[Task]:
        for i, j in _batches(sources, pset, lowest_soc):
            spans.append((i, j))
            batch = tuple(_portable(src, use_steps) for src in sources[i:j])
            yield Task(f"sources {i + 1}-{j} ({sources[i].name})", (batch, pset, soc_start_pct, reserve_pct, lowest_soc))

    for k, res in enumerate(executor.run(_predict_arrays, tasks())):
        i, j = spans[k]
        if not res.ok:
            raise CevmError(f"predictions for sources {i + 1}-{j} failed on a worker: {res.error}")
        yield from _finish(_as_blocks(sources[i:j], pset, res.value, i), soc_start_pct, reserve_pct, ranges)


# ------------------------------------------------------------------ range and limits
#
# Where a vehicle first crosses its reserve or runs empty along a source, the range at
# its load, and whether it can follow the source at all (power, top speed). Computed
# from the plain per-step terms (:class:`StepTable`), for the rows that need them: the
# energy drawn is summed step by step as the CE model's terms give it, so the total at
# the end equals the model's.
#
# Energy along the way, per step i (EV, battery [J]; ICE, fuel [l]), from
# :mod:`cevm.core.energy`:
#
#   EV:  g_i = W_i / eta + P_aux(T) dt_i,  W_i = Delta_i, or w Delta_i for a negative
#        non-simplified step, w = eta eta_r (:func:`~cevm.core.energy.ev_negative_weight`),
#        P_aux from :func:`~cevm.core.energy.ev_aux_power_w`; the warm-up energy of the
#        start (:func:`~cevm.core.energy.ev_start_energy_j`) before the first step.
#   ICE: g_i = W_i / (U eta) + c_kin m max(k_i, 0) / U + r_run dt_i (simplified steps)
#        + r_idle dt_i (standstill) + r_T(T) dt_i, W_i with the braking mode's weight
#        (1 for the paper's eq. 24, 0 for no-credit); the cold-start fuel first.
#
# A level L (the energy above the reserve, or the whole usable battery or tank) is first
# crossed in the step where the running sum E_j reaches L; the point is interpolated
# linearly inside that step (the step's energy spread evenly over its time and distance).
#
# Beyond the source's end, the range counts the source driven again and again, without a
# stop to recharge or refuel and without another cold start: the repetition k and step j
# of the first crossing of lump + k S + C_j >= L, S the energy of one pass (without the
# start's), C_j the running sum inside a pass. A source that gives back at least what it
# takes (S <= 0, a descent) has no range limit: infinite.


@dataclass(frozen=True, eq=False)
class StepTable:
    """A source's per-step terms in driving order (legs one after another), SI: ``k``
    (kinetic, J/kg), ``x`` = k + e (J/kg), ``a`` (J/m^2), ``r`` (J/kg per unit Cr),
    ``dt`` [s], ``dd`` (distance of the step [m]), ``t0`` and ``d0`` (time [s] and
    distance [m] at the step's start), ``simplified`` (criterion 8 with the source's
    Cr0), ``moving`` (a > 0); ``v_max_mps`` the source's top speed."""

    k: np.ndarray
    x: np.ndarray
    a: np.ndarray
    r: np.ndarray
    dt: np.ndarray
    dd: np.ndarray
    t0: np.ndarray
    d0: np.ndarray
    simplified: np.ndarray
    moving: np.ndarray
    v_max_mps: float

    @property
    def n(self) -> int:
        return int(self.dt.size)

    @property
    def duration_s(self) -> float:
        return float(self.t0[-1] + self.dt[-1]) if self.n else 0.0

    @property
    def distance_m(self) -> float:
        return float(self.d0[-1] + self.dd[-1]) if self.n else 0.0


def build_step_table(legs: Sequence[LegProfile], *, cr0: float = CR0_DEFAULT,
                     physics: Physics = PAPER_PHYSICS) -> StepTable:
    """The :class:`StepTable` of a source's legs."""
    ks, xs, as_, rs, dts = [], [], [], [], []
    vmax = 0.0
    for leg in legs:
        st = step_terms(leg.time_s, leg.speed_mps, leg.elevation_m, physics)
        ks.append(st.k)
        xs.append(st.k + st.e)
        as_.append(st.a)
        rs.append(st.r)
        dts.append(st.dt)
        if leg.speed_mps.size:
            vmax = max(vmax, float(np.max(leg.speed_mps)))
    z = np.zeros(0)
    k, x, a, r, dt = (v[0] if len(v) == 1 else np.concatenate(v) if v else z  # one leg: no copy
                      for v in (ks, xs, as_, rs, dts))
    dd = r / physics.g_mps2
    t0 = np.concatenate([[0.0], np.cumsum(dt)[:-1]]) if dt.size else z
    d0 = np.concatenate([[0.0], np.cumsum(dd)[:-1]]) if dd.size else z
    return StepTable(k=k, x=x, a=a, r=r, dt=dt, dd=dd, t0=t0, d0=d0, simplified=(x + cr0 * r) > 0,
                     moving=a > 0, v_max_mps=vmax)


@dataclass(frozen=True, eq=False)
class _StepCoefficients:
    """Per row, the energy of step i as kx x_i + kr r_i + ka a_i (its negative part,
    on non-simplified steps, weighted by w) + ck max(k_i, 0) + (aux + run [simplified]
    + idle [standstill]) dt_i, and ``lump`` before the first step (units of the row:
    J for an EV, l for an ICE)."""

    kx: np.ndarray
    kr: np.ndarray
    ka: np.ndarray
    w: np.ndarray
    ck: np.ndarray
    aux: np.ndarray
    run: np.ndarray
    idle: np.ndarray
    lump: np.ndarray

    def take(self, rows: np.ndarray) -> _StepCoefficients:
        return _StepCoefficients(*(getattr(self, f)[rows] for f in self.__dataclass_fields__))


def step_coefficients(pset: PredictionSet, ambient_c) -> _StepCoefficients:
    """The per-step energy coefficients of every row of ``pset`` (see :class:`StepTable`
    and the notes above), with every term of :mod:`cevm.core.energy` at each row's
    ambient temperature ``ambient_c`` [degC] (P,) (a block's ``ambient_c``)."""
    n = pset.n
    t = np.broadcast_to(np.asarray(ambient_c, dtype=np.float64), (n,))
    m, cda, cr, eta = pset.mass_kg, pset.cda_m2, pset.cr, pset.eta
    scale = np.where(pset.is_ev, 1.0 / eta, 1.0 / (eta * np.where(pset.is_ev, 1.0, pset.lhv_j_per_l)))
    out = {f: np.zeros(n) for f in ("w", "ck", "aux", "run", "idle", "lump")}
    for j, v in enumerate(pset.vehicles):
        rows = np.flatnonzero(pset.vehicle_index == j)
        if not rows.size:
            continue
        if v.is_ev:
            out["w"][rows] = energy.ev_negative_weight(v)
            out["aux"][rows] = energy.ev_aux_power_w(v, t[rows])
            out["lump"][rows] = energy.ev_start_energy_j(v, t[rows])
        else:
            out["w"][rows] = braking_weight(pset.braking[j] or v.ice_braking)
            out["ck"][rows] = energy.ice_kinetic_coefficient(v) * m[rows] / v.fuel_lhv_j_per_l
            out["aux"][rows] = energy.ice_time_fuel_lps(v, t[rows])
            out["run"][rows] = v.running_fuel_lps
            out["idle"][rows] = v.idle_fuel_lps
            out["lump"][rows] = energy.ice_start_fuel_l(v, t[rows])
    return _StepCoefficients(kx=m * scale, kr=m * cr * scale, ka=cda * scale, **out)


def step_energies(st: StepTable, c: _StepCoefficients) -> np.ndarray:
    """(R, N) energy of each step for R rows of coefficients ``c`` (J or l)."""
    g = c.kx[:, None] * st.x[None, :]
    g += c.kr[:, None] * st.r[None, :]
    g += c.ka[:, None] * st.a[None, :]
    ns = ~st.simplified
    if ns.any():
        neg = np.minimum(g[:, ns], 0.0)
        neg *= (c.w - 1.0)[:, None]
        g[:, ns] += neg
    if np.any(c.ck != 0):
        g += c.ck[:, None] * np.maximum(st.k, 0.0)[None, :]
    if np.any(c.aux != 0):
        g += c.aux[:, None] * st.dt[None, :]
    if np.any(c.run != 0):
        g += c.run[:, None] * np.where(st.simplified, st.dt, 0.0)[None, :]
    if np.any(c.idle != 0):
        g += c.idle[:, None] * np.where(st.moving, 0.0, st.dt)[None, :]
    return g


def _crossing_point(st: StepTable, cum: np.ndarray, before: np.ndarray, target: np.ndarray,
                    rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each row r of ``rows``: the first step j with ``cum[r, j] >= target[r]``
    (``before[r]`` the sum before the first step), and the time [s] and distance [m]
    at which it is reached, interpolated inside the step. Returns (found, t, d)."""
    hit = cum[rows] >= target[:, None]
    found = hit.any(axis=1)
    j = np.argmax(hit, axis=1)
    prev = np.where(j > 0, cum[rows, np.maximum(j - 1, 0)], before)
    step = cum[rows, j] - prev
    with np.errstate(invalid="ignore", divide="ignore"):
        frac = np.clip(np.where(step > 0, (target - prev) / step, 1.0), 0.0, 1.0)
    return found, st.t0[j] + frac * st.dt[j], st.d0[j] + frac * st.dd[j]


#: Rows x steps of one chunk of :func:`crossings` (8 MB of float64).
_RANGE_CHUNK_CELLS = 1 << 20


def crossings(st: StepTable, c: _StepCoefficients, levels: np.ndarray, *, repeat: bool
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where the running energy of each row first reaches each of its ``levels``
    (R, J), along the source and, with ``repeat``, with the source driven again and
    again after its end (see the notes above).

    Returns ``(time_s, distance_m, within)``, each (R, J): NaN where never reached (a
    level above what the source takes, without ``repeat``; infinite with ``repeat`` when
    one pass gives back what it takes), ``within`` True where reached in the first pass.
    """
    levels = np.atleast_2d(np.asarray(levels, dtype=np.float64))
    r_count, n_levels = levels.shape
    t_out = np.full((r_count, n_levels), np.nan)
    d_out = np.full((r_count, n_levels), np.nan)
    within = np.zeros((r_count, n_levels), dtype=bool)
    if r_count == 0:
        return t_out, d_out, within
    n = st.n
    at_start = c.lump[:, None] >= levels
    t_out[at_start] = 0.0
    d_out[at_start] = 0.0
    within |= at_start
    if n == 0:
        return t_out, d_out, within
    step = max(1, _RANGE_CHUNK_CELLS // n)
    for lo in range(0, r_count, step):
        sl = slice(lo, lo + step)
        cc = c.take(np.arange(r_count)[sl])
        cum = np.cumsum(step_energies(st, cc), axis=1)  # C_j, one pass, without the lump
        per_pass = cum[:, -1]
        peak = cum.max(axis=1)
        lump = cc.lump
        for jl in range(n_levels):
            todo = ~at_start[sl, jl]
            if not todo.any():
                continue
            rows = np.flatnonzero(todo)
            target = levels[sl, jl][rows] - lump[rows]  # C_j must reach this
            found, t, d = _crossing_point(st, cum, np.zeros(rows.size), target, rows)
            r_found = lo + rows[found]
            t_out[r_found, jl], d_out[r_found, jl], within[r_found, jl] = t[found], d[found], True
            if not repeat:
                continue
            rest = rows[~found]
            target = target[~found]
            gains = per_pass[rest] > 0
            t_out[lo + rest[~gains], jl] = np.inf
            d_out[lo + rest[~gains], jl] = np.inf
            rest, target = rest[gains], target[gains]
            if not rest.size:
                continue
            s = per_pass[rest]
            k = np.maximum(1.0, np.ceil((target - peak[rest]) / s))
            k = np.where(target - k * s > peak[rest], k + 1.0, k)  # rounding
            found, t, d = _crossing_point(st, cum, np.zeros(rest.size), target - k * s, rest)
            t_out[lo + rest, jl] = np.where(found, k * st.duration_s + t, np.nan)
            d_out[lo + rest, jl] = np.where(found, k * st.distance_m + d, np.nan)
    return t_out, d_out, within


#: The fields :func:`source_ranges` fills (of :class:`SweepBlock`, and of
#: :class:`cevm.core.feasibility.Feasibility`).
RANGE_FIELDS = ("reserve_at_m", "reserve_at_s", "empty_at_m", "empty_at_s", "range_m", "range_reserve_m")


def source_ranges(block: SweepBlock, *, soc_start_pct: float = DEFAULT_SOC_START_PCT,
                  reserve_pct: float = DEFAULT_RESERVE_PCT, repeat: bool = True) -> SweepBlock:
    """``block`` with where each row first crosses its reserve (EV) and runs empty
    (EV battery, ICE tank) along the source, its range (``repeat``: the source driven
    again and again; see the notes above), and no state of charge below zero: a row
    that runs empty on the way has ``soc_min_pct`` 0 and ``soc_end_pct`` NaN (it does
    not reach the end).

    Rows that cannot cross inside the source (EV: lowest SoC above the reserve; ICE:
    fuel within the tank and never falling along the way) are not summed step by step
    unless ``repeat`` asks for their range. EV rows without a lowest SoC (a sweep with
    ``lowest_soc=False``) get NaN. SI fields: ``reserve_at_m``, ``reserve_at_s``,
    ``empty_at_m``, ``empty_at_s``, ``range_m`` (to empty), ``range_reserve_m`` (to the
    reserve; EV only).
    """
    from dataclasses import replace

    ps = block.pset
    n = ps.n
    ev = ps.is_ev
    cap = np.where(ev, ps.battery_j, np.nan)
    l_empty = np.where(ev, soc_start_pct / 100.0 * cap, ps.tank_l)
    l_res = np.where(ev, (soc_start_pct - reserve_pct) / 100.0 * cap, np.nan)
    has_level = np.isfinite(l_empty)
    if ev.any() and np.all(np.isnan(block.soc_min_pct[ev])):
        has_level &= ~ev  # no lowest SoC: the EV rows are not evaluated
    if repeat:
        need = has_level
    else:
        # an ICE's running fuel can fall along the way only with braking credited (w > 0)
        # or a kinetic efficiency above eta (a negative kinetic term)
        with np.errstate(invalid="ignore"):
            need = ev & (block.soc_min_pct < reserve_pct)
            if not ev.all():
                falls = np.array([not v.is_ev and (braking_weight(ps.braking[j] or v.ice_braking) > 0
                                                   or (v.kinetic_eta is not None and v.kinetic_eta > v.eta))
                                  for j, v in enumerate(ps.vehicles)])[ps.vehicle_index]
                need |= ~ev & ((block.fuel_l >= ps.tank_l) | falls)
        need &= has_level
    rows = np.flatnonzero(need)
    with np.errstate(invalid="ignore"):
        clean = not (np.any(block.soc_end_pct < 0) or np.any(block.soc_min_pct < 0))
    if not rows.size and not repeat and clean:
        return block  # nothing crosses anything: the common case costs no copy
    out = {f: np.full(n, np.nan) for f in RANGE_FIELDS}
    if rows.size:
        coef = step_coefficients(ps, block.ambient_c)
        levels = np.stack([l_res[rows], l_empty[rows]], axis=1)
        t, d, inside = crossings(block.source.step_table, coef.take(rows), levels, repeat=repeat)
        res = ev[rows]
        out["reserve_at_s"][rows] = np.where(inside[:, 0] & res, t[:, 0], np.nan)
        out["reserve_at_m"][rows] = np.where(inside[:, 0] & res, d[:, 0], np.nan)
        out["empty_at_s"][rows] = np.where(inside[:, 1], t[:, 1], np.nan)
        out["empty_at_m"][rows] = np.where(inside[:, 1], d[:, 1], np.nan)
        if repeat:
            out["range_m"][rows] = d[:, 1]
            out["range_reserve_m"][rows] = np.where(res, d[:, 0], np.nan)
    if not repeat:
        out["range_m"] = out["range_reserve_m"] = None
    soc_end = block.soc_end_pct.copy()
    soc_min = block.soc_min_pct.copy()
    empty = np.isfinite(out["empty_at_m"]) & ev
    with np.errstate(invalid="ignore"):
        soc_end[empty | (soc_end < 0)] = np.nan
        soc_min[empty | (soc_min < 0)] = 0.0
    return replace(block, soc_end_pct=soc_end, soc_min_pct=soc_min, **out)


#: The window over which the power a source asks is averaged [s] (:func:`follow_flags`):
#: a drivetrain delivers its rated power for seconds, and one-second steps of a logged
#: trace carry speed and elevation noise (1 m of elevation noise in 1 s is 430 kW at
#: 44 t); over 5 s the kinetic and potential energy of the noise cancel.
POWER_WINDOW_S = 5.0


def _window_coefficients(st: StepTable, window_s: float = POWER_WINDOW_S):
    """Per window of consecutive steps lasting at least ``window_s`` (one starting at
    each moving step): the sums of x, r, a over its moving steps and its duration, so
    that its mean wheel power at mass m is (m (sx + Cr sr) + CdA sa) / T. They depend
    on the source alone: made once per step table (every vehicle of a sweep asks)."""
    cache = st.__dict__.setdefault("_power_windows", {})  # goes with the table (Source.release)
    if window_s not in cache:
        cache[window_s] = _window_sums(st, window_s)
    return cache[window_s]


def _window_sums(st: StepTable, window_s: float):
    mv = st.moving
    x = np.where(mv, st.x, 0.0)  # standstill: the brakes hold the vehicle, no wheel work

    def csum(v: np.ndarray) -> np.ndarray:  # [0, cumsum...] without a second copy
        out = np.empty(v.size + 1)
        out[0] = 0.0
        np.cumsum(v, out=out[1:])
        return out

    cx, cr_, ca, ct = csum(x), csum(st.r), csum(st.a), csum(st.dt)
    starts = np.flatnonzero(mv)
    ends = np.searchsorted(ct, ct[starts] + window_s * (1.0 - 1e-12), side="left")
    ends = np.minimum(np.maximum(ends, starts + 1), st.n)
    dur = ct[ends] - ct[starts]
    return cx[ends] - cx[starts], cr_[ends] - cr_[starts], ca[ends] - ca[starts], dur


def peak_wheel_power_w(st: StepTable, mass_kg, cda_m2: float, cr: float, window_s: float = POWER_WINDOW_S
                       ) -> np.ndarray:
    """The largest mean wheel power [W] a source asks of a vehicle at each mass, over
    any ``window_s`` of driving (eq. 28 summed over the window, no rotating inertia);
    0 for a source that never moves."""
    m = np.atleast_1d(np.asarray(mass_kg, dtype=np.float64))
    if not st.moving.any():
        return np.zeros(m.shape)
    sx, sr, sa, dur = _window_coefficients(st, window_s)
    slope = (sx + cr * sr) / dur
    icpt = cda_m2 * sa / dur
    out = np.empty(m.shape)
    step = max(1, _RANGE_CHUNK_CELLS // slope.size)
    for lo in range(0, m.size, step):
        out[lo:lo + step] = (m[lo:lo + step, None] * slope[None, :] + icpt[None, :]).max(axis=1)
    return out


def power_mass_window(st: StepTable, max_power_w: float, cda_m2: float, cr: float,
                      window_s: float = POWER_WINDOW_S) -> tuple[float, float]:
    """The masses [kg] at which a vehicle of rated power ``max_power_w`` [W] can follow
    the source: (low, high) with :func:`peak_wheel_power_w` <= ``max_power_w`` exactly
    between them (each window's power is affine in the mass, so the set is an
    interval); (nan, nan) when no mass can."""
    if not st.moving.any():
        return 0.0, math.inf
    sx, sr, sa, dur = _window_coefficients(st, window_s)
    slope = (sx + cr * sr) / dur
    icpt = cda_m2 * sa / dur
    if np.any((slope == 0) & (icpt > max_power_w)):
        return math.nan, math.nan
    with np.errstate(divide="ignore", invalid="ignore"):
        bound = (max_power_w - icpt) / slope
    hi = float(np.min(bound[slope > 0], initial=math.inf))
    lo = float(np.max(bound[slope < 0], initial=0.0))
    if lo > hi:
        return math.nan, math.nan
    return lo, hi


def follow_flags(block: SweepBlock) -> SweepBlock:
    """``block`` with ``over_power`` (the source asks more wheel power than the vehicle's
    ``max_power_kw`` at the row's mass; see :func:`power_mass_window`) and
    ``over_speed`` (the source is faster than its ``max_speed_kmh``): 1.0 / 0.0, NaN for
    rows of vehicles without the key. The power is the mean over any
    :data:`POWER_WINDOW_S` of driving, and rated power is at the motor or engine shaft,
    so the test is lenient: the drivetrain's losses and rotating parts ask more still."""
    from dataclasses import replace

    ps = block.pset
    if all(v.max_power_w is None and v.max_speed_mps is None for v in ps.vehicles):
        return block
    over_p = np.full(ps.n, np.nan)
    over_v = np.full(ps.n, np.nan)
    for j, v in enumerate(ps.vehicles):
        if v.max_power_w is None and v.max_speed_mps is None:
            continue
        rows = np.flatnonzero(ps.vehicle_index == j)
        st = block.source.step_table
        if v.max_speed_mps is not None:
            over_v[rows] = float(st.v_max_mps > v.max_speed_mps * (1.0 + 1e-9))
        if v.max_power_w is not None:
            lo, hi = power_mass_window(st, v.max_power_w, v.cda_m2, v.cr)
            m = ps.mass_kg[rows]
            over_p[rows] = np.where(np.isnan(lo), 1.0, ((m < lo) | (m > hi)).astype(float))
    return replace(block, over_power=over_p, over_speed=over_v)
