"""The angular error metric (Chen et al. 1999 Eq. 1-2) against hand-computed geometry."""

import math

import numpy as np
import pytest

from conftest import make_field
from lodsprite.camera import Projection, look_at
from lodsprite.sprite import fallback, raycast
from lodsprite.sprite.metric import (
    MAX_FALLBACK,
    MIN_SAMPLES,
    ErrorMetric,
    angles_at_eye,
    in_view,
)
from lodsprite.sprite.policy import KeyframePolicy
from lodsprite.sprite.raycast import coarse_squares, ray_triangle_t, reprojected_centres
from lodsprite.terrain.heightfield import HeightField

H_SPIKE = 50.0


def spiked_field(spike: float = H_SPIKE) -> HeightField:
    """16 x 16 quads, 10 m spacing, flat at z = 0 except the centre vertex of each square of
    the 4 x 4 level, raised to 50 m.  The coarse level is then exactly the plane z = 0."""
    h = np.zeros((17, 17), np.float32)
    h[2::4, 2::4] = spike
    return HeightField(h, 10.0, 10.0, "spikes")


def test_centres_are_full_resolution_centre_vertices():
    hf = spiked_field()
    sq = coarse_squares(hf, 4)
    assert sq.centres.shape == (16, 3)
    np.testing.assert_allclose(sq.centres[:, 2], H_SPIKE)
    # The coarse triangles are flat (all coarse vertices are at z = 0).
    np.testing.assert_allclose(sq.tris[..., 2], 0.0)


def test_c_prime_is_where_the_keyframe_ray_meets_the_coarse_surface():
    hf = spiked_field()
    sq = coarse_squares(hf, 4)
    eye = np.array([13.0, -7.0, 400.0])
    cp = reprojected_centres(sq, eye)
    # Ray from eye through C reaches z = 0 at t = eye_z / (eye_z - C_z).
    t = eye[2] / (eye[2] - H_SPIKE)
    expect = eye + t * (sq.centres - eye)
    np.testing.assert_allclose(cp, expect, atol=1e-9)


def test_theta_matches_hand_computation():
    hf = spiked_field()
    metric = ErrorMetric.for_level(hf, 4)
    c = metric.squares.centres[5]
    key_eye = np.array([c[0], c[1], 300.0])  # straight above C: C' = (Cx, Cy, 0)
    cp = metric.reproject(key_eye)
    np.testing.assert_allclose(cp[5], [c[0], c[1], 0.0], atol=1e-9)
    a = 120.0
    eye = np.array([c[0] + a, c[1], 300.0])
    expected = math.atan(a / (300.0 - H_SPIKE)) - math.atan(a / 300.0)
    got = angles_at_eye(eye, c[None], cp[5][None])[0]
    assert got == pytest.approx(abs(expected), rel=1e-9)


def test_theta_is_zero_at_the_keyframe_viewpoint():
    hf = spiked_field(5.0)
    metric = ErrorMetric.for_level(hf, 4)
    vp = look_at((30.0, -250.0, 220.0), (0.0, 0.0, 0.0))
    proj = Projection(45.0, 1.0, 1.0, 2000.0)
    cp = metric.reproject(vp.o)
    th = metric.theta(cp, vp.o, proj.matrix() @ vp.view_matrix())
    assert th.size == 16 and np.all(np.isfinite(th))
    np.testing.assert_allclose(th, 0.0, atol=1e-7)
    assert metric.error_px(cp, vp.o, proj.matrix() @ vp.view_matrix(),
                           proj.pixel_angle_rad(512)) == pytest.approx(0.0, abs=1e-4)


def test_error_grows_with_distance_from_the_keyframe_and_matches_eq2():
    hf = spiked_field(5.0)
    metric = ErrorMetric.for_level(hf, 4)
    proj = Projection(45.0, 1.0, 1.0, 2000.0)
    beta = proj.pixel_angle_rad(512)
    key = look_at((0.0, -300.0, 250.0), (0.0, 0.0, 0.0))
    cp = metric.reproject(key.o)
    errors = []
    for step in (5.0, 10.0, 20.0, 40.0):
        vp = look_at((step, -300.0, 250.0), (0.0, 0.0, 0.0))
        vpm = proj.matrix() @ vp.view_matrix()
        e = metric.error_px(cp, vp.o, vpm, beta)
        th = metric.theta(cp, vp.o, vpm)
        assert np.all(np.isfinite(th))
        # Eq. 2: mean(θ²) >= (β ε)²  <=>  error_px >= ε
        for eps in (0.5, 1.0, 2.0, 4.0):
            assert (np.mean(th**2) >= (beta * eps) ** 2) == (e >= eps)
        errors.append(e)
    assert all(b > a for a, b in zip(errors, errors[1:], strict=False))


def test_nothing_in_view_means_a_keyframe_is_due():
    hf = spiked_field()
    metric = ErrorMetric.for_level(hf, 4)
    proj = Projection(45.0, 1.0, 1.0, 2000.0)
    away = look_at((0.0, 0.0, 100.0), (0.0, 1000.0, 100.0))  # looking at the horizon, no terrain
    cp = metric.reproject(np.array([0.0, -300.0, 250.0]))
    vpm = proj.matrix() @ away.view_matrix()
    assert metric.theta(cp, away.o, vpm).size == 0
    assert metric.error_px(cp, away.o, vpm, 0.001) == math.inf  # used to be 0: never due
    assert len(metric.fallback_points(vpm)[0]) == 0


def test_ray_triangle_hits_and_misses():
    tri = np.array([[[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]])[None]  # (1, 1, 3, 3)
    origin = np.array([0.2, 0.2, 1.0])
    t = ray_triangle_t(origin, np.array([[0.0, 0.0, -1.0]]), tri)
    assert t[0, 0] == pytest.approx(1.0)
    t = ray_triangle_t(origin, np.array([[1.0, 1.0, -0.1]]), tri)
    assert np.isnan(t[0, 0])


def hit_or_miss(sq, eye):
    """Per square centre, whether the ray eye -> C meets any coarse triangle in front of the
    eye: brute force over every triangle of the level."""
    d = sq.centres - eye
    every = np.broadcast_to(sq.own.reshape(1, -1, 3, 3), (len(d), len(sq.own) * 2, 3, 3))
    t = ray_triangle_t(eye, d, every)
    return np.any(t > 0, axis=1)


def test_rays_missing_the_coarse_surface_count_at_the_terrain_edge():
    hf = spiked_field()
    metric = ErrorMetric.for_level(hf, 4)
    # Grazing keyframe: rays through the far spikes leave the terrain before reaching z = 0.
    key = np.array([0.0, -400.0, 250.0])
    hit = hit_or_miss(metric.squares, key)
    assert 0 < hit.sum() < hit.size
    cp = metric.reproject(key)
    assert np.all(np.isfinite(cp))
    # A miss's C' is on the ray, beyond C, in the vertical plane of the terrain's edge.
    c = metric.squares.centres
    t = (cp - key)[:, 1] / (c - key)[:, 1]
    np.testing.assert_allclose(cp[~hit], (key + t[:, None] * (c - key))[~hit], atol=1e-9)
    assert np.all(t[~hit] > 1)
    lo, hi = hf.bounds()
    on_edge = np.isclose(np.abs(cp[~hit, 0]), hi[0]) | np.isclose(np.abs(cp[~hit, 1]), hi[1])
    assert on_edge.all()

    proj = Projection(45.0, 1.0, 1.0, 2000.0)
    vp = look_at((10.0, -400.0, 250.0), (0.0, 0.0, 0.0))
    vpm, beta = proj.matrix() @ vp.view_matrix(), proj.pixel_angle_rad(512)
    e = metric.error_px(cp, vp.o, vpm, beta)
    # Independently: the squares in view whose rays hit, as the metric once averaged alone.
    vis = in_view(np.c_[c, np.ones(len(c))], vpm)
    assert vis[~hit].any()
    th_hits = angles_at_eye(vp.o, c[vis & hit], cp[vis & hit])
    hits_only = float(np.sqrt(np.mean(th_hits**2)) / beta)
    # A miss counts with the angle to its exit point, but never less than the worst hit.
    th_miss = np.maximum(angles_at_eye(vp.o, c[vis & ~hit], cp[vis & ~hit]), th_hits.max())
    expect = float(np.sqrt(np.mean(np.r_[th_hits, th_miss] ** 2)) / beta)
    assert e == pytest.approx(expect, rel=1e-9)
    assert e > 1.02 * hits_only  # the misses no longer pull the mean down (old: equal)
    at_key = look_at(key, (0.0, 0.0, 0.0))
    assert metric.error_px(cp, key, proj.matrix() @ at_key.view_matrix(),
                           beta) == pytest.approx(0.0, abs=1e-6)


def test_hits_behind_the_keyframe_eye_do_not_count():
    # A keyframe eye 10 m above the flat coarse level looks up at the 50 m spikes: each ray
    # through a spike meets z = 0 only behind the eye, where the keyframe saw nothing.
    hf = spiked_field()
    metric = ErrorMetric.for_level(hf, 4)
    key = np.array([0.0, -75.0, 10.0])
    cp = metric.reproject(key)
    c = metric.squares.centres
    ahead = np.einsum("kj,kj->k", cp - key, c - key)
    assert np.all(ahead > 0)


def wavy_field() -> HeightField:
    """16 x 16 quads, 10 m spacing, smooth relief that the 4 x 4 level does not follow."""
    r, c = np.meshgrid(np.arange(17.0), np.arange(17.0), indexing="ij")
    h = 20.0 * np.sin(r * 0.9) * np.cos(c * 0.7) + 3.0 * r
    return HeightField(h.astype(np.float32), 10.0, 10.0, "wavy")


def brute_force_error(metric, hf, key_eye, vp, proj, height_px):
    """sqrt(mean θ²)/β over every full-resolution vertex in view that is not a coarse vertex,
    C' from rays against every coarse triangle (the hit in front of the eye nearest C)."""
    rr, cc = (a.ravel() for a in np.meshgrid(np.arange(hf.rows), np.arange(hf.cols),
                                             indexing="ij"))
    step = hf.quads // metric.squares.level_quads
    keep = (rr % step != 0) | (cc % step != 0)
    pts = hf.points(rr[keep], cc[keep])
    vpm = proj.matrix() @ vp.view_matrix()
    clip = np.c_[pts, np.ones(len(pts))] @ vpm.T
    vis = (clip[:, 3] > 0) & np.all(np.abs(clip[:, :3]) <= clip[:, 3:4], axis=1)
    pts = pts[vis]
    d = pts - key_eye
    every = np.broadcast_to(metric.squares.own.reshape(1, -1, 3, 3), (len(d), 32, 3, 3))
    t = ray_triangle_t(key_eye, d, every)
    t = np.where(t > 0, t, np.nan)
    best = t[np.arange(len(t)), np.nanargmin(np.abs(t - 1.0), axis=1)]
    th = angles_at_eye(vp.o, pts, key_eye + best[:, None] * d)
    return len(pts), float(np.sqrt(np.mean(th**2)) / proj.pixel_angle_rad(height_px))


def test_flying_low_between_the_centres_measures_the_fallback_sample():
    hf = wavy_field()
    metric = ErrorMetric.for_level(hf, 4)
    proj = Projection(45.0, 1.0, 1.0, 2000.0)
    # 30 m above the edge midpoint (row 4, col 2), looking down: the nearest square centres
    # (rows 2 and 6) are 20 m away, outside the view, though terrain fills it.
    spot = hf.points(np.array(4), np.array(2))
    vp = look_at(spot + (0.0, -1.0, 30.0), spot)
    vpm = proj.matrix() @ vp.view_matrix()
    assert metric.theta(metric.reproject(vp.o), vp.o, vpm).size == 0
    key_eye = vp.o + np.array([-25.0, 0.0, 10.0])
    cp = metric.reproject(key_eye)
    e = metric.error_px(cp, vp.o, vpm, proj.pixel_angle_rad(512))
    n, expect = brute_force_error(metric, hf, key_eye, vp, proj, 512)
    assert n >= 4
    assert e == pytest.approx(expect, rel=1e-9)
    assert e > 1.0  # the old metric said 0 here: no keyframe would ever be due
    same = metric.error_px(metric.reproject(vp.o), vp.o, vpm, proj.pixel_angle_rad(512))
    assert same == pytest.approx(0.0, abs=1e-6)


def noncoarse_in_view(hf, step, vpm):
    rr, cc = (a.ravel() for a in np.meshgrid(np.arange(hf.rows), np.arange(hf.cols),
                                             indexing="ij"))
    keep = (rr % step != 0) | (cc % step != 0)
    pts = hf.points(rr[keep], cc[keep])
    return int(in_view(np.c_[pts, np.ones(len(pts))], vpm).sum())


@pytest.mark.parametrize("eye, target, key_offset", [
    # Low views over a 512² ridged field at level 16 where the frustum holds only 2 or 3
    # full-resolution vertices, none of them a square centre: the fallback grid used to
    # stay at spacing step/2 (its bounding box reached far beyond the slope) and say inf.
    ((-5278.321944110511, -2322.045435917755, 126.87180830306852),
     (-5277.639752078112, -2321.5099885363147, 126.37390255632538), (-15.0, -5.0, 30.0)),
    ((-5197.9361351982025, 1213.0522493096105, 262.86120771861306),
     (-5197.155828325078, 1213.484906554816, 263.31279258541633), (15.0, 5.0, 3.0)),
])
def test_vertices_in_view_are_always_measured(eye, target, key_offset):
    hf = make_field(512, relief=400.0, spacing=30.0, kind="ridges")
    p = KeyframePolicy.for_terrain(hf, 16, 1.0, (512, 512), predict=False)
    m = p.metric
    vp = look_at(eye, target)
    proj = p.projection(vp)
    vpm = proj.matrix() @ vp.view_matrix()
    assert 0 < noncoarse_in_view(hf, m.squares.step, vpm) < MIN_SAMPLES
    assert in_view(m._centres_h, vpm).sum() == 0
    assert len(m.fallback_points(vpm)[0]) == noncoarse_in_view(hf, m.squares.step, vpm)
    cp = m.reproject(vp.o + np.array(key_offset))  # their rays meet the coarse surface
    assert not m.fallback_theta(cp.key_eye, vp.o, vpm)[1].any()
    assert math.isfinite(p.error_px(cp, vp, proj))  # was inf: no fallback vertex found


def test_the_fallback_sample_never_exceeds_its_cap(monkeypatch):
    # Level 64 of a 128² field (step 2): the coarsest fallback grid is already the full
    # grid, and a low view looking down along a slope holds thousands of its vertices.
    hf = make_field(128, relief=400.0, spacing=30.0, kind="ridges")
    m = ErrorMetric.for_level(hf, 64)
    tested = []
    real = fallback.in_view

    def counting(points_h, view_proj):
        tested.append(len(points_h))
        return real(points_h, view_proj)

    monkeypatch.setattr(fallback, "in_view", counting)
    proj = Projection(80.0, 1.0, 0.5, 12000.0)
    spot = hf.points(np.array(37), np.array(41))
    for vp in (look_at(spot + (0.0, -1.0, 400.0), spot),
               look_at(spot + (0.0, -900.0, 300.0), spot),
               look_at(spot + (5.0, -1.0, 2.0), spot)):
        vpm = proj.matrix() @ vp.view_matrix()
        tested.clear()
        pts, square = m.fallback_points(vpm)
        assert 0 < len(pts) <= MAX_FALLBACK
        assert max(tested) <= fallback.CANDIDATE_CHUNK
        assert np.all(in_view(np.c_[pts, np.ones(len(pts))], vpm))
    assert len(pts) < noncoarse_in_view(hf, 2, vpm) or len(pts) == MAX_FALLBACK


def test_the_fallback_reprojection_is_cached_per_keyframe(monkeypatch):
    hf = wavy_field()
    metric = ErrorMetric.for_level(hf, 4)
    proj = Projection(45.0, 1.0, 1.0, 2000.0)
    spot = hf.points(np.array(4), np.array(2))
    vp = look_at(spot + (0.0, -1.0, 30.0), spot)
    vpm, beta = proj.matrix() @ vp.view_matrix(), proj.pixel_angle_rad(512)
    cp = metric.reproject(vp.o + np.array([-25.0, 0.0, 10.0]))
    calls = []
    real = fallback.reproject_points

    def counting(squares, key_eye, points, square=None):
        calls.append(len(points))
        return real(squares, key_eye, points, square)

    monkeypatch.setattr(fallback, "reproject_points", counting)
    first = metric.error_px(cp, vp.o, vpm, beta)
    assert len(calls) == 1
    again = metric.error_px(cp, vp.o, vpm, beta)
    assert again == first and len(calls) == 1  # the same keyframe: nothing reprojected
    moved = look_at(spot + (3.0, -1.0, 30.0), spot + (3.0, 0.0, 0.0))
    vpm2 = proj.matrix() @ moved.view_matrix()
    e2 = metric.error_px(cp, moved.o, vpm2, beta)
    fresh = metric.reproject(cp.key_eye)
    assert e2 == metric.error_px(fresh, moved.o, vpm2, beta)  # cached C' equals fresh C'
    other = metric.reproject(vp.o)  # another keyframe: its own cache
    n = len(calls)
    metric.error_px(other, vp.o, vpm, beta)
    assert len(calls) == n + 1


def test_the_whole_level_search_in_blocks_equals_the_unblocked_search():
    hf = make_field(16, relief=300.0, spacing=10.0, kind="ridges")
    sq = coarse_squares(hf, 8)
    every = sq.own.reshape(-1, 3, 3)
    key = np.array([3.0, -120.0, 200.0])
    d = sq.centres - key
    d = np.r_[d, d * np.array([1.0, 1.0, -1.0]), d * 3.0]  # hits, misses, far points

    def tris(k0, k1, j0, j1):
        return np.broadcast_to(every[None, j0:j1], (k1 - k0, j1 - j0, 3, 3))

    whole = raycast.nearest_hits(key, d, tris, len(every), chunk_pairs=10**9)
    every_b = np.broadcast_to(every[None], (len(d), *every.shape))
    t = ray_triangle_t(key, d, every_b)
    np.testing.assert_array_equal(whole, raycast._nearest_to_c(t))
    assert np.isnan(whole).any() and np.isfinite(whole).any()
    for chunk in (5, 7, len(every), 3 * len(every) + 1):
        blocked = raycast.nearest_hits(key, d, tris, len(every), chunk)
        np.testing.assert_array_equal(blocked, whole)
    # one pair a block (a Python step per ray and triangle): every 8th ray, hits and misses
    np.testing.assert_array_equal(raycast.nearest_hits(key, d[::8], tris, len(every), 1),
                                  whole[::8])


def test_reprojection_in_blocks_equals_reprojection_at_once(monkeypatch):
    hf = make_field(32, relief=300.0, spacing=10.0, kind="ridges")
    sq = coarse_squares(hf, 16)
    key = np.array([0.0, -150.0, 160.0])  # grazing: misses reach the whole-level stage
    at_once = raycast.reproject_points(sq, key, sq.centres)
    assert at_once[1].any()
    monkeypatch.setattr(raycast, "RAY_PAIRS", 13)
    monkeypatch.setattr(raycast.nearest_hits, "__defaults__", (13,))
    blocked = raycast.reproject_points(sq, key, sq.centres)
    np.testing.assert_array_equal(blocked[0], at_once[0])
    np.testing.assert_array_equal(blocked[1], at_once[1])


def test_when_every_sample_misses_a_keyframe_is_due():
    # A keyframe eye far away at the spikes' height: every ray through a spike passes
    # above the flat coarse level until it leaves the terrain.
    hf = spiked_field()
    metric = ErrorMetric.for_level(hf, 4)
    key = np.array([0.0, -1000.0, 55.0])
    cp = metric.reproject(key)
    assert cp.missed.all()
    proj = Projection(45.0, 1.0, 1.0, 2000.0)
    vp = look_at((0.0, -300.0, 250.0), (0.0, 0.0, 0.0))
    vpm = proj.matrix() @ vp.view_matrix()
    assert metric.theta(cp, vp.o, vpm).size == 16
    assert metric.error_px(cp, vp.o, vpm, proj.pixel_angle_rad(512)) == math.inf  # was 84.6 px


@pytest.mark.parametrize("key", [(0.0, -150.0, 160.0), (400.0, 500.0, 90.0),
                                 (-30.0, 20.0, 400.0)])
def test_the_whole_level_stage_tests_the_squares_under_the_ray_as_every_square(key):
    # Grazing keys (inside and outside the footprint, and a high one with near-vertical
    # rays): the rays reaching the whole-level stage meet the same nearest triangle among
    # the squares their ground track crosses as among all 2 n² (exactly, the same t).
    hf = make_field(64, relief=300.0, spacing=10.0, kind="ridges")
    sq = coarse_squares(hf, 32)
    key = np.array(key)
    pts = np.r_[sq.centres, sq.centres * np.array([1.0, 1.0, -0.5]),
                np.c_[sq.centres[:8, :2], np.full(8, 900.0)], [[key[0], key[1], -5.0]]]
    d = pts - key
    every = sq.own.reshape(-1, 3, 3)
    crossed = raycast.crossed_triangles(sq, key, d)
    assert crossed.shape[1] < len(every) / 4  # far fewer than the whole level
    fast = raycast.nearest_hits(key, d, lambda k0, k1, j0, j1: every[crossed[k0:k1, j0:j1]],
                                crossed.shape[1])
    brute = raycast.nearest_hits(
        key, d, lambda k0, k1, j0, j1: np.broadcast_to(every[None, j0:j1],
                                                       (k1 - k0, j1 - j0, 3, 3)), len(every))
    assert np.isfinite(brute).sum() > 100 and np.isnan(brute).any()
    np.testing.assert_array_equal(fast, brute)
