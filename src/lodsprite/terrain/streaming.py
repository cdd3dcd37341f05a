"""Streaming terrain tiles for the adaptive renderer: loaders filling a host cache, and
the bookkeeping of the GPU cache's slots; both least-recently-used under a budget in MB,
GL-free.

The frame asks its loader for the nodes it wants, most urgent first, and takes what has
arrived, uploading it into GPU slots (:class:`SlotCache`), evicting the slots used longest
ago.  A node whose data cannot be read, or holds unwritten samples (NaN), is bad: it is
reported once and never becomes resident, so its parent keeps being drawn in its place.

* :class:`StoreTileLoader` (terrain stores): a reader process
  (:mod:`lodsprite.terrain.reader`, a :class:`~lodsprite.workers.ProcessWorker`) reads
  and decodes; the frame's own thread sends requests and collects answers without
  blocking, so no thread waits on the GIL that the draw calls hold.  A reader process
  that dies is started again (its request in flight is counted bad); after three deaths
  the remaining requests are bad.
* :class:`TileLoader` (in-memory pyramids): the frame's thread copies nodes out of
  memory, a few dozen a frame.
"""
from __future__ import annotations

import heapq
import logging
from collections import OrderedDict

import numpy as np

from lodsprite.errors import InputError

log = logging.getLogger(__name__)


class HostCache:
    """The host LRU cache of node samples and the wish list, shared by the loaders (all
    driven from the frame's thread)."""

    def __init__(self, tree, host_mb: float) -> None:
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

    def _wish(self, requests: list, busy=()) -> None:
        """Replace the wish list."""
        self._queue, self._queued = [], set()
        for urgency, node in requests:
            if node in self.cache or node in self.bad or node in self._queued or node in busy:
                continue
            self._queue.append((-urgency, id(node), node))
            self._queued.add(node)
        heapq.heapify(self._queue)

    def _next(self):
        if not self._queue:
            return None
        _, _, node = heapq.heappop(self._queue)
        self._queued.discard(node)
        return node

    def _keep(self, node, data) -> np.ndarray | None:
        """Validate and cache ``data`` (an array, or an exception or text saying why
        not)."""
        try:
            if isinstance(data, (BaseException, str)):
                raise OSError(str(data))
            data = np.asarray(data, np.float32)
            if not np.isfinite(data).all():
                raise ValueError("unwritten samples")
        except Exception as exc:  # a damaged chunk: draw the parent instead
            if node not in self.bad:
                log.warning("terrain tile %s unreadable (%s): its parent is drawn "
                            "instead", node, exc)
            self.bad.add(node)
            return None
        self.cache[node] = data
        self.loaded += 1
        while len(self.cache) > self.capacity:
            self.cache.popitem(last=False)
            self.evicted += 1
        return data

    def _read_in_place(self, node):
        r0, r1, c0, c1 = self.tree.samples(node)
        try:
            return self.tree.p.read(node.k, r0, r1, c0, c1)
        except Exception as exc:
            return exc

    def read_now(self, node) -> np.ndarray | None:
        """Read ``node`` on the calling thread (the roots, before the first frame)."""
        if node in self.cache:
            return self.cache[node]
        return self._keep(node, self._read_in_place(node))

    def take(self, node) -> np.ndarray | None:
        """The node's samples if they have arrived (marks them recently used)."""
        data = self.cache.get(node)
        if data is not None:
            self.cache.move_to_end(node)
        return data


class TileLoader(HostCache):
    """Copies nodes of ``tree`` (:class:`~lodsprite.terrain.quadtree.Quadtree`) of an
    in-memory pyramid into a host cache of ``host_mb`` megabytes, on the frame's thread:
    a copy out of memory (tens of microseconds) waits on nothing, so a thread would only
    contend for the GIL.  At most ``per_pump`` nodes a :meth:`pump`."""

    def __init__(self, tree, host_mb: float = 256.0, per_pump: int = 48) -> None:
        super().__init__(tree, host_mb)
        self.per_pump = max(1, int(per_pump))

    def pump(self) -> None:
        """Copy the next ``per_pump`` nodes of the wish list."""
        for _ in range(self.per_pump):
            node = self._next()
            if node is None:
                return
            self._keep(node, self._read_in_place(node))

    def want(self, requests: list) -> None:
        """Replace the wish list with ``(urgency, node)`` requests (most urgent read
        first; what the frame no longer wants is dropped), and pump."""
        self._wish(requests)
        self.pump()

    def idle(self) -> bool:
        """Nothing left on the wish list."""
        self.pump()
        return not self._queue

    @property
    def pending(self) -> list:
        """Nodes in flight: none (each is copied as it is taken from the wish list)."""
        return []

    def close(self) -> None:
        self._queue, self._queued = [], set()

    @property
    def in_flight_tiles(self) -> int:
        """Tiles asked for and not yet read."""
        with self._cv:
            return len(self._queue)


class StoreTileLoader(HostCache):
    """Reads nodes of a terrain store through a reader process, driven by the frame's
    thread (module docstring): at most ``in_flight`` requests outstanding."""

    RESTARTS = 3

    def __init__(self, tree, host_mb: float = 256.0, in_flight: int = 48) -> None:
        from lodsprite.terrain.reader import reader_worker

        super().__init__(tree, host_mb)
        self.worker = reader_worker(tree.p.path, tree.p.exaggeration, in_flight,
                                    self.RESTARTS)

    def pump(self) -> None:
        """Collect what has arrived and send what the wish list wants next."""
        from lodsprite.terrain.reader import tile_answer, tile_request

        for node, answer in self.worker.poll():
            self._keep(node, tile_answer(answer))
        while self._queue and not self.worker.full:
            node = self._next()
            self.worker.submit(node, tile_request(node.k, *self.tree.samples(node)))
        if not self.worker.alive:  # no reader: what is wanted cannot be read
            for node, answer in self.worker.poll():
                self._keep(node, tile_answer(answer))

    def want(self, requests: list) -> None:
        """Replace the wish list with ``(urgency, node)`` requests (most urgent read
        first; what the frame no longer wants is dropped), and pump."""
        self._wish(requests, busy=set(self.worker.pending))
        self.pump()

    def idle(self) -> bool:
        """Nothing wanted and nothing in flight."""
        self.pump()
        return not self._queue and not self.worker.pending

    @property
    def pending(self) -> list:
        """The nodes sent to the reader and not answered yet, oldest first."""
        return self.worker.pending

    @property
    def in_flight_tiles(self) -> int:
        """Tiles sent to the reader process and not yet answered."""
        return len(self._sent)

    def reader_peak_mb(self) -> float:
        """The reader process's peak resident memory in MB (0 when none runs)."""
        return self.worker.peak_mb()

    def close(self) -> None:
        self.worker.close()


def tile_loader(tree, host_mb: float = 256.0) -> HostCache:
    """The loader for ``tree``'s pyramid: a reader process for a store, copies on the
    frame's thread for an in-memory pyramid."""
    from lodsprite.terrain.store import TerrainStore

    if isinstance(tree.p, TerrainStore):
        return StoreTileLoader(tree, host_mb)
    return TileLoader(tree, host_mb)


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
