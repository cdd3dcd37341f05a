"""View-dependent selection over a terrain pyramid, in the manner of CDLOD (Strugar 2009)
with screen-space error (as CesiumJS refines its tiles), GL-free.

A node ``(k, i, j)`` is a ``G x G``-quad block of pyramid level ``k``: its samples
``[i G, i G + G] x [j G, j G + G]`` (a shared border), placed at every ``2^k``-th level-0
position (so the grids of successive levels nest).  Its children are the four nodes of
level ``k - 1`` beneath it; the roots tile the coarsest level.

Level ``k``'s geometric error ``e_k`` (metres, the store's ``level_errors``: the
triangulated level-``k`` grid against level 0) seen from distance ``d`` spans
``e_k · H / (2 d tan(fov / 2))`` pixels of an ``H``-pixel-high image, so level ``k`` is
fine enough beyond the range ``R_k = e_k · H / (2 τ tan(fov / 2))`` for a tolerance of
``τ`` pixels.  A node is refined while the distance from the eye to its bounding box is
below ``R_k`` (its projected error exceeds ``τ``) and all four children are resident;
otherwise it is drawn (a parent stands in for children still loading, whose loads are
requested, most urgent first: largest ``R_k / d``).  Ranges at least double from level to
level and grow by at least a node's diagonal, so neighbours differ by at most one level; a
vertex of a level-``k`` node morphs towards level ``k + 1``'s surface over the last
``MORPH_SPAN`` of ``[R_k, R_{k+1}]``, reaching it where the parent would be drawn instead
(no pop, no crack once the wanted nodes are resident; while a parent stands in for
children still loading, its edge against their loaded neighbours may show T-junctions).
"""

from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass

import numpy as np

from lodsprite.camera import boxes_in_frustum

MORPH_SPAN = 0.3
DEFAULT_GRID = 64


@dataclass(frozen=True)
class Node:
    """A quadtree node: level ``k``, block row ``i`` and column ``j``."""

    k: int
    i: int
    j: int

    def parent(self) -> Node:
        return Node(self.k + 1, self.i // 2, self.j // 2)

    def children(self) -> tuple[Node, ...]:
        return tuple(Node(self.k - 1, 2 * self.i + a, 2 * self.j + b)
                     for a in (0, 1) for b in (0, 1))


def ranges(level_errors, tolerance_px: float, height_px: int, fov_y_deg: float,
           node_diagonals=None) -> np.ndarray:
    """``R_k`` (metres) per level: where level ``k``'s error projects to the tolerance,
    at least doubling from level to level and, given ``node_diagonals`` (a node's
    diagonal per level, metres), at least ``R_{k-1}`` plus a level-``k`` node's diagonal
    (CDLOD's condition for neighbours at most one level apart)."""
    f = height_px / (2.0 * tolerance_px * math.tan(math.radians(fov_y_deg) / 2))
    r = np.asarray(level_errors, dtype=np.float64) * f
    for k in range(1, len(r)):
        r[k] = max(r[k], 2.0 * r[k - 1], 1e-6)
        if node_diagonals is not None:
            r[k] = max(r[k], r[k - 1] + node_diagonals[k])
    r[0] = 0.0
    return r


def screen_error_px(error_m: float, distance_m: float, height_px: int, fov_y_deg: float
                    ) -> float:
    """A geometric error ``error_m`` seen from ``distance_m``, in pixels."""
    return error_m * height_px / (2.0 * max(distance_m, 1e-9)
                                  * math.tan(math.radians(fov_y_deg) / 2))


class Quadtree:
    """Nodes, bounds and selection over a pyramid (``levels``, ``shape(k)``,
    ``minmax(k)`` per ``chunk``, ``level_errors``, ``dx``, ``dy``; see
    :class:`~lodsprite.terrain.store.TerrainStore`)."""

    def __init__(self, pyramid, grid: int = DEFAULT_GRID) -> None:
        self.p, self.g = pyramid, int(grid)
        r0, c0 = pyramid.shape(0)
        self.rows0, self.cols0 = r0, c0
        self.levels = pyramid.levels
        self.top = self.levels - 1
        self.errors = np.asarray(pyramid.level_errors, dtype=np.float64)
        self.minmax = [np.asarray(pyramid.minmax(k)) for k in range(self.levels)]
        self.chunk = pyramid.chunk
        self._bounds: dict[Node, tuple[np.ndarray, np.ndarray]] = {}
        self._kids: dict[Node, list[Node]] = {}

    def node_diagonals(self) -> np.ndarray:
        """A node's diagonal (metres) per level."""
        return np.array([math.hypot(self.g * (1 << k) * self.p.dx, self.g * (1 << k) * self.p.dy)
                         for k in range(self.levels)])

    def blocks(self, k: int) -> tuple[int, int]:
        """Node rows and columns at level ``k``."""
        r, c = self.p.shape(k)
        return max(1, -(-(r - 1) // self.g)), max(1, -(-(c - 1) // self.g))

    def kids(self, n: Node) -> list[Node]:
        """``n``'s children that exist (computed once a node)."""
        out = self._kids.get(n)
        if out is None:
            out = self._kids[n] = [c for c in n.children() if self.exists(c)]
        return out

    def roots(self) -> list[Node]:
        br, bc = self.blocks(self.top)
        return [Node(self.top, i, j) for i in range(br) for j in range(bc)]

    def exists(self, n: Node) -> bool:
        if not 0 <= n.k < self.levels:
            return False
        br, bc = self.blocks(n.k)
        return 0 <= n.i < br and 0 <= n.j < bc

    def samples(self, n: Node) -> tuple[int, int, int, int]:
        """The node's level-``k`` sample window ``r0, r1, c0, c1`` (``r1`` exclusive,
        clipped to the level)."""
        r, c = self.p.shape(n.k)
        r0, c0 = n.i * self.g, n.j * self.g
        return r0, min(r, r0 + self.g + 1), c0, min(c, c0 + self.g + 1)

    def world_xy(self, k: int, rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, ...]:
        """World ``x`` (east) and ``y`` (north), metres, of level-``k`` sample indices,
        the level-0 grid centred on the origin."""
        s = 1 << k
        x = (np.asarray(cols) * s - (self.cols0 - 1) / 2.0) * self.p.dx
        y = ((self.rows0 - 1) / 2.0 - np.asarray(rows) * s) * self.p.dy
        return x, y

    def box(self) -> tuple[np.ndarray, np.ndarray]:
        """The terrain's box ``(lo (3,), hi (3,))`` metres: level 0's extent, heights from
        the coarsest level's chunk bounds (what near and far planes are fitted to)."""
        mm = self.minmax[self.top]
        x, y = self.world_xy(0, np.array([0, self.rows0 - 1]), np.array([0, self.cols0 - 1]))
        return (np.array([x.min(), y.min(), float(np.nanmin(mm[..., 0]))]),
                np.array([x.max(), y.max(), float(np.nanmax(mm[..., 1]))]))

    def height_range(self) -> tuple[float, float]:
        """Level 0's lowest and highest height (metres, from its chunk bounds)."""
        mm = self.minmax[0]
        return float(np.nanmin(mm[..., 0])), float(np.nanmax(mm[..., 1]))

    def ground_below(self, eye) -> float:
        """A height (metres) at or above the ground under ``eye``: the highest sample of
        the level-0 chunk it stands over (the lowest of the terrain off its footprint).
        The near plane sits at half the eye's clearance above it: the terrain's lowest
        point there put the near plane beyond the ground in view of a low flight."""
        col = eye[0] / self.p.dx + (self.cols0 - 1) / 2.0
        row = (self.rows0 - 1) / 2.0 - eye[1] / self.p.dy
        if not (0 <= row <= self.rows0 - 1 and 0 <= col <= self.cols0 - 1):
            return float(self.box()[0][2])
        mm = self.minmax[0]
        i = min(int(row) // self.chunk, mm.shape[0] - 1)
        j = min(int(col) // self.chunk, mm.shape[1] - 1)
        return float(mm[i, j, 1])

    def bounds(self, n: Node) -> tuple[np.ndarray, np.ndarray]:
        """The node's bounding box ``(lo (3,), hi (3,))``, heights from its chunks' min and
        max widened by the level's error (computed once a node)."""
        box = self._bounds.get(n)
        if box is None:
            box = self._bounds[n] = self._box(n)
        return box

    def _box(self, n: Node) -> tuple[np.ndarray, np.ndarray]:
        r0, r1, c0, c1 = self.samples(n)
        x, y = self.world_xy(n.k, np.array([r0, r1 - 1]), np.array([c0, c1 - 1]))
        mm = self.minmax[n.k][r0 // self.chunk: (r1 - 1) // self.chunk + 1,
                              c0 // self.chunk: (c1 - 1) // self.chunk + 1]
        lo_z, hi_z = np.nanmin(mm[..., 0]), np.nanmax(mm[..., 1])
        # the node's own error, and how far its vertices may morph towards the parent
        e = self.errors[min(n.k + 1, self.top)]
        return (np.array([x.min(), y.min(), lo_z - e]), np.array([x.max(), y.max(), hi_z + e]))

    def select(self, eye: np.ndarray, planes: np.ndarray, r: np.ndarray, resident,
               ) -> tuple[list[Node], list[tuple[float, Node]]]:
        """The nodes to draw and the loads to request ``(urgency, node)``: see the module
        doc.  ``resident(node) -> bool``; ``planes (6, 4)`` the frustum."""
        draw, want = [], []
        stack = [n for n in self.roots() if resident(n)]
        while stack:
            n = stack.pop()
            lo, hi = self.bounds(n)
            if not boxes_in_frustum(planes, lo[None], hi[None])[0]:
                continue
            d = float(np.linalg.norm(np.clip(eye, lo, hi) - eye))
            if n.k > 0 and d < r[n.k]:
                kids = self.kids(n)
                missing = [c for c in kids if not resident(c)]
                if not missing:
                    stack.extend(kids)
                    continue
                urgency = r[n.k] / max(d, 1e-6)
                want.extend((urgency, c) for c in missing)
            draw.append(n)
        return draw, want


def selection_counts(tree: Quadtree, eye: np.ndarray, planes: np.ndarray,
                     ranges_by_setting: np.ndarray) -> np.ndarray:
    """How many nodes :meth:`Quadtree.select` would draw under each of several range sets
    (every node resident), in one traversal: ``ranges_by_setting (s, levels)`` the ``R_k``
    of each setting, non-decreasing down the settings (finer tolerances, longer ranges:
    :func:`ranges` of descending tolerances), ``planes (6, 4)`` the frustum -> ``(s,)
    int64`` nodes drawn (the scene budget's terrain cost model: triangles are these times
    ``2 · grid²``).  A node is split where ``d < R_k``; since the ranges grow down the
    settings, the settings that reach a node, and those that split it, are each a suffix
    ``i >= j``: a node reached from ``j`` and split from ``i0`` is drawn by ``j <= i <
    i0``.  Breadth first, one frustum test a level."""
    R = np.asarray(ranges_by_setting, np.float64)
    if np.any(np.diff(R, axis=0) < 0):
        raise ValueError("ranges must not shrink down the settings")
    s_count = R.shape[0]
    by_level = [R[:, k].tolist() for k in range(R.shape[1])]
    diff = [0] * (s_count + 1)   # drawn from j to i0: +1 at j, -1 at i0
    level = [(n, 0) for n in tree.roots()]
    eye = np.asarray(eye, np.float64)
    while level:
        boxes = [tree.bounds(n) for n, _ in level]
        lo = np.array([b[0] for b in boxes])
        hi = np.array([b[1] for b in boxes])
        inside = boxes_in_frustum(planes, lo, hi).tolist()
        dist = np.linalg.norm(np.clip(eye, lo, hi) - eye, axis=1).tolist()
        nxt = []
        for (n, j), d, seen in zip(level, dist, inside, strict=True):
            if not seen:
                continue
            i0 = s_count
            if n.k > 0:
                i0 = max(j, bisect_right(by_level[n.k], d))
                if i0 < s_count:
                    kids = tree.kids(n)
                    if kids:
                        nxt.extend((c, i0) for c in kids)
                    else:
                        i0 = s_count
            diff[j] += 1
            diff[i0] -= 1
        level = nxt
    return np.cumsum(diff[:-1]).astype(np.int64)


def morph_factor(distance: np.ndarray, k: int, r: np.ndarray) -> np.ndarray:
    """How far a level-``k`` vertex at ``distance`` has morphed towards level ``k + 1``:
    0 until ``R_{k+1} - MORPH_SPAN (R_{k+1} - R_k)``, 1 from ``R_{k+1}``."""
    if k + 1 >= len(r):
        return np.zeros_like(np.asarray(distance, dtype=np.float64))
    end = r[k + 1]
    start = end - MORPH_SPAN * (r[k + 1] - r[k])
    return np.clip((np.asarray(distance, np.float64) - start) / max(end - start, 1e-9), 0, 1)


def coarse_surface(fine_uv: np.ndarray, quadrant: tuple[int, int], parent: np.ndarray,
                   grid: int) -> np.ndarray:
    """Level ``k + 1``'s triangulated surface at the samples ``fine_uv (..., 2)`` (row,
    column) of a level-``k`` node in ``quadrant`` of its parent (heights ``parent``): the
    mean of the two parent samples at the floor and ceiling of the position."""
    p = np.asarray(quadrant)[None, :] * (grid // 2) + np.asarray(fine_uv, np.float64) / 2
    lo, hi = np.floor(p).astype(int), np.ceil(p).astype(int)
    rmax, cmax = parent.shape[0] - 1, parent.shape[1] - 1
    lo = np.minimum(lo, [rmax, cmax])
    hi = np.minimum(hi, [rmax, cmax])
    return 0.5 * (parent[lo[..., 0], lo[..., 1]] + parent[hi[..., 0], hi[..., 1]])
