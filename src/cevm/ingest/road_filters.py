"""The filters of a road profile on a uniform distance grid (pure): the robust smoothing
of :func:`cevm.ingest.elevation.road_profile_m` (a running median as reference ground,
surface objects bridged, a Gaussian low-pass; ends padded by odd reflection so that
ramps pass unchanged) and the grade bound (:func:`bound_grade`). Split from
:mod:`cevm.ingest.elevation`, which builds the grid, fills gaps and fetches the DSM.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Protocol

import numpy as np
from scipy import ndimage
from scipy.fft import next_fast_len


class SmoothingParams(Protocol):
    """What :func:`smooth_profile` reads of :class:`cevm.ingest.elevation.ElevationParams`
    (a protocol, so that this module need not import the one that imports it)."""

    @property
    def median_window_m(self) -> float: ...
    @property
    def spike_threshold_m(self) -> float: ...
    @property
    def lowpass_sigma_m(self) -> float: ...

__all__ = ["FFT_MIN_TAPS", "SmoothingParams", "bound_grade", "bound_grade_or_same", "gaussian_valid",
           "gaussian_weights", "odd_pad", "runs", "smooth_profile"]


def odd_pad(x: np.ndarray, r: int) -> np.ndarray:
    """Pad by point reflection about each end value (x[0] - (x[k] - x[0])), which
    continues a straight line: symmetric filters then keep ramps up to the ends."""
    if r <= 0:
        return x
    if x.size == 1:
        return np.full(2 * r + 1, x[0])
    if r >= x.size:  # reflected more than once
        return np.pad(x, r, mode="reflect", reflect_type="odd")
    out = np.empty(x.size + 2 * r)
    out[r : r + x.size] = x
    out[:r] = 2 * x[0] - x[r:0:-1]  # as np.pad(x, r, mode="reflect", reflect_type="odd")
    out[r + x.size :] = 2 * x[-1] - x[-2 : -r - 2 : -1]
    return out


def smooth_profile(h: np.ndarray, step: float, params: SmoothingParams) -> np.ndarray:
    """Robust smoothing of a gap-free uniform profile with spacing ``step`` [m].

    A running median of ``median_window_m`` is the reference ground; cells further than
    ``spike_threshold_m`` from it are surface objects: they are dropped and bridged by
    straight lines between the remaining cells (a Hampel filter). Then a Gaussian
    low-pass of ``lowpass_sigma_m``. Ends are padded by odd reflection, so a straight
    ramp comes out unchanged, ends included. (Taking the median itself as the profile
    would shift a ramp near an object by half the object's length times the grade.)
    """
    k = 2 * int(params.median_window_m / (2 * step)) + 1
    if k > 1 and h.size > 2:
        r = k // 2
        ground = ndimage.median_filter(odd_pad(h, r), size=k, mode="nearest")[r:-r]
        spike = np.abs(h - ground) > params.spike_threshold_m
        if spike.all():
            h = ground
        elif spike.any():
            idx = np.arange(h.size, dtype=np.float64)
            h = h.copy()
            h[spike] = np.interp(idx[spike], idx[~spike], h[~spike])
    sigma = params.lowpass_sigma_m / step
    if sigma > 0 and h.size > 1:
        r = int(4.0 * sigma + 0.5)
        h = gaussian_valid(odd_pad(h, r), sigma, r)
    return h


#: Kernels longer than this [taps] are applied by FFT (same result within rounding).
FFT_MIN_TAPS = 96


def gaussian_valid(x: np.ndarray, sigma: float, r: int) -> np.ndarray:
    """Gaussian low-pass (standard deviation ``sigma`` cells, radius ``r`` cells) of
    ``x`` at the cells ``r .. len(x) - r - 1``, whose windows lie inside ``x``: what
    ``ndimage.gaussian_filter1d(x, sigma, truncate=4.0)[r:-r]`` gives for
    ``r = int(4 * sigma + 0.5)``, whatever its boundary mode. Long kernels (the GPS
    profile's, 481 taps) go through an FFT of a length :func:`scipy.fft.next_fast_len`
    chooses, O(n log n) instead of O(n r); the result differs only by floating-point
    rounding (about 1e-12 m). (``scipy.signal.fftconvolve`` gives the same bits, but
    importing ``scipy.signal`` costs each process 47 MB; ``oaconvolve`` differs by up to
    3e-13 m and was 2x slower on trips under 5,000 cells.)"""
    k = gaussian_weights(float(sigma), int(r))
    if 2 * r + 1 < FFT_MIN_TAPS:  # gaussian_filter1d's own steps, with the weights made once
        return ndimage.correlate1d(x, k, mode="nearest")[r:-r]
    nfft = next_fast_len(x.size + k.size - 1, real=True)
    y = np.fft.irfft(np.fft.rfft(x, nfft) * np.fft.rfft(k, nfft), nfft)
    return y[2 * r : x.size]


@lru_cache(maxsize=32)
def gaussian_weights(sigma: float, r: int) -> np.ndarray:
    """The normalised Gaussian kernel of ``2 r + 1`` taps (symmetric), as scipy's
    ``gaussian_filter1d`` makes it; made once per (sigma, r), read-only."""
    k = np.exp(-0.5 / (sigma * sigma) * np.arange(-r, r + 1, dtype=np.float64) ** 2)
    k /= k.sum()
    k.setflags(write=False)
    return k


def runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) index ranges of True runs."""
    m = np.concatenate(([False], mask, [False]))
    edges = np.flatnonzero(m[1:] != m[:-1])
    return list(zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True))


def bound_grade(h: np.ndarray, step: float, max_grade: float) -> np.ndarray:
    """Bound the grade of a uniform profile (spacing ``step`` [m]) to ``max_grade``.

    Returns the mean of the two Lipschitz envelopes of ``h``: the largest profile below
    ``h`` and the smallest profile above ``h`` whose grade never exceeds ``max_grade``
    (``min_j h_j + G |i - j| step`` and ``max_j h_j - G |i - j| step``, computed with
    running minima/maxima, O(n)). Both envelopes obey the bound, so their mean does.
    Where ``h`` already obeys it both equal ``h``: the profile changes only around a
    violation, which becomes a ramp centred on it, and total rise and fall far from it
    are kept. So there is no drift, unlike clipping the grade and integrating.
    """
    if h.size < 2 or np.all(np.abs(np.diff(h)) <= max_grade * step):
        return h.copy()
    s = max_grade * step * np.arange(h.size)
    up_fwd = s + np.minimum.accumulate(h - s)  # min over j <= i of h_j + G (i - j) step
    up_bwd = (np.minimum.accumulate((h + s)[::-1]))[::-1] - s  # j >= i
    lo_fwd = np.maximum.accumulate(h + s) - s
    lo_bwd = (np.maximum.accumulate((h - s)[::-1]))[::-1] + s
    lower_env = np.minimum(up_fwd, up_bwd)
    upper_env = np.maximum(lo_fwd, lo_bwd)
    return 0.5 * (lower_env + upper_env)


def bound_grade_or_same(h: np.ndarray, step: float, max_grade: float) -> np.ndarray:
    """:func:`bound_grade`, returning ``h`` itself (not a copy) where it obeys the bound."""
    if h.size < 2 or np.all(np.abs(np.diff(h)) <= max_grade * step):
        return h
    return bound_grade(h, step, max_grade)
