"""The LOD-sprite error estimate on the keyframe's own depth: Eq. 1-2 of Chen, Swan &
Kaufman (1999, §3.2) with the depth mesh (:mod:`lodsprite.gl.depth_mesh`) as the proxy,
in closed form, plus the keyframe image's resampling (their §5) and the view's uncovered
area.

**Eq. 1.**  The proxy is a vertex every ``stride`` keyframe texels, unprojected from the
keyframe's z-buffer, two triangles a cell.  ``C`` are keyframe texels between the
vertices (each cell's centre and the midpoints of its lower and left edges), unprojected
from their own depth: the surface the keyframe saw.  ``C'`` is where the keyframe ray
through ``C`` meets the mesh.  On a plane the inverse eye depth ``1/d`` is affine in the
image, so on a mesh triangle ``1/d'`` is the barycentric blend of its vertices' ``1/d``
(a sky vertex beside ground takes its farthest ground neighbour's depth, as the mesh does;
other sky: ``1/d = 0``, a point at infinity): no ray is cast.  Each point is kept
homogeneous, ``(r + e/d, 1/d)`` with ``r`` the keyframe ray scaled to unit eye depth and
``e`` the keyframe eye, so points at infinity need no special case.  ``θ`` is the angle
at the current eye between ``C`` and ``C'``; a sample that saw sky counts 0 (the
silhouette's cells carry their sky texels with the ground, over sky or over what the
keyframe never saw, which the uncovered share counts).

**Resampling.**  Each sample's ``θ²`` gains ``(β e_res)²``: ``e_res`` is
:mod:`lodsprite.sprite.resampling`'s blur and alias terms of the map from current pixels
to keyframe pixels on the mesh triangle's plane, in display pixels (a keyframe ``k``
times the display's size a side is a display-sized image of ``k²`` samples a pixel), and
a phase term: the bilinear tap of a keyframe of ``k`` texels a pixel at the sub-texel
phase ``f`` is a filter of variance ``f (1 - f) / k²`` px² along each texel axis, against
the reference's box of ``1/12``; ``e_phase² = Σ_axes |f (1 - f) / k² - 1/12|``.  At
``k = 1`` a texel centre (``f = 0``) aliases by ``0.41`` px and a half-texel phase blurs by
``0.58`` px; at ``k = 2`` the half-texel phase, a spriteframe at its keyframe's own view,
is within ``0.2`` px of the box.

**Contrast.**  A displacement over flat colour changes the image little, over a ridge line
or a textured field much: with the keyframe's colour at hand (:meth:`DepthEstimate.
weigh_by`), each sample's share of the means is its local mean squared luminance gradient
(plus a floor of :data:`CONTRAST_FLOOR` of its mean), so ``mean θ²`` and the resampling
terms are means weighted by what the keyframe shows there.

**Uncovered area.**  The current image is cut into cells (at most ``COVER_GRID`` a side,
each at least twice the mesh's vertex spacing); a cell in which no keyframe vertex lands
(sky directions included) shows what the keyframe never saw (the fallback under the
mesh).  Its share ``u`` of the cells counts at :data:`UNCOVERED_PX`:
``E² = (1 - u) mean(θ²) + u (β UNCOVERED_PX)²``, and the error is ``sqrt(E²) / β``
pixels (Eq. 2: a keyframe is due when it reaches ε).

The keyframe's depth and colour reach the CPU once per keyframe (read back after an inline
keyframe, inside its timed frame; shipped with a worker's); the samples are at most
:data:`MAX_SAMPLES`, evenly over the cells, so a frame's estimate costs about a
millisecond of numpy at 512² (the resampling terms on at most :data:`MAX_RESAMPLED` of the
samples in view, the keyframe's side of their Jacobians computed once), a keyframe's about
5 ms to build and 6 ms to weigh (1152² texels at scale 2; 2-core machine).
"""

from __future__ import annotations

import math

import numpy as np

from lodsprite.camera import Projection, Viewpoint
from lodsprite.sprite.resampling import (
    cross,
    jacobian,
    pixel_derivatives,
    resampling_from_singular,
    singular_values,
    tangent_basis,
)

MAX_SAMPLES = 4096     # keyframe samples a frame's estimate measures
MAX_RESAMPLED = 1024   # of those in view, the most whose resampling term is evaluated
MAX_COVER = 8192       # keyframe vertices (at most) that say what the view holds
COVER_GRID = 16        # the current image's cells a side (at most), for that
UNCOVERED_PX = 2.0     # the error counted where the keyframe saw nothing (pixels)
CONTRAST_FLOOR = 0.1   # of the mean: the weight of a sample over flat colour
#: Where a cell's sample sits, as fractions ``(u, v)`` of the cell: centre, lower and
#: left edge midpoints.
CELL_SAMPLES = ((0.5, 0.5), (0.5, 0.0), (0.0, 0.5))


def grid_axis(n: int, stride: int) -> np.ndarray:
    """The mesh's vertex texels along an axis of ``n`` texels: every ``stride``-th and
    the last (as :func:`lodsprite.gl.depth_mesh.grid_vertices` places them)."""
    return np.unique(np.r_[np.arange(0, n, stride), n - 1])


def inverse_depth(z: np.ndarray, near: float, far: float) -> np.ndarray:
    """``1/d`` (1/metres) of window depths ``z`` of a perspective z-buffer with ``near`` and
    ``far`` planes; 0 for the far plane and beyond (sky)."""
    z = np.asarray(z, np.float64)
    d = 2.0 * near * far / (far + near - (2.0 * z - 1.0) * (far - near))
    return np.where(z >= 1.0, 0.0, 1.0 / np.maximum(d, 1e-30))


def key_rays(px: np.ndarray, py: np.ndarray, size: tuple[int, int], key: Viewpoint,
             projection: Projection) -> np.ndarray:
    """World rays ``(K, 3)`` through texel centres ``(px, py)`` (GL rows, bottom up) of a
    keyframe of ``size = (w, h)`` texels, scaled to unit eye depth."""
    w, h = size
    ty = math.tan(math.radians(projection.fov_y_deg) / 2.0)
    tx = ty * projection.aspect
    nx = ((px + 0.5) / w * 2.0 - 1.0) * tx
    ny = ((py + 0.5) / h * 2.0 - 1.0) * ty
    x, y, z = (np.asarray(a, np.float64) for a in (key.x, key.y, key.z))
    return nx[:, None] * x + ny[:, None] * y - z


def dilated(z: np.ndarray) -> np.ndarray:
    """Vertex window depths ``z (rows, cols)`` with each sky vertex (``z >= 1``) beside
    ground moved to its farthest ground neighbour's depth, as the mesh draws it: the
    silhouette's cells carry its sky texels with the ground."""
    rows, cols = z.shape
    pad = np.pad(z, 1, constant_values=1.0)
    g = np.zeros_like(z)
    for j in range(3):
        for i in range(3):
            n = pad[j:j + rows, i:i + cols]
            g = np.where(n < 1.0, np.maximum(g, n), g)
    return np.where((z >= 1.0) & (g > 0.0), g, z)


def even(n: int, most: int) -> np.ndarray:
    """At most ``most`` indices of ``range(n)``, evenly spread."""
    if n <= most:
        return np.arange(n)
    return np.unique(np.linspace(0, n - 1, most).astype(np.int64))


class DepthEstimate:
    """One keyframe's samples ``C`` and ``C'`` (module docstring), from its window depth
    ``depth (h, w) float32`` (row 0 at the top, as read back or shipped), its viewpoint
    ``key`` and projection (guard band included), a mesh of ``stride`` texels and a
    keyframe ``key_scale`` texels a display pixel."""

    def __init__(self, depth: np.ndarray, key: Viewpoint, projection: Projection,
                 stride: int, key_scale: float = 1.0) -> None:
        depth = np.asarray(depth, np.float32)[::-1]  # GL rows: bottom up
        h, w = depth.shape
        self.size = (w, h)
        self.key_scale = float(key_scale)
        self.key_px = (max(1, round(w / key_scale)), max(1, round(h / key_scale)))
        self.key_view_proj = projection.matrix() @ key.view_matrix()
        eye = np.asarray(key.o, np.float64)
        self.eye = eye
        xs, ys = grid_axis(w, stride), grid_axis(h, stride)
        inv = inverse_depth(dilated(depth[np.ix_(ys, xs)]), projection.near, projection.far)

        # samples: each cell's, evenly thinned to MAX_SAMPLES
        cy, cx = np.meshgrid(np.arange(len(ys) - 1), np.arange(len(xs) - 1), indexing="ij")
        cells = np.stack([cy.ravel(), cx.ravel()], 1)
        per = [(cells, u, v) for u, v in CELL_SAMPLES]
        iy = np.concatenate([c[:, 0] for c, _, _ in per])
        ix = np.concatenate([c[:, 1] for c, _, _ in per])
        fu = np.concatenate([np.full(len(c), u) for c, u, _ in per])
        fv = np.concatenate([np.full(len(c), v) for c, _, v in per])
        keep = even(len(iy), MAX_SAMPLES)
        iy, ix, fu, fv = iy[keep], ix[keep], fu[keep], fv[keep]
        x0, x1, y0, y1 = xs[ix], xs[ix + 1], ys[iy], ys[iy + 1]
        px = x0 + np.floor(fu * (x1 - x0)).astype(np.int64)
        py = y0 + np.floor(fv * (y1 - y0)).astype(np.int64)
        u = (px - x0) / (x1 - x0)
        v = (py - y0) / (y1 - y0)
        i00, i10, i11, i01 = (inv[iy, ix], inv[iy, ix + 1], inv[iy + 1, ix + 1],
                              inv[iy + 1, ix])
        lower = u >= v  # triangle (00, 10, 11), else (00, 11, 01)
        inv_mesh = np.where(lower, (1 - u) * i00 + (u - v) * i10 + v * i11,
                            (1 - v) * i00 + u * i11 + (v - u) * i01)
        inv_true = inverse_depth(depth[py, px], projection.near, projection.far)
        self.rays = key_rays(px, py, self.size, key, projection)
        self.inv_true, self.inv_mesh = inv_true, inv_mesh
        self.texel = np.c_[px + 0.5, py + 0.5]
        # the triangle's plane for the resampling term (all three vertices on ground)
        corner = [(iy, ix), (iy, ix + 1), (iy + 1, ix + 1), (iy + 1, ix)]
        pts = []
        for ry, rx in corner:
            r = key_rays(xs[rx], ys[ry], self.size, key, projection)
            pts.append(eye + r / np.maximum(inv[ry, rx], 1e-30)[:, None])
        p00, p10, p11, p01 = pts
        self.normals = np.where(lower[:, None], np.cross(p10 - p00, p11 - p00),
                                np.cross(p11 - p00, p01 - p00))
        ground = (inv_true > 0) & np.where(lower, (i00 > 0) & (i10 > 0) & (i11 > 0),
                                           (i00 > 0) & (i11 > 0) & (i01 > 0))
        self.ground = ground
        self.points = eye + self.rays / np.maximum(inv_true, 1e-30)[:, None]
        # the keyframe's side of each sample's Jacobian, once
        self.t1, self.t2 = tangent_basis(self.normals)
        self.b, self.kw = pixel_derivatives(self.points, self.t1, self.t2,
                                            self.key_view_proj, self.key_px)
        # coverage: the mesh's vertices (every step-th a side), sky directions included
        step = max(1, math.ceil(math.sqrt(len(xs) * len(ys) / MAX_COVER)))
        gy, gx = np.meshgrid(ys[::step], xs[::step], indexing="ij")
        cr = key_rays(gx.ravel(), gy.ravel(), self.size, key, projection)
        ci = inv[::step, ::step].ravel()
        self.cover_h = np.c_[cr + eye * ci[:, None], ci]
        self.cover_spacing_px = stride * step / self.key_scale  # display pixels
        self.samples_h = np.c_[self.rays + eye * inv_true[:, None], inv_true]
        self.weights = np.ones(len(inv_true))  # each sample's share of the mean
        self._cells = (px, py, max(1, stride // 2))

    def weigh_by(self, color: np.ndarray) -> None:
        """Weight each sample by the keyframe's contrast around it: the mean squared
        luminance gradient ``|∇L|²`` (grey levels per display pixel: every ``k``-th texel
        of a keyframe at scale ``k``) over a box of about ``stride`` texels a side about
        the sample, plus a floor of :data:`CONTRAST_FLOOR` of its mean,
        over the mean weight.  A displacement over smooth ground changes the image little;
        over a ridge line or a textured field, much.  ``color (h, w, 3) uint8``: the
        keyframe's colour, row 0 at the top, at the depth's size."""
        rgb = np.asarray(color)
        if rgb.shape[:2] != self.size[::-1]:
            raise ValueError(f"colour {rgb.shape} does not match the depth {self.size}")
        step = max(1, int(round(self.key_scale)))  # at the display's resolution
        c = rgb[::-1][::step, ::step].astype(np.float64)
        # float64, one operation at a time: the page's port (depth_estimate.js) gets the same bits
        lum = 0.2126 * c[..., 0] + 0.7152 * c[..., 1] + 0.0722 * c[..., 2]
        g2 = np.zeros_like(lum)
        g2[:, :-1] += np.diff(lum, axis=1) ** 2
        g2[:-1, :] += np.diff(lum, axis=0) ** 2
        table = np.zeros((g2.shape[0] + 1, g2.shape[1] + 1), np.float64)
        table[1:, 1:] = g2.cumsum(0).cumsum(1)
        px, py, r = (v // step for v in self._cells)
        r = max(1, r)
        h, w = g2.shape
        x0, x1 = np.clip(px - r, 0, w), np.clip(px + r + 1, 0, w)
        y0, y1 = np.clip(py - r, 0, h), np.clip(py + r + 1, 0, h)
        box = (table[y1, x1] - table[y0, x1] - table[y1, x0] + table[y0, x0]) / (
            (x1 - x0) * (y1 - y0))
        mean = float(box.mean())
        if not mean > 0:
            return
        wts = box + CONTRAST_FLOOR * mean
        self.weights = wts / wts.mean()

    def error_px(self, eye: np.ndarray, view_proj: np.ndarray, pixel_angle_rad: float,
                 size: tuple[int, int]) -> float:
        """The estimate (pixels) at a current eye ``eye (3,)`` through ``view_proj (4, 4)``
        on a ``size = (w, h)`` image with pixel angle ``pixel_angle_rad``; ``math.inf`` when
        no sample is in view."""
        eye = np.asarray(eye, np.float64)
        clip = self.samples_h @ view_proj.T
        w = clip[:, 3]
        vis = (w > 0) & (np.abs(clip[:, 0]) <= w) & (np.abs(clip[:, 1]) <= w)
        if not vis.any():
            return math.inf
        off = self.eye - eye
        r = self.rays[vis]
        a = r + off * self.inv_true[vis, None]
        b = r + off * self.inv_mesh[vis, None]
        theta = np.arctan2(np.sqrt((cross(a, b) ** 2).sum(1)), (a * b).sum(1))
        theta[self.inv_true[vis] == 0.0] = 0.0  # sky: drawn with the ground it borders
        beta = pixel_angle_rad
        idx = np.flatnonzero(vis)
        wts = self.weights[idx]
        total = float(wts.sum())
        g = idx[self.ground[idx]]
        res2 = 0.0  # the resampling terms' mean over the samples in view (sky: none)
        if len(g):
            sub = g[even(len(g), MAX_RESAMPLED)]
            ws = self.weights[sub]
            res2 = (float(ws @ self.resampling2(sub, view_proj, size)) / float(ws.sum())
                    * float(self.weights[g].sum()) / total)
        mean2 = float(wts @ theta ** 2) / total + beta ** 2 * res2
        u = self.uncovered(view_proj, size)
        return math.sqrt((1.0 - u) * mean2 + u * (beta * UNCOVERED_PX) ** 2) / beta

    def resampling2(self, idx: np.ndarray, view_proj: np.ndarray,
                    size: tuple[int, int]) -> np.ndarray:
        """``e_res² + e_phase²`` (px²) of the ground samples ``idx`` (module docstring)."""
        a, cw = pixel_derivatives(self.points[idx], self.t1[idx], self.t2[idx], view_proj,
                                  size)
        j, ok = jacobian(a, cw, self.b[idx], self.kw[idx])
        s1, s2 = singular_values(j)
        e_res = np.where(ok, resampling_from_singular(s1, s2), 0.0)
        # the sub-texel phase of the current pixel centre nearest the sample
        k = self.key_scale
        clip = self.samples_h[idx] @ view_proj.T
        p = (clip[:, :2] / clip[:, 3:4] + 1.0) * 0.5 * np.asarray(size, np.float64)
        d = np.floor(p) + 0.5 - p
        q = self.texel[idx] + k * np.einsum("kij,kj->ki", np.where(ok[:, None, None], j, 0), d)
        f = q - 0.5 - np.floor(q - 0.5)
        phase2 = np.abs(f * (1.0 - f) / k ** 2 - 1.0 / 12.0).sum(1)
        return e_res ** 2 + phase2

    def outside(self, view_proj: np.ndarray, key_view_proj: np.ndarray) -> float:
        """The share of this keyframe's vertices in the view through ``view_proj`` that
        another keyframe, through ``key_view_proj``, would not hold: what a keyframe not
        drawn yet (a look-ahead candidate) leaves uncovered of the view, as far as this
        one saw it."""
        def inside(m: np.ndarray, pts: np.ndarray) -> np.ndarray:
            c = pts @ m.T
            w = c[:, 3]
            return (w > 0) & (np.abs(c[:, 0]) <= w) & (np.abs(c[:, 1]) <= w)

        now = self.cover_h[inside(view_proj, self.cover_h)]
        if len(now) == 0:
            return 0.0
        return 1.0 - float(inside(key_view_proj, now).mean())

    def uncovered(self, view_proj: np.ndarray, size: tuple[int, int]) -> float:
        """The share of the current image's cells in which no keyframe vertex lands: at
        most :data:`COVER_GRID` a side, each at least twice the vertices' spacing at the
        keyframe's view (so that a turn alone leaves none empty), at least 4."""
        clip = self.cover_h @ view_proj.T
        w = clip[:, 3]
        vis = (w > 0) & (np.abs(clip[:, 0]) <= w) & (np.abs(clip[:, 1]) <= w)
        if not vis.any():
            return 1.0
        grid = int(np.clip(min(size) // (2.0 * self.cover_spacing_px), 4, COVER_GRID))
        ndc = clip[vis, :2] / w[vis, None]
        cell = np.clip(((ndc + 1.0) * 0.5 * grid).astype(np.int64), 0, grid - 1)
        hit = np.zeros((grid, grid), bool)
        hit[cell[:, 1], cell[:, 0]] = True
        return 1.0 - float(hit.mean())


class DepthReprojection:
    """A keyframe's ``C'`` under the depth estimate: ``base`` (the policy's own metric's
    ``C'``, what a keyframe not drawn yet, such as a look-ahead candidate, is judged by)
    until :attr:`estimate` is bound from the keyframe's depth once it is drawn."""

    def __init__(self, base) -> None:
        self.base = base
        self.estimate: DepthEstimate | None = None

    def __getattr__(self, name: str):
        if name in ("base", "estimate"):  # not set yet (unpickling)
            raise AttributeError(name)
        return getattr(self.base, name)
