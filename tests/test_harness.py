"""The one harness and the registry: what every run writes, and that the quality replay
draws the images the timed run showed."""

import csv
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from lodsprite import Renderer, get_path, load_scene, techniques
from lodsprite.harness import CORE_COLUMNS, CORE_KEYS, run_path, write_run

ROOT = Path(__file__).resolve().parents[1]
TERRAIN = ("full", "lod", "sprite", "adaptive", "sprite-adaptive")


def timed_run(t, path) -> tuple[list, list]:
    """Warm ``t`` up, then run ``path``: each frame's image as shown and its decision."""
    t.warm_up(path.viewpoints[0])
    shown, decisions = [], []
    for vp in path.viewpoints:
        t.frame(vp)
        shown.append(t.read_image())
        decisions.append(t.decision())
    return shown, decisions


def test_every_builtin_technique_is_registered_lazily():
    assert set(TERRAIN) | {"distributed", "manager", "independent", "discrete"} <= set(
        techniques.names())
    assert len(techniques.names(["lightfield"])) == 8
    # reading the registry loads the entry points' spec modules only (and their empty
    # packages), never a technique's class nor GL
    code = ("import sys, lodsprite.techniques as t; t.names(); "
            "print(sorted(m for m in sys.modules if m.startswith(('lodsprite.lumigraph', "
            "'lodsprite.manager', 'lodsprite.distributed', 'lodsprite.layered', 'moderngl')) "
            "and not m.endswith('.spec') and '.' in m[len('lodsprite.'):]))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert out.strip() == "[]"


def test_unknown_technique_and_option_are_user_errors():
    from lodsprite.errors import InputError

    with pytest.raises(InputError, match="unknown technique 'warp'"):
        techniques.get("warp")
    with pytest.raises(InputError, match="no option nope"):
        techniques.get("lod").create(None, nope=1)


@pytest.mark.parametrize("name", TERRAIN)
def test_the_replay_draws_what_the_timed_run_showed(gl, name):
    """Each frame's image read right after it was shown (outside the harness) equals the
    image the replay of its recorded decision draws."""
    scene = load_scene("fractal:64:3", grid=64)
    path = get_path("chen1999", scene.hf, 16)
    with Renderer(scene, (64, 64), ctx=gl.mgl) as renderer:
        t = techniques.create(name, renderer, **techniques.get(name).bind(
            {"lod": 8, "epsilon": 2.0, "key_sse": 1.0}))
        try:
            shown, decisions = [], []
            for vp in path.viewpoints:
                t.frame(vp)
                shown.append(t.read_image())
                decisions.append(t.decision())
            for i, (vp, d) in enumerate(zip(path.viewpoints, decisions, strict=True)):
                assert np.array_equal(t.replay(vp, d), shown[i]), (name, i)
        finally:
            t.release()


def test_the_adaptive_proxy_replay_draws_what_the_timed_run_showed(gl):
    """sprite-adaptive with --proxy-sse: the replay freezes each keyframe's recorded proxy
    selection (out of order too) and draws the images the timed run showed."""
    scene = load_scene("fractal:256:3", grid=256)
    path = get_path("chen1999", scene.hf, 16)
    with Renderer(scene, (64, 64), ctx=gl.mgl) as renderer:
        t = techniques.create("sprite-adaptive", renderer, lod=8, epsilon=1.0, key_sse=1.0,
                              proxy_sse=8.0)
        try:
            shown, decisions = timed_run(t, path)
            s = t.summary([])
            assert s["proxy_sse"] == 8.0 and s["mean_proxy_triangles"] > 0
            order = list(range(len(decisions)))[::-1]
            for i in order:
                assert np.array_equal(t.replay(path.viewpoints[i], decisions[i]), shown[i]), i
        finally:
            t.release()


SLEPT_MS = 5.0


@pytest.mark.parametrize("name", ["lod", "sprite"])
def test_a_run_writes_the_core_columns_and_keys(gl, tmp_path, name):
    scene = load_scene("fractal:64:3", grid=64)
    path = get_path("chen1999", scene.hf, 12)
    with Renderer(scene, (64, 64), ctx=gl.mgl) as renderer:
        t = techniques.create(name, renderer, lod=8)
        drawn = t.frame

        def frame(vp):  # a known floor under every frame's time: 5 ms slept
            time.sleep(SLEPT_MS / 1e3)
            return drawn(vp)

        t.frame = frame
        try:
            t0 = time.perf_counter()
            result = run_path(t, path, ground_truth=True, quality_stride=2)
            wall_ms = (time.perf_counter() - t0) * 1e3
        finally:
            t.release()
    write_run(tmp_path, result)
    rows = list(csv.DictReader((tmp_path / "frames.csv").open()))
    assert tuple(list(rows[0])[:5]) == CORE_COLUMNS
    assert [r["rmse"] != "" for r in rows] == [i % 2 == 0 for i in range(12)]
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert set(CORE_KEYS) <= set(summary) and summary["frames"] == 12
    assert summary["quality_frames"] == 6
    # the frame clock against two independent ones: the sleep inside each frame and the
    # wall clock around the whole run (warm-up and replays included)
    ms = np.array([float(r["ms"]) for r in rows])
    assert ms.min() >= SLEPT_MS and summary["median_ms"] >= SLEPT_MS
    assert 12 * SLEPT_MS <= summary["total_s"] * 1e3 <= wall_ms
    assert ms.sum() <= wall_ms and summary["max_ms"] <= wall_ms
    if name == "lod":  # the coarse level's replay is its own image: rmse_mean is its error
        assert summary["rmse_mean"] > 0


def test_the_worked_example_runs():
    import doctest
    import importlib.util

    spec = importlib.util.spec_from_file_location("custom_technique",
                                                  ROOT / "examples" / "custom_technique.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    failed, tried = doctest.testmod(module, raise_on_error=False)
    assert tried > 5 and failed == 0


@pytest.mark.parametrize("mode", ["manager", "independent", "discrete"])
def test_the_crowd_replay_draws_what_the_timed_run_showed(gl, mode):
    from lodsprite.scene import open_scene

    scene = open_scene("crowd:80")
    path = scene.path("walk", 10)
    with Renderer(scene, (64, 48), path.fov_y_deg, ctx=gl.mgl) as renderer:
        t = techniques.create(mode, renderer, slots=4, active=20)
        try:
            shown, decisions = timed_run(t, path)
            for i in (7, 2, 3, 9):  # out of order: a replay restarts from frame 0's state
                assert np.array_equal(t.replay(path.viewpoints[i], decisions[i]), shown[i])
        finally:
            t.release()


def test_the_lumigraph_replay_shows_the_frames_the_timed_run_reconstructed(gl, tmp_path):
    from lodsprite.lumigraph.run import capture_lumigraph
    from lodsprite.scene import open_scene

    capture_lumigraph("still-life", tmp_path / "lf", n_st=8, n_uv=48, codec="png")
    scene = open_scene(str(tmp_path / "lf"))
    path = scene.path("arc", 6)
    with Renderer(scene, (48, 48), path.fov_y_deg, ctx=gl.mgl) as renderer:
        t = techniques.create("lumigraph-critical", renderer)
        try:
            t.plan_replay({1, 4})
            shown, decisions = timed_run(t, path)
            for i in (4, 1):
                assert np.array_equal(t.replay(path.viewpoints[i], decisions[i]), shown[i])
        finally:
            t.release()


@pytest.mark.parametrize("mode", ["adaptive", "sprite-adaptive"])
def test_the_viewer_flies_the_adaptive_techniques_from_the_registry(gl, mode):
    """The viewer's modes for a terrain come from the registry, the adaptive renderer and
    LOD-sprite with adaptive keyframes among them; their HUD line counts the tiles."""
    import re

    from lodsprite.gl.target import RenderTarget
    from lodsprite.scene import open_scene
    from lodsprite.viewer.controls import CameraController
    from lodsprite.viewer.core import ViewerCore

    scene = open_scene("fractal:128:3", grid=128)
    modes = techniques.factories(scene.layers, ("distributed",), lod=16, threaded=False)
    assert list(modes)[:5] == ["full", "lod", "sprite", "adaptive", "sprite-adaptive"]
    core = ViewerCore(gl.mgl, scene, (64, 64), modes, mode,
                      CameraController.from_home(scene.camera_home()))
    target = RenderTarget(gl, 64, 64)
    try:
        for _ in range(3):
            core.frame(1 / 30, target.fbo)
            core.log_frame()
        status = core.technique.status()
        m = re.search(r"tiles: (\d+) resident, (\d+) loaded, (\d+) in flight", status)
        assert m, status
        t = core.technique
        terrain = t.terrain if mode == "adaptive" else t.adaptive
        assert int(m[1]) == len(terrain.slots.slots) >= len(terrain.roots)
        assert int(m[2]) == terrain.loader.loaded
        img = core.technique.read_image()
        assert (img != img[0, 0]).any(axis=2).mean() > 0.2  # terrain, not only sky
    finally:
        core.release()
        target.release()


def test_the_viewer_checks_options_against_the_scene_layers_before_any_window():
    from lodsprite.errors import InputError
    from lodsprite.viewer.app import ViewOptions, view

    with pytest.raises(InputError, match="goes with a crowd"):
        view(ViewOptions(terrain="fractal:64", grid=64, target_fps=30.0))
    with pytest.raises(InputError, match="goes with a terrain"):
        view(ViewOptions(terrain="crowd:20", server="127.0.0.1:1"))
    with pytest.raises(InputError, match="use one of full, lod, sprite, adaptive"):
        view(ViewOptions(terrain="fractal:64", grid=64, mode="manager"))


def test_the_viewer_switches_from_sprite_to_sprite_adaptive_over_a_store(gl, tmp_path):
    """sprite-adaptive takes the proxy from the store's level 0 after sprite drew its own
    proxy: the geometry drops the old proxies and both techniques go on drawing."""
    from lodsprite.gl.target import RenderTarget
    from lodsprite.scene import open_scene
    from lodsprite.terrain.store import build_store
    from lodsprite.terrain.storefield import StoreField
    from lodsprite.viewer.controls import CameraController
    from lodsprite.viewer.core import ViewerCore

    build_store("fractal:257:4", tmp_path / "s.zarr", tile=128, chunk=32)
    scene = open_scene(str(tmp_path / "s.zarr"), grid=64)
    modes = techniques.factories(scene.layers, ("distributed",), lod=16, threaded=False)
    core = ViewerCore(gl.mgl, scene, (64, 64), modes, "sprite",
                      CameraController.from_home(scene.camera_home()))
    target = RenderTarget(gl, 64, 64)
    try:
        for mode in ("sprite", "sprite-adaptive", "sprite"):
            core.switch_mode(mode)
            assert core.mode == mode
            for _ in range(2):
                core.frame(1 / 30, target.fbo)
                core.log_frame()
            img = core.technique.read_image()
            assert (img != img[0, 0]).any(axis=2).mean() > 0.2, mode
        assert isinstance(core.renderer.terrain_gl.geometry.full, StoreField)
    finally:
        core.release()
        target.release()


def test_a_registered_technique_is_a_render_mode_and_a_viewer_mode(tmp_path):
    """One class and one registry entry: render_path runs it (its own column in
    frames.csv, quality from its replay) and the viewer lists it for a terrain."""
    import importlib.util

    from lodsprite.run import RenderConfig, render_path

    spec = importlib.util.spec_from_file_location("custom_technique",
                                                  ROOT / "examples" / "custom_technique.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    module.register()
    try:
        assert "every-other" in techniques.factories(["terrain"])
        s = render_path(RenderConfig(terrain="fractal:64", grid=64, mode="every-other",
                                     frames=6, size=(32, 32), ground_truth=True), tmp_path)
        rows = list(csv.DictReader((tmp_path / "frames.csv").open()))
        assert [r["source"] for r in rows] == ["0", "0", "2", "2", "4", "4"]
        rmse = [float(r["rmse"]) for r in rows]  # a repeat shows the last frame's view
        assert all(rmse[i] < rmse[i + 1] for i in (0, 2, 4)), rmse
        assert s["technique"] == "every-other" and s["rmse_mean"] > 0
    finally:
        techniques.unregister("every-other")


def test_the_technique_summary_is_of_the_timed_run_not_of_the_replay(gl):
    """Regression: the harness read a technique's own summary after the quality replay, so
    an adaptive run with --ground-truth or --save-frames could report tiles that its replay
    read (``tiles_loaded``, evictions, peak memory) as the timed run's.  Here the replay
    of a real technique counts its replayed frames; the summary must see none of them."""
    scene = load_scene("fractal:64:5", grid=64)
    path = get_path("chen1999", scene.hf, 6)
    with Renderer(scene, (32, 32), 45.0, ctx=gl.mgl) as r:
        t = techniques.create("lod", r, lod=8)
        replayed = []
        real_replay = t.replay
        t.replay = lambda vp, d: (replayed.append(1), real_replay(vp, d))[1]
        t.summary = lambda frames: {"replayed_before_summary": len(replayed),
                                    "frames_seen": len(frames)}
        try:
            result = run_path(t, path, ground_truth=True)
        finally:
            t.release()
    assert len(replayed) == 6  # every frame was replayed for its quality ...
    assert result.summary["replayed_before_summary"] == 0  # ... after the summary was read
    assert result.summary["frames_seen"] == 6 and "rmse_mean" in result.summary


def test_a_quality_stride_judges_the_frame_after_each_for_its_flicker(gl):
    """With a stride of 3 the replay judges frames 0, 3, 6 (every quality column) and
    the frames after them, 1, 4 (the flicker against the judged frame before it only)."""
    scene = load_scene("fractal:32", grid=32)
    path = get_path("chen1999", scene.hf, 7)
    with Renderer(scene, (32, 32), ctx=gl.mgl) as r:
        t = techniques.create("lod", r, lod=8)
        try:
            result = run_path(t, path, ground_truth=True, quality_stride=3)
        finally:
            t.release()
    rows = result.rows
    assert [i for i, row in enumerate(rows) if "rmse" in row] == [0, 3, 6]
    assert [i for i, row in enumerate(rows) if "flicker" in row] == [1, 4]
    assert result.summary["quality_frames"] == 3
    assert result.summary["flicker_mean"] == pytest.approx(
        np.mean([rows[1]["flicker"], rows[4]["flicker"]]))
    assert "flicker" in result.columns
