"""Level-0 chunks of a terrain store asked of a reader process, never waited for on the
frame's thread (issue 22, must-have 6).

:class:`~lodsprite.terrain.storefield.LazyHeights`, once it reads without blocking, asks
a :class:`ChunkReader` for the chunks a frame lacks and collects them later, as
:class:`~lodsprite.terrain.streaming.StoreTileLoader` streams the adaptive renderer's
tiles: the reads run in a tile reader process (:mod:`lodsprite.terrain.reader`, a
:class:`~lodsprite.workers.ProcessWorker`: moderngl holds the GIL through the draws, so
a Python thread would read only between them), requests and answers go through pipes
without waiting.  The wish list holds the newest ``capacity`` chunk ids and is sent
newest first, at most ``in_flight`` outstanding.  A process that dies is started again
at most :data:`READER_RESTARTS` times; the request it died on fails (the caller counts
that chunk unreadable).
"""

from __future__ import annotations

import logging
import time
from collections import OrderedDict
from collections.abc import Callable

import numpy as np

log = logging.getLogger(__name__)

READER_RESTARTS = 3  # a reader process that dies is started again this many times
READY_S = 30.0       # the setup waits at most this long for the process's first answer


class ChunkReader:
    """Chunks of level 0 of ``store`` read by a reader process: ``window(id) -> (r0, r1,
    c0, c1)`` gives a chunk's samples; at most ``in_flight`` requests outstanding and
    ``capacity`` chunk ids wished for.  Made at setup: it waits there for the process's
    first answer (a sample of level ``ready_level``), so that starting Python and Zarr
    (a CPU second or so) takes nothing from the first timed frames."""

    def __init__(self, store, window: Callable[[int], tuple[int, int, int, int]],
                 in_flight: int, capacity: int, ready_level: int = 0) -> None:
        from lodsprite.terrain.reader import reader_worker

        self.worker = reader_worker(store.path, store.exaggeration, in_flight,
                                    READER_RESTARTS)
        self.window, self.capacity, self.path = window, int(capacity), store.path
        self.wanted: OrderedDict = OrderedDict()  # chunk id -> None, newest last
        self._ready(ready_level)

    def _ready(self, k: int, timeout_s: float = READY_S) -> None:
        from lodsprite.terrain.reader import tile_request

        self.worker.submit("ready", tile_request(k, 0, 1, 0, 1))
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if any(key == "ready" for key, _ in self.worker.poll()):
                return
            time.sleep(0.005)
        log.warning("%s: the level-0 reader process gave no answer in %.0f s", self.path,
                    timeout_s)

    def want(self, ids: np.ndarray, skip: set) -> None:
        """Wish for chunks ``ids`` (newest wishes last; the oldest dropped past
        ``capacity``), but not those in ``skip`` or in flight."""
        if len(ids) == 0:
            return
        busy = set(self.worker.pending)
        for cid in ids.tolist():
            if cid not in skip and cid not in busy:
                self.wanted[cid] = None
                self.wanted.move_to_end(cid)
        while len(self.wanted) > self.capacity:
            self.wanted.popitem(last=False)

    def send(self, have: set) -> None:
        """Send the newest wishes the process has room for (not those in ``have``)."""
        from lodsprite.terrain.reader import tile_request

        while self.wanted and not self.worker.full:
            cid, _ = self.wanted.popitem(last=True)
            if cid not in have:
                self.worker.submit(cid, tile_request(0, *self.window(cid)))

    def answers(self) -> list[tuple[int, np.ndarray | str]]:
        """``(chunk id, samples float32 or the error's text)`` arrived since the last
        call; never waits."""
        from lodsprite.terrain.reader import tile_answer

        return [(cid, tile_answer(a)) for cid, a in self.worker.poll() if cid != "ready"]

    @property
    def busy(self) -> bool:
        """Chunks wished for or in flight."""
        return bool(self.wanted or self.worker.pending)

    @property
    def alive(self) -> bool:
        return self.worker.alive

    @property
    def restarts(self) -> int:
        """Times the process died and was started again (at most :data:`READER_RESTARTS`)."""
        return min(self.worker.deaths, READER_RESTARTS)

    def peak_mb(self) -> float:
        """The process's peak resident memory in MB (0 when none runs)."""
        return self.worker.peak_mb()

    def close(self) -> None:
        self.worker.close()
        self.wanted.clear()
