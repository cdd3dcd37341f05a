"""The web wire: one WebSocket binary message carries one protocol message.

A message is ``u32le n_parts``, then ``n_parts`` x ``u32le length``, then the parts back
to back.  Part 0 is the msgpack header (the Structs of
:mod:`lodsprite.distributed.messages`, decoded and validated by
:func:`lodsprite.distributed.protocol.decode_message`); parts 1.. are the buffers the
header declares (keyframe and scene images).  The ZeroMQ wire's multipart frames are the
same parts, so a keyframe a renderer encodes for ZeroMQ crosses the web unchanged.

Limits are checked before anything is allocated: at most :data:`MAX_PARTS` parts, the
lengths must add up to the message exactly, and the whole message is at most the cap of
the kind its header names (:data:`MAX_BYTES`).  A page can send only the kinds of
:data:`PAGE_KINDS`; the WebSocket's own ``max_msg_size`` is :data:`MAX_PAGE_MESSAGE`.
"""

from __future__ import annotations

import struct

from lodsprite.distributed.protocol import (
    MAX_ACK_BYTES,
    MAX_CONTROL_BYTES,
    MAX_KEYFRAME_FRAME_BYTES,
    MAX_REPLY_BYTES,
    MAX_REQUEST_BYTES,
    MAX_SCENE_BYTES,
    MAX_VIEWPOINT_BYTES,
    Message,
    ProtocolError,
    decode_message,
    encode,
)

__all__ = ["MAX_BYTES", "MAX_PAGE_MESSAGE", "MAX_PARTS", "PAGE_KINDS", "decode_web", "pack",
           "pack_message", "unpack"]

MAX_PARTS = 4
"""Most parts of one web message (a header and at most two buffers, with room to spare)."""
MAX_BYTES = {"control": MAX_CONTROL_BYTES, "viewpoint": MAX_VIEWPOINT_BYTES,
             "ack": MAX_ACK_BYTES, "request": MAX_REQUEST_BYTES,
             "reply": MAX_REPLY_BYTES, "keyframe": 2 * MAX_KEYFRAME_FRAME_BYTES,
             "scene": MAX_SCENE_BYTES}
"""Largest whole web message of each kind, bytes (length words included)."""
PAGE_KINDS = ("control", "viewpoint", "ack", "request")
"""The kinds a page may send the server."""
MAX_PAGE_MESSAGE = max(MAX_BYTES[k] for k in PAGE_KINDS)
"""The server's WebSocket ``max_msg_size``: a larger message closes that connection."""

_U32 = struct.Struct("<I")


def pack(parts: list) -> bytes:
    """One web message from ``parts`` (bytes-like objects: header first)."""
    if not 1 <= len(parts) <= MAX_PARTS:
        raise ProtocolError(f"{len(parts)} parts: a web message has 1..{MAX_PARTS}")
    views = [memoryview(p).cast("B") for p in parts]
    head = struct.pack(f"<{len(views) + 1}I", len(views), *(v.nbytes for v in views))
    return b"".join([head, *views])


def pack_message(header: dict | Message, *buffers) -> bytes:
    """One web message from a header (a message Struct or a map, as
    :func:`~lodsprite.distributed.protocol.encode` takes) and its buffers."""
    return pack(encode(header, *buffers))


def unpack(data: bytes | bytearray | memoryview, max_bytes: int = MAX_PAGE_MESSAGE
           ) -> list[memoryview]:
    """The parts of one web message (views of ``data``, no copies); raises
    :class:`ProtocolError` for anything malformed or over ``max_bytes``."""
    try:
        view = memoryview(data).cast("B")
    except TypeError:
        raise ProtocolError("a web message must be bytes") from None
    size = view.nbytes
    if size > max_bytes:
        raise ProtocolError(f"web message of {size} bytes, at most {max_bytes}")
    if size < 4:
        raise ProtocolError("web message shorter than its part count")
    (n,) = _U32.unpack_from(view, 0)
    if not 1 <= n <= MAX_PARTS:
        raise ProtocolError(f"{n} parts: a web message has 1..{MAX_PARTS}")
    start = 4 * (n + 1)
    if size < start:
        raise ProtocolError("web message shorter than its part lengths")
    lengths = struct.unpack_from(f"<{n}I", view, 4)
    if start + sum(lengths) != size:
        raise ProtocolError(f"part lengths add up to {start + sum(lengths)} bytes, the "
                            f"message has {size}")
    parts = []
    for length in lengths:
        parts.append(view[start:start + length])
        start += length
    return parts


def decode_web(data: bytes | bytearray | memoryview, kinds: tuple[str, ...] = PAGE_KINDS,
               max_bytes: int = MAX_PAGE_MESSAGE) -> tuple[Message, list[memoryview]]:
    """The validated header and buffers of one web message whose kind is in ``kinds``
    and whose size is within its kind's cap; raises :class:`ProtocolError` only."""
    parts = unpack(data, max_bytes)
    msg, buffers = decode_message(parts)
    kind = type(msg).__struct_config__.tag
    if kind not in kinds:
        raise ProtocolError(f"a {kind} message is not accepted here")
    if len(data) > MAX_BYTES[kind]:
        raise ProtocolError(f"{kind}: {len(data)} bytes, at most {MAX_BYTES[kind]}")
    return msg, buffers
