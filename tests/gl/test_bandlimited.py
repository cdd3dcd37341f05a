"""The band-limited reference (lodsprite.gl.bandlimited, lodsprite.gl.reference): against
an analytic image, stable under resampling, drawn in image tiles as in one piece, and
independent of the renderers it judges."""

from __future__ import annotations

import math

import numpy as np
import pytest

import lodsprite.gl.bandlimited as bandlimited
from lodsprite.bandlimit import downsample, linear_to_srgb, srgb_to_linear
from lodsprite.camera import look_at
from lodsprite.gl.reference import LevelZeroReference
from lodsprite.terrain.generators import fractal
from lodsprite.terrain.heightfield import HeightField

HEIGHT_M = 100.0       # the eye above the flat checker
SIDE_PX = 64
WHITE, BLACK = 230, 25  # the checker's encoded grey levels


def rmse(a, b) -> float:
    return float(np.sqrt(np.mean((np.asarray(a, float) - np.asarray(b, float)) ** 2)))


def _square_integral(x: np.ndarray, cell: float) -> np.ndarray:
    """Antiderivative of the square wave +1 on even cells of ``cell`` metres, -1 on odd."""
    u = x / cell
    n = np.floor(u)
    frac = u - n
    return cell * np.where(n % 2 == 0, frac, 1.0 - frac)


def analytic_checker(cell: float) -> np.ndarray:
    """The exact band-limited image (a box a pixel, in linear light) of a flat checker of
    ``cell`` metres seen straight down from ``HEIGHT_M`` through a 45° square view."""
    e = HEIGHT_M * math.tan(math.radians(22.5))
    p = 2 * e / SIDE_PX
    edges = -e + p * np.arange(SIDE_PX + 1)
    sx = np.diff(_square_integral(edges, cell)) / p            # columns: x east
    sy = np.diff(_square_integral(edges, cell))[::-1] / p      # rows: y north, top first
    white = 0.5 + 0.5 * sy[:, None] * sx[None, :]
    lw, lb = srgb_to_linear(np.array([WHITE, BLACK]) / 255.0)
    out = linear_to_srgb(white * lw + (1 - white) * lb)
    return np.repeat(np.rint(out * 255)[..., None], 3, axis=2)


def checker_scene(cell: float, texels: int = 2048) -> tuple[HeightField, np.ndarray]:
    """A flat 160 m field and its checker texture (texel centres in world metres)."""
    hf = HeightField(np.zeros((17, 17), np.float32), 10.0, 10.0, "flat")
    c = (np.arange(texels) + 0.5) / texels * hf.width - hf.width / 2
    x, y = c[None, :], -c[:, None]
    parity = (np.floor(x / cell) + np.floor(y / cell)) % 2 == 0
    tex = np.where(parity, WHITE, BLACK).astype(np.uint8)
    return hf, np.repeat(tex[..., None], 3, axis=2)


@pytest.mark.parametrize("cell_px", [3.3, 1.7])
def test_a_checker_seen_straight_down_matches_its_analytic_band_limited_image(gl, cell_px):
    """Against the exact pixel integrals (a box a pixel, in linear light) the reference
    converges as its samples grow: 1, 4, 16 a pixel side each closer, 16 within RMSE 5
    grey levels (a regular grid of k samples misjudges an edge's coverage by up to
    1/(2k) of a pixel: at 16, up to about 6 grey levels at a pixel the edge crosses, and
    most pixels of a 1.7-pixel checker are crossed); one sample a pixel aliases, over 10
    times as far off."""
    pixel_m = 2 * HEIGHT_M * math.tan(math.radians(22.5)) / SIDE_PX
    hf, tex = checker_scene(cell_px * pixel_m)
    want = analytic_checker(cell_px * pixel_m)
    vp = look_at((0.0, 0.0, HEIGHT_M), (0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0))
    errors = {}
    for k in (1, 4, 16):
        ref = LevelZeroReference(gl, hf, (SIDE_PX, SIDE_PX), 45.0, "texture", tex, samples=k)
        try:
            errors[k] = rmse(ref.image(vp), want)
        finally:
            ref.release()
    assert errors[16] < errors[4] < errors[1], errors
    assert errors[16] <= 5.0 and errors[1] >= 10 * errors[16], errors


@pytest.fixture(scope="module")
def field():
    return fractal(128, seed=3)


def _view(hf):
    w = hf.width
    return look_at((0.1 * w, -0.75 * w, 0.3 * w), (0.0, 0.0, 0.0))


def test_the_reference_is_stable_under_resampling(gl, field):
    """The 64² reference against the 128² one box-filtered to 64²: at 4x4 samples a pixel
    at least three times closer than at one sample (aliasing is what differs)."""
    vp = _view(field)
    diff = {}
    for k in (1, 4):
        small = LevelZeroReference(gl, field, (64, 64), samples=k)
        large = LevelZeroReference(gl, field, (128, 128), samples=k)
        try:
            diff[k] = rmse(small.image(vp), downsample(large.image(vp), 2))
        finally:
            small.release()
            large.release()
    assert diff[4] * 3 <= diff[1], diff


def test_image_tiles_give_the_image_drawn_in_one_piece(gl, field, monkeypatch):
    """Tiles of 40 sample pixels (an off-centre projection each) against one tile: the same
    image within one grey level at a few pixels along the tiles' seams."""
    vp = _view(field)
    one = LevelZeroReference(gl, field, (48, 36), samples=3)
    try:
        a = one.image(vp)
    finally:
        one.release()
    monkeypatch.setattr(bandlimited, "TILE", 40)
    tiled = LevelZeroReference(gl, field, (48, 36), samples=3)
    try:
        b = tiled.image(vp)
        assert len(tiled._drawer.tiles) == 12
    finally:
        tiled.release()
    d = np.abs(a.astype(int) - b)
    assert a.std() > 5 and d.max() <= 1 and np.mean(d > 0) < 0.02


def test_a_wrong_vertex_offset_in_the_renderers_leaves_the_reference_unchanged(
        gl, monkeypatch):
    """A planted bug in the renderers' terrain drawer (every vertex shifted 2.5 samples
    east) raises the error of every technique that draws through it (full, lod, LOD-sprite
    in memory) and does not change the reference's images."""
    import lodsprite as ls
    from lodsprite import techniques
    from lodsprite.gl.terrain import TerrainGeometry
    from lodsprite.harness import run_path, scene_reference

    scene = ls.load_scene("fractal:64", grid=64)
    path = ls.get_path("chen1999", scene.hf, 4)

    def measure() -> tuple[dict[str, float], list[np.ndarray]]:
        out = {}
        with ls.Renderer(scene, (48, 48)) as r:
            for name in ("full", "lod", "sprite"):
                t = techniques.create(name, r)
                try:
                    out[name] = run_path(t, path, ground_truth=True).summary["rmse_mean"]
                finally:
                    t.release()
            with scene_reference(r) as ref:
                images = [ref(vp) for vp in path.viewpoints]
        return out, images

    honest, ref_honest = measure()
    plain = TerrainGeometry.set_uniforms

    def shifted(self, prog, step):
        plain(self, prog, step)
        if "u_corner" in prog:
            x, y = self.corner
            prog["u_corner"].value = (x + 2.5 * self.hf.dx, y)

    monkeypatch.setattr(TerrainGeometry, "set_uniforms", shifted)
    broken, ref_broken = measure()
    for name in honest:
        assert broken[name] > honest[name] + 1.0, (name, honest, broken)
    for a, b in zip(ref_honest, ref_broken, strict=True):
        assert np.array_equal(a, b)
