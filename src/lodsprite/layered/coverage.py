"""The screen coverage of a scene's layers, measured on the CPU from their geometry: the
``Size`` of the frame budget's benefits (Funkhouser & Séquin 1993, §4;
:mod:`lodsprite.scene.costs`), never read back from the GPU.

Every figure is the fraction of the cells of a coarse ``n x n`` grid over the window
(:data:`GRID`; each cell the same share of the window's area, whatever its aspect) whose
centre a layer covers; shapes that overlap count once:

* :func:`terrain_coverage` - the terrain's non-sky part: a ray from the eye through each
  cell centre (a coarser grid, :data:`TERRAIN_GRID`) marched through the terrain's
  bounding box against its max-pooled heights (:func:`coarse_max`); a ray that meets the
  ground covers its cell (the sky line and the terrain's edges both come out of the
  geometry);
* :func:`rects_coverage` - the union of window rectangles (the light fields' proxies'
  screen rectangles, :func:`~lodsprite.layered.lightfields.screen_rect`);
* :func:`discs_coverage` - the union of discs in pixels (the objects' bounding spheres
  projected).

Occlusion between layers is left out: each layer's figure is what it would cover alone.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from lodsprite.camera import Viewpoint
    from lodsprite.terrain.heightfield import HeightField

#: Cells a side of the coverage grid.
GRID = 32
#: :func:`discs_coverage`: discs up to this many cells in radius are splatted.
SPLAT = 3
#: Cells a side of :func:`terrain_coverage`'s grid (a ray each).
TERRAIN_GRID = 16
#: Blocks a side of the max-pooled heights the terrain's rays are marched against.
COARSE = 64


def grid_points(n: int = GRID) -> np.ndarray:
    """The cell centres ``(n * n, 2) float64`` in window fractions ``0..1``."""
    f = (np.arange(n) + 0.5) / n
    u, v = np.meshgrid(f, f)
    return np.c_[u.ravel(), v.ravel()]


def rects_coverage(rects, n: int = GRID) -> float:
    """The fraction of the window the union of ``rects`` covers: each ``(x0, y0, w, h)``
    in window fractions (as :func:`~lodsprite.layered.lightfields.screen_rect`)."""
    p = grid_points(n)
    hit = np.zeros(len(p), bool)
    for x0, y0, w, h in rects:
        hit |= ((p[:, 0] >= x0) & (p[:, 0] <= x0 + w) & (p[:, 1] >= y0) & (p[:, 1] <= y0 + h))
    return float(hit.mean())


def discs_coverage(centres_px: np.ndarray, radii_px: np.ndarray, size: tuple[int, int],
                   n: int = GRID) -> float:
    """The fraction of a ``size (w, h)`` pixel window the union of discs covers: centres
    ``(k, 2)`` and radii ``(k,)`` in pixels (any origin corner: the grid is symmetric).
    A disc at most :data:`SPLAT` cells in radius tests the cells round its own; a larger
    one every cell."""
    c = np.asarray(centres_px, np.float64).reshape(-1, 2)
    r = np.asarray(radii_px, np.float64).reshape(-1)
    cell = np.asarray(size, np.float64) / n
    hit = np.zeros(n * n, bool)
    small = r <= SPLAT * cell.min()
    off = np.stack(np.meshgrid(np.arange(-SPLAT - 1, SPLAT + 2),
                               np.arange(-SPLAT - 1, SPLAT + 2)), -1).reshape(-1, 2)
    cand = np.floor(c[small] / cell).astype(np.intp)[:, None, :] + off[None]   # (k, m, 2)
    inside = ((((cand + 0.5) * cell - c[small][:, None, :]) ** 2).sum(-1)
              <= r[small][:, None] ** 2) & (cand >= 0).all(-1) & (cand < n).all(-1)
    hit[cand[inside][:, 1] * n + cand[inside][:, 0]] = True
    p = grid_points(n) * np.asarray(size, np.float64)
    for centre, radius in zip(c[~small], r[~small], strict=True):
        hit |= ((p - centre) ** 2).sum(1) <= radius ** 2
    return float(hit.mean())


def cell_rays(viewpoint: Viewpoint, projection: np.ndarray, n: int = GRID) -> np.ndarray:
    """Unit directions ``(n * n, 3)`` from the eye through each cell centre (world)."""
    inv = np.linalg.inv(np.asarray(projection, np.float64) @ viewpoint.view_matrix())
    ndc = grid_points(n) * 2.0 - 1.0
    far = np.c_[ndc, np.ones(len(ndc)), np.ones(len(ndc))] @ inv.T
    d = far[:, :3] / far[:, 3:] - np.asarray(viewpoint.o, np.float64)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def coarse_max(hf: HeightField, cells: int = COARSE) -> np.ndarray:
    """The heightfield's heights max-pooled to at most ``cells x cells`` blocks ``(r, c)
    float64`` (metres; row 0 the north edge, as ``hf.heights``): conservative, a thin
    ridge is never lost between samples."""
    h = np.asarray(hf.heights, np.float64)
    rs = np.array_split(np.arange(h.shape[0]), min(cells, h.shape[0]))
    cs = np.array_split(np.arange(h.shape[1]), min(cells, h.shape[1]))
    return np.array([[h[r[0]:r[-1] + 1, c[0]:c[-1] + 1].max() for c in cs] for r in rs])


def terrain_coverage(hf: HeightField, viewpoint: Viewpoint, projection: np.ndarray,
                     n: int = TERRAIN_GRID, coarse: np.ndarray | None = None,
                     max_steps: int = 128) -> float:
    """The fraction of the window the terrain ``hf`` covers (its non-sky part) seen from
    ``viewpoint`` through ``projection (4, 4)``: a ray through each of ``n x n`` cell
    centres, from where it enters the terrain's bounding box to where it leaves, sampled
    every half a block of ``coarse`` (:func:`coarse_max`, made if not given; at most
    ``max_steps`` samples a ray); it covers its cell if a sample is at or below the
    block's highest height."""
    top = coarse_max(hf) if coarse is None else coarse
    lo, hi = hf.bounds()
    block = min(hf.width / top.shape[1], hf.depth / top.shape[0])
    lo[2], hi[2] = lo[2] - block, top.max()  # a flat terrain's box has depth too
    o = np.asarray(viewpoint.o, np.float64)
    d = cell_rays(viewpoint, projection, n)
    with np.errstate(divide="ignore", invalid="ignore"):
        a, b = (lo - o) / d, (hi - o) / d
    t_in = np.nanmax(np.maximum(np.fmin(a, b), [0.0, 0.0, 0.0]), axis=1)
    t_out = np.nanmin(np.fmax(a, b), axis=1)
    k = np.arange(max_steps) + 0.5
    step = np.maximum((t_out - t_in) / max_steps, block / 2)
    t = t_in[:, None] + k[None, :] * step[:, None]
    pts = o + d[:, None, :] * t[..., None]                    # (rays, steps, 3)
    ok = (t < t_out[:, None]) & (t_out > t_in)[:, None]
    row = np.clip(((hi[1] - pts[..., 1]) / hf.depth * top.shape[0]).astype(np.intp), 0,
                  top.shape[0] - 1)
    col = np.clip(((pts[..., 0] - lo[0]) / hf.width * top.shape[1]).astype(np.intp), 0,
                  top.shape[1] - 1)
    return float((ok & (pts[..., 2] <= top[row, col])).any(1).mean())
