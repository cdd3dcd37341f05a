"""The sprite technique's engines (:mod:`lodsprite.techniques.sprite_engines`) as the
window uses them: what :meth:`draw_to` puts on a framebuffer is the frame
:meth:`read_image` gives, for whole and tiled keyframes, keyframes and spriteframes."""

from __future__ import annotations

import numpy as np
import pytest

from lodsprite import Renderer, get_path, load_scene, techniques
from lodsprite.errors import InputError
from lodsprite.sprite.tiled import TILES

SIZE = 64


@pytest.mark.parametrize("options", [{"epsilon": 16.0}, {"epsilon": 0.5, "tiles": 2,
                                                         "tile_budget_ms": 0.0}],
                         ids=["whole", "tiled"])
def test_draw_to_shows_the_frame_read_image_gives(gl, options):
    # The tiled engine once drew the warm-up's whole keyframe for every frame that was
    # not a keyframe (the inline engine beside it never drew a frame).
    scene = load_scene("fractal:64:3", grid=64)
    path = get_path("chen1999", scene.hf, 12)
    with Renderer(scene, (SIZE, SIZE), ctx=gl.mgl) as renderer:
        t = techniques.create("sprite", renderer, **techniques.get("sprite").bind(
            {"lod": 8, **options}))
        fbo = gl.mgl.simple_framebuffer((SIZE, SIZE), components=4)
        try:
            t.warm_up(path.viewpoints[0])
            kinds = set()
            for vp in path.viewpoints:
                kinds.add(t.frame(vp).kind)
                fbo.use()
                fbo.clear()
                t.draw_to(fbo)
                drawn = np.frombuffer(fbo.read(components=3), np.uint8)
                drawn = drawn.reshape(SIZE, SIZE, 3)[::-1]
                assert np.array_equal(drawn, t.read_image()), t.decision()
            assert kinds - {"keyframe"}, kinds  # spriteframes (or tile frames) drawn too
            assert "tiles" not in options or TILES in kinds
        finally:
            fbo.release()
            t.release()


def test_what_worker_tiles_cannot_do_is_an_input_error(gl):
    """Tiles from the worker keep no cache; a grid of no tiles is no grid (both refused
    before any worker process starts)."""
    scene = load_scene("fractal:64:3", grid=64)
    with Renderer(scene, (SIZE, SIZE), ctx=gl.mgl) as renderer:
        with pytest.raises(InputError, match="keep no cache"):
            techniques.create("sprite", renderer, lod=8, tiles=2, keyframes="worker",
                              cache_mb=8.0)
        with pytest.raises(InputError, match="--tiles"):
            techniques.create("sprite", renderer, lod=8, tiles=0, keyframes="worker")


@pytest.mark.parametrize("threaded", [False, True], ids=["inline", "worker"])
def test_the_depth_estimate_judges_inline_and_worker_keyframes(gl, threaded, monkeypatch):
    """With ``metric="depth"`` each keyframe, drawn here or shipped by the worker, is
    judged on its own depth: at its own viewpoint the estimate is the phase term of a
    scale-2 keyframe (0.204 px) over the samples that saw ground (sky counts 0), each
    weighted by the keyframe's contrast; the frames' errors are finite.  The worker
    builds its keyframes' estimates itself: the drawing side never does."""
    from lodsprite.sprite import depth_metric, worker_engine
    from lodsprite.sprite.depth_metric import DepthReprojection

    def built_here(*args, **kw):
        raise AssertionError("the drawing side built a worker keyframe's estimate")

    if threaded:  # the worker process builds its own (this patch does not reach it);
        # unpickling a shipped one does not call __init__
        monkeypatch.setattr(depth_metric.DepthEstimate, "__init__", built_here)

    scene = load_scene("fractal:64:3", grid=64)
    path = get_path("chen1999", scene.hf, 6)
    with Renderer(scene, (SIZE, SIZE), ctx=gl.mgl) as renderer:
        sprite = renderer.sprite(1.0, 8, threaded=threaded, depth_stride=4, key_scale=2.0,
                                 metric="depth")
        try:
            errors = [sprite.frame(vp).error_px for vp in path.viewpoints]
            engine = sprite.engine
            c_prime = engine._c_prime if threaded else engine.policy.c_prime
            assert isinstance(c_prime, DepthReprojection) and c_prime.estimate is not None
            key = engine.keyframes[-1]
            proj = renderer.terrain_gl.drawer.projection(key.viewpoint)
            est = c_prime.estimate
            m = proj.matrix() @ key.viewpoint.view_matrix()
            own = est.error_px(key.viewpoint.o, m, proj.pixel_angle_rad(SIZE), (SIZE, SIZE))
            clip = est.samples_h @ m.T
            seen = (clip[:, 3] > 0) & np.all(np.abs(clip[:, :2]) <= clip[:, 3:], axis=1)
            wts = est.weights[seen]  # by the keyframe's contrast; sky samples count 0
            ground = wts[est.ground[seen]].sum() / wts.sum()
            assert 0.2 < ground <= 1.0 and np.ptp(wts) > 0
            assert own == pytest.approx(np.sqrt(2 * (1 / 12 - 1 / 16) * ground), abs=1e-3)
            assert all(np.isfinite(errors[1:])), errors
        finally:
            sprite.release()
        started: list = []  # refused before a keyframe worker process starts
        monkeypatch.setattr(worker_engine, "KeyframeWorker", lambda *a: started.append(a))
        with pytest.raises(InputError, match="--proxy depth"):
            renderer.sprite(1.0, 8, threaded=threaded, metric="depth")
        assert started == []
