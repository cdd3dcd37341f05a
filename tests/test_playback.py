"""A path played in time (:mod:`lodsprite.playback`): the image on screen is judged at each
display tick against the viewpoint of that instant, so a technique's latency costs it
error.  A hand-made path and a technique with a known delay (it sleeps before drawing)."""

from __future__ import annotations

import time

import numpy as np
import pytest

from lodsprite import Renderer, load_scene, techniques
from lodsprite.camera import look_at
from lodsprite.errors import InputError
from lodsprite.paths import CameraPath
from lodsprite.playback import run_played
from lodsprite.techniques import Technique

DELAY_S = 0.05
FPS = 30.0


class Delayed(Technique):
    """Full resolution at the viewpoint it is given, after sleeping ``delay_s``."""

    name = "delayed"

    def __init__(self, renderer, delay_s: float) -> None:
        super().__init__(renderer)
        self.delay_s = delay_s

    def frame(self, viewpoint):
        time.sleep(self.delay_s)
        return self.renderer.render(viewpoint, None)


def flight(scene, moving: bool) -> CameraPath:
    """Twelve frames (0.37 s at 30 fps) of a low flight, turning fast, or standing still."""
    hf = scene.hf
    z = float(hf.heights.max()) + 0.2 * hf.width
    out = []
    for i in range(12):
        a = 0.15 * i if moving else 0.0
        eye = (0.3 * hf.width * np.cos(a), 0.3 * hf.width * np.sin(a), z)
        out.append(look_at(eye, (0.0, 0.0, float(hf.heights.mean()))))
    return CameraPath("hand-made", tuple(out), 45.0)


@pytest.fixture(scope="module")
def scene():
    return load_scene("fractal:64:3", grid=64)


def test_each_tick_judges_the_frame_on_screen_at_that_instants_viewpoint(gl, scene):
    path = flight(scene, moving=True)
    judged = []
    with Renderer(scene, (64, 64), ctx=gl.mgl) as renderer:

        def reference(viewpoint):
            judged.append(viewpoint)
            renderer.render(viewpoint, None)
            return renderer.read_color()

        t = Delayed(renderer, DELAY_S)
        r = run_played(t, path, fps=FPS, ground_truth=True, reference=reference)
    shown = np.array([row["shown_s"] for row in r.rows])
    start = np.array([row["start_s"] for row in r.rows])
    assert (np.diff(start) > 0).all() and (shown - start >= DELAY_S).all()
    assert start[-1] <= path.duration_s(FPS) < shown[-1] + DELAY_S * 3
    # one judgement a tick of 60 Hz, from the first frame shown to the path's end
    assert len(judged) == len(r.ticks) == r.summary["ticks"]
    assert r.summary["tick_hz"] == 60.0
    for tick, vp in zip(r.ticks, judged, strict=True):
        np.testing.assert_allclose(vp.o, path.at_time(tick["t_s"], FPS).o, atol=1e-9)
        assert shown[tick["frame"]] <= tick["t_s"] + 1e-9   # shown by then ...
        later = shown[tick["frame"] + 1:]
        assert not len(later) or later[0] > tick["t_s"]       # ... and not yet replaced
    # the camera moved on while each frame was drawn and shown: late, it is not exact
    assert all(tick["rmse"] > 0.5 for tick in r.ticks)
    held = [row["ticks"] for row in r.rows if "ticks" in row]
    assert sum(held) == len(r.ticks)   # every tick counted once, on the frame shown then
    assert r.summary["rmse_time_weighted"] == pytest.approx(
        np.mean([t["rmse"] for t in r.ticks]))
    assert r.summary["latency_ms_mean"] >= DELAY_S * 1e3


def test_a_still_camera_makes_latency_cost_nothing(gl, scene):
    """The control: the same delay on a path that does not move shows, at every tick, what
    the same drawer draws there: no error and no flicker."""
    from lodsprite.harness import full_resolution

    with Renderer(scene, (64, 64), ctx=gl.mgl) as renderer:
        r = run_played(Delayed(renderer, DELAY_S), flight(scene, moving=False), fps=FPS,
                       ground_truth=True, reference=full_resolution(renderer))
    assert r.ticks and all(t["rmse"] == 0.0 for t in r.ticks)
    assert r.summary["flicker"] == 0.0 and r.summary["rmse_worst_second"] == 0.0


def test_a_display_rate_spaces_the_frames(gl, scene):
    with Renderer(scene, (64, 64), ctx=gl.mgl) as renderer:
        t = techniques.create("lod", renderer, lod=16)
        try:
            r = run_played(t, flight(scene, moving=True), fps=FPS, rate=10.0)
        finally:
            t.release()
    start = np.array([row["start_s"] for row in r.rows])
    assert (start >= np.arange(len(start)) * 0.1 - 1e-3).all()   # never before its slot
    assert len(start) <= 0.37 / 0.1 + 2
    assert r.summary["display_rate"] == 10.0 and r.summary["truncated"] is False


def test_a_run_stopped_by_the_frame_cap_says_so(gl, scene):
    with Renderer(scene, (32, 32), ctx=gl.mgl) as renderer:
        r = run_played(Delayed(renderer, 0.0), flight(scene, moving=True), max_frames=3)
    assert len(r.rows) == 3 and r.summary["truncated"] is True


def test_a_technique_that_counts_frames_is_not_played_in_time(gl, scene):
    class Counting(Delayed):
        plays_in_time = False

    with Renderer(scene, (32, 32), ctx=gl.mgl) as renderer, pytest.raises(
            InputError, match="cannot be played in time"):
        run_played(Counting(renderer, 0.0), flight(scene, moving=True))


@pytest.mark.parametrize("kwargs", [{"fps": 0.0}, {"rate": -1.0}, {"quality_stride": 0}])
def test_impossible_settings_are_input_errors(gl, scene, kwargs):
    with Renderer(scene, (32, 32), ctx=gl.mgl) as renderer, pytest.raises(InputError):
        run_played(Delayed(renderer, 0.0), flight(scene, moving=True), **kwargs)


def test_a_path_interpolates_between_its_frames_in_time(scene):
    path = flight(scene, moving=True)
    np.testing.assert_allclose(path.at_time(2 / FPS, FPS).o, path.viewpoints[2].o)
    mid = path.at_time(2.5 / FPS, FPS).o
    np.testing.assert_allclose(mid, (path.viewpoints[2].o + path.viewpoints[3].o) / 2)
    assert path.at_time(99.0, FPS) is path.viewpoints[-1]   # clamped to its end


def test_at_a_display_rate_frames_are_shown_on_its_slots_and_missed_slots_counted(gl, scene):
    """At 30 Hz a frame that takes 50 ms is shown on the slot after it ends, the next one
    starts there, and every other slot keeps the previous image: about half missed."""
    with Renderer(scene, (32, 32), ctx=gl.mgl) as renderer:
        r = run_played(Delayed(renderer, DELAY_S), flight(scene, moving=True), fps=FPS,
                       rate=30.0)
    shown = np.array([row["shown_s"] for row in r.rows])
    start = np.array([row["start_s"] for row in r.rows])
    assert np.allclose(shown * 30, np.rint(shown * 30), atol=1e-6)   # on slots
    assert (shown - start >= DELAY_S).all()
    assert 0.3 <= r.summary["missed_slots"] <= 0.7, r.summary["missed_slots"]


@pytest.mark.parametrize("predictor", ["kalman", "decay"])
def test_with_prediction_a_frame_draws_the_viewpoint_predicted_for_its_display(
        gl, scene, predictor):
    """On a straight flight at constant speed a predictor, one slot ahead, draws where the
    camera is when the frame is shown: closer to that viewpoint than the viewpoint at the
    frame's start."""
    hf = scene.hf
    z = float(hf.heights.max()) + 0.2 * hf.width
    path = CameraPath("straight", tuple(
        look_at((-0.3 * hf.width + 0.02 * hf.width * i, -0.4 * hf.width, z),
                (-0.3 * hf.width + 0.02 * hf.width * i, 0.0, 0.0)) for i in range(12)), 45.0)
    drawn = []

    class Recording(Delayed):
        def frame(self, viewpoint):
            drawn.append(viewpoint)
            return super().frame(viewpoint)

    with Renderer(scene, (32, 32), ctx=gl.mgl) as renderer:
        r = run_played(Recording(renderer, 0.01), path, fps=FPS, rate=20.0, predict=predictor)
    assert r.summary["predictor"] == predictor
    drawn = drawn[1:]   # the warm-up's
    rows = r.rows[2:]   # from the third frame the predictor has a velocity
    at_start = [np.linalg.norm(path.at_time(row["start_s"], FPS).o
                               - path.at_time(row["shown_s"], FPS).o) for row in rows]
    predicted = [np.linalg.norm(vp.o - path.at_time(row["shown_s"], FPS).o)
                 for vp, row in zip(drawn[2:], rows, strict=True)]
    inside = [i for i, row in enumerate(rows) if row["shown_s"] < path.duration_s(FPS)]
    assert inside
    assert np.mean([predicted[i] for i in inside]) < 0.5 * np.mean([at_start[i]
                                                                    for i in inside])
