"""A crowd (Gumbau et al.'s scene, :mod:`lodsprite.manager.scene`) as a world standing on
flat ground: the scene model a server's renderers and pages draw (the static layers in
keyframes, the walkers by the page), so ``crowd:N`` is served as a scene file is (GL-free).

The ground is the crowd's own: a flat square of half width 1.5 × the crowd's extent (the
square :class:`~lodsprite.gl.crowd.CrowdGL` draws), :data:`GROUND_QUADS` quads a side, its
texture the same grid of lines every :data:`LINE_M` metres in the same two colours, at
:data:`TEXEL_M` metres a texel (at most :data:`MAX_TEXTURE_SIDE` a side).  Every member
and tree becomes a standing instance of its type, at its place and heading; a type keeps
its LOD model (the same progressive mesh the crowd draws).
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from lodsprite.manager.scene import Crowd
    from lodsprite.scene import Scene
    from lodsprite.scene.world import World
    from lodsprite.terrain import HeightField

__all__ = ["GROUND_QUADS", "crowd_ground", "crowd_world", "ground_texture", "world_scene"]

GROUND_QUADS = 64
"""Quads a side of the flat ground's height field."""
GROUND_SCALE = 1.5
"""The ground's half width over the crowd's extent (as the crowd's own ground square)."""
LINE_M = 8.0
"""The ground's grid lines: one every this many metres (as the crowd's ground shader)."""
LINE_SHARE = 0.06
"""The share of a grid cell a line covers."""
FIELD_RGB = (0.36, 0.42, 0.3)
LINE_RGB = (0.3, 0.35, 0.25)
TEXEL_M = 0.25
MAX_TEXTURE_SIDE = 2048


def ground_texture(half_m: float) -> np.ndarray:
    """``(n, n, 3) uint8``: the ground's texture over ``[-half_m, half_m]²`` metres (row 0
    north), texel centres sampled as the crowd's ground shader colours its fragments."""
    n = int(min(MAX_TEXTURE_SIDE, max(2, np.ceil(2 * half_m / TEXEL_M))))
    c = (np.arange(n) + 0.5) / n * 2 * half_m - half_m
    g = np.abs((c / LINE_M) % 1.0 - 0.5)                      # GLSL's fract
    on_x = g >= 0.5 - LINE_SHARE / 2
    line = on_x[None, :] | on_x[::-1, None]                    # rows north to south
    rgb = np.where(line[..., None], LINE_RGB, FIELD_RGB)
    return np.round(rgb * 255).astype(np.uint8)


def crowd_ground(crowd: Crowd) -> HeightField:
    """The crowd's flat ground: heights 0 over a square of half width
    :data:`GROUND_SCALE` × its extent (metres)."""
    from lodsprite.terrain import HeightField

    side = 2 * GROUND_SCALE * float(crowd.extent)
    d = side / GROUND_QUADS
    return HeightField(np.zeros((GROUND_QUADS + 1, GROUND_QUADS + 1), np.float32), d, d,
                       "crowd-ground")


def crowd_world(crowd: Crowd, ground: HeightField) -> World:
    """``crowd``'s members and trees as standing instances of its types on ``ground``."""
    from lodsprite.scene.objects import model_type
    from lodsprite.scene.world import Instances, World

    types = [model_type(m.name, m, "linear", m.triangles(0.0) / max(1, m.triangles(1.0)))
             for m in crowd.models]
    instances = [Instances(t, crowd.positions[crowd.types == t, :2].astype(np.float64),
                           crowd.yaw[crowd.types == t].astype(np.float64))
                 for t in range(len(types)) if (crowd.types == t).any()]
    return World(types, instances, ground)


def world_scene(scene: Scene) -> Scene:
    """``scene`` with its crowd as a world on the crowd's ground (module doc): a terrain
    layer (the ground and its texture), the objects a :class:`World`, its paths the
    crowd's ``walk`` and the built-in terrain paths over the ground.  A scene without a
    crowd is returned as it is."""
    from lodsprite.manager.scene import Crowd, walkthrough
    from lodsprite.paths import get_path

    crowd = scene.objects
    if not isinstance(crowd, Crowd) or scene.hf is not None:
        return scene
    ground = crowd_ground(crowd)

    def paths(name: str, frames: int | None):
        return walkthrough(crowd, frames or 600) if name == "walk" else get_path(
            name, ground, frames)

    return replace(scene, hf=ground, texture=ground_texture(ground.width / 2),
                   objects=crowd_world(crowd, ground), paths=paths)
