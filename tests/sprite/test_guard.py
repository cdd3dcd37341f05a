"""The worker keyframe's guard band sized to the predictor's measured error
(sprite/guard.py): the miss against analytic turns, and the band it asks for."""

import math

import numpy as np
import pytest

from lodsprite.camera import Viewpoint, look_at, turned
from lodsprite.sprite.guard import MAX_SPREAD, GuardBand, overshoot_px

FOV, W, H = 45.0, 320, 240
F = (H / 2) / math.tan(math.radians(FOV) / 2)  # focal length, pixels
VP = look_at((0.0, -1000.0, 300.0), (0.0, 0.0, 0.0))


def rolled(vp: Viewpoint, angle: float) -> Viewpoint:
    c, s = math.cos(angle), math.sin(angle)
    return Viewpoint(c * vp.x + s * vp.y, -s * vp.x + c * vp.y, vp.z, vp.o)


def test_the_same_view_misses_nothing():
    assert overshoot_px(VP, VP, FOV, (W, H)) == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize("px", [3.0, 12.0, 40.0])
def test_a_yaw_misses_by_the_shift_of_the_frame_edge(px):
    # turned so that the centre moves px: the far edge's corners land at f tan(θe + a),
    # rows at (h/2) / (cos a - tan θe sin a)
    a = math.atan(px / F)
    te = (W / 2) / F
    u = F * math.tan(math.atan(te) + a) - W / 2
    v = (H / 2) / (math.cos(a) - te * math.sin(a)) - H / 2
    shown = turned(VP, px, H, FOV)
    assert overshoot_px(shown, VP, FOV, (W, H)) == pytest.approx(max(u, v), rel=1e-6)
    assert max(u, v) > px  # the edge moves further than the centre


@pytest.mark.parametrize("deg", [1.0, 5.0])
def test_a_roll_misses_by_the_corners_turn(deg):
    # rolled about the view axis, corners stay at their radius r from the centre
    r = math.hypot(W / 2, H / 2)
    c0 = math.atan2(H / 2, W / 2)
    a = math.radians(deg)
    want = max(r * math.cos(c0 - a) - W / 2, r * math.sin(c0 + a) - H / 2)
    assert overshoot_px(rolled(VP, a), VP, FOV, (W, H)) == pytest.approx(want, rel=1e-6)


def test_a_view_turned_behind_misses_the_whole_frame():
    back = Viewpoint(-VP.x, VP.y, -VP.z, VP.o)
    assert overshoot_px(back, VP, FOV, (W, H)) == W


def test_the_guard_band_grows_with_the_misses_and_stops_at_its_cap():
    band = GuardBand(16, (W, H), FOV)
    assert band.spread() == 1.0 and band.guard_px == 16  # nothing measured: the base
    for i, px in enumerate([4.0, 6.0, 8.0, 10.0]):
        band.aim(float(i), VP)
        band.observe(i - 0.5, turned(VP, 99.0, H, FOV))  # before its time: not a miss
        band.observe(float(i), turned(VP, px, H, FOV))
    misses = [overshoot_px(turned(VP, px, H, FOV), VP, FOV, (W, H))
              for px in (4.0, 6.0, 8.0, 10.0)]
    assert list(band.misses) == pytest.approx(misses)
    assert band.guard_px == pytest.approx(16 + np.quantile(misses, 0.9))
    assert band.spread() == pytest.approx((H + 2 * band.guard_px) / (H + 32))
    band.aim(9.0, VP)
    band.observe(9.0, turned(VP, 400.0, H, FOV))  # one miss past the cap
    band.aim(10.0, VP)
    band.observe(10.0, turned(VP, 400.0, H, FOV))
    assert band.spread() == pytest.approx(MAX_SPREAD)
    assert band.summary()["guard_misses"] == 6
    assert band.summary()["guard_miss_max_px"] == pytest.approx(
        overshoot_px(turned(VP, 400.0, H, FOV), VP, FOV, (W, H)))
    assert band.aim(11.0, VP) == pytest.approx(MAX_SPREAD)
    assert band.summary()["guard_spread_max"] == pytest.approx(MAX_SPREAD)
