"""A whole scene in one frame: terrain, objects and light fields composited by depth
(issue 23; Chen, Swan & Kaufman 1999 built LOD-sprite for a battlefield of terrain and
entities and note it suits architectures that decompose a scene into layers).

:class:`LayeredTechnique` (registered as ``scene``) draws, every frame, into the
renderer's one framebuffer and depth buffer:

1. the terrain by any terrain technique (:class:`~lodsprite.layered.layers.
   TerrainLayer`: ``full``, ``lod``, ``adaptive``, ``sprite``, ``sprite-adaptive``);
2. the objects by the LODManager engine (:class:`~lodsprite.layered.objects.
   ObjectsLayer`), poses from the world at the frame's time (a crowd stands still);
3. the placed light fields (:class:`~lodsprite.layered.lightfields.LightFieldLayer`),
   each reconstructed in its own target and composited through its proxy's depth.

It draws the layers the scene has (:class:`~lodsprite.scene.Scene`: the renderer's, or
the one given): a crowd alone is drawn on its own ground through its own projection.

What LOD-sprite's keyframes hold (``keyframe_holds``): ``static`` (the default) renders the
static objects (``walk_mps = 0``) into every keyframe after its terrain, so spriteframes
warp them with the terrain and a frame draws only the moving objects, depth tested
against the keyframe's depth warped under the spriteframe (whole keyframes,
:class:`~lodsprite.gl.key_depth.KeyDepthPass`); ``terrain`` keeps keyframes terrain only
and draws every object every frame.  Light fields are view dependent: never in keyframes.
``benchmarks/scene_layers.py`` measures the two (docs/scenes.md).

Per frame ``Frame.extra`` holds ``ms_terrain``, ``ms_objects``, ``ms_lightfields`` (each
layer between two ``ctx.finish()``), ``knob_<layer>`` (each layer's setting),
``triangles_<layer>`` and the
budget's ``predicted_ms_<layer>``; the budget (:class:`~lodsprite.scene.budget.
LayerBudget`, ``schedule`` ``none`` | ``scheduler`` | ``independent`` under
``target_fps``) turns the knobs before each frame.  ``ground_truth=True`` is the
full-detail reference: full-resolution terrain, full meshes (LOD exponent 0), every
lumigraph node.

:func:`render_scene` is ``lodsprite render --scene FILE``: the technique over a scene
file's world along its ``[view]`` path, ``frames.csv`` with the per-layer columns and
``summary.json`` with the core keys and ``share_<layer>``; with ``ground_truth`` every frame
replayed untimed against the full-detail scene (:func:`reference`).
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from lodsprite.errors import InputError
from lodsprite.layered.layers import Layer, TerrainLayer, layer_work, timed
from lodsprite.techniques.base import Frame, Param, Technique

if TYPE_CHECKING:
    from lodsprite.api import Renderer
    from lodsprite.camera import Viewpoint
    from lodsprite.paths import CameraPath
    from lodsprite.scene import Scene

#: The time between frames (s): frame ``i`` shows the world at ``i * FRAME_S``.
FRAME_S = 1.0 / 30.0
KEYFRAME_HOLDS = ("static", "terrain")
KEYFRAMES = ("inline", "worker")
#: The terrain modes whose keyframes ``keyframes="worker"`` renders in the worker (with the
#: static objects); the others draw as they do inline.
REUSED = ("sprite", "sprite-adaptive")
#: ``render --scene``'s image size when neither the command nor ``[view]`` gives one.
DEFAULT_SIZE = (512, 512)
#: Objects whose LOD the manager updates a frame (its active list).
ACTIVE = 300


class LayeredTechnique(Technique):
    """A scene's layers in one frame (module doc); ``scene`` default: the renderer's."""

    plays_in_time = False  # the world advances one frame_s a frame, whatever the clock

    name = "scene"

    def __init__(self, renderer: Renderer, scene: Scene | None = None,
                 terrain_mode: str = "adaptive", schedule: str = "none",
                 target_fps: float | None = None, keyframe_holds: str = "static",
                 exponent: float = 1.0, nodes: int = 8, ground_truth: bool = False,
                 frame_s: float = FRAME_S, active: int | None = ACTIVE,
                 keyframes: str = "inline", **terrain_options: Any) -> None:
        super().__init__(renderer)
        from lodsprite.layered.lightfields import LightFieldLayer
        from lodsprite.layered.objects import ObjectsLayer
        from lodsprite.scene.budget import LayerBudget

        if keyframe_holds not in KEYFRAME_HOLDS:
            raise InputError(f"unknown keyframe_holds {keyframe_holds!r}: use one of "
                             f"{', '.join(KEYFRAME_HOLDS)}")
        if keyframes not in KEYFRAMES:
            raise InputError(f"unknown keyframes {keyframes!r}: use one of "
                             f"{', '.join(KEYFRAMES)}")
        if ground_truth:
            terrain_mode, exponent, schedule = "full", 0.0, "none"
        if terrain_mode not in REUSED:  # keyframes are LOD-sprite's (the window's default)
            keyframes = "inline"
        scene = renderer.scene if scene is None else scene
        placed = tuple(lf for lf in scene.lightfields if lf.placed)
        if scene.hf is None and scene.objects is None:
            raise InputError("the scene technique draws terrain and objects: this scene "
                             "has neither (a light field alone: a lumigraph technique)")
        self.scene, self.frame_s, self.keyframe_holds = scene, float(frame_s), keyframe_holds
        self.keyframes = keyframes
        self.count = 0 if scene.objects is None else len(scene.objects)
        self.budget = LayerBudget(schedule, None if target_fps is None else 1e3 / target_fps)
        self.layers: list[Layer] = []
        self.terrain: TerrainLayer | None = None
        self.objects: ObjectsLayer | None = None
        self.lightfields: LightFieldLayer | None = None
        try:
            if scene.hf is not None:
                self.terrain = (TerrainLayer(renderer, terrain_mode, **terrain_options)
                                if keyframes == "inline" else
                                _keyframed(renderer, scene, terrain_mode, exponent,
                                           terrain_options))
                self.layers.append(self.terrain)
            # the LODManager's active list (§4.2): ``active`` objects' LODs updated a
            # frame (300, the crowd's default; None: every object, as the reference)
            if self.count:
                self.objects = ObjectsLayer(renderer, scene.objects, exponent,
                                            None if ground_truth else active)
                self.layers.append(self.objects)
            if placed:
                self.lightfields = LightFieldLayer(renderer, placed, scene.hf,
                                                   "full" if ground_truth else "arbitrary",
                                                   nodes)
                self.layers.append(self.lightfields)
        except BaseException:
            self.release()
            raise
        if not self.layers:
            raise InputError("the scene has nothing to draw (no terrain, no objects)")
        self.static_in_keyframes = (self.objects is not None and self.terrain is not None
                                    and (keyframes == "worker" or keyframe_holds == "static"
                                         and self.terrain.keyframe_hook(
                                             self.objects.draw_static)))
        if self.static_in_keyframes:
            self.objects.subset = self.objects.moving
        self.index = 0
        self._last: dict[str, Any] = {}
        self._decided = True

    def projection(self, viewpoint: Viewpoint) -> np.ndarray:
        """The frame's projection ``(4, 4)``: the terrain technique's (without terrain,
        the object set's own)."""
        if self.terrain is None:
            return self.objects.projection(viewpoint)
        return self.terrain.projection(viewpoint)

    def warm_up(self, viewpoint: Viewpoint) -> None:
        proj = self.projection(viewpoint)
        for layer in sorted(self.layers, key=lambda x: x is self.terrain):  # objects first
            layer.warm_up(viewpoint, proj)
        self.renderer.gl.finish()

    def plan_replay(self, frames: set[int]) -> None:
        if self.terrain is not None:
            self.terrain.plan_replay(frames)
        if self.objects is not None:
            self.objects.recording = bool(frames)
        if self.lightfields is not None:
            self.lightfields.plan_replay(frames)

    def frame(self, viewpoint: Viewpoint) -> Frame:
        t = self.index * self.frame_s
        t0 = time.perf_counter()
        self.budget.before([layer.control() for layer in self.layers])
        proj = self.projection(viewpoint)
        finish = self.renderer.gl.finish
        drawn = {layer.name: timed(finish, lambda la=layer: la.draw(viewpoint, t, proj))
                 for layer in self.layers}
        ms = (time.perf_counter() - t0) * 1e3
        knobs = {layer.name: layer.control().value for layer in self.layers}
        extra: dict[str, Any] = {"t": t}
        work = {}
        for name, f in drawn.items():
            extra[f"ms_{name}"] = f.ms
            extra[f"knob_{name}"] = knobs[name]
            extra[f"triangles_{name}"] = f.triangles
            work[name], own = layer_work(f)
            extra.update(own)
        extra.update(self.budget.after({n: (knobs[n], f.ms, work[n])
                                        for n, f in drawn.items()}, ms))
        self._last, self._decided = {"t": t}, False  # decisions: after the clock
        self.index += 1
        terrain = drawn.get("terrain")
        kind = "scene" if terrain is None else terrain.extra.get("terrain_kind", "scene")
        return Frame(kind, ms, sum(f.triangles for f in drawn.values()),
                     float("nan") if terrain is None else terrain.error_px, extra)

    def decision(self) -> dict[str, Any]:
        """The last frame's decision, every layer's taken here, once, after the frame's
        clock stopped (a layer's may read back: the light fields keep their
        reconstructions for the replay)."""
        if not self._decided:
            self._last.update({layer.name: layer.decision() for layer in self.layers})
            self._decided = True
        return self._last

    def replay(self, viewpoint: Viewpoint, decision: dict[str, Any]) -> np.ndarray:
        proj = self.projection(viewpoint)
        t = decision["t"]
        if self.objects is not None:
            self.objects.replaying = decision  # keyframes redraw their recorded objects
        try:
            for layer in self.layers:
                layer.replay(viewpoint, t, proj, decision[layer.name])
        finally:
            if self.objects is not None:
                self.objects.replaying = None
        self.renderer.gl.finish()
        return self.read_image()

    def summary(self, frames: list[Frame]) -> dict[str, Any]:
        """The budget's ``share_<layer>`` (fraction of frame ms), ``schedule``,
        ``target_ms``; mean ms per layer; the terrain mode and what keyframes held."""
        out: dict[str, Any] = {**self.budget.summary(),
                               "terrain_mode": getattr(self.terrain, "mode", None),
                               "keyframe_holds": ("static" if self.static_in_keyframes
                                                  else "terrain"),
                               "keyframes_at": self.keyframes,
                               "layers": [layer.name for layer in self.layers],
                               "instances": self.count,
                               "lightfields": self._placed()}
        for layer in self.layers:
            col = [f.extra[f"ms_{layer.name}"] for f in frames]
            out[f"mean_ms_{layer.name}"] = float(np.mean(col)) if col else float("nan")
        out["keyframes"] = int(sum(f.kind == "keyframe" for f in frames))
        return {**out, **self.terrain.summary()} if hasattr(self.terrain, "summary") else out

    def reference(self, path: CameraPath) -> AbstractContextManager[Callable]:
        """The full-detail scene along ``path`` (:func:`reference`): full-resolution
        terrain, full meshes, every lumigraph node, the world at each frame's time."""
        return _full_detail(self.renderer, self.scene, path, self.frame_s)

    def _placed(self) -> int:
        return 0 if self.lightfields is None else len(self.lightfields.items)

    def params(self) -> dict[str, Param]:
        technique = getattr(self.terrain, "technique", None)
        return {} if technique is None else technique.params()

    def set_param(self, name: str, value: float) -> None:
        technique = getattr(self.terrain, "technique", None)
        if technique is None:
            raise InputError(f"the scene technique has no parameter {name!r} here")
        technique.set_param(name, value)

    def read_image(self) -> np.ndarray:
        return self.renderer.target.read_color()

    def status(self) -> str:
        e = self._last
        return (f"scene t {e.get('t', 0.0):.1f} s, {self.count} objects, "
                f"{self._placed()} light fields")

    def release(self) -> None:
        for layer in reversed(self.layers):
            layer.release()
        self.layers = []


def _keyframed(renderer: Renderer, scene: Scene, mode: str, exponent: float,
               options: dict[str, Any]) -> Layer:
    """The terrain and static objects from the scene's keyframe worker
    (:class:`~lodsprite.layered.reuse.KeyframedTerrain`): LOD-sprite's ``mode`` over a
    scene file's world (handed to the worker); ``sprite-adaptive``'s keyframes by the
    adaptive renderer (its options among ``options``), ``sprite``'s at full resolution."""
    from lodsprite import techniques
    from lodsprite.layered.reuse import KeyframedTerrain
    from lodsprite.layered.scene_keys import SceneKeys
    from lodsprite.sprite.policy import DEFAULT_EPSILON_PX
    from lodsprite.techniques.defaults import terrain_defaults
    from lodsprite.terrain.lod import DEFAULT_COARSE

    if scene.source is None or not Path(scene.source).is_file():
        raise InputError("--keyframes worker in a scene needs a scene file")
    own = {o.name for o in techniques.get("adaptive").options}
    adaptive = mode == "sprite-adaptive"
    keys = SceneKeys(str(scene.source), "adaptive" if adaptive else "full",
                     {k: v for k, v in options.items()
                      if adaptive and k in own and v is not None})
    epsilon, lod = options.get("epsilon"), options.get("lod")  # None: the defaults
    if options.get("key_scale") not in (None, 1.0):
        raise InputError("a scene's keyframe worker renders at keyframe scale 1: "
                         "--key-scale needs --keyframes inline in a scene")
    stride = None
    if options.get("proxy") not in (None, "geometry"):  # the stride given, or the default
        stride = (options.get("depth_stride")
                  or terrain_defaults(scene.terrain_spec)["depth_stride"])
    layer = KeyframedTerrain(renderer, keys, float(epsilon or DEFAULT_EPSILON_PX),
                             int(lod or DEFAULT_COARSE), exponent, depth_stride=stride,
                             pair=bool(options.get("pair")))
    layer.sprite.use_depth_proxy(options.get("proxy") or "geometry")
    return layer


def reference(renderer: Renderer, scene: Scene, path: CameraPath, frame_s: float = FRAME_S,
              samples: int | None = None
              ) -> tuple[Callable[[Viewpoint], np.ndarray], Callable[[], None]]:
    """The full-detail reference of a run along ``path``, band-limited: ``(viewpoint ->
    image, release)``.  The full-detail scene is drawn on the renderer's context at
    ``samples`` x ``samples`` its size (default :data:`~lodsprite.gl.reference.SAMPLES`,
    fewer where that passes 8192 pixels a side) and filtered down
    (:func:`lodsprite.bandlimit.resolve`: a box a pixel, in linear light); a viewpoint's
    time is its index along ``path`` (matched by identity) times ``frame_s``."""
    from lodsprite.api import Renderer
    from lodsprite.bandlimit import resolve
    from lodsprite.gl.reference import SAMPLES

    w, h = renderer.size
    k = max(1, min(SAMPLES if samples is None else int(samples), 8192 // max(w, h)))
    big = Renderer(scene, (k * w, k * h), renderer.fov_y_deg, ctx=renderer.gl.mgl)
    try:
        ref = LayeredTechnique(big, scene, ground_truth=True, frame_s=frame_s)
        ref.warm_up(path.viewpoints[0])
    except BaseException:
        big.release()
        raise
    index = {id(vp): i for i, vp in enumerate(path.viewpoints)}

    def image(viewpoint: Viewpoint) -> np.ndarray:
        ref.index = index.get(id(viewpoint), 0)
        ref.frame(viewpoint)
        return resolve(ref.read_image(), k)

    def release() -> None:
        ref.release()
        big.release()

    return image, release


@contextmanager
def _full_detail(renderer: Renderer, scene: Scene, path: CameraPath, frame_s: float
                 ) -> Iterator[Callable[[Viewpoint], np.ndarray]]:
    image, release = reference(renderer, scene, path, frame_s)
    try:
        yield image
    finally:
        release()


def create(renderer: Renderer, world: Scene | None = None, **options: Any
           ) -> LayeredTechnique:
    """The registry's factory of ``scene``: the layers of ``world`` (a scene; default: the
    renderer's)."""
    return LayeredTechnique(renderer, world, **options)


def with_view_fov(cam: CameraPath, scene: Scene) -> CameraPath:
    """``cam`` with the vertical field of view of a scene file's ``[view] fov`` (degrees),
    if the file gives one."""
    from dataclasses import replace

    fov = None if scene.view is None else scene.view.fov
    return cam if fov is None else replace(cam, fov_y_deg=float(fov))


def render_scene(scene_file: str | os.PathLike, out_dir: str | os.PathLike,
                 size: tuple[int, int] | None = None, frames: int | None = None,
                 terrain_mode: str | None = None,
                 target_fps: float | None = None, ground_truth: bool = False,
                 flip: bool = False, path: str | None = None, progress=None,
                 measure=None, **options: Any) -> dict[str, Any]:
    """Run the ``scene`` technique over the world of ``scene_file`` along its ``[view]``
    path (or ``path``) and write the run to ``out_dir``; returns the summary.
    ``terrain_mode`` left None is the file's ``[terrain] mode`` (else ``adaptive``), and
    the file's ``[terrain.options]`` go to it under the ``options`` given here.
    ``target_fps`` runs the budget's scheduler (none without).  ``size`` and
    ``target_fps`` left None are the file's ``[view]`` values (else 512x512 and none); its
    ``fov`` replaces the path's.  ``measure`` (a :class:`~lodsprite.driver.Measure`):
    what else the run measures and keeps (saved frames, a video, a quality stride), in
    place of ``ground_truth`` and ``flip``."""
    from lodsprite import techniques
    from lodsprite.driver import Measure
    from lodsprite.run import run_scene
    from lodsprite.scene.world import load_scene_file
    from lodsprite.techniques.scenes import checked

    if target_fps is not None and not target_fps > 0:
        raise InputError(f"--target-fps must be > 0, got {target_fps}")
    scene = checked(load_scene_file(scene_file))  # the file read and checked once
    view = scene.view
    terrain_mode = terrain_mode or scene.terrain_mode or "adaptive"
    options = {**scene.terrain_options, **options}
    size = size or view.size_px() or DEFAULT_SIZE
    target_fps = target_fps if target_fps is not None else view.target_fps
    cam = with_view_fov(scene.path(path or view.path, frames), scene)
    own = {o.name for o in techniques.get("scene").options}
    result = run_scene(
        scene, "scene",
        {"terrain_mode": terrain_mode,
         "schedule": "scheduler" if target_fps is not None else "none",
         "target_fps": target_fps,
         "terrain_options": {k: v for k, v in options.items() if k not in own},
         **{k: v for k, v in options.items() if k in own}},
        cam, size, Path(out_dir), measure or Measure(ground_truth, flip=flip),
        progress=progress,
        summary={"mode": "scene", "scene": str(scene_file), "terrain": scene.terrain_spec,
                 "path": path or view.path, "size": list(size)})
    return result.summary
