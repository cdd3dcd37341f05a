"""The honest measure's renderer side (issue 22): level 0 drawn at full resolution from a
store as from memory, the reference (:class:`lodsprite.gl.reference.LevelZeroReference`)
independent of the adaptive renderer, windows of level 0 where it is too large, and the
heights shading (per-pixel normals) keeping level-0 detail."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy.ndimage import uniform_filter

from conftest import run_cli
from lodsprite.camera import look_at
from lodsprite.gl.reference import LevelZeroReference
from lodsprite.terrain.heightfield import HeightField
from lodsprite.terrain.store import TerrainStore, build_store

SIZE = (80, 60)
LIGHT = np.array([-0.450473, 0.450473, 0.770810])  # gl.shaders.TERRAIN_SHADE's sun


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    out = tmp_path_factory.mktemp("ref") / "f256.zarr"
    build_store("fractal:256:1", out)
    return TerrainStore(out)


def level0(store: TerrainStore) -> HeightField:
    r, c = store.shape(0)
    return HeightField(store.read(0, 0, r, 0, c), store.dx, store.dy, "level 0")


def views(store: TerrainStore):
    """An oblique view of the whole terrain and a steep one of a small part of it."""
    w = (store.shape(0)[1] - 1) * store.dx
    return [look_at((0.0, -0.9 * w, 0.5 * w), (0.0, 0.0, 0.0)),
            look_at((300.0, -900.0, 2500.0), (300.0, 300.0, 0.0))]


def rmse(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((a.astype(np.float64) - b) ** 2)))


def test_full_on_a_store_draws_level_0_as_the_same_field_in_memory(store, tmp_path):
    """``render --mode full`` on a store draws level 0's own 256² samples (not the 512²
    working grid), the same image (at most 1 grey level apart) as level 0 in memory."""
    from lodsprite.api import Renderer, read_image
    from lodsprite.paths import get_path
    from lodsprite.scene import Scene

    proc = run_cli("render", "--terrain", store.path, "--mode", "full", "--size", "64x48",
                   "--frames", "2", "--out", tmp_path, "--save-frames")
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["grid"] == 255 and summary["shading"] == "heights"
    hf = level0(store)
    path = get_path("chen1999", hf, 2)
    with Renderer(Scene(hf, np.zeros((2, 2, 3), np.uint8)), (64, 48)) as r:
        r.terrain_gl.drawer.shading = "heights"
        for i, vp in enumerate(path.viewpoints):
            r.render(vp)
            saved = read_image(tmp_path / "frames" / f"frame_{i:05d}.png")
            d = np.abs(r.read_color().astype(int) - saved)
            assert d.max() <= 1, d.max()


def test_reference_from_a_store_equals_the_field_in_memory(gl, store):
    a = LevelZeroReference(gl, store, SIZE)
    b = LevelZeroReference(gl, level0(store), SIZE)
    try:
        for vp in views(store):
            ia, ib = a.image(vp), b.image(vp)
            assert ia.std() > 5  # terrain in view, not the sky alone
            assert np.abs(ia.astype(int) - ib).max() <= 1
        assert "level 0 whole, 256x256 samples" in a.describe()
    finally:
        a.release()
        b.release()


def test_adaptive_at_a_tiny_tolerance_matches_the_reference(gl, store):
    """Adaptive at 1e-6 px, settled, against level 0 drawn by the reference's own path at
    one sample a pixel (the same sampling as the renderer's), heights shading both: RMSE
    at most 1 grey level, at most 0.5 % of pixels more than 16 apart (node edges: a
    tile's normals are one-sided on its border).  Same projection too."""
    from lodsprite.gl.target import RenderTarget
    from lodsprite.techniques.adaptive_terrain import AdaptiveTerrain

    ref = LevelZeroReference(gl, store, SIZE, samples=1)
    target = RenderTarget(gl, *SIZE)
    adaptive = AdaptiveTerrain(gl, store, target, 45.0, 1e-6, grid=64)
    try:
        for vp in views(store):
            np.testing.assert_allclose(ref.projection(vp).matrix(), adaptive.projection(vp),
                                       rtol=1e-9)
            truth = ref.image(vp)
            adaptive.settle(vp)
            img = target.read_color()
            assert rmse(img, truth) <= 1.0
            assert np.mean(np.abs(img.astype(int) - truth).max(axis=2) > 16) <= 0.005
    finally:
        adaptive.release()
        target.release()
        ref.release()


def test_a_window_of_level_0_equals_the_whole_level(gl, store):
    """Forced by a small cap: the window cropped to the view's footprint lands where the
    whole level does (at most 2 grey levels apart, mean under 0.05)."""
    whole = LevelZeroReference(gl, store, SIZE)
    window = LevelZeroReference(gl, store, SIZE, max_side=160)
    try:
        _, steep = views(store)
        a, b = whole.image(steep), window.image(steep)
        assert "in one piece" in window.describe()
        d = np.abs(a.astype(int) - b)
        assert d.max() <= 2 and d.mean() < 0.05 and a.std() > 5
    finally:
        whole.release()
        window.release()


@pytest.mark.parametrize("max_side", [160, 64])
def test_a_footprint_beyond_the_cap_is_drawn_tile_by_tile_as_the_whole_level(
        gl, store, max_side):
    """A footprint of more than ``max_side`` samples a side (the whole 256² level in
    view) is drawn in tiles into one target: RMSE within 1.0 grey level of the whole
    level, at most 1 % of pixels more than 16 apart (the tiles' inner edges, where the
    per-pixel normals are one-sided), never the sky where the whole level has terrain."""
    whole = LevelZeroReference(gl, store, (160, 120))
    tiled = LevelZeroReference(gl, store, (160, 120), max_side=max_side)
    try:
        wide, _ = views(store)
        a, b = whole.image(wide), tiled.image(wide)
        assert "tiles" in tiled.describe() and a.std() > 5
        assert rmse(a, b) <= 1.0, rmse(a, b)
        assert np.mean(np.abs(a.astype(int) - b).max(axis=2) > 16) <= 0.01
        a2 = tiled.image(wide)  # again, from fresh tiles: the same image
        assert np.array_equal(a2, b)
    finally:
        whole.release()
        tiled.release()


def test_tile_ranges_cover_the_window_with_shared_edges():
    from lodsprite.gl.reference import tile_ranges, tiles

    assert tile_ranges(0, 9, 5) == [(0, 5), (4, 9)]
    assert tile_ranges(3, 7, 4097) == [(3, 7)]
    for lo, hi, cap in ((0, 257, 64), (10, 4107, 4097), (5, 9000, 4097), (0, 2, 2)):
        parts = tile_ranges(lo, hi, cap)
        assert parts[0][0] == lo and parts[-1][1] == hi
        assert all(b - a <= cap for a, b in parts)
        assert all(p[1] - 1 == q[0] for p, q in zip(parts[:-1], parts[1:], strict=True))
    assert len(tiles((0, 257, 0, 257), 64)) == 25


def test_full_on_a_store_beyond_the_cap_exits_2_with_one_line(store, monkeypatch, tmp_path):
    monkeypatch.setattr("lodsprite.terrain.loaders.STORE_MAX_SIDE", 128)
    proc = run_cli("render", "--terrain", store.path, "--mode", "full", "--size", "64x48",
                   "--frames", "2", "--out", tmp_path)
    assert proc.returncode == 2
    lines = [ln for ln in proc.stderr.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and "level 0 is 256x256" in lines[0], proc.stderr
    assert "--mode adaptive" in lines[0]


def numpy_shade(h: np.ndarray, rows: np.ndarray, cols: np.ndarray, dx: float, dy: float,
                lo: float, hi: float) -> np.ndarray:
    """terrain_shade of heights ``h`` at fractional samples ``rows, cols`` (normals: the
    bilinear blend of central differences), ``(..., 3)`` in grey levels."""
    gy, gx = np.gradient(h.astype(np.float64))

    def bilinear(a):
        r0 = np.clip(np.floor(rows).astype(int), 0, a.shape[0] - 2)
        c0 = np.clip(np.floor(cols).astype(int), 0, a.shape[1] - 2)
        fr, fc = rows - r0, cols - c0
        return ((a[r0, c0] * (1 - fc) + a[r0, c0 + 1] * fc) * (1 - fr)
                + (a[r0 + 1, c0] * (1 - fc) + a[r0 + 1, c0 + 1] * fc) * fr)

    n = np.stack([-bilinear(gx) / dx, bilinear(gy) / dy, np.ones_like(rows)], axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    t = np.clip((bilinear(h) - lo) / max(hi - lo, 1e-3), 0, 1)[..., None]
    low, mid, high = np.array([0.32, 0.45, 0.25]), np.array([0.55, 0.48, 0.34]), np.full(3, 0.9)
    c = np.where(t < 0.6, low + (mid - low) * (t / 0.6), mid + (high - mid) * ((t - 0.6) / 0.4))
    lit = 0.3 + 0.7 * np.maximum(n @ LIGHT, 0.0)
    return c * lit[..., None] * 255.0


def test_heights_shading_has_level_0_detail(gl, store):
    """A near-orthographic zenith view of 48 samples over 64 pixels: the image matches a
    numpy shading of level 0's own samples (RMSE under 2 grey levels), and is at least
    three times closer to it than to the same shading of level 0 smoothed over 8 samples
    (what a texture of a coarser grid shows)."""
    hf = level0(store)
    side, altitude = 64, 1.0e5
    half = 24 * hf.dx
    fov = math.degrees(2 * math.atan(half / altitude))
    ref = LevelZeroReference(gl, store, (side, side), fov)
    try:
        x0, y0 = 450.0, -300.0
        vp = look_at((x0, y0, altitude), (x0, y0, 0.0), up=(0.0, 1.0, 0.0))
        img = ref.image(vp)
        inv = np.linalg.inv(ref.projection(vp).matrix() @ vp.view_matrix())
        px = (np.arange(side) + 0.5) / side * 2 - 1
        nx, ny = np.meshgrid(px, -px)  # row 0 on top
        z_mean = float(hf.heights.mean())
        ends = []
        for z in (-1.0, 1.0):
            p = np.stack([nx, ny, np.full_like(nx, z), np.ones_like(nx)], -1) @ inv.T
            ends.append(p[..., :3] / p[..., 3:])
        s = (z_mean - ends[0][..., 2]) / (ends[1][..., 2] - ends[0][..., 2])
        world = ends[0] + s[..., None] * (ends[1] - ends[0])
        rows, cols = hf.grid_index(world[..., 0], world[..., 1])
        lo, hi = float(hf.heights.min()), float(hf.heights.max())
        fine = numpy_shade(hf.heights, rows, cols, hf.dx, hf.dy, lo, hi)
        smooth = uniform_filter(hf.heights.astype(np.float64), 8, mode="nearest")
        coarse = numpy_shade(smooth, rows, cols, hf.dx, hf.dy, lo, hi)
        assert rmse(img, fine) < 2.0
        assert rmse(img, coarse) > 3 * rmse(img, fine)
    finally:
        ref.release()


def test_shading_reaches_every_terrain_technique_auto_is_heights_on_a_store(store, tmp_path):
    from lodsprite import techniques

    for name in ("full", "lod", "sprite", "adaptive", "sprite-adaptive"):
        assert "shading" in {o.name for o in techniques.get(name).options}, name
    runs = {"store": ["--terrain", store.path, "--mode", "adaptive"],
            "memory": ["--terrain", "fractal:64:3", "--mode", "adaptive"],
            "forced": ["--terrain", "fractal:64:3", "--mode", "lod", "--lod", "8",
                       "--shading", "heights"]}
    for key, args in runs.items():
        proc = run_cli("render", *args, "--size", "32x32", "--frames", "2", "--out",
                       tmp_path / key)
        assert proc.returncode == 0, proc.stderr
        summary = json.loads((tmp_path / key / "summary.json").read_text())
        assert summary["shading"] == {"store": "heights", "memory": "texture",
                                      "forced": "heights"}[key]
    proc = run_cli("render", "--terrain", "fractal:64:3", "--shading", "hillshade",
                   "--out", tmp_path / "bad")
    assert proc.returncode == 2 and "option --shading: got 'hillshade'" in proc.stderr


def test_a_texture_reference_of_a_field_draws_the_texture(gl):
    """``auto`` with an in-memory field and its texture draws the texture (jacksboro and
    chen1999 keep theirs): at one sample a pixel the full-resolution renderer's image,
    for a smooth texture (where the renderer's mipmaps and the reference's base level
    agree; the reference samples the base level only and leaves the filtering to its
    supersampling)."""
    from lodsprite.gl.terrain import TerrainDrawer, TerrainGeometry

    hf = HeightField(np.asarray(np.random.default_rng(3).normal(0, 40, (65, 65)), np.float32),
                     30.0, 30.0)
    r_, c_ = np.indices((256, 256)) / 255.0
    tex = np.stack([40 + 180 * c_, 60 + 150 * r_, 200 - 120 * c_ * r_], -1).astype(np.uint8)
    vp = look_at((0.0, -2000.0, 1500.0), (0.0, 0.0, 0.0))
    ref = LevelZeroReference(gl, hf, SIZE, shading="auto", texture=tex, samples=1)
    geo = TerrainGeometry(gl, hf, tex)
    r = TerrainDrawer(gl, geo, *SIZE)
    try:
        img = ref.image(vp)
        r.render(vp, None, ref.projection(vp))
        assert ref.shading == "texture" and img.std() > 5
        d = np.abs(img.astype(int) - r.target.read_color())
        # a mipmap level's texel against the base level's bilinear sample: a few pixels
        assert rmse(img, r.target.read_color()) <= 1.0 and np.mean(d > 2) <= 0.01, d.max()
    finally:
        ref.release()
        r.release()
        geo.release()


def test_the_reference_shares_no_code_with_the_renderers():
    """Its draw is its own (gl.bandlimited): no import of the renderers' terrain drawer,
    the adaptive renderer, its selection's streaming or a technique (only the quadtree's
    box and ground, so the projection is fitted the same way)."""
    import ast
    import inspect

    import lodsprite.gl.reference as module

    tree = ast.parse(inspect.getsource(module))
    imported = {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    imported |= {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    assert not {m for m in imported if m and ("adaptive" in m or "streaming" in m
                                              or m.startswith("lodsprite.techniques"))}
    assert "lodsprite.gl.terrain" not in imported and "lodsprite.gl.bandlimited" in imported
    import lodsprite.gl.bandlimited as drawing

    tree = ast.parse(inspect.getsource(drawing))
    own = {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    assert own <= {"__future__", "collections.abc", "lodsprite.camera", "lodsprite.errors",
                   "lodsprite.gl.context", "lodsprite.gl.shaders"}, own
