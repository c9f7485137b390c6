"""Measured consumption of a trip from a log's energy sources (rates, counters, SoC):
the parameters, each source's estimate, and the choice among a trip's sources.

The estimators themselves run over many trips at once, for one trip as for a thousand
(:mod:`cevm.ingest.measured`: :func:`~cevm.ingest.measured.measure_trips`); pure
functions over sorted sample arrays: no I/O, no per-sample Python loops.

Three kinds of source (attribute ``kind`` of an energy source, see
:class:`EnergySourceLike`):

``rate``
    A flow: fuel rate [l/s] (``quantity == "fuel_l"``) or electric power [W = J/s]
    (``quantity == "energy_j"``). Integrated over the trip with the trapezoid rule on
    the piecewise-linear interpolant of the samples, exactly from ``t0`` to ``t1`` (the
    edge values are held when the first or last sample lies inside the span). Steps
    between samples longer than ``max_gap_s`` are *gaps*: they are bridged linearly (the
    best estimate) but their total duration is reported as the gap share, and they add
    an uncertainty term. A column written ``"a*b"`` (or the virtual column
    ``"battery_power_w"``) is the product of two canonical columns, evaluated where
    either is sampled, each factor interpolated in time over at most ``max_gap_s``:
    battery power = ``battery_voltage_v * battery_current_a`` [W].
``counter``
    A cumulative counter [l or J]. The trip's value is the sum of the corrected
    increments between the first and the last valid sample inside ``[t0, t1]``:

    - a step below ``-modulus/2`` of a counter with a known ``modulus`` (optional
      attribute of the source) is a wrap: ``+modulus``;
    - a step within the plausible band ``[-max_rate_neg dt - 2 q, max_rate dt + 2 q]``
      (q = resolution; ``max_rate_neg`` = 0 for fuel, which never flows back, and
      ``max_power_w`` for a net energy counter, which runs backwards during
      regeneration) is kept as it is (one-step flicker of a quantised reading cancels);
    - an implausibly large negative step to a value near zero
      (``<= reset_fraction * min(previous, median reading) + 2 q``) is a *reset* (ECU swapped or counter
      cleared): the step counts 0 and differencing continues from the new base;
    - any other implausible step (up or down) is a *jump* (glitch, or a wrap at an
      unknown modulus): it counts 0 as well.

    Each reset or jump loses the consumption of one sampling step; it is not guessed but
    added to the uncertainty at the trip's mean rate.
``soc``
    Battery state of charge [%]: energy = (soc_first - soc_last) / 100 * capacity_j, with
    the first and the last valid readings inside ``[t0, t1]`` (quantised readings: no
    fitting). A BMS's SoC is an estimate; the result is only as good as the nominal
    usable capacity.

Uncertainty (1 sigma, in the measurement's unit), terms added in quadrature:

- quantisation of a difference of two readings (counter, SoC), each uniformly
  quantised with step q and independent: sqrt(2 q^2 / 12) = q / sqrt(6);
- quantisation noise of an integrated rate with resolution q [unit/s]: each sample's
  rounding error is uniform, sigma q / sqrt(12), weighted by its trapezoid weight w_k
  [s]: q / sqrt(12) * sqrt(sum w_k^2);
- gaps of an integrated rate: the mean rate over a gap of length G_j is unknown with
  the spread of the trip's rate samples s_r (population std): s_r * sqrt(sum G_j^2);
- lost steps of a counter (resets, jumps) and the uncovered edges of a counter or SoC
  span (trip time before the first / after the last reading): the trip's mean rate
  times the lost time, one term per lost step and one for the edges.

- the source's systematic (calibration) uncertainty: ``accuracy_pct`` of the value, as
  the profile declares it for that source, else :data:`DEFAULT_ACCURACY_PCT` of its
  kind. Every estimate keeps both parts (``random_uncertainty``,
  ``systematic_uncertainty``); ``uncertainty`` is their quadrature sum.

When several sources are given, :func:`choose_measurement` chooses among those *valid* for the
trip (coverage of the trip duration >= ``min_coverage`` and, for rates, gap share <=
``max_gap_share``): the quantity of the most trusted valid source (lowest ``priority``:
fuel or electric energy), and of that quantity the source with the **least
uncertainty** (ties: lower ``priority``, then the order given), the systematic parts
taken at one common value (the median of the estimates, so that equal accuracies do not
favour the source that reads less). So integrated battery
power at 1 Hz (no quantisation; 1 Hz sampling of a varying power agrees with a 10 Hz
meter within 0.1 %) is chosen over a 0.1 kWh counter on a 2 kWh trip (0.04 kWh of
quantisation, 2 %), while the counter wins on trips long enough that its fixed
quantisation weighs less than the power's extra sampling error. The other valid sources
of that quantity are reported as cross-checks, e.g.
``"fuel_rate_lps vs flowmeter_fuel_lps: +3.1 % (0.9 sigma)"`` (the first is 3.1 % above the
chosen, 0.9 combined standard uncertainties), and a difference beyond
``disagreement_sigma`` combined standard uncertainties is also a warning.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from cevm.core.trip import Measurement

#: Systematic (calibration) uncertainty of a source, 1 sigma, in % of its value, by kind,
#: for a profile entry without ``accuracy_pct``. ``rate`` and ``counter``: 2 %, between a
#: calibrated meter (flow meters and HV current sensors are specified at 0.5-1 %) and the
#: fuel an ECU computes from its injection commands (off by a few percent); ``soc``: 5 %,
#: since a state of charge is the BMS's estimate and the usable capacity drifts with age
#: and temperature. Declare your logger's figure in its profile.
DEFAULT_ACCURACY_PCT: dict[str, float] = {"rate": 2.0, "counter": 2.0, "soc": 5.0}

#: Virtual column: battery power [W] = battery_voltage_v * battery_current_a.
BATTERY_POWER_COLUMN = "battery_power_w"
_BATTERY_POWER_FACTORS = ("battery_voltage_v", "battery_current_a")


class EnergySourceLike(Protocol):
    """What :mod:`cevm.ingest.consumption` needs of an energy source (``cevm.ingest.reading``).

    ``column``: canonical column, ``"a*b"`` product of two columns, or
    ``"battery_power_w"``; ``kind``: ``"rate"``, ``"counter"`` or ``"soc"``;
    ``quantity``: ``"fuel_l"`` or ``"energy_j"``; ``resolution``: quantisation step in
    the column's unit (l, J, l/s, W, or % for SoC); ``priority``: lower = more trusted;
    ``capacity_j``: usable battery energy [J] for a SoC source, else None. Optional
    attributes, read with ``getattr``: ``modulus`` (counter wrap value, same unit) and
    ``accuracy_pct`` (1-sigma systematic uncertainty in % of the value; None or absent:
    :data:`DEFAULT_ACCURACY_PCT` of its kind).
    """

    # read-only (properties): a frozen dataclass such as reading.EnergySource fits
    @property
    def column(self) -> str: ...
    @property
    def kind(self) -> str: ...
    @property
    def quantity(self) -> str: ...
    @property
    def resolution(self) -> float: ...
    @property
    def priority(self) -> int: ...
    @property
    def capacity_j(self) -> float | None: ...


@dataclass(frozen=True)
class ConsumptionParams:
    """Parameters of the measured-consumption estimate.

    - ``min_coverage = 0.9``: a source must cover at least 90 % of the trip's duration
      (span of its readings, or for a rate 1 - gap share) to be used; below that the
      missing part (uncounted consumption) could exceed the model's own error (~4 %).
    - ``max_gap_s = 15.0``: rate samples further apart than this are a gap; covers
      1 Hz loggers with missed ticks and the 1-10 s sampling of telematics portals.
    - ``max_gap_share = 0.1``: a rate with more than 10 % of the trip in gaps is not
      used (same reasoning as ``min_coverage``).
    - ``max_fuel_lps = 0.1``: 360 l/h, well above the full-load consumption of the
      largest truck engines (~600 kW x 0.25 l/kWh = 150 l/h); faster counter steps are
      glitches.
    - ``max_power_w = 2.0e6``: 2 MW, well above any road vehicle's battery power (large
      e-buses and e-trucks stay below 1 MW); bound for energy counters both ways.
    - ``reset_fraction = 0.01``: a counter that drops to at most 1 % of its level (the
      previous reading or the median reading, the smaller; plus two quantisation steps)
      was reset; 1 % of a lifetime total is still far above one trip's consumption.
    - ``disagreement_sigma = 3.0``: two sources whose difference exceeds three combined
      standard uncertainties disagree (by chance, with honest uncertainties, one pair
      in 370): a warning, since one of them, or its declared accuracy, is wrong.
    """

    min_coverage: float = 0.9
    max_gap_s: float = 15.0
    max_gap_share: float = 0.1
    max_fuel_lps: float = 0.1
    max_power_w: float = 2.0e6
    reset_fraction: float = 0.01
    disagreement_sigma: float = 3.0


@dataclass(frozen=True)
class SourceEstimate:
    """One source's estimate for one trip (valid or not, with the reason).

    ``uncertainty`` (1 sigma, the measurement's unit) is the quadrature sum of
    ``random_uncertainty`` (quantisation, gaps, lost counter steps) and
    ``systematic_uncertainty`` (``accuracy_pct`` of the value)."""

    source: str
    kind: str
    quantity: str
    priority: int
    value: float
    resolution: float  # in the measurement's unit (0.0 for an integrated rate)
    uncertainty: float
    coverage: float  # share of the trip duration covered, 0..1
    gap_share: float  # share of the trip duration in gaps (rates), else 1 - coverage
    valid: bool
    reason: str = ""
    counts: dict = field(default_factory=dict)
    random_uncertainty: float = math.nan
    systematic_uncertainty: float = math.nan
    accuracy_pct: float = math.nan

    def measurement(self) -> Measurement:
        return Measurement(
            kind=self.quantity,  # type: ignore[arg-type]
            value=float(self.value),
            source=self.source,
            resolution=float(self.resolution),
            uncertainty=float(self.uncertainty),
        )

    def as_dict(self) -> dict:
        """JSON-serialisable summary (non-finite numbers become None)."""
        return {
            "source": self.source,
            "kind": self.kind,
            "quantity": self.quantity,
            "priority": int(self.priority),
            "value": _jsonable(self.value),
            "resolution": _jsonable(self.resolution),
            "uncertainty": _jsonable(self.uncertainty),
            "random_uncertainty": _jsonable(self.random_uncertainty),
            "systematic_uncertainty": _jsonable(self.systematic_uncertainty),
            "accuracy_pct": _jsonable(self.accuracy_pct),
            "coverage": _jsonable(self.coverage),
            "gap_share": _jsonable(self.gap_share),
            "valid": bool(self.valid),
            "reason": self.reason,
            **{k: int(v) for k, v in self.counts.items()},
        }


def accuracy_pct_of(source: EnergySourceLike) -> float:
    """The source's 1-sigma systematic uncertainty [% of the value]: its own
    ``accuracy_pct``, else :data:`DEFAULT_ACCURACY_PCT` of its kind (0 for an unknown
    kind, which is invalid anyway)."""
    acc = getattr(source, "accuracy_pct", None)
    return float(acc) if acc is not None else DEFAULT_ACCURACY_PCT.get(str(source.kind), 0.0)


def _jsonable(x: float) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


# --------------------------------------------------------------------------- samples


#: Elements at a time of the elementwise steps over long arrays (interpolation,
#: distances, jump tests): their temporaries then take a few MB instead of several
#: arrays of a log's length; the results do not depend on it.
CHUNK_ROWS = 1 << 16


def chunks(n: int, size: int | None = None):
    """(start, stop) of consecutive slices of ``range(n)`` of at most ``size`` (default
    :data:`CHUNK_ROWS`)."""
    size = size or CHUNK_ROWS
    return ((a, min(a + size, n)) for a in range(0, n, size))


def interp_limited(
    q: np.ndarray, ts: np.ndarray, vs: np.ndarray, max_gap_s: float, *more: np.ndarray,
    right: np.ndarray | None = None,
):
    """Linear interpolation of samples (ts strictly increasing, vs) at times q, NaN
    where q lies outside the samples or between two samples more than ``max_gap_s``
    apart (exact sample times always get their value). Further value arrays in
    ``more`` (same sample times) are interpolated too; then a list is returned.
    ``right``: ``np.searchsorted(ts, q, side="left")`` when the caller knows it (for
    samples at ``q[mask]`` of a strictly increasing ``q``: ``cumsum(mask) - mask``).
    A long ``q`` is done :data:`CHUNK_ROWS` at a time (bounded temporaries)."""
    n = ts.size
    arrays = (vs, *more)
    if n == 0:
        outs = [np.full(q.shape, np.nan) for _ in arrays]
        return outs if more else outs[0]
    if q.ndim == 1 and q.size > CHUNK_ROWS:
        outs = [np.empty(q.shape) for _ in arrays]
        for a, b in chunks(q.size):
            part = interp_limited(q[a:b], ts, vs, max_gap_s, *more, right=None if right is None else right[a:b])
            for o, x in zip(outs, part if more else [part], strict=True):
                o[a:b] = x
        return outs if more else outs[0]
    if right is None:
        right = np.searchsorted(ts, q, side="left")
    rc = np.minimum(right, n - 1)
    exact = ts[rc] == q
    lc = np.maximum(right - 1, 0)
    span = ts[rc] - ts[lc]
    ok = (right > 0) & (right < n) & (span <= max_gap_s) & (span > 0)
    w = (q - ts[lc]) / np.where(ok, span, 1.0)
    miss = ~(ok | exact)
    outs = []
    for a in arrays:
        al = a[lc]
        val = np.where(exact, a[rc], al + w * (a[rc] - al))
        val[miss] = np.nan
        outs.append(val)
    return outs if more else outs[0]


def columns_read(column: str) -> set[str]:
    """The canonical columns that the estimate of a source column may read
    (:func:`cevm.ingest.measured.window_samples`): the column itself, or a product's
    factors."""
    return {column, *_BATTERY_POWER_FACTORS, *(part.strip() for part in column.split("*"))}


def product_factors(column: str) -> tuple[str, ...]:
    """The factor columns of a source column that is a product (``"battery_power_w"``:
    voltage times current; ``"a*b"``: its parts); KeyError for any other column (one
    that is absent from the log)."""
    if column == BATTERY_POWER_COLUMN:
        return _BATTERY_POWER_FACTORS
    if "*" in column:
        return tuple(part.strip() for part in column.split("*"))
    raise KeyError(column)


# ------------------------------------------------------------------------ estimators


@dataclass(frozen=True)
class RawEstimate:
    """An estimator's figures for one trip, before the choice of a valid source: its
    value, random uncertainty, coverage, gap share, repair counts, and why it has none."""

    value: float
    uncertainty: float
    coverage: float
    gap_share: float
    counts: dict
    reason: str = ""


#: why a logged state of charge measured nothing: the profile gives no capacity
NO_CAPACITY = "state of charge logged, but no capacity_j to turn it into energy"


def invalid_estimate(source: EnergySourceLike, reason: str, raw: RawEstimate | None = None) -> SourceEstimate:
    """The estimate of a source not valid for a trip, and why (with what was measured)."""
    return SourceEstimate(
        str(source.column), str(source.kind), str(source.quantity), int(source.priority),
        raw.value if raw else math.nan, 0.0,
        raw.uncertainty if raw else math.nan,
        raw.coverage if raw else 0.0, raw.gap_share if raw else 1.0,
        False, reason, raw.counts if raw else {},
    )


def finish_estimate(source: EnergySourceLike, raw: RawEstimate, resolution: float,
                    params: ConsumptionParams) -> SourceEstimate:
    """A source's estimate for a trip from its raw figures: invalid (with the reason)
    where it has none, no finite value, too many gaps or too little coverage; else its
    value with the systematic uncertainty added."""
    if raw.reason:
        return invalid_estimate(source, raw.reason, raw)
    if not math.isfinite(raw.value):
        return invalid_estimate(source, "no finite value", raw)
    if str(source.kind) == "rate" and raw.gap_share > params.max_gap_share:
        return invalid_estimate(source, f"gap share {raw.gap_share:.3f} > {params.max_gap_share}", raw)
    if raw.coverage < params.min_coverage:
        return invalid_estimate(source, f"coverage {raw.coverage:.3f} < {params.min_coverage}", raw)
    accuracy = accuracy_pct_of(source)
    systematic = accuracy / 100.0 * abs(raw.value)
    return SourceEstimate(
        str(source.column), str(source.kind), str(source.quantity), int(source.priority), raw.value, resolution,
        math.hypot(raw.uncertainty, systematic), raw.coverage, raw.gap_share, True, "", raw.counts, raw.uncertainty,
        systematic, accuracy,
    )


def choose_measurement(estimates: Sequence[SourceEstimate],
                       params: ConsumptionParams = ConsumptionParams()) -> tuple[Measurement | None, dict]:
    """A trip's measured consumption from its sources' estimates: the
    :class:`~cevm.core.trip.Measurement` of the chosen source (see the module docstring:
    the least uncertain valid source of the most trusted valid source's quantity) or
    None, and a JSON-serialisable quality dict: ``sources`` (every source's estimate,
    both parts of its uncertainty, and its validity), ``cross_checks`` (other valid
    sources of the chosen quantity against the chosen one, in percent and in combined
    standard uncertainties), ``warnings`` (those beyond ``disagreement_sigma``),
    ``chosen_by`` and, for the chosen source, ``source``, ``coverage``, ``gap_share``
    and its repair counts."""
    quality: dict = {"sources": [e.as_dict() for e in estimates], "cross_checks": [], "warnings": []}
    valid = [e for e in estimates if e.valid]
    if not valid:
        quality["source"] = None
        if any(e.reason == NO_CAPACITY for e in estimates):
            quality["warnings"].append(
                "no measured energy: the log's state of charge gives none without the battery's usable capacity; "
                "give 'capacity' and 'capacity_unit' in the profile's soc [[energy]] entry")
        return None, quality
    quantity = min(valid, key=lambda e: e.priority).quantity  # min() keeps the first of equals
    same = [e for e in valid if e.quantity == quantity]
    # uncertainties compared at one common value (the median estimate), so that equal
    # accuracies do not favour the source that happens to read less
    ref = statistics.median(abs(e.value) for e in same)
    best = min(same, key=lambda e: (_sortable(math.hypot(e.random_uncertainty, e.accuracy_pct / 100.0 * ref)),
                                    e.priority))
    quality.update(
        source=best.source,
        chosen_by="least uncertainty" if len(same) > 1 else "only valid source",
        coverage=_jsonable(best.coverage),
        gap_share=_jsonable(best.gap_share),
        **{k: int(v) for k, v in best.counts.items()},
    )
    for e in same:
        if e is best:
            continue
        combined = math.hypot(e.uncertainty, best.uncertainty)
        diff = e.value - best.value
        sigmas = abs(diff) / combined if combined > 0 else (0.0 if diff == 0 else math.inf)
        sig = f"{sigmas:.1f} sigma" if math.isfinite(sigmas) else "no uncertainty to compare with"
        if best.value != 0:
            check = f"{e.source} vs {best.source}: {diff / abs(best.value) * 100.0:+.1f} % ({sig})"
        else:
            check = f"{e.source} vs {best.source}: chosen value is 0 ({sig})"
        quality["cross_checks"].append(check)
        if sigmas > params.disagreement_sigma:
            quality["warnings"].append(
                f"measured {quantity} disagrees: {check}, beyond {params.disagreement_sigma:g} combined "
                "standard uncertainties (a sensor or its declared accuracy_pct is wrong)")
    return best.measurement(), quality


def _sortable(x: float) -> float:
    return x if math.isfinite(x) else math.inf
