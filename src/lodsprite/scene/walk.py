"""Walking instances: straight lines at constant speed, reflected at the terrain's edge.

Each walker starts at ``xy0`` and heads along ``heading`` (radians about ``+z``, 0 = east)
at ``speed`` m/s in the horizontal plane.  At the edge of its rectangle ``[lo, hi]`` (the
terrain, or its section's ``area``) it reflects like a billiard ball: the component of
its velocity normal to that edge turns back.  The position at time ``t`` is closed form
(no state, no time steps): the unfolded straight-line position is folded back into the
rectangle by the triangle wave ``u -> L - |L - (u mod 2L)|`` on each axis, and the
heading's component on an axis is negated on the folded half-periods.  So any ``t`` can
be asked in any order, in one vectorised call, and every walker keeps its speed in the
plane exactly (but at the instant of a bounce); the height (``z``) follows the ground, so
the speed along a slope is larger than the plane speed.  The walkers are deterministic:
the start and heading come from the scene's seeded placement
(:mod:`lodsprite.scene.placement`).
"""

from __future__ import annotations

import numpy as np


def walk(xy0: np.ndarray, heading: np.ndarray, speed: np.ndarray, t: float,
         lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Positions ``(k, 2) float64`` metres and headings ``(k,) float64`` radians of ``k``
    walkers at time ``t`` seconds.

    ``xy0 (k, 2)`` starts inside ``[lo, hi]`` (metres, ``(2,)`` each, or ``(k, 2)``: a
    rectangle per walker), ``heading (k,)`` radians, ``speed (k,)`` m/s (0: stands still,
    keeps its heading).
    """
    xy0 = np.asarray(xy0, dtype=np.float64)
    direction = np.stack([np.cos(heading), np.sin(heading)], axis=1)
    span = np.maximum(np.asarray(hi, np.float64) - lo, 1e-12)
    u = (xy0 - lo) + direction * (np.asarray(speed, np.float64) * float(t))[:, None]
    u = np.mod(u, 2.0 * span)
    back = u > span
    xy = lo + np.where(back, 2.0 * span - u, u)
    turned = np.where(back, -direction, direction)
    return xy, np.arctan2(turned[:, 1], turned[:, 0])
