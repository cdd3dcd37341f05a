"""No blocking storage read on the frame's thread (issue 22, must-have 6): LOD-sprite's
level-0 heights over a store come from a reader process, and from a coarser level held
in memory until they arrive."""

from __future__ import annotations

import os
import signal
import threading
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.ndimage import map_coordinates

from lodsprite.terrain.store import TerrainStore, build_store
from lodsprite.terrain.storefield import store_field

A, B, CHECKER = 0.5, 0.25, 4.0  # the hand-made store: 100 + A r + B c ± CHECKER


@pytest.fixture(scope="module")
def ramp(tmp_path_factory):
    """A 300² store whose level 0 is a plane plus a ±4 m checkerboard: level 1 (the exact
    2×2 mean) is the plane alone, so a coarse value is told from an exact one."""
    import rasterio
    from rasterio.transform import from_origin

    d = tmp_path_factory.mktemp("nb")
    r, c = np.mgrid[0:300, 0:300]
    h = 100.0 + A * r + B * c + CHECKER * (-1.0) ** (r + c)
    with rasterio.open(d / "ramp.tif", "w", driver="GTiff", height=300, width=300, count=1,
                       dtype="float32", crs="EPSG:32614",
                       transform=from_origin(500000, 4000000, 10.0, 10.0)) as ds:
        ds.write(h.astype(np.float32), 1)
    build_store(str(d / "ramp.tif"), d / "ramp.zarr", tile=64, chunk=16)
    st = TerrainStore(d / "ramp.zarr")
    assert st.levels == 2
    return st, st.read(0, 0, 300, 0, 300).astype(np.float64)


@pytest.fixture
def reads(monkeypatch):
    """Every level read and chunk-bounds read of a store in this process, from now on:
    ``(kind, level, in_frame, thread)``; ``reads.in_frame`` is set by the test's loop."""
    log: list = []
    state = {"in_frame": False}
    read, minmax = TerrainStore.read, TerrainStore.minmax

    def spy_read(self, k, *window):
        log.append(("read", k, state["in_frame"], threading.get_ident()))
        return read(self, k, *window)

    def spy_minmax(self, k):
        log.append(("minmax", k, state["in_frame"], threading.get_ident()))
        return minmax(self, k)

    monkeypatch.setattr(TerrainStore, "read", spy_read)
    monkeypatch.setattr(TerrainStore, "minmax", spy_minmax)
    return SimpleNamespace(log=log, state=state)


def _dies_with(heights, rows, cols) -> np.ndarray:
    """Ask for ``heights[rows, cols]`` while the reader process is stopped, then kill it
    and reap it: the request dies in flight.  Returns the values given at once."""
    proc = heights.reader.worker._child.process
    os.kill(proc.pid, signal.SIGSTOP)
    first = heights[rows, cols]
    os.kill(proc.pid, signal.SIGKILL)
    proc.join(timeout=10)
    return first


def _running(pid: int) -> bool:
    """Whether process ``pid`` exists (a zombie, not yet reaped, counts)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def test_a_missing_chunk_is_answered_from_the_coarse_level_then_exactly(ramp, reads):
    st, level0 = ramp
    h = store_field(st).heights
    h.start_reader()
    assert not h.blocking and h.coarse_level == 1 and h.coarse.shape == (150, 150)
    before = len(reads.log)
    rows, cols = np.array([100, 257, 400]), np.array([50, 300, 333])
    fr, fc = rows * 299 / 512, cols * 299 / 512
    got = h[rows, cols]
    assert len(reads.log) == before  # nothing read in this process
    # level 1 sampled at the same place: the plane (level 1's sample i is level 0's 2i
    # and 2i+1 averaged, so it stands half a sample further on)
    np.testing.assert_allclose(got, 100 + A * (fr + 0.5) + B * (fc + 0.5), atol=1e-3)
    exact = map_coordinates(level0, [fr, fc], order=1)
    assert np.abs(got - exact).max() > 1.0
    assert h.approximate == 3 and not h.exact(rows, cols).any()
    assert h.settle(30.0)
    assert h.exact(rows, cols).all()
    np.testing.assert_allclose(h[rows, cols], exact, atol=1e-3)
    # four chunks: (257, 300) is level 0's (150.1, 175.2), astride chunk columns 10 and 11
    assert h.approximate == 3 and h.chunks_read == 4 and len(reads.log) == before
    r3, c3 = np.array([500]), np.array([10])  # untimed use: read here and now, exactly
    with h.waiting():
        np.testing.assert_allclose(h[r3, c3], map_coordinates(
            level0, [r3 * 299 / 512, c3 * 299 / 512], order=1), atol=1e-3)
    assert [r[:2] for r in reads.log[before:]] == [("read", 0)] and not h.blocking
    pid = h.reader.worker.pid
    h.close()
    assert not _running(pid) and h.reader is None and h.blocking
    np.testing.assert_allclose(h[rows, cols], exact, atol=1e-3)  # blocking again


def test_a_dying_reader_is_started_again_three_times_then_chunks_stay_coarse(ramp):
    st, level0 = ramp
    h = store_field(st).heights
    h.start_reader()
    try:
        for kill in range(1, 5):
            r, c = np.array([64 * kill]), np.array([20])  # level-0 chunk row 2, 4, 7, 9
            first = _dies_with(h, r, c)
            h.settle(30.0)
            assert h.reader_restarts == min(kill, 3) and h.reader.alive == (kill <= 3)
            # the chunk the process died on is unreadable: it keeps level 1's value
            assert len(h.bad) == kill and not h.exact(r, c).any()
            np.testing.assert_allclose(h[r, c], first)
            r2 = np.array([64 * kill + 32])  # the next chunk row
            h[r2, c]
            assert h.settle(30.0)
            if kill <= 3:  # a process runs again: a new chunk arrives exactly
                want = map_coordinates(level0, [r2 * 299 / 512, c * 299 / 512], order=1)
                assert h.exact(r2, c).all()
                np.testing.assert_allclose(h[r2, c], want, atol=1e-3)
            else:  # no process any more: what is asked for fails at once, stays coarse
                assert len(h.bad) == kill + 1 and not h.exact(r2, c).any()
    finally:
        h.close()


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    """A 512² store of 16² chunks (1024: more than the chunk cache holds), its level 0."""
    path = tmp_path_factory.mktemp("fl") / "s.zarr"
    build_store("fractal:512:7", path, tile=256, chunk=16)
    return path, TerrainStore(path).read(0, 0, 512, 0, 512).astype(np.float64)


def test_sprite_adaptive_reads_no_store_inside_its_frames_and_converges(gl, flight, reads,
                                                                         monkeypatch):
    """A low flyover over a coarse level of 8² squares: the metric's fallback grid
    (fewer than 4 centres in view) takes level-0 heights inside frames (its candidates'
    view test; their C is the keyframe's drawn surface); none is read in this process
    while a frame runs, and once the reader is idle they are exact."""
    from lodsprite.api import Renderer
    from lodsprite.paths import get_path
    from lodsprite.scene import load_scene
    from lodsprite.sprite import metric
    from lodsprite.techniques.adaptive import SpriteAdaptiveTechnique

    store, level0 = flight
    scene = load_scene(str(store), grid=64)
    path = get_path("flyover:100", scene.hf, 30)
    fallbacks = []
    theta = metric.ErrorMetric.fallback_sample

    def counted(self, *args, **kwargs):
        fallbacks.append(reads.state["in_frame"])
        return theta(self, *args, **kwargs)

    with Renderer(scene, (64, 64), ctx=gl.mgl) as renderer:
        # the class itself: the uniform coarse level and the warp metric (the store's
        # defaults, which techniques.create fills, draw on the adaptive proxy)
        t = SpriteAdaptiveTechnique(renderer, lod=8, epsilon=1.0, key_sse=1.0)
        h = t.heights
        pid = h.reader.worker.pid
        monkeypatch.setattr(metric.ErrorMetric, "fallback_sample", counted)
        try:
            t.warm_up(path.viewpoints[0])
            setup_chunks = h.chunks_read
            for vp in path.viewpoints:
                reads.state["in_frame"] = True
                t.frame(vp)
                reads.state["in_frame"] = False
            in_frame = [r for r in reads.log if r[2]]
            assert in_frame == []
            assert any(fallbacks) and h.approximate > 0
            summary = t.summary([])
            assert summary["level0_samples_approximate"] == h.approximate
            # the reader process's memory is counted in the run's peak
            assert summary["peak_rss_mb_level0_reader"] > 0
            assert summary["peak_rss_mb"] >= (summary["peak_rss_mb_reader"]
                                              + summary["peak_rss_mb_level0_reader"])
            # converged: pumped to idle, the fallback sample's heights are level 0's own
            m, vp = t.sprite.engine.metric, path.viewpoints[-1]
            view_proj = t.sprite.engine.policy.projection(vp).matrix() @ vp.view_matrix()
            rr, cc = m.fallback_grid(view_proj)
            assert len(rr) > 0
            assert h.settle(30.0) and h.exact(rr, cc).all()
            assert h.chunks_read > setup_chunks  # through the reader process
            s = 511 / 512
            np.testing.assert_allclose(h[rr, cc], map_coordinates(level0, [rr * s, cc * s],
                                                                  order=1), atol=1e-3)
        finally:
            t.release()
    assert not _running(pid) and h.reader is None


def test_a_sprite_made_over_the_same_level_0_keeps_the_reader_until_it_is_released(
        gl, flight, reads):
    """The viewer makes the next technique before releasing the last: plain LOD-sprite
    after sprite-adaptive takes the store's level 0 it left and reads it without blocking
    too; the reader process ends with the last of them."""
    from lodsprite import techniques
    from lodsprite.api import Renderer
    from lodsprite.paths import get_path
    from lodsprite.scene import load_scene
    from lodsprite.techniques.terrain import SpriteTechnique

    scene = load_scene(str(flight[0]), grid=64)
    path = get_path("flyover:100", scene.hf, 8)
    with Renderer(scene, (64, 64), ctx=gl.mgl) as renderer:
        first = techniques.create("sprite-adaptive", renderer, lod=8, key_sse=1.0)
        h = first.heights
        pid = h.reader.worker.pid
        # the class itself: techniques.create("sprite") over a store is sprite-adaptive
        second = SpriteTechnique(renderer, lod=8)
        first.release()
        try:
            assert second.heights is h and not h.blocking and _running(pid)
            for vp in path.viewpoints:
                reads.state["in_frame"] = True
                second.frame(vp)
                reads.state["in_frame"] = False
            assert [r for r in reads.log if r[2]] == []
        finally:
            second.release()
    assert not _running(pid) and h.reader is None and h.blocking


def _level0_reads(reads) -> int:
    return sum(1 for kind, k, _, _ in reads.log if kind == "read" and k == 0)


@pytest.mark.parametrize("proxy_sse", [None, 8.0])
def test_sprite_adaptive_setup_reads_no_level_0_and_its_c_is_the_drawn_surface(
        gl, flight, reads, proxy_sse):
    """Setup over a store of 1024 small chunks: the uniform proxy, its ribbons and the
    metric's coarse triangles come from the coarse level held whole (at most 64 level-0
    chunk reads allowed; 0 made; read through level 0 they were 846); no frame reads the
    store; each keyframe's C (uniform or proxy metric) is taken from the nodes that
    keyframe then draws (tests/gl/test_drawn_surface.py: those are the GPU's mesh)."""
    from lodsprite import techniques
    from lodsprite.api import Renderer
    from lodsprite.paths import get_path
    from lodsprite.scene import load_scene

    scene = load_scene(str(flight[0]), grid=64)
    path = get_path("flyover:100", scene.hf, 24)
    with Renderer(scene, (64, 64), ctx=gl.mgl) as renderer:
        before = _level0_reads(reads)
        t = techniques.create("sprite-adaptive", renderer, lod=8, key_sse=1.0,
                              proxy_sse=proxy_sse)
        try:
            assert _level0_reads(reads) - before <= 64
            assert _level0_reads(reads) == before and t.heights.chunks_read == 0
            assert t.heights.setup_samples > 0  # the setup's samples: the coarse level's
            calls = []
            heights = t.surface.heights

            def recorded(eye, view_proj):
                f = heights(eye, view_proj)
                calls.append((np.array(eye), set(t.surface.last), f))
                return f

            t.surface.heights = recorded
            t.sprite.engine.policy.metric = _with_surface(t.sprite.engine.policy.metric, recorded)
            t.warm_up(path.viewpoints[0])
            checked = 0
            for vp in path.viewpoints:
                reads.state["in_frame"] = True
                f = t.frame(vp)
                reads.state["in_frame"] = False
                if f.kind != "keyframe":
                    continue
                key = t.sprite.engine.keyframes[-1].viewpoint.o
                made = [c for c in calls if np.array_equal(c[0], key)]
                assert made and made[-1][1] == set(t.adaptive.last_draw)
                cp = t.sprite.engine.policy.c_prime
                pts = cp.points
                # stated tolerance: C's heights are the drawn surface's to 1 µm
                np.testing.assert_allclose(pts[:, 2], made[-1][2](pts[:, 0], pts[:, 1]),
                                           atol=1e-6)
                checked += 1
            assert checked >= 2
            assert [r for r in reads.log if r[2]] == []
        finally:
            t.release()


def _with_surface(metric, surface):
    """``metric`` taking C from ``surface``: the uniform metric is replaced; the proxy
    metric's points come from the technique's surface's ``heights``, replaced already."""
    from dataclasses import replace

    from lodsprite.sprite.proxy_metric import ProxyMetric

    return metric if isinstance(metric, ProxyMetric) else replace(metric, surface=surface)
