"""The terrain techniques: ``full`` (full resolution), ``lod`` (one uniform coarse level),
``sprite`` (LOD-sprite, Chen, Swan & Kaufman 1999), ``adaptive`` (the CDLOD-style adaptive
renderer over a store or an in-memory pyramid) and ``sprite-adaptive`` (LOD-sprite with
keyframes drawn by the adaptive renderer).  Registered in :mod:`lodsprite.techniques.builtin`.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any

import numpy as np

from lodsprite.sprite.engine import DEFAULT_EPSILON_PX, FRAME_TYPES, KEYFRAME
from lodsprite.techniques.base import FALLBACK_TINT, Frame, Param, Technique
from lodsprite.terrain.lod import DEFAULT_COARSE, level_step

if TYPE_CHECKING:
    from lodsprite.api import LodSprite, Renderer
    from lodsprite.camera import Projection, Viewpoint


class FullTechnique(Technique):
    """The full-resolution terrain: the ground truth."""

    name = "full"

    def __init__(self, renderer: Renderer) -> None:
        super().__init__(renderer)

    def frame(self, viewpoint: Viewpoint) -> Frame:
        t0 = time.perf_counter()
        stats = self.renderer.render(viewpoint, None)
        return Frame("full", (time.perf_counter() - t0) * 1e3, stats.triangles)

    def summary(self, frames: list[Frame]) -> dict[str, Any]:
        return {"lod": self.renderer.scene.hf.quads}


class LodTechnique(Technique):
    """One uniform coarse level ``lod`` (quads per side): fast, with geometric error."""

    name = "lod"

    def __init__(self, renderer: Renderer, lod: int = DEFAULT_COARSE) -> None:
        super().__init__(renderer)
        self.quads = renderer.scene.hf.quads
        level_step(self.quads, lod)
        self.lod = lod

    def params(self) -> dict[str, Param]:
        return {"lod": Param("lod", self.lod, 2, self.quads, 2.0, "quads", integer=True)}

    def set_param(self, name: str, value: float) -> None:
        if name != "lod":
            super().set_param(name, value)
        level_step(self.quads, int(value))
        self.lod = int(value)

    def frame(self, viewpoint: Viewpoint) -> Frame:
        t0 = time.perf_counter()
        stats = self.renderer.render(viewpoint, self.lod)
        return Frame("lod", (time.perf_counter() - t0) * 1e3, stats.triangles)

    def coarse_level(self) -> int | None:
        return self.lod

    def summary(self, frames: list[Frame]) -> dict[str, Any]:
        return {"lod": self.lod}


class SpriteTechnique(Technique):
    """LOD-sprite: keyframes on a worker thread (``threaded``) or inline (the 1999
    algorithm, what batch runs time).  Records per frame the keyframe shown; its replay
    renders that keyframe from its logged viewpoint and projection, then the frame."""

    name = "sprite"

    def __init__(self, renderer: Renderer, lod: int = DEFAULT_COARSE,
                 epsilon: float = DEFAULT_EPSILON_PX, threaded: bool = False,
                 visibility: str | None = None, guard_px: int | None = None,
                 border: bool = True, metric: str = "warp") -> None:
        super().__init__(renderer)
        from lodsprite.gl.sprite import DEFAULT_GUARD_PX, DEFAULT_VISIBILITY

        level_step(renderer.scene.hf.quads, lod)
        self.threaded = threaded
        self.metric = metric
        self.sprite: LodSprite = renderer.sprite(
            epsilon, lod, threaded=threaded, visibility=visibility or DEFAULT_VISIBILITY,
            guard_px=DEFAULT_GUARD_PX if guard_px is None else guard_px, border=border,
            metric=metric)
        self._tint = False
        self._replayed: int | None = None
        self._last = None

    @property
    def engine(self):
        return self.sprite.engine

    def params(self) -> dict[str, Param]:
        return {"epsilon": Param("epsilon", self.sprite.epsilon_px, 0.125, 64.0, 1.25, "px")}

    def set_param(self, name: str, value: float) -> None:
        if name != "epsilon":
            super().set_param(name, value)
        self.sprite.epsilon_px = value

    def warm_up(self, viewpoint: Viewpoint) -> None:
        """Shaders compiled on a keyframe and a spriteframe drawn outside the engine, so
        that the timed run starts with no keyframe, as the 1999 algorithm does."""
        if self.threaded:
            self.frame(viewpoint)
            return
        s = self.sprite.sprite
        s.render_keyframe(viewpoint, 0.0)
        s.render_spriteframe(viewpoint)
        self.renderer.gl.finish()

    def frame(self, viewpoint: Viewpoint) -> Frame:
        f = self.sprite.frame(viewpoint)
        self._last = f
        return Frame(f.type, f.ms, f.triangles, f.error_px,
                     {"keyframe": f.keyframe, "keyframes": len(self.sprite.keyframes)})

    def decision(self) -> dict[str, Any]:
        return {"keyframe": self._last.keyframe, "kind": self._last.type,
                "shows_keyframe": (not self.threaded) and self.engine.shows_keyframe}

    def replay(self, viewpoint: Viewpoint, decision: dict[str, Any]) -> np.ndarray:
        s = self.sprite.sprite
        k = decision["keyframe"]
        if k != self._replayed:
            key = self.sprite.keyframes[k]
            s.render_keyframe(key.viewpoint, 0.0, key.projection)
            self._replayed = k
        if decision["shows_keyframe"]:
            return s.keyframe_color()
        s.render_spriteframe(viewpoint)
        return s.target.read_color()

    def quality_extra(self, viewpoint: Viewpoint, decision: dict[str, Any],
                      truth: np.ndarray) -> dict[str, float]:
        """The plain coarse level and the coarse level with LOD-sprite's border ribbons
        against the same reference: ``rmse_lod, psnr_lod, ssim_lod, rmse_lod_border``."""
        from lodsprite.metrics import psnr, rmse, ssim

        r = self.renderer.paths.renderer
        lod = self.sprite.lod
        r.render(viewpoint, lod)
        plain = r.target.read_color()
        r.render_proxy(viewpoint, lod, border=True)
        ribbons = r.target.read_color()
        return {"rmse_lod": rmse(plain, truth), "psnr_lod": psnr(plain, truth),
                "ssim_lod": ssim(plain, truth), "rmse_lod_border": rmse(ribbons, truth)}

    def summary(self, frames: list[Frame]) -> dict[str, Any]:
        """Keyframe count and fraction, mean time per frame kind (ms), mean error (px)."""
        out: dict[str, Any] = {"lod": self.sprite.lod, "epsilon": self.sprite.epsilon_px,
                               "visibility": self.sprite.sprite.visibility,
                               "metric": self.metric,
                               "keyframes": sum(f.kind == KEYFRAME for f in frames)}
        for t in FRAME_TYPES:
            ms = [f.ms for f in frames if f.kind == t]
            out[f"mean_ms_{t}"] = float(np.mean(ms)) if ms else float("nan")
        out["keyframe_fraction"] = out["keyframes"] / max(1, len(frames))
        out["mean_error_px"] = float(np.mean([f.error_px for f in frames]))
        return out

    def draw_to(self, framebuffer=None) -> None:
        self.sprite.draw_to(framebuffer)

    def read_image(self) -> np.ndarray:
        return self.sprite.read_image()

    def key_view(self) -> tuple[Viewpoint, Projection] | None:
        return self.sprite.key_view()

    def coarse_level(self) -> int | None:
        return self.sprite.lod

    def set_fallback_tint(self, on: bool) -> None:
        self.sprite.sprite.fallback_tint = FALLBACK_TINT if on else (*FALLBACK_TINT[:3], 0.0)

    def status(self) -> str:
        if not self.threaded:
            return "keyframes: inline"
        engine = self.engine
        w = engine.worker
        state = f"failed: {w.error}" if w.error is not None else (
            "rendering" if w.busy else "idle")
        return (f"keyframes: worker thread, {state}; {w.rendered} rendered, "
                f"{engine.discarded} discarded, lead {w.lead_s * 1e3:.0f} ms")

    def release(self) -> None:
        self.sprite.release()
