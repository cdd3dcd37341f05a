"""A view-dependent sprite proxy (Chen, Swan & Kaufman 1999 §5, "view-dependent LODs
under the sprite"): LOD-sprite's spriteframes draw the adaptive mesh
(:mod:`lodsprite.techniques.adaptive_terrain`) selected at a coarse tolerance
``proxy_sse`` pixels, geomorphed, instead of one uniform coarse level.

The design:

* **Selected at the keyframe, frozen for its lifetime.**  When a keyframe is decided, the
  quadtree selection (CDLOD ranges of ``proxy_sse``) is made at its eye and culled with its
  frustum widened ``WIDEN`` times (tangents of the half-angles, guard band included), so
  frames turning away from the keyframe still find geometry; morph factors are those at
  the keyframe eye.  The keyframe's spriteframes draw that instance list (each the nodes
  whose boxes meet its own view), and its coarse z-buffer (visibility rule ``coarse``) is
  the same mesh from the keyframe's view.
* **The ordering.**  The error metric's ``C'`` needs the proxy, and the policy asks for
  ``C'`` (:meth:`ProxyMetric.reproject`) before the engine renders the keyframe.  So the
  selection is made in :meth:`AdaptiveProxySource.select`, called by the metric with the
  keyframe's eye and view; the GL freeze (:meth:`for_keyframe`, when the keyframe is
  kept) takes the selection made for that same eye and view.  The selection is pinned at
  once: its tiles (and the parents it morphs towards) stay in the GPU cache while the
  keyframe may be shown.
* **Tiles.**  Only resident nodes are selected (their descendants are selected only when
  resident): coarse levels the keyframe's own selection holds, so nothing is read here.
  The metric's CPU copy of a node's samples comes from the host cache, else from its GPU
  slot (:meth:`~lodsprite.techniques.adaptive_terrain.AdaptiveTerrain.node_heights`).
* **No border ribbons.**  The uniform proxy's ribbons (:mod:`lodsprite.terrain.proxy`)
  hang from a coarse edge that stands below the full-resolution edge; the adaptive
  proxy's edge is the adaptive mesh's, within ``proxy_sse`` pixels of the full edge at the
  keyframe, so keyframe pixels above it are at most that far off.  They are not drawn:
  those pixels show sky in a spriteframe, and the metric counts their samples' rays as
  misses if they leave the proxy.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from lodsprite.camera import frustum_planes
from lodsprite.errors import InputError
from lodsprite.sprite.proxy_surface import ProxyNodes, ProxySurface, triangle_height
from lodsprite.terrain.quadtree import morph_factor, ranges

WIDEN = 2.0     # the proxy's culling frustum: the keyframe's, tangents times this
PROXY_GRID = 16  # quads per side of a proxy node's mesh (every G/16-th node sample)
_CACHED = 4     # selections kept for the freeze (the look-ahead tries several eyes)
_ALL = np.array([[0.0, 0.0, 0.0, 1.0]] * 6)  # planes every box is inside


def strided_errors(errors: np.ndarray, stride: int) -> np.ndarray:
    """Per level ``k``, the error (metres) of its nodes drawn with every ``stride``-th
    sample: level ``k + log2 stride``'s (a decimated level), doubling per level past the
    top (an extrapolation: the pyramid has no coarser level to measure)."""
    e = np.asarray(errors, np.float64)
    shift, top = int(round(np.log2(stride))), len(e) - 1
    k = np.arange(len(e)) + shift
    return np.where(k <= top, e[np.minimum(k, top)], e[top] * 2.0 ** (k - top))


def parent_surfaces(pos: np.ndarray, quadrant: np.ndarray, parent: np.ndarray,
                    top: np.ndarray, grid: int, stride: int,
                    which: np.ndarray | None = None) -> np.ndarray:
    """Each parent's surface on its own proxy mesh (every ``stride``-th sample) at its
    child's samples ``pos (N, ..., 2)`` (row, column), the child in ``quadrant (N, 2)``;
    ``parent (N, R, C)`` the parents' samples, ``top (N, 2)`` their last valid row and
    column: the vertex shader's morph target (:data:`lodsprite.gl.adaptive.
    ADAPTIVE_POSITION_COMMON`).  ``which (N,) intp``: the row of ``parent`` each child
    reads (default: its own, ``parent`` and ``top`` then have ``N`` rows too)."""
    extra = (1,) * (pos.ndim - 2)
    q = np.asarray(quadrant).reshape(len(pos), *extra, 2)
    rows = np.arange(len(pos)) if which is None else np.asarray(which, np.intp)
    cap = np.asarray(top)[rows].reshape(len(pos), *extra, 2)
    p = (q * (grid // 2) + pos / 2.0) / stride
    lo = np.minimum(np.floor(p).astype(np.intp) * stride, cap)
    hi = np.minimum(np.ceil(p).astype(np.intp) * stride, cap)
    idx = rows.reshape(len(pos), *extra)
    return 0.5 * (parent[idx, lo[..., 0], lo[..., 1]] + parent[idx, hi[..., 0], hi[..., 1]])


def parent_surface(pos: np.ndarray, quadrant: tuple[int, int], parent: np.ndarray,
                   grid: int, stride: int) -> np.ndarray:
    """:func:`parent_surfaces` of one node: ``pos (..., 2)``, ``parent (R, C)``."""
    return parent_surfaces(np.asarray(pos)[None], np.asarray(quadrant)[None], parent[None],
                           np.array([parent.shape]) - 1, grid, stride)[0]


def node_layout(tree, nodes, stride: int) -> tuple[np.ndarray, ...]:
    """Where ``nodes`` of ``tree`` stand, drawn with every ``stride``-th sample: ``(origin
    (N, 2) metres, spacing (N, 2) metres, ext (N, 2) intp: the last valid sample row and
    column within the node, windows (N, 4) intp level-0 windows, k (N,) levels, s (N,)
    level scales 2^k)``."""
    win = np.array([tree.samples(n) for n in nodes], np.intp).reshape(-1, 4)
    k = np.array([n.k for n in nodes], np.intp)
    s = (1 << k).astype(np.float64)
    x, y = tree.world_xy(0, win[:, 0] * s, win[:, 2] * s)  # level-0 indices
    origin = np.c_[x, y]
    spacing = np.c_[stride * s * tree.p.dx, stride * s * tree.p.dy]
    ext = np.minimum(tree.g, np.c_[win[:, 1] - win[:, 0] - 1, win[:, 3] - win[:, 2] - 1])
    windows = np.c_[win[:, 0], win[:, 0] + ext[:, 0], win[:, 2], win[:, 2] + ext[:, 1]]
    windows = (windows * s[:, None]).astype(np.intp)
    return origin, spacing, ext, windows, k, s


def _stacked(terrain, nodes) -> tuple[np.ndarray, np.ndarray]:
    """The resident samples of ``nodes`` as ``(heights (N, G+1, G+1) float64, top (N, 2)
    intp: each one's last row and column)``."""
    g = terrain.tree.g
    out = np.zeros((len(nodes), g + 1, g + 1))
    top = np.zeros((len(nodes), 2), np.intp)
    for i, n in enumerate(nodes):
        tile = terrain.node_heights(n)
        out[i, :tile.shape[0], :tile.shape[1]] = tile
        top[i] = np.array(tile.shape) - 1
    return out, top


def _morphed(terrain, nodes, which: np.ndarray, mask: np.ndarray, pos: np.ndarray,
             xy: np.ndarray, heights: np.ndarray, eye: np.ndarray, stride: int,
             r: np.ndarray) -> np.ndarray:
    """``heights (M, ...)`` at samples ``pos (M, ..., 2)`` (world ``xy (M, ..., 2)``) of
    the nodes ``which (M,)`` indexes in ``nodes``, those with ``mask (M,)`` geomorphed
    towards their parents at ``eye`` as the vertex shader morphs them."""
    if not mask.any():
        return heights
    sub = np.unique(which[mask])
    par, ptop = _stacked(terrain, [nodes[i].parent() for i in sub])
    rows = np.searchsorted(sub, which[mask])
    quad = np.array([(nodes[i].i % 2, nodes[i].j % 2) for i in which[mask]],
                    np.intp).reshape(-1, 2)
    hc = parent_surfaces(pos[mask], quad, par, ptop, terrain.tree.g, stride, rows)
    h = heights[mask]
    d = np.sqrt(((np.concatenate([xy[mask], h[..., None]], -1) - eye) ** 2).sum(-1))
    m = np.zeros_like(d)
    k = np.array([nodes[i].k for i in which[mask]], np.intp)
    for lev in np.unique(k):
        sel = k == lev
        m[sel] = morph_factor(d[sel], int(lev), r)
    out = heights.copy()
    out[mask] = h + m * (hc - h)
    return out


def frozen_nodes(terrain, nodes, morphed: frozenset, eye: np.ndarray, stride: int,
                 r: np.ndarray) -> ProxyNodes:
    """``nodes`` of ``terrain`` (an :class:`~lodsprite.techniques.adaptive_terrain.
    AdaptiveTerrain`; resident) as :class:`ProxyNodes`: every ``stride``-th sample, those
    in ``morphed`` geomorphed towards their parents at ``eye (3,)`` by the range table
    ``r`` as the vertex shader morphs them (heights from the host cache or the GPU slots,
    :meth:`~lodsprite.techniques.adaptive_terrain.AdaptiveTerrain.node_heights`)."""
    tree, st = terrain.tree, stride
    nv = tree.g // st
    origin, spacing, ext, windows, _, s = node_layout(tree, nodes, st)
    own, _ = _stacked(terrain, nodes)
    rc = np.stack(np.meshgrid(np.arange(nv + 1), np.arange(nv + 1), indexing="ij"), -1)
    pos = np.minimum(rc[None] * st, ext[:, None, None, :])  # clamped as the shader does
    which = np.arange(len(nodes))
    heights = own[which[:, None, None], pos[..., 0], pos[..., 1]]
    xy = origin[:, None, None, :] + pos[..., ::-1] * (
        s[:, None] * np.array([tree.p.dx, -tree.p.dy]))[:, None, None, :]
    mask = np.array([n in morphed for n in nodes], bool)
    heights = _morphed(terrain, nodes, which, mask, pos, xy, heights,
                       np.asarray(eye, np.float64), st, r)
    return ProxyNodes(origin, spacing, ext / st, heights, windows)


def drawn_heights(terrain, nodes, morphed: frozenset, eye: np.ndarray, r: np.ndarray
                  ) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """The surface ``nodes`` draw at full resolution (stride 1), geomorphed at ``eye``, as
    a height function ``(x (K,), y (K,)) -> z (K,) float64`` metres (NaN off the nodes):
    the same values as ``ProxySurface(frozen_nodes(..., stride=1)).height``, evaluated at
    the points' cell corners alone (not every sample of every node).  The nodes' layout
    and locator are made once here; each call reads only the nodes its points fall in."""
    tree = terrain.tree
    origin, spacing, ext, windows, _, s = node_layout(tree, nodes, 1)
    surface = ProxySurface(ProxyNodes(origin, spacing, ext.astype(np.float64),
                                      np.zeros((len(nodes), 1, 1)), windows), side=tree.g)
    is_morphed = np.array([n in morphed for n in nodes], bool)
    eye = np.asarray(eye, np.float64)
    corner = np.array([[0, 0], [0, 1], [1, 0], [1, 1]], np.intp)  # nw, ne, sw, se
    step = np.array([tree.p.dx, -tree.p.dy])

    def height(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        j, row, col, fu, fv, inside = surface.cells(x, y)
        j, row, col = j[inside], row[inside], col[inside]
        pos = np.minimum(np.stack([row, col], -1)[:, None] + corner[None], ext[j][:, None])
        sub, rows = np.unique(j, return_inverse=True)
        own, _ = _stacked(terrain, [nodes[i] for i in sub])
        h = own[rows[:, None], pos[..., 0], pos[..., 1]]
        xy = origin[j][:, None] + pos[..., ::-1] * (s[j, None] * step)[:, None]
        h = _morphed(terrain, nodes, j, is_morphed[j], pos, xy, h, eye, 1, r)
        z = np.full(np.shape(x), np.nan)
        z[inside] = triangle_height(h[:, 0], h[:, 1], h[:, 2], h[:, 3], fu[inside],
                                    fv[inside])
        return z

    return height


class AdaptiveProxySource:
    """The view-dependent proxy of ``terrain`` (an
    :class:`~lodsprite.techniques.adaptive_terrain.AdaptiveTerrain`, whose atlas, slots and
    loader it shares) at ``proxy_sse`` pixels: a proxy geometry factory for
    :meth:`lodsprite.gl.sprite.SpriteDrawer.set_proxy` and the source of
    :class:`~lodsprite.sprite.proxy_metric.ProxyMetric`."""

    def __init__(self, terrain, proxy_sse: float, height_px: int,
                 grid: int = PROXY_GRID) -> None:
        from lodsprite.gl.adaptive import AdaptiveProxy

        if not proxy_sse > 0:
            raise InputError(f"--proxy-sse must be > 0 pixels, got {proxy_sse}")
        self.terrain, self.sse = terrain, float(proxy_sse)
        tree = terrain.tree
        self.stride = max(1, tree.g // max(2, min(int(grid), tree.g)))
        self.r = ranges(strided_errors(tree.errors, self.stride), proxy_sse, height_px,
                        terrain.fov, tree.node_diagonals())
        self._made: list[tuple[bytes, tuple, frozenset]] = []  # (key, nodes, morphed)
        self._frozen: dict[int, tuple[tuple, frozenset, object]] = {}  # target -> GL proxy
        self._gl = lambda: AdaptiveProxy(terrain.drawer, terrain.extent, self.stride)
        self.twin = AdaptiveProxy.twin
        self.forced: tuple[tuple, frozenset] | None = None  # a replay's recorded selection
        self.last: tuple[tuple, frozenset] = ((), frozenset())  # the last frozen selection
        self.triangles: list[int] = []  # per keyframe frozen

    @staticmethod
    def _key(eye: np.ndarray, view_proj: np.ndarray | None) -> bytes:
        vp = b"" if view_proj is None else np.asarray(view_proj, np.float64).tobytes()
        return np.asarray(eye, np.float64).tobytes() + vp

    def select(self, eye: np.ndarray, view_proj: np.ndarray | None) -> tuple[tuple, frozenset]:
        """The proxy's nodes and the ones that morph, for a keyframe at ``eye (3,)`` seen
        through ``view_proj (4, 4)`` (None: not culled); made once per eye and view."""
        key = self._key(eye, view_proj)
        for k, nodes, morphed in self._made:
            if k == key:
                return nodes, morphed
        if self.forced is not None:
            nodes, morphed = self.forced
        else:
            t = self.terrain
            planes = _ALL
            if view_proj is not None:
                planes = frustum_planes(np.diag([1 / WIDEN, 1 / WIDEN, 1.0, 1.0]) @ view_proj)
            found, _ = t.tree.select(np.asarray(eye, np.float64), planes, self.r,
                                     t.slots.__contains__)
            nodes = tuple(found)
            morphed = frozenset(n for n in nodes
                                if n.k < t.tree.top and n.parent() in t.slots)
        self._made = [*self._made[-(_CACHED - 1):], (key, nodes, morphed)]
        self._pin()
        return nodes, morphed

    def _pin(self) -> None:
        pins = set()
        groups = [(n, m) for _, n, m in self._made] + [v[:2] for v in self._frozen.values()]
        if self.forced is not None:
            groups.append(self.forced)
        for nodes, morphed in groups:
            pins.update(nodes)
            pins.update(n.parent() for n in morphed)
        self.terrain.pinned = pins

    def nodes(self, eye: np.ndarray, view_proj: np.ndarray | None) -> ProxyNodes:
        """The proxy of :meth:`select` as arrays (:class:`ProxyNodes`), heights morphed at
        ``eye`` as the vertex shader morphs them: the metric's source."""
        nodes, morphed = self.select(eye, view_proj)
        return frozen_nodes(self.terrain, nodes, morphed, eye, self.stride, self.r)

    def force(self, selection: tuple[tuple, frozenset] | None) -> None:
        """Freeze ``selection`` (a recorded :attr:`last`) for the next keyframes, its tiles
        made resident now (an untimed replay); None: select again."""
        self.forced, self._made = selection, []
        self._pin()
        if selection is not None:
            nodes, morphed = selection
            self.terrain.make_resident(list(nodes) + [n.parent() for n in morphed])

    def for_keyframe(self, slot, viewpoint, projection):
        """The GL proxy frozen for the keyframe rendered into ``slot`` (a render target)
        from ``viewpoint`` through ``projection``: the selection made for that eye and view
        (made now if the metric did not ask for it)."""
        eye = np.asarray(viewpoint.o, np.float64)
        nodes, morphed = self.select(eye, projection.matrix() @ viewpoint.view_matrix())
        old = self._frozen.get(id(slot))
        gl = old[2] if old is not None else self._gl()
        instances, _ = self.terrain.instances(list(nodes), morphed, self.r)
        boxes = [self.terrain.tree.bounds(n) for n in nodes]
        gl.set(instances, eye, (np.array([b[0] for b in boxes]).reshape(-1, 3),
                                np.array([b[1] for b in boxes]).reshape(-1, 3)))
        self._frozen[id(slot)] = (nodes, morphed, gl)
        self._made = []  # this keyframe's selection is kept by _frozen now
        self._pin()
        self.last = (nodes, morphed)
        self.triangles.append(len(nodes) * 2 * (self.terrain.tree.g // self.stride) ** 2)
        return gl

    def draw(self, program, view_proj: np.ndarray) -> int:
        """Draw the proxy last frozen (the proxy geometry interface)."""
        if not self._frozen:
            return 0
        return list(self._frozen.values())[-1][2].draw(program, view_proj)

    def release(self) -> None:
        for _, _, gl in self._frozen.values():
            gl.release()
        self._frozen.clear()
        self.terrain.pinned = set()
