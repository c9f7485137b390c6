"""Drive cycles and their CE vectors (paper eq. 9-23; discretisation of PAPER-NOTES.md).

A drive cycle is N samples of time T_i [s], speed v_i [m/s] and road elevation h_i [m].
Step i joins sample i to i+1 (dt_i = T_{i+1} - T_i > 0) and carries four per-step terms:

    k_i = 1/2 (v_{i+1}^2 - v_i^2)                 [J/kg]      kinetic        (11)
    a_i = 1/4 rho_air (v_i^3 + v_{i+1}^3) dt_i    [J/m^2]     aerodynamic    (14)
    r_i = 1/2 g (v_i + v_{i+1}) dt_i              [J/kg]      rolling, per Cr (17)
    e_i = g (h_{i+1} - h_i)                       [J/kg]      potential      (20)

so that a vehicle of mass m, drag area CdA and rolling coefficient Cr needs at the wheels

    Delta_i = m (k_i + e_i) + CdA a_i + Cr m r_i  [J]                          (28)

A step is *simplified* when k_i + e_i + Cr0 r_i > 0 (criterion (8) times the step's
distance, division-free). For every vehicle with Cr >= Cr0 those steps need positive
wheel energy, so their sum collapses into three numbers, the drive-cycle vector

    Delta = [S_m + S_e, S_a, S_r]   (eq. 21, with the paper's erratum corrected)

The other steps (braking, descending) are kept in compact form: their sign depends on
the vehicle. :class:`CycleVector` holds both, so any vehicle and payload can be predicted
afterwards, exactly, without the original samples (see :mod:`cevm.core.model`).
"""

from __future__ import annotations

import io
import math
import struct
from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np

#: Density of air [kg/m^3], the paper's value.
RHO_AIR_KG_M3 = 1.225
#: Gravitational acceleration [m/s^2], the paper's value.
G_MPS2 = 9.81
#: Default conservative rolling-resistance coefficient Cr0 [-] of criterion (8).
#: 0.004 is the upper bound of the best class (A) of the EU tyre label for heavy-vehicle
#: (C3) tyres, Regulation (EU) 2020/740: no heavy vehicle on road tyres rolls with less.
#: The split into simplified steps is exact for every vehicle with Cr >= Cr0; predictions
#: for a vehicle with a lower Cr are refused (recompute the vector with a lower cr0).
CR0_DEFAULT = 0.004


@dataclass(frozen=True)
class Physics:
    """Physical constants used to build per-step terms."""

    rho_air_kg_m3: float = RHO_AIR_KG_M3
    g_mps2: float = G_MPS2


PAPER_PHYSICS = Physics()


@dataclass(frozen=True)
class DriveCycle:
    """A speed (and elevation) trace: the raw input of the CE model.

    ``elevation_m`` may be None for a flat road. Arrays are float64 of equal length,
    time strictly increasing, speed non-negative (checked by :func:`validate_cycle`).
    """

    time_s: np.ndarray
    speed_mps: np.ndarray
    elevation_m: np.ndarray | None = None
    name: str = ""

    def __post_init__(self) -> None:
        validate_cycle(self.time_s, self.speed_mps, self.elevation_m)

    @property
    def duration_s(self) -> float:
        return float(self.time_s[-1] - self.time_s[0])

    @property
    def distance_m(self) -> float:
        """Trapezoidal distance [m], consistent with the r_i term."""
        return trapezoid_distance_m(self.time_s, self.speed_mps)


def trapezoid_distance_m(time_s: np.ndarray, speed_mps: np.ndarray) -> float:
    """Distance [m] of a speed trace by the trapezoid rule: sum (v_i + v_{i+1}) / 2 dt_i,
    the distance the CE model's r_i terms use."""
    v = np.asarray(speed_mps, dtype=np.float64)
    return float(np.sum((v[:-1] + v[1:]) * np.diff(np.asarray(time_s, dtype=np.float64))) * 0.5)


def validate_cycle(time_s, speed_mps, elevation_m=None) -> None:
    """Raise ValueError unless the arrays form a valid cycle.

    Valid: 1-D, equal lengths, at least 2 samples, finite, time strictly increasing,
    speed >= 0. (File readers check the same with line numbers, see cevm.io.cycles.)
    """
    t = np.asarray(time_s)
    v = np.asarray(speed_mps)
    if t.ndim != 1 or v.shape != t.shape:
        raise ValueError("time_s and speed_mps must be 1-D arrays of equal length")
    if elevation_m is not None and np.shape(elevation_m) != t.shape:
        raise ValueError("elevation_m must have the length of time_s")
    if t.size < 2:
        raise ValueError("a drive cycle needs at least 2 samples")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(v))):
        raise ValueError("time_s and speed_mps must be finite")
    if elevation_m is not None and not np.all(np.isfinite(elevation_m)):
        raise ValueError("elevation_m must be finite")
    if np.any(np.diff(t) <= 0):
        raise ValueError("time_s must be strictly increasing")
    if np.any(v < 0):
        raise ValueError("speed_mps must be >= 0")


@dataclass(frozen=True, eq=False)
class StepTerms:
    """Per-step terms k, a, r, e and dt of a cycle (arrays of N-1 steps)."""

    k: np.ndarray  # J/kg
    a: np.ndarray  # J/m^2
    r: np.ndarray  # J/kg per unit Cr
    e: np.ndarray  # J/kg
    dt: np.ndarray  # s


def step_terms(
    time_s: np.ndarray,
    speed_mps: np.ndarray,
    elevation_m: np.ndarray | None = None,
    physics: Physics = PAPER_PHYSICS,
) -> StepTerms:
    """Per-step terms of eq. (11), (14), (17), (20) for N samples -> N-1 steps.

    Parameters
    ----------
    time_s : (N,) time [s], strictly increasing
    speed_mps : (N,) speed [m/s], >= 0
    elevation_m : (N,) road elevation [m], or None for a flat road
    physics : air density and gravity
    """
    t = np.asarray(time_s, dtype=np.float64)
    v = np.asarray(speed_mps, dtype=np.float64)
    dt = t[1:] - t[:-1]
    v0 = v[:-1]
    v1 = v[1:]
    v0sq = v0 * v0
    v1sq = v1 * v1
    k = 0.5 * (v1sq - v0sq)
    a = (0.25 * physics.rho_air_kg_m3) * (v0sq * v0 + v1sq * v1) * dt
    r = (0.5 * physics.g_mps2) * (v0 + v1) * dt
    if elevation_m is None:
        e = np.zeros_like(k)
    else:
        h = np.asarray(elevation_m, dtype=np.float64)
        e = physics.g_mps2 * (h[1:] - h[:-1])
    return StepTerms(k=k, a=a, r=r, e=e, dt=dt)


@dataclass(frozen=True, eq=False)
class ThresholdTable:
    """Non-simplified moving steps sorted by the CdA/m at which their Delta turns positive,
    for one rolling coefficient Cr, with prefix sums (leading zero) of x, r and a.

    For c = CdA/m: the steps with Delta_i > 0 are exactly the first
    ``searchsorted(threshold, c, side='left')`` of them.
    """

    cr: float
    threshold: np.ndarray  # (n,) sorted ascending
    x_cum: np.ndarray  # (n+1,)
    r_cum: np.ndarray  # (n+1,)
    a_cum: np.ndarray  # (n+1,)


_TABLE_CACHE_LIMIT = 64


@dataclass(frozen=True, eq=False)
class CycleVector:
    """The CE drive-cycle vector of one cycle, with its non-simplified steps.

    Attributes (units per unit of the vehicle parameter each multiplies):

    - ``s_me``  S_m + S_e over simplified steps [J/kg]       (multiplies m)
    - ``s_a``   S_a over simplified steps [J/m^2]            (multiplies CdA)
    - ``s_r``   S_r over simplified steps [J/kg]             (multiplies Cr m)
    - ``ns_x``, ``ns_a``, ``ns_r``: x_i = k_i + e_i, a_i, r_i of the non-simplified steps
      with the vehicle moving (a_i > 0); their sign depends on the vehicle.
    - ``stand_x``  sum of x_i = e_i over non-simplified steps at standstill (v = 0 at
      both ends; a_i = r_i = 0, so Delta_i = m e_i <= 0 whatever the vehicle) [J/kg].
    - ``cr0``: the criterion's Cr0; predictions need Cr >= cr0.
    - ``duration_s``, ``distance_m``, ``idle_s`` (time of steps at standstill),
      ``n_samples``, and the ``physics`` the terms were computed with.
    - ``k_pos``: the positive kinetic energy per kg, sum of max(k_i, 0) over every step
      [J/kg] (the kinetic term of an ICE, :mod:`cevm.core.energy`); NaN for a vector
      stored before it existed (format version 2).
    - ``traction_s``: the time of the simplified steps [s], those that need positive
      wheel work for every vehicle with Cr >= Cr0 (an engine's running fuel is burnt
      then, not while it coasts or brakes with its fuel cut off); NaN in version 2.

    Vectors of consecutive pieces add (``a + b``): a route is the sum of its cycles.
    """

    s_me: float
    s_a: float
    s_r: float
    ns_x: np.ndarray
    ns_a: np.ndarray
    ns_r: np.ndarray
    stand_x: float
    cr0: float
    duration_s: float
    distance_m: float
    idle_s: float
    n_samples: int
    physics: Physics = PAPER_PHYSICS
    k_pos: float = math.nan
    traction_s: float = math.nan
    _tables: dict = field(default_factory=dict, repr=False, compare=False)
    _direct_uses: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def delta(self) -> np.ndarray:
        """The paper's drive-cycle vector [S_m + S_e, S_a, S_r] (eq. 21, corrected)."""
        return np.array([self.s_me, self.s_a, self.s_r])

    @property
    def n_nonsimplified(self) -> int:
        """Number of non-simplified moving steps kept."""
        return int(self.ns_x.size)

    @cached_property
    def ns_sums(self) -> tuple[float, float, float]:
        """Sums of x, a, r over all non-simplified steps (standstill x included)."""
        return (
            float(self.ns_x.sum()) + self.stand_x,
            float(self.ns_a.sum()),
            float(self.ns_r.sum()),
        )

    def threshold_table(self, cr: float) -> ThresholdTable:
        """The sorted threshold table for rolling coefficient ``cr`` (cached per cr)."""
        cr = float(cr)
        table = self._tables.get(cr)
        if table is None:
            # a_i > 0 on every kept step, so the division is safe.
            threshold = -(self.ns_x + cr * self.ns_r) / self.ns_a
            order = np.argsort(threshold, kind="stable")
            zero = np.zeros(1)
            table = ThresholdTable(
                cr=cr,
                threshold=threshold[order],
                x_cum=np.concatenate([zero, np.cumsum(self.ns_x[order])]),
                r_cum=np.concatenate([zero, np.cumsum(self.ns_r[order])]),
                a_cum=np.concatenate([zero, np.cumsum(self.ns_a[order])]),
            )
            if len(self._tables) >= _TABLE_CACHE_LIMIT:
                self._tables.clear()
                self._direct_uses.clear()
            self._tables[cr] = table
        return table

    def __add__(self, other: CycleVector) -> CycleVector:
        if not isinstance(other, CycleVector):
            return NotImplemented
        if self.cr0 != other.cr0 or self.physics != other.physics:
            raise ValueError("cannot add cycle vectors with different cr0 or physics")
        return CycleVector(
            s_me=self.s_me + other.s_me,
            s_a=self.s_a + other.s_a,
            s_r=self.s_r + other.s_r,
            ns_x=np.concatenate([self.ns_x, other.ns_x]),
            ns_a=np.concatenate([self.ns_a, other.ns_a]),
            ns_r=np.concatenate([self.ns_r, other.ns_r]),
            stand_x=self.stand_x + other.stand_x,
            cr0=self.cr0,
            duration_s=self.duration_s + other.duration_s,
            distance_m=self.distance_m + other.distance_m,
            idle_s=self.idle_s + other.idle_s,
            n_samples=self.n_samples + other.n_samples,
            physics=self.physics,
            k_pos=self.k_pos + other.k_pos,
            traction_s=self.traction_s + other.traction_s,
        )

    @property
    def has_trip_sums(self) -> bool:
        """Whether the vector carries k_pos and traction_s (format 3; not a version-2
        vector read from an older store)."""
        return math.isfinite(self.k_pos) and math.isfinite(self.traction_s)

    def with_trip_sums(self, time_s: np.ndarray, speed_mps: np.ndarray,
                       elevation_m: np.ndarray | None = None) -> CycleVector:
        """This vector with k_pos and traction_s computed from its cycle's samples (for a
        version-2 vector, from the profile stored beside it); the rest unchanged. The
        samples must be those the vector was made from (a stored profile's float32
        rounding of speed and elevation can move a step across the criterion: the sums
        then differ by that step)."""
        st = step_terms(time_s, speed_mps, elevation_m, self.physics)
        simplified = (st.k + st.e + self.cr0 * st.r) > 0
        return replace(self, k_pos=float(np.maximum(st.k, 0.0).sum()), traction_s=float(st.dt[simplified].sum()),
                       _tables={}, _direct_uses={})

    def repeated(self, n: int) -> CycleVector:
        """The vector of ``n`` consecutive copies of this cycle, in O(1) in ``n``.

        Equal (to rounding) to ``self + self + ... + self``: every sum is n times as
        large, and each kept step stands once with n times its weight (x, a and r scale
        together, so the steps' thresholds, and with them every prediction's split, are
        the same as for n copies of the step).
        """
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
            raise ValueError(f"repeat must be an integer >= 1, got {n!r}")
        if n == 1:
            return self
        k = float(n)
        return CycleVector(
            s_me=self.s_me * k, s_a=self.s_a * k, s_r=self.s_r * k,
            ns_x=self.ns_x * k, ns_a=self.ns_a * k, ns_r=self.ns_r * k,
            stand_x=self.stand_x * k, cr0=self.cr0, duration_s=self.duration_s * k,
            distance_m=self.distance_m * k, idle_s=self.idle_s * k, n_samples=self.n_samples * int(n),
            physics=self.physics, k_pos=self.k_pos * k, traction_s=self.traction_s * k,
        )

    # --- serialisation (for the store) -------------------------------------------------
    def to_bytes(self) -> bytes:
        """Serialise to bytes; inverse of :meth:`from_bytes`.

        Layout (little-endian): the 8-byte magic ``b"CEVMVEC3"``, a uint32 n (the
        non-simplified steps), 13 float64 scalars (s_me, s_a, s_r, stand_x, cr0,
        duration_s, distance_m, idle_s, n_samples, rho_air, g, k_pos, traction_s), then
        ns_x, ns_a, ns_r as n float64 each. Version 2 (``b"CEVMVEC2"``, 11 scalars) and
        version 1 (an npz archive, 30x slower to read) are still read, with k_pos and
        traction_s NaN.
        """
        scalars = np.array(
            [self.s_me, self.s_a, self.s_r, self.stand_x, self.cr0, self.duration_s, self.distance_m,
             self.idle_s, float(self.n_samples), self.physics.rho_air_kg_m3, self.physics.g_mps2, self.k_pos,
             self.traction_s],
            dtype="<f8",
        )
        n = int(self.ns_x.size)
        return b"".join([_VECTOR_MAGIC, struct.pack("<I", n), scalars.tobytes(),
                         np.ascontiguousarray(np.stack([self.ns_x, self.ns_a, self.ns_r]), dtype="<f8").tobytes()])

    @classmethod
    def from_bytes(cls, data: bytes) -> CycleVector:
        """A vector from :meth:`to_bytes` (or the npz of version 1)."""
        data = bytes(data)
        if data[:2] == b"PK":
            return cls._from_npz(data)
        magic = data[: len(_VECTOR_MAGIC)]
        n_scalars = {_VECTOR_MAGIC: _N_SCALARS, _VECTOR_MAGIC_V2: _N_SCALARS - 2}.get(magic)
        if n_scalars is None:
            raise ValueError("not a cycle vector (bad magic)")
        head = len(_VECTOR_MAGIC)
        if len(data) < head + 4:
            raise ValueError(f"truncated cycle vector: {len(data)} bytes")
        (n,) = struct.unpack_from("<I", data, head)
        if len(data) != head + 4 + 8 * (n_scalars + 3 * n):
            raise ValueError(f"truncated cycle vector: {len(data)} bytes for {n} steps")
        values = np.frombuffer(data, dtype="<f8", offset=head + 4).astype(np.float64)
        return cls._from_arrays(values[:n_scalars], values[n_scalars:].reshape(3, n))

    @classmethod
    def _from_npz(cls, data: bytes) -> CycleVector:
        with np.load(io.BytesIO(data)) as z:
            if int(z["version"][0]) != 1:
                raise ValueError(f"unknown cycle vector version {int(z['version'][0])}")
            return cls._from_arrays(z["scalars"], z["ns"].copy())

    @classmethod
    def _from_arrays(cls, s: np.ndarray, ns: np.ndarray) -> CycleVector:
        return cls(
            s_me=float(s[0]),
            s_a=float(s[1]),
            s_r=float(s[2]),
            ns_x=ns[0],
            ns_a=ns[1],
            ns_r=ns[2],
            stand_x=float(s[3]),
            cr0=float(s[4]),
            duration_s=float(s[5]),
            distance_m=float(s[6]),
            idle_s=float(s[7]),
            n_samples=int(s[8]),
            physics=Physics(rho_air_kg_m3=float(s[9]), g_mps2=float(s[10])),
            k_pos=float(s[11]) if s.size > 11 else math.nan,
            traction_s=float(s[12]) if s.size > 12 else math.nan,
        )


_VECTOR_MAGIC = b"CEVMVEC3"
_VECTOR_MAGIC_V2 = b"CEVMVEC2"
_N_SCALARS = 13


def drive_cycle_vector(
    time_s: np.ndarray,
    speed_mps: np.ndarray,
    elevation_m: np.ndarray | None = None,
    *,
    cr0: float = CR0_DEFAULT,
    physics: Physics = PAPER_PHYSICS,
    validate: bool = True,
) -> CycleVector:
    """Compute the CE drive-cycle vector of a cycle, once, for every vehicle after.

    Parameters
    ----------
    time_s : (N,) time [s], strictly increasing
    speed_mps : (N,) speed [m/s], >= 0
    elevation_m : (N,) road elevation [m]; None means a flat road
    cr0 : conservative rolling coefficient of criterion (8) [-], default
        :data:`CR0_DEFAULT` (0.004)
    physics : air density and gravity (the paper's by default)
    validate : check the arrays first (skip only for arrays already validated)

    Returns
    -------
    CycleVector
    """
    if validate:
        validate_cycle(time_s, speed_mps, elevation_m)
    if cr0 < 0:
        raise ValueError("cr0 must be >= 0")
    st = step_terms(time_s, speed_mps, elevation_m, physics)
    x = st.k + st.e
    simplified = (x + cr0 * st.r) > 0
    moving = st.a > 0
    # Steps with a_i = 0 have v = 0 at both ends (speeds are >= 0), hence r_i = 0 too.
    # Positions, then take(): the elements a boolean mask selects, in its order (so the
    # same sums, bit for bit), at a third of the cost on a long cycle.
    simple = np.flatnonzero(simplified)
    keep = np.flatnonzero(~simplified & moving)
    stand = np.flatnonzero(~simplified & ~moving)
    return CycleVector(
        s_me=float(x.take(simple).sum()),
        s_a=float(st.a.take(simple).sum()),
        s_r=float(st.r.take(simple).sum()),
        ns_x=x.take(keep),
        ns_a=st.a.take(keep),
        ns_r=st.r.take(keep),
        stand_x=float(x.take(stand).sum()),
        cr0=float(cr0),
        duration_s=float(st.dt.sum()),
        distance_m=float(st.r.sum() / physics.g_mps2),
        idle_s=float(st.dt[~moving].sum()),
        n_samples=int(np.size(time_s)),
        physics=physics,
        k_pos=float(np.maximum(st.k, 0.0).sum()),
        traction_s=float(st.dt.take(simple).sum()),
    )


def cycle_vector(cycle: DriveCycle, *, cr0: float = CR0_DEFAULT, physics: Physics = PAPER_PHYSICS) -> CycleVector:
    """:func:`drive_cycle_vector` of a validated :class:`DriveCycle`."""
    return drive_cycle_vector(cycle.time_s, cycle.speed_mps, cycle.elevation_m, cr0=cr0, physics=physics,
                              validate=False)
