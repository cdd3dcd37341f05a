"""The crowd scene of Gumbau et al. (§5.3, Figure 1): thousands of LOD objects of a few
types standing on a ground, trees among them, and a walkthrough path; GL-free.

Objects are placed on a jittered grid (about ``spacing`` metres apart) over a square
centred on the origin, each turned at random about ``+z``; trees are scattered over the
same square.  The walkthrough is a closed loop at eye height through the crowd, looking
ahead along the motion.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lodsprite.camera import look_at
from lodsprite.errors import InputError
from lodsprite.manager.models import LodModel
from lodsprite.paths import CameraPath

MAX_OBJECTS = 200_000
EYE_HEIGHT_M = 1.7


@dataclass
class Crowd:
    """``models`` by type; per object: ``types (N,) int``, ``positions (N, 3)`` metres
    (feet), ``yaw (N,)`` radians; the ground's half width ``extent`` (metres)."""

    models: list[LodModel]
    types: np.ndarray
    positions: np.ndarray
    yaw: np.ndarray
    extent: float

    def __len__(self) -> int:
        return len(self.types)

    @property
    def radii(self) -> np.ndarray:
        """Each object's bounding radius (metres), ``(N,)``."""
        return np.array([m.radius for m in self.models])[self.types]

    @property
    def centres(self) -> np.ndarray:
        """Each object's bounding-sphere centre, ``(N, 3)``: half its height above its
        feet."""
        heights = np.array([m.vertices[:, 2].max() for m in self.models])[self.types]
        return self.positions + np.stack([np.zeros(len(self)), np.zeros(len(self)),
                                          heights / 2], axis=1)


def build_crowd(models: list[LodModel], objects: int = 3000, trees: int = 0,
                tree_model: LodModel | None = None, spacing: float = 4.0,
                seed: int = 1) -> Crowd:
    """``objects`` crowd members (type 0, ``models[0]``) and ``trees`` trees
    (``tree_model``, the last type) over one square."""
    if objects < 0 or trees < 0 or objects + trees == 0:
        raise InputError(f"a crowd needs a positive number of objects, got {objects} "
                         f"objects and {trees} trees")
    if objects + trees > MAX_OBJECTS:
        raise InputError(f"at most {MAX_OBJECTS:,} objects, got {objects + trees:,}")
    if trees and tree_model is None:
        raise InputError("trees need a tree model")
    rng = np.random.default_rng(seed)
    side = max(1, int(np.ceil(np.sqrt(max(objects, 1)))))
    extent = side * spacing / 2
    ij = np.stack(np.unravel_index(np.arange(objects), (side, side)), axis=1)
    xy = (ij + 0.5) * spacing - extent + rng.uniform(-0.35, 0.35, (objects, 2)) * spacing
    txy = rng.uniform(-extent, extent, (trees, 2))
    all_xy = np.concatenate([xy, txy])
    positions = np.concatenate([all_xy, np.zeros((len(all_xy), 1))], axis=1)
    kinds = list(models) + ([tree_model] if trees else [])
    types = np.concatenate([np.zeros(objects, np.int64),
                            np.full(trees, len(kinds) - 1, np.int64)])
    return Crowd(kinds, types, positions, rng.uniform(0, 2 * np.pi, len(types)), extent)


def walkthrough(crowd: Crowd, frames: int = 600, laps: float = 1.0) -> CameraPath:
    """A closed loop at eye height through the crowd (an ellipse over 70 % of the ground),
    looking ahead along the motion and a little down."""
    if frames < 2:
        raise InputError(f"a path needs at least 2 frames, got {frames}")
    a = np.linspace(0.0, 2 * np.pi * laps, frames, endpoint=False)
    rx, ry = 0.7 * crowd.extent, 0.45 * crowd.extent
    eyes = np.stack([rx * np.cos(a), ry * np.sin(a), np.full_like(a, EYE_HEIGHT_M)], 1)
    ahead = np.stack([-rx * np.sin(a), ry * np.cos(a), np.zeros_like(a)], 1)
    ahead /= np.linalg.norm(ahead, axis=1, keepdims=True)
    targets = eyes + 20.0 * ahead - np.array([0.0, 0.0, 1.2])
    return CameraPath("crowd-walkthrough", tuple(look_at(e, t) for e, t in zip(
        eyes, targets, strict=True)), 60.0)


def spheres_in_frustum(planes: np.ndarray, centres: np.ndarray, radii: np.ndarray
                       ) -> np.ndarray:
    """``(N,) bool``: spheres not wholly outside any of the frustum's ``planes (6, 4)``
    (``a x + b y + c z + d >= 0`` inside, normals unit)."""
    d = centres @ planes[:, :3].T + planes[:, 3]
    return (d >= -radii[:, None]).all(axis=1)
