"""Terrain: height fields in metres, their loaders, generators and textures.

Re-exports :class:`HeightField`, :func:`load_heightfield` (raw data),
:func:`fractal`, :func:`make_texture`, :func:`hillshade` and the defaults, and
implements :func:`load_terrain`, which loads a spec, resamples it to a square
power-of-two working grid and applies the vertical exaggeration.
"""

from __future__ import annotations

from lodsprite.terrain.generators import fractal
from lodsprite.terrain.heightfield import DEFAULT_EXAGGERATION, DEFAULT_GRID, HeightField
from lodsprite.terrain.loaders import STORE_MAX_SIDE, load_heightfield, parse_fractal_spec
from lodsprite.terrain.textures import hillshade, make_texture

__all__ = [
    "DEFAULT_EXAGGERATION",
    "DEFAULT_GRID",
    "HeightField",
    "fractal",
    "hillshade",
    "load_heightfield",
    "load_terrain",
    "make_texture",
]


def load_terrain(spec: str, grid: int | None = None,
                 exaggeration: float = DEFAULT_EXAGGERATION,
                 store_side: int = STORE_MAX_SIDE) -> HeightField:
    """Load ``spec``, resample to ``grid`` quads per side, exaggerate heights.

    The result has ``(grid+1, grid+1)`` float32 heights in metres times
    ``exaggeration`` over the source's full extent.  ``grid=None`` means the
    fractal's own SIZE for ``fractal:SIZE`` specs and ``DEFAULT_GRID`` (512)
    otherwise.  A terrain store is resampled from its finest level of at most
    ``store_side`` samples a side.  Raises :class:`~lodsprite.errors.TerrainError` on bad
    input.
    """
    hf = load_heightfield(spec, store_side)
    if grid is None:
        parsed = parse_fractal_spec(spec) if isinstance(spec, str) else None
        grid = parsed[0] if parsed is not None else DEFAULT_GRID
    return hf.resampled(grid).scaled(exaggeration)
