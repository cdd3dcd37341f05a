"""The ``scene`` technique's spec (entry point ``scene`` of the group
``lodsprite.techniques``): terrain, objects and light fields composited by depth.  Its
terrain is drawn by any terrain technique of the registry (``terrain_mode``).  The
factory imports the technique when called."""

from __future__ import annotations

from typing import Any

from lodsprite.techniques.builtin import (
    EPSILON,
    GPU_MB,
    HOST_MB,
    KEYFRAMES,
    LOD,
    SHADING,
    SSE,
)
from lodsprite.techniques.options import Option
from lodsprite.techniques.registry import TechniqueSpec

OPTIONS = (
    Option("world", object, None, "the world (default: the scene file's)"),
    Option("terrain_mode", str, "adaptive", "scene: the terrain's technique, any terrain "
           "technique of the registry (lodsprite info)"),
    Option("schedule", str, "none", "scene: the frame budget",
           choices=("none", "scheduler", "independent")),
    Option("target_fps", float, None, "scene: the frame-rate target of the budget", min=0,
           above=True, unit="fps", none="none (no budget)"),
    Option("keyframe_holds", str, "static", "scene, LOD-sprite: keyframes hold the static "
           "layers (static) or the terrain only (terrain)", choices=("static", "terrain")),
    Option("exponent", float, 1.0, "scene: the objects' LOD exponent (0: full meshes)",
           min=0),
    Option("nodes", int, 8, "scene: the light fields' node budget", min=1),
    Option("ground_truth", bool, False, "scene: the full-detail reference"),
    Option("frame_s", float, 1.0 / 30.0, "scene: seconds of world time a frame", min=0,
           above=True, unit="s"),
    Option("terrain_options", object, None, "scene: the terrain technique's own options "
           "(name -> value; lod, epsilon, sse, shading, gpu_mb, host_mb are also options "
           "of the scene)"),
    KEYFRAMES, LOD, EPSILON, SSE, SHADING, GPU_MB, HOST_MB)


def create(renderer: Any, terrain_options: dict[str, Any] | None = None,
           **options: Any) -> Any:
    from lodsprite.layered.technique import create as make

    return make(renderer, **{**(terrain_options or {}), **options})


SCENE = TechniqueSpec("scene", create, OPTIONS, ("terrain", "objects"),
                      "terrain, objects and light fields composited by depth", order=300,
                      batch=False)
