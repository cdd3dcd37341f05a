"""GL work of the distributed programs: the server's keyframe renderer.

The server renders the full-resolution terrain from the predicted viewpoint and reads
the colour back, so the keyframe can cross the network as plain arrays.  For the
default ``coarse`` visibility rule it sends the coarse level's z-buffer from the same
view (all that rule reads) instead of the full one, so the client only uploads.
Images are read in OpenGL's bottom-up row order and sent as they are.
"""

from __future__ import annotations

from numbers import Real

from lodsprite.camera import Viewpoint
from lodsprite.distributed.pacing import DEFAULT_PACE, PACES, KeyframePacer
from lodsprite.distributed.protocol import Keyframe, ProtocolError
from lodsprite.gl.paths import PathRenderer
from lodsprite.gl.sprite import DEFAULT_VISIBILITY, VISIBILITY_MODES
from lodsprite.gl.target import RenderTarget
from lodsprite.scene import load_scene
from lodsprite.terrain import DEFAULT_EXAGGERATION

SCENE_KEYS = ("terrain", "texture", "grid", "exaggeration", "size", "fov_y_deg")
SPRITE_KEYS = ("lod", "visibility", "border", "epsilon", "pace")


def scene_args(terrain: str, texture: str, grid: int | None, exaggeration: float,
               size: tuple[int, int], fov_y_deg: float = 45.0) -> dict:
    """The scene part of the ``load`` control message's arguments (the client adds its
    ``SPRITE_KEYS``: coarse level, visibility rule, border ribbons, ε in pixels, pace)."""
    return {"terrain": terrain, "texture": texture, "grid": grid,
            "exaggeration": exaggeration, "size": list(size), "fov_y_deg": fov_y_deg}


def check_load_args(args: dict) -> None:
    """Raise :class:`ProtocolError` for ``load`` arguments of the wrong type or range
    (a terrain that does not load is reported by the renderer)."""
    def bad(key: str) -> ProtocolError:
        return ProtocolError(f"load: bad {key} {args.get(key)!r}")

    size = args.get("size", [512, 512])
    if not (isinstance(size, list) and len(size) == 2
            and all(isinstance(n, int) and 1 <= n <= 16384 for n in size)):
        raise bad("size")
    for key in ("exaggeration", "fov_y_deg", "epsilon"):
        value = args.get(key, 1.0)
        if isinstance(value, bool) or not isinstance(value, Real) or not value > 0:
            raise bad(key)
    lod = args.get("lod", 16)
    if isinstance(lod, bool) or not isinstance(lod, int) or lod < 1:
        raise bad("lod")
    if args.get("visibility", DEFAULT_VISIBILITY) not in VISIBILITY_MODES:
        raise bad("visibility")
    if args.get("pace", DEFAULT_PACE) not in PACES:
        raise bad("pace")
    if not isinstance(args.get("border", True), bool):
        raise bad("border")


class KeyframeRenderer:
    """Full-resolution renderer of one scene, created and used on one thread."""

    def __init__(self, args: dict) -> None:
        scene = load_scene(args.get("terrain", "jacksboro"), args.get("texture", "terrain"),
                           args.get("grid"), args.get("exaggeration", DEFAULT_EXAGGERATION))
        size = tuple(args.get("size", (512, 512)))
        self.paths = PathRenderer(scene, size, float(args.get("fov_y_deg", 45.0)))
        self.lod = int(args.get("lod", 16))
        self.border = bool(args.get("border", True))
        self.coarse_z = args.get("visibility", DEFAULT_VISIBILITY) == "coarse"
        self.coarse = RenderTarget(self.paths.ctx, *size, color=False) if self.coarse_z else None
        self.pacer = KeyframePacer(scene.hf, self.lod, float(args.get("epsilon", 1.0)),
                                   size[1], args.get("pace", DEFAULT_PACE))

    def projection(self, viewpoint: Viewpoint):
        return self.paths.renderer.projection(viewpoint)

    def render(self, viewpoint: Viewpoint, seq: int, t0: float) -> Keyframe:
        r = self.paths.renderer
        projection = r.projection(viewpoint)
        r.render(viewpoint, None, projection)
        color = r.target.read_color(copy=False)
        if self.coarse is not None:
            r.render_proxy(viewpoint, self.lod, self.border, projection, self.coarse)
            depth, zbuffer = self.coarse.read_depth(copy=False), "coarse"
        else:
            depth, zbuffer = r.target.read_depth(copy=False), "full"
        self.pacer.rendered(viewpoint)
        return Keyframe(seq, t0, viewpoint, projection, color, depth, zbuffer)

    def release(self) -> None:
        if self.coarse is not None:
            self.coarse.release()
        self.paths.release()
