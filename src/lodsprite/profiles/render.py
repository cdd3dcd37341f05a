"""Render shots of LOD-chain objects (each object at its own LOD) to images.

A thin layer over :class:`lodsprite.gl.mesh.MeshDrawer` that keeps one chain's levels on
the GPU and turns a :class:`~lodsprite.profiles.scenes.Shot` plus per-object LOD indices
into an ``(H, W, 3) uint8`` image, optionally colour-coded by LOD as in the paper's
Figures 7c and 8 (red: high LOD number, green: low, white: the full model).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from lodsprite.gl.context import GLContext
from lodsprite.gl.mesh import MeshDrawer, MeshSet
from lodsprite.profiles.generate import DEFAULT_LIGHT
from lodsprite.profiles.scenes import Shot

GREEN = np.array([0.15, 0.8, 0.2])
RED = np.array([0.9, 0.15, 0.1])


def lod_colours(levels: np.ndarray, n_levels: int) -> np.ndarray:
    """Albedo ``(K, 3)`` coding LOD ``levels (K,)``: green (coarsest) to red (finest
    simplified level), white for the full model (level ``n_levels - 1``)."""
    levels = np.asarray(levels, dtype=np.int64)
    t = levels / max(n_levels - 2, 1)
    rgb = GREEN[None, :] * (1 - t[:, None]) + RED[None, :] * t[:, None]
    rgb[levels == n_levels - 1] = 1.0
    return rgb


class ChainDrawer:
    """Draws shots of one LOD chain's objects into ``size x size`` images."""

    def __init__(self, ctx: GLContext, levels: Sequence[tuple[np.ndarray, np.ndarray]],
                 size: int = 512, samples: int = 4,
                 light: Sequence[float] = DEFAULT_LIGHT) -> None:
        self.ctx = ctx
        self.levels = len(levels)
        self.light = tuple(float(v) for v in light)
        self.meshes = MeshSet(ctx, levels)
        self.drawer = MeshDrawer(ctx, size, size, samples=samples)

    @property
    def size(self) -> int:
        return self.drawer.width

    def image(self, shot: Shot, lods: np.ndarray, coded: bool = False) -> np.ndarray:
        """The shot with object ``k`` drawn at LOD ``lods[k]``; ``(H, W, 3) uint8``."""
        albedo = lod_colours(lods, self.levels) if coded else None
        self.drawer.render(self.meshes, lods, shot.models, shot.view_proj, self.light,
                             albedo=albedo)
        img = self.drawer.read_rgb8()
        self.ctx.check_error("shot")
        return img

    def full(self, shot: Shot) -> np.ndarray:
        """The shot with every object at full resolution."""
        return self.image(shot, np.full(len(shot.models), self.levels - 1))

    def release(self) -> None:
        self.drawer.forget(self.meshes)
        self.meshes.release()
        self.drawer.release()
