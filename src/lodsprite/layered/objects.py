"""The objects layer of a scene: its object set by the LODManager engine (Gumbau et al.:
shared LODs, instancing): a scene file's world standing and walking on the terrain, or a
crowd (:class:`~lodsprite.manager.scene.Crowd`) standing on its own ground.

The world's object types become the crowd's LOD models (a built-in keeps its own; a mesh
file becomes a progressive mesh), its instances the crowd's objects; every frame their
poses come from :meth:`~lodsprite.scene.world.World.poses` at the frame's time (walkers
follow the ground).  The engine draws without its own ground and without clearing, into
the terrain's framebuffer, through the frame's projection, depth tested against what the
terrain left (:class:`~lodsprite.manager.engine.CrowdEngine` ``ground=False``).

Types with ``lod = "profile"`` take their desired LOD from their error profile (the
engine's ``desired_hook``, :func:`profile_lod`); the others are distance-linear.
The knob is the LOD exponent ``p`` of §4.2 (``lod = (1 - (d - near) / (far - near)) ** p``;
larger is coarser) and, below the coarsest exponent, the draw count: settings of
:data:`CULL` (``p`` 11.3 to 32) draw only the objects whose type's height projects to at
least so many pixels (contribution culling, the "not drawn" level of Funkhouser
& Séquin 1993 and Unity's culled LOD), so that a crowd's cost has no floor at its
coarsest meshes (100 trees at 10 % of their triangles cost more than a 5 fps frame here;
a type's ``lod_floor`` sets that fraction).  The LOD ranges scale with the tallest type.
``p = 0`` is every object at its full mesh (the full-detail reference).
:meth:`ObjectsLayer.work` predicts the triangles of every setting from the objects seen
last frame, the scheduler's cost model.  With LOD-sprite keyframes holding the static
objects, a frame draws the moving ones only and each keyframe the static ones
(``subset``); the replay re-applies the recorded extraction orders up to the frame, as
the crowd technique's replay does.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from lodsprite.layered.layers import Layer, layer_frame
from lodsprite.scene.budget import LayerControl

if TYPE_CHECKING:
    from lodsprite.camera import Viewpoint
    from lodsprite.manager.scene import Crowd
    from lodsprite.record import Frame
    from lodsprite.scene.model import ObjectSet
    from lodsprite.scene.world import World

#: LOD exponents, ascending quality (coarse to fine).
EXPONENTS = (8.0, 5.7, 4.0, 2.8, 2.0, 1.4, 1.0, 0.7, 0.5, 0.35, 0.25)
#: The draw-count settings below the coarsest exponent, ascending quality: ``(knob value,
#: smallest projected height drawn, px)``; the value is also the LOD exponent they draw at.
CULL = ((32.0, 8.0), (22.6, 4.0), (16.0, 2.0), (11.3, 1.0))
#: Every knob setting of the objects layer, ascending quality.
SETTINGS = tuple(v for v, _ in CULL) + EXPONENTS


def setting(value: float) -> tuple[float, float]:
    """A knob value's ``(LOD exponent, smallest projected height drawn, px)``."""
    for v, px in CULL:
        if abs(value - v) < 1e-6:
            return float(v), px
    return float(value), 0.0


def projected_height(centres: np.ndarray, heights: np.ndarray, eye: np.ndarray,
                     fov_y_deg: float, height_px: int) -> np.ndarray:
    """Objects' projected heights, px: ``centres (N, 3)``, ``heights (N,)`` metres (their
    type's), ``eye (3,)`` -> ``(N,)`` float64."""
    d = np.maximum(np.linalg.norm(np.asarray(centres, np.float64) - eye, axis=1), 1e-3)
    focal = height_px / 2 / np.tan(np.radians(fov_y_deg) / 2)
    return np.asarray(heights, np.float64) * focal / d


def predicted_triangles(factor: Callable[[float], np.ndarray], size: np.ndarray,
                        least: np.ndarray, full: np.ndarray, values: tuple[float, ...]
                        ) -> np.ndarray:
    """Triangles the visible objects draw at each knob value: ``factor(p) (k,)`` their LOD
    factors in 0..1 under exponent ``p`` (called once an exponent), ``size (k,)`` their
    projected heights (px), ``least``, ``full (k,)`` their type's coarsest and full
    triangle counts -> ``(len(values),)`` float64 (triangles linear in the factor, as the
    models count them)."""
    out = np.empty(len(values))
    factors: dict[float, np.ndarray] = {}
    for i, v in enumerate(values):
        p, px = setting(v)
        if p not in factors:
            factors[p] = np.asarray(factor(p), np.float64)
        f, keep = factors[p], size >= px
        out[i] = float((least[keep] + f[keep] * (full[keep] - least[keep])).sum())
    return out


def world_crowd(world: World) -> Crowd:
    """The world's instances as a crowd (positions at ``t = 0``); its extent the terrain's
    half width."""
    from lodsprite.manager.models import ProgressiveMesh
    from lodsprite.manager.scene import Crowd

    models = [t.model if t.model is not None else
              ProgressiveMesh(t.name, t.vertices, t.faces, t.colours, t.lod_floor)
              for t in world.types]
    poses = world.poses(0.0).astype(np.float64)
    lo, hi = world.extent
    return Crowd(models, world.type_indices().astype(np.int64), poses[:, :3].copy(),
                 poses[:, 3].copy(), float(np.max(hi - lo)) / 2)


def profile_lod(world: World, crowd: Crowd, renderer):
    """The profile-LOD hook (Scoggins et al. 2000) over the world's ``lod = "profile"``
    types, for :attr:`~lodsprite.manager.engine.CrowdEngine.desired_hook`
    (:func:`lodsprite.profiles.object_lod.profile_hook`, built now, untimed), or None: no
    profile type, or a tree without the profile-LOD part (the distance-linear LOD then)."""
    if not any(t.lod == "profile" for t in world.types):
        return None
    try:
        from lodsprite.profiles.object_lod import profile_hook
    except ImportError:  # the profile-LOD part not merged yet
        return None
    return profile_hook(world.types, crowd.models, crowd.types, renderer.fov_y_deg,
                        renderer.size[1])


class ObjectsLayer(Layer):
    """An object set (a world or a crowd) on ``renderer``'s target (see the module doc).
    ``exponent``: the starting LOD exponent; ``active``: objects whose LOD is updated a
    frame (default: all); ``slots``: LOD slots per type."""

    name = "objects"

    def __init__(self, renderer, objects: ObjectSet, exponent: float = 1.0,
                 active: int | None = None, slots: int = 16) -> None:
        from lodsprite.manager.engine import CrowdEngine
        from lodsprite.scene.world import World

        self.renderer = renderer
        self.world = objects if isinstance(objects, World) else None
        if self.world is not None:
            self.crowd = world_crowd(self.world)
            self.moving = self.world.moving()
            heights = np.array([t.height_m for t in self.world.types], np.float64)
        else:  # a crowd: its own models, standing still on its own ground
            self.crowd = objects
            self.moving = np.zeros(len(objects), bool)
            heights = np.array([float(np.ptp(m.vertices[:, 2])) for m in objects.models])
        height = float(heights.max()) if len(heights) else 2.0
        own_ground = renderer.scene.hf is None  # no terrain: the crowd's ground clears
        self.engine = CrowdEngine(renderer.gl, self.crowd, renderer.target, "manager",
                                  slots=slots, active=active or max(1, len(self.crowd)),
                                  range_near=2.0 * height, range_far=150.0 * height,
                                  fov_y_deg=renderer.fov_y_deg, ground=own_ground)
        self.knob = float(exponent)
        self.min_px = 0.0
        self.engine.feedback.exponent = float(exponent)
        # each object's type's coarsest and full triangles and height (m)
        types = self.crowd.types
        self._least = np.array([m.triangles(0.0) for m in self.crowd.models], np.float64)[types]
        self._full = np.array([m.triangles(1.0) for m in self.crowd.models], np.float64)[types]
        self._heights = heights[types]
        self.engine.desired_hook = (None if self.world is None
                                    else profile_lod(self.world, self.crowd, renderer))
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
        self._seen_visible: np.ndarray | None = None      # ... and what it had in view

    @property
    def exponent(self) -> float:
        return self.engine.feedback.exponent

    def set_exponent(self, value: float) -> None:
        """The knob: a LOD exponent (>= 0; 0: full meshes); those of :data:`CULL` also
        leave the objects under their projected height undrawn."""
        self.knob = max(0.0, float(value))
        p, self.min_px = setting(self.knob)
        self.engine.feedback.exponent = p

    def control(self) -> LayerControl:
        return LayerControl("objects", SETTINGS, self.knob, self.set_exponent,
                            detail=self.detail, work=self.work)

    def _visible(self) -> np.ndarray | None:
        """The last frame's objects in the frustum (and in :attr:`subset`), ``(N,)`` bool;
        None before a frame."""
        from lodsprite.camera import frustum_planes
        from lodsprite.manager.scene import spheres_in_frustum

        if self._seen is None:
            return None
        if self._seen_visible is None:  # once a frame: detail() and work() both ask
            viewpoint, projection = self._seen
            e = self.engine
            visible = spheres_in_frustum(frustum_planes(projection @ viewpoint.view_matrix()),
                                         e.centres, e.radii)
            self._seen_visible = visible if self.subset is None else visible & self.subset
        return self._seen_visible

    def detail(self) -> tuple | None:
        """The last frame's visible objects for the budget's benefit model: their
        distance-linear LOD factors, projected areas, screen coverage
        (:func:`~lodsprite.scene.costs.object_detail`) and the knob's :func:`setting`;
        None before a frame."""
        from lodsprite.scene.costs import object_detail

        visible = self._visible()
        if visible is None:
            return None
        e, eye = self.engine, self._seen[0].o
        lin, cov, _ = object_detail(e.centres, e.radii, eye, visible, *e.range,
                                    e.fov_y_deg, e.target.size)
        coverage = self._coverage(visible, cov)
        size = projected_height(e.centres[visible], self._heights[visible], eye,
                                e.fov_y_deg, e.target.size[1])
        return lin, cov, coverage, setting, size

    def _coverage(self, visible: np.ndarray, cov: np.ndarray) -> float:
        """The union of the visible objects' projected discs (areas ``cov (k,)`` px,
        centres projected through the last frame's view), a fraction of the window
        (:func:`~lodsprite.layered.coverage.discs_coverage`: overlaps counted once)."""
        from lodsprite.camera import project_points
        from lodsprite.layered.coverage import discs_coverage

        viewpoint, projection = self._seen
        size = self.engine.target.size
        px, _, _ = project_points(self.engine.centres[visible],
                                  projection @ viewpoint.view_matrix(), *size)
        return discs_coverage(px, np.sqrt(cov / np.pi), size)

    def work(self) -> np.ndarray | None:
        """Predicted triangles at every setting of :data:`SETTINGS` ``(n,)`` from the
        last frame's visible objects (:func:`predicted_triangles`; the profile types'
        factors from their profiles, as the engine's hook gives them); None before a
        frame."""
        from lodsprite.manager.core import desired_lod

        visible = self._visible()
        if visible is None:
            return None
        e, vp = self.engine, self._seen[0]
        dist = np.linalg.norm(e.centres - vp.o, axis=1)
        size = projected_height(e.centres[visible], self._heights[visible], vp.o,
                                e.fov_y_deg, e.target.size[1])

        def factor(p: float) -> np.ndarray:
            f = desired_lod(dist, *e.range, p)
            if e.desired_hook is not None:
                f = e.desired_hook(vp, e.transforms, f, p)
            return np.asarray(f, np.float64)[visible]

        return predicted_triangles(factor, size, self._least[visible], self._full[visible],
                                   SETTINGS)

    def _drawn(self, viewpoint: Viewpoint, subset: np.ndarray | None) -> np.ndarray | None:
        """The objects of ``subset`` (None: all) a frame draws: those at least
        :attr:`min_px` across (all of them without a draw-count setting)."""
        if self.min_px <= 0:
            return subset
        e = self.engine
        big = projected_height(e.centres, self._heights, viewpoint.o, e.fov_y_deg,
                               e.target.size[1]) >= self.min_px
        return big if subset is None else big & subset

    def _engine_frame(self, viewpoint: Viewpoint, t: float, projection: np.ndarray,
                      subset: np.ndarray | None, fbo=None, keep: bool = False,
                      cull: bool = False) -> tuple[Any, dict]:
        """One engine frame of ``subset`` (``cull``: less the objects under
        :attr:`min_px`); its extraction orders logged only when a replay will come
        (``recording``) or ``keep`` (the warm-up's): never a list a frame otherwise."""
        self._pose(t)
        if cull:
            subset = self._drawn(viewpoint, subset)
        f = self.engine.frame(viewpoint, projection=projection, subset=subset, fbo=fbo)
        if self.recording or keep:
            self._log.append(list(self.engine.last_orders))
        return f, {"entry": len(self._log) - 1, "using": self.engine.last_using.copy(),
                   "t": t, "drawn": subset}

    def _pose(self, t: float) -> None:
        """The world's poses at time ``t`` s (a crowd stands still)."""
        if self.world is not None:
            self.engine.set_poses(self.world.poses(t))

    def projection(self, viewpoint: Viewpoint) -> np.ndarray:
        """The engine's own projection ``(4, 4)`` (a scene without terrain draws
        through it: near/far fitted to the crowd's ground)."""
        return self.engine.projection

    def warm_up(self, viewpoint: Viewpoint, projection: np.ndarray) -> None:
        """Untimed: the first LODs extracted (kept as the replay's starting state)."""
        self._engine_frame(viewpoint, 0.0, projection, np.zeros(len(self.crowd), bool),
                           keep=True)
        self._warm, self._log = self._log[-1], []
        # the first plan predicts from this view
        self._seen, self._seen_visible = (viewpoint, projection), None

    def draw(self, viewpoint: Viewpoint, t: float, projection: np.ndarray) -> Frame:
        f, self._last = self._engine_frame(viewpoint, t, projection, self.subset, cull=True)
        self._seen, self._seen_visible = (viewpoint, projection), None
        return layer_frame(self.name, f.ms, f.triangles, work=float(max(f.triangles, 1)),
                          extra={k: f.extra[k] for k in ("extractions", "draw_calls",
                                                         "visible")})

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
            self.engine.drawer.set_indices(buffer, type_index,
                                             self.crowd.models[type_index].extract(lod))
        self._applied = entry

    def replay(self, viewpoint: Viewpoint, t: float, projection: np.ndarray,
               decision: dict[str, Any]) -> None:
        self._pose(decision["t"])
        self._restore(decision["entry"])
        self.engine.redraw(viewpoint, decision["using"], [], projection,
                           decision.get("drawn", self.subset))

    def release(self) -> None:
        self.engine.release()
