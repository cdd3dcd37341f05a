"""Streaming terrain tiles for the adaptive renderer: a background loader filling a host
cache, and the bookkeeping of the GPU cache's slots; both least-recently-used under a
budget in MB, GL-free.

The frame asks :class:`TileLoader` for the nodes it wants, most urgent first; a worker
thread reads each node's samples from the pyramid (a Zarr store decodes its chunks with the
GIL released) into the host cache; the frame takes what has arrived and uploads it into
GPU slots (:class:`SlotCache`), evicting the slots used longest ago.  A node whose data
cannot be read, or holds unwritten samples (NaN), is bad: it is reported once and never
becomes resident, so its parent keeps being drawn in its place.
"""

from __future__ import annotations

import heapq
import logging
import threading
from collections import OrderedDict

import numpy as np

from lodsprite.background import BackgroundLoader
from lodsprite.errors import InputError

log = logging.getLogger(__name__)


class TileLoader(BackgroundLoader):
    """Reads nodes of ``tree`` (:class:`~lodsprite.terrain.quadtree.Quadtree`) on a
    daemon thread into a host cache of ``host_mb`` megabytes."""

    def __init__(self, tree, host_mb: float = 256.0) -> None:
        if not host_mb > 0:
            raise InputError(f"the host cache budget must be > 0 MB, got {host_mb}")
        self.tree = tree
        self.node_bytes = (tree.g + 1) ** 2 * 4
        self.capacity = max(4, int(host_mb * 2 ** 20 // self.node_bytes))
        self.cache: OrderedDict = OrderedDict()
        self.bad: set = set()
        self.loaded = self.evicted = 0
        self._queue: list = []
        self._queued: set = set()
        self._cv = threading.Condition()
        super().__init__("tile-loader")

    def read_now(self, node) -> np.ndarray | None:
        """Read ``node`` on the calling thread (the roots, before the first frame)."""
        with self._cv:
            if node in self.cache:
                return self.cache[node]
        return self._load(node)

    def want(self, requests: list) -> None:
        """Replace the wish list with ``(urgency, node)`` requests (most urgent read
        first): what the frame no longer wants is dropped."""
        with self._cv:
            self._queue, self._queued = [], set()
            for urgency, node in requests:
                if node in self.cache or node in self.bad or node in self._queued:
                    continue
                self._queue.append((-urgency, id(node), node))
                self._queued.add(node)
            heapq.heapify(self._queue)
            self._cv.notify()

    def idle(self) -> bool:
        """Nothing left on the wish list."""
        with self._cv:
            return not self._queue

    def take(self, node) -> np.ndarray | None:
        """The node's samples if they have arrived (marks them recently used)."""
        with self._cv:
            data = self.cache.get(node)
            if data is not None:
                self.cache.move_to_end(node)
            return data

    def _load(self, node) -> np.ndarray | None:
        r0, r1, c0, c1 = self.tree.samples(node)
        try:
            data = np.asarray(self.tree.p.read(node.k, r0, r1, c0, c1), np.float32)
            if not np.isfinite(data).all():
                raise ValueError("unwritten samples")
        except Exception as exc:  # a damaged chunk: draw the parent instead
            with self._cv:
                if node not in self.bad:
                    log.warning("terrain tile %s unreadable (%s): its parent is drawn "
                                "instead", node, exc)
                self.bad.add(node)
            return None
        with self._cv:
            self.cache[node] = data
            self.loaded += 1
            while len(self.cache) > self.capacity:
                self.cache.popitem(last=False)
                self.evicted += 1
        return data

    def _next(self):
        if not self._queue:
            return None
        _, _, node = heapq.heappop(self._queue)
        self._queued.discard(node)
        return node


class SlotCache:
    """The GPU cache's bookkeeping: ``capacity`` slots, node -> slot, least recently
    drawn evicted first; never a slot drawn in the current frame."""

    def __init__(self, capacity: int) -> None:
        if capacity < 1:
            raise InputError(f"the GPU cache holds no tile (capacity {capacity})")
        self.capacity = int(capacity)
        self.slots: OrderedDict = OrderedDict()
        self.free = list(range(self.capacity - 1, -1, -1))
        self.evicted = 0

    def __contains__(self, node) -> bool:
        return node in self.slots

    def touch(self, node) -> None:
        self.slots.move_to_end(node)

    def slot(self, node) -> int:
        return self.slots[node]

    def assign(self, node, keep: set) -> int | None:
        """A slot for ``node``: a free one, or the least recently used one not in
        ``keep``; None if every slot is kept."""
        if self.free:
            s = self.free.pop()
        else:
            victim = next((n for n in self.slots if n not in keep), None)
            if victim is None:
                return None
            s = self.slots.pop(victim)
            self.evicted += 1
        self.slots[node] = s
        return s
