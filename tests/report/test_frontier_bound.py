"""The frontier's lower bound: a faster technique whose fastest run is already below an
error level is at least that run's speedup there."""

from __future__ import annotations

import pytest

from lodsprite.report.frontier import frontier, frontier_speedup, speedup_lower_bound

SLOW = frontier([(10.0, 4.0), (20.0, 2.0), (40.0, 1.0)])


def test_a_fastest_run_below_the_level_gives_at_least_its_speedup():
    fast = frontier([(5.0, 1.5), (8.0, 0.5)])
    assert frontier_speedup(SLOW, fast, 3.0) is None  # no interpolation reaches 3.0
    # the slower needs 10 * sqrt(2) ms at 3.0 (halfway from 4 to 2, in log time)
    assert speedup_lower_bound(SLOW, fast, 3.0) == pytest.approx((10 * 2 ** 0.5) / 5.0)


def test_no_bound_where_the_exact_speedup_applies_or_the_slower_has_no_time():
    fast = frontier([(5.0, 3.0), (8.0, 0.5)])
    assert speedup_lower_bound(SLOW, fast, 2.0) is None
    assert frontier_speedup(SLOW, fast, 2.0) is not None
    assert speedup_lower_bound(SLOW, frontier([(5.0, 0.2)]), 0.5) is None  # SLOW stops at 1
    assert speedup_lower_bound(SLOW, [], 2.0) is None
