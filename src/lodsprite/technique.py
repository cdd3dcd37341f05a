"""The technique interface the viewer drives, and the terrain techniques.

A :class:`Technique` turns a viewpoint into a frame on a :class:`~lodsprite.api.Renderer`:
:meth:`~Technique.frame` renders (and times) it, :meth:`~Technique.draw_to` puts it into
a framebuffer, :meth:`~Technique.read_image` reads it back.  Techniques declare their
live-adjustable parameters as :class:`Param` (the viewer binds keys to them) and may
offer overlays (the keyframe shown, the coarse level) and a status line.  A technique is
made by a factory ``(renderer) -> Technique``; the viewer keeps a dict of factories by
mode name, so a new technique (a light field, a crowd) plugs in by adding a factory,
with no change to the viewer.

Terrain techniques: ``full`` (full resolution), ``lod`` (uniform coarse level N),
``sprite`` (LOD-sprite, keyframes on a worker thread by default).  The distributed
technique lives in :mod:`lodsprite.distributed.technique`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import moderngl
import numpy as np

from lodsprite.api import LodSprite, Renderer
from lodsprite.camera import Projection, Viewpoint
from lodsprite.errors import InputError
from lodsprite.sprite.engine import DEFAULT_EPSILON_PX
from lodsprite.terrain.lod import DEFAULT_COARSE, level_step

FALLBACK_TINT = (1.0, 0.0, 1.0, 0.45)


@dataclass(frozen=True)
class Param:
    """A live-adjustable parameter: value, bounds and the factor one key press applies
    (``step > 1``: multiply or divide, e.g. 2 for a level, 1.25 for ε)."""

    name: str
    value: float
    lo: float
    hi: float
    step: float
    unit: str = ""
    integer: bool = False

    def stepped(self, up: bool) -> Param:
        """The parameter one key press up or down, clamped to its bounds."""
        v = self.value * self.step if up else self.value / self.step
        v = min(max(v, self.lo), self.hi)
        return replace(self, value=float(round(v)) if self.integer else v)


@dataclass(frozen=True)
class FrameInfo:
    """One frame: its type (``full``, ``lod``, ``keyframe``, ``first_sprite``,
    ``sprite``, ...), time (ms, GL work finished), triangles drawn, the error of the image
    shown (pixels; NaN where the technique does not measure one) and keyframes so far."""

    type: str
    ms: float
    triangles: int
    error_px: float = math.nan
    keyframes: int = 0


class Technique:
    """Base of the techniques the viewer drives (see the module docstring)."""

    name = "technique"

    def __init__(self, renderer: Renderer) -> None:
        self.renderer = renderer

    def params(self) -> dict[str, Param]:
        """Live-adjustable parameters by name (none by default)."""
        return {}

    def set_param(self, name: str, value: float) -> None:
        raise InputError(f"{self.name} has no parameter {name!r}")

    def frame(self, viewpoint: Viewpoint) -> FrameInfo:
        raise NotImplementedError

    def draw_to(self, framebuffer: moderngl.Framebuffer | None = None) -> None:
        """Draw the last frame over ``framebuffer``'s viewport (default: the bound one)."""
        self.renderer.draw_to(framebuffer)

    def read_image(self) -> np.ndarray:
        """The last frame, ``(h, w, 3) uint8``, row 0 at the top."""
        return self.renderer.read_color()

    def key_view(self) -> tuple[Viewpoint, Projection] | None:
        """The viewpoint and projection of the keyframe shown, for the frustum overlay."""
        return None

    def coarse_level(self) -> int | None:
        """The coarse level drawn (quads per side), for the wireframe overlay."""
        return None

    def set_fallback_tint(self, on: bool) -> None:
        """Tint where a spriteframe fell back to the terrain texture (if it draws any)."""

    def status(self) -> str:
        """One line for the HUD (empty: nothing to add)."""
        return ""

    def release(self) -> None:
        """Release what the technique made (never the renderer)."""


TechniqueFactory = Callable[[Renderer], Technique]


class FullTechnique(Technique):
    """The full-resolution terrain: the ground truth."""

    name = "full"

    def frame(self, viewpoint: Viewpoint) -> FrameInfo:
        t0 = time.perf_counter()
        stats = self.renderer.render(viewpoint, None)
        return FrameInfo("full", (time.perf_counter() - t0) * 1e3, stats.triangles)


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

    def frame(self, viewpoint: Viewpoint) -> FrameInfo:
        t0 = time.perf_counter()
        stats = self.renderer.render(viewpoint, self.lod)
        return FrameInfo("lod", (time.perf_counter() - t0) * 1e3, stats.triangles)

    def coarse_level(self) -> int | None:
        return self.lod


class SpriteTechnique(Technique):
    """LOD-sprite: keyframes on a worker thread (``threaded``, default) or inline."""

    name = "sprite"

    def __init__(self, renderer: Renderer, lod: int = DEFAULT_COARSE,
                 epsilon_px: float = DEFAULT_EPSILON_PX, threaded: bool = True) -> None:
        super().__init__(renderer)
        self.threaded = threaded
        self.sprite: LodSprite = renderer.sprite(epsilon_px, lod, threaded=threaded)
        self._tint = False

    def params(self) -> dict[str, Param]:
        return {"epsilon": Param("epsilon", self.sprite.epsilon_px, 0.125, 64.0, 1.25, "px")}

    def set_param(self, name: str, value: float) -> None:
        if name != "epsilon":
            super().set_param(name, value)
        self.sprite.epsilon_px = value

    def frame(self, viewpoint: Viewpoint) -> FrameInfo:
        f = self.sprite.frame(viewpoint)
        return FrameInfo(f.type, f.ms, f.triangles, f.error_px, len(self.sprite.keyframes))

    def draw_to(self, framebuffer: moderngl.Framebuffer | None = None) -> None:
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
        engine = self.sprite.engine
        w = engine.worker
        state = f"failed: {w.error}" if w.error is not None else (
            "rendering" if w.busy else "idle")
        return (f"keyframes: worker thread, {state}; {w.rendered} rendered, "
                f"{engine.discarded} discarded, lead {w.lead_s * 1e3:.0f} ms")

    def release(self) -> None:
        self.sprite.release()


def terrain_techniques(lod: int = DEFAULT_COARSE, epsilon_px: float = DEFAULT_EPSILON_PX,
                       threaded: bool = True) -> dict[str, TechniqueFactory]:
    """Factories of the terrain techniques by mode name: ``full``, ``lod``, ``sprite``."""
    return {
        "full": FullTechnique,
        "lod": lambda r: LodTechnique(r, lod),
        "sprite": lambda r: SpriteTechnique(r, lod, epsilon_px, threaded),
    }


def stage_scene(label: str):
    """A placeholder terrain for a technique that draws no terrain (a lumigraph, a crowd):
    the viewer's renderer then supplies only the GL context, size, presenter and HUD.
    ``label`` names the scene in summaries."""
    from lodsprite.scene import Scene
    from lodsprite.terrain.heightfield import HeightField

    hf = HeightField(np.zeros((17, 17), np.float32), 1.0, 1.0, name="stage")
    return Scene(hf, np.zeros((16, 16, 3), np.uint8), str(label), "none")
