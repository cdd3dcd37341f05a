"""Rendering tests on the real GL driver (llvmpipe here) against analytic expectations."""

import gc
import resource
import tracemalloc

import numpy as np
import pytest

from conftest import make_field
from lodsprite.camera import Projection, look_at, project_points
from lodsprite.errors import InputError
from lodsprite.gl.terrain import SKY_RGB, TerrainGeometry, TerrainRenderer

SKY = np.round(np.array(SKY_RGB) * 255).astype(np.uint8)


def solid(hf, rgb=(200, 40, 40)):
    tex = np.zeros((8, 8, 3), np.uint8)
    tex[:] = rgb
    return tex


@pytest.fixture
def renderer_for(gl):
    made = []

    def build(hf, texture, size=(128, 128)):
        geo = TerrainGeometry(gl, hf, texture)
        r = TerrainRenderer(gl, geo, *size)
        made.append((r, geo))
        return r

    yield build
    for r, geo in made:
        r.release()
        geo.release()


def terrain_mask(img):
    return np.any(np.abs(img.astype(int) - SKY.astype(int)) > 3, axis=-1)


def test_flat_terrain_lands_where_the_projection_says(renderer_for):
    hf = make_field(32, kind="flat", spacing=10.0)  # 320 m square at z = 0
    r = renderer_for(hf, solid(hf), size=(160, 120))
    vp = look_at((60.0, -450.0, 300.0), (0.0, 0.0, 0.0))
    stats = r.render(vp)
    assert stats.triangles == 2 * 32 * 32
    mask = terrain_mask(r.target.read_color())
    proj = Projection(45.0, 160 / 120, stats.projection.near, stats.projection.far)
    lo, hi = hf.bounds()
    corners = np.array([[x, y, 0.0] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])])
    px, _, _ = project_points(corners, proj.matrix() @ vp.view_matrix(), 160, 120)
    rows, cols = np.nonzero(mask)
    # Extremes of the drawn quadrilateral match the projected corners to a pixel.
    assert cols.min() == pytest.approx(px[:, 0].min(), abs=1.0)
    assert cols.max() + 1 == pytest.approx(px[:, 0].max(), abs=1.0)
    assert rows.min() == pytest.approx(px[:, 1].min(), abs=1.0)
    assert rows.max() + 1 == pytest.approx(px[:, 1].max(), abs=1.0)
    # Depth buffer: terrain pixels nearer than the far plane, sky at 1.
    depth = r.target.read_depth()
    assert np.all(depth[mask] < 1.0) and np.all(depth[~mask] == 1.0)


def test_full_and_coarse_agree_on_flat_ground_and_differ_on_relief(renderer_for):
    checker = np.kron((np.indices((16, 16)).sum(0) % 2)[..., None] * [255, -255, 0] + [0, 255, 0],
                      np.ones((16, 16, 1))).astype(np.uint8)
    vp = look_at((0.0, -2200.0, 1500.0), (0.0, 0.0, 0.0))
    flat = make_field(64, kind="flat")
    r = renderer_for(flat, checker)
    r.render(vp)
    a = r.target.read_color().astype(int)
    r.render(vp, 4)
    b = r.target.read_color().astype(int)
    assert np.mean(np.abs(a - b)) < 0.5

    hf = make_field(64, relief=600.0)
    hf = type(hf)(hf.heights * np.float32(0) + np.float32(600) *
                  np.exp(-((np.indices(hf.heights.shape) - 32) ** 2).sum(0) / 12.0)
                  .astype(np.float32), hf.dx, hf.dy, "spike")
    r2 = renderer_for(hf, checker)
    r2.render(vp)
    full = r2.target.read_color().astype(int)
    r2.render(vp, 4)
    coarse = r2.target.read_color().astype(int)
    diff = np.abs(full - coarse).sum(-1) > 30
    # Outside the four central coarse quads both models are exactly flat.
    third = 64 * 30.0 / 4
    corners = np.array([[x, y, z] for x in (-third, third) for y in (-third, third)
                        for z in (0.0, 600.0)])
    proj = r2.projection(vp)
    px, _, _ = project_points(corners, proj.matrix() @ vp.view_matrix(), 128, 128)
    inside = np.zeros(diff.shape, bool)
    c0, r0 = np.floor(px.min(0)).astype(int)
    c1, r1 = np.ceil(px.max(0)).astype(int)
    inside[max(r0, 0):r1 + 1, max(c0, 0):c1 + 1] = True
    assert diff[inside].sum() > 100
    # Only single pixels along the terrain's silhouette may differ (edge rasterisation).
    assert diff[~inside].mean() < 1e-3


def test_checker_texture_shows(renderer_for):
    from lodsprite.terrain import make_texture

    hf = make_field(32, kind="flat", spacing=10.0)
    tex = make_texture("checker:4", hf)
    r = renderer_for(hf, tex, size=(128, 128))
    half = 160.0
    # Straight down from a height where the 320 m field exactly fills a 90-degree view.
    r.fov_y_deg = 90.0
    r.render(look_at((0.0, 0.0, half), (0.0, 0.0, 0.0), up=(0, 1, 0)))
    img = r.target.read_color().astype(int)
    centres = (np.arange(4) + 0.5) * 32
    colours = img[centres.astype(int)[:, None], centres.astype(int)[None, :]]
    red = (colours[..., 0] > 200) & (colours[..., 1] < 50)
    green = (colours[..., 1] > 200) & (colours[..., 0] < 50)
    assert np.all(red | green)
    assert np.all(red[:, :-1] != red[:, 1:]) and np.all(red[:-1] != red[1:])


def test_bad_level_and_oversized_field_raise(renderer_for, gl):
    hf = make_field(32)
    r = renderer_for(hf, solid(hf))
    with pytest.raises(InputError):
        r.render(look_at((0.0, -900.0, 600.0), (0, 0, 0)), 3)
    with pytest.raises(InputError):
        r.render(look_at((0.0, -900.0, 600.0), (0, 0, 0)), 64)
    with pytest.raises(InputError):
        TerrainGeometry(gl, hf, np.zeros((4, 4), np.uint8))


def test_ten_thousand_frames_do_not_grow_memory(renderer_for, gl):
    hf = make_field(64)
    r = renderer_for(hf, solid(hf), size=(32, 32))
    vps = [look_at((2000 * np.cos(a), 2000 * np.sin(a), 900.0), (0, 0, 0))
           for a in np.linspace(0, 2 * np.pi, 50)]
    # Any GL object dropped without release() lands in ctx.objects under context_gc.
    gc.collect()  # earlier tests' garbage is not this test's
    gl.mgl.gc_mode = "context_gc"

    def run(n):
        for i in range(n):
            r.render(vps[i % len(vps)], 8 if i % 2 else None)
        gl.finish()
        gc.collect()
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * resource.getpagesize()

    try:
        tracemalloc.start()
        rss_3000 = run(3000)
        py_3000 = tracemalloc.get_traced_memory()[0]
        rss_10000 = run(7000)
        py_10000 = tracemalloc.get_traced_memory()[0]
    finally:
        tracemalloc.stop()
        dropped = list(gl.mgl.objects)
        gl.mgl.objects.clear()
        gl.mgl.gc_mode = None
    # Objects released properly become InvalidObject; anything else was leaked.
    leaked = [o for o in dropped if type(o.mglo).__name__ != "InvalidObject"]
    for o in leaked:
        o.release()
    assert leaked == []
    assert py_10000 - py_3000 < 64 * 1024  # Python heap: no per-frame objects kept
    # The driver's memory (llvmpipe bins) plateaus; a per-frame leak would climb steadily.
    assert rss_10000 - rss_3000 < 32 * 2**20
