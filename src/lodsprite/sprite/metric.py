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
  *fallback sample* is measured instead, if it is larger: full-resolution vertices inside
  the view that are not coarse vertices (on a coarse vertex ``C' = C`` always).  They are
  enumerated only inside the coarse squares whose bounding box (with the heights of
  their vertices) meets the view frustum, on the grid of spacing ``step/2``, then
  ``step/4``, ...: the grid is refined while fewer than :data:`MIN_SAMPLES` of its
  vertices are in view, or while the finer grid has at most ``ENUMERATE_FACTOR *
  MAX_FALLBACK`` candidates in those squares, down to spacing 1 (every vertex).  So
  every vertex in view is found when fewer than :data:`MIN_SAMPLES` are.  Candidates are
  tested against the view :data:`CANDIDATE_CHUNK` at a time; of those in view at most
  :data:`MAX_FALLBACK` are kept, evenly in row-major order.  They are reprojected through
  the keyframe eye exactly as the centres are, misses included, once per keyframe: the
  keyframe's :class:`~lodsprite.sprite.raycast.Reprojection` caches the ``C'`` of every
  fallback vertex met so far (up to ``FALLBACK_CACHE``), so that later frames reproject
  only new vertices (over a store read without blocking, a vertex whose level-0 chunk
  is not resident yet is measured with the coarse level's height and not cached:
  :mod:`lodsprite.terrain.storefield`).  The square centres are themselves points of
  those grids, so the fallback measures the same kind of sample, only denser.
  :meth:`ErrorMetric.error_px` returns ``math.inf`` (a keyframe is due) when no terrain
  vertex is in view, and when every sample measured
  missed (e.g. a keyframe eye level with or below the coarse surface ahead): the sprite
  draws none of them anywhere, there is no hit to floor the misses, and the angles to
  the exit points alone would judge the frame better than it is.  This holds at the
  keyframe's own viewpoint too.  Callers compare the value with thresholds and never
  assume it is finite.
* **Cost.**  The per-frame part (:meth:`ErrorMetric.error_px`) tests the ``n²`` centres
  against the view; only frames with fewer than :data:`MIN_SAMPLES` centres in view add
  the fallback (culling the ``n²`` square boxes, enumerating candidates, reprojecting
  the vertices not yet cached).  Ray casting (:mod:`lodsprite.sprite.raycast`): a ray
  that misses its 3x3 neighbourhood is tested against the wider ones of
  ``SEARCH_RADII`` and, missing those, against the coarse triangles under its ground
  track (:func:`~lodsprite.sprite.raycast.crossed_triangles`, about ``12 n``; no other
  triangle can meet it); every stage runs in blocks of ``RAY_PAIRS`` ray-triangle pairs,
  so its memory is bounded (about 32 MB of temporaries) while its time grows with
  ``misses × n``.  The results are those of the unblocked search, bit for bit.

The fallback needs the keyframe eye: :meth:`ErrorMetric.reproject` returns a
:class:`Reprojection`, an ``(n*n, 3)`` array of ``C'`` that also carries it.

**Resampling** (``ErrorMetric(resampling=True)``, the technique option ``metric="resample"``;
Chen et al. §5's double resampling): each sample's θ² gains ``(β e_res)²``, ``e_res`` the
keyframe image's resampling error in pixels at ``C'`` on the coarse triangle there
(:mod:`lodsprite.sprite.resampling`), so the error stays ``sqrt(mean θ²) / β``; the
keyframe's matrix and size come with its :class:`Reprojection`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from lodsprite.camera import view_footprint  # noqa: F401  (moved there; re-exported)
from lodsprite.sprite.fallback import (  # noqa: F401  (the constants re-exported)
    CANDIDATE_CHUNK,
    ENUMERATE_FACTOR,
    MAX_FALLBACK,
    MIN_SAMPLES,
    Boxes,
    containing_square,
    fallback_grid,
    fallback_vertices,
    in_view,
    reproject_fallback,
    square_boxes,
    squares_in_view,
)
from lodsprite.sprite.raycast import (
    CoarseSquares,
    Reprojection,
    coarse_normals,
    coarse_squares,
    reproject_points,
    reprojected_centres,
)
from lodsprite.sprite.resampling import resampling_px
from lodsprite.terrain.heightfield import HeightField

#: A keyframe's drawn surface: ``(key_eye (3,), key_view_proj (4, 4) | None) ->
#: height``, ``height(x (K,), y (K,)) -> z (K,) float64`` metres (NaN: unknown there).
SurfaceSource = Callable[[np.ndarray, "np.ndarray | None"], Callable]

def miss_floor(theta: np.ndarray, missed: np.ndarray) -> np.ndarray:
    """θ ``(K,)`` radians with each missed sample raised to at least the largest θ of the
    samples that hit (module docstring); non-finite θ become π."""
    theta = np.where(np.isfinite(theta), theta, np.pi)
    if missed.any() and not missed.all():
        theta = np.where(missed, np.maximum(theta, theta[~missed].max()), theta)
    return theta


def angles_at_eye(eye: np.ndarray, p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Angles (radians) at ``eye (3,)`` between points ``p (K, 3)`` and ``q (K, 3)``."""
    a = (p - eye).T
    b = (q - eye).T
    cx = a[1] * b[2] - a[2] * b[1]
    cy = a[2] * b[0] - a[0] * b[2]
    cz = a[0] * b[1] - a[1] * b[0]
    return np.arctan2(np.sqrt(cx * cx + cy * cy + cz * cz), (a * b).sum(axis=0))


@dataclass(frozen=True)
class ErrorMetric:
    """The metric of one coarse level.

    ``C'`` depends only on the keyframe eye, so :meth:`reproject` runs once per
    keyframe (all squares); :meth:`error_px` is the cheap per-frame part.

    ``resampling``: add the keyframe image's resampling error to each sample's angle,
    ``θ² = θ_warp² + (β e_res)²`` (:mod:`lodsprite.sprite.resampling`, evaluated at ``C'``
    on the coarse triangle there; misses add nothing before :func:`miss_floor`); False is
    the 1999 metric.

    ``surface`` (:data:`SurfaceSource`): each keyframe's ``C`` is the surface that keyframe
    shows at the square centres' ``x, y`` (and at the fallback vertices), not the
    squares' own ``C``: ``sprite-adaptive`` gives the adaptive renderer's selection at
    ``--key-sse`` (:class:`~lodsprite.techniques.drawn_surface.DrawnSurface`), resident, so
    neither setup nor a frame reads a store's level 0 for it.  None: the 1999 metric's
    exact full-resolution ``C``.
    """

    squares: CoarseSquares
    resampling: bool = False
    surface: SurfaceSource | None = None

    @cached_property
    def _centres_h(self) -> np.ndarray:
        c = self.squares.centres
        return np.c_[c, np.ones(len(c))]

    @classmethod
    def for_level(cls, hf: HeightField, level_quads: int,
                  resampling: bool = False) -> ErrorMetric:
        return cls(coarse_squares(hf, level_quads), resampling)

    def reproject(self, key_eye: np.ndarray, key_view_proj: np.ndarray | None = None,
                  key_size: tuple[int, int] | None = None) -> Reprojection:
        """``C' (n*n, 3)`` in metres for a keyframe rendered from ``key_eye`` through
        ``key_view_proj (4, 4)`` on a ``key_size = (w, h)`` pixel image (guard band
        included; both needed by the resampling term only)."""
        if self.surface is None:
            return reprojected_centres(self.squares, key_eye, key_view_proj, key_size)
        height = self.surface(np.asarray(key_eye, np.float64), key_view_proj)
        points = self.squares.centres.copy()
        z = height(points[:, 0], points[:, 1])
        points[:, 2] = np.where(np.isnan(z), points[:, 2], z)  # none resident: the squares'
        c_prime, missed = reproject_points(self.squares, key_eye, points)
        out = Reprojection(c_prime, key_eye, missed, key_view_proj, key_size)
        out.set_points(points, height)
        return out

    def theta(self, c_prime: np.ndarray, eye: np.ndarray, view_proj: np.ndarray) -> np.ndarray:
        """θ (radians) of the squares whose centre ``C`` is in the current view (misses
        with the angle to their exit point, before :func:`miss_floor`)."""
        return self._theta(c_prime, eye, view_proj)[0]

    def _theta(self, c_prime: np.ndarray, eye: np.ndarray,
               view_proj: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(θ, missed, C')`` of the square centres in view."""
        points = getattr(c_prime, "points", None)
        if points is None:  # the squares' own centres
            points, points_h = self.squares.centres, self._centres_h
        else:
            points_h = c_prime.points_h
        vis = in_view(points_h, view_proj)
        cp = np.asarray(c_prime)[vis]
        th = angles_at_eye(np.asarray(eye, dtype=np.float64), points[vis], cp)
        missed = getattr(c_prime, "missed", None)
        return th, (np.zeros(th.size, bool) if missed is None else missed[vis]), cp

    @cached_property
    def _square_boxes(self) -> Boxes:
        """``(lo, hi) (n*n, 3)``: each coarse square's vertex bounds
        (:func:`~lodsprite.sprite.fallback.square_boxes`)."""
        return square_boxes(self.squares)

    def squares_in_view(self, view_proj: np.ndarray) -> np.ndarray:
        """Indices ``(Q,) intp`` of the coarse squares whose bounding box meets the view
        frustum of ``view_proj`` (conservatively: every vertex in view lies in one)."""
        return squares_in_view(self._square_boxes, view_proj)

    def fallback_grid(self, view_proj: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(rows (K,), cols (K,)) intp`` of the fallback sample of the current view
        (:func:`~lodsprite.sprite.fallback.fallback_grid`)."""
        return fallback_grid(self.squares, self._square_boxes, view_proj)

    def fallback_points(self, view_proj: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The fallback sample of the current view: ``(points (K, 3) float64 metres,
        square (K,) intp)``, full-resolution vertices in view that are not coarse vertices
        (module docstring, :meth:`fallback_grid`), and the coarse square each lies in."""
        rr, cc = self.fallback_grid(view_proj)
        return self.squares.hf.points(rr, cc), containing_square(self.squares, rr, cc)

    def fallback_theta(self, key_eye: np.ndarray, eye: np.ndarray, view_proj: np.ndarray,
                       cache: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(θ (K,) radians, missed (K,) bool)`` of the fallback sample
        (:meth:`fallback_points`) for the keyframe rendered from ``key_eye``.

        ``cache``: a keyframe's ``Reprojection.fallback_cache``; vertices reprojected
        before for that keyframe are taken from it (the same ``C'``, computed once)."""
        return self.fallback_sample(key_eye, eye, view_proj, cache)[:2]

    def fallback_sample(self, key_eye: np.ndarray, eye: np.ndarray, view_proj: np.ndarray,
                        cache: dict | None = None, surface=None
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`fallback_theta` with the fallback vertices' ``C' (K, 3)`` metres;
        ``surface(x, y) -> z``: the keyframe's drawn surface their ``C`` is taken from
        (a :class:`Reprojection`'s ``surface``; None: the full-resolution field)."""
        rr, cc = self.fallback_grid(view_proj)
        if len(rr) == 0:
            return np.zeros(0), np.zeros(0, bool), np.zeros((0, 3))
        pts = fallback_vertices(self.squares, rr, cc, surface)
        p_prime, missed = reproject_fallback(self.squares, key_eye, rr, cc, pts, cache,
                                             surface)
        return angles_at_eye(np.asarray(eye, dtype=np.float64), pts, p_prime), missed, p_prime

    def covers(self, viewpoint, projection, key_viewpoint, key_projection) -> bool:
        """Whether every square centre in the current view is also in the keyframe's view."""
        cur = in_view(self._centres_h, projection.matrix() @ viewpoint.view_matrix())
        key = in_view(self._centres_h, key_projection.matrix() @ key_viewpoint.view_matrix())
        return bool(np.all(key[cur]))

    def in_view_mask(self, viewpoint, projection) -> np.ndarray:
        """``(n*n,) bool``: the square centres in the view (what :meth:`covers` compares)."""
        return in_view(self._centres_h, projection.matrix() @ viewpoint.view_matrix())

    def error_px(self, c_prime: np.ndarray, eye: np.ndarray, view_proj: np.ndarray,
                 pixel_angle_rad: float, size: tuple[int, int] | None = None) -> float:
        """``sqrt(mean(θ²)) / β`` in pixels, over the square centres in view, or over the
        fallback sample when fewer than :data:`MIN_SAMPLES` centres are in view and
        ``c_prime`` is a :class:`Reprojection`; misses count as :func:`miss_floor` says;
        ``math.inf`` when nothing is measurable (a keyframe is due): no sample in view, or
        every sample in view missed.

        With :attr:`resampling`, ``size = (w, h)`` is the current image's and ``c_prime``
        a :class:`Reprojection` carrying ``key_view_proj`` and ``key_size`` (ValueError
        otherwise); each hit's θ² gains ``(β e_res)²``.

        Eq. 2's test ``mean(θ²) >= (β ε)²`` is equivalent to ``error_px >= ε``.
        """
        th, missed, cp = self._theta(c_prime, eye, view_proj)
        key_eye = getattr(c_prime, "key_eye", None)
        if th.size < MIN_SAMPLES and key_eye is not None:
            fallback = self.fallback_sample(key_eye, eye, view_proj,
                                            getattr(c_prime, "fallback_cache", None),
                                            surface=getattr(c_prime, "surface", None))
            if fallback[0].size > th.size:
                th, missed, cp = fallback
        if th.size == 0 or missed.all():  # nothing in view, or nothing the sprite draws
            return math.inf
        if self.resampling:
            th = self._with_resampling(th, missed, cp, c_prime, view_proj, pixel_angle_rad,
                                       size)
        th = miss_floor(th, missed)
        return float(np.sqrt(np.mean(th * th)) / pixel_angle_rad)

    def _with_resampling(self, th: np.ndarray, missed: np.ndarray, cp: np.ndarray,
                         c_prime: np.ndarray, view_proj: np.ndarray, beta: float,
                         size: tuple[int, int] | None,
                         idx: np.ndarray | None = None) -> np.ndarray:
        """``sqrt(θ² + (β e_res)²)`` for the hits (``e_res`` at ``C' = cp (K, 3)`` on the
        coarse triangle there); misses keep θ (the floor raises them).  ``idx``: which
        samples of ``c_prime`` ``cp`` are (unused here: the coarse normals come from
        ``cp``; a view-dependent proxy's metric reads its own normals by it)."""
        key_view_proj = getattr(c_prime, "key_view_proj", None)
        key_size = getattr(c_prime, "key_size", None)
        if size is None or key_view_proj is None or key_size is None:
            raise ValueError("the resampling metric needs the current image size and a "
                             "Reprojection with key_view_proj and key_size")
        hit = ~missed
        e = np.zeros(len(th))
        e[hit] = resampling_px(cp[hit], coarse_normals(self.squares, cp[hit]), key_view_proj,
                               key_size, view_proj, size)
        return np.sqrt(th * th + (beta * e) ** 2)
