"""Tiled keyframes and tiled spriteframes on the real GL driver."""

import numpy as np
import pytest

from conftest import make_field
from lodsprite.camera import look_at
from lodsprite.gl.sprite import SpriteDrawer
from lodsprite.gl.terrain import TerrainDrawer, TerrainGeometry
from lodsprite.sprite.engine import KEYFRAME
from lodsprite.sprite.tiled import TILES
from lodsprite.sprite.tiled_engine import TiledSpriteEngine
from lodsprite.terrain import make_texture


@pytest.fixture
def build(gl):
    made = []

    def make(coarse=8, visibility="coarse", size=(128, 128), guard=16):
        hf = make_field(64, kind="ridges", relief=150.0)
        geo = TerrainGeometry(gl, hf, make_texture("terrain", hf))
        tr = TerrainDrawer(gl, geo, *size)
        sp = SpriteDrawer(tr, coarse, visibility, guard_px=guard)
        made.append((sp, tr, geo))
        return sp

    yield make
    for sp, tr, geo in made:
        sp.release()
        tr.release()
        geo.release()


VP = look_at((0.0, -300.0, 1500.0), (0.0, 0.0, 0.0))
VP2 = look_at((120.0, -380.0, 1450.0), (10.0, 0.0, 0.0))
VP3 = look_at((400.0, 300.0, 500.0), (0.0, -100.0, 0.0))


@pytest.mark.parametrize(("visibility", "shading"),
                         [("coarse", "texture"), ("fragment", "texture"), ("coarse", "heights")])
def test_tiles_from_one_viewpoint_equal_the_whole_keyframe(build, visibility, shading):
    # Every tile rendered from one viewpoint: the keyframe image is the whole keyframe's
    # (scissored tiles, chunks culled by sub-frusta), and the tiled spriteframe from a
    # second viewpoint equals the whole-keyframe spriteframe, fallback fragments coloured
    # by the same shading.  Stated tolerance: 99.9 % of pixels within 1 grey level, mean
    # difference under 0.05.
    sp = build(visibility=visibility)
    sp.terrain.shading = shading
    vp2 = VP2 if shading == "texture" else VP3  # VP3: many fragments VP did not see
    eng = TiledSpriteEngine(sp, 1.0, 3)
    try:
        f = eng.frame(VP)
        assert f.type == KEYFRAME and eng.last_tiles == tuple(range(9))
        tiled_key = eng.tiled.keyframe_color().astype(int)
        eng.tiled.render_spriteframe(vp2)
        tiled = sp.target.read_color().astype(int)
        sp.render_keyframe(VP, 0.0)
        key = sp.keyframe_color().astype(int)
        sp.render_spriteframe(vp2)
        whole = sp.target.read_color().astype(int)
    finally:
        eng.release()
    for a, b in ((tiled_key, key), (tiled, whole)):
        diff = np.abs(a - b).max(-1)
        assert np.percentile(diff, 99.9) <= 1
        assert diff.mean() < 0.05


def test_a_tile_rendered_from_elsewhere_changes_only_its_rectangle(build):
    # The scissor: re-rendering tile 4 from another viewpoint changes no pixel outside it.
    sp = build()
    eng = TiledSpriteEngine(sp, 1.0, 3)
    try:
        eng.frame(VP)
        before = eng.tiled.target.read_color().astype(int)
        from lodsprite.sprite.policy import KeyChoice

        eng.render_tiles([4], KeyChoice(VP2, sp.terrain.projection(VP2), False))
        after = eng.tiled.target.read_color().astype(int)
    finally:
        eng.release()
    x0, y0, x1, y1 = eng.tiled.rects[4]
    h = before.shape[0]
    inside = np.zeros(before.shape[:2], bool)
    inside[h - y1:h - y0, x0:x1] = True  # rows top-down
    changed = np.abs(after - before).max(-1) > 0
    assert changed[inside].any()
    assert not changed[~inside].any()


def test_the_replay_reproduces_the_timed_mosaic(build):
    # A short flight with a small budget renders tiles from several viewpoints; an untimed
    # replay of each frame's mosaic in a second engine gives the timed image exactly.
    sp = build(coarse=16)
    eng = TiledSpriteEngine(sp, 0.02, 3, tile_budget_ms=0.0)  # only forced tiles
    path = [look_at((20.0 * i, -300.0 - 15 * i, 1500.0 - 10 * i), (8.0 * i, 0.0, 0.0))
            for i in range(6)]
    timed, records = [], []
    try:
        for vp in path:
            f = eng.frame(vp)
            timed.append(eng.read_image())
            records.append((eng.mosaic.copy(), eng.shows_keyframe, f.type))
        assert TILES in {r[2] for r in records}
        assert len({tuple(r[0]) for r in records}) >= 3  # mosaics of several viewpoints
        shown = np.full(eng.tiled.count, -1)
        for vp, img, (mosaic, key, _) in zip(path, timed, records, strict=True):
            again = eng.replay(vp, mosaic, key, shown)
            assert np.array_equal(again, img)
    finally:
        eng.release()


def _fly(t, viewpoints) -> tuple[list, list, list]:
    """Warm ``t`` up, then fly it: ``(frames, images, decisions)``."""
    t.warm_up(viewpoints[0])
    frames, shown, decisions = [], [], []
    for vp in viewpoints:
        frames.append(t.frame(vp))
        shown.append(t.read_image())
        decisions.append(t.decision())
    return frames, shown, decisions


@pytest.mark.parametrize("name", ["sprite", "sprite-adaptive"])
def test_the_technique_replay_draws_the_timed_mosaic(gl, name):
    # Through the registry, in-memory and adaptive keyframes: each frame's image equals
    # its replay, frames replayed out of order; tiles_rendered counts every tile drawn.
    from lodsprite import Renderer, get_path, load_scene, techniques

    scene = load_scene("fractal:64:3", grid=64)
    path = get_path("chen1999", scene.hf, 12)
    with Renderer(scene, (64, 64), ctx=gl.mgl) as renderer:
        t = techniques.create(name, renderer, **techniques.get(name).bind(
            {"lod": 8, "epsilon": 0.5, "key_sse": 1.0, "tiles": 2, "tile_budget_ms": 0.0}))
        try:
            frames, shown, decisions = _fly(t, path.viewpoints)
            assert frames[0].kind == KEYFRAME and frames[0].extra["tiles"] == 4
            assert TILES in {f.kind for f in frames}
            s = t.summary(frames)
            assert s["tiles_rendered"] == sum(len(d["tiles"]) for d in decisions)
            assert s["tiles_rendered"] < 4 * len(frames)
            order = [5, 0, 11, 3, 4, 10, 1]
            for i in order:
                assert np.array_equal(t.replay(path.viewpoints[i], decisions[i]), shown[i]), i
            # the scissor holds for this technique's tile drawer too
            eng = t.engine.tiled
            before = eng.tiled.target.read_color().astype(int)
            eng.render_tiles([3], eng.updates[0])
            changed = np.abs(eng.tiled.target.read_color().astype(int) - before).max(-1) > 0
            x0, y0, x1, y1 = eng.tiled.rects[3]
            h = changed.shape[0]
            changed[h - y1:h - y0, x0:x1] = False
            assert not changed.any()
        finally:
            t.release()


def test_the_viewer_flies_tiled_lod_sprite(gl):
    # The viewer's sprite mode with tiles: frames drawn to its framebuffer (the tiled
    # keyframe's centre on the first), the status line names the tiles.
    from lodsprite import techniques
    from lodsprite.gl.target import RenderTarget
    from lodsprite.scene import open_scene
    from lodsprite.viewer.controls import CameraController
    from lodsprite.viewer.core import ViewerCore

    scene = open_scene("fractal:128:3", grid=128)
    modes = techniques.factories(scene.layers, ("distributed",), lod=16, keyframes="inline",
                                 tiles=3, tile_budget_ms=4.0)
    core = ViewerCore(gl.mgl, scene, (64, 64), modes, "sprite",
                      CameraController.from_home(scene.camera_home()))
    core.toggles["hud"] = False
    target = RenderTarget(gl, 64, 64)
    try:
        core.frame(1 / 30, target.fbo)
        first = target.read_color()
        assert np.array_equal(first, core.technique.read_image())  # the keyframe's centre
        for _ in range(2):
            core.frame(1 / 30, target.fbo)
        assert "3x3 tiles" in core.technique.status()
        assert (first != first[0, 0]).any(axis=2).mean() > 0.2  # terrain, not only sky
    finally:
        core.release()
        target.release()


@pytest.mark.parametrize("metric", ["warp", "resample"])
def test_one_tile_measures_the_whole_keyframes_error(build, metric):
    # One tile is a whole keyframe: its error at a second view equals the whole keyframe's
    # (the policy's C', resampling term through the keyframe's view and size included)
    # within 2 %; the resampling metric measures more than the warp alone there.
    from lodsprite.sprite.metric import ErrorMetric
    from lodsprite.sprite.policy import keyframe_error_px

    sp = build()
    eng = TiledSpriteEngine(sp, 1.0, 1, metric=metric)
    try:
        eng.frame(VP)
        tiled = float(eng.errors(VP2)[0][0])
    finally:
        eng.release()
    proj = sp.terrain.projection(VP)
    key_view_proj = sp.key_projection(proj).matrix() @ VP.view_matrix()
    metric_ = ErrorMetric.for_level(sp.terrain.geometry.full, sp.coarse_quads,
                                    metric == "resample")
    c_prime = metric_.reproject(VP.o, key_view_proj, sp.key_size)
    whole = keyframe_error_px(metric_, c_prime, VP2, sp.terrain.projection(VP2),
                              sp.target.height)
    assert 0 < whole < 1e3
    assert tiled == pytest.approx(whole, rel=0.02)
    if metric == "resample":
        warp = ErrorMetric.for_level(sp.terrain.geometry.full, sp.coarse_quads)
        assert whole > keyframe_error_px(warp, warp.reproject(VP.o), VP2,
                                         sp.terrain.projection(VP2), sp.target.height)


def test_the_tile_cache_serves_the_best_render_back_and_replays_it(build):
    # Tiles from VP, all re-rendered at VP2 (ε tiny, budget ample), then back at VP: every
    # tile shows its cached VP render (copied back into the mosaic) instead of a new one,
    # the image equals its replay (tiles re-rendered from VP) and the spriteframe of an
    # engine without a cache with every tile from VP; the cache stays within its budget.
    sp = build()
    eng = TiledSpriteEngine(sp, 0.02, 2, tile_budget_ms=1e4, cache_mb=1.0)
    plain = TiledSpriteEngine(sp, 0.02, 2, tile_budget_ms=1e4)
    try:
        assert eng.frame(VP).type == KEYFRAME
        assert eng.frame(VP2).type == KEYFRAME and list(eng.mosaic) == [1] * 4
        f = eng.frame(VP)
        assert f.type != KEYFRAME and eng.last_tiles == ()
        assert list(eng.mosaic) == [0] * 4 and eng.cache_tiles == 4
        assert f.error_px < 0.02
        timed = eng.read_image()
        assert eng.cache.resident_bytes <= eng.cache.budget_bytes
        assert eng.cache.resident == 8
        again = eng.replay(VP, eng.mosaic.copy(), False, np.full(4, 1))
        plain.frame(VP)
        plain.tiled.render_spriteframe(VP)
        fresh = sp.target.read_color()
    finally:
        eng.release()
        plain.release()
    assert np.array_equal(again, timed)
    assert np.array_equal(fresh, timed)


@pytest.mark.parametrize("name", ["sprite", "sprite-adaptive"])
def test_tiled_cache_through_the_registry_replays_and_hits(gl, name):
    # tiles + cache_mb + metric resample through the registry on the patrol path (back and
    # forth): some tiles are served from the cache (cache_hits > 0), fewer tiles are
    # rendered than without the cache, and every frame equals its replay.
    from lodsprite import Renderer, get_path, load_scene, techniques

    scene = load_scene("fractal:64:3", grid=64)
    path = get_path("patrol", scene.hf, 16)
    rendered = {}
    with Renderer(scene, (64, 64), ctx=gl.mgl) as renderer:
        for mb in (0.0, 4.0):
            t = techniques.create(name, renderer, **techniques.get(name).bind(
                {"lod": 8, "epsilon": 0.5, "key_sse": 1.0, "tiles": 2, "tile_budget_ms": 0.0,
                 "cache_mb": mb, "metric": "resample"}))
            try:
                frames, shown, decisions = _fly(t, path.viewpoints)
                s = t.summary(frames)
                rendered[mb] = s["tiles_rendered"]
                if mb:
                    assert s["cache_hits"] > 0 and s["cache_keyframes"] >= 4
                    assert t.engine.tiled.cache.resident_bytes <= mb * 2 ** 20
                for i in [7, 0, 15, 3, 12]:
                    assert np.array_equal(t.replay(path.viewpoints[i], decisions[i]),
                                          shown[i]), i
            finally:
                t.release()
    assert rendered[4.0] < rendered[0.0], rendered


@pytest.mark.parametrize("cache_mb", [0.0, 4.0])
def test_tiles_draw_the_view_dependent_proxy_and_replay(gl, cache_mb):
    # sprite-adaptive with --proxy-sse and tiles (and the cache): the proxy is frozen at
    # a tile update and kept until stale (mean_proxy_triangles counts the freezes), tile
    # errors use the proxy metric (finite, its own samples), and every frame equals its
    # replay out of order (each update's tiles on the proxy frozen for it).
    from lodsprite import Renderer, get_path, load_scene, techniques
    from lodsprite.sprite.proxy_metric import ProxyMetric

    scene = load_scene("fractal:256:3", grid=256)
    path = get_path("chen1999", scene.hf, 14)
    with Renderer(scene, (64, 64), ctx=gl.mgl) as renderer:
        t = techniques.create("sprite-adaptive", renderer, **techniques.get(
            "sprite-adaptive").bind({"lod": 8, "epsilon": 1.0, "key_sse": 1.0, "tiles": 2,
                                     "tile_budget_ms": 0.0, "proxy_sse": 8.0,
                                     "cache_mb": cache_mb}))
        try:
            assert isinstance(t.engine.tiled.metric, ProxyMetric)
            frames, shown, decisions = _fly(t, path.viewpoints)
            assert TILES in {f.kind for f in frames}
            assert all(np.isfinite(f.error_px) for f in frames)
            s = t.summary(frames)
            assert s["proxy_sse"] == 8.0 and s["mean_proxy_triangles"] > 0
            eng = t.engine.tiled
            assert len(t.proxy.triangles) == len(set(eng.frozen_for)) == len(eng.hold.reasons)
            for i in [6, 0, 13, 2, 9]:
                assert np.array_equal(t.replay(path.viewpoints[i], decisions[i]), shown[i]), i
        finally:
            t.release()


def test_one_tile_on_the_proxy_measures_the_whole_keyframes_proxy_error(gl):
    # The proxy metric per tile: one tile from VP is the whole keyframe there, so its error
    # at a nearby view equals the proxy metric's error of the keyframe's C' within 5 %
    # (the tile charges samples its key view lost with θ = π; near VP they are few).
    from lodsprite import Renderer, get_path, load_scene, techniques
    from lodsprite.sprite.policy import keyframe_error_px

    scene = load_scene("fractal:256:3", grid=256)
    vps = get_path("chen1999", scene.hf, 64).viewpoints
    with Renderer(scene, (64, 64), ctx=gl.mgl) as renderer:
        t = techniques.create("sprite-adaptive", renderer, lod=8, epsilon=1.0, key_sse=1.0,
                              proxy_sse=8.0)
        sp = t.sprite.sprite
        eng = TiledSpriteEngine(sp, 1.0, 1)
        try:
            eng.metric = metric = t.sprite.engine.policy.metric
            eng.tiled.use_proxy()
            eng.frame(vps[0])
            tiled = float(eng.errors(vps[1])[0][0])
            assert eng.tiled.proxy_gl is not None
            c_prime = eng.c_primes[0]
            whole = keyframe_error_px(metric, c_prime, vps[1], sp.terrain.projection(vps[1]),
                                      sp.target.height)
        finally:
            eng.release()
            t.release()
    assert len(c_prime.points) > 16 and 0 < whole < 1e3
    assert tiled == pytest.approx(whole, rel=0.05), (tiled, whole)


def test_tile_updates_keep_a_fresh_proxy_and_freeze_a_stale_one_again(gl):
    # Along a short path the updates keep the proxy frozen at the first (no new selection,
    # no new GL freeze); a view turned around, off the proxy's footprint, is stale
    # ("region") and freezes it again.  No update makes a selection for the whole view:
    # the adaptive renderer selects once per tile drawn, never for the whole view.
    from lodsprite import Renderer, get_path, load_scene, techniques
    from lodsprite.sprite.proxy_hold import ERROR, REGION

    scene = load_scene("fractal:256:3", grid=256)
    vps = get_path("chen1999", scene.hf, 64).viewpoints[:6]
    with Renderer(scene, (64, 64), ctx=gl.mgl) as renderer:
        t = techniques.create("sprite-adaptive", renderer, lod=8, epsilon=0.25, key_sse=1.0,
                              tiles=2, tile_budget_ms=0.0, proxy_sse=8.0)
        eng, adaptive = t.engine.tiled, t.adaptive
        calls = {"freeze": 0, "nodes": 0, "stream": 0}

        def counted(name, fn):
            def wrapper(*a, **k):
                calls[name] += 1
                return fn(*a, **k)
            return wrapper

        t.proxy.for_keyframe = counted("freeze", t.proxy.for_keyframe)
        t.proxy.nodes = counted("nodes", t.proxy.nodes)  # a selection made for the metric
        adaptive._stream = counted("stream", adaptive._stream)
        try:
            t.warm_up(vps[0])
            for k in calls:
                calls[k] = 0
            n0, frozen0, drawn = len(eng.updates), len(set(eng.frozen_for)), 0
            for vp in vps:
                t.frame(vp)
                drawn += len(eng.last_tiles)
            kept = [u for u, f in enumerate(eng.frozen_for) if f != u and u >= n0]
            assert len(eng.updates) > n0 + 2 and kept, eng.frozen_for
            frozen = len(set(eng.frozen_for)) - frozen0
            assert calls["freeze"] == calls["nodes"] == frozen < len(eng.updates) - n0
            assert calls["stream"] == drawn  # one selection a tile drawn, no whole view
            x, y, _ = vps[5].o  # down near the ground, looking level: the proxy's error
            low = np.array([x, y, scene.hf.height_at(x, y) + 5.0])  # bound passes 2x
            n = len(eng.updates)
            t.frame(look_at(low, low + np.r_[-vps[5].z[:2], 0.0]))
            assert len(eng.updates) == n + 1 and eng.frozen_for[-1] == n, eng.hold.reasons
            assert eng.hold.reasons[-1] in (REGION, ERROR) and calls["freeze"] == frozen + 1
        finally:
            t.release()


@pytest.mark.parametrize("threaded", [False, True], ids=["inline", "worker"])
def test_tiles_at_keyframe_scale_2_draw_what_a_whole_keyframe_draws(gl, threaded):
    """Tiles rendered at twice the display's resolution (inline, or by the worker, which
    renders its tiles at the same scale) make the keyframe a whole keyframe at scale 2
    is: the frame drawn from them is the whole keyframe's spriteframe at the same view
    (within 1 grey level; measured identical), never the keyframe shown as it is."""
    from lodsprite import Renderer, get_path, load_scene, techniques

    scene = load_scene("fractal:64:3", grid=64)
    vp = get_path("chen1999", scene.hf, 4).viewpoints[0]
    shown = {}
    with Renderer(scene, (64, 64), ctx=gl.mgl) as renderer:
        for tiles in (1, 2):
            t = techniques.create("sprite", renderer, lod=8, key_scale=2.0, tiles=tiles,
                                  tile_budget_ms=0.0, keyframes="worker"
                                  if threaded and tiles > 1 else "inline")
            try:
                t.warm_up(vp)
                t.frame(vp)
                assert not t.decision()["shows_keyframe"]
                shown[tiles] = t.read_image().astype(int)
            finally:
                t.release()
    assert np.abs(shown[1] - shown[2]).max() <= 1
