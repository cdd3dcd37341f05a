"""``patrol``: back and forth over one stretch of the terrain, several passes - the case
for which Chen, Swan & Kaufman (1999, §5) propose a cache of keyframes (a viewer moving
back and forth in one region sees the same views again).

The camera flies the centre line of a ``track_m`` metre stretch (at most 90 % of the
terrain's depth) ``passes`` times, north then south then north ..., easing in and out at
each end (``y = -L/2 cos(pi passes t)``), ``height_m`` above the highest ground near the
track (the :mod:`lodsprite.paths.flyover` floor), low enough that keyframes are needed.
It keeps its heading (north, pitched down as the flyover): a patrol camera on a dolly, so
that every pass sees the views of the others; one that turned round at the ends would see
two sets of views and need twice the cache.  Metres, whatever the terrain's size.
"""

from __future__ import annotations

import math

import numpy as np

from lodsprite.errors import PathError
from lodsprite.paths.core import CHEN1999_FRAMES, CameraPath, _check_frames
from lodsprite.paths.flyover import along_track
from lodsprite.terrain.heightfield import HeightField

DEFAULT_HEIGHT_M = 500.0
DEFAULT_TRACK_M = 4000.0
DEFAULT_PASSES = 6
SPEC = "patrol[:HEIGHT_M[:TRACK_M[:PASSES]]]"


def parse_patrol(spec: str) -> tuple[float, float, int] | None:
    """``patrol[:HEIGHT_M[:TRACK_M[:PASSES]]]`` as ``(height_m, track_m, passes)``; None
    for other specs; raises :class:`PathError` when malformed."""
    head, *rest = spec.strip().lower().split(":")
    if head != "patrol":
        return None
    if len(rest) > 3:
        raise PathError(f"path {spec!r}: use {SPEC}")
    try:
        values = [float(v) for v in rest]
    except ValueError:
        raise PathError(f"path {spec!r}: height, track and passes are numbers") from None
    defaults = [DEFAULT_HEIGHT_M, DEFAULT_TRACK_M, float(DEFAULT_PASSES)]
    height, track, passes = values + defaults[len(values):]
    if not (math.isfinite(height) and height > 0 and math.isfinite(track) and track > 0):
        raise PathError(f"path {spec!r}: height and track must be positive metres")
    if passes != int(passes) or not 1 <= passes <= 1000:
        raise PathError(f"path {spec!r}: passes must be a whole number in 1..1000")
    return height, track, int(passes)


def patrol(hf: HeightField, frames: int = CHEN1999_FRAMES, height_m: float = DEFAULT_HEIGHT_M,
           track_m: float = DEFAULT_TRACK_M, passes: int = DEFAULT_PASSES) -> CameraPath:
    """The patrol (module docstring): ``frames`` viewpoints, ``passes`` passes."""
    n = _check_frames(frames)
    length = min(track_m, 0.9 * hf.depth)
    t = np.linspace(0.0, 1.0, n)
    ys = -0.5 * length * np.cos(math.pi * passes * t)
    return CameraPath(f"patrol:{height_m:g}:{track_m:g}:{passes}",
                      along_track(hf, ys, length, height_m))
