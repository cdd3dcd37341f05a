"""The local render pool's broker: the embedded default of ``serve --web`` and of the
notebook widgets, the renderers local processes of this machine.  The Paranoid Pirate
queue of the ZeroMQ guide (Hintjens, *ZeroMQ*, ch. 4, "Robust Reliable Queuing") between
a keyframe submitter (the web server) and render workers (:mod:`.render_worker`).

Renderers on other machines are Ray actors (:mod:`.ray_pool`, ``--ray``): the broker
no longer takes workers of other hosts (no TCP endpoint, no CURVE, no slow-link
allowance).  What is kept, and why Ray does not do it: this pool runs where Ray is not
installed (Ray is an extra; a lean install serves the page with local renderers), and
starting a Ray instance (about 7 s and several processes here) for one machine's
renderers is not what a notebook or a small server should pay.  Its heartbeats and
re-queues are the local pool's liveness: a local worker can hang or die in its GL (a
driver, the out-of-memory killer) without its process exiting on its own.

A ROUTER socket, bound to a private ``ipc://`` endpoint for the workers this process
starts (:meth:`Broker.spawn_local`).  One thread owns the socket:

* a worker says ``ready``; the broker heartbeats each :data:`~.jobs.HEARTBEAT_S`; a
  worker silent for more than :data:`~.jobs.LIVENESS_S` is dead, its job re-queued
  (:mod:`.dispatch` holds the workers and jobs and decides who gets what, who is lost
  and which jobs fail: declined by every worker, or lost under
  :data:`~.dispatch.MAX_TRIES` workers);
* every message is received frame by frame with a cap (:mod:`..frames`), each frame under
  ``zmq.MAXMSGSIZE``, and validated (:func:`~.jobs.decode_pool`, a keyframe by
  :func:`~lodsprite.distributed.protocol.decode_keyframe`); a bad one is counted
  (``stats()['rejected']``) and dropped, a result for a job the worker does not hold is
  ignored, a worker that sends a bad keyframe is disconnected and its job re-queued.

:meth:`Broker.submit` and :meth:`Broker.poll` never block; :meth:`Broker.fileno` is a
pipe readable while results wait (``loop.add_reader``).  :meth:`Broker.close` terminates
the local workers, which also exit by themselves when their parent process is gone.
"""

from __future__ import annotations

import logging
import os
import shutil
import tempfile
import threading
import time
from collections import deque
from pathlib import Path

import zmq

from lodsprite.distributed.frames import check_frames, recv_frames
from lodsprite.distributed.pool.dispatch import MAX_TRIES, Key
from lodsprite.distributed.pool.jobs import (
    HEARTBEAT_S,
    KEYFRAME_PARTS,
    MAX_RESULT_FRAME_BYTES,
    POOL_VERSION,
    Disconnect,
    Heartbeat,
    Job,
    JobMessage,
    Ready,
    ResultMessage,
    WorkerInfo,
    check_job,
    decode_pool,
    encode_pool,
)
from lodsprite.distributed.pool.render_worker import end_processes, spawn_workers
from lodsprite.distributed.pool.results import PoolResults, drain, signal
from lodsprite.distributed.protocol import CODECS, ProtocolError
from lodsprite.errors import InputError, LodspriteError

log = logging.getLogger("lodsprite.pool")

__all__ = ["JOB_TIMEOUT_S", "MAX_TRIES", "Broker", "WorkerInfo"]

JOB_TIMEOUT_S = 120.0


class Broker(PoolResults):
    """The local pool's broker.  ``codec``: keyframe images ``raw`` or ``zlib``.
    ``data_dir``: the data folder local workers serve (the web server's ``--data``)."""

    def __init__(self, codec: str = "raw", data_dir: Path | str | None = None,
                 job_timeout_s: float = JOB_TIMEOUT_S) -> None:
        if codec not in CODECS:
            raise InputError(f"unknown codec '{codec}': use {', '.join(CODECS)}")
        super().__init__(job_timeout_s)
        self.codec = codec
        self.data_dir = None if data_dir is None else str(Path(data_dir).resolve())
        self._dir = tempfile.mkdtemp(prefix="lodsprite-pool-")
        self.local_endpoint = f"ipc://{self._dir}/workers"
        self._ctx = zmq.Context()
        self._socks: list[zmq.Socket] = []
        self._procs: list = []
        self._inbox: deque[Job] = deque()
        self._stop = threading.Event()
        self._wake_r, self._wake_w = os.pipe()
        for fd in (self._wake_r, self._wake_w):
            os.set_blocking(fd, False)
        self._closed = False
        try:
            self._socks.append(self._router(self.local_endpoint))
        except BaseException:
            self.close()
            raise
        self._thread = threading.Thread(target=self._run, daemon=True, name="pool-broker")
        self._thread.start()

    def submit(self, job: Job) -> None:
        """Queue ``job`` (never blocks; thread-safe)."""
        self._inbox.append(check_job(job))
        signal(self._wake_w)

    def spawn_local(self, n: int, cache: int = 2) -> list[int]:
        """Start ``n`` worker processes (multiprocessing spawn, each with its own GL
        context) connecting over the private ``ipc://`` endpoint; their pids."""
        procs = spawn_workers(n, self.local_endpoint, self.data_dir, cache)
        self._procs += procs
        return [p.pid for p in procs]

    def local_processes(self) -> list:
        """The ``multiprocessing.Process`` objects :meth:`spawn_local` started."""
        return list(self._procs)

    def close(self) -> None:
        """Stop: tell the workers, end the thread, terminate the local workers (killed
        if they do not exit within 2 s), remove the ipc folder.  Idempotent."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        thread = getattr(self, "_thread", None)
        if thread is not None:
            signal(self._wake_w)
            thread.join(timeout=5.0)
        for s in self._socks:
            s.close(linger=0)
        self._ctx.term()
        end_processes(self._procs)
        for fd in (self._wake_r, self._wake_w):
            os.close(fd)
        self._close_results()
        shutil.rmtree(self._dir, ignore_errors=True)

    def __enter__(self) -> Broker:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---------------------------------------------------------------------- sockets

    def _router(self, address: str) -> zmq.Socket:
        sock = self._ctx.socket(zmq.ROUTER)
        sock.setsockopt(zmq.LINGER, 0)
        sock.setsockopt(zmq.MAXMSGSIZE, MAX_RESULT_FRAME_BYTES)
        sock.setsockopt(zmq.ROUTER_MANDATORY, 1)  # a departed worker: an error, not a drop
        try:
            sock.bind(address)
        except zmq.ZMQError as exc:
            sock.close(linger=0)
            raise LodspriteError(f"render pool: cannot bind {address}: {exc}") from exc
        return sock

    # ----------------------------------------------------------------------- thread

    def _run(self) -> None:
        poller = zmq.Poller()
        for s in self._socks:
            poller.register(s, zmq.POLLIN)
        poller.register(self._wake_r, zmq.POLLIN)
        beat = time.monotonic() + HEARTBEAT_S
        while not self._stop.is_set():
            try:
                events = dict(poller.poll(self._timeout(beat) * 1000))
                for i, s in enumerate(self._socks):
                    if s in events:
                        self._receive(i, s)
                self.table.lose_unreachable()
                drain(self._wake_r)
                while self._inbox:
                    self.table.add(self._inbox.popleft())
                now = time.monotonic()
                self._purge(now)
                if now >= beat:
                    self._broadcast(Heartbeat(POOL_VERSION))
                    beat = now + HEARTBEAT_S
                self._dispatch(now)
                self._changed()
            except Exception as exc:  # noqa: BLE001 - a bug must not stop the pool
                log.error("render pool broker: internal error %r", exc)
        self._broadcast(Disconnect(POOL_VERSION, "broker closing", stop=True))

    def _timeout(self, beat: float) -> float:
        """Seconds until the next heartbeat or the next worker's expiry."""
        return max(0.0, self.table.next_due(beat) - time.monotonic())

    def _receive(self, index: int, sock: zmq.Socket) -> None:
        for _ in range(1000):  # bounded: heartbeats and dispatch still run under a flood
            try:
                frames = recv_frames(sock, 2 + KEYFRAME_PARTS)
            except zmq.Again:
                return
            key = (index, bytes(frames[0]))
            try:
                check_frames(frames)
                msg, parts = decode_pool(frames[1:])
            except ProtocolError as exc:
                self._reject(exc)
                continue
            self._handle(key, msg, parts)

    def _reject(self, exc: Exception) -> None:
        self.table.counts["rejected"] += 1
        if self.table.counts["rejected"] == 1:  # said once: a flood must not flood the log
            log.warning("render pool: a bad message from a worker: %s", exc)

    def _handle(self, key: Key, msg, parts: list) -> None:
        now = time.monotonic()
        peer = self.table.peers.get(key)
        if isinstance(msg, Ready):
            self.table.ready(key, msg, now)
            return
        if peer is None:  # a worker from before a restart, or a stranger: start over
            if not isinstance(msg, Disconnect):
                self._send(key, Disconnect(POOL_VERSION, "unknown worker: say ready"))
            return
        self.table.heard(peer, now)
        if isinstance(msg, Disconnect):
            self.table.lose(key, "disconnected")
        elif isinstance(msg, ResultMessage):
            self._result(key, msg, parts, now)

    def _result(self, key: Key, msg: ResultMessage, parts: list, now: float) -> None:
        try:
            self.table.settle(key, msg, parts, now)
        except ProtocolError as exc:  # the worker is broken or hostile: the job goes on
            self._reject(exc)
            self._send(key, Disconnect(POOL_VERSION, "bad keyframe"))
            self.table.lose(key, "sent a bad keyframe")

    def _purge(self, now: float) -> None:
        silent, late = self.table.expired(now)
        for key in silent:
            self.table.lose(key, "silent")
        for key in late:
            if key in self.table.peers:
                self._send(key, Disconnect(POOL_VERSION, "job timed out"))
                self.table.lose(key, "timed out")

    def _dispatch(self, now: float) -> None:
        """Each job the table assigns sent to its worker (one that cannot take it is
        lost after the next receive, the job back in front)."""
        for key, entry in self.table.assign(now):
            self._send(key, JobMessage(POOL_VERSION, entry.job, self.codec))

    def _send(self, key: Key, msg) -> None:
        """Send ``msg`` to one worker; one that cannot take it (gone under
        ROUTER_MANDATORY, or not keeping up) is lost after the next receive, so that a
        ``disconnect`` it sent just before it closed counts as one, not as a death."""
        try:
            self._socks[key[0]].send_multipart([key[1], *encode_pool(msg)], zmq.NOBLOCK)
        except zmq.ZMQError:
            self.table.unreachable.add(key)

    def _broadcast(self, msg) -> None:
        for key in list(self.table.peers):
            self._send(key, msg)

