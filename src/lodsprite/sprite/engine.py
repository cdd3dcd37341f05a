"""The LOD-sprite frame loop (Chen, Swan & Kaufman 1999, §3.1 steps 1-4).

step 1  render a keyframe from the full-resolution terrain and cache it as the sprite;
step 2  for a new viewpoint, evaluate the error metric (Eq. 2); if ``mean θ² >= (β ε)²``
        go to step 1;
step 3  otherwise render the coarse level texture-mapped with the sprite;
step 4  go to step 2.

With ``predict=True`` (the default) a due keyframe is rendered from a viewpoint
extrapolated ahead of the viewer (the paper's §5 proposal, :mod:`lodsprite.sprite.predict`).
The first look-ahead tried is the previous keyframe interval; up to ``LOOKAHEAD_TRIES``
candidates are tried, each shorter than the last.  A candidate is taken when (a) the
current frame's error against it, computed on the CPU from ``C'`` before any rendering,
is under ``PREDICT_MARGIN`` ε (0.9 ε), and (b) every coarse square in the current view
is also in the candidate's view, guard band included (otherwise the current frame would
fall back to the terrain texture along the borders).  The current frame is then a
spriteframe from it.  When no candidate passes, the keyframe is rendered at the current
viewpoint, as in the paper.

Keyframes are rendered with a guard band (:class:`~lodsprite.gl.sprite.SpriteRenderer`
``guard_px``); a frame that is a keyframe shows the keyframe's centre.

A frame's time covers everything it costs: choosing the projection, the error
metric, the GL work, ``C'`` for a new keyframe, and ``ctx.finish()``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from lodsprite.camera import Viewpoint
from lodsprite.errors import InputError
from lodsprite.gl.sprite import SpriteRenderer
from lodsprite.sprite.metric import ErrorMetric
from lodsprite.sprite.policy import keyframe_error_px
from lodsprite.sprite.predict import extrapolate

KEYFRAME, FIRST_SPRITE, SPRITE = "keyframe", "first_sprite", "sprite"
FRAME_TYPES = (KEYFRAME, FIRST_SPRITE, SPRITE)
DEFAULT_EPSILON_PX = 1.0
PREDICT_MARGIN = 0.9
LOOKAHEAD_AIM = 0.95   # aim a rescaled look-ahead at this fraction of the margin
LOOKAHEAD_TRIES = 4


@dataclass(frozen=True)
class SpriteFrame:
    """One frame: its type, the error of the image shown (pixels; 0 for a keyframe), the
    error that decided it (pixels, measured against the previous keyframe), triangles
    drawn, wall time (ms) and the index of the keyframe the image comes from."""

    type: str
    error_px: float
    decision_error_px: float
    triangles: int
    ms: float
    keyframe: int = -1  # index in LodSpriteEngine.keyframes of the keyframe shown


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
        # Every keyframe rendered, in order: (viewpoint, frame projection) it was rendered
        # from (ahead of the viewer, with prediction).
        self.keyframes: list[tuple[Viewpoint, object]] = []

    def read_image(self) -> np.ndarray:
        """The image of the last frame, ``(H, W, 3) uint8``, row 0 at the top: the keyframe
        (without its guard band) when the frame was one, else the spriteframe."""
        if self._shows_keyframe:
            return self.sprite.keyframe_color()
        return self.sprite.target.read_color()

    def _error(self, c_prime, viewpoint: Viewpoint, projection) -> float:
        return keyframe_error_px(self.metric, c_prime, viewpoint, projection,
                                 self.sprite.target.height)

    def _ahead(self, viewpoint: Viewpoint, projection) -> tuple | None:
        """``(viewpoint, projection, C', error)`` of a keyframe ahead of ``viewpoint`` that
        serves it within the margin, or None.

        The first look-ahead is the previous keyframe interval.  The error of the current
        frame grows about linearly with the look-ahead, so a candidate whose error is too
        large is followed by one scaled to land at ``LOOKAHEAD_AIM`` of the margin; a
        candidate under the ground or not covering the view by half the look-ahead.
        """
        if not self.predict or self._prev is None or self._interval < 2:
            return None
        hf = self.sprite.terrain.geometry.hf
        limit = PREDICT_MARGIN * self.epsilon_px
        steps = float(self._interval)
        for _ in range(LOOKAHEAD_TRIES):
            if steps < 1:
                return None
            ahead = extrapolate(self._prev, viewpoint, steps)
            key_proj = self.sprite.terrain.projection(ahead)
            if ahead.o[2] <= float(hf.height_at(ahead.o[0], ahead.o[1])) or not \
                    self.metric.covers(viewpoint, projection, ahead,
                                       self.sprite.key_projection(key_proj)):
                steps *= 0.5
                continue
            c_prime = self.metric.reproject(ahead.o)
            err = self._error(c_prime, viewpoint, projection)
            if err < limit:
                return ahead, key_proj, c_prime, err
            steps *= min(LOOKAHEAD_AIM * limit / err, 0.75)
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
                self.keyframes.append((viewpoint, projection))
                self._c_prime, shown, self._shows_keyframe = (
                    self.metric.reproject(viewpoint.o), 0.0, True)
            else:
                key_vp, key_proj, self._c_prime, shown = ahead
                key_stats = self.sprite.render_keyframe(key_vp, t0, key_proj)
                self.keyframes.append((key_vp, key_proj))
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
                           (time.perf_counter() - t0) * 1e3, len(self.keyframes) - 1)
