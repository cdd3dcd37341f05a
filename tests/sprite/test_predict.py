"""Viewpoint extrapolation for keyframes rendered ahead of the viewer."""

import numpy as np
from scipy.spatial.transform import Rotation

from lodsprite.camera import Viewpoint, look_at, rotated_viewpoint, view_rotation
from lodsprite.sprite.predict import extrapolate


def rotated(vp: Viewpoint, rotvec) -> Viewpoint:
    r = Rotation.from_rotvec(rotvec)
    axes = r.apply(np.stack([vp.x, vp.y, vp.z]))
    return Viewpoint(axes[0], axes[1], axes[2], vp.o)


def test_straight_constant_speed_motion_is_extrapolated_exactly():
    a = look_at((0.0, -1000.0, 500.0), (0.0, 0.0, 0.0))
    step = np.array([12.0, 3.0, -1.5])
    b = Viewpoint(a.x, a.y, a.z, a.o + step)
    c = extrapolate(a, b, 7.0)
    np.testing.assert_allclose(c.o, b.o + 7.0 * step, atol=1e-9)
    for k in "xyz":
        np.testing.assert_allclose(getattr(c, k), getattr(b, k), atol=1e-12)


def test_constant_turn_rate_is_continued():
    a = look_at((0.0, -1000.0, 500.0), (0.0, 0.0, 0.0))
    turn = np.array([0.0, 0.0, np.radians(2.0)])  # 2 degrees per frame about world z
    b = rotated(a, turn)
    c = extrapolate(a, b, 5.0)
    expect = rotated(a, 6.0 * turn)
    for k in "xyz":
        np.testing.assert_allclose(getattr(c, k), getattr(expect, k), atol=1e-9)


def test_zero_steps_returns_the_current_viewpoint():
    a = look_at((10.0, -1000.0, 500.0), (0.0, 0.0, 0.0))
    b = look_at((20.0, -990.0, 505.0), (0.0, 0.0, 0.0))
    c = extrapolate(a, b, 0.0)
    for k in "xyzo":
        np.testing.assert_allclose(getattr(c, k), getattr(b, k), atol=1e-12)


def test_the_one_rotation_helper_maps_eye_space_to_world_space_and_back():
    vp = look_at((300.0, -1000.0, 500.0), (0.0, 50.0, 0.0))
    r = view_rotation(vp)
    # The camera looks along eye-space -z: in world space, towards the target.
    np.testing.assert_allclose(r.apply([0.0, 0.0, -1.0]), vp.forward, atol=1e-12)
    np.testing.assert_allclose(r.apply([1.0, 0.0, 0.0]), vp.x, atol=1e-12)
    back = rotated_viewpoint(r, vp.o)
    for k in "xyzo":
        np.testing.assert_allclose(getattr(back, k), getattr(vp, k), atol=1e-12)
