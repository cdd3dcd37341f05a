"""``lodsprite view`` in a real window: a process on a virtual X screen (Xvfb), playing a
path and exiting, compared with offscreen renders of the same frames; and its errors when
there is no display or the options are wrong (no window needed)."""

import csv
import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from conftest import run_cli
from lodsprite import Renderer, get_path, load_scene, read_image
from lodsprite.metrics import rmse

FRAMES, EVERY, SIZE = 30, 10, (256, 256)
SHOTS = [f"frame_{i:05d}.png" for i in range(0, FRAMES, EVERY)]

# Full mode: the window's context and the offscreen one are the same driver (Mesa llvmpipe
# here, through GLX and EGL) drawing the same geometry, the window straight into its own
# framebuffer, and a screenshot copies that framebuffer before the HUD is drawn, so the
# frames are the same bits: measured RMSE 0.0 at frames 0, 10 and 20.  Half a grey level
# allows a driver that rounds a few pixels differently per context; a wrong viewpoint, size
# or row order is off by tens (neighbouring frames of this path differ by about 20).
FULL_RMSE_TOL = 0.5
# Sprite mode, keyframes on the worker thread: an approximation (spriteframes resample the
# keyframe; the worker's timing decides which keyframe is shown).  Measured over 10 runs
# on llvmpipe: 0.01 at frame 0 (the first keyframe), 5.6-7.3 at frames 10 and 20, with 1
# to 5 keyframes; the tolerance is twice the worst, still below the ~20 between
# neighbouring frames of the path.
SPRITE_RMSE_TOL = 15.0


def lodsprite(*args, env=None, timeout=120):
    return subprocess.run([sys.executable, "-c", "from lodsprite.cli import main; main()", *args],
                          capture_output=True, text=True, env=env, timeout=timeout)


def no_display_env():
    env = dict(os.environ)
    env.pop("DISPLAY", None)
    env.pop("WAYLAND_DISPLAY", None)
    return env


def assert_one_line_error(proc, fragment):
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, proc.stderr
    assert fragment in lines[0].lower()


@pytest.fixture(scope="module")
def display():
    """The environment of a process on a fresh 1280x1024 virtual X screen."""
    if shutil.which("Xvfb") is None:
        pytest.skip("the real-window viewer tests need the Xvfb binary (apt-get install xvfb "
                    "xauth; .ci/run installs them)")
    from xvfbwrapper import Xvfb

    xvfb = Xvfb(width=1280, height=1024, colordepth=24)
    xvfb.start()
    try:
        env = no_display_env()
        env["DISPLAY"] = f":{xvfb.new_display}"
        yield env
    finally:
        xvfb.stop()


@pytest.fixture(scope="module")
def jacksboro():
    scene = load_scene("jacksboro")
    return scene, get_path("chen1999", scene.hf, FRAMES)


@pytest.fixture
def references(gl, jacksboro):
    """Offscreen full-resolution renders of every screenshot's frame (and its neighbours)."""
    scene, path = jacksboro
    refs = {}
    with Renderer(scene, SIZE, ctx=gl.mgl) as r:
        for i in sorted({j for s in range(0, FRAMES, EVERY) for j in (s - 1, s, s + 1)
                         if 0 <= j < FRAMES}):
            r.render(path.viewpoints[i])
            refs[i] = r.read_color()
    return refs


def play(display, tmp_path, mode, fps):
    shots, out = tmp_path / "shots", tmp_path / "out"
    proc = lodsprite("view", "jacksboro", "--play", "chen1999", "--frames", str(FRAMES),
                     "--mode", mode, "--size", f"{SIZE[0]}x{SIZE[1]}", "--screenshots",
                     str(shots), "--every", str(EVERY), "--exit", "--out", str(out),
                     "--fps", str(fps), env=display)
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    rows = list(csv.DictReader((out / "frames.csv").open()))
    assert [int(r["frame"]) for r in rows] == list(range(FRAMES))
    assert {"frame", "kind", "ms"} <= set(rows[0])
    summary = json.loads((out / "summary.json").read_text())
    for key in ("median_ms", "p99_ms", "mean_ms", "keyframes"):
        assert key in summary, key
    assert summary["frames"] == FRAMES and summary["mode"] == mode
    assert summary["size"] == list(SIZE)
    assert sorted(p.name for p in shots.iterdir()) == SHOTS
    return rows, summary, {i: read_image(shots / f"frame_{i:05d}.png")
                           for i in range(0, FRAMES, EVERY)}


def test_full_mode_window_plays_and_matches_offscreen(display, tmp_path, references):
    rows, summary, shots = play(display, tmp_path, "full", fps=0)
    assert {r["kind"] for r in rows} == {"full"} and summary["keyframes"] == 0
    for i, shot in shots.items():
        assert shot.shape == (*SIZE[::-1], 3)
        assert rmse(shot, references[i]) < FULL_RMSE_TOL, i


def test_sprite_mode_window_stays_close_to_full_resolution(display, tmp_path, references):
    rows, summary, shots = play(display, tmp_path, "sprite", fps=30)
    assert {r["kind"] for r in rows} <= {"keyframe", "first_sprite", "sprite"}
    assert summary["keyframes"] >= 1
    for i, shot in shots.items():
        err = rmse(shot, references[i])
        assert err < SPRITE_RMSE_TOL, (i, err)
        # Closer to its own frame than to the path's neighbouring frames.
        for j in (i - 1, i + 1):
            if j in references:
                assert err < rmse(shot, references[j]), (i, j)
    assert np.std(shots[FRAMES - EVERY]) > 0


def test_no_display_is_one_line_and_exit_code_2(tmp_path):
    proc = lodsprite("view", "fractal:64", "--mode", "full", "--size", "64x64",
                     env=no_display_env(), timeout=60)
    assert_one_line_error(proc, "display")


@pytest.mark.parametrize(("args", "fragment"), [
    (["--play", "chen1999", "--every", "0"], "--every"),
    (["--exit"], "--play"),
    (["--record", "flight.txt"], ".json"),
])
def test_bad_options_are_one_line_before_any_window(cli, monkeypatch, args, fragment):
    # No display either: the options are checked first, so their error is the one shown.
    # (In this process, through the console script's main: nothing is opened before it.)
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert_one_line_error(cli("view", "fractal:64", *args), fragment)


def test_the_embedding_example_runs_in_a_window(display):
    """examples/embed_moderngl_window.py: lodsprite drawing into a moderngl-window app."""
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    proc = subprocess.run([sys.executable, os.path.join(root, "examples",
                                                         "embed_moderngl_window.py"),
                           "--frames", "5"], capture_output=True, text=True, env=display,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "5 frames" in proc.stdout


def test_view_and_render_draw_the_same_frames(display, tmp_path):
    """The window and ``render`` give the same images for the same scene and options
    (inline keyframes, no frame-rate cap: every frame decided alike): LOD-sprite on the
    keyframe's own depth at scale 2, within 1 grey level (the same driver through GLX and
    EGL)."""
    options = ["--mode", "sprite", "--proxy", "depth", "--key-scale", "2", "--frames", "8",
               "--size", "64x64"]
    shots = tmp_path / "shots"
    proc = lodsprite("view", "fractal:128:2", "--play", "chen1999", "--screenshots",
                     str(shots), "--exit", "--inline-keyframes", "--fps", "0", *options,
                     env=display)
    assert proc.returncode == 0, proc.stderr
    # render in this process (offscreen EGL, as in a process of its own): no second start-up
    proc = run_cli("render", "--terrain", "fractal:128:2", "--path", "chen1999",
                   "--save-frames", "--out", str(tmp_path / "r"), *options)
    assert proc.returncode == 0, proc.stderr
    for i in range(8):
        shown = read_image(shots / f"frame_{i:05d}.png").astype(int)
        saved = read_image(tmp_path / "r" / "frames" / f"frame_{i:05d}.png")
        assert np.abs(shown - saved).max() <= 1, i
