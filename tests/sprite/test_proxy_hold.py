"""The held proxy's staleness rule (lodsprite.sprite.proxy_hold), on hand-made proxies."""

import numpy as np
import pytest

from lodsprite.sprite.proxy_hold import ERROR, REGION, HeldProxy, split_ratio
from lodsprite.sprite.proxy_surface import ProxyNodes


def grid_proxy(n: int = 2, side_m: float = 100.0, g: int = 4) -> ProxyNodes:
    """``n x n`` flat nodes of ``side_m`` metres from (0, 0) east and north."""
    origin = [(c * side_m, (r + 1) * side_m) for r in range(n) for c in range(n)]
    k = n * n
    return ProxyNodes(np.array(origin, float), np.tile([side_m / g, side_m / g], (k, 1)),
                      np.full((k, 2), float(g)), np.zeros((k, g + 1, g + 1)),
                      np.zeros((k, 4), np.intp))


def held(split_m: float = 50.0, eye=(100.0, 100.0, 400.0)) -> HeldProxy:
    nodes = grid_proxy()
    lo = np.c_[nodes.origin[:, 0], nodes.origin[:, 1] - 100.0, np.full(4, -1.0)]
    hi = np.c_[nodes.origin[:, 0] + 100.0, nodes.origin[:, 1], np.full(4, 1.0)]
    return HeldProxy.make(np.array(eye), nodes, lo, hi, np.full(4, split_m))


def test_split_ratio_is_the_worst_range_over_distance():
    lo, hi = np.array([[0.0, 0, 0], [10, 0, 0]]), np.array([[1.0, 1, 1], [11, 1, 1]])
    eye = np.array([0.5, 0.5, 11.0])  # 10 m above box 0, sqrt(9.5² + 10²) from box 1
    assert split_ratio(lo, hi, np.array([20.0, 20.0]), eye) == pytest.approx(2.0)
    assert split_ratio(lo, hi, np.array([0.0, 30.0]), eye) == pytest.approx(30 / np.sqrt(190.25))
    assert split_ratio(lo, hi, np.zeros(2), eye) == 0.0  # level 0 nodes never split


def test_a_near_view_keeps_the_proxy_fresh():
    h = held()
    on = np.array([[50.0, 50.0, 0.0], [150.0, 150.0, 0.0]])
    assert h.ratio0 < 1.0
    assert h.stale(np.array([110.0, 90.0, 380.0]), on) is None


def test_a_view_beyond_its_footprint_is_stale():
    h = held()
    off = np.array([[50.0, 50.0, 0.0], [250.0, 50.0, 0.0]])  # x 250: east of every node
    assert h.stale(np.array([100.0, 100.0, 400.0]), off) == REGION


def test_an_eye_that_closes_in_past_twice_the_tolerance_is_stale():
    h = held(split_m=50.0)  # at 399 m above the nodes: ratio 50 / 399
    on = np.array([[50.0, 50.0, 0.0]])
    assert h.stale(np.array([100.0, 100.0, 30.0]), on) is None  # 29 m: ratio 1.72 <= 2
    assert h.stale(np.array([100.0, 100.0, 20.0]), on) == ERROR  # 19 m: ratio 2.6 > 2


def test_a_proxy_frozen_over_its_tolerance_may_grow_twice_from_there():
    h = held(split_m=800.0)  # frozen with ratio 800 / 399, its children not resident
    on = np.array([[50.0, 50.0, 0.0]])
    assert h.ratio0 == pytest.approx(800 / 399)
    assert h.stale(np.array([100.0, 100.0, 250.0]), on) is None  # ratio 3.2 <= 4.0
    assert h.stale(np.array([100.0, 100.0, 150.0]), on) == ERROR  # ratio 5.4 > 4.0
