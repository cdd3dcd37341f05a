"""Keyframes refreshed tile by tile under a frame budget, free of GL (Qu, Wan, Qin & Kaufman
2000: no whole keyframes, part of the image re-rendered every frame; the error of each
part is Chen, Swan & Kaufman 1999 Eq. 1-2).

The keyframe image (the frame plus its guard band) is split into an ``N x N`` grid of
screen tiles.  Tile ``t`` keeps its own keyframe: a viewpoint, the full widened key
projection there (the tile is its sub-rectangle), its own ``C'`` and its error.

* **Which tile serves a sample.**  A metric sample (a coarse square centre ``C`` in the
  current view) is served by the first tile, in index order, whose key projection maps
  ``C`` into the tile's rectangle (:func:`serving_tiles`); the tiled spriteframe shader
  picks its tile per fragment by the same rule.  A sample no tile serves (the view turned
  beyond every tile's keyframe) is charged to the tile whose rectangle holds it in the
  current view's key projection, with ``θ = π`` (a miss): that tile, re-rendered now,
  serves it.
* **Samples.**  The metric's square centres, or, with a view-dependent proxy
  (:class:`~lodsprite.sprite.proxy_metric.ProxyMetric`), each update's own samples (its
  ``C'`` carries them, :func:`samples`): a tile's are those of its own ``C'`` it serves.
* **Error per tile** (:func:`tile_errors`): ``sqrt(mean θ²) / β`` over the samples it
  serves, ``θ`` measured against the tile's own ``C'`` (misses floored as in
  :func:`~lodsprite.sprite.metric.miss_floor`).  A tile serving fewer than
  :data:`~lodsprite.sprite.metric.MIN_SAMPLES` samples takes the whole view's error
  measured with its own ``C'`` (:meth:`~lodsprite.sprite.metric.ErrorMetric.error_px`,
  fallback sample included): the 1999 metric of its keyframe.
* **Selection** (:func:`select_tiles`), as the lumigraph's critical-time selection orders
  nodes: tiles over ε are candidates, ordered by benefit/cost, ``benefit = error/ε x
  served area`` (the fraction of the view's samples the tile serves, at least
  ``1/T``), ``cost`` = the tile's last measured time (ms).  They are taken in that order,
  skipping those that no longer fit, while the sum of costs stays within
  ``budget_ms``.  **Forced tiles** (the documented exception to the budget): tiles never
  rendered are all taken (the first frame is a whole keyframe); otherwise, when some
  candidate is over ``2 ε``, the worst one (largest error) is taken first whatever its
  cost, and the budget left for the others is ``budget_ms`` minus its cost.  So the cost
  selected is at most ``max(budget_ms, cost of the forced tile)`` once every tile has been
  rendered.
"""

from __future__ import annotations

import math

import numpy as np

from lodsprite.sprite.metric import MIN_SAMPLES, ErrorMetric, angles_at_eye, in_view, miss_floor
from lodsprite.sprite.raycast import Reprojection, reproject_points

TILES = "tiles"  # frame kind: some tiles, not all, re-rendered
FORCE_FACTOR = 2.0  # a candidate over this many ε forces the worst tile in


def tile_rects(n: int, size: tuple[int, int]) -> np.ndarray:
    """Pixel rectangles ``(n*n, 4) int64`` ``(x0, y0, x1, y1)`` of an ``n x n`` grid over
    an image of ``size = (w, h)`` pixels, GL window coordinates (``y`` up from the
    bottom row), tile ``t = row * n + col`` with row 0 at the bottom; half-open."""
    if not (isinstance(n, int | np.integer) and n >= 1):
        raise ValueError(f"tiles must be a whole number >= 1, got {n}")
    w, h = size
    xs = np.linspace(0, w, n + 1).round().astype(np.int64)
    ys = np.linspace(0, h, n + 1).round().astype(np.int64)
    r, c = np.divmod(np.arange(n * n), n)
    return np.c_[xs[c], ys[r], xs[c + 1], ys[r + 1]]


def ndc_rects(rects: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """The pixel rectangles ``(T, 4)`` of :func:`tile_rects` in NDC, ``(T, 4) float64``
    ``(x0, y0, x1, y1)`` in [-1, 1]."""
    w, h = size
    scale = np.array([w, h, w, h], np.float64)
    return np.asarray(rects, np.float64) / scale * 2.0 - 1.0


def sub_view_proj(view_proj: np.ndarray, ndc_rect: np.ndarray) -> np.ndarray:
    """``(4, 4)``: ``view_proj`` restricted to the NDC rectangle ``(x0, y0, x1, y1)``: the
    rectangle maps to the whole of [-1, 1]², so its frustum planes
    (:func:`~lodsprite.camera.frustum_planes`) bound the tile's sub-frustum."""
    x0, y0, x1, y1 = (float(v) for v in ndc_rect)
    s = np.eye(4)
    s[0, 0], s[0, 3] = 2.0 / (x1 - x0), -(x1 + x0) / (x1 - x0)
    s[1, 1], s[1, 3] = 2.0 / (y1 - y0), -(y1 + y0) / (y1 - y0)
    return s @ np.asarray(view_proj, np.float64)


def in_rects(points_h: np.ndarray, view_projs: np.ndarray, rects: np.ndarray) -> np.ndarray:
    """``(T, K) bool``: homogeneous points ``(K, 4)`` in front of each key view ``(T, 4, 4)``
    whose NDC ``x, y`` fall in the tile's NDC rectangle ``(T, 4)`` (half-open, as pixels)."""
    clip = np.einsum("tij,kj->tki", view_projs, points_h)
    w = clip[..., 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        x, y = clip[..., 0] / w, clip[..., 1] / w
    r = rects[:, None, :]
    return ((w > 0) & (x >= r[..., 0]) & (x < r[..., 2]) & (y >= r[..., 1]) & (y < r[..., 3]))


def serving_tiles(points_h: np.ndarray, view_projs: np.ndarray, rects: np.ndarray) -> np.ndarray:
    """``(K,) intp``: for each homogeneous point ``(K, 4)``, the first tile whose key view
    maps it into its rectangle, -1 where none does."""
    inside = in_rects(points_h, view_projs, rects)
    first = np.argmax(inside, axis=0)
    return np.where(inside.any(axis=0), first, -1)


def tile_errors(metric: ErrorMetric, c_primes: list, key_view_projs: np.ndarray,
                rects: np.ndarray, eye: np.ndarray, view_proj: np.ndarray,
                key_view_proj: np.ndarray, pixel_angle_rad: float,
                size: tuple[int, int] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(errors (T,) px, served (T,) samples)`` of the tiles at the current view.

    ``c_primes``: each tile's ``C'`` (``(n*n, 3)``, a Reprojection; None: never rendered,
    error ``inf``); ``key_view_projs (T, 4, 4)``: each tile's key view-projection;
    ``rects (T, 4)``: NDC rectangles; ``view_proj``: the current frame's;
    ``key_view_proj``: the key projection at the current viewpoint (where samples no tile
    serves are charged); ``pixel_angle_rad``: β; ``size = (w, h)``: the current image's
    pixels, needed when ``metric.resampling`` (each tile's ``C'`` then carries its key
    view-projection and key size, :func:`reproject_in_key_view`, and every hit's θ² gains
    the resampling term of :mod:`lodsprite.sprite.resampling` through that tile's key
    view).  Module docstring for the rule.
    """
    t = len(rects)
    errors = np.full(t, math.inf)
    served = np.zeros(t, np.intp)
    eye = np.asarray(eye, np.float64)
    groups: dict[int, tuple] = {}  # per C' (tiles of one update share it): its samples
    for i in range(t):
        if c_primes[i] is None:
            continue
        key = id(c_primes[i])
        if key not in groups:
            points, points_h = samples(metric, c_primes[i])
            vis = np.flatnonzero(in_view(points_h, view_proj))
            owner = serving_tiles(points_h[vis], key_view_projs, rects)
            lost = owner < 0
            if lost.any():
                owner[lost] = serving_tiles(points_h[vis[lost]],
                                            key_view_proj[None].repeat(t, 0), rects)
            groups[key] = (points, vis, owner, lost, None)
        points, vis, owner, lost, whole = groups[key]
        mine = owner == i
        served[i] = int(mine.sum())
        if served[i] < MIN_SAMPLES:
            if whole is None:
                whole = _whole_px(metric, c_primes[i], eye, view_proj, pixel_angle_rad, size)
                groups[key] = (points, vis, owner, lost, whole)
            errors[i] = whole
            continue
        err = _rms_px(metric, c_primes[i], points, vis[mine], lost[mine], eye, view_proj,
                      pixel_angle_rad, size)
        if err is not None:
            errors[i] = err
    return errors, served


def samples(metric, c_prime) -> tuple[np.ndarray, np.ndarray]:
    """``(points (K, 3), points_h (K, 4))``: the samples ``C`` of ``c_prime``: its own
    (a view-dependent proxy's :class:`~lodsprite.sprite.proxy_metric.ProxyReprojection`),
    else the metric's square centres."""
    points = getattr(c_prime, "points", None)
    if points is not None:
        return points, c_prime.points_h
    return metric.squares.centres, metric._centres_h


def _whole_px(metric, c_prime, eye, view_proj, beta, size) -> float:
    """The whole view's error of ``c_prime`` (the metric's own rule)."""
    if getattr(metric, "resampling", False):
        return metric.error_px(c_prime, eye, view_proj, beta, size=size)
    return metric.error_px(c_prime, eye, view_proj, beta)


def _rms_px(metric: ErrorMetric, c_prime, points: np.ndarray, idx: np.ndarray,
            gone: np.ndarray, eye: np.ndarray, view_proj: np.ndarray, beta: float,
            size: tuple[int, int] | None) -> float | None:
    """``sqrt(mean θ²) / β`` px over the samples ``points[idx]`` a tile serves against its
    ``c_prime`` (``gone``: samples no tile serves, ``θ = π``), misses floored, the
    resampling term added with ``metric.resampling``; None when every sample missed."""
    cp = np.asarray(c_prime)[idx]
    th = angles_at_eye(eye, points[idx], cp)
    missed = getattr(c_prime, "missed", None)
    missed = np.zeros(len(idx), bool) if missed is None else missed[idx].copy()
    th[gone], missed[gone] = np.pi, True
    if missed.all():
        return None  # nothing this tile draws
    if getattr(metric, "resampling", False):
        th = metric._with_resampling(th, missed, cp, c_prime, view_proj, beta, size, idx)
    th = miss_floor(th, missed)
    return float(np.sqrt(np.mean(th * th)) / beta)


def render_error(metric: ErrorMetric, c_prime, key_view_proj: np.ndarray, rect: np.ndarray,
                 eye: np.ndarray, view_proj: np.ndarray, pixel_angle_rad: float,
                 size: tuple[int, int] | None = None) -> float:
    """Error (px) at the current view of one render of a tile, alone: over the centres in
    view that its key view ``key_view_proj (4, 4)`` maps into the tile's NDC ``rect (4,)``
    (which tile serves a sample is ignored: the tiled cache compares renders of one tile
    with it, :class:`lodsprite.sprite.cache.TileCache`); the whole view's error with its ``C'``
    below :data:`~lodsprite.sprite.metric.MIN_SAMPLES`; ``inf`` when nothing it draws is
    in view."""
    points, points_h = samples(metric, c_prime)
    vis = np.flatnonzero(in_view(points_h, view_proj))
    mine = vis[in_rects(points_h[vis], np.asarray(key_view_proj)[None],
                        np.asarray(rect)[None])[0]]
    eye = np.asarray(eye, np.float64)
    if mine.size < MIN_SAMPLES:
        return _whole_px(metric, c_prime, eye, view_proj, pixel_angle_rad, size)
    err = _rms_px(metric, c_prime, points, mine, np.zeros(mine.size, bool), eye, view_proj,
                  pixel_angle_rad, size)
    return math.inf if err is None else err


def tiles_frustum(key_view_proj: np.ndarray, ndc: np.ndarray, chosen) -> np.ndarray | None:
    """``(4, 4)``: the sub-frustum of the tiles ``chosen`` (indices into ``ndc (T, 4)``,
    their NDC bounding rectangle) in ``key_view_proj``, whose samples alone an update of
    those tiles needs in its ``C'``; None when every tile is chosen."""
    if len(chosen) == len(ndc):
        return None
    r = np.asarray(ndc)[np.asarray(chosen, np.intp)]
    box = np.array([r[:, 0].min(), r[:, 1].min(), r[:, 2].max(), r[:, 3].max()])
    return sub_view_proj(key_view_proj, box)


def reproject_in_key_view(metric: ErrorMetric, key_eye: np.ndarray,
                          key_view_proj: np.ndarray,
                          key_size: tuple[int, int] | None = None,
                          within: np.ndarray | None = None) -> Reprojection:
    """``C'`` of a tile update (:class:`~lodsprite.sprite.raycast.Reprojection`, ``(n*n,
    3)``) computed only for the centres inside its key view ``key_view_proj (4, 4)``: no
    tile of the update serves the others.  They count as misses (``C' = C``, floored to
    the worst hit by :func:`~lodsprite.sprite.metric.miss_floor`) should the whole-view
    error of a tile serving few samples meet them.  Ray casting grazing rays to centres
    behind or beside a low keyframe eye was most of the cost of a full ``C'``.  The
    Reprojection carries ``key_view_proj`` and ``key_size = (w, h)`` (the keyframe target's
    pixels, guard band included) for the resampling term.  A metric without square centres
    (a view-dependent proxy's, :class:`~lodsprite.sprite.proxy_metric.ProxyMetric`, whose
    samples are the proxy's nodes culled by the key view) gives its own ``reproject``, and
    so does one taking its ``C`` from the surface the keyframe shows (``metric.surface``,
    over a store: :class:`~lodsprite.techniques.drawn_surface.DrawnSurface`).

    ``within (4, 4)``: the sub-frustum of the tiles the update re-renders
    (:func:`sub_view_proj`): only samples there are reprojected (the other tiles keep
    their own ``C'``); a view-dependent proxy's metric takes it too."""
    if not hasattr(metric, "squares"):
        return metric.reproject(key_eye, key_view_proj, key_size, within=within)
    if getattr(metric, "surface", None) is not None:
        return metric.reproject(key_eye, key_view_proj, key_size)
    sq = metric.squares
    vis = np.flatnonzero(in_view(metric._centres_h, key_view_proj if within is None
                                 else within))
    c_prime = sq.centres.astype(np.float64).copy()
    missed = np.ones(len(c_prime), bool)
    if vis.size:
        c_prime[vis], missed[vis] = reproject_points(sq, key_eye, sq.centres[vis], vis)
    return Reprojection(c_prime, key_eye, missed, key_view_proj, key_size)


def combined_error(errors: np.ndarray, served: np.ndarray) -> float:
    """The error of the whole image (px): ``sqrt(Σ served·err² / Σ served)`` over tiles that
    serve samples (the RMS over every sample); the largest error when none serves."""
    errors = np.asarray(errors, np.float64)
    w = np.asarray(served, np.float64)
    if w.sum() <= 0:
        return float(errors.max()) if errors.size else 0.0
    on = w > 0
    if np.any(~np.isfinite(errors[on])):
        return math.inf
    return float(np.sqrt((w[on] * errors[on] ** 2).sum() / w.sum()))


def select_tiles(errors: np.ndarray, epsilon_px: float, costs_ms: np.ndarray,
                 served: np.ndarray, budget_ms: float,
                 rendered: np.ndarray | None = None) -> np.ndarray:
    """The tiles to re-render this frame, ``(S,) intp`` in the order to render them.

    ``errors (T,) px`` (``inf``/NaN count as over every threshold), ``costs_ms (T,)``
    (last measured or estimated), ``served (T,)`` (samples each serves), ``rendered (T,)
    bool`` (default all True).  Module docstring for the rule (forced tiles first, then
    benefit/cost order within the budget)."""
    errors = np.where(np.isnan(errors), np.inf, np.asarray(errors, np.float64))
    costs = np.maximum(np.asarray(costs_ms, np.float64), 1e-6)
    t = len(errors)
    rendered = np.ones(t, bool) if rendered is None else np.asarray(rendered, bool)
    if not rendered.all():
        return np.arange(t)
    over = np.flatnonzero(errors >= epsilon_px)
    if over.size == 0:
        return over
    area = np.maximum(np.asarray(served, np.float64) / max(1, int(np.sum(served))), 1.0 / t)
    with np.errstate(invalid="ignore"):
        benefit = np.minimum(errors / epsilon_px, 1e12) * area
    order = over[np.argsort(-(benefit[over] / costs[over]), kind="stable")]
    chosen: list[int] = []
    left = float(budget_ms)
    worst = over[np.argmax(errors[over])]
    if errors[worst] >= FORCE_FACTOR * epsilon_px:
        chosen.append(int(worst))
        left -= costs[worst]
    for i in order:
        if i in chosen or costs[i] > left:
            continue
        chosen.append(int(i))
        left -= costs[i]
    return np.asarray(chosen, np.intp)
