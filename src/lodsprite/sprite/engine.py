"""The LOD-sprite frame loop (Chen, Swan & Kaufman 1999, §3.1 steps 1-4).

step 1  render a keyframe from the full-resolution terrain and cache it as the sprite;
step 2  for a new viewpoint, evaluate the error metric (Eq. 2); if ``mean θ² >= (β ε)²``
        go to step 1;
step 3  otherwise render the coarse level texture-mapped with the sprite;
step 4  go to step 2.

With ``predict=True`` (the default) a due keyframe is rendered from a viewpoint
extrapolated ahead of the viewer (the paper's §5 proposal, :mod:`lodsprite.sprite.predict`).
Look-aheads of 1, 3/4, 1/2 and 1/4 of the previous keyframe interval are tried, largest
first; a candidate is taken when (a) the current frame's error against it, computed on
the CPU from ``C'`` before any rendering, is under ``PREDICT_MARGIN`` ε (0.9 ε), and
(b) every coarse square in the current view is also in the candidate's view (otherwise
the current frame would fall back to the terrain texture along the borders).  The
current frame is then a spriteframe from it.  When no candidate passes, the keyframe is
rendered at the current viewpoint, as in the paper.

A frame's time covers everything it costs: choosing the projection, the error
metric, culling, the GL work, ``C'`` for a new keyframe, and ``ctx.finish()``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

from lodsprite.camera import Viewpoint
from lodsprite.errors import InputError
from lodsprite.gl.sprite import SpriteRenderer
from lodsprite.gl.target import RenderTarget
from lodsprite.sprite.metric import ErrorMetric
from lodsprite.sprite.predict import extrapolate

KEYFRAME, FIRST_SPRITE, SPRITE = "keyframe", "first_sprite", "sprite"
FRAME_TYPES = (KEYFRAME, FIRST_SPRITE, SPRITE)
DEFAULT_EPSILON_PX = 1.0
PREDICT_MARGIN = 0.9
LOOKAHEAD_FRACTIONS = (1.0, 0.75, 0.5, 0.25)


@dataclass(frozen=True)
class SpriteFrame:
    """One frame: its type, the error of the image shown (pixels; 0 for a keyframe), the
    error that decided it (pixels, measured against the previous keyframe), triangles
    drawn and wall time (ms)."""

    type: str
    error_px: float
    decision_error_px: float
    triangles: int
    ms: float


class LodSpriteEngine:
    """Decides and renders keyframes and spriteframes for a stream of viewpoints."""

    def __init__(self, sprite: SpriteRenderer, epsilon_px: float = DEFAULT_EPSILON_PX,
                 predict: bool = True) -> None:
        if not epsilon_px > 0:
            raise InputError(f"error threshold epsilon must be > 0 pixels, got {epsilon_px}")
        self.sprite = sprite
        self.epsilon_px = float(epsilon_px)
        self.predict = predict
        hf = sprite.terrain.geometry.hf
        self.metric = ErrorMetric.for_level(hf, sprite.coarse_quads)
        self._c_prime = None
        self._since_key = 0
        self._interval = 0          # frames between the last two keyframes
        self._prev: Viewpoint | None = None
        self._shows_keyframe = True
        self.predicted_keyframes = 0

    @property
    def image_target(self) -> RenderTarget:
        """The target holding the image of the last frame."""
        return self.sprite.keyframe.target if self._shows_keyframe else self.sprite.target

    def _error(self, c_prime, viewpoint: Viewpoint, projection) -> float:
        view_proj = projection.matrix() @ viewpoint.view_matrix()
        beta = projection.pixel_angle_rad(self.sprite.target.height)
        return self.metric.error_px(c_prime, viewpoint.o, view_proj, beta)

    def _ahead(self, viewpoint: Viewpoint, projection) -> tuple | None:
        """``(viewpoint, projection, C', error)`` of a keyframe ahead of ``viewpoint`` that
        serves it within the margin, or None."""
        if not self.predict or self._prev is None or self._interval < 2:
            return None
        hf = self.sprite.terrain.geometry.hf
        for fraction in LOOKAHEAD_FRACTIONS:
            steps = fraction * self._interval
            if steps < 1:
                continue
            ahead = extrapolate(self._prev, viewpoint, steps)
            if ahead.o[2] <= float(hf.height_at(ahead.o[0], ahead.o[1])):
                continue
            key_proj = self.sprite.terrain.projection(ahead)
            if not self.metric.covers(viewpoint, projection, ahead, key_proj):
                continue
            c_prime = self.metric.reproject(ahead.o)
            err = self._error(c_prime, viewpoint, projection)
            if err < PREDICT_MARGIN * self.epsilon_px:
                return ahead, key_proj, c_prime, err
        return None

    def frame(self, viewpoint: Viewpoint) -> SpriteFrame:
        """Render the frame for ``viewpoint``; returns once the GL work has finished."""
        t0 = time.perf_counter()
        terrain = self.sprite.terrain
        projection = terrain.projection(viewpoint)
        decision = 0.0 if self._c_prime is None else self._error(self._c_prime, viewpoint,
                                                                 projection)
        if self._c_prime is None or decision >= self.epsilon_px:
            ahead = self._ahead(viewpoint, projection)
            if ahead is None:
                stats = self.sprite.render_keyframe(viewpoint, t0, projection)
                self._c_prime, shown, self._shows_keyframe = (
                    self.metric.reproject(viewpoint.o), 0.0, True)
            else:
                key_vp, key_proj, self._c_prime, shown = ahead
                key_stats = self.sprite.render_keyframe(key_vp, t0, key_proj)
                stats = self.sprite.render_spriteframe(viewpoint, projection)
                stats = replace(stats, triangles=stats.triangles + key_stats.triangles)
                self._shows_keyframe = False
                self.predicted_keyframes += 1
            kind = KEYFRAME
            self._interval, self._since_key = self._since_key + 1, 0
        else:
            stats = self.sprite.render_spriteframe(viewpoint, projection)
            kind = FIRST_SPRITE if self._since_key == 0 else SPRITE
            shown = decision
            self._since_key += 1
            self._shows_keyframe = False
        terrain.ctx.finish()
        self._prev = viewpoint
        return SpriteFrame(kind, shown, decision, stats.triangles,
                           (time.perf_counter() - t0) * 1e3)
