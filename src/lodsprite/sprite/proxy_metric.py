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

**The approximation.**  The proxy surface is evaluated as the GPU draws it, and the ray
marched onto it and bisected (:mod:`lodsprite.sprite.proxy_surface`); a root between two
steps of one sign (the ray grazing a ridge thinner than a step) is not seen.

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

import numpy as np

from lodsprite.camera import boxes_in_frustum, frustum_planes
from lodsprite.sprite.metric import ErrorMetric, angles_at_eye, in_view, miss_floor
from lodsprite.sprite.proxy_surface import (
    ProxyNodes,
    ProxySurface,
    reproject_onto,
    surface_normals,
)
from lodsprite.sprite.raycast import Reprojection
from lodsprite.sprite.resampling import resampling_px

MAX_SAMPLES = 8192   # sample points C per keyframe, at most
SAMPLES_PER_NODE = 4  # k: a k x k subgrid per proxy node (fewer when nodes are many)


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
