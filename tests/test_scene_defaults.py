"""Store scenes load only what their mode draws, and LOD-sprite's store defaults
(issue 22, must-have 1 "peak RSS without objects the mode never uses", must-have 7)."""

from __future__ import annotations

import numpy as np
import pytest

import lodsprite.scene.model
from lodsprite.terrain.store import TerrainStore, build_store

SIDE = 512


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    path = tmp_path_factory.mktemp("light") / "s.zarr"
    build_store(f"fractal:{SIDE}:3", path, tile=256, chunk=64)
    return str(path)


@pytest.fixture
def reads(monkeypatch):
    """Every window read from a store, ``(level, rows, cols)``; the light scene's level
    capped at 257 a side (so that a 512² store stands in for a 4k² one)."""
    seen: list[tuple[int, int, int]] = []
    read = TerrainStore.read

    def spy(self, k, r0, r1, c0, c1):
        seen.append((k, r1 - r0, c1 - c0))
        return read(self, k, r0, r1, c0, c1)

    monkeypatch.setattr(TerrainStore, "read", spy)
    monkeypatch.setattr(lodsprite.scene.model, "LIGHT_SIDE", 257)
    return seen


def _whole_level0(seen) -> bool:
    return (0, SIDE, SIDE) in seen


def test_an_adaptive_run_over_a_store_never_reads_level_0_whole(store, reads):
    from lodsprite.run import RenderConfig, prepare

    cfg = RenderConfig(terrain=store, mode="adaptive", frames=4, size=(64, 64), grid=64)
    scene, _ = prepare(cfg)
    assert not _whole_level0(reads) and scene.hf.quads == 64
    assert scene.texture is None  # shaded from heights: no colour texture made
    assert max(r * c for _, r, c in reads) <= 256 * 256  # a coarse level, nothing more
    reads.clear()
    # With --ground-truth the scene stays light too: the reference is level 0 drawn by
    # gl.reference.LevelZeroReference (it reads level 0 itself, at the replay), never a
    # working grid resampled by prepare().
    scene, _ = prepare(RenderConfig(terrain=store, mode="adaptive", frames=4, size=(64, 64),
                                    grid=64, ground_truth=True))
    assert not _whole_level0(reads) and scene.hf.quads == 64


def test_the_light_scene_leaves_adaptive_images_unchanged(store, reads):
    """Same viewpoints, same settled adaptive frames: the light scene's coarse grid
    changes nothing the adaptive renderer draws (exactly equal images; exaggerated, which
    the renderer takes from the scene's field)."""
    from lodsprite import Renderer, techniques
    from lodsprite.camera import look_at
    from lodsprite.scene import load_scene

    images = []
    for light in (False, True):
        scene = load_scene(store, grid=64, exaggeration=2.0, light=light, textured=not light)
        w = scene.hf.width
        views = [look_at((0.3 * w * s, -0.6 * w, 0.4 * w), (0.0, 0.1 * w * s, 0.0))
                 for s in (-1.0, 1.0)]
        with Renderer(scene, (64, 64)) as r:
            t = techniques.create("adaptive", r)
            try:
                for vp in views:
                    t.terrain.settle(vp)
                    images.append(r.read_color())
            finally:
                t.release()
    old, new = images[:2], images[2:]
    for a, b in zip(old, new, strict=True):
        assert a.std() > 1.0  # terrain drawn, not sky
        np.testing.assert_array_equal(a, b)


def test_store_defaults_fill_what_was_not_given_and_keep_what_was(store):
    from lodsprite.run import RenderConfig
    from lodsprite.techniques.defaults import MEMORY_DEFAULTS, STORE_DEFAULTS
    from lodsprite.viewer.app import ViewOptions

    c = RenderConfig(terrain=store, mode="sprite").resolved()
    assert c.key_sse == STORE_DEFAULTS["key_sse"] == 0.5
    assert c.technique == "sprite-adaptive" and c.tiles == STORE_DEFAULTS["tiles"]
    assert RenderConfig(terrain=store, mode="sprite").technique == "sprite-adaptive"
    kept = RenderConfig(terrain=store, mode="sprite", key_sse=2.0, tiles=3, metric="resample")
    assert kept.resolved().key_sse == 2.0 and kept.technique_options()["tiles"] == 3
    assert kept.technique_options()["metric"] == "resample"
    mem = RenderConfig(terrain="fractal:64", mode="sprite").resolved()
    assert mem.key_sse is None and mem.technique == "sprite" and mem.lod == MEMORY_DEFAULTS["lod"]
    assert RenderConfig(terrain=store, mode="adaptive").resolved().key_sse is None
    v = ViewOptions(terrain=store).resolved()
    assert v.mode == "sprite-adaptive" and v.technique_options()["key_sse"] == 0.5
    assert ViewOptions(terrain=store, mode="lod").resolved().mode == "lod"
    assert ViewOptions(terrain="fractal:64").resolved().mode is None


def test_worker_keyframes_over_a_store_when_asked_and_without_the_proxy_default(store):
    """The window draws a store's adaptive keyframes inline unless --keyframes worker is
    given (in memory the worker is its default); with the worker the store's proxy_sse
    default is not filled (the proxy is frozen at inline keyframes), one given is
    refused."""
    from lodsprite.errors import InputError
    from lodsprite.run import RenderConfig
    from lodsprite.viewer.app import ViewOptions

    assert ViewOptions(terrain=store).technique_options()["keyframes"] == "inline"
    assert ViewOptions(terrain="fractal:64").technique_options()["keyframes"] == "worker"
    # tiles over a store: the worker's, without the proxy default (was inline)
    tiled = ViewOptions(terrain=store, options={"tiles": 2}).technique_options()
    assert tiled["keyframes"] == "worker" and tiled.get("proxy_sse") is None
    assert ViewOptions(terrain=store, threaded=False,
                       options={"tiles": 2}).technique_options()["keyframes"] == "inline"
    # tiles stay inline with a cache (worker tiles keep none; it was refused)
    cached = ViewOptions(terrain="fractal:64", options={"tiles": 2, "cache_mb": 16.0})
    assert cached.technique_options()["keyframes"] == "inline"
    asked = ViewOptions(terrain=store, options={"keyframes": "worker"}).technique_options()
    assert asked["keyframes"] == "worker" and asked.get("proxy_sse") is None
    c = RenderConfig(terrain=store, mode="sprite", keyframes="worker").resolved()
    assert c.technique == "sprite-adaptive" and c.proxy_sse is None and c.key_sse == 0.5
    c.validate()  # the worker over a store is no longer refused
    with pytest.raises(InputError, match="no --proxy-sse"):
        RenderConfig(terrain=store, mode="sprite", keyframes="worker", proxy_sse=4.0).validate()


def test_a_sprite_run_on_a_store_draws_adaptive_keyframes_and_reports_its_counts(
        store, tmp_path):
    from lodsprite.run import RenderConfig, render_path

    s = render_path(RenderConfig(terrain=store, mode="sprite", frames=4, size=(48, 48),
                                 grid=64), tmp_path / "run")
    assert s["key_sse"] == 0.5 and s["config"]["key_sse"] == 0.5
    assert s["keyframes"] >= 1 and s["tiles_rendered"] == s["keyframes"]
    assert s["cache_hits"] == 0
