"""The LOD-sprite proxy mesh: a coarse level plus border ribbons (pure numpy)."""

import numpy as np
import pytest

from lodsprite.errors import InputError
from lodsprite.terrain.heightfield import HeightField
from lodsprite.terrain.lod import level_indices
from lodsprite.terrain.proxy import border_ribbon, level_mesh, proxy_mesh


def rough_field(n: int = 32, seed: int = 3) -> HeightField:
    rng = np.random.default_rng(seed)
    return HeightField(rng.uniform(0.0, 50.0, (n + 1, n + 1)).astype(np.float32), 10.0, 10.0)


def test_level_mesh_is_the_subsampled_grid():
    hf = rough_field()
    mesh = level_mesh(hf, 8)
    idx = level_indices(hf, 8)
    rr, cc = np.meshgrid(idx, idx, indexing="ij")
    np.testing.assert_allclose(mesh.positions, hf.points(rr, cc).reshape(-1, 3), atol=1e-3)
    assert mesh.triangles == mesh.level_triangles == 2 * 8 * 8
    assert mesh.uv.min() == 0.0 and mesh.uv.max() == 1.0


def test_a_border_linear_between_coarse_vertices_needs_no_ribbon():
    r, c = np.mgrid[0:33, 0:33].astype(np.float32)
    hf = HeightField(3.0 * r + 2.0 * c, 10.0, 10.0)  # a plane: every border is a line
    assert border_ribbon(hf, 4, 0.0).triangles == 0
    assert proxy_mesh(hf, 4).triangles == level_mesh(hf, 4).triangles


def test_unsimplified_ribbon_joins_the_coarse_line_to_the_full_profile():
    hf = rough_field()
    rib = border_ribbon(hf, 4, tolerance_m=0.0)
    # Every sample of every border off its coarse line gives quads: 2 triangles each.
    step = 8
    quads = 0
    for edge in (hf.heights[0], hf.heights[-1], hf.heights[:, 0], hf.heights[:, -1]):
        k = np.arange(len(edge))
        line = np.interp(k, k[::step], edge[::step])
        off = edge != line
        quads += int(np.sum(off[:-1] | off[1:]))
    assert rib.triangles == 2 * quads
    # Unsimplified, each border contributes its n+1 line vertices then its n+1 profile
    # vertices (north, south, west, east), all in the border's vertical plane.
    n1 = hf.quads + 1
    p = rib.positions.astype(np.float64).reshape(4, 2, n1, 3)
    edges = [(hf.heights[0], 1, hf.depth / 2), (hf.heights[-1], 1, -hf.depth / 2),
             (hf.heights[:, 0], 0, -hf.width / 2), (hf.heights[:, -1], 0, hf.width / 2)]
    for e, (edge, axis, value) in enumerate(edges):
        k = np.arange(n1)
        np.testing.assert_allclose(p[e, :, :, axis], value, atol=1e-3)
        np.testing.assert_allclose(p[e, 0, :, 2], np.interp(k, k[::step], edge[::step]),
                                   atol=1e-3)
        np.testing.assert_allclose(p[e, 1, :, 2], edge, atol=1e-3)


def test_simplified_profile_keeps_coarse_vertices_and_stays_within_tolerance():
    hf = rough_field(64)
    tol = 5.0
    rib = border_ribbon(hf, 8, tolerance_m=tol)
    full = border_ribbon(hf, 8, tolerance_m=0.0)
    assert 0 < rib.triangles < full.triangles
    # South border profile vertices, in order of x.
    p = rib.positions.astype(np.float64)
    south = np.isclose(p[:, 1], -hf.depth / 2)  # (also the west and east corners)
    xs_all = np.unique(p[south, 0])
    coarse_x = hf.world_xy(np.zeros(9), level_indices(hf, 8))[0]
    assert np.all(np.isin(np.round(coarse_x, 6), np.round(xs_all, 6)))
    # Every dropped sample lies within tol (perpendicular) of the kept polyline.
    edge = hf.heights[-1].astype(np.float64)
    x = hf.world_xy(np.full(len(edge), hf.rows - 1), np.arange(len(edge)))[0]
    kept = np.isin(np.round(x, 6), np.round(xs_all, 6))
    xk, hk = x[kept], edge[kept]
    for xi, hi in zip(x[~kept], edge[~kept], strict=True):
        j = np.searchsorted(xk, xi) - 1
        a, b = np.array([xk[j], hk[j]]), np.array([xk[j + 1], hk[j + 1]])
        d = b - a
        dist = abs(d[0] * (hi - a[1]) - d[1] * (xi - a[0])) / np.hypot(*d)
        assert dist <= tol + 1e-6


def test_negative_tolerance_is_refused():
    with pytest.raises(InputError):
        border_ribbon(rough_field(), 4, tolerance_m=-1.0)
