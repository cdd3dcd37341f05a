"""Served keyframes at level-0 detail: a store's keyframes and a large in-memory grid's are
drawn by the adaptive renderer (lodsprite.distributed.render.AdaptiveKeyframeService),
checked against the band-limited level-0 reference of the same view; a small grid is
still drawn whole."""

from __future__ import annotations

import numpy as np

from lodsprite.camera import look_at
from lodsprite.distributed.protocol import LoadArgs
from lodsprite.distributed.render import (
    AdaptiveKeyframeService,
    KeyframeService,
    keyframe_kind,
    keyframe_service,
)
from lodsprite.gl.reference import LevelZeroReference
from lodsprite.scene.model import load_scene
from lodsprite.terrain.store import TerrainStore

SIZE = (96, 96)
VIEW = look_at((0.0, -9000.0, 5000.0), (0.0, 0.0, 0.0))


def rmse(a, b) -> float:
    return float(np.sqrt(np.mean((np.asarray(a, float) - np.asarray(b, float)) ** 2)))


def test_stores_and_large_grids_are_drawn_adaptively_small_grids_whole(gl, store512):
    def args(terrain, grid=None):
        return LoadArgs(terrain=terrain, size=SIZE, lod=16, grid=grid, pace="continuous")

    assert [keyframe_kind(args(t)) for t in (store512, "fractal:2048:1", "fractal:1024:1")] \
        == ["adaptive", "adaptive", "whole"]
    assert keyframe_kind(args("fractal:256:1", grid=2048)) == "adaptive"  # the grid decides
    made = [keyframe_service(args(t), gl) for t in (store512, "fractal:256:1")]
    try:
        assert [type(s) for s in made] == [AdaptiveKeyframeService, KeyframeService]
        kf = made[0].render(VIEW, 3, 1.5)
        assert (kf.seq, kf.t0, kf.zbuffer) == (3, 1.5, "coarse")
        assert kf.color.shape == (SIZE[1], SIZE[0], 3) and kf.depth.shape == SIZE[::-1]
        assert kf.color.std() > 1.0  # terrain drawn
    finally:
        for s in made:
            s.release()


def test_a_store_keyframe_shows_level_zero_detail(gl, store512):
    """Seen from above, against the band-limited level 0 of the same view, the adaptive
    keyframe errs little (1.2 grey levels measured; tolerance 2.5); the same view of a 64²
    working grid (what a page was served before) errs 7.2 (more than twice the keyframe's
    tolerance)."""
    size, view = (128, 128), look_at((0.0, 0.0, 6000.0), (0.0, 100.0, 0.0))
    args = LoadArgs(terrain=store512, size=size, lod=16, grid=64, pace="continuous")
    service = AdaptiveKeyframeService(args, gl, key_sse=0.5)
    reference = LevelZeroReference(gl, TerrainStore(store512), size, 45.0, "heights")
    coarse = LevelZeroReference(gl, load_scene(store512, grid=64, textured=False).hf, size,
                                45.0, "heights")
    try:
        kf = service.render(view, 1, 0.0)
        truth = reference.image(view, kf.projection)
        assert truth.std() > 10  # terrain in view
        near = rmse(kf.color, truth)  # rows top-down, as the reference's
        far = rmse(coarse.image(view, kf.projection), truth)
        assert near < 2.5 and far > 5.0, (near, far)
        assert service.deficit_px == 0.0  # the first keyframe waits for its tiles
    finally:
        service.release()
        reference.release()
        coarse.release()
