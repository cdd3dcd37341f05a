"""A worker keyframe's guard band sized to the viewpoint predictor's error.

A keyframe from the worker is rendered for where the viewer is predicted to be when it
arrives (Swan et al. 2002's VIEWPOINT-PREDICTOR over the measured latency).  The predictor
errs, and a frame that turned further than the keyframe's guard band shows the fallback
along its border.  The guard band is therefore widened by the predictor's measured error:
the frame actually shown at the time a keyframe was aimed at is projected into the frame
the keyframe was rendered for, and how far its corners land outside that frame (pixels,
yaw, pitch and roll together) is one miss (:func:`overshoot_px`).  :class:`GuardBand`
keeps the latest misses and asks the next keyframe for the base guard band plus their
upper quantile, spread over the same texels (:func:`lodsprite.camera.widened`'s
``spread``): memory stays that of the base guard band; a wide guard band samples the
keyframe less finely, which the error estimate sees (its texels a pixel).

Translation is left out of the miss: it moves near surfaces more than far ones, which the
keyframe's own depth mesh follows (parallax), while the guard band is about the frame's
border.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from lodsprite.camera import Viewpoint

MISSES_KEPT = 16      # misses the quantile is taken over
MISS_QUANTILE = 0.9   # the share of recent misses the guard band covers
MAX_SPREAD = 1.5      # at most 1.5x the base view: texels a pixel down to 2/3


def overshoot_px(shown: Viewpoint, aimed: Viewpoint, fov_y_deg: float,
                 size: tuple[int, int]) -> float:
    """How far (pixels, >= 0) the ``size = (w, h)`` frame seen from ``shown`` reaches
    outside the frame seen from ``aimed`` (same field of view ``fov_y_deg``, degrees):
    the largest distance of its four corner rays, projected into ``aimed``'s image
    plane, past that image's edges.  A corner at or behind ``aimed``'s eye plane counts
    as the whole frame's width."""
    w, h = size
    ty = math.tan(math.radians(fov_y_deg) / 2.0)
    tx = ty * w / h
    f = (h / 2.0) / ty  # focal length, pixels
    corners = np.array([[sx * tx, sy * ty, -1.0] for sx in (-1, 1) for sy in (-1, 1)])
    shown_axes = np.stack([shown.x, shown.y, shown.z])    # rows: camera axes in the world
    aimed_axes = np.stack([aimed.x, aimed.y, aimed.z])
    rays = corners @ shown_axes @ aimed_axes.T            # (4, 3) in aimed's camera
    depth = -rays[:, 2]
    if np.any(depth <= 1e-9):
        return float(w)
    u = np.abs(rays[:, 0] / depth) * f - w / 2.0
    v = np.abs(rays[:, 1] / depth) * f - h / 2.0
    return float(max(0.0, np.max(np.maximum(u, v))))


class GuardBand:
    """The guard band for the next worker keyframe, from the misses measured so far.

    ``base_px``: the guard band the keyframe slots are allocated for (pixels); ``size``
    ``(w, h)`` and ``fov_y_deg``: the frame's.  :meth:`aim` records where a requested
    keyframe was aimed and when; :meth:`observe` (every frame) measures the miss once the
    frame shown at that time is known; :meth:`spread` is what the next request asks for.
    """

    def __init__(self, base_px: int, size: tuple[int, int], fov_y_deg: float) -> None:
        self.base_px = int(base_px)
        self.size = (int(size[0]), int(size[1]))
        self.fov_y_deg = float(fov_y_deg)
        self.misses: deque[float] = deque(maxlen=MISSES_KEPT)
        self.measured = 0        # misses measured in all
        self.worst_px = 0.0      # the largest of them (pixels)
        self.widest = 1.0        # the largest spread asked for
        self._aim: tuple[float, Viewpoint] | None = None

    def aim(self, t: float, viewpoint: Viewpoint) -> float:
        """A keyframe is asked for at ``viewpoint``, meant to be shown at ``t`` seconds
        (the request's time plus the measured latency); returns the spread it is asked
        with (:meth:`spread`, from the misses measured before it)."""
        spread = self.spread()
        self.widest = max(self.widest, spread)
        self._aim = (float(t), viewpoint)
        return spread

    def summary(self) -> dict[str, float]:
        """What the band did over a run: misses measured, the largest (pixels), the
        90th percentile of the last :data:`MISSES_KEPT` and the widest spread asked."""
        recent = float(np.quantile(self.misses, MISS_QUANTILE)) if self.misses else 0.0
        return {"guard_misses": self.measured, "guard_miss_max_px": self.worst_px,
                "guard_miss_p90_px": recent, "guard_spread_max": self.widest}

    def observe(self, t: float, viewpoint: Viewpoint) -> None:
        """The frame shown at ``t``: the miss of the aimed keyframe, once ``t`` reaches
        its time."""
        if self._aim is not None and t >= self._aim[0]:
            miss = overshoot_px(viewpoint, self._aim[1], self.fov_y_deg, self.size)
            self.misses.append(miss)
            self.measured += 1
            self.worst_px = max(self.worst_px, miss)
            self._aim = None

    @property
    def guard_px(self) -> float:
        """The guard band wanted (pixels): the base plus the recent misses' upper
        quantile, within :data:`MAX_SPREAD`."""
        miss = float(np.quantile(self.misses, MISS_QUANTILE)) if self.misses else 0.0
        small = min(self.size)
        return min(self.base_px + miss, ((small + 2 * self.base_px) * MAX_SPREAD - small) / 2)

    def spread(self) -> float:
        """The spread (:func:`lodsprite.camera.widened`) that gives the smaller side of
        the frame :attr:`guard_px` pixels at the base guard band's texels (1: no miss)."""
        small = min(self.size)
        return (small + 2.0 * self.guard_px) / (small + 2.0 * self.base_px)
