"""The viewer's core, headless: synthetic key, mouse and resize events drive a
:class:`ViewerCore` on the session's GL context, drawing into an offscreen framebuffer."""

import csv
import json
import math
import multiprocessing

import numpy as np
import pytest

from lodsprite import Renderer, get_path, load_scene, read_image, terrain_techniques
from lodsprite.errors import LodspriteError
from lodsprite.gl.target import RenderTarget
from lodsprite.technique import FALLBACK_TINT, FullTechnique
from lodsprite.viewer.controls import CameraController, FlightRecorder
from lodsprite.viewer.core import WINDOW_COLUMNS, PlayPlan, ViewerCore

SIZE = (96, 96)
MAGENTA = np.array(FALLBACK_TINT[:3]) * 255.0
SUMMARY_KEYS = ("frames", "mode", "terrain", "path", "size", "median_ms", "p99_ms",
                "mean_ms", "keyframes", "gl_renderer")


@pytest.fixture(scope="module")
def scene():
    return load_scene("fractal:64")


@pytest.fixture
def make_core(gl, scene):
    """Build cores (and their offscreen framebuffers); all released before the GL check."""
    made = []

    def build(mode="full", size=SIZE, factories=None, **kwargs):
        factories = factories or terrain_techniques(16, 1.0, threaded=False)
        kwargs.setdefault("controller", CameraController.for_terrain(scene.hf))
        core = ViewerCore(gl.mgl, scene, size, factories, mode, **kwargs)
        made.append(core)
        return core

    def target(size=SIZE):
        t = RenderTarget(gl, *size)
        made.append(t)
        return t

    build.target = target
    yield build
    for obj in reversed(made):
        obj.release()


def show(core, fbo, frames=1, dt=0.0):
    """``frames`` frames as the window loop shows them: draw, then log."""
    for _ in range(frames):
        core.frame(dt, fbo)
        core.log_frame()


def play(core, fbo, limit=100):
    """Warm up, then frames until the played path quits; the number of frames shown."""
    core.warm_up(fbo)
    n = 0
    while not core.quit and n < limit:
        show(core, fbo)
        n += 1
    return n


# ------------------------------------------------------------------------- camera input

def test_holding_w_moves_the_eye_forward_and_releasing_stops_it(make_core):
    core, t = make_core(), make_core.target()
    show(core, t.fbo)
    start = core.controller.viewpoint
    before = core.technique.read_image()
    core.key("w", True)
    show(core, t.fbo, dt=0.2)
    core.key("w", False)
    moved = core.controller.viewpoint
    step = moved.o - start.o
    assert np.dot(step, start.forward) > 0.5 * core.controller.speed_mps * 0.2
    assert not np.array_equal(core.technique.read_image(), before)
    show(core, t.fbo, dt=0.2)
    assert np.array_equal(core.controller.viewpoint.o, moved.o)


def test_drag_turns_scroll_speeds_up_escape_quits(make_core):
    core = make_core()
    f0, speed = core.controller.viewpoint.forward, core.controller.speed_mps
    core.drag(40.0, 0.0)
    assert not np.allclose(core.controller.viewpoint.forward, f0)
    core.scroll(2)
    assert core.controller.speed_mps == pytest.approx(speed * 1.25**2)
    assert not core.quit
    core.key("escape")
    assert core.quit


def test_unknown_mode_is_refused(make_core):
    with pytest.raises(LodspriteError, match="unknown mode"):
        make_core(mode="warp")


# --------------------------------------------------------------------------- modes

def test_number_keys_switch_mode_and_release_the_old_technique(make_core):
    made, released = [], []

    def tracked(factory):
        def make(renderer):
            tech = factory(renderer)
            made.append(tech)
            release = tech.release
            tech.release = lambda: (released.append(tech), release())
            return tech
        return make

    factories = {k: tracked(f) for k, f in terrain_techniques(16, 1.0, False).items()}
    core, t = make_core(factories=factories), make_core.target()
    show(core, t.fbo)
    for key, mode in [("2", "lod"), ("3", "sprite"), ("1", "full"), ("3", "sprite"),
                      ("2", "lod"), ("1", "full")]:
        old = core.technique
        core.key(key)
        assert core.mode == mode and core.technique.name == mode
        assert core.technique is not old and released[-1] is old
        show(core, t.fbo, 2)
        assert core.hud.frame_type in ({"keyframe", "first_sprite", "sprite"}
                                       if mode == "sprite" else {mode})
    assert released == made[:-1]
    n = len(made)
    core.key("1")  # the mode shown: nothing made, nothing released
    core.key("9")  # no ninth mode
    core.key("0")
    assert core.mode == "full" and len(made) == n and len(released) == n - 1


def test_failing_factory_keeps_the_mode_and_says_why(make_core):
    def broken(renderer):
        raise LodspriteError("no server at nowhere:1")

    factories = {"full": FullTechnique, "broken": broken,
                 "lod": terrain_techniques(16, 1.0, False)["lod"]}
    core, t = make_core(factories=factories), make_core.target()
    tech = core.technique
    core.key("2")
    assert core.mode == "full" and core.technique is tech
    assert "cannot switch" in core.hud.status and "nowhere:1" in core.hud.status
    show(core, t.fbo)  # the HUD keeps the message
    assert "cannot switch" in core.hud.status
    assert "cannot switch" in core.hud.lines()[-1]
    core.key("3")
    assert core.mode == "lod" and core.hud.status == ""


def test_brackets_step_epsilon_in_sprite_mode(make_core):
    core, t = make_core(mode="sprite"), make_core.target()
    eps = core.technique.sprite
    core.key("]")
    assert eps.epsilon_px == pytest.approx(1.25)
    core.key("[")
    core.key("[")
    assert eps.epsilon_px == pytest.approx(0.8)
    for _ in range(30):
        core.key("[")
    assert eps.epsilon_px == pytest.approx(0.125)
    for _ in range(40):
        core.key("]")
    assert eps.epsilon_px == pytest.approx(64.0)
    show(core, t.fbo)
    assert "epsilon 64px" in core.hud.lines()[1]


def test_brackets_double_and_halve_n_in_lod_mode(make_core, scene):
    core, t = make_core(mode="lod"), make_core.target()
    seen = []
    for key in "]]]" + "[" * 8:
        core.key(key)
        seen.append(core.technique.lod)
        show(core, t.fbo)
        assert 0 < core.hud.triangles <= 2 * seen[-1] ** 2
    assert seen == [32, 64, 64, 32, 16, 8, 4, 2, 2, 2, 2]
    assert scene.hf.quads == 64


def test_brackets_do_nothing_in_full_mode(make_core):
    core = make_core()
    core.key("]")
    core.key("[")
    assert core.technique.params() == {}


# ------------------------------------------------------------------- toggles and overlays

def test_toggle_keys_flip_the_toggles_and_overlays_draw(make_core):
    core, t = make_core(mode="sprite"), make_core.target()
    core.key("h")  # HUD off: the framebuffer shows exactly the technique's image
    show(core, t.fbo)
    plain = t.read_color()
    assert np.array_equal(plain, core.technique.read_image())
    start = dict(core.toggles)
    assert start == {"wireframe": False, "tint": False, "frustum": False, "hud": False}
    for key, name in [("x", "wireframe"), ("t", "tint"), ("k", "frustum"), ("h", "hud")]:
        core.key(key)
        assert core.toggles[name] is not start[name]
        assert {k: v for k, v in core.toggles.items() if k != name} == \
               {k: v for k, v in start.items() if k != name}
        show(core, t.fbo)
        if name in ("wireframe", "hud"):
            assert not np.array_equal(t.read_color(), plain), name
        core.key(key)
        assert core.toggles == start
    # Everything on at once, in every mode.
    for key in "xtkh":
        core.key(key)
    for key in "123":
        core.key(key)
        show(core, t.fbo, 2)


def test_tint_marks_only_the_fallback_of_a_spriteframe(make_core):
    # ε at its maximum: the camera slides far from the keyframe without a new one.
    factories = terrain_techniques(16, 64.0, threaded=False)
    t = make_core.target()
    images = []
    for tint in (False, True):  # the keyframe itself is shown as is: no fallback, no tint
        core = make_core(mode="sprite", factories=factories)
        if tint:
            core.key("t")
        show(core, t.fbo)
        assert core.hud.frame_type == "keyframe"
        images.append(core.technique.read_image())
    assert np.array_equal(*images)

    core.key("t")  # tint off
    core.key("d", True)
    show(core, t.fbo, 12, dt=0.25)
    core.key("d", False)
    assert core.hud.frame_type == "sprite" and core.hud.keyframes == 1
    off = core.technique.read_image()
    core.key("t")
    show(core, t.fbo)
    assert core.hud.frame_type == "sprite" and core.hud.keyframes == 1
    on = core.technique.read_image()
    changed = np.any(on != off, axis=-1)
    assert 0 < changed.mean() < 0.5  # some fallback, far from all of the image
    # Fallback fragments are mixed with the tint by its alpha; the others are untouched.
    tinted = (1 - FALLBACK_TINT[3]) * off.astype(float) + FALLBACK_TINT[3] * MAGENTA
    assert np.abs(on[changed] - tinted[changed]).max() <= 1.0


# ------------------------------------------------------------------------------- HUD

def spy_frames(technique) -> list:
    """Every :class:`FrameInfo` ``technique.frame`` returns from now on, in order."""
    seen, frame = [], technique.frame
    technique.frame = lambda vp: seen.append(frame(vp)) or seen[-1]
    return seen


def assert_hud_shows(core, f) -> None:
    """The HUD's state and text are those of the technique's frame ``f``."""
    h = core.hud
    assert (h.frame_type, h.keyframes, h.triangles) == (f.type, f.keyframes, f.triangles)
    assert h.error_px == f.error_px or (math.isnan(h.error_px) and math.isnan(f.error_px))
    err = "-" if math.isnan(f.error_px) else f"{f.error_px:.2f} px"
    lines = h.lines()
    assert lines[2] == f"frame {f.type}   error {err}   keyframes {f.keyframes}"
    assert lines[3] == f"triangles {f.triangles:,}"


def test_hud_state_after_frames(make_core, gl):
    core, t = make_core(mode="sprite"), make_core.target()
    seen = spy_frames(core.technique)
    assert core.hud.fps == 0.0
    show(core, t.fbo)
    assert_hud_shows(core, seen[-1])
    assert core.hud.frame_type == "keyframe" and core.hud.keyframes == 1
    assert core.hud.triangles > 0 and core.hud.error_px == 0.0
    core.key("w", True)
    for _ in range(6):
        show(core, t.fbo, dt=0.05)
        f = seen[-1]
        assert_hud_shows(core, f)
        # what is shown is within ε (1 px) of the geometry: a keyframe exactly
        assert f.error_px == 0.0 if f.type == "keyframe" else 0.0 <= f.error_px < 1.0
    types = [f.type for f in seen]
    # inline keyframes: each keyframe frame adds one; a spriteframe follows one
    assert [f.keyframes for f in seen] == [types[:i + 1].count("keyframe")
                                           for i in range(len(types))]
    assert set(types[1:]) <= {"keyframe", "first_sprite", "sprite"} and "sprite" in types
    assert core.index == 7 and [r["kind"] for r in core.rows] == types
    # the frame rate over the window of intervals logged (the first frame has none)
    intervals = [r["interval_ms"] for r in core.rows[1:]]
    assert core.hud.fps == pytest.approx(1e3 / np.mean(intervals))
    lines = core.hud.lines()
    median = float(lines[0].split("frame ")[1].split(" ms median")[0])
    assert median == pytest.approx(np.median([r["window_ms"] for r in core.rows]), abs=0.006)
    assert lines[1] == "mode sprite  epsilon 1px"
    assert lines[4] == f"GL {gl.info.renderer}"
    core.key("x")
    show(core, t.fbo)
    core._panel_at = -math.inf  # the panel refreshes at most PANEL_HZ times a second
    show(core, t.fbo)
    assert "wireframe" in core.hud.lines()
    assert_hud_shows(core, seen[-1])


# ------------------------------------------------------------------ played paths, files

def test_played_path_writes_frames_summary_and_screenshots(make_core, gl, scene, tmp_path):
    path = get_path("chen1999", scene.hf, 5)
    plan = PlayPlan(path, tmp_path / "out", tmp_path / "shots", every=2, exit=True)
    rec = FlightRecorder()
    core, t = make_core(mode="sprite", play=plan, record=rec), make_core.target()
    assert play(core, t.fbo) == 5
    assert core.quit and len(rec) == 5
    flown = rec.save(tmp_path / "flown.json", path.fov_y_deg)
    np.testing.assert_array_equal(flown.eyes(), path.eyes())   # the path's frames, in order

    with (tmp_path / "out" / "frames.csv").open() as fh:
        head = fh.readline().strip().split(",")
        assert head[:5] == ["frame", "kind", "ms", "triangles", "error_px"]
    rows = list(csv.DictReader((tmp_path / "out" / "frames.csv").open()))
    assert len(rows) == 5 and list(rows[0])[-len(WINDOW_COLUMNS):] == list(WINDOW_COLUMNS)
    assert [int(r["frame"]) for r in rows] == list(range(5))
    assert all(float(r["ms"]) > 0 for r in rows)

    # The reference: the same technique driven straight along the path, after the same
    # warm-up (three frames at the first viewpoint).  Inline keyframes are deterministic,
    # so every frame's type, triangles, keyframes and error must be the played ones.
    with Renderer(scene, SIZE, 45.0, ctx=gl.mgl) as r:
        tech = terrain_techniques(16, 1.0, threaded=False)["sprite"](r)
        try:
            for _ in range(3):
                tech.frame(path.viewpoints[0])
            ref, images = [], []
            for vp in path.viewpoints:
                ref.append(tech.frame(vp))
                images.append(tech.read_image())
        finally:
            tech.release()
    assert [r["kind"] for r in rows] == [f.type for f in ref]
    assert [int(r["triangles"]) for r in rows] == [f.triangles for f in ref]
    assert [int(r["keyframes"]) for r in rows] == [f.keyframes for f in ref]
    np.testing.assert_allclose([float(r["error_px"]) for r in rows],
                               [f.error_px for f in ref], rtol=1e-5, atol=1e-9)

    # The summary is of those rows (keys read: frames, mode, path, size, keyframes,
    # median_ms, p99_ms, mean_ms).
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    for key in SUMMARY_KEYS:
        assert key in summary, key
    assert summary["frames"] == 5 and summary["mode"] == "sprite"
    assert summary["path"] == path.name and summary["size"] == list(SIZE)
    assert summary["keyframes"] == ref[-1].keyframes
    ms = np.array([float(r["ms"]) for r in rows])
    assert summary["median_ms"] == pytest.approx(np.median(ms), rel=1e-5)  # csv: 6 digits
    assert summary["p99_ms"] == pytest.approx(np.percentile(ms, 99), rel=1e-5)
    assert summary["mean_ms"] == pytest.approx(ms.mean(), rel=1e-5)

    # Screenshots of every second frame, each the reference's image of that frame.
    shots = sorted(p.name for p in (tmp_path / "shots").iterdir())
    assert shots == ["frame_00000.png", "frame_00002.png", "frame_00004.png"]
    for i in (0, 2, 4):
        shot = read_image(tmp_path / "shots" / f"frame_{i:05d}.png")
        assert shot.shape == (96, 96, 3)
        assert np.abs(shot.astype(int) - images[i]).max() <= 1, i


def test_a_played_paths_ms_is_the_harness_ms_and_window_times_are_extra_columns(
        make_core, gl, scene, tmp_path):
    """The window writes its rows through the harness's record: the same core columns as
    a harness run of the same technique along the same path, ``ms`` the technique's
    frame and ``ctx.finish()`` (within the window's whole frame, ``window_ms``, every
    row), the window's own times in extra columns, the summary's timing keys of ``ms``."""
    from lodsprite.harness import CORE_COLUMNS, CORE_KEYS, run_path, write_run

    path = get_path("chen1999", scene.hf, 6)
    core, t = make_core(mode="sprite", play=PlayPlan(path, tmp_path / "view")), \
        make_core.target()
    assert play(core, t.fbo) == 6
    with Renderer(scene, SIZE, 45.0, ctx=gl.mgl) as r:
        tech = terrain_techniques(16, 1.0, threaded=False)["sprite"](r)
        try:
            write_run(tmp_path / "batch", run_path(tech, path))
        finally:
            tech.release()
    view = list(csv.DictReader((tmp_path / "view" / "frames.csv").open()))
    batch = list(csv.DictReader((tmp_path / "batch" / "frames.csv").open()))
    assert list(view[0])[:len(CORE_COLUMNS)] == list(batch[0])[:len(CORE_COLUMNS)] \
        == list(CORE_COLUMNS)
    assert set(WINDOW_COLUMNS) <= set(view[0]) and not set(WINDOW_COLUMNS) & set(batch[0])
    assert len(view) == len(batch) == 6
    for r in view:
        ms, window = float(r["ms"]), float(r["window_ms"])
        parts = sum(float(r[k]) for k in ("present_ms", "hud_ms", "swap_ms"))
        assert 0 < ms <= window and parts <= window
    summary = json.loads((tmp_path / "view" / "summary.json").read_text())
    assert set(CORE_KEYS) <= set(summary)
    ms = np.array([float(r["ms"]) for r in view])
    assert summary["median_ms"] == pytest.approx(np.median(ms), rel=1e-5)
    assert summary["window_median_ms"] == pytest.approx(
        np.median([float(r["window_ms"]) for r in view]), rel=1e-5)
    assert summary["first_frame_ms"] > 0


def test_played_path_without_exit_hands_over_to_the_controller(make_core, scene, tmp_path):
    path = get_path("chen1999", scene.hf, 3)
    core, t = make_core(play=PlayPlan(path, tmp_path, exit=False)), make_core.target()
    core.warm_up(t.fbo)
    show(core, t.fbo, 3)
    assert not core.quit and core.play is None
    assert len((tmp_path / "frames.csv").read_text().splitlines()) == 4
    show(core, t.fbo)  # the controller's view now
    assert core.index == 4


def test_key_p_writes_a_screenshot(make_core, tmp_path):
    core, t = make_core(screenshot_dir=tmp_path / "s"), make_core.target()
    show(core, t.fbo)
    core.key("p")  # a screenshot of the next frame, read before its HUD
    show(core, t.fbo)
    assert [p.name for p in (tmp_path / "s").iterdir()] == ["frame_00001.png"]
    assert np.array_equal(read_image(core.screenshots[0]), core.technique.read_image())


def test_full_mode_screenshot_is_the_offscreen_render(make_core, gl, scene, tmp_path):
    path = get_path("chen1999", scene.hf, 3)
    plan = PlayPlan(path, screenshots=tmp_path, every=1)
    core, t = make_core(play=plan), make_core.target()
    core.key("h")
    assert play(core, t.fbo) == 3
    with Renderer(scene, SIZE, ctx=gl.mgl) as ref:
        for i, vp in enumerate(path.viewpoints):
            ref.render(vp)
            expected = ref.read_color()
            shot = read_image(tmp_path / f"frame_{i:05d}.png")
            assert np.abs(shot.astype(int) - expected).max() <= 1, i
    # What the framebuffer shows (HUD off) is the same image.
    assert np.abs(t.read_color().astype(int) - expected).max() <= 1


# ---------------------------------------------------------------------------- resize

def test_resize_makes_frames_of_the_new_size(make_core, tmp_path):
    core = make_core(mode="sprite", screenshot_dir=tmp_path)
    core.key("t")
    show(core, make_core.target().fbo)
    tech = core.technique
    core.resize(SIZE)  # same size: nothing remade
    core.resize((8, 8))  # too small (a minimised window): ignored
    assert core.technique is tech and core.renderer.size == SIZE
    core.resize((128, 80))
    assert core.renderer.size == (128, 80) and core.technique is not tech
    assert core.technique.sprite.sprite.fallback_tint == FALLBACK_TINT  # tint kept
    t = make_core.target((128, 80))
    show(core, t.fbo, 2, dt=0.1)
    assert core.technique.read_image().shape == (80, 128, 3)
    assert read_image(core.screenshot()).shape == (80, 128, 3)
    assert core.summary()["size"] == [128, 80]
    core.key("1")
    show(core, t.fbo)
    assert core.technique.read_image().shape == (80, 128, 3)


# ----------------------------------------------------------------------- worker process

def workers():
    return [p for p in multiprocessing.active_children() if p.name == "lodsprite-keyframes"]


def test_threaded_sprite_mode_renders_and_release_stops_the_worker(make_core, scene):
    before = len(workers())
    path = get_path("chen1999", scene.hf, 8)
    core = make_core(mode="sprite", factories=terrain_techniques(16, 1.0, threaded=True),
                     play=PlayPlan(path))
    t = make_core.target()
    assert len(workers()) == before + 1
    assert play(core, t.fbo) == 8
    status = core.technique.status()
    assert core.hud.keyframes >= 1 and status.startswith("keyframes: worker process")
    assert "lead -" not in status  # the lead is a latency, never negative
    assert {r["kind"] for r in core.rows} <= {"keyframe", "first_sprite", "sprite"}
    assert core.technique.read_image().std() > 0
    core.technique.release()
    assert len(workers()) == before


def test_a_resize_that_fails_keeps_the_old_renderer_and_technique(make_core, tmp_path):
    calls = []

    def flaky(renderer):
        calls.append(renderer)
        if len(calls) > 1:
            raise LodspriteError("server gone")
        return FullTechnique(renderer)

    core = make_core(factories={"full": flaky}, mode="full")
    t = make_core.target()
    old = core.renderer.size
    core.resize((64, 48))
    assert core.renderer.size == old and "cannot resize" in core.hud.status
    show(core, t.fbo)  # the old pair still draws
    assert core.rows[-1]["triangles"] > 0


def test_log_frame_before_any_frame_does_nothing(make_core):
    core = make_core()
    core.log_frame()
    assert core.rows == [] and core.index == 0


@pytest.mark.parametrize("mode", ["full", "sprite"])
def test_frames_drawn_straight_into_the_window_framebuffer_match_the_offscreen_ones(
        make_core, gl, scene, tmp_path, mode):
    """As the window does: the renderer draws into the given framebuffer (no copy)."""
    path = get_path("chen1999", scene.hf, 4)
    window = make_core.target()  # stands in for the window's screen (colour and depth)
    direct = make_core(mode=mode, framebuffer=window.fbo,
                       play=PlayPlan(path, screenshots=tmp_path / "d", every=1))
    direct.toggles["hud"] = False
    offscreen = make_core(mode=mode, play=PlayPlan(path, screenshots=tmp_path / "o", every=1))
    offscreen.toggles["hud"] = False
    other = make_core.target()
    assert play(direct, window.fbo) == play(offscreen, other.fbo) == 4
    for i in range(4):
        a = read_image(tmp_path / "d" / f"frame_{i:05d}.png")
        b = read_image(tmp_path / "o" / f"frame_{i:05d}.png")
        assert np.abs(a.astype(int) - b).max() <= 1, i
    # the framebuffer holds the last frame, and the screenshot is what it held
    assert np.abs(window.read_color().astype(int) - a).max() <= 1


def test_a_screenshot_that_cannot_be_written_does_not_end_the_flight(make_core, tmp_path):
    blocker = tmp_path / "not_a_folder"
    blocker.write_text("a file where the screenshot folder should be")
    core, t = make_core(screenshot_dir=blocker), make_core.target()
    show(core, t.fbo)
    core.key("p")
    show(core, t.fbo)  # no exception: the flight goes on
    assert "cannot save a screenshot" in core.hud.status
    show(core, t.fbo)
    assert len(core.rows) == 3
