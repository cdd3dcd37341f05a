"""Every reconstruction method of §3-4 covers what it draws with alphas summing to one,
on the real GL driver (each method rendered with white node images: the image is the
alpha sum)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import binary_dilation, binary_erosion

from lodsprite.camera import look_at, perspective
from lodsprite.gl.lumigraph import ColorMeshDrawer
from lodsprite.gl.target import RenderTarget
from lodsprite.lumigraph.capture import capture, textured_plane
from lodsprite.lumigraph.geometry import Slab
from lodsprite.lumigraph.methods import METHODS, Context, make_method
from lodsprite.lumigraph.store import Lumigraph, node_name, save

SIZE = 80
# Half floats round each addition by up to 2.4e-4 near one, and a pixel near fictitious
# corners or fading nodes sums up to ~10 draws.
TOL = 4e-3


@pytest.fixture
def lf_folder(gl, tmp_path):
    slab = Slab(np.eye(4), st_size=3.0, uv_size=2.0, st_distance=2.5, n_st=8, n_uv=32)
    plane = textured_plane(2.0, 8)
    obj = ColorMeshDrawer(gl, plane.vertices, plane.faces, plane.colors, plane.normals)
    target = RenderTarget(gl, 32, 32)
    try:
        images = capture(obj, slab, target, near=0.1, far=10.0)
    finally:
        target.release()
        obj.release()
    save(tmp_path / "lf", [slab], [images], plane, "plane", 0.1, 10.0, codec="png")
    return tmp_path / "lf"


def arc(n=6, distance=4.2):
    return [look_at((0.1 * k - 0.25, 0.05 * k - 0.1, distance), (0.0, 0.0, 0.0),
                    up=(0.0, 1.0, 0.0)) for k in range(n)]


def st_plane_seen(vp, proj, slab: Slab) -> np.ndarray:
    """Pixels whose ray crosses the st square (slab frame = world), analytically."""
    inv = np.linalg.inv(proj @ vp.view_matrix())
    y, x = np.mgrid[0:SIZE, 0:SIZE]
    ndc = np.stack([(x + 0.5) / SIZE * 2 - 1, 1 - (y + 0.5) / SIZE * 2, np.ones_like(x, float),
                    np.ones_like(x, float)], -1)
    far = ndc @ inv.T
    far = far[..., :3] / far[..., 3:]
    d = far - vp.o
    k = (slab.st_distance - vp.o[2]) / d[..., 2]
    hit = vp.o[:2] + k[..., None] * d[..., :2]
    return (np.abs(hit) <= slab.st_size / 2).all(axis=-1) & (k > 0)


def run(gl, folder, method, views, **opts):
    lf = Lumigraph(folder)
    proxy_mesh = lf.proxy()
    proxy = ColorMeshDrawer(gl, proxy_mesh.vertices, proxy_mesh.faces, proxy_mesh.colors,
                              proxy_mesh.normals)
    m = make_method(method, Context(gl, lf, 0, (SIZE, SIZE), proxy, white=True), **opts)
    proj = perspective(32.0, 1.0, 0.5, 30.0)
    try:
        if hasattr(m, "warm_up"):
            m.warm_up(views[0], proj)
        for i, vp in enumerate(views):
            f = m.frame(i, vp, proj)
            yield vp, proj, m.output.read_rgba()[..., 3], f, m
    finally:
        m.release()
        proxy.release()


@pytest.mark.parametrize("method", [m for m in METHODS if m != "projective"])
def test_every_method_sums_its_alphas_to_one(gl, lf_folder, method):
    slab = Lumigraph(lf_folder).slabs[0]
    for distance in (4.2, 12.0):  # the st plane fills the view; is seen whole
        for vp, proj, a, f, _ in run(gl, lf_folder, method, arc(4, distance),
                                     nodes=6, level=1, texture_mb=0.02):
            seen = st_plane_seen(vp, proj, slab)
            inside = binary_erosion(seen, iterations=2)
            outside = ~binary_dilation(seen, iterations=2)
            assert inside.any() and f.extra["images"] >= 1
            assert outside.any() == (distance > 5)
            assert np.abs(a[inside] - 1.0).max() < TOL, (method, distance)
            assert np.abs(a[outside]).max(initial=0.0) < TOL


def test_projective_reuse_covers_the_geometry_with_the_reused_alphas(gl, lf_folder):
    # frame 0 reconstructs (st plane fills the view: alpha 1 everywhere) and warps it on
    # the plate; the frames after it reuse that image: alpha 1 on the plate, 0 off it
    plate_mask = None
    for i, (vp, proj, a, f, m) in enumerate(run(gl, lf_folder, "projective", arc(3),
                                                 reuse=3, nodes=6)):
        assert f.kind == ("keyframe" if i == 0 else "reuse")
        t = RenderTarget(gl, SIZE, SIZE)
        try:
            m.ctx.proxy.render(proj @ vp.view_matrix(), t.fbo)
            plate_mask = t.read_color().sum(axis=2) > 0
        finally:
            t.release()
        inside = binary_erosion(plate_mask, iterations=2)
        outside = ~binary_dilation(plate_mask, iterations=2)
        assert inside.mean() > 0.2
        assert np.abs(a[inside] - 1.0).max() < TOL
        assert np.abs(a[outside]).max() < TOL


def test_a_missing_node_is_drawn_without_data_and_leaves_no_hole(gl, lf_folder):
    lf = Lumigraph(lf_folder)
    slab = lf.slabs[0]
    st = (arc(1)[0].o[:2] * slab.st_distance / arc(1)[0].o[2])
    from lodsprite.lumigraph.subsets import nearest_nodes

    gone = int(nearest_nodes(slab, st, 1)[0])
    (lf_folder / node_name(0, gone // 8, gone % 8, "png")).unlink()
    for method in ("full", "arbitrary", "critical"):
        for vp, proj, a, _f, m in run(gl, lf_folder, method, arc(2), nodes=6):
            inside = binary_erosion(st_plane_seen(vp, proj, slab), iterations=2)
            assert np.abs(a[inside] - 1.0).max() < TOL, method
            assert gone in {n for (_, i, j) in m.ctx.lf.bad_nodes for n in [i * 8 + j]}


def test_progressive_fading_never_overflows_texture_memory(gl, lf_folder):
    """Regression: nodes fading out were unbounded; jumping the eye between far-apart
    places filled the texture array and the next upload raised StopIteration."""
    far = [look_at((x, y, 4.2), (0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0))
           for x, y in [(-1.2, -1.2)] * 8 + [(1.2, -1.2)] * 4 + [(0.0, 1.2)] * 4]
    for _vp, _proj, _a, f, m in run(gl, lf_folder, "progressive", far, nodes=6, fade=8):
        assert len(m.rec.slot_of) <= m.rec.capacity and f.extra["images"] <= m.rec.capacity


def test_projective_predicts_from_the_real_eye(gl, lf_folder):
    """Regression: the projective method fed its own predicted viewpoints to the motion
    predictor, which then saw a velocity of about -2v after each new image."""
    line = [look_at((0.02 * k - 0.3, 0.0, 4.2), (0.02 * k - 0.3, 0.0, 0.0),
                    up=(0.0, 1.0, 0.0)) for k in range(14)]
    for i, (vp, _proj, _a, _f, m) in enumerate(run(gl, lf_folder, "projective", line,
                                                    reuse=3, nodes=6)):
        if i >= 2:
            v = (m.predictor.predict(1.0).o - vp.o)   # metres a second, 30 frames a second
            np.testing.assert_allclose(v, [0.02 * 30, 0.0, 0.0], atol=1e-6)
