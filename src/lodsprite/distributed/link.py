"""The client's connection to one LOD server: three sockets and the control requests.

CLIENT-CONTROL (Swan et al. 2002, §3.2) keeps each server loaded with the client's scene
and started (:func:`keep_loaded`); :class:`ServerLink` owns the sockets.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Iterator

import zmq

from lodsprite.distributed.keys import ClientKeys
from lodsprite.distributed.protocol import ProtocolError, decode, encode
from lodsprite.distributed.server import endpoints

log = logging.getLogger("lodsprite.client")

CONTROL_TIMEOUT_MS = 1000


class ServerLink:
    """The client's three sockets to one server."""

    def __init__(self, ctx: zmq.Context, address: str, keys: ClientKeys | None = None) -> None:
        self.address = address
        self.keys = keys
        self.control_ep, self.viewpoint_ep, self.keyframe_ep = endpoints(address, bind=False)
        self.ctx = ctx
        self.viewpoint = self._socket(zmq.PUB)
        self.viewpoint.setsockopt(zmq.SNDHWM, 1)
        self.viewpoint.connect(self.viewpoint_ep)
        self.keyframes = self._socket(zmq.DEALER)
        self.keyframes.connect(self.keyframe_ep)
        self.control: zmq.Socket | None = None
        self.last_seq = 0
        self.loaded = False
        self.alive: bool | None = None  # None until the first ping is answered or not
        self.refusal: str | None = None  # the server's reason for refusing the last load
        self.closed = False
        self.lock = threading.Lock()  # the control socket moves between threads

    def _socket(self, kind: int) -> zmq.Socket:
        sock = self.ctx.socket(kind)
        if self.keys is not None:
            self.keys.apply(sock)
        return sock

    def request(self, header: dict) -> dict | None:
        """Send a control message; the reply header, or None if the server did not answer
        (the REQ socket is then replaced, as a REQ cannot send twice in a row)."""
        with self.lock:
            return self._request(header)

    def _request(self, header: dict) -> dict | None:
        if self.closed:  # never open a socket after close(): the context could not end
            return None
        if self.control is None:
            self.control = self._socket(zmq.REQ)
            self.control.setsockopt(zmq.LINGER, 0)
            self.control.connect(self.control_ep)
        self.control.send_multipart(encode(header))
        if self.control.poll(CONTROL_TIMEOUT_MS):
            try:
                return decode(self.control.recv_multipart())[0]
            except ProtocolError as exc:
                log.warning("rejected control reply from %s: %s", self.address, exc)
                return None
        self.control.close(linger=0)
        self.control = None
        return None

    def close(self) -> None:
        """Close the sockets; later requests answer None at once (thread-safe)."""
        with self.lock:
            self.closed = True
            for s in (self.viewpoint, self.keyframes, self.control):
                if s is not None:
                    s.close(linger=0)
            self.control = None


def control(link: ServerLink, counter: Iterator[int], op: str,
            args: dict | None = None) -> dict | None:
    """Send the control request ``op`` to one server; its reply header, or None."""
    return link.request({"kind": "control", "seq": next(counter), "op": op,
                         "args": args or {}})


def keep_loaded(link: ServerLink, load_args: dict, counter: Iterator[int]) -> None:
    """One CLIENT-CONTROL round for one server: ping it; load the scene and start it when
    it has none, is not running, or an earlier load or start got no answer (a server
    busy starting up may have lost it).  Sets ``link.alive`` and ``link.loaded``."""
    reply = control(link, counter, "ping")
    link.alive = reply is not None
    if reply is None:
        link.loaded = False
        return
    data = reply.get("data", {})
    if link.loaded and data.get("running") and data.get("loaded"):
        return
    link.last_seq = 0  # a restarted server counts from 1 again
    replies = [control(link, counter, "load", load_args), control(link, counter, "start")]
    link.loaded = all(r is not None and r.get("ok") for r in replies)
    refusal = replies[0].get("error") if replies[0] and not replies[0].get("ok") else None
    if refusal and refusal != link.refusal:
        log.warning("%s refused the scene: %s", link.address, refusal)
    link.refusal = refusal
