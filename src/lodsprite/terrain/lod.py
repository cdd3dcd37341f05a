"""Quadtree levels of detail of a working height field, by subsampling.

Chen, Swan & Kaufman (1999, §4) build the low-resolution terrain by
downsampling the ``512 x 512`` height field to ``16 x 16`` quads.  Here a level
is named by ``n``, its number of quads per side (a power of two dividing the
working grid's ``N``); its vertices are the full-resolution samples whose row
and column are multiples of the step ``s = N / n``, so every coarse vertex is
an exact full-resolution sample.

For drawing, a level is split into square chunks of ``C`` level quads, each
with its world-space bounding box for view-frustum culling.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lodsprite.errors import InputError
from lodsprite.terrain.heightfield import HeightField, is_power_of_two

DEFAULT_COARSE = 16
DEFAULT_CHUNK = 64


def level_step(grid_quads: int, level_quads: int) -> int:
    """Step ``s = N / n`` in full-resolution samples between a level's vertices.

    Raises :class:`InputError` unless ``n`` is a power of two with ``2 <= n <= N``.
    """
    if not is_power_of_two(level_quads) or not 2 <= level_quads <= grid_quads:
        raise InputError(f"level of detail must be a power of two between 2 and {grid_quads} "
                         f"quads per side, got {level_quads}")
    return grid_quads // level_quads


def level_indices(hf: HeightField, level_quads: int) -> np.ndarray:
    """Full-resolution sample indices ``(n+1,) intp`` of a level's rows (equally its columns)."""
    return np.arange(level_quads + 1) * level_step(hf.quads, level_quads)


def level_heights(hf: HeightField, level_quads: int) -> np.ndarray:
    """The level's heights ``(n+1, n+1) float32`` (metres): an exact subsample."""
    idx = level_indices(hf, level_quads)
    return hf.heights[np.ix_(idx, idx)]


def _block_max(a: np.ndarray, c: int) -> np.ndarray:
    k = a.shape[0] // c
    return a.reshape(k, c, k, c).max(axis=(1, 3))


@dataclass(frozen=True)
class ChunkLayout:
    """Chunks of one level: ``origins (K, 2) int32`` as (col, row) of each chunk's first
    full-resolution sample, world boxes ``mins, maxs (K, 3) float64`` (metres)."""

    level_quads: int
    step: int
    chunk_quads: int
    origins: np.ndarray
    mins: np.ndarray
    maxs: np.ndarray

    @property
    def triangles_per_chunk(self) -> int:
        return 2 * self.chunk_quads * self.chunk_quads


def chunk_layout(hf: HeightField, level_quads: int,
                 chunk_quads: int = DEFAULT_CHUNK) -> ChunkLayout:
    """Split level ``level_quads`` into chunks of ``min(chunk_quads, n)`` quads per side."""
    step = level_step(hf.quads, level_quads)
    c = min(chunk_quads, level_quads)
    k = level_quads // c
    h = level_heights(hf, level_quads)
    # Each chunk spans level samples [i*c, (i+1)*c] inclusive: combine four shifted block maxima.
    hmax = np.maximum.reduce([_block_max(h[a:a + level_quads, b:b + level_quads], c)
                              for a in (0, 1) for b in (0, 1)])
    hmin = -np.maximum.reduce([_block_max(-h[a:a + level_quads, b:b + level_quads], c)
                               for a in (0, 1) for b in (0, 1)])
    rows, cols = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
    r0 = rows.ravel() * c * step
    c0 = cols.ravel() * c * step
    x0, y0 = hf.world_xy(r0, c0)
    x1, y1 = hf.world_xy(r0 + c * step, c0 + c * step)
    mins = np.stack([x0, y1, hmin.ravel().astype(np.float64)], axis=1)
    maxs = np.stack([x1, y0, hmax.ravel().astype(np.float64)], axis=1)
    origins = np.stack([c0, r0], axis=1).astype(np.int32)
    return ChunkLayout(level_quads, step, c, origins, mins, maxs)


def is_working_grid(hf: HeightField) -> bool:
    """True for a square grid of ``(N+1)²`` samples, ``N`` a power of two (every level)."""
    return hf.rows == hf.cols and is_power_of_two(hf.quads)


def grid_layout(hf: HeightField, chunk_quads: int = DEFAULT_CHUNK,
                corner: tuple[float, float] | None = None) -> ChunkLayout:
    """Full resolution of a field of any ``rows x cols`` in chunks of ``C = chunk_quads``
    (the last chunks of a row or column overhang the edge: the vertex shader collapses
    their vertices past it onto it).  ``corner``: world ``(x, y)`` metres of sample
    ``(0, 0)`` (default: the field centred on the origin, :meth:`HeightField.world_xy`)."""
    c = max(1, min(chunk_quads, hf.rows - 1, hf.cols - 1))
    kr, kc = -(-(hf.rows - 1) // c), -(-(hf.cols - 1) // c)
    h = np.pad(hf.heights, ((0, kr * c + 1 - hf.rows), (0, kc * c + 1 - hf.cols)), mode="edge")

    def block(sign: float) -> np.ndarray:  # extremes over samples [i c, (i+1) c] inclusive
        return sign * np.maximum.reduce([
            (sign * h[a:a + kr * c, b:b + kc * c]).reshape(kr, c, kc, c).max(axis=(1, 3))
            for a in (0, 1) for b in (0, 1)]).ravel().astype(np.float64)

    x_west, y_north = corner if corner is not None else (-hf.width / 2, hf.depth / 2)
    rows, cols = np.meshgrid(np.arange(kr), np.arange(kc), indexing="ij")
    r0, c0 = rows.ravel() * c, cols.ravel() * c
    r1, c1 = np.minimum(r0 + c, hf.rows - 1), np.minimum(c0 + c, hf.cols - 1)
    mins = np.stack([x_west + c0 * hf.dx, y_north - r1 * hf.dy, block(-1.0)], axis=1)
    maxs = np.stack([x_west + c1 * hf.dx, y_north - r0 * hf.dy, block(1.0)], axis=1)
    origins = np.stack([c0, r0], axis=1).astype(np.int32)
    return ChunkLayout(hf.quads, 1, c, origins, mins, maxs)


def grid_mesh(chunk_quads: int) -> tuple[np.ndarray, np.ndarray]:
    """A ``C x C`` quad grid: vertices ``((C+1)^2, 2) int32`` as (col, row), triangle indices
    ``(2*C*C, 3) uint32``, counter-clockwise seen from above (+z, with rows running south)."""
    c = chunk_quads
    rows, cols = np.meshgrid(np.arange(c + 1), np.arange(c + 1), indexing="ij")
    verts = np.stack([cols.ravel(), rows.ravel()], axis=1).astype(np.int32)
    v = np.arange((c + 1) * (c + 1), dtype=np.uint32).reshape(c + 1, c + 1)
    a, b = v[:-1, :-1].ravel(), v[:-1, 1:].ravel()      # north-west, north-east
    d, e = v[1:, :-1].ravel(), v[1:, 1:].ravel()        # south-west, south-east
    # Seen from above with x east and y north, (nw, sw, se) and (nw, se, ne) are counter-clockwise.
    tris = np.concatenate([np.stack([a, d, e], 1), np.stack([a, e, b], 1)])
    return verts, tris
