"""Camera paths round a light field: the arc in front of one slab, the orbit round six.

Below both the run (:mod:`lodsprite.lumigraph.run`) and the technique
(:mod:`lodsprite.lumigraph.technique`), which both fly them.  Eyes and targets in the
lumigraph's world units; the paths' vertical field of view is :data:`FOV_Y_DEG` degrees.
"""

from __future__ import annotations

import numpy as np

from lodsprite.camera import look_at
from lodsprite.errors import InputError
from lodsprite.lumigraph.geometry import Slab
from lodsprite.lumigraph.store import Lumigraph
from lodsprite.paths import CameraPath

FOV_Y_DEG = 30.0


def object_path(slab: Slab, frames: int, arc_deg: float = 50.0) -> CameraPath:
    """An arc of ``frames`` viewpoints in front of the slab, looking at the uv plane's
    centre, that stays within the st plane's coverage: eyes at 1.6 times the st plane's
    distance, swinging ``arc_deg`` degrees about the slab's up axis, a little above."""
    if frames < 2:
        raise InputError(f"a path needs at least 2 frames, got {frames}")
    d = 1.6 * slab.st_distance
    a = np.radians(np.linspace(-arc_deg / 2, arc_deg / 2, frames))
    local = np.stack([d * np.sin(a), np.full_like(a, 0.12 * d), d * np.cos(a),
                      np.ones_like(a)], axis=1)
    eyes = local @ slab.frame.T
    centre = slab.frame[:3, 3]
    up = slab.frame[:3, 1]
    return CameraPath("lumigraph-arc", tuple(look_at(e[:3], centre, up) for e in eyes),
                      FOV_Y_DEG)


def orbit_path(slabs: list[Slab], frames: int, elevation_deg: float = 15.0) -> CameraPath:
    """A full orbit round the object of a six-slab lumigraph, about its y axis, at 2.2
    times the st planes' distance, looking at the centre."""
    if frames < 2:
        raise InputError(f"a path needs at least 2 frames, got {frames}")
    centre = slabs[0].frame[:3, 3]
    d = 2.2 * max(s.st_distance for s in slabs)
    a = np.linspace(0.0, 2 * np.pi, frames, endpoint=False)
    e = np.radians(elevation_deg)
    eyes = centre + d * np.stack([np.cos(e) * np.sin(a), np.full_like(a, np.sin(e)),
                                  np.cos(e) * np.cos(a)], axis=1)
    return CameraPath("lumigraph-orbit", tuple(look_at(p, centre, (0.0, 1.0, 0.0))
                                               for p in eyes), FOV_Y_DEG)


def default_path(lf: Lumigraph, frames: int) -> CameraPath:
    """The arc in front of a one-slab lumigraph, the orbit round a six-slab one."""
    return object_path(lf.slabs[0], frames) if len(lf.slabs) == 1 else orbit_path(lf.slabs,
                                                                                frames)
