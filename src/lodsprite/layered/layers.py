"""The layers of a scene frame (issue 23; Chen, Swan & Kaufman 1999 §1 on decomposing a
scene into layers): :class:`Layer`, what each layer's frame was (:func:`layer_frame`),
and the terrain layer (:class:`TerrainLayer`).

Every layer draws into the renderer's one framebuffer and depth buffer, in the order
terrain, objects, light fields, through the frame's projection (the terrain technique's
own, near/far fitted to the terrain).  Each layer's time is measured with
``ctx.finish()`` before its clock starts and after its draw (GL time queries would not
include the CPU work of LOD selection and extraction, which is most of a layer's cost on
llvmpipe).

The terrain layer is any terrain technique of the registry (``full``, ``lod``,
``adaptive``, ``sprite``, ``sprite-adaptive``, a plug-in's), made on the same renderer,
not copied; its spec's ``knob`` says what a frame budget may turn.
LOD-sprite shows a keyframe as it is on the frame that renders it (no spriteframe, no
proxy depth); in a scene the layer draws the spriteframe of that keyframe on such a frame
too, so that every frame's depth buffer is the proxy's and later layers test against it.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from lodsprite.record import Frame
from lodsprite.scene.budget import LayerControl

if TYPE_CHECKING:
    from lodsprite.api import Renderer
    from lodsprite.camera import Viewpoint
    from lodsprite.techniques.base import Technique


def terrain_modes() -> tuple[str, ...]:
    """The techniques a terrain layer may be drawn by: the registry's that draw the
    terrain alone (plug-ins included)."""
    from lodsprite import techniques

    return techniques.names(("terrain",))


#: Knob settings, ascending quality: ε (sprite, px), tolerance (adaptive, px), level (lod);
#: ε in √2 steps to 4 px, then 2^(1/4) steps (the terrain's triangles rise faster than 1/ε
#: below a few pixels, so the finer steps keep a setting near any budget).
EPSILONS = (16.0, 11.3, 8.0, 5.7, 4.0, 3.4, 2.8, 2.4, 2.0, 1.7, 1.4, 1.2, 1.0, 0.84, 0.71,
            0.59, 0.5)
LEVELS = (8.0, 16.0, 32.0, 64.0)
#: The adaptive terrain's work table (triangles at every ε) is recomputed every this many
#: plans; the budget's measured/predicted ratio corrects it between.
WORK_EVERY = 4
WORK = "work"  # the key of a layer frame's work counter in its extra


def layer_frame(layer: str, ms: float, triangles: int = 0, error_px: float = math.nan,
                work: float | None = None, extra: dict[str, Any] | None = None) -> Frame:
    """One layer's part of a frame, as the one frame record: ``kind`` the layer's name,
    ``ms`` (GL finished), ``triangles`` drawn, ``error_px`` (NaN where the layer measures
    none), and in ``extra`` the layer's own columns and ``work`` (its own counter for its
    cost model: triangles, nodes; None: none), which the scene's frame takes out
    (:func:`layer_work`)."""
    return Frame(layer, ms, triangles, error_px, {**(extra or {}), WORK: work})


def layer_work(f: Frame) -> tuple[float | None, dict[str, Any]]:
    """A layer frame's ``work`` and its own columns (the rest of its ``extra``)."""
    return f.extra.get(WORK), {k: v for k, v in f.extra.items() if k != WORK}


class Layer:
    """One layer of a frame (see the module doc).  ``name``: ``terrain``, ``objects`` or
    ``lightfields``."""

    name = "layer"

    def draw(self, viewpoint: Viewpoint, t: float, projection: np.ndarray) -> Frame:
        """Draw the layer at time ``t`` (seconds) through ``projection (4, 4)``."""
        raise NotImplementedError

    def control(self) -> LayerControl:
        """What the budget may turn on this layer."""
        raise NotImplementedError

    def decision(self) -> dict[str, Any]:
        """What the last draw decided (cheap: no GPU reads)."""
        return {}

    def replay(self, viewpoint: Viewpoint, t: float, projection: np.ndarray,
               decision: dict[str, Any]) -> None:
        """Draw a recorded decision again, untimed, to the same pixels."""
        self.draw(viewpoint, t, projection)

    def warm_up(self, viewpoint: Viewpoint, projection: np.ndarray) -> None:
        """Untimed work before the first timed frame."""

    def release(self) -> None:
        """Release what the layer made."""


def timed(finish: Callable[[], None], draw: Callable[[], Frame]) -> Frame:
    """``draw()`` between two ``finish()`` calls; its frame with ``ms`` measured here."""
    finish()
    t0 = time.perf_counter()
    f = draw()
    finish()
    return replace(f, ms=(time.perf_counter() - t0) * 1e3)


class TerrainLayer(Layer):
    """The terrain by a registered terrain technique ``mode`` on ``renderer`` (options go
    to it); its knob: ε (sprite), tolerance (adaptive), level (lod), none (full)."""

    name = "terrain"

    def __init__(self, renderer: Renderer, mode: str = "adaptive", **options: Any) -> None:
        from lodsprite import techniques
        from lodsprite.errors import InputError

        if mode not in terrain_modes():
            raise InputError(f"unknown terrain mode {mode!r}: use one of "
                             f"{', '.join(terrain_modes())}")
        self.renderer, self.mode = renderer, mode
        self.spec = spec = techniques.get(mode)
        self.technique: Technique = spec.create(renderer, **spec.bind(options))
        # the spec's knob says what the technique is: epsilon -> LOD-sprite (its LodSprite)
        self.sprite = self.technique.sprite if spec.knob == "epsilon" else None
        self._last = None
        self._seen: Viewpoint | None = None       # the last frame's viewpoint
        self._table: np.ndarray | None = None     # the adaptive work table, and its age
        self._plans = 0
        self._coarse: np.ndarray | None = None    # max-pooled heights, for coverage
        self._covered: tuple[int, float] | None = None  # (plan, coverage)
        self._depth = None  # the keyframe's depth under spriteframes (static layers kept)

    def projection(self, viewpoint: Viewpoint) -> np.ndarray:
        """The frame's projection ``(4, 4)``: the terrain technique's own."""
        if self.spec.knob == "sse":  # the adaptive renderer fits its own near/far
            return self.technique.terrain.projection(viewpoint)
        return self.renderer.projection(viewpoint).matrix()

    def plan_replay(self, frames: set[int]) -> None:
        """The frames a replay will come for (the technique's own plan)."""
        self.technique.plan_replay(frames)

    def keyframe_hook(self, draw: Callable[[Viewpoint, np.ndarray, Any], None]) -> bool:
        """With LOD-sprite: ``draw(viewpoint, projection (4, 4), fbo)`` runs after the
        terrain of every keyframe, into the keyframe (static layers); False without."""
        if self.sprite is None:
            return False

        def after(viewpoint, projection, target) -> None:
            draw(viewpoint, projection.matrix(), target.fbo)

        self.sprite.sprite.after_keyframe = after
        if getattr(self.technique.engine, "tiled", None) is None:  # whole keyframes
            from lodsprite.gl.key_depth import KeyDepthPass

            self._depth = KeyDepthPass(self.sprite.sprite)
        return True

    def _spriteframe(self, viewpoint: Viewpoint) -> None:
        """A keyframe shown as it is: its spriteframe drawn too (the proxy's depth); with
        static layers in the keyframes, the depth buffer then the keyframe's own, warped
        (:class:`~lodsprite.gl.key_depth.KeyDepthPass`), so that what the sprite shows
        in front of a moving object hides it."""
        if self.sprite is not None and self.sprite.engine.shows_keyframe:
            self.sprite.sprite.render_spriteframe(viewpoint)
        if self._depth is not None:
            self._depth.draw(viewpoint, self.renderer.projection(viewpoint))

    def warm_up(self, viewpoint: Viewpoint, projection: np.ndarray) -> None:
        from lodsprite.layered.coverage import coarse_max

        self.technique.warm_up(viewpoint)
        if self._depth is not None:  # its program compiled here, not in the first frame
            self._depth.draw(viewpoint, self.renderer.projection(viewpoint))
        self._seen = viewpoint  # the first plan predicts from this view
        # the coverage rays' max-pooled heights (28 ms at 1025², 90 ms at 4097²): made here,
        # untimed, not in the first timed frame's plan
        self._coarse = coarse_max(self.renderer.scene.hf)

    def _adaptive_work(self) -> np.ndarray | None:
        """The adaptive renderer's triangles at every tolerance of :data:`EPSILONS` from
        the last frame's viewpoint (one traversal of its quadtree), every
        ``WORK_EVERY``-th plan; between, the table kept (None before a frame)."""
        if self._seen is None:
            return None
        self._plans += 1
        if self._table is None or self._plans % WORK_EVERY == 0:
            self._table = self.technique.terrain.triangles_at(self._seen, EPSILONS)
        return self._table

    def coverage(self) -> float | None:
        """The terrain's non-sky fraction of the window from the last frame's viewpoint
        (:func:`~lodsprite.layered.coverage.terrain_coverage`), measured every
        ``WORK_EVERY``-th call; None before a frame."""
        from lodsprite.layered.coverage import coarse_max, terrain_coverage

        if self._seen is None:
            return None
        calls = self._covered[0] + 1 if self._covered else 0
        if self._covered is None or calls % WORK_EVERY == 0:
            hf = self.renderer.scene.hf
            self._coarse = coarse_max(hf) if self._coarse is None else self._coarse
            size = terrain_coverage(hf, self._seen, self.projection(self._seen),
                                    coarse=self._coarse)
        else:
            size = self._covered[1]
        self._covered = (calls, size)
        return size

    def draw(self, viewpoint: Viewpoint, t: float, projection: np.ndarray) -> Frame:
        self._seen = viewpoint
        f = self._last = self.technique.frame(viewpoint)
        self._spriteframe(viewpoint)
        extra = {"terrain_kind": f.kind}
        if "keyframes" in f.extra:
            extra["keyframes"] = f.extra["keyframes"]
        return layer_frame(self.name, f.ms, f.triangles, f.error_px, float(max(f.triangles, 1)),
                           extra)

    def decision(self) -> dict[str, Any]:
        return self.technique.decision()

    def replay(self, viewpoint: Viewpoint, t: float, projection: np.ndarray,
               decision: dict[str, Any]) -> None:
        if self.sprite is not None and "shows_keyframe" in decision:
            decision = {**decision, "shows_keyframe": False}  # the spriteframe, as drawn
        self.technique.replay(viewpoint, decision)
        if self._depth is not None:
            self._depth.draw(viewpoint, self.renderer.projection(viewpoint))

    def control(self) -> LayerControl:
        t = self.technique
        if self.sprite is not None:
            return LayerControl("terrain", EPSILONS, float(self.sprite.epsilon_px),
                                lambda v: t.set_param("epsilon", v), coverage=self.coverage)
        if self.spec.knob == "sse":
            return LayerControl("terrain", EPSILONS, float(t.terrain.sse), t.terrain.set_sse,
                                work=self._adaptive_work, coverage=self.coverage)
        if self.spec.knob == "lod":
            levels = tuple(v for v in LEVELS if v <= self.renderer.scene.hf.quads) or (2.0,)
            return LayerControl("terrain", levels, float(t.lod),
                                lambda v: t.set_param("lod", v), coverage=self.coverage)
        return LayerControl("terrain", (1.0,), 1.0, lambda v: None)

    def release(self) -> None:
        if self._depth is not None:
            self._depth.release()
        self.technique.release()
