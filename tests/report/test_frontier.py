"""Error–time frontiers on hand-made points: the envelope, interpolation in log time
between bracketing points, and no extrapolation."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from lodsprite.errors import InputError
from lodsprite.report.frontier import frontier, frontier_speedup, plot_frontiers, time_at_error

POINTS = [(10.0, 8.0), (20.0, 4.0), (15.0, 9.0), (40.0, 2.0), (40.0, 3.0), (80.0, 2.5),
          (float("nan"), 1.0)]


def test_the_envelope_keeps_only_points_no_other_beats_in_time_and_error():
    assert frontier(POINTS) == [(10.0, 8.0), (20.0, 4.0), (40.0, 2.0)]


def test_a_measured_point_gives_its_own_time_and_between_two_the_log_time_interpolates():
    f = frontier(POINTS)
    assert time_at_error(f, 4.0) == pytest.approx(20.0)
    # halfway in error between (10, 8) and (20, 4): halfway in log time, the geometric mean
    assert time_at_error(f, 6.0) == pytest.approx(math.sqrt(10.0 * 20.0))
    # a quarter of the way from (20, 4) to (40, 2)
    assert time_at_error(f, 3.5) == pytest.approx(20.0 * 2.0 ** 0.25)


@pytest.mark.parametrize("error", [1.9, 8.1, float("nan")])
def test_no_time_outside_the_measured_errors(error):
    assert time_at_error(frontier(POINTS), error) is None
    assert time_at_error([], 3.0) is None


def test_the_speedup_is_the_slower_frontiers_time_over_the_faster_ones_or_none():
    slow = frontier([(100.0, 4.0), (200.0, 1.0)])
    fast = frontier([(10.0, 4.0), (20.0, 2.0)])
    assert frontier_speedup(slow, fast, 4.0) == pytest.approx(10.0)
    assert frontier_speedup(slow, fast, 1.0) is None  # fast never reached 1.0


def test_impossible_points_are_refused():
    with pytest.raises(InputError):
        frontier([(0.0, 1.0)])
    with pytest.raises(InputError):
        frontier([(1.0, -1.0)])


@given(st.lists(st.tuples(st.floats(0.1, 1e4), st.floats(0.0, 100.0)), min_size=1,
                max_size=30))
def test_the_envelope_is_time_ascending_error_descending_and_dominates_every_point(pts):
    f = frontier(pts)
    t, e = np.array(f).T
    assert (np.diff(t) > 0).all() and (np.diff(e) < 0).all()
    for p in pts:  # every point has a frontier point at least as fast and as good
        assert any(ft <= p[0] and fe <= p[1] for ft, fe in f)
    for ft, fe in f:
        got = time_at_error(f, fe)
        assert got == pytest.approx(ft)


def test_the_plot_is_written(tmp_path):
    out = plot_frontiers({"adaptive": POINTS[:3], "sprite": [(5.0, 6.0), (9.0, 3.0)]},
                         tmp_path / "f.png", "jacksboro, chen1999", levels=(4.0,))
    assert out.stat().st_size > 1000 and out.read_bytes()[:4] == b"\x89PNG"
