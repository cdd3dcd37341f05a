"""A terrain store's tiles read by a worker process (:mod:`lodsprite.workers`), collected
without waiting by the thread that draws.

Zarr v3 reads a window through its asyncio event-loop thread and a codec pool: one read
of a 65² node hands the GIL between threads some twenty times.  While the frame's thread
holds the GIL (moderngl keeps it through each draw call, for the whole llvmpipe
rasterisation), every hand-off waits for the draw to end: a read taking 1.9 ms alone took
113 ms beside a busy Python thread, and a loader *thread* fed the adaptive renderer about
one tile a frame.  So the reads run in a separate process (its own GIL), and the frame's
own thread sends requests and collects answers with non-blocking pipe I/O.

A request's ``meta`` is five little-endian int64 ``k, r0, r1, c0, c1``; an answer's is two
int64 ``a, b`` and its ``data`` the ``a * b`` float32 samples.  A negative ``k`` asks for
imagery level ``-1 - k`` (:func:`imagery_request`): its answer's ``data`` is ``a * b * 4``
bytes of sRGB RGBA.
"""

from __future__ import annotations

import struct

import numpy as np

from lodsprite.workers import ProcessWorker, WorkerError

MAX_WINDOW = 4097 * 4097  # samples: no request may ask for more
FACTORY = "lodsprite.terrain.reader:tile_reader"
_REQ = struct.Struct("<5q")
_SHAPE = struct.Struct("<2q")


def tile_reader(path: str, exaggeration: float = 1.0):
    """The worker's handler: read the requested window of level ``k`` of the store."""
    from lodsprite.terrain.store import TerrainStore

    store = TerrainStore(path, exaggeration)

    def handle(meta: bytes, data: bytes) -> tuple[bytes, bytes]:
        k, r0, r1, c0, c1 = _REQ.unpack(meta)
        if not (0 <= r0 <= r1 and 0 <= c0 <= c1 and (r1 - r0) * (c1 - c0) <= MAX_WINDOW):
            raise ValueError(f"bad window {r0}:{r1}, {c0}:{c1}")
        if k < 0:  # imagery
            if store.imagery is None or -1 - k >= store.imagery.levels:
                raise ValueError(f"no imagery level {-1 - k}")
            rgba = np.ascontiguousarray(store.read_imagery(-1 - k, r0, r1, c0, c1))
            return _SHAPE.pack(*rgba.shape[:2]), rgba.tobytes()
        a = np.ascontiguousarray(store.read(k, r0, r1, c0, c1), np.float32)
        return _SHAPE.pack(*a.shape), a.tobytes()

    return handle


def reader_worker(path, exaggeration: float = 1.0, in_flight: int = 48,
                  restarts: int = 3) -> ProcessWorker:
    """A worker process reading the store at ``path`` (requests: :func:`tile_request`)."""
    return ProcessWorker(FACTORY, {"path": str(path), "exaggeration": float(exaggeration)},
                         in_flight, restarts, name="terrain tile reader")


def tile_request(k: int, r0: int, r1: int, c0: int, c1: int) -> bytes:
    """A request for samples ``[r0:r1, c0:c1]`` of level ``k``."""
    return _REQ.pack(k, r0, r1, c0, c1)


def tile_answer(answer: tuple[bytes, bytes] | WorkerError) -> np.ndarray | str:
    """An answer as samples ``(a, b) float32``, or the error text."""
    if isinstance(answer, WorkerError):
        return answer.text
    meta, data = answer
    a, b = _SHAPE.unpack(meta)
    return np.frombuffer(data, np.float32).reshape(a, b)


def imagery_request(j: int, r0: int, r1: int, c0: int, c1: int) -> bytes:
    """A request for texels ``[r0:r1, c0:c1]`` of imagery level ``j``."""
    return _REQ.pack(-1 - j, r0, r1, c0, c1)


def imagery_answer(answer: tuple[bytes, bytes] | WorkerError) -> np.ndarray | str:
    """An imagery answer as ``(a, b, 4) uint8`` RGBA, or the error text."""
    if isinstance(answer, WorkerError):
        return answer.text
    meta, data = answer
    a, b = _SHAPE.unpack(meta)
    return np.frombuffer(data, np.uint8).reshape(a, b, 4)
