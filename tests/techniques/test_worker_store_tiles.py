"""Tiles from the keyframe worker over a terrain store (issue 32, must-have 3): the
process draws each tile asked for with its own adaptive renderer; each comes with what
it lacks, in its error until the tiles it needs have arrived, and with the selection it
was drawn with, which the untimed replay draws again."""

from __future__ import annotations

import time

import numpy as np
import pytest

from lodsprite import Renderer, get_path, load_scene, techniques
from lodsprite.metrics import rmse
from lodsprite.sprite.tiled import TILES

SIZE = (96, 96)


@pytest.fixture
def scene(store512):
    return load_scene(store512, light=True)


def test_worker_tiles_over_a_store_sharpen_as_tiles_arrive_and_replay_what_was_drawn(
        gl, scene):
    path = get_path("flyover", scene.hf, 20)
    a, b = path.viewpoints[0], path.viewpoints[-1]
    spec = techniques.get("sprite-adaptive")
    with Renderer(scene, SIZE, path.fov_y_deg, ctx=gl.mgl) as renderer:
        t = techniques.create("sprite-adaptive", renderer, **spec.bind(
            {"lod": 8, "key_sse": 0.5, "keyframes": "worker", "tiles": 2, "epsilon": 1.0}))
        try:
            t.warm_up(a)
            tiled = t.engine.tiled
            lacked: list[float] = []
            deadline = time.monotonic() + 60.0  # a guard against a hang only
            while time.monotonic() < deadline:  # held still where nothing is resident
                f = t.frame(b)
                if f.kind == TILES:
                    lacked.append(float(tiled.deficits.max()))
                    assert f.error_px >= 0.0
                if lacked and tiled.deficits.max() < 0.5 and not tiled.worker.busy:
                    break
                time.sleep(0.01)
            shown = []
            for vp in path.viewpoints:
                f = t.frame(vp)
                shown.append((vp, f, t.decision(), t.read_image().copy()))
                time.sleep(0.01)
            replays = [rmse(t.replay(vp, d), image) for vp, _, d, image in shown]
        finally:
            t.release()
    # what the first tiles drawn at b lacked was in their error; the last lack none
    assert max(lacked) > 1.0 and lacked[-1] < 1.0
    assert all(f.kind != "keyframe" for _, f, _, _ in shown)
    # every tile shown came with the worker's selection, which the replay draws again
    used = {(int(u), i) for _, _, d, _ in shown for i, u in enumerate(d["mosaic"])}
    assert used <= set(tiled.selections)
    assert max(replays) < 0.5 and np.std(shown[-1][3]) > 5
