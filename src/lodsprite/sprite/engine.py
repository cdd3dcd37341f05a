"""The LOD-sprite frame loop (Chen, Swan & Kaufman 1999, §3.1 steps 1-4): the GL driver.

step 1  render a keyframe from the full-resolution terrain and cache it as the sprite;
step 2  for a new viewpoint, evaluate the error metric (Eq. 2); if ``mean θ² >= (β ε)²``
        go to step 1;
step 3  otherwise render the coarse level texture-mapped with the sprite;
step 4  go to step 2.

What to draw (steps 2 and 4, and where a keyframe goes: at the viewer, or ahead of it
with ``predict=True``, the paper's §5 proposal) is decided by the GL-free
:class:`~lodsprite.sprite.policy.KeyframePolicy`; this module renders what it decides
(steps 1 and 3) with a :class:`~lodsprite.gl.sprite.SpriteDrawer`.

Keyframes are rendered with a guard band (:class:`~lodsprite.gl.sprite.SpriteDrawer`
``guard_px``); a frame that is a keyframe shows the keyframe's centre.  A keyframe placed
ahead of the viewer is followed, in the same frame, by a spriteframe from it.

With a keyframe cache (``cache_mb > 0``, :mod:`lodsprite.sprite.cache`) the keyframes
rendered stay in a pool of GPU slots within the budget, and a frame may show an older one
(the policy's lowest error here): :attr:`SpriteFrame.keyframe` is then that keyframe's
index in :attr:`LodSpriteEngine.keyframes`.

A frame's time covers everything it costs: choosing the projection, the error
metric, the GL work, ``C'`` for a new keyframe, and ``ctx.finish()``.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from lodsprite.camera import Viewpoint
from lodsprite.errors import InputError
from lodsprite.gl.sprite import SpriteDrawer
from lodsprite.record import Frame
from lodsprite.sprite.cache import DEFAULT_POLICY, KeyframeCache
from lodsprite.sprite.metric import ErrorMetric
from lodsprite.sprite.policy import (
    DEFAULT_EPSILON_PX,
    FIRST_SPRITE,
    FRAME_TYPES,
    KEYFRAME,
    SPRITE,
    KeyChoice,
    KeyframePolicy,
    resampling_metric,
)

__all__ = ["DEFAULT_EPSILON_PX", "FIRST_SPRITE", "FRAME_TYPES", "KEYFRAME", "SPRITE",
           "LodSpriteEngine", "SpriteFrame", "sprite_frame"]


#: A LOD-sprite frame: the one frame record (:class:`~lodsprite.record.Frame`), ``kind``
#: its type, ``error_px`` the error of the image shown (pixels; 0 for a keyframe), ``extra``
#: ``keyframe`` (the index in :attr:`LodSpriteEngine.keyframes` of the keyframe shown) and
#: ``decision_error_px`` (the error that decided it, against the previous keyframe).
SpriteFrame = Frame


def sprite_frame(kind: str, ms: float, triangles: int, error_px: float, keyframe: int,
                 decision_error_px: float) -> Frame:
    """A LOD-sprite engine's frame record (:data:`SpriteFrame`)."""
    return Frame(kind, ms, triangles, error_px,
                 {"keyframe": keyframe, "decision_error_px": decision_error_px})


class LodSpriteEngine:
    """Renders keyframes and spriteframes for a stream of viewpoints, as its
    :class:`~lodsprite.sprite.policy.KeyframePolicy` (:attr:`policy`) decides."""

    def __init__(self, sprite: SpriteDrawer, epsilon_px: float = DEFAULT_EPSILON_PX,
                 predict: bool = True, cache_mb: float = 0.0,
                 cache_policy: str = DEFAULT_POLICY, metric: str = "warp") -> None:
        self.sprite = sprite
        hf = sprite.terrain.geometry.full  # the terrain, or a store's level 0
        cache = (KeyframeCache(cache_mb * 2 ** 20, sprite.keyframe_bytes(), cache_policy)
                 if cache_mb > 0 else None)
        self.policy = KeyframePolicy(
            ErrorMetric.for_level(hf, sprite.coarse_quads, resampling_metric(metric)), hf,
            epsilon_px, sprite.target.height, sprite.terrain.projection,
            sprite.key_projection, predict, cache, key_size=sprite.key_px)
        if metric == "depth":
            if sprite.depth_mesh is None:
                raise InputError("the depth metric judges the keyframe's own depth mesh: "
                                 "it needs --proxy depth")
            self.policy.depth = (sprite.depth_mesh.stride, sprite.key_scale)
        self._shows_keyframe = True
        # Called in every frame that draws no keyframe, inside its clock (None: nothing).
        self.between_keyframes = None
        # Every keyframe rendered, in order: its viewpoint, frame projection and whether
        # look-ahead placed it ahead of the viewer.
        self.keyframes: list[KeyChoice] = []

    @property
    def cache(self) -> KeyframeCache | None:
        """The keyframe cache (None: off)."""
        return self.policy.cache

    @property
    def metric(self) -> ErrorMetric:
        return self.policy.metric

    @property
    def epsilon_px(self) -> float:
        return self.policy.epsilon_px

    @property
    def predict(self) -> bool:
        return self.policy.predict

    @property
    def predicted_keyframes(self) -> int:
        """Keyframes placed ahead of the viewer so far."""
        return self.policy.predicted_keyframes

    @property
    def shows_keyframe(self) -> bool:
        """Whether the last frame was a keyframe shown as it is (no spriteframe drawn)."""
        return self._shows_keyframe

    def read_image(self) -> np.ndarray:
        """The image of the last frame, ``(H, W, 3) uint8``, row 0 at the top: the keyframe
        (without its guard band) when the frame was one, else the spriteframe."""
        if self._shows_keyframe:
            return self.sprite.keyframe_color()
        return self.sprite.target.read_color()

    def frame(self, viewpoint: Viewpoint) -> Frame:
        """Render the frame for ``viewpoint``; returns once the GL work has finished."""
        t0 = time.perf_counter()
        d = self.policy.decide(viewpoint)
        stats = None
        if d.key is not None:
            stats = self.sprite.render_keyframe(d.key.viewpoint, t0, d.key.projection, d.slot)
            self.policy.keyframe_drawn(self.sprite.keyframe_depth, d.key.viewpoint,
                                       self.sprite.keyframe.projection,
                                       self.sprite.keyframe_image)
            self.keyframes.append(d.key)
        elif d.slot is not None:
            self.sprite.show(d.slot)  # a cached keyframe (binding only, no GL work)
        shows = d.shows_keyframe and self.sprite.keyframe_is_frame
        if not shows:
            key_stats = stats
            stats = self.sprite.render_spriteframe(viewpoint, d.projection)
            if key_stats is not None:
                stats = replace(stats, triangles=stats.triangles + key_stats.triangles)
        if d.key is None and self.between_keyframes is not None:
            self.between_keyframes()  # e.g. streaming for the next keyframe, timed here
        self._shows_keyframe = shows
        self.sprite.terrain.ctx.finish()
        ms = (time.perf_counter() - t0) * 1e3
        if d.key is not None:
            self.policy.keyframe_cost(ms)
        shown = len(self.keyframes) - 1 if d.keyframe is None else d.keyframe
        return sprite_frame(d.type, ms, stats.triangles, d.error_px, shown, d.decision_error_px)
