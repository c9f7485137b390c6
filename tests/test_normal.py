"""cevm.core.distribution's standard normal functions (no scipy.special import) against
scipy.special's ndtr and ndtri (an independent implementation, cephes)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.special import ndtr, ndtri

from cevm.core.distribution import normal_cdf, normal_quantile


@settings(max_examples=200, deadline=None)
@given(st.floats(-40.0, 40.0))
def test_normal_cdf_is_scipys_ndtr(z):
    got = float(normal_cdf(np.array([z]))[0])
    want = float(ndtr(z))
    assert abs(got - want) <= 4.5e-16
    assert abs(got - want) <= 2e-13 * want or want < 1e-300


def test_normal_cdf_edges():
    got = normal_cdf(np.array([np.nan, np.inf, -np.inf, 0.0, -0.0]))
    assert np.isnan(got[0]) and got[1] == 1.0 and got[2] == 0.0 and got[3] == 0.5 and got[4] == 0.5
    assert normal_cdf(np.zeros((2, 3))).shape == (2, 3)


@settings(max_examples=200, deadline=None)
@given(st.floats(1e-12, 1.0 - 1e-12))
def test_normal_quantile_is_scipys_ndtri(p):
    want = float(ndtri(p))
    assert abs(normal_quantile(p) - want) <= 1e-15 * max(1.0, abs(want))


def test_normal_quantile_of_known_levels():
    # the textbook z of the central 90 % and 95 % intervals
    assert abs(normal_quantile(0.95) - 1.6448536269514722) < 1e-15
    assert abs(normal_quantile(0.975) - 1.959963984540054) < 1e-15


def test_normal_quantiles_edges_as_ndtri():
    from cevm.core.distribution import normal_quantiles

    p = np.array([0.0, 1.0, np.nan, -0.1, 1.1, 0.05, 0.5])
    np.testing.assert_array_equal(np.isnan(normal_quantiles(p)), np.isnan(ndtri(p)))
    np.testing.assert_allclose(normal_quantiles(p)[[0, 1, 5, 6]], ndtri(p)[[0, 1, 5, 6]], rtol=1e-15)
