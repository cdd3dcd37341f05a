"""The LOD-sprite angular error metric (Chen, Swan & Kaufman 1999, §3.2, Eq. 1-2) on a
view-dependent proxy: the adaptive mesh frozen at each keyframe's viewpoint (their §5,
"view-dependent LODs under the sprite"), instead of one uniform coarse level.

The quantities are the paper's, with the proxy in place of the coarse level:

* ``C``  are full-resolution (level-0) samples: ``k x k`` per frozen proxy node, at the
  centres of ``k x k`` of its mesh cells, evenly spread (at most ``MAX_SAMPLES`` in all;
  on a proxy vertex ``C' = C`` up to the morph, as on a coarse vertex in the paper);
* ``C'`` is where the ray from the keyframe eye ``v1`` through ``C`` meets the proxy
  surface, the point the sprite texture maps ``C``'s colour onto;
* ``θ``  is the angle at the current eye ``v2`` between ``C`` and ``C'``; a keyframe is due
  when ``sqrt(mean θ²) / β >= ε`` (Eq. 2, ``β`` the angle of one pixel).

**The approximation.**  The proxy surface is evaluated as the GPU draws it: each node's
vertex heights geomorphed towards its parent by the distance from the keyframe eye (the
morph frozen with the selection), linear over the mesh's triangles (squares split along
their north-west/south-east diagonal).  The ray is solved for ``t`` in
``P(t) = v1 + t (C - v1)``, ``f(t) = P_z(t) - z(P_xy(t)) = 0``, from ``t = 1`` (at ``C``):
one vertical fixed-point step, then secant steps (``ITERATIONS`` in all), vectorised over
all samples.  It finds the intersection nearest to ``C`` along the ray that the iteration
reaches, as :mod:`lodsprite.sprite.metric` keeps the hit nearest to ``C``; on a piecewise
linear surface the secant step is exact once two iterates lie on one triangle.  A sample
converges when ``|f| <= TOLERANCE * |C - v1|`` (a vertical residual of 1e-4 of the ray's
length: an angle of at most about 1e-4 rad at ``v1``, 0.07 px of a 512-pixel 45° image).
On a flat proxy through ``C``, ``f(1) = 0`` and ``C' = C`` exactly.

**Misses** are samples that did not converge, whose ray left the proxy's footprint or
went behind ``v1``: the sprite maps their colour nowhere certain.  Their ``C'`` is ``C``
itself and their θ is raised to the largest θ of the samples that hit
(:func:`~lodsprite.sprite.metric.miss_floor`), as the uniform metric counts misses; when
every sample in view missed, or none is in view, the error is ``inf`` (a keyframe is due).

``C'`` is computed once per keyframe (:meth:`ProxyMetric.reproject`); per frame only the
angles (:meth:`ProxyMetric.error_px`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from lodsprite.sprite.metric import ErrorMetric, angles_at_eye, in_view, miss_floor
from lodsprite.sprite.raycast import Reprojection

MAX_SAMPLES = 8192   # sample points C per keyframe, at most
SAMPLES_PER_NODE = 4  # k: a k x k subgrid per proxy node (fewer when nodes are many)
ITERATIONS = 10
TOLERANCE = 1e-4     # of the ray's length |C - v1|: the vertical residual of a hit


@dataclass(frozen=True)
class ProxyNodes:
    """A frozen proxy as arrays (``N`` nodes, grid ``G``).

    ``origin (N, 2)``: world x, y (metres) of each node's vertex (0, 0); ``spacing (N, 2)``:
    metres a mesh vertex east and south; ``last (N, 2) float``: where the last vertex row,
    column stands, in vertex steps (fractional where the node's edge cell is narrower:
    vertices past it are clamped onto it); ``heights (N, G+1, G+1) float64``: the vertex
    heights as drawn (morphed at the keyframe eye); ``windows (N, 4) int``: each node's
    level-0 sample window ``r0, r1, c0, c1`` (``r1``, ``c1`` inclusive)."""

    origin: np.ndarray
    spacing: np.ndarray
    last: np.ndarray
    heights: np.ndarray
    windows: np.ndarray

    def __len__(self) -> int:
        return len(self.origin)


class ProxySurface:
    """The height function of a :class:`ProxyNodes` proxy: which node holds a point (a
    raster of the finest node's size) and its triangulated, morphed height there."""

    def __init__(self, nodes: ProxyNodes) -> None:
        self.nodes = nodes
        sx, sy = nodes.spacing[:, 0], nodes.spacing[:, 1]
        g = nodes.heights.shape[1] - 1
        self.cell = np.array([g * sx.min(), g * sy.min()])
        self.x0, self.y0 = nodes.origin[:, 0].min(), nodes.origin[:, 1].max()
        c0 = np.round((nodes.origin[:, 0] - self.x0) / self.cell[0]).astype(int)
        r0 = np.round((self.y0 - nodes.origin[:, 1]) / self.cell[1]).astype(int)
        c1 = c0 + np.maximum(1, np.ceil(nodes.last[:, 1] * sx / self.cell[0] - 1e-9)).astype(int)
        r1 = r0 + np.maximum(1, np.ceil(nodes.last[:, 0] * sy / self.cell[1] - 1e-9)).astype(int)
        self.raster = np.full((r1.max(), c1.max()), -1, np.intp)
        for i in range(len(nodes)):
            self.raster[r0[i]:r1[i], c0[i]:c1[i]] = i

    def node_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """``(K,) intp`` index of the node holding each point, -1 off the proxy."""
        fc = (x - self.x0) / self.cell[0]
        fr = (self.y0 - y) / self.cell[1]
        rows, cols = self.raster.shape
        eps = 1e-9
        ok = (fr >= -eps) & (fr <= rows + eps) & (fc >= -eps) & (fc <= cols + eps)
        r = np.clip(np.floor(fr[ok]), 0, rows - 1).astype(np.intp)  # edges belong in
        c = np.clip(np.floor(fc[ok]), 0, cols - 1).astype(np.intp)
        out = np.full(x.shape, -1, np.intp)
        out[ok] = self.raster[r, c]
        return out

    def height(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """The proxy's height ``(K,) float64`` metres at ``(x, y)``; NaN off the proxy."""
        nd = self.nodes
        x = np.asarray(x, np.float64)
        y = np.asarray(y, np.float64)
        i = self.node_at(x, y)
        inside = i >= 0
        j = np.where(inside, i, 0)
        ext = nd.last[j]
        u = (nd.origin[j, 1] - y) / nd.spacing[j, 1]
        v = (x - nd.origin[j, 0]) / nd.spacing[j, 0]
        eps = 1e-6  # a partly filled raster cell (an edge node narrower than a cell)
        inside &= (u >= -eps) & (u <= ext[:, 0] + eps) & (v >= -eps) & (v <= ext[:, 1] + eps)
        u, v = np.clip(u, 0, ext[:, 0]), np.clip(v, 0, ext[:, 1])
        top = np.maximum(np.ceil(ext - 1e-9) - 1, 0)  # the last cell's first vertex
        r = np.clip(np.floor(u), 0, top[:, 0]).astype(np.intp)
        c = np.clip(np.floor(v), 0, top[:, 1]).astype(np.intp)
        r1, c1 = r + 1, c + 1
        fu = (u - r) / np.maximum(np.minimum(r1, ext[:, 0]) - r, 1e-9)
        fv = (v - c) / np.maximum(np.minimum(c1, ext[:, 1]) - c, 1e-9)
        h = nd.heights
        nw, se = h[j, r, c], h[j, r1, c1]
        sw, ne = h[j, r1, c], h[j, r, c1]
        lower = fu >= fv  # the (nw, sw, se) triangle, else (nw, se, ne)
        z = np.where(lower, nw + fu * (sw - nw) + fv * (se - sw),
                     nw + fv * (ne - nw) + fu * (se - ne))
        return np.where(inside, z, np.nan)


def reproject_onto(surface: ProxySurface, key_eye: np.ndarray,
                   points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(C' (K, 3) float64 metres, missed (K,) bool)``: where the rays from ``key_eye
    (3,)`` through ``points (K, 3)`` meet ``surface`` (module docstring); a missed
    sample's ``C'`` is the sample itself."""
    e = np.asarray(key_eye, np.float64)
    c = np.asarray(points, np.float64)
    d = c - e

    def f(t: np.ndarray) -> np.ndarray:
        p = e + t[:, None] * d
        return p[:, 2] - surface.height(p[:, 0], p[:, 1])

    tol = TOLERANCE * np.linalg.norm(d, axis=1)
    t0 = np.ones(len(c))
    f0 = f(t0)
    dz = np.where(np.abs(d[:, 2]) > 1e-9, d[:, 2], 1e-9)
    t1 = np.where(np.abs(f0) <= tol, t0, t0 - f0 / dz)
    f1 = f(t1)
    for _ in range(ITERATIONS - 1):
        done = ~(np.abs(f1) > tol)  # converged, or NaN (left the proxy): stop there
        df = f1 - f0
        step = np.where(np.abs(df) > 1e-12, f1 * (t1 - t0) / np.where(df == 0, 1, df), 0.0)
        t2 = np.where(done, t1, t1 - step)
        t0, f0 = t1, f1
        t1 = t2
        f1 = np.where(done, f1, f(t1))
    hit = (np.abs(f1) <= tol) & (t1 > 0)
    c_prime = np.where(hit[:, None], e + t1[:, None] * d, c)
    return c_prime, ~hit


def node_samples(hf, windows: np.ndarray, steps: np.ndarray, per_node: int = SAMPLES_PER_NODE,
                 limit: int = MAX_SAMPLES) -> np.ndarray:
    """Sample points ``C (K, 3) float64`` metres: level-0 samples of ``hf`` (``hf.points(
    rows, cols)``) in each window ``(N, 4)`` (``r0, r1, c0, c1`` inclusive), at the centres
    of ``k x k`` of its proxy mesh cells, evenly spread (``steps (N,)``: level-0 samples
    between the node's mesh vertices; ``k = per_node`` or fewer so that ``K <= limit``).
    Cell centres, as the paper's square centres: a sample on a proxy vertex would measure
    nothing but the morph."""
    w = np.asarray(windows, np.int64)
    st = np.maximum(np.asarray(steps, np.int64), 1)[:, None]
    k = max(1, min(per_node, int(math.isqrt(max(1, limit // max(1, len(w)))))))
    f = (np.arange(k) + 0.5) / k

    def axis(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        cells = np.maximum(-(-(b - a)[:, None] // st), 1)
        j = np.floor(f[None] * cells).astype(np.int64)
        return a[:, None] + np.minimum(j * st + st // 2, (b - a)[:, None])

    rr, cc = axis(w[:, 0], w[:, 1]), axis(w[:, 2], w[:, 3])
    rows = np.repeat(rr, k, axis=1).ravel()
    cols = np.tile(cc, (1, k)).ravel()
    return np.asarray(hf.points(rows, cols), np.float64)


class ProxyReprojection(Reprojection):
    """A keyframe's ``C' (K, 3)`` on its proxy, with the keyframe eye, the misses and the
    sample points ``points (K, 3)`` (``C``) they belong to."""

    points: np.ndarray | None
    points_h: np.ndarray | None  # (K, 4): the points with w = 1, for the per-frame test

    def __array_finalize__(self, obj) -> None:
        super().__array_finalize__(obj)
        pts = getattr(obj, "points", None)
        same = pts is not None and len(pts) == len(self)
        self.points = pts if same else None
        self.points_h = getattr(obj, "points_h", None) if same else None


#: The proxy frozen for a keyframe: ``(key_eye (3,), key_view_proj (4, 4) | None) ->
#: ProxyNodes`` (the same selection the keyframe's spriteframes then draw).
ProxySource = Callable[[np.ndarray, "np.ndarray | None"], ProxyNodes]


class ProxyMetric:
    """The interface :class:`~lodsprite.sprite.policy.KeyframePolicy` uses
    (:meth:`reproject`, :meth:`error_px`, :meth:`covers`) over a view-dependent proxy.

    ``source`` freezes the proxy for a keyframe (its selection is made there, and the GL
    side draws that same selection); ``hf`` gives level-0 samples; ``coarse`` is a uniform
    level's :class:`~lodsprite.sprite.metric.ErrorMetric`, whose square centres
    :meth:`covers` tests (a look-ahead keyframe's proxy is not selected yet)."""

    def __init__(self, source: ProxySource, hf, coarse: ErrorMetric,
                 per_node: int = SAMPLES_PER_NODE, limit: int = MAX_SAMPLES) -> None:
        self.source, self.hf, self.coarse = source, hf, coarse
        self.per_node, self.limit = int(per_node), int(limit)

    def reproject(self, key_eye: np.ndarray, key_view_proj: np.ndarray | None = None,
                  key_size=None) -> ProxyReprojection:
        """Freeze the keyframe's proxy and return ``C'`` of its samples (once a keyframe)."""
        eye = np.asarray(key_eye, np.float64)
        nodes = self.source(eye, key_view_proj)
        steps = np.rint(nodes.spacing[:, 0] / self.hf.dx).astype(np.int64)
        points = node_samples(self.hf, nodes.windows, steps, self.per_node, self.limit)
        c_prime, missed = reproject_onto(ProxySurface(nodes), eye, points)
        out = ProxyReprojection(c_prime, eye, missed)
        out.points, out.points_h = points, np.c_[points, np.ones(len(points))]
        return out

    def error_px(self, c_prime: ProxyReprojection, eye: np.ndarray, view_proj: np.ndarray,
                 pixel_angle_rad: float) -> float:
        """``sqrt(mean θ²) / β`` pixels over the samples in the current view (misses as
        :func:`~lodsprite.sprite.metric.miss_floor` counts them); ``inf`` when none is in
        view or all missed."""
        pts = c_prime.points
        vis = in_view(c_prime.points_h, view_proj)
        missed = c_prime.missed[vis]
        if not vis.any() or missed.all():
            return math.inf
        th = angles_at_eye(np.asarray(eye, np.float64), pts[vis], np.asarray(c_prime)[vis])
        th = miss_floor(th, missed)
        return float(np.sqrt(np.mean(th * th)) / pixel_angle_rad)

    def covers(self, viewpoint, projection, key_viewpoint, key_projection) -> bool:
        return self.coarse.covers(viewpoint, projection, key_viewpoint, key_projection)
