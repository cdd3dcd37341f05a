"""Height fields: a regular grid of elevations in metres, placed in world space.

Conventions used throughout lodsprite:

* ``heights`` is a ``(rows, cols) float32`` array of elevations in metres; row 0
  is the northern edge and column 0 the western edge, as in raster files.
* ``dx`` / ``dy`` are the spacings in metres between columns (east) and rows
  (south).
* World space is right-handed, metres, ``+x`` east, ``+y`` north, ``+z`` up,
  with the terrain's horizontal centre at the origin: sample ``(r, c)`` lies at
  ``x = c*dx - width/2``, ``y = depth/2 - r*dy``, ``z = heights[r, c]``.
* A *working* height field has ``(N+1) x (N+1)`` samples for ``N`` quads per side,
  ``N`` a power of two, so that quadtree levels are exact subsamples.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from lodsprite.errors import TerrainError

DEFAULT_GRID = 512
DEFAULT_EXAGGERATION = 1.0


def is_power_of_two(n: int) -> bool:
    return n > 0 and (n & (n - 1)) == 0


@dataclass(frozen=True)
class HeightField:
    """Elevations ``heights (rows, cols) float32`` in metres with spacings ``dx, dy`` in metres."""

    heights: np.ndarray
    dx: float
    dy: float
    name: str = "terrain"
    meta: dict = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        h = np.asarray(self.heights)
        if h.ndim != 2 or min(h.shape) < 2:
            raise TerrainError(f"{self.name}: height field must be 2-D with at least 2x2 "
                               f"samples, got shape {h.shape}")
        if not np.issubdtype(h.dtype, np.number) or np.issubdtype(h.dtype, np.complexfloating):
            raise TerrainError(f"{self.name}: heights must be real numbers, got {h.dtype}")
        h = np.ascontiguousarray(h, dtype=np.float32)
        if not np.all(np.isfinite(h)):
            raise TerrainError(f"{self.name}: heights contain NaN or infinite values")
        if not (self.dx > 0 and self.dy > 0 and np.isfinite(self.dx) and np.isfinite(self.dy)):
            raise TerrainError(f"{self.name}: spacing must be positive, got {self.dx}, {self.dy}")
        object.__setattr__(self, "heights", h)
        object.__setattr__(self, "dx", float(self.dx))
        object.__setattr__(self, "dy", float(self.dy))

    @property
    def rows(self) -> int:
        return int(self.heights.shape[0])

    @property
    def cols(self) -> int:
        return int(self.heights.shape[1])

    @property
    def width(self) -> float:
        """East-west extent in metres."""
        return (self.cols - 1) * self.dx

    @property
    def depth(self) -> float:
        """North-south extent in metres."""
        return (self.rows - 1) * self.dy

    @property
    def extent(self) -> float:
        """``L``, the larger horizontal extent in metres (Chen et al. 1999, Figure 7)."""
        return max(self.width, self.depth)

    @property
    def quads(self) -> int:
        """Quads per side of a working (square, power-of-two) grid."""
        return self.cols - 1

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """World-space bounding box ``(min (3,), max (3,))`` in metres (copies)."""
        lo, hi = self._bounds
        return lo.copy(), hi.copy()

    @cached_property
    def _bounds(self) -> tuple[np.ndarray, np.ndarray]:
        lo = np.array([-self.width / 2, -self.depth / 2, float(self.heights.min())])
        hi = np.array([self.width / 2, self.depth / 2, float(self.heights.max())])
        return lo, hi

    def world_xy(self, rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World ``x, y`` (metres) of fractional sample indices ``rows, cols``."""
        return (np.asarray(cols, dtype=np.float64) * self.dx - self.width / 2,
                self.depth / 2 - np.asarray(rows, dtype=np.float64) * self.dy)

    def grid_index(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Fractional ``(rows, cols)`` of world ``x, y`` (metres); inverse of :meth:`world_xy`."""
        return ((self.depth / 2 - np.asarray(y, dtype=np.float64)) / self.dy,
                (np.asarray(x, dtype=np.float64) + self.width / 2) / self.dx)

    def points(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """World points ``(..., 3) float64`` of integer sample indices."""
        rows = np.asarray(rows)
        cols = np.asarray(cols)
        x, y = self.world_xy(rows, cols)
        return np.stack([x, y, self.heights[rows, cols].astype(np.float64)], axis=-1)

    def height_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Bilinearly interpolated height (metres) at world ``x, y``; clamped at the edges."""
        r, c = self.grid_index(x, y)
        r = np.clip(r, 0, self.rows - 1)
        c = np.clip(c, 0, self.cols - 1)
        r0 = np.minimum(np.floor(r).astype(np.intp), self.rows - 2)
        c0 = np.minimum(np.floor(c).astype(np.intp), self.cols - 2)
        fr, fc = r - r0, c - c0
        h = self.heights
        top = h[r0, c0] * (1 - fc) + h[r0, c0 + 1] * fc
        bot = h[r0 + 1, c0] * (1 - fc) + h[r0 + 1, c0 + 1] * fc
        return top * (1 - fr) + bot * fr

    def scaled(self, exaggeration: float) -> HeightField:
        """A copy with heights multiplied by the vertical ``exaggeration`` (> 0)."""
        if not (exaggeration > 0 and np.isfinite(exaggeration)):
            raise TerrainError(f"vertical exaggeration must be positive, got {exaggeration}")
        return HeightField(self.heights * np.float32(exaggeration), self.dx, self.dy,
                           self.name, {**self.meta, "exaggeration": float(exaggeration)})

    def resampled(self, quads: int) -> HeightField:
        """The field resampled to ``(quads+1)^2`` samples over the same extent.

        ``quads`` must be a power of two.  Downsampling low-pass filters first
        (scikit-image ``resize`` with anti-aliasing); upsampling is bilinear.
        A field already of that size is returned unchanged.
        """
        if not is_power_of_two(quads) or quads < 16:
            raise TerrainError(f"working grid must be a power of two >= 16 quads, got {quads}")
        n = quads + 1
        if self.heights.shape == (n, n):
            return self
        from skimage.transform import resize

        down = n < max(self.rows, self.cols)
        h = resize(self.heights.astype(np.float64), (n, n), order=1, mode="edge",
                   anti_aliasing=down, preserve_range=True).astype(np.float32)
        return HeightField(h, self.width / quads, self.depth / quads, self.name,
                           {**self.meta, "source_shape": [self.rows, self.cols]})
