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
``P(t) = v1 + t (C - v1)``, ``f(t) = P_z(t) - z(P_xy(t)) = 0``, vectorised over all samples:
from ``t = 1`` (at ``C``) it marches ``MARCH`` steps of half a proxy cell (along the ground)
towards the eye, then ``MARCH`` even steps on to the eye, and as many away (to twice C's
distance); it keeps the sign change nearest to ``C`` (towards the eye on a tie), as
:mod:`lodsprite.sprite.metric` keeps the hit nearest to ``C``, and bisects it
``BISECTIONS`` times: ``t`` to ``2^-16`` of a step, far below a pixel.  A root between two
steps of one sign (the ray grazing a ridge thinner than a step) is not seen.  (Secant
steps from ``t = 1`` missed 12 % of the samples of a 4k² flyover keyframe at
``proxy_sse`` 8, 7 % after 100 steps, on the proxy's rough piecewise surface; this march
misses 0.8 % there, mostly rays that leave the proxy.)  On a flat proxy through ``C``,
``f(1) = 0`` and ``C' = C``.

**Misses** are samples whose ray meets the proxy nowhere within the march (it leaves the
proxy's footprint first, or stays above or below it): the sprite maps their colour
nowhere certain.  Their ``C'`` is ``C`` itself and their θ is raised to the largest θ
of the samples that hit (:func:`~lodsprite.sprite.metric.miss_floor`), as the uniform
metric counts misses; when every sample in view missed, or none is in view, the error
is ``inf`` (a keyframe is due).

``C'`` is computed once per keyframe (:meth:`ProxyMetric.reproject`); per frame only the
angles (:meth:`ProxyMetric.error_px`).  ``C`` is the surface the keyframe shows when
``points`` is given: ``sprite-adaptive`` gives the adaptive renderer's selection at
``--key-sse`` (:class:`~lodsprite.techniques.drawn_surface.DrawnSurface`), whose tiles are
resident, so no keyframe reads storage (through level 0, a 16k² flyover keyframe read
2560 chunks, 9 s, for 2080 samples spread over the widened frustum).  Without it ``C`` is
``hf.points(rows, cols)``: level 0's samples.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from lodsprite.camera import boxes_in_frustum, frustum_planes
from lodsprite.sprite.metric import ErrorMetric, angles_at_eye, in_view, miss_floor
from lodsprite.sprite.raycast import Reprojection
from lodsprite.sprite.resampling import resampling_px

MAX_SAMPLES = 8192   # sample points C per keyframe, at most
SAMPLES_PER_NODE = 4  # k: a k x k subgrid per proxy node (fewer when nodes are many)
MARCH = 32           # steps of half a proxy cell each way along the ray from C, then as
                     # many even ones on to the eye (t = 0) and to FAR_T
FAR_T = 2.0          # the march away from the eye ends at twice C's distance
MAX_DT = 0.05        # of the ray's length: the longest step (rays seen from straight above)
BISECTIONS = 16      # halvings of the bracket: t to 2^-16 of a step (1 mm a 60 m step)
MARCH_BLOCK = 8      # march steps evaluated at once


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
    raster of the finest node's size) and its triangulated, morphed height there.

    ``side``: the nodes' vertex grid ``G`` when ``nodes.heights`` holds none (a locator
    only: :meth:`cells` works, :meth:`height` needs the heights)."""

    def __init__(self, nodes: ProxyNodes, side: int | None = None) -> None:
        self.nodes = nodes
        sx, sy = nodes.spacing[:, 0], nodes.spacing[:, 1]
        g = nodes.heights.shape[1] - 1 if side is None else int(side)
        self.cell = np.array([g * sx.min(), g * sy.min()])
        self.x0, self.y0 = nodes.origin[:, 0].min(), nodes.origin[:, 1].max()
        c0 = np.round((nodes.origin[:, 0] - self.x0) / self.cell[0]).astype(int)
        r0 = np.round((self.y0 - nodes.origin[:, 1]) / self.cell[1]).astype(int)
        c1 = c0 + np.maximum(1, np.ceil(nodes.last[:, 1] * sx / self.cell[0] - 1e-9)).astype(int)
        r1 = r0 + np.maximum(1, np.ceil(nodes.last[:, 0] * sy / self.cell[1] - 1e-9)).astype(int)
        top = np.maximum(np.ceil(nodes.last - 1e-9) - 1, 0)
        self._params = np.c_[nodes.origin, nodes.spacing, nodes.last, top]
        self._flat = np.ascontiguousarray(nodes.heights, np.float64).ravel()
        self._flat_side = nodes.heights.shape[1]
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

    def cells(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, ...]:
        """Where points ``(x, y) (K,)`` fall: ``(node (K,) intp, row (K,), column (K,)
        intp of the cell's first vertex, fu, fv (K,) float64 within the cell, inside (K,)
        bool)``; a point off the proxy has ``inside`` False (its other values are node 0's,
        meaningless)."""
        x = np.asarray(x, np.float64)
        y = np.asarray(y, np.float64)
        i = self.node_at(x, y)
        inside = i >= 0
        j = np.where(inside, i, 0)
        q = self._params[j]  # origin x, y; spacing x, y; last row, column
        ext_r, ext_c = q[:, 4], q[:, 5]
        u = (q[:, 1] - y) / q[:, 3]
        v = (x - q[:, 0]) / q[:, 2]
        eps = 1e-6  # a partly filled raster cell (an edge node narrower than a cell)
        inside &= (u >= -eps) & (u <= ext_r + eps) & (v >= -eps) & (v <= ext_c + eps)
        u, v = np.clip(u, 0, ext_r), np.clip(v, 0, ext_c)
        r = np.minimum(np.floor(u), q[:, 6])  # q[:, 6:8]: the last cell's first vertex
        c = np.minimum(np.floor(v), q[:, 7])
        fu = (u - r) / np.maximum(np.minimum(r + 1, ext_r) - r, 1e-9)
        fv = (v - c) / np.maximum(np.minimum(c + 1, ext_c) - c, 1e-9)
        return j, r.astype(np.intp), c.astype(np.intp), fu, fv, inside

    def height(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """The proxy's height ``(K,) float64`` metres at ``(x, y)``; NaN off the proxy."""
        j, r, c, fu, fv, inside = self.cells(x, y)
        side = self._flat_side
        base = j * side * side + r * side + c
        h = self._flat
        z = triangle_height(h[base], h[base + 1], h[base + side], h[base + side + 1], fu, fv)
        return np.where(inside, z, np.nan)


def triangle_height(nw: np.ndarray, ne: np.ndarray, sw: np.ndarray, se: np.ndarray,
                    fu: np.ndarray, fv: np.ndarray) -> np.ndarray:
    """The height in a square cell at ``(fu, fv)`` (row, column fractions) from its corner
    heights, linear over its two triangles as the GPU draws them (split along the
    north-west/south-east diagonal: ``(nw, sw, se)`` where ``fu >= fv``, else
    ``(nw, se, ne)``)."""
    return np.where(fu >= fv, nw + fu * (sw - nw) + fv * (se - sw),
                    nw + fv * (ne - nw) + fu * (se - ne))


def _march(dt: np.ndarray, side: float, end: float) -> np.ndarray:
    """``t (K, 2 MARCH)`` of the march from ``t = 1`` on one side: ``MARCH`` steps of
    ``dt (K,)``, then ``MARCH`` even ones on to ``end``."""
    fine = 1.0 + side * dt[:, None] * np.arange(1, MARCH + 1)[None]
    last = fine[:, -1:]
    ts = np.concatenate([fine, last + (np.arange(1, MARCH + 1) / MARCH)[None] * (end - last)],
                        axis=1)
    return np.maximum(ts, 1e-3) if side < 0 else np.minimum(ts, FAR_T)


def reproject_onto(surface: ProxySurface, key_eye: np.ndarray, points: np.ndarray,
                   steps_m: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(C' (K, 3) float64 metres, missed (K,) bool)``: where the rays from ``key_eye
    (3,)`` through ``points (K, 3)`` meet ``surface`` nearest to the points (module
    docstring); a missed sample's ``C'`` is the sample itself.  ``steps_m (K,)``: the
    marching step along the ground, metres (default: the proxy's finest vertex spacing)."""
    e = np.asarray(key_eye, np.float64)
    c = np.asarray(points, np.float64)
    d = c - e
    k = len(c)

    def f(t: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        dd = d if rows is None else d[rows]  # t (K,), or (len(rows), m) for those rays
        p = e + t[..., None] * (dd if t.ndim == 1 else dd[:, None])
        z = surface.height(p[..., 0].ravel(), p[..., 1].ravel()).reshape(t.shape)
        return p[..., 2] - z

    if steps_m is None:
        steps_m = np.full(k, surface.nodes.spacing.min())
    ground = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)
    dt = np.minimum(0.5 * np.asarray(steps_m, np.float64) / ground, MAX_DT)
    f0 = f(np.ones(k))
    n = 2 * MARCH
    best_j = np.full(k, n + 1)  # steps from C to the nearest bracket so far
    lo, hi = np.ones(k), np.ones(k)
    for side, end in ((-1.0, 1e-3), (1.0, FAR_T)):  # towards the eye, then away
        ts = _march(dt, side, end)
        prev_t, prev_f = np.ones(k), f0.copy()
        open_ = ~np.isnan(f0)  # still marching on this side
        for b0 in range(0, n, MARCH_BLOCK):  # in blocks: most rays bracket in the first
            rows = np.flatnonzero(open_ & (b0 + 1 < best_j))
            if rows.size == 0:
                break
            fs = f(ts[rows, b0:b0 + MARCH_BLOCK], rows)
            nan = np.isnan(fs)
            change = (np.sign(fs) != np.sign(prev_f[rows])[:, None]) & ~nan
            change &= np.cumsum(nan, axis=1) == 0  # none past a point off the proxy
            has = change.any(axis=1)
            first = change.argmax(axis=1)
            steps = b0 + first + 1
            ok = has & (steps < best_j[rows])
            r_ok = rows[ok]
            before = np.where(first[ok] > 0,
                              ts[r_ok, b0 + np.maximum(first[ok] - 1, 0)], prev_t[r_ok])
            lo[r_ok], hi[r_ok] = before, ts[r_ok, b0 + first[ok]]
            best_j[r_ok] = steps[ok]
            stop = has | nan.any(axis=1)
            open_[rows[stop]] = False
            prev_t[rows], prev_f[rows] = ts[rows, b0 + fs.shape[1] - 1], fs[:, -1]
    found = (best_j <= n) | (f0 == 0)
    flo = f(lo)
    for _ in range(BISECTIONS):  # the root stays between lo and hi (f is continuous)
        mid = 0.5 * (lo + hi)
        fm = f(mid)
        left = np.sign(fm) == np.sign(flo)
        lo, flo = np.where(left, mid, lo), np.where(left, fm, flo)
        hi = np.where(left, hi, mid)
    t = np.where(f0 == 0, 1.0, 0.5 * (lo + hi))
    hit = found & ~np.isnan(f0)
    c_prime = np.where(hit[:, None], e + t[:, None] * d, c)
    return c_prime, ~hit


def surface_normals(surface: ProxySurface, points: np.ndarray) -> np.ndarray:
    """Unit normals ``(K, 3)`` of the proxy ``surface`` at ``points (K, 3)`` metres, by
    central differences of a quarter of the local vertex spacing (``(0, 0, 1)`` off the
    proxy): the plane whose homography the resampling term measures
    (:mod:`lodsprite.sprite.resampling`)."""
    x, y = points[:, 0], points[:, 1]
    j, *_, inside = surface.cells(x, y)
    d = 0.25 * surface.nodes.spacing[j]
    z = surface.height(x, y)

    def slope(dx: np.ndarray, dy: np.ndarray, step: np.ndarray) -> np.ndarray:
        """Central difference; one-sided where a side is off the proxy (an edge)."""
        up, down = surface.height(x + dx, y + dy), surface.height(x - dx, y - dy)
        out = (up - down) / (2 * step)
        out = np.where(np.isnan(up), (z - down) / step, out)
        out = np.where(np.isnan(down), (up - z) / step, out)
        return np.nan_to_num(out)

    zero = np.zeros(len(x))
    n = np.c_[-slope(d[:, 0], zero, d[:, 0]), -slope(zero, d[:, 1], d[:, 1]), np.ones(len(x))]
    n[~inside] = (0.0, 0.0, 1.0)
    return n / np.linalg.norm(n, axis=1, keepdims=True)


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


#: The keyframe's own ``C``: ``(key_eye (3,), key_view_proj (4, 4) | None) -> points``,
#: ``points(rows, cols) -> (K, 3) float64`` metres at level-0 sample indices (e.g. the
#: surface the keyframe shows, :class:`~lodsprite.techniques.drawn_surface.DrawnSurface`).
PointSource = Callable[[np.ndarray, "np.ndarray | None"], Callable]


class _Points:
    """``points(rows, cols)`` as the ``hf.points`` :func:`node_samples` calls."""

    def __init__(self, points: Callable) -> None:
        self.points = points


class ProxyReprojection(Reprojection):
    """A keyframe's ``C' (K, 3)`` on its proxy, with the keyframe eye, the misses and the
    sample points ``points (K, 3)`` (``C``) they belong to, and ``points_h (K, 4)`` with
    w = 1 for the per-frame test
    (:meth:`~lodsprite.sprite.raycast.Reprojection.set_points` keeps them)."""


#: The proxy frozen for a keyframe: ``(key_eye (3,), key_view_proj (4, 4) | None) ->
#: ProxyNodes`` (the same selection the keyframe's spriteframes then draw).
ProxySource = Callable[[np.ndarray, "np.ndarray | None"], ProxyNodes]


def nodes_in_view(nodes: ProxyNodes, view_proj: np.ndarray) -> np.ndarray:
    """``(N,) bool``: the nodes whose bounding boxes (their vertices' extent, heights as
    drawn) meet the frustum of ``view_proj (4, 4)`` (conservative)."""
    x0, y1 = nodes.origin[:, 0], nodes.origin[:, 1]
    x1 = x0 + nodes.last[:, 1] * nodes.spacing[:, 0]
    y0 = y1 - nodes.last[:, 0] * nodes.spacing[:, 1]
    h = nodes.heights.reshape(len(nodes), -1)
    mins = np.c_[x0, y0, h.min(axis=1)]
    maxs = np.c_[x1, y1, h.max(axis=1)]
    return boxes_in_frustum(frustum_planes(view_proj), mins, maxs)


class ProxyMetric:
    """The interface :class:`~lodsprite.sprite.policy.KeyframePolicy` uses
    (:meth:`reproject`, :meth:`error_px`, :meth:`covers`) over a view-dependent proxy.

    ``source`` freezes the proxy for a keyframe (its selection is made there, and the GL
    side draws that same selection); ``hf`` gives level-0 samples; ``coarse`` is a uniform
    level's :class:`~lodsprite.sprite.metric.ErrorMetric`, whose square centres
    :meth:`covers` tests (a look-ahead keyframe's proxy is not selected yet).  ``points``
    (:data:`PointSource`): ``C`` from the surface the keyframe shows instead of ``hf``
    (what ``sprite-adaptive`` gives: nothing is read from storage)."""

    def __init__(self, source: ProxySource, hf, coarse: ErrorMetric,
                 per_node: int = SAMPLES_PER_NODE, limit: int = MAX_SAMPLES,
                 points: PointSource | None = None) -> None:
        self.source, self.hf, self.coarse = source, hf, coarse
        self.per_node, self.limit = int(per_node), int(limit)
        self.points = points

    def reproject(self, key_eye: np.ndarray, key_view_proj: np.ndarray | None = None,
                  key_size=None, within: np.ndarray | None = None) -> ProxyReprojection:
        """Freeze the keyframe's proxy and return ``C'`` of its samples (once a keyframe).
        ``within (4, 4)``: a view whose frustum the samples' nodes must meet (a tile
        update's tiles, :func:`~lodsprite.sprite.tiled.sub_view_proj`): ``C'`` of those
        alone, the proxy still frozen for the whole key view."""
        eye = np.asarray(key_eye, np.float64)
        nodes = self.source(eye, key_view_proj)
        keep = np.ones(len(nodes), bool) if within is None else nodes_in_view(nodes, within)
        if not keep.any():  # no proxy node in the view: nothing measurable
            out = ProxyReprojection(np.zeros((0, 3)), eye, np.zeros(0, bool))
            out.set_points(np.zeros((0, 3)))
            return out
        steps = np.rint(nodes.spacing[keep, 0] / self.hf.dx).astype(np.int64)
        view = key_view_proj if within is None else within
        hf = self.hf if self.points is None else _Points(self.points(eye, view))
        points = node_samples(hf, nodes.windows[keep], steps, self.per_node, self.limit)
        cell_m = np.repeat(nodes.spacing[keep].min(axis=1),
                           len(points) // max(1, int(keep.sum())))
        surface = ProxySurface(nodes)
        c_prime, missed = reproject_onto(surface, eye, points, cell_m)
        out = ProxyReprojection(c_prime, eye, missed, key_view_proj, key_size)
        out.set_points(points)
        if self.resampling:
            out.normals = surface_normals(surface, c_prime)
        return out

    @property
    def resampling(self) -> bool:
        """Whether the error adds the keyframe image's resampling term (the uniform
        metric's setting, ``metric="resample"``)."""
        return bool(getattr(self.coarse, "resampling", False))

    def error_px(self, c_prime: ProxyReprojection, eye: np.ndarray, view_proj: np.ndarray,
                 pixel_angle_rad: float, size: tuple[int, int] | None = None) -> float:
        """``sqrt(mean θ²) / β`` pixels over the samples in the current view (misses as
        :func:`~lodsprite.sprite.metric.miss_floor` counts them); ``inf`` when none is in
        view or all missed.  With :attr:`resampling`, each hit's θ² gains ``(β e_res)²``
        (``size = (w, h)``: the current image's pixels), the normal at ``C'`` the proxy's."""
        pts = c_prime.points
        vis = in_view(c_prime.points_h, view_proj)
        missed = c_prime.missed[vis]
        if not vis.any() or missed.all():
            return math.inf
        cp = np.asarray(c_prime)[vis]
        th = angles_at_eye(np.asarray(eye, np.float64), pts[vis], cp)
        if self.resampling:
            th = self._with_resampling(th, missed, cp, c_prime, view_proj, pixel_angle_rad,
                                       size, np.flatnonzero(vis))
        th = miss_floor(th, missed)
        return float(np.sqrt(np.mean(th * th)) / pixel_angle_rad)

    def _with_resampling(self, th: np.ndarray, missed: np.ndarray, cp: np.ndarray,
                         c_prime: ProxyReprojection, view_proj: np.ndarray, beta: float,
                         size: tuple[int, int] | None, idx: np.ndarray) -> np.ndarray:
        """``sqrt(θ² + (β e_res)²)`` for the hits among the samples ``idx`` of ``c_prime``
        (``cp``: their ``C'``), the normals the proxy's there (made at :meth:`reproject`);
        misses keep θ."""
        normals = getattr(c_prime, "normals", None)
        if size is None or c_prime.key_view_proj is None or c_prime.key_size is None \
                or normals is None:
            raise ValueError("the resampling metric needs the current image size and a "
                             "keyframe's key_view_proj, key_size and proxy normals")
        hit = ~missed
        e = np.zeros(len(th))
        e[hit] = resampling_px(cp[hit], normals[idx][hit], c_prime.key_view_proj,
                               c_prime.key_size, view_proj, size)
        return np.sqrt(th * th + (beta * e) ** 2)

    def in_view_mask(self, viewpoint, projection):
        """The uniform level's square centres in view (the keyframe cache's test of which
        cached keyframe's view holds the current one, as :meth:`covers` tests)."""
        return self.coarse.in_view_mask(viewpoint, projection)

    def covers(self, viewpoint, projection, key_viewpoint, key_projection) -> bool:
        return self.coarse.covers(viewpoint, projection, key_viewpoint, key_projection)
