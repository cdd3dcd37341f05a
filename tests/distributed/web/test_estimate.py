"""The page's error estimate and request logic (``lodsprite.distributed.web.estimate``,
the Python side of ``static/predictor.js``; ``test_browser.py`` checks the two agree):
``C'`` on the coarse mesh, against an analytic plane and against lodsprite's own metric,
and the predictor's requests."""

from types import SimpleNamespace

import numpy as np
import pytest

from lodsprite.camera import Viewpoint, look_at
from lodsprite.distributed.protocol import LoadArgs
from lodsprite.distributed.web.estimate import ErrorMetric, Predictor
from lodsprite.distributed.web.scene import build_scene_field, decode_scene


def plane_scene(n=8, spacing=100.0, slope=(0.3, 0.1), base=500.0, relief=20.0):
    """A scene whose coarse level is the plane ``z = base + sx x + sy y``."""
    origin = (0.0, 0.0)
    j, i = np.meshgrid(np.arange(n + 1), np.arange(n + 1))
    heights = base + slope[0] * j * spacing + slope[1] * i * spacing
    header = SimpleNamespace(coarse=n, origin=origin, spacing=spacing, spacing_y=spacing,
                             relief=relief, size=(128, 128), fov=45.0, near=1.0,
                             far=1e5, epsilon=1.0)
    return SimpleNamespace(header=header, heights=heights.astype(np.float32))


def expected_error(scene, key_eye, vp: Viewpoint, view_proj, beta) -> float:
    """Eq. 2 with ``C'`` where the ray from ``key_eye`` through each raised centre meets
    the plane, computed here in closed form."""
    h = scene.header
    n, s = h.coarse, h.spacing
    sx = (scene.heights[0, 1] - scene.heights[0, 0]) / s
    sy = (scene.heights[1, 0] - scene.heights[0, 0]) / s
    z0 = float(scene.heights[0, 0])
    jj, ii = np.meshgrid(np.arange(n) + 0.5, np.arange(n) + 0.5)
    c = np.stack([jj * s, ii * s, z0 + sx * jj * s + sy * ii * s + h.relief], -1).reshape(-1, 3)
    d = c - key_eye
    t = (z0 + sx * key_eye[0] + sy * key_eye[1] - key_eye[2]) / (d[:, 2] - sx * d[:, 0]
                                                                  - sy * d[:, 1])
    cp = key_eye + d * t[:, None]
    assert ((cp[:, :2] > 0) & (cp[:, :2] < n * s)).all()  # every C' on the terrain
    k = np.c_[c, np.ones(len(c))] @ view_proj.T
    inside = (k[:, 3] > 0) & (np.abs(k[:, :3]) <= k[:, 3:]).all(1)
    a = c[inside] - vp.o
    b = cp[inside] - vp.o
    cos = (a * b).sum(1) / np.linalg.norm(a, axis=1) / np.linalg.norm(b, axis=1)
    theta = np.arccos(np.clip(cos, -1.0, 1.0))
    return float(np.sqrt(np.mean(theta**2)) / beta)


def test_c_prime_is_where_the_ray_meets_a_sloping_coarse_surface():
    """On a sloping plane the estimate is Eq. 2 with ``C'`` on the plane itself (the
    page's first estimate met a horizontal plane through each square's centre instead,
    which a slope puts elsewhere)."""
    scene = plane_scene()
    metric, pred = ErrorMetric(scene), Predictor(scene)
    key = np.array([400.0, -500.0, 1500.0])
    rep = metric.reproject(key)
    assert not rep.missed.any()
    sx, sy = 0.3, 0.1
    z = 500.0 + sx * rep.c_prime[:, 0] + sy * rep.c_prime[:, 1]
    np.testing.assert_allclose(rep.c_prime[:, 2], z, atol=1e-6)  # on the plane
    vp = look_at((440.0, -470.0, 1480.0), (400.0, 400.0, 700.0))
    vpm = pred.proj @ vp.view_matrix()
    want = expected_error(scene, key, vp, vpm, pred.beta)
    assert want > 0.1  # a measurable parallax
    assert pred.error_px(metric, key, vp) == pytest.approx(want, rel=1e-6)


def test_the_estimate_is_zero_at_the_keyframe_eye_and_inf_without_a_keyframe():
    scene = plane_scene()
    metric, pred = ErrorMetric(scene), Predictor(scene)
    vp = look_at((400.0, -500.0, 1500.0), (400.0, 400.0, 700.0))
    assert pred.error_px(metric, vp.o, vp) == pytest.approx(0.0, abs=1e-9)
    assert pred.error_px(metric, None, vp) == float("inf")
    away = look_at((400.0, -500.0, 1500.0), (400.0, -9000.0, 1500.0))  # facing away
    assert pred.error_px(metric, vp.o, away) == float("inf")


@pytest.fixture(scope="module")
def fractal():
    args = LoadArgs(terrain="fractal:128:1", size=(128, 128), lod=16)
    parts, hf = build_scene_field(args)
    return decode_scene(parts), hf


@pytest.mark.parametrize("spec", ["chen1999", "swan2002"])
def test_the_estimate_follows_lodsprites_metric(fractal, spec):
    """A keyframe one frame old: the page's estimate is within 2x of lodsprite's exact
    metric (full-resolution centres, ``C'`` cast on the coarse level), over a path.  The
    first estimate (a horizontal plane) judged these 3.7x (swan2002) and 16x (chen1999)
    worse than they are."""
    from lodsprite.paths import get_path
    from lodsprite.sprite.metric import ErrorMetric as Exact

    scene, hf = fractal
    metric, pred = ErrorMetric(scene), Predictor(scene)
    exact = Exact.for_level(hf, scene.header.coarse)
    path = list(get_path(spec, hf, 60).viewpoints)
    est, ref = [], []
    for k in range(0, 59, 2):
        key, vp = path[k].o, path[k + 1]
        vpm = pred.proj @ vp.view_matrix()
        ref.append(exact.error_px(exact.reproject(key), vp.o, vpm, pred.beta))
        est.append(pred.error_px(metric, key, vp))
    est, ref = np.array(est), np.array(ref)
    both = np.isfinite(est) & np.isfinite(ref)
    assert both.sum() >= 20
    ratio = est[both].mean() / ref[both].mean()
    assert 0.5 <= ratio <= 2.0, ratio


def test_c_prime_is_cast_once_per_keyframe_eye(fractal):
    scene, _ = fractal
    metric = ErrorMetric(scene)
    a = metric.reproject(np.array([0.0, -3000.0, 2500.0]))
    assert metric.reproject(np.array([0.0, -3000.0, 2500.0])) is a
    assert metric.reproject(np.array([0.0, -2900.0, 2500.0])) is not a


def test_the_predictor_asks_one_latency_ahead_and_never_with_a_request_in_flight():
    scene = plane_scene(relief=40.0)
    metric, pred = ErrorMetric(scene), Predictor(scene)
    key = look_at((400.0, -500.0, 1500.0), (400.0, 400.0, 700.0))
    pred.sample(0.0, key)
    assert pred.want(metric, key.o, 0.0) is None  # at the keyframe's eye: nothing to ask
    step = np.array([30.0, 0.0, 0.0])  # 30 m in 1/30 s: the viewer moves sideways
    vp = Viewpoint(key.x, key.y, key.z, key.o + step)
    pred.sample(1 / 30, vp)
    ahead = pred.want(metric, key.o, 1 / 30)
    assert ahead is not None  # the error there reaches epsilon/2
    lead = pred.lead()
    assert lead == pytest.approx(0.1)  # the starting latency
    np.testing.assert_allclose(ahead.o, vp.o + step * lead * 30, atol=1e-9)
    pred.sent(1 / 30)
    assert pred.want(metric, key.o, 2 / 30) is None  # one in flight
    pred.arrived(1 / 30, 1 / 30 + 0.5)
    assert not pred.inflight and pred.latency == pytest.approx(0.1 + 0.3 * (0.5 - 0.1))
    pred.sent(1.0)
    assert pred.want(metric, key.o, 6.5) is not None  # given up after 5 s unanswered


def test_with_two_jobs_the_predictor_staggers_its_requests_over_the_latency():
    """Two renders a session in flight: a second request goes out while one is in flight,
    but no sooner than half the latency after it, and never a third; a keyframe that came
    after a newer one frees its place without counting its latency."""
    scene = plane_scene(relief=40.0)
    metric, pred = ErrorMetric(scene), Predictor(scene, jobs=2)
    key = look_at((400.0, -500.0, 1500.0), (400.0, 400.0, 700.0))
    step = np.array([30.0, 0.0, 0.0])
    pred.latency = 0.4

    def at(t: float) -> Viewpoint:
        pred.sample(t, Viewpoint(key.x, key.y, key.z, key.o + step * 30 * t))
        return pred.want(metric, key.o, t)

    at(0.0)
    assert at(1 / 30) is not None  # the error ahead reaches epsilon / 2
    pred.sent(1 / 30)
    assert at(2 / 30) is None  # within latency / 2 of the last request
    assert at(1 / 30 + 0.21) is not None  # past it: a second in flight
    pred.sent(1 / 30 + 0.21)
    assert at(1 / 30 + 0.5) is None  # two in flight: no third
    pred.dropped(1 / 30)  # the first came after the second's keyframe
    assert pred.inflight == [1 / 30 + 0.21] and pred.latency == 0.4
    assert at(1 / 30 + 0.5) is not None


def ridge_scene():
    """A flat coarse level at 500 m with a 400 m ridge along row 6 (y = 600 m)."""
    scene = plane_scene(n=16, slope=(0.0, 0.0))
    scene.header.visibility = "coarse"
    scene.heights[6] += 400.0
    return scene


def test_squares_the_keyframe_did_not_see_count_once_the_view_shows_them():
    """Behind the ridge, seen from a low keyframe eye, the coarse level hides the squares'
    fragments: at that eye they count nothing (the view does not show them either); from
    higher up the view shows them drawn from the fallback, and each counts at least the
    worst hit, as a miss does (the first estimate counted their parallax as hits)."""
    scene = ridge_scene()
    metric, pred = ErrorMetric(scene), Predictor(scene)
    key = look_at((800.0, -300.0, 700.0), (800.0, 1200.0, 500.0))
    rep = metric.reproject(key.o)
    rows = metric.square[:, 0]
    assert not rep.hidden[rows <= 4].any()  # before the ridge: seen
    assert rep.hidden[rows >= 8].sum() >= 0.5 * (rows >= 8).sum()  # behind it: mostly not
    assert pred.error_px(metric, key.o, key) == pytest.approx(0.0, abs=1e-9)
    up = look_at((800.0, -300.0, 1600.0), (800.0, 1200.0, 500.0))
    vpm = pred.proj @ up.view_matrix()
    err = pred.error_px(metric, key.o, up)
    shown = rep.hidden & ~metric._hidden(up.o) & _inside(metric.fragments, vpm)
    assert shown.sum() >= 10  # the rise shows squares the keyframe did not see
    hit = _inside(metric.centres, vpm) & ~rep.hidden & ~rep.missed
    worst = max(_theta(up.o, metric.centres[hit], rep.c_prime[hit]))
    assert err * pred.beta >= worst * np.sqrt(shown.sum() / (hit.sum() + shown.sum())) - 1e-12


def test_turning_in_place_counts_the_squares_outside_the_keyframe():
    """A view turned from its keyframe at the same eye has no parallax, but its edge
    shows squares outside the keyframe's frustum (the fallback): given the keyframe's
    view-projection the estimate counts them, and the predictor asks for a keyframe."""
    scene = ridge_scene()
    metric, pred = ErrorMetric(scene), Predictor(scene)
    key = look_at((800.0, -300.0, 1500.0), (300.0, 1200.0, 500.0))
    key_vp = pred.proj @ key.view_matrix()
    assert pred.error_px(metric, key.o, key, key_vp) == pytest.approx(0.0, abs=1e-9)
    turned = look_at((800.0, -300.0, 1500.0), (1300.0, 1200.0, 500.0))
    assert pred.error_px(metric, key.o, turned) == pytest.approx(0.0, abs=1e-9)
    assert pred.error_px(metric, key.o, turned, key_vp) > 0.5 * pred.epsilon
    pred.sample(0.0, turned)
    assert pred.want(metric, key.o, 0.0) is None
    assert pred.want(metric, key.o, 0.0, key_vp) is not None


def _inside(p, m):
    k = np.c_[p, np.ones(len(p))] @ m.T
    return (k[:, 3] > 0) & (np.abs(k[:, :3]) <= k[:, 3:]).all(1)


def _theta(eye, p, q):
    a, b = p - eye, q - eye
    cos = (a * b).sum(1) / np.linalg.norm(a, axis=1) / np.linalg.norm(b, axis=1)
    return np.arccos(np.clip(cos, -1.0, 1.0))
