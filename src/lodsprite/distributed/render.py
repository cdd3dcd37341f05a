"""GL work of the distributed programs: the server's keyframe renderer.

The server renders the full-resolution terrain from the predicted viewpoint and reads
the colour and depth back, so the keyframe can cross the network as plain arrays.
"""

from __future__ import annotations

from lodsprite.camera import Viewpoint
from lodsprite.distributed.protocol import Keyframe
from lodsprite.run import PathRenderer
from lodsprite.scene import load_scene
from lodsprite.terrain import DEFAULT_EXAGGERATION

SCENE_KEYS = ("terrain", "texture", "grid", "exaggeration", "size", "fov_y_deg")


def scene_args(terrain: str, texture: str, grid: int | None, exaggeration: float,
               size: tuple[int, int], fov_y_deg: float = 45.0) -> dict:
    """The ``load`` control message's arguments: everything both sides must agree on."""
    return {"terrain": terrain, "texture": texture, "grid": grid,
            "exaggeration": exaggeration, "size": list(size), "fov_y_deg": fov_y_deg}


class KeyframeRenderer:
    """Full-resolution renderer of one scene, created and used on one thread."""

    def __init__(self, args: dict) -> None:
        scene = load_scene(args.get("terrain", "jacksboro"), args.get("texture", "terrain"),
                           args.get("grid"), args.get("exaggeration", DEFAULT_EXAGGERATION))
        size = tuple(args.get("size", (512, 512)))
        self.paths = PathRenderer(scene, size, float(args.get("fov_y_deg", 45.0)))

    def render(self, viewpoint: Viewpoint, seq: int, t0: float) -> Keyframe:
        r = self.paths.renderer
        projection = r.projection(viewpoint)
        r.render(viewpoint, None, projection)
        color, depth = r.target.read_color(), r.target.read_depth()
        return Keyframe(seq, t0, viewpoint, projection, color, depth)

    def release(self) -> None:
        self.paths.release()
