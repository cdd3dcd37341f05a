"""The web server's core: sessions, their scenes, and fair keyframe scheduling over the
render pool.

* ``load``: the names resolve by the ``--data`` rule (:class:`~lodsprite.distributed.
  datasets.Datasets`, as for ZeroMQ clients); a scene the machine cannot hold is refused
  before anything is allocated (:func:`~lodsprite.distributed.render.estimate_scene_bytes`
  against ``MemAvailable``); the ``scene`` message is built in a thread of the server
  process (GL-free, :mod:`.scene`), cached by its arguments, and sent, then the reply.
  Meanwhile a pool that can (the local pool's ``prepare``) has one renderer open the
  scene, which the page's first request then goes to.  Only the session's newest
  ``load`` takes effect; one session's load never changes
  another's (jobs carry their session's arguments; renderers cache scenes by them).
* Scheduling: round robin over the sessions with waiting requests and fewer than
  ``session_jobs`` in flight, one job per live worker at a time, so that a session asking
  often gets no more renders than one asking when it needs to.  The pool owns the job
  timeout (the pool's ``job_timeout_s``: it re-queues a job whose worker died or is too
  slow, and fails it after ``MAX_TRIES`` workers; a job a worker declines goes to another
  worker, up to ``MAX_TRIES`` of them); the hub forgets a job (counted ``failed``) only
  after all those tries and :data:`JOB_GRACE_S` more, as a backstop against a pool that
  never answers, so it never resubmits while a worker still renders.
* A failed job's ``reply`` (not ok) carries ``data.code``: ``refused`` (every worker that
  tried refused it: a dataset or a scene size it does not serve), ``failed`` (a render
  failed) or ``lost`` (its workers died).
* Generations: each applied ``load`` starts a new generation of its session; its requests
  of the older one are forgotten and a result that still comes for one is dropped
  (counted ``stale``), so a page never gets a keyframe of the terrain it left.
* ``path``: one in flight per session (another is refused), built under the same
  semaphore as scenes, from the height field cached with the session's scene (the
  newest built scene's only; another's is loaded again).
* Jobs carry the page's names (validated here); a worker resolves them by its own
  ``--data`` rule (local workers share the server's data folder).
* Results: the keyframe a renderer encoded (the ZeroMQ ``keyframe`` message) goes to its
  session with the request's ``seq`` and ``t0`` set to the request's ``t`` (the page's
  clock); the images are not touched.
"""

from __future__ import annotations

import asyncio
import itertools
import logging
import time
from collections import OrderedDict
from typing import Any

import msgspec

from lodsprite.distributed.datasets import Datasets
from lodsprite.distributed.pool import Job
from lodsprite.distributed.pool.dispatch import JOB_TIMEOUT_S, MAX_TRIES
from lodsprite.distributed.pool.jobs import job_key
from lodsprite.distributed.protocol import (
    MAX_SCENE_COARSE,
    KeyframeMessage,
    LoadArgs,
    PathArgs,
    ProtocolError,
    decode_message,
    encode,
)
from lodsprite.distributed.render import working_grid
from lodsprite.distributed.served import OBJECT_KINDS
from lodsprite.distributed.server import check_scene_memory
from lodsprite.distributed.web.scene import build_scene_field, path_data, scene_key
from lodsprite.distributed.web.sessions import Caps, Pending, Session
from lodsprite.errors import InputError, LodspriteError

log = logging.getLogger("lodsprite.web")

__all__ = ["JOB_GRACE_S", "POOL_TRIES", "SCENES_CACHED", "Hub"]

JOB_GRACE_S = 10.0
"""Seconds past the pool's last try after which the hub forgets a job."""
POOL_TRIES = 2 * MAX_TRIES
"""Workers the pool may give a job: MAX_TRIES lost ones and MAX_TRIES that declined."""
SCENES_CACHED = 4
TICK_S = 0.05


class Hub:
    """Sessions and the pool (the pool interface: submit, poll, fileno, workers).  Start
    with :meth:`start` inside the running event loop; :meth:`stop` ends its tasks."""

    def __init__(self, pool: Any, datasets: Datasets, caps: Caps | None = None,
                 codec: str = "raw") -> None:
        self.pool = pool
        self.datasets = datasets
        self.caps = caps or Caps()
        self.codec = codec
        self.sessions: OrderedDict[str, Session] = OrderedDict()
        self.jobs: dict[int, tuple[Session, Pending, float]] = {}
        self._ids = itertools.count(1)
        self._turn = 0
        self._scenes: OrderedDict[tuple, tuple[list, Any]] = OrderedDict()  # parts, hf
        self._builds = asyncio.Semaphore(1)
        self._generation: dict[str, int] = {}
        self._tasks: set[asyncio.Task] = set()
        self._ticker: asyncio.Task | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        timeout = getattr(pool, "job_timeout_s", JOB_TIMEOUT_S)  # the pool's: one timeout
        self.job_timeout_s = timeout * POOL_TRIES + JOB_GRACE_S

    # ------------------------------------------------------------------- lifetime

    def start(self) -> None:
        loop = asyncio.get_running_loop()
        start = getattr(self.pool, "start", None)
        if start is not None:  # a pool that can run on this loop (the Ray pool)
            start(loop)
        loop.add_reader(self.pool.fileno(), self.drain)
        self._loop = loop
        self._ticker = loop.create_task(self._tick())

    async def stop(self) -> None:
        self.close()

    def close(self) -> None:
        """End the hub's tasks and sessions (from the loop's thread; idempotent)."""
        loop = self._loop
        if loop is not None and not loop.is_closed():
            loop.remove_reader(self.pool.fileno())
        for task in [self._ticker, *self._tasks]:
            if task is not None:
                task.cancel()
        for s in list(self.sessions.values()):
            s.close()

    async def _tick(self) -> None:
        while True:  # the pool's descriptor may be edge-triggered: poll it regularly too
            await asyncio.sleep(TICK_S)
            self.drain()
            self._expire()

    def open_session(self, sid: str | None = None) -> Session:
        s = Session(self, self.caps, sid)
        self.sessions[s.id] = s
        return s

    def close_session(self, s: Session) -> None:
        named = s.named
        s.close()
        self.sessions.pop(s.id, None)
        self._generation.pop(s.id, None)
        self.forget(named)

    def forget(self, named: LoadArgs | None) -> None:
        """A session stopped using the scene ``named`` (it closed, released it or loaded
        another): when no open session uses it, the pool's renderers drop it (a pool
        without ``release``, Ray's, keeps it until its cache needs the room)."""
        if named is None:
            return
        key = job_key(named)
        if any(s.named is not None and job_key(s.named) == key
               for s in self.sessions.values() if not s.closed):
            return
        release = getattr(self.pool, "release", None)
        if release is not None:
            release(key)

    def workers_count(self) -> int:
        return len(self.pool.workers())

    def summary(self) -> dict:
        """Server-wide figures: sessions, workers, jobs in flight, the pool's counts
        (the pool's stats: jobs, results, failed, requeued, dead workers, ...) and each
        session's keyframes sent and dropped."""
        pool_stats = getattr(self.pool, "stats", None)
        return {"sessions": len(self.sessions), "workers": self.workers_count(),
                "inflight": len(self.jobs), "pool": pool_stats() if pool_stats else {},
                "per_session": [{"session": s.id,
                                 "scene": s.named.terrain if s.named is not None else None,
                                 "keyframes_sent": s.counts["keyframes_sent"],
                                 "keyframes_dropped": s.counts["keyframes_dropped"],
                                 "requests": s.counts["requests"]}
                                for s in self.sessions.values()]}

    # ------------------------------------------------------------------------ load

    def load(self, session: Session, args: LoadArgs, seq: int) -> None:
        """Start loading ``args`` for ``session`` (the reply comes later)."""
        gen = self._generation.get(session.id, 0) + 1
        self._generation[session.id] = gen
        task = asyncio.get_running_loop().create_task(self._load(session, args, seq, gen))
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _load(self, session: Session, args: LoadArgs, seq: int, gen: int) -> None:
        try:
            resolved = await asyncio.to_thread(self._resolve, args)  # opens files: not here
            prepare = getattr(self.pool, "prepare", None)
            if prepare is not None and not session.closed and (
                    self._generation.get(session.id) == gen):  # still the newest load:
                prepare(args)  # a renderer opens the scene while its message is built
            key = scene_key(resolved)
            cached = self._scenes.get(key)
            if cached is None:
                async with self._builds:  # one scene built at a time
                    if session.closed or self._generation.get(session.id) != gen:
                        return  # superseded while waiting: build nothing for it
                    root = self.datasets.data_dir
                    cached = self._scenes.get(key) or await asyncio.to_thread(
                        build_scene_field, resolved, self.codec,
                        None if root is None else str(root))
                self._scenes[key] = cached
                while len(self._scenes) > SCENES_CACHED:
                    self._scenes.popitem(last=False)
                for other, (parts, hf) in self._scenes.items():  # one working field kept:
                    if other != key and hf is not None:  # up to 268 MB at the grid cap
                        self._scenes[other] = (parts, None)
            self._scenes.move_to_end(key)
        except Exception as exc:  # noqa: BLE001 - any dataset's failure is the page's reply
            if self._generation.get(session.id) == gen:
                reason = exc if isinstance(exc, LodspriteError | OSError | ValueError) else (
                    f"internal error: {type(exc).__name__}")
                session.reply(seq, False, self._local(f"load: {reason}"))
            return
        if session.closed or self._generation.get(session.id) != gen:
            return  # a newer load of this session, or a closed one: this one is moot
        self._apply(session, args, resolved, gen)
        parts = cached[0]
        header = msgspec.msgpack.decode(parts[0])
        session.push_scene(encode({**header, "seq": seq}, *parts[1:]))  # the cached buffers
        session.reply(seq, True, data={"coarse": resolved.lod, "size": list(resolved.size),
                                       "jobs": self.caps.session_jobs})

    def _local(self, message: str) -> str:
        """``message`` as a page may read it (never the server's paths:
        :meth:`~lodsprite.distributed.datasets.Datasets.local_message`)."""
        return message if self.datasets is None else self.datasets.local_message(message)

    def _apply(self, session: Session, named: LoadArgs, resolved: LoadArgs, gen: int) -> None:
        """Make ``resolved`` the session's scene (generation ``gen``): its waiting and
        in-flight requests, all of the old scene, are forgotten by the session (a worker
        still rendering one stays busy in :attr:`jobs`; its result is dropped)."""
        old = session.named
        session.load = resolved
        session.named = named  # jobs carry the names: each worker resolves them by its --data
        if old is not None and job_key(old) != job_key(named):
            self.forget(old)
        session.generation = gen
        session.pending.clear()
        session.inflight.clear()

    def path(self, session: Session, args: PathArgs, seq: int) -> None:
        """Answer ``path`` for ``session`` (later, from a thread); one at a time."""
        if session.load is None:
            session.reply(seq, False, "path: load a scene first")
            return
        if session.path_busy:
            session.reply(seq, False, "path: another path of this session is being computed")
            return
        session.path_busy = True
        task = asyncio.get_running_loop().create_task(self._path(session, args, seq))
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _path(self, session: Session, args: PathArgs, seq: int) -> None:
        load = session.load
        try:
            async with self._builds:  # server-wide: as scene builds
                cached = self._scenes.get(scene_key(load))
                hf = cached[1] if cached is not None else None
                root = self.datasets.data_dir
                data = await asyncio.to_thread(path_data, load, args, hf,
                                               None if root is None else str(root))
        except (LodspriteError, MemoryError, OSError, ValueError) as exc:
            session.reply(seq, False, self._local(f"path: {exc}"))
            return
        finally:
            session.path_busy = False
        if not session.closed:
            session.reply(seq, True, data=data)

    def _resolve(self, args: LoadArgs) -> LoadArgs:
        """``args`` with the terrain and texture resolved to loader specs (a scene file:
        its absolute path inside the data folder); raises :class:`InputError` for a name,
        a size or a scene this server refuses, and for a scene of a kind the page does not
        draw (a light field, a plug-in's: the page draws terrains, scene files and
        crowds)."""
        named = self.datasets.scene(args.terrain)  # confined to the data folder, capped
        if named.kind in OBJECT_KINDS:
            if args.lod > MAX_SCENE_COARSE:
                raise InputError(f"lod {args.lod}: at most {MAX_SCENE_COARSE} for a web page")
            resolved = msgspec.structs.replace(args, terrain=named.spec)
            if named.terrain is not None:  # its terrain held to this machine's memory
                reason = check_scene_memory(
                    msgspec.structs.replace(args, terrain=named.terrain.spec),
                    named.terrain.shape, None)
                if reason is not None:
                    raise InputError(reason)
            return resolved
        if named.kind is not None or named.terrain is None:
            raise InputError(f"{args.terrain!r} is a {named.kind} scene: a page draws "
                             "terrains, scene files and crowds (open it with lodsprite "
                             "view or render)")
        terrain = named.terrain
        texture = self.datasets.texture(args.texture)
        grid = working_grid(args)
        if args.lod > grid:
            raise InputError(f"lod {args.lod} exceeds the working grid {grid}")
        if args.lod > MAX_SCENE_COARSE:
            raise InputError(f"lod {args.lod}: at most {MAX_SCENE_COARSE} for a web page")
        reason = check_scene_memory(args, terrain.shape, texture.shape)
        if reason is not None:
            raise InputError(reason)
        return msgspec.structs.replace(args, terrain=terrain.spec, texture=texture.spec)

    # ------------------------------------------------------------------ scheduling

    def schedule(self) -> None:
        """Hand waiting requests to free workers, one session at a time in turn."""
        free = self.workers_count() - len(self.jobs)
        order = list(self.sessions.values())
        while free > 0 and order:
            n = len(order)
            for i in range(n):
                s = order[(self._turn + i) % n]
                if s.pending and len(s.inflight) < self.caps.session_jobs and s.named:
                    self._turn = (self._turn + i + 1) % n
                    self._submit(s, s.pending.popleft())
                    free -= 1
                    break
            else:
                return

    def _submit(self, s: Session, p: Pending) -> None:
        job = next(self._ids)
        try:
            self.pool.submit(Job(job, s.id, s.named, p.viewpoint, p.t))
        except LodspriteError as exc:  # the pool refused the job: the page hears why
            s.counts["failed"] += 1
            s.reply(p.seq, False, f"request: {exc}")
            return
        s.inflight[job] = p
        self.jobs[job] = (s, p, time.monotonic())
        p.generation = s.generation

    def drain(self) -> None:
        """Take the pool's results to their sessions; never raises."""
        try:
            results = self.pool.poll()
        except Exception as exc:  # noqa: BLE001 - a broken pool must not stop the loop
            log.error("render pool: %r", exc)
            return
        for r in results:
            entry = self.jobs.pop(r.job, None)
            if entry is None:
                continue  # expired, or its session closed
            s, p, _ = entry
            s.inflight.pop(r.job, None)
            if s.closed:
                continue
            if p.generation != s.generation:
                s.counts["stale"] += 1  # a keyframe of the scene the page left
                continue
            if not r.ok:
                s.counts["failed"] += 1
                s.reply(p.seq, False, self._local(f"render: {r.error}"),
                        {"code": r.code or "failed"})
                continue
            try:
                s.push_keyframe(_restamp(r.parts, p), p)
            except ProtocolError as exc:
                s.counts["failed"] += 1
                s.reply(p.seq, False, self._local(f"render: {exc}"))
        self.schedule()

    def _expire(self) -> None:
        now = time.monotonic()
        for job, (s, _, start) in list(self.jobs.items()):
            if now - start > self.job_timeout_s or s.closed:
                del self.jobs[job]
                s.inflight.pop(job, None)
                s.counts["failed"] += 0 if s.closed else 1
        self.schedule()


def _restamp(parts: list, p: Pending) -> list:
    """The keyframe message ``parts`` with ``seq`` and ``t0`` of the request ``p``."""
    msg, _ = decode_message(parts, KeyframeMessage)
    return [*encode(msgspec.structs.replace(msg, seq=p.seq, t0=p.t)), *parts[1:]]
