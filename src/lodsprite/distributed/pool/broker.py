"""The render pool's broker: the Paranoid Pirate queue of the ZeroMQ guide (Hintjens,
*ZeroMQ*, ch. 4, "Robust Reliable Queuing") between a keyframe submitter (the web server)
and render workers (:mod:`.worker`).

A ROUTER socket, bound to a private ``ipc://`` endpoint for the workers this process
starts (:meth:`Broker.spawn_local`) and, with ``bind``, to ``tcp://HOST:PORT`` for workers
on other hosts (``lodsprite render-worker``; CURVE with ``curve`` keys: only workers whose
public key file lies in the keys folder get in).  One thread owns the sockets:

* a worker says ``ready``; the broker heartbeats each :data:`~.jobs.HEARTBEAT_S`; a
  worker silent for more than :data:`~.jobs.LIVENESS_S` (plus the transfer time of a
  result it announced) is dead, its job re-queued at the front (a job whose workers died
  :data:`MAX_TRIES` times fails instead: it may be what kills them);
* a worker that declines a job (``result`` not ok: it refuses the job, a dataset its
  ``--data`` lacks or a scene its machine cannot hold, or its render failed) does not fail
  it while another connected worker has not declined it: the job goes back to the front
  of the queue for one of those; declined by :data:`MAX_TRIES` workers, or by every worker
  connected, it fails with :attr:`~.jobs.Result.code` ``refused`` (all refusals) or
  ``failed``, and the workers' reasons;
* jobs go one at a time to idle workers that have not declined them, first to one that
  has the job's scene loaded, else to the one idle longest;
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
from dataclasses import dataclass, field
from pathlib import Path

import zmq

from lodsprite.distributed.frames import check_frames, recv_frames
from lodsprite.distributed.keys import ServerKeys
from lodsprite.distributed.pool.jobs import (
    HEARTBEAT_S,
    KEYFRAME_PARTS,
    LIVENESS_S,
    MAX_GRACE_S,
    MAX_RESULT_FRAME_BYTES,
    MIN_LINK_BYTES_S,
    POOL_VERSION,
    Disconnect,
    Heartbeat,
    Job,
    JobMessage,
    Ready,
    Result,
    ResultMessage,
    WorkerInfo,
    check_bind,
    check_job,
    decode_pool,
    encode_pool,
    job_key,
)
from lodsprite.distributed.pool.render_worker import end_processes, spawn_workers
from lodsprite.distributed.protocol import CODECS, ProtocolError, decode_keyframe
from lodsprite.errors import InputError, LodspriteError

log = logging.getLogger("lodsprite.pool")

__all__ = ["JOB_TIMEOUT_S", "MAX_TRIES", "Broker", "WorkerInfo"]

JOB_TIMEOUT_S = 120.0
JOB_TIMES = 1000
"""Jobs whose dispatch-to-answer time :meth:`Broker.stats` keeps."""
MAX_TRIES = 3
"""Workers a job may see die under it before it fails."""


@dataclass(eq=False)  # queued entries are told apart by identity
class _Queued:
    """A job in the broker's hands: ``tries`` workers lost under it, the workers that
    declined it (their key: their reason) and whether each of those refused it."""

    job: Job
    tries: int = 0
    declined: dict[tuple[int, bytes], str] = field(default_factory=dict)
    refused: bool = True


@dataclass
class _Peer:
    sock: int
    ident: bytes
    info: Ready
    seen: float
    entry: _Queued | None = None
    since: float = 0.0
    grace: float = 0.0
    idle_since: float = 0.0
    scenes: deque = field(default_factory=lambda: deque(maxlen=4))

    @property
    def job(self) -> Job | None:
        return None if self.entry is None else self.entry.job


class Broker:
    """The pool's broker.  ``bind``: ``tcp://HOST:PORT`` for remote workers (None: local
    workers only); a host beyond loopback needs ``curve`` or ``allow_remote``.
    ``curve``: the server's CURVE keys (:class:`~lodsprite.distributed.keys.ServerKeys`).
    ``codec``: keyframe images ``raw`` or ``zlib``.  ``data_dir``: the data folder local
    workers serve (the web server's ``--data``)."""

    def __init__(self, bind: str | None = None, curve: ServerKeys | None = None,
                 codec: str = "raw", data_dir: Path | str | None = None,
                 allow_remote: bool = False, job_timeout_s: float = JOB_TIMEOUT_S) -> None:
        if codec not in CODECS:
            raise InputError(f"unknown codec '{codec}': use {', '.join(CODECS)}")
        if bind is not None:
            check_bind(bind, curve is not None or allow_remote)
        self.codec = codec
        self.job_timeout_s = float(job_timeout_s)
        self.data_dir = None if data_dir is None else str(Path(data_dir).resolve())
        self.curve = curve
        self._dir = tempfile.mkdtemp(prefix="lodsprite-pool-")
        self.local_endpoint = f"ipc://{self._dir}/workers"
        self.endpoints = [self.local_endpoint]
        self._ctx = zmq.Context()
        self._auth = None
        self._socks: list[zmq.Socket] = []
        self._procs: list = []
        self._queue: deque[_Queued] = deque()
        self._inbox: deque[Job] = deque()
        self._done: deque[Result] = deque()
        self._peers: dict[tuple[int, bytes], _Peer] = {}
        self._unreachable: set[tuple[int, bytes]] = set()  # a send failed: lose next
        self._snapshot: list[WorkerInfo] = []
        self._stats = dict.fromkeys(("jobs", "results", "failed", "requeued", "declined",
                                     "dead", "rejected", "ignored"), 0)
        self._busy_s = 0.0  # seconds workers spent on jobs they answered
        self._job_s: deque[float] = deque(maxlen=JOB_TIMES)  # dispatch -> answer, s
        self._stop = threading.Event()
        self._wake_r, self._wake_w = os.pipe()
        self._ready_r, self._ready_w = os.pipe()
        for fd in (self._wake_r, self._wake_w, self._ready_r, self._ready_w):
            os.set_blocking(fd, False)
        self._closed = False
        try:
            self._open(bind)
        except BaseException:
            self.close()
            raise
        self._thread = threading.Thread(target=self._run, daemon=True, name="pool-broker")
        self._thread.start()

    def submit(self, job: Job) -> None:
        """Queue ``job`` (never blocks; thread-safe)."""
        self._inbox.append(check_job(job))
        _signal(self._wake_w)

    def poll(self) -> list[Result]:
        """The results (successes and failures) since the last call; never blocks."""
        _drain(self._ready_r)
        return [self._done.popleft() for _ in range(len(self._done))]

    def fileno(self) -> int:
        """A descriptor readable while :meth:`poll` has results (level-triggered)."""
        return self._ready_r

    def workers(self) -> list[WorkerInfo]:
        """The workers connected now."""
        return list(self._snapshot)

    def stats(self) -> dict[str, float]:
        """Counts: jobs, results, failed, requeued (after a lost worker), declined
        (results not ok, each retried elsewhere or failed), dead, rejected, ignored; and
        the render capacity: ``busy_s`` (seconds workers spent on the jobs they answered,
        dispatch to answer, all workers together: over a wall-clock window and the
        worker count it gives their utilisation) and ``job_ms_p50``/``job_ms_p90`` (a
        job's dispatch to answer, ms, over the last :data:`JOB_TIMES`; None before
        one)."""
        times = sorted(self._job_s)

        def pct(q: float) -> float | None:
            return 1e3 * times[min(len(times) - 1, int(q * len(times)))] if times else None

        return {**self._stats, "busy_s": self._busy_s, "job_ms_p50": pct(0.5),
                "job_ms_p90": pct(0.9)}

    def wait_workers(self, n: int, timeout: float) -> bool:
        """Wait until at least ``n`` workers are connected (at most ``timeout`` s)."""
        deadline = time.monotonic() + timeout
        while len(self._snapshot) < n and time.monotonic() < deadline:
            time.sleep(0.02)
        return len(self._snapshot) >= n

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
            _signal(self._wake_w)
            thread.join(timeout=5.0)
        for s in self._socks:
            s.close(linger=0)
        if self._auth is not None:
            self._auth.stop()
        self._ctx.term()
        end_processes(self._procs)
        for fd in (self._wake_r, self._wake_w, self._ready_r, self._ready_w):
            os.close(fd)
        shutil.rmtree(self._dir, ignore_errors=True)

    def __enter__(self) -> Broker:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---------------------------------------------------------------------- sockets

    def _open(self, bind: str | None) -> None:
        self._socks.append(self._router(self.local_endpoint, None))
        if bind is not None:
            if self.curve is not None:
                from zmq.auth.thread import ThreadAuthenticator

                self._auth = ThreadAuthenticator(self._ctx)
                self._auth.start()  # admits the public keys in the keys folder only
                self._auth.configure_curve(domain="*", location=str(self.curve.clients_dir))
            self._socks.append(self._router(bind, self.curve))
            self.endpoints.append(self._socks[-1].getsockopt_string(zmq.LAST_ENDPOINT))

    def _router(self, address: str, curve: ServerKeys | None) -> zmq.Socket:
        sock = self._ctx.socket(zmq.ROUTER)
        sock.setsockopt(zmq.LINGER, 0)
        sock.setsockopt(zmq.MAXMSGSIZE, MAX_RESULT_FRAME_BYTES)
        sock.setsockopt(zmq.ROUTER_MANDATORY, 1)  # a departed worker: an error, not a drop
        if curve is not None:
            curve.apply(sock)
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
                self._lose_unreachable()
                _drain(self._wake_r)
                while self._inbox:
                    self._queue.append(_Queued(self._inbox.popleft()))
                    self._stats["jobs"] += 1
                now = time.monotonic()
                self._purge(now)
                if now >= beat:
                    self._broadcast(Heartbeat(POOL_VERSION))
                    beat = now + HEARTBEAT_S
                self._dispatch(now)
                self._snapshot = [WorkerInfo(p.ident.hex(), p.info.pid, p.info.name,
                                             p.sock > 0, p.job and p.job.job)
                                  for p in self._peers.values()]
            except Exception as exc:  # noqa: BLE001 - a bug must not stop the pool
                log.error("render pool broker: internal error %r", exc)
        self._broadcast(Disconnect(POOL_VERSION, "broker closing", stop=True))

    def _timeout(self, beat: float) -> float:
        """Seconds until the next heartbeat or the next worker's expiry."""
        if self._unreachable:
            return 0.0  # read what they said last before losing them
        due = min((p.seen + LIVENESS_S + p.grace for p in self._peers.values()),
                  default=beat)
        return max(0.0, min(beat, due + 1e-3) - time.monotonic())

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
        self._stats["rejected"] += 1
        if self._stats["rejected"] == 1:  # said once: a flood must not flood the log
            log.warning("render pool: a bad message from a worker: %s", exc)

    def _handle(self, key: tuple[int, bytes], msg, parts: list) -> None:
        now = time.monotonic()
        peer = self._peers.get(key)
        if isinstance(msg, Ready):
            if peer is None and len(self._peers) < 4096:
                self._peers[key] = _Peer(key[0], key[1], msg, now, idle_since=now)
            return
        if peer is None:  # a worker from before a restart, or a stranger: start over
            if not isinstance(msg, Disconnect):
                self._send(key, Disconnect(POOL_VERSION, "unknown worker: say ready"))
            return
        peer.seen = now
        sending = isinstance(msg, Heartbeat) and msg.sending and peer.job is not None
        peer.grace = min(msg.sending / MIN_LINK_BYTES_S, MAX_GRACE_S) if sending else 0.0
        if isinstance(msg, Disconnect):
            self._lose(key, "disconnected")
        elif isinstance(msg, ResultMessage):
            self._result(key, peer, msg, parts)

    def _result(self, key, peer: _Peer, msg: ResultMessage, parts: list) -> None:
        job = peer.job
        if job is None or job.job != msg.job:
            self._stats["ignored"] += 1
            return
        worker = key[1].hex()
        took = max(0.0, time.monotonic() - peer.since)
        self._busy_s += took
        self._job_s.append(took)
        if not msg.ok:
            entry = peer.entry
            peer.entry, peer.idle_since = None, time.monotonic()
            self._stats["declined"] += 1
            entry.declined[key] = msg.error
            entry.refused = entry.refused and msg.refused
            if not self._fail_if_stuck(entry):
                self._queue.appendleft(entry)  # another worker may render it
            return
        data = [bytes(p) for p in parts]
        try:
            kf = decode_keyframe(data)
            if kf.seq != job.job:
                raise ProtocolError(f"keyframe seq {kf.seq} for job {job.job}")
        except ProtocolError as exc:  # the worker is broken or hostile: the job goes on
            self._reject(exc)
            self._send(key, Disconnect(POOL_VERSION, "bad keyframe"))
            self._lose(key, "sent a bad keyframe")
            return
        peer.entry, peer.idle_since = None, time.monotonic()
        peer.scenes.append(job_key(job.load))
        self._finish(Result(job.job, job.session, True, "", data, worker))

    def _finish(self, result: Result) -> None:
        self._stats["results" if result.ok else "failed"] += 1
        self._done.append(result)
        _signal(self._ready_w)

    def _purge(self, now: float) -> None:
        for key in [k for k, p in self._peers.items()
                    if now - p.seen > LIVENESS_S + p.grace]:
            self._lose(key, "silent")
        for key in [k for k, p in self._peers.items()
                    if p.job is not None and now - p.since > self.job_timeout_s]:
            self._send(key, Disconnect(POOL_VERSION, "job timed out"))
            self._lose(key, "timed out")

    def _lose(self, key: tuple[int, bytes], why: str) -> None:
        """Forget a worker; its job goes back to the front of the queue."""
        peer = self._peers.pop(key, None)
        if peer is None:
            return
        self._stats["dead"] += why != "disconnected"
        log.info("render pool: worker %s (pid %d) %s", key[1].hex(), peer.info.pid, why)
        entry = peer.entry
        if entry is not None:
            entry.tries += 1
            if entry.tries >= MAX_TRIES:
                self._finish(Result(entry.job.job, entry.job.session, False,
                                    f"{entry.tries} workers were lost rendering this job",
                                    code="lost"))
            else:
                self._stats["requeued"] += 1
                self._queue.appendleft(entry)
        for waiting in [q for q in self._queue if q.declined]:  # their last hope gone?
            if self._fail_if_stuck(waiting):
                self._queue.remove(waiting)

    def _fail_if_stuck(self, entry: _Queued) -> bool:
        """Fail ``entry`` (and say True) if :data:`MAX_TRIES` workers declined it or
        every connected worker did."""
        if len(entry.declined) < MAX_TRIES and any(
                k not in entry.declined for k in self._peers):
            return False
        reasons = sorted(set(entry.declined.values()))
        code = "refused" if entry.refused else "failed"
        self._finish(Result(entry.job.job, entry.job.session, False,
                            f"{code} by {len(entry.declined)} render worker(s): "
                            + "; ".join(reasons), code=code))
        return True

    def _dispatch(self, now: float) -> None:
        """Each queued job, in order, to an idle worker that has not declined it."""
        for entry in list(self._queue):
            idle = [p for p in self._peers.values()
                    if p.entry is None and (p.sock, p.ident) not in self._unreachable]
            if not idle:
                return
            idle = [p for p in idle if (p.sock, p.ident) not in entry.declined]
            if not idle:
                continue  # a busy worker may take it later
            self._queue.remove(entry)
            scene = job_key(entry.job.load)
            warm = [p for p in idle if scene in p.scenes]
            peer = min(warm or idle, key=lambda p: p.idle_since)
            peer.entry, peer.since = entry, now
            # Unreachable: lost after the next receive, the job back in front.
            self._send((peer.sock, peer.ident),
                       JobMessage(POOL_VERSION, entry.job, self.codec))

    def _send(self, key: tuple[int, bytes], msg) -> None:
        """Send ``msg`` to one worker; one that cannot take it (gone under
        ROUTER_MANDATORY, or not keeping up) is lost after the next receive, so that a
        ``disconnect`` it sent just before it closed counts as one, not as a death."""
        try:
            self._socks[key[0]].send_multipart([key[1], *encode_pool(msg)], zmq.NOBLOCK)
        except zmq.ZMQError:
            self._unreachable.add(key)

    def _lose_unreachable(self) -> None:
        """Lose the workers a send failed to (their job back in front of the queue),
        unless what was just received already let them go."""
        gone, self._unreachable = self._unreachable, set()
        for key in gone:
            self._lose(key, "unreachable")

    def _broadcast(self, msg) -> None:
        for key in list(self._peers):
            self._send(key, msg)


def _signal(fd: int) -> None:
    try:
        os.write(fd, b"\x01")
    except (BlockingIOError, OSError):
        pass  # the pipe is full (a wake-up is pending anyway) or closed


def _drain(fd: int) -> None:
    try:
        while os.read(fd, 4096):
            pass
    except (BlockingIOError, OSError):
        pass
