"""The crowd techniques' specs (entry points ``manager``, ``independent``, ``discrete`` of
the group ``lodsprite.techniques``): the LODManager's crowd (Gumbau et al.) and its two
baselines.  The factory imports the technique when called."""

from __future__ import annotations

from typing import Any

from lodsprite.techniques.options import Option
from lodsprite.techniques.registry import TechniqueSpec

OPTIONS = (
    Option("crowd", object, None, "the crowd (default: the scene's object set)"),
    Option("target_fps", float, None, "crowd: bend the LODs to hold this frame rate",
           min=0, above=True, unit="fps", none="none (no LOD feedback)"),
    Option("slots", int, 16, "crowd: LOD slots per type in the manager's table", min=1),
    Option("active", int, 300, "crowd: objects whose LOD is updated per frame", min=1),
    Option("range_near", float, 5.0, "crowd: distance of the finest LOD", min=0,
           above=True, unit="m"),
    Option("range_far", float, 150.0, "crowd: distance of the coarsest LOD", min=0,
           above=True, unit="m"),
    Option("dist", object, None, "crowd: the snapshots' distribution (default linear)"))


def create(renderer: Any, **options: Any) -> Any:
    from lodsprite.manager.technique import create as make

    return make(renderer, **options)


def _spec(mode: str, text: str, order: int) -> TechniqueSpec:
    return TechniqueSpec(mode, create, OPTIONS, ("objects",), text,
                         fixed={"mode": mode}, order=order)


MANAGER = _spec("manager", "the LODManager's crowd (Gumbau et al.)", 100)
INDEPENDENT = _spec("independent", "every object extracts its own LOD (baseline a)", 110)
DISCRETE = _spec("discrete", "discrete LODs by screen size (baseline b)", 120)
