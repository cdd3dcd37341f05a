"""Scenes of the LOD-matching experiments (Scoggins et al. 2000 §4.2-4.3), as arrays.

* The sphereflake spiral (Figure 7): sphereflakes drawn at geometrically increasing
  distances (the importance-sampling ratio of §3.3), arranged in a spiral about the view
  axis, nearest in the upper left and farthest near the centre, under a 10 degree field
  of view.  Each sphere of each flake is one object (a model matrix placing the unit-
  diameter LOD sphere), so every sphere gets its own LOD.
* The mountain sweep (Figure 6b, 8): a 30 degree camera moving away from the mountain
  at evenly spaced distances, looking at its centre.

Pure numpy: no GL here.  World space is right-handed, +z up; the camera of the spiral
sits at the origin and looks along +y.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lodsprite.camera import Projection, Viewpoint, look_at

SPIRAL_FOV_DEG = 10.0   # §4.2
MOUNTAIN_FOV_DEG = 30.0  # §4.3


@dataclass(frozen=True, eq=False)
class Shot:
    """One image: objects ``models (K, 4, 4)`` (object-to-world) of one LOD chain, the group
    each belongs to ``group (K,)`` (a flake or a frame), and the camera."""

    models: np.ndarray
    group: np.ndarray
    viewpoint: Viewpoint
    projection: Projection

    @property
    def view_proj(self) -> np.ndarray:
        return self.projection.matrix() @ self.viewpoint.view_matrix()


def placement(centre: np.ndarray, scale: float | np.ndarray) -> np.ndarray:
    """Model matrices ``(K, 4, 4)``: uniform ``scale (K,)``, then a move to ``centre (K, 3)``."""
    centre = np.atleast_2d(np.asarray(centre, dtype=np.float64))
    scale = np.broadcast_to(np.asarray(scale, dtype=np.float64), (len(centre),))
    m = np.zeros((len(centre), 4, 4))
    m[:, 0, 0] = m[:, 1, 1] = m[:, 2, 2] = scale
    m[:, :3, 3] = centre
    m[:, 3, 3] = 1.0
    return m


def spiral(flake_centres: np.ndarray, flake_radii: np.ndarray, count: int, first: float,
           ratio: float, size: int = 512, sphere_radius: float = 0.5,
           fov_y_deg: float = SPIRAL_FOV_DEG) -> tuple[Shot, np.ndarray]:
    """``count`` sphereflakes at distances ``first * ratio**n`` (units of the LOD sphere's
    diameter when ``sphere_radius`` is 0.5) in a spiral about the view axis.

    ``flake_centres (S, 3)``, ``flake_radii (S,)``: one flake's spheres.  Returns the shot
    (``count * S`` objects, group = flake number) and the flake distances ``(count,)``.
    """
    dist = first * ratio ** np.arange(count)
    extent = float(np.max(np.linalg.norm(flake_centres, axis=1) + flake_radii))
    half = dist * math.tan(math.radians(fov_y_deg) / 2.0)
    # Off-axis radius (fraction of the half-height) shrinks towards the centre.
    room = np.clip(1.0 - extent / half - 0.04, 0.0, None)
    rho = room * np.linspace(1.0, 0.08, count)
    psi = math.radians(135.0) - np.arange(count) * (2 * math.pi / 7.0)
    offsets = np.stack([rho * half * np.cos(psi), dist, rho * half * np.sin(psi)], axis=1)
    centres = (offsets[:, None, :] + flake_centres[None, :, :]).reshape(-1, 3)
    scales = np.tile(flake_radii / sphere_radius, count)
    group = np.repeat(np.arange(count), len(flake_radii))
    vp = look_at(np.zeros(3), np.array([0.0, 1.0, 0.0]))
    near = max(float(dist[0] - extent) * 0.5, 1e-3)
    proj = Projection(fov_y_deg, 1.0, near, float(dist[-1] + extent) * 1.5)
    return Shot(placement(centres, scales), group, vp, proj), dist


def sweep_distances(radius: float, count: int, far_ratio: float,
                    fov_y_deg: float = MOUNTAIN_FOV_DEG) -> np.ndarray:
    """``count`` evenly spaced camera distances ``(count,)`` from where an object of bounding
    ``radius`` fills the view to ``far_ratio`` times that."""
    near = radius / math.sin(math.radians(fov_y_deg) / 2.0)
    return np.linspace(near, near * far_ratio, count)


def sweep_shot(centre: np.ndarray, radius: float, distance: float, phi_deg: float,
               theta_deg: float, fov_y_deg: float = MOUNTAIN_FOV_DEG) -> Shot:
    """One frame of the sweep: the object at the origin (identity model), the camera
    ``distance`` from ``centre`` towards azimuth ``phi`` and elevation ``theta``."""
    p, t = math.radians(phi_deg), math.radians(theta_deg)
    d = np.array([math.cos(t) * math.cos(p), math.cos(t) * math.sin(p), math.sin(t)])
    centre = np.asarray(centre, dtype=np.float64)
    vp = look_at(centre + distance * d, centre)
    proj = Projection(fov_y_deg, 1.0, max(distance - 1.5 * radius, distance * 1e-3),
                      distance + 1.5 * radius)
    return Shot(np.eye(4)[None], np.zeros(1, dtype=np.int64), vp, proj)
