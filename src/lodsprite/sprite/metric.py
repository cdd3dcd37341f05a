"""The LOD-sprite angular error metric (Chen, Swan & Kaufman 1999, §3.2, Eq. 1-2).

For every square of the coarse quadtree level that is in the current view:

* ``C``  is the full-resolution vertex at the square's centre (an exact sample);
* ``C'`` is where the ray from the keyframe eye ``v1`` through ``C`` meets the
  coarse surface: the point the sprite texture maps ``C``'s colour onto;
* ``θ``  is the angle at the current eye ``v2`` between ``C`` and ``C'``.

A new keyframe is due when ``mean(θ²) >= (β ε)²`` (Eq. 2), with ``β`` the
angle of one pixel (vertical fov / image height, radians) and ``ε`` the user's
threshold in pixels.  The reported error in pixels is ``sqrt(mean(θ²)) / β``.

``C'`` is computed exactly, not with the paper's shortcuts (one α for all
vertices, ``b`` = distance to the edge): the ray is intersected with the two
coarse triangles of the square and of its eight neighbours (Möller-Trumbore,
vectorised over all squares), and the hit nearest to ``C`` along the ray is
kept; rays missing that neighbourhood (grazing views) are tested against every
coarse triangle.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from lodsprite.terrain.heightfield import HeightField
from lodsprite.terrain.lod import level_indices, level_step

SEARCH_RADII = (3, 8, 1 << 30)


@dataclass(frozen=True)
class CoarseSquares:
    """Geometry of one coarse level for the metric.

    ``centres (n*n, 3)``: the full-resolution centre vertex ``C`` of each square;
    ``tris (n*n, 18, 3, 3)``: for each square, the 18 coarse triangles of its
    3x3 neighbourhood (degenerate copies at the borders), vertices in metres.
    """

    level_quads: int
    centres: np.ndarray
    tris: np.ndarray
    own: np.ndarray  # (n*n, 2, 3, 3) the square's own two triangles


def coarse_squares(hf: HeightField, level_quads: int) -> CoarseSquares:
    """Precompute centres and neighbourhood triangles of level ``level_quads`` (needs step >= 2)."""
    step = level_step(hf.quads, level_quads)
    if step < 2:
        raise ValueError("the error metric needs a coarse level (step >= 2)")
    n = level_quads
    idx = level_indices(hf, n)
    rr, cc = np.meshgrid(idx, idx, indexing="ij")
    verts = hf.points(rr, cc)  # (n+1, n+1, 3)
    nw, ne = verts[:-1, :-1], verts[:-1, 1:]
    sw, se = verts[1:, :-1], verts[1:, 1:]
    # The same diagonal split as the renderer's grid mesh: (nw, sw, se) and (nw, se, ne).
    own = np.stack([np.stack([nw, sw, se], -2), np.stack([nw, se, ne], -2)], 2)  # (n,n,2,3,3)
    pad = np.pad(own, ((1, 1), (1, 1), (0, 0), (0, 0), (0, 0)), mode="edge")
    neigh = np.stack([pad[1 + a:1 + a + n, 1 + b:1 + b + n] for a in (-1, 0, 1)
                      for b in (-1, 0, 1)], axis=2)  # (n, n, 9, 2, 3, 3)
    ci = idx[:-1] + step // 2
    cr, ccol = np.meshgrid(ci, ci, indexing="ij")
    centres = hf.points(cr, ccol).reshape(-1, 3)
    return CoarseSquares(n, centres, neigh.reshape(n * n, 18, 3, 3), own.reshape(n * n, 2, 3, 3))


def ray_triangle_t(origin: np.ndarray, direction: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Ray parameters ``t`` of hits of rays ``origin + t * direction`` with triangles.

    ``origin (3,)``, ``direction (K, 3)``, ``tris (K, T, 3, 3)``; returns ``(K, T)``
    with NaN where a ray misses a triangle (Möller & Trumbore 1997).
    """
    a, b, c = tris[..., 0, :], tris[..., 1, :], tris[..., 2, :]
    e1, e2 = b - a, c - a
    d = direction[:, None, :]
    p = np.cross(d, e2)
    det = np.einsum("ktj,ktj->kt", e1, p)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / det
        s = origin - a
        u = np.einsum("ktj,ktj->kt", s, p) * inv
        q = np.cross(s, e1)
        v = np.einsum("ktj,ktj->kt", np.broadcast_to(d, q.shape), q) * inv
        t = np.einsum("ktj,ktj->kt", e2, q) * inv
    eps = 1e-9
    hit = (np.abs(det) > 1e-12) & (u >= -eps) & (v >= -eps) & (u + v <= 1 + eps)
    return np.where(hit, t, np.nan)


def _nearest_to_c(t: np.ndarray) -> np.ndarray:
    """Per row of ray parameters ``(K, T)``, the hit nearest to ``C`` (t = 1); NaN if none."""
    score = np.where(np.isnan(t), np.inf, np.abs(t - 1.0))
    return t[np.arange(len(t)), np.argmin(score, axis=1)]


def reprojected_centres(squares: CoarseSquares, key_eye: np.ndarray) -> np.ndarray:
    """``C'`` for every square ``(n*n, 3)``: the ray ``key_eye -> C`` meeting the coarse surface.

    Of the hits in the first neighbourhood that has any, the one nearest to ``C`` along
    the ray is kept.  Rays missing the 3x3
    neighbourhood of their square are tested against wider neighbourhoods
    (``SEARCH_RADII`` squares) and finally against every coarse triangle; a ray that
    meets no coarse triangle at all (``C`` stands above the coarse silhouette, so its
    sprite texel is mapped nowhere) gives NaN and is left out of the mean.
    """
    key_eye = np.asarray(key_eye, dtype=np.float64)
    d = squares.centres - key_eye  # C at t = 1
    t_best = _nearest_to_c(ray_triangle_t(key_eye, d, squares.tris))
    n = squares.level_quads
    for radius in SEARCH_RADII:
        missing = np.flatnonzero(np.isnan(t_best))
        if missing.size == 0:
            break
        if radius >= n:  # the whole level
            every = squares.own.reshape(1, -1, 3, 3)
            tris = np.broadcast_to(every, (missing.size, *every.shape[1:]))
        else:
            tris = _neighbourhood(squares, missing, radius)
        t_best[missing] = _nearest_to_c(ray_triangle_t(key_eye, d[missing], tris))
        if radius >= n:
            break
    return key_eye + t_best[:, None] * d


def _neighbourhood(squares: CoarseSquares, index: np.ndarray, radius: int) -> np.ndarray:
    """Triangles ``(K, 2 (2r+1)^2, 3, 3)`` of the squares within ``radius`` of each square
    in ``index`` (clamped at the borders, so some repeat)."""
    n = squares.level_quads
    r, c = np.divmod(index, n)
    off = np.arange(-radius, radius + 1)
    rr = np.clip(r[:, None, None] + off[None, :, None], 0, n - 1)
    cc = np.clip(c[:, None, None] + off[None, None, :], 0, n - 1)
    sq = (rr * n + cc).reshape(len(index), -1)
    return squares.own[sq].reshape(len(index), -1, 3, 3)


def angles_at_eye(eye: np.ndarray, p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Angles (radians) at ``eye (3,)`` between points ``p (K, 3)`` and ``q (K, 3)``."""
    a = (p - eye).T
    b = (q - eye).T
    cx = a[1] * b[2] - a[2] * b[1]
    cy = a[2] * b[0] - a[0] * b[2]
    cz = a[0] * b[1] - a[1] * b[0]
    return np.arctan2(np.sqrt(cx * cx + cy * cy + cz * cz), (a * b).sum(axis=0))


def in_view(points_h: np.ndarray, view_proj: np.ndarray) -> np.ndarray:
    """``(K,) bool``: homogeneous points ``(K, 4)`` inside the view frustum of ``view_proj``."""
    clip = points_h @ view_proj.T
    w = clip[:, 3:4]
    return (w[:, 0] > 0) & np.all(np.abs(clip[:, :3]) <= w, axis=1)


@dataclass(frozen=True)
class ErrorMetric:
    """The metric of one coarse level.

    ``C'`` depends only on the keyframe eye, so :meth:`reproject` runs once per
    keyframe (all squares); :meth:`error_px` is the cheap per-frame part.
    """

    squares: CoarseSquares

    @cached_property
    def _centres_h(self) -> np.ndarray:
        c = self.squares.centres
        return np.c_[c, np.ones(len(c))]

    @classmethod
    def for_level(cls, hf: HeightField, level_quads: int) -> ErrorMetric:
        return cls(coarse_squares(hf, level_quads))

    def reproject(self, key_eye: np.ndarray) -> np.ndarray:
        """``C' (n*n, 3)`` in metres for a keyframe rendered from ``key_eye``."""
        return reprojected_centres(self.squares, key_eye)

    def theta(self, c_prime: np.ndarray, eye: np.ndarray, view_proj: np.ndarray) -> np.ndarray:
        """θ (radians) of the squares whose centre ``C`` is in the current view."""
        vis = in_view(self._centres_h, view_proj)
        return angles_at_eye(np.asarray(eye, dtype=np.float64), self.squares.centres[vis],
                             c_prime[vis])

    def covers(self, viewpoint, projection, key_viewpoint, key_projection) -> bool:
        """Whether every square centre in the current view is also in the keyframe's view."""
        cur = in_view(self._centres_h, projection.matrix() @ viewpoint.view_matrix())
        key = in_view(self._centres_h, key_projection.matrix() @ key_viewpoint.view_matrix())
        return bool(np.all(key[cur]))

    def error_px(self, c_prime: np.ndarray, eye: np.ndarray, view_proj: np.ndarray,
                 pixel_angle_rad: float) -> float:
        """``sqrt(mean(θ²)) / β`` in pixels (0 when no square is in view).

        Eq. 2's test ``mean(θ²) >= (β ε)²`` is equivalent to ``error_px >= ε``.
        """
        th = self.theta(c_prime, eye, view_proj)
        th = th[np.isfinite(th)]
        if th.size == 0:
            return 0.0
        return float(np.sqrt(np.mean(th * th)) / pixel_angle_rad)
