"""The fleet's duties summed up (pure): how many complete, at what confidence, and the
battery and charger that would complete a share of them; and what a duty asks beyond
what the candidate's calibration saw.

Sizes for a share q of the duties: where each duty starts from the same level (a full
charge overnight) a duty's need does not depend on the others, and the fleet's size is
the q-quantile of the duties' needs (:func:`~cevm.core.replay.sizing.size_for_share`).
Where the level carries across duties (one chain per vehicle), the share of duties a
battery completes is itself monotone in its size (every level is, :mod:`~cevm.core.replay.chain`),
so the fleet's size is bisected directly on it (:func:`chained_sizes`), every vehicle's
chain at once.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from cevm.core.replay.chain import Lanes, Stops, run_chains
from cevm.core.replay.plan import Excess, VehiclePlan
from cevm.core.replay.sizing import charger_upper, smallest_passing, undecided_trips
from cevm.core.vehicle import extrapolation_mask, extrapolation_text


def duty_extrapolation(plan: VehiclePlan) -> list[str]:
    """Per duty, what its trips ask beyond what the candidate's calibration saw: "none",
    or the axes of :data:`cevm.core.vehicle.EXTRAPOLATION_AXES` (temperature, mass, speed,
    duty) joined by "+", as ``cevm predict`` says them (:func:`cevm.core.vehicle.extrapolation_mask`)."""
    t = plan.trips
    e = plan.energies
    with np.errstate(divide="ignore", invalid="ignore"):
        speed = t.distance_m / e.duration_s
        idle = np.where(e.duration_s > 0, e.idle_s / e.duration_s, np.nan)
    mask = extrapolation_mask(plan.vehicle.calibration, mass_kg=e.mass_kg, ambient_c=e.ambient_c,
                              mean_speed_mps=speed, idle_share=idle)
    if not mask.size:
        return []
    per = np.bitwise_or.reduceat(np.broadcast_to(mask, (t.n,)), plan.duties.first)
    return [extrapolation_text(int(m)) for m in per.tolist()]


@dataclass
class Fleet:
    """The duties of a replay, gathered vehicle by vehicle (:meth:`add`): per duty its
    vehicle, start [s], energy and its interval [J or l], whether it completes at the
    mean, whether the candidate can follow its trips (``follows``), its probability, and
    its battery and charger needs at the mean energies and at the sizing's confidence
    (``battery_conf``, ``charger_conf``; inf where the candidate cannot follow it)."""

    vehicle: list
    start_s: list
    energy: list
    low: list
    high: list
    completes: list
    follows: list
    p: list
    battery: list
    charger: list
    battery_conf: list
    charger_conf: list

    @classmethod
    def empty(cls) -> Fleet:
        return cls(*([] for _ in range(12)))

    def add(self, plan: VehiclePlan, p: np.ndarray, low: np.ndarray, high: np.ndarray) -> None:
        first = plan.duties.first
        self.vehicle += [plan.trips.vehicle_id] * plan.duties.n
        self.start_s.append(plan.trips.start_s[first])
        self.energy.append(np.add.reduceat(plan.energies.energy, first) if first.size else np.zeros(0))
        self.low.append(low)
        self.high.append(high)
        self.completes.append(plan.completes)
        self.follows.append(plan.follows)
        self.p.append(plan.judged(p))
        # a duty the candidate cannot follow: no battery or charger completes it
        self.battery.append(np.where(plan.follows, plan.battery_needed, np.inf))
        self.charger.append(np.where(plan.follows | np.isnan(plan.charger_needed_w), plan.charger_needed_w, np.inf))
        self.battery_conf.append(np.where(plan.follows, plan.battery_needed_conf, np.inf))
        self.charger_conf.append(np.where(plan.follows | np.isnan(plan.charger_needed_w_conf),
                                          plan.charger_needed_w_conf, np.inf))

    def array(self, name: str) -> np.ndarray:
        parts = getattr(self, name)
        return np.concatenate(parts) if parts else np.zeros(0)

    @property
    def n(self) -> int:
        return len(self.vehicle)


# ------------------------------------------------------------ levels carried across duties


@dataclass(frozen=True, eq=False)
class Chain:
    """One vehicle's chain of duties for the fleet's sizing: its trips' energies, excess
    (:class:`~cevm.core.replay.plan.Excess`, and ``exact`` to learn more), stops, duty
    bounds, and which duties the candidate can follow (a duty it cannot is completed by no
    battery or charger)."""

    energy: np.ndarray
    excess: Excess
    exact: Callable[[np.ndarray], np.ndarray]
    stops: Stops
    bounds: np.ndarray
    follows: np.ndarray | None = None  # per duty: the candidate can follow its trips (None: all)


def _joined(chains: Sequence[Chain]) -> tuple[np.ndarray, Stops, np.ndarray, Lanes, np.ndarray]:
    sizes = np.array([c.energy.size for c in chains], dtype=np.int64)
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    energy = np.concatenate([c.energy for c in chains])
    stops = Stops(*(np.concatenate([getattr(c.stops, f) for c in chains])
                    for f in ("dwell_s", "power_w", "sizable", "duty_end")))
    bounds = np.concatenate([c.bounds[:-1] + o for c, o in zip(chains, offsets[:-1], strict=True)] + [offsets[-1:]])
    lanes = Lanes.of(offsets[:-1], offsets[1:])
    return energy, stops, bounds, lanes, offsets


def chained_sizes(chains: Sequence[Chain], share: float, *, soc_start: float, reserve: float, efficiency: float,
                  capacity: float, battery_step: float, charger_step: float) -> tuple[float, float]:
    """The smallest battery (a multiple of ``battery_step``) and, at ``capacity``, the
    smallest charger (of ``charger_step`` [W]) with which at least ``share`` of the
    duties of ``chains`` keep their reserve, levels carried across duties (module notes;
    ``soc_start`` and ``reserve`` are shares of the capacity); inf where none does, NaN
    without duties. The trips' excess is refined as for one duty's sizes."""
    if not chains:
        return float("nan"), float("nan")
    energy, stops, bounds, lanes, offsets = _joined(chains)
    n_duties = bounds.size - 1
    follows = np.concatenate([np.ones(c.bounds.size - 1, dtype=bool) if c.follows is None else c.follows
                              for c in chains])

    def excess(which: str) -> np.ndarray:
        return np.concatenate([getattr(c.excess, which) for c in chains])

    def share_at(x: np.ndarray, cap: float, start: float, power: np.ndarray | None = None) -> float:
        run = run_chains(lanes, energy, x, stops, capacity=cap, start=start, efficiency=efficiency, power_w=power)
        low = lanes.put(run.low, energy.size)
        kept = np.minimum.reduceat(low, bounds[:-1]) >= reserve * cap
        return float(np.count_nonzero(kept & follows)) / n_duties

    def learn(trips: np.ndarray) -> None:
        owner = np.searchsorted(offsets, trips, side="right") - 1
        for v in np.unique(owner).tolist():
            chains[v].excess.learn(trips[owner == v] - offsets[v], chains[v].exact)

    def refined(need: Callable[[np.ndarray], float], undecided: Callable[[float], np.ndarray]) -> float:
        while True:
            hi, lo = need(excess("bound")), need(excess("value"))
            if hi == lo:
                return hi
            trips = undecided(lo)
            if not trips.size:
                return hi
            learn(trips)

    battery = float("nan")
    if soc_start > reserve:
        top = np.concatenate([np.maximum(c.energy, 0.0) for c in chains]).sum()
        top += excess("bound").max(initial=0.0)
        k_top = max(1, int(np.ceil(top / (soc_start - reserve) / battery_step)))

        def need_c(x: np.ndarray) -> float:
            k = smallest_passing(lambda k: np.array([share_at(x, float(k[0]) * battery_step,
                                                              soc_start * float(k[0]) * battery_step) >= share]),
                                 np.array([1]), np.array([k_top]))[0]
            return float(k) * battery_step if k <= k_top else float("inf")

        def undecided_c(lo: float) -> np.ndarray:
            return undecided_trips(lanes, bounds, energy, excess("value"), excess("bound"), excess("known"), stops,
                                   capacity=lo, start=soc_start * lo, reserve=reserve * lo, efficiency=efficiency)

        battery = refined(need_c, undecided_c)
    charger = float("nan")
    if stops.sizable.any():
        k_top = int(np.ceil(charger_upper(stops, capacity, efficiency) / charger_step))

        def need_p(x: np.ndarray) -> float:
            k = smallest_passing(lambda k: np.array([share_at(x, capacity, soc_start * capacity,
                                                              stops.with_power(float(k[0]) * charger_step)) >= share]),
                                 np.array([0]), np.array([k_top]))[0]
            return float(k) * charger_step if k <= k_top else float("inf")

        def undecided_p(lo: float) -> np.ndarray:
            return undecided_trips(lanes, bounds, energy, excess("value"), excess("bound"), excess("known"), stops,
                                   capacity=capacity, start=soc_start * capacity, reserve=reserve * capacity,
                                   efficiency=efficiency, power_w=stops.with_power(lo))

        charger = refined(need_p, undecided_p)
    return battery, charger
