"""Low flights at a fixed height above the ground, the same in metres whatever the
terrain's size: ``flyover`` (the path for comparing renderers across terrain sizes) and
``patrol`` (back and forth over one stretch).

The papers' paths scale with the terrain (Chen et al. 1999 orbit at 1.5 ``L``): over a
491 km field they fly so high that coarse levels meet one pixel almost everywhere, so a
view-dependent renderer's work and error no longer depend on the data.  ``flyover`` flies
north along the terrain's centre line, ``track_m`` metres long (at most 90 % of the
terrain's depth), ``height_m`` above the highest ground within ``height_m`` of the track
ahead and behind (a smoothed running maximum that never falls below it), looking along
the track pitched down by ``PITCH_DEG``; the ground is sampled from the in-memory field.

``patrol``: back and forth over one stretch of the terrain, several passes - the case for
which Chen, Swan & Kaufman (1999, §5) propose a cache of keyframes (a viewer moving back
and forth in one region sees the same views again).  The camera flies the centre line of
a ``track_m`` metre stretch (at most 90 % of the terrain's depth) ``passes`` times, north
then south then north ..., easing in and out at each end (``y = -L/2 cos(pi passes t)``),
``height_m`` above the flyover's floor, low enough that keyframes are needed.  It keeps
its heading (north, pitched down as the flyover): a patrol camera on a dolly, so
that every pass sees the views of the others; one that turned round at the ends would see
two sets of views and need twice the cache.  Metres, whatever the terrain's size.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from lodsprite.camera import Viewpoint
from lodsprite.errors import PathError
from lodsprite.paths.core import CHEN1999_FRAMES, CameraPath, _check_frames
from lodsprite.terrain.heightfield import HeightField

DEFAULT_HEIGHT_M = 1000.0
DEFAULT_TRACK_M = 10000.0
PATROL_HEIGHT_M = 500.0
PATROL_TRACK_M = 4000.0
PATROL_PASSES = 6
PATROL_SPEC = "patrol[:HEIGHT_M[:TRACK_M[:PASSES]]]"
PITCH_DEG = 20.0
_SAMPLES = 2048  # ground samples along the track


def parse_flyover(spec: str) -> tuple[float, float] | None:
    """``flyover[:HEIGHT_M[:TRACK_M]]`` as ``(height_m, track_m)``; None for other specs;
    raises :class:`PathError` when malformed."""
    head, *rest = spec.strip().lower().split(":")
    if head != "flyover":
        return None
    if len(rest) > 2:
        raise PathError(f"path {spec!r}: use flyover[:HEIGHT_M[:TRACK_M]]")
    try:
        values = [float(v) for v in rest]
    except ValueError:
        raise PathError(f"path {spec!r}: height and track are metres (numbers)") from None
    height = values[0] if values else DEFAULT_HEIGHT_M
    track = values[1] if len(values) > 1 else DEFAULT_TRACK_M
    if not (math.isfinite(height) and height > 0 and math.isfinite(track) and track > 0):
        raise PathError(f"path {spec!r}: height and track must be positive metres")
    return height, track


def ground_floor(ground: np.ndarray, step_m: float, height_m: float) -> np.ndarray:
    """A smooth floor ``(S,) metres`` under the ground heights ``ground (S,)`` sampled every
    ``step_m`` metres along a track: the mean, over ``±reach/2``, of maxima over
    ``±2 reach`` (``reach`` = ``height_m`` in samples), so at least the highest ground
    within ``±height_m`` (every maximum averaged covers that window)."""
    reach = max(1, int(math.ceil(height_m / step_m)))
    floor = ndimage.maximum_filter1d(ground, 4 * reach + 1, mode="nearest")
    return ndimage.uniform_filter1d(floor, reach, mode="nearest")


def flyover(hf: HeightField, frames: int = CHEN1999_FRAMES, height_m: float = DEFAULT_HEIGHT_M,
            track_m: float = DEFAULT_TRACK_M) -> CameraPath:
    """The flight (module docstring): ``frames`` viewpoints evenly spaced along the track."""
    n = _check_frames(frames)
    length = min(track_m, 0.9 * hf.depth)
    ys = np.linspace(-length / 2, length / 2, n)
    return CameraPath(f"flyover:{height_m:g}:{track_m:g}", along_track(hf, ys, length,
                                                                      height_m))


def along_track(hf: HeightField, ys: np.ndarray, length: float,
                height_m: float) -> tuple[Viewpoint, ...]:
    """Viewpoints at ``ys (N,)`` metres north on the centre line of a track ``length``
    metres long, ``height_m`` above its smoothed running maximum ground, looking north
    pitched down by ``PITCH_DEG``."""
    y = np.linspace(-length / 2, length / 2, _SAMPLES)
    ground = hf.height_at(np.zeros_like(y), y)
    floor = ground_floor(ground, length / (_SAMPLES - 1), height_m)
    zs = np.interp(ys, y, floor) + height_m
    p = math.radians(PITCH_DEG)
    d = np.array([0.0, -math.cos(p), math.sin(p)])  # the camera looks along -d
    up = np.array([0.0, math.sin(p), math.cos(p)])
    right = np.cross(up, d)
    return tuple(Viewpoint(right, up, d, np.array([0.0, ys[i], zs[i]]))
                 for i in range(len(ys)))


def parse_patrol(spec: str) -> tuple[float, float, int] | None:
    """``patrol[:HEIGHT_M[:TRACK_M[:PASSES]]]`` as ``(height_m, track_m, passes)``; None
    for other specs; raises :class:`PathError` when malformed."""
    head, *rest = spec.strip().lower().split(":")
    if head != "patrol":
        return None
    if len(rest) > 3:
        raise PathError(f"path {spec!r}: use {PATROL_SPEC}")
    try:
        values = [float(v) for v in rest]
    except ValueError:
        raise PathError(f"path {spec!r}: height, track and passes are numbers") from None
    defaults = [PATROL_HEIGHT_M, PATROL_TRACK_M, float(PATROL_PASSES)]
    height, track, passes = values + defaults[len(values):]
    if not (math.isfinite(height) and height > 0 and math.isfinite(track) and track > 0):
        raise PathError(f"path {spec!r}: height and track must be positive metres")
    if passes != int(passes) or not 1 <= passes <= 1000:
        raise PathError(f"path {spec!r}: passes must be a whole number in 1..1000")
    return height, track, int(passes)


def patrol(hf: HeightField, frames: int = CHEN1999_FRAMES, height_m: float = PATROL_HEIGHT_M,
           track_m: float = PATROL_TRACK_M, passes: int = PATROL_PASSES) -> CameraPath:
    """The patrol (module docstring): ``frames`` viewpoints, ``passes`` passes."""
    n = _check_frames(frames)
    length = min(track_m, 0.9 * hf.depth)
    t = np.linspace(0.0, 1.0, n)
    ys = -0.5 * length * np.cos(math.pi * passes * t)
    return CameraPath(f"patrol:{height_m:g}:{track_m:g}:{passes}",
                      along_track(hf, ys, length, height_m))
