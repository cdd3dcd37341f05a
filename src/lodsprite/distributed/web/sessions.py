"""One web page's session: its messages in, its replies and keyframes out.

Every WebSocket message is hostile until :func:`~lodsprite.distributed.web.wire.decode_web`
has validated it; :meth:`Session.handle` never raises: a message over the rate cap is
dropped and counted (``rate_dropped``), a malformed one is counted (``rejected``) and
answered ``ok: false`` with the reason.  ``load`` goes to the hub (which resolves the
dataset and sends the ``scene``), ``request`` waits in :attr:`Session.pending` (at most
``session_jobs`` requests: a newer one pushes out the oldest, counted ``superseded``)
until the hub's round robin hands it to a renderer.

Out: replies and scenes wait in a queue of :data:`MAX_REPLIES` (oldest dropped,
``replies_dropped``); at most one scene waits there (a newer one replaces it,
``scenes_replaced``), queued as the hub's cached parts, not a copy: it is joined into one
WebSocket message (in a thread) only when its turn to be sent comes.  Keyframes wait in
one of ``queue`` keyframes (default 2): when it is full the OLDEST queued keyframe is
dropped (``keyframes_dropped``), so a page always gets the newest.  One writer task per
session sends them (:meth:`Session.run_writer`); a page that stops reading blocks only its
own writer (aiohttp waits for the socket to drain), never the event loop or another
session; a send that takes over :data:`SEND_TIMEOUT_S`
closes that session.
"""

from __future__ import annotations

import asyncio
import logging
import secrets
import time
from collections import deque
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from lodsprite.distributed.protocol import (
    Ack,
    Control,
    ProtocolError,
    Request,
    ViewpointMessage,
    viewpoint_from_wire,
)
from lodsprite.distributed.web.security import RateLimit
from lodsprite.distributed.web.wire import MAX_PARTS, decode_web, pack, pack_message

if TYPE_CHECKING:
    from lodsprite.distributed.protocol import LoadArgs, WireViewpoint

log = logging.getLogger("lodsprite.web")

__all__ = ["COUNTS", "MAX_REPLIES", "SEND_TIMEOUT_S", "Caps", "Session"]

MAX_REPLIES = 64
"""Replies (and scenes) a session's outbound queue holds."""
SEND_TIMEOUT_S = 20.0
"""A send that waits longer for the page to read closes the session."""
MAX_LATENCIES = 1000
COUNTS = ("received", "rejected", "rate_dropped", "requests", "superseded", "keyframes_sent",
          "keyframes_dropped", "failed", "replies_dropped", "viewpoints", "acks", "internal",
          "stale", "scenes_replaced")


@dataclass(frozen=True)
class Caps:
    """Per-session limits: keyframe jobs in flight (the page keeps as many requests in
    flight, spread over its latency), keyframes queued out, messages/s."""

    session_jobs: int = 1
    queue: int = 2
    rate: float = 240.0


@dataclass
class Pending:
    """A request waiting for (or in) a render: the page's ``seq``, ``t`` and viewpoint,
    and when it arrived (server monotonic clock, s)."""

    seq: int
    t: float
    viewpoint: WireViewpoint
    arrived: float
    generation: int = 0
    """The session's load generation when it was handed to the pool."""


class Session:
    """The state of one WebSocket.  ``hub`` is the server core
    (:class:`~lodsprite.distributed.web.hub.Hub`): ``load(session, args, seq)``,
    ``schedule()``, ``summary()``."""

    def __init__(self, hub: Any, caps: Caps | None = None, sid: str | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.id = sid or secrets.token_hex(8)
        self.hub = hub
        self.caps = caps or Caps()
        self.clock = clock
        self.load: LoadArgs | None = None  # resolved (loader specs), after a good load
        self.named: LoadArgs | None = None  # the same as the page named it (for workers)
        self.generation = 0  # of the applied load (the hub's count)
        self.path_busy = False  # a path is being computed
        self.pending: deque[Pending] = deque()
        self.inflight: dict[int, Pending] = {}
        self.counts = dict.fromkeys(COUNTS, 0)
        self.latencies: deque[float] = deque(maxlen=MAX_LATENCIES)
        self.closed = False
        self._rate = RateLimit(self.caps.rate, clock)
        self._replies: deque[bytes | list] = deque()  # a list: a scene's parts
        self._keyframes: deque[tuple[list, float]] = deque()  # parts, arrived
        self._wake = asyncio.Event()
        self._said: set[str] = set()

    # ------------------------------------------------------------------------ in

    def handle(self, data: Any) -> None:
        """Take one WebSocket message (its payload); never raises."""
        try:
            self.counts["received"] += 1
            if not self._rate.allow():
                self.counts["rate_dropped"] += 1
                return
            try:
                msg, _ = decode_web(data)
            except ProtocolError as exc:
                self.counts["rejected"] += 1
                self._once("rejected", "session %s: rejected a message: %s", exc)
                self.reply(0, False, str(exc))
                return
            self._dispatch(msg)
        except Exception as exc:  # a bug must not stop the server: count it, go on
            self.counts["internal"] += 1
            self._once(f"internal:{type(exc).__name__}",
                       "session %s: internal error handling a message: %r", exc, logging.ERROR)

    def _dispatch(self, msg: Any) -> None:
        if isinstance(msg, Request):
            self._request(msg)
        elif isinstance(msg, Control):
            self._control(msg)
        elif isinstance(msg, ViewpointMessage):
            self.counts["viewpoints"] += 1
        elif isinstance(msg, Ack):
            self.counts["acks"] += 1

    def _request(self, msg: Request) -> None:
        self.counts["requests"] += 1
        if self.load is None:
            self.reply(msg.seq, False, "request: load a scene first")
            return
        try:
            viewpoint_from_wire(msg.viewpoint)  # axes orthonormal: checked before a render
        except ProtocolError as exc:
            self.counts["rejected"] += 1
            self.reply(msg.seq, False, f"request: {exc}")
            return
        if len(self.pending) >= self.caps.session_jobs:
            self.pending.popleft()
            self.counts["superseded"] += 1
        self.pending.append(Pending(msg.seq, msg.t, msg.viewpoint, self.clock()))
        self.hub.schedule()

    def _control(self, msg: Control) -> None:
        op = msg.op
        if op == "load":
            self.hub.load(self, msg.args, msg.seq)
        elif op == "ping":
            self.reply(msg.seq, True, data={"loaded": self.load is not None,
                                            "session": self.id,
                                            "workers": self.hub.workers_count()})
        elif op == "stats":
            self.reply(msg.seq, True, data={"session": self.stats(),
                                            "server": self.hub.summary()})
        elif op == "path":
            self.hub.path(self, msg.args, msg.seq)
        elif op == "shutdown":
            self.reply(msg.seq, False, "shutdown: a web page cannot stop the server")
        else:  # start, stop: keyframes come only for requests; release drops the scene
            if op in ("stop", "release"):
                self.pending.clear()
            if op == "release":
                named, self.load, self.named = self.named, None, None
                self.hub.forget(named)
            self.reply(msg.seq, True)

    # ------------------------------------------------------------------------ out

    def reply(self, seq: int, ok: bool, error: str = "", data: dict | None = None) -> None:
        """Queue a ``reply`` message."""
        self.push_reply(pack_message({"kind": "reply", "seq": seq, "ok": ok,
                                      "error": error[:4000], "data": data or {}}))

    def push_reply(self, data: bytes | list) -> None:
        """Queue a reply (or :meth:`push_scene`'s parts; bounded: the oldest is dropped)."""
        if len(self._replies) >= MAX_REPLIES:
            self._replies.popleft()
            self.counts["replies_dropped"] += 1
        self._replies.append(data)
        self._wake.set()

    def push_scene(self, parts: list) -> None:
        """Queue a scene message's ``parts`` (kept, not copied); an older scene still
        waiting is dropped."""
        for i, item in enumerate(self._replies):
            if isinstance(item, list):
                del self._replies[i]
                self.counts["scenes_replaced"] += 1
                break
        self.push_reply(parts)

    def push_keyframe(self, parts: list, pending: Pending) -> None:
        """Queue a keyframe (its message parts, kept: joined when sent) answering
        ``pending``; when the queue is full the oldest queued keyframe is dropped.  Raises
        :class:`ProtocolError` for more parts than a web message has."""
        if not 1 <= len(parts) <= MAX_PARTS:
            raise ProtocolError(f"{len(parts)} parts: a web message has 1..{MAX_PARTS}")
        if len(self._keyframes) >= self.caps.queue:
            self._keyframes.popleft()
            self.counts["keyframes_dropped"] += 1
        self._keyframes.append((parts, pending.arrived))
        self._wake.set()

    def close(self) -> None:
        self.closed = True
        self.pending.clear()
        self._wake.set()

    async def run_writer(self, send: Callable[[bytes], Awaitable[None]]) -> None:
        """Send what is queued, replies first, until :meth:`close`; raises
        :class:`TimeoutError` when a send waits over :data:`SEND_TIMEOUT_S`."""
        while not self.closed:
            await self._wake.wait()
            self._wake.clear()
            while not self.closed and (self._replies or self._keyframes):
                if self._replies:
                    data = await _joined(self._replies.popleft())
                    await asyncio.wait_for(send(data), SEND_TIMEOUT_S)
                    continue
                parts, arrived = self._keyframes.popleft()
                await asyncio.wait_for(send(await _joined(parts)), SEND_TIMEOUT_S)
                self.counts["keyframes_sent"] += 1
                self.latencies.append((self.clock() - arrived) * 1e3)

    # --------------------------------------------------------------------- stats

    def stats(self) -> dict:
        """Counts (:data:`COUNTS`), keyframe latency (request in -> keyframe sent, ms:
        median and p99 of the last 1000), requests waiting and in flight, the scene loaded
        (``scene``: its name as the page gave it; ``keyframes``: drawn ``adaptive`` or
        ``whole``; None before a load)."""
        from lodsprite.distributed.render import keyframe_kind

        lat = np.asarray(self.latencies, dtype=np.float64)
        return {**self.counts, "pending": len(self.pending), "inflight": len(self.inflight),
                "queued": len(self._keyframes), "loaded": self.load is not None,
                "scene": self.named.terrain if self.named is not None else None,
                "keyframes": keyframe_kind(self.load) if self.load is not None else None,
                "latency_ms_p50": float(np.median(lat)) if lat.size else None,
                "latency_ms_p99": float(np.percentile(lat, 99)) if lat.size else None}

    def _once(self, key: str, fmt: str, arg: Any, level: int = logging.WARNING) -> None:
        if key not in self._said:  # said once per kind of trouble, not per message
            self._said.add(key)
            log.log(level, fmt, self.id, arg)


async def _joined(item: bytes | list) -> bytes:
    """A queued item as one web message: a scene's or keyframe's parts are joined in a
    thread (megabytes: never a copy on the event loop), a reply is already bytes."""
    return await asyncio.to_thread(pack, item) if isinstance(item, list) else item
