"""Terrain textures: hypsometric tint with hillshade, test checkerboard, image files.

Implements :func:`hillshade` (Lambertian shading of a height grid, the standard
GIS formula with central-difference gradients) and :func:`make_texture`
(``(H, W, 3) uint8`` RGB, row 0 = north, the same orientation as the heights).

Units: heights in metres, ``dx`` / ``dy`` in metres, angles in degrees.
Texture specs:

* ``terrain`` -- colour ramp by normalised elevation (green lowlands, brown,
  grey, white peaks) times the hillshade (sun azimuth 315, altitude 45), one
  texel per height sample.
* ``checker`` / ``checker:K`` -- pure red (255, 0, 0) / green (0, 255, 0)
  checkerboard with ``K`` squares per side (default 32), 1024 x 1024 texels, as
  in Figure 13 of Chen et al. 1999; the north-west corner square is red.
* any other spec -- an image file read with Pillow and converted to RGB.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lodsprite.errors import TerrainError
from lodsprite.terrain.heightfield import HeightField

CHECKER_SIZE = 1024
"""Side of the checkerboard texture in texels."""

DEFAULT_CHECKER_SQUARES = 32

RED = (255, 0, 0)
GREEN = (0, 255, 0)

AMBIENT = 0.15
"""Share of the tint kept in full shadow by the ``terrain`` texture."""

# Hypsometric ramp: normalised elevation -> RGB.
_RAMP_STOPS = np.array([0.0, 0.15, 0.35, 0.55, 0.72, 0.86, 0.94, 1.0])
_RAMP_RGB = np.array([
    (62, 115, 48),      # dark green lowlands
    (104, 150, 66),     # green
    (160, 165, 92),     # olive
    (150, 120, 78),     # brown
    (122, 102, 84),     # dark brown
    (140, 138, 134),    # grey rock
    (230, 230, 230),    # snow line
    (255, 255, 255),    # white peaks
], dtype=np.float64)


def hillshade(heights: np.ndarray, dx: float, dy: float, azimuth_deg: float = 315.0,
              altitude_deg: float = 45.0) -> np.ndarray:
    """Lambertian shading ``(rows, cols) float32`` in ``[0, 1]`` of a height grid.

    ``heights (rows, cols)`` metres, row 0 north; ``dx`` (east) and ``dy``
    (south) spacings in metres.  The sun is at ``azimuth_deg`` clockwise from
    north and ``altitude_deg`` above the horizon; slopes facing away from it
    are 0.  A flat grid shades to ``sin(altitude)``.
    """
    h = np.asarray(heights, dtype=np.float32)
    if h.ndim != 2 or min(h.shape) < 2:
        raise TerrainError(f"hillshade needs a 2-D grid of at least 2x2, got shape {h.shape}")
    if not (dx > 0 and dy > 0):
        raise TerrainError(f"hillshade spacing must be positive, got {dx}, {dy}")
    dz_drow, dz_east = np.gradient(h, np.float32(dy), np.float32(dx))
    dz_north = -dz_drow                                 # rows run south
    az, alt = np.radians(azimuth_deg), np.radians(altitude_deg)
    sun_e = np.float32(np.sin(az) * np.cos(alt))
    sun_n = np.float32(np.cos(az) * np.cos(alt))
    sun_z = np.float32(np.sin(alt))
    # normal (-dz_east, -dz_north, 1) / |.| dotted with the sun direction
    shade = sun_z - dz_east * sun_e - dz_north * sun_n
    shade /= np.sqrt(1 + dz_east * dz_east + dz_north * dz_north)
    return np.clip(shade, 0, 1).astype(np.float32, copy=False)


#: The heights shading's sun (unit, towards it: the north-west, 50.4° up) and ramp colours
#: (``gl.shaders``' TERRAIN_SHADE: the one shading of the terrain from its heights).
SHADE_LIGHT = np.array([-0.450473, 0.450473, 0.770810])
SHADE_AZIMUTH_DEG = 315.0
SHADE_ALTITUDE_DEG = float(np.degrees(np.arcsin(SHADE_LIGHT[2])))
SHADE_LOW, SHADE_MID, SHADE_HIGH = (0.32, 0.45, 0.25), (0.55, 0.48, 0.34), (0.9, 0.9, 0.9)


def height_shading(heights: np.ndarray, dx: float, dy: float, lo: float, hi: float
                   ) -> np.ndarray:
    """``(rows, cols, 3) uint8``: the terrain's heights shading at its samples, row 0
    north, as the renderers colour a terrain store (``TERRAIN_SHADE`` of
    :mod:`lodsprite.gl.shaders`: a height ramp over ``lo..hi`` metres, level 0's lowest
    and highest, lit by one sun with 30 % ambient: :func:`hillshade`, whose normals are
    its ``height_normal``'s at a sample).  What a web page shows where no keyframe saw the
    surface, in the keyframes' colours."""
    h = np.asarray(heights, np.float32)  # float32 as the shader: 4 bytes a sample an array
    if h.ndim != 2 or min(h.shape) < 2:
        raise TerrainError(f"height shading needs a 2-D grid of at least 2x2, got {h.shape}")
    t = np.clip((h - np.float32(lo)) / np.float32(max(hi - lo, 1e-3)), 0.0, 1.0)[..., None]
    low, mid, high = (np.asarray(c, np.float32) for c in (SHADE_LOW, SHADE_MID, SHADE_HIGH))
    c = np.where(t < 0.6, low + (mid - low) * (t / np.float32(0.6)),
                 mid + (high - mid) * ((t - np.float32(0.6)) / np.float32(0.4)))
    lit = 0.3 + 0.7 * hillshade(h, dx, dy, SHADE_AZIMUTH_DEG, SHADE_ALTITUDE_DEG)
    return np.clip(np.round(c * lit[..., None] * 255.0), 0, 255).astype(np.uint8)


IMAGERY_SPECS = ("imagery", "imagery+hillshade")
"""Texture names of a terrain store's own imagery: as stored, or with a hillshade over it."""


def drape(rgba: np.ndarray, hf: HeightField, hillshade: bool = False,
          height_range: tuple[float, float] | None = None) -> np.ndarray:
    """A store's imagery ``(H, W, 4) uint8`` (alpha: coverage) as the terrain's texture
    ``(H, W, 3) uint8`` over ``hf`` (the same extent: texel centres spread from its first
    sample to its last): where no source covers the ground, the heights shading of ``hf``
    (its ramp over ``height_range``, default ``hf``'s own) shows through, blended by
    alpha.  ``hillshade``: the colours times the heights shading's light (30 % ambient,
    the same sun), divided by a flat ground's, so flat ground keeps the imagery's own
    colours and slopes facing away from the sun darken."""
    from PIL import Image

    a = np.asarray(rgba)
    if a.ndim != 3 or a.shape[2] != 4 or a.dtype != np.uint8:
        raise TerrainError("imagery must be an (H, W, 4) uint8 array")
    holes = bool((a[..., 3] < 255).any())
    if not (holes or hillshade):
        return np.ascontiguousarray(a[..., :3])
    size = (a.shape[1], a.shape[0])
    rows, cols = hf.heights.shape
    box = (0.5, 0.5, cols - 0.5, rows - 0.5)  # PIL's pixel centres onto the samples

    def spread(img):
        return np.asarray(img.resize(size, Image.Resampling.BILINEAR, box=box), np.float32)

    out = a[..., :3].astype(np.float32)
    h = np.asarray(hf.heights, np.float32)
    if holes:
        lo, hi = height_range or (float(np.nanmin(h)), float(np.nanmax(h)))
        alpha = a[..., 3:4].astype(np.float32) / 255.0
        base = spread(Image.fromarray(height_shading(h, hf.dx, hf.dy, lo, hi)))
        out = out * alpha + base * (1 - alpha)
    if hillshade:
        lit = 0.3 + 0.7 * hillshade_grid(h, hf)
        flat = 0.3 + 0.7 * float(SHADE_LIGHT[2])
        out *= spread(Image.fromarray((lit / flat).astype(np.float32), "F"))[..., None]
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def hillshade_grid(h: np.ndarray, hf: HeightField) -> np.ndarray:
    """The heights shading's hillshade of ``h`` (``hf``'s spacing), ``float32`` [0, 1]."""
    return hillshade(h, hf.dx, hf.dy, SHADE_AZIMUTH_DEG, SHADE_ALTITUDE_DEG)


def make_texture(spec: str, hf: HeightField) -> np.ndarray:
    """The texture named by ``spec`` for ``hf``: ``(H, W, 3) uint8`` RGB, row 0 north.

    ``terrain`` is ``(hf.rows, hf.cols)`` texels; ``checker[:K]`` is 1024 x 1024;
    a file keeps its own size.  Raises :class:`TerrainError` for a bad spec or
    an unreadable image.
    """
    if not isinstance(spec, str) or not spec.strip():
        raise TerrainError(f"texture spec must be a non-empty string, got {spec!r}")
    spec = spec.strip()
    name = spec.lower()
    if name == "terrain":
        return terrain_texture(hf)
    if name == "checker" or name.startswith("checker:"):
        return checker_texture(_checker_squares(spec))
    if name in IMAGERY_SPECS:
        raise TerrainError(f"texture {spec!r} is a terrain store's own imagery (tile the "
                           "store with --imagery ORTHO.tif)")
    return image_texture(spec)


def terrain_texture(hf: HeightField, azimuth_deg: float = 315.0,
                    altitude_deg: float = 45.0) -> np.ndarray:
    """Hypsometric tint times hillshade, ``(hf.rows, hf.cols, 3) uint8``."""
    h = hf.heights
    lo, hi = float(h.min()), float(h.max())
    e = (h - np.float32(lo)) * np.float32(1.0 / (hi - lo)) if hi > lo else np.zeros_like(h)
    shade = hillshade(h, hf.dx, hf.dy, azimuth_deg, altitude_deg)
    shade *= np.float32(1 - AMBIENT)
    shade += np.float32(AMBIENT)
    rgb = np.zeros((*h.shape, 3), dtype=np.uint8)
    for c in range(3):
        tint = np.interp(e, _RAMP_STOPS, _RAMP_RGB[:, c]).astype(np.float32)
        tint *= shade
        rgb[..., c] = np.clip(np.rint(tint), 0, 255)
    return rgb


def checker_texture(squares: int = DEFAULT_CHECKER_SQUARES,
                    size: int = CHECKER_SIZE) -> np.ndarray:
    """Red/green checkerboard ``(size, size, 3) uint8`` with ``squares`` per side."""
    if not 1 <= squares <= size:
        raise TerrainError(f"checker squares per side must be in 1..{size}, got {squares}")
    cell = np.arange(size) * squares // size            # square index of each texel
    green = (cell[:, None] + cell[None, :]) % 2 == 1
    return np.where(green[..., None], np.array(GREEN, dtype=np.uint8),
                    np.array(RED, dtype=np.uint8))


def image_texture(path: str | Path) -> np.ndarray:
    """An image file as ``(H, W, 3) uint8`` RGB (Pillow; alpha and palettes dropped)."""
    from PIL import Image

    p = Path(path).expanduser()
    if not p.exists():
        raise TerrainError(f"no such texture file or built-in: {path}")
    if not p.is_file():
        raise TerrainError(f"texture path is not a file: {path}")
    try:
        with Image.open(p) as img:
            rgb = np.array(img.convert("RGB"))
    except (OSError, SyntaxError, ValueError, Image.DecompressionBombError) as e:
        raise TerrainError(f"cannot read texture image {path}: {_first_line(e)}") from e
    return rgb


def _checker_squares(spec: str) -> int:
    _, _, count = spec.partition(":")
    if not count:
        return DEFAULT_CHECKER_SQUARES
    try:
        return int(count)
    except ValueError:
        raise TerrainError(f"malformed texture spec {spec!r}: expected checker:K with K "
                           "an integer") from None


def _first_line(e: BaseException) -> str:
    text = str(e).strip()
    return text.splitlines()[0] if text else type(e).__name__
