"""A scene: the working height field and its colour texture, loaded from user specs."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lodsprite.terrain import DEFAULT_EXAGGERATION, HeightField, load_terrain, make_texture


@dataclass(frozen=True)
class Scene:
    """Working height field (metres, power-of-two grid) and its ``(H, W, 3) uint8`` texture."""

    hf: HeightField
    texture: np.ndarray
    terrain_spec: str
    texture_spec: str


def load_scene(terrain: str = "jacksboro", texture: str = "terrain", grid: int | None = None,
               exaggeration: float = DEFAULT_EXAGGERATION) -> Scene:
    """Load, resample and texture a terrain (raises :class:`~lodsprite.TerrainError`)."""
    hf = load_terrain(terrain, grid=grid, exaggeration=exaggeration)
    return Scene(hf, make_texture(texture, hf), terrain, texture)
