"""The crowd in the viewer: ``lodsprite view crowd[:OBJECTS[:TREES]]`` walks through the
LODManager's crowd with the viewer's window, controls, HUD and played paths; keys 1-3
switch between the manager, baseline (a) (every object extracts its own LOD) and
baseline (b) (discrete LODs by screen size).  The crowd stands on ``z = 0`` in the
viewer's own z-up world."""

from __future__ import annotations

import numpy as np

from lodsprite.camera import Viewpoint
from lodsprite.errors import InputError
from lodsprite.techniques import Frame, Param, Technique, TechniqueFactory

VIEW_MODES = ("manager", "independent", "discrete")


def parse_crowd(spec: str) -> tuple[int, int]:
    """``crowd[:OBJECTS[:TREES]]`` -> (objects, trees); defaults 3000 and 0."""
    parts = spec.split(":")
    if parts[0] != "crowd" or len(parts) > 3:
        raise InputError(f"a crowd is crowd[:OBJECTS[:TREES]], got {spec!r}")
    try:
        objects = int(parts[1]) if len(parts) > 1 else 3000
        trees = int(parts[2]) if len(parts) > 2 else 0
    except ValueError as exc:
        raise InputError(f"a crowd is crowd[:OBJECTS[:TREES]] with whole numbers, got "
                         f"{spec!r}") from exc
    return objects, trees


def crowd_columns(f) -> dict:
    """A crowd frame's own ``frames.csv`` columns."""
    return {"fps": 1e3 / f.ms if f.ms > 0 else float("inf"), "lod_ms": f.lod_ms,
            "extractions": f.extractions, "draw_calls": f.draw_calls, "visible": f.visible,
            "exponent": f.exponent, "switches": f.switches}


class CrowdTechnique(Technique):
    """One crowd mode on the viewer's renderer (its GL context and size)."""

    def __init__(self, renderer, crowd, mode: str, target_fps: float | None) -> None:
        super().__init__(renderer)
        from lodsprite.gl.target import RenderTarget
        from lodsprite.manager.engine import CrowdEngine

        self.name = mode
        self.target = RenderTarget(renderer.gl, *renderer.size)
        try:
            self.engine = CrowdEngine(renderer.gl, crowd, self.target, mode,
                                      target_fps=target_fps, fov_y_deg=renderer.fov_y_deg)
        except BaseException:
            self.target.release()
            raise
        self._last = None

    def params(self) -> dict[str, Param]:
        fb = self.engine.feedback
        if self.name == "discrete" or fb.target_fps is None:
            return {}
        return {"fps": Param("fps", fb.target_fps, 2.0, 240.0, 1.25, " fps")}

    def set_param(self, name: str, value: float) -> None:
        if name != "fps" or not self.params():
            raise InputError(f"{self.name} has no parameter {name!r}")
        self.engine.feedback.target_fps = float(value)

    def frame(self, viewpoint: Viewpoint) -> Frame:
        f = self.engine.frame(viewpoint)
        self._last = f
        return Frame(self.name, f.ms, f.triangles, extra=crowd_columns(f))

    def draw_to(self, framebuffer=None) -> None:
        self.renderer.present(self.target.color, (0.0, 0.0, 1.0, 1.0), framebuffer)

    def read_image(self) -> np.ndarray:
        return self.target.read_color()

    def status(self) -> str:
        f = self._last
        if f is None:
            return ""
        return (f"{f.visible} visible, {f.draw_calls} draws, {f.extractions} extractions, "
                f"LOD {f.lod_ms:.1f} ms, p {f.exponent:.2f}")

    def release(self) -> None:
        self.engine.release()
        self.target.release()


def create(renderer, mode: str, crowd=None, target_fps: float | None = None
           ) -> CrowdTechnique:
    """The registry's factory of ``manager``, ``independent`` and ``discrete``: ``crowd``
    (default: the one the scene's spec ``crowd[:OBJECTS[:TREES]]`` names)."""
    if crowd is None:
        from lodsprite.manager.run import CrowdConfig, make_crowd

        objects, trees = parse_crowd(renderer.scene.terrain_spec)
        crowd = make_crowd(CrowdConfig(objects=objects, trees=trees))
    return CrowdTechnique(renderer, crowd, mode, target_fps)


def crowd_techniques(crowd, target_fps: float | None = None) -> dict[str, TechniqueFactory]:
    """The viewer's modes for a crowd: one factory per mode."""
    def factory(mode):
        return lambda renderer: CrowdTechnique(renderer, crowd, mode, target_fps)

    return {mode: factory(mode) for mode in VIEW_MODES}


def crowd_controller(crowd):
    """Home on the walkthrough's first eye, orbiting the crowd's centre, feet on the
    ground (eye height above ``z = 0``)."""
    from lodsprite.manager.scene import EYE_HEIGHT_M, walkthrough
    from lodsprite.viewer.controls import CameraController

    home = walkthrough(crowd, 2).viewpoints[0]
    return CameraController(home, np.zeros(3), 8.0,
                            lambda x, y: np.zeros_like(np.asarray(x, dtype=np.float64)),
                            clearance_m=EYE_HEIGHT_M)
