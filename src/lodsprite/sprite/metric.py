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
vectorised over all squares), and the hit in front of ``v1`` nearest to ``C``
along the ray is kept (a hit behind ``v1`` is a point the keyframe never saw);
rays missing that neighbourhood (grazing views) are tested against wider
neighbourhoods and finally against every coarse triangle.

Two cases the paper leaves open are decided here, so that no frame is ever judged
better than it is:

* **Misses.**  A ray that meets no coarse triangle in front of ``v1`` (``C`` stands
  above the coarse silhouette, e.g. a peak seen against the sky from a low keyframe)
  passes above the coarse surface until it leaves the terrain's footprint: a spriteframe
  maps ``C``'s texel nowhere, unless a border ribbon stands where the ray leaves (the
  vertical plane of the terrain's edge).  Its ``C'`` is that exit point, and its θ is
  the angle to the exit point, raised to at least the largest θ of the samples in view
  whose rays hit (:func:`miss_floor`): a texel drawn nowhere is counted as no better than
  the worst texel drawn somewhere.  So misses can only raise the mean (before, they were
  left out of it, which averaged only the easy squares), and at ``v1`` every θ, misses
  included, is still 0.  (The exit angle alone can be smaller than the hits' angles, when
  the exit point lies just behind ``C``: it would still pull the mean down.)
* **Nothing measurable.**  When fewer than :data:`MIN_SAMPLES` square centres lie in the
  view (flying low, the view can fall between them although terrain fills it), a
  *fallback sample* is measured instead: full-resolution vertices inside the view that
  are not coarse vertices (on a coarse vertex ``C' = C`` always), on the finest regular
  grid of spacing ``step/2, step/4, ...`` with at most ``ENUMERATE_FACTOR * MAX_FALLBACK``
  vertices in the footprint of the view (at most :data:`MAX_FALLBACK` of those in view are
  kept, evenly), reprojected through the keyframe eye exactly as the centres are, misses
  included.  The square centres are themselves points of those grids, so the fallback
  measures the same kind of sample, only denser; it costs about 0.5 ms for 256 samples,
  in those frames only.  When no terrain vertex at all is in view,
  :meth:`ErrorMetric.error_px` returns ``math.inf``: a keyframe is due.  Callers compare
  the value with thresholds and never assume it is finite.

The fallback needs the keyframe eye: :meth:`ErrorMetric.reproject` returns a
:class:`Reprojection`, an ``(n*n, 3)`` array of ``C'`` that also carries it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from lodsprite.terrain.heightfield import HeightField
from lodsprite.terrain.lod import level_indices, level_step

SEARCH_RADII = (3, 8, 1 << 30)
MIN_SAMPLES = 4       # fewer square centres in view than this: measure the fallback sample
MAX_FALLBACK = 256    # at most this many fallback vertices are measured (evenly chosen)
ENUMERATE_FACTOR = 4  # the fallback grid has at most this times MAX_FALLBACK vertices in
                      # the view's footprint (a bounding box: only part of it is in view)


@dataclass(frozen=True)
class CoarseSquares:
    """Geometry of one coarse level for the metric.

    ``centres (n*n, 3)``: the full-resolution centre vertex ``C`` of each square;
    ``tris (n*n, 18, 3, 3)``: for each square, the 18 coarse triangles of its
    3x3 neighbourhood (degenerate copies at the borders), vertices in metres;
    ``own (n*n, 2, 3, 3)``: the square's own two triangles; ``hf`` the full-resolution
    field and ``step`` the level's step in its samples.
    """

    level_quads: int
    centres: np.ndarray
    tris: np.ndarray
    own: np.ndarray
    hf: HeightField
    step: int


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
    return CoarseSquares(n, centres, neigh.reshape(n * n, 18, 3, 3),
                         own.reshape(n * n, 2, 3, 3), hf, step)


class Reprojection(np.ndarray):
    """``C' (n*n, 3) float64`` metres of one keyframe, with that keyframe's eye
    ``key_eye (3,) float64`` (what the fallback sample of :class:`ErrorMetric` needs) and
    ``missed (n*n,) bool``, the rays that met no coarse triangle (their ``C'`` is the exit
    point, module docstring).

    An ``ndarray`` subclass: it indexes, compares and pickles like the array; ufuncs and
    reductions give plain arrays and scalars.  A view of another shape drops ``missed``
    (it no longer lines up; such a view counts every ray as a hit).
    """

    key_eye: np.ndarray | None
    missed: np.ndarray | None

    def __new__(cls, c_prime: np.ndarray, key_eye: np.ndarray,
                missed: np.ndarray | None = None) -> Reprojection:
        obj = np.asarray(c_prime, dtype=np.float64).view(cls)
        obj.key_eye = np.array(key_eye, dtype=np.float64)
        obj.missed = None if missed is None else np.asarray(missed, dtype=bool)
        return obj

    def __array_finalize__(self, obj) -> None:
        self.key_eye = getattr(obj, "key_eye", None)
        missed = getattr(obj, "missed", None)
        self.missed = missed if missed is not None and obj.shape == self.shape else None

    def __array_wrap__(self, arr, context=None, return_scalar=False):
        # Results of ufuncs and reductions are plain arrays and scalars, not C'.
        plain = arr.view(np.ndarray)
        return plain[()] if return_scalar else plain

    def __reduce__(self):
        fn, args, state = super().__reduce__()
        return fn, args, (state, self.key_eye, self.missed)

    def __setstate__(self, state) -> None:
        array_state, self.key_eye, self.missed = state
        super().__setstate__(array_state)


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
    """Per row of ray parameters ``(K, T)``, the hit in front of the eye (t > 0) nearest to
    ``C`` (t = 1); NaN if none."""
    score = np.where(np.isnan(t) | (t <= 0), np.inf, np.abs(t - 1.0))
    best = t[np.arange(len(t)), np.argmin(score, axis=1)]
    return np.where(np.isfinite(score.min(axis=1)), best, np.nan)


def _exit_t(squares: CoarseSquares, origin: np.ndarray, d: np.ndarray) -> np.ndarray:
    """``(K,)`` ray parameter ``t >= 1`` where rays ``origin + t d (K, 3)`` (inside the
    terrain's footprint at t = 1) leave it through its vertical sides."""
    lo, hi = squares.hf.bounds()
    with np.errstate(divide="ignore", invalid="ignore"):
        bound = np.where(d[:, :2] > 0, hi[:2], lo[:2])
        t = np.where(d[:, :2] != 0, (bound - origin[:2]) / d[:, :2], np.inf)
    return np.maximum(t.min(axis=1), 1.0)


def reproject_points(squares: CoarseSquares, key_eye: np.ndarray, points: np.ndarray,
                     square: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(C' (K, 3) float64, missed (K,) bool)``: rays ``key_eye -> points (K, 3)``
    meeting the coarse surface.

    ``square (K,) intp`` is the coarse square each point lies in (None: point ``k`` is
    the centre of square ``k``).  Of the hits in the first neighbourhood (3x3 squares,
    then ``SEARCH_RADII`` squares, then the whole level) that has any, the one in front of
    the eye nearest to the point along the ray is kept.  A ray that meets no coarse
    triangle is ``missed``; its ``C'`` is where it leaves the terrain's footprint.
    """
    key_eye = np.asarray(key_eye, dtype=np.float64)
    d = points - key_eye  # the point at t = 1
    first = squares.tris if square is None else squares.tris[square]
    t_best = _nearest_to_c(ray_triangle_t(key_eye, d, first))
    index = np.arange(len(points)) if square is None else square
    n = squares.level_quads
    for radius in SEARCH_RADII:
        missing = np.flatnonzero(np.isnan(t_best))
        if missing.size == 0:
            break
        if radius >= n:  # the whole level
            every = squares.own.reshape(1, -1, 3, 3)
            tris = np.broadcast_to(every, (missing.size, *every.shape[1:]))
        else:
            tris = _neighbourhood(squares, index[missing], radius)
        t_best[missing] = _nearest_to_c(ray_triangle_t(key_eye, d[missing], tris))
        if radius >= n:
            break
    missed = np.isnan(t_best)
    if missed.any():
        t_best[missed] = _exit_t(squares, key_eye, d[missed])
    return key_eye + t_best[:, None] * d, missed


def reprojected_centres(squares: CoarseSquares, key_eye: np.ndarray) -> Reprojection:
    """``C'`` for every square ``(n*n, 3)``: the ray ``key_eye -> C`` meeting the coarse
    surface (:func:`reproject_points`), carrying ``key_eye`` and the misses."""
    c_prime, missed = reproject_points(squares, key_eye, squares.centres)
    return Reprojection(c_prime, key_eye, missed)


def miss_floor(theta: np.ndarray, missed: np.ndarray) -> np.ndarray:
    """θ ``(K,)`` radians with each missed sample raised to at least the largest θ of the
    samples that hit (module docstring); non-finite θ become π."""
    theta = np.where(np.isfinite(theta), theta, np.pi)
    if missed.any() and not missed.all():
        theta = np.where(missed, np.maximum(theta, theta[~missed].max()), theta)
    return theta


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


_FRUSTUM_EDGES = ((0, 1), (2, 3), (4, 5), (6, 7), (0, 2), (1, 3), (4, 6), (5, 7),
                  (0, 4), (1, 5), (2, 6), (3, 7))


def view_footprint(view_proj: np.ndarray, lo: np.ndarray,
                   hi: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """``(xy_min (2,), xy_max (2,))`` metres bounding the part of the box ``lo..hi (3,)``
    inside the view frustum of ``view_proj (4, 4)``, or None if it is empty.

    The frustum's slice between the box's lowest and highest z is a convex polytope whose
    vertices are frustum corners in that slab and frustum edges crossing its planes; their
    xy bounds, clipped to the box's, bound the footprint (a superset of it).
    """
    ndc = np.array([[x, y, z, 1.0] for z in (-1, 1) for y in (-1, 1) for x in (-1, 1)])
    world = ndc @ np.linalg.inv(view_proj).T
    corners = world[:, :3] / world[:, 3:4]
    pts = [corners[(corners[:, 2] >= lo[2]) & (corners[:, 2] <= hi[2])]]
    a = corners[[e[0] for e in _FRUSTUM_EDGES]]
    b = corners[[e[1] for e in _FRUSTUM_EDGES]]
    for z in (lo[2], hi[2]):
        dz = b[:, 2] - a[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (z - a[:, 2]) / dz
        ok = (dz != 0) & (s >= 0) & (s <= 1)
        pts.append(a[ok] + s[ok, None] * (b[ok] - a[ok]))
    pts = np.concatenate(pts)
    if pts.size == 0:
        return None
    xy_min = np.maximum(pts[:, :2].min(axis=0), lo[:2])
    xy_max = np.minimum(pts[:, :2].max(axis=0), hi[:2])
    if np.any(xy_min > xy_max):
        return None
    return xy_min, xy_max


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

    def reproject(self, key_eye: np.ndarray) -> Reprojection:
        """``C' (n*n, 3)`` in metres for a keyframe rendered from ``key_eye``."""
        return reprojected_centres(self.squares, key_eye)

    def theta(self, c_prime: np.ndarray, eye: np.ndarray, view_proj: np.ndarray) -> np.ndarray:
        """θ (radians) of the squares whose centre ``C`` is in the current view (misses
        with the angle to their exit point, before :func:`miss_floor`)."""
        return self._theta(c_prime, eye, view_proj)[0]

    def _theta(self, c_prime: np.ndarray, eye: np.ndarray,
               view_proj: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        vis = in_view(self._centres_h, view_proj)
        th = angles_at_eye(np.asarray(eye, dtype=np.float64), self.squares.centres[vis],
                           np.asarray(c_prime)[vis])
        missed = getattr(c_prime, "missed", None)
        return th, (np.zeros(th.size, bool) if missed is None else missed[vis])

    def fallback_points(self, view_proj: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The fallback sample of the current view: ``(points (K, 3) float64 metres,
        square (K,) intp)``, full-resolution vertices in view that are not coarse vertices
        (module docstring), and the coarse square each lies in."""
        sq = self.squares
        hf, step, n = sq.hf, sq.step, sq.level_quads
        lo, hi = hf.bounds()
        box = view_footprint(view_proj, lo, hi)
        empty = np.zeros((0, 3)), np.zeros(0, np.intp)
        if box is None:
            return empty
        (x0, y0), (x1, y1) = box
        r0, c0 = hf.grid_index(x0, y1)  # north-west corner: smallest row and column
        r1, c1 = hf.grid_index(x1, y0)
        r0, c0 = max(int(np.floor(r0)), 0), max(int(np.floor(c0)), 0)
        r1, c1 = min(int(np.ceil(r1)), hf.rows - 1), min(int(np.ceil(c1)), hf.cols - 1)
        def count(s: int) -> int:
            return ((r1 - r0) // s + 1) * ((c1 - c0) // s + 1)

        s = step // 2  # the centres' spacing: every grid below includes them
        while s > 1 and count(s // 2) <= ENUMERATE_FACTOR * MAX_FALLBACK:
            s //= 2
        rows = np.arange(-(-r0 // s) * s, r1 + 1, s)
        cols = np.arange(-(-c0 // s) * s, c1 + 1, s)
        rr, cc = (a.ravel() for a in np.meshgrid(rows, cols, indexing="ij"))
        keep = (rr % step != 0) | (cc % step != 0)
        rr, cc = rr[keep], cc[keep]
        pts = hf.points(rr, cc)
        vis = in_view(np.c_[pts, np.ones(len(pts))], view_proj)
        pts, rr, cc = pts[vis], rr[vis], cc[vis]
        if len(pts) > MAX_FALLBACK:
            pick = np.linspace(0, len(pts) - 1, MAX_FALLBACK).round().astype(np.intp)
            pts, rr, cc = pts[pick], rr[pick], cc[pick]
        square = np.minimum(rr // step, n - 1) * n + np.minimum(cc // step, n - 1)
        return pts, square

    def fallback_theta(self, key_eye: np.ndarray, eye: np.ndarray,
                       view_proj: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(θ (K,) radians, missed (K,) bool)`` of the fallback sample
        (:meth:`fallback_points`) for the keyframe rendered from ``key_eye``."""
        pts, square = self.fallback_points(view_proj)
        if len(pts) == 0:
            return np.zeros(0), np.zeros(0, bool)
        p_prime, missed = reproject_points(self.squares, key_eye, pts, square)
        return angles_at_eye(np.asarray(eye, dtype=np.float64), pts, p_prime), missed

    def covers(self, viewpoint, projection, key_viewpoint, key_projection) -> bool:
        """Whether every square centre in the current view is also in the keyframe's view."""
        cur = in_view(self._centres_h, projection.matrix() @ viewpoint.view_matrix())
        key = in_view(self._centres_h, key_projection.matrix() @ key_viewpoint.view_matrix())
        return bool(np.all(key[cur]))

    def error_px(self, c_prime: np.ndarray, eye: np.ndarray, view_proj: np.ndarray,
                 pixel_angle_rad: float) -> float:
        """``sqrt(mean(θ²)) / β`` in pixels, over the square centres in view, or over the
        fallback sample when fewer than :data:`MIN_SAMPLES` centres are in view and
        ``c_prime`` is a :class:`Reprojection`; misses count as :func:`miss_floor` says;
        ``math.inf`` when nothing is measurable (a keyframe is due).

        Eq. 2's test ``mean(θ²) >= (β ε)²`` is equivalent to ``error_px >= ε``.
        """
        th, missed = self._theta(c_prime, eye, view_proj)
        key_eye = getattr(c_prime, "key_eye", None)
        if th.size < MIN_SAMPLES and key_eye is not None:
            fallback = self.fallback_theta(key_eye, eye, view_proj)
            if fallback[0].size > th.size:
                th, missed = fallback
        if th.size == 0:
            return math.inf
        th = miss_floor(th, missed)
        return float(np.sqrt(np.mean(th * th)) / pixel_angle_rad)
