"""The render pool on Ray (``serve --web --ray ADDRESS``): renderers as Ray actors
(:class:`~.ray_actor.RenderActor`) on the machines of a Ray cluster, behind the interface
of the local pool (:class:`~.local_pool.LocalPool`: :meth:`RayPool.submit`, :meth:`RayPool.poll`,
:meth:`RayPool.fileno`, :meth:`RayPool.workers`, :meth:`RayPool.stats`,
:meth:`RayPool.close`), so the web hub keeps its policy (newest request wins, fairness
among sessions) and the pool keeps the dispatch one (:class:`~.dispatch.JobTable`: scene
affinity, refusals with a code, a job given up after :data:`~.dispatch.MAX_TRIES`).

What Ray does: placement of the actors (one CPU each, ``gpus_per_renderer`` GPUs), their
liveness, restarts of a dead actor (``max_restarts=-1``), transport of jobs and of
keyframes (megabytes: inline in the reply up to Ray's ``max_direct_call_object_size``,
else through its object store), its dashboard and logs.  What stays here: the job of an
actor that died goes back to the front of the queue (Ray's own task retries are off:
they would wait for that actor's restart, where another renderer may be free now), the
restarted actor joins again once it answers :meth:`~.ray_actor.RenderActor.ready`, and a
job past ``job_timeout_s`` has its actor killed (Ray restarts it).

An asyncio loop owns the table and awaits the actors' replies: the web hub's own loop
(:meth:`RayPool.start`, called by the hub: a job goes from the hub to Ray and its
keyframe back with no hop between threads of the server process, each of which waits
for the GIL under load), else a thread of the pool's own.  :meth:`RayPool.submit` and
:meth:`RayPool.poll` never block (a pipe wakes the caller's loop, as the local pool's).
Ray is imported here only when a pool is made: :func:`require_ray` names the ``ray``
extra in one line where it is not installed.
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from pathlib import Path
from types import ModuleType
from typing import Any

import msgspec

from lodsprite.distributed.pool.dispatch import JOB_TIMEOUT_S, Key
from lodsprite.distributed.pool.jobs import (
    POOL_VERSION,
    Job,
    JobMessage,
    Ready,
    ResultMessage,
    check_job,
    decode_pool,
)
from lodsprite.distributed.pool.results import PoolResults
from lodsprite.distributed.protocol import CODECS, ProtocolError
from lodsprite.errors import InputError, LodspriteError
from lodsprite.terrain.remote import data_root

log = logging.getLogger("lodsprite.pool")

__all__ = ["RAY_EXTRA", "RayPool", "check_address", "connect", "require_ray"]

RAY_EXTRA = "lodsprite[ray]"
INLINE_BYTES = 16 * 2**20
"""Replies up to this size travel inline with the call's answer (Ray's
``max_direct_call_object_size``, set where this process starts Ray: ``--ray local``)
rather than through the object store: a 256² keyframe's dispatch overhead drops from
3.6 ms to 2.4 ms on a 2-core machine (``benchmarks/pool_overhead.py``)."""
TICK_S = 0.25
"""How often the pool looks for jobs past their timeout (s)."""
CONNECT_S = 5.0
"""How long a Ray head's address may take to accept a connection (s)."""
REJOIN_S = 0.1
REJOIN_DEADLINE_S = 120.0
"""How long a renderer may take to come back from a restart before it is left out."""
"""Pause between ``ready`` calls to a restarting actor (s)."""


def require_ray() -> ModuleType:
    """The ``ray`` module, or :class:`InputError` naming the extra that installs it."""
    try:
        import ray
    except ImportError:
        raise InputError(f"--ray needs Ray: pip install '{RAY_EXTRA}'") from None
    return ray


def connect(address: str, **init: Any) -> bool:
    """Join Ray at ``address`` (``auto``: the cluster running on this machine,
    ``ray://HOST:PORT``: a Ray Client server, ``HOST:PORT``: a head's GCS, ``local``: a
    Ray instance started here for this process) unless this process already has;
    ``init``: more ``ray.init`` arguments.  Whether it joined (and must leave);
    :class:`LodspriteError` when the cluster cannot be reached."""
    ray = require_ray()
    if ray.is_initialized():
        return False
    if address == "local":
        init.setdefault("_system_config", {"max_direct_call_object_size": INLINE_BYTES})
        address = None
    elif address != "auto":
        _check_reachable(address)
    init.setdefault("logging_level", logging.WARNING)
    try:
        ray.init(address=address, **init)
    except Exception as exc:  # noqa: BLE001 - Ray raises ConnectionError, ValueError, ...
        reason = " ".join(str(exc).split())[:300] or type(exc).__name__
        raise LodspriteError(f"--ray {address}: cannot join the Ray cluster: {reason}"
                             ) from None
    return True


def check_address(address: str) -> tuple[str, int] | None:
    """The head's (host, port) of a ``[ray://]HOST:PORT`` address, None for ``auto`` or
    ``local``; raises :class:`InputError` for anything else."""
    if address in ("auto", "local"):
        return None
    host, _, port = address.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise InputError(f"--ray must be auto, local, HOST:PORT or ray://HOST:PORT, "
                         f"got {address!r}")
    return host.strip("[]"), int(port)


def _check_reachable(address: str) -> None:
    """Refuse, in one line, a ``[ray://]HOST:PORT`` that takes no TCP connection within
    :data:`CONNECT_S` (Ray itself retries an unreachable head for minutes)."""
    import socket

    host, port = check_address(address)
    try:
        socket.create_connection((host, port), timeout=CONNECT_S).close()
    except OSError as exc:
        raise LodspriteError(f"--ray {address}: no Ray head answers there ({exc})") from None


class RayPool(PoolResults):
    """``renderers`` Ray actors rendering keyframes, with the local pool's interface.

    ``address``: see :func:`connect` (ignored when this process already joined Ray).
    ``data_dir``: the folder jobs may name, the same path on every node (None: built-ins
    only).  ``codec``: keyframe images ``raw`` or ``zlib``.  ``gpus_per_renderer``: GPUs
    Ray reserves for each actor (0: none).  ``cache``: scenes each actor keeps."""

    def __init__(self, address: str, renderers: int, data_dir: Path | str | None = None,
                 codec: str = "raw", gpus_per_renderer: float = 0.0, cache: int = 2,
                 job_timeout_s: float = JOB_TIMEOUT_S, **init: Any) -> None:
        if codec not in CODECS:
            raise InputError(f"unknown codec '{codec}': use {', '.join(CODECS)}")
        if not 1 <= renderers <= 4096:
            raise InputError(f"renderers must be 1..4096, got {renderers}")
        if gpus_per_renderer < 0:
            raise InputError(f"gpus per renderer must be >= 0, got {gpus_per_renderer}")
        self._ray = require_ray()
        self._joined = connect(address, **init)
        super().__init__(job_timeout_s)
        self.codec = codec
        self._closed = False
        self._of: dict[Key, int] = {}  # a joined renderer: its actor's index
        try:
            self._actors = self._start_actors(renderers, data_dir, cache, gpus_per_renderer)
        except BaseException:
            self._close_results()
            if self._joined:
                self._ray.shutdown()
            raise
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._owner = 0  # the id of the thread running the pool's loop
        self._tasks: set[asyncio.Task] = set()

    def start(self, loop: asyncio.AbstractEventLoop | None = None) -> None:
        """Run the pool on ``loop``, the running loop of the calling thread (the web
        hub's: its submit and poll then reach the pool without a hop between threads,
        each a wait for the GIL under load) or, with None, on a thread of its own.  A
        pool already started stays where it runs; :meth:`submit` and
        :meth:`wait_workers` start one that was not, on a thread of its own."""
        if self._loop is not None or self._closed:
            return
        if loop is None:
            self._loop = asyncio.new_event_loop()
            self._thread = threading.Thread(target=self._run, daemon=True, name="ray-pool")
            self._thread.start()
        else:
            self._loop, self._owner = loop, threading.get_ident()
            self._begin()

    def _start_actors(self, n: int, data_dir: Path | str | None, cache: int,
                      gpus: float) -> list:
        from lodsprite.distributed.pool.ray_actor import RenderActor

        actor = self._ray.remote(RenderActor).options(
            num_cpus=1, num_gpus=gpus, max_restarts=-1, max_task_retries=0,
            max_concurrency=1)
        folder = data_root(data_dir)
        return [actor.remote(folder, cache) for _ in range(n)]

    # ------------------------------------------------------------- the interface

    def submit(self, job: Job) -> None:
        """Queue ``job`` (never blocks; thread-safe)."""
        job = check_job(job)
        if self._closed:
            raise LodspriteError("the render pool is closed")
        if self._loop is None:
            self.start()
        if threading.get_ident() == self._owner:
            self._add(job)
        else:
            self._loop.call_soon_threadsafe(self._add, job)

    def wait_workers(self, n: int, timeout: float) -> bool:
        """Wait until at least ``n`` renderers have joined (at most ``timeout`` s; not
        from the thread of the pool's loop)."""
        if self._loop is None:
            self.start()
        return super().wait_workers(n, timeout)

    def actor_pids(self) -> dict[int, int]:
        """Each joined renderer's actor index: its process id."""
        return {i: int(key[1].split(b":")[1]) for key, i in dict(self._of).items()}

    def close(self) -> None:
        """Stop the loop, kill the actors (no restart), leave Ray if this pool joined it.
        Idempotent."""
        if self._closed:
            return
        self._closed = True
        if self._thread is not None:
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(timeout=5.0)
        elif self._loop is not None:
            try:
                self._loop.call_soon_threadsafe(self._cancel)
            except RuntimeError:
                pass  # the caller's loop is closed: its tasks went with it
        for actor in self._actors:
            try:
                self._ray.kill(actor, no_restart=True)
            except Exception as exc:  # noqa: BLE001 - gone already, or Ray gone
                log.debug("ray pool: kill: %r", exc)
        if self._joined:
            self._ray.shutdown()
        self._close_results()

    def __enter__(self) -> RayPool:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---------------------------------------------------------------- the loop

    def _run(self) -> None:
        asyncio.set_event_loop(self._loop)
        self._owner = threading.get_ident()
        self._begin()
        try:
            self._loop.run_forever()
        finally:
            self._cancel()
            self._loop.run_until_complete(asyncio.sleep(0))
            self._loop.close()

    def _begin(self) -> None:
        for i in range(len(self._actors)):
            self._spawn(self._join(i))
        self._spawn(self._tick())

    def _cancel(self) -> None:
        for task in list(self._tasks):
            task.cancel()

    def _spawn(self, coro) -> None:
        task = self._loop.create_task(coro)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    def _add(self, job: Job) -> None:
        self.table.add(job)
        self._dispatch()

    def _dispatch(self) -> None:
        if self._closed:
            return
        for key, entry in self.table.assign(time.monotonic()):
            self._spawn(self._render(key, entry.job))
        self._changed()

    async def _join(self, i: int, killed: int | None = None) -> None:
        """Wait for actor ``i`` to answer ``ready`` (through its restarts), then give it
        jobs; an actor Ray gave up on, or one without GL, is left out (logged).

        ``killed``: the pid of the process just killed; a ``ready`` it still answers (the
        kill is asynchronous) is not a join, or the next job would be lost with it."""
        ray = self._ray
        deadline = time.monotonic() + REJOIN_DEADLINE_S
        while True:
            try:
                info = await self._actors[i].ready.remote()
                if killed is None or info["pid"] != killed:
                    break
                if time.monotonic() > deadline:
                    log.error("ray pool: renderer %d left out: not restarted", i)
                    return
                await asyncio.sleep(REJOIN_S)
            except (ray.exceptions.ActorUnavailableError, ray.exceptions.RayActorError) as exc:
                # restarting (or the call reached the process being killed): Ray brings
                # it back (max_restarts=-1); left out only past the deadline
                if time.monotonic() > deadline:
                    log.error("ray pool: renderer %d left out: %s", i, _first_line(exc))
                    return
                await asyncio.sleep(REJOIN_S)
            except Exception as exc:  # noqa: BLE001 - no GL there, or Ray gone
                log.error("ray pool: renderer %d left out: %s", i, _first_line(exc))
                return
        key = (1, f"{i}:{info['pid']}".encode())
        gpus = f" gpu {','.join(info['gpus'])}" if info["gpus"] else ""
        name = f"ray-{i}@{info['host']}{gpus} ({info['gl']})"[:256]
        self._of[key] = i
        self.table.ready(key, Ready(POOL_VERSION, info["pid"], name), time.monotonic())
        log.info("ray pool: renderer %s joined", name)
        self._dispatch()

    async def _render(self, key: Key, job: Job) -> None:
        """Send ``job`` to ``key``'s actor and settle its answer; a dead actor is lost
        (its job back in front of the queue) and joins again after its restart."""
        i = self._of[key]
        msg = msgspec.msgpack.encode(JobMessage(POOL_VERSION, job, self.codec))
        try:
            frames = await self._actors[i].render.remote(msg)
            answer, parts = decode_pool(frames)
            if not isinstance(answer, ResultMessage):
                raise ProtocolError(f"a {type(answer).__name__} for a job")
            self.table.settle(key, answer, parts, time.monotonic())
        except self._ray.exceptions.RayActorError as exc:
            self._lose(key, f"died ({_first_line(exc)})", restart=False)
        except (ProtocolError, self._ray.exceptions.RayError) as exc:
            self._lose(key, f"answered badly ({_first_line(exc)})", restart=True)
        self._dispatch()

    def _lose(self, key: Key, why: str, restart: bool) -> None:
        """Forget renderer ``key`` (its job back in the queue) and wait for it to join
        again; ``restart``: kill its process first (Ray starts another)."""
        i = self._of.pop(key, None)
        if i is None or self._closed:
            return
        self.table.lose(key, why)
        killed = int(key[1].decode().split(":")[1]) if restart else None
        if restart:
            try:
                self._ray.kill(self._actors[i], no_restart=False)
            except Exception as exc:  # noqa: BLE001 - dead already, or Ray gone
                log.warning("ray pool: could not restart renderer %d: %s", i,
                            _first_line(exc))
        self._spawn(self._join(i, killed))

    async def _tick(self) -> None:
        while True:
            await asyncio.sleep(TICK_S)
            late = self.table.expired(time.monotonic())
            for key in late:  # a renderer stuck on a job: restarted by Ray
                self._lose(key, "timed out", restart=True)
            if late:
                self._dispatch()


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return (text[0] if text else type(exc).__name__)[:300]

