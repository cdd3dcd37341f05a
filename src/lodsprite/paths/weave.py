"""A low path among a scene's objects: ``weave[:HEIGHT_M[:HALF_M[:TURNS]]]``.

The flights of :mod:`lodsprite.paths.flyover` pass high over a scene; a viewer among its
objects (the battlefield of Chen, Swan & Kaufman 1999, issue 23) walks or drives low
between them, sees them large and near and the terrain at grazing angles.  ``weave``
flies north across a square of half side ``half_m`` metres centred on the terrain's
centre (at most 45 % of the terrain's smaller side), weaving east and west ``turns``
times (``x = 0.6 half_m sin(pi turns s)``, ``s`` from 0 to 1 along the track, so the
camera crosses the crowd's middle and its sides), ``height_m`` above a smoothed running
maximum of the ground under the track (:func:`~lodsprite.paths.flyover.ground_floor`,
so about the highest ground within ``height_m`` along it, and never less than the ground
under the eye), looking along the direction of
travel pitched down by ``PITCH_DEG``.  The default height, 8 m, is 2-5 times the height
of a person-sized object (2.2 m, the built-in ogre); metres, whatever the terrain's size.
"""

from __future__ import annotations

import math

import numpy as np

from lodsprite.camera import Viewpoint
from lodsprite.errors import PathError
from lodsprite.paths.core import CHEN1999_FRAMES, CameraPath, _check_frames
from lodsprite.paths.flyover import ground_floor
from lodsprite.terrain.heightfield import HeightField

WEAVE_HEIGHT_M = 8.0
WEAVE_HALF_M = 400.0
WEAVE_TURNS = 3
WEAVE_SPEC = "weave[:HEIGHT_M[:HALF_M[:TURNS]]]"
PITCH_DEG = 8.0
_SAMPLES = 2048  # ground samples along the track


def parse_weave(spec: str) -> tuple[float, float, int] | None:
    """``weave[:HEIGHT_M[:HALF_M[:TURNS]]]`` as ``(height_m, half_m, turns)``; None for
    other specs; raises :class:`PathError` when malformed."""
    head, *rest = spec.strip().lower().split(":")
    if head != "weave":
        return None
    if len(rest) > 3:
        raise PathError(f"path {spec!r}: use {WEAVE_SPEC}")
    try:
        values = [float(v) for v in rest]
    except ValueError:
        raise PathError(f"path {spec!r}: height, half side and turns are numbers") from None
    height, half, turns = values + [WEAVE_HEIGHT_M, WEAVE_HALF_M, float(WEAVE_TURNS)
                                    ][len(values):]
    if not (math.isfinite(height) and height > 0 and math.isfinite(half) and half > 0):
        raise PathError(f"path {spec!r}: height and half side must be positive metres")
    if turns != int(turns) or not 1 <= turns <= 100:
        raise PathError(f"path {spec!r}: turns must be a whole number in 1..100")
    return height, half, int(turns)


def weave_track(half_m: float, turns: int, s: np.ndarray) -> np.ndarray:
    """The track's ``(len(s), 2)`` x, y metres at ``s`` in 0..1 (module docstring)."""
    return np.stack([0.6 * half_m * np.sin(math.pi * turns * s),
                     half_m * (2.0 * s - 1.0)], axis=1)


def weave(hf: HeightField, frames: int = CHEN1999_FRAMES, height_m: float = WEAVE_HEIGHT_M,
          half_m: float = WEAVE_HALF_M, turns: int = WEAVE_TURNS) -> CameraPath:
    """The low weaving path (module docstring): ``frames`` viewpoints evenly spaced in
    the track's parameter."""
    n = _check_frames(frames)
    half = min(half_m, 0.45 * min(hf.width, hf.depth))
    s = np.linspace(0.0, 1.0, _SAMPLES)
    xy = weave_track(half, turns, s)
    step = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    floor = ground_floor(hf.height_at(xy[:, 0], xy[:, 1]), float(step.mean()), height_m)
    si = np.linspace(0.0, 1.0, n)
    at = weave_track(half, turns, si)
    ahead = weave_track(half, turns, np.minimum(si + 1e-3, 1.0)) - weave_track(
        half, turns, np.maximum(si - 1e-3, 0.0))
    heading = ahead / np.linalg.norm(ahead, axis=1, keepdims=True)
    z = np.maximum(np.interp(si, s, floor), hf.height_at(at[:, 0], at[:, 1])) + height_m
    p = math.radians(PITCH_DEG)
    views = []
    for i in range(n):
        h = np.array([heading[i, 0], heading[i, 1], 0.0])
        d = -math.cos(p) * h + np.array([0.0, 0.0, math.sin(p)])  # the camera looks along -d
        up = math.sin(p) * h + np.array([0.0, 0.0, math.cos(p)])
        views.append(Viewpoint(np.cross(up, d), up, d, np.array([at[i, 0], at[i, 1], z[i]])))
    return CameraPath(f"weave:{height_m:g}:{half_m:g}:{turns}", tuple(views))
