"""cevm.ingest.dsm.projection: the fitted transform agrees with pyproj (the reference)
within its tolerance, or is pyproj itself."""

from __future__ import annotations

import numpy as np
import pyproj
import pytest

from cevm.ingest.dsm.projection import MIN_POINTS, to_crs


def _track(rng, n, lon0, lat0, extent_deg):
    """A wandering track of ``n`` fixes within ``extent_deg`` of a corner."""
    steps = rng.standard_normal((n, 2)).cumsum(axis=0)
    steps = (steps - steps.min(axis=0)) / np.ptp(steps, axis=0) * extent_deg
    return lon0 + steps[:, 0], lat0 + steps[:, 1]


@pytest.mark.parametrize("dst, lon0, lat0", [("EPSG:27700", -0.9, 51.8), ("EPSG:32632", 8.5, 47.2),
                                             ("EPSG:3857", -6.9, 33.9), ("EPSG:2154", 2.2, 48.7)])
@pytest.mark.parametrize("extent", [0.01, 0.3, 1.5])
def test_agrees_with_pyproj_within_tolerance(dst, lon0, lat0, extent):
    rng = np.random.default_rng(7)
    lon, lat = _track(rng, 20_000, lon0, lat0, extent)
    tol = 2e-8
    x, y = to_crs(lon, lat, "EPSG:4326", dst, tol)
    px, py = pyproj.Transformer.from_crs("EPSG:4326", dst, always_xy=True).transform(lon, lat)
    err = np.maximum(np.abs(x - px), np.abs(y - py)).max()
    # the check is on held-out points: elsewhere a smooth map is followed as closely
    assert err <= 10 * tol, err


def test_pyproj_itself_when_the_fit_cannot_agree():
    """A lookup spanning a continent, or fewer than MIN_POINTS points: pyproj's values
    exactly."""
    rng = np.random.default_rng(3)
    tr = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:32632", always_xy=True)
    for lon, lat in (_track(rng, 5000, -10.0, 35.0, 30.0), _track(rng, MIN_POINTS - 1, 8.5, 47.2, 0.1)):
        x, y = to_crs(lon, lat, "EPSG:4326", "EPSG:32632", 1e-8)
        px, py = tr.transform(lon, lat)
        assert np.array_equal(x, px) and np.array_equal(y, py)


def test_same_crs_is_the_points_themselves():
    lon = np.linspace(0, 1, 1000)
    x, y = to_crs(lon, lon, "EPSG:4326", "EPSG:4326", 1e-8)
    assert x is lon and y is lon


def test_pyproj_sees_only_the_fit_and_check_points(monkeypatch):
    """Over a lookup's usual extent (a batch of trips: tens of kilometres) the fit is
    used: pyproj transforms its nodes and check points only, not the 20,000 fixes."""
    import cevm.ingest.dsm.projection as projection

    seen = []
    real = projection._transformer("EPSG:4326", "EPSG:27700")

    class Counting:
        def transform(self, x, y):
            seen.append(np.size(x))
            return real.transform(x, y)

    monkeypatch.setattr(projection, "_transformer", lambda src, dst: Counting())
    lon, lat = _track(np.random.default_rng(1), 20_000, -0.9, 51.8, 0.3)
    to_crs(lon, lat, "EPSG:4326", "EPSG:27700", 2e-8)
    assert seen and sum(seen) <= 200
