"""A local render worker: the Paranoid Pirate worker of the ZeroMQ guide (Hintjens,
*ZeroMQ*, ch. 4) rendering keyframes for a :class:`~.broker.Broker`, a process the broker's
process starts (:meth:`~.broker.Broker.spawn_local`).  Renderers of other machines are
Ray actors (:mod:`.ray_pool`); this worker is the local pool's, kept for where Ray is not
installed (see :mod:`.broker`).

A DEALER connects to the broker and says ``ready``.  Two threads: the I/O thread (here,
:meth:`Worker.run`) owns the socket, sends a heartbeat every :data:`~.jobs.HEARTBEAT_S`,
takes jobs and forwards results; the render thread hands one job at a time to the render
process (:mod:`.render_process`: the GL context and the scenes, rendered with
:class:`~lodsprite.distributed.render.KeyframeService`) and waits on its pipe, so
heartbeats go on while a scene loads or a keyframe renders, whatever holds the render
process's GIL (a 4096² scene's draws and uploads did, past the broker's liveness).
A broker silent for :data:`~.jobs.LIVENESS_S` is dead: the worker closes its socket and
connects again after a backoff (0.25 s doubling to 4 s, reset by the broker's first
message); a result of a job from a lost connection is dropped.

Workers render every job they are given: the submitter (the web page) decides when a
keyframe is due, so a worker's renderer does not pace (``pace="continuous"``: no
per-keyframe reprojection for a pacer nobody asks).  Scenes are kept by their ``load``
arguments, least recently used dropped first (``cache``, all sharing the render
process's one GL context).  A render process that dies (a driver crash, the kernel's
out-of-memory killer) fails the job it held and is started again, at most three times.
Names follow the ``--data`` rule of
:mod:`lodsprite.distributed.datasets` on the worker: built-ins, files relative to the
worker's own data folder, or absolute paths inside it (what a local web server's
resolution gives).  A scene the machine cannot hold (its memory estimate against
``MemAvailable``) is refused before anything loads.  Every message is validated
(:func:`~.jobs.decode_pool`); a bad one is counted and ignored, never fatal.

Stopping (:meth:`Worker.stop`; SIGTERM or SIGINT with :func:`stop_on_signals`): the I/O
thread says ``disconnect`` to the broker, which re-queues the job this worker held at
once, the render thread stops waiting for the render in progress (if any; its result is
dropped) and ends the render process (which finishes that render within a second or is
killed; its scenes and GL context go with it), and :meth:`Worker.run` returns.  A local worker
ignores SIGINT (a terminal's Ctrl-C reaches the whole process group: its web server stops
it) and stops on SIGTERM.
"""

from __future__ import annotations

import logging
import os
import queue
import signal
import threading
import time
from pathlib import Path

import msgspec
import zmq

from lodsprite.distributed.datasets import Datasets
from lodsprite.distributed.frames import check_frames, recv_frames
from lodsprite.distributed.pool.jobs import (
    HEARTBEAT_S,
    LIVENESS_S,
    MAX_JOB_BYTES,
    POOL_VERSION,
    Disconnect,
    Heartbeat,
    JobMessage,
    Ready,
    ResultMessage,
    decode_pool,
    encode_pool,
)
from lodsprite.distributed.protocol import ProtocolError

log = logging.getLogger("lodsprite.pool")

__all__ = ["BACKOFF_MAX_S", "Worker", "end_processes", "run_local_worker",
           "spawn_workers", "stop_on_signals"]

BACKOFF_MAX_S = 4.0
DISCONNECT_LINGER_MS = 500
"""How long a stopping worker's ``disconnect`` may wait to reach the broker (a broker
that is gone costs the stop this much)."""


class _RenderThread(threading.Thread):
    """The render thread: jobs in from a queue, handed to the render process
    (:mod:`.render_process`, the GL's own process, its own GIL), result frames out over
    an inproc PAIR.  It only waits on the process's pipe, so the I/O thread's heartbeats
    go on whatever the GL does."""

    def __init__(self, zctx: zmq.Context, address: str, datasets: Datasets,
                 cache: int) -> None:
        super().__init__(daemon=True, name="pool-render")
        self.jobs: queue.Queue[JobMessage | None] = queue.Queue()
        self.out = zctx.socket(zmq.PAIR)
        self.out.setsockopt(zmq.LINGER, 0)
        self.out.connect(address)
        self.args = {"data_dir": None if datasets.data_dir is None else str(datasets.data_dir),
                     "cache": cache}
        self.process = None
        self.stopping = threading.Event()

    def drop_jobs(self) -> int:
        """Forget the jobs not yet started (a reconnect or a stop); how many."""
        n = 0
        while True:
            try:
                self.jobs.get_nowait()
            except queue.Empty:
                return n
            n += 1

    def stop(self) -> None:
        """End after the job in hand (its result dropped) and the jobs queued."""
        self.stopping.set()
        self.jobs.put(None)

    def run(self) -> None:
        try:
            while (msg := self.jobs.get()) is not None:
                frames = self._render(msg)
                if frames is not None:
                    self.out.send_multipart(frames)
        finally:
            self.release()

    def release(self) -> None:
        """End the render process (its scenes and GL context go with it) and close the
        result socket, on the thread that rendered; log what was released."""
        had = self.process is not None
        if had:
            self.process.close()
            self.process = None
        self.out.close(linger=0)
        log.info("render worker: %s", "the render process ended: its scenes and the GL "
                 "context released" if had else "no render process started")

    def _render(self, msg: JobMessage) -> list | None:
        """The result frames of one job (None: stopped while it rendered); never raises."""
        from multiprocessing.connection import wait

        from lodsprite.distributed.pool.render_process import FACTORY, unpack
        from lodsprite.workers import ProcessWorker, WorkerError

        if self.process is None:
            self.process = ProcessWorker(FACTORY, self.args, in_flight=1, name="render",
                                         max_request=MAX_JOB_BYTES)
        try:
            self.process.submit(msg.job.job, msgspec.msgpack.encode(msg))
        except ValueError as exc:  # larger than a job frame can be: not from a broker
            return encode_pool(ResultMessage(POOL_VERSION, msg.job.job, False, str(exc)))
        while not (answers := self.process.poll()):
            if self.stopping.is_set():
                return None
            wait([self.process], timeout=0.05)  # the answer pipe, or a death
        answer = answers[0][1]
        if isinstance(answer, WorkerError):  # the process died on it (started again)
            return encode_pool(ResultMessage(POOL_VERSION, msg.job.job, False,
                                             answer.text[:4000]))
        return unpack(*answer)


class Worker:
    """One render worker connecting to ``connect`` (the broker's ``ipc://…`` endpoint).

    ``data_dir``: the folder whose files jobs may name (None: built-ins only).  ``cache``:
    scenes kept loaded.  ``parent_pid``: exit when this process is no longer the parent
    (local workers never outlive their broker's process)."""

    def __init__(self, connect: str, data_dir: Path | str | None = None, cache: int = 2,
                 name: str = "", parent_pid: int | None = None) -> None:
        self.connect = connect
        self.datasets = Datasets(data_dir)
        self.cache = max(1, min(int(cache), 64))
        self.name = name[:256]
        self.parent_pid = parent_pid
        self.rejected = 0
        self.connections = 0
        self._stop = threading.Event()

    def stop(self) -> None:
        """Make :meth:`run` return (thread-safe)."""
        self._stop.set()

    def run(self) -> None:
        """Serve the broker until :meth:`stop`, a ``disconnect`` is not followed by a
        broker again (it reconnects), or the parent process goes away."""
        zctx = zmq.Context()
        address = f"inproc://pool-render-{id(self)}"
        pipe = zctx.socket(zmq.PAIR)
        pipe.bind(address)
        renderer = _RenderThread(zctx, address, self.datasets, self.cache)
        renderer.start()
        backoff = HEARTBEAT_S
        try:
            while not self._should_stop():
                heard = self._session(zctx, pipe, renderer)
                backoff = HEARTBEAT_S if heard else min(2 * backoff, BACKOFF_MAX_S)
                self._stop.wait(backoff)
        finally:
            renderer.drop_jobs()
            renderer.stop()  # behind nothing: the render thread ends, its job dropped
            renderer.join(timeout=10.0)
            pipe.close(linger=0)
            if not renderer.is_alive():  # a thread stuck in a render still holds a socket
                zctx.term()

    def _should_stop(self) -> bool:
        if self.parent_pid is not None and os.getppid() != self.parent_pid:
            return True
        return self._stop.is_set()

    def _session(self, zctx: zmq.Context, pipe: zmq.Socket, renderer: _RenderThread) -> bool:
        """One connection to the broker, until it is silent too long or says disconnect;
        whether it heard the broker at all."""
        sock = zctx.socket(zmq.DEALER)
        sock.setsockopt(zmq.LINGER, 0)
        sock.setsockopt(zmq.MAXMSGSIZE, MAX_JOB_BYTES)
        sock.connect(self.connect)
        self.connections += 1
        renderer.drop_jobs()  # the last connection's jobs went back to the broker's queue
        sock.send_multipart(encode_pool(Ready(POOL_VERSION, os.getpid(), self.name,
                                              self.cache)))
        poller = zmq.Poller()
        poller.register(sock, zmq.POLLIN)
        poller.register(pipe, zmq.POLLIN)
        mine: set[int] = set()  # jobs of this connection
        heard = False
        now = time.monotonic()
        deadline, beat = now + LIVENESS_S, now + HEARTBEAT_S
        try:
            while not self._should_stop():
                events = dict(poller.poll(max(0.0, beat - time.monotonic()) * 1000))
                if sock in events:
                    alive = self._from_broker(sock, renderer, mine)
                    if alive is False:
                        return heard
                    if alive:
                        heard = True
                        deadline = time.monotonic() + LIVENESS_S
                if pipe in events:
                    frames = pipe.recv_multipart(copy=False)
                    job = msgspec.msgpack.decode(frames[0].buffer, type=ResultMessage).job
                    if job in mine:
                        mine.discard(job)
                        sock.send_multipart(frames, copy=False)
                now = time.monotonic()
                if now >= beat:
                    sock.send_multipart(encode_pool(Heartbeat(POOL_VERSION)))
                    beat = now + HEARTBEAT_S
                if now > deadline:
                    log.info("render worker: broker %s silent, reconnecting", self.connect)
                    return heard
            sock.send_multipart(encode_pool(Disconnect(POOL_VERSION, "worker stopping")))
            sock.close(linger=DISCONNECT_LINGER_MS)  # sent, not dropped by the close
            return heard
        finally:
            sock.close(linger=0)

    def _from_broker(self, sock: zmq.Socket, renderer: _RenderThread,
                     mine: set[int]) -> bool | None:
        """Handle the waiting messages: True if the broker spoke, False if it said
        disconnect, None if only bad messages came."""
        heard = None
        while True:
            try:
                frames = recv_frames(sock, 1)
            except zmq.Again:
                return heard
            try:
                check_frames(frames)
                msg, _ = decode_pool(frames)
            except ProtocolError as exc:
                self.rejected += 1
                if self.rejected == 1:
                    log.warning("render worker: a bad message from the broker: %s", exc)
                continue
            if isinstance(msg, Disconnect):
                if msg.stop and self.parent_pid is not None:
                    self._stop.set()  # a local worker ends with its broker
                return False
            heard = True
            if isinstance(msg, JobMessage):
                mine.add(msg.job.job)
                renderer.jobs.put(msg)


def stop_on_signals(worker: Worker, signums: tuple[int, ...] = (signal.SIGTERM,
                                                                 signal.SIGINT)) -> None:
    """Make the signals ``signums`` stop ``worker`` (its :meth:`Worker.run` returns
    within a heartbeat, after the render in progress); call from the main thread."""
    def handler(signum: int, frame: object) -> None:
        worker.stop()

    for signum in signums:
        signal.signal(signum, handler)


def run_local_worker(connect: str, data_dir: str | None, cache: int, parent_pid: int) -> None:
    """Entry point of a local worker process (:meth:`Broker.spawn_local`): SIGINT
    ignored (the parent stops it), SIGTERM stops it."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    logging.basicConfig(level=logging.WARNING, format="lodsprite worker: %(message)s")
    worker = Worker(connect, data_dir, cache, f"local-{os.getpid()}", parent_pid)
    stop_on_signals(worker, (signal.SIGTERM,))
    worker.run()


def spawn_workers(n: int, connect: str, data_dir: str | None, cache: int) -> list:
    """Start ``n`` local worker processes connecting to ``connect``
    (:func:`lodsprite.procs.start_child`: spawn, a fresh interpreter, its own GL
    context); their :class:`~lodsprite.procs.Child` handles (``pid``, ``is_alive``)."""
    from lodsprite.procs import start_child

    return [start_child(run_local_worker, (connect, data_dir, cache, os.getpid()),
                        name="lodsprite-worker") for _ in range(n)]


def end_processes(procs: list) -> None:
    """Stop local workers (they were told): 2 s to exit, then terminate, then kill."""
    from lodsprite.procs import stop_children

    stop_children(procs, 2.0)
