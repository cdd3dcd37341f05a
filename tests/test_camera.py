import math

import numpy as np
import pytest

from lodsprite.camera import (
    Projection,
    Viewpoint,
    boxes_in_frustum,
    fit_near_far,
    frustum_planes,
    look_at,
    perspective,
    project_points,
    widened,
)
from lodsprite.errors import InputError


def test_look_at_axes_are_orthonormal_right_handed():
    vp = look_at((100.0, -200.0, 300.0), (0.0, 0.0, 0.0))
    axes = np.stack([vp.x, vp.y, vp.z])
    np.testing.assert_allclose(axes @ axes.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(axes) == pytest.approx(1.0)
    # The camera looks along -z, towards the target.
    np.testing.assert_allclose(vp.forward, -np.array([100, -200, 300]) / math.sqrt(140000))
    assert vp.y[2] > 0  # screen-up has a positive world-up component


def test_view_matrix_maps_eye_to_origin_and_target_to_minus_z():
    vp = look_at((10.0, 20.0, 30.0), (10.0, 20.0 + 5.0, 30.0))
    v = vp.view_matrix()
    np.testing.assert_allclose(v @ [10, 20, 30, 1], [0, 0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(v @ [10, 25, 30, 1], [0, 0, -5, 1], atol=1e-12)


def test_perspective_maps_near_and_far_to_ndc_limits():
    p = perspective(45.0, 2.0, 1.0, 100.0)
    for z, ndc in ((-1.0, -1.0), (-100.0, 1.0)):
        clip = p @ [0, 0, z, 1]
        assert clip[2] / clip[3] == pytest.approx(ndc)
    # A point on the top edge of the frustum at depth d maps to ndc y = 1.
    d = 10.0
    clip = p @ [0, d * math.tan(math.radians(22.5)), -d, 1]
    assert clip[1] / clip[3] == pytest.approx(1.0)
    clip = p @ [2 * d * math.tan(math.radians(22.5)), 0, -d, 1]
    assert clip[0] / clip[3] == pytest.approx(1.0)


def test_bad_projection_raises_typed_error():
    with pytest.raises(InputError):
        perspective(0.0, 1.0, 1.0, 2.0)
    with pytest.raises(InputError):
        perspective(45.0, 1.0, 2.0, 1.0)
    with pytest.raises(InputError):
        Viewpoint(np.array([1, 0, 0]), np.array([1, 0, 0]), np.array([0, 0, 1]), np.zeros(3))
    with pytest.raises(InputError):
        look_at((0, 0, 10), (0, 0, 0), up=(0, 0, 1))


def test_pixel_angle_is_fov_over_height():
    assert Projection(45.0, 1.0, 1, 2).pixel_angle_rad(512) == pytest.approx(math.pi / 4 / 512)


def test_project_points_centre_and_corners():
    vp = look_at((0.0, 0.0, 100.0), (0.0, 0.0, 0.0), up=(0, 1, 0))
    p = Projection(90.0, 1.0, 1.0, 1000.0)
    vpm = p.matrix() @ vp.view_matrix()
    px, _, w = project_points(np.array([[0, 0, 0], [100, 100, 0], [-100, -100, 0]]), vpm, 200, 200)
    np.testing.assert_allclose(px, [[100, 100], [200, 0], [0, 200]], atol=1e-9)
    assert np.all(w > 0)


def test_frustum_culling_keeps_visible_boxes_and_drops_hidden_ones():
    vp = look_at((0.0, -100.0, 0.0), (0.0, 0.0, 0.0))
    p = Projection(60.0, 1.0, 1.0, 500.0)
    planes = frustum_planes(p.matrix() @ vp.view_matrix())
    mins = np.array([[-1, -1, -1], [-1, -300, -1], [1000, 0, 0], [-1, 390, -1], [-1, 600, -1]])
    maxs = mins + 2
    assert boxes_in_frustum(planes, mins, maxs).tolist() == [True, False, False, True, False]


def test_fit_near_far_encloses_box():
    lo, hi = np.array([-50.0, -50, 0]), np.array([50.0, 50, 10])
    vp = look_at((0.0, -200.0, 50.0), (0.0, 0.0, 0.0))
    near, far = fit_near_far(vp, lo, hi)
    corners = np.array([[x, y, z] for x in (-50, 50) for y in (-50, 50) for z in (0, 10)])
    depth = (corners - vp.o) @ vp.forward
    assert near <= depth.min() and far >= depth.max()
    # Inside the box: near comes from the clearance.
    vp2 = look_at((0.0, 0.0, 5.0), (0.0, 40.0, 0.0))
    near2, far2 = fit_near_far(vp2, lo, hi, clearance=5.0)
    assert near2 == pytest.approx(2.5) and far2 > near2


def test_viewpoint_dict_round_trip():
    vp = look_at((1.0, 2.0, 3.0), (4.0, 5.0, 1.0))
    vp2 = Viewpoint.from_dict(vp.to_dict())
    for k in "xyzo":
        np.testing.assert_array_equal(getattr(vp, k), getattr(vp2, k))
    with pytest.raises(InputError):
        Viewpoint.from_dict({"x": [1, 0, 0]})


@pytest.mark.parametrize(("w", "h", "m"), [(512, 512, 32), (640, 360, 16), (64, 128, 0)])
def test_widened_projection_puts_the_image_at_an_offset_pixel_for_pixel(w, h, m):
    vp = look_at((30.0, -400.0, 250.0), (0.0, 0.0, 0.0))
    p = Projection(45.0, w / h, 1.0, 5000.0)
    q = widened(p, w, h, m)
    rng = np.random.default_rng(1)
    pts = rng.uniform(-300, 300, (50, 3))
    a, za, _ = project_points(pts, p.matrix() @ vp.view_matrix(), w, h)
    b, zb, _ = project_points(pts, q.matrix() @ vp.view_matrix(), w + 2 * m, h + 2 * m)
    np.testing.assert_allclose(b, a + m, atol=1e-6)
    np.testing.assert_allclose(zb, za, atol=1e-12)  # same near/far: same depths
    assert q.pixel_angle_rad(h + 2 * m) == pytest.approx(p.pixel_angle_rad(h), rel=0.02)


def test_widened_projection_refuses_a_negative_guard_band():
    with pytest.raises(InputError):
        widened(Projection(45.0, 1.0, 1.0, 10.0), 64, 64, -1)
