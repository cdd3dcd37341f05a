"""The keyframe worker's process side (:mod:`lodsprite.sprite.keyframe_worker` is the
drawing side's end): its priority lowered, its own headless OpenGL context and the
scene's in-memory terrain made from the arrays handed over through shared memory, the
full-resolution keyframe rendered for each viewpoint sent, its colour, z-buffer and
``C'`` answered.  Over a store the process runs
:func:`lodsprite.techniques.adaptive_worker.store_keyframe_handler` instead.
"""

from __future__ import annotations

import logging
import os
import pickle
import threading
import time
from multiprocessing import shared_memory
from typing import TYPE_CHECKING

import numpy as np

from lodsprite.camera import Viewpoint
from lodsprite.sprite.metric import ErrorMetric

if TYPE_CHECKING:
    from lodsprite.sprite.keyframe_worker import WorkerSettings
    from lodsprite.terrain import HeightField

log = logging.getLogger(__name__)


def copy_shared(shm_name: str, layout: dict[str, tuple]) -> dict[str, np.ndarray]:
    """The arrays :func:`~lodsprite.sprite.keyframe_worker.share_arrays` put in the
    segment ``shm_name``, copied out."""
    shm = shared_memory.SharedMemory(shm_name)
    try:
        return {name: np.ndarray(shape, dtype, buffer=shm.buf, offset=off).copy()
                for name, (off, shape, dtype) in layout.items()}
    finally:
        shm.close()


def keyframe_handler(shm_name: str, layout: dict, field: tuple, settings: WorkerSettings):
    """The worker process's request handler (:mod:`lodsprite.workers`' factory): its
    priority lowered, its context and scene made from the shared arrays.  A request's
    meta is ``(viewpoint, predicted, requested_at)`` pickled; the answer's meta the
    keyframe's fields pickled, its data the depth then the colour bytes."""
    from lodsprite.terrain import HeightField

    lower_priority(settings.nice)
    arrays = copy_shared(shm_name, layout)
    dx, dy, name, meta = field
    gl = _WorkerGL(HeightField(arrays["heights"], dx, dy, name, meta), arrays.get("texture"),
                   settings)

    def answer(meta: bytes, data: bytes) -> tuple[bytes, bytes]:
        vp, predicted, asked = pickle.loads(meta)
        return gl.render(vp, predicted, asked)

    return answer


class _WorkerGL:
    """The worker's GL state: its own context, the terrain (height field ``hf``, colour
    ``texture (H, W, 3) uint8`` or None) and the keyframe renderer."""

    def __init__(self, hf: HeightField, texture: np.ndarray | None, s: WorkerSettings
                 ) -> None:
        from lodsprite.gl.context import GLContext
        from lodsprite.gl.sprite import SpriteDrawer
        from lodsprite.gl.terrain import TerrainDrawer, TerrainGeometry

        self.ctx = GLContext()
        made = [self.ctx]
        try:
            made.append(TerrainGeometry(self.ctx, hf, texture))
            made.append(TerrainDrawer(self.ctx, made[-1], s.size[0], s.size[1], s.fov_y_deg))
            self.terrain = made[-1]
            self.sprite = SpriteDrawer(self.terrain, s.lod, s.visibility, border=s.border,
                                         guard_px=s.guard_px)
        except BaseException:  # released in the order made, backwards
            for obj in reversed(made):
                obj.release()
            raise
        self.metric = ErrorMetric.for_level(hf, s.lod, s.resampling)
        self.zbuffer = "coarse" if s.visibility == "coarse" else "full"

    def render(self, vp: Viewpoint, predicted: bool, asked: float) -> tuple[bytes, bytes]:
        t0 = time.perf_counter()
        frame_projection = self.terrain.projection(vp)
        self.sprite.render_keyframe(vp, t0, frame_projection)
        self.ctx.finish()
        key = self.sprite.keyframe
        c_prime = self.metric.reproject(vp.o, key.projection.matrix() @ vp.view_matrix(),
                                        key.target.size)
        return keyframe_answer(self.sprite, self.zbuffer, {
            "viewpoint": vp, "frame_projection": frame_projection, "c_prime": c_prime,
            "requested_at": asked, "predicted": predicted}, t0)


def keyframe_answer(sprite, zbuffer: str, fields: dict, t0: float) -> tuple[bytes, bytes]:
    """The answer for the keyframe ``sprite`` (a :class:`~lodsprite.gl.sprite.SpriteDrawer`)
    shows: meta ``fields`` with its projection, z-buffer kind, size and ``render_ms``
    (since ``t0``, ``time.perf_counter`` seconds) pickled; data its depth (``zbuffer``:
    "coarse" or "full") then colour bytes."""
    key = sprite.keyframe
    color = key.target.read_color()
    depth = (key.coarse if zbuffer == "coarse" else key.target).read_depth()
    fields = {**fields, "projection": key.projection, "zbuffer": zbuffer,
              "render_ms": (time.perf_counter() - t0) * 1e3, "key_size": key.target.size}
    return pickle.dumps(fields), b"".join((np.ascontiguousarray(depth, np.float32).data,
                                           np.ascontiguousarray(color, np.uint8).data))


def lower_priority(nice: int) -> None:
    """Raise this thread's nice value by ``nice`` (Linux threads have their own); threads
    it starts later inherit it.  Ignored where the platform has no per-thread priority."""
    if nice <= 0 or not hasattr(os, "setpriority"):
        return
    try:
        tid = threading.get_native_id()
        os.setpriority(os.PRIO_PROCESS, tid, os.getpriority(os.PRIO_PROCESS, tid) + nice)
    except OSError as exc:
        log.debug("could not lower the keyframe worker's priority: %s", exc)
