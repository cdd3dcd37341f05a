"""LOD-sprite's view-dependent proxy (the adaptive mesh frozen at each keyframe) on the real
GL driver: spriteframes at the keyframe's viewpoint, the frozen selection, the metric."""

import numpy as np
import pytest

from conftest import make_field
from lodsprite.camera import look_at
from lodsprite.gl.sprite import SpriteDrawer
from lodsprite.gl.terrain import TerrainDrawer, TerrainGeometry
from lodsprite.sprite.metric import ErrorMetric
from lodsprite.sprite.proxy_metric import ProxyMetric
from lodsprite.sprite.proxy_surface import ProxySurface
from lodsprite.techniques.adaptive_terrain import AdaptiveTerrain
from lodsprite.techniques.sprite_proxy import (
    AdaptiveProxySource,
    parent_surface,
    strided_errors,
)
from lodsprite.terrain import make_texture
from lodsprite.terrain.pyramid import MemoryPyramid
from lodsprite.terrain.quadtree import coarse_surface

SIZE = 128


@pytest.fixture
def setup(gl):
    made = []

    def make(kind="ridges", relief=150.0, proxy_sse=8.0, n=256):
        hf = make_field(n, kind=kind, relief=relief)
        geo = TerrainGeometry(gl, hf, make_texture("terrain", hf))
        tr = TerrainDrawer(gl, geo, SIZE, SIZE)
        sp = SpriteDrawer(tr, 8, "coarse", guard_px=0)
        at = AdaptiveTerrain(gl, MemoryPyramid.from_heightfield(hf), tr.target, 45.0, 1.0,
                             gpu_mb=16, host_mb=16, color=geo.color_tex)
        sp.keyframe_drawer = at.render_into
        src = AdaptiveProxySource(at, proxy_sse, SIZE)
        sp.set_proxy(src)
        made.append((src, sp, at, tr, geo))
        return hf, sp, at, src

    yield make
    for src, sp, at, tr, geo in made:
        src.release()
        sp.release()
        at.release()
        tr.release()
        geo.release()


def key_view():
    return look_at((0.0, -3000.0, 2500.0), (0.0, 0.0, 0.0))


def test_spriteframe_at_the_keyframe_viewpoint_reproduces_the_keyframe(setup):
    # As the uniform proxy does (tests/gl/test_sprite.py): the coarse z-buffer is the same
    # frozen mesh from the keyframe view, so every fragment takes the sprite.
    hf, sp, at, src = setup()
    vp = key_view()
    at.settle(vp)
    sp.render_keyframe(vp, 0.0)
    key = sp.keyframe_color().astype(int)
    assert src.triangles and src.triangles[-1] > 0
    sp.render_spriteframe(vp)
    diff = np.abs(sp.target.read_color().astype(int) - key)
    # Stated tolerance: mean difference under 0.25 grey levels, 99 % of pixels within 2.
    assert diff.mean() < 0.25
    assert np.percentile(diff.max(-1), 99) <= 2


def test_the_frozen_proxy_has_fewer_triangles_than_the_keyframe_and_stays_put(setup):
    hf, sp, at, src = setup()
    vp = key_view()
    at.settle(vp)
    sp.render_keyframe(vp, 0.0)
    key_tris = at.drawer.triangles  # the keyframe's own selection at 1 px
    proxy_tris = src.triangles[-1]
    assert 0 < proxy_tris < key_tris
    # frozen: spriteframes from elsewhere draw the frozen nodes in their view (no
    # reselection); a view away from the terrain draws none of them
    before = src.last
    other = look_at((400.0, -2500.0, 2000.0), (0.0, 0.0, 0.0))
    assert 0 < sp.render_spriteframe(other).triangles <= proxy_tris
    sky = look_at((0.0, -3000.0, 2500.0), (0.0, -6000.0, 5000.0))
    assert sp.render_spriteframe(sky).triangles == 0
    assert src.last == before
    # its nodes (and the parents they morph to) are pinned in the GPU cache
    nodes, morphed = src.last
    assert set(nodes) <= at.pinned and all(n in at.slots for n in nodes)


def _proxy_metric(setup):
    """A settled key view and the proxy metric over its frozen proxy."""
    hf, sp, at, src = setup()
    vp = key_view()
    at.settle(vp)
    proj = sp.terrain.projection(vp)
    metric = ProxyMetric(src.nodes, hf, ErrorMetric.for_level(hf, 8))
    return hf, sp, at, src, vp, proj, metric, proj.matrix() @ vp.view_matrix()


def test_the_proxy_metric_is_zero_at_the_keyframe_eye_and_grows_away(setup):
    hf, sp, at, src, vp, proj, metric, vp_key = _proxy_metric(setup)
    c_prime = metric.reproject(vp.o, key_view_proj=vp_key)
    beta = proj.pixel_angle_rad(SIZE)
    assert len(c_prime.points) > 100 and (~c_prime.missed).mean() > 0.9
    assert metric.error_px(c_prime, vp.o, vp_key, beta) == pytest.approx(0.0, abs=1e-6)
    errs = []
    for dx in (100.0, 300.0, 900.0):
        moved = look_at((dx, -3000.0, 2500.0), (0.0, 0.0, 0.0))
        p = sp.terrain.projection(moved)
        errs.append(metric.error_px(c_prime, moved.o, p.matrix() @ moved.view_matrix(), beta))
    assert 0 < errs[0] < errs[1] < errs[2]
    # the GL freeze of that keyframe takes the very selection the metric was made on
    chosen = src.select(vp.o, vp_key)
    sp.render_keyframe(vp, 0.0, proj)
    assert src.last == chosen


def test_a_tile_updates_c_prime_holds_the_samples_of_its_tiles_alone(setup):
    """``within`` (a tile update's sub-frustum): C' of the samples whose proxy nodes meet
    it, the same C' as the whole view's for those samples (the proxy frozen for the
    whole key view either way)."""
    from lodsprite.sprite.tiled import sub_view_proj

    hf, sp, at, src, vp, proj, metric, vp_key = _proxy_metric(setup)
    whole = metric.reproject(vp.o, key_view_proj=vp_key)
    corner = sub_view_proj(vp_key, np.array([0.0, 0.0, 1.0, 1.0]))  # the top-right quarter
    part = metric.reproject(vp.o, key_view_proj=vp_key, within=corner)
    assert 0 < len(part.points) < 0.6 * len(whole.points)
    # every sample of the part is one of the whole view's, with the same C'
    index = {tuple(np.round(p, 6)): i for i, p in enumerate(whole.points)}
    rows = [index[tuple(np.round(p, 6))] for p in part.points]
    np.testing.assert_allclose(np.asarray(part), np.asarray(whole)[rows], atol=1e-6)
    # and the samples in that quarter of the image are all there
    clip = whole.points_h @ corner.T
    ndc = clip[:, :2] / clip[:, 3:]
    inside = (clip[:, 3] > 0) & (np.abs(ndc) <= 0.95).all(axis=1)
    assert inside.any()
    assert set(np.flatnonzero(inside)) <= set(rows)


def test_the_proxy_metric_adds_the_resampling_term_when_asked(setup):
    """``metric="resample"`` on the view-dependent proxy: zero at the keyframe's own view
    (J = I), and above the warp-only error once the eye moves in (magnification)."""
    hf, sp, at, src = setup()
    vp = key_view()
    at.settle(vp)
    proj = sp.terrain.projection(vp)
    vp_key = proj.matrix() @ vp.view_matrix()
    beta = proj.pixel_angle_rad(SIZE)
    warp = ProxyMetric(src.nodes, hf, ErrorMetric.for_level(hf, 8))
    both = ProxyMetric(src.nodes, hf, ErrorMetric.for_level(hf, 8, resampling=True))
    assert both.resampling and not warp.resampling
    c_warp = warp.reproject(vp.o, vp_key, (SIZE, SIZE))
    c_both = both.reproject(vp.o, vp_key, (SIZE, SIZE))
    assert c_both.normals.shape == (len(c_both), 3)
    assert both.error_px(c_both, vp.o, vp_key, beta, size=(SIZE, SIZE)) == pytest.approx(
        0.0, abs=1e-6)
    closer = look_at((0.0, -1800.0, 1500.0), (0.0, 0.0, 0.0))  # 40 % nearer, same line
    p2 = sp.terrain.projection(closer)
    vp2 = p2.matrix() @ closer.view_matrix()
    e_warp = warp.error_px(c_warp, closer.o, vp2, beta)
    e_both = both.error_px(c_both, closer.o, vp2, beta, size=(SIZE, SIZE))
    # magnification 1/0.6: blur = 0.67 px at the view centre, more nearer the eye
    assert e_both > e_warp + 0.3


def test_proxy_normals_are_the_planes_normal():
    from lodsprite.sprite.proxy_surface import ProxyNodes, surface_normals

    g = 4
    rows, cols = np.mgrid[0:g + 1, 0:g + 1].astype(np.float64)
    x, y = cols * 10.0, 100.0 - rows * 10.0  # origin (0, 100), 10 m east and south
    heights = (0.3 * x - 0.2 * y)[None]  # z = 0.3 x - 0.2 y
    nodes = ProxyNodes(np.array([[0.0, 100.0]]), np.array([[10.0, 10.0]]),
                       np.array([[g, g]], np.float64), heights, np.array([[0, g, 0, g]]))
    pts = np.array([[15.0, 75.0, 0.0], [33.0, 62.0, 0.0], [500.0, 500.0, 0.0]])
    n = surface_normals(ProxySurface(nodes), pts)
    want = np.array([-0.3, 0.2, 1.0]) / np.linalg.norm([-0.3, 0.2, 1.0])
    np.testing.assert_allclose(n[:2], [want, want], atol=1e-9)
    np.testing.assert_allclose(n[2], [0.0, 0.0, 1.0])  # off the proxy


def test_the_proxy_morphs_to_its_parent_as_the_quadtree_does():
    # stride 1 is the adaptive renderer's own morph target; stride s the parent's mesh of
    # every s-th sample (even fine vertices land on it, odd ones halfway)
    rng = np.random.default_rng(1)
    parent = rng.normal(size=(65, 65))
    pos = np.stack(np.meshgrid(np.arange(65), np.arange(65), indexing="ij"), -1)
    for q in ((0, 0), (1, 1), (0, 1)):
        assert np.allclose(parent_surface(pos, q, parent, 64, 1),
                           coarse_surface(pos, q, parent, 64))
    p4 = parent_surface(pos[::4, ::4], (1, 0), parent, 64, 4)
    assert p4[0, 0] == parent[32, 0] and p4[2, 2] == parent[36, 4]
    assert p4[1, 1] == pytest.approx(0.5 * (parent[32, 0] + parent[36, 4]))
    e = strided_errors(np.array([0.0, 1.0, 3.0, 7.0]), 4)
    assert e.tolist() == [3.0, 7.0, 14.0, 28.0]


def test_the_metrics_proxy_surface_is_the_mesh_the_gpu_draws(setup):
    # The coarse z-buffer is the frozen proxy drawn from the keyframe's view; unprojected,
    # its pixels lie on ProxySurface (the metric's CPU copy: heights, stride, morph at the
    # keyframe eye, triangulation), within depth-buffer precision.
    hf, sp, at, src = setup()
    vp = key_view()
    at.settle(vp)
    sp.render_keyframe(vp, 0.0)
    key = sp.keyframe
    depth = key.coarse.read_depth()  # (H, W) window depth, row 0 at the top
    h, w = depth.shape
    rows, cols = np.mgrid[0:h:4, 0:w:4]
    z = depth[rows, cols]
    hit = z < 1.0
    ndc = np.stack([(cols + 0.5) / w * 2 - 1, 1 - (rows + 0.5) / h * 2, z * 2 - 1,
                    np.ones_like(z)], -1)[hit]
    world = ndc @ np.linalg.inv(key.view_proj).T
    world = world[:, :3] / world[:, 3:]
    nodes = src.nodes(vp.o, key.view_proj)
    surf = ProxySurface(nodes)
    err = np.abs(surf.height(world[:, 0], world[:, 1]) - world[:, 2])
    assert hit.sum() > 500
    assert src.last[1]  # some nodes morph: the morph is checked too
    # stated tolerance: every pixel within 5 cm (depth-buffer precision at ~4 km; 8 mm
    # measured; a CPU copy with the wrong stride is off by 9-65 m)
    assert not np.isnan(err).any() and err.max() < 0.05
