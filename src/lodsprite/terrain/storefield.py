"""A terrain store's finest level seen as a LOD-sprite working grid, read on demand.

LOD-sprite (Chen, Swan & Kaufman 1999, §3.1-3.2) needs three things from the full
resolution model: the coarse proxy's vertices, the border ribbons' profiles and, for the
error metric (Eq. 1-2), ``C``, the full-resolution sample at each coarse square's centre
(plus, when few centres are in view, denser full-resolution vertices).  For a store
larger than memory these are read from level 0 of the store, never from the in-memory
level that commands load whole (4096² at most).

:class:`StoreField` is a :class:`~lodsprite.terrain.heightfield.HeightField` whose
``heights`` is a :class:`LazyHeights`: the store's level 0 resampled bilinearly onto a
square working grid of ``(Q+1)²`` samples over level 0's extent, ``Q`` the power of two
at or above the longer side's quads (so ``Q = rows - 1`` samples level 0 exactly when
that is a power of two).  Indexing it with integer arrays reads only the level-0 chunks
those samples lie in, through a least-recently-used chunk cache; its minimum and maximum
come from the store's per-chunk bounds.  World coordinates are those of the adaptive
renderer (:meth:`lodsprite.terrain.quadtree.Quadtree.world_xy`): level 0 centred on the
origin, x east, y north, metres.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from lodsprite.errors import TerrainError
from lodsprite.terrain.heightfield import HeightField

DEFAULT_CACHE_CHUNKS = 256  # level-0 chunks kept decoded (256² float32: 64 MB)


def working_quads(rows: int, cols: int) -> int:
    """The power of two at or above ``max(rows, cols) - 1`` (at least 16)."""
    q = 16
    while q < max(rows, cols) - 1:
        q *= 2
    return q


class LazyHeights:
    """Level 0 of ``store`` resampled bilinearly to ``(quads+1)²`` samples, read on
    demand: ``heights[rows, cols]`` with integer index arrays (broadcast together) returns
    ``float32`` metres of that shape.  Thread-safe."""

    dtype = np.dtype(np.float32)
    ndim = 2

    def __init__(self, store, quads: int, cache_chunks: int = DEFAULT_CACHE_CHUNKS) -> None:
        self.store = store
        self.quads = quads
        self.shape = (quads + 1, quads + 1)
        self.rows0, self.cols0 = store.shape(0)
        self.chunk = store.chunk
        self.scale = ((self.rows0 - 1) / quads, (self.cols0 - 1) / quads)
        self.capacity = max(4, cache_chunks)
        self._cache: OrderedDict = OrderedDict()
        self._lock = threading.Lock()
        self.chunks_read = 0

    def __getitem__(self, key) -> np.ndarray:
        if not (isinstance(key, tuple) and len(key) == 2):
            raise TypeError("index the lazy heights with (rows, cols) integer arrays")
        rows, cols = np.broadcast_arrays(np.asarray(key[0]), np.asarray(key[1]))
        if rows.dtype.kind not in "iu" or cols.dtype.kind not in "iu":
            raise TypeError("the lazy heights take integer indices only")
        if rows.size and (rows.min() < 0 or cols.min() < 0 or rows.max() > self.quads
                          or cols.max() > self.quads):
            raise IndexError("index outside the working grid")
        return self.sample(rows * self.scale[0], cols * self.scale[1])

    def sample(self, fr: np.ndarray, fc: np.ndarray) -> np.ndarray:
        """Bilinear heights (float32 metres) at fractional level-0 ``(rows, cols)``."""
        fr = np.clip(np.asarray(fr, np.float64), 0, self.rows0 - 1)
        fc = np.clip(np.asarray(fc, np.float64), 0, self.cols0 - 1)
        r0 = np.minimum(np.floor(fr).astype(np.intp), max(self.rows0 - 2, 0))
        c0 = np.minimum(np.floor(fc).astype(np.intp), max(self.cols0 - 2, 0))
        wr, wc = fr - r0, fc - c0
        r1, c1 = np.minimum(r0 + 1, self.rows0 - 1), np.minimum(c0 + 1, self.cols0 - 1)
        out = np.zeros(fr.shape)
        for rr, cc, w in ((r0, c0, (1 - wr) * (1 - wc)), (r0, c1, (1 - wr) * wc),
                          (r1, c0, wr * (1 - wc)), (r1, c1, wr * wc)):
            m = w > 0  # a corner of weight 0 is not read (its chunk may be another)
            if m.any():
                out[m] += self.gather(rr[m], cc[m]) * w[m]
        return out.astype(np.float32)

    def gather(self, r: np.ndarray, c: np.ndarray) -> np.ndarray:
        """Level-0 samples at integer ``(r, c)`` (metres, float64), chunk by chunk."""
        out = np.empty(r.shape, np.float64)
        cid = (r // self.chunk) * (self.cols0 // self.chunk + 1) + c // self.chunk
        flat_r, flat_c, flat_id = r.ravel(), c.ravel(), cid.ravel()
        order = np.argsort(flat_id, kind="stable")
        ids, starts = np.unique(flat_id[order], return_index=True)
        flat = out.reshape(-1)
        for i, start in enumerate(starts):
            end = starts[i + 1] if i + 1 < len(starts) else len(order)
            sel = order[start:end]
            cr, cc = flat_r[sel[0]] // self.chunk, flat_c[sel[0]] // self.chunk
            block = self._chunk(int(cr), int(cc))
            flat[sel] = block[flat_r[sel] - cr * self.chunk, flat_c[sel] - cc * self.chunk]
        return out

    def _chunk(self, cr: int, cc: int) -> np.ndarray:
        key = (cr, cc)
        with self._lock:
            block = self._cache.get(key)
            if block is not None:
                self._cache.move_to_end(key)
                return block
        c = self.chunk
        block = np.asarray(self.store.read(0, cr * c, min((cr + 1) * c, self.rows0),
                                           cc * c, min((cc + 1) * c, self.cols0)))
        if not np.all(np.isfinite(block)):
            raise TerrainError(f"{self.store.path}: level-0 chunk ({cr}, {cc}) holds unwritten "
                               "or invalid heights")
        with self._lock:
            self._cache[key] = block
            self.chunks_read += 1
            while len(self._cache) > self.capacity:
                self._cache.popitem(last=False)
        return block

    def min(self) -> float:
        return float(self.store.minmax(0)[..., 0].min())

    def max(self) -> float:
        return float(self.store.minmax(0)[..., 1].max())

    def block_extremes(self, n: int, step: int) -> tuple[np.ndarray, np.ndarray]:
        """``(lo, hi) (n, n)`` bounds of the heights in each square of ``step`` working
        quads (edges included), from the level-0 chunks each square overlaps."""
        mm = self.store.minmax(0)
        lo, hi = np.empty((n, n)), np.empty((n, n))
        sr, sc = self.scale
        c = self.chunk
        for a in range(n):
            ra, rb = int(a * step * sr) // c, int(np.ceil((a + 1) * step * sr)) // c + 1
            for b in range(n):
                ca, cb = int(b * step * sc) // c, int(np.ceil((b + 1) * step * sc)) // c + 1
                block = mm[ra:rb, ca:cb]
                lo[a, b], hi[a, b] = block[..., 0].min(), block[..., 1].max()
        return lo, hi


@dataclass(frozen=True)
class StoreField(HeightField):
    """A :class:`HeightField` over a store's level 0 whose ``heights`` is a
    :class:`LazyHeights` (read on demand; never loaded whole).  Build it with
    :func:`store_field`."""

    def __post_init__(self) -> None:  # the lazy heights are validated as they are read
        object.__setattr__(self, "dx", float(self.dx))
        object.__setattr__(self, "dy", float(self.dy))

    def scaled(self, exaggeration: float) -> HeightField:
        raise TerrainError("a store field is exaggerated when its store is opened")

    def resampled(self, quads: int) -> HeightField:
        raise TerrainError("a store field is not resampled; open it at another grid")


def store_field(store, cache_chunks: int = DEFAULT_CACHE_CHUNKS) -> StoreField:
    """The working-grid view of ``store``
    (:class:`~lodsprite.terrain.store.TerrainStore`, heights already exaggerated)."""
    rows, cols = store.shape(0)
    q = working_quads(rows, cols)
    heights = LazyHeights(store, q, cache_chunks)
    return StoreField(heights, (cols - 1) * store.dx / q, (rows - 1) * store.dy / q,
                      store.path.name, {"source": str(store.path), "working_quads": q,
                                        "store_rows": rows, "store_cols": cols})
