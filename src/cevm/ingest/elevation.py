"""Road elevation for a trip: road-profile smoothing of DSM samples (pure; the filters
in :mod:`cevm.ingest.road_filters`), with GPS altitude or a flat road where the DSM has
long gaps.

:func:`road_profile_m`, :func:`combine_elevation` turn raw, spiky DSM samples (roofs,
trees, bridges, vehicles) into a plausible road profile along distance, with a fallback
to GPS altitude or a flat profile where the DSM has long gaps; :func:`trip_elevation`
samples the DSM (:class:`cevm.ingest.dsm.DsmSampler`, the raster access) at a trip's
fixes and does both.

All elevations are metres, distances metres, grades dimensionless (rise / run).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from functools import lru_cache
from pathlib import Path

import numpy as np

from cevm.ingest.dsm import DsmSampler
from cevm.ingest.road_filters import bound_grade, bound_grade_or_same, runs, smooth_profile

__all__ = [
    "ElevationParams",
    "ElevationResult",
    "bound_grade",
    "combine_elevation",
    "road_profile_m",
    "sample_trips",
    "trip_elevation",
]

# --------------------------------------------------------------------------------------
# Parameters and results
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ElevationParams:
    """Parameters of the road-profile smoothing and fallbacks.

    Attributes
    ----------
    grid_step_m : float, default 5.0
        Spacing of the uniform distance grid the profile is built on [m]. 5 m is finer
        than any road feature that matters for energy, and coarse enough to keep the
        filters cheap (a 1 Hz trip at 10 m/s gives two grid points per sample).
    max_gap_m : float, default 200.0
        Longest stretch of road [m] without a valid DSM sample that is bridged by linear
        interpolation along distance. Measured between the valid samples on either side
        of a run of invalid ones (or from the trip's end). Longer gaps fall back to GPS
        altitude or to a flat/linear fill. 200 m keeps bridges, tunnels' mouths and
        small DSM holes in the DSM profile, where a straight line is a good road.
    median_window_m : float, default 100.0
        Length [m] of the running median that serves as reference ground to detect
        surface objects. A median ignores an object shorter than about half its window
        whatever its height; 100 m covers roofs, trees, vehicles and bridge decks up to
        about 40 m long as seen by the fixes (a single 1 Hz fix on an object at 20 m/s
        spans 2 x 20 m after resampling), and a median follows ramps exactly.
    spike_threshold_m : float, default 1.0
        Grid cells more than this above or below the running median are surface objects
        (or DSM voids) and are replaced by straight lines between their neighbours. DSM
        noise on tarmac is about 0.1-0.3 m and a median's error on vertical curves of
        roads a few tenths of a metre, while vehicles, hedges, roofs and trees stand
        metres high. Lower objects are left to the low-pass.
    lowpass_sigma_m : float, default 15.0
        Standard deviation [m] of the Gaussian low-pass applied after the median, to
        remove the DSM's roughness (about 0.1-0.3 m on tarmac) and the staircase of the
        median. Linear ramps pass unchanged (ends are padded by odd reflection).
    max_grade : float, default 0.15
        Largest road grade magnitude allowed (0.15 = 15 %), see :func:`bound_grade`.
        Public roads rarely exceed 10-12 % over more than 100 m; 15 % leaves room for
        the steep urban streets that do exist while rejecting DSM cliffs.
    gps_lowpass_sigma_m : float, default 300.0
        Gaussian low-pass [m] for GPS altitude (the fallback where the DSM has nothing).
        A phone's vertical error is 10-30 m and correlated over minutes, so the DSM's
        15 m filter would keep it as false hills: their climbs cost energy the vehicle
        never spent (a model without braking credit counts every one). 300 m keeps the
        hills that matter for energy over a trip and removes most of the noise.
    gps_median_window_m : float, default 500.0
        Running-median window [m] of the GPS-altitude profile, whose spike threshold is
        ``gps_spike_threshold_m``.
    gps_spike_threshold_m : float, default 30.0
        GPS altitudes further than this from their running median are dropped as
        outliers (a lost fix, a multipath jump) before the low-pass.
    gps_min_valid_pct : float, default 50.0
        GPS altitude is used only when at least this share of samples carries a finite
        value inside ``gps_alt_range_m``.
    gps_alt_range_m : tuple[float, float], default (-500.0, 9000.0)
        Plausible GPS altitudes [m]; values outside are treated as missing (loggers write
        0, -1000 or 99999 as "no fix"). A trip whose GPS altitude is constant is rejected
        too (a placeholder, not a measurement).
    dsm_range_m : tuple[float, float], default (-500.0, 9000.0)
        Plausible DSM heights [m]: from below the Dead Sea shore (-430 m) to above
        Everest (8849 m), roofs and towers included. Raw DSM samples outside are refused
        (a DSM in the wrong unit or with a wrong scale factor: heights in mm, or scaled by
        1e6) and the trip falls back as in a DSM gap, with a warning.
    dsm_gps_max_median_m : float, default 250.0
        A DSM whose heights differ from the trip's GPS altitude by more than this median
        [m] is suspect (its unit or vertical datum): a warning. GPS altitude is off by tens
        of metres, and above the ellipsoid rather than the geoid (up to about 100 m apart).
    steep_warn_share : float, default 0.1
        When the grade bound changes the profile by more than 1 m on over this share of
        the trip's road, the raw profile was implausibly steep (DSM cliffs, a bad join):
        a warning.
    """

    grid_step_m: float = 5.0
    max_gap_m: float = 200.0
    median_window_m: float = 100.0
    spike_threshold_m: float = 1.0
    lowpass_sigma_m: float = 15.0
    max_grade: float = 0.15
    gps_lowpass_sigma_m: float = 300.0
    gps_median_window_m: float = 500.0
    gps_spike_threshold_m: float = 30.0
    gps_min_valid_pct: float = 50.0
    gps_alt_range_m: tuple[float, float] = (-500.0, 9000.0)
    dsm_range_m: tuple[float, float] = (-500.0, 9000.0)
    dsm_gps_max_median_m: float = 250.0
    steep_warn_share: float = 0.1

    def for_gps(self) -> ElevationParams:
        """These parameters with the GPS-altitude smoothing in place of the DSM's."""
        return replace(self, lowpass_sigma_m=self.gps_lowpass_sigma_m, median_window_m=self.gps_median_window_m,
                       spike_threshold_m=self.gps_spike_threshold_m)

    def __post_init__(self) -> None:
        checks = {
            "grid_step_m": self.grid_step_m > 0,
            "max_gap_m": self.max_gap_m >= 0,
            "median_window_m": self.median_window_m >= 0,
            "spike_threshold_m": self.spike_threshold_m >= 0,
            "lowpass_sigma_m": self.lowpass_sigma_m >= 0,
            "max_grade": self.max_grade > 0,
            "gps_min_valid_pct": 0 <= self.gps_min_valid_pct <= 100,
            "gps_lowpass_sigma_m": self.gps_lowpass_sigma_m >= 0,
            "gps_median_window_m": self.gps_median_window_m >= 0,
            "gps_spike_threshold_m": self.gps_spike_threshold_m >= 0,
        }
        for name, ok in checks.items():
            value = getattr(self, name)
            if not ok or (isinstance(value, float) and math.isnan(value)):
                raise ValueError(f"ElevationParams.{name} = {value!r} is out of range")
        for name in ("gps_alt_range_m", "dsm_range_m"):
            lo, hi = getattr(self, name)
            if not lo < hi:
                raise ValueError(f"ElevationParams.{name} = {getattr(self, name)!r}: need low < high")


@dataclass(frozen=True, eq=False)
class ElevationResult:
    """Elevation of a trip's samples and how it was obtained.

    Attributes
    ----------
    elevation_m : ndarray of float64
        Road elevation per sample [m]; finite everywhere. Samples that share a distance
        (standstill) share an elevation.
    source : str
        ``"dsm"`` (DSM everywhere, short gaps interpolated), ``"dsm+gps"`` (long DSM gaps
        filled from GPS altitude offset to join the DSM), ``"dsm+flat"`` (long DSM gaps
        bridged linearly / held level, no usable GPS), ``"dsm+gps+flat"`` (both kinds
        of fill: GPS altitude missing in some long DSM gaps), ``"gps"`` (no DSM value at
        all, smoothed GPS altitude) or ``"flat"`` (nothing usable: 0 m everywhere).
    dsm_coverage_pct : float
        Share of samples with a valid raw DSM value [%] (0 without a DSM).
    filled_short_m : float
        Road length [m] of DSM gaps up to ``max_gap_m`` bridged by interpolation.
    filled_gps_m : float
        Road length [m] filled from GPS altitude.
    filled_flat_m : float
        Road length [m] filled by a straight line between DSM ends or held level.
    notes : tuple of str
        Human-readable remarks (why a fallback was taken, ...).
    warnings : tuple of str
        What the caller should report (refused DSM heights, unreadable tiles, a DSM
        that disagrees with GPS altitude, an implausibly steep profile).
    dsm_refused : int
        Samples whose raw DSM height was outside ``dsm_range_m`` (refused).
    grade_bounded_m : float
        Road length [m] where the grade bound moved the profile by more than 1 m.
    """

    elevation_m: np.ndarray
    source: str
    dsm_coverage_pct: float
    filled_short_m: float = 0.0
    filled_gps_m: float = 0.0
    filled_flat_m: float = 0.0
    notes: tuple[str, ...] = ()
    warnings: tuple[str, ...] = ()
    dsm_refused: int = 0
    grade_bounded_m: float = 0.0

    def quality(self) -> dict:
        """JSON-serialisable summary for ``Trip.quality``."""
        return {
            "elevation_source": self.source,
            "dsm_coverage_pct": round(float(self.dsm_coverage_pct), 3),
            "elevation_filled_short_m": round(float(self.filled_short_m), 1),
            "elevation_filled_gps_m": round(float(self.filled_gps_m), 1),
            "elevation_filled_flat_m": round(float(self.filled_flat_m), 1),
            "elevation_notes": list(self.notes),
            "elevation_warnings": list(self.warnings),
            "dsm_refused_samples": int(self.dsm_refused),
            "elevation_grade_bounded_m": round(float(self.grade_bounded_m), 1),
        }


# --------------------------------------------------------------------------------------
# Road profile (pure)
# --------------------------------------------------------------------------------------


def _grid(d0: float, d1: float, step: float) -> np.ndarray:
    """Uniform grid from d0 to d1 inclusive with spacing <= step."""
    if not d1 > d0:
        return np.array([d0], dtype=np.float64)
    n = int(math.ceil((d1 - d0) / step - 1e-9)) + 1
    return np.linspace(d0, d1, max(n, 2))


def _check_distance(distance_m: np.ndarray) -> None:
    if not np.all(np.isfinite(distance_m)):
        raise ValueError("distance_m must be finite")
    if distance_m.size > 1 and np.any(np.diff(distance_m) < 0):
        raise ValueError("distance_m must be non-decreasing")


@dataclass(frozen=True)
class _Gaps:
    """Runs of invalid samples, classified by the road length they span: from the last
    valid sample before to the first valid one after (or the trip's end)."""

    short_m: float  # total span of the runs bridged by interpolation [m]
    long: list[tuple[float, float, str]] = field(default_factory=list)  # (a, b, "lead"|"inner"|"trail")


def _find_gaps(d: np.ndarray, valid: np.ndarray, max_gap_m: float) -> _Gaps:
    """Classify runs of invalid samples by the road length they span."""
    n = d.size
    vi = np.flatnonzero(valid)
    if vi.size == 0:
        return _Gaps(0.0, [(float(d[0]), float(d[-1]), "all")] if n else [])
    spans: list[tuple[float, float, str]] = []
    if vi[0] > 0:
        spans.append((float(d[0]), float(d[vi[0]]), "lead"))
    inner = np.flatnonzero(np.diff(vi) > 1)
    spans.extend(zip(d[vi[inner]].tolist(), d[vi[inner + 1]].tolist(), ["inner"] * inner.size, strict=True))
    if vi[-1] < n - 1:
        spans.append((float(d[vi[-1]]), float(d[-1]), "trail"))
    short = sum(b - a for a, b, _ in spans if b - a <= max_gap_m)
    return _Gaps(float(short), [s for s in spans if s[1] - s[0] > max_gap_m])


def _resample(d: np.ndarray, z: np.ndarray, valid: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """Valid samples onto the grid: samples are averaged per grid cell (standstill
    repeats and dense logging), then cells are joined by linear interpolation along
    distance; held level beyond the first/last valid sample."""
    dv, zv = d[valid], z[valid]
    if grid.size == 1:
        return np.array([zv.mean()])
    step = grid[1] - grid[0]
    cell = np.rint((dv - grid[0]) / step).astype(np.int64)
    before, after = cell < 0, cell >= grid.size  # samples beyond a partial grid: anchors only
    if before.any() or after.any():
        keep = ~(before | after)
        d_lo, z_lo, d_hi, z_hi = dv[before], zv[before], dv[after], zv[after]
        dv, zv, cell = dv[keep], zv[keep], cell[keep]
    else:
        d_lo = z_lo = d_hi = z_hi = dv[:0]
    cnt = np.bincount(cell, minlength=grid.size)
    has = cnt > 0
    zc = np.bincount(cell, weights=zv, minlength=grid.size)[has] / cnt[has]
    dc = np.bincount(cell, weights=dv, minlength=grid.size)[has] / cnt[has]
    if d_lo.size or d_hi.size:
        dc = np.concatenate((d_lo, dc, d_hi))
        zc = np.concatenate((z_lo, zc, z_hi))
    out = np.interp(grid, dc, zc)
    if dc.size > 1:
        # A cell mean sits up to half a step inside its cell: continue the line of the
        # first (last) two cells over that half step, not level (keeps ramps exact).
        for k, (i, j) in ((0, (0, 1)), (-1, (-2, -1))):
            if 0 < abs(grid[k] - dc[k]) <= 0.5 * step * (1 + 1e-9) and dc[j] > dc[i]:
                out[k] = zc[i] + (grid[k] - dc[i]) * (zc[j] - zc[i]) / (dc[j] - dc[i])
    return out


def _profile_grid(d: np.ndarray, z: np.ndarray, params: ElevationParams, grid: np.ndarray,
                  max_gap_m: float) -> tuple[np.ndarray, _Gaps]:
    """Smoothed (not yet grade-bounded) profile on ``grid``, NaN inside long gaps."""
    valid = np.isfinite(z)
    gaps = _find_gaps(d, valid, max_gap_m)
    if not valid.any():
        return np.full(grid.size, np.nan), gaps
    h = _resample(d, z, valid, grid)
    # Blank long gaps, keeping the first grid point past the valid sample on each side
    # so that the samples next to the gap still interpolate between finite points.
    for a, b, kind in gaps.long:
        lo = 0 if kind == "lead" else np.searchsorted(grid, a, side="right") + 1
        hi = grid.size if kind == "trail" else np.searchsorted(grid, b, side="left") - 1
        if hi > lo:
            h[lo:hi] = np.nan
    step = grid[1] - grid[0] if grid.size > 1 else params.grid_step_m
    for lo, hi in runs(np.isfinite(h)):
        h[lo:hi] = smooth_profile(h[lo:hi], step, params)
    return h, gaps


def road_profile_m(distance_m, raw_elevation_m, params: ElevationParams = ElevationParams()) -> np.ndarray:
    """Road elevation profile [m] from raw (spiky, gappy) elevation samples.

    Steps: (1) resample onto a uniform grid of ``grid_step_m`` along distance (means
    per cell, linear between cells); (2) bridge runs of NaN samples spanning up to
    ``max_gap_m`` by linear interpolation along distance, leave longer gaps NaN;
    (3) running median of ``median_window_m`` (removes roofs, trees, vehicles, bridge
    decks), repeated on its residuals to cancel the median's bias on slopes, then Gaussian
    low-pass of ``lowpass_sigma_m``, each covered stretch apart;
    (4) bound the grade to ``max_grade`` with :func:`bound_grade` (no drift);
    (5) interpolate back to the samples by distance, so samples that share a distance
    (standstill) get the same elevation.

    Parameters
    ----------
    distance_m : array_like
        Cumulative distance of the samples [m], finite and non-decreasing.
    raw_elevation_m : array_like
        Raw elevation per sample [m], NaN where unknown.
    params : ElevationParams

    Returns
    -------
    ndarray of float64
        Elevation per sample [m]; NaN only inside gaps longer than ``max_gap_m`` (and
        everywhere if no sample is valid).
    """
    d = np.asarray(distance_m, dtype=np.float64)
    z = np.asarray(raw_elevation_m, dtype=np.float64)
    if d.shape != z.shape or d.ndim != 1:
        raise ValueError("distance_m and raw_elevation_m must be 1-D arrays of one length")
    if d.size == 0:
        return np.empty(0)
    _check_distance(d)
    grid = _grid(d[0], d[-1], params.grid_step_m)
    h, _ = _profile_grid(d, z, params, grid, params.max_gap_m)
    step = grid[1] - grid[0] if grid.size > 1 else params.grid_step_m
    for lo, hi in runs(np.isfinite(h)):
        h[lo:hi] = bound_grade(h[lo:hi], step, params.max_grade)
    return _to_samples(d, grid, h)


def _to_samples(d: np.ndarray, grid: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Profile on the grid back to the samples, linear along distance; a sample with a
    NaN grid neighbour of non-zero weight is NaN."""
    if grid.size == 1:
        return np.full(d.size, h[0])
    out = np.interp(d, grid, h)
    if np.isnan(h).any():
        k = np.clip(np.searchsorted(grid, d, side="right") - 1, 0, grid.size - 2)
        w = (d - grid[k]) / (grid[k + 1] - grid[k])
        bad = (np.isnan(h[k]) & (w < 1)) | (np.isnan(h[k + 1]) & (w > 0))
        out[bad] = np.nan
    return out


def _mean_finite(x: np.ndarray) -> float | None:
    x = x[np.isfinite(x)]
    return float(x.mean()) if x.size else None


def _gps_usable(gps: np.ndarray | None, params: ElevationParams) -> tuple[np.ndarray | None, str]:
    """Plausible GPS altitudes (implausible ones as NaN), or None with the reason."""
    if gps is None:
        return None, "no GPS altitude"
    g = np.asarray(gps, dtype=np.float64).copy()
    lo, hi = params.gps_alt_range_m
    ok = (g >= lo) & (g <= hi)
    g[~ok] = np.nan
    n_ok = int(np.count_nonzero(ok))
    if g.size == 0 or 100.0 * n_ok / g.size < params.gps_min_valid_pct:
        return None, f"GPS altitude valid on {100.0 * n_ok / max(g.size, 1):.0f}% of samples only"
    valid = g[ok]
    if n_ok > 1 and valid.max() == valid.min():
        return None, "GPS altitude is constant (a placeholder)"
    return g, ""


def combine_elevation(distance_m, raw_dsm_m, gps_alt_m=None, params: ElevationParams = ElevationParams(), *,
                      have_dsm: bool = True) -> ElevationResult:
    """Road elevation of a trip from raw DSM samples, with GPS altitude or a flat fill
    as fallback (pure).

    The DSM profile is built as in :func:`road_profile_m`. Gaps longer than
    ``max_gap_m`` are filled from GPS altitude, smoothed the same way (its own gaps
    bridged whatever their length), plus an offset that varies linearly across the gap
    from the mean (DSM - GPS) over up to ``median_window_m`` of DSM profile before it
    to the same mean after it, so the fill joins the DSM profile on both sides (a
    constant offset at the trip's ends; the grade bound absorbs the small residual
    step). Without usable GPS (over the whole trip, or in that gap), a long gap is
    bridged by a straight line between the DSM values at its ends, or held level at the
    trip's ends. Without any DSM value the profile is the smoothed GPS
    altitude, or 0 m everywhere ("flat"). The grade bound is applied last, to the whole
    profile.

    The steps, a function each: the inputs checked (:func:`_elevation_inputs`),
    implausible DSM heights refused (:func:`_refuse_implausible_dsm`), the DSM profile
    on the grid (:func:`_profile_grid`), the usable GPS altitude (:func:`_gps_usable`)
    and its agreement with the DSM (:func:`_dsm_gps_warning`), then either the profile
    without any DSM value (:func:`_profile_without_dsm`) or the DSM's long gaps filled
    (:func:`_fill_long_gaps`), and the grade bound (:func:`_bound_profile_grade`).

    Parameters
    ----------
    distance_m : array_like
        Cumulative distance [m], finite, non-decreasing.
    raw_dsm_m : array_like or None
        Raw DSM elevation per sample [m], NaN where invalid; None if there is no DSM.
    gps_alt_m : array_like or None
        GPS altitude per sample [m], NaN where missing.
    params : ElevationParams
    have_dsm : bool
        False when no DSM was given at all (changes only the notes).
    """
    d, z, have_dsm = _elevation_inputs(distance_m, raw_dsm_m, gps_alt_m, have_dsm)
    n = d.size
    if n == 0:
        return ElevationResult(np.empty(0), "flat", 0.0, notes=("empty trip",))
    _check_distance(d)
    notes: list[str] = []
    warnings: list[str] = []
    z, refused = _refuse_implausible_dsm(z, raw_dsm_m, params, warnings)
    valid = np.isfinite(z)
    coverage = 100.0 * valid.sum() / n if have_dsm else 0.0
    grid = _grid(d[0], d[-1], params.grid_step_m)
    step = grid[1] - grid[0] if grid.size > 1 else params.grid_step_m
    h, gaps = _profile_grid(d, z, params, grid, params.max_gap_m)
    gps, why_not_gps = _gps_usable(gps_alt_m, params)
    if gps is not None:
        _dsm_gps_warning(z, gps, params, warnings)
    if not valid.any():
        h, fill = _profile_without_dsm(d, grid, gps, why_not_gps, have_dsm, params, notes)
        short = 0.0
    else:
        short = gaps.short_m
        fill = _fill_long_gaps(h, d, grid, step, gaps, gps, why_not_gps, params, notes)
        if short > 0:
            notes.append(f"DSM gaps up to {_gap_str(params)} ({short:.0f} m) interpolated along distance")
    bounded, moved_m = _bound_profile_grade(h, d, step, params, notes, warnings)
    return ElevationResult(
        elevation_m=_to_samples(d, grid, bounded),
        source=fill.source,
        dsm_coverage_pct=float(coverage),
        filled_short_m=float(short),
        filled_gps_m=float(fill.gps_m),
        filled_flat_m=float(fill.flat_m),
        notes=tuple(notes),
        warnings=tuple(warnings),
        dsm_refused=refused,
        grade_bounded_m=moved_m,
    )


def _elevation_inputs(distance_m, raw_dsm_m, gps_alt_m, have_dsm: bool) -> tuple[np.ndarray, np.ndarray, bool]:
    """Distance and DSM heights as float64 arrays of one length (the heights all NaN
    without a DSM, which is then not had), the GPS altitude's length checked."""
    d = np.asarray(distance_m, dtype=np.float64)
    if raw_dsm_m is None:
        have_dsm = False
        z = np.full(d.size, np.nan)
    else:
        z = np.asarray(raw_dsm_m, dtype=np.float64)
    if z.shape != d.shape or d.ndim != 1:
        raise ValueError("distance_m and raw_dsm_m must be 1-D arrays of one length")
    if gps_alt_m is not None and np.shape(gps_alt_m) != d.shape:
        raise ValueError("gps_alt_m must have the length of distance_m")
    return d, z, have_dsm


def _refuse_implausible_dsm(z: np.ndarray, raw_dsm_m, params: ElevationParams,
                            warnings: list[str]) -> tuple[np.ndarray, int]:
    """DSM heights outside ``params.dsm_range_m`` as NaN (a warning with their median),
    and how many there were."""
    lo_m, hi_m = params.dsm_range_m
    implausible = np.isfinite(z) & ~((z >= lo_m) & (z <= hi_m))
    refused = int(implausible.sum())
    if refused:
        z = np.where(implausible, np.nan, z)
        warnings.append(f"DSM heights outside {lo_m:g}..{hi_m:g} m refused at {refused} of {z.size} samples "
                        f"(median {float(np.median(np.asarray(raw_dsm_m, dtype=np.float64)[implausible])):.4g} m: "
                        "a DSM in the wrong unit or scale?)")
    return z, refused


def _dsm_gps_warning(z: np.ndarray, gps: np.ndarray, params: ElevationParams, warnings: list[str]) -> None:
    """A warning when the DSM and the GPS altitude differ by more than
    ``dsm_gps_max_median_m`` (median, where both are known on at least half the
    samples): the DSM's unit or vertical datum."""
    k = max(1, z.size // 2000)  # every k-th sample: a median of up to ~4000 is plenty for a warning
    dz = np.abs(z[::k] - gps[::k])
    both = np.isfinite(dz)
    if both.sum() >= 0.5 * dz.size:
        off = float(np.median(dz[both]))
        if off > params.dsm_gps_max_median_m:
            warnings.append(f"DSM heights differ from GPS altitude by {off:.0f} m (median): "
                            "check the DSM's unit and vertical datum")


@dataclass(frozen=True)
class _Fill:
    """Where a trip's profile comes from (``source``) and the road filled from GPS
    altitude and by straight lines or level [m]."""

    source: str
    gps_m: float = 0.0
    flat_m: float = 0.0


def _profile_without_dsm(d: np.ndarray, grid: np.ndarray, gps: np.ndarray | None, why_not_gps: str,
                         have_dsm: bool, params: ElevationParams, notes: list[str]) -> tuple[np.ndarray, _Fill]:
    """The profile of a trip without any DSM value: its smoothed GPS altitude, or flat
    at 0 m."""
    notes.append("no DSM given" if not have_dsm else "no valid DSM value on this trip")
    road_m = float(d[-1] - d[0])
    if gps is not None:
        g, _ = _profile_grid(d, gps, _gps_params(params), grid, math.inf)
        notes.append("smoothed GPS altitude used")
        return g, _Fill("gps", gps_m=road_m)
    notes.append(f"{why_not_gps}: flat profile at 0 m")
    return np.zeros(grid.size), _Fill("flat", flat_m=road_m)


def _fill_long_gaps(h: np.ndarray, d: np.ndarray, grid: np.ndarray, step: float, gaps: _Gaps,
                    gps: np.ndarray | None, why_not_gps: str, params: ElevationParams,
                    notes: list[str]) -> _Fill:
    """The DSM profile's long gaps (NaN in ``h``, filled in place): from GPS altitude
    joined to the DSM on both sides where the gap has it (:func:`_gps_fill`), else by
    straight lines (level at the trip's ends)."""
    holes = np.isnan(h)
    if not holes.any():
        return _Fill("dsm")
    gap_a = np.array([g[0] for g in gaps.long])
    gap_m = np.array([g[1] - g[0] for g in gaps.long])
    by_gps = np.zeros(gap_m.size, dtype=bool)
    if gps is not None:
        span = max(1, int(round(params.median_window_m / step)))
        for lo, hi in runs(holes):
            if _gps_fill(h, d, gps, grid, lo, hi, span, params):
                by_gps[max(0, np.searchsorted(gap_a, grid[lo], side="right") - 1)] = True
    filled_gps = float(gap_m[by_gps].sum())
    filled_flat = float(gap_m[~by_gps].sum())
    holes = np.isnan(h)
    if holes.any():
        ok = ~holes
        h[holes] = np.interp(grid[holes], grid[ok], h[ok])
    source = "dsm"
    if filled_gps > 0:
        source = "dsm+gps"
        notes.append(f"{int(by_gps.sum())} DSM gap(s) over {_gap_str(params)} ({filled_gps:.0f} m) filled from GPS "
                     f"altitude joined to the DSM")
    if filled_flat > 0:
        source = "dsm+gps+flat" if filled_gps > 0 else "dsm+flat"
        why = why_not_gps if gps is None else "no GPS altitude there"
        notes.append(f"{int((~by_gps).sum())} DSM gap(s) over {_gap_str(params)} ({filled_flat:.0f} m) bridged by "
                     f"straight lines ({why})")
    return _Fill(source, filled_gps, filled_flat)


def _gps_fill(h: np.ndarray, d: np.ndarray, gps: np.ndarray, grid: np.ndarray, lo: int, hi: int, span: int,
              params: ElevationParams) -> bool:
    """Fill the gap ``h[lo:hi]`` (in place) with the smoothed GPS altitude plus the
    DSM - GPS offset, averaged over the DSM stretch (up to ``median_window_m``) on
    each side of the gap to average out GPS noise, and varying linearly across it
    (constant where one side has no DSM). False, and nothing filled, where the gap has
    GPS fixes in under half of it (left to the straight line)."""
    g = _gps_around(d, gps, params, grid, lo, hi, span)
    off_l = _mean_finite(h[max(0, lo - span) : lo] - g[max(0, lo - span) : lo])
    off_r = _mean_finite(h[hi : hi + span] - g[hi : hi + span])
    # the samples at grid[lo] .. grid[hi - 1]: a slice, as distance never decreases
    inside = slice(int(np.searchsorted(d, grid[lo], side="left")), int(np.searchsorted(d, grid[hi - 1], side="right")))
    gps_inside = np.isfinite(gps[inside]).mean() if inside.stop > inside.start else 0.0
    if gps_inside < 0.5 or not np.isfinite(g[lo:hi]).all() or (off_l is None and off_r is None):
        return False
    if off_l is None or off_r is None:
        off = np.full(hi - lo, off_r if off_l is None else off_l)
    else:
        w = (grid[lo:hi] - grid[lo - 1]) / (grid[hi] - grid[lo - 1])
        off = off_l + w * (off_r - off_l)
    h[lo:hi] = g[lo:hi] + off
    return True


def _bound_profile_grade(h: np.ndarray, d: np.ndarray, step: float, params: ElevationParams,
                         notes: list[str], warnings: list[str]) -> tuple[np.ndarray, float]:
    """The profile with its grade bounded to ``max_grade``, and the road [m] on which
    that moved it by over 1 m (a note; a warning when that is over
    ``steep_warn_share`` of the trip: an implausibly steep profile)."""
    bounded = bound_grade_or_same(h, step, params.max_grade)
    moved_m = 0.0 if bounded is h else float(np.count_nonzero(np.abs(bounded - h) > 1.0) * step)
    if moved_m > 0:
        notes.append(f"grade bounded to {100 * params.max_grade:g} %: profile moved by over 1 m on {moved_m:.0f} m")
        road_m = float(d[-1] - d[0])
        if road_m > 0 and moved_m > params.steep_warn_share * road_m:
            warnings.append(f"road profile implausibly steep: the {100 * params.max_grade:g} % grade bound moved it "
                            f"by over 1 m on {moved_m:.0f} of {road_m:.0f} m")
    return bounded, moved_m


def _gps_around(d, gps, params: ElevationParams, grid, lo: int, hi: int, span: int) -> np.ndarray:
    """Smoothed GPS profile on ``grid``, computed only over grid[lo:hi] widened by
    ``span`` cells (for the offsets) and the filters' reach (so that the values there
    are practically those of a whole-trip computation); NaN elsewhere."""
    step = grid[1] - grid[0]
    params = _gps_params(params)
    reach = span + int(params.median_window_m / step) + int(4 * params.lowpass_sigma_m / step) + 2
    a, b = max(0, lo - reach), min(grid.size, hi + reach)
    i, j = np.searchsorted(d, grid[a], side="left"), np.searchsorted(d, grid[b - 1], side="right")
    i, j = max(0, i - 1), min(d.size, j + 1)  # one sample beyond, for the interpolation
    g = np.full(grid.size, np.nan)
    g[a:b], _ = _profile_grid(d[i:j], gps[i:j], params, grid[a:b], math.inf)
    return g


@lru_cache(maxsize=16)
def _gps_params(params: ElevationParams) -> ElevationParams:
    """``params.for_gps()``, made once per parameter set."""
    return params.for_gps()


def _gap_str(params: ElevationParams) -> str:
    return f"{params.max_gap_m:g} m"


def trip_elevation(distance_m, lon_deg, lat_deg, gps_alt_m=None, sampler: DsmSampler | None = None,
                   params: ElevationParams = ElevationParams(), *, raw_dsm_m=None) -> ElevationResult:
    """Road elevation of a trip: DSM lookup at the fixes (if ``sampler``), then
    :func:`combine_elevation`.

    Parameters
    ----------
    distance_m : array_like
        Cumulative distance [m], finite, non-decreasing.
    lon_deg, lat_deg : array_like
        WGS84 fixes [deg], NaN where there is no fix.
    gps_alt_m : array_like or None
        GPS altitude [m], NaN where missing; None if the logger has none.
    sampler : DsmSampler or None
        The DSM; None gives GPS altitude (if plausible) or a flat profile.
    params : ElevationParams
    raw_dsm_m : array_like or None
        ``sampler.sample(lon_deg, lat_deg)`` if the caller has it already (sampling the
        trips of a file in one call costs less than one call per trip,
        :func:`sample_trips`).
    """
    if sampler is None:
        return combine_elevation(distance_m, None, gps_alt_m, params, have_dsm=False)
    raw = sampler.sample(lon_deg, lat_deg) if raw_dsm_m is None else np.asarray(raw_dsm_m, dtype=np.float64)
    res = combine_elevation(distance_m, raw, gps_alt_m, params)
    return _name_dsm_tiles(res, raw, lon_deg, lat_deg, sampler, params)


def sample_trips(sampler: DsmSampler, lon_deg: list, lat_deg: list) -> list[np.ndarray]:
    """Raw DSM samples of several trips (lists of WGS84 longitude and latitude arrays)
    in one lookup: the values of one :meth:`DsmSampler.sample` per trip, for less
    per-call work (transform, tile search and window gathering run once)."""
    if not lon_deg:
        return []
    z = sampler.sample(np.concatenate(lon_deg), np.concatenate(lat_deg))
    return np.split(z, np.cumsum([np.size(a) for a in lon_deg])[:-1])


def _name_dsm_tiles(res: ElevationResult, raw: np.ndarray, lon_deg, lat_deg, sampler: DsmSampler,
                    params: ElevationParams) -> ElevationResult:
    """``res`` with warnings naming the tiles whose heights were refused and the
    unreadable tiles the trip crossed (their samples had no DSM value). Looks the
    tiles up only when there is something to say."""
    lo, hi = params.dsm_range_m
    refused = np.isfinite(raw) & ~((raw >= lo) & (raw <= hi))
    unreadable = sampler.windows.failed
    if not refused.any() and not (unreadable and np.isnan(raw).any()):
        return res
    tiles = sampler.tiles_at(lon_deg, lat_deg)
    warnings = list(res.warnings)
    if refused.any():
        names = sorted({Path(sampler.tiles[i].name).name for i in np.unique(tiles[refused]) if i >= 0})
        warnings.append(f"refused DSM heights in tile(s) {', '.join(names[:3])}{' ...' if len(names) > 3 else ''}")
    for i in sorted(set(np.unique(tiles[np.isnan(raw)]).tolist()) & set(unreadable)):
        n = int(np.count_nonzero(tiles == i))
        warnings.append(f"DSM tile {sampler.tiles[i].name} unreadable ({unreadable[i]}): {n} samples without DSM")
    return replace(res, warnings=tuple(warnings))
