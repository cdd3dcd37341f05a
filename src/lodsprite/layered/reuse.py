"""The reused static layers of a scene (issue 32, must-have 5): ``--keyframes worker``.

:class:`KeyframedTerrain` takes the terrain layer's place: the terrain and the static
objects are in LOD-sprite keyframes rendered by the scene's keyframe worker
(:mod:`lodsprite.layered.scene_keys`) from predicted viewpoints, and a frame draws the
spriteframe of the newest keyframe the display has (the worker engine's rule:
:class:`~lodsprite.sprite.worker_engine.WorkerLodSpriteEngine`, which never waits after
the first keyframe and polls without blocking), then replaces the depth buffer with the
keyframe's (:class:`~lodsprite.gl.key_depth.KeyDepthPass`), so that the moving objects
and light fields drawn after it are hidden behind the static objects the sprite shows.

Its knob sets ε and the keyframe tolerance together (:data:`~lodsprite.scene.reuse.
REUSE_SETTINGS`); its model (:class:`~lodsprite.scene.reuse.ReuseModel`) learns the
worker's keyframe time at each tolerance from the keyframes delivered and the view's
error growth from the frames shown, and predicts each setting's error (its benefit) and
the display's ms (its cost).  The replay draws a frame's recorded keyframe (kept for the
frames a replay was planned for) as the spriteframe it showed.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any

import numpy as np

from lodsprite.layered.layers import Layer, layer_frame
from lodsprite.scene.budget import LayerControl
from lodsprite.scene.reuse import REUSE_SETTINGS, reuse_model, tolerance_for
from lodsprite.sprite.worker_engine import WorkerLodSpriteEngine

if TYPE_CHECKING:
    from lodsprite.api import Renderer
    from lodsprite.camera import Viewpoint
    from lodsprite.layered.scene_keys import SceneKeys
    from lodsprite.record import Frame

EPSILONS = tuple(e for e, _ in REUSE_SETTINGS)


class SceneKeyEngine(WorkerLodSpriteEngine):
    """The worker engine over the scene's keyframe worker; :attr:`shown` is the keyframe
    image shown and :attr:`adopted_at` when (``time.perf_counter`` s)."""

    def __init__(self, sprite, scene, fov_y_deg: float, epsilon_px: float,
                 keys: SceneKeys) -> None:
        from lodsprite.layered.scene_keys import SceneKeyframeWorker

        super().__init__(sprite, scene, fov_y_deg, epsilon_px, make_worker=lambda sc, st:
                         SceneKeyframeWorker(sc, st, keys))
        self.shown = None
        self.adopted_at = 0.0

    def _adopt(self, key, now: float) -> None:
        super()._adopt(key, now)
        full_depth(self.sprite, key)
        self.shown, self.adopted_at = key, now


def full_depth(sprite, key) -> None:
    """The keyframe image ``key``'s full z-buffer into the shown keyframe's depth (the
    ``coarse`` rule's upload keeps only its own coarse z-buffer, which the depth pass
    reads beside it)."""
    sprite.keyframe.target.depth.write(np.ascontiguousarray(key.depth[::-1], np.float32))


class KeyframedTerrain(Layer):
    """The terrain and static objects from the scene's keyframe worker (module doc),
    spriteframes of ``lod`` quads drawn on ``renderer`` (or, with ``depth_stride``, on the
    keyframe's own depth, ``pair`` with the keyframe before it); ``epsilon`` the starting
    ε (its setting's tolerance with it)."""

    name = "terrain"

    def __init__(self, renderer: Renderer, keys: SceneKeys, epsilon: float = 1.0,
                 lod: int = 16, exponent: float = 1.0, depth_stride: int | None = None,
                 pair: bool = False) -> None:
        from lodsprite.gl.key_depth import KeyDepthPass
        from lodsprite.gl.sprite import DEFAULT_VISIBILITY, SpriteDrawer

        self.renderer, self.mode = renderer, "sprite"
        self.sprite = SpriteDrawer(renderer.terrain_gl.drawer, lod, DEFAULT_VISIBILITY,
                                   depth_stride=depth_stride, pair=pair)
        try:
            self.engine = SceneKeyEngine(self.sprite, renderer.scene, renderer.fov_y_deg,
                                         epsilon, keys)
        except BaseException:
            self.sprite.release()
            raise
        self.depth = KeyDepthPass(self.sprite)
        self.model = reuse_model()
        self.engine.worker.exponent = float(exponent)
        self.set_epsilon(epsilon)
        self.kept: dict[int, Any] = {}     # keyframe index -> image, for the replay
        self._replays: set[int] = set()
        self._frames = 0
        self._last_t: float | None = None
        self._delivered = 0

    def set_epsilon(self, value: float) -> None:
        """The knob: ε (px) and its keyframe tolerance (:func:`tolerance_for`)."""
        self.engine.epsilon_px = float(value)
        self.engine.worker.tolerance = tolerance_for(value)

    def projection(self, viewpoint: Viewpoint) -> np.ndarray:
        return self.renderer.projection(viewpoint).matrix()

    def plan_replay(self, frames: set[int]) -> None:
        self._replays = set(frames)

    def warm_up(self, viewpoint: Viewpoint, projection: np.ndarray) -> None:
        """The first keyframe waited for (the worker's context, scene and shaders ready)
        and a spriteframe drawn."""
        self.engine.frame(viewpoint)
        self.depth.draw(viewpoint, self.renderer.projection(viewpoint))

    def draw(self, viewpoint: Viewpoint, t: float, projection: np.ndarray) -> Frame:
        f = self.engine.frame(viewpoint)
        self.depth.draw(viewpoint, self.renderer.projection(viewpoint))
        now = time.perf_counter()
        w = self.engine.worker
        for tau, ms in w.timings[self._delivered:]:
            self.model.rate.observe(tau, ms)
        # the worker's ms this frame (what it cost the display: the cost model's counter)
        work = sum(ms for _, ms in w.timings[self._delivered:])
        self._delivered = len(w.timings)
        self.model.observe_view(f.error_px, now - self.engine.adopted_at,
                                0.0 if self._last_t is None else now - self._last_t)
        self._last_t = now
        k = len(self.engine.keyframes) - 1
        if self._frames in self._replays:
            self.kept[k] = self.engine.shown
        self._frames += 1
        return layer_frame(self.name, f.ms, f.triangles, f.error_px, max(work, 1e-3),
                           {"terrain_kind": f.kind, "keyframes": w.rendered,
                            "keyframe": k, "tolerance": w.tolerance})

    def decision(self) -> dict[str, Any]:
        return {"keyframe": len(self.engine.keyframes) - 1}

    def replay(self, viewpoint: Viewpoint, t: float, projection: np.ndarray,
               decision: dict[str, Any]) -> None:
        key = self.kept[decision["keyframe"]]
        self.sprite.upload_keyframe(key.viewpoint, key.projection, key.color, key.depth, 0.0,
                                    key.zbuffer)
        full_depth(self.sprite, key)
        frame_projection = self.renderer.projection(viewpoint)
        self.sprite.render_spriteframe(viewpoint, frame_projection)
        self.depth.draw(viewpoint, frame_projection)

    def control(self) -> LayerControl:
        return LayerControl("terrain", EPSILONS, float(self.engine.epsilon_px),
                            self.set_epsilon, model=lambda: self.model)

    def summary(self) -> dict[str, Any]:
        """The worker's keyframes: rendered, discarded, median render ms, and the rate
        (keyframes a second) at the last setting's tolerance."""
        w = self.engine.worker
        ms = [m for _, m in w.timings]
        return {"keyframes_rendered": w.rendered, "keyframes_discarded": self.engine.discarded,
                "keyframe_ms_median": float(np.median(ms)) if ms else float("nan"),
                "keyframe_rate": self.model.rate.rate(w.tolerance)}

    def release(self) -> None:
        self.engine.close()
        self.depth.release()
        self.sprite.release()
