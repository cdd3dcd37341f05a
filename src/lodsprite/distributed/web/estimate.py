"""The web page's request logic and error estimate (``static/predictor.js``) in Python:
what simulated pages (``benchmarks/web_load.py``) run, and what tests check the page's
module against.  The two implement one algorithm; a change to one is a change to both.

**The estimate** (Chen, Swan & Kaufman 1999, §3.2, Eq. 1-2, with what a page has: the
coarse level and the scene's ``relief``).  Each coarse square's full-resolution centre
``C`` is estimated at the mean of its four corners raised by ``relief`` (metres).  ``C'``
is where the keyframe eye's ray through ``C`` meets the coarse mesh (the triangles the
page draws, each square split along its north-west to south-east diagonal): first among
the two triangles of ``C``'s square and of its eight neighbours, else among those of the
squares the ray's ground track crosses inside the terrain; of the hits in front of the
keyframe eye, the one nearest to ``C`` along the ray (as
:func:`lodsprite.sprite.raycast.reproject_points`).  ``C'`` depends on the keyframe eye
only, so it is cast once per keyframe (:meth:`ErrorMetric.reproject`, cached for the last
eye); a frame measures ``θ`` at its eye between ``C`` and ``C'`` for the centres in view.
A ray that meets no triangle is a miss, counted as the worst hit.  The error is
``sqrt(mean θ²) / β`` pixels; ``inf`` when no centre is in view or none in view is a hit.

It also counts what the spriteframe cannot show from the keyframe.  A square whose
fragment ``F`` (the coarse surface under ``C``, on the square's diagonal: where the page
draws its colour) the keyframe did not see is drawn from the terrain texture (``gl.js``'s
fallback), which puts ``C``'s texel at ``F``.  Not seen: hidden behind the keyframe's
coarse level (the keyframe eye's ray to ``F`` meets it nearer than ``F`` by more than the
page's tolerance, :data:`TOLERANCE`: its coarse z-buffer rule; cast once a keyframe) or,
when the keyframe's view-projection is given, outside its frustum.  When the current view
shows that ``F`` (inside its frustum, and the same cast from the current eye, for those
squares only), the square counts as a
miss does, no better than the worst hit (:func:`lodsprite.sprite.metric.miss_floor`),
and with the angle between ``C`` and ``F`` when that is larger.  At the keyframe's own
eye nothing the keyframe did not see is in view, and the error is 0 still.  (The
first estimate counted parallax only: flying the flyover over Jacksboro it read a third
of a pixel while the page showed rows of fallback texels; ``docs/web.md``.)

(The page's first estimate met the ray with the horizontal plane of the square's centre
instead of the mesh: for an eye a few hundred metres above rough terrain a grazing ray
met that plane far away, so a keyframe one frame old was judged 5-15x worse than
lodsprite's exact metric says; ``docs/web.md``.)

**The predictor**: the viewpoint extrapolated linearly from the last two samples (eye and
axes, the axes made orthonormal again) to one measured keyframe latency ahead (an
exponential mean of request to keyframe), at most :data:`MAX_AHEAD_S`.  A request goes
out when the shown keyframe's error there reaches ε/2, never with one in flight (one
unanswered for :data:`LOST_S` is given up).  (Looking further ahead, by the latency and
half the interval between keyframes so that a keyframe stands in the middle of the time
it is shown, was measured and not kept: a straight line strays from the curved paths, and
the mean error over the five built-in paths rose at 250 ms latency; ``docs/web.md``.)
"""

from __future__ import annotations

import numpy as np

from lodsprite.camera import Projection, Viewpoint
from lodsprite.sprite.metric import angles_at_eye
from lodsprite.sprite.raycast import ray_triangle_t

__all__ = ["LATENCY_START_S", "LOST_S", "MAX_AHEAD_S", "MAX_CENTRES", "TOLERANCE",
           "ErrorMetric", "Predictor", "Reprojection"]

MAX_CENTRES = 4096
"""Square centres measured (a finer coarse level: evenly, row-major)."""
MAX_AHEAD_S = 1.0
"""Look at most this far ahead (s): a straight line strays from a curved flight."""
LOST_S = 5.0
"""A request unanswered this long (s) is given up."""
LATENCY_START_S = 0.1
"""The latency assumed before one is measured (s)."""
SMOOTHING = 0.3
"""Weight of a new latency in its exponential mean."""
T_MIN = 1e-6
"""Hits nearer the keyframe eye than this (in units of the eye-to-C distance) are not
in front of it."""
TOLERANCE = {"coarse": 0.002, "full": 0.03}
"""The page's visibility tolerance by the scene's ``visibility`` (``gl.js``: lodsprite.gl.
sprite's ``DEFAULT_COARSE_TOL`` and ``DEFAULT_FRAGMENT_TOL``), relative to depth."""
TRACK_PAIRS = 1 << 16
"""Ray-square pairs of the ground-track search tested at once (bounded memory)."""


class Reprojection:
    """``C' (K, 3)`` metres and ``missed (K,) bool`` of the metric's centres for the
    keyframe eye ``key_eye (3,)``, and ``hidden (K,) bool``: the squares whose ``F`` the
    keyframe's coarse level hides from it."""

    def __init__(self, key_eye: np.ndarray, c_prime: np.ndarray, missed: np.ndarray,
                 hidden: np.ndarray | None = None) -> None:
        self.key_eye = key_eye
        self.c_prime = c_prime
        self.missed = missed
        self.hidden = np.zeros(len(c_prime), bool) if hidden is None else hidden


class ErrorMetric:
    """The page's estimate for a scene (:class:`~lodsprite.distributed.web.scene.
    SceneData`: ``header`` with ``coarse``, ``origin``, ``spacing``, ``spacing_y``,
    ``relief``; ``heights (n+1, n+1)``, row 0 south)."""

    def __init__(self, scene) -> None:
        hdr = scene.header
        h = np.asarray(scene.heights, np.float64)
        n = int(hdr.coarse)
        self.n = n
        self.origin = np.array(hdr.origin, np.float64)
        self.step = np.array([hdr.spacing, hdr.spacing_y], np.float64)
        self.relief = float(hdr.relief)
        self.tol = TOLERANCE.get(getattr(hdr, "visibility", None), TOLERANCE["full"])
        jj, ii = np.meshgrid(np.arange(n + 1), np.arange(n + 1))
        self.vertices = np.stack([self.origin[0] + jj * self.step[0],
                                  self.origin[1] + ii * self.step[1], h], -1)  # (n+1, n+1, 3)
        mid = 0.25 * (h[:-1, :-1] + h[:-1, 1:] + h[1:, :-1] + h[1:, 1:])
        ci, cj = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
        keep = np.arange(n * n)
        stride = -(-n * n // MAX_CENTRES)
        if stride > 1:
            keep = keep[::stride]
        self.square = np.stack([ci.ravel()[keep], cj.ravel()[keep]], -1)  # (K, 2) row, col
        i, j = self.square.T
        self.centres = np.stack([self.origin[0] + (j + 0.5) * self.step[0],
                                 self.origin[1] + (i + 0.5) * self.step[1],
                                 mid[i, j] + self.relief], -1)  # C (K, 3)
        self.fragments = np.c_[self.centres[:, :2],
                               0.5 * (h[i + 1, j] + h[i, j + 1])]  # F (K, 3): nw-se diagonal
        di, dj = np.meshgrid([-1, 0, 1], [-1, 0, 1], indexing="ij")
        ni, nj = i[:, None] + di.ravel(), j[:, None] + dj.ravel()  # (K, 9)
        ok = (ni >= 0) & (ni < n) & (nj >= 0) & (nj < n)
        near = self.triangles(np.clip(ni, 0, n - 1), np.clip(nj, 0, n - 1))
        self._near = near.reshape(len(i), 18, 3, 3)  # each centre's 3x3 squares' triangles
        self._near_ok = np.repeat(ok, 2, axis=1)  # (K, 18)
        self._all = self.triangles(*np.meshgrid(np.arange(n), np.arange(n),
                                                indexing="ij"))  # (n, n, 2, 3, 3)
        self._z_range = (np.minimum(np.minimum(h[:-1, :-1], h[:-1, 1:]),
                                    np.minimum(h[1:, :-1], h[1:, 1:])),
                         np.maximum(np.maximum(h[:-1, :-1], h[:-1, 1:]),
                                    np.maximum(h[1:, :-1], h[1:, 1:])))  # (n, n) each
        self._last: Reprojection | None = None

    # ---------------------------------------------------------------- per keyframe

    def triangles(self, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        """``(..., 2, 3, 3)``: the two triangles of squares ``(i, j)`` (row from the
        south, column), split north-west to south-east as the page draws them."""
        v = self.vertices
        a, b = v[i, j], v[i, j + 1]
        c, d = v[i + 1, j], v[i + 1, j + 1]
        return np.stack([np.stack([c, a, b], -2), np.stack([c, b, d], -2)], -3)

    def reproject(self, key_eye: np.ndarray) -> Reprojection:
        """``C'`` of every centre for the keyframe eye ``key_eye (3,)`` metres (the last
        eye's is cached)."""
        key_eye = np.asarray(key_eye, np.float64)
        if self.cached(key_eye):
            return self._last
        d = self.centres - key_eye  # C at t = 1
        t = _hits(key_eye, d, self._near)  # (K, 18)
        best = _nearest_one(np.where(self._near_ok, t, np.nan))
        miss = np.flatnonzero(np.isnan(best))  # rays that missed their neighbourhood
        block = max(1, TRACK_PAIRS // (2 * self.n + 3))  # bounded temporaries
        for k0 in range(0, len(miss), block):
            best[miss[k0:k0 + block]] = self._along_track(key_eye, d[miss[k0:k0 + block]])
        missed = np.isnan(best)
        c_prime = key_eye + d * np.where(missed, 1.0, best)[:, None]
        self._last = Reprojection(key_eye, c_prime, missed, self._hidden(key_eye))
        return self._last

    def _hidden(self, eye: np.ndarray, k: np.ndarray | None = None) -> np.ndarray:
        """``(K,) bool``: whether the coarse level hides ``F`` of the squares ``k`` (None:
        all) from ``eye (3,)``: the ray meets it first nearer than ``F`` by more than
        :attr:`tol`, relative."""
        d = self.fragments[slice(None) if k is None else k] - eye  # F at t = 1
        first = np.empty(len(d))
        block = max(1, TRACK_PAIRS // (2 * self.n + 3))
        for k0 in range(0, len(d), block):
            first[k0:k0 + block] = self._along_track(eye, d[k0:k0 + block], first=True)
        return ~np.isnan(first) & (first * (1.0 + self.tol) < 1.0)

    def cached(self, key_eye: np.ndarray) -> bool:
        """Whether ``C'`` of ``key_eye`` is cast already (:meth:`reproject` is then
        free)."""
        last = self._last
        return last is not None and np.array_equal(last.key_eye, key_eye)

    def keep(self, rep: Reprojection) -> None:
        """Take ``rep``, a :meth:`reproject` of this scene cast elsewhere (another
        process), as the cached one."""
        self._last = rep

    def _along_track(self, eye: np.ndarray, d: np.ndarray, first: bool = False) -> np.ndarray:
        """``t (R,)`` of the hit nearest ``t = 1`` (``first``: the smallest ``t``) among the
        squares the rays' ground tracks cross inside the terrain (NaN: none)."""
        n, lo, step = self.n, self.origin, self.step
        hi = lo + n * step
        dxy = d[:, :2]
        with np.errstate(divide="ignore", invalid="ignore"):
            t0 = (lo - eye[:2]) / dxy
            t1 = (hi - eye[:2]) / dxy
        inside = (eye[:2] >= lo) & (eye[:2] <= hi)
        flat = np.abs(dxy) <= 1e-12 * (np.abs(d).max(1, keepdims=True) + 1e-300)
        t_in = np.where(flat, np.where(inside, -np.inf, np.inf), np.minimum(t0, t1))
        t_out = np.where(flat, np.where(inside, np.inf, -np.inf), np.maximum(t0, t1))
        a = np.maximum(np.max(t_in, 1), 0.0)
        b = np.min(t_out, 1)
        good = (b > a) & np.isfinite(b)
        lines = [lo[k] + np.arange(n + 1) * step[k] for k in (0, 1)]
        with np.errstate(divide="ignore", invalid="ignore"):
            cross = np.concatenate([(lines[k][None] - eye[k]) / dxy[:, k:k + 1]
                                    for k in (0, 1)], 1)  # (R, 2n+2)
        cross = np.where((cross > a[:, None]) & (cross < b[:, None]), cross, np.nan)
        ts = np.sort(np.concatenate([a[:, None], cross, b[:, None]], 1), 1)
        mid = 0.5 * (ts[:, :-1] + ts[:, 1:])  # (R, 2n+3): inside one square each
        valid = np.isfinite(mid) & good[:, None]
        mid = np.where(valid, mid, 0.0)
        p = eye[:2] + dxy[:, None] * mid[..., None]
        cell = np.floor((p - lo) / step).astype(np.int64)
        ci, cj = np.clip(cell[..., 1], 0, n - 1), np.clip(cell[..., 0], 0, n - 1)
        # Only squares whose height range the ray's stretch over them meets can be hit
        # (a triangle lies within its square's corners' heights): the others are not
        # tested, which changes no result and spares most of the work.
        z0, z1 = eye[2] + d[:, 2:3] * ts[:, :-1], eye[2] + d[:, 2:3] * ts[:, 1:]
        zlo, zhi = self._z_range
        tol = 1e-9 * (1.0 + np.abs(zhi[ci, cj]))
        near = valid & (np.maximum(z0, z1) >= zlo[ci, cj] - tol) & (
            np.minimum(z0, z1) <= zhi[ci, cj] + tol)
        r, m = np.nonzero(near)
        t = np.full(mid.shape + (2,), np.nan)
        if r.size:
            t[r, m] = _hits(eye, d[r], self._all[ci[r, m], cj[r, m]])  # (P, 2)
        t = t.reshape(len(d), -1)
        if first:
            return np.where(np.isnan(t).all(1), np.nan,
                            np.nanmin(np.where(np.isnan(t), np.inf, t), 1))
        return _nearest_one(t)

    # ------------------------------------------------------------------- per frame

    def error_px(self, key_eye, vp: Viewpoint, view_proj: np.ndarray, beta: float,
                 key_view_proj: np.ndarray | None = None) -> float:
        """Error (px) of the keyframe seen from ``key_eye (3,)`` (None: none shown:
        ``inf``) shown at ``vp`` through ``view_proj (4, 4)``, ``beta`` radians a pixel;
        ``key_view_proj (4, 4)``: the keyframe's (its squares outside it count as not
        seen; None: not tested); ``inf`` when no centre is in view or none in view is a
        hit."""
        if key_eye is None:
            return float("inf")
        rep = self.reproject(key_eye)
        c, f = self.centres, self.fragments
        inside = _in_view(c, view_proj)
        unseen = inside & rep.hidden
        if key_view_proj is not None:
            unseen |= inside & ~_in_view(f, key_view_proj)
        k = np.flatnonzero(unseen & _in_view(f, view_proj))  # F drawn in this view
        shown = k[~self._hidden(np.asarray(vp.o, np.float64), k)]  # F seen from here
        hit = inside & ~unseen & ~rep.missed
        misses = int((inside & ~unseen & rep.missed).sum())
        if not hit.any():
            return float("inf")
        theta = angles_at_eye(vp.o, c[hit], rep.c_prime[hit])  # Eq. 1's θ, lodsprite's own
        worst = theta.max()
        fallback = np.maximum(angles_at_eye(vp.o, c[shown], f[shown]), worst)
        total = (theta**2).sum() + misses * worst**2 + (fallback**2).sum()
        return float(np.sqrt(total / (hit.sum() + misses + len(shown))) / beta)


def _in_view(p: np.ndarray, view_proj: np.ndarray) -> np.ndarray:
    """``(K,) bool``: points ``p (K, 3)`` inside the clip volume of ``view_proj``."""
    k = np.c_[p, np.ones(len(p))] @ np.asarray(view_proj, np.float64).T
    w = k[:, 3]
    return (w > 0) & (np.abs(k[:, :3]) <= w[:, None]).all(1)


def _hits(o: np.ndarray, d: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """``t (K, T)`` where rays ``o + t d`` (``o (3,)``, ``d (K, 3)``) meet triangles
    ``tris (K, T, 3, 3)`` (Möller-Trumbore, :func:`~lodsprite.sprite.raycast.
    ray_triangle_t`), NaN where they miss or ``t <= T_MIN``."""
    t = ray_triangle_t(o, d, tris)
    return np.where(t > T_MIN, t, np.nan)


def _nearest_one(t: np.ndarray) -> np.ndarray:
    """Per row of ``t (R, M)``: the value nearest 1 (NaN: the row has none)."""
    dist = np.where(np.isnan(t), np.inf, np.abs(t - 1.0))
    k = dist.argmin(1)
    out = t[np.arange(len(t)), k]
    return np.where(np.isfinite(dist[np.arange(len(t)), k]), out, np.nan)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


class Predictor:
    """The page's request logic for a scene (its ``header``: ``size``, ``fov``,
    ``near``, ``far``, ``epsilon``), with at most ``jobs`` requests in flight (the load
    reply's ``jobs``), a new one no sooner than the latency over ``jobs`` after the last."""

    def __init__(self, scene, jobs: int = 1) -> None:
        hdr = scene.header
        w, h = hdr.size
        self.epsilon = float(hdr.epsilon)
        self.proj = Projection(hdr.fov, w / h, hdr.near, hdr.far).matrix()
        self.beta = float(np.radians(hdr.fov) / h)
        self.samples: list[tuple[float, Viewpoint]] = []
        self.latency = LATENCY_START_S  # s, request to keyframe
        self.jobs = max(1, int(jobs))
        self.inflight: list[float] = []  # the requests' t, oldest first

    def sample(self, t: float, vp: Viewpoint) -> None:
        """The viewer is at ``vp`` at time ``t`` (s)."""
        self.samples = [*self.samples[-1:], (t, vp)]

    def predict(self, t: float) -> Viewpoint:
        """The viewpoint extrapolated to time ``t`` (s) from the last two samples."""
        if len(self.samples) < 2 or self.samples[1][0] <= self.samples[0][0]:
            return self.samples[-1][1]
        (t0, a), (t1, b) = self.samples
        f = (t - t1) / (t1 - t0)
        x = _unit(b.x + (b.x - a.x) * f)
        y = b.y + (b.y - a.y) * f
        y = _unit(y - x * (y @ x))
        return Viewpoint(x, y, np.cross(x, y), b.o + (b.o - a.o) * f)

    def lead(self) -> float:
        """Seconds ahead a request looks: the measured latency, at most
        :data:`MAX_AHEAD_S`."""
        return min(self.latency, MAX_AHEAD_S)

    def error_px(self, metric: ErrorMetric, key_eye, vp: Viewpoint,
                 key_view_proj: np.ndarray | None = None) -> float:
        return metric.error_px(key_eye, vp, self.proj @ vp.view_matrix(), self.beta,
                               key_view_proj)

    def want(self, metric: ErrorMetric, key_eye, t: float,
             key_view_proj: np.ndarray | None = None) -> Viewpoint | None:
        """What to request at time ``t`` (a viewpoint) or None (the page's moving case;
        a resting viewer's last request is the page's own); ``key_view_proj``: the shown
        keyframe's (:meth:`ErrorMetric.error_px`)."""
        self.inflight = [r for r in self.inflight if t - r <= LOST_S]  # lost: given up
        n = len(self.inflight)
        if n >= self.jobs or (n and t - self.inflight[-1] < self.lead() / self.jobs):
            return None
        ahead = self.predict(t + self.lead())
        return (ahead if self.error_px(metric, key_eye, ahead, key_view_proj)
                >= 0.5 * self.epsilon else None)

    def sent(self, t: float) -> None:
        self.inflight.append(t)

    def dropped(self, t0: float) -> None:
        """The keyframe requested at ``t0`` came after a newer one: not in flight, its
        latency not counted."""
        self.inflight = [r for r in self.inflight if r != t0]

    def arrived(self, t0: float, now: float) -> None:
        """The keyframe requested at ``t0`` arrived at ``now`` (s)."""
        if t0 in self.inflight:
            self.latency += SMOOTHING * (max(0.0, now - t0) - self.latency)
            self.inflight.remove(t0)
