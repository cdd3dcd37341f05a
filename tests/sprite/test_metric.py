"""The angular error metric (Chen et al. 1999 Eq. 1-2) against hand-computed geometry."""

import math

import numpy as np
import pytest

from lodsprite.camera import Projection, look_at
from lodsprite.sprite.metric import (
    ErrorMetric,
    angles_at_eye,
    coarse_squares,
    ray_triangle_t,
    reprojected_centres,
)
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


def test_squares_outside_the_view_are_ignored():
    hf = spiked_field()
    metric = ErrorMetric.for_level(hf, 4)
    proj = Projection(45.0, 1.0, 1.0, 2000.0)
    away = look_at((0.0, 0.0, 100.0), (0.0, 1000.0, 100.0))  # looking at the horizon, no terrain
    cp = metric.reproject(np.array([0.0, -300.0, 250.0]))
    assert metric.theta(cp, away.o, proj.matrix() @ away.view_matrix()).size == 0
    assert metric.error_px(cp, away.o, proj.matrix() @ away.view_matrix(), 0.001) == 0.0


def test_ray_triangle_hits_and_misses():
    tri = np.array([[[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]])[None]  # (1, 1, 3, 3)
    origin = np.array([0.2, 0.2, 1.0])
    t = ray_triangle_t(origin, np.array([[0.0, 0.0, -1.0]]), tri)
    assert t[0, 0] == pytest.approx(1.0)
    t = ray_triangle_t(origin, np.array([[1.0, 1.0, -0.1]]), tri)
    assert np.isnan(t[0, 0])


def test_ray_missing_the_coarse_surface_is_left_out():
    hf = spiked_field()
    metric = ErrorMetric.for_level(hf, 4)
    # Grazing keyframe: rays through the far spikes leave the terrain before reaching z = 0.
    key = np.array([0.0, -400.0, 250.0])
    cp = metric.reproject(key)
    assert np.isnan(cp).any() and np.isfinite(cp).any()
    proj = Projection(45.0, 1.0, 1.0, 2000.0)
    vp = look_at((10.0, -400.0, 250.0), (0.0, 0.0, 0.0))
    e = metric.error_px(cp, vp.o, proj.matrix() @ vp.view_matrix(), proj.pixel_angle_rad(512))
    assert np.isfinite(e) and e > 0
