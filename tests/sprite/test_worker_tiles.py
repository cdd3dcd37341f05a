"""LOD-sprite with tiles rendered by a worker process (its own GL context)."""

from __future__ import annotations

import os
import signal
import threading

import numpy as np
import pytest
import worker_fixtures

from conftest import wait_until
from lodsprite.camera import look_at
from lodsprite.errors import InputError
from lodsprite.metrics import rmse
from lodsprite.sprite.keyframe_process import checked_tiles
from lodsprite.sprite.policy import KEYFRAME, KeyChoice
from lodsprite.sprite.tiled import TILES
from lodsprite.sprite.tiled_engine import TiledSpriteEngine
from lodsprite.sprite.worker_settings import WorkerSettings
from lodsprite.sprite.worker_tiles import WorkerTiledEngine, adopted

SIZE = worker_fixtures.SIZE
scene, sprite = worker_fixtures.scene, worker_fixtures.sprite  # the fixtures


def orbit(n: int, start_deg: float = 0.0, span_deg: float = 40.0):
    return [look_at((1400 * np.cos(a), 1400 * np.sin(a), 900), (0, 0, 100))
            for a in np.radians(np.linspace(start_deg, start_deg + span_deg, n))]


def test_only_tiles_whose_update_is_better_are_adopted():
    current = np.array([0.2, 3.0, np.inf, 1.0])
    candidate = np.array([0.1, 1.0, 9.0, 2.0])
    # tile 0 is better but was not in the update; tile 3 would get worse
    assert adopted(current, candidate, (1, 2, 3)).tolist() == [1, 2]


def test_a_tile_request_is_checked_in_the_process():
    assert checked_tiles([(3, 0)], 16) == (3, 0)
    for bad in ([], [()], [(1, 1)], [(16,)], [(-1,)], [(1.0,)], [[1]], [(1,), (2,)]):
        with pytest.raises(ValueError):
            checked_tiles(bad, 16)
    # the answer slot holds every tile's depth, RGBA colour and coarse depth
    s = WorkerSettings(SIZE, 45.0, 8, "coarse", True, 4, tiles=4)
    assert s.answer_bytes == (SIZE[0] + 8) * (SIZE[1] + 8) * 12  # depth, RGBA, coarse


def test_a_tile_read_and_uploaded_is_the_tile_rendered(gl, sprite):
    """What the worker answers (:meth:`read_tile`) written back over other renders gives
    the mosaic, its depth and its coarse z-buffer of the first render, bit for bit, and
    the coarse z-buffer drawn here when the answer has none."""
    a, b = orbit(2, span_deg=50)
    engine = TiledSpriteEngine(sprite, 0.5, 4)
    t = engine.tiled
    try:
        key = KeyChoice(a, sprite.terrain.projection(a), False)
        engine.render_tiles(range(16), key, measure=False)
        parts = [t.read_tile(i) for i in range(16)]
        want = (t.target.read_color(), t.target.read_depth(), t.coarse.read_depth())
        kp = sprite.key_projection(key.projection)
        for coarse in (True, False):
            engine.render_tiles(range(16), KeyChoice(b, sprite.terrain.projection(b), False),
                                measure=False)
            assert t.target.read_depth().tobytes() != want[1].tobytes()  # overwritten
            for i, (depth, color, zc) in enumerate(parts):
                t.upload_tile(i, a, kp, depth, color, zc if coarse else b"")
            got = (t.target.read_color(), t.target.read_depth(), t.coarse.read_depth())
            for g, w in zip(got, want, strict=True):
                np.testing.assert_array_equal(g, w)
            np.testing.assert_allclose(t.view_projs[5], kp.matrix() @ a.view_matrix())
        with pytest.raises(InputError, match="tile 0 is"):
            t.upload_tile(0, a, kp, parts[0][0][:-4], parts[0][1])
    finally:
        engine.release()


def test_worker_tiles_draw_what_inline_tiles_draw_and_only_stale_tiles_are_asked(
        gl, scene, sprite):
    path = orbit(400, span_deg=60)
    engine = WorkerTiledEngine(sprite, scene, 45.0, 0.5, 4)
    asked: list[tuple[tuple[int, ...], tuple[int, ...]]] = []  # (asked, due) a request
    request = engine.worker.request

    def spy(tiles=None):
        sent = request(tiles)
        if sent:  # the tiles at or over half ε at the view the request was made at
            errors, _ = engine.errors(engine.worker._samples[-1][1])
            due = tuple(int(i) for i in np.flatnonzero(~(errors < 0.5 * 0.5)))
            asked.append((tuple(tiles), due))
        return sent

    engine.worker.request = spy
    try:
        first = engine.frame(path[0])  # waits for every tile, rendered at path[0]
        worker_first = engine.read_image()
        frames = [first]
        it = iter(path[1:])

        def partial():  # a frame that adopted some tiles, not all
            frames.append(engine.frame(next(it)))
            return frames[-1].type == TILES and len(engine.last_tiles) < 16

        wait_until(partial, 60, "a partial tile update adopted", interval_s=0.005)
        last_vp = path[len(frames) - 1]
        live = engine.read_image()
        shown = np.full(16, -1)
        replayed = engine.replay(last_vp, engine.mosaic, False, shown)
    finally:
        engine.release()
    assert first.type == KEYFRAME and all(f.type != KEYFRAME for f in frames[1:])
    assert len(asked[0][0]) == 16 and len(asked) >= 2
    # every later request names exactly the tiles at or over half ε, not all of them
    assert all(tiles == due for tiles, due in asked[1:])
    assert any(len(tiles) < 16 for tiles, _ in asked[1:])
    # the replay renders each tile again here from the viewpoint it was rendered from
    assert rmse(replayed, live) < 0.5 and live.std() > 5
    # the worker's first update is the inline engine's first keyframe, tile by tile
    inline = TiledSpriteEngine(sprite, 0.5, 4)
    try:
        key = KeyChoice(path[0], sprite.terrain.projection(path[0]), False)
        inline.render_tiles(range(16), key, measure=False)
        inline.tiled.render_spriteframe(path[0])
        here = sprite.target.read_color()
    finally:
        inline.release()
    assert rmse(worker_first, here) < 0.5  # measured 0.0 on llvmpipe


def test_the_drawing_side_never_waits_for_a_slow_tile_worker(gl, scene, sprite):
    """A stopped worker: frames still come (under a deadline) and its tiles arrive once
    it goes on."""
    path = orbit(60, span_deg=60)
    engine = WorkerTiledEngine(sprite, scene, 45.0, 0.5, 4, request_fraction=0.0)
    pid = None
    try:
        engine.frame(path[0])
        engine.worker.wait(30.0) if engine.worker.busy else None
        pid = engine.worker.pid
        os.kill(pid, signal.SIGSTOP)
        got: list = []

        def draw() -> None:
            got.extend(engine.frame(vp) for vp in path[1:11])  # the 1st asks

        drawer = threading.Thread(target=draw, daemon=True)
        drawer.start()
        drawer.join(30.0)
        assert not drawer.is_alive(), "the drawing side waited for the stopped worker"
        assert [f.type for f in got] == ["sprite"] * 10 and engine.worker.busy
        os.kill(pid, signal.SIGCONT)
        pid = None
        update = engine.worker.wait(30.0)
        assert len(update.tiles) >= 1 and len(update.depth) == len(update.tiles)
    finally:
        if pid is not None:
            os.kill(pid, signal.SIGCONT)
        engine.release()
