"""The wire protocol's schemas and limits: every header a declared
:class:`msgspec.Struct` tagged by ``kind``, with the ranges, lengths and enumerated values
:mod:`lodsprite.distributed.protocol` validates (the table of messages is there), and the
per-socket size limits."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from msgspec import Meta, Struct, field

from lodsprite.distributed.pacing import DEFAULT_PACE
from lodsprite.errors import LodspriteError
from lodsprite.scene.file import MAX_GRID as SCENE_MAX_GRID
from lodsprite.scene.spec import MAX_NAME as SCENE_MAX_NAME
from lodsprite.scene.spec import SceneSpec

PROTOCOL_VERSION = 5
"""4: the web wire's ``request`` and ``scene`` kinds (:mod:`lodsprite.distributed.web`);
5: a keyframe says what it lacks while its terrain's tiles stream (``deficit_px``)."""
KINDS = ("control", "reply", "viewpoint", "keyframe", "ack", "request", "scene")
CONTROL_OPS = ("start", "stop", "load", "stats", "shutdown", "ping", "release", "path")
LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "::1", "[::1]")
"""Host names that mean this machine (binds that need no token, keys or --allow-remote)."""
CODECS = ("raw", "zlib")
ZBUFFERS = ("full", "coarse")
VISIBILITY = ("triangle", "fragment", "coarse")  # lodsprite.gl.sprite.VISIBILITY_MODES
PACE_NAMES = ("needed", "continuous")  # lodsprite.distributed.pacing.PACES

MAX_IMAGE_SIDE = 4096
"""Largest keyframe (and server render target) side in pixels."""
MAX_GRID = SCENE_MAX_GRID
"""Largest working grid (quads per side) a ``load`` may ask for (a scene file's cap)."""
MAX_SLOTS = 64
"""Most servers one client may use."""
MAX_NAME = SCENE_MAX_NAME
"""Longest terrain or texture name, characters (a scene description's cap)."""
MAX_COORD = 1e9
"""Largest coordinate (metres) of a viewpoint on the wire."""
MAX_TIME = 1e12
"""Largest clock value (seconds) on the wire."""

MAX_CONTROL_BYTES = 64 * 1024
MAX_VIEWPOINT_BYTES = 4 * 1024
MAX_ACK_BYTES = 4 * 1024
MAX_REQUEST_BYTES = 4 * 1024
MAX_REPLY_BYTES = 64 * 1024 * 1024  # a stats reply: at most 8 x 10,000 timings, under 1 MiB
MAX_KEYFRAME_FRAME_BYTES = (MAX_IMAGE_SIDE**2 * 4 * 102) // 100 + 65536
"""Largest frame of a keyframe message: the depth image at the largest size (4 bytes a
pixel), plus zlib's worst-case expansion of incompressible data and the header."""
MAX_SCENE_COARSE = 2048
"""Largest coarse level (quads a side) a ``scene`` message carries."""
MAX_RIBBON_VERTICES = 8 * (MAX_GRID + 1)
"""Most border ribbon vertices a ``scene`` message carries (two a border sample)."""
MAX_RIBBON_TRIANGLES = 8 * MAX_GRID
"""Most border ribbon triangles a ``scene`` message carries (two a border quad)."""
MAX_WALKERS = 20_000
"""Most walkers a ``scene`` message carries (a session's objects cap)."""
MAX_WALKER_TYPES = 32
MAX_WALKER_LEVELS = 8
MAX_WALKER_VERTICES = 2**18
"""Most vertices of one walker type (its finest LOD's vertex buffer)."""
MAX_WALKER_TRIANGLES = 2**19
"""Most triangles of one LOD level of one walker type."""
MAX_GROUND_SIDE = 1025
"""Largest side of the ground heights a ``scene`` message carries for its walkers."""
MAX_WALKER_BYTES = (MAX_WALKER_TYPES * (36 * MAX_WALKER_VERTICES
                                        + MAX_WALKER_LEVELS * 12 * MAX_WALKER_TRIANGLES)
                    + 74 * MAX_WALKERS + 4 * MAX_GROUND_SIDE**2)
MAX_SCENE_BYTES = ((MAX_IMAGE_SIDE**2 * 3 + (MAX_SCENE_COARSE + 1) ** 2 * 4) * 102 // 100
                   + 12 * (MAX_RIBBON_VERTICES + MAX_RIBBON_TRIANGLES) + MAX_WALKER_BYTES
                   + 65536)
"""Largest ``scene`` message: the texture at the largest side (RGB) and the coarse heights,
with zlib's worst-case expansion, the border ribbon, the walkers and the header."""


class ProtocolError(LodspriteError, ValueError):
    """A message that does not follow the protocol (malformed, truncated, wrong version)."""


# ------------------------------------------------------------------------------ schemas

Seq = Annotated[int, Meta(ge=0, le=2**63 - 1)]
Coord = Annotated[float, Meta(ge=-MAX_COORD, le=MAX_COORD)]
Time = Annotated[float, Meta(ge=-MAX_TIME, le=MAX_TIME)]
Vec3 = tuple[Coord, Coord, Coord]
Matrix = Annotated[list[Annotated[float, Meta(ge=-1e15, le=1e15)]],
                   Meta(min_length=16, max_length=16)]
ClientId = Annotated[str, Meta(pattern="^(?:[0-9a-f]{16,64})?$")]
Name = Annotated[str, Meta(min_length=1, max_length=MAX_NAME)]
Side = Annotated[int, Meta(ge=1, le=MAX_IMAGE_SIDE)]
Slot = Annotated[int, Meta(ge=0, lt=MAX_SLOTS)]


class WireViewpoint(Struct, forbid_unknown_fields=True):
    """A viewpoint: unit axes ``x, y, z`` and eye ``o`` (metres), 3 numbers each."""

    x: Vec3
    y: Vec3
    z: Vec3
    o: Vec3


class Shown(Struct, forbid_unknown_fields=True):
    """The keyframe a client shows: its eye (metres) and the slot of its server."""

    eye: Vec3
    slot: Slot


KEY_SCALES = (1.0, 1.5, 2.0)
"""Keyframe texels a frame pixel side a ``load`` may ask for (``lodsprite.gl.sprite``'s)."""


class LoadArgs(SceneSpec, forbid_unknown_fields=True, omit_defaults=True):
    """Arguments of ``load``: the scene's description (:class:`~lodsprite.scene.spec.
    SceneSpec`: terrain and texture names, working grid in quads, vertical exaggeration,
    with the scene files' caps), keyframe size ``(width, height)`` px, vertical field of
    view in degrees, the client's sprite settings (coarse level in quads, visibility
    rule, border ribbons, ε in pixels, pace), its place among its servers (slot of
    slots) and ``key_scale``, keyframe texels a frame pixel side (keyframes are rendered
    at ``key_scale`` times ``size``, at most :data:`MAX_IMAGE_SIDE` a side)."""

    size: tuple[Side, Side] = (512, 512)
    fov_y_deg: Annotated[float, Meta(ge=1.0, le=179.0)] = 45.0
    lod: Annotated[int, Meta(ge=1, le=MAX_GRID)] = 16
    visibility: Literal[VISIBILITY] = "coarse"  # type: ignore[valid-type]
    border: bool = True
    epsilon: Annotated[float, Meta(gt=0.0, le=10000.0)] = 1.0
    pace: Literal[PACE_NAMES] = DEFAULT_PACE  # type: ignore[valid-type]
    slot: Slot = 0
    slots: Annotated[int, Meta(ge=1, le=MAX_SLOTS)] = 1
    key_scale: Annotated[float, Meta(ge=1.0, le=2.0)] = 1.0

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.key_scale not in KEY_SCALES:
            raise ValueError(f"key_scale {self.key_scale:g} is not one of "
                             f"{', '.join(f'{k:g}' for k in KEY_SCALES)}")
        side = round(self.key_scale * max(self.size))
        if side > MAX_IMAGE_SIDE:
            raise ValueError(f"key_scale {self.key_scale:g} makes keyframes {side} pixels a "
                             f"side, more than {MAX_IMAGE_SIDE}")
        if self.lod & (self.lod - 1):
            raise ValueError(f"lod {self.lod} is not a power of two")
        if self.grid is not None and self.lod > self.grid:
            raise ValueError(f"lod {self.lod} exceeds the grid {self.grid}")
        if not self.slot < self.slots:
            raise ValueError(f"slot {self.slot} is not below slots {self.slots}")


MAX_PATH_FRAMES = 20000
"""Most viewpoints a ``path`` reply carries."""
PATH_SPEC = r"^(?:chen1999|swan2002|walk|(?:flyover|patrol|bank)(?::[0-9.]{1,12}){0,3})$"
"""The paths a web page may ask for: the built-in ones (``walk``: a crowd's walkthrough;
never a file: a page names none)."""


class PathArgs(Struct, forbid_unknown_fields=True):
    """Arguments of ``path`` (web pages only): a built-in path ``spec``
    (:func:`lodsprite.paths.get_path`) sampled at ``frames`` viewpoints (None: its own
    default) over the session's loaded terrain."""

    spec: Annotated[str, Meta(pattern=PATH_SPEC)] = "chen1999"
    frames: Annotated[int, Meta(ge=2, le=MAX_PATH_FRAMES)] | None = None


class NoArgs(Struct, forbid_unknown_fields=True):
    """Arguments of every op other than ``load``: none (an empty map)."""


class ImageSpec(Struct, forbid_unknown_fields=True):
    """An image buffer: ``shape`` (H, W) or (H, W, C), ``dtype`` and ``codec``."""

    shape: Annotated[list[Side], Meta(min_length=2, max_length=3)]
    dtype: Literal["uint8", "float32"]
    codec: Literal[CODECS]  # type: ignore[valid-type]


class Message(Struct, forbid_unknown_fields=True, omit_defaults=True, tag_field="kind"):
    """Every header: protocol version and sequence number (``kind`` is the tag)."""

    v: Literal[PROTOCOL_VERSION]  # type: ignore[valid-type]
    seq: Seq


class Control(Message, tag="control"):
    """A control request.  On the wire ``args`` is a map; :func:`decode_message` replaces
    it with the op's argument Struct (:class:`LoadArgs` or :class:`NoArgs`)."""

    op: Literal[CONTROL_OPS]  # type: ignore[valid-type]
    args: Any = field(default_factory=dict)
    client: ClientId = ""


class Reply(Message, tag="reply"):
    ok: bool
    error: Annotated[str, Meta(max_length=4096)] = ""
    data: dict[str, Any] = field(default_factory=dict)


class ViewpointMessage(Message, tag="viewpoint"):
    t: Time
    viewpoint: WireViewpoint
    shown: Shown | None = None
    client: ClientId = ""


class KeyframeMessage(Message, tag="keyframe"):
    t0: Time
    viewpoint: WireViewpoint
    view: Matrix
    proj: Matrix
    fov: Annotated[float, Meta(gt=0.0, lt=180.0)]
    aspect: Annotated[float, Meta(gt=0.0, le=1e4)]
    near: Annotated[float, Meta(gt=0.0, le=MAX_COORD)]
    far: Annotated[float, Meta(gt=0.0, le=1e12)]
    zbuffer: Literal[ZBUFFERS]  # type: ignore[valid-type]
    color: ImageSpec
    depth: ImageSpec
    deficit_px: Annotated[float, Meta(ge=0.0, le=1e6)] = 0.0


class Ack(Message, tag="ack"):
    t: Time = 0.0


class Request(Message, tag="request"):
    """A web page asks for a keyframe at ``viewpoint`` (its predicted viewpoint at its
    clock's ``t``, seconds); the keyframe comes back with this ``seq`` and ``t0 = t``."""

    t: Time
    viewpoint: WireViewpoint
    client: ClientId = ""


class WalkerLevel(Struct, forbid_unknown_fields=True):
    """One LOD of a walker type: ``fraction`` of its triangles (0: its floor) and its
    triangles' vertex indices, ``(T, 3) uint32`` little-endian bytes."""

    fraction: Annotated[float, Meta(ge=0.0, le=1.0)]
    indices: Annotated[bytes, Meta(max_length=12 * MAX_WALKER_TRIANGLES)]


class WalkerType(Struct, forbid_unknown_fields=True):
    """A walker type in its own frame (z up, base at 0): ``vertices (V, 9) float32``
    (position metres, normal, colour 0..1) and its LOD ``levels``, finest first."""

    name: Annotated[str, Meta(max_length=256)]
    vertices: Annotated[bytes, Meta(max_length=36 * MAX_WALKER_VERTICES)]
    levels: Annotated[list[WalkerLevel], Meta(min_length=1, max_length=MAX_WALKER_LEVELS)]


class WalkerSet(Struct, forbid_unknown_fields=True):
    """A scene's moving objects, which the page draws each frame
    (:mod:`lodsprite.distributed.web.walkers`): ``count`` walkers' start ``xy0 (K, 2)``
    metres, ``heading (K,)`` radians, ``speed (K,)`` m/s, walking rectangle ``box (K, 4)``
    (x0, y0, x1, y1; float64 each) and ``type (K,) uint16``; the ground heights
    ``ground_shape`` (rows, cols) float32, row 0 north, ``ground_dx``/``ground_dy``
    metres apart, centred on the origin; the LOD range ``near``/``far`` metres."""

    types: Annotated[list[WalkerType], Meta(min_length=1, max_length=MAX_WALKER_TYPES)]
    count: Annotated[int, Meta(ge=1, le=MAX_WALKERS)]
    xy0: Annotated[bytes, Meta(max_length=16 * MAX_WALKERS)]
    heading: Annotated[bytes, Meta(max_length=8 * MAX_WALKERS)]
    speed: Annotated[bytes, Meta(max_length=8 * MAX_WALKERS)]
    box: Annotated[bytes, Meta(max_length=32 * MAX_WALKERS)]
    type: Annotated[bytes, Meta(max_length=2 * MAX_WALKERS)]
    ground: Annotated[bytes, Meta(max_length=4 * MAX_GROUND_SIDE**2)]
    ground_shape: tuple[Annotated[int, Meta(ge=2, le=MAX_GROUND_SIDE)],
                        Annotated[int, Meta(ge=2, le=MAX_GROUND_SIDE)]]
    ground_dx: Annotated[float, Meta(gt=0.0, le=MAX_COORD)]
    ground_dy: Annotated[float, Meta(gt=0.0, le=MAX_COORD)]
    near: Annotated[float, Meta(ge=0.0, le=MAX_COORD)]
    far: Annotated[float, Meta(gt=0.0, le=MAX_COORD)]


class Georef(Struct, forbid_unknown_fields=True):
    """Where the scene's terrain lies in its dataset's CRS (:func:`lodsprite.terrain.
    rasters.georef`), for the page's cursor coordinates: ``crs`` (its name, e.g.
    ``EPSG:32614``), ``bounds`` west, south, east, north (CRS units, the cells' outer
    edges; the world's origin is their centre) and ``metres_per_unit`` east and north."""

    crs: Annotated[str, Meta(max_length=200)]
    bounds: tuple[Coord, Coord, Coord, Coord]
    metres_per_unit: tuple[Annotated[float, Meta(ge=1e-9, le=1e9)],
                           Annotated[float, Meta(ge=1e-9, le=1e9)]]

    def __post_init__(self) -> None:
        w, s, e, n = self.bounds
        if not (w < e and s < n):
            raise ValueError("georef bounds must be west < east and south < north")


MAX_ATTRIBUTION = 1000
"""Longest imagery attribution a scene message carries (characters)."""


class SceneMessage(Message, tag="scene"):
    """What a web page draws spriteframes from, after its ``load``: the coarse level
    (``coarse`` quads a side) as heights ``(coarse+1, coarse+1) float32`` (world z,
    metres; row i at ``y = origin[1] + i * spacing_y``, column j at ``x = origin[0] +
    j * spacing``), the terrain texture ``(H, W, 3) uint8`` over the same extent (row 0
    south), keyframe ``size`` (w, h) px, ``fov`` (vertical, degrees), a ``near``/``far``
    covering the terrain, ``epsilon`` px, ``visibility`` (the z-buffer keyframes
    carry) and ``relief`` (metres: the RMS height of the full-resolution square centres
    above or below the coarse surface, what the page's error estimate needs of them).
    ``ribbon`` and ``ribbon_tris``: the border ribbons of the coarse level
    (:func:`lodsprite.terrain.proxy.border_ribbon`; empty when the load asked for none),
    vertices ``(V, 3) float32`` world metres and triangles ``(T, 3) uint32`` indices into
    them, little-endian bytes: what the keyframe's coarse z-buffer was drawn with.
    ``walkers``: a scene file's moving objects (:class:`WalkerSet`), None without.
    ``exaggeration``: the vertical exaggeration the heights carry; ``georef``: where the
    terrain lies in its dataset's CRS (:class:`Georef`), None for a terrain without one;
    ``attribution``: the licence and attribution line of the imagery it drapes ("" for
    none), which the page shows."""

    coarse: Annotated[int, Meta(ge=1, le=MAX_SCENE_COARSE)]
    origin: tuple[Coord, Coord]
    spacing: Annotated[float, Meta(gt=0.0, le=MAX_COORD)]
    spacing_y: Annotated[float, Meta(gt=0.0, le=MAX_COORD)]
    size: tuple[Side, Side]
    fov: Annotated[float, Meta(gt=0.0, lt=180.0)]
    near: Annotated[float, Meta(gt=0.0, le=MAX_COORD)]
    far: Annotated[float, Meta(gt=0.0, le=1e12)]
    epsilon: Annotated[float, Meta(gt=0.0, le=10000.0)]
    visibility: Literal[ZBUFFERS]  # type: ignore[valid-type]
    heights: ImageSpec
    texture: ImageSpec
    relief: Annotated[float, Meta(ge=0.0, le=MAX_COORD)] = 0.0
    ribbon: Annotated[bytes, Meta(max_length=12 * MAX_RIBBON_VERTICES)] = b""
    ribbon_tris: Annotated[bytes, Meta(max_length=12 * MAX_RIBBON_TRIANGLES)] = b""
    walkers: WalkerSet | None = None
    exaggeration: Annotated[float, Meta(gt=0.0, le=1000.0)] = 1.0
    georef: Georef | None = None
    attribution: Annotated[str, Meta(max_length=MAX_ATTRIBUTION)] = ""


ANY_MESSAGE = (Control | Reply | ViewpointMessage | KeyframeMessage | Ack | Request
               | SceneMessage)
BUFFERS = {"control": 0, "reply": 0, "viewpoint": 0, "keyframe": 2, "ack": 0, "request": 0,
           "scene": 2}
OP_ARGS: dict[str, type[Struct]] = {op: {"load": LoadArgs, "path": PathArgs}.get(op, NoArgs)
                                     for op in CONTROL_OPS}
