"""The node loader of the critical-time lumigraph (Sloan, Cohen & Gortler 1997, §4.2):
fetching node files and decoding them in a worker process, so that a frame never waits
for disk or JPEG.

The renderer hands the loader its wish list each frame (nodes in benefit/cost order,
:func:`~lodsprite.lumigraph.critical.plan`); at most ``in_flight`` of them at a time go to
a decoder process (:class:`~lodsprite.workers.ProcessWorker`, started on the first wish
list), which fetches and decodes each, measures both costs, and writes the image into a
slot of memory shared with the loader (the pipe carries only a header: a frame that
collects late never leaves the process waiting on a full pipe).  The frame's thread
collects what has arrived without waiting and keeps decoded images in a memory cache of
``ram_mb`` megabytes (least recently used out first).
A thread would not do: moderngl holds the GIL through each draw call, and a decoder
thread beside a busy draw loop decoded 6.5-31.5 nodes a second, where the process decodes
50-101 (``benchmarks/beside_draws.py``; 226-521 alone, either way).
"""

from __future__ import annotations

import struct
import time
from collections import OrderedDict

import numpy as np

from lodsprite.lumigraph.store import Lumigraph
from lodsprite.workers import ProcessWorker, WorkerError

FACTORY = "lodsprite.lumigraph.loader:node_decoder"
IN_FLIGHT = 16  # nodes sent to the decoder ahead (the critical method requests 16 a frame)
_REQ = struct.Struct("<q")
_ANSWER = struct.Struct("<3q2d")  # h, w, channels, fetch ms, decode ms


def node_decoder(path: str, slab: int, level: int):
    """The worker's handler: fetch and decode a node (``meta``: its int64 index); answers
    ``(h, w, 3) uint8`` and the fetch and decode times in ms, or raises why not."""
    lf = Lumigraph(path)
    n_st = lf.slabs[slab].n_st

    def handle(meta: bytes, data: bytes) -> tuple[bytes, bytes]:
        i, j = divmod(_REQ.unpack(meta)[0], n_st)
        t0 = time.perf_counter()
        raw = lf.node_bytes(slab, i, j)
        t1 = time.perf_counter()
        img = None if raw is None else lf.decode(raw, slab, i, j, level)
        t2 = time.perf_counter()
        if img is None:
            raise OSError(lf.bad_nodes.get((slab, i, j), "unusable"))
        img = np.ascontiguousarray(img, np.uint8)
        return (_ANSWER.pack(*img.shape, (t1 - t0) * 1e3, (t2 - t1) * 1e3), img.tobytes())

    return handle


class NodeLoader:
    """Fetch and decode the nodes of ``slab`` at uv ``level`` in a worker process."""

    def __init__(self, lumigraph: Lumigraph, slab: int = 0, level: int = 0,
                 ram_mb: float = 256.0, in_flight: int = IN_FLIGHT) -> None:
        self.lf, self.slab, self.level = lumigraph, int(slab), int(level)
        s = lumigraph.slabs[self.slab]
        self.n_st = s.n_st
        m = max(1, s.n_uv >> self.level)
        self.image_bytes = m * m * 3  # one decoded node, uint8 RGB
        self.max_images = max(1, int(ram_mb * 2 ** 20 // self.image_bytes))
        self.in_flight = int(in_flight)
        self._cache: OrderedDict[int, np.ndarray] = OrderedDict()
        self._bad: set[int] = set()
        self._wanted: list[int] = []
        self._worker: ProcessWorker | None = None  # started by the first wish list
        self.loaded: list[tuple[int, float, float]] = []  # (node, fetch_ms, decode_ms)
        self.decoded = 0  # nodes fetched and decoded in all

    def want(self, nodes: np.ndarray) -> None:
        """Replace the wish list (best first) and :meth:`pump`."""
        busy = set(self._worker.pending) if self._worker is not None else set()
        self._wanted = [int(n) for n in nodes if int(n) not in self._cache
                        and int(n) not in self._bad and int(n) not in busy]
        self.pump()

    def pump(self) -> None:
        """Collect the nodes decoded so far and send the next wanted ones (never waits)."""
        if self._worker is None:
            if not self._wanted:
                return
            self._worker = ProcessWorker(FACTORY, {"path": str(self.lf.folder.resolve()),
                                                   "slab": self.slab, "level": self.level},
                                         self.in_flight, name="lumigraph node decoder",
                                         slot_bytes=self.image_bytes)
        for node, answer in self._worker.poll():
            self._arrived(int(node), answer)
        while self._wanted and not self._worker.full:
            self._worker.submit(node := self._wanted.pop(0), _REQ.pack(node))

    def _arrived(self, node: int, answer: tuple[bytes, bytes] | WorkerError) -> None:
        if isinstance(answer, WorkerError):
            self._bad.add(node)
            i, j = divmod(node, self.n_st)
            self.lf.mark_bad(self.slab, i, j, answer.text)
            return
        meta, data = answer
        h, w, c, fetch_ms, decode_ms = _ANSWER.unpack(meta)
        self._put(node, np.frombuffer(data, np.uint8).reshape(h, w, c), fetch_ms, decode_ms)

    def _put(self, node: int, img: np.ndarray, fetch_ms: float, decode_ms: float) -> None:
        self._cache[node] = img
        self._cache.move_to_end(node)
        self.decoded += 1
        while len(self._cache) > self.max_images:
            self._cache.popitem(last=False)
        self.loaded.append((node, fetch_ms, decode_ms))

    def get(self, node: int) -> np.ndarray | None:
        """A decoded node image, or None if not held (marks it recently used)."""
        img = self._cache.get(node)
        if img is not None:
            self._cache.move_to_end(node)
        return img

    def holds(self, n_nodes: int) -> np.ndarray:
        """``(n_nodes,) bool``: which nodes are decoded in memory."""
        out = np.zeros(n_nodes, dtype=bool)
        out[list(self._cache)] = True
        return out

    @property
    def bad(self) -> set[int]:
        return set(self._bad)

    def drain_costs(self) -> list[tuple[int, float, float]]:
        """The (node, fetch ms, decode ms) measured since the last call."""
        out, self.loaded = self.loaded, []
        return out

    def load_now(self, node: int) -> np.ndarray | None:
        """Fetch and decode ``node`` on the calling thread (warm-up, and the methods that
        decode in the frame)."""
        img = self.get(node)
        if img is not None or node in self._bad:
            return img
        i, j = divmod(node, self.n_st)
        t0 = time.perf_counter()
        data = self.lf.node_bytes(self.slab, i, j)
        t1 = time.perf_counter()
        img = None if data is None else self.lf.decode(data, self.slab, i, j, self.level)
        t2 = time.perf_counter()
        if img is None:
            self._bad.add(node)
            return None
        self._put(node, img, (t1 - t0) * 1e3, (t2 - t1) * 1e3)
        return img

    def close(self) -> None:
        """End the decoder process (what is in flight is dropped)."""
        if self._worker is not None:
            self._worker.close()
            self._worker = None
