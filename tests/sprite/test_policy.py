"""The GL-free LOD-sprite keyframe policy: the Eq. 2 rule against ε and the look-ahead.

No GL here: projections are the pure camera functions the terrain renderer also uses.
"""

import math

import numpy as np
import pytest

from conftest import make_field
from lodsprite.camera import Projection, Viewpoint, look_at
from lodsprite.sprite.metric import ErrorMetric
from lodsprite.sprite.policy import (
    FIRST_SPRITE,
    KEYFRAME,
    SPRITE,
    KeyframePolicy,
    keyframe_due,
    keyframe_needed,
)

PROJ = Projection(45.0, 1.0, 1.0, 20000.0)
HEIGHT = 96


@pytest.mark.parametrize(("error", "eps", "due"), [
    (0.0, 1.0, False), (0.999, 1.0, False), (1.0, 1.0, True), (3.0, 1.0, True),
    (math.inf, 1.0, True), (math.nan, 1.0, True), (0.4, 0.5, False), (0.5, 0.5, True),
])
def test_a_keyframe_is_due_iff_its_error_reaches_epsilon(error, eps, due):
    assert keyframe_due(error, eps) is due


class DistanceMetric:
    """A stand-in metric: the error (pixels) grows with the horizontal distance from the
    keyframe eye (``C'`` is just that eye), one pixel per ``metres_per_px``; ``covers`` is
    always true.  Lets the policy's logic be checked against exact numbers."""

    def __init__(self, metres_per_px: float = 50.0, error: float | None = None) -> None:
        self.metres_per_px, self.fixed = metres_per_px, error

    def reproject(self, key_eye, **_):  # key_view_proj, key_size: unused here
        return np.asarray(key_eye, dtype=np.float64).copy()

    def error_px(self, c_prime, eye, view_proj, beta):
        if self.fixed is not None:
            return self.fixed
        return float(np.hypot(*(np.asarray(eye)[:2] - c_prime[:2]))) / self.metres_per_px

    def covers(self, *_):
        return True


def level_flight(n: int, z: float = 50.0, step: float = 10.0) -> list[Viewpoint]:
    return [look_at((step * i, 0.0, z), (step * i + 100.0, 0.0, 0.0)) for i in range(n)]


def policy(metric, eps: float = 1.0, predict: bool = True) -> KeyframePolicy:
    return KeyframePolicy(metric, make_field(64, kind="flat"), eps, HEIGHT, lambda vp: PROJ,
                          predict=predict)


def test_decisions_follow_the_threshold_on_a_level_flight():
    # One pixel of error per 50 m, ε = 1 px, 10 m per frame: a keyframe every 5 frames.
    p = policy(DistanceMetric(), predict=False)
    decisions = [p.decide(vp) for vp in level_flight(16)]
    kinds = [d.type for d in decisions]
    assert kinds == [KEYFRAME, FIRST_SPRITE, SPRITE, SPRITE, SPRITE] * 3 + [KEYFRAME]
    assert [d.decision_error_px for d in decisions[1:6]] == pytest.approx([.2, .4, .6, .8, 1.])
    keyed = [d for d in decisions if d.key is not None]
    assert all(d.shows_keyframe and d.error_px == 0.0 for d in keyed)
    assert all(d.error_px == d.decision_error_px < 1.0 for d in decisions if d.key is None)


def test_an_unmeasurable_error_makes_a_keyframe_due_every_frame():
    p = policy(DistanceMetric(error=math.inf))
    decisions = [p.decide(vp) for vp in level_flight(8)]
    assert [d.type for d in decisions] == [KEYFRAME] * 8
    # No look-ahead candidate can be judged either: keyframes stay at the viewer.
    assert all(d.shows_keyframe for d in decisions)
    assert p.predicted_keyframes == 0


def test_lookahead_places_the_keyframe_ahead_within_the_margin():
    p = policy(DistanceMetric())
    decisions = [p.decide(vp) for vp in level_flight(11)]
    last = decisions[-1]
    assert last.type == KEYFRAME and last.key.predicted and not last.shows_keyframe
    # The third keyframe is the first with an interval to extrapolate: 5 frames ahead
    # errs 1.0 px here (over 0.9 ε), so the look-ahead is rescaled to 3.75 frames.
    np.testing.assert_allclose(last.key.viewpoint.o, [100.0 + 37.5, 0.0, 50.0], atol=1e-9)
    assert last.error_px == pytest.approx(0.75)
    # The frames after it are served by the keyframe ahead: the error first falls.
    after = [p.decide(vp) for vp in level_flight(15)[11:]]
    assert after[0].error_px < last.error_px


def test_a_lookahead_candidate_under_the_ground_is_rejected():
    eps_flight = level_flight(10)
    level, dive = policy(DistanceMetric()), policy(DistanceMetric())
    for vp in eps_flight:
        level.decide(vp)
        dive.decide(vp)
    # Frame 10, where a keyframe is due: flying on level, or dropping 45 m in one frame to
    # 5 m above the ground.  Horizontally both are the same, and so is every error of the
    # stand-in metric; only the diving extrapolation leads under the ground.
    on = level.decide(look_at((100.0, 0.0, 50.0), (200.0, 0.0, 0.0)))
    down = dive.decide(look_at((100.0, 0.0, 5.0), (200.0, 0.0, 0.0)))
    assert on.type == down.type == KEYFRAME
    assert on.key.predicted
    assert not down.key.predicted and down.shows_keyframe
    np.testing.assert_allclose(down.key.viewpoint.o, [100.0, 0.0, 5.0])


def test_keyframe_needed_skips_missing_keyframes_and_takes_any_that_serves():
    m = DistanceMetric()
    vp = look_at((100.0, 0.0, 50.0), (200.0, 0.0, 0.0))
    near, far = m.reproject([80.0, 0.0, 50.0]), m.reproject([0.0, 0.0, 50.0])  # 0.4, 2 px
    assert keyframe_needed(m, [], vp, PROJ, HEIGHT, 1.0)
    assert keyframe_needed(m, [None, far], vp, PROJ, HEIGHT, 1.0)
    assert not keyframe_needed(m, [far, None, near], vp, PROJ, HEIGHT, 1.0)
    assert keyframe_needed(m, [near], vp, PROJ, HEIGHT, 0.4)  # at the limit: due


def test_the_real_metric_drives_the_decision_on_a_terrain():
    """With the 1999 metric on a ridged field: along a sideways move the policy renders a
    keyframe exactly where the error of the previous one, computed independently, reaches ε."""
    hf = make_field(64, kind="ridges", relief=150.0)
    p = KeyframePolicy.for_terrain(hf, 8, 0.5, (512, 512), predict=False)
    path = [look_at((dx, -1500.0, 1200.0), (dx, 0.0, 0.0)) for dx in np.linspace(0, 900, 40)]
    metric = ErrorMetric.for_level(hf, 8)
    key, kinds = None, []
    for vp in path:
        d = p.decide(vp)
        kinds.append(d.type)
        proj = p.projection(vp)
        if key is None:
            assert d.type == KEYFRAME
        else:
            view_proj = proj.matrix() @ vp.view_matrix()
            err = metric.error_px(metric.reproject(key.o), vp.o, view_proj,
                                  math.radians(proj.fov_y_deg) / 512)
            assert d.decision_error_px == pytest.approx(err)
            assert (d.type == KEYFRAME) is (err >= 0.5)
        if d.type == KEYFRAME:
            key = d.key.viewpoint
    assert 2 < kinds.count(KEYFRAME) < len(path) // 2  # the rule fired, and not always
