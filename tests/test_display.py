"""Error over display time (lodsprite.display) and the temporal error (flicker)."""

from __future__ import annotations

import numpy as np
import pytest

from lodsprite.camera import look_at
from lodsprite.display import (
    ReferenceCache,
    judge_display,
    on_screen,
    tick_hz,
    tick_times,
    weights,
    worst_second,
)
from lodsprite.metrics import flicker
from lodsprite.playback import missed_slots

HZ = 60.0


class Held:
    """A played run's stand-in technique: frame k replays as a constant image of grey
    level ``levels[k]``, counting its replays."""

    def __init__(self, levels):
        self.levels, self.replays = levels, []

    def replay(self, viewpoint, decision):
        self.replays.append(decision["k"])
        return np.full((4, 4, 3), self.levels[decision["k"]], np.uint8)


def test_an_image_held_ten_display_intervals_weighs_ten_times_one_held_one():
    """Frame 0 shown at 0 s and held for 10 ticks, frame 1 shown at 10/60 s until the
    end at 10/60 s: weights 10 and 1; the time-weighted RMSE is (10 e0 + e1) / 11."""
    shown = np.array([0.0, 10 / HZ])
    assert weights(shown, 10 / HZ, HZ).tolist() == [10, 1]
    tech = Held([100, 130])
    vps = [look_at((0, -10, 5), (0, 0, 0))] * 2
    rows, summary = judge_display(
        tech, vps, [{"k": 0}, {"k": 1}], shown, lambda t: [vps[0]] * len(t),
        lambda vp: np.full((4, 4, 3), 110, np.uint8), HZ, 10 / HZ)
    assert [r["frame"] for r in rows] == [0] * 10 + [1]
    assert summary["rmse_time_weighted"] == pytest.approx((10 * 10 + 20) / 11)
    assert tech.replays == [0, 1]  # each shown image replayed once, in order
    # the flicker sees the one change of image (30 levels) against a still reference
    assert summary["flicker"] == pytest.approx(30 / 10)
    assert summary["ticks"] == 11 and summary["tick_hz"] == HZ


def test_a_frame_replaced_before_any_tick_is_never_judged():
    shown = np.array([0.0, 0.001, 0.002, 1 / HZ])
    assert on_screen(shown, tick_times(0.0, 2 / HZ, HZ)).tolist() == [0, 3, 3]


def test_ticks_run_at_least_at_60_hz_and_at_the_display_rate_above():
    assert tick_hz(None) == tick_hz(30) == 60 and tick_hz(120) == 120
    assert tick_times(0.01, 0.05, 100).tolist() == pytest.approx([0.01, 0.02, 0.03, 0.04,
                                                                  0.05])


def test_the_worst_window_is_the_largest_mean_over_that_much_path_time():
    v = np.array([1, 1, 5, 5, 1, 1, 1], float)
    t = np.arange(len(v), dtype=float)  # one value a second
    assert worst_second(t, v, 2.0) == 5 and worst_second(t, v, 3.0) == pytest.approx(11 / 3)
    assert worst_second(t, v, 100.0) == pytest.approx(v.mean())


def test_flicker_of_a_jittered_static_scene_is_positive_and_zero_without_jitter(gl):
    """A still terrain view drawn with a one-pixel jitter on alternate frames flickers
    against its (still) reference; the same sequence without the jitter scores 0, as
    does the reference's own motion (a pan the technique follows exactly)."""
    import lodsprite as ls
    from lodsprite.harness import scene_reference

    scene = ls.load_scene("fractal:64", grid=64)
    path = ls.get_path("chen1999", scene.hf, 3)
    with ls.Renderer(scene, (48, 40)) as r, scene_reference(r, samples=2) as ref:
        still = ref(path.viewpoints[0])
        moved = ref(path.viewpoints[2])
    jittered = [still, np.roll(still, 1, axis=1), still, np.roll(still, 1, axis=1)]
    steady = [still] * 4
    jitter = [flicker(a, b, still, still) for b, a in zip(jittered, jittered[1:], strict=False)]
    none = [flicker(a, b, still, still) for b, a in zip(steady, steady[1:], strict=False)]
    assert min(jitter) > 1.0 and max(none) == 0.0
    assert flicker(moved, still, moved, still) == 0.0
    assert flicker(still, still, moved, still) > 1.0  # held while the reference moves


def test_missed_slots_count_the_slots_that_showed_no_new_frame():
    assert missed_slots(np.array([0, 1, 2, 3]) / 30, 30) == 0.0
    assert missed_slots(np.array([0, 2, 3, 5]) / 30, 30) == pytest.approx(2 / 5)


def test_the_reference_cache_draws_each_viewpoint_once():
    drawn = []
    cache = ReferenceCache(lambda vp: drawn.append(vp) or np.zeros((2, 2, 3), np.uint8),
                           key="k", max_bytes=24)
    a, b = look_at((0, -10, 5), (0, 0, 0)), look_at((1, -10, 5), (0, 0, 0))
    for vp in (a, b, a, a):
        cache(vp)
    assert len(drawn) == 2 and cache.hits == 2
    cache(look_at((2, -10, 5), (0, 0, 0)))  # over 24 bytes: the least recently used goes
    cache(b)
    assert len(drawn) == 4


def test_the_worst_second_is_over_path_time_whatever_the_stride():
    """Pairs every 0.25 s (8 rows a second): the worst second's mean is over the rows of
    one second of path time, not over 60 rows."""
    t = np.array([(k // 2) * 0.25 + (k % 2) / 60 for k in range(40)])  # 5 s of pairs
    v = np.where((t >= 2.0) & (t < 3.0), 10.0, 1.0)
    assert worst_second(t, v) == pytest.approx(10.0)
    assert worst_second(t[:6], v[:6]) == pytest.approx(v[:6].mean())  # under a second


def test_flicker_is_over_one_sixtieth_of_a_second_at_every_rate():
    """A held image (frame 0 on screen throughout) against a reference that changes every
    tick: at 120 Hz the flicker compares ticks 1/60 s apart, as at 60 Hz, and the tick
    numbers are the absolute ones of each rate."""
    vps = [look_at((float(i), -10, 5), (0, 0, 0)) for i in range(40)]

    def run(hz):
        tech = Held([100])
        ref_at = {}

        def reference(vp):  # grey rises with the eye's x: 5 levels a 1/120 s
            key = float(vp.o[0])
            if key not in ref_at:
                ref_at[key] = np.full((4, 4, 3), int(key * 5), np.uint8)
            return ref_at[key]

        return judge_display(tech, vps, [{"k": 0}], np.array([0.0]),
                             lambda t: [vps[int(round(x * 120))] for x in t], reference,
                             hz, 0.2)

    rows60, s60 = run(60.0)
    rows120, s120 = run(120.0)
    assert [r["tick"] for r in rows120][:3] == [0, 1, 2]
    assert s60["flicker"] == pytest.approx(10.0) and s120["flicker"] == pytest.approx(10.0)
