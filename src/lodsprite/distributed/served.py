"""The scenes of objects a server's pages and widgets draw with image reuse (GL-free).

A page draws a terrain, or a scene of objects standing on a ground: a scene file
(``scene-file``), or a crowd (``crowd[:OBJECTS[:TREES]]``, served as a world on the
crowd's flat ground, :func:`lodsprite.manager.world.world_scene`).  The renderers draw
such a scene's static layers into keyframes; the page draws its walkers.  Other kinds (a
light-field folder, a plug-in's) are refused by the page and shown by the stream widget.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from lodsprite.scene import Scene

__all__ = ["OBJECT_KINDS", "is_object_scene", "open_object_scene"]

OBJECT_KINDS = ("scene-file", "crowd")
"""The kinds of scene of objects a page draws."""


def is_object_scene(spec: str) -> bool:
    """Whether ``spec`` (a resolved name) is a scene of :data:`OBJECT_KINDS`."""
    from lodsprite.manager.technique import SCENE_KIND as CROWD
    from lodsprite.scene.kinds import is_scene_file

    return is_scene_file(spec) or CROWD.claims(spec)


def open_object_scene(spec: str, root: str | None = None) -> Scene:
    """The scene ``spec`` names, of objects on a ground (a crowd as its world); a scene
    file opens confined to ``root`` (the data folder)."""
    from lodsprite.manager.world import world_scene
    from lodsprite.techniques.scenes import open_scene

    return world_scene(open_scene(spec, light=True, root=root))
