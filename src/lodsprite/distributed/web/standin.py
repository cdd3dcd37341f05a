"""A minimal stand-in render pool, behind the interface of
``lodsprite.distributed.pool.Broker`` (issue 24's workers part), until that lands.

``spawn_local(n)`` starts ``n`` renderer processes (multiprocessing spawn, each with its
own GL context) that take :class:`Job` s from one queue and put :class:`Result` s on
another; a thread moves results to :meth:`StandinPool.poll` and wakes the event loop
through :meth:`fileno` (a pipe).  No heartbeats, no remote workers: a job whose worker
dies is lost (the web server's job deadline forgets it).  To be deleted when the Broker
is merged.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import threading
from collections import deque

from msgspec import Struct

from lodsprite.distributed.protocol import LoadArgs, WireViewpoint

log = logging.getLogger("lodsprite.web")

__all__ = ["Job", "Result", "StandinPool"]

MAX_RENDERERS_CACHED = 2
"""Scenes a renderer process keeps loaded, each a KeyframeRenderer with its own GL
context.  A renderer does not make its context current by itself: with two alive in one
process the older one drew the newer one's scene until each draw and release was done
with its own context made current (:func:`_current`)."""


class Job(Struct):
    """One keyframe to render: ``job`` id, ``session`` id, the resolved ``load``
    arguments, the ``viewpoint`` and ``t`` (the page's clock, s)."""

    job: int
    session: str
    load: LoadArgs
    viewpoint: WireViewpoint
    t: float


class Result(Struct):
    """A job's outcome: on success ``parts`` are the keyframe message's frames
    (:func:`lodsprite.distributed.protocol.encode_keyframe`)."""

    job: int
    session: str
    ok: bool
    error: str = ""
    parts: list[bytes] = []


def _worker(jobs, results, codec: str, data_dir) -> None:
    """A renderer process: render jobs until it gets None (names resolved by the
    ``--data`` rule with ``data_dir``)."""
    import msgspec

    from lodsprite.distributed.datasets import Datasets
    from lodsprite.distributed.protocol import encode_keyframe, viewpoint_from_wire
    from lodsprite.distributed.render import KeyframeRenderer

    datasets = Datasets(data_dir)

    renderers: dict[bytes, KeyframeRenderer] = {}
    while (job := jobs.get()) is not None:
        try:
            key = msgspec.msgpack.encode(job.load)  # Structs are not hashable
            r = renderers.pop(key, None)
            if r is None:
                if len(renderers) >= MAX_RENDERERS_CACHED:
                    _release(renderers.pop(next(iter(renderers))))
                r = KeyframeRenderer(msgspec.structs.replace(
                    job.load, terrain=datasets.terrain(job.load.terrain).spec,
                    texture=datasets.texture(job.load.texture).spec))
            renderers[key] = r  # most recently used last
            with r.paths.ctx.mgl:  # this renderer's context current while it draws
                kf = r.render(viewpoint_from_wire(job.viewpoint), job.job, job.t)
            parts = [bytes(memoryview(p).cast("B")) for p in encode_keyframe(kf, codec)]
            results.put(Result(job.job, job.session, True, "", parts))
        except Exception as exc:  # noqa: BLE001 - a failed job is reported, not fatal
            results.put(Result(job.job, job.session, False, f"{type(exc).__name__}: {exc}"))
    for r in renderers.values():
        _release(r)


def _release(renderer) -> None:
    """Release ``renderer`` with its own context current (its GL names are its own)."""
    renderer.paths.ctx.mgl.__enter__()  # no __exit__: the context is gone after this
    renderer.release()


class StandinPool:
    """Local renderer processes behind the Broker's interface (submit, poll, fileno,
    spawn_local, workers, close)."""

    def __init__(self, codec: str = "raw", data_dir=None) -> None:
        self._ctx = mp.get_context("spawn")
        self._jobs = self._ctx.Queue()
        self._results = self._ctx.Queue()
        self._codec = codec
        self._data_dir = data_dir
        self._procs: list = []
        self._done: deque[Result] = deque()
        self._read, self._write = os.pipe()
        os.set_blocking(self._read, False)
        self._collector = threading.Thread(target=self._collect, daemon=True,
                                           name="pool-results")
        self._collector.start()

    def _collect(self) -> None:
        while (r := self._results.get()) is not None:
            self._done.append(r)
            try:
                os.write(self._write, b"\x01")
            except OSError:
                return

    def spawn_local(self, n: int) -> None:
        """Start ``n`` renderer processes."""
        for _ in range(n):
            p = self._ctx.Process(target=_worker, args=(self._jobs, self._results, self._codec,
                                                          self._data_dir),
                                  daemon=True)
            p.start()
            self._procs.append(p)

    def workers(self) -> list[str]:
        """Ids of the live workers."""
        return [str(p.pid) for p in self._procs if p.is_alive()]

    def submit(self, job: Job) -> None:
        self._jobs.put(job)

    def poll(self) -> list[Result]:
        try:
            while os.read(self._read, 4096):
                pass
        except (BlockingIOError, OSError):
            pass
        out = []
        while self._done:
            out.append(self._done.popleft())
        return out

    def fileno(self) -> int:
        return self._read

    def close(self) -> None:
        for _ in self._procs:
            self._jobs.put(None)
        for p in self._procs:
            p.join(timeout=3.0)
            if p.is_alive():
                p.kill()
        self._results.put(None)
        self._collector.join(timeout=2.0)
        os.close(self._read)
        os.close(self._write)
