"""The crowd in the viewer: ``lodsprite view crowd[:OBJECTS[:TREES]]`` walks through the
LODManager's crowd with the viewer's window, controls, HUD and played paths; keys 1-3
switch between the manager, baseline (a) (every object extracts its own LOD) and
baseline (b) (discrete LODs by screen size).  The crowd stands on ``z = 0`` in the
viewer's own z-up world."""

from __future__ import annotations

import numpy as np

from lodsprite.camera import Viewpoint
from lodsprite.errors import InputError
from lodsprite.scene import Scene, SceneKind
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


class CrowdTechnique(Technique):
    """One crowd mode on the viewer's renderer (its GL context and size)."""

    def __init__(self, renderer, crowd, mode: str, target_fps: float | None,
                 **engine: object) -> None:
        super().__init__(renderer)
        from lodsprite.gl.target import RenderTarget
        from lodsprite.manager.engine import CrowdEngine

        self.name = mode
        self.target = RenderTarget(renderer.gl, *renderer.size)
        try:
            self.engine = CrowdEngine(renderer.gl, crowd, self.target, mode,
                                      target_fps=target_fps, fov_y_deg=renderer.fov_y_deg,
                                      **engine)
        except BaseException:
            self.target.release()
            raise
        self._last = None
        self._warm: list = []     # the warm-up's extraction orders
        self._orders: list = []   # each timed frame's
        self._replayed: int | None = None

    def warm_up(self, viewpoint: Viewpoint) -> None:
        self.engine.frame(viewpoint)
        self._warm = list(self.engine.last_orders)

    def decision(self) -> dict:
        """The frame's index and the index buffer each object used (its extraction
        orders are kept by the technique: a replay applies every order up to the frame)."""
        return {"frame": len(self._orders) - 1, "using": self.engine.last_using.copy()}

    def replay(self, viewpoint: Viewpoint, decision: dict) -> np.ndarray:
        i = decision["frame"]
        if self._replayed is None or i <= self._replayed:  # from the state before frame 0
            self.engine.reset_indices()
            pending = self._warm + [o for f in self._orders[:i + 1] for o in f]
        else:
            pending = [o for f in self._orders[self._replayed + 1:i + 1] for o in f]
        self.engine.redraw(viewpoint, decision["using"], pending)
        self._replayed = i
        return self.target.read_color()

    def summary(self, frames: list) -> dict:
        ms = np.array([f.ms for f in frames])
        col = {k: np.array([f.extra[k] for f in frames], dtype=np.float64)
               for k in ("extractions", "draw_calls", "lod_ms", "switches", "exponent")}
        seconds = ms.sum() / 1e3
        return {"extractions_total": int(col["extractions"].sum()),
                "fps_mean": float(len(frames) / seconds),
                "draw_calls_mean": float(col["draw_calls"].mean()),
                "lod_cpu_ms_mean": float(col["lod_ms"].mean()),
                "switches_per_s": float(col["switches"].sum() / seconds),
                "exponent_final": float(col["exponent"][-1]),
                "warmup_extractions": len(self._warm)}

    def outputs(self, result, path) -> dict:
        """Each row's frame rate (``fps = 1000 / ms``, after ``ms``); no files."""
        for row in result.rows:
            row["fps"] = 1e3 / row["ms"]
        result.columns.insert(result.columns.index("ms") + 1, "fps")
        return {}

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
        self._orders.append(list(self.engine.last_orders))
        return f

    def draw_to(self, framebuffer=None) -> None:
        self.renderer.present(self.target.color, (0.0, 0.0, 1.0, 1.0), framebuffer)

    def read_image(self) -> np.ndarray:
        return self.target.read_color()

    def status(self) -> str:
        f = self._last
        if f is None:
            return ""
        x = f.extra
        return (f"{x['visible']} visible, {x['draw_calls']} draws, {x['extractions']} "
                f"extractions, LOD {x['lod_ms']:.1f} ms, p {x['exponent']:.2f}")

    def release(self) -> None:
        self.engine.release()
        self.target.release()


def create(renderer, mode: str, crowd=None, target_fps: float | None = None,
           slots: int = 16, active: int = 300, range_near: float = 5.0,
           range_far: float = 150.0, dist=None) -> CrowdTechnique:
    """The registry's factory of ``manager``, ``independent`` and ``discrete``: ``crowd``
    (default: the scene's object set)."""
    if crowd is None:
        crowd = renderer.scene.objects
    if crowd is None:
        raise InputError("a crowd technique needs a scene with an object set")
    extra = {} if dist is None else {"dist": dist}
    return CrowdTechnique(renderer, crowd, mode, target_fps, slots=slots, active=active,
                          range_near=range_near, range_far=range_far, **extra)


def crowd_techniques(crowd, target_fps: float | None = None) -> dict[str, TechniqueFactory]:
    """The viewer's modes for a crowd: one factory per mode."""
    def factory(mode):
        return lambda renderer: CrowdTechnique(renderer, crowd, mode, target_fps)

    return {mode: factory(mode) for mode in VIEW_MODES}


def crowd_home(crowd):
    """Home on the walkthrough's first eye, orbiting the crowd's centre, feet on the
    ground (eye height above ``z = 0``), a 60° field of view."""
    from lodsprite.manager.scene import EYE_HEIGHT_M, walkthrough
    from lodsprite.scene import CameraHome

    home = walkthrough(crowd, 2).viewpoints[0]
    return CameraHome(home, np.zeros(3), 8.0,
                      lambda x, y: np.zeros_like(np.asarray(x, dtype=np.float64)),
                      clearance_m=EYE_HEIGHT_M, fov_y_deg=60.0)


def open_crowd(spec: str, target_fps: float | None = None, **_: object) -> Scene:
    """The scene of ``crowd[:OBJECTS[:TREES]]``: the crowd as its object set, the camera
    home, ``walk`` (the walkthrough, 600 frames by default) or a JSON path file."""
    from lodsprite.manager.run import CrowdConfig, make_crowd
    from lodsprite.manager.scene import walkthrough
    from lodsprite.paths import load_path_json

    objects, trees = parse_crowd(spec)
    cfg = CrowdConfig(objects=objects, trees=trees, target_fps=target_fps)
    cfg.validate()
    crowd = make_crowd(cfg)

    def paths(name: str, frames: int | None):
        return walkthrough(crowd, frames or 600) if name == "walk" else load_path_json(name)

    return Scene(objects=crowd, home=crowd_home(crowd), paths=paths, mode="manager",
                 label=spec, path_name="walk")


#: The crowd's scene kind (the ``lodsprite.scenes`` entry point ``crowd``).
SCENE_KIND = SceneKind("crowd", lambda spec: spec == "crowd" or spec.startswith("crowd:"),
                       open_crowd)
