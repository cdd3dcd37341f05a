"""Wire protocol between the LOD server and the LOD client (Swan et al. 2002, §3, Figure 4).

Every message is a ZeroMQ multipart message: frame 0 is a msgpack header, the following
frames are raw buffers (images), never pickled.  The header always carries
``v`` (protocol version), ``kind`` and ``seq`` (sequence number).

=========  ============================================  =====================================
kind       header fields                                 buffers
=========  ============================================  =====================================
control    ``op`` (start, stop, load, stats, shutdown,   none
           ping), ``args`` (dict)
reply      ``ok`` (bool), ``error`` (str), ``data``      none
viewpoint  ``t`` (client clock, s), ``viewpoint``        none
           ({x, y, z, o} lists of 3 floats), optional
           ``shown`` ({eye: 3 floats, slot: int}: the
           keyframe the client shows and the server it
           came from, for the servers' pacing)
keyframe   ``t0`` (server clock when rendering began),   colour (H, W, 3) uint8; depth (H, W)
           ``viewpoint``, ``view``, ``proj`` (16 floats  float32 window depth in [0, 1];
           each, row-major), ``fov``, ``near``, ``far``, both with rows bottom-up (OpenGL's
           ``zbuffer`` (``full``: the full-resolution    order, so neither side flips them);
           z-buffer, ``coarse``: the coarse level's,     each raw or zlib compressed
           all the ``coarse`` visibility rule reads),    (``codec``)
           ``color``/``depth`` ({shape, dtype, codec})
ack        ``t`` (client clock)                          none
=========  ============================================  =====================================

:func:`decode` rejects anything malformed - wrong version, missing or mistyped
fields, truncated or oversized buffers - with :class:`ProtocolError`.  Buffers are not
copied on the way through: :func:`decode` hands out memoryviews of the received frames
(``recv_multipart(copy=False)``) and a decoded keyframe's images are views of them.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import msgpack
import numpy as np

from lodsprite.camera import Projection, Viewpoint
from lodsprite.errors import InputError, LodspriteError

PROTOCOL_VERSION = 2
KINDS = ("control", "reply", "viewpoint", "keyframe", "ack")
CONTROL_OPS = ("start", "stop", "load", "stats", "shutdown", "ping")
CODECS = ("raw", "zlib")
ZBUFFERS = ("full", "coarse")
MAX_IMAGE_SIDE = 16384


class ProtocolError(LodspriteError, ValueError):
    """A message that does not follow the protocol (malformed, truncated, wrong version)."""


def encode(header: dict, *buffers) -> list:
    """Multipart frames for ``header`` (must hold ``kind`` and ``seq``) and raw buffers
    (any objects with the buffer protocol: bytes, contiguous arrays)."""
    head = {"v": PROTOCOL_VERSION, **header}
    return [msgpack.packb(head, use_bin_type=True), *buffers]


def decode(frames: list) -> tuple[dict, list[memoryview]]:
    """Header and buffers of a multipart message (``bytes`` or ``zmq.Frame``); raises
    :class:`ProtocolError`.  The buffers are views of the frames, not copies."""
    if not frames:
        raise ProtocolError("empty message")
    try:
        header = msgpack.unpackb(bytes(frames[0]), raw=False, strict_map_key=True)
    except Exception as exc:  # msgpack raises several exception types
        raise ProtocolError(f"header is not valid msgpack: {exc}") from exc
    if not isinstance(header, dict):
        raise ProtocolError("header is not a map")
    if header.get("v") != PROTOCOL_VERSION:
        raise ProtocolError(f"protocol version {header.get('v')!r}, expected {PROTOCOL_VERSION}")
    if header.get("kind") not in KINDS:
        raise ProtocolError(f"unknown message kind {header.get('kind')!r}")
    seq = header.get("seq")
    if isinstance(seq, bool) or not isinstance(seq, int) or seq < 0:
        raise ProtocolError(f"bad sequence number {seq!r}")
    return header, [memoryview(f).cast("B") for f in frames[1:]]


def _floats(value, n: int, name: str) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ProtocolError(f"{name} is not numeric") from exc
    if a.shape != (n,) or not np.all(np.isfinite(a)):
        raise ProtocolError(f"{name} must be {n} finite numbers")
    return a


def viewpoint_to_wire(vp: Viewpoint) -> dict:
    return vp.to_dict()


def viewpoint_from_wire(d) -> Viewpoint:
    if not isinstance(d, dict):
        raise ProtocolError("viewpoint is not a map")
    parts = [_floats(d.get(k), 3, f"viewpoint.{k}") for k in ("x", "y", "z", "o")]
    try:
        return Viewpoint(*parts)
    except InputError as exc:
        raise ProtocolError(f"bad viewpoint: {exc}") from exc


def shown_from_wire(value) -> tuple[np.ndarray, int] | None:
    """The optional ``shown`` field of a viewpoint message: the shown keyframe's eye
    ``(3,)`` in metres and the slot of the server that rendered it; None when absent."""
    if value is None:
        return None
    if not isinstance(value, dict):
        raise ProtocolError("shown is not a map")
    slot = value.get("slot")
    if isinstance(slot, bool) or not isinstance(slot, int) or slot < 0:
        raise ProtocolError(f"shown.slot {slot!r} is not a server slot")
    return _floats(value.get("eye"), 3, "shown.eye"), slot


@dataclass(frozen=True, eq=False)
class Keyframe:
    """A keyframe crossing the wire: the 2002 paper's (sprite, z-buffer, view, t0) plus the
    projection.  ``color (H, W, 3) uint8``, ``depth (H, W) float32`` window depth in [0, 1],
    row 0 at the top of the image; ``t0`` in seconds on the server's clock.  ``zbuffer``
    says whose depth it is: ``full`` (the full-resolution terrain's) or ``coarse`` (the
    coarse level's, from the same view: all that the default visibility rule reads).

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
              "zbuffer": kf.zbuffer, "color": color_spec, "depth": depth_spec}
    return encode(header, color, depth)


def _image(spec, data, dtype: str, channels: int | None, name: str) -> np.ndarray:
    if not isinstance(spec, dict) or spec.get("dtype") != dtype or spec.get("codec") not in CODECS:
        raise ProtocolError(f"{name}: bad image description {spec!r}")
    shape = spec.get("shape")
    want = 3 if channels else 2
    if (not isinstance(shape, list) or len(shape) != want
            or not all(isinstance(s, int) and 1 <= s <= MAX_IMAGE_SIDE for s in shape[:2])
            or (channels and shape[2] != channels)):
        raise ProtocolError(f"{name}: bad shape {shape!r}")
    size = int(np.prod(shape)) * np.dtype(dtype).itemsize
    if spec["codec"] == "zlib":
        try:
            data = zlib.decompress(data, bufsize=size)
        except zlib.error as exc:
            raise ProtocolError(f"{name}: corrupt zlib data") from exc
    if len(data) != size:
        raise ProtocolError(f"{name}: {len(data)} bytes, expected {size}")
    return np.frombuffer(data, dtype=dtype).reshape(shape)[::-1]  # rows arrive bottom-up


def decode_keyframe(frames: list[bytes]) -> Keyframe:
    """A :class:`Keyframe` from message frames; raises :class:`ProtocolError`."""
    header, buffers = decode(frames)
    if header["kind"] != "keyframe" or len(buffers) != 2:
        raise ProtocolError("not a keyframe message with two image buffers")
    vp = viewpoint_from_wire(header.get("viewpoint"))
    nums = {k: header.get(k) for k in ("t0", "fov", "aspect", "near", "far")}
    if not all(isinstance(v, int | float) and not isinstance(v, bool) and np.isfinite(v)
               for v in nums.values()):
        raise ProtocolError("keyframe timing or projection fields missing or not numbers")
    try:
        proj = Projection(float(nums["fov"]), float(nums["aspect"]), float(nums["near"]),
                          float(nums["far"]))
        proj.matrix()
    except InputError as exc:
        raise ProtocolError(f"bad projection: {exc}") from exc
    color = _image(header.get("color"), buffers[0], "uint8", 3, "color")
    depth = _image(header.get("depth"), buffers[1], "float32", None, "depth")
    if color.shape[:2] != depth.shape:
        raise ProtocolError("colour and depth sizes differ")
    zbuffer = header.get("zbuffer")
    if zbuffer not in ZBUFFERS:
        raise ProtocolError(f"unknown z-buffer {zbuffer!r}")
    return Keyframe(header["seq"], float(nums["t0"]), vp, proj, color, depth, zbuffer)
