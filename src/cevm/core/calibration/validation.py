"""Honest validation: every trip predicted by a fit that never saw it (pure).

Folds are built over groups (a group key such as the day keeps near-duplicate trips, one
driver, one load, one weather, on one side): K-fold (default 5), or leave-one-group-out
when there are fewer than ``loo_below`` (10) groups. The error of a trip is
e = (predicted - measured) / measured, reported as the paper's mean and standard
deviation in percent.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from cevm.core.calibration.data import TripSet
from cevm.core.cycle import CycleVector
from cevm.core.vehicle import Vehicle, predict


@dataclass(frozen=True)
class ErrorStats:
    """Statistics of the per-trip error e = (predicted - measured) / measured [%].

    std_pct uses ddof = 1 (sample standard deviation); NaN for fewer than 2 trips.
    """

    n: int
    mean_pct: float
    std_pct: float
    rms_pct: float
    max_abs_pct: float

    @classmethod
    def of(cls, error_pct: np.ndarray) -> ErrorStats:
        e = np.asarray(error_pct, dtype=np.float64)
        e = e[np.isfinite(e)]
        if e.size == 0:
            return cls(0, math.nan, math.nan, math.nan, math.nan)
        return cls(
            n=int(e.size),
            mean_pct=float(e.mean()),
            std_pct=float(e.std(ddof=1)) if e.size > 1 else math.nan,
            rms_pct=float(np.sqrt(np.mean(e * e))),
            max_abs_pct=float(np.abs(e).max()),
        )


@dataclass(frozen=True)
class TripRow:
    """Per-trip outcome of a calibration (consumption in litres or joules).

    weight is the trip's share of the fit's total weight (weights of used trips sum to 1);
    fold is the cross-validation fold that held the trip out (-1 without CV);
    predicted_low / predicted_high the held-out prediction's interval (at the
    calibration's ``interval`` level; NaN without CV) and sd_cv its standard deviation,
    against the measurement (the measurement's own random uncertainty included);
    sd_in_sample the same of the in-sample prediction (the posterior of all trips);
    flags notes on the trip (a splice the cleaner could not repair ...).
    """

    trip_id: str
    group: str | None
    mass_kg: float
    distance_m: float
    measured: float
    uncertainty: float
    rel_uncertainty: float
    weight: float
    predicted_in_sample: float
    predicted_cv: float
    error_pct_in_sample: float
    error_pct_cv: float
    fold: int
    ambient_c: float = math.nan
    mass_source: str | None = None
    predicted_low: float = math.nan
    predicted_high: float = math.nan
    sd_cv: float = math.nan
    flags: tuple = ()
    sd_in_sample: float = math.nan

    @property
    def inside(self) -> bool | None:
        """Whether the measurement lies inside the held-out interval (None without one)."""
        if not (math.isfinite(self.predicted_low) and math.isfinite(self.predicted_high)):
            return None
        return bool(self.predicted_low <= self.measured <= self.predicted_high)


def folds(data: TripSet, cv_folds: int, loo_below: int, seed: int) -> tuple[np.ndarray, str]:
    """Fold index per trip (-1: no CV) and a description; groups never straddle folds."""
    keys = [g if g is not None else f"\0{tid}" for g, tid in zip(data.groups, data.ids, strict=True)]
    uniq = list(dict.fromkeys(keys))
    grouped = any(g is not None for g in data.groups)
    G = len(uniq)
    if cv_folds < 2 or G < 2:
        return np.full(data.n, -1), "none"
    if loo_below > G or cv_folds >= G:
        fold_of = {g: i for i, g in enumerate(uniq)}
        scheme = f"leave-one-group-out ({G} groups)" if grouped else "leave-one-out"
    else:
        rng = np.random.default_rng(seed)
        order = [uniq[i] for i in rng.permutation(G)]
        size = dict.fromkeys(uniq, 0)
        for k in keys:
            size[k] += 1
        order.sort(key=lambda g: -size[g])  # stable: shuffled order among equal sizes
        load = np.zeros(cv_folds)
        fold_of = {}
        for g in order:
            f = int(np.argmin(load))
            fold_of[g] = f
            load[f] += size[g]
        scheme = f"grouped {cv_folds}-fold ({G} groups)" if grouped else f"{cv_folds}-fold"
    return np.array([fold_of[k] for k in keys]), scheme


def predict_one(vehicle: Vehicle, vector: CycleVector, mass_kg: float, ambient_c: float) -> float:
    """One trip's consumption with :func:`cevm.core.vehicle.predict` [J or l]; a NaN
    temperature means "not logged": the vehicle's default is used (only a vehicle with
    temperature terms depends on it, and those are fitted only on trips with one)."""
    p = predict(vector, vehicle, float(mass_kg), ambient_c=None if not math.isfinite(ambient_c) else float(ambient_c))
    q = p.energy_j if vehicle.is_ev else p.fuel_l
    assert q is not None  # predict() sets the powertrain's quantity
    return float(q)


def predict_set(vehicle: Vehicle, data: TripSet, idx=None) -> np.ndarray:
    """:func:`predict_one` for the trips ``idx`` of ``data`` (all by default)."""
    idx = range(data.n) if idx is None else idx
    return np.array([predict_one(vehicle, data.vectors[i], data.mass[i], data.ambient_c[i]) for i in idx])


def time_predictions(vehicle: Vehicle, data: TripSet, repeats: int) -> tuple[float, float] | None:
    """(mean, std) over trips of the time of one prediction from a cached vector [s]."""
    if repeats <= 0 or data.n == 0:
        return None
    per_trip = np.empty(data.n)
    for i, (v, m, t) in enumerate(zip(data.vectors, data.mass, data.ambient_c, strict=True)):
        predict_one(vehicle, v, m, t)  # warm any per-vector cache first
        t0 = time.perf_counter()
        for _ in range(repeats):
            predict_one(vehicle, v, m, t)
        per_trip[i] = (time.perf_counter() - t0) / repeats
    return float(per_trip.mean()), float(per_trip.std(ddof=1)) if data.n > 1 else 0.0
