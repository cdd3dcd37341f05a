"""The resampling term of the error metric (lodsprite.sprite.resampling) and the metric that
adds it (ErrorMetric(resampling=True), KeyframePolicy with metric="resample")."""

import math

import numpy as np
import pytest

from conftest import make_field
from lodsprite.camera import Projection, look_at, widened
from lodsprite.errors import InputError
from lodsprite.sprite.metric import ErrorMetric
from lodsprite.sprite.policy import KEYFRAME, KeyframePolicy, keyframe_error_px
from lodsprite.sprite.raycast import coarse_normals
from lodsprite.sprite.resampling import (
    resampling_px,
    singular_values,
    texel_jacobian,
)

PROJ = Projection(45.0, 4 / 3, 1.0, 50000.0)
SIZE = (128, 96)
UP = np.array([[0.0, 0.0, 1.0]])


def view_proj(eye, target, proj=PROJ, up=(0.0, 1.0, 0.0)):
    return proj.matrix() @ look_at(eye, target, up).view_matrix()


def test_zero_at_the_keyframe_viewpoint_with_its_guard_band():
    rng = np.random.default_rng(1)
    pts = rng.uniform(-300, 300, (200, 3)) * [1, 1, 0.2]
    normals = rng.normal(size=(200, 3)) + [0, 0, 3]
    eye, target = (40.0, -700.0, 600.0), (0.0, 0.0, 0.0)
    cur = view_proj(eye, target, up=(0, 0, 1))
    guard = 16
    key = widened(PROJ, *SIZE, guard).matrix() @ look_at(eye, target).view_matrix()
    e = resampling_px(pts, normals, key, (SIZE[0] + 2 * guard, SIZE[1] + 2 * guard),
                      cur, SIZE)
    assert np.abs(e).max() < 1e-9
    # Without the guard band's wider image the same matrix is a 1/(1 + 2g/h) zoom: not 0.
    e_small = resampling_px(pts, normals, key, SIZE, cur, SIZE)
    assert e_small.min() > 0.1


@pytest.mark.parametrize("d_key", [200.0, 1000.0])
def test_zoom_along_the_view_axis_scales_both_singular_values(d_key):
    # A plane seen face-on at its principal point: texels per pixel = d / d_key exactly.
    p = np.zeros((1, 3))
    key = view_proj((0, 0, d_key), (0, 0, 0))
    ds = d_key * np.array([0.25, 0.5, 0.8, 1.0, 1.25, 2.0, 4.0, 8.0])
    e, s = [], []
    for d in ds:
        cur = view_proj((0, 0, d), (0, 0, 0))
        j, ok = texel_jacobian(p, UP, key, SIZE, cur, SIZE)
        s.append(np.r_[singular_values(j)])
        e.append(resampling_px(p, UP, key, SIZE, cur, SIZE)[0])
        assert ok.all()
    s, e = np.array(s), np.array(e)
    np.testing.assert_allclose(s[:, 0], ds / d_key, rtol=1e-9)
    np.testing.assert_allclose(s[:, 1], ds / d_key, rtol=1e-9)
    zoom_out = ds >= d_key
    # minification: alias = 1 - d_key / d, growing; magnification: blur = d_key / d - 1
    np.testing.assert_allclose(e[zoom_out], 1 - d_key / ds[zoom_out], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(e[~zoom_out], d_key / ds[~zoom_out] - 1, rtol=1e-9)
    assert np.all(np.diff(e[zoom_out]) > 0) and np.all(np.diff(e[~zoom_out]) < 0)


@pytest.mark.parametrize("ratio", [1.0, 1.5])
def test_grazing_angle_matches_the_analytic_footprint(ratio):
    # Keyframe face-on at d_key; now at distance d = ratio d_key, at angle phi from the
    # normal: along the tilt one pixel covers d beta / cos(phi) metres, so s1 =
    # ratio / cos(phi) and s2 = ratio (tolerance 1e-9 relative: the derivation is exact
    # on the principal ray).
    d_key = 500.0
    p = np.zeros((1, 3))
    key = view_proj((0, 0, d_key), (0, 0, 0))
    phis = np.radians([0, 10, 30, 50, 70, 80, 85])
    s1, s2, e = [], [], []
    for phi in phis:
        d = ratio * d_key
        eye = (0.0, -d * math.sin(phi), d * math.cos(phi))
        cur = view_proj(eye, (0, 0, 0), up=(0, 0, 1) if phi > 0 else (0, 1, 0))
        a, b = singular_values(texel_jacobian(p, UP, key, SIZE, cur, SIZE)[0])
        s1.append(a[0])
        s2.append(b[0])
        e.append(resampling_px(p, UP, key, SIZE, cur, SIZE)[0])
    np.testing.assert_allclose(s1, ratio / np.cos(phis), rtol=1e-9)
    np.testing.assert_allclose(s2, np.full(len(phis), ratio), rtol=1e-9)
    np.testing.assert_allclose(e, 1 - np.cos(phis) / ratio, rtol=1e-9, atol=1e-12)
    assert np.all(np.diff(e) > 0)


def test_a_keyframe_that_saw_the_plane_edge_on_blurs_without_bound():
    p = np.zeros((1, 3))
    cur = view_proj((0, 0, 500.0), (0, 0, 0))
    e = [resampling_px(p, UP, view_proj((0, -500 * math.sin(a), 500 * math.cos(a)),
                                        (0, 0, 0), up=(0, 0, 1)), SIZE, cur, SIZE)[0]
         for a in np.radians([30, 60, 80, 88])]
    # blur = 1/s2 - 1 = 1/cos(a) - 1 (key face-on at cos a): no 1 px cap as aliasing has
    np.testing.assert_allclose(e, 1 / np.cos(np.radians([30, 60, 80, 88])) - 1, rtol=1e-9)


def test_coarse_normals_are_the_triangle_under_the_point():
    hf = make_field(32, kind="ridges")
    m = ErrorMetric.for_level(hf, 8)
    own = m.squares.own.reshape(-1, 3, 3)  # every coarse triangle
    centroids = own.mean(axis=1)
    n = np.cross(own[:, 1] - own[:, 0], own[:, 2] - own[:, 0])
    n = n * np.sign(n[:, 2:3]) / np.linalg.norm(n, axis=1, keepdims=True)
    np.testing.assert_allclose(coarse_normals(m.squares, centroids), n, atol=1e-12)


def terrain_case(resampling: bool):
    hf = make_field(64, kind="bump")
    metric = ErrorMetric.for_level(hf, 8, resampling)
    key_vp = look_at((0.0, -1500.0, 1200.0), (0.0, 0.0, 0.0))
    key_vp_proj = PROJ.matrix() @ key_vp.view_matrix()
    return metric, key_vp, metric.reproject(key_vp.o, key_vp_proj, SIZE)


def test_the_combined_metric_is_the_warp_metric_when_resampling_is_off():
    warp, key_vp, cp = terrain_case(False)
    res = ErrorMetric(warp.squares, resampling=True)
    plain = ErrorMetric.for_level(warp.squares.hf, 8).reproject(key_vp.o)
    assert res.error_px(cp, key_vp.o, PROJ.matrix() @ key_vp.view_matrix(),
                        PROJ.pixel_angle_rad(SIZE[1]), size=SIZE) < 1e-9
    for eye in [(100.0, -1500.0, 1200.0), (0.0, -2400.0, 1500.0), (300.0, -900.0, 500.0)]:
        vp = look_at(eye, (0.0, 0.0, 0.0))
        w = keyframe_error_px(warp, cp, vp, PROJ, SIZE[1])
        assert w == keyframe_error_px(warp, plain, vp, PROJ, SIZE[1])  # bit for bit
        r = keyframe_error_px(res, cp, vp, PROJ, SIZE[1])
        assert r > w > 0  # the term only adds
    with pytest.raises(ValueError, match="key_view_proj"):
        keyframe_error_px(res, plain, vp, PROJ, SIZE[1])


def zoom_out(n: int = 40):
    return [look_at((0.0, -800.0 - 40.0 * i, 600.0 + 30.0 * i), (0.0, 0.0, 0.0))
            for i in range(n)]


def first_new_keyframe(metric: str, eps: float) -> int:
    hf = make_field(64, kind="bump")
    p = KeyframePolicy.for_terrain(hf, 8, eps, SIZE, guard_px=8, predict=False, metric=metric)
    kinds = [p.decide(vp).type for vp in zoom_out()]
    return next((i for i, k in enumerate(kinds) if k == KEYFRAME and i > 0), len(kinds))


def test_the_resample_policy_keys_earlier_on_a_zoom_out():
    warp, res = first_new_keyframe("warp", 0.5), first_new_keyframe("resample", 0.5)
    assert res < warp
    assert res < 20  # the minification of the zoom-out itself is seen


def test_an_unknown_metric_is_refused():
    with pytest.raises(InputError, match="metric"):
        KeyframePolicy.for_terrain(make_field(16), 4, 1.0, SIZE, metric="sampling")


def test_the_metric_option_reaches_the_sprite_techniques_and_is_checked():
    from lodsprite.run import RenderConfig
    from lodsprite.techniques import registry

    for name in ("sprite", "sprite-adaptive"):
        opts = {o.name: o for o in registry.get(name).options}
        assert opts["metric"].default is None  # the terrain's: warp in memory
    assert RenderConfig(terrain="fractal:64", mode="sprite").technique_options()["metric"] \
        == "warp"
    assert RenderConfig(mode="sprite", metric="resample").technique_options()["metric"] == \
        "resample"
    with pytest.raises(InputError, match="metric"):
        RenderConfig(mode="sprite", metric="sampling").validate()


def test_a_reprojection_pickles_with_its_keyframe_matrix_and_size():
    import pickle

    _, key_vp, cp = terrain_case(True)
    back = pickle.loads(pickle.dumps(cp))
    np.testing.assert_array_equal(back.key_view_proj, cp.key_view_proj)
    assert back.key_size == SIZE and np.array_equal(back.missed, cp.missed)
    assert cp[:5].key_size == SIZE  # views keep them


def test_the_distributed_mode_refuses_the_resample_metric():
    from lodsprite.cli.render import _check_mode

    assert _check_mode("distributed", False, None, "warp")
    with pytest.raises(InputError, match="--metric resample"):
        _check_mode("distributed", False, None, "resample")
    assert not _check_mode("sprite", False, None, "resample")
