"""A path played in time (:mod:`lodsprite.playback`): each displayed frame is judged at the
viewpoint of its display time, so a technique's latency costs it error.  A hand-made
path and a technique with a known delay (it sleeps before drawing)."""

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


def test_each_frame_is_judged_at_its_display_times_viewpoint(gl, scene):
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
    assert len(judged) == len(r.rows)
    for row, vp in zip(r.rows, judged, strict=True):
        np.testing.assert_allclose(vp.o, path.at_time(row["shown_s"], FPS).o, atol=1e-9)
    # the camera moved on while each frame was drawn: full resolution, late, is not exact
    # (a frame shown after the path's end is judged at its clamped end: left out)
    inside = [row for row in r.rows if row["shown_s"] <= path.duration_s(FPS)]
    assert inside and all(row["rmse"] > 0.5 for row in inside)
    assert r.summary["latency_ms_mean"] >= DELAY_S * 1e3


def test_a_still_camera_makes_latency_cost_nothing(gl, scene):
    """The control: the same delay on a path that does not move gives the reference."""
    with Renderer(scene, (64, 64), ctx=gl.mgl) as renderer:
        r = run_played(Delayed(renderer, DELAY_S), flight(scene, moving=False), fps=FPS,
                       ground_truth=True)
    assert all(row["rmse"] == 0.0 for row in r.rows)


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
