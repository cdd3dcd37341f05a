"""Covering the st plane with a subset of nodes (Sloan, Cohen & Gortler 1997, §3.1, §3.3,
Figures 3-4), GL-free.

Every method reconstructs from a list of *draws*: an st-plane triangle, the node whose uv
image textures it, and an alpha at each of its three corners.  The alphas of all draws
that cover a point sum to one (§3.1 (b)), so additive blending reconstructs the image.

* :func:`cover_draws` - the paper's ``draw_node_with_data`` / ``draw_node_without_data``
  over any triangulation whose vertices carry a data *validity* in [0, 1] (§3.3; 1 for a
  node with data, 0 for a fictitious node).  Node ``a`` with validity ``v_a`` gets alpha
  ``v_a`` at itself on every triangle round it, and ``(1 - v_b) / n_b`` at each
  neighbour ``b`` with ``v_b < 1`` on every triangle round ``b`` (``n_b``: neighbours of
  ``b`` with data), so at every vertex ``v_b + (1 - v_b) = 1``.  A vertex with
  ``v < 1`` and no neighbour with data is a hole (:attr:`Draws.holes`).
* :func:`grid_cover`, :func:`subset_cover` - the full grid; any subset of nodes,
  triangulated (Delaunay) with fictitious nodes at the st square's corners so that the
  whole plane is covered (sub-sample, fixed 9, arbitrary, progressive).
* :func:`line_draws` - nodes along a row or column: strips perpendicular to the line,
  each drawn twice, alpha 1 along the line through its node and 0 at the far edge (§3.1,
  Figure 4).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import Delaunay

from lodsprite.errors import InputError
from lodsprite.lumigraph.geometry import Slab, grid_triangles

FICTITIOUS = -1


@dataclass(frozen=True)
class Cover:
    """A triangulated covering of the st plane: ``points (V, 2)`` st metres, ``tris (T, 3)
    int`` vertex indices, ``node (V,) int`` the grid node ``i * n_st + j`` a vertex is
    (-1: a fictitious vertex) and ``validity (V,)`` in [0, 1] (0 for fictitious ones)."""

    points: np.ndarray
    tris: np.ndarray
    node: np.ndarray
    validity: np.ndarray


@dataclass(frozen=True)
class Draws:
    """What to draw: ``corners (D, 3, 2)`` st metres of each draw's triangle, ``node (D,)``
    the grid node whose uv image textures it, ``alpha (D, 3)`` at its corners; ``holes``
    counts vertices left without any data in reach."""

    corners: np.ndarray
    node: np.ndarray
    alpha: np.ndarray
    holes: int = 0

    @property
    def nodes(self) -> np.ndarray:
        """The distinct nodes drawn, sorted."""
        return np.unique(self.node)

    def __len__(self) -> int:
        return len(self.node)


def _edges(tris: np.ndarray, n_vertices: int, extra: np.ndarray | None = None
           ) -> tuple[np.ndarray, np.ndarray]:
    """The triangulation's neighbours (plus ``extra (E, 2)`` pairs) as CSR ``(indptr
    (V+1,), indices)``, both ways."""
    e = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    if extra is not None and len(extra):
        e = np.concatenate([e, extra])
    e = np.concatenate([e, e[:, ::-1]])
    key = np.unique(e[:, 0].astype(np.int64) * n_vertices + e[:, 1])
    src, dst = key // n_vertices, key % n_vertices
    indptr = np.searchsorted(src, np.arange(n_vertices + 1))
    return indptr, dst


def _valid_neighbours(indptr: np.ndarray, nbr: np.ndarray, v: np.ndarray) -> np.ndarray:
    src = np.repeat(np.arange(len(v)), np.diff(indptr))
    return np.bincount(src, weights=(v[nbr] > 0), minlength=len(v))


def cover_draws(cover: Cover) -> Draws:
    """The draws of §3.1's ``draw_node_with_data`` over ``cover`` with §3.3's validity.

    Beyond the paper: a vertex lacking data with no neighbour that has some (the paper's
    hole) borrows its nearest vertex with data as a neighbour, so any covering with at
    least one node with data has no hole."""
    tris = np.asarray(cover.tris, dtype=np.int64)
    v = np.clip(np.asarray(cover.validity, dtype=np.float64), 0.0, 1.0)
    pts = np.asarray(cover.points, dtype=np.float64)
    nv = len(v)
    indptr, nbr = _edges(tris, nv)
    n_valid = _valid_neighbours(indptr, nbr, v)
    used = np.bincount(tris.reshape(-1), minlength=nv) > 0
    lonely = np.flatnonzero(used & (v < 1.0) & (n_valid == 0))
    data = np.flatnonzero(v > 0)
    if len(lonely) and len(data):
        d = np.linalg.norm(pts[lonely][:, None] - pts[data][None], axis=2)
        d[lonely[:, None] == data[None]] = np.inf               # never itself
        near = data[np.argmin(d, axis=1)]
        ok = np.isfinite(d.min(axis=1))
        indptr, nbr = _edges(tris, nv, np.stack([lonely[ok], near[ok]], axis=1))
        n_valid = _valid_neighbours(indptr, nbr, v)
    deg = np.diff(indptr)
    src = np.repeat(np.arange(nv), deg)
    # Candidate (triangle, texture node): each corner's own data, and its neighbours' data
    # where the corner lacks some (draw_node_without_data).
    t_idx = np.repeat(np.arange(len(tris)), 3)
    k = tris.reshape(-1)
    counts = deg[k]
    at = np.repeat(indptr[k] - np.cumsum(counts) + counts, counts) + np.arange(counts.sum())
    t = np.concatenate([t_idx, np.repeat(t_idx, counts)])
    a = np.concatenate([k, nbr[at]])
    keep = v[a] > 0
    pair = np.unique(t[keep] * nv + a[keep])
    t, a = pair // nv, pair % nv
    corner = tris[t]                                             # (P, 3)
    edge_keys = src * nv + nbr                                   # sorted
    q = a[:, None] * nv + corner
    pos = np.clip(np.searchsorted(edge_keys, q), 0, max(len(edge_keys) - 1, 0))
    adjacent = (edge_keys[pos] == q) if len(edge_keys) else np.zeros_like(q, bool)
    vk = v[corner]
    with np.errstate(divide="ignore", invalid="ignore"):
        share = np.where(n_valid[corner] > 0, (1.0 - vk) / n_valid[corner], 0.0)
    alpha = np.where(corner == a[:, None], v[a][:, None],
                     np.where(adjacent & (vk < 1.0), share, 0.0))
    drawn = alpha.max(axis=1) > 0
    holes = int(np.count_nonzero(used & (v < 1.0) & (n_valid == 0)))
    node = np.asarray(cover.node)[a[drawn]]
    return Draws(pts[corner[drawn]], node, alpha[drawn], holes)


def grid_cover(slab: Slab, validity: np.ndarray | None = None) -> Cover:
    """The full ``n_st x n_st`` grid (Figure 2); ``validity (n_st, n_st)`` (default: 1)."""
    n = slab.n_st
    s = slab.st_coords()
    ss, tt = np.meshgrid(s, s, indexing="ij")
    v = np.ones(n * n) if validity is None else np.asarray(validity, np.float64).reshape(-1)
    node = np.arange(n * n)
    return Cover(np.stack([ss.ravel(), tt.ravel()], 1), grid_triangles(n), node, v)


def subset_cover(slab: Slab, nodes: np.ndarray, validity: np.ndarray | None = None,
                 ring: bool = True) -> Cover:
    """Nodes ``i * n_st + j`` (any subset, validity default 1) plus fictitious nodes,
    triangulated (Delaunay) so that the whole st square is covered (Figure 3): with
    ``ring``, the grid nodes next to the subset (8-neighbours not in it), so that a
    triangle outside the subset is drawn from the one or two nodes beside it as in
    Figure 3; and the st square's corners."""
    nodes = np.asarray(nodes, dtype=np.int64).reshape(-1)
    if len(nodes) == 0:
        raise InputError("a node subset needs at least one node")
    n = slab.n_st
    s = slab.st_coords()
    pts = np.stack([s[nodes // n], s[nodes % n]], 1)
    v = np.ones(len(nodes)) if validity is None else np.asarray(validity, np.float64)
    h = slab.st_size / 2
    corners = np.array([[-h, -h], [h, -h], [h, h], [-h, h]])
    if ring:
        around = _ring(nodes, n)
        corners = np.concatenate([np.stack([s[around // n], s[around % n]], 1), corners])
    corners = np.unique(corners, axis=0)                           # a ring node may be one
    near = np.linalg.norm(corners[:, None, :] - pts[None], axis=2).min(axis=1)
    corners = corners[near > 1e-9 * slab.st_size]               # corners that are not nodes
    all_pts = np.concatenate([pts, corners])
    if len(all_pts) < 3:
        raise InputError("a node subset must span the st plane with its fictitious corners")
    tri = Delaunay(all_pts, qhull_options="QJ Pp")
    return Cover(all_pts, tri.simplices.astype(np.int64),
                 np.concatenate([nodes, np.full(len(corners), FICTITIOUS)]),
                 np.concatenate([v, np.zeros(len(corners))]))


def _ring(nodes: np.ndarray, n: int) -> np.ndarray:
    """Grid nodes next to ``nodes`` (8-neighbourhood) but not among them."""
    inside = np.zeros((n + 2, n + 2), bool)
    inside[nodes // n + 1, nodes % n + 1] = True
    grown = inside.copy()
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            grown[1:-1, 1:-1] |= inside[1 + di: n + 1 + di, 1 + dj: n + 1 + dj]
    ring = grown[1:-1, 1:-1] & ~inside[1:-1, 1:-1]
    return np.flatnonzero(ring.ravel())


def subsample_nodes(n_st: int, level: int) -> np.ndarray:
    """The nodes of level ``level`` of the st mipmap: every ``2**level``-th node along s and
    t, plus the last one so the level spans the whole plane, ``(k,)`` ``i * n_st + j``."""
    step = 1 << int(level)
    idx = np.arange(0, n_st, step)
    if idx[-1] != n_st - 1:
        idx = np.append(idx, n_st - 1)
    ii, jj = np.meshgrid(idx, idx, indexing="ij")
    return (ii * n_st + jj).ravel()


def nearest_block(slab: Slab, st: np.ndarray, k: int = 3) -> np.ndarray:
    """The ``k x k`` nodes round the st point ``st (2,)`` (Figure 3's 9 for ``k = 3``),
    clamped inside the grid, ``(k*k,)`` ``i * n_st + j``."""
    n = slab.n_st
    k = min(int(k), n)
    spacing = slab.st_size / (n - 1)
    centre = np.rint((np.asarray(st, float) + slab.st_size / 2) / spacing).astype(int)
    lo = np.clip(centre - k // 2, 0, n - k)
    ii, jj = np.meshgrid(np.arange(lo[0], lo[0] + k), np.arange(lo[1], lo[1] + k),
                         indexing="ij")
    return (ii * n + jj).ravel()


def nearest_nodes(slab: Slab, st: np.ndarray, count: int) -> np.ndarray:
    """The ``count`` nodes nearest the st point ``st (2,)``, nearest first."""
    pts = slab.node_local()[..., :2].reshape(-1, 2)
    d = np.linalg.norm(pts - np.asarray(st, float), axis=1)
    return np.argsort(d, kind="stable")[: max(1, int(count))]


def line_draws(slab: Slab, st: np.ndarray, direction: np.ndarray) -> Draws:
    """§3.1's nodes along a line: the row (motion mostly along s) or column (along t) of
    nodes through the node nearest ``st (2,)``; the strip between adjacent line nodes,
    spanning the st square across the line, is drawn once from each with alpha 1 along
    the line through that node and 0 along the other edge (Figure 4)."""
    n, h = slab.n_st, slab.st_size / 2
    c = slab.st_coords()
    axis = 0 if abs(float(direction[0])) >= abs(float(direction[1])) else 1
    other = int(np.argmin(np.abs(c - float(st[1 - axis]))))
    a, b = c[:-1], c[1:]
    idx = np.arange(n - 1)

    def quad(x0, x1):  # two triangles of the strip [x0, x1] x [-h, h], as (s, t) corners
        lo, hi = np.full_like(x0, -h), np.full_like(x0, h)
        p = [np.stack([x0, lo], -1), np.stack([x1, lo], -1), np.stack([x1, hi], -1),
             np.stack([x0, hi], -1)]
        tri = np.stack([np.stack([p[0], p[1], p[2]], 1), np.stack([p[0], p[2], p[3]], 1)], 1)
        return tri if axis == 0 else tri[..., ::-1]           # (S, 2, 3, 2)

    tri = quad(a, b).reshape(-1, 3, 2)
    near_a = np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 1.0]])    # alpha 1 on the x0 edge
    alpha_a = np.tile(near_a, (n - 1, 1))
    node_a = np.repeat(idx, 2)
    node_b = node_a + 1
    line = (lambda k: k * n + other) if axis == 0 else (lambda k: other * n + k)
    return Draws(np.concatenate([tri, tri]), np.concatenate([line(node_a), line(node_b)]),
                 np.concatenate([alpha_a, 1.0 - alpha_a]))
