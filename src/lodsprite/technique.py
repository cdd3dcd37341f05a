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
    found = factories(("terrain",), lod=lod, epsilon=epsilon_px,
                      keyframes="worker" if threaded else "inline")
    return {k: found[k] for k in ("full", "lod", "sprite")}

