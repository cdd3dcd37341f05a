"""The light-field layer of a scene: each placed lumigraph (Sloan, Cohen & Gortler 1997)
reconstructed into its own target and composited into the frame by its proxy's depth.

Placement: a lumigraph's world is ``+y`` up (:data:`~lodsprite.lumigraph.technique.
VIEWER_TO_LUMIGRAPH`); its object (the proxy mesh's bounds) is turned ``+y -> +z``,
scaled uniformly to ``height_m``, its base centre put on the ground at ``position``:
``M = T(x, y, ground) · s · B · T(-base)`` (lumigraph -> world, :func:`placement`).  The
frame's viewpoint is taken into the lumigraph's world by ``M``'s inverse (rotation and
eye; the scale moves into the projection's depth terms, so the reconstruction's pixels
and window depth are the frame's).

Reconstruction: the ``arbitrary`` method (the ``nodes`` nearest the eye, the layer's knob,
its node budget) or, for the full-detail reference, ``full`` (every node); several slabs
through :class:`~lodsprite.lumigraph.methods.MultiSlabMethod`.  Each reconstruction has
a small target of its own (half the frame's side, :data:`TARGET_SCALE`) through the
frame's projection cropped to the placed proxy's screen rectangle (:func:`crop`): an
object smaller than half the frame gets more texels than its screen pixels, a larger one
fewer, and a reconstruction costs at most a quarter of the frame's pixels.  Compositing:
:class:`~lodsprite.gl.composite.ProxyCompositor` draws the proxy placed in the world with
the reconstruction projected onto it, depth tested and written in the frame's one depth
buffer (no ``gl_FragDepth``: the proxy's own rasterised depth is exact and keeps early
depth testing).

Light fields are view dependent, so LOD-sprite keyframes never hold them: they are drawn
every frame, those whose placed proxy box is in the frustum (the others are neither
reconstructed nor composited).  A method's node cache cannot be rewound, so the replay
composites a GPU copy of each frame's reconstruction made after the timed frame (as the
lumigraph technique's).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from lodsprite.camera import Viewpoint
from lodsprite.errors import InputError
from lodsprite.layered.layers import Layer, layer_frame
from lodsprite.scene.budget import LayerControl

if TYPE_CHECKING:
    from lodsprite.record import Frame
    from lodsprite.scene import LightField
    from lodsprite.terrain import HeightField

#: Node budgets, ascending quality.
NODES = (2.0, 4.0, 8.0, 16.0)
#: A reconstruction target's side, as a fraction of the frame's.
TARGET_SCALE = 0.5


def screen_rect(view_proj: np.ndarray, lo: np.ndarray, hi: np.ndarray
                ) -> tuple[float, float, float, float]:
    """The window region ``(x0, y0, width, height)`` (fractions, bottom-up) the box
    ``lo..hi (3,)`` covers through ``view_proj``, clipped to the window; the whole window
    when a corner is behind the eye."""
    corners = np.array([[x, y, z, 1.0] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                        for z in (lo[2], hi[2])])
    clip = corners @ view_proj.T
    if (clip[:, 3] <= 1e-6).any():
        return 0.0, 0.0, 1.0, 1.0
    ndc = clip[:, :2] / clip[:, 3:]
    a = np.clip((ndc.min(0) + 1) / 2, 0.0, 1.0)
    b = np.clip((ndc.max(0) + 1) / 2, 0.0, 1.0)
    size = np.maximum(b - a, 1e-3)
    return float(a[0]), float(a[1]), float(size[0]), float(size[1])


def crop(projection: np.ndarray, rect: tuple[float, float, float, float]) -> np.ndarray:
    """``projection`` followed by the window-region ``rect`` stretched over the whole
    target (a linear map of clip space: window depth unchanged)."""
    x0, y0, w, h = rect
    c = np.eye(4)
    c[0, 0], c[1, 1] = 1.0 / w, 1.0 / h
    c[0, 3], c[1, 3] = (1.0 - 2.0 * x0) / w - 1.0, (1.0 - 2.0 * y0) / h - 1.0
    return c @ projection


def placement(vertices: np.ndarray, position: tuple[float, float], ground_z: float,
              height_m: float) -> tuple[np.ndarray, float]:
    """``M (4, 4)`` lumigraph -> world for a proxy of ``vertices (n, 3)`` (lumigraph
    world, y up) standing at ``position`` on ground ``ground_z``, ``height_m`` tall; and
    the scale ``s``."""
    from lodsprite.lumigraph.technique import VIEWER_TO_LUMIGRAPH

    lo, hi = vertices.min(0), vertices.max(0)
    if not hi[1] - lo[1] > 0:
        raise InputError("a light field's proxy has no height (flat along +y)")
    s = float(height_m) / float(hi[1] - lo[1])
    base = np.array([(lo[0] + hi[0]) / 2, lo[1], (lo[2] + hi[2]) / 2])
    m = np.eye(4)
    m[:3, :3] = s * VIEWER_TO_LUMIGRAPH.T
    m[:3, 3] = np.array([position[0], position[1], ground_z]) - m[:3, :3] @ base
    return m, s


def to_local(viewpoint: Viewpoint, m: np.ndarray, s: float) -> Viewpoint:
    """``viewpoint`` (world) in the lumigraph's world of ``M = m`` (scale ``s``)."""
    r = m[:3, :3] / s
    return Viewpoint(r.T @ viewpoint.x, r.T @ viewpoint.y, r.T @ viewpoint.z,
                     r.T @ (viewpoint.o - m[:3, 3]) / s)


def local_projection(projection: np.ndarray, s: float) -> np.ndarray:
    """The frame's projection for eye coordinates scaled by ``1 / s`` (same window
    positions and depths): the depth translation term divided by ``s``."""
    p = np.array(projection, dtype=np.float64)
    p[2, 3] /= s
    return p


class PlacedLightField:
    """One lumigraph in the world: its method, depth-correction proxy and compositor."""

    def __init__(self, gl, size: tuple[int, int], where: LightField,
                 ground_z: float, method: str, nodes: int) -> None:
        from lodsprite.gl.composite import ProxyCompositor
        from lodsprite.gl.lumigraph import ColorMeshDrawer
        from lodsprite.lumigraph.methods import Context, MultiSlabMethod, make_method
        from lodsprite.lumigraph.store import Lumigraph

        self.lf = Lumigraph(where.source)
        mesh = self.lf.proxy()
        self.m, self.s = placement(mesh.vertices, where.position, ground_z, where.height_m)
        self.proxy_vertices = np.asarray(mesh.vertices, np.float64)
        self.max_nodes = int(min(nodes, self.lf.slabs[0].n_st ** 2))
        self.proxy = ColorMeshDrawer(gl, mesh.vertices, mesh.faces, mesh.colors,
                                       mesh.normals)
        self.compositor = ProxyCompositor(gl, mesh.vertices, mesh.faces, mesh.colors,
                                          mesh.normals)
        self.size = (max(8, int(size[0] * TARGET_SCALE)), max(8, int(size[1] * TARGET_SCALE)))
        self.rect = (0.0, 0.0, 1.0, 1.0)
        ctx = Context(gl, self.lf, 0, self.size, self.proxy)
        options = {"nodes": self.max_nodes} if method == "arbitrary" else {}
        self.method = (make_method(method, ctx, **options) if len(self.lf.slabs) == 1
                       else MultiSlabMethod(ctx, method, options))
        self.index = 0

    def box(self) -> tuple[np.ndarray, np.ndarray]:
        """The placed proxy's world box ``lo (3,)``, ``hi (3,)`` metres."""
        v = self.proxy_vertices @ self.m[:3, :3].T + self.m[:3, 3]
        return v.min(0), v.max(0)

    def set_nodes(self, n: int) -> None:
        target = getattr(self.method, "current", self.method)
        if target is not None and hasattr(target, "count"):
            target.count = int(np.clip(n, 1, self.max_nodes))

    def reconstruct(self, viewpoint: Viewpoint, projection: np.ndarray) -> Frame:
        """Reconstruct through ``projection`` cropped to the proxy's screen rectangle
        (:attr:`rect`) into the method's small target."""
        self.rect = screen_rect(projection @ viewpoint.view_matrix(), *self.box())
        f = self.method.frame(self.index, to_local(viewpoint, self.m, self.s),
                              local_projection(crop(projection, self.rect), self.s))
        self.index += 1
        return f

    def composite(self, projection: np.ndarray, viewpoint: Viewpoint, image, fbo,
                  rect: tuple[float, float, float, float] | None = None) -> int:
        mvp = projection @ viewpoint.view_matrix() @ self.m
        return self.compositor.draw(mvp, image, fbo, self.rect if rect is None else rect)

    def release(self) -> None:
        self.method.release()
        self.proxy.release()
        self.compositor.release()


class LightFieldLayer(Layer):
    """The placed ``lightfields`` standing on ``ground`` (the terrain's height field) on
    ``renderer``'s target (module doc); ``method``: ``arbitrary`` (knob: nodes) or
    ``full`` (the reference)."""

    name = "lightfields"

    def __init__(self, renderer, lightfields: tuple[LightField, ...], ground: HeightField,
                 method: str = "arbitrary", nodes: int = 8) -> None:
        from lodsprite.scene.placement import ground as ground_z

        self.renderer = renderer
        self.fbo = renderer.target.fbo
        self.nodes = float(nodes)
        self.items: list[PlacedLightField] = []
        self._pool: list = []             # per item: its one replay target (or None)
        self._snaps: dict[int, list] = {}
        try:
            for where in lightfields:
                z = float(ground_z(ground, np.array([where.position], np.float64))[0])
                self.items.append(PlacedLightField(renderer.gl, renderer.size, where, z,
                                                   method, int(max(NODES))))
        except BaseException:
            self.release()
            raise
        self.set_nodes(nodes)
        corners = [item.box() for item in self.items]
        self._lo = np.array([c[0] for c in corners]).reshape(-1, 3)
        self._hi = np.array([c[1] for c in corners]).reshape(-1, 3)
        self._drawn = np.zeros(len(self.items), bool)
        self._keep: set[int] = set()
        self._frame = -1

    def set_nodes(self, value: float) -> None:
        self.nodes = float(value)
        for item in self.items:
            item.set_nodes(int(value))

    def control(self) -> LayerControl:
        return LayerControl("lightfields", NODES, self.nodes, self.set_nodes,
                            coverage=self.coverage)

    def coverage(self) -> float | None:
        """The union of the last frame's drawn light fields' screen rectangles, a
        fraction of the window (:func:`~lodsprite.layered.coverage.rects_coverage`); None
        before a frame."""
        from lodsprite.layered.coverage import rects_coverage

        if self._frame < 0:
            return None
        return rects_coverage([item.rect for item, shown in zip(self.items, self._drawn,
                                                                 strict=True) if shown])

    def warm_up(self, viewpoint: Viewpoint, projection: np.ndarray) -> None:
        for item in self.items:
            item.reconstruct(viewpoint, projection)

    def in_view(self, viewpoint: Viewpoint, projection: np.ndarray) -> np.ndarray:
        """``(items,) bool``: whose placed proxy box is not wholly outside the frustum."""
        from lodsprite.camera import boxes_in_frustum, frustum_planes

        if not self.items:
            return np.zeros(0, bool)
        planes = frustum_planes(projection @ viewpoint.view_matrix())
        return boxes_in_frustum(planes, self._lo, self._hi)

    def draw(self, viewpoint: Viewpoint, t: float, projection: np.ndarray) -> Frame:
        """Reconstruct and composite every light field in view (the others cost nothing)."""
        return self.draw_into(viewpoint, projection, self.fbo)

    def draw_into(self, viewpoint: Viewpoint, projection: np.ndarray, fbo) -> Frame:
        """:meth:`draw` into ``fbo`` (a keyframe's target: a server's keyframes hold the
        light fields of their view, composited by depth with what stands)."""
        images = tris = 0
        self._drawn = self.in_view(viewpoint, projection)
        for item, shown in zip(self.items, self._drawn, strict=True):
            if not shown:
                continue
            self.set_nodes(self.nodes)  # a slab switch makes a new method
            f = item.reconstruct(viewpoint, projection)
            images += f.extra["images"]
            tris += item.composite(projection, viewpoint, item.method.output.color, fbo)
        self._frame += 1
        return layer_frame(self.name, 0.0, tris, work=float(max(images, 1)),
                          extra={"lf_images": images, "lf_drawn": int(self._drawn.sum())})

    def plan_replay(self, frames: set[int]) -> None:
        """Keep the reconstructions of ``frames`` for a replay: each read back to host
        memory after its timed frame (:meth:`decision`; the small cropped images, raw
        half floats); the copies of an earlier plan are dropped."""
        self._keep = set(frames)
        self._snaps = {}

    def decision(self) -> dict[str, Any]:
        i = self._frame
        if i in self._keep:
            self._snaps[i] = [(item.method.output.size, item.method.output.color.read(
                alignment=1)) for item in self.items]
        return {"frame": i, "drawn": tuple(bool(d) for d in self._drawn),
                "rects": tuple(item.rect for item in self.items)}

    def replay(self, viewpoint: Viewpoint, t: float, projection: np.ndarray,
               decision: dict[str, Any]) -> None:
        if not self.items:
            return
        snaps = self._snaps.get(decision["frame"])
        if snaps is None:
            raise InputError(f"frame {decision['frame']} was not kept for a replay")
        for k, ((size, data), item, shown, rect) in enumerate(zip(
                snaps, self.items, decision["drawn"], decision["rects"], strict=True)):
            if shown:
                texture = self._upload(k, size, data)
                item.composite(projection, viewpoint, texture, self.fbo, rect)

    def _upload(self, k: int, size: tuple[int, int], data: bytes):
        """Item ``k``'s kept reconstruction in its one replay texture (made once)."""
        from lodsprite.gl.lumigraph import FloatTarget

        while len(self._pool) <= k:
            self._pool.append(None)
        if self._pool[k] is None or self._pool[k].size != tuple(size):
            if self._pool[k] is not None:
                self._pool[k].release()
            self._pool[k] = FloatTarget(self.renderer.gl, *size)
        self._pool[k].color.write(data, alignment=1)
        return self._pool[k].color

    def release(self) -> None:
        for target in getattr(self, "_pool", []):
            if target is not None:
                target.release()
        self._pool, self._snaps = [], {}
        for item in self.items:
            item.release()
        self.items = []
