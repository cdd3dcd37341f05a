"""The render pool's bookkeeping and dispatch policy, without processes: the workers
ready, the jobs queued, who declined what, the results ready, and which idle worker gets
which job.  A pool (:mod:`.local_pool`, :mod:`.ray_pool`) owns the renderers and a thread
and tells :class:`JobTable` what it received; everything here runs on that thread.

* a worker lost (died, timed out, or sent a bad keyframe) puts its job back at the front
  of the queue; a job whose workers died :data:`MAX_TRIES` times fails (``lost``);
* a job declined by :data:`MAX_TRIES` workers, or by every worker connected, fails with
  :attr:`~.jobs.Result.code` ``refused`` (all refusals) or ``failed``;
* jobs go one at a time to idle workers that have not declined them, first to one that
  has the job's scene loaded, else to the one idle longest.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

from lodsprite.distributed.pool.jobs import (
    Job,
    Ready,
    Result,
    ResultMessage,
    WorkerInfo,
    job_key,
)
from lodsprite.distributed.protocol import ProtocolError, decode_keyframe

log = logging.getLogger("lodsprite.pool")

JOB_TIMEOUT_S = 120.0
"""A job's longest time on a renderer before the renderer counts as hung."""
JOB_TIMES = 1000
"""Jobs whose dispatch-to-answer time :meth:`JobTable.stats` keeps."""
MAX_TRIES = 3
"""Workers a job may see die under it before it fails."""
MAX_PEERS = 4096
"""Workers the table holds at most (a ``ready`` beyond them is ignored)."""

Key = tuple[int, bytes]
"""A worker: a number of the pool's and its identity (the local pool's holds its pid)."""


@dataclass(eq=False)  # queued entries are told apart by identity
class QueuedJob:
    """A job in the pool's hands: ``tries`` workers lost under it, the workers that
    declined it (their key: their reason) and whether each of those refused it."""

    job: Job
    tries: int = 0
    declined: dict[Key, str] = field(default_factory=dict)
    refused: bool = True


@dataclass
class Peer:
    """A worker ready: what it said in ``ready``, the job it holds since when (monotonic
    s), when it went idle, and the scenes it loaded last."""

    sock: int
    ident: bytes
    info: Ready
    entry: QueuedJob | None = None
    since: float = 0.0
    idle_since: float = 0.0
    scenes: deque = field(default_factory=lambda: deque(maxlen=4))

    @property
    def key(self) -> Key:
        return self.sock, self.ident

    @property
    def job(self) -> Job | None:
        return None if self.entry is None else self.entry.job


class JobTable:
    """Workers, jobs and results; ``notify`` is called whenever a result is ready."""

    def __init__(self, job_timeout_s: float, notify: Callable[[], None]) -> None:
        self.job_timeout_s = float(job_timeout_s)
        self.notify = notify
        self.peers: dict[Key, Peer] = {}
        self.queue: deque[QueuedJob] = deque()
        self.done: deque[Result] = deque()
        self.counts = dict.fromkeys(("jobs", "results", "failed", "requeued", "declined",
                                     "dead", "rejected", "ignored", "released",
                                     "prepared"), 0)
        self.busy_s = 0.0  # seconds workers spent on jobs they answered
        self.job_s: deque[float] = deque(maxlen=JOB_TIMES)  # dispatch -> answer, s
        self.overhead_s: deque[float] = deque(maxlen=JOB_TIMES)  # that less the worker's own

    def add(self, job: Job) -> None:
        self.queue.append(QueuedJob(job))
        self.counts["jobs"] += 1

    def ready(self, key: Key, info: Ready, now: float) -> None:
        """A worker said ``ready`` (a second ``ready`` from it changes nothing)."""
        if key not in self.peers and len(self.peers) < MAX_PEERS:
            self.peers[key] = Peer(key[0], key[1], info, idle_since=now)

    def answered(self, peer: Peer, now: float, render_ms: float = 0.0) -> None:
        """``peer`` answered its job (a keyframe or a decline): its time, dispatch to
        answer, counted, and the dispatch overhead (that time less the worker's own
        ``render_ms``)."""
        took = max(0.0, now - peer.since)
        self.busy_s += took
        self.job_s.append(took)
        self.overhead_s.append(max(0.0, took - 1e-3 * render_ms))

    def settle(self, key: Key, msg: ResultMessage, parts: list, now: float) -> bool:
        """Worker ``key``'s answer ``msg`` (with the keyframe's frames ``parts``): a
        keyframe finishes its job, a decline puts it back for another worker (or fails
        it); an answer to a job it does not hold is counted ``ignored``.  Raises
        :class:`ProtocolError` for a keyframe that does not decode as its job's (the
        caller then loses the worker, the job back in the queue); False when ignored."""
        peer = self.peers.get(key)
        job = None if peer is None else peer.job
        if job is None or job.job != msg.job:
            self.counts["ignored"] += 1
            return False
        self.answered(peer, now, msg.render_ms)
        if not msg.ok:
            self.declined(key, self.release(peer, now), msg.error, msg.refused)
            return True
        data = [bytes(p) for p in parts]
        kf = decode_keyframe(data)
        if kf.seq != job.job:
            raise ProtocolError(f"keyframe seq {kf.seq} for job {job.job}")
        self.release(peer, now)
        peer.scenes.append(job_key(job.load))
        self.finish(Result(job.job, job.session, True, "", data, key[1].hex(),
                           render_ms=msg.render_ms))
        return True

    def release(self, peer: Peer, now: float) -> QueuedJob:
        """``peer`` idle from ``now``; returns the job's entry it held."""
        entry = peer.entry
        peer.entry, peer.idle_since = None, now
        return entry

    def declined(self, key: Key, entry: QueuedJob, error: str, refused: bool) -> None:
        """Worker ``key`` declined ``entry``: back in front for another worker, or failed
        when none is left to try."""
        self.counts["declined"] += 1
        entry.declined[key] = error
        entry.refused = entry.refused and refused
        if not self.fail_if_stuck(entry):
            self.queue.appendleft(entry)

    def finish(self, result: Result) -> None:
        self.counts["results" if result.ok else "failed"] += 1
        self.done.append(result)
        self.notify()

    def expired(self, now: float) -> list[Key]:
        """The workers holding a job past the job timeout."""
        return [k for k, p in self.peers.items()
                if p.job is not None and now - p.since > self.job_timeout_s]

    def lose(self, key: Key, why: str) -> None:
        """Forget a worker; its job goes back to the front of the queue."""
        peer = self.peers.pop(key, None)
        if peer is None:
            return
        self.counts["dead"] += 1
        log.info("render pool: worker %s (pid %d) %s", key[1].hex(), peer.info.pid, why)
        entry = peer.entry
        if entry is not None:
            entry.tries += 1
            if entry.tries >= MAX_TRIES:
                self.finish(Result(entry.job.job, entry.job.session, False,
                                   f"{entry.tries} workers were lost rendering this job",
                                   code="lost"))
            else:
                self.counts["requeued"] += 1
                self.queue.appendleft(entry)
        for waiting in [q for q in self.queue if q.declined]:  # their last hope gone?
            if self.fail_if_stuck(waiting):
                self.queue.remove(waiting)

    def fail_if_stuck(self, entry: QueuedJob) -> bool:
        """Fail ``entry`` (and say True) if :data:`MAX_TRIES` workers declined it or
        every connected worker did."""
        if len(entry.declined) < MAX_TRIES and any(
                k not in entry.declined for k in self.peers):
            return False
        reasons = sorted(set(entry.declined.values()))
        code = "refused" if entry.refused else "failed"
        self.finish(Result(entry.job.job, entry.job.session, False,
                           f"{code} by {len(entry.declined)} render worker(s): "
                           + "; ".join(reasons), code=code))
        return True

    def assign(self, now: float) -> list[tuple[Key, QueuedJob]]:
        """Each queued job, in order, to an idle reachable worker that has not declined
        it (a warm one first, else the one idle longest); the assignments made, each
        taken off the queue and held by its worker from ``now``."""
        out = []
        for entry in list(self.queue):
            idle = [p for p in self.peers.values() if p.entry is None]
            if not idle:
                break
            idle = [p for p in idle if p.key not in entry.declined]
            if not idle:
                continue  # a busy worker may take it later
            self.queue.remove(entry)
            scene = job_key(entry.job.load)
            warm = [p for p in idle if scene in p.scenes]
            peer = min(warm or idle, key=lambda p: p.idle_since)
            peer.entry, peer.since = entry, now
            out.append((peer.key, entry))
        return out

    def snapshot(self) -> list[WorkerInfo]:
        return [WorkerInfo(p.ident.hex(), p.info.pid, p.info.name, p.job and p.job.job)
                for p in self.peers.values()]

    def stats(self) -> dict[str, float]:
        """The counts, ``busy_s``, ``job_ms_p50``/``job_ms_p90`` and the dispatch
        overhead ``overhead_ms_p50``/``overhead_ms_p90`` (None before one):
        :meth:`lodsprite.distributed.pool.results.PoolResults.stats`."""
        return {**self.counts, "busy_s": self.busy_s,
                "job_ms_p50": _pct(self.job_s, 0.5), "job_ms_p90": _pct(self.job_s, 0.9),
                "overhead_ms_p50": _pct(self.overhead_s, 0.5),
                "overhead_ms_p90": _pct(self.overhead_s, 0.9)}


def _pct(seconds: deque, q: float) -> float | None:
    """The ``q`` quantile of ``seconds``, in ms (None when empty)."""
    times = sorted(seconds)
    return 1e3 * times[min(len(times) - 1, int(q * len(times)))] if times else None
