"""The scenes of objects a server's pages and widgets draw with image reuse (GL-free).

A page draws a terrain, or a scene of objects standing on a ground: a scene file
(``scene-file``), or a crowd (``crowd[:OBJECTS[:TREES]]``, served as a world on the
crowd's flat ground, :func:`lodsprite.manager.world.world_scene`).  The renderers draw
such a scene's static layers into keyframes; the page draws its walkers and a crowd's
members, standing (:func:`page_drawn`; a crowd's trees stay in the keyframes).  Other
kinds (a light-field folder alone, a plug-in's) are refused by the page and shown by the
stream widget.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from lodsprite.scene.world import World

if TYPE_CHECKING:
    from lodsprite.scene import Scene

__all__ = ["OBJECT_KINDS", "heights_shaded", "is_object_scene", "keyframe_world",
           "open_object_scene", "page_drawn"]

OBJECT_KINDS = ("scene-file", "crowd")
"""The kinds of scene of objects a page draws."""


def is_object_scene(spec: str) -> bool:
    """Whether ``spec`` (a resolved name) is a scene of :data:`OBJECT_KINDS`."""
    from lodsprite.manager.technique import SCENE_KIND as CROWD
    from lodsprite.scene.kinds import is_scene_file

    return is_scene_file(spec) or CROWD.claims(spec)


def heights_shaded(terrain: str, texture: str, terrain_spec: str) -> bool:
    """Whether the keyframes of a load naming ``terrain`` with ``texture`` are the heights
    shading of a terrain store (``terrain_spec``: the scene's terrain, a path): a store's
    are, unless a terrain load asked for another texture or the store holds imagery (then
    draped, as ``auto`` drapes it); a scene file's or a crowd's terrain is shaded as the
    window's ``auto`` shades it, a store from its heights."""
    from lodsprite.scene.model import store_imagery
    from lodsprite.terrain.store_format import is_store

    if not terrain_spec or not is_store(terrain_spec) or store_imagery(terrain_spec):
        return False  # a store with imagery: draped, as auto drapes it
    return is_object_scene(terrain) or texture == "terrain"


def page_drawn(spec: str, world: World) -> np.ndarray:
    """``(count,) bool``: the instances of ``spec``'s world the page draws itself, each
    frame (instanced at their LOD, as :mod:`~lodsprite.distributed.web.walkers`): the
    walkers, and a crowd's members (its first type) though they stand.  The eye walks
    among a crowd, where a member a few metres away parallaxes tens of pixels within one
    keyframe's latency (measured with the members in the keyframes: 25 px estimate,
    judged RMSE 23-51 along its walk at 20 m/s); drawn each frame, they are where they
    are at any view.  A crowd's trees stay in the keyframes: a tree's mesh is past what a
    scene message carries (:data:`~lodsprite.distributed.messages.MAX_WALKER_VERTICES`)."""
    from lodsprite.manager.technique import SCENE_KIND as CROWD

    drawn = world.moving()
    if CROWD.claims(spec):
        drawn = drawn | (world.type_indices() == 0)
    return drawn


def keyframe_world(world: World, drawn: np.ndarray) -> World:
    """``world`` without the instances the page draws (``drawn``, :func:`page_drawn`):
    what a renderer draws into keyframes."""
    out, k = [], 0
    for inst in world.instances:
        keep = ~drawn[k:k + len(inst)]
        k += len(inst)
        if keep.any():
            out.append(replace(inst, xy=inst.xy[keep], yaw=inst.yaw[keep]))
    return replace(world, instances=out)


def open_object_scene(spec: str, root: str | None = None, keyframes: bool = False
                      ) -> Scene:
    """The scene ``spec`` names, of objects on a ground (a crowd as its world); a scene
    file opens confined to ``root`` (the data folder).  ``keyframes``: the scene a
    renderer draws into keyframes, without the objects the page draws itself
    (:func:`page_drawn`)."""
    from lodsprite.manager.world import world_scene
    from lodsprite.techniques.scenes import open_scene

    scene = world_scene(open_scene(spec, light=True, root=root))
    if keyframes and isinstance(scene.objects, World):
        scene = replace(scene, objects=keyframe_world(scene.objects,
                                                      page_drawn(spec, scene.objects)))
    return scene
