"""A scene's static layers reused from the keyframe worker (issue 32, must-have 5):
``keyframes="worker"`` on the scene technique.

A flat terrain, the camera low in the south looking north; a grey static cube 170 m
ahead and a red walking cube straight behind it (270 m ahead, smaller on screen).  The
static cube is in the worker's keyframes, the walker drawn each frame: it must be hidden
by the cube's sprite (the keyframe's depth), and, with the static cube removed (the
control), show."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from lodsprite import techniques
from lodsprite.api import Renderer
from lodsprite.camera import look_at, project_points
from lodsprite.errors import InputError
from lodsprite.scene.world import load_scene_file

N, SPACING_M = 32, 30.0
SIZE = (96, 64)
EYE, AIM = (0.0, -470.0, 40.0), (0.0, 0.0, 40.0)
STATIC, WALKER = (0.0, -300.0), (0.0, -200.0)


def scene(folder: Path, static: bool, hills_m: float = 0.0) -> Path:
    """The scene file: flat, or hills ``hills_m`` high (LOD-sprite's error metric
    measures the terrain's warp: over flat ground it is 0 whatever the motion)."""
    import trimesh

    r, c = np.mgrid[0:N + 1, 0:N + 1] * 0.7
    np.save(folder / "flat.npy", (hills_m * (np.sin(r) * np.cos(c)) ** 2).astype(np.float32))
    grey = trimesh.creation.box((1.0, 1.0, 1.0)).subdivide()
    grey.export(folder / "grey.off")
    red = trimesh.creation.box((1.0, 1.0, 1.0)).subdivide()
    red.visual.vertex_colors = np.tile([230, 20, 20, 255], (len(red.vertices), 1))
    red.export(folder / "red.ply")
    body = f'[terrain]\nsource = "flat.npy"\ngrid = {N}\ntexture = "checker:4"\n'
    for name, mesh, (x, y), walk in (("s", "grey.off", STATIC, 0.0),
                                     ("w", "red.ply", WALKER, 0.01)):
        if name == "s" and not static:
            continue
        (folder / f"{name}.csv").write_text(f"{x},{y}\n")
        body += (f'[[objects]]\nmesh = "{mesh}"\nheight_m = 50.0\npoints = "{name}.csv"\n'
                 f"walk_mps = {walk}\n")
    p = folder / "scene.toml"
    p.write_text(body)
    return p


def pixel(renderer, vp, xyz) -> tuple[int, int]:
    view_proj = renderer.projection(vp).matrix() @ vp.view_matrix()
    px = project_points(np.array([xyz], np.float64), view_proj, *SIZE)[0][0]
    return int(px[1]), int(px[0])


def shown_with_worker(gl, folder: Path, static: bool, keyframes: str = "worker"):
    """The second frame of the scene technique with ``keyframes`` from the worker (or
    inline), and the walker's pixel (row, column)."""
    world = load_scene_file(scene(folder, static))
    vp = look_at(EYE, AIM)
    with Renderer(world, SIZE, 45.0, ctx=gl.mgl) as r:
        t = techniques.create("scene", r, world=world, terrain_mode="sprite",
                              keyframes=keyframes, epsilon=4.0, lod=8)
        try:
            assert t.static_in_keyframes and t.objects.subset is t.objects.moving
            t.warm_up(vp)
            for _ in range(2):
                t.frame(vp)
            img = t.read_image().astype(int)
        finally:
            t.release()
        walker = pixel(r, vp, (*WALKER, 25.0))
    return img, walker


@pytest.mark.parametrize("keyframes", ["worker", "inline"])
def test_a_walker_behind_a_static_cube_in_the_keyframe_is_hidden(gl, tmp_path, keyframes):
    """Inline keyframes too: they left the proxy's depth alone, and the walker showed
    through the static cube's sprite."""
    (tmp_path / "a").mkdir(), (tmp_path / "b").mkdir()
    img, walker = shown_with_worker(gl, tmp_path / "a", static=True, keyframes=keyframes)
    red = img[walker]
    assert not (red[0] > red[1] + 60 and red[0] > red[2] + 60), red  # the cube's grey
    # the control: the static cube removed, the same walker shows red at that pixel
    ctrl, same = shown_with_worker(gl, tmp_path / "b", static=False, keyframes=keyframes)
    assert same == walker
    c = ctrl[walker]
    assert c[0] > c[1] + 60 and c[0] > c[2] + 60, c


def test_worker_keyframes_give_frames_keyframes_and_their_replay(gl, tmp_path):
    world = load_scene_file(scene(tmp_path, static=True, hills_m=20.0))
    vps = [look_at((x, -470.0, 40.0), (x, 0.0, 40.0)) for x in np.linspace(0, 200, 12)]
    with Renderer(world, SIZE, 45.0, ctx=gl.mgl) as r:
        t = techniques.create("scene", r, world=world, terrain_mode="sprite",
                              keyframes="worker", epsilon=0.5, lod=8)
        try:
            t.plan_replay(set(range(len(vps))))
            t.warm_up(vps[0])
            shown, decisions, frames = [], [], []
            deadline = time.monotonic() + 30.0
            i = 0
            while t.terrain.engine.worker.rendered < 3 and time.monotonic() < deadline:
                vp = vps[min(i, len(vps) - 1)]
                frames.append(t.frame(vp))
                shown.append((vp, t.read_image()))
                decisions.append(t.decision())
                i += 1
                if i >= len(vps):
                    time.sleep(0.05)  # the path's end: the worker's keyframe still due
            assert t.terrain.engine.worker.rendered >= 3, "no keyframes within 30 s"
            s = t.summary(frames)
            assert s["keyframes_rendered"] >= 3 and s["keyframe_ms_median"] > 0
            assert all(f.kind in ("sprite", "first_sprite") for f in frames)
            assert all(np.isfinite(f.extra["ms_terrain"]) for f in frames)
            for k in (0, min(len(vps), len(frames)) - 1):
                vp, img = shown[k]
                again = t.replay(vp, decisions[k])
                assert np.abs(again.astype(int) - img).max() <= 1, k
        finally:
            t.release()


def test_worker_keyframes_are_lod_sprites_and_need_a_scene_file(gl, tmp_path):
    from dataclasses import replace

    from lodsprite.layered.layers import TerrainLayer

    world = load_scene_file(scene(tmp_path, static=True))
    with Renderer(world, SIZE, 45.0, ctx=gl.mgl) as r:
        t = techniques.create("scene", r, world=world, terrain_mode="full", keyframes="worker")
        try:  # full-resolution terrain has no keyframes: drawn as inline
            assert isinstance(t.terrain, TerrainLayer) and t.keyframes == "inline"
        finally:
            t.release()
        with pytest.raises(InputError, match="scene file"):
            techniques.create("scene", r, world=replace(world, source=None),
                              terrain_mode="sprite", keyframes="worker")


def test_the_worker_is_handed_the_displays_scene_through_shared_memory(tmp_path):
    """The worker process is not made to read the scene file again: what it receives
    (:func:`share_scene`, then :func:`received_scene` as the process does) is the
    display's scene: the same heights, texture and objects, standing on the same ground,
    with no link left to the display's arrays."""
    from lodsprite.layered.scene_keys import received_scene, share_scene

    world = load_scene_file(scene(tmp_path, static=True, hills_m=20.0))
    shm, layout, rest = share_scene(world)
    try:
        got = received_scene(shm.name, layout, rest)
    finally:
        shm.close()
        shm.unlink()
    assert np.array_equal(got.hf.heights, world.hf.heights)
    assert got.hf.heights.dtype == world.hf.heights.dtype
    assert (got.hf.dx, got.hf.dy, got.hf.name) == (world.hf.dx, world.hf.dy, world.hf.name)
    assert np.array_equal(got.texture, world.texture) and got.texture.dtype == np.uint8
    assert not np.shares_memory(got.hf.heights, world.hf.heights)
    assert got.objects.ground_field is got.hf
    assert world.objects.ground_field is world.hf  # the display's scene is left whole
    assert np.array_equal(got.objects.moving(), world.objects.moving())
    for t in (0.0, 7.5):  # the walker where the display has it, the cube on the ground
        assert np.array_equal(got.objects.poses(t), world.objects.poses(t))
    assert got.source == world.source and got.lightfields == world.lightfields
