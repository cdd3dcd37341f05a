"""LOD-sprite with keyframes from a worker thread (its own GL context)."""

from __future__ import annotations

import itertools
import threading

import numpy as np
import pytest

from conftest import make_field, wait_until
from lodsprite.camera import look_at
from lodsprite.errors import LodspriteError
from lodsprite.gl.sprite import SpriteDrawer
from lodsprite.gl.terrain import TerrainDrawer, TerrainGeometry
from lodsprite.metrics import rmse
from lodsprite.scene import Scene
from lodsprite.sprite.engine import KEYFRAME, LodSpriteEngine
from lodsprite.sprite.keyframe_worker import KeyframeWorker, WorkerSettings
from lodsprite.sprite.threaded import ThreadedLodSpriteEngine
from lodsprite.terrain import make_texture

SIZE = (96, 96)


@pytest.fixture
def scene() -> Scene:
    hf = make_field(64, kind="ridges")
    return Scene(hf, make_texture("terrain", hf), "ridges", "terrain")


@pytest.fixture
def sprite(gl, scene):
    geo = TerrainGeometry(gl, scene.hf, scene.texture)
    tr = TerrainDrawer(gl, geo, *SIZE)
    sp = SpriteDrawer(tr, 8, guard_px=4)
    yield sp
    sp.release()
    tr.release()
    geo.release()


def orbit(n: int, start_deg: float = 0.0, span_deg: float = 40.0):
    out = []
    for a in np.radians(np.linspace(start_deg, start_deg + span_deg, n)):
        out.append(look_at((1400 * np.cos(a), 1400 * np.sin(a), 900), (0, 0, 100)))
    return out


def worker_threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name == "lodsprite-keyframes"]


def test_a_worker_keyframe_draws_the_same_spriteframe_as_an_inline_one(gl, scene, sprite):
    vp = orbit(1)[0]
    engine = ThreadedLodSpriteEngine(sprite, scene, 45.0, 1.0)
    try:
        first = engine.frame(vp)  # waits for the worker's first keyframe, at vp
        threaded = engine.read_image()
    finally:
        engine.close()
    assert first.type == KEYFRAME and len(engine.keyframes) == 1
    np.testing.assert_allclose(engine.keyframes[0].viewpoint.o, vp.o)
    inline = LodSpriteEngine(sprite, 1.0, predict=False)
    inline.frame(vp)
    sprite.render_spriteframe(vp)
    local = sprite.target.read_color()
    # Same keyframe, one rendered on the worker's context and uploaded, one rendered here:
    # the spriteframes differ by no more than rounding (measured 0.0 on llvmpipe).
    assert rmse(threaded, local) < 0.5
    assert threaded.std() > 5  # a picture, not a cleared target


def test_frames_go_on_while_the_worker_renders_and_it_stops_on_close(gl, scene, sprite):
    path = orbit(40)
    engine = ThreadedLodSpriteEngine(sprite, scene, 45.0, 0.5)
    try:
        frames = [engine.frame(vp) for vp in path]
        # let the worker finish what it was asked for, then take it
        engine.worker.wait(30.0) if engine.worker.busy else None
    finally:
        engine.close()
    assert not worker_threads()
    assert frames[0].type == KEYFRAME
    assert all(f.type != KEYFRAME for f in frames[1:])  # the drawing thread never renders one
    assert engine.worker.rendered >= 2  # keyframes were asked for along the orbit
    assert engine.worker.error is None
    # errors are measured per frame; the first is the keyframe's own view
    assert frames[0].error_px == pytest.approx(0.0, abs=1e-6)
    assert all(np.isfinite(f.error_px) for f in frames)


def test_an_adopted_keyframe_is_never_worse_than_the_one_shown(gl, scene, sprite):
    engine = ThreadedLodSpriteEngine(sprite, scene, 45.0, 0.5)
    views = itertools.cycle(orbit(600, span_deg=60))  # slowly: keyframes arrive on the way
    adopted = []

    def adopt_three() -> bool:
        vp = next(views)
        before = engine.error_px(vp, sprite.terrain.projection(vp))
        f = engine.frame(vp)
        if f.type == "first_sprite":
            adopted.append((f.error_px, before))
        return len(adopted) >= 3

    try:
        wait_until(adopt_three, 60, "three keyframes adopted", interval_s=0.002)
    finally:
        engine.close()
    assert all(shown < before for shown, before in adopted)  # never worse


def test_a_worker_that_cannot_start_says_why(gl, scene):
    with pytest.raises(LodspriteError, match="could not start"):
        KeyframeWorker(scene, WorkerSettings((1 << 20, 16), 45.0, 8, "coarse", True, 0))
    assert not worker_threads()


def test_an_unknown_predictor_is_refused(scene):
    with pytest.raises(LodspriteError, match="predictor"):
        KeyframeWorker(scene, WorkerSettings((64, 64), 45.0, 8, "coarse", True, 0, "psychic"))


def test_the_lead_comes_from_every_delivered_keyframe_not_the_start_up_one(gl, scene, sprite):
    vp = orbit(1)[0]
    engine = ThreadedLodSpriteEngine(sprite, scene, 45.0, 1.0, request_fraction=0.0)
    try:
        engine.frame(vp)  # start-up: waited for, not a measure of the latency
        assert engine.worker.lead_s == 0.0
        # the viewer stays put: every new keyframe is no better, and is discarded
        wait_until(lambda: (engine.frame(vp), engine.discarded)[1], 60,
                   "a keyframe discarded", interval_s=0.005)
        assert engine.discarded >= 1 and len(engine.keyframes) == 1
        # a discarded keyframe still says how long keyframes take to arrive
        assert engine.worker.lead_s > 0.0
    finally:
        engine.close()


def test_frames_say_so_when_the_worker_has_died(gl, scene, sprite, monkeypatch):
    from lodsprite.sprite import keyframe_worker as worker_module

    engine = ThreadedLodSpriteEngine(sprite, scene, 45.0, 1.0, request_fraction=0.0)
    try:
        engine.frame(orbit(1)[0])

        def broken(self, target, asked):
            raise RuntimeError("the GL context was lost")

        monkeypatch.setattr(worker_module._WorkerGL, "render", broken)
        views = itertools.cycle(orbit(400))  # keyframes are asked for every frame
        with pytest.raises(LodspriteError, match="worker stopped: the GL context was lost"):
            wait_until(lambda: engine.frame(next(views)) and False, 60,
                       "a frame that says the worker died", interval_s=0.002)
    finally:
        engine.close()


def test_the_worker_gives_the_resample_metric_its_keyframe_matrix_and_size(gl, scene, sprite):
    path = orbit(6, span_deg=10)
    engine = ThreadedLodSpriteEngine(sprite, scene, 45.0, 1.0, metric="resample")
    try:
        frames = [engine.frame(vp) for vp in path]
        cp = engine._c_prime
    finally:
        engine.close()
    assert engine.metric.resampling
    assert cp.key_size == (SIZE[0] + 8, SIZE[1] + 8) and cp.key_view_proj.shape == (4, 4)
    # at the keyframe's own view the resampling term is 0 too (guard band included)
    assert frames[0].error_px == pytest.approx(0.0, abs=1e-6)
    assert all(np.isfinite(f.error_px) for f in frames)


def test_the_inline_engine_decides_with_the_resample_metric(gl, scene, sprite):
    path = orbit(12, span_deg=20)
    warp, res = (LodSpriteEngine(sprite, 0.5, predict=False, metric=m)
                 for m in ("warp", "resample"))
    assert res.policy.key_size == (SIZE[0] + 8, SIZE[1] + 8) and res.metric.resampling
    fw = [warp.frame(vp) for vp in path]
    fr = [res.frame(vp) for vp in path]
    # the same first keyframe; the resampling term only adds to the error of what follows
    assert fw[1].extra["decision_error_px"] < fr[1].extra["decision_error_px"]
    assert sum(f.type == KEYFRAME for f in fr) >= sum(f.type == KEYFRAME for f in fw)
