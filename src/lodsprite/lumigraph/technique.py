"""The lumigraph in the viewer: each reconstruction method of
:mod:`lodsprite.lumigraph.methods` as a :class:`~lodsprite.technique.Technique`, so that
``lodsprite view LF`` flies round a lumigraph with the same window, controls, HUD,
screenshots and played paths as a terrain (keys 1-8 switch method).

The viewer's world has z up (terrain); a lumigraph's objects have y up.  The technique
turns the viewer's viewpoints by :data:`VIEWER_TO_LUMIGRAPH` before reconstructing, and
:func:`lumigraph_home` places the camera home in front of the object (the front slab),
orbiting its centre; :func:`open_scene` makes a lumigraph folder a scene.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager
from dataclasses import replace
from pathlib import Path

import numpy as np

from lodsprite.camera import Viewpoint, look_at, perspective
from lodsprite.errors import InputError
from lodsprite.scene import LightField, Scene, SceneKind
from lodsprite.techniques import Frame, Param, Technique, TechniqueFactory

#: Viewer world (z up, home to the south) to lumigraph world (y up, front towards +z).
VIEWER_TO_LUMIGRAPH = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
VIEW_METHODS = ("critical", "full", "arbitrary", "fixed", "line", "projective",
                "progressive", "subsample")


def to_lumigraph(vp: Viewpoint) -> Viewpoint:
    """A viewer viewpoint in the lumigraph's world."""
    m = VIEWER_TO_LUMIGRAPH
    return Viewpoint(m @ vp.x, m @ vp.y, m @ vp.z, m @ vp.o)


def viewer_path(path):
    """A camera path in the lumigraph's world as the viewer plays it (in its own)."""
    from lodsprite.paths import CameraPath

    b = VIEWER_TO_LUMIGRAPH.T
    return CameraPath(path.name, tuple(Viewpoint(b @ v.x, b @ v.y, b @ v.z, b @ v.o)
                                       for v in path.viewpoints), path.fov_y_deg)


def method_facts(m) -> dict:
    """A reconstruction method's run facts for a summary: nodes decoded, texture layers and
    MB; the slab switches of six slabs; the critical method's target and cost model."""
    out = {"nodes_decoded": m.loader.decoded, "texture_layers": m.rec.capacity,
           "texture_mb": m.rec.capacity * m.rec.node_bytes / 2 ** 20}
    if hasattr(m, "switches"):
        out["slab_switches"] = m.switches
    if hasattr(m, "target_ms"):
        out.update(target_ms=m.target_ms, scale=dict(m.costs.scale),
                   fetch_ms=m.costs.fetch, decode_ms=m.costs.decode,
                   upload_ms_per_node=m.costs.upload * m.costs.scale["upload"])
    return out


class LumigraphTechnique(Technique):
    """One reconstruction method on the viewer's renderer and GL context."""

    def __init__(self, renderer, folder, method: str, options: dict,
                 depth_correction: bool = True) -> None:
        super().__init__(renderer)
        from lodsprite.gl.lumigraph import ColorMeshDrawer
        from lodsprite.lumigraph.methods import Context, MultiSlabMethod, make_method
        from lodsprite.lumigraph.store import Lumigraph

        self.name = method
        self.lf = Lumigraph(folder)
        gl = renderer.gl
        self.proxy = None
        if depth_correction:
            mesh = self.lf.proxy()
            self.proxy = ColorMeshDrawer(gl, mesh.vertices, mesh.faces, mesh.colors,
                                           mesh.normals)
        ctx = Context(gl, self.lf, 0, renderer.size, self.proxy)
        try:
            self.method = (make_method(method, ctx, **options) if len(self.lf.slabs) == 1
                           else MultiSlabMethod(ctx, method, options))
        except BaseException:
            if self.proxy is not None:
                self.proxy.release()
            raise
        w, h = renderer.size
        self.projection = perspective(renderer.fov_y_deg, w / h, self.lf.header.near,
                                      4 * self.lf.header.far)
        self.index = 0
        self._last = None
        self._warm = False
        self._keep: set[int] = set()  # frames whose image is kept for the replay
        self._snaps: dict = {}
        self._pool: list = []  # GPU copies made by plan_replay, not yet used

    def params(self) -> dict[str, Param]:
        if hasattr(self.method, "target_ms"):
            return {"fps": Param("fps", round(1e3 / self.method.target_ms, 3), 2.0, 240.0,
                                 1.25, " fps")}
        return {}

    def set_param(self, name: str, value: float) -> None:
        if name != "fps" or not hasattr(self.method, "target_ms"):
            raise InputError(f"{self.name} has no parameter {name!r}")
        self.method.target_ms = 1e3 / float(value)

    def warm_up(self, viewpoint: Viewpoint) -> None:
        """Untimed: the first nodes decoded and resident."""
        vp = to_lumigraph(viewpoint)
        if hasattr(self.method, "warm_up"):
            self.method.warm_up(vp, self.projection)
        else:
            self.method.frame(0, vp, self.projection)
        self._warm = True

    def frame(self, viewpoint: Viewpoint) -> Frame:
        if not self._warm:  # the viewer's first frame
            self.warm_up(viewpoint)
        f = self.method.frame(self.index, to_lumigraph(viewpoint), self.projection)
        self.index += 1
        self._last = f
        return replace(f, triangles=self.method.rec.vertex_count // 3)

    def plan_replay(self, frames: set[int]) -> None:
        """The GPU copies of the frames to be replayed, made now (before the warm-up), so
        that between timed frames only a copy runs."""
        from lodsprite.gl.lumigraph import FloatTarget

        for snap in self._pool:  # a plan made before (another run on this technique)
            snap.release()
        self._keep = set(frames)
        # the methods draw at the renderer's size (six slabs make their method on first use)
        self._pool = [FloatTarget(self.renderer.gl, *self.renderer.size) for _ in self._keep]

    def decision(self) -> dict:
        """The frame's index; for a frame to be replayed, its reconstruction is copied on
        the GPU (after the frame's clock stopped, finished before the next frame): a
        method's node cache and loader cannot be rewound, so its image is the decision."""
        i = self.index - 1
        if i in self._keep and self._pool:
            snap = self._pool.pop()
            self.renderer.gl.mgl.copy_framebuffer(snap.fbo, self.method.output.fbo)
            self.renderer.gl.finish()
            self._snaps[i] = snap
        return {"frame": i}

    def replay(self, viewpoint: Viewpoint, decision: dict) -> np.ndarray:
        snap = self._snaps.pop(decision["frame"], None)
        if snap is None:
            raise InputError(f"frame {decision['frame']} was not kept for a replay")
        try:
            return snap.read_rgb8()
        finally:
            snap.release()

    def summary(self, frames: list[Frame]) -> dict:
        return {"images_per_frame_mean": float(np.mean([f.extra["images"] for f in frames])),
                "uploads_per_frame_mean": float(np.mean([f.extra["uploads"] for f in frames])),
                **method_facts(self.method)}

    def reference(self, path) -> AbstractContextManager[Callable]:
        """The ground truth: the object the lumigraph was captured from (its folder's
        ``object.npz``) drawn directly from the same eye, at the same projection
        (:class:`~lodsprite.lumigraph.reference.ObjectReference`), band-limited (``k x k``
        samples a pixel filtered by :func:`lodsprite.bandlimit.resolve`); a folder
        without it is an :class:`~lodsprite.errors.InputError`."""
        return self._object_reference()

    @contextmanager
    def _object_reference(self) -> Iterator[Callable]:
        from lodsprite.bandlimit import resolve
        from lodsprite.gl.reference import SAMPLES
        from lodsprite.lumigraph.reference import object_reference

        w, h = self.renderer.size
        k = max(1, min(SAMPLES, 8192 // max(w, h)))  # band-limited: k x k a pixel, a box
        with object_reference(self.renderer.gl, self.lf.folder, (k * w, k * h),
                              self.projection) as ref:
            yield lambda viewpoint: resolve(ref(to_lumigraph(viewpoint)), k)

    def draw_to(self, framebuffer=None) -> None:
        self.renderer.present(self.method.output.color, (0.0, 0.0, 1.0, 1.0), framebuffer)

    def read_image(self) -> np.ndarray:
        return self.method.output.read_rgb8()

    def status(self) -> str:
        f = self._last
        if f is None:
            return ""
        rec = self.method.rec
        mb = rec.capacity * rec.node_bytes / 2 ** 20
        return (f"{f.extra['images']} node images, {f.extra['uploads']} uploaded; texture "
                f"{len(rec.slot_of)}/"
                f"{rec.capacity} ({mb:.1f} MB); decoded {self.method.loader.decoded}")

    def release(self) -> None:
        for snap in [*self._snaps.values(), *self._pool]:
            snap.release()
        self._snaps.clear()
        self._pool.clear()
        self.method.release()
        if self.proxy is not None:
            self.proxy.release()


def create(renderer, method: str, folder: str = "", depth_correction: bool = True,
           **options) -> LumigraphTechnique:
    """The registry's factory of the ``lumigraph-METHOD`` techniques: ``folder`` (default:
    the scene's)."""
    folder = folder or renderer.scene.lightfield
    if not folder:
        raise InputError("a lumigraph technique needs a scene with a light field")
    return LumigraphTechnique(renderer, folder, method, options, depth_correction)


def lumigraph_techniques(folder, **options) -> dict[str, TechniqueFactory]:
    """The viewer's modes for a lumigraph folder: one factory per method."""
    def factory(name):
        return lambda renderer: LumigraphTechnique(renderer, folder, name, options)

    return {name: factory(name) for name in VIEW_METHODS}


def lumigraph_home(folder):
    """The camera home for the lumigraph: the default path's first eye, orbiting the
    object's centre, in the viewer's (z up) world."""
    from lodsprite.lumigraph.paths import default_path
    from lodsprite.lumigraph.store import Lumigraph
    from lodsprite.scene import CameraHome

    lf = Lumigraph(folder)
    back = VIEWER_TO_LUMIGRAPH.T
    centre = back @ lf.slabs[0].frame[:3, 3]
    eye = back @ default_path(lf, 2).viewpoints[0].o
    d = float(np.linalg.norm(eye - centre))
    return CameraHome(look_at(eye, centre), centre, d / 4.0,
                      min_distance_m=lf.slabs[0].st_distance * 1.5)


def open_lumigraph(folder: str, **_: object) -> Scene:
    """The scene of a lumigraph folder: the light field as its layer, the camera home,
    ``arc`` (the default path: an arc, or an orbit for six slabs; 240 frames by default)
    or a JSON path file in the lumigraph's coordinates, turned into the viewer's."""
    from lodsprite.lumigraph.paths import default_path
    from lodsprite.lumigraph.store import Lumigraph
    from lodsprite.paths import load_path_json

    lf = Lumigraph(folder)  # the header checked now

    def paths(name: str, frames: int | None):
        return viewer_path(default_path(lf, frames or 240) if name == "arc"
                           else load_path_json(name))

    return Scene(lightfields=(LightField(Path(folder)),), home=lumigraph_home(folder),
                 paths=paths, mode="critical", source=Path(folder), path_name="arc")


#: The lumigraph folder's scene kind (the ``lodsprite.scenes`` entry point ``lumigraph``):
#: a folder holding ``lumigraph.json``.
SCENE_KIND = SceneKind("lumigraph", lambda spec: (Path(spec) / "lumigraph.json").is_file(),
                       open_lumigraph)
