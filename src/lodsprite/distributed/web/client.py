"""A web page's side of the wire in Python: what tests and load benchmarks use to act as
pages (``benchmarks/web_load.py``'s simulated clients), over an aiohttp WebSocket.

:class:`WebPage` sends typed messages (:mod:`.wire`) and decodes what comes back with the
protocol: :meth:`WebPage.load` returns the :class:`~.scene.SceneData`, :meth:`WebPage.keyframe`
a :class:`~lodsprite.distributed.protocol.Keyframe` answering a request, :meth:`WebPage.stats`
the ``stats`` reply's data.  Messages that are not the one awaited (replies to earlier
messages) are skipped.
"""

from __future__ import annotations

from typing import Any

import aiohttp

from lodsprite.distributed.protocol import (
    Keyframe,
    Message,
    ProtocolError,
    decode_keyframe,
    decode_message,
    encode,
)
from lodsprite.distributed.web.scene import SceneData, decode_scene
from lodsprite.distributed.web.wire import pack, unpack

__all__ = ["WebPage", "connect"]

MAX_IN = 2**31 - 1


async def connect(http: aiohttp.ClientSession, url: str, token: str, **kw: Any) -> WebPage:
    """A :class:`WebPage` on the WebSocket of the server at ``url`` (``http(s)://HOST:PORT``)."""
    ws = await http.ws_connect(f"{url.rstrip('/')}/ws?token={token}", max_msg_size=0, **kw)
    return WebPage(ws)


class WebPage:
    """One WebSocket speaking the web wire (``ws``: an aiohttp client WebSocket)."""

    def __init__(self, ws: aiohttp.ClientWebSocketResponse) -> None:
        self.ws = ws
        self.seq = 0
        self.jobs = 1  # renders in flight the server allows this page (its load reply)

    async def send(self, header: dict, *buffers) -> int:
        """Send a message (``kind`` and fields; ``seq`` is numbered here); its ``seq``."""
        self.seq += 1
        await self.ws.send_bytes(pack(encode({"seq": self.seq, **header}, *buffers)))
        return self.seq

    async def recv(self, kind: str | None = None) -> tuple[Message, list]:
        """The next message (of ``kind`` when given): its header and parts; raises
        :class:`ProtocolError` when the connection closes or sends something else."""
        while True:
            msg = await self.ws.receive()
            if msg.type != aiohttp.WSMsgType.BINARY:
                raise ProtocolError(f"the WebSocket sent {msg.type.name}, not a message")
            parts = unpack(msg.data, MAX_IN)
            header, _ = decode_message(parts)
            if kind is None or header.__struct_config__.tag == kind:
                return header, parts

    async def reply(self, seq: int) -> Message:
        """The reply to the message numbered ``seq``; raises :class:`ProtocolError` if it
        says ``ok: false``."""
        while True:
            reply, _ = await self.recv("reply")
            if reply.seq == seq:
                if not reply.ok:
                    raise ProtocolError(reply.error)
                return reply

    async def load(self, args: dict) -> SceneData:
        """``load`` ``args`` (LoadArgs fields); the scene that comes back (and in
        :attr:`jobs`, the requests the server renders at once for this page)."""
        seq = await self.send({"kind": "control", "op": "load", "args": args})
        while True:
            header, parts = await self.recv()
            kind = header.__struct_config__.tag
            if kind == "scene" and header.seq == seq:
                scene = decode_scene(parts)
                reply = await self.reply(seq)
                jobs = reply.data.get("jobs", 1)
                self.jobs = jobs if isinstance(jobs, int) and 1 <= jobs <= 16 else 1
                return scene
            if kind == "reply" and header.seq == seq and not header.ok:
                raise ProtocolError(header.error)

    async def request(self, viewpoint: dict, t: float) -> int:
        """Ask for a keyframe at ``viewpoint`` (wire form {x, y, z, o}) for the page's
        time ``t`` (s); the request's ``seq``."""
        return await self.send({"kind": "request", "t": t, "viewpoint": viewpoint})

    async def keyframe(self, viewpoint: dict, t: float) -> Keyframe:
        """Request a keyframe and wait for it (its ``seq`` is the request's)."""
        seq = await self.request(viewpoint, t)
        while True:
            header, parts = await self.recv()
            kind = header.__struct_config__.tag
            if kind == "keyframe" and header.seq == seq:
                return decode_keyframe(parts)
            if kind == "reply" and header.seq == seq and not header.ok:
                raise ProtocolError(header.error)

    async def stats(self) -> dict:
        """The ``stats`` reply's data: ``session`` and ``server`` figures."""
        seq = await self.send({"kind": "control", "op": "stats"})
        return (await self.reply(seq)).data

    async def close(self) -> None:
        await self.ws.close()
