"""The decoded level-0 chunks of a terrain store that
:class:`~lodsprite.terrain.storefield.LazyHeights` keeps: where each chunk lies on
level 0, and a least-recently-used cache of them with a residency mask that a whole
frame's samples are tested against at once (:meth:`ChunkCache.here`).

A chunk is known by its id ``row * chunk_cols + col`` (row, column of ``chunk``-sample
chunks over a ``rows0 x cols0`` level 0).  Thread-safe: blocks come in from the reading
thread or the reader process's answers (:mod:`lodsprite.terrain.chunkreader`)."""

from __future__ import annotations

import threading
from collections import OrderedDict

import numpy as np


class ChunkCache:
    """At most ``capacity`` (4 or more) decoded chunks of a ``shape0 = (rows0, cols0)``
    level 0 cut in ``chunk x chunk`` samples; :attr:`chunks_read` counts every chunk kept
    so far (re-reads included)."""

    def __init__(self, shape0: tuple[int, int], chunk: int, capacity: int) -> None:
        self.rows0, self.cols0 = int(shape0[0]), int(shape0[1])
        self.chunk = int(chunk)
        self.chunk_cols = -(-self.cols0 // self.chunk)
        self.capacity = max(4, int(capacity))
        self.here = np.zeros(-(-self.rows0 // self.chunk) * self.chunk_cols, bool)
        self.chunks_read = 0
        self._blocks: OrderedDict[int, np.ndarray] = OrderedDict()
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self._blocks)

    def ids(self, r: np.ndarray, c: np.ndarray) -> np.ndarray:
        """The chunk id of each level-0 sample ``(r, c)`` (integer arrays)."""
        return (r // self.chunk) * self.chunk_cols + c // self.chunk

    def window(self, cid: int) -> tuple[int, int, int, int]:
        """Chunk ``cid``'s samples on level 0: ``r0, r1, c0, c1`` (``r1``, ``c1``
        exclusive)."""
        cr, cc = divmod(cid, self.chunk_cols)
        c = self.chunk
        return cr * c, min((cr + 1) * c, self.rows0), cc * c, min((cc + 1) * c, self.cols0)

    def get(self, cid: int) -> np.ndarray | None:
        """Chunk ``cid``'s block (now the most recently used), or None if not held."""
        with self._lock:
            block = self._blocks.get(cid)
            if block is not None:
                self._blocks.move_to_end(cid)
            return block

    def keep(self, cid: int, block: np.ndarray) -> None:
        """Hold ``block`` as chunk ``cid``, dropping the least recently used beyond
        :attr:`capacity`."""
        with self._lock:
            self._blocks[cid] = block
            self._blocks.move_to_end(cid)
            self.here[cid] = True
            self.chunks_read += 1
            while len(self._blocks) > self.capacity:
                self.here[self._blocks.popitem(last=False)[0]] = False

    def held(self) -> set[int]:
        """The ids held now."""
        with self._lock:
            return set(self._blocks)
