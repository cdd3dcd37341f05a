"""Node subsets of §3.1/§3.3, GL-free: every covering's alphas sum to one everywhere on
the st plane (checked by barycentric interpolation at random points)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lodsprite.lumigraph.geometry import Slab
from lodsprite.lumigraph.subsets import (
    Cover,
    cover_draws,
    grid_cover,
    line_draws,
    nearest_block,
    nearest_nodes,
    subsample_nodes,
    subset_cover,
)

SLAB = Slab(np.eye(4), st_size=3.0, uv_size=2.0, st_distance=2.5, n_st=8, n_uv=32)


def alpha_sum(draws, pts: np.ndarray) -> np.ndarray:
    """The summed alpha of all draws at ``pts (P, 2)``, as additive blending makes it."""
    total = np.zeros(len(pts))
    for c, a in zip(draws.corners, draws.alpha, strict=True):
        m = np.vstack([c.T, np.ones(3)])
        if abs(np.linalg.det(m)) < 1e-12:
            continue
        bary = np.linalg.solve(m, np.vstack([pts.T, np.ones(len(pts))]))
        inside = (bary >= -1e-9).all(axis=0)
        total[inside] += (a[:, None] * bary).sum(axis=0)[inside]
    return total


def points(n=300, seed=0):
    h = SLAB.st_size / 2 * 0.999
    return np.random.default_rng(seed).uniform(-h, h, (n, 2))


def test_the_full_grid_draws_each_triangle_once_per_corner_alpha_one_at_it():
    d = cover_draws(grid_cover(SLAB))
    assert len(d) == 3 * 2 * 7 * 7
    assert sorted(d.alpha.sum(axis=1)) == [1.0] * len(d)  # one corner at 1, two at 0
    np.testing.assert_allclose(alpha_sum(d, points()), 1.0, atol=1e-9)


@pytest.mark.parametrize("nodes", [
    nearest_block(SLAB, np.array([0.2, -0.1])),          # Figure 3's fixed 9
    nearest_block(SLAB, np.array([1.5, 1.5])),           # clamped into a corner
    subsample_nodes(8, 1), subsample_nodes(8, 2),        # the st mipmap
    nearest_nodes(SLAB, np.array([0.3, 0.4]), 5),        # an arbitrary handful
    np.array([27]),                                      # one node
])
def test_subsets_with_fictitious_corners_cover_the_plane_with_unit_alphas(nodes):
    cover = subset_cover(SLAB, nodes)
    d = cover_draws(cover)
    assert d.holes == 0 and set(d.nodes) <= set(nodes.tolist())
    np.testing.assert_allclose(alpha_sum(d, points()), 1.0, atol=1e-9)


def test_figure_3_alphas_of_the_fixed_nine():
    # inside the nine every triangle is drawn three times; the paper's triangle I (nodes
    # a, b with data, fictitious (b, c) beside them) is drawn from a with alphas 1 at a,
    # 0 at b and 1/2 at the fictitious node, whose only neighbours with data are a and b
    cover = subset_cover(SLAB, nearest_block(SLAB, np.zeros(2)))
    d = cover_draws(cover)
    data = {tuple(np.round(p, 9)) for p, n in zip(cover.points, cover.node, strict=True)
            if n >= 0}
    draws_of: dict = {}
    for c, n, a in zip(d.corners, d.node, d.alpha, strict=True):
        key = tuple(sorted(tuple(np.round(p, 9)) for p in c))
        draws_of.setdefault(key, []).append((int(n), c, a))
    inner = [k for k in draws_of if all(p in data for p in k)]
    assert len(inner) == 8 and all(len(draws_of[k]) == 3 for k in inner)
    halves = 0
    for k, ds in draws_of.items():
        if sum(p in data for p in k) == 2 and len(ds) == 2:
            for _, c, a in ds:
                fict = [i for i in range(3) if tuple(np.round(c[i], 9)) not in data]
                assert len(fict) == 1 and a[fict[0]] == 0.5
                assert sorted(np.delete(a, fict[0]).tolist()) == [0.0, 1.0]
            halves += 1
    assert halves >= 4  # along the block's sides (diagonal ring nodes touch three)


@settings(max_examples=30, deadline=None)
@given(st.lists(st.integers(0, 63), min_size=1, max_size=20, unique=True),
       st.lists(st.floats(0.05, 1.0), min_size=20, max_size=20))
def test_any_subset_with_any_validities_sums_to_one(nodes, validity):
    # §3.3: a vertex with validity v keeps v and its neighbours with data share 1 - v
    v = np.array(validity[: len(nodes)])
    if len(nodes) == 1:
        v[0] = 1.0  # a lone node fading in has nothing to share its 1 - v with
    d = cover_draws(subset_cover(SLAB, np.array(nodes), v))
    assert d.holes == 0
    np.testing.assert_allclose(alpha_sum(d, points(120, len(nodes))), 1.0, atol=1e-9)


def test_a_covering_with_no_data_at_all_is_all_holes():
    cover = Cover(np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]), np.array([[0, 1, 2]]),
                  np.array([0, -1, -1]), np.array([0.0, 0.0, 0.0]))
    d = cover_draws(cover)
    assert len(d) == 0 and d.holes == 3


def test_a_vertex_out_of_reach_of_data_borrows_the_nearest_node():
    # data only at vertex 0; vertex 3 shares no triangle edge with it (the paper's hole)
    pts = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    cover = Cover(pts, np.array([[0, 1, 2], [1, 3, 2]]), np.array([5, -1, -1, -1]),
                  np.array([1.0, 0.0, 0.0, 0.0]))
    d = cover_draws(cover)
    assert d.holes == 0 and set(d.nodes) == {5}
    inside = np.random.default_rng(1).uniform(0.01, 0.99, (200, 2))
    np.testing.assert_allclose(alpha_sum(d, inside), 1.0, atol=1e-9)


def test_a_node_in_a_corner_of_the_plane_covers_it_alone():
    # the corner is a node, so the other three corners are fictitious: one of them has
    # no neighbour with data in the triangulation and borrows that node
    d = cover_draws(subset_cover(SLAB, np.array([0])))
    assert d.holes == 0
    np.testing.assert_allclose(alpha_sum(d, points()), 1.0, atol=1e-9)


@pytest.mark.parametrize("direction, axis", [((1.0, 0.2), 0), ((-0.1, 1.0), 1)])
def test_nodes_along_a_line_are_strips_drawn_twice(direction, axis):
    d = line_draws(SLAB, np.array([0.2, -0.4]), np.array(direction))
    assert len(d) == 2 * 2 * 7                      # 7 strips, 2 triangles, 2 textures
    n = SLAB.n_st
    idx = d.nodes // n if axis == 0 else d.nodes % n
    other = d.nodes % n if axis == 0 else d.nodes // n
    assert sorted(idx) == list(range(n)) and len(set(other)) == 1
    np.testing.assert_allclose(alpha_sum(d, points()), 1.0, atol=1e-9)
