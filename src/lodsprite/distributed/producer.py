"""The KEYFRAME-RENDERER of a LOD server (Swan et al. 2002, §3.3, Figure 6): the thread that
owns the GL context and produces keyframes into the SERVER-KEYFRAME-QUEUE.

SERVER-CONTROL hands it a scene to load (:meth:`KeyframeProducer.request`); the thread
loads it, and while the server runs produces keyframes: it waits for a first viewpoint,
predicts where the viewer will be when the keyframe arrives (:mod:`.viewpoints`, ``δt``
from :mod:`.transmitter`), with pace ``needed`` waits until the client will need a new
keyframe (:mod:`.pacing`), renders and queues it.

The thread survives a scene that fails to load or render (any exception, ``MemoryError``
and GL errors included): its ``state`` (``idle``, ``loading``, ``ready``, ``failed``) and
last ``error`` say so, the server stops running, and a later request starts afresh.  At
start it reads the GL driver's maximum texture size (``max_texture``), so that SERVER-
CONTROL can refuse oversized scenes before anything is allocated.

The thread shares the server's process, and its GIL, with SERVER-CONTROL, the viewpoint
receiver and the transmitter.  :class:`~.render.KeyframeService` draws and waits for its
draws (``glFinish``) with the GIL released, so a 4096² keyframe (33.5 M triangles, seconds
on llvmpipe) does not keep the control thread from answering within a client's control
timeout.  Loading a scene still holds the GIL through each texture upload (moderngl):
up to 1.3 s measured for a 4096² scene's colour texture and mipmaps on a loaded 2-core
machine; a client's ``ping`` may time out once while such a scene loads.  The render
pool's workers, whose liveness is a 1 s heartbeat, render in a process of their own
instead (:mod:`.pool.render_process`).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

from lodsprite.distributed.hold import Hold
from lodsprite.distributed.protocol import Keyframe, LoadArgs
from lodsprite.distributed.queue import Closed, KeyframeQueue
from lodsprite.distributed.render import KeyframeService
from lodsprite.distributed.server_stats import ServerStats
from lodsprite.distributed.viewpoints import ViewpointReceiver

log = logging.getLogger("lodsprite.server")

STATES = ("idle", "loading", "ready", "failed")


class KeyframeProducer:
    """Loads the requested scene and renders keyframes; :meth:`run` is the thread's body.

    ``running`` and ``stop`` are the server's; ``delta_t`` gives the last measured δt
    (seconds).  ``pending``: the scene requested and not yet taken by the thread."""

    def __init__(self, queue: KeyframeQueue[Keyframe], stats: ServerStats,
                 viewpoints: ViewpointReceiver, hold: Hold, delta_t: Callable[[], float],
                 running: threading.Event, stop: threading.Event) -> None:
        self.queue, self.stats, self.viewpoints, self.hold = queue, stats, viewpoints, hold
        self.delta_t = delta_t
        self.state, self.error = "idle", ""
        self.max_texture: int | None = None  # from the GL driver, once probed
        self.scene_bytes = 0  # estimate for the scene asked for last (0 once it failed)
        self.slot, self.slots = 0, 1  # this server's place among the client's servers
        self.pending: LoadArgs | None = None
        self._running, self._stop = running, stop
        self._lock = threading.Lock()
        self._seq = 0

    def request(self, scene: LoadArgs, scene_bytes: int) -> None:
        """Load ``scene`` (about ``scene_bytes``) next, instead of the current one."""
        self.slot, self.slots = scene.slot, scene.slots
        with self._lock:
            self.pending = scene
            self.scene_bytes = scene_bytes
            self._set_state("loading", "")

    def _set_state(self, state: str, error: str | None = None) -> None:
        self.state = state
        if error is not None:
            self.error = error

    def _probe_gl(self) -> None:
        """Read the GL driver's maximum texture size (for refusing oversized loads)."""
        from lodsprite.gl.context import GLContext

        try:
            ctx = GLContext()
        except Exception as exc:
            self._set_state("failed", f"no OpenGL: {exc}")
            log.error("no OpenGL context: %s", exc)
            return
        try:
            self.max_texture = ctx.info.max_texture_size
        finally:
            ctx.release()

    def _fail(self, what: str, exc: BaseException) -> None:
        error = f"{what}: {type(exc).__name__}: {exc}"[:2000]
        with self._lock:
            if self.pending is None:  # a newer load is not failed by this one
                self._set_state("failed", error)
                self.scene_bytes = 0  # the failed scene is released: it holds nothing
        self._running.clear()
        log.error("%s", error)

    def run(self) -> None:
        """Load and render until the server stops or the queue closes."""
        service: KeyframeService | None = None

        def release() -> None:
            nonlocal service
            if service is not None:
                try:
                    service.release()
                except Exception as exc:  # a broken context: drop it all the same
                    log.warning("releasing the scene: %r", exc)
                service = None

        self._probe_gl()
        try:
            while not self._stop.is_set():
                self.hold.current()  # lapse an expired hold
                with self._lock:
                    request, self.pending = self.pending, None
                if request is not None:
                    release()
                    service = self._open(request)
                if service is None or not self._running.is_set():
                    time.sleep(0.01)
                    continue
                try:
                    self._produce(service)
                except Closed:
                    raise
                except Exception as exc:
                    self._fail("cannot render a keyframe", exc)
                    release()
        except Closed:
            pass
        finally:
            release()

    def _open(self, scene: LoadArgs) -> KeyframeService | None:
        """A keyframe service for ``scene``; None (state ``failed``) when it cannot be made."""
        try:
            service = KeyframeService(scene)
        except Exception as exc:  # MemoryError, GL errors, bad files, anything
            self._fail("cannot load the scene", exc)
            return None
        with self._lock:
            if self.pending is None:
                self._set_state("ready", "")
        return service

    def predicted_viewpoint(self):
        """The viewpoint a keyframe started now should show, and what the client shows.

        Aimed ``δt`` plus the time since the newest sample arrived after that sample
        (:meth:`.ViewpointReceiver.predict`).  With several servers, server ``slot`` of
        ``slots`` aims ``δt (1 + slot/slots)`` ahead, so their keyframes cover different
        moments."""
        return self.viewpoints.predict(self.delta_t() * (1.0 + self.slot / self.slots))

    def due(self, service: KeyframeService, vp, shown) -> bool:
        """Whether to render for ``vp``.  With several servers they take turns: it is this
        server's turn when the client shows the previous slot's keyframe."""
        eye, turn = None, True
        if shown is not None:
            eye, slot = shown
            turn = (slot + 1) % self.slots == self.slot
        return service.pacer.due(vp, service.projection(vp), eye, turn)

    def _produce(self, service: KeyframeService) -> None:
        t0 = time.perf_counter()
        if not self.viewpoints.have.wait(0.1):
            return
        t_vp = time.perf_counter()
        vp, shown = self.predicted_viewpoint()
        while vp is None or not self.due(service, vp, shown):
            if self._stop.is_set() or not self._running.is_set() or self.pending is not None:
                return
            self.viewpoints.fresh.wait(0.05)  # check again with the next viewpoint
            self.viewpoints.fresh.clear()
            vp, shown = self.predicted_viewpoint()
        t1 = time.perf_counter()  # δt runs from here: the prediction was made for t1 + δt
        self._seq += 1
        kf = service.render(vp, self._seq, t1)
        t2 = time.perf_counter()
        while not self.queue.put(kf, timeout=0.1):
            if self._stop.is_set() or not self._running.is_set():
                return
        t3 = time.perf_counter()
        self.stats.rendered(viewpoint_wait=(t_vp - t0) * 1e3, paced=(t1 - t_vp) * 1e3,
                            render=(t2 - t1) * 1e3, queue_insert=(t3 - t2) * 1e3,
                            production=(t3 - t0) * 1e3)
