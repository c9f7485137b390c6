"""What a timetable adds to replay's machinery: a per-trip spread of its own (a synthesised
cycle: the spread between its draws), independent from trip to trip, added in quadrature
to a trip's and a duty's variance and drawn in the Monte Carlo (cevm.core.replay.spread,
cevm.core.replay.montecarlo); duties given by the caller (blocks that run at the same
time: cevm.core.replay.duties, rule "given")."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import norm

from cevm.core.replay import Stops, TripSpread, group_duties
from cevm.core.replay.montecarlo import DrawPlan, p_complete


def _spread(n: int) -> TripSpread:
    return TripSpread(np.zeros((n, 0)), np.zeros((0, 0)), 0.1, np.full(n, 2.0), np.full(n, 1.0), np.zeros(n), 0.5,
                      "prior", "", None)


def test_own_spread_adds_in_quadrature():
    sp = _spread(3)
    mean = np.array([10.0, 20.0, 30.0])
    bounds = np.array([0, 3])
    own = np.array([3.0, 4.0, 12.0])
    with_own = sp.with_own(own)
    # per trip: var + own^2
    assert with_own.trip_sd(mean) ** 2 == pytest.approx(sp.trip_sd(mean) ** 2 + own ** 2)
    # per duty: the own parts are independent, their variances add (9 + 16 + 144)
    assert with_own.duty_sd(mean, bounds)[0] ** 2 == pytest.approx(sp.duty_sd(mean, bounds)[0] ** 2 + 169.0)
    # taken along with the trips
    assert with_own.take(np.array([2])).own.tolist() == [12.0]
    assert sp.own.tolist() == [0.0, 0.0, 0.0]


def test_monte_carlo_draws_the_own_spread():
    # no model spread at all, only the own: a duty of 4 trips of 10 +- 3 each without charging,
    # 50 available above the reserve: P(sum <= 50) = Phi((50 - 40) / (3 * 2)) analytically
    n = 4
    sp = TripSpread.none(n).with_own(np.full(n, 3.0))
    stops = Stops(dwell_s=np.full(n, 60.0), power_w=np.zeros(n), sizable=np.zeros(n, bool),
                  duty_end=np.array([False, False, False, True]))
    plan = DrawPlan(mean=np.full(n, 10.0), excess=np.zeros(n), spread=sp, stops=stops, bounds=np.array([0, n]),
                    chained=False, capacity=100.0, start=100.0, reserve=50.0, efficiency=0.9, key="b",
                    duty_start_s=np.zeros(1))
    draws = 40_000
    p = p_complete(plan, draws=draws, seed=1)[0]
    expect = norm.cdf(10.0 / 6.0)
    assert abs(p - expect) < 4 * np.sqrt(expect * (1 - expect) / draws)
    # chained (levels carried across duties): the same draws' law
    p2 = p_complete(DrawPlan(**{**plan.__dict__, "chained": True}), draws=draws, seed=2)[0]
    assert abs(p2 - expect) < 4 * np.sqrt(expect * (1 - expect) / draws)


def test_given_duties_may_overlap_in_time():
    # two blocks at the same time: block 0 (three trips), block 1 (two trips)
    start = np.array([0.0, 100.0, 300.0, 50.0, 200.0])
    end = np.array([90.0, 250.0, 400.0, 150.0, 260.0])
    d = group_duties(start, end, rule="given", day=np.array([0, 0, 0, 1, 1]))
    assert d.bounds.tolist() == [0, 3, 5]
    # inside a duty the stops as ever (10 s, 50 s); after a duty's last trip none (NaN)
    assert d.dwell_s[[0, 1, 3]].tolist() == [10.0, 50.0, 50.0]
    assert np.isnan(d.dwell_s[[2, 4]]).all()
    with pytest.raises(ValueError, match="lie together"):
        group_duties(start, end, rule="given", day=np.array([0, 1, 0, 1, 1]))
    with pytest.raises(ValueError, match="within a duty"):
        group_duties(start[[1, 0, 2, 3, 4]], end, rule="given", day=np.array([0, 0, 0, 1, 1]))
