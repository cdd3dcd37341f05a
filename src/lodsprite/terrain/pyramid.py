"""An in-memory terrain pyramid with the reading interface of
:class:`~lodsprite.terrain.store.TerrainStore`, so that the adaptive renderer draws any
height field the loaders read (``jacksboro``, ``fractal:SIZE``, a GeoTIFF) as well as a
store: the same exact 2×2-mean levels, per-chunk min, max and geometric error, and the
summed ``level_errors``."""

from __future__ import annotations

import numpy as np

from lodsprite.terrain.store import MIN_LEVEL_SIDE, coarse_error, downsample, pyramid_levels


class MemoryPyramid:
    """The pyramid of ``heights (rows, cols)`` metres, spacings ``dx``, ``dy`` metres."""

    def __init__(self, heights: np.ndarray, dx: float, dy: float, chunk: int = 64,
                 name: str = "terrain") -> None:
        h = np.asarray(heights, dtype=np.float32)
        self.dx, self.dy, self.chunk, self.name = float(dx), float(dy), int(chunk), name
        self.data = [h]
        for _ in range(1, pyramid_levels(*h.shape)):
            self.data.append(downsample(self.data[-1]))
        self._minmax, self.level_errors, total = [], [], 0.0
        for k, a in enumerate(self.data):
            err = (coarse_error(a, self.data[k - 1], *a.shape) if k
                   else np.zeros(a.shape, np.float32))
            total += float(err.max()) if k else 0.0
            self.level_errors.append(total)
            self._minmax.append(_chunk_stats(a, err, self.chunk))
        assert max(self.data[-1].shape) <= MIN_LEVEL_SIDE or len(self.data) == 1

    @classmethod
    def from_heightfield(cls, hf) -> MemoryPyramid:
        return cls(hf.heights, hf.dx, hf.dy, name=hf.name)

    @property
    def levels(self) -> int:
        return len(self.data)

    def shape(self, k: int) -> tuple[int, int]:
        return self.data[k].shape

    def read(self, k: int, r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
        return self.data[k][r0:r1, c0:c1]

    def minmax(self, k: int) -> np.ndarray:
        return self._minmax[k]


def _chunk_stats(a: np.ndarray, err: np.ndarray, c: int) -> np.ndarray:
    cr, cc = -(-a.shape[0] // c), -(-a.shape[1] // c)
    out = np.zeros((cr, cc, 3), np.float32)
    for i in range(cr):
        for j in range(cc):
            b = a[i * c:(i + 1) * c, j * c:(j + 1) * c]
            out[i, j] = (b.min(), b.max(), err[i * c:(i + 1) * c, j * c:(j + 1) * c].max())
    return out
