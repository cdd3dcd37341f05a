"""The objects layer of a scene: a world's mesh instances by the LODManager engine
(Gumbau et al.: shared LODs, instancing), standing and walking on the terrain.

The world's object types become the crowd's LOD models (a built-in keeps its own; a mesh
file becomes a progressive mesh), its instances the crowd's objects; every frame their
poses come from :meth:`~lodsprite.scene.world.World.poses` at the frame's time (walkers
follow the ground).  The engine draws without its own ground and without clearing, into
the terrain's framebuffer, through the frame's projection, depth tested against what the
terrain left (:class:`~lodsprite.manager.engine.CrowdEngine` ``ground=False``).

Types with ``lod = "profile"`` take their desired LOD from their error profile (the
engine's ``desired_hook``, :func:`profile_lod`); the others are distance-linear.
The knob is the LOD exponent ``p`` of §4.2 (``lod = (1 - (d - near) / (far - near)) ** p``;
larger is coarser); the LOD ranges scale with the tallest type.  ``p = 0`` is every object
at its full mesh (the full-detail reference).  With LOD-sprite keyframes holding the
static objects, a frame draws the moving ones only and each keyframe the static ones
(``subset``); the replay re-applies the recorded extraction orders up to the frame, as
the crowd technique's replay does.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from lodsprite.layered.layers import Layer, LayerFrame
from lodsprite.scene.budget import LayerControl

if TYPE_CHECKING:
    from lodsprite.camera import Viewpoint
    from lodsprite.manager.scene import Crowd
    from lodsprite.scene.world import World

#: LOD exponents, ascending quality (coarse to fine).
EXPONENTS = (8.0, 5.7, 4.0, 2.8, 2.0, 1.4, 1.0, 0.7, 0.5, 0.35, 0.25)


def world_crowd(world: World) -> Crowd:
    """The world's instances as a crowd (positions at ``t = 0``); its extent the terrain's
    half width."""
    from lodsprite.manager.models import ProgressiveMesh
    from lodsprite.manager.scene import Crowd

    models = [t.model if t.model is not None else
              ProgressiveMesh(t.name, t.vertices, t.faces, t.colours) for t in world.types]
    poses = world.poses(0.0).astype(np.float64)
    lo, hi = world.extent
    return Crowd(models, world.type_indices().astype(np.int64), poses[:, :3].copy(),
                 poses[:, 3].copy(), float(np.max(hi - lo)) / 2)


def profile_lod(world: World, crowd: Crowd, renderer):
    """The profile-LOD hook (Scoggins et al. 2000) over the world's ``lod = "profile"``
    types, for :attr:`~lodsprite.manager.engine.CrowdEngine.desired_hook`
    (:func:`lodsprite.scene.profile_lod.profile_hook`, built now, untimed), or None: no
    profile type, or a tree without the profile-LOD part (the distance-linear LOD then)."""
    if not any(t.lod == "profile" for t in world.types):
        return None
    try:
        from lodsprite.scene.profile_lod import profile_hook
    except ImportError:  # the profile-LOD part not merged yet
        return None
    return profile_hook(world.types, crowd.models, crowd.types, renderer.fov_y_deg,
                        renderer.size[1])


class ObjectsLayer(Layer):
    """A world's instances on ``renderer``'s terrain target (see the module doc).
    ``exponent``: the starting LOD exponent; ``active``: objects whose LOD is updated a
    frame (default: all); ``slots``: LOD slots per type."""

    name = "objects"

    def __init__(self, renderer, world: World, exponent: float = 1.0,
                 active: int | None = None, slots: int = 16) -> None:
        from lodsprite.manager.engine import CrowdEngine

        self.world, self.renderer = world, renderer
        self.crowd = world_crowd(world)
        self.moving = world.moving()
        height = max((t.height_m for t in world.types), default=2.0)
        target = renderer.paths.renderer.target
        self.engine = CrowdEngine(renderer.gl, self.crowd, target, "manager", slots=slots,
                                  active=active or max(1, len(self.crowd)),
                                  range_near=2.0 * height, range_far=150.0 * height,
                                  fov_y_deg=renderer.fov_y_deg, ground=False)
        self.engine.feedback.exponent = float(exponent)
        self.engine.desired_hook = profile_lod(world, self.crowd, renderer)
        self.subset: np.ndarray | None = None  # None: every object each frame
        self._log: list[list] = []             # extraction orders of every engine frame
        self._applied: int | None = None       # replay: orders applied up to this entry
        self._warm: list = []
        self._last: dict[str, Any] = {}
        self.keyframe_draws: list[tuple[Any, dict]] = []  # (keyframe viewpoint, decision)
        # whether a replay will come (the harness says so; the viewer never replays):
        # without, no extraction orders nor keyframe draws are kept
        self.recording = False
        self._seen: tuple[Any, np.ndarray] | None = None  # the last draw's view, projection

    @property
    def exponent(self) -> float:
        return self.engine.feedback.exponent

    def set_exponent(self, value: float) -> None:
        """The LOD exponent (>= 0; 0: full meshes)."""
        self.engine.feedback.exponent = max(0.0, float(value))

    def control(self) -> LayerControl:
        return LayerControl("objects", EXPONENTS, self.exponent, self.set_exponent,
                            detail=self.detail)

    def detail(self) -> tuple[np.ndarray, np.ndarray, float] | None:
        """The last frame's visible objects for the budget's benefit model: their
        distance-linear LOD factors, projected areas and screen coverage
        (:func:`~lodsprite.scene.costs.object_detail`); None before a frame."""
        from lodsprite.camera import frustum_planes
        from lodsprite.manager.scene import spheres_in_frustum
        from lodsprite.scene.costs import object_detail

        if self._seen is None:
            return None
        viewpoint, projection = self._seen
        e = self.engine
        planes = frustum_planes(projection @ viewpoint.view_matrix())
        visible = spheres_in_frustum(planes, e.centres, e.radii)
        return object_detail(e.centres, e.radii, viewpoint.o, visible, *e.range,
                             e.fov_y_deg, e.target.size)

    def _engine_frame(self, viewpoint: Viewpoint, t: float, projection: np.ndarray,
                      subset: np.ndarray | None, fbo=None, keep: bool = False
                      ) -> tuple[Any, dict]:
        """One engine frame; its extraction orders logged only when a replay will come
        (``recording``) or ``keep`` (the warm-up's): never a list a frame otherwise."""
        self.engine.set_poses(self.world.poses(t))
        f = self.engine.frame(viewpoint, projection=projection, subset=subset, fbo=fbo)
        if self.recording or keep:
            self._log.append(list(self.engine.last_orders))
        return f, {"entry": len(self._log) - 1, "using": self.engine.last_using.copy(),
                   "t": t}

    def warm_up(self, viewpoint: Viewpoint, projection: np.ndarray) -> None:
        """Untimed: the first LODs extracted (kept as the replay's starting state)."""
        self._engine_frame(viewpoint, 0.0, projection, np.zeros(len(self.crowd), bool),
                           keep=True)
        self._warm, self._log = self._log[-1], []

    def draw(self, viewpoint: Viewpoint, t: float, projection: np.ndarray) -> LayerFrame:
        f, self._last = self._engine_frame(viewpoint, t, projection, self.subset)
        self._seen = (viewpoint, projection)
        return LayerFrame(f.ms, f.triangles, work=float(max(f.triangles, 1)),
                          extra={"extractions": f.extractions, "draw_calls": f.draw_calls,
                                 "visible": f.visible})

    def draw_static(self, viewpoint: Viewpoint, projection: np.ndarray, fbo) -> None:
        """The static objects into a keyframe's framebuffer (LOD-sprite's static layer)."""
        if self.replaying is not None:
            d = self._keyframe_decision(viewpoint)
            self._restore(d["entry"])
            self.engine.redraw(viewpoint, d["using"], [], projection, ~self.moving, fbo)
            return
        _, d = self._engine_frame(viewpoint, 0.0, projection, ~self.moving, fbo)
        if self.recording:
            self.keyframe_draws.append((viewpoint, d))

    replaying: dict | None = None  # set while a replay redraws keyframes

    def _keyframe_decision(self, viewpoint: Viewpoint) -> dict:
        for vp, d in reversed(self.keyframe_draws):
            if vp is viewpoint or (np.array_equal(vp.o, viewpoint.o)
                                   and np.array_equal(vp.z, viewpoint.z)):
                return d
        raise LookupError("no keyframe drawn from this viewpoint")

    def decision(self) -> dict[str, Any]:
        return self._last

    def _restore(self, entry: int) -> None:
        """The index buffers as they were after log entry ``entry``."""
        if self._applied is None or entry < self._applied:  # from before the first frame
            self.engine.reset_indices()
            pending = self._warm + [o for e in self._log[:entry + 1] for o in e]
        else:
            pending = [o for e in self._log[self._applied + 1:entry + 1] for o in e]
        for buffer, type_index, lod in pending:
            self.engine.renderer.set_indices(buffer, type_index,
                                             self.crowd.models[type_index].extract(lod))
        self._applied = entry

    def replay(self, viewpoint: Viewpoint, t: float, projection: np.ndarray,
               decision: dict[str, Any]) -> None:
        self.engine.set_poses(self.world.poses(decision["t"]))
        self._restore(decision["entry"])
        self.engine.redraw(viewpoint, decision["using"], [], projection, self.subset)

    def release(self) -> None:
        self.engine.release()
