"""The local render pool: the embedded default of ``serve --web`` and of the notebook
widgets, one renderer a process of this machine (:class:`~lodsprite.workers.ProcessWorker`
running :mod:`.render_process`), behind the interface :class:`~.ray_pool.RayPool`
implements for renderers across machines (``--ray``).

No broker and no heartbeats: a renderer is a child process whose answer pipe this
process reads, so its death is seen at once (the pipe ends), and a renderer that hangs is
seen by its job's timeout.  One thread waits on every renderer's pipe and a wake-up pipe
(``multiprocessing.connection.wait``) and keeps the job table (:class:`~.dispatch.JobTable`:
fairness in submission order, scene affinity, declines, :data:`~.dispatch.MAX_TRIES`):

* a renderer joins the table when its process says ready, under a key holding its pid,
  so that nothing a killed process said can be taken for its successor's;
* a renderer that dies puts its job back in front of the queue (a try counted) and is
  started again after a backoff (0.25 s doubling to 4 s, reset by its first keyframe);
* a job past ``job_timeout_s`` kills its renderer (the same as a death, at once);
* an answer that does not decode as its job's keyframe loses the renderer, killed.

Keyframes come back through shared memory (one slot a renderer,
:data:`SLOT_BYTES`), the pipe carrying their header.  :meth:`LocalPool.submit` and
:meth:`LocalPool.poll` never block; :meth:`LocalPool.fileno` is readable while results
wait.  :meth:`LocalPool.close` ends every renderer; they also end when this process does
(their request pipe closes).
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from multiprocessing.connection import wait
from pathlib import Path

import msgspec

from lodsprite.distributed.pool.dispatch import JOB_TIMEOUT_S, Key
from lodsprite.distributed.pool.jobs import (
    MAX_JOB_BYTES,
    POOL_VERSION,
    Job,
    JobMessage,
    PrepareMessage,
    Ready,
    ReleaseMessage,
    ResultMessage,
    check_job,
    check_load,
    decode_pool,
    job_key,
)
from lodsprite.distributed.pool.results import PoolResults, drain, signal
from lodsprite.distributed.protocol import CODECS, LoadArgs, ProtocolError
from lodsprite.errors import InputError
from lodsprite.sprite.worker_settings import DEFAULT_WORKER_NICE
from lodsprite.terrain.remote import data_root

log = logging.getLogger("lodsprite.pool")

MAX_LOADS_KEPT = 256
"""Loads remembered by their scene key (what a replacement renderer opens again)."""

__all__ = ["BACKOFF_MAX_S", "BACKOFF_S", "SLOT_BYTES", "LocalPool"]

BACKOFF_S = 0.25
BACKOFF_MAX_S = 4.0
SLOT_BYTES = 32 << 20
"""Shared memory a renderer answers in (a keyframe's frames; a larger one takes the pipe)."""
MAX_CACHE = 64


@dataclass(eq=False)
class _Slot:
    """One renderer slot: its process (None while it waits to start again), its key in
    the job table once ready, and when it may start again."""

    index: int
    worker: object | None = None
    child: object | None = None  # its last process, kept after it ends
    key: Key | None = None
    start_at: float = 0.0
    backoff: float = BACKOFF_S
    releases: list = field(default_factory=list)  # scene keys to drop, not yet sent
    reopen: list = field(default_factory=list)  # the scenes its last process held (loads)
    reopening: int = 0  # of those, openings in flight: it joins when they are answered
    reopened: list = field(default_factory=list)  # the scene keys it opened again
    reopen_since: float = 0.0


class LocalPool(PoolResults):
    """Renderers in processes of this machine.  ``codec``: keyframe images ``raw`` or
    ``zlib``; ``data_dir``: the folder whose files jobs may name (the web server's
    ``--data``); ``job_timeout_s``: a job's longest render before its renderer is killed;
    ``keyframes``: how they are drawn, ``auto`` (adaptive over a store or a large grid,
    else whole), ``adaptive`` or ``whole`` (:func:`~lodsprite.distributed.render.
    keyframe_service`; the benchmarks compare the two); ``renderer_mb``: what a renderer's
    scenes may hold together (:data:`~.render_process.RENDERER_MB`); ``nice``: how much
    the renderers lower their priority (they draw beside a page or a notebook on this
    machine, whose frames come first: a keyframe late by a few milliseconds costs less
    than a frame dropped; 0 keeps it)."""

    def __init__(self, codec: str = "raw", data_dir: Path | str | None = None,
                 job_timeout_s: float = JOB_TIMEOUT_S, keyframes: str = "auto",
                 renderer_mb: float | None = None, nice: int = DEFAULT_WORKER_NICE) -> None:
        from lodsprite.distributed.render import KEYFRAME_WAYS

        if codec not in CODECS:
            raise InputError(f"unknown codec '{codec}': use {', '.join(CODECS)}")
        if keyframes not in KEYFRAME_WAYS:
            raise InputError(f"keyframes are drawn {', '.join(KEYFRAME_WAYS)}, not "
                             f"{keyframes!r}")
        super().__init__(job_timeout_s)
        self.keyframes = keyframes
        self.renderer_mb = renderer_mb
        self.nice = int(nice)
        self.codec = codec
        self.data_dir = data_root(data_dir)
        self.cache = 2
        self._renderers: list[_Slot] = []
        self._inbox: deque[Job] = deque()
        self._releases: deque[bytes] = deque()  # scenes to drop, for every renderer
        self._prepares: deque[LoadArgs] = deque()  # scenes to open, on one renderer
        self._loads: dict[bytes, LoadArgs] = {}  # the loads of the scenes renderers hold
        self._stop = threading.Event()
        self._lock = threading.Lock()  # the renderer list: spawn_local beside the thread
        self._wake_r, self._wake_w = os.pipe()
        for fd in (self._wake_r, self._wake_w):
            os.set_blocking(fd, False)
        self._closed = False
        self._thread = threading.Thread(target=self._run, daemon=True, name="pool-local")
        self._thread.start()

    def submit(self, job: Job) -> None:
        """Queue ``job`` (never blocks; thread-safe)."""
        self._inbox.append(check_job(job))
        signal(self._wake_w)

    def release(self, key: bytes) -> None:
        """Have every renderer drop the scene ``key`` (:func:`~.jobs.job_key` of its load:
        no session uses it any more); counted ``released`` where one held it.  Never
        blocks; thread-safe."""
        self._releases.append(bytes(key))
        signal(self._wake_w)

    def prepare(self, load: LoadArgs) -> None:
        """Have one renderer open the scene of ``load`` now (a page loaded it; its first
        request follows once the page has the scene message): the idle renderer idle
        longest, unless one holds it already; it counts as holding the scene from now, so
        the first job goes to it, behind the opening.  Counted ``prepared``.  Never
        blocks; thread-safe.  ``load`` is taken as a job's is decoded (its key is then a
        job's); raises :class:`~lodsprite.errors.InputError` for one no job could carry."""
        self._prepares.append(check_load(load))
        signal(self._wake_w)

    def spawn_local(self, n: int, cache: int = 2) -> list[int]:
        """Start ``n`` renderers (each a spawned process with its own GL context, keeping
        ``cache`` scenes); their pids."""
        self.cache = max(1, min(int(cache), MAX_CACHE))
        with self._lock:
            new = [_Slot(len(self._renderers) + i) for i in range(int(n))]
            for r in new:
                self._start(r)
            self._renderers += new
        signal(self._wake_w)
        return [r.worker.pid for r in new if r.worker is not None and r.worker.pid]

    def local_processes(self) -> list:
        """Each renderer's last process (``pid``, ``is_alive()``), ended or not."""
        with self._lock:
            return [r.child for r in self._renderers if r.child is not None]

    def close(self) -> None:
        """Stop the thread and end every renderer (a render in progress is cut off).
        Idempotent."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        signal(self._wake_w)
        self._thread.join(timeout=10.0)
        with self._lock:
            for r in self._renderers:
                if r.worker is not None:
                    r.worker.close()
                    r.worker = None
        for fd in (self._wake_r, self._wake_w):
            os.close(fd)
        self._close_results()

    def __enter__(self) -> LocalPool:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ----------------------------------------------------------------- renderers

    def _start(self, r: _Slot) -> None:
        from lodsprite.distributed.pool.render_process import FACTORY
        from lodsprite.workers import ProcessWorker

        args = {"data_dir": self.data_dir, "cache": self.cache, "keyframes": self.keyframes,
                "nice": self.nice}
        if self.renderer_mb is not None:
            args["max_mb"] = self.renderer_mb
        r.worker = ProcessWorker(FACTORY, args,  # a job, and a release behind it
                                 in_flight=2, restarts=0, name="render",
                                 slot_bytes=SLOT_BYTES, max_request=MAX_JOB_BYTES)
        r.key, r.child = None, r.worker.child

    def _end(self, r: _Slot, why: str, now: float, backoff: bool = True) -> None:
        """Kill ``r``'s process; its job back in the queue; started again after the
        backoff (at once with ``backoff=False``: a timeout, not a crash)."""
        if r.worker is not None:
            r.worker.close()
            r.worker = None
        if r.key is not None:
            peer = self.table.peers.get(r.key)
            held = list(dict.fromkeys(peer.scenes)) if peer is not None else []
            r.reopen = [self._loads[k] for k in held[-self.cache:] if k in self._loads]
            self.table.lose(r.key, why)
            r.key = None
        r.reopening = 0
        r.start_at = now + (r.backoff if backoff else 0.0)
        if backoff:
            r.backoff = min(2 * r.backoff, BACKOFF_MAX_S)

    # -------------------------------------------------------------------- thread

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                wait([self._wake_r, *self._pipes()], timeout=self._timeout())
                drain(self._wake_r)
                while self._inbox:
                    self.table.add(self._inbox.popleft())
                now = time.monotonic()
                with self._lock:
                    while self._releases:
                        key = self._releases.popleft()
                        for r in self._renderers:
                            r.releases.append(key)
                    for r in self._renderers:
                        self._service(r, now)
                        self._send_releases(r)
                    while self._prepares:
                        self._send_prepare(self._prepares.popleft())
                    self._expire(now)
                    self._dispatch(now)
                self._changed()
            except Exception as exc:  # noqa: BLE001 - a bug must not stop the pool
                log.error("render pool: internal error %r", exc)
                self._stop.wait(0.05)

    def _pipes(self) -> list[int]:
        with self._lock:
            return [r.worker.fileno() for r in self._renderers
                    if r.worker is not None and r.worker.alive]

    def _timeout(self) -> float:
        """Seconds until a renderer is due to start, a job to time out, or 1 s."""
        now = time.monotonic()
        due = [now + 1.0]
        with self._lock:
            due += [r.start_at for r in self._renderers if r.worker is None]
        due += [p.since + self.job_timeout_s for p in self.table.peers.values()
                if p.entry is not None]
        return max(0.0, min(due) - now) + 1e-3

    def _service(self, r: _Slot, now: float) -> None:
        """``r``'s answers settled, its readiness registered, its death handled, or its
        start when due."""
        if r.worker is None:
            if now >= r.start_at:
                self._start(r)
            return
        answers = r.worker.poll()
        if r.key is None and r.worker.ready and r.worker.alive and r.reopen:
            # a replacement: it opens what the lost one held before it takes jobs, so
            # that none waits behind a cold opening while the others serve
            for load in r.reopen[:2]:  # in flight at once: the worker's two slots
                r.worker.submit(("reopen", job_key(load)), msgspec.msgpack.encode(
                    PrepareMessage(POOL_VERSION, load)))
            r.reopening, r.reopen, r.reopen_since = len(r.reopen[:2]), [], now
        if r.key is None and r.reopening and now - r.reopen_since > self.job_timeout_s:
            self._end(r, "hung opening the scenes it replaces", now, backoff=False)
            r.reopen = []  # started again plain
            return
        self._join(r, now)
        for key, answer in answers:
            if isinstance(key, tuple):  # a release's or prepare's answer: true or false
                done = isinstance(answer, tuple) and self._released(answer)
                if key[0] == "reopen":
                    r.reopening = max(0, r.reopening - 1)
                    if done:
                        r.reopened.append(key[1])
                if done:
                    self.table.counts["released" if key[0] == "release" else "prepared"] += 1
                elif key[0] == "prepare":  # not opened: no affinity for it
                    peer = self.table.peers.get(r.key) if r.key is not None else None
                    if peer is not None and key[1] in peer.scenes:
                        peer.scenes.remove(key[1])
            elif isinstance(answer, tuple) and r.key is not None:
                self._answer(r, answer, now)
        self._join(r, now)  # its last reopening answered just now
        if r.worker is not None and not r.worker.alive:
            self._end(r, f"died ({r.worker.gone})", now)

    def _join(self, r: _Slot, now: float) -> None:
        """``r`` into the job table once its process is ready and has opened again what
        the renderer it replaces held (those scenes its own from the start)."""
        if r.key is None and r.worker is not None and r.worker.ready and r.worker.alive \
                and not r.reopening:
            pid = r.worker.pid or 0
            r.key = (0, f"{r.index}:{pid}".encode())
            self.table.ready(r.key, Ready(POOL_VERSION, pid, f"local-{pid}", self.cache), now)
            peer = self.table.peers.get(r.key)
            if peer is not None:
                peer.scenes.extend(r.reopened)
            r.reopened = []

    def _answer(self, r: _Slot, answer: tuple, now: float) -> None:
        from lodsprite.distributed.pool.render_process import unpack

        try:
            msg, parts = decode_pool(unpack(*answer))
            if not isinstance(msg, ResultMessage):
                raise ProtocolError(f"a {type(msg).__name__} where a result belongs")
            self.table.settle(r.key, msg, parts, now)
        except (ProtocolError, msgspec.DecodeError, ValueError) as exc:
            self.table.counts["rejected"] += 1
            log.warning("render pool: a bad answer from renderer %d: %s", r.index, exc)
            self._end(r, "sent a bad keyframe", now)
            return
        if msg.ok:
            r.backoff = BACKOFF_S

    def _send_releases(self, r: _Slot) -> None:
        """``r``'s next pending release, behind its job: one release in flight at most, so
        that a job always finds room; the scene leaves its affinity at once."""
        if r.worker is None or not r.worker.alive or not r.releases:
            if r.worker is None:
                r.releases.clear()  # a new process holds nothing
            return
        peer = self.table.peers.get(r.key) if r.key is not None else None
        if not any(isinstance(k, tuple) for k in r.worker.pending) and not r.worker.full:
            key = r.releases.pop(0)
            if peer is not None and key in peer.scenes:
                peer.scenes.remove(key)
            r.worker.submit(("release", key), msgspec.msgpack.encode(
                ReleaseMessage(POOL_VERSION, key)))

    def _send_prepare(self, load: LoadArgs) -> None:
        """The prepare of ``load`` to the idle renderer idle longest (none: dropped), unless
        one holds the scene already; that renderer holds it from now (dispatch's affinity)."""
        key = job_key(load)
        peers = self.table.peers
        if any(key in p.scenes for p in peers.values()):
            return
        idle = [r for r in self._renderers if r.key in peers and peers[r.key].entry is None
                and r.worker is not None and r.worker.alive and not r.worker.pending]
        if not idle:
            return
        r = min(idle, key=lambda r: peers[r.key].idle_since)
        self._loads[key] = load
        r.worker.submit(("prepare", key), msgspec.msgpack.encode(
            PrepareMessage(POOL_VERSION, load)))
        peers[r.key].scenes.append(key)
        # idle from now: the last choice for a job of another scene (which would wait
        # behind the opening), the first for this scene's (affinity)
        peers[r.key].idle_since = time.monotonic()

    @staticmethod
    def _released(answer: tuple) -> bool:
        """Whether a release's answer (msgpack ``true`` or ``false``) says it held the scene."""
        try:
            return msgspec.msgpack.decode(answer[0], type=bool)
        except (msgspec.DecodeError, msgspec.ValidationError):
            return False

    def _expire(self, now: float) -> None:
        for key in self.table.expired(now):
            for r in self._renderers:
                if r.key == key:
                    self._end(r, "timed out", now, backoff=False)

    def _dispatch(self, now: float) -> None:
        by_key = {r.key: r for r in self._renderers if r.key is not None}
        for key, entry in self.table.assign(now):
            r = by_key[key]
            load = entry.job.load
            self._loads.pop(job_key(load), None)  # most recently used last
            self._loads[job_key(load)] = load
            while len(self._loads) > MAX_LOADS_KEPT:
                self._loads.pop(next(iter(self._loads)))
            msg = JobMessage(POOL_VERSION, entry.job, self.codec)
            try:
                r.worker.submit(entry.job.job, msgspec.msgpack.encode(msg))
            except ValueError as exc:  # larger than a job may be: declined, not fatal
                self.table.settle(key, ResultMessage(POOL_VERSION, entry.job.job, False,
                                                     str(exc)), [], now)
