"""LOD-sprite's full-resolution model read from a terrain store's level 0 (issue 16, 3)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import map_coordinates

from lodsprite.sprite.metric import ErrorMetric
from lodsprite.terrain.heightfield import HeightField
from lodsprite.terrain.proxy import proxy_mesh
from lodsprite.terrain.store import TerrainStore, build_store
from lodsprite.terrain.storefield import store_field, working_quads


@pytest.fixture(scope="module")
def exact(tmp_path_factory):
    """A 257² store: its working grid (256 quads) is level 0 itself."""
    path = tmp_path_factory.mktemp("sf") / "e.zarr"
    build_store("fractal:257:4", path, tile=128, chunk=32)
    st = TerrainStore(path)
    return st, st.read(0, 0, 257, 0, 257)


def test_a_power_of_two_store_is_read_exactly_and_only_the_chunks_needed(exact):
    st, level0 = exact
    f = store_field(st)
    assert f.quads == 256 and f.heights.shape == (257, 257)
    rows = np.array([0, 5, 128, 256, 31, 32])
    cols = np.array([0, 200, 128, 256, 31, 32])
    np.testing.assert_array_equal(f.heights[rows, cols], level0[rows, cols])
    # chunks (0,0), (0,6), (4,4), (8,8), (0,0) again, (1,1)
    assert f.heights.chunks_read == 5
    lo, hi = f.bounds()
    assert lo[2] == pytest.approx(level0.min()) and hi[2] == pytest.approx(level0.max())
    assert f.width == pytest.approx(256 * st.dx)


def test_proxy_and_metric_from_the_store_equal_those_of_the_level_in_memory(exact):
    st, level0 = exact
    f = store_field(st)
    mem = HeightField(level0, st.dx, st.dy)
    a, b = proxy_mesh(f, 16), proxy_mesh(mem, 16)
    np.testing.assert_array_equal(a.tris, b.tris)
    np.testing.assert_allclose(a.positions, b.positions, atol=1e-3)
    ma, mb = ErrorMetric.for_level(f, 16), ErrorMetric.for_level(mem, 16)
    np.testing.assert_allclose(ma.squares.centres, mb.squares.centres, atol=1e-6)
    # the squares' height bounds come from chunk bounds: never tighter than the samples'
    (lo_a, hi_a), (lo_b, hi_b) = ma._square_boxes, mb._square_boxes
    assert np.all(lo_a[:, 2] <= lo_b[:, 2] + 1e-4) and np.all(hi_a[:, 2] >= hi_b[:, 2] - 1e-4)
    np.testing.assert_allclose(lo_a[:, :2], lo_b[:, :2])
    eye = np.array([0.0, -3000.0, float(level0.max()) + 800.0])
    np.testing.assert_allclose(ma.reproject(eye), mb.reproject(eye), atol=1e-3)


def test_a_store_of_any_shape_is_resampled_bilinearly_over_level_0s_extent(tmp_path):
    build_store("fractal:300x190:2", tmp_path / "n.zarr", tile=128, chunk=64)
    st = TerrainStore(tmp_path / "n.zarr")
    level0 = st.read(0, 0, 300, 0, 190)
    f = store_field(st, cache_chunks=4)
    q = working_quads(300, 190)
    assert q == 512 and f.quads == 512
    assert f.width == pytest.approx(189 * st.dx) and f.depth == pytest.approx(299 * st.dy)
    rng = np.random.default_rng(0)
    r, c = rng.integers(0, q + 1, 500), rng.integers(0, q + 1, 500)
    want = map_coordinates(level0.astype(np.float64), [r * 299 / q, c * 189 / q], order=1)
    np.testing.assert_allclose(f.heights[r, c], want, rtol=1e-5, atol=1e-3)
    # a world point maps to the same level-0 place as in the adaptive renderer
    x, y = f.world_xy(np.array([q]), np.array([0]))
    assert x[0] == pytest.approx(-189 * st.dx / 2) and y[0] == pytest.approx(-299 * st.dy / 2)
    assert len(f.heights.chunks) <= 4  # the cache holds its budget
    # the in-memory level spans level 0's extent too
    hf = st.heightfield(128)
    assert hf.width == pytest.approx(f.width) and hf.depth == pytest.approx(f.depth)


def test_an_exaggerated_store_scales_heights_bounds_and_errors(exact):
    st, level0 = exact
    st2 = TerrainStore(st.path, exaggeration=2.5)
    np.testing.assert_allclose(st2.read(0, 10, 20, 30, 40), 2.5 * level0[10:20, 30:40],
                               rtol=1e-6)
    np.testing.assert_allclose(st2.minmax(1), 2.5 * st.minmax(1), rtol=1e-6)
    assert st2.level_errors[-1] == pytest.approx(2.5 * st.level_errors[-1])


def test_sprite_mode_with_adaptive_keys_takes_proxy_and_metric_from_level_0(tmp_path):
    from lodsprite.run import RenderConfig, TerrainGL, field_of_view, prepare, sprite_frames
    from lodsprite.terrain.storefield import StoreField

    build_store("fractal:513:6", tmp_path / "s.zarr", tile=256, chunk=64)
    level0 = TerrainStore(tmp_path / "s.zarr").read(0, 0, 513, 0, 513)
    cfg = RenderConfig(terrain=str(tmp_path / "s.zarr"), mode="sprite", key_sse=0.5, frames=6,
                       size=(64, 64), lod=16, grid=64)
    scene, path = prepare(cfg)
    with TerrainGL(scene, cfg.size, field_of_view(cfg, path)) as pr:
        rows = sprite_frames(pr, path, cfg)
        full = pr.geometry.full
        used = pr.geometry.proxy(16, True)[2]
    assert len(rows) == 6 and used > 0
    assert isinstance(full, StoreField) and full.quads == 512
    # the coarse vertices are level 0's samples, not the 64-quad working grid's
    z = proxy_mesh(full, 16).positions[:17 * 17, 2].reshape(17, 17)
    np.testing.assert_allclose(z, level0[::32, ::32], atol=1e-3)
    z_grid = proxy_mesh(scene.hf, 16).positions[:17 * 17, 2].reshape(17, 17)
    assert np.abs(z_grid - level0[::32, ::32]).max() > 1.0
