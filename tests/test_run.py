"""lodsprite.run: what ``lodsprite render --mode sprite`` records about its keyframes."""

import csv
import json

import numpy as np
import pytest

from lodsprite.camera import Viewpoint, fitted_projection
from lodsprite.run import RenderConfig, field_of_view, prepare, render_path
from lodsprite.sprite.metric import ErrorMetric
from lodsprite.sprite.policy import keyframe_error_px


def test_sprite_frames_name_the_keyframe_they_show_and_its_viewpoint(tmp_path, gl):
    config = RenderConfig(terrain="fractal:64:3", mode="sprite", lod=8, size=(64, 64),
                          frames=40, epsilon=4.0)
    render_path(config, tmp_path)
    rows = list(csv.DictReader((tmp_path / "frames.csv").open()))
    keys = json.loads((tmp_path / "keyframes.json").read_text())["keyframes"]
    shown = [int(r["keyframe"]) for r in rows]
    assert shown[0] == 0 and shown == sorted(shown) and shown[-1] == len(keys) - 1
    assert sum(r["kind"] == "keyframe" for r in rows) == len(keys)
    for row, k in zip(rows, shown, strict=True):  # each frame's keyframe eye, in metres
        eye = [float(row[c]) for c in ("key_x", "key_y", "key_z")]
        assert np.allclose(eye, keys[k]["viewpoint"]["o"], rtol=1e-5)
    # Recompute every spriteframe's error from the logged keyframe viewpoint: it must be
    # the error the run reported (wrong if the log named another keyframe or viewpoint).
    scene, path = prepare(config)
    metric = ErrorMetric.for_level(scene.hf, config.lod)
    checked = 0
    for i, row in enumerate(rows):
        if row["kind"] == "keyframe":
            continue
        eye = Viewpoint.from_dict(keys[shown[i]]["viewpoint"]).o
        vp = path.viewpoints[i]
        projection = fitted_projection(vp, field_of_view(config, path), 1.0, *scene.hf.bounds(),
                                       float(scene.hf.height_at(vp.o[0], vp.o[1])))
        err = keyframe_error_px(metric, metric.reproject(eye), vp, projection, 64)
        # the CSV keeps 6 significant digits
        assert np.isclose(err, float(row["error_px"]), rtol=1e-4, atol=1e-6), i
        checked += 1
    assert checked > 10



def test_a_path_file_is_rendered_with_its_own_field_of_view(tmp_path):
    from lodsprite import CameraPath, Renderer, get_path, load_scene, read_image
    from lodsprite.metrics import rmse

    scene = load_scene("fractal:64", grid=64)
    vp = get_path("chen1999", scene.hf, 2).viewpoints[0]
    CameraPath("narrow", (vp, vp), fov_y_deg=30.0).to_json(tmp_path / "narrow.json")
    config = RenderConfig(terrain="fractal:64", grid=64, path=str(tmp_path / "narrow.json"),
                          size=(64, 64), save_frames=True)
    render_path(config, tmp_path / "out")
    shown = read_image(tmp_path / "out" / "frames" / "frame_00000.png")
    refs = {}
    for fov in (30.0, 45.0):
        with Renderer(scene, (64, 64), fov) as r:
            r.render(vp)
            refs[fov] = r.read_color()
    assert rmse(shown, refs[30.0]) < 0.5 < rmse(shown, refs[45.0])


def test_a_renderer_releases_the_context_it_made_and_its_sprites():
    from lodsprite import Renderer, load_scene

    with Renderer(load_scene("fractal:64", grid=64), (32, 32)) as r:
        gl = r.gl
        sprite = r.sprite()
    assert gl.mgl is None and r.gl is None  # the EGL context was released
    assert sprite.sprite is None  # and the sprite with it
    sprite.release()  # a second release is harmless


def test_a_renderer_that_fails_to_build_releases_the_context_it_made(monkeypatch):
    from lodsprite import Renderer, load_scene
    from lodsprite.errors import InputError
    from lodsprite.gl import terrain_gl as gl_state
    from lodsprite.gl.context import GLContext

    released = []
    real_release = GLContext.release
    monkeypatch.setattr(GLContext, "release",
                        lambda self: (released.append(self), real_release(self)))

    def no_renderer(*args, **kwargs):
        raise InputError("no renderer today")

    monkeypatch.setattr(gl_state, "TerrainDrawer", no_renderer)
    with pytest.raises(InputError, match="no renderer today"):
        Renderer(load_scene("fractal:64", grid=64), (32, 32))
    assert released and released[-1].mgl is None


def test_a_framebuffer_with_an_offset_viewport_is_refused(gl):
    from lodsprite import Renderer, load_scene
    from lodsprite.errors import InputError
    from lodsprite.gl.target import RenderTarget

    target = RenderTarget(gl, 64, 64)
    try:
        target.fbo.viewport = (8, 8, 48, 48)
        with pytest.raises(InputError, match="viewport"):
            Renderer(load_scene("fractal:64", grid=64), ctx=gl.mgl, framebuffer=target.fbo)
    finally:
        target.release()
