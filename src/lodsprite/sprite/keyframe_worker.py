"""Keyframes rendered off the drawing thread: Swan et al. (2002)'s server/client split
inside one process.

The 2002 paper renders keyframes on a second graphics pipe (the LOD server) so that the
client draws spriteframes at a steady rate.  :class:`KeyframeWorker` is that server as a
thread with its own OpenGL context: it renders the full-resolution terrain for a viewpoint
predicted ``δt`` ahead (:mod:`lodsprite.sprite.predictors`, the paper's
VIEWPOINT-PREDICTOR; δt is the measured request-to-adoption latency), reads the keyframe's
colour and z-buffer back and hands them over, with the keyframe's ``C'`` (the error
metric's reprojected centres, Eq. 2), to the drawing thread, which uploads them
(:meth:`~lodsprite.gl.sprite.SpriteDrawer.upload_keyframe`) and never waits.

The worker thread lowers its own scheduling priority (``nice``, Linux) before it makes its
context, so that the software rasteriser's threads it starts inherit it: on a machine
without a GPU, the drawing thread's spriteframes come first and keyframes take the
remaining CPU time.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from lodsprite.camera import Projection, Viewpoint
from lodsprite.errors import LodspriteError
from lodsprite.sprite.metric import ErrorMetric
from lodsprite.sprite.predictors import PREDICTORS

if TYPE_CHECKING:  # the scene is passed in
    from lodsprite.scene import Scene

log = logging.getLogger(__name__)

DEFAULT_WORKER_NICE = 10
SAMPLES_KEPT = 64


@dataclass(frozen=True)
class KeyframeImage:
    """A keyframe rendered by the worker, ready to upload.

    ``color (H, W, 3) uint8`` and ``depth (H, W) float32`` (window depth; whose z-buffer:
    ``zbuffer``, "coarse" or "full"), row 0 at the top, at the keyframe size (image plus
    guard band); ``projection``: the keyframe's own (widened); ``frame_projection``: the
    frame projection at its viewpoint; ``c_prime (n*n, 3)`` metres; ``requested_at``
    (``time.perf_counter`` seconds); ``render_ms``: the worker's time for it;
    ``predicted``: placed ahead of the latest viewpoint sample."""

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


@dataclass(frozen=True)
class WorkerSettings:
    """How the worker renders: image size ``(w, h)`` pixels, vertical field of view
    (degrees), coarse level (quads per side), visibility rule, border ribbons, guard band
    (pixels), predictor name, the nice increment of the worker thread and whether the
    keyframes' ``C'`` are for the resampling metric (their matrix and size attached)."""

    size: tuple[int, int]
    fov_y_deg: float
    lod: int
    visibility: str
    border: bool
    guard_px: int
    predictor: str = "linear"
    nice: int = DEFAULT_WORKER_NICE
    resampling: bool = False


class KeyframeWorker:
    """A thread with its own GL context that renders keyframes on request.

    The drawing thread calls :meth:`observe` every frame (cheap), :meth:`request` when a
    keyframe is wanted and :meth:`poll` for the newest finished one; it never blocks but
    in :meth:`wait` (start-up).  :attr:`lead_s` is how far ahead keyframes are placed.
    """

    def __init__(self, scene: Scene, settings: WorkerSettings) -> None:
        if settings.predictor not in PREDICTORS:
            raise LodspriteError(f"unknown predictor {settings.predictor!r}")
        self.scene = scene
        self.settings = settings
        self.lead_s = 0.0
        self.rendered = 0
        self.error: BaseException | None = None
        self._samples: deque[tuple[float, Viewpoint]] = deque(maxlen=SAMPLES_KEPT)
        self._lock = threading.Lock()
        self._wake = threading.Condition(self._lock)
        self._done = threading.Condition(self._lock)
        self._wanted: float | None = None   # request time of the keyframe asked for
        self._ready: KeyframeImage | None = None
        self._stop = False
        self._started = threading.Event()
        self._thread = threading.Thread(target=self._run, name="lodsprite-keyframes",
                                        daemon=True)
        self._thread.start()
        self._started.wait()
        if self.error is not None:
            raise LodspriteError(f"keyframe worker could not start: {self.error}") from self.error

    # ---------------------------------------------------------------- drawing thread side

    def observe(self, t: float, viewpoint: Viewpoint) -> None:
        """A viewpoint sample at ``t`` seconds (``time.perf_counter``)."""
        self._samples.append((t, viewpoint))

    @property
    def busy(self) -> bool:
        """Whether a keyframe has been requested and not yet taken."""
        return self._wanted is not None

    def request(self) -> None:
        """Ask for a keyframe at the predicted viewpoint; no-op while one is on its way."""
        with self._lock:
            if self._wanted is None and not self._stop:
                self._wanted = time.perf_counter()
                self._wake.notify()

    def poll(self) -> KeyframeImage | None:
        """The keyframe finished since the last call, or None (never blocks)."""
        if self._ready is None:
            return None
        with self._lock:
            ready, self._ready = self._ready, None
            return ready

    def wait(self, timeout_s: float = 60.0) -> KeyframeImage:
        """Block until the requested keyframe is ready (start-up only)."""
        with self._lock:
            if not self._done.wait_for(lambda: self._ready is not None or self.error
                                       is not None or not self._thread.is_alive(), timeout_s):
                raise LodspriteError(f"no keyframe within {timeout_s:g} s")
            if self._ready is None:
                raise LodspriteError(f"keyframe worker failed: {self.error}")
            ready, self._ready = self._ready, None
            return ready

    def close(self) -> None:
        """Stop the thread and release its GL objects (in the thread, where they live)."""
        with self._lock:
            self._stop = True
            self._wake.notify()
        self._thread.join(timeout=30.0)

    # ---------------------------------------------------------------- worker thread side

    def _run(self) -> None:
        _lower_priority(self.settings.nice)
        try:
            gl = _WorkerGL(self.scene, self.settings)  # releases what it made if it fails
        except BaseException as exc:  # reported to the constructor
            self.error = exc
            self._started.set()
            return
        self._started.set()
        predictor = PREDICTORS[self.settings.predictor]()
        fed = -np.inf
        try:
            while True:
                with self._lock:
                    self._wake.wait_for(lambda: self._stop or self._wanted is not None)
                    if self._stop:
                        return
                    asked = self._wanted
                    # tuple() copies the deque in one step: observe() may append meanwhile
                    samples = [s for s in tuple(self._samples) if s[0] > fed]
                for t, vp in samples:
                    predictor.observe(t, vp)
                    fed = t
                image = gl.render(self._target(predictor, samples), asked)
                with self._lock:
                    self._ready, self._wanted = image, None
                    self.rendered += 1
                    self._done.notify_all()
        except BaseException as exc:  # noqa: BLE001 - reported to the drawing thread
            log.error("keyframe worker stopped: %s", exc)
            self.error = exc
            with self._lock:
                self._done.notify_all()
        finally:
            gl.release()

    def _target(self, predictor, samples: list) -> tuple[Viewpoint, bool]:
        """The viewpoint to render: the latest sample moved ``lead_s`` ahead, unless the
        prediction goes under the ground."""
        latest_t, latest = self._samples[-1] if self._samples else samples[-1]
        ahead = time.perf_counter() - latest_t + self.lead_s
        if ahead <= 0 or len(self._samples) < 2:
            return latest, False
        vp = predictor.predict(ahead)
        ground = float(self.scene.hf.height_at(vp.o[0], vp.o[1]))
        return (vp, True) if vp.o[2] > ground else (latest, False)


class _WorkerGL:
    """The worker's GL state: its own context, terrain and keyframe renderer."""

    def __init__(self, scene: Scene, s: WorkerSettings) -> None:
        from lodsprite.gl.sprite import SpriteDrawer
        from lodsprite.gl.terrain_gl import TerrainGL

        self.terrain_gl = TerrainGL(scene, s.size, s.fov_y_deg)
        self.terrain_gl.drawer.unlocked_draws = True  # the drawing thread runs meanwhile
        try:
            self.sprite = SpriteDrawer(self.terrain_gl.drawer, s.lod, s.visibility,
                                         border=s.border, guard_px=s.guard_px)
        except BaseException:
            self.terrain_gl.release()
            raise
        self.metric = ErrorMetric.for_level(scene.hf, s.lod, s.resampling)
        self.zbuffer = "coarse" if s.visibility == "coarse" else "full"

    def render(self, target: tuple[Viewpoint, bool], asked: float) -> KeyframeImage:
        vp, predicted = target
        t0 = time.perf_counter()
        frame_projection = self.terrain_gl.drawer.projection(vp)
        self.sprite.render_keyframe(vp, t0, frame_projection)
        self.terrain_gl.ctx.finish_unlocked()  # the drawing thread runs meanwhile
        key = self.sprite.keyframe
        color = key.target.read_color()
        depth = (key.coarse if self.zbuffer == "coarse" else key.target).read_depth()
        c_prime = self.metric.reproject(vp.o, key.projection.matrix() @ vp.view_matrix(),
                                        key.target.size)
        return KeyframeImage(vp, key.projection, frame_projection, color, depth, self.zbuffer,
                             c_prime, asked, (time.perf_counter() - t0) * 1e3, predicted)

    def release(self) -> None:
        self.sprite.release()
        self.terrain_gl.release()


def _lower_priority(nice: int) -> None:
    """Raise this thread's nice value by ``nice`` (Linux threads have their own); threads
    it starts later inherit it.  Ignored where the platform has no per-thread priority."""
    if nice <= 0 or not hasattr(os, "setpriority"):
        return
    try:
        tid = threading.get_native_id()
        os.setpriority(os.PRIO_PROCESS, tid, os.getpriority(os.PRIO_PROCESS, tid) + nice)
    except OSError as exc:
        log.debug("could not lower the keyframe worker's priority: %s", exc)
