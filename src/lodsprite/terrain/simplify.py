"""Douglas-Peucker simplification of a polygonal chain (the border ribbons' profiles).

:func:`approximate_polygon` is scikit-image's ``skimage.measure.approximate_polygon``
(0.26, BSD-3-Clause, Copyright the scikit-image team), the same operations in the same
order so that it keeps the same points bit for bit (``tests/terrain/test_simplify.py``
checks it against scikit-image's).  It lives here because the module scikit-image
keeps it in imports ``scipy.signal``, and with it ``scipy.stats``, for another
function: 0.7-0.8 s of CPU (user+sys, medians of 5 on the 2-core sandbox under load)
at the start of every process that draws a proxy mesh; numpy alone serves it here.
"""

from __future__ import annotations

import numpy as np

__all__ = ["approximate_polygon"]


def approximate_polygon(coords: np.ndarray, tolerance: float) -> np.ndarray:
    """The points of the chain ``coords (K, 2)`` kept by Douglas-Peucker within
    ``tolerance`` (the same units as ``coords``): ``(L, 2)``, L <= K, in order, both ends
    kept.  Each point left out lies within ``tolerance`` of the kept chain (its
    perpendicular distance to the segment where it projects inside it, else its distance
    to the nearer end).  ``tolerance <= 0`` returns ``coords`` itself."""
    if tolerance <= 0:
        return coords
    chain = np.zeros(coords.shape[0], bool)
    dists = np.zeros(coords.shape[0])
    chain[0] = chain[-1] = True
    stack = [(0, chain.shape[0] - 1)]
    while stack:
        start, end = stack.pop()
        r0, c0 = coords[start, :]
        r1, c1 = coords[end, :]
        dr, dc = r1 - r0, c1 - c0
        angle = -np.arctan2(dr, dc)
        offset = c0 * np.sin(angle) + r0 * np.cos(angle)
        inner = coords[start + 1:end, :]
        d = dists[start + 1:end]
        dr0, dc0 = inner[:, 0] - r0, inner[:, 1] - c0
        dr1, dc1 = inner[:, 0] - r1, inner[:, 1] - c1
        # inside the segment (projected on it from both ends): perpendicular distance
        perp = np.logical_and(dr0 * dr + dc0 * dc > 0, -dr1 * dr - dc1 * dc > 0)
        eucl = np.logical_not(perp)
        d[perp] = np.abs(inner[perp, 0] * np.cos(angle) + inner[perp, 1] * np.sin(angle)
                         - offset)
        d[eucl] = np.minimum(np.sqrt(dc0[eucl] ** 2 + dr0[eucl] ** 2),
                             np.sqrt(dc1[eucl] ** 2 + dr1[eucl] ** 2))
        if np.any(d > tolerance):
            split = start + np.argmax(d) + 1
            stack.append((split, end))
            stack.append((start, split))
            chain[split] = True
    return coords[chain, :]
