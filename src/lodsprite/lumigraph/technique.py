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

import numpy as np

from lodsprite.camera import Viewpoint, look_at, perspective
from lodsprite.errors import InputError
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


class LumigraphTechnique(Technique):
    """One reconstruction method on the viewer's renderer and GL context."""

    def __init__(self, renderer, folder, method: str, options: dict) -> None:
        super().__init__(renderer)
        from lodsprite.gl.lumigraph import ColorMeshRenderer
        from lodsprite.lumigraph.methods import Context, MultiSlabMethod, make_method
        from lodsprite.lumigraph.store import Lumigraph

        self.name = method
        self.lf = Lumigraph(folder)
        mesh = self.lf.proxy()
        gl = renderer.gl
        self.proxy = ColorMeshRenderer(gl, mesh.vertices, mesh.faces, mesh.colors,
                                       mesh.normals)
        ctx = Context(gl, self.lf, 0, renderer.size, self.proxy)
        try:
            self.method = (make_method(method, ctx, **options) if len(self.lf.slabs) == 1
                           else MultiSlabMethod(ctx, method, options))
        except BaseException:
            self.proxy.release()
            raise
        w, h = renderer.size
        self.projection = perspective(renderer.fov_y_deg, w / h, self.lf.header.near,
                                      4 * self.lf.header.far)
        self.index = 0
        self._last = None

    def params(self) -> dict[str, Param]:
        if hasattr(self.method, "target_ms"):
            return {"fps": Param("fps", round(1e3 / self.method.target_ms, 3), 2.0, 240.0,
                                 1.25, " fps")}
        return {}

    def set_param(self, name: str, value: float) -> None:
        if name != "fps" or not hasattr(self.method, "target_ms"):
            raise InputError(f"{self.name} has no parameter {name!r}")
        self.method.target_ms = 1e3 / float(value)

    def frame(self, viewpoint: Viewpoint) -> Frame:
        vp = to_lumigraph(viewpoint)
        if self.index == 0:  # untimed: the first nodes decoded and resident
            if hasattr(self.method, "warm_up"):
                self.method.warm_up(vp, self.projection)
            else:
                self.method.frame(0, vp, self.projection)
        f = self.method.frame(self.index, vp, self.projection)
        self.index += 1
        self._last = f
        return Frame(f.kind, f.ms, self.method.rec.vertex_count // 3)

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
        return (f"{f.images} node images, {f.uploads} uploaded; texture {len(rec.slot_of)}/"
                f"{rec.capacity} ({mb:.1f} MB); decoded {self.method.loader.decoded}")

    def release(self) -> None:
        self.method.release()
        self.proxy.release()


def create(renderer, method: str, folder: str = "", **options) -> LumigraphTechnique:
    """The registry's factory of the ``lumigraph-METHOD`` techniques: ``folder`` (default:
    the scene's)."""
    folder = folder or renderer.scene.lightfield
    if not folder:
        raise InputError("a lumigraph technique needs a scene with a light field")
    return LumigraphTechnique(renderer, folder, method, options)


def lumigraph_techniques(folder, **options) -> dict[str, TechniqueFactory]:
    """The viewer's modes for a lumigraph folder: one factory per method."""
    def factory(name):
        return lambda renderer: LumigraphTechnique(renderer, folder, name, options)

    return {name: factory(name) for name in VIEW_METHODS}


def lumigraph_home(folder):
    """The camera home for the lumigraph: the default path's first eye, orbiting the
    object's centre, in the viewer's (z up) world."""
    from lodsprite.lumigraph.run import default_path
    from lodsprite.lumigraph.store import Lumigraph
    from lodsprite.scene import CameraHome

    lf = Lumigraph(folder)
    back = VIEWER_TO_LUMIGRAPH.T
    centre = back @ lf.slabs[0].frame[:3, 3]
    eye = back @ default_path(lf, 2).viewpoints[0].o
    d = float(np.linalg.norm(eye - centre))
    return CameraHome(look_at(eye, centre), centre, d / 4.0,
                      min_distance_m=lf.slabs[0].st_distance * 1.5)


def open_scene(folder: str, **_: object):
    """The scene of a lumigraph folder: the light field as its layer, the camera home,
    ``arc`` (the default path: an arc, or an orbit for six slabs; 240 frames by default)
    or a JSON path file in the lumigraph's coordinates, turned into the viewer's."""
    from lodsprite.lumigraph.run import default_path
    from lodsprite.lumigraph.store import Lumigraph
    from lodsprite.paths import load_path_json
    from lodsprite.scene import Scene

    lf = Lumigraph(folder)  # the header checked now

    def paths(name: str, frames: int | None):
        return viewer_path(default_path(lf, frames or 240) if name == "arc"
                           else load_path_json(name))

    return Scene(lightfield=str(folder), home=lumigraph_home(folder), paths=paths,
                 mode="critical")
