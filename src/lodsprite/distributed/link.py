"""The client's connection to one LOD server: three sockets and the control requests.

CLIENT-CONTROL (Swan et al. 2002, §3.2) keeps each server loaded with the client's scene
and started (:func:`keep_loaded_steps`); :class:`ServerLink` owns the sockets.  The client
drives it from its frame's thread, sending each request and collecting its reply without
waiting (:class:`LinkKeeper`): no thread beside the draws (moderngl holds the GIL through
each draw call, and a thread there waits for every draw to end).  :func:`keep_loaded`
runs one round blocking, for tools and tests.

Each link has a random client id (16 hex digits): it travels in every control and
viewpoint message, and it is the ZeroMQ identity of the link's keyframe socket, so that
the server (one client holds it at a time, :mod:`.server`) sends keyframes to this
client only.  Every socket has a ``zmq.MAXMSGSIZE``.
"""

from __future__ import annotations

import logging
import secrets
import time
from collections.abc import Callable, Generator, Iterator

import zmq

from lodsprite.distributed.keys import ClientKeys
from lodsprite.distributed.protocol import (
    MAX_CONTROL_BYTES,
    MAX_KEYFRAME_FRAME_BYTES,
    MAX_REPLY_BYTES,
    ProtocolError,
    decode,
    encode,
)
from lodsprite.distributed.server import endpoints

log = logging.getLogger("lodsprite.client")

CONTROL_TIMEOUT_MS = 1000
RELEASE_TIMEOUT_MS = 300
KEYFRAME_RCVHWM = 4
"""Keyframe messages the link's keyframe socket queues; the server holds the rest."""
ACK_SNDHWM = 16
"""Acknowledgements queued for a server; more are dropped (the server reads none)."""
RETRY_FIRST_S = 2.0
"""Wait before loading again a scene that failed on the server; doubled after each
failure, up to :data:`RETRY_MAX_S`."""
RETRY_MAX_S = 60.0


def new_client_id() -> str:
    """A random client id: 16 lowercase hex digits."""
    return secrets.token_hex(8)


class ServerLink:
    """The client's three sockets to one server; ``client_id`` (default: a new random
    one) names the client in its messages and is its keyframe socket's identity."""

    def __init__(self, ctx: zmq.Context, address: str, keys: ClientKeys | None = None,
                 client_id: str | None = None) -> None:
        self.address = address
        self.keys = keys
        self.client_id = client_id or new_client_id()
        self.control_ep, self.viewpoint_ep, self.keyframe_ep = endpoints(address, bind=False)
        self.ctx = ctx
        self.viewpoint = self._socket(zmq.PUB, MAX_CONTROL_BYTES)
        self.viewpoint.setsockopt(zmq.SNDHWM, 1)
        self.viewpoint.connect(self.viewpoint_ep)
        self.keyframes = self._socket(zmq.DEALER, MAX_KEYFRAME_FRAME_BYTES)
        self.keyframes.setsockopt(zmq.IDENTITY, self.client_id.encode())
        # Bounded both ways: a few keyframes waiting (the server holds the rest), and
        # acknowledgements that a server does not read are dropped, never waited for.
        self.keyframes.setsockopt(zmq.RCVHWM, KEYFRAME_RCVHWM)
        self.keyframes.setsockopt(zmq.SNDHWM, ACK_SNDHWM)
        self.keyframes.setsockopt(zmq.LINGER, 0)
        self.keyframes.connect(self.keyframe_ep)
        self.control: zmq.Socket | None = None
        self.last_seq = 0
        self.taken = 0  # keyframes taken from this server (the client's receiver counts)
        self.taken_at_load = 0  # ... when the scene was last sent
        self.last_taken = 0.0  # time.monotonic() when a keyframe was last taken
        self.failure: str | None = None  # the server's error for the scene, said once
        self.retry_at: float | None = None  # when to send a failed scene again
        self.retry_s = RETRY_FIRST_S  # the wait before the next reload of a failed scene
        self.loaded = False
        self.alive: bool | None = None  # None until the first ping is answered or not
        self.refusal: str | None = None  # the server's reason for refusing the last load
        self.closed = False
        self._asked: float | None = None  # deadline of the request :meth:`ask` sent
        self._done: tuple[bool, dict | None] | None = None  # its outcome, if taken early

    def _socket(self, kind: int, max_bytes: int) -> zmq.Socket:
        sock = self.ctx.socket(kind)
        sock.setsockopt(zmq.MAXMSGSIZE, max_bytes)
        if self.keys is not None:
            self.keys.apply(sock)
        return sock

    def ask(self, header: dict, timeout_ms: int = CONTROL_TIMEOUT_MS) -> None:
        """Send a control message (this client's id added) without waiting; its reply
        comes from :meth:`answer`."""
        if self._asked is not None:  # a request not answered yet is given up
            self._drop_control()
        self._done = None
        if self.closed:  # never open a socket after close(): the context could not end
            self._done = (True, None)
            return
        if self.control is None:
            self.control = self._socket(zmq.REQ, MAX_REPLY_BYTES)
            self.control.setsockopt(zmq.LINGER, 0)
            self.control.connect(self.control_ep)
        try:
            self.control.send_multipart(encode({**header, "client": self.client_id}),
                                        flags=zmq.NOBLOCK)
        except zmq.Again:
            self._drop_control()
            self._done = (True, None)
            return
        self._asked = time.monotonic() + timeout_ms / 1e3

    def answer(self) -> tuple[bool, dict | None]:
        """Never waits: ``(False, None)`` while the request :meth:`ask` sent awaits its
        reply, then ``(True, reply header)``, or ``(True, None)`` when the server did not
        answer in time (the REQ socket is then replaced, as a REQ cannot send twice in a
        row)."""
        if self._done is not None:
            out, self._done = self._done, None
            return out
        if self._asked is None:
            return True, None
        if self.control.poll(0):
            self._asked = None
            try:
                return True, decode(self.control.recv_multipart())[0]
            except ProtocolError as exc:
                log.warning("rejected control reply from %s: %s", self.address, exc)
                return True, None
        if time.monotonic() >= self._asked:
            self._drop_control()
            return True, None
        return False, None

    def _finish_asked(self) -> None:
        """Wait for the reply of the request :meth:`ask` sent, keeping it for
        :meth:`answer` (a blocking request must not take it)."""
        remaining = max(0, int((self._asked - time.monotonic()) * 1e3))
        if self.control is not None:
            self.control.poll(remaining)
        done, reply = self.answer()
        self._done = (True, reply if done else None)
        if not done:
            self._drop_control()

    def _drop_control(self) -> None:
        if self.control is not None:
            self.control.close(linger=0)
        self.control = None
        self._asked = None

    def request(self, header: dict, timeout_ms: int = CONTROL_TIMEOUT_MS) -> dict | None:
        """Send a control message (this client's id added) and wait for the reply header,
        or None if the server did not answer (the REQ socket is then replaced)."""
        pending = None
        if self._asked is not None:  # the frame's CLIENT-CONTROL awaits a reply: first
            self._finish_asked()
            pending = self._done
        self.ask(header, timeout_ms)
        if self._asked is not None and self.control is not None:
            self.control.poll(timeout_ms)
        done, reply = self.answer()
        if not done:
            self._drop_control()
            reply = None
        self._done = pending  # the outcome the frame's CLIENT-CONTROL has not taken yet
        return reply

    def send_viewpoint(self, header: dict) -> None:
        """Publish a viewpoint message (this client's id added); never blocks."""
        try:
            self.viewpoint.send_multipart(encode({**header, "client": self.client_id}),
                                          flags=zmq.NOBLOCK)
        except zmq.Again:
            pass

    def close(self, release: bool = True) -> None:
        """Close the sockets; later requests answer None at once.  With
        ``release`` a server this link loaded is told first (briefly), so that another
        client may take it at once rather than after the hold's lease.  A request the
        frame's CLIENT-CONTROL sent is given up."""
        if self._asked is not None:
            self._drop_control()
        if release and self.loaded and self.alive and not self.closed:
            self.request({"kind": "control", "seq": 0, "op": "release", "args": {}},
                         RELEASE_TIMEOUT_MS)
        self.closed = True
        for s in (self.viewpoint, self.keyframes, self.control):
            if s is not None:
                s.close(linger=0)
        self.control, self._asked = None, None


def control(link: ServerLink, counter: Iterator[int], op: str,
            args: dict | None = None) -> dict | None:
    """Send the control request ``op`` to one server; its reply header, or None."""
    return link.request(_header(counter, op, args))


def _header(counter: Iterator[int], op: str, args: dict | None = None) -> dict:
    return {"kind": "control", "seq": next(counter), "op": op, "args": args or {}}


def keep_loaded(link: ServerLink, load_args: dict, counter: Iterator[int],
                now: Callable[[], float] = time.monotonic) -> None:
    """One CLIENT-CONTROL round (:func:`keep_loaded_steps`), each request waiting for its
    reply."""
    steps = keep_loaded_steps(link, load_args, counter, now)
    try:
        header = next(steps)
        while True:
            header = steps.send(link.request(header))
    except StopIteration:
        pass


def keep_loaded_steps(link: ServerLink, load_args: dict, counter: Iterator[int],
                      now: Callable[[], float] = time.monotonic
                      ) -> Generator[dict, dict | None, None]:
    """One CLIENT-CONTROL round for one server, as a generator that yields each control
    request's header and is sent its reply header (None: no answer): ping it; load the
    scene and start it when this client does not hold it (another client's hold lapsed
    or was released, or the server restarted), it is not running, or an earlier load or
    start got no answer (a server busy starting up may have lost it).  A scene that
    failed on the server (to load or to render) is loaded again after
    :data:`RETRY_FIRST_S`, then after twice as long each time it fails again, up to
    :data:`RETRY_MAX_S`, until a keyframe arrives: a passing failure heals, a lasting one
    costs a load a minute.  Its error is said once.  Sets ``link.alive`` and
    ``link.loaded``.  ``now``: the clock of the retries (seconds)."""
    reply = yield _header(counter, "ping")
    link.alive = reply is not None
    if reply is None:
        link.loaded = False
        return
    data = reply.get("data", {})
    if not isinstance(data, dict):
        data = {}
    yours = data.get("yours", True) is True  # servers before protocol 3 have no holds
    if link.taken > link.taken_at_load:  # keyframes came since the last load: it works
        link.retry_s, link.failure = RETRY_FIRST_S, None
    if link.loaded and yours and data.get("state") == "failed":
        error = str(data.get("error", ""))
        if error != link.failure:
            log.warning("%s could not load or render the scene: %s (loading it again in "
                        "%.0f s, then less often while it fails)", link.address, error,
                        link.retry_s)
            link.failure = error
        if link.retry_at is None:  # this failure's reload is not scheduled yet
            link.retry_at = now() + link.retry_s
            link.retry_s = min(2 * link.retry_s, RETRY_MAX_S)
        if now() < link.retry_at:
            return
    elif link.loaded and yours and data.get("running") and data.get("loaded"):
        return
    link.retry_at, link.taken_at_load = None, link.taken
    link.last_seq = 0  # a restarted server counts from 1 again
    replies = [(yield _header(counter, "load", load_args)), (yield _header(counter, "start"))]
    # Loaded once the load was accepted and the start answered: a start refused because
    # the scene failed meanwhile leaves the reload to the backoff above.
    link.loaded = bool(replies[0] is not None and replies[0].get("ok")
                       and replies[1] is not None)
    refusal = replies[0].get("error") if replies[0] and not replies[0].get("ok") else None
    if refusal and refusal != link.refusal:
        log.warning("%s refused the scene: %s", link.address, refusal)
    link.refusal = refusal


class LinkKeeper:
    """CLIENT-CONTROL for one link, driven by :meth:`step` from the frame's thread: a round
    of :func:`keep_loaded_steps` every ``period_s`` seconds, each request sent and its
    reply collected without waiting."""

    def __init__(self, link: ServerLink, load_args: dict, counter: Iterator[int],
                 period_s: float = 1.0) -> None:
        self.link, self.load_args, self.counter = link, load_args, counter
        self.period_s = float(period_s)
        self._steps: Generator[dict, dict | None, None] | None = None
        self._next = 0.0  # time.monotonic() of the next round

    def step(self) -> None:
        """Go on with the round (never waits): start one when it is due, or hand the
        request in flight its reply once it has come (or timed out)."""
        if self._steps is None:
            if time.monotonic() < self._next:
                return
            self._steps = keep_loaded_steps(self.link, self.load_args, self.counter)
            self._advance(None)
            return
        done, reply = self.link.answer()
        if done:
            self._advance(reply)

    def _advance(self, reply: dict | None) -> None:
        """Send ``reply`` to the round (None also starts it) and ask what it asks next."""
        try:
            header = self._steps.send(reply)
        except StopIteration:
            self._steps, self._next = None, time.monotonic() + self.period_s
            return
        self.link.ask(header)
