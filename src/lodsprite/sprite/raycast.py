"""C' by ray casting against a coarse level (Chen, Swan & Kaufman 1999, §3.2, Fig. 4).

``C'`` is where the ray from the keyframe eye through a full-resolution vertex ``C`` meets
the coarse surface.  It is computed exactly (Möller & Trumbore 1997, vectorised): against
the two coarse triangles of the vertex's square and its eight neighbours, then wider
neighbourhoods (:data:`SEARCH_RADII`), finally every coarse triangle under the ray's
ground track (:func:`crossed_triangles`: no other can meet it); the hit in front of
the eye nearest to ``C`` along the ray is kept.  A ray that meets nothing ends where it
leaves the terrain's footprint (a miss, see :mod:`lodsprite.sprite.metric`).  Every stage
runs in blocks of at most :data:`RAY_PAIRS` ray-triangle pairs, so memory stays bounded
(about 32 MB of temporaries) while time grows with misses × n².
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lodsprite.sprite.resampling import cross
from lodsprite.terrain.heightfield import HeightField
from lodsprite.terrain.lod import level_indices, level_step

SEARCH_RADII = (3, 8, 1 << 30)
RAY_PAIRS = 1 << 17   # ray-triangle pairs intersected at once (about 32 MB of temporaries)
TRACK_RAYS = 256      # rays whose ground tracks are gathered at once (whole-level stage)
FALLBACK_CACHE = 1 << 15  # reprojected fallback vertices kept per keyframe and level


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

    ``fallback_cache`` holds the fallback vertices already reprojected for this keyframe
    (:meth:`ErrorMetric.fallback_theta`), so that successive frames measuring the
    fallback sample reproject only the vertices they have not met yet; views share it,
    pickling drops it.

    For the resampling term (:mod:`lodsprite.sprite.resampling`) it also carries the
    keyframe's ``key_view_proj (4, 4) float64`` (the widened projection it was rendered
    through, times its view matrix) and ``key_size (w, h)`` pixels (image plus guard band),
    both None when unknown (the metric takes the normal at ``C'`` from
    :func:`coarse_normals`).

    ``points (n*n, 3)``: the keyframe's own ``C`` when the metric takes it from the
    surface the keyframe shows (``ErrorMetric.surface``; None: the squares' centres), with
    ``points_h`` (w = 1) and that surface's height function ``surface(x, y) -> z`` (for
    the fallback sample); views of the same shape keep them, pickling drops them.
    """

    key_eye: np.ndarray | None
    missed: np.ndarray | None
    fallback_cache: dict
    key_view_proj: np.ndarray | None
    key_size: tuple[int, int] | None
    points: np.ndarray | None
    points_h: np.ndarray | None
    surface: object | None

    def __new__(cls, c_prime: np.ndarray, key_eye: np.ndarray,
                missed: np.ndarray | None = None, key_view_proj: np.ndarray | None = None,
                key_size: tuple[int, int] | None = None) -> Reprojection:
        obj = np.asarray(c_prime, dtype=np.float64).view(cls)
        obj.key_eye = np.array(key_eye, dtype=np.float64)
        obj.missed = None if missed is None else np.asarray(missed, dtype=bool)
        obj.fallback_cache = {}
        obj.key_view_proj = (None if key_view_proj is None
                             else np.array(key_view_proj, dtype=np.float64))
        obj.key_size = None if key_size is None else (int(key_size[0]), int(key_size[1]))
        obj.points = obj.points_h = obj.surface = None
        return obj

    def set_points(self, points: np.ndarray, surface=None) -> None:
        """Carry the keyframe's own ``C (K, 3)`` (and the surface it was taken from)."""
        self.points = np.asarray(points, np.float64)
        self.points_h = np.c_[self.points, np.ones(len(self.points))]
        self.surface = surface

    def __array_finalize__(self, obj) -> None:
        self.key_eye = getattr(obj, "key_eye", None)
        cache = getattr(obj, "fallback_cache", None)
        self.fallback_cache = {} if cache is None else cache
        missed = getattr(obj, "missed", None)
        self.missed = missed if missed is not None and obj.shape == self.shape else None
        self.key_view_proj = getattr(obj, "key_view_proj", None)
        self.key_size = getattr(obj, "key_size", None)
        pts = getattr(obj, "points", None)
        same = pts is not None and len(pts) == len(self) and obj.shape == self.shape
        self.points = pts if same else None
        self.points_h = getattr(obj, "points_h", None) if same else None
        self.surface = getattr(obj, "surface", None)

    def __array_wrap__(self, arr, context=None, return_scalar=False):
        # Results of ufuncs and reductions are plain arrays and scalars, not C'.
        plain = arr.view(np.ndarray)
        return plain[()] if return_scalar else plain

    def __reduce__(self):
        fn, args, state = super().__reduce__()
        return fn, args, (state, self.key_eye, self.missed, self.key_view_proj, self.key_size)

    def __setstate__(self, state) -> None:
        array_state, self.key_eye, self.missed, *key = state
        self.key_view_proj, self.key_size = (key + [None, None])[:2]
        self.fallback_cache = {}
        self.points = self.points_h = self.surface = None
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
    return _nearest_score(t)[0]


def _nearest_score(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(t, |t - 1|)`` per row of :func:`_nearest_to_c` (NaN and inf where none)."""
    score = np.where(np.isnan(t) | (t <= 0), np.inf, np.abs(t - 1.0))
    j = np.argmin(score, axis=1)
    rows = np.arange(len(t))
    best, low = t[rows, j], score[rows, j]
    return np.where(np.isfinite(low), best, np.nan), low


def nearest_hits(origin: np.ndarray, d: np.ndarray, tris, count: int,
                 chunk_pairs: int = RAY_PAIRS) -> np.ndarray:
    """:func:`_nearest_to_c` of rays ``origin + t d (K, 3)`` against ``count`` triangles
    per ray, ``tris(k0, k1, j0, j1) -> (k1-k0, j1-j0, 3, 3)`` giving those of rays
    ``k0:k1``, numbers ``j0:j1``; intersected in blocks of at most ``chunk_pairs``
    ray-triangle pairs (rays, then triangles), so that temporaries stay bounded.  Equal to
    the unblocked result: of equally near hits, the first triangle's is kept in both.
    """
    k = len(d)
    t_best = np.full(k, np.nan)
    if k == 0 or count == 0:
        return t_best
    per = max(1, min(count, chunk_pairs))
    rays = max(1, chunk_pairs // per)
    for k0 in range(0, k, rays):
        k1 = min(k0 + rays, k)
        low = np.full(k1 - k0, np.inf)
        best = np.full(k1 - k0, np.nan)
        for j0 in range(0, count, per):
            j1 = min(j0 + per, count)
            t, score = _nearest_score(ray_triangle_t(origin, d[k0:k1], tris(k0, k1, j0, j1)))
            better = score < low
            low = np.where(better, score, low)
            best = np.where(better, t, best)
        t_best[k0:k1] = np.where(np.isfinite(low), best, np.nan)
    return t_best


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
    Every stage runs in blocks of at most :data:`RAY_PAIRS` ray-triangle pairs
    (:func:`nearest_hits`): the whole level costs about ``12 n`` tests per ray that
    reaches it (the squares its ground track crosses, :func:`crossed_triangles`; every
    ``2 n²`` triangles before: 4 s a keyframe at ``n = 128``), never more memory than one
    block.
    """
    key_eye = np.asarray(key_eye, dtype=np.float64)
    d = points - key_eye  # the point at t = 1
    index = np.arange(len(points)) if square is None else np.asarray(square, np.intp)
    n = squares.level_quads
    first = squares.tris
    t_best = nearest_hits(key_eye, d, lambda k0, k1, j0, j1: first[index[k0:k1], j0:j1],
                          first.shape[1])
    every = squares.own.reshape(-1, 3, 3)
    for radius in SEARCH_RADII:
        missing = np.flatnonzero(np.isnan(t_best))
        if missing.size == 0:
            break
        at = index[missing]
        if radius >= n:  # the whole level: the squares under the ray only, in blocks
            for b in range(0, len(missing), TRACK_RAYS):  # bounded index arrays
                rays = missing[b:b + TRACK_RAYS]
                crossed = crossed_triangles(squares, key_eye, d[rays])

                def tris(k0, k1, j0, j1, crossed=crossed):
                    return every[crossed[k0:k1, j0:j1]]
                t_best[rays] = nearest_hits(key_eye, d[rays], tris, crossed.shape[1])
            break
        def tris(k0, k1, j0, j1, at=at, radius=radius):
            return _neighbourhood(squares, at[k0:k1], radius)[:, j0:j1]
        t_best[missing] = nearest_hits(key_eye, d[missing], tris, 2 * (2 * radius + 1) ** 2)
    missed = np.isnan(t_best)
    if missed.any():
        t_best[missed] = _exit_t(squares, key_eye, d[missed])
    return key_eye + t_best[:, None] * d, missed


def crossed_triangles(squares: CoarseSquares, origin: np.ndarray,
                      d: np.ndarray) -> np.ndarray:
    """``(K, M) intp`` indices into ``squares.own.reshape(-1, 3, 3)``: for each ray
    ``origin + t d (K, 3)``, ``t > 0``, the triangles of every coarse square its ground
    track crosses inside the footprint (no triangle elsewhere can meet it), rows padded
    with repeats.  The track is sampled every half square, and the 3x3 squares around
    each sample are taken (a square the track only clips at a corner neighbours a
    sample): about ``2 n`` squares a ray instead of the whole level's ``n²``."""
    n = squares.level_quads
    lo, hi = squares.hf.bounds()
    size = (hi[:2] - lo[:2]) / n  # a square's extent, x and y
    o, dd = np.asarray(origin, np.float64)[:2], d[:, :2]
    with np.errstate(divide="ignore", invalid="ignore"):
        ta, tb = (lo[:2] - o) / dd, (hi[:2] - o) / dd
        t_in = np.nanmax(np.where(dd != 0, np.minimum(ta, tb), -np.inf), axis=1)
        t_out = np.nanmin(np.where(dd != 0, np.maximum(ta, tb), np.inf), axis=1)
    # a vertical ray (no ground track) or a track that never enters: one point, C's own
    flat = ~np.isfinite(t_out)
    t_in = np.where(flat, 1.0, np.maximum(t_in, 0.0))
    t_out = np.where(flat, 1.0, np.maximum(t_out, t_in))
    span = np.hypot(*((t_out - t_in)[:, None] * dd / size).T)  # track length in squares
    steps = int(np.clip(np.ceil(2 * span.max(initial=0.0)), 1, 4 * n)) + 1
    f = np.linspace(0.0, 1.0, steps)
    t = t_in[:, None] + f[None] * (t_out - t_in)[:, None]  # (K, S)
    x = o[0] + t * dd[:, 0:1]
    y = o[1] + t * dd[:, 1:2]
    col = np.clip(np.floor((x - lo[0]) / size[0]), 0, n - 1).astype(np.intp)
    row = np.clip(np.floor((hi[1] - y) / size[1]), 0, n - 1).astype(np.intp)  # row 0 north
    off = np.array([-1, 0, 1])
    rr = np.clip(row[:, :, None, None] + off[None, None, :, None], 0, n - 1)
    cc = np.clip(col[:, :, None, None] + off[None, None, None, :], 0, n - 1)
    sq = np.sort((rr * n + cc).reshape(len(d), -1), axis=1)
    keep = np.ones(sq.shape, bool)
    keep[:, 1:] = sq[:, 1:] != sq[:, :-1]
    width = int(keep.sum(axis=1).max(initial=1))
    order = np.argsort(~keep, axis=1, kind="stable")[:, :width]  # the unique ones first
    uniq = np.take_along_axis(sq, order, axis=1)
    valid = np.take_along_axis(keep, order, axis=1)
    uniq = np.where(valid, uniq, uniq[:, :1])  # padded with the first square
    return (2 * uniq[:, :, None] + np.array([0, 1])).reshape(len(d), -1)


def reprojected_centres(squares: CoarseSquares, key_eye: np.ndarray,
                        key_view_proj: np.ndarray | None = None,
                        key_size: tuple[int, int] | None = None) -> Reprojection:
    """``C'`` for every square ``(n*n, 3)``: the ray ``key_eye -> C`` meeting the coarse
    surface (:func:`reproject_points`), carrying ``key_eye``, the misses and the
    keyframe's ``key_view_proj`` and ``key_size`` (None: unknown)."""
    c_prime, missed = reproject_points(squares, key_eye, squares.centres)
    return Reprojection(c_prime, key_eye, missed, key_view_proj, key_size)


def coarse_normals(squares: CoarseSquares, points: np.ndarray) -> np.ndarray:
    """Unit normals ``(K, 3) float64`` (pointing up) of the coarse triangles under
    ``points (K, 3)`` metres: the square whose xy extent holds the point (clamped at the
    borders) and the half of it on the point's side of the nw-se diagonal (the
    renderer's split).  On a hit ``C'`` this is the triangle the ray met."""
    own = squares.own  # (n*n, 2, 3, 3): (nw, sw, se) and (nw, se, ne)
    n = squares.level_quads
    grid = own.reshape(n, n, 2, 3, 3)
    xs = np.r_[grid[0, :, 0, 0, 0], grid[0, -1, 1, 2, 0]]      # nw x per column, ne x last
    ys = np.r_[grid[:, 0, 0, 0, 1], grid[-1, 0, 0, 1, 1]]      # nw y per row, sw y last
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    col = np.clip(np.searchsorted(xs, p[:, 0]) - 1, 0, n - 1)
    row = np.clip(np.searchsorted(-ys, -p[:, 1]) - 1, 0, n - 1)
    u = (p[:, 0] - xs[col]) / (xs[col + 1] - xs[col])          # west -> east
    v = (ys[row] - p[:, 1]) / (ys[row] - ys[row + 1])          # north -> south
    tri = own[row * n + col, np.where(v >= u, 0, 1)]           # (K, 3, 3)
    nrm = cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    nrm *= np.where(nrm[:, 2:3] < 0, -1.0, 1.0)
    return nrm / np.linalg.norm(nrm, axis=1, keepdims=True)


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
