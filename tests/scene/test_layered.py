"""The scene technique (issue 23, must-have 2): layers composited by depth in one frame.

An analytic scene: a flat terrain with a ridge across it (``y`` in -60..60 m, 200 m high),
the camera low in the south looking north.  A cube in front of the ridge shows; one
behind it is hidden; a light field's pixels appear only where its proxy is in front.
Moving objects move between frames while LOD-sprite's keyframes hold the static ones;
the untimed replay draws the timed frame's image; ``render --scene`` writes its run."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from lodsprite import techniques
from lodsprite.api import Renderer
from lodsprite.camera import look_at, project_points
from lodsprite.scene.world import load_scene_file

N, SPACING_M = 32, 30.0          # 960 m square, x and y in -480..480
SIZE = (96, 64)
EYE, AIM = (0.0, -470.0, 40.0), (0.0, 0.0, 40.0)
FRONT, BEHIND = (-60.0, -300.0), (60.0, 250.0)


def ridge_terrain(folder: Path, ridge_m: float = 200.0) -> None:
    r, c = np.mgrid[0:N + 1, 0:N + 1].astype(np.float64)
    y = N * SPACING_M / 2 - r * SPACING_M
    np.save(folder / "ridge.npy", np.where(np.abs(y) <= 60.0, ridge_m, 0.0).astype(np.float32))


def scene_file(folder: Path, body: str, ridge_m: float = 200.0) -> Path:
    import trimesh

    ridge_terrain(folder, ridge_m)
    box = trimesh.creation.box((1.0, 1.0, 1.0))
    for _ in range(3):  # 768 triangles: a progressive mesh to extract LODs from
        box = box.subdivide()
    box.export(folder / "cube.off")
    p = folder / "scene.toml"
    p.write_text(f'[terrain]\nsource = "ridge.npy"\ngrid = {N}\ntexture = "checker:4"\n'
                 + body)
    return p


def world_with(folder: Path, objects: list[tuple[list, float]], lightfields: str = "",
               ridge_m: float = 200.0):
    body = ""
    for k, (points, walk) in enumerate(objects):
        (folder / f"p{k}.csv").write_text("\n".join(f"{x},{y}" for x, y in points) + "\n")
        body += (f'[[objects]]\nmesh = "cube.off"\nheight_m = 50.0\npoints = "p{k}.csv"\n'
                 f"walk_mps = {walk}\n")
    return load_scene_file(scene_file(folder, body + lightfields, ridge_m))


def pixel(renderer, vp, xyz) -> tuple[int, int]:
    view_proj = renderer.projection(vp).matrix() @ vp.view_matrix()
    px = project_points(np.array([xyz], np.float64), view_proj, *SIZE)[0][0]
    return int(px[1]), int(px[0])  # row, column


def run(technique, viewpoints):
    technique.warm_up(viewpoints[0])
    shown, decisions = [], []
    for vp in viewpoints:
        technique.frame(vp)
        shown.append(technique.read_image())
        decisions.append(technique.decision())
    return shown, decisions


def cubes_over(gl, folder: Path, ridge_m: float):
    """The front and behind cubes over a ridge ``ridge_m`` high: ``(image, bare terrain,
    front pixel, behind pixel)``."""
    world = world_with(folder, [([FRONT, BEHIND], 0.0)], ridge_m=ridge_m)
    vp = look_at(EYE, AIM)
    with Renderer(world, SIZE, 45.0, ctx=gl.mgl) as r:
        r.render(vp, None)
        bare = r.read_color().astype(int)
        t = techniques.create("scene", r, world=world, terrain_mode="full")
        try:
            (img,), _ = run(t, [vp])
        finally:
            t.release()
        front, behind = pixel(r, vp, (*FRONT, 25.0)), pixel(r, vp, (*BEHIND, 25.0))
    return img.astype(int), bare, front, behind


def test_an_object_in_front_of_the_ridge_shows_and_one_behind_it_is_hidden(gl, tmp_path):
    img, bare, front, behind = cubes_over(gl, tmp_path, 200.0)
    assert 0 <= behind[0] < SIZE[1] and 0 <= behind[1] < SIZE[0]  # on screen, behind
    assert np.abs(img[front] - bare[front]).max() > 30      # the cube covers the terrain
    assert np.abs(img[behind] - bare[behind]).max() <= 2    # the ridge covers the cube
    changed = np.abs(img - bare).max(axis=2) > 2
    assert changed.sum() < 0.2 * changed.size               # only the front cube's pixels
    # the control (review finding 13): the ridge flattened, the behind cube's pixel shows it
    img, bare, _, flat_behind = cubes_over(gl, tmp_path, 0.0)
    assert flat_behind == behind
    assert np.abs(img[behind] - bare[behind]).max() > 30


@pytest.fixture(scope="module")
def lf_folder(tmp_path_factory) -> Path:
    from lodsprite.lumigraph.run import capture_lumigraph

    folder = tmp_path_factory.mktemp("lf") / "lf"
    capture_lumigraph("still-life", folder, n_st=4, n_uv=32, codec="png")
    return folder


def test_a_light_field_shows_only_where_its_proxy_is_in_front(gl, tmp_path, lf_folder):
    lfs = "".join(f'[[lightfields]]\nsource = "{lf_folder}"\nposition = [{x}, {y}]\n'
                  f"height_m = 120.0\n" for x, y in (FRONT, BEHIND))
    world = world_with(tmp_path, [], lfs)
    vp = look_at(EYE, AIM)
    with Renderer(world, SIZE, 45.0, ctx=gl.mgl) as r:
        r.render(vp, None)
        bare = r.read_color().astype(int)
        t = techniques.create("scene", r, world=world, terrain_mode="full")
        try:
            (img,), _ = run(t, [vp])
            assert t.lightfields.in_view(vp, t.projection(vp)).all()
            back = look_at(EYE, (0.0, -900.0, 40.0))  # both behind the eye: neither drawn
            assert not t.lightfields.in_view(back, t.projection(back)).any()
            items = t.lightfields.items
            proxy_px = []
            target = r.terrain_gl.drawer.target
            for item in items:  # each proxy's own silhouette, alone on magenta
                target.use((1.0, 0.0, 1.0))
                item.compositor.draw(t.projection(vp) @ vp.view_matrix() @ item.m,
                                     item.method.output.color, target.fbo)
                proxy_px.append((r.read_color() != [255, 0, 255]).any(axis=2))
        finally:
            t.release()
    changed = np.abs(img.astype(int) - bare).max(axis=2) > 2
    front, behind = proxy_px
    assert changed[front].mean() > 0.9 and front.sum() > 20  # the front one shows
    assert not changed[~front].any()                         # nothing outside its proxy
    assert behind.sum() > 0 and not (changed & behind & ~front).any()  # hidden by the ridge


def test_walkers_move_while_keyframes_hold_the_static_objects(gl, tmp_path):
    world = world_with(tmp_path, [([FRONT], 0.0), ([(60.0, -300.0)], 100.0)])
    vps = [look_at(EYE, AIM)] * 3
    with Renderer(world, SIZE, 45.0, ctx=gl.mgl) as r:
        t = techniques.create("scene", r, world=world, terrain_mode="sprite", epsilon=64.0,
                              lod=8, frame_s=1.0)
        try:
            shown, _ = run(t, vps)
            assert t.static_in_keyframes and t.summary([])["keyframe_holds"] == "static"
            key = t.terrain.sprite.sprite.keyframe_color().astype(int)
            r.render(vps[0], None)
            bare = r.read_color().astype(int)
            p0 = world.objects.poses(0.0)[1]
            p1 = world.objects.poses(1.0)[1]
            static = pixel(r, vps[0], (*FRONT, 25.0))
            walker0 = pixel(r, vps[0], (p0[0], p0[1], p0[2] + 25.0))
        finally:
            t.release()
    assert np.linalg.norm(p1[:2] - p0[:2]) > 90.0
    assert np.abs(key[static] - bare[static]).max() > 30    # the static cube: in the keyframe
    assert np.abs(key[walker0] - bare[walker0]).max() <= 8  # the walker: not in it
    assert np.abs(shown[0][walker0].astype(int) - bare[walker0]).max() > 30
    assert not np.array_equal(shown[0], shown[2])           # the walker moved
    for img in shown:                                       # the static cube stays
        assert np.abs(img[static].astype(int) - bare[static]).max() > 30


@pytest.mark.parametrize("mode", ["sprite", "sprite-adaptive", "adaptive"])
def test_the_replay_draws_the_timed_frames(gl, tmp_path, lf_folder, mode):
    lfs = f'[[lightfields]]\nsource = "{lf_folder}"\nposition = [0.0, -200.0]\nheight_m = 80.0\n'
    world = world_with(tmp_path, [([FRONT], 0.0), ([(60.0, -300.0)], 40.0)], lfs)
    vps = [look_at((x, -470.0, 40.0), (x, 0.0, 40.0)) for x in np.linspace(0, 60, 4)]
    with Renderer(world, SIZE, 45.0, ctx=gl.mgl) as r:
        t = techniques.create("scene", r, world=world, terrain_mode=mode, epsilon=2.0, lod=8)
        try:
            t.plan_replay({0, 1, 2, 3})
            shown, decisions = run(t, vps)
            for i in (3, 1, 2, 0):
                assert np.abs(t.replay(vps[i], decisions[i]).astype(int)
                              - shown[i]).max() <= 1, i
        finally:
            t.release()


def test_planned_replays_keep_host_copies_not_a_gpu_target_per_frame(gl, tmp_path, lf_folder,
                                                                      monkeypatch):
    # review finding 4: plan_replay made a GPU target per frame per light field up front,
    # and a second plan never freed the first's
    import lodsprite.gl.lumigraph as gl_lumigraph

    made = []

    class Counted(gl_lumigraph.FloatTarget):
        def __init__(self, *args, **kwargs):
            made.append(args[1:])
            super().__init__(*args, **kwargs)

    lfs = f'[[lightfields]]\nsource = "{lf_folder}"\nposition = [0.0, -200.0]\nheight_m = 80.0\n'
    world = world_with(tmp_path, [], lfs)
    vps = [look_at((x, -470.0, 40.0), (x, 0.0, 40.0)) for x in (0.0, 20.0, 40.0)]
    with Renderer(world, SIZE, 45.0, ctx=gl.mgl) as r:
        t = techniques.create("scene", r, world=world, terrain_mode="full")
        try:
            monkeypatch.setattr(gl_lumigraph, "FloatTarget", Counted)
            t.plan_replay(set(range(500)))
            t.plan_replay({0, 1, 2})
            assert made == []
            shown, decisions = run(t, vps)
            for i in (2, 0, 1):
                assert np.abs(t.replay(vps[i], decisions[i]).astype(int)
                              - shown[i]).max() <= 1, i
            assert len(made) <= len(t.lightfields.items)   # one replay target per item
        finally:
            t.release()


def test_frames_without_a_planned_replay_log_nothing(gl, tmp_path):
    # review finding 10: the objects layer appended a list a frame even with no replay
    world = world_with(tmp_path, [([FRONT], 0.0), ([(60.0, -300.0)], 40.0)])
    vps = [look_at(EYE, AIM)] * 4
    with Renderer(world, SIZE, 45.0, ctx=gl.mgl) as r:
        t = techniques.create("scene", r, world=world, terrain_mode="full")
        try:
            run(t, vps)
            assert t.objects._log == []
            t.plan_replay({0, 1})
            shown, decisions = run(t, vps[:2])
            assert len(t.objects._log) == 2
            assert np.abs(t.replay(vps[0], decisions[0]).astype(int) - shown[0]).max() <= 1
        finally:
            t.release()


def test_render_scene_writes_the_layers_columns_and_shares(tmp_path):
    from conftest import run_cli

    scene = scene_file(tmp_path, '[[objects]]\nmesh = "ogre"\nheight_m = 30.0\ncount = 8\n'
                                 'seed = 1\nwalk_mps = 5.0\n[view]\npath = "flyover"\n')
    out = tmp_path / "run"
    done = run_cli("render", "--scene", str(scene), "--size", "64x64", "--frames", "5",
                   "--mode", "lod", "--out", str(out), "--ground-truth")
    assert done.returncode == 0, done.stderr
    header = (out / "frames.csv").read_text().splitlines()
    assert len(header) == 6
    for col in ("ms_terrain", "ms_objects", "knob_terrain", "knob_objects", "rmse"):
        assert col in header[0].split(",")
    s = json.loads((out / "summary.json").read_text())
    assert s["frames"] == 5 and {"median_ms", "p99_ms", "rmse_mean"} <= set(s)
    assert 0 < s["share_terrain"] < 1 and 0 < s["share_objects"] < 1
    assert s["share_terrain"] + s["share_objects"] <= 1.0 + 1e-9


def test_the_viewer_opens_a_scene_file_and_flies_its_layers(gl, tmp_path):
    from lodsprite.gl.target import RenderTarget
    from lodsprite.scene import open_scene
    from lodsprite.viewer.app import ViewOptions, factories
    from lodsprite.viewer.controls import CameraController
    from lodsprite.viewer.core import ViewerCore

    (tmp_path / "p0.csv").write_text(f"{FRONT[0]},{FRONT[1]}\n")
    path = scene_file(tmp_path, '[[objects]]\nmesh = "cube.off"\nheight_m = 50.0\n'
                                'points = "p0.csv"\n')
    scene = open_scene(str(path))
    assert scene.mode == "scene" and scene.objects.count == 1
    modes = factories(ViewOptions(terrain=str(path)), scene)
    assert "scene" in modes and "manager" not in modes  # no crowd modes on a world
    core = ViewerCore(gl.mgl, scene, (64, 48), modes, "scene",
                      CameraController.from_home(scene.camera_home()))
    target = RenderTarget(gl, 64, 48)
    try:
        for _ in range(2):
            core.frame(1 / 30, target.fbo)
            core.log_frame()
        assert "1 objects" in core.technique.status()
        img = core.technique.read_image()
        assert (img != img[0, 0]).any(axis=2).mean() > 0.2  # terrain, not only sky
    finally:
        core.release()
        target.release()


def test_render_scene_refuses_bad_input_in_one_line(cli, tmp_path):
    for args, words in ((("--target-fps", "30"), "--scene"),
                        (("--scene", str(tmp_path / "none.toml")), "none.toml"),
                        (("--scene", str(scene_file(tmp_path, "")), "--target-fps", "-1"),
                         "--target-fps")):
        done = cli("render", *args, "--out", str(tmp_path / "run"))
        assert done.returncode == 2, (args, done.stdout, done.stderr)
        text = (done.stdout + done.stderr).strip()
        assert words in text and len(text.splitlines()) <= 2, text
    assert not (tmp_path / "run").exists()


def test_the_reference_is_the_scene_at_full_detail(gl, tmp_path):
    from lodsprite.harness import run_path
    from lodsprite.layered.technique import reference
    from lodsprite.paths import CameraPath

    world = world_with(tmp_path, [([FRONT, BEHIND], 0.0), ([(60.0, -300.0)], 20.0)])
    path = CameraPath("t", tuple(look_at((x, -470.0, 40.0), (x, 0.0, 40.0))
                                 for x in (0.0, 20.0, 40.0)), 45.0)
    runs = {}
    with Renderer(world, SIZE, 45.0, ctx=gl.mgl) as r:
        for samples in (1, 4):
            truth, release = reference(r, world, path, samples=samples)
            try:
                for exponent in (0.0, 8.0):  # full meshes, then the coarsest LODs
                    t = techniques.create("scene", r, world=world, terrain_mode="full",
                                          exponent=exponent)
                    try:
                        runs[samples, exponent] = run_path(
                            t, path, ground_truth=True, reference=truth).summary["rmse_mean"]
                    finally:
                        t.release()
            finally:
                release()
    assert runs[1, 0.0] == 0.0      # one sample a pixel: the same scene drawn, no error
    assert runs[1, 8.0] > 0.0       # coarse LODs differ from it
    # band-limited (4x4 samples a pixel): full meshes alias a little, coarse LODs differ
    assert 0.0 < runs[4, 0.0] < runs[4, 8.0]


def test_the_cropped_reconstruction_matches_a_whole_frame_one(gl, tmp_path, lf_folder,
                                                              monkeypatch):
    """The small target through the cropped projection shows what a frame-size target
    through the frame's own projection shows (from where the lumigraph was captured)."""
    import lodsprite.layered.lightfields as lfl
    from lodsprite.lumigraph.paths import default_path
    from lodsprite.lumigraph.store import Lumigraph

    lfs = f'[[lightfields]]\nsource = "{lf_folder}"\nposition = [0.0, -300.0]\nheight_m = 120.0\n'
    world = world_with(tmp_path, [], lfs)
    lf = Lumigraph(lf_folder)
    eye, centre = default_path(lf, 2).viewpoints[0].o, lf.slabs[0].frame[:3, 3]
    images = []
    with Renderer(world, (96, 96), 45.0, ctx=gl.mgl) as r:
        r.render(look_at((0.0, -470.0, 40.0), (0.0, 0.0, 40.0)), None)
        for whole in (False, True):
            if whole:
                monkeypatch.setattr(lfl, "TARGET_SCALE", 1.0)
                monkeypatch.setattr(lfl, "screen_rect", lambda *a: (0.0, 0.0, 1.0, 1.0))
            t = techniques.create("scene", r, world=world, terrain_mode="full", nodes=16)
            try:
                m = t.lightfields.items[0].m
                vp = look_at(m[:3, :3] @ eye + m[:3, 3], m[:3, :3] @ centre + m[:3, 3])
                (img,), _ = run(t, [vp])
                if not whole:
                    x0, y0, w, h = t.lightfields.items[0].rect
                    assert 0 < w * h < 0.9  # a crop, not the whole frame
                images.append(img.astype(float))
            finally:
                t.release()
    cropped, whole = images
    assert np.abs(cropped - whole).mean() < 4.0          # the same picture, resampled
    assert np.abs(cropped - whole).max(axis=2).mean() < 8.0


VIEW = '[view]\npath = "flyover"\nsize = "48x32"\nfov = 30.0\ntarget_fps = 50.0\n'


def test_render_scene_takes_size_fov_and_target_fps_from_view(tmp_path, monkeypatch):
    # review finding 7: [view] size, fov and target_fps were validated but never used
    import lodsprite.api
    from lodsprite.layered.technique import render_scene

    scene = scene_file(tmp_path, VIEW)
    opened, created = [], []
    renderer, create = lodsprite.api.Renderer, techniques.TechniqueSpec.create

    def spy_renderer(scene_, size, fov, *args, **kwargs):
        opened.append((tuple(size), fov))
        return renderer(scene_, size, fov, *args, **kwargs)

    def spy_create(spec, r, **options):
        if spec.name == "scene":  # not the terrain layer's own technique
            created.append(options)
        return create(spec, r, **options)

    monkeypatch.setattr(lodsprite.api, "Renderer", spy_renderer)
    monkeypatch.setattr(techniques.TechniqueSpec, "create", spy_create)
    s = render_scene(scene, tmp_path / "a", frames=2, terrain_mode="lod")
    assert s["size"] == [48, 32] and opened[-1] == ((48, 32), 30.0)
    assert created[-1]["target_fps"] == 50.0 and created[-1]["schedule"] == "scheduler"
    s = render_scene(scene, tmp_path / "b", (40, 24), frames=2, terrain_mode="lod",
                     target_fps=20.0)                       # what the command gives wins
    assert s["size"] == [40, 24] and created[-1]["target_fps"] == 20.0


def test_the_viewer_takes_size_fov_and_target_fps_from_view(tmp_path):
    from lodsprite.scene import open_scene
    from lodsprite.viewer.app import ViewOptions, with_scene_view

    path = scene_file(tmp_path, VIEW)
    scene = open_scene(str(path))
    o, fov = with_scene_view(ViewOptions(terrain=str(path)), scene)
    assert o.size == (48, 32) and o.target_fps == 50.0 and fov == 30.0
    assert o.technique_options()["schedule"] == "scheduler"
    o, _ = with_scene_view(ViewOptions(terrain=str(path), size=(100, 80), target_fps=20.0),
                           scene)
    assert o.size == (100, 80) and o.target_fps == 20.0
    bare = open_scene(str(scene_file(tmp_path, "")))
    o, fov = with_scene_view(ViewOptions(terrain=str(path)), bare)
    assert o.size == (1024, 768) and o.target_fps is None and fov is None


def test_a_draw_count_setting_leaves_out_the_objects_under_its_height(gl, tmp_path):
    """The objects knob's draw counts (``CULL``): at 32 only objects whose height projects
    to 8 px or more are drawn.  The near cube (about 20 px) is, the far one (about 5 px) is
    not: the frame is that of a world without the far cube, triangles included, and at 1
    (no culling) the far cube's triangles are drawn."""
    from lodsprite.layered.objects import projected_height

    near, far = (0.0, -300.0), (0.0, 250.0)
    vp = look_at(EYE, AIM)

    def frames(folder: Path, points) -> dict:
        folder.mkdir()
        world = world_with(folder, [(points, 0.0)], ridge_m=0.0)
        out = {}
        with Renderer(world, SIZE, 45.0, ctx=gl.mgl) as r:
            t = techniques.create("scene", r, world=world, terrain_mode="full")
            try:
                t.warm_up(vp)
                out["heights"] = projected_height(t.objects.engine.centres,
                                                  np.full(len(points), 50.0), vp.o, 45.0,
                                                  SIZE[1])
                for knob in (1.0, 32.0):
                    t.objects.set_exponent(knob)
                    f = t.frame(vp)
                    out[knob] = (f.extra["visible"], t.read_image().astype(int),
                                 f.triangles)
            finally:
                t.release()
        return out

    both, alone = frames(tmp_path / "both", [near, far]), frames(tmp_path / "near", [near])
    assert both["heights"][0] > 8.0 > both["heights"][1]
    assert both[1.0][0] == 2 and both[32.0][0] == 1
    assert np.abs(both[32.0][1] - alone[32.0][1]).max() <= 1     # the far cube left out
    assert both[32.0][2] == alone[32.0][2]
    assert both[1.0][2] > alone[1.0][2]                           # ... and drawn at 1


def counting_reads(monkeypatch, clock: dict) -> None:
    """Every read of a moderngl texture, framebuffer or buffer counted in ``clock``:
    ``reads`` (names) while ``clock["running"]``, ``outside`` otherwise."""
    import moderngl

    def counted(real, what: str):
        def read(self, *args, **kwargs):
            if clock["running"]:
                clock["reads"].append(what)
            else:
                clock["outside"] += 1
            return real(self, *args, **kwargs)
        return read

    for cls in (moderngl.Texture, moderngl.Framebuffer, moderngl.Buffer):
        for name in ("read", "read_into", "read_chunks", "read_chunks_into"):
            if hasattr(cls, name):
                monkeypatch.setattr(cls, name, counted(getattr(cls, name),
                                                       f"{cls.__name__}.{name}"))


def test_no_timed_frame_reads_the_gpu_back(gl, tmp_path, lf_folder, monkeypatch):
    # issue 30, must-have 4: the light fields' replay copies were read back inside frame()
    # (LayeredTechnique.frame called every layer's decision()); every read between the
    # harness's clock start and stop is counted (its perf_counter: start, then stop)
    import time
    import types

    import lodsprite.harness as harness
    from lodsprite.paths import CameraPath

    clock = {"running": False, "reads": [], "outside": 0}

    def perf_counter() -> float:
        clock["running"] = not clock["running"]
        return time.perf_counter()

    monkeypatch.setattr(harness, "time", types.SimpleNamespace(perf_counter=perf_counter))
    counting_reads(monkeypatch, clock)
    lfs = f'[[lightfields]]\nsource = "{lf_folder}"\nposition = [0.0, -200.0]\nheight_m = 80.0\n'
    world = world_with(tmp_path, [([FRONT], 0.0), ([(60.0, -300.0)], 40.0)], lfs)
    vps = [look_at((x, -470.0, 40.0), (x, 0.0, 40.0)) for x in np.linspace(0, 60, 4)]
    with Renderer(world, SIZE, 45.0, ctx=gl.mgl) as r:
        t = techniques.create("scene", r, world=world, terrain_mode="sprite", epsilon=2.0)
        try:
            result = harness.run_path(t, CameraPath("east", tuple(vps), 45.0),
                                      ground_truth=True,
                                      reference=lambda vp: np.zeros((*SIZE[::-1], 3), np.uint8))
        finally:
            t.release()
    assert len(result.frames) == 4 and not clock["running"]
    assert clock["reads"] == []
    assert clock["outside"] >= 4          # the replay copies and images were read, untimed


def test_the_budget_weighs_each_layer_by_its_measured_coverage(gl, tmp_path, lf_folder):
    # issue 30, must-have 4: the benefits' Size was a prior (terrain 1, light fields 0.05,
    # objects' areas summed over overlaps); now each layer's coverage from its geometry
    from lodsprite.layered.coverage import TERRAIN_GRID, rects_coverage
    from lodsprite.scene.costs import object_detail

    lfs = f'[[lightfields]]\nsource = "{lf_folder}"\nposition = [0.0, -200.0]\nheight_m = 80.0\n'
    world = world_with(tmp_path, [([FRONT, (-60.0, -300.5)], 0.0)], lfs, ridge_m=80.0)
    vp = look_at(EYE, AIM)
    with Renderer(world, SIZE, 45.0, ctx=gl.mgl) as r:
        t = techniques.create("scene", r, world=world, terrain_mode="adaptive",
                              schedule="scheduler", target_fps=5.0)
        try:
            run(t, [vp, vp, vp])
            got = {n: m.benefit.coverage for n, m in t.budget.models.items()}
            rects = [item.rect for item in t.lightfields.items]
            visible = t.objects._visible()
            _, cov, summed = object_detail(
                t.objects.engine.centres, t.objects.engine.radii, vp.o, visible,
                *t.objects.engine.range, t.objects.engine.fov_y_deg, SIZE)
        finally:
            t.release()
    # the level eye at 40 m (45° view) sees ground below the horizon and the ridge, 80 m
    # high and 410 m ahead, above it up to v = 40 / 410 / tan 22.5°
    ridge_top = 40.0 / 410.0 / np.tan(np.radians(22.5))
    assert got["terrain"] == pytest.approx((1 + ridge_top) / 2, abs=1.0 / TERRAIN_GRID)
    assert got["lightfields"] == rects_coverage(rects) and got["lightfields"] > 0
    assert 0 < got["objects"] < 0.75 * summed        # the two cubes overlap: counted once


def test_the_terrain_coverage_pools_its_heights_in_the_warm_up_not_in_a_frame(
        gl, tmp_path, monkeypatch):
    # Regression: the coverage rays' max-pooled heights were made by the first timed
    # frame's plan (90 ms at 4097²); the warm-up makes them, and no frame does
    import lodsprite.layered.coverage as coverage

    real, calls = coverage.coarse_max, []

    def counted(hf):
        calls.append(phase)
        return real(hf)

    monkeypatch.setattr(coverage, "coarse_max", counted)
    world = world_with(tmp_path, [([FRONT], 0.0)])
    vps = [look_at((x, -470.0, 40.0), (x, 0.0, 40.0)) for x in np.linspace(0, 60, 6)]
    with Renderer(world, SIZE, 45.0, ctx=gl.mgl) as r:
        t = techniques.create("scene", r, world=world, terrain_mode="adaptive")
        try:
            phase = "warm-up"
            t.warm_up(vps[0])
            phase = "frames"
            for vp in vps:
                t.frame(vp)
        finally:
            t.release()
    assert calls == ["warm-up"]


def test_render_scene_saves_frames_and_strides_quality_as_render_does(tmp_path):
    """``render --scene FILE`` takes the batch driver's measurement options too: saved
    PNG frames and a quality stride (before, only --ground-truth and --flip reached it)."""
    import csv

    from conftest import run_cli

    scene = scene_file(tmp_path, VIEW)
    out = tmp_path / "run"
    r = run_cli("render", "--scene", str(scene), "--mode", "lod", "--frames", "4",
                "--ground-truth", "--quality-stride", "2", "--save-frames", "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in (out / "frames").iterdir()) == [
        *(f"frame_{i:05d}.png" for i in range(4)), *(f"ref_{i:05d}.png" for i in range(4))]
    with open(out / "frames.csv") as f:
        rows = list(csv.DictReader(f))
    assert [bool(row["rmse"]) for row in rows] == [True, False, True, False]
