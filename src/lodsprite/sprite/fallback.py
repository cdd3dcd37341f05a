"""The error metric's fallback sample (:mod:`lodsprite.sprite.metric`, "Nothing
measurable"): when fewer than :data:`MIN_SAMPLES` coarse square centres lie in the view,
full-resolution vertices in view that are not coarse vertices are measured instead.

They are enumerated only inside the coarse squares whose bounding box (with the heights
of their vertices, :func:`square_boxes`) meets the view frustum (:func:`squares_in_view`),
on the grid of spacing ``step/2``, then ``step/4``, ... down to 1, refined while fewer
than :data:`MIN_SAMPLES` are in view or while the finer grid has at most
``ENUMERATE_FACTOR * MAX_FALLBACK`` candidates (:func:`fallback_grid`); candidates are
tested :data:`CANDIDATE_CHUNK` at a time, and at most :data:`MAX_FALLBACK` are kept,
evenly in row-major order.  Their ``C'`` is reprojected through the keyframe eye once
per keyframe and cached in its :class:`~lodsprite.sprite.raycast.Reprojection`
(:func:`reproject_fallback`).  Pure numpy over a
:class:`~lodsprite.sprite.raycast.CoarseSquares`.
"""

from __future__ import annotations

import numpy as np

from lodsprite.sprite.raycast import FALLBACK_CACHE, CoarseSquares, reproject_points
from lodsprite.terrain.lod import level_indices

MIN_SAMPLES = 4       # fewer square centres in view than this: measure the fallback sample
MAX_FALLBACK = 256    # at most this many fallback vertices are measured (evenly chosen)
ENUMERATE_FACTOR = 4  # the fallback grid is refined while it has at most this times
                      # MAX_FALLBACK candidate vertices in the coarse squares the view meets
CANDIDATE_CHUNK = 1 << 14  # candidate vertices tested against the view at once

Boxes = tuple[np.ndarray, np.ndarray]
"""``(lo, hi) (n*n, 3)`` float64 metres: each coarse square's vertex bounds."""


def in_view(points_h: np.ndarray, view_proj: np.ndarray) -> np.ndarray:
    """``(K,) bool``: homogeneous points ``(K, 4)`` inside the view frustum of ``view_proj``."""
    clip = points_h @ view_proj.T
    w = clip[:, 3:4]
    return (w[:, 0] > 0) & np.all(np.abs(clip[:, :3]) <= w, axis=1)


def square_boxes(sq: CoarseSquares) -> Boxes:
    """``(lo, hi) (n*n, 3)``: bounds of the full-resolution vertices of each coarse
    square (edges included)."""
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


def squares_in_view(boxes: Boxes, view_proj: np.ndarray) -> np.ndarray:
    """Indices ``(Q,) intp`` of the coarse squares whose bounding box meets the view
    frustum of ``view_proj`` (conservatively: every vertex in view lies in one)."""
    lo, hi = boxes
    m = np.asarray(view_proj, dtype=np.float64)
    planes = np.array([m[3] + m[0], m[3] - m[0], m[3] + m[1], m[3] - m[1],
                       m[3] + m[2], m[3] - m[2]])
    keep = np.ones(len(lo), bool)
    scale = np.abs(np.r_[lo.min(axis=0), hi.max(axis=0)]).max() + 1.0
    for pl in planes:
        top = np.where(pl[:3] > 0, hi, lo) @ pl[:3] + pl[3]
        keep &= top >= -1e-9 * (np.abs(pl[:3]).sum() * scale + abs(pl[3]))
    return np.flatnonzero(keep)


def visible_grid(sq: CoarseSquares, squares: np.ndarray, s: int,
                 view_proj: np.ndarray) -> np.ndarray:
    """Sorted linear indices of the vertices on the grid of spacing ``s`` inside the
    coarse ``squares`` that are in view and are not coarse vertices; the candidates are
    tested :data:`CANDIDATE_CHUNK` at a time."""
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


def fallback_grid(sq: CoarseSquares, boxes: Boxes,
                  view_proj: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(rows (K,), cols (K,)) intp`` of the fallback sample of the current view: at most
    :data:`MAX_FALLBACK` vertices, in row-major order."""
    step = sq.step
    squares = squares_in_view(boxes, view_proj)
    s = step // 2  # the centres' spacing: every grid below includes them
    while True:
        idx = visible_grid(sq, squares, s, view_proj)
        if s == 1:
            break
        finer = len(squares) * (2 * step // s + 1) ** 2  # candidates at spacing s/2
        if len(idx) >= MIN_SAMPLES and finer > ENUMERATE_FACTOR * MAX_FALLBACK:
            break
        s //= 2
    if len(idx) > MAX_FALLBACK:
        idx = idx[np.linspace(0, len(idx) - 1, MAX_FALLBACK).round().astype(np.intp)]
    return np.divmod(idx, sq.hf.cols)


def containing_square(sq: CoarseSquares, rr: np.ndarray, cc: np.ndarray) -> np.ndarray:
    """``(K,) intp``: the coarse square each vertex ``(rr, cc)`` lies in."""
    n, step = sq.level_quads, sq.step
    return np.minimum(rr // step, n - 1) * n + np.minimum(cc // step, n - 1)


def fallback_vertices(sq: CoarseSquares, rr: np.ndarray, cc: np.ndarray,
                      surface) -> np.ndarray:
    """Points ``(K, 3)`` of the fallback vertices: on ``surface(x, y) -> z`` where it has
    a height (None: nowhere), else the full-resolution field's."""
    hf = sq.hf
    if surface is None:
        return hf.points(rr, cc)
    x, y = hf.world_xy(rr, cc)
    z = surface(x, y)
    if np.isnan(z).any():
        z = np.where(np.isnan(z), hf.points(rr, cc)[:, 2], z)
    return np.c_[x, y, z]


def reproject_fallback(sq: CoarseSquares, key_eye: np.ndarray, rr: np.ndarray,
                       cc: np.ndarray, pts: np.ndarray, cache: dict | None,
                       surface) -> tuple[np.ndarray, np.ndarray]:
    """``(C' (K, 3) metres, missed (K,) bool)`` of the fallback vertices ``pts`` at
    ``(rr, cc)`` for the keyframe seen from ``key_eye``.  ``cache``: that keyframe's
    ``Reprojection.fallback_cache``; vertices reprojected before are taken from it and
    the new ones added (up to ``FALLBACK_CACHE``; over a store, a vertex whose level-0
    height is not resident yet is not cached)."""
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
        square = containing_square(sq, rr[new], cc[new])
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
    return p_prime, missed
