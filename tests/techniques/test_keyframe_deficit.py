"""A keyframe knows what it lacks (issue 32, must-have 6): a keyframe drawn adaptively
while the tiles its tolerance needs are still streaming carries the screen-space error
of the coarser nodes it drew in its error, so LOD-sprite keys again as they arrive and a
still view sharpens as the adaptive renderer's does."""

from __future__ import annotations

import time

import pytest

from lodsprite import Renderer, get_path, load_scene, techniques
from lodsprite.metrics import rmse

SIZE = (96, 96)
KEY_SSE = 0.5
EPSILON = 1.0
#: The last keyframe of the still view against the adaptive renderer's settled image
#: of the same view at the same tolerance: RMSE (0-255 grey levels) at most this.
MATCH_RMSE = 1.0


@pytest.fixture
def views(store512):
    """A light scene over the store and two views far apart: ``A`` to warm up at (its
    tiles resident), ``B`` to hold still at (its tiles not yet streamed)."""
    scene = load_scene(store512, light=True)
    path = get_path("flyover", scene.hf, 20)
    return scene, path.viewpoints[0], path.viewpoints[-1], path.fov_y_deg


def sprite_adaptive(renderer, **options):
    spec = techniques.get("sprite-adaptive")
    # keyframes at scale 1: held still, what is shown is then the adaptive image itself
    return techniques.create("sprite-adaptive", renderer, **spec.bind(
        {"lod": 8, "key_sse": KEY_SSE, "epsilon": EPSILON, "key_scale": 1.0, **options}))


def settled_adaptive(renderer, viewpoint):
    """The adaptive renderer's image at ``viewpoint`` once every tile it wants arrived."""
    a = techniques.create("adaptive", renderer, sse=KEY_SSE)
    try:
        a.terrain.settle(viewpoint)
        return a.read_image().copy()
    finally:
        a.release()


def test_a_frame_drawn_before_its_tiles_arrived_lacks_pixels_and_a_settled_one_none(
        gl, views):
    scene, _, b, fov = views
    with Renderer(scene, SIZE, fov, ctx=gl.mgl) as renderer:
        a = techniques.create("adaptive", renderer, sse=KEY_SSE)
        try:
            a.terrain.frame(b)  # the roots alone resident: coarser than the tolerance
            early = a.terrain.deficit_px()
            a.terrain.settle(b)
            late = a.terrain.deficit_px()
        finally:
            a.release()
    assert early > EPSILON
    assert late == 0.0


def test_held_still_over_a_streaming_store_lod_sprite_keys_again_until_it_matches_adaptive(
        gl, views):
    scene, a, b, fov = views
    with Renderer(scene, SIZE, fov, ctx=gl.mgl) as renderer:
        t = sprite_adaptive(renderer)
        try:
            t.warm_up(a)
            keys, deadline = [], time.monotonic() + 60.0  # a guard against a hang only
            while time.monotonic() < deadline:
                f = t.frame(b)
                if f.kind == "keyframe":
                    keys.append((f.error_px, t.read_image().copy()))
                elif f.error_px < EPSILON:
                    break  # keyed until what the keyframe lacks is under ε
            last_error = f.error_px
        finally:
            t.release()
        truth = settled_adaptive(renderer, b)
    assert len(keys) >= 2  # keyed again as the tiles arrived
    first_error, first_image = keys[0]
    _, last_image = keys[-1]
    assert first_error >= EPSILON  # the first keyframe at B said what it lacked
    assert last_error < EPSILON
    assert rmse(last_image, truth) <= MATCH_RMSE
    assert rmse(first_image, truth) > 2 * MATCH_RMSE  # the control: it did lack detail


def test_without_the_deficit_the_first_keyframe_would_have_been_kept(gl, views, monkeypatch):
    """The control of the test above: with the deficit left out of the error, held still
    the keyframe of the first frame is kept (the error reads 0 px)."""
    from lodsprite.techniques.adaptive_terrain import AdaptiveTerrain

    monkeypatch.setattr(AdaptiveTerrain, "deficit_px", lambda self: 0.0)
    scene, a, b, fov = views
    with Renderer(scene, SIZE, fov, ctx=gl.mgl) as renderer:
        t = sprite_adaptive(renderer)
        try:
            t.warm_up(a)
            frames = [t.frame(b) for _ in range(8)]
        finally:
            t.release()
    assert [f.kind for f in frames].count("keyframe") == 1
    assert all(f.error_px < EPSILON for f in frames[1:])
