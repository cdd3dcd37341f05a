"""The error metric on a view-dependent proxy (Eq. 1-2, lodsprite.sprite.proxy_metric),
GL-free: the proxy's height function, the ray solve, misses and the per-frame error."""

import math

import numpy as np
import pytest

from conftest import make_field
from lodsprite.camera import fitted_projection, look_at
from lodsprite.sprite.metric import ErrorMetric
from lodsprite.sprite.proxy_metric import ProxyMetric, node_samples
from lodsprite.sprite.proxy_surface import ProxyNodes, ProxySurface, reproject_onto


def grid_proxy(hf, per: int, step: int) -> ProxyNodes:
    """``per x per`` nodes of ``hf``'s every ``step``-th sample (a uniform coarse proxy),
    each a ``G = (hf.quads / per) / step`` vertex mesh."""
    n = hf.quads // per  # samples per node side
    g = n // step
    xs, ys = hf.world_xy(np.arange(hf.cols), np.arange(hf.rows))
    origin, heights, windows = [], [], []
    for i in range(per):
        for j in range(per):
            r0, c0 = i * n, j * n
            origin.append((xs[c0], ys[r0]))
            heights.append(hf.heights[r0:r0 + n + 1:step, c0:c0 + n + 1:step].astype(float))
            windows.append((r0, r0 + n, c0, c0 + n))
    k = per * per
    return ProxyNodes(np.array(origin), np.tile([step * hf.dx, step * hf.dy], (k, 1)),
                      np.full((k, 2), float(g)), np.array(heights), np.array(windows))


def test_the_proxy_height_is_the_meshes_triangulation():
    hf = make_field(64, kind="ridges", relief=100.0)
    surf = ProxySurface(grid_proxy(hf, 2, 4))
    # every proxy vertex exactly; the mid-point of a cell's nw-se diagonal is their mean
    xs, ys = hf.world_xy(np.arange(0, 65, 4), np.arange(0, 65, 4))
    x, y = np.meshgrid(xs, ys)
    assert np.allclose(surf.height(x.ravel(), y.ravel()),
                       hf.heights[::4, ::4].ravel(), atol=1e-4)
    h = hf.heights
    mx, my = (xs[0] + xs[1]) / 2, (ys[0] + ys[1]) / 2
    assert surf.height(np.array([mx]), np.array([my]))[0] == pytest.approx(
        0.5 * (h[0, 0] + h[4, 4]), abs=1e-3)
    # a point on the sw side of the diagonal is in the (nw, sw, se) triangle
    px, py = xs[0] + 0.25 * (xs[1] - xs[0]), ys[0] + 0.75 * (ys[1] - ys[0])
    want = h[0, 0] + 0.75 * (h[4, 0] - h[0, 0]) + 0.25 * (h[4, 4] - h[4, 0])
    assert surf.height(np.array([px]), np.array([py]))[0] == pytest.approx(want, abs=1e-3)
    assert np.isnan(surf.height(np.array([xs[-1] + 50.0]), np.array([0.0])))[0]


def test_on_a_flat_terrain_c_prime_is_c():
    hf = make_field(64, kind="flat")
    nodes = grid_proxy(hf, 2, 8)
    pts = node_samples(hf, nodes.windows, np.full(len(nodes), 8), 4)
    cp, missed = reproject_onto(ProxySurface(nodes), np.array([100.0, -900.0, 700.0]), pts)
    assert not missed.any()
    assert np.array_equal(cp, pts)


def test_c_prime_lies_on_the_proxy_and_on_the_ray():
    hf = make_field(64, kind="ridges", relief=150.0)
    nodes = grid_proxy(hf, 2, 8)
    surf = ProxySurface(nodes)
    eye = np.array([0.0, -1500.0, 1500.0])
    pts = node_samples(hf, nodes.windows, np.full(len(nodes), 8), 4)
    cp, missed = reproject_onto(surf, eye, pts)
    assert (~missed).mean() > 0.95
    hit = ~missed
    dist = np.linalg.norm(pts[hit] - eye, axis=1)
    # stated accuracy: t to 2^-16 of a marching step (half a 240 m cell here): a vertical
    # residual under 1e-5 of the ray's length (2 cm at 2 km)
    assert np.all(np.abs(cp[hit, 2] - surf.height(cp[hit, 0], cp[hit, 1])) <= 1e-5 * dist)
    ray = (pts[hit] - eye) / dist[:, None]
    to_cp = cp[hit] - eye
    assert np.allclose(np.cross(ray, to_cp), 0.0, atol=1e-6 * dist.max())


class Fixed:
    def __init__(self, nodes):
        self.nodes, self.calls = nodes, []

    def __call__(self, eye, view_proj):
        self.calls.append((np.array(eye), view_proj))
        return self.nodes


def test_the_error_is_zero_at_the_keyframe_and_grows_away():
    hf = make_field(64, kind="ridges", relief=150.0)
    src = Fixed(grid_proxy(hf, 2, 8))
    metric = ProxyMetric(src, hf, ErrorMetric.for_level(hf, 8))
    key = look_at((0.0, -1500.0, 1500.0), (0.0, 0.0, 0.0))
    lo, hi = hf.bounds()

    def view(vp):
        p = fitted_projection(vp, 45.0, 1.0, lo, hi, 0.0)
        return p.matrix() @ vp.view_matrix(), p.pixel_angle_rad(256)

    kvp, beta = view(key)
    cp = metric.reproject(key.o, key_view_proj=kvp)
    assert np.array_equal(src.calls[-1][1], kvp)  # the keyframe's view reaches the source
    assert metric.error_px(cp, key.o, kvp, beta) == pytest.approx(0.0, abs=1e-9)
    errs = []
    for dx in (50.0, 150.0, 450.0):
        vp = look_at((dx, -1500.0, 1500.0), (0.0, 0.0, 0.0))
        errs.append(metric.error_px(cp, vp.o, *view(vp)))
    assert 0 < errs[0] < errs[1] < errs[2]
    # nothing in view: a keyframe is due
    away = look_at((0.0, -1500.0, 1500.0), (0.0, -3000.0, 1600.0))
    assert metric.error_px(cp, away.o, *view(away)) == math.inf


def test_samples_stand_at_mesh_cell_centres_never_on_proxy_vertices():
    hf = make_field(512, kind="ridges", relief=150.0)
    nodes = grid_proxy(hf, 32, 4)  # 1024 nodes: k shrinks to 2 under the sample limit
    pts = node_samples(hf, nodes.windows, np.full(len(nodes), 4), 4, 4096)
    assert len(pts) == 4096
    rows, cols = hf.grid_index(pts[:, 0], pts[:, 1])
    assert np.all(np.rint(rows) % 4 == 2) and np.all(np.rint(cols) % 4 == 2)
    surf = ProxySurface(nodes)
    assert np.abs(surf.height(pts[:, 0], pts[:, 1]) - pts[:, 2]).max() > 1.0


def test_the_hit_nearest_to_c_is_kept_behind_a_ridge_the_secant_would_cross():
    # a proxy one ridge: C on the far flank, the ray from a low eye crosses the near flank
    # first; the hit kept is the one nearest C (the far flank), as the uniform metric keeps
    hf = make_field(64, kind="flat")
    nodes = grid_proxy(hf, 1, 1)
    x = hf.world_xy(np.arange(65), np.arange(65))[0]
    h = 200.0 * np.exp(-(x / 200.0) ** 2)
    heights = np.broadcast_to(h[None, :], (65, 65)).copy()[None]
    nodes = type(nodes)(nodes.origin, nodes.spacing, nodes.last, heights, nodes.windows)
    surf = ProxySurface(nodes)
    c = np.array([[300.0, 0.0, surf.height(np.array([300.0]), np.array([0.0]))[0] + 5.0]])
    eye = np.array([-900.0, 0.0, 60.0])
    cp, missed = reproject_onto(surf, eye, c)
    assert not missed[0]
    assert cp[0, 0] > 0 and abs(cp[0, 0] - 300.0) < 100.0  # the far flank, near C


def test_a_keyframe_whose_proxy_has_no_node_is_due_not_a_crash():
    """A look-ahead keyframe looking off the terrain selects no proxy node: its ``C'`` is
    empty and its error ``inf`` (a keyframe is due), where the reprojection raised
    ValueError on the empty node arrays."""
    hf = make_field(64, kind="ridges", relief=150.0)
    full = grid_proxy(hf, 2, 8)
    empty = ProxyNodes(full.origin[:0], full.spacing[:0], full.last[:0], full.heights[:0],
                       full.windows[:0])
    metric = ProxyMetric(Fixed(empty), hf, ErrorMetric.for_level(hf, 8))
    key = look_at((0.0, -1500.0, 1500.0), (0.0, -3000.0, 1600.0))
    lo, hi = hf.bounds()
    p = fitted_projection(key, 45.0, 1.0, lo, hi, 0.0)
    kvp = p.matrix() @ key.view_matrix()
    cp = metric.reproject(key.o, key_view_proj=kvp)
    assert len(cp) == 0
    assert metric.error_px(cp, key.o, kvp, p.pixel_angle_rad(256)) == math.inf
