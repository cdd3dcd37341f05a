"""Keyframes rendered beside the drawing loop: Swan et al. (2002)'s server/client split,
the server as a process of its own.

The 2002 paper renders keyframes on a second graphics pipe (the LOD server) so that the
client draws spriteframes at a steady rate.  :class:`KeyframeWorker` is the client's
end of that server, which runs as a :class:`~lodsprite.workers.ProcessWorker` (the one
process mechanism, :mod:`lodsprite.procs`: moderngl holds the GIL through each draw, so
a thread beside the draws runs only between them).  The process makes its own headless
OpenGL context and the scene's terrain from the drawing side's arrays (the same heights,
exaggeration included, and texture, handed over once through shared memory), renders
the full-resolution terrain for the viewpoint it is sent, reads the keyframe's colour
and z-buffer back and answers them through a shared-memory slot, with the keyframe's
``C'`` (the error metric's reprojected centres, Eq. 2).  The drawing side places each
request ``δt`` ahead (:mod:`lodsprite.sprite.predictors`, the paper's
VIEWPOINT-PREDICTOR, fed with the observed viewpoints; δt is the measured
request-to-adoption latency), polls for the answer without waiting and uploads it
(:meth:`~lodsprite.gl.sprite.SpriteDrawer.upload_keyframe`).

Over a terrain store (``sprite-adaptive``, keyframes drawn by the adaptive renderer at
``--key-sse``: :attr:`WorkerSettings.store`) the process opens the store itself and
renders each keyframe with its own adaptive renderer, streaming its own tiles
(:mod:`lodsprite.techniques.adaptive_worker`); its answer adds what the keyframe lacks
(``deficit_px``: tiles its tolerance needs that had not arrived) and the selection it
was drawn with (for the untimed replay).

The process lowers its own scheduling priority (``nice``, Linux) before it makes its
context, so that the software rasteriser's threads it starts inherit it: on a machine
without a GPU, the drawing loop's spriteframes come first and keyframes take the
remaining CPU time.
"""

from __future__ import annotations

import logging
import pickle
import time
from collections import deque
from dataclasses import dataclass
from multiprocessing import shared_memory
from multiprocessing.connection import wait as wait_readable
from typing import TYPE_CHECKING

import numpy as np

from lodsprite.camera import Projection, Viewpoint
from lodsprite.errors import LodspriteError
from lodsprite.procs import WorkerDied, WorkerError, WorkerUnavailable
from lodsprite.sprite.guard import GuardBand
from lodsprite.sprite.predictors import PREDICTORS
from lodsprite.sprite.worker_settings import WorkerSettings
from lodsprite.workers import ProcessWorker

if TYPE_CHECKING:  # the scene is passed in
    from lodsprite.scene import Scene
    from lodsprite.sprite.depth_metric import DepthEstimate

log = logging.getLogger(__name__)

SAMPLES_KEPT = 64
READY_S = 60.0          # the process's start (context, scene, shaders) has this long
MAX_REQUEST = 4096      # bytes: a pickled viewpoint and two numbers
LEAD_SMOOTHING = 0.3    # weight of the newest latency in the lead's running mean
FACTORY = "lodsprite.sprite.keyframe_process:keyframe_handler"


@dataclass(frozen=True)
class KeyframeImage:
    """A keyframe rendered by the worker, ready to upload.

    ``color (H, W, 3) uint8`` and ``depth (H, W) float32`` (window depth; whose z-buffer:
    ``zbuffer``, "coarse" or "full"), row 0 at the top, at the keyframe size (image plus
    guard band); ``projection``: the keyframe's own (widened); ``frame_projection``: the
    frame projection at its viewpoint; ``c_prime (n*n, 3)`` metres (a
    :class:`~lodsprite.sprite.raycast.Reprojection`); ``requested_at``
    (``time.perf_counter`` seconds of the drawing process); ``render_ms``: the worker's
    time for it; ``predicted``: placed ahead of the latest viewpoint sample;
    ``estimate``: the error estimate on its own depth, when the worker built it."""

    viewpoint: Viewpoint
    projection: Projection
    frame_projection: Projection
    color: np.ndarray
    depth: np.ndarray
    zbuffer: str
    c_prime: np.ndarray
    requested_at: float
    render_ms: float
    predicted: bool
    deficit_px: float = 0.0
    selection: tuple | None = None
    estimate: DepthEstimate | None = None


class KeyframeWorker:
    """A process with its own GL context that renders keyframes on request.

    The drawing loop calls :meth:`observe` every frame (cheap), :meth:`request` when a
    keyframe is wanted (the viewpoint is predicted there) and :meth:`poll` for a finished
    one; none of them waits, only :meth:`wait` does (start-up, with a deadline).
    :attr:`lead_s` is how far ahead keyframes are placed; :attr:`guard` widens whole
    keyframes' guard band by the predictor's measured error
    (:class:`~lodsprite.sprite.guard.GuardBand`; set it to None for the fixed guard band
    the slots hold); :attr:`render_ms` lists the
    process's time for each keyframe delivered (ms, the first one included).  A process
    that fails to start raises :class:`~lodsprite.procs.WorkerUnavailable` here; one that
    dies or fails to render sets :attr:`error` (a :class:`~lodsprite.procs.WorkerError`):
    it is not started again (no keyframe will come).
    """

    def __init__(self, scene: Scene, settings: WorkerSettings, ready_s: float = READY_S,
                 start=None) -> None:
        if settings.predictor not in PREDICTORS:
            raise LodspriteError(f"unknown predictor {settings.predictor!r}")
        if scene.hf is None:
            raise LodspriteError("the keyframe worker needs a scene with terrain")
        self.scene = scene
        self.settings = settings
        self.lead_s = 0.0
        self._leads = 0  # latencies measured into lead_s
        self.rendered = 0
        self.render_ms: list[float] = []
        self.error: WorkerError | None = None
        self._samples: deque[tuple[float, Viewpoint]] = deque(maxlen=SAMPLES_KEPT)
        self._predictor = PREDICTORS[settings.predictor]()
        self._fed = -np.inf
        self._wanted: float | None = None  # request time of the keyframe asked for
        self._closed = False
        # whole keyframes: the guard band widened by the predictor's error (None: fixed)
        self.guard: GuardBand | None = (
            GuardBand(settings.guard_px, settings.size, settings.fov_y_deg)
            if settings.tiles <= 1 else None)
        self.request_extra: tuple = ()  # appended to each request (another handler's)
        # ``start(scene, settings, ready_s)``: another handler's process (a scene's)
        self._proc = (start or _start)(scene, settings, ready_s)

    @property
    def pid(self) -> int | None:
        """The worker process's id (None once it is gone)."""
        return self._proc.pid

    def observe(self, t: float, viewpoint: Viewpoint) -> None:
        """A viewpoint sample at ``t`` seconds (``time.perf_counter``)."""
        self._samples.append((t, viewpoint))
        if self.guard is not None:
            self.guard.observe(t, viewpoint)

    @property
    def busy(self) -> bool:
        """Whether a keyframe has been requested and not yet taken."""
        return self._wanted is not None

    def measure_lead(self, requested_at: float, now: float) -> None:
        """A delivery at ``now`` of what was asked for at ``requested_at``
        (``time.perf_counter`` seconds) in :attr:`lead_s`, the running mean of
        request-to-delivery latencies.  Callers measure every delivery, taken or not
        (from adopted ones only, a lead that overshot would discard every later one and
        never be corrected), and not the first, waited for at start-up."""
        latency = max(now - requested_at, 0.0)
        w = LEAD_SMOOTHING if self._leads else 1.0
        self._leads += 1
        self.lead_s = (1 - w) * self.lead_s + w * latency

    def request(self, tiles: tuple[int, ...] | None = None) -> bool:
        """Ask for a keyframe at the predicted viewpoint (``tiles``: only those tiles of
        it, :attr:`WorkerSettings.tiles`); no-op while one is on its way, after a failure
        or :meth:`close`.  Returns whether a request was sent."""
        if self._wanted is not None or self._closed or self.error is not None:
            return False
        if not self._samples:
            raise LodspriteError("a keyframe request needs an observed viewpoint")
        now = time.perf_counter()
        vp, predicted = self._target(now)
        self._wanted = now
        spread = 1.0 if self.guard is None else self.guard.aim(now + self.lead_s, vp)
        extra = self.request_extra if tiles is None else (tuple(int(t) for t in tiles),)
        self._proc.submit(now, pickle.dumps((vp, predicted, now, spread, *extra)))
        return True

    def poll(self) -> KeyframeImage | None:
        """The keyframe finished since the last call, or None (never blocks).  A failed
        render or a dead process sets :attr:`error`."""
        if self._closed:
            return None
        got = None
        for _, answer in self._proc.poll():
            self._wanted = None
            if isinstance(answer, WorkerError):
                self._fail(answer)
            else:
                got = _image(*answer)
                self.rendered += 1
                self.render_ms.append(got.render_ms)
        if self.error is None and not self._proc.alive:
            self._fail(self._proc.gone or WorkerDied("the keyframe process stopped"))
        return got

    def wait(self, timeout_s: float = 60.0) -> KeyframeImage:
        """Block until the requested keyframe is ready (start-up only); raises
        :class:`~lodsprite.errors.LodspriteError` when it fails or ``timeout_s`` passes."""
        deadline = time.monotonic() + timeout_s
        while True:
            got = self.poll()
            if got is not None:
                return got
            if self.error is not None:
                raise LodspriteError(f"keyframe worker failed: {self.error}") from self.error
            if self._wanted is None:
                raise LodspriteError("no keyframe was requested")
            left = deadline - time.monotonic()
            if left <= 0:
                raise LodspriteError(f"no keyframe within {timeout_s:g} s")
            wait_readable([self._proc], timeout=min(left, 0.5))  # an answer or a death

    def close(self) -> None:
        """End the process (its GL context and objects go with it).  Idempotent."""
        self._closed = True
        self._wanted = None
        self._proc.close()

    def _fail(self, error: WorkerError) -> None:
        log.error("keyframe worker stopped: %s", error)
        self.error = error

    def _target(self, now: float) -> tuple[Viewpoint, bool]:
        """The viewpoint to render: the latest sample moved ``lead_s`` ahead (the
        predictor fed with the samples observed since the last request), unless the
        prediction goes under the ground."""
        for t, vp in tuple(self._samples):
            if t > self._fed:
                self._predictor.observe(t, vp)
                self._fed = t
        latest_t, latest = self._samples[-1]
        ahead = now - latest_t + self.lead_s
        if ahead <= 0 or len(self._samples) < 2:
            return latest, False
        vp = self._predictor.predict(ahead)
        ground = float(self.scene.hf.height_at(vp.o[0], vp.o[1]))
        return (vp, True) if vp.o[2] > ground else (latest, False)


def _start(scene: Scene, settings: WorkerSettings, ready_s: float) -> ProcessWorker:
    """The worker process, ready (its context and scene made), or
    :class:`~lodsprite.procs.WorkerUnavailable` saying why not.  The scene's arrays go
    through a shared-memory segment that is unlinked once the process has copied them."""
    hf = scene.hf
    arrays = {"heights": hf.heights}
    if scene.texture is not None:
        arrays["texture"] = np.ascontiguousarray(scene.texture)
    shm, layout = share_arrays(arrays)
    return start_ready(FACTORY if settings.store is None else settings.store.factory,
                       {"layout": layout, "field": (hf.dx, hf.dy, hf.name, dict(hf.meta))},
                       shm, settings, ready_s, "keyframes")


def start_ready(factory: str, args: dict, shm: shared_memory.SharedMemory,
                settings: WorkerSettings, ready_s: float, name: str) -> ProcessWorker:
    """The keyframe process ``name`` of the request handler ``factory`` (called with
    ``args``, ``settings`` and ``shm_name``), ready, or
    :class:`~lodsprite.procs.WorkerUnavailable` saying why not; the segment ``shm`` is
    closed and unlinked once the process has copied it out (or is gone)."""
    try:
        proc = ProcessWorker(factory, {**args, "shm_name": shm.name, "settings": settings},
                             in_flight=1, restarts=0, name=name, max_request=MAX_REQUEST,
                             slot_bytes=settings.answer_bytes, ready_s=ready_s)
        if not proc.wait_ready(ready_s):
            proc.poll()  # a start that failed, or a deadline passed: the reason
            why = proc.gone or WorkerUnavailable(f"not ready in {ready_s:g} s")
            proc.close()
            raise WorkerUnavailable(f"the {name} worker could not start: {why}") from why
        return proc
    finally:
        shm.close()
        shm.unlink()


def share_arrays(arrays: dict[str, np.ndarray]
                 ) -> tuple[shared_memory.SharedMemory, dict[str, tuple]]:
    """``arrays`` copied into one new shared-memory segment; the segment (its creator
    closes and unlinks it) and the layout
    :func:`~lodsprite.sprite.keyframe_process.copy_shared` reads them back by: per name,
    ``(offset bytes, shape, dtype str)``."""
    layout, at = {}, 0
    for name, a in arrays.items():
        layout[name] = (at, tuple(a.shape), a.dtype.str)
        at += -(-a.nbytes // 64) * 64
    shm = shared_memory.SharedMemory(create=True, size=max(at, 1))
    for name, a in arrays.items():
        off, shape, dtype = layout[name]
        np.ndarray(shape, dtype, buffer=shm.buf, offset=off)[...] = a
    return shm, layout


@dataclass(frozen=True)
class TileUpdate:
    """Tiles of a keyframe rendered by the worker (:attr:`WorkerSettings.tiles`), ready to
    upload (:meth:`~lodsprite.gl.sprite_tiles.TiledSpriteDrawer.upload_tile`): ``tiles``
    their indices, and per tile its ``depth`` (float32), ``color`` (RGBA8) and ``coarse``
    z-buffer (float32; empty unless the ``coarse`` rule) bytes, GL row order; the other
    fields as :class:`KeyframeImage`'s (``c_prime`` reprojected for these tiles'
    sub-frustum only).  Over a store, per tile what it lacks
    (``deficits``, pixels) and the adaptive selection it was drawn with
    (``selections``)."""

    viewpoint: Viewpoint
    projection: Projection
    frame_projection: Projection
    tiles: tuple[int, ...]
    depth: tuple[bytes, ...]
    color: tuple[bytes, ...]
    coarse: tuple[bytes, ...]
    c_prime: np.ndarray
    requested_at: float
    render_ms: float
    predicted: bool
    deficits: tuple[float, ...] | None = None
    selections: tuple[tuple, ...] | None = None


def _image(meta: bytes, data: bytes) -> KeyframeImage | TileUpdate:
    """A process answer (:func:`keyframe_handler`) as the keyframe (or tiles) it
    carries."""
    fields = pickle.loads(meta)
    points = fields.pop("points", None)  # a drawn surface's C (pickling drops it)
    if points is not None:
        fields["c_prime"].set_points(points)
    if "tile_bytes" in fields:  # tiles: per tile its depth, colour and coarse bytes
        sizes, parts, at = fields.pop("tile_bytes"), [], 0
        for n, c in sizes:
            parts.append((data[at:at + n], data[at + n:at + 2 * n],
                          data[at + 2 * n:at + 2 * n + c]))
            at += 2 * n + c
        return TileUpdate(depth=tuple(p[0] for p in parts), color=tuple(p[1] for p in parts),
                          coarse=tuple(p[2] for p in parts), **fields)
    w, h = fields.pop("key_size")
    fields["c_prime"].deficit_px = fields.get("deficit_px", 0.0)  # in its error
    depth = np.frombuffer(data, np.float32, w * h).reshape(h, w)
    color = np.frombuffer(data, np.uint8, w * h * 3, offset=w * h * 4).reshape(h, w, 3)
    return KeyframeImage(color=color, depth=depth, **fields)
