"""A scene's static layers in keyframes from a worker process (issue 32, must-have 5; Swan
et al. 2002's LOD server): the terrain and the static objects rendered into LOD-sprite
keyframes by a process with its own GL context, from predicted viewpoints.

The process is a :class:`~lodsprite.sprite.keyframe_worker.KeyframeWorker` (the same
client end, protocol, predictor and shared-memory answers as the terrain's worker) whose
handler is :func:`scene_key_handler`: it is handed the display's scene (its terrain's
heights and texture through a shared-memory segment, as the terrain's worker is, the rest
pickled: the same instances as the display's, not read from the file again), makes a
:class:`~lodsprite.api.Renderer` of the display's size and field of view and, for each
request ``(viewpoint, predicted, requested_at, tolerance, exponent)``, renders into a
keyframe slot (the guard-band widened projection, as inline keyframes): the terrain,
by the adaptive renderer at the keyframe tolerance ``tolerance`` (px) over a store, or
at full resolution in memory (``terrain="full"``), then the static objects (``walk_mps
= 0``) by the LODManager engine at the LOD exponent ``exponent``.  It answers the
keyframe's colour and its *full* z-buffer (terrain and static objects: what the display's
moving layers are depth-tested against, :mod:`lodsprite.gl.key_depth`) and the error
metric's ``C'`` of the display's coarse level (Chen et al. 1999 Eq. 2).  A server's
renderers (:class:`SceneKeyframes` with ``SceneKeys.lightfields``) draw the light fields
in view into the keyframe too, composited by their proxies' depth: a web page draws none
itself.
"""

from __future__ import annotations

import pickle
import time
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from lodsprite.errors import InputError
from lodsprite.procs import lower_priority
from lodsprite.sprite.keyframe_process import (
    checked_spread,
    copy_shared,
    keyframe_answer,
)
from lodsprite.sprite.keyframe_worker import KeyframeWorker, share_arrays, start_ready
from lodsprite.sprite.worker_settings import WorkerSettings
from lodsprite.workers import ProcessWorker

if TYPE_CHECKING:
    from multiprocessing.shared_memory import SharedMemory

    from lodsprite.camera import Projection, Viewpoint
    from lodsprite.scene import Scene

FACTORY = "lodsprite.layered.scene_keys:scene_key_handler"
KEY_TERRAIN = ("full", "adaptive")


@dataclass(frozen=True)
class SceneKeys:
    """What the scene's worker draws: ``scene_file`` (the display's scene's file),
    ``terrain`` (``full``:
    the in-memory terrain at full resolution; ``adaptive``: the adaptive renderer, over a
    store), ``terrain_options`` (the adaptive technique's own) and the objects' ``active``
    count (None: every static object's LOD updated each keyframe); ``lightfields``: the light
    fields in view drawn into each keyframe too, from that many nodes each (0: none, the
    window's worker: the display draws them every frame; a server's renderers for a page,
    which draws none itself)."""

    scene_file: str
    terrain: str = "full"
    terrain_options: dict[str, Any] = field(default_factory=dict)
    active: int | None = None
    lightfields: int = 0


def scene_starter(keys: SceneKeys):
    """A ``start(scene, settings, ready_s)`` for :class:`KeyframeWorker`: the process of
    :func:`scene_key_handler`, ready, or :class:`~lodsprite.workers.WorkerUnavailable`."""
    if keys.terrain not in KEY_TERRAIN:
        raise InputError(f"the scene's keyframes draw terrain {' or '.join(KEY_TERRAIN)}, "
                         f"not {keys.terrain!r}")

    def start(scene: Scene, settings: WorkerSettings, ready_s: float) -> ProcessWorker:
        shm, layout, rest = share_scene(scene)
        return start_ready(FACTORY, {"keys": keys, "layout": layout, "rest": rest}, shm,
                           settings, ready_s, "scene-keyframes")

    return start


def share_scene(scene: Scene) -> tuple[SharedMemory, dict[str, tuple], tuple]:
    """The display's ``scene`` for the worker process: its terrain's heights
    (``(rows, cols) float32`` metres) and texture (``(H, W, 3) uint8``) copied into a new
    shared-memory segment (:func:`~lodsprite.sprite.keyframe_worker.share_arrays`; the
    caller closes and unlinks it), and the rest of the scene without them (its world's
    ground field and its path maker left out too), for :func:`received_scene`.  Returns
    ``(segment, layout, rest)``."""
    from lodsprite.scene.world import World

    hf = scene.hf
    arrays = {"heights": hf.heights}
    if scene.texture is not None:
        arrays["texture"] = scene.texture
    objects = scene.objects
    if isinstance(objects, World):
        objects = replace(objects, ground_field=None)
    rest = replace(scene, hf=None, texture=None, objects=objects, paths=None)
    shm, layout = share_arrays({k: np.ascontiguousarray(a) for k, a in arrays.items()})
    return shm, layout, (rest, (hf.dx, hf.dy, hf.name, dict(hf.meta)))


def received_scene(shm_name: str, layout: dict, rest: tuple) -> Scene:
    """The scene :func:`share_scene` handed over, made again in the worker process: the
    same heights, texture and objects, standing on the same ground."""
    from lodsprite.scene.world import World
    from lodsprite.terrain import HeightField

    arrays = copy_shared(shm_name, layout)
    scene, (dx, dy, name, meta) = rest
    hf = HeightField(arrays["heights"], dx, dy, name, meta)
    objects = scene.objects
    if isinstance(objects, World):
        objects = replace(objects, ground_field=hf)
    return replace(scene, hf=hf, texture=arrays.get("texture"), objects=objects)


class SceneKeyframeWorker(KeyframeWorker):
    """The client end (:class:`KeyframeWorker`) of :func:`scene_key_handler`'s process;
    :attr:`tolerance` and :attr:`exponent` go with each request, and :attr:`timings`
    lists ``(tolerance, render ms)`` of every keyframe delivered."""

    def __init__(self, scene: Scene, settings: WorkerSettings, keys: SceneKeys,
                 ready_s: float = 120.0) -> None:
        super().__init__(scene, settings, ready_s, start=scene_starter(keys))
        self.tolerance, self.exponent = 1.0, 1.0
        self.timings: list[tuple[float, float]] = []
        self._asked: float | None = None

    def request(self) -> None:
        if self.busy:
            return
        self.request_extra = (self.tolerance, self.exponent)
        self._asked = self.tolerance
        super().request()

    def poll(self):
        got = super().poll()
        if got is not None:
            self.timings.append((float(self._asked or self.tolerance), got.render_ms))
        return got


# ----------------------------------------------------------------- the worker process


def scene_key_handler(keys: SceneKeys, settings: WorkerSettings, shm_name: str,
                      layout: dict, rest: tuple):
    """The process's request handler (:mod:`lodsprite.workers`' factory): its priority
    lowered, the display's scene received (:func:`received_scene`), the renderer and
    layers made."""
    lower_priority(settings.nice)
    gl = _SceneKeysGL(received_scene(shm_name, layout, rest), keys, settings)

    def answer(meta: bytes, data: bytes) -> tuple[bytes, bytes]:
        vp, predicted, asked, spread, tolerance, exponent = pickle.loads(meta)
        return gl.render(vp, predicted, asked, float(tolerance), float(exponent),
                         checked_spread(spread))

    return answer


class SceneKeyframes:
    """A scene's static layers drawn into LOD-sprite keyframes (module doc): a renderer of
    the keyframe ``settings``' size and field of view over ``scene`` (on ``ctx``, a
    moderngl context to share, or its own), the terrain (full resolution, or adaptive at
    the tolerance each keyframe asks), the static objects at the LOD exponent asked.
    Used by the window's scene worker and by a server's renderers."""

    def __init__(self, scene: Scene, keys: SceneKeys, s: WorkerSettings, ctx=None) -> None:
        from lodsprite.api import Renderer
        from lodsprite.gl.sprite import SpriteDrawer
        from lodsprite.layered.layers import TerrainLayer
        from lodsprite.layered.objects import ObjectsLayer

        self.renderer = Renderer(scene, s.size, s.fov_y_deg, ctx)
        self.terrain = self.objects = self.sprite = self.lights = None
        try:
            self.sprite = SpriteDrawer(self.renderer.terrain_gl.drawer, s.lod, s.visibility,
                                       border=s.border, guard_px=s.guard_px,
                                       key_scale=s.key_scale)
            if keys.terrain == "adaptive":
                self.terrain = TerrainLayer(self.renderer, "adaptive", **keys.terrain_options)
                self.sprite.keyframe_drawer = self.terrain.technique.terrain.render_into
            if scene.objects is not None and not scene.objects.moving().all():
                self.objects = ObjectsLayer(self.renderer, scene.objects, 1.0, keys.active)
            if keys.lightfields and scene.lightfields:
                from lodsprite.layered.lightfields import LightFieldLayer

                self.lights = LightFieldLayer(self.renderer, scene.lightfields, scene.hf,
                                              "arbitrary", keys.lightfields)
            if self.objects is not None or self.lights is not None:
                self.sprite.after_keyframe = self._static
        except BaseException:
            self.release()
            raise
        self._warm = False

    def _static(self, viewpoint: Viewpoint, projection: Projection, target) -> None:
        if self.objects is not None:
            self.objects.draw_static(viewpoint, projection.matrix(), target.fbo)
        if self.lights is not None:
            self.lights.draw_into(viewpoint, projection.matrix(), target.fbo)

    def keyframe(self, vp: Viewpoint, tolerance: float | None = None, exponent: float = 1.0,
                 spread: float = 1.0, t0: float | None = None):
        """The keyframe at ``vp`` drawn and finished: the terrain (adaptive at
        ``tolerance`` px, None: its own default), the static objects at LOD exponent
        ``exponent``; returns ``(GLKeyframe, frame projection)``."""
        t0 = time.perf_counter() if t0 is None else t0
        if self.terrain is not None:
            if not self._warm:  # the first view's tiles resident (as a run's warm-up)
                self.terrain.technique.warm_up(vp)
            if tolerance is not None:
                self.terrain.technique.terrain.set_sse(tolerance)
            self.terrain.technique.terrain.prefetch()
        if self.objects is not None:
            self.objects.set_exponent(exponent)
        self._warm = True
        frame_projection = self.renderer.projection(vp)
        self.sprite.render_keyframe(vp, t0, frame_projection, spread=spread)
        self.renderer.gl.finish()
        return self.sprite.keyframe, frame_projection

    def deficit_px(self) -> float:
        """Pixels of error the adaptive terrain lacks while its tiles stream (0 drawn
        at full resolution)."""
        if self.terrain is None:
            return 0.0
        return float(self.terrain.technique.terrain.deficit_px())

    def release(self) -> None:
        for part in (self.lights, self.objects, self.terrain):
            if part is not None:
                part.release()
        self.lights = self.objects = self.terrain = None
        if self.sprite is not None:
            self.sprite.release()
            self.sprite = None
        self.renderer.release()


class _SceneKeysGL(SceneKeyframes):
    """The worker process's keyframes, answered with the display's ``C'``."""

    def __init__(self, scene: Scene, keys: SceneKeys, s: WorkerSettings) -> None:
        from lodsprite.sprite.metric import ErrorMetric

        super().__init__(scene, keys, s)
        self.metric = ErrorMetric.for_level(scene.hf, s.lod, s.resampling)
        self.estimate_stride = s.estimate_stride

    def render(self, vp: Viewpoint, predicted: bool, asked: float, tolerance: float,
               exponent: float, spread: float = 1.0) -> tuple[bytes, bytes]:
        t0 = time.perf_counter()
        key, frame_projection = self.keyframe(vp, tolerance, exponent, spread, t0)
        c_prime = self.metric.reproject(vp.o, key.projection.matrix() @ vp.view_matrix(),
                                        key.target.size)
        return keyframe_answer(self.sprite, "full", {
            "viewpoint": vp, "frame_projection": frame_projection, "c_prime": c_prime,
            "requested_at": asked, "predicted": predicted}, t0, self.estimate_stride)
