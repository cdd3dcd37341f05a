"""LOD-sprite's adaptive keyframes from the worker process over a terrain store (issue
32, must-have 2): the process opens the store and draws each keyframe with its own
adaptive renderer; the drawing side never waits for it after the first, its error adds
what a keyframe lacks, and the untimed replay draws the selection the worker drew."""

from __future__ import annotations

import os
import signal
import time

import pytest

from lodsprite import Renderer, get_path, load_scene, techniques
from lodsprite.errors import InputError
from lodsprite.metrics import rmse

SIZE = (96, 96)
KEY_SSE = 0.5


@pytest.fixture
def scene(store512):
    return load_scene(store512, light=True)


def worker_technique(renderer, **options):
    spec = techniques.get("sprite-adaptive")
    return techniques.create("sprite-adaptive", renderer, **spec.bind(
        {"lod": 8, "key_sse": KEY_SSE, "keyframes": "worker", **options}))


def hold_still(t, viewpoint) -> list[float]:
    """Frames at ``viewpoint`` until the keyframe shown is under ε/2 and none is on its
    way; what each keyframe adopted there lacked (pixels)."""
    engine = t.engine.sprite.engine
    deficits, deadline = [], time.monotonic() + 60.0  # a guard against a hang only
    while time.monotonic() < deadline:
        f = t.frame(viewpoint)
        if f.kind == "first_sprite":
            deficits.append(engine.deficit_px)
            assert f.error_px >= engine.deficit_px  # the error carries it
        if deficits and f.error_px < 0.5 and not engine.worker.busy:
            break
        time.sleep(0.01)
    return deficits


def fly(t, viewpoints) -> list:
    """Each view's frame, decision and image, the path played with a pause a frame (the
    worker gets its turn)."""
    shown = []
    for vp in viewpoints:
        f = t.frame(vp)
        shown.append((vp, f, t.decision(), t.read_image().copy()))
        time.sleep(0.01)
    return shown


def stopped_frames(t, viewpoints, seconds: float) -> list:
    """Frames drawn for ``seconds`` with the worker process stopped (SIGSTOP), every one
    asking for a keyframe; it goes on after."""
    worker = t.engine.sprite.engine.worker
    os.kill(worker.pid, signal.SIGSTOP)
    try:
        t.engine.set_epsilon(0.01)
        frames, deadline = [], time.monotonic() + seconds
        while time.monotonic() < deadline:
            frames.append(t.frame(viewpoints[len(frames) % len(viewpoints)]))
        assert worker.busy  # a keyframe was asked for and is not coming
    finally:
        os.kill(worker.pid, signal.SIGCONT)
    return frames


def test_the_worker_over_a_store_keys_what_it_lacks_replays_honestly_and_never_blocks(
        gl, scene):
    """Warmed up at one view and held still at another whose tiles are not resident:
    the worker's first keyframe there lacks pixels (in the frames' error), the last under
    ε.  Along a path, each keyframe comes with the selection it was drawn with, which the
    replay draws again to the image shown.  With the worker stopped, frames keep coming
    until a deadline (no count fixed ahead), every one a spriteframe; it goes on after."""
    path = get_path("flyover", scene.hf, 20)
    a, b = path.viewpoints[0], path.viewpoints[-1]
    with Renderer(scene, SIZE, path.fov_y_deg, ctx=gl.mgl) as renderer:
        t = worker_technique(renderer, epsilon=1.0)
        try:
            t.warm_up(a)
            engine = t.engine.sprite.engine
            worker = engine.worker
            deficits = hold_still(t, b)
            t.engine.set_epsilon(0.5)
            shown = fly(t, path.viewpoints)
            replays = [rmse(t.replay(vp, d), image) for vp, _, d, image in shown]
            rendered = worker.rendered
            stopped = stopped_frames(t, path.viewpoints, 1.0)
            deadline = time.monotonic() + 60.0  # a guard against a hang only
            while worker.rendered <= rendered and time.monotonic() < deadline:
                t.frame(b)
                time.sleep(0.01)
        finally:
            t.release()
    assert max(deficits) > 1.0 and deficits[-1] < 1.0
    assert all(f.kind != "keyframe" for _, f, _, _ in shown)  # spriteframes only here
    assert len(engine.keyframes) >= 3
    # each keyframe came with the worker's adaptive selection, for the replay
    assert len(engine.selections) == len(engine.keyframes)
    assert all(s is not None for s in engine.selections)
    assert max(replays) < 0.5  # the replay redraws what the worker drew
    assert len(stopped) >= 3 and all(f.kind != "keyframe" for f in stopped)
    assert worker.rendered > rendered and worker.error is None


def test_what_the_worker_does_not_take_is_refused_in_one_line(gl, scene):
    with Renderer(scene, SIZE, ctx=gl.mgl) as renderer:
        with pytest.raises(InputError, match="no proxy_sse"):
            worker_technique(renderer, proxy_sse=8.0)
