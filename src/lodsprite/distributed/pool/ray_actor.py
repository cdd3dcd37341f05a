"""A renderer as a Ray actor (``serve --web --ray``): one process, one GL context, the
scenes it has loaded.

:class:`RenderActor` is a plain class; :class:`~.ray_pool.RayPool` makes it an actor
(``ray.remote``) with one CPU, ``--gpus-per-renderer`` GPUs, restarts by Ray and no
retries by Ray (the pool re-submits a job whose actor died, to whichever renderer is free
first).  Its methods run one at a time on the actor's one thread (Ray's default for a
synchronous actor), the thread that made the GL context: no Python thread beside the
draws (moderngl holds the GIL through them).

Where Ray assigns GPUs it sets ``CUDA_VISIBLE_DEVICES`` for the actor; the headless
context is made on EGL's first device (glcontext's default, ``GLCONTEXT_DEVICE_INDEX``
picks another), which is the assigned GPU where the driver's EGL device list follows
``CUDA_VISIBLE_DEVICES`` (not verified here: no GPU).  :meth:`RenderActor.ready` reports
the GPU ids and the GL renderer string, so that a deployment can check.

The job arrives as the pool's ``job`` message (msgpack bytes, :class:`~.jobs.JobMessage`),
the answer is the pool's ``result`` frames (:func:`~.jobs.encode_pool`: the header, then
on success the keyframe message's frames), returned as a list of ``bytes``: Ray sends
them inline or through its object store, and the web server awaits them.
"""

from __future__ import annotations

import os
import socket

import msgspec

from lodsprite.distributed.pool.jobs import JobMessage
from lodsprite.distributed.pool.render_process import SceneCache

__all__ = ["RenderActor"]


class RenderActor:
    """One renderer: ``data_dir`` the folder whose files jobs may name (on the node the
    actor runs on; None: built-ins only), ``cache`` scenes kept loaded (least recently
    used dropped)."""

    def __init__(self, data_dir: str | None, cache: int) -> None:
        self.scenes = SceneCache(data_dir, max(1, min(int(cache), 64)))
        self._decoder = msgspec.msgpack.Decoder(JobMessage)

    def ready(self) -> dict:
        """Make the GL context (raises :class:`~lodsprite.errors.GLUnavailableError`
        without one) and say who this is: ``pid``, ``host``, ``gpus`` (Ray's GPU ids),
        ``gl`` (the GL renderer string)."""
        import ray

        from lodsprite.gl.context import GLContext

        if self.scenes.gl is None:
            self.scenes.gl = GLContext()
        return {"pid": os.getpid(), "host": socket.gethostname()[:200],
                "gpus": [str(g) for g in ray.get_gpu_ids()],
                "gl": self.scenes.gl.info.renderer[:200]}

    def render(self, job: bytes) -> list[bytes]:
        """The ``result`` frames of one job (msgpack :class:`~.jobs.JobMessage`); never
        raises for a job's failure (it is the result's ``error``)."""
        frames = self.scenes.render(self._decoder.decode(job))
        return [bytes(f) for f in frames]
