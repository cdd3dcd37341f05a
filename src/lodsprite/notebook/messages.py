"""The notebook widget's own messages, browser to kernel, validated before use.

A widget's custom messages arrive as a JSON ``content`` and binary ``buffers`` from the
front end (``loader.js``), which runs in the user's browser: each is hostile until
:func:`decode_front` has checked it against these schemas (:mod:`msgspec`: types, ranges,
no unknown fields) and its buffers against :data:`MAX_BUFFERS` and the caps of its kind.
The web messages a ``wire`` message carries are then validated again, exactly as the web
server's are (:func:`lodsprite.distributed.web.wire.decode_web`, inside
:meth:`~lodsprite.distributed.web.sessions.Session.handle`).
"""

from __future__ import annotations

import math
from typing import Annotated, Any

import msgspec
from msgspec import Meta, Struct

from lodsprite.distributed.protocol import ProtocolError
from lodsprite.distributed.web.wire import MAX_PAGE_MESSAGE

__all__ = ["MAX_PNG_BYTES", "STATS_KEYS", "Closed", "Failed", "Played", "Shot", "Status",
           "Wire", "decode_front", "viewpoint_row"]

MAX_PNG_BYTES = 64 << 20
"""Largest screenshot a front end may send (a 4096² RGBA PNG, uncompressed, is 64 MiB)."""
MAX_BUFFERS = 1
ViewId = Annotated[str, Meta(pattern=r"^[0-9a-f]{16}$")]
Number = Annotated[float, Meta(ge=-1e12, le=1e12)]
STATS_KEYS = ("frames", "keyframes", "median_ms", "p99_ms", "error_px", "error_px_mean",
              "latency_ms", "input_ms", "input_ms_p99", "inputs")


class Wire(Struct, tag="wire", tag_field="kind", forbid_unknown_fields=True):
    """One web message (the buffer) from the view's client to its session."""

    view: ViewId


class Status(Struct, tag="status", tag_field="kind", forbid_unknown_fields=True):
    """The view's client's figures (``stats()`` of app.js), its camera (12 numbers: axes
    x, y, z, then the eye) and its state line."""

    view: ViewId
    stats: dict[Annotated[str, Meta(max_length=32)], Number | None]
    camera: Annotated[list[Number], Meta(min_length=12, max_length=12)] | None = None
    state: Annotated[str, Meta(max_length=4000)] = ""


class Played(Struct, tag="played", tag_field="kind", forbid_unknown_fields=True):
    """The view played its path to the end and shows the held view's keyframe."""

    view: ViewId
    frames: Annotated[int, Meta(ge=0)] = 0


class Failed(Struct, tag="failed", tag_field="kind", forbid_unknown_fields=True):
    """The view's client failed (its load, a path): the reason, one line."""

    view: ViewId
    error: Annotated[str, Meta(max_length=4000)] = ""


class Shot(Struct, tag="shot", tag_field="kind", forbid_unknown_fields=True):
    """A screenshot (the buffer: a PNG) answering the kernel's request ``id``."""

    view: ViewId
    id: Annotated[int, Meta(ge=0)]


class Closed(Struct, tag="closed", tag_field="kind", forbid_unknown_fields=True):
    """The view was removed (its cell cleared, the page closed)."""

    view: ViewId


FrontMessage = Wire | Status | Played | Failed | Shot | Closed
_BUFFER_CAP = {Wire: MAX_PAGE_MESSAGE, Shot: MAX_PNG_BYTES}


def decode_front(content: Any, buffers: list | None) -> tuple[FrontMessage, bytes | None]:
    """The validated message and its buffer (bytes; None for kinds without one) of one
    custom message from a front end; raises :class:`ProtocolError` only."""
    try:
        msg = msgspec.convert(content, FrontMessage, strict=True)
    except msgspec.ValidationError as exc:
        raise ProtocolError(f"widget message: {exc}") from None
    buffers = list(buffers or ())
    cap = _BUFFER_CAP.get(type(msg))
    if cap is None:
        if buffers:
            raise ProtocolError(f"widget message {type(msg).__name__.lower()}: no buffer "
                                "expected")
        return msg, None
    if len(buffers) != MAX_BUFFERS:
        raise ProtocolError(f"widget message: {len(buffers)} buffers, expected 1")
    try:
        view = memoryview(buffers[0]).cast("B")
    except TypeError:
        raise ProtocolError("widget message: the buffer is not bytes") from None
    if view.nbytes > cap:
        raise ProtocolError(f"widget message: {view.nbytes} bytes, at most {cap}")
    return msg, bytes(view)


def viewpoint_row(camera: list[float] | None) -> list[float] | None:
    """``camera`` (12 numbers) when finite, else None."""
    if camera is None or not all(math.isfinite(v) for v in camera):
        return None
    return list(camera)
