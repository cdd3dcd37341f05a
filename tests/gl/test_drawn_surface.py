"""The surface a keyframe drawn by the adaptive renderer shows (the LOD-sprite metric's
``C`` in ``sprite-adaptive``, :mod:`lodsprite.techniques.drawn_surface`) is the mesh the
GPU draws: its depth buffer, unprojected, lies on it."""

import numpy as np
import pytest

from conftest import make_field
from lodsprite.camera import look_at
from lodsprite.gl.terrain import TerrainDrawer, TerrainGeometry
from lodsprite.techniques.adaptive_terrain import AdaptiveTerrain
from lodsprite.techniques.drawn_surface import DrawnSurface
from lodsprite.terrain import make_texture
from lodsprite.terrain.pyramid import MemoryPyramid

SIZE = 128


@pytest.fixture
def terrain(gl):
    hf = make_field(512, kind="ridges", relief=300.0)
    geo = TerrainGeometry(gl, hf, make_texture("terrain", hf))
    tr = TerrainDrawer(gl, geo, SIZE, SIZE)
    at = AdaptiveTerrain(gl, MemoryPyramid.from_heightfield(hf), tr.target, 45.0, 1.0,
                         grid=16, gpu_mb=16, host_mb=16, color=geo.color_tex)
    yield hf, at, tr
    at.release()
    tr.release()
    geo.release()


def _unprojected(depth: np.ndarray, view_proj: np.ndarray) -> np.ndarray:
    h, w = depth.shape
    rows, cols = np.mgrid[0:h:2, 0:w:2]
    z = depth[rows, cols]
    hit = z < 1.0
    ndc = np.stack([(cols + 0.5) / w * 2 - 1, 1 - (rows + 0.5) / h * 2, z * 2 - 1,
                    np.ones_like(z)], -1)[hit]
    world = ndc @ np.linalg.inv(view_proj).T
    return world[:, :3] / world[:, 3:]


def test_the_drawn_surface_is_the_mesh_the_adaptive_renderer_draws(terrain):
    hf, at, tr = terrain
    vp = look_at((0.0, -5000.0, 2000.0), (0.0, 0.0, 0.0))
    at.settle(vp)  # everything the view wants resident: the selection is stable
    proj = at.projection(vp)
    view_proj = proj @ vp.view_matrix()
    surface = DrawnSurface(at)
    height = surface.heights(vp.o, view_proj)
    at.frame(vp, proj)
    assert set(surface.last) == set(at.last_draw)  # the selection the draw made
    assert at.last_morphed and len({n.k for n in at.last_draw}) > 1  # morph, mixed levels
    world = _unprojected(tr.target.read_depth(), view_proj)
    err = np.abs(height(world[:, 0], world[:, 1]) - world[:, 2])
    assert len(world) > 1000
    # stated tolerance: 5 cm (depth-buffer precision at ~5 km); level 0's own samples (what
    # C was before) are off by metres wherever a coarser node is drawn
    assert not np.isnan(err).any() and err.max() < 0.05
    level0 = np.abs(hf.height_at(world[:, 0], world[:, 1]) - world[:, 2])
    assert level0.max() > 1.0


def test_points_outside_the_selection_take_the_finest_resident_node(terrain):
    hf, at, tr = terrain
    vp = look_at((0.0, -5000.0, 2000.0), (0.0, 0.0, 0.0))
    at.settle(vp)
    proj = at.projection(vp)
    surface = DrawnSurface(at)
    height = surface.heights(vp.o, proj @ vp.view_matrix())
    # behind the eye: culled from the selection, covered by resident coarse nodes
    x = np.linspace(-hf.width / 2 + 10, hf.width / 2 - 10, 50)
    y = np.full_like(x, -hf.depth / 2 + 10)
    z = height(x, y)
    assert not np.isnan(z).any()
    # the coarsest level's surface there, within its own error (metres)
    err = np.abs(z - hf.height_at(x, y))
    assert err.max() < at.tree.errors[at.tree.top] + 1e-6


def test_pointwise_heights_equal_the_whole_frozen_surface(terrain):
    """``drawn_heights`` evaluates the drawn surface at the points' cell corners only;
    it must give the surface built from every sample of every node (to float rounding)."""
    from lodsprite.sprite.proxy_surface import ProxySurface
    from lodsprite.techniques.sprite_proxy import drawn_heights, frozen_nodes

    hf, at, tr = terrain
    vp = look_at((300.0, -4000.0, 1500.0), (0.0, 0.0, 0.0))
    at.settle(vp)
    surface = DrawnSurface(at)
    eye = np.asarray(vp.o, np.float64)
    nodes, morphed = surface.selection(eye, at.projection(vp) @ vp.view_matrix())
    assert morphed and len({n.k for n in nodes}) > 1
    rng = np.random.default_rng(3)
    x = rng.uniform(-hf.width / 2, hf.width / 2, 4000)
    y = rng.uniform(-hf.depth / 2, hf.depth / 2, 4000)
    whole = ProxySurface(frozen_nodes(at, nodes, morphed, eye, 1, at.r)).height(x, y)
    points = drawn_heights(at, nodes, morphed, eye, at.r)(x, y)
    assert np.isfinite(whole).sum() > 1000  # most points on the selection
    np.testing.assert_array_equal(np.isnan(points), np.isnan(whole))
    ok = ~np.isnan(whole)
    assert np.abs(points[ok] - whole[ok]).max() < 1e-9
