"""Measured consumption of a trip from a log's energy sources (rates, counters, SoC).

Pure functions over sorted sample arrays: no I/O, no per-sample Python loops.

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

When several sources are given, :func:`measure_trip` chooses among those *valid* for the
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
from collections.abc import Mapping, Sequence
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


def _interp_limited(
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
            part = _interp_limited(q[a:b], ts, vs, max_gap_s, *more, right=None if right is None else right[a:b])
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
    (:func:`source_samples`): the column itself, or a product's factors."""
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


def source_samples(
    time_s: np.ndarray, columns: Mapping[str, np.ndarray], column: str, max_gap_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """Valid samples (times [s], values) of a source column.

    ``time_s`` is sorted and strictly increasing, ``columns`` maps canonical names to
    arrays aligned with it (NaN = no value). A product column ``"a*b"`` or
    ``"battery_power_w"`` is evaluated at the times where either factor has a value,
    each factor interpolated linearly over at most ``max_gap_s`` [s]. Raises KeyError
    when a needed column is missing.
    """
    if column in columns:
        v = np.asarray(columns[column], dtype=float)
        ok = np.isfinite(v)
        return time_s[ok], v[ok]
    arrays = [np.asarray(columns[f], dtype=float) for f in product_factors(column)]  # KeyError if absent
    any_ok = np.zeros(time_s.shape, dtype=bool)
    for a in arrays:
        any_ok |= np.isfinite(a)
    q = time_s[any_ok]
    prod = np.ones(q.shape)
    for a in arrays:
        ok = np.isfinite(a)
        if np.array_equal(ok, any_ok):  # sampled at every q: its own values (exact times)
            prod *= a[ok]
        else:  # samples at q[mask] of the strictly increasing q
            mask = ok[any_ok]
            prod *= _interp_limited(q, time_s[ok], a[ok], max_gap_s, right=np.cumsum(mask) - mask)
    ok = np.isfinite(prod)
    return q[ok], prod[ok]


# ------------------------------------------------------------------------ estimators


@dataclass(frozen=True)
class _Raw:
    value: float
    uncertainty: float
    coverage: float
    gap_share: float
    counts: dict
    reason: str = ""


def integrate_rate(
    ts: np.ndarray,
    rate: np.ndarray,
    t0: float,
    t1: float,
    *,
    max_gap_s: float = 15.0,
    resolution: float = 0.0,
) -> _Raw:
    """Integral of a sampled rate [unit/s] over ``[t0, t1]`` [s] -> [unit].

    Trapezoid rule on the piecewise-linear interpolant through the samples (``ts``
    sorted, strictly increasing; values outside the samples held at the edge value),
    evaluated at ``t0``, every sample strictly inside, and ``t1``. Steps longer than
    ``max_gap_s`` count as gaps. Uncertainty: see the module docstring.
    """
    duration = t1 - t0
    ok = np.isfinite(ts) & np.isfinite(rate)
    ts, rate = ts[ok], rate[ok]
    if ts.size == 0 or duration < 0:
        return _Raw(math.nan, math.nan, 0.0, 1.0, {}, "no samples")
    if duration == 0:
        return _Raw(0.0, 0.0, 1.0, 0.0, {"rate_gaps": 0})
    inside = (ts > t0) & (ts < t1)
    pts = np.concatenate(([t0], ts[inside], [t1]))
    vals = np.interp(pts, ts, rate)
    dts = np.diff(pts)
    value = float(np.sum(0.5 * (vals[1:] + vals[:-1]) * dts))
    gap = dts > max_gap_s
    gap_s = float(np.sum(dts[gap]))
    gap_share = gap_s / duration
    # trapezoid weight of each point
    w = np.zeros(pts.size)
    w[:-1] += 0.5 * dts
    w[1:] += 0.5 * dts
    var = (resolution**2 / 12.0) * float(np.sum(w * w))
    if gap.any():
        s_r = float(np.std(vals))
        var += s_r**2 * float(np.sum(dts[gap] ** 2))
    return _Raw(value, math.sqrt(var), 1.0 - gap_share, gap_share, {"rate_gaps": int(gap.sum())})


def counter_increase(
    ts: np.ndarray,
    counter: np.ndarray,
    t0: float,
    t1: float,
    *,
    resolution: float,
    max_rate: float,
    max_rate_neg: float = 0.0,
    modulus: float | None = None,
    reset_fraction: float = 0.01,
) -> _Raw:
    """Increase of a cumulative counter [unit] between its first and last reading in
    ``[t0, t1]`` [s], with wraps, resets and jumps handled as in the module docstring.

    ``max_rate`` / ``max_rate_neg`` [unit/s] bound plausible forward / backward steps.
    """
    duration = t1 - t0
    sel = (ts >= t0) & (ts <= t1) & np.isfinite(counter)
    t = ts[sel]
    c = counter[sel]
    if t.size < 2 or duration <= 0:
        return _Raw(math.nan, math.nan, 0.0, 1.0, {}, "fewer than 2 readings")
    d = np.diff(c)
    dt = np.diff(t)
    q = abs(resolution)
    wraps = np.zeros(d.shape, dtype=bool)
    if modulus is not None and modulus > 0:
        wraps = d < -0.5 * modulus
        d = np.where(wraps, d + modulus, d)
    plausible = (d >= -max_rate_neg * dt - 2 * q) & (d <= max_rate * dt + 2 * q)
    # "near zero" relative to the counter's level: the previous reading, or the
    # median reading if smaller (so that coming down from a glitch is not a reset)
    level = np.minimum(np.abs(c[:-1]), abs(float(np.median(c))))
    resets = ~plausible & (d < 0) & (c[1:] <= reset_fraction * level + 2 * q)
    jumps = ~plausible & ~resets
    lost = resets | jumps
    d = np.where(lost, 0.0, d)
    value = float(np.sum(d))
    covered = float(t[-1] - t[0])
    coverage = covered / duration
    mean_rate = value / covered if covered > 0 else 0.0
    var = q * q / 6.0
    var += float(np.sum((mean_rate * dt[lost]) ** 2))
    var += (mean_rate * (duration - covered)) ** 2
    counts = {
        "counter_wraps": int(wraps.sum()),
        "counter_resets": int(resets.sum()),
        "counter_jumps": int(jumps.sum()),
    }
    return _Raw(value, math.sqrt(var), coverage, 1.0 - coverage, counts)


def soc_energy(
    ts: np.ndarray,
    soc_pct: np.ndarray,
    t0: float,
    t1: float,
    *,
    resolution_pct: float,
    capacity_j: float,
) -> _Raw:
    """Battery energy [J] used over ``[t0, t1]`` [s] from the first and last SoC
    readings [%] in the span: (soc_first - soc_last) / 100 * capacity_j."""
    duration = t1 - t0
    sel = (ts >= t0) & (ts <= t1) & np.isfinite(soc_pct)
    t = ts[sel]
    s = soc_pct[sel]
    if t.size < 2 or duration <= 0:
        return _Raw(math.nan, math.nan, 0.0, 1.0, {}, "fewer than 2 readings")
    value = float((s[0] - s[-1]) / 100.0 * capacity_j)
    covered = float(t[-1] - t[0])
    coverage = covered / duration
    q_j = abs(resolution_pct) / 100.0 * capacity_j
    mean_rate = value / covered if covered > 0 else 0.0
    var = q_j * q_j / 6.0 + (mean_rate * (duration - covered)) ** 2
    return _Raw(value, math.sqrt(var), coverage, 1.0 - coverage, {})


def estimate_source(
    time_s: np.ndarray,
    columns: Mapping[str, np.ndarray],
    source: EnergySourceLike,
    t0: float,
    t1: float,
    params: ConsumptionParams = ConsumptionParams(),
) -> SourceEstimate:
    """Estimate a trip's consumption over ``[t0, t1]`` [s] from one source.

    ``time_s`` sorted, strictly increasing [s]; ``columns`` arrays aligned with it.
    The result says whether the source is valid for the trip, and why not.
    """
    kind, quantity = str(source.kind), str(source.quantity)
    res = float(source.resolution)
    name = str(source.column)

    def invalid(reason: str, raw: _Raw | None = None) -> SourceEstimate:
        return invalid_estimate(source, reason, raw)

    if quantity not in ("fuel_l", "energy_j"):
        return invalid(f"unknown quantity {quantity!r}")
    max_rate = params.max_fuel_lps if quantity == "fuel_l" else params.max_power_w
    # a window slightly wider than the trip, so rates can be interpolated at its ends
    lo = np.searchsorted(time_s, t0 - params.max_gap_s, side="left")
    hi = np.searchsorted(time_s, t1 + params.max_gap_s, side="right")
    window_t = time_s[lo:hi]
    window = {k: np.asarray(columns[k])[lo:hi] for k in columns_read(name) if k in columns}
    try:
        ts, vs = source_samples(window_t, window, name, params.max_gap_s)
    except KeyError:
        return invalid("column not in the log")
    if kind == "rate":
        # negative fuel flow is impossible; power may be negative (regeneration)
        lim_lo = 0.0 if quantity == "fuel_l" else -max_rate
        ok = (vs >= lim_lo - 2 * abs(res)) & (vs <= max_rate)
        raw = integrate_rate(ts[ok], vs[ok], t0, t1, max_gap_s=params.max_gap_s, resolution=res)
        raw.counts["rate_values_rejected"] = int((~ok).sum())
        resolution = 0.0
    elif kind == "counter":
        modulus = getattr(source, "modulus", None)
        raw = counter_increase(
            ts, vs, t0, t1, resolution=res, max_rate=max_rate,
            max_rate_neg=0.0 if quantity == "fuel_l" else max_rate,
            modulus=modulus, reset_fraction=params.reset_fraction,
        )
        resolution = abs(res)
    elif kind == "soc":
        cap = getattr(source, "capacity_j", None)
        if quantity != "energy_j" or cap is None or not cap > 0:
            if np.count_nonzero((vs >= 0) & (vs <= 100)) >= 2:
                return invalid(NO_CAPACITY)
            return invalid("SoC source needs quantity 'energy_j' and a capacity_j > 0")
        ok = (vs >= 0) & (vs <= 100)
        raw = soc_energy(ts[ok], vs[ok], t0, t1, resolution_pct=res, capacity_j=float(cap))
        resolution = abs(res) / 100.0 * float(cap)
    else:
        return invalid(f"unknown kind {kind!r}")
    return finish_estimate(source, raw, resolution, params)


#: why a logged state of charge measured nothing: the profile gives no capacity
NO_CAPACITY = "state of charge logged, but no capacity_j to turn it into energy"


def invalid_estimate(source: EnergySourceLike, reason: str, raw: _Raw | None = None) -> SourceEstimate:
    """The estimate of a source not valid for a trip, and why (with what was measured)."""
    return SourceEstimate(
        str(source.column), str(source.kind), str(source.quantity), int(source.priority),
        raw.value if raw else math.nan, 0.0,
        raw.uncertainty if raw else math.nan,
        raw.coverage if raw else 0.0, raw.gap_share if raw else 1.0,
        False, reason, raw.counts if raw else {},
    )


def finish_estimate(source: EnergySourceLike, raw: _Raw, resolution: float,
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


def measure_trip(
    time_s: np.ndarray,
    columns: Mapping[str, np.ndarray],
    sources: Sequence[EnergySourceLike],
    t0: float,
    t1: float,
    params: ConsumptionParams = ConsumptionParams(),
) -> tuple[Measurement | None, dict]:
    """A trip's measured consumption over ``[t0, t1]`` [s] from the best valid source.

    Returns the :class:`~cevm.core.trip.Measurement` of the chosen source (see the module
    docstring: the least uncertain valid source of the most trusted valid source's
    quantity) or None, and a JSON-serialisable quality dict: ``sources`` (every
    source's estimate, both parts of its uncertainty, and its validity),
    ``cross_checks`` (other valid sources of the chosen quantity against the chosen
    one, in percent and in combined standard uncertainties), ``warnings`` (those beyond
    ``disagreement_sigma``), ``chosen_by`` and, for the chosen source, ``source``,
    ``coverage``, ``gap_share`` and its repair counts.
    """
    return choose_measurement([estimate_source(time_s, columns, s, t0, t1, params) for s in sources], params)


def choose_measurement(estimates: Sequence[SourceEstimate],
                       params: ConsumptionParams = ConsumptionParams()) -> tuple[Measurement | None, dict]:
    """A trip's measured consumption from its sources' estimates (:func:`measure_trip`):
    the chosen measurement or None, and the quality dict."""
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
