"""The LOD-sprite frame loop (Chen, Swan & Kaufman 1999, §3.1 steps 1-4).

step 1  render a keyframe from the full-resolution terrain and cache it as the sprite;
step 2  for a new viewpoint, evaluate the error metric (Eq. 2); if ``mean θ² >= (β ε)²``
        go to step 1;
step 3  otherwise render the coarse level texture-mapped with the sprite;
step 4  go to step 2.

A frame's time covers everything it costs: choosing the projection, the error
metric, culling, the GL work, ``C'`` for a new keyframe, and ``ctx.finish()``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from lodsprite.camera import Viewpoint
from lodsprite.errors import InputError
from lodsprite.gl.sprite import SpriteRenderer
from lodsprite.gl.target import RenderTarget
from lodsprite.sprite.metric import ErrorMetric

KEYFRAME, FIRST_SPRITE, SPRITE = "keyframe", "first_sprite", "sprite"
FRAME_TYPES = (KEYFRAME, FIRST_SPRITE, SPRITE)
DEFAULT_EPSILON_PX = 1.0


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

    def __init__(self, sprite: SpriteRenderer, epsilon_px: float = DEFAULT_EPSILON_PX) -> None:
        if not epsilon_px > 0:
            raise InputError(f"error threshold epsilon must be > 0 pixels, got {epsilon_px}")
        self.sprite = sprite
        self.epsilon_px = float(epsilon_px)
        hf = sprite.terrain.geometry.hf
        self.metric = ErrorMetric.for_level(hf, sprite.coarse_quads)
        self._c_prime = None
        self._since_key = 0
        self._last_type = KEYFRAME

    @property
    def image_target(self) -> RenderTarget:
        """The target holding the image of the last frame."""
        if self._last_type == KEYFRAME:
            return self.sprite.keyframe.target
        return self.sprite.target

    def frame(self, viewpoint: Viewpoint) -> SpriteFrame:
        """Render the frame for ``viewpoint``; returns once the GL work has finished."""
        t0 = time.perf_counter()
        terrain = self.sprite.terrain
        projection = terrain.projection(viewpoint)
        if self._c_prime is None:
            decision = 0.0
        else:
            view_proj = projection.matrix() @ viewpoint.view_matrix()
            beta = projection.pixel_angle_rad(self.sprite.target.height)
            decision = self.metric.error_px(self._c_prime, viewpoint.o, view_proj, beta)
        if self._c_prime is None or decision >= self.epsilon_px:
            stats = self.sprite.render_keyframe(viewpoint, t0, projection)
            self._c_prime = self.metric.reproject(viewpoint.o)
            kind, shown, self._since_key = KEYFRAME, 0.0, 0
        else:
            stats = self.sprite.render_spriteframe(viewpoint, projection)
            kind = FIRST_SPRITE if self._since_key == 0 else SPRITE
            shown = decision
            self._since_key += 1
        terrain.ctx.finish()
        self._last_type = kind
        return SpriteFrame(kind, shown, decision, stats.triangles,
                           (time.perf_counter() - t0) * 1e3)
