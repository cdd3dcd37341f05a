"""The one warm-up contract (issue 30, must-have 3): every technique's ``warm_up`` leaves
its shaders compiled and the first view's data resident, so that the first timed frame at
that view compiles nothing and streams nothing in; the harness times the warm-up on its
own (``first_frame_ms``), outside the run's figures."""

from __future__ import annotations

import pytest

from lodsprite import Renderer, get_path, load_scene, techniques

TERRAIN = [("full", {}), ("lod", {"lod": 8}), ("sprite", {"lod": 8}),
           ("sprite", {"lod": 8, "tiles": 2}), ("sprite", {"lod": 8, "keyframes": "worker"}),
           ("adaptive", {}), ("sprite-adaptive", {"lod": 8}),
           ("sprite-adaptive", {"lod": 8, "proxy_sse": 8.0}),
           ("sprite-adaptive", {"lod": 8, "tiles": 2})]
CROWD = ("manager", "independent", "discrete")
#: Techniques checked elsewhere: ``distributed`` waits in its warm-up for a first keyframe
#: from its servers (tests/distributed), which this file does not start.
ELSEWHERE = {"distributed"}


def test_every_registered_technique_is_checked_here():
    here = {n for n, _ in TERRAIN} | set(CROWD) | {"scene"} | set(
        techniques.names(["lightfield"])) | ELSEWHERE
    assert set(techniques.names()) <= here


def programs_made(mgl, monkeypatch) -> list:
    """Count the GL programs made on ``mgl`` from now on (the real ``program`` is called:
    every one is compiled and linked by the driver)."""
    made, real = [], mgl.program

    def program(*args, **kwargs):
        made.append(kwargs.get("vertex_shader", "")[:40])
        return real(*args, **kwargs)

    monkeypatch.setattr(mgl, "program", program)
    return made


def warm_then_first(t, viewpoint, mgl, monkeypatch):
    """Warm ``t`` up at ``viewpoint``, then draw its first frame there: that frame's
    record and the programs it made."""
    t.warm_up(viewpoint)
    made = programs_made(mgl, monkeypatch)
    f = t.frame(viewpoint)
    return f, made


@pytest.mark.parametrize(("name", "options"), TERRAIN, ids=lambda x: str(x))
def test_after_the_warm_up_a_terrain_techniques_first_frame_compiles_and_streams_nothing(
        gl, monkeypatch, name, options):
    scene = load_scene("fractal:256:3", grid=256)
    path = get_path("chen1999", scene.hf, 4)
    with Renderer(scene, (64, 64), ctx=gl.mgl) as renderer:
        t = techniques.create(name, renderer, **techniques.get(name).bind(options))
        try:
            f, made = warm_then_first(t, path.viewpoints[0], gl.mgl, monkeypatch)
            assert made == [], name
            assert f.extra.get("uploaded", 0) == 0, name  # adaptive: no tile came in late
            adaptive = getattr(t, "terrain", None) or getattr(t, "adaptive", None)
            if adaptive is not None and hasattr(adaptive, "fill"):
                # nothing the first view wants is left to stream (sprite-adaptive:
                # through its keyframe's guard-banded projection)
                if name == "adaptive":
                    assert adaptive.fill(path.viewpoints[0]) == 0
                else:
                    s = t.sprite.sprite
                    key = s.key_projection(s.terrain.projection(path.viewpoints[0]))
                    assert adaptive.fill(path.viewpoints[0], key.matrix()) == 0
        finally:
            t.release()


def test_adaptive_starts_its_timed_run_with_the_first_view_settled(gl, tmp_path):
    """Over a store (tiles from a reader process): after the warm-up, frame 0 uploads no
    tile and has as many resident as the view settled alone; before the symmetric
    warm-up, frame 0 streamed from the roots inside the timed run."""
    from lodsprite.harness import run_path
    from lodsprite.paths import CameraPath
    from lodsprite.terrain.store import build_store

    store = tmp_path / "s.zarr"
    build_store("fractal:1024:1", store)
    scene = load_scene(str(store))
    path = get_path("flyover", scene.hf, 3)  # low: the view wants more than the roots
    still = CameraPath("still", (path.viewpoints[0],) * 2, path.fov_y_deg)
    with Renderer(scene, (96, 96), path.fov_y_deg, ctx=gl.mgl) as renderer:
        t = techniques.create("adaptive", renderer)
        try:
            settled = t.terrain.settle(path.viewpoints[0]).extra["resident"]
        finally:
            t.release()
        t = techniques.create("adaptive", renderer)
        try:
            result = run_path(t, still)
        finally:
            t.release()
    first = result.rows[0]
    assert settled > len(t.terrain.roots)
    assert first["uploaded"] == 0 and first["resident"] == settled
    assert result.summary["first_frame_ms"] > 0 and "first_frame_ms" in result.summary


@pytest.mark.parametrize("mode", CROWD)
def test_after_the_warm_up_a_crowds_first_frame_compiles_nothing(gl, monkeypatch, mode):
    from lodsprite.scene import open_scene

    scene = open_scene("crowd:40")
    path = scene.path("walk", 2)
    with Renderer(scene, (64, 48), path.fov_y_deg, ctx=gl.mgl) as renderer:
        t = techniques.create(mode, renderer, slots=4, active=20)
        try:
            _, made = warm_then_first(t, path.viewpoints[0], gl.mgl, monkeypatch)
            assert made == [], mode
        finally:
            t.release()


@pytest.fixture(scope="module")
def lumigraph(tmp_path_factory):
    from lodsprite.lumigraph.run import capture_lumigraph

    folder = tmp_path_factory.mktemp("lf") / "lf"
    capture_lumigraph("still-life", folder, n_st=8, n_uv=48, codec="png")
    return folder


@pytest.mark.parametrize("name", sorted(techniques.names(["lightfield"])))
def test_after_the_warm_up_a_lumigraphs_first_frame_compiles_nothing(gl, monkeypatch,
                                                                     lumigraph, name):
    from lodsprite.scene import open_scene

    scene = open_scene(str(lumigraph))
    path = scene.path("arc", 2)
    with Renderer(scene, (48, 48), path.fov_y_deg, ctx=gl.mgl) as renderer:
        t = techniques.create(name, renderer)
        try:
            _, made = warm_then_first(t, path.viewpoints[0], gl.mgl, monkeypatch)
            assert made == [], name
        finally:
            t.release()


@pytest.mark.parametrize("terrain_mode", ["full", "adaptive", "sprite-adaptive"])
def test_after_the_warm_up_a_scenes_first_frame_compiles_and_streams_nothing(
        gl, monkeypatch, tmp_path, terrain_mode):
    from lodsprite.scene.world import load_scene_file

    toml = tmp_path / "scene.toml"
    toml.write_text('[terrain]\nsource = "fractal:128:3"\n\n[[objects]]\nmesh = "ogre"\n'
                    'height_m = 20.0\ncount = 12\nseed = 1\nwalk_mps = 1.5\n'
                    'area = [-300.0, -300.0, 300.0, 300.0]\nlod = "linear"\n')
    world = load_scene_file(toml, textured=False)
    path = world.path("flyover", 2)
    with Renderer(world, (64, 48), path.fov_y_deg, ctx=gl.mgl) as renderer:
        t = techniques.create("scene", renderer, world=world, terrain_mode=terrain_mode,
                              lod=8)
        try:
            f, made = warm_then_first(t, path.viewpoints[0], gl.mgl, monkeypatch)
            assert made == [], terrain_mode
            assert f.extra.get("uploaded", 0) == 0, terrain_mode
        finally:
            t.release()
