"""Tile bookkeeping, per-tile error and the budgeted benefit/cost selection (GL-free)."""

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import make_field
from lodsprite.camera import Projection, look_at, widened
from lodsprite.sprite.metric import ErrorMetric
from lodsprite.sprite.tiled import (
    FORCE_FACTOR,
    combined_error,
    ndc_rects,
    select_tiles,
    serving_tiles,
    sub_view_proj,
    tile_errors,
    tile_rects,
)


def test_tile_rects_partition_the_image():
    rects = tile_rects(3, (100, 70))
    cover = np.zeros((70, 100), int)
    for x0, y0, x1, y1 in rects:
        cover[y0:y1, x0:x1] += 1
    assert (cover == 1).all()
    ndc = ndc_rects(rects, (100, 70))
    assert ndc.min() == -1.0 and ndc.max() == 1.0


def test_sub_view_proj_maps_the_rectangle_to_the_whole_ndc_square():
    vp = look_at((0.0, -500.0, 800.0), (0.0, 0.0, 0.0))
    m = Projection(45.0, 1.0, 1.0, 5000.0).matrix() @ vp.view_matrix()
    rect = np.array([-0.2, 0.1, 0.6, 0.5])
    sub = sub_view_proj(m, rect)
    rng = np.random.default_rng(1)
    pts = np.c_[rng.uniform(-400, 400, (200, 2)), rng.uniform(0, 200, 200), np.ones(200)]
    a, b = pts @ m.T, pts @ sub.T
    na, nb = a[:, :2] / a[:, 3:], b[:, :2] / b[:, 3:]
    inside = np.all((na >= rect[:2]) & (na <= rect[2:]), axis=1)
    assert inside.any() and (~inside).any()
    assert np.array_equal(np.all(np.abs(nb) <= 1 + 1e-9, axis=1), inside)


def test_serving_tile_is_the_first_whose_rectangle_holds_the_point():
    vp = look_at((0.0, -500.0, 800.0), (0.0, 0.0, 0.0))
    m = Projection(45.0, 1.0, 1.0, 5000.0).matrix() @ vp.view_matrix()
    rects = ndc_rects(tile_rects(2, (64, 64)), (64, 64))
    pts = np.array([[-100.0, 50.0, 0.0, 1.0], [100.0, 50.0, 0.0, 1.0], [0.0, 0.0, 9e3, 1.0]])
    owner = serving_tiles(pts, np.stack([m] * 4), rects)
    clip = pts @ m.T
    ndc = clip[:, :2] / clip[:, 3:]
    for k in range(2):
        col, row = int(ndc[k, 0] >= 0), int(ndc[k, 1] >= 0)
        assert owner[k] == row * 2 + col
    assert owner[2] == -1  # behind the eye


def _scene():
    hf = make_field(64, kind="ridges", relief=150.0)
    metric = ErrorMetric.for_level(hf, 16)
    vp = look_at((0.0, -900.0, 1300.0), (0.0, 0.0, 0.0))
    proj = Projection(45.0, 1.0, 10.0, 8000.0)
    return metric, vp, proj


def test_a_tile_over_epsilon_is_rerendered_and_one_under_it_is_not():
    # Four tiles; tile 2's keyframe is from a viewpoint 150 m away, the others' from the
    # current one: only tile 2 has an error, over ε, and only it is selected.
    metric, vp, proj = _scene()
    key = widened(proj, 128, 128, 16)
    here = metric.reproject(vp.o)
    other_vp = look_at((150.0, -900.0, 1300.0), (0.0, 0.0, 0.0))
    there = metric.reproject(other_vp.o)
    kvp_here = key.matrix() @ vp.view_matrix()
    kvp_there = key.matrix() @ other_vp.view_matrix()
    rects = ndc_rects(tile_rects(2, (160, 160)), (160, 160))
    c_primes = [here, here, there, here]
    views = np.stack([kvp_here, kvp_here, kvp_there, kvp_here])
    view_proj = proj.matrix() @ vp.view_matrix()
    beta = proj.pixel_angle_rad(128)
    errors, served = tile_errors(metric, c_primes, views, rects, vp.o, view_proj, kvp_here,
                                 beta)
    assert served.sum() > 0 and served[2] >= 4
    np.testing.assert_allclose(errors[[0, 1, 3]], 0.0, atol=1e-9)
    assert errors[2] > 0.5
    chosen = select_tiles(errors, 0.5, np.ones(4), served, budget_ms=10.0)
    assert chosen.tolist() == [2]
    # combined error: the RMS over every sample, tiles weighted by what they serve
    assert combined_error(errors, served) == errors[2] * math.sqrt(served[2] / served.sum())


def test_never_rendered_tiles_are_all_taken_and_inf_forces():
    assert select_tiles(np.full(4, np.inf), 1.0, np.ones(4), np.zeros(4), 0.0,
                        rendered=np.zeros(4, bool)).tolist() == [0, 1, 2, 3]
    # A tile whose error cannot be measured (inf) is over 2 ε: forced even with no budget.
    assert select_tiles(np.array([0.1, np.inf, 1.5]), 1.0, np.array([1.0, 9.0, 1.0]),
                        np.ones(3), 0.0).tolist() == [1]


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.floats(0.0, 5.0), st.floats(0.01, 10.0), st.integers(0, 50)),
                min_size=1, max_size=16),
       st.floats(0.0, 20.0))
def test_the_budget_holds_on_a_synthetic_cost_model(tiles, budget):
    errors, costs, served = (np.array(v, float) for v in zip(*tiles, strict=True))
    eps = 1.0
    chosen = select_tiles(errors, eps, costs, served, budget).tolist()
    assert len(set(chosen)) == len(chosen)
    assert all(errors[i] >= eps for i in chosen)
    over = np.flatnonzero(errors >= eps)
    forced = None
    if over.size and errors[over].max() >= FORCE_FACTOR * eps:
        forced = int(over[np.argmax(errors[over])])
        assert chosen[0] == forced
    rest = chosen[1:] if forced is not None else chosen
    spent = sum(costs[i] for i in chosen)
    limit = max(budget, costs[forced]) if forced is not None else budget
    assert spent <= limit + 1e-9  # the budget, except the documented forced tile
    # benefit/cost order, and every candidate left out no longer fitted at its turn
    area = np.maximum(served / max(1, served.sum()), 1.0 / len(errors))
    ratio = errors / eps * area / costs
    assert all(ratio[a] >= ratio[b] for a, b in zip(rest, rest[1:], strict=False))
    left = budget - (costs[forced] if forced is not None else 0.0)
    for i in over[np.argsort(-ratio[over], kind="stable")]:
        if i == forced:
            continue
        if i in rest:
            left -= costs[i]
        else:
            assert costs[i] > left


def test_the_update_c_prime_is_the_full_one_inside_the_key_view():
    from lodsprite.sprite.metric import in_view
    from lodsprite.sprite.tiled import reproject_in_key_view

    metric, vp, proj = _scene()
    low = look_at((0.0, -700.0, 260.0), (0.0, 0.0, 100.0))  # a low eye: many centres unseen
    kvp = widened(proj, 128, 128, 16).matrix() @ low.view_matrix()
    full = metric.reproject(low.o)
    part = reproject_in_key_view(metric, low.o, kvp)
    vis = in_view(metric._centres_h, kvp)
    assert 0 < vis.sum() < len(vis)
    np.testing.assert_array_equal(np.asarray(part)[vis], np.asarray(full)[vis])
    np.testing.assert_array_equal(part.missed[vis], full.missed[vis])
    assert part.missed[~vis].all()
    np.testing.assert_array_equal(part.key_eye, full.key_eye)


def test_combined_error_ignores_tiles_that_serve_no_sample():
    """A tile serving no sample may have an infinite error of its own (no sample of its
    update's C' in view): the image's error is the served tiles' RMS, never NaN."""
    errors = np.array([math.inf, 0.5, 1.5])
    served = np.array([0.0, 10.0, 30.0])
    got = combined_error(errors, served)
    assert got == math.sqrt((10 * 0.25 + 30 * 2.25) / 40)
