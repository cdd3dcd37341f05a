"""The ``scene`` message a web page draws spriteframes from (Swan et al. 2002, §3.2: the
client holds the coarse model and renders spriteframes from it and the last keyframe),
and the answer to its ``path`` op.

Computed in the server process, GL-free, from the scene a ``load`` describes (its
:class:`~lodsprite.scene.spec.SceneSpec`, opened by :func:`~lodsprite.scene.spec.
open_spec` as every renderer opens it): :func:`scene_parts` makes the message from the
:class:`~lodsprite.scene.Scene`'s terrain layer, its working height field's coarse level
(an exact subsample, ``lod`` quads a side, as the sprite drawer's proxy) and its
texture, both turned so row 0 is south (the page's ``y`` grows with the row), and (unless
the load says ``border: false``) the coarse level's border ribbons
(:func:`lodsprite.terrain.proxy.border_ribbon`), which the page draws with the coarse
level: the server's coarse z-buffer is drawn with them (:mod:`lodsprite.distributed.
render`), and lodsprite's own spriteframes draw them (:class:`lodsprite.gl.sprite.
SpriteDrawer`).

``path`` (after a ``load``): the viewpoints of a built-in camera path
(:func:`lodsprite.paths.get_path`: Chen, Swan & Kaufman 1999 Figure 7's orbit, Swan et
al. 2002's fly-in, ...) over the session's terrain, computed here so that the page plays
exactly the path the Python side plays (one implementation of the paths, not a second in
JavaScript).  The reply's ``data``: ``viewpoints`` (12 numbers a frame: the camera axes
``x, y, z`` then the eye ``o``, metres, as :class:`~lodsprite.camera.Viewpoint`) and
``fov`` (the path's vertical field of view, degrees).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from lodsprite.distributed.protocol import (
    MAX_IMAGE_SIDE,
    MAX_SCENE_COARSE,
    LoadArgs,
    PathArgs,
    ProtocolError,
    SceneMessage,
    decode_image,
    decode_message,
    encode,
)

if TYPE_CHECKING:
    from lodsprite.scene import Scene

__all__ = ["SceneData", "build_scene", "build_scene_field", "decode_ribbon", "decode_scene",
           "path_data", "relief", "scene_key", "scene_parts", "shaded_texture"]

SCENE_FIELDS = ("terrain", "texture", "grid", "exaggeration", "lod", "size", "fov_y_deg",
                "epsilon", "visibility", "border")


def scene_key(args: LoadArgs) -> tuple:
    """What a scene message depends on (the cache key of :func:`build_scene`)."""
    return tuple((k, getattr(args, k)) for k in SCENE_FIELDS)


def _spec(a: np.ndarray, codec: str) -> tuple[dict, bytes | np.ndarray]:
    import zlib

    data = np.ascontiguousarray(a)
    spec = {"shape": list(a.shape), "dtype": str(a.dtype), "codec": codec}
    return spec, (zlib.compress(data, 1) if codec == "zlib" else data)


def relief(heights: np.ndarray, step: int) -> float:
    """RMS height (metres) of the full-resolution square centres of the coarse level
    (``step`` samples a side) above or below the mean of their square's four corners:
    the deviation of the terrain from its coarse level that makes a spriteframe's error
    (Chen, Swan & Kaufman 1999, Eq. 1: ``C`` against ``C'``)."""
    if step < 2:
        return 0.0
    h = np.asarray(heights, dtype=np.float64)
    corners = h[::step, ::step]
    mean = 0.25 * (corners[:-1, :-1] + corners[1:, :-1] + corners[:-1, 1:] + corners[1:, 1:])
    centres = h[step // 2::step, step // 2::step][:mean.shape[0], :mean.shape[1]]
    return float(np.sqrt(np.mean((centres - mean) ** 2)))


def build_scene(args: LoadArgs, codec: str = "raw") -> list:
    """The parts (header, heights, texture) of the scene message for resolved ``load``
    arguments ``args`` (terrain and texture as loader specs); raises
    :class:`~lodsprite.errors.LodspriteError` when the dataset does not load."""
    return build_scene_field(args, codec)[0]


def build_scene_field(args: LoadArgs, codec: str = "raw",
                      root: str | None = None) -> tuple[list, Any]:
    """:func:`build_scene`'s parts and the working height field they came from
    (:class:`~lodsprite.terrain.HeightField`, kept for :func:`path_data`).  A scene file
    (resolved: an absolute path) opens confined to ``root`` (the data folder), its
    walkers in the message (:mod:`.walkers`)."""
    from lodsprite.errors import InputError
    from lodsprite.scene.spec import open_spec

    if args.lod > MAX_SCENE_COARSE:
        raise InputError(f"lod {args.lod}: a web page's coarse level is at most "
                         f"{MAX_SCENE_COARSE} quads a side")
    from lodsprite.distributed.served import is_object_scene, open_object_scene

    if is_object_scene(args.terrain):
        scene = open_object_scene(args.terrain, root)
        if scene.hf is not None and args.lod > scene.hf.quads:
            raise InputError(f"lod {args.lod} exceeds the scene's terrain grid "
                             f"{scene.hf.quads}")
        return scene_parts(scene, args, codec), scene.hf
    # the load's scene description (a SceneSpec); a store's working grid as its adaptive
    # renderers load it (light: from its finest level of at most 1025 a side, not up to 4096²: a
    # 16k² store's message in 0.8 s instead of 3.5 s here, from the keyframes' own grid)
    scene = open_spec(args, light=True)
    return scene_parts(scene, args, codec), scene.hf


def warm_imports() -> None:
    """Import what building a scene message and a path needs (the scene model, terrain
    loaders and stores, SciPy's and scikit-image's resampling, the paths: about 1 s here),
    so that a server's first page does not wait for them; a server calls it in a thread
    once it serves."""
    import scipy.ndimage  # noqa: F401
    import skimage.transform  # noqa: F401

    import lodsprite.paths  # noqa: F401
    import lodsprite.scene.model  # noqa: F401
    import lodsprite.terrain.store  # noqa: F401
    import lodsprite.terrain.textures  # noqa: F401
    from lodsprite.distributed import served  # noqa: F401


def scene_parts(scene: Scene, args: LoadArgs, codec: str = "raw") -> list:
    """The parts (header, heights, texture) of the scene message of ``scene``'s terrain
    layer, as the client's ``args`` (coarse level, size, field of view, ε, visibility)
    asks; raises :class:`~lodsprite.errors.InputError` for a scene without terrain or
    texture."""
    from lodsprite.errors import InputError
    from lodsprite.terrain.proxy import border_ribbon

    hf = scene.hf
    if hf is None or scene.texture is None:
        raise InputError(f"scene {scene.name!r}: a web page draws a textured terrain")
    step = hf.quads // args.lod
    heights = np.ascontiguousarray(hf.heights[::step, ::step][::-1], dtype=np.float32)
    from lodsprite.distributed.served import heights_shaded

    texture = (shaded_texture(scene) if heights_shaded(args.terrain, args.texture,
                                                       scene.terrain_spec) else scene.texture)
    k = -(-max(texture.shape[:2]) // MAX_IMAGE_SIDE)  # keep within the image side cap
    texture = np.ascontiguousarray(texture[::k, ::k][::-1], dtype=np.uint8)
    lo, hi = hf.bounds()
    far = 2.0 * float(np.linalg.norm(hi - lo))  # any eye over the terrain sees all of it
    h_spec, h_data = _spec(heights, codec)
    t_spec, t_data = _spec(texture, codec)
    header = {"kind": "scene", "seq": 0, "coarse": args.lod,
              "origin": [float(lo[0]), float(lo[1])],
              "spacing": hf.dx * step, "spacing_y": hf.dy * step,
              "size": list(args.size), "fov": args.fov_y_deg,
              "near": far / 1e4, "far": far,
              "epsilon": args.epsilon,
              "visibility": "coarse" if args.visibility == "coarse" else "full",
              "heights": h_spec, "texture": t_spec,
              "relief": relief(hf.heights, step),
              "exaggeration": float(hf.meta.get("exaggeration", 1.0))}
    from lodsprite.scene.model import scene_attribution

    credit = scene_attribution(scene)
    if credit:  # the imagery's licence, shown by the page and the widget
        header["attribution"] = credit[:1000]
    ref = hf.meta.get("georef")
    if ref and hf.meta.get("crs"):  # the page's cursor in the dataset's own coordinates
        header["georef"] = {"crs": str(hf.meta["crs"])[:200], "bounds": ref["bounds"],
                            "metres_per_unit": ref["metres_per_unit"]}
    from lodsprite.scene.world import World

    if isinstance(scene.objects, World):
        from lodsprite.distributed.served import page_drawn
        from lodsprite.distributed.web.walkers import walker_header

        walkers = walker_header(scene.objects, page_drawn(args.terrain, scene.objects))
        if walkers is not None:
            header["walkers"] = walkers
    if args.border:
        rib = border_ribbon(hf, args.lod)
        header["ribbon"] = rib.positions.astype("<f4").tobytes()
        header["ribbon_tris"] = rib.tris.astype("<u4").tobytes()
    return encode(header, h_data, t_data)


def shaded_texture(scene: Scene) -> np.ndarray:
    """``(rows, cols, 3) uint8``, row 0 north: a terrain store's working grid in the heights
    shading its keyframes are drawn in (the ramp over level 0's lowest and highest
    heights), so that where the page shows no keyframe it shows the keyframes' colours
    (the terrain texture there read as another terrain)."""
    from lodsprite.terrain.store import TerrainStore
    from lodsprite.terrain.textures import height_shading

    hf = scene.hf
    mm = TerrainStore(scene.terrain_spec, float(hf.meta.get("exaggeration", 1.0))).minmax(0)
    lo, hi = float(np.nanmin(mm[..., 0])), float(np.nanmax(mm[..., 1]))
    k = -(-max(hf.heights.shape) // MAX_IMAGE_SIDE)  # thinned first: the image side cap
    return height_shading(hf.heights[::k, ::k], hf.dx * k, hf.dy * k, lo, hi)


class SceneData:
    """A decoded scene message: ``header`` (:class:`SceneMessage`), ``heights``
    ``(n+1, n+1) float32`` (row 0 south), ``texture (H, W, 3) uint8`` (row 0 south) and
    the border ribbon, ``ribbon (V, 3) float32`` metres and ``ribbon_tris (T, 3) uint32``
    (empty without one); ``walkers`` a scene file's moving objects
    (:func:`~.walkers.decode_walkers`) or None."""

    def __init__(self, header: SceneMessage, heights: np.ndarray, texture: np.ndarray,
                 ribbon: np.ndarray | None = None,
                 ribbon_tris: np.ndarray | None = None) -> None:
        self.header = header
        self.heights = heights
        self.texture = texture
        self.ribbon = np.zeros((0, 3), np.float32) if ribbon is None else ribbon
        self.ribbon_tris = np.zeros((0, 3), np.uint32) if ribbon_tris is None else ribbon_tris
        self.walkers: dict | None = None  # decoded walkers (.walkers.decode_walkers)


def decode_ribbon(msg: SceneMessage) -> tuple[np.ndarray, np.ndarray]:
    """``(vertices (V, 3) float32, triangles (T, 3) uint32)`` of a scene message's border
    ribbon; raises :class:`ProtocolError` when the bytes are not whole vertices and
    triangles or a triangle names a vertex the message lacks (caps: the schema's)."""
    if len(msg.ribbon) % 12 or len(msg.ribbon_tris) % 12:
        raise ProtocolError("ribbon: not whole (x, y, z) vertices and (i, j, k) triangles")
    vertices = np.frombuffer(msg.ribbon, "<f4").reshape(-1, 3).astype(np.float32)
    tris = np.frombuffer(msg.ribbon_tris, "<u4").reshape(-1, 3).astype(np.uint32)
    if tris.size and int(tris.max()) >= len(vertices):
        raise ProtocolError(f"ribbon: a triangle names vertex {int(tris.max())} of "
                            f"{len(vertices)}")
    if not np.isfinite(vertices).all():
        raise ProtocolError("ribbon: a vertex is not finite")
    return vertices, tris


def decode_scene(parts: list) -> SceneData:
    """A :class:`SceneData` from a scene message's parts; raises :class:`ProtocolError`."""
    msg, buffers = decode_message(parts, SceneMessage)
    n = msg.coarse + 1
    heights = decode_image(msg.heights, buffers[0], "float32", None, "heights", False)
    if heights.shape != (n, n):
        raise ProtocolError(f"heights: shape {heights.shape}, expected {(n, n)}")
    texture = decode_image(msg.texture, buffers[1], "uint8", 3, "texture", False)
    data = SceneData(msg, heights, texture, *decode_ribbon(msg))
    if msg.walkers is not None:
        from lodsprite.distributed.web.walkers import decode_walkers

        data.walkers = decode_walkers(msg.walkers)
    return data


def path_data(load: LoadArgs, args: PathArgs, hf: Any = None, root: str | None = None
              ) -> dict:
    """The reply data of ``path`` for a session whose resolved ``load`` is ``load``
    (terrain as a loader spec), over ``hf`` (its working height field, None: loaded
    here); a scene file's path is its scene's own (opened confined to ``root``); raises
    :class:`~lodsprite.errors.LodspriteError` for a path the terrain cannot give."""
    from lodsprite.distributed.served import is_object_scene, open_object_scene
    from lodsprite.paths import get_path

    if is_object_scene(load.terrain):
        path = open_object_scene(load.terrain, root).path(args.spec, args.frames)
    else:
        if hf is None:
            from lodsprite.scene.spec import open_spec

            hf = open_spec(load, light=True).hf  # as build_scene_field
        path = get_path(args.spec, hf, args.frames)
    rows = np.array([np.concatenate([vp.x, vp.y, vp.z, vp.o]) for vp in path.viewpoints],
                    dtype=np.float64)
    return {"viewpoints": rows.tolist(), "fov": float(path.fov_y_deg)}
