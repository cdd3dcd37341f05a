"""The node loader of the critical-time lumigraph (Sloan, Cohen & Gortler 1997, §4.2):
fetching node files and decoding them on a worker thread, so that a frame never waits
for disk or JPEG.

The renderer hands the loader its wish list each frame (nodes in benefit/cost order,
:func:`~lodsprite.lumigraph.critical.plan`); the worker fetches and decodes the first node
of the list it does not hold yet, measures both costs, and keeps decoded images in a
memory cache of ``ram_mb`` megabytes (least recently used out first).  Pillow releases
the GIL while it decodes.
"""

from __future__ import annotations

import threading
import time
from collections import OrderedDict

import numpy as np

from lodsprite.background import BackgroundLoader
from lodsprite.lumigraph.store import Lumigraph


class NodeLoader(BackgroundLoader):
    """Fetch and decode the nodes of ``slab`` at uv ``level`` in a daemon thread."""

    def __init__(self, lumigraph: Lumigraph, slab: int = 0, level: int = 0,
                 ram_mb: float = 256.0) -> None:
        self.lf, self.slab, self.level = lumigraph, int(slab), int(level)
        s = lumigraph.slabs[self.slab]
        self.n_st = s.n_st
        m = max(1, s.n_uv >> self.level)
        self.max_images = max(1, int(ram_mb * 2 ** 20 // (m * m * 3)))
        self._cache: OrderedDict[int, np.ndarray] = OrderedDict()
        self._bad: set[int] = set()
        self._wanted: list[int] = []
        self._cv = threading.Condition()
        self.loaded: list[tuple[int, float, float]] = []  # (node, fetch_ms, decode_ms)
        self.decoded = 0  # nodes fetched and decoded in all
        super().__init__("lumigraph-loader")

    def want(self, nodes: np.ndarray) -> None:
        """Replace the wish list (best first)."""
        with self._cv:
            self._wanted = [int(n) for n in nodes if int(n) not in self._cache
                            and int(n) not in self._bad]
            if self._wanted:
                self._cv.notify()

    def get(self, node: int) -> np.ndarray | None:
        """A decoded node image, or None if not held (marks it recently used)."""
        with self._cv:
            img = self._cache.get(node)
            if img is not None:
                self._cache.move_to_end(node)
            return img

    def holds(self, n_nodes: int) -> np.ndarray:
        """``(n_nodes,) bool``: which nodes are decoded in memory."""
        out = np.zeros(n_nodes, dtype=bool)
        with self._cv:
            out[list(self._cache)] = True
        return out

    @property
    def bad(self) -> set[int]:
        with self._cv:
            return set(self._bad)

    def drain_costs(self) -> list[tuple[int, float, float]]:
        """The (node, fetch ms, decode ms) measured since the last call."""
        with self._cv:
            out, self.loaded = self.loaded, []
        return out

    def load_now(self, node: int) -> np.ndarray | None:
        """Fetch and decode ``node`` on the calling thread (warm-up only)."""
        img = self.get(node)
        return img if img is not None else self._load(node)

    def _load(self, node: int) -> np.ndarray | None:
        i, j = divmod(node, self.n_st)
        t0 = time.perf_counter()
        data = self.lf.node_bytes(self.slab, i, j)
        t1 = time.perf_counter()
        img = None if data is None else self.lf.decode(data, self.slab, i, j, self.level)
        t2 = time.perf_counter()
        with self._cv:
            if img is None:
                self._bad.add(node)
                return None
            self._cache[node] = img
            self.decoded += 1
            while len(self._cache) > self.max_images:
                self._cache.popitem(last=False)
            self.loaded.append((node, (t1 - t0) * 1e3, (t2 - t1) * 1e3))
        return img

    def _next(self) -> int | None:
        while self._wanted:
            node = self._wanted.pop(0)
            if node not in self._cache and node not in self._bad:
                return node
        return None
