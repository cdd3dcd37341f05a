"""A low banking flight: an S-turn at a fixed height above the ground, the camera rolling
into each turn (the case the resampling metric is validated on, issue 22: grazing views
whose texel footprint changes fast; :mod:`lodsprite.sprite.resampling`).

Not a paper's path.  Like :mod:`lodsprite.paths.flyover` it is given in metres, the same
over a terrain of any size: the track is ``track_m`` long (scaled down to fit within 80 %
of the terrain's smaller side), its heading swings ``±TURN_DEG`` about north as
``TURN_DEG sin(2π s)`` (``s`` the fraction flown), so it turns right, then left, then
right again; the camera rolls into the turn by ``ROLL_DEG`` times the turn rate over its
largest value (right wing down while turning right) and looks ahead pitched down by
``PITCH_DEG``.  The height is ``height_m`` above the highest ground near the track (the
flyover's smoothed running maximum, :func:`~lodsprite.paths.flyover.ground_floor`).
"""

from __future__ import annotations

import math

import numpy as np

from lodsprite.camera import Viewpoint
from lodsprite.errors import PathError
from lodsprite.paths.core import CHEN1999_FRAMES, CameraPath, _check_frames
from lodsprite.paths.flyover import ground_floor
from lodsprite.terrain.heightfield import HeightField

DEFAULT_HEIGHT_M = 300.0
DEFAULT_TRACK_M = 8000.0
TURN_DEG = 60.0    # heading amplitude about north
ROLL_DEG = 35.0    # roll at the largest turn rate
PITCH_DEG = 12.0   # the camera looks this far below the horizon
FIT = 0.8          # the track's extent at most this fraction of the terrain's side
_SAMPLES = 2048


def parse_bank(spec: str) -> tuple[float, float] | None:
    """``bank[:HEIGHT_M[:TRACK_M]]`` as ``(height_m, track_m)``; None for other specs;
    raises :class:`PathError` when malformed."""
    head, *rest = spec.strip().lower().split(":")
    if head != "bank":
        return None
    try:
        values = [float(v) for v in rest]
    except ValueError:
        raise PathError(f"path {spec!r}: height and track are metres (numbers)") from None
    if len(values) > 2 or not all(math.isfinite(v) and v > 0 for v in values):
        raise PathError(f"path {spec!r}: use bank[:HEIGHT_M[:TRACK_M]], positive metres")
    defaults = (DEFAULT_HEIGHT_M, DEFAULT_TRACK_M)
    return values[0] if values else defaults[0], values[1] if len(values) > 1 else defaults[1]


def track(hf: HeightField, track_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                     float]:
    """``(xy (S, 2) metres, heading (S,) radians from north, turn rate (S,) rad per unit
    s, length m)`` of the S-turn sampled at :data:`_SAMPLES` points, centred on the
    terrain and scaled to fit."""
    s = np.linspace(0.0, 1.0, _SAMPLES)
    amp = math.radians(TURN_DEG)
    heading = amp * np.sin(2 * np.pi * s)
    rate = amp * 2 * np.pi * np.cos(2 * np.pi * s)
    step = np.diff(s, prepend=0.0)
    xy = np.cumsum(np.c_[np.sin(heading), np.cos(heading)] * step[:, None], axis=0)
    extent = np.ptp(xy, axis=0)
    length = min(track_m, FIT * min(hf.width, hf.depth) / float(extent.max()))
    xy = (xy - (xy.min(axis=0) + xy.max(axis=0)) / 2) * length
    return xy, heading, rate, length


def bank(hf: HeightField, frames: int = CHEN1999_FRAMES, height_m: float = DEFAULT_HEIGHT_M,
         track_m: float = DEFAULT_TRACK_M) -> CameraPath:
    """The flight (module docstring): ``frames`` viewpoints evenly spaced along the track."""
    n = _check_frames(frames)
    xy, heading, rate, length = track(hf, track_m)
    ground = hf.height_at(xy[:, 0], xy[:, 1])
    floor = ground_floor(ground, length / (_SAMPLES - 1), height_m)
    pick = np.linspace(0, _SAMPLES - 1, n).round().astype(np.intp)
    psi, roll = heading[pick], math.radians(ROLL_DEG) * rate[pick] / np.abs(rate).max()
    p = math.radians(PITCH_DEG)
    vps = []
    for i, k in enumerate(pick):
        f = np.array([math.sin(psi[i]) * math.cos(p), math.cos(psi[i]) * math.cos(p),
                      -math.sin(p)])
        r0 = np.array([math.cos(psi[i]), -math.sin(psi[i]), 0.0])
        u0 = np.cross(r0, f)
        c, s = math.cos(roll[i]), math.sin(roll[i])
        right, up = r0 * c - u0 * s, u0 * c + r0 * s  # right wing down when turning right
        vps.append(Viewpoint(right, up, -f, np.array([xy[k, 0], xy[k, 1],
                                                      floor[k] + height_m])))
    return CameraPath(f"bank:{height_m:g}:{track_m:g}", tuple(vps))
