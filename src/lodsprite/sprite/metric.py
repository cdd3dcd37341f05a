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
from lodsprite.sprite.raycast import (
    FALLBACK_CACHE,
    CoarseSquares,
    Reprojection,
    coarse_normals,
    coarse_squares,
    reproject_points,
    reprojected_centres,
)
from lodsprite.sprite.resampling import resampling_px
from lodsprite.terrain.heightfield import HeightField
from lodsprite.terrain.lod import level_indices

#: A keyframe's drawn surface: ``(key_eye (3,), key_view_proj (4, 4) | None) ->
#: height``, ``height(x (K,), y (K,)) -> z (K,) float64`` metres (NaN: unknown there).
SurfaceSource = Callable[[np.ndarray, "np.ndarray | None"], Callable]

MIN_SAMPLES = 4       # fewer square centres in view than this: measure the fallback sample
MAX_FALLBACK = 256    # at most this many fallback vertices are measured (evenly chosen)
ENUMERATE_FACTOR = 4  # the fallback grid is refined while it has at most this times
                      # MAX_FALLBACK candidate vertices in the coarse squares the view meets
CANDIDATE_CHUNK = 1 << 14  # candidate vertices tested against the view at once


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
    def _square_boxes(self) -> tuple[np.ndarray, np.ndarray]:
        """``(lo, hi) (n*n, 3)``: bounds of the full-resolution vertices of each coarse
        square (edges included)."""
        sq = self.squares
        hf, step, n = sq.hf, sq.step, sq.level_quads
        if hasattr(hf.heights, "block_extremes"):  # a store read on demand: chunk bounds
            zlo, zhi = hf.heights.block_extremes(n, step)
        else:
            h = hf.heights.astype(np.float64)
            m = n * step

            def extreme(red) -> np.ndarray:
                cols = red(red.reduce(h[:, :m].reshape(len(h), n, step), axis=2),
                           h[:, step::step])
                return red(red.reduce(cols[:m].reshape(n, step, n), axis=1), cols[step::step])

            zlo, zhi = extreme(np.minimum), extreme(np.maximum)
        idx = level_indices(hf, n)
        x, y = hf.world_xy(idx, idx)  # x by column index, y by row index
        rr, cc = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
        x0, x1 = x[cc].ravel(), x[cc + 1].ravel()
        y0, y1 = y[rr + 1].ravel(), y[rr].ravel()  # row 0 is north: y falls with the row
        lo = np.c_[x0, y0, zlo.ravel()]
        hi = np.c_[x1, y1, zhi.ravel()]
        return lo, hi

    def squares_in_view(self, view_proj: np.ndarray) -> np.ndarray:
        """Indices ``(Q,) intp`` of the coarse squares whose bounding box meets the view
        frustum of ``view_proj`` (conservatively: every vertex in view lies in one)."""
        lo, hi = self._square_boxes
        m = np.asarray(view_proj, dtype=np.float64)
        planes = np.array([m[3] + m[0], m[3] - m[0], m[3] + m[1], m[3] - m[1],
                           m[3] + m[2], m[3] - m[2]])
        keep = np.ones(len(lo), bool)
        scale = np.abs(np.r_[lo.min(axis=0), hi.max(axis=0)]).max() + 1.0
        for pl in planes:
            top = np.where(pl[:3] > 0, hi, lo) @ pl[:3] + pl[3]
            keep &= top >= -1e-9 * (np.abs(pl[:3]).sum() * scale + abs(pl[3]))
        return np.flatnonzero(keep)

    def _visible_grid(self, squares: np.ndarray, s: int, view_proj: np.ndarray) -> np.ndarray:
        """Sorted linear indices of the vertices on the grid of spacing ``s`` inside the
        coarse ``squares`` that are in view and are not coarse vertices; the candidates
        are tested :data:`CANDIDATE_CHUNK` at a time."""
        sq = self.squares
        hf, step, n = sq.hf, sq.step, sq.level_quads
        off = np.arange(0, step + 1, s)
        per = len(off) ** 2
        found = []
        for q0 in range(0, len(squares), max(1, CANDIDATE_CHUNK // per)):
            r, c = np.divmod(squares[q0:q0 + max(1, CANDIDATE_CHUNK // per)], n)
            rr = (r[:, None, None] * step + off[None, :, None]) + 0 * off[None, None, :]
            cc = (c[:, None, None] * step + off[None, None, :]) + 0 * off[None, :, None]
            rr, cc = rr.ravel(), cc.ravel()
            keep = (rr % step != 0) | (cc % step != 0)
            rr, cc = rr[keep], cc[keep]
            pts = hf.points(rr, cc)
            vis = in_view(np.c_[pts, np.ones(len(pts))], view_proj)
            found.append(np.unique(rr[vis] * hf.cols + cc[vis]))
        return np.unique(np.concatenate(found)) if found else np.zeros(0, np.intp)

    def fallback_grid(self, view_proj: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(rows (K,), cols (K,)) intp`` of the fallback sample of the current view
        (module docstring): at most :data:`MAX_FALLBACK` vertices, in row-major order."""
        sq = self.squares
        hf, step = sq.hf, sq.step
        squares = self.squares_in_view(view_proj)
        s = step // 2  # the centres' spacing: every grid below includes them
        while True:
            idx = self._visible_grid(squares, s, view_proj)
            if s == 1:
                break
            finer = len(squares) * (2 * step // s + 1) ** 2  # candidates at spacing s/2
            if len(idx) >= MIN_SAMPLES and finer > ENUMERATE_FACTOR * MAX_FALLBACK:
                break
            s //= 2
        if len(idx) > MAX_FALLBACK:
            idx = idx[np.linspace(0, len(idx) - 1, MAX_FALLBACK).round().astype(np.intp)]
        return np.divmod(idx, hf.cols)

    def fallback_points(self, view_proj: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The fallback sample of the current view: ``(points (K, 3) float64 metres,
        square (K,) intp)``, full-resolution vertices in view that are not coarse vertices
        (module docstring, :meth:`fallback_grid`), and the coarse square each lies in."""
        sq = self.squares
        rr, cc = self.fallback_grid(view_proj)
        n, step = sq.level_quads, sq.step
        square = np.minimum(rr // step, n - 1) * n + np.minimum(cc // step, n - 1)
        return sq.hf.points(rr, cc), square

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
        sq = self.squares
        rr, cc = self.fallback_grid(view_proj)
        if len(rr) == 0:
            return np.zeros(0), np.zeros(0, bool), np.zeros((0, 3))
        n, step = sq.level_quads, sq.step
        pts = self._fallback_points(rr, cc, surface)
        lin = rr * sq.hf.cols + cc
        entry = None if cache is None else cache.get(id(sq))
        if entry is not None and entry[0] is not sq:
            entry = None
        p_prime = np.empty((len(lin), 3))
        missed = np.zeros(len(lin), bool)
        new = np.ones(len(lin), bool)
        if entry is not None:
            _, known, known_cp, known_missed = entry
            pos = np.minimum(np.searchsorted(known, lin), len(known) - 1)
            new = known[pos] != lin
            p_prime[~new], missed[~new] = known_cp[pos[~new]], known_missed[pos[~new]]
        if new.any():
            square = (np.minimum(rr[new] // step, n - 1) * n
                      + np.minimum(cc[new] // step, n - 1))
            p_prime[new], missed[new] = reproject_points(sq, key_eye, pts[new], square)
            # a store's heights not resident yet are approximate: not cached, taken again
            exact = None if surface is not None else getattr(sq.hf.heights, "exact", None)
            keep = new if exact is None else new & exact(rr, cc)
            if cache is not None and keep.any():
                if entry is None or len(entry[1]) + int(keep.sum()) > FALLBACK_CACHE:
                    entry = (sq, np.zeros(0, lin.dtype), np.zeros((0, 3)), np.zeros(0, bool))
                keys = np.r_[entry[1], lin[keep]]
                order = np.argsort(keys, kind="stable")
                cache[id(sq)] = (sq, keys[order], np.r_[entry[2], p_prime[keep]][order],
                                 np.r_[entry[3], missed[keep]][order])
        return angles_at_eye(np.asarray(eye, dtype=np.float64), pts, p_prime), missed, p_prime

    def _fallback_points(self, rr: np.ndarray, cc: np.ndarray, surface) -> np.ndarray:
        """Points ``(K, 3)`` of the fallback vertices: on ``surface`` where it has a
        height, else the full-resolution field's."""
        hf = self.squares.hf
        if surface is None:
            return hf.points(rr, cc)
        x, y = hf.world_xy(rr, cc)
        z = surface(x, y)
        if np.isnan(z).any():
            z = np.where(np.isnan(z), hf.points(rr, cc)[:, 2], z)
        return np.c_[x, y, z]

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
