"""The technique interface, kept importable here: it lives in :mod:`lodsprite.techniques`
(interface, registry) and :mod:`lodsprite.techniques.terrain` (the terrain techniques)."""

from __future__ import annotations

from lodsprite.techniques import (
    FALLBACK_TINT,
    Frame,
    FrameInfo,
    Param,
    Technique,
    TechniqueFactory,
    factories,
)
from lodsprite.techniques.terrain import FullTechnique, LodTechnique, SpriteTechnique

__all__ = ["FALLBACK_TINT", "Frame", "FrameInfo", "FullTechnique", "LodTechnique", "Param",
           "SpriteTechnique", "Technique", "TechniqueFactory", "terrain_techniques"]


def terrain_techniques(lod: int = 16, epsilon_px: float = 1.0,
                       threaded: bool = True) -> dict[str, TechniqueFactory]:
    """Factories of the basic terrain techniques by mode name: ``full``, ``lod``,
    ``sprite`` (the registry's, :func:`lodsprite.techniques.factories`)."""
    found = factories(("terrain",), lod=lod, epsilon=epsilon_px, threaded=threaded)
    return {k: found[k] for k in ("full", "lod", "sprite")}


def stage_scene(label: str):
    """A placeholder terrain for a technique that draws no terrain (to be replaced by the
    scene's layers)."""
    import numpy as np

    from lodsprite.scene import Scene
    from lodsprite.terrain.heightfield import HeightField

    hf = HeightField(np.zeros((17, 17), np.float32), 1.0, 1.0, name="stage")
    return Scene(hf, np.zeros((16, 16, 3), np.uint8), str(label), "none")
