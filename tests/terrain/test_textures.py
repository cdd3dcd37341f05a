"""Tests of terrain textures and hillshading (lodsprite.terrain.textures)."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from lodsprite.errors import TerrainError
from lodsprite.terrain import HeightField, hillshade, make_texture


def _plane(slope_east: float, slope_south: float, n: int = 16, d: float = 10.0) -> HeightField:
    """A plane rising ``slope_east`` m/m to the east and ``slope_south`` m/m to the south."""
    r, c = np.mgrid[0:n, 0:n].astype(np.float64)
    return HeightField(c * d * slope_east + r * d * slope_south, d, d, "plane")


@pytest.fixture
def hill() -> HeightField:
    r, c = np.mgrid[0:65, 0:65].astype(np.float64)
    h = 1000.0 * np.exp(-((r - 32) ** 2 + (c - 32) ** 2) / 200.0)
    return HeightField(h, 30.0, 30.0, "hill")


def test_hillshade_plane_facing_sun_is_brighter():
    # rising to the south-east = facing north-west, toward the default sun (az 315)
    toward = _plane(0.5, 0.5)
    away = _plane(-0.5, -0.5)
    lit = hillshade(toward.heights, toward.dx, toward.dy)
    dark = hillshade(away.heights, away.dx, away.dy)
    assert lit.mean() > dark.mean() + 0.3
    flat = hillshade(np.zeros((8, 8)), 10.0, 10.0)
    assert np.allclose(flat, np.sin(np.radians(45.0)), atol=1e-6)
    assert lit.mean() > flat.mean() > dark.mean()


def test_hillshade_uses_row_zero_north():
    # rising to the north (toward row 0) faces south: dark under a northern sun
    north_rising = _plane(0.0, -1.0)
    lit_from_north = hillshade(north_rising.heights, 10.0, 10.0, azimuth_deg=0.0)
    lit_from_south = hillshade(north_rising.heights, 10.0, 10.0, azimuth_deg=180.0)
    assert lit_from_south.mean() > lit_from_north.mean()


def test_hillshade_uses_spacing():
    h = _plane(1.0, 0.0).heights                 # rises 10 m per column
    steep = hillshade(h, 10.0, 10.0, azimuth_deg=270.0)
    gentle = hillshade(h, 1000.0, 1000.0, azimuth_deg=270.0)
    assert gentle.mean() < steep.mean()          # west sun: steep east-rising slope lit more


def test_hillshade_shape_dtype_range(hill):
    s = hillshade(hill.heights, hill.dx, hill.dy)
    assert s.shape == hill.heights.shape
    assert s.dtype == np.float32
    assert s.min() >= 0.0 and s.max() <= 1.0


def test_terrain_texture(hill):
    tex = make_texture("terrain", hill)
    assert tex.shape == (65, 65, 3)
    assert tex.dtype == np.uint8
    # north-west flank (lit) brighter than south-east flank (shadow)
    assert tex[22, 22].astype(int).sum() > tex[42, 42].astype(int).sum()
    # lowland corners greenish
    r, g, b = tex[0, 0].astype(int)
    assert g > r and g > b


def test_terrain_texture_flat_field():
    flat = HeightField(np.full((9, 9), 5.0), 1.0, 1.0)
    tex = make_texture("terrain", flat)
    assert tex.shape == (9, 9, 3)
    assert np.all(tex == tex[0, 0])


def test_checker_default_colours(hill):
    tex = make_texture("checker", hill)
    assert tex.shape == (1024, 1024, 3)
    assert tex.dtype == np.uint8
    red = np.all(tex == (255, 0, 0), axis=-1)
    green = np.all(tex == (0, 255, 0), axis=-1)
    assert np.all(red ^ green)                       # every texel pure red or pure green
    assert tuple(tex[0, 0]) == (255, 0, 0)           # north-west square red
    assert tuple(tex[0, 32]) == (0, 255, 0)          # 32 squares -> 32 texels each
    assert tuple(tex[32, 32]) == (255, 0, 0)
    assert (tex[..., 0] == 255).mean() == pytest.approx(0.5)


def test_checker_k_squares(hill):
    tex = make_texture("checker:4", hill)
    assert tex.shape == (1024, 1024, 3)
    assert tuple(tex[255, 255]) == (255, 0, 0)
    assert tuple(tex[255, 256]) == (0, 255, 0)
    assert tuple(tex[1023, 1023]) == (255, 0, 0)


@pytest.mark.parametrize("spec", ["checker:0", "checker:x", "checker:-3", "checker:4096"])
def test_bad_checker_specs(spec, hill):
    with pytest.raises(TerrainError):
        make_texture(spec, hill)


def test_image_file_texture(tmp_path, hill):
    rgba = np.zeros((20, 30, 4), dtype=np.uint8)
    rgba[..., 2] = 200
    rgba[..., 3] = 255
    path = tmp_path / "tex.png"
    Image.fromarray(rgba, "RGBA").save(path)
    tex = make_texture(str(path), hill)
    assert tex.shape == (20, 30, 3)
    assert tex.dtype == np.uint8
    assert tuple(tex[0, 0]) == (0, 0, 200)


def test_missing_texture_file(tmp_path, hill):
    missing = tmp_path / "nope.png"
    with pytest.raises(TerrainError, match="nope.png"):
        make_texture(str(missing), hill)
    with pytest.raises(TerrainError, match="no such texture file or built-in: foo"):
        make_texture("foo", hill)


def test_corrupt_texture_file(tmp_path, hill):
    path = tmp_path / "bad.png"
    path.write_bytes(b"\x89PNG not really an image")
    with pytest.raises(TerrainError, match="bad.png"):
        make_texture(str(path), hill)
