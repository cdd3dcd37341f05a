"""Wire protocol between the LOD server and the LOD client (Swan et al. 2002, §3, Figure 4).

Every message is a ZeroMQ multipart message: frame 0 is a msgpack header, the following
frames are raw buffers (images), never pickled.  Each header is one declared schema, a
:class:`msgspec.Struct` tagged by ``kind``, and every message is decoded and validated
here, in one place (:func:`decode_message`): types, ranges, lengths, enumerated values,
image shapes and dtypes, the number of buffers.  Anything else raises
:class:`ProtocolError`, never another exception.  Every header carries ``v`` (protocol
version, :data:`PROTOCOL_VERSION`), ``kind`` and ``seq`` (a sequence number in
``0 .. 2**63 - 1``).

=========  ================================================  ==================================
kind       header fields (ranges)                            buffers
=========  ================================================  ==================================
control    ``op`` (start, stop, load, stats, shutdown,       none
           ping, release, path), ``args`` (op arguments:
           :class:`LoadArgs` for ``load``, ``PathArgs``
           for ``path``, an empty map otherwise),
           ``client`` (the sender's id: 16-64 lowercase
           hex digits, or "" for anonymous)
reply      ``ok`` (bool), ``error`` (str, <= 4096 chars),    none
           ``data`` (map)
viewpoint  ``t`` (client clock, s, ``|t| <= 1e12``),         none
           ``viewpoint`` ({x, y, z, o}: 3 numbers each,
           ``|c| <= 1e9``, axes orthonormal), optional
           ``shown`` ({eye: 3 numbers, slot: 0..63}: the
           keyframe the client shows and the server it came
           from, for the servers' pacing), ``client``
keyframe   ``t0`` (server clock when rendering began),       colour (H, W, 3) uint8; depth
           ``viewpoint``, ``view``, ``proj`` (16 numbers     (H, W) float32 window depth in
           each, row-major), ``fov`` (0..180 degrees),       [0, 1]; rows bottom-up (OpenGL's
           ``aspect``, ``near``, ``far`` (> near > 0),       order, so neither side flips
           ``zbuffer`` (``full``: the full-resolution        them); H, W in 1..4096; each raw
           z-buffer, ``coarse``: the coarse level's),        or zlib compressed (``codec``);
           ``color``/``depth`` ({shape, dtype, codec})       zlib output bounded to the size
ack        ``t`` (client clock)                              none
request    ``t`` (page clock), ``viewpoint``, ``client``:    none
           a web page asks for a keyframe there
scene      a web page's coarse level and texture after       heights (n+1, n+1) float32;
           its ``load`` (:class:`SceneMessage`)               texture (H, W, 3) uint8
=========  ================================================  ==================================

Buffers are not copied on the way through: :func:`decode_message` hands out memoryviews
of the received frames (``recv_multipart(copy=False)``) and a decoded keyframe's raw
images are views of them.  A declared image shape never allocates anything by itself:
a raw buffer must have exactly the declared size, and a zlib stream is inflated with
``decompressobj().decompress(data, size)`` and refused if it holds more (or less).

The ``MAX_*_BYTES`` constants are the ``zmq.MAXMSGSIZE`` of each socket (ZeroMQ applies
it to each frame): a peer that sends more is disconnected by ZeroMQ itself.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass
from typing import Any

import msgspec
import numpy as np
from msgspec import Struct

from lodsprite.camera import Projection, Viewpoint
from lodsprite.distributed.messages import (
    ANY_MESSAGE,
    BUFFERS,
    CODECS,
    CONTROL_OPS,
    KINDS,
    LOOPBACK_HOSTS,
    MAX_ACK_BYTES,
    MAX_CONTROL_BYTES,
    MAX_COORD,
    MAX_GRID,
    MAX_IMAGE_SIDE,
    MAX_KEYFRAME_FRAME_BYTES,
    MAX_NAME,
    MAX_REPLY_BYTES,
    MAX_REQUEST_BYTES,
    MAX_SCENE_BYTES,
    MAX_SCENE_COARSE,
    MAX_SLOTS,
    MAX_TIME,
    MAX_VIEWPOINT_BYTES,
    OP_ARGS,
    PACE_NAMES,
    PROTOCOL_VERSION,
    VISIBILITY,
    ZBUFFERS,
    Ack,
    ClientId,
    Control,
    Coord,
    ImageSpec,
    KeyframeMessage,
    LoadArgs,
    Matrix,
    Message,
    Name,
    NoArgs,
    PathArgs,
    ProtocolError,
    Reply,
    Request,
    SceneMessage,
    Seq,
    Shown,
    Side,
    Slot,
    Time,
    Vec3,
    ViewpointMessage,
    WireViewpoint,
)
from lodsprite.errors import InputError


class _Envelope(Struct):
    """The first look at a header: only version and kind, any other field ignored."""

    v: Any = None
    kind: Any = None


_envelope = msgspec.msgpack.Decoder(_Envelope)
_decoder = msgspec.msgpack.Decoder(ANY_MESSAGE)


def _enc_hook(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise NotImplementedError(f"cannot encode {type(obj).__name__}")


_encoder = msgspec.msgpack.Encoder(enc_hook=_enc_hook)


# ---------------------------------------------------------------------- encode / decode

def encode(header: dict | Message, *buffers) -> list:
    """Multipart frames for ``header`` and raw buffers (any objects with the buffer
    protocol: bytes, contiguous arrays).  ``header`` is a message Struct or a map holding
    ``kind`` and ``seq`` (``v`` is added)."""
    if isinstance(header, Message):
        return [_encoder.encode(header), *buffers]
    return [_encoder.encode({"v": PROTOCOL_VERSION, **header}), *buffers]


def _view(frame) -> memoryview:
    try:
        return memoryview(frame).cast("B")
    except TypeError as exc:
        raise ProtocolError(f"a frame is not a buffer: {type(frame).__name__}") from exc


def decode_message(frames: list, expect: type | None = None
                   ) -> tuple[Message, list[memoryview]]:
    """The typed header and buffers of a multipart message (frames are ``bytes``,
    ``memoryview`` or ``zmq.Frame``); raises :class:`ProtocolError` and nothing else,
    also when ``expect`` (a message Struct) is given and the message is another kind.

    The buffers are views of the frames, not copies.  A control message's ``args`` is
    replaced by the op's argument Struct."""
    try:
        if not isinstance(frames, list | tuple) or not frames:
            raise ProtocolError("empty message")
        head = _view(frames[0])
        try:
            env = _envelope.decode(head)
        except (msgspec.DecodeError, msgspec.ValidationError) as exc:
            raise ProtocolError(f"header is not a msgpack map: {exc}") from None
        if env.v != PROTOCOL_VERSION or isinstance(env.v, bool):
            raise ProtocolError(f"protocol version {env.v!r}, expected {PROTOCOL_VERSION}")
        if env.kind not in KINDS:
            raise ProtocolError(f"unknown message kind {env.kind!r}")
        try:
            msg = _decoder.decode(head)
        except (msgspec.DecodeError, msgspec.ValidationError) as exc:
            raise ProtocolError(f"{env.kind}: {exc}") from None
        if len(frames) - 1 != BUFFERS[env.kind]:
            raise ProtocolError(f"{env.kind}: {len(frames) - 1} buffers, expected "
                                f"{BUFFERS[env.kind]}")
        if isinstance(msg, Control):
            try:
                msg.args = msgspec.convert(msg.args, OP_ARGS[msg.op])
            except msgspec.ValidationError as exc:
                raise ProtocolError(f"{msg.op}: {exc}") from None
        if expect is not None and not isinstance(msg, expect):
            raise ProtocolError(f"expected a {expect.__name__} message, got {env.kind}")
        return msg, [_view(f) for f in frames[1:]]
    except ProtocolError:
        raise
    except (RecursionError, MemoryError, ValueError, TypeError, OverflowError) as exc:
        raise ProtocolError(f"undecodable message: {type(exc).__name__}") from None


def decode(frames: list) -> tuple[dict, list[memoryview]]:
    """Header (the map as sent, after validation by :func:`decode_message`) and buffers
    of a multipart message; raises :class:`ProtocolError`.  The buffers are views of the
    frames, not copies."""
    _, buffers = decode_message(frames)
    return msgspec.msgpack.decode(_view(frames[0])), buffers


def viewpoint_to_wire(vp: Viewpoint) -> dict:
    return vp.to_dict()


def viewpoint_from_wire(d: WireViewpoint | dict) -> Viewpoint:
    """A :class:`Viewpoint` from its wire form; raises :class:`ProtocolError`."""
    if not isinstance(d, WireViewpoint):
        try:
            d = msgspec.convert(d, WireViewpoint)
        except msgspec.ValidationError as exc:
            raise ProtocolError(f"viewpoint: {exc}") from None
    try:
        return Viewpoint(np.array(d.x), np.array(d.y), np.array(d.z), np.array(d.o))
    except InputError as exc:
        raise ProtocolError(f"bad viewpoint: {exc}") from None


def shown_from_wire(value: Shown | dict | None) -> tuple[np.ndarray, int] | None:
    """The optional ``shown`` field of a viewpoint message: the shown keyframe's eye
    ``(3,)`` in metres and the slot of the server that rendered it; None when absent."""
    if value is None:
        return None
    if not isinstance(value, Shown):
        try:
            value = msgspec.convert(value, Shown)
        except msgspec.ValidationError as exc:
            raise ProtocolError(f"shown: {exc}") from None
    return np.array(value.eye, dtype=np.float64), value.slot


def check_load_args(args: dict | LoadArgs) -> LoadArgs:
    """``load`` arguments validated against :class:`LoadArgs`; raises
    :class:`ProtocolError` (a terrain that does not load is reported by the renderer)."""
    if isinstance(args, LoadArgs):
        return args
    try:
        return msgspec.convert(args, LoadArgs)
    except msgspec.ValidationError as exc:
        raise ProtocolError(f"load: {exc}") from None


# ------------------------------------------------------------------------------ keyframes

@dataclass(frozen=True, eq=False)
class Keyframe:
    """A keyframe crossing the wire: the 2002 paper's (sprite, z-buffer, view, t0) plus the
    projection.  ``color (H, W, 3) uint8``, ``depth (H, W) float32`` window depth in [0, 1],
    row 0 at the top of the image; ``t0`` in seconds on the server's clock.  ``zbuffer``
    says whose depth it is: ``full`` (the full-resolution terrain's) or ``coarse`` (the
    coarse level's, from the same view: all that the default visibility rule reads).
    ``deficit_px``: what it lacks (pixels of error beyond its renderer's tolerance, from
    tiles not yet arrived when it was drawn); a client asks again while it is above 0.

    Arrays that are ``[::-1]`` views of contiguous bottom-up rows (what
    :meth:`~lodsprite.gl.target.RenderTarget.read_color` gives with ``copy=False`` and what
    :func:`decode_keyframe` returns) cross the wire and reach a texture without a copy.
    """

    seq: int
    t0: float
    viewpoint: Viewpoint
    projection: Projection
    color: np.ndarray
    depth: np.ndarray
    zbuffer: str = "full"
    deficit_px: float = 0.0


def _image_spec(a: np.ndarray, codec: str) -> tuple[dict, object]:
    data = np.ascontiguousarray(a[::-1])  # bottom-up rows; no copy for a flipped GL read
    if codec == "zlib":
        data = zlib.compress(data, 1)
    return {"shape": list(a.shape), "dtype": str(a.dtype), "codec": codec}, data


def encode_keyframe(kf: Keyframe, codec: str = "raw") -> list:
    """Frames of a keyframe message; ``codec`` is ``raw`` or ``zlib`` (both images).  Raw
    image frames are the keyframe's own buffers where its arrays allow (send them with
    ``copy=False``)."""
    if codec not in CODECS:
        raise InputError(f"codec must be one of {CODECS}, got {codec!r}")
    if kf.zbuffer not in ZBUFFERS:
        raise InputError(f"zbuffer must be one of {ZBUFFERS}, got {kf.zbuffer!r}")
    color_spec, color = _image_spec(kf.color, codec)
    depth_spec, depth = _image_spec(kf.depth, codec)
    p = kf.projection
    header = {"kind": "keyframe", "seq": kf.seq, "t0": float(kf.t0),
              "viewpoint": viewpoint_to_wire(kf.viewpoint),
              "view": kf.viewpoint.view_matrix().ravel().tolist(),
              "proj": p.matrix().ravel().tolist(),
              "fov": p.fov_y_deg, "aspect": p.aspect, "near": p.near, "far": p.far,
              "zbuffer": kf.zbuffer, "color": color_spec, "depth": depth_spec,
              "deficit_px": float(kf.deficit_px)}
    return encode(header, color, depth)


def inflate(data: memoryview | bytes, size: int, name: str = "image") -> bytes:
    """Exactly ``size`` bytes from the zlib stream ``data``; raises :class:`ProtocolError`
    for a corrupt or truncated stream, one that inflates to more or fewer bytes, or
    trailing data.  Never produces more than ``size + 1`` bytes (no zlib bombs)."""
    d = zlib.decompressobj()
    try:
        out = d.decompress(data, size)
        if not d.eof:
            if d.decompress(d.unconsumed_tail, 1):
                raise ProtocolError(f"{name}: zlib data inflates beyond {size} bytes")
            if not d.eof:
                raise ProtocolError(f"{name}: truncated zlib data")
    except zlib.error as exc:
        raise ProtocolError(f"{name}: corrupt zlib data") from exc
    if d.unused_data:
        raise ProtocolError(f"{name}: data after the zlib stream")
    if len(out) != size:
        raise ProtocolError(f"{name}: zlib data inflates to {len(out)} bytes, expected {size}")
    return out


def decode_image(spec: ImageSpec, data: memoryview, dtype: str, channels: int | None,
                 name: str, bottom_up: bool = True) -> np.ndarray:
    """The image a buffer holds, checked against its declared ``spec`` (dtype, shape,
    ``channels`` 3 or None, size; a zlib stream inflated within that size): ``(H, W[, 3])``,
    row 0 at the top when the rows arrive ``bottom_up`` (keyframes), else as they came."""
    want = (3,) if channels else ()
    if spec.dtype != dtype or len(spec.shape) != 2 + len(want) or (
            channels and spec.shape[2] != channels):
        raise ProtocolError(f"{name}: expected {dtype} of shape (H, W{', 3' if channels else ''})"
                            f", got {spec.dtype} {spec.shape}")
    size = int(np.prod(spec.shape)) * np.dtype(dtype).itemsize
    if spec.codec == "zlib":
        data = inflate(data, size, name)
    elif len(data) != size:
        raise ProtocolError(f"{name}: {len(data)} bytes, expected {size}")
    image = np.frombuffer(data, dtype=dtype).reshape(spec.shape)
    return image[::-1] if bottom_up else image


def decode_keyframe(frames: list) -> Keyframe:
    """A :class:`Keyframe` from message frames; raises :class:`ProtocolError` only."""
    msg, buffers = decode_message(frames, KeyframeMessage)
    vp = viewpoint_from_wire(msg.viewpoint)
    try:
        proj = Projection(msg.fov, msg.aspect, msg.near, msg.far)
        proj.matrix()
    except (InputError, ValueError, ZeroDivisionError) as exc:
        raise ProtocolError(f"bad projection: {exc}") from None
    color = decode_image(msg.color, buffers[0], "uint8", 3, "color")
    depth = decode_image(msg.depth, buffers[1], "float32", None, "depth")
    if color.shape[:2] != depth.shape:
        raise ProtocolError("colour and depth sizes differ")
    return Keyframe(msg.seq, msg.t0, vp, proj, color, depth, msg.zbuffer, msg.deficit_px)


__all__ = ["ANY_MESSAGE", "Ack", "BUFFERS", "CODECS", "CONTROL_OPS", "ClientId", "Control",
           "Coord", "ImageSpec", "KINDS", "Keyframe", "KeyframeMessage", "LOOPBACK_HOSTS",
           "LoadArgs",
           "MAX_ACK_BYTES", "MAX_CONTROL_BYTES", "MAX_COORD", "MAX_GRID", "MAX_IMAGE_SIDE",
           "MAX_KEYFRAME_FRAME_BYTES", "MAX_NAME", "MAX_REPLY_BYTES", "MAX_REQUEST_BYTES",
           "MAX_SCENE_BYTES", "MAX_SCENE_COARSE", "MAX_SLOTS", "MAX_TIME", "MAX_VIEWPOINT_BYTES",
           "Matrix", "Message", "Name", "NoArgs", "OP_ARGS", "PACE_NAMES", "PROTOCOL_VERSION",
           "PathArgs", "ProtocolError", "Reply", "Request", "SceneMessage", "Seq", "Shown",
           "Side", "Slot", "Time", "VISIBILITY", "Vec3", "ViewpointMessage", "WireViewpoint",
           "ZBUFFERS",
           "check_load_args", "decode", "decode_keyframe", "decode_message", "encode",
           "encode_keyframe", "inflate", "shown_from_wire", "viewpoint_from_wire",
           "viewpoint_to_wire"]
