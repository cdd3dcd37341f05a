"""The LOD-sprite keyframe policy, free of GL (Chen, Swan & Kaufman 1999, §3.1-3.2, Eq. 2,
and the look-ahead their §5 proposes).

Which image a viewer may show is decided from geometry alone: the error metric of
:mod:`lodsprite.sprite.metric` measures a keyframe's ``C'`` at a viewpoint, in pixels
(:func:`keyframe_error_px`), and a keyframe is due when that error reaches the threshold
(:func:`keyframe_due`: Eq. 2's ``mean θ² >= (β ε)²`` is ``error_px >= ε``).  Everything
here is numpy and camera math; the GL drivers render what it decides:

* the in-process engine (:class:`lodsprite.sprite.engine.LodSpriteEngine`) follows a
  :class:`KeyframePolicy` frame by frame (§3.1 steps 1-4, with look-ahead);
* the distributed client decides with :func:`keyframe_due` when to render its own
  keyframe (at the current viewpoint, as in the paper's step 1) and whether a server
  keyframe serves;
* the distributed server's pacer decides with :func:`keyframe_needed`, the same rule
  applied to the keyframes the client may show.

Look-ahead (``predict=True``): a due keyframe is placed at a viewpoint extrapolated ahead
of the viewer (:func:`lodsprite.sprite.predict.extrapolate`), so that it serves the frames
on both sides of it.  The first look-ahead tried is the previous keyframe interval; up to
``LOOKAHEAD_TRIES`` candidates are tried, each shorter than the last.  A candidate is
taken when (a) its eye is above the ground, (b) every coarse square in the current view
is also in the candidate's view (guard band included; otherwise the current frame would
fall back to the terrain texture along its borders), and (c) the current frame's error
against it is under ``PREDICT_MARGIN`` ε.  The current frame is then a spriteframe from
it.  When no candidate passes, the keyframe is placed at the current viewpoint, as in the
paper.

Keyframe cache (``cache``, :mod:`lodsprite.sprite.cache`, the 1999 §5 proposal): every
keyframe rendered is kept within a GPU byte budget; each frame shows the cached keyframe
with the lowest error here (Eq. 2 with the term of a keyframe shown far from where it was
taken, :meth:`KeyframePolicy.cached_error_px`), among the nearest-eyed candidates that
cover the view, and a new keyframe is due only when that lowest error reaches ε.  Without
a cache (None) the policy keeps one keyframe, as the paper does.

Errors are plain floats compared with thresholds: an infinite error (nothing measurable,
:meth:`~lodsprite.sprite.metric.ErrorMetric.error_px`) makes a keyframe due, and so
does NaN.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np

from lodsprite.camera import Projection, Viewpoint, fitted_projection, widened
from lodsprite.errors import InputError
from lodsprite.sprite.cache import (
    SWITCH_FRACTION,
    CachedKeyframe,
    KeyframeCache,
    far_error_px,
)
from lodsprite.sprite.depth_metric import UNCOVERED_PX, DepthEstimate, DepthReprojection
from lodsprite.sprite.metric import ErrorMetric
from lodsprite.sprite.predict import extrapolate
from lodsprite.terrain.heightfield import HeightField

KEYFRAME, FIRST_SPRITE, SPRITE = "keyframe", "first_sprite", "sprite"
FRAME_TYPES = (KEYFRAME, FIRST_SPRITE, SPRITE)
DEFAULT_EPSILON_PX = 1.0
METRICS = ("warp", "resample", "depth")  # the technique option ``metric``
PREDICT_MARGIN = 0.9   # of ε: a look-ahead keyframe must serve the current frame under this
LOOKAHEAD_AIM = 0.95   # aim a rescaled look-ahead at this fraction of the margin
LOOKAHEAD_TRIES = 4

#: A frame's projection at a viewpoint (near/far fitted to the scene).
ProjectionFn = Callable[[Viewpoint], Projection]
#: The projection a keyframe is rendered through, from the frame's (guard band added).
KeyProjectionFn = Callable[[Projection], Projection]


def keyframe_error_px(metric: ErrorMetric, c_prime: np.ndarray, viewpoint: Viewpoint,
                      projection: Projection, height_px: int) -> float:
    """Error (pixels, Eq. 2) of showing the keyframe whose reprojected centres are
    ``c_prime (n*n, 3)`` metres at ``viewpoint`` seen through ``projection`` on an
    image ``height_px`` pixels high.  May be ``inf`` (nothing measurable).  A keyframe
    whose ``C'`` carries ``deficit_px`` (what it lacks: drawn while the tiles its
    tolerance needs were streaming, :mod:`lodsprite.techniques.adaptive_keys`) adds it."""
    view_proj = projection.matrix() @ viewpoint.view_matrix()
    beta = projection.pixel_angle_rad(height_px)
    lacks = float(getattr(c_prime, "deficit_px", 0.0))
    if isinstance(c_prime, DepthReprojection):  # the depth estimate, once it is drawn
        if c_prime.estimate is not None:
            size = (max(1, round(projection.aspect * height_px)), int(height_px))
            return lacks + c_prime.estimate.error_px(viewpoint.o, view_proj, beta, size)
        c_prime = c_prime.base
    if not getattr(metric, "resampling", False):  # the 1999 metric (or a stand-in)
        return lacks + metric.error_px(c_prime, viewpoint.o, view_proj, beta)
    size = (max(1, round(projection.aspect * height_px)), int(height_px))
    return lacks + metric.error_px(c_prime, viewpoint.o, view_proj, beta, size=size)


def resampling_metric(metric: str) -> bool:
    """Whether the technique option ``metric`` (one of :data:`METRICS`: ``"warp"``, the 1999
    Eq. 1-2 metric, ``"resample"``, which adds the resampling term, or ``"depth"``, the
    estimate on each keyframe's own depth, :mod:`lodsprite.sprite.depth_metric`, whose
    keyframes not drawn yet are judged by the warp metric) asks for the coarse metric's
    resampling term; :class:`~lodsprite.errors.InputError` for any other value."""
    if metric not in METRICS:
        raise InputError(f"metric must be one of {', '.join(METRICS)}, got {metric!r}")
    return metric == "resample"


def key_image_size(projection: Projection, key_projection: Projection,
                   height_px: int) -> tuple[int, int]:
    """``(w, h)`` pixels of a keyframe rendered through ``key_projection`` at the pixel angle
    of ``projection`` on ``height_px`` rows (a :func:`~lodsprite.camera.widened` one: the
    image plus its guard band)."""
    ratio = (math.tan(math.radians(key_projection.fov_y_deg) / 2)
             / math.tan(math.radians(projection.fov_y_deg) / 2))
    h = max(1, round(height_px * ratio))
    return max(1, round(key_projection.aspect * h)), h


def keyframe_due(error_px: float, limit_px: float) -> bool:
    """Whether a keyframe whose error at the current viewpoint is ``error_px`` must be
    replaced under the threshold ``limit_px`` (pixels): ``error_px >= limit_px``, the 1999
    rule.  ``inf`` and NaN are due: an error that cannot be measured is not small."""
    return not error_px < limit_px


def keyframe_needed(metric: ErrorMetric, c_primes: Iterable[np.ndarray | None],
                    viewpoint: Viewpoint, projection: Projection, height_px: int,
                    limit_px: float) -> bool:
    """Whether a new keyframe is needed at ``viewpoint``: True unless one of the keyframes
    whose ``C'`` are ``c_primes`` (None entries skipped) serves it under ``limit_px``."""
    for c_prime in c_primes:
        if c_prime is not None and not keyframe_due(
                keyframe_error_px(metric, c_prime, viewpoint, projection, height_px),
                limit_px):
            return False
    return True


@dataclass(frozen=True)
class KeyChoice:
    """A keyframe to render: its viewpoint, the frame projection there (the renderer adds
    the guard band) and whether it was placed ahead of the viewer."""

    viewpoint: Viewpoint
    projection: Projection
    predicted: bool


@dataclass(frozen=True)
class Decision:
    """What to draw at one viewpoint.

    ``type``: one of :data:`FRAME_TYPES`; ``projection``: the frame's; ``key``: the keyframe
    to render first (None: draw a spriteframe from the current keyframe).  A keyframe at the
    current viewpoint is shown as it is; one placed ahead is followed by a spriteframe from
    it.  ``error_px``: the error of the image shown (0 for a keyframe shown as it is);
    ``decision_error_px``: the error of the previous keyframe here, which decided (0 for
    the first frame, which has none).  With a keyframe cache, ``slot`` is the GPU slot of
    the keyframe shown (the new one's, or a cached one's) and ``keyframe`` its index among
    the keyframes rendered; both None without a cache (the newest, in the next slot).
    """

    type: str
    projection: Projection
    key: KeyChoice | None
    error_px: float
    decision_error_px: float
    slot: int | None = None
    keyframe: int | None = None

    @property
    def shows_keyframe(self) -> bool:
        """Whether the frame is the new keyframe itself (no spriteframe drawn)."""
        return self.key is not None and not self.key.predicted


class KeyframePolicy:
    """The LOD-sprite decision for a stream of viewpoints (GL-free, stateful).

    ``metric``: the error metric of the coarse level; ``hf``: the terrain (ground height
    for the look-ahead); ``epsilon_px``: the threshold ε in pixels; ``height_px``: the
    image height (sets the pixel angle β); ``projection(viewpoint)``: the frame projection;
    ``key_projection(projection)``: the projection a keyframe is rendered through (default:
    the frame's); ``predict``: place due keyframes ahead of the viewer; ``cache``: a
    :class:`~lodsprite.sprite.cache.KeyframeCache` to keep keyframes in (None: one keyframe);
    ``key_size``: the keyframe image's ``(w, h)`` pixels, guard band included (None: from
    the widened projection at the frame's pixel angle, :func:`key_image_size`).  Each
    keyframe's ``C'`` carries its view-projection matrix and size (the resampling term's
    input).
    """

    def __init__(self, metric: ErrorMetric, hf: HeightField, epsilon_px: float,
                 height_px: int, projection: ProjectionFn,
                 key_projection: KeyProjectionFn | None = None, predict: bool = True,
                 cache: KeyframeCache | None = None,
                 key_size: tuple[int, int] | None = None) -> None:
        if not epsilon_px > 0:
            raise InputError(f"error threshold epsilon must be > 0 pixels, got {epsilon_px}")
        self.metric = metric
        self.hf = hf
        self.epsilon_px = float(epsilon_px)
        self.height_px = int(height_px)
        self.projection = projection
        self.key_projection = key_projection or (lambda p: p)
        self.predict = predict
        self.key_size = key_size
        self.c_prime: np.ndarray | None = None  # C' of the current keyframe, (n*n, 3) metres
        self.predicted_keyframes = 0
        self._since_key = 0
        self._interval = 0          # frames between the last two keyframes
        self._prev: Viewpoint | None = None
        self.cache = cache
        self.rendered = 0           # keyframes decided so far (the next one's index)
        self._frame = 0

    @classmethod
    def for_terrain(cls, hf: HeightField, lod: int, epsilon_px: float,
                    size: tuple[int, int], fov_y_deg: float = 45.0, guard_px: int = 0,
                    predict: bool = True, cache: KeyframeCache | None = None,
                    metric: str = "warp") -> KeyframePolicy:
        """The policy for ``hf`` at coarse level ``lod`` on ``size = (w, h)`` pixel images,
        with the projections the terrain renderer uses (near/far fitted to the terrain,
        keyframes widened by ``guard_px`` pixels on every side), deciding with ``metric``
        (:func:`resampling_metric`)."""
        w, h = size
        lo, hi = hf.bounds()

        def projection(vp: Viewpoint) -> Projection:
            ground = float(hf.height_at(vp.o[0], vp.o[1]))
            return fitted_projection(vp, fov_y_deg, w / h, lo, hi, ground)

        return cls(ErrorMetric.for_level(hf, lod, resampling_metric(metric)), hf, epsilon_px,
                   h, projection, lambda p: widened(p, w, h, guard_px), predict, cache,
                   (w + 2 * guard_px, h + 2 * guard_px))

    def error_px(self, c_prime: np.ndarray, viewpoint: Viewpoint,
                 projection: Projection) -> float:
        """:func:`keyframe_error_px` with this policy's metric and image height."""
        return keyframe_error_px(self.metric, c_prime, viewpoint, projection, self.height_px)

    def reproject(self, key: Viewpoint, projection: Projection) -> np.ndarray:
        """``C'`` of a keyframe at ``key`` whose frame projection is ``projection``: the
        metric is told the keyframe's view (guard band included), which a view-dependent
        proxy (:mod:`lodsprite.sprite.proxy_metric`) is selected for, and, for the
        resampling term, the keyframe image's size."""
        key_proj = self.key_projection(projection)
        key_view_proj = key_proj.matrix() @ key.view_matrix()
        if not getattr(self.metric, "resampling", False):  # the 1999 metric needs the eye only
            c_prime = self.metric.reproject(key.o, key_view_proj=key_view_proj)
        else:
            size = self.key_size or key_image_size(projection, key_proj, self.height_px)
            c_prime = self.metric.reproject(key.o, key_view_proj, size)
        return DepthReprojection(c_prime) if self.depth is not None else c_prime

    #: ``(stride, key_scale)`` of the depth mesh whose keyframes the estimate on their own
    #: depth judges (:mod:`lodsprite.sprite.depth_metric`; None: the metric's own ``C'``).
    depth: tuple[int, float] | None = None

    def keyframe_drawn(self, depth: Callable[[], np.ndarray], key: Viewpoint,
                       projection: Projection,
                       color: Callable[[], np.ndarray] | None = None) -> None:
        """The current keyframe was drawn at ``key`` through ``projection`` (guard band
        included): under the depth estimate, bind it from the keyframe's window depth
        (``depth()``, read only then), its samples weighted by the keyframe's contrast
        (``color()``, likewise) when given."""
        if self.depth is None or not isinstance(self.c_prime, DepthReprojection):
            return
        stride, scale = self.depth
        est = DepthEstimate(depth(), key, projection, stride, scale)
        if color is not None:
            est.weigh_by(color())
        self.c_prime.estimate = est

    def lookahead(self, viewpoint: Viewpoint,
                  projection: Projection) -> tuple[KeyChoice, np.ndarray, float] | None:
        """A keyframe ahead of ``viewpoint`` that serves it within the margin, as
        ``(choice, C', error of the current frame against it)``, or None.

        The first look-ahead is the previous keyframe interval.  The error of the current
        frame grows about linearly with the look-ahead, so a candidate whose error is too
        large is followed by one scaled to land at ``LOOKAHEAD_AIM`` of the margin; a
        candidate under the ground or not covering the view by half the look-ahead.
        """
        if not self.predict or self._prev is None or self._interval < 2:
            return None
        limit = PREDICT_MARGIN * self.epsilon_px
        steps = float(self._interval)
        for _ in range(LOOKAHEAD_TRIES):
            if steps < 1:
                return None
            ahead = extrapolate(self._prev, viewpoint, steps)
            if not self.above_ground(ahead):
                steps *= 0.5
                continue
            key_proj = self.projection(ahead)
            if not self.metric.covers(viewpoint, projection, ahead,
                                      self.key_projection(key_proj)):
                steps *= 0.5
                continue
            c_prime = self.reproject(ahead, key_proj)
            err = self.uncovered_by(ahead, key_proj, viewpoint, projection,
                                    self.error_px(c_prime, viewpoint, projection))
            if not keyframe_due(err, limit):
                return KeyChoice(ahead, key_proj, True), c_prime, err
            # inf or NaN (nothing measurable from here): no shorter look-ahead can tell
            steps = steps * min(LOOKAHEAD_AIM * limit / err, 0.75) if err < math.inf else 0.0
        return None

    def uncovered_by(self, ahead: Viewpoint, key_proj: Projection, viewpoint: Viewpoint,
                     projection: Projection, error_px: float) -> float:
        """``error_px`` of a look-ahead candidate at ``ahead`` (frame projection
        ``key_proj``) seen from ``viewpoint``, with, under the depth estimate, the share of
        the view it would leave uncovered (as the current keyframe's depth tells) counted
        as the estimate counts it."""
        est = getattr(self.c_prime, "estimate", None)
        if est is None or not math.isfinite(error_px):
            return error_px
        u = est.outside(projection.matrix() @ viewpoint.view_matrix(),
                        self.key_projection(key_proj).matrix() @ ahead.view_matrix())
        return math.sqrt(error_px ** 2 + u * UNCOVERED_PX ** 2)

    def above_ground(self, viewpoint: Viewpoint) -> bool:
        """Whether the eye of ``viewpoint`` is above the terrain surface below it."""
        o = viewpoint.o
        return bool(o[2] > float(self.hf.height_at(o[0], o[1])))

    def best_cached(self, viewpoint: Viewpoint,
                    projection: Projection) -> tuple[CachedKeyframe | None, float]:
        """The cached keyframe with the lowest error at ``viewpoint`` and that error
        (``(None, inf)`` when none is cached); the shown keyframe needs no coverage test
        (its guard band serves it, as without a cache) and, under ``SWITCH_FRACTION`` ε,
        no search (:mod:`lodsprite.sprite.cache`: the cost and the prunings)."""
        shown = self.cache.shown
        if shown is None:
            return None, math.inf
        best, best_err = shown, self.cached_error_px(shown, viewpoint, projection)
        if best_err < SWITCH_FRACTION * self.epsilon_px:
            return best, best_err
        here = None
        for e in self.cache.candidates(viewpoint.o)[1:]:
            if e.in_view is None:
                e.in_view = self.metric.in_view_mask(e.viewpoint,
                                                     self.key_projection(e.projection))
            if here is None:
                here = self.metric.in_view_mask(viewpoint, projection)
            if not np.all(e.in_view[here]):
                continue
            err = self.cached_error_px(e, viewpoint, projection)
            if err < best_err:
                best, best_err = e, err
        return best, best_err

    def cached_error_px(self, entry: CachedKeyframe, viewpoint: Viewpoint,
                        projection: Projection) -> float:
        """A cached keyframe's error at ``viewpoint``: Eq. 2 and the term of one shown far
        from where it was taken (:func:`~lodsprite.sprite.cache.far_error_px`) in
        quadrature."""
        err = self.error_px(entry.c_prime, viewpoint, projection)
        far = far_error_px(self.metric, entry.c_prime, entry.viewpoint.o, viewpoint.o,
                           projection.matrix() @ viewpoint.view_matrix(),
                           projection.pixel_angle_rad(self.height_px))
        return math.hypot(err, far)

    def keyframe_cost(self, ms: float) -> None:
        """What the keyframe just rendered cost (ms): the ``benefit`` policy weighs it."""
        if self.cache is not None and self.cache.shown is not None:
            self.cache.shown.cost_ms = float(ms)

    def decide(self, viewpoint: Viewpoint) -> Decision:
        """The decision for the next frame, at ``viewpoint``; the policy then takes it as
        done (a new keyframe's ``C'`` becomes the current one)."""
        self._frame += 1
        projection = self.projection(viewpoint)
        cached = None
        if self.cache is not None:
            cached, decision = self.best_cached(viewpoint, projection)
            if cached is None:  # the first frame
                decision = 0.0
        else:
            decision = (0.0 if self.c_prime is None
                        else self.error_px(self.c_prime, viewpoint, projection))
        if self.c_prime is None or keyframe_due(decision, self.epsilon_px):
            ahead = self.lookahead(viewpoint, projection)
            if ahead is None:
                key = KeyChoice(viewpoint, projection, False)
                self.c_prime, shown = self.reproject(viewpoint, projection), 0.0
            else:
                key, self.c_prime, shown = ahead
                self.predicted_keyframes += 1
            kind = KEYFRAME
            self._interval, self._since_key = self._since_key + 1, 0
            if self.cache is not None:
                cached = self.cache.insert(self.rendered, key.viewpoint, key.projection,
                                           self.c_prime, self._frame)
            self.rendered += 1
        else:
            key, shown = None, decision
            kind = FIRST_SPRITE if self._since_key == 0 else SPRITE
            self._since_key += 1
            if cached is not None:
                self.cache.use(cached, self._frame)
                self.c_prime = cached.c_prime
        self._prev = viewpoint
        if cached is None:
            return Decision(kind, projection, key, shown, decision)
        return Decision(kind, projection, key, shown, decision, cached.slot, cached.index)
