"""The crowd, frame by frame: LOD selection, extraction, instanced drawing (Gumbau et al.).

:class:`CrowdEngine` runs one of three modes on a :class:`~lodsprite.manager.scene.Crowd`:

* ``manager`` - the LODManager (§4): desired LOD from distance and frame-rate feedback,
  the active list, §4.1's borrowing of similar LODs from ``D_T``, extractions for the rest;
* ``independent`` - baseline (a): the same, but every object extracts its own LOD when
  its desired factor leaves its bucket (no sharing);
* ``discrete`` - baseline (b), the engines' default: a chain of four LODs per type
  extracted once (factors 1, 0.5, 0.25, 0), picked per object by projected screen height
  with hysteresis (Unity's LODGroup, Godot's mesh LOD); its LOD switches are counted.

Every frame: frustum culling (bounding spheres), LOD work (timed as ``lod_ms``: the
decisions, the extractions and their uploads), then the visible objects grouped by the
index buffer they draw, one instanced draw a group.  Times stop after ``ctx.finish()``.
A :attr:`CrowdEngine.desired_hook` may replace the distance-linear desired factors of
some objects (a scene's profile LOD: :class:`lodsprite.profiles.object_lod.ProfileLod`).
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from lodsprite.camera import Viewpoint, frustum_planes, perspective
from lodsprite.errors import InputError
from lodsprite.manager.core import Feedback, LodManager, active_list, desired_lod, linear
from lodsprite.manager.scene import Crowd, spheres_in_frustum
from lodsprite.record import Frame

MODES = ("manager", "independent", "discrete")
DISCRETE_LEVELS = (1.0, 0.5, 0.25, 0.0)
#: Projected height (fraction of the screen) below which a finer level gives way.
DISCRETE_THRESHOLDS = (0.25, 0.1, 0.04)
HYSTERESIS = 0.15


#: The columns a crowd frame (:meth:`CrowdEngine.frame`, the one frame record
#: :class:`~lodsprite.record.Frame`) has in ``extra``: ``lod_ms`` of LOD work,
#: ``extractions``, ``draw_calls``, ``visible`` objects, the feedback ``exponent`` and
#: (discrete) LOD ``switches``.
CROWD_COLUMNS = ("lod_ms", "extractions", "draw_calls", "visible", "exponent", "switches")


def discrete_levels(height_frac: np.ndarray, current: np.ndarray,
                    thresholds=DISCRETE_THRESHOLDS, hysteresis: float = HYSTERESIS
                    ) -> np.ndarray:
    """Baseline (b): the level (0 finest) each object shows given its projected height
    (fraction of the screen); a level changes only once the height passes its threshold
    by ``hysteresis`` (relative) in the direction of the change."""
    t = np.asarray(thresholds, dtype=np.float64)
    h = np.asarray(height_frac, dtype=np.float64)[:, None]
    plain = (h < t[None, :]).sum(axis=1)                  # no hysteresis
    finer = (h < t[None, :] * (1 + hysteresis)).sum(axis=1)
    coarser = (h < t[None, :] * (1 - hysteresis)).sum(axis=1)
    cur = np.asarray(current)
    return np.where(plain < cur, np.minimum(cur, finer),
                    np.where(plain > cur, np.maximum(cur, coarser), cur))


class CrowdEngine:
    """A crowd on a GL context, drawn into ``target`` (a RenderTarget or wrapped window
    framebuffer) of ``size``; see the module doc for ``mode``."""

    def __init__(self, gl, crowd: Crowd, target, mode: str = "manager", slots: int = 16,
                 active: int = 300, target_fps: float | None = None, range_near: float = 5.0,
                 range_far: float = 150.0, dist=linear, fov_y_deg: float = 60.0,
                 penalty: float = 0.25, ground: bool = True) -> None:
        from lodsprite.gl.crowd import CrowdDrawer

        if mode not in MODES:
            raise InputError(f"unknown crowd mode {mode!r}: use one of {', '.join(MODES)}")
        if active < 1:
            raise InputError(f"--active must be at least 1, got {active}")
        if not (0 <= range_near < range_far):
            raise InputError(f"LOD ranges need 0 <= near < far, got {range_near}, {range_far}")
        self.gl, self.crowd, self.target, self.mode = gl, crowd, target, mode
        self.ground = bool(ground)  # False: no clear, no ground; drawn over target's depth
        self.n_active, self.penalty, self.dist = int(active), float(penalty), dist
        self.range = (float(range_near), float(range_far))
        self.feedback = Feedback(target_fps)
        w, h = target.size
        self.fov_y_deg = fov_y_deg
        self.projection = perspective(fov_y_deg, w / h, 0.3, 4.0 * crowd.extent + 100.0)
        self.drawer = CrowdDrawer(gl, crowd.models, crowd.extent)
        n_types = len(crowd.models)
        self.manager = LodManager(crowd.types, n_types, slots, base_lod=0.0,
                                  share=(mode == "manager"), dist=dist)
        self.reset_indices()
        self.centres, self.radii = crowd.centres, crowd.radii
        self.level = np.full(len(crowd), len(DISCRETE_LEVELS) - 1)
        if mode == "discrete":
            for t, m in enumerate(crowd.models):
                for k, f in enumerate(DISCRETE_LEVELS):
                    self.drawer.set_indices(self._discrete_id(t, k), t, m.extract(f))
        self.transforms = np.concatenate([crowd.positions, crowd.yaw[:, None]],
                                         axis=1).astype(np.float32)
        self.last_orders: list[tuple[int, int, float]] = []  # the last frame's extractions
        self.last_using: np.ndarray | None = None
        # Per-object desired factors from elsewhere (e.g. a scene's profile LOD,
        # lodsprite.profiles.object_lod.ProfileLod): (viewpoint, transforms (N, 4),
        # desired (N,), exponent) -> (N,) factors; None: the distance-linear ones.
        self.desired_hook: Callable[..., np.ndarray] | None = None

    def reset_indices(self) -> None:
        """Every type's index buffer on its base LOD (the state before the first frame)."""
        for t, m in enumerate(self.crowd.models):
            self.drawer.set_indices(t, t, m.extract(0.0))

    def _discrete_id(self, t: int, k: int) -> int:
        return len(self.crowd.models) + t * len(DISCRETE_LEVELS) + k

    def set_poses(self, poses: np.ndarray) -> None:
        """Every object's ``(x, y, z, yaw)`` now, ``(N, 4)`` metres and radians (moving
        objects: a scene's walkers); the bounding spheres follow."""
        self.transforms = np.ascontiguousarray(poses, np.float32)
        lift = self.centres - self.crowd.positions  # half each object's height
        self.crowd.positions = np.asarray(poses[:, :3], np.float64)
        self.centres = self.crowd.positions + lift

    def frame(self, viewpoint: Viewpoint, extra_ms: float = 0.0,
              projection: np.ndarray | None = None, subset: np.ndarray | None = None,
              fbo=None) -> Frame:
        """Select, extract and draw one frame from ``viewpoint``: through ``projection``
        (``(4, 4)``; default the engine's own), of the objects in ``subset`` (``(N,)
        bool``; default all) into ``fbo`` (default the target's).  Its ``kind`` is the
        engine's mode, ``ms`` in all (GL finished), the rest in ``extra``
        (:data:`CROWD_COLUMNS`)."""
        t0 = time.perf_counter()
        view_proj = (self.projection if projection is None else projection
                     ) @ viewpoint.view_matrix()
        visible = spheres_in_frustum(frustum_planes(view_proj), self.centres, self.radii)
        if subset is not None:
            visible &= subset
        dist = np.linalg.norm(self.centres - viewpoint.o, axis=1)
        t_lod = time.perf_counter()
        switches = extractions = 0
        self.last_orders = []
        if self.mode == "discrete":
            height = self.radii / np.maximum(dist, 1e-6) / np.tan(np.radians(self.fov_y_deg) / 2)
            new = discrete_levels(height, self.level)
            switches = int(np.count_nonzero(new != self.level))
            self.level = new
            using = np.array([self._discrete_id(t, 0) for t in range(len(self.crowd.models))]
                             )[self.crowd.types] + self.level
        else:
            desired = desired_lod(dist, *self.range, self.feedback.exponent)
            if self.desired_hook is not None:
                desired = self.desired_hook(viewpoint, self.transforms, desired,
                                            self.feedback.exponent)
            active = active_list(desired, self.manager.lod, visible, self.n_active,
                                 self.manager.n_slots, self.penalty, self.dist)
            orders = self.manager.update(active, desired)
            for o in orders:
                self.drawer.set_indices(o.buffer, o.type_index,
                                          self.crowd.models[o.type_index].extract(o.lod))
            extractions = len(orders)
            using = self.manager.using
            self.last_orders = [(o.buffer, o.type_index, o.lod) for o in orders]
        lod_ms = (time.perf_counter() - t_lod) * 1e3
        idx = np.flatnonzero(visible)
        self.last_using = using
        self._draw(view_proj, using, idx, fbo)
        self.gl.finish()
        ms = (time.perf_counter() - t0) * 1e3
        exponent = self.feedback.exponent
        self.feedback.observe(ms + extra_ms)
        return Frame(self.mode, ms, self.drawer.triangles, extra=dict(zip(
            CROWD_COLUMNS, (lod_ms, extractions, self.drawer.draw_calls, len(idx), exponent,
                            switches), strict=True)))

    def _draw(self, view_proj: np.ndarray, using: np.ndarray, idx: np.ndarray,
              fbo=None) -> None:
        order = idx[np.argsort(using[idx], kind="stable")]
        buffers, first, counts = np.unique(using[order], return_index=True, return_counts=True)
        self.drawer.upload_instances(self.transforms[order])
        self.drawer.draw(view_proj, self.target.fbo if fbo is None else fbo,
                           list(zip(buffers.tolist(), first.tolist(), counts.tolist(),
                                    strict=True)), ground=self.ground)

    def redraw(self, viewpoint: Viewpoint, using: np.ndarray,
               orders: list[tuple[int, int, float]], projection: np.ndarray | None = None,
               subset: np.ndarray | None = None, fbo=None) -> None:
        """Draw a recorded frame again (an untimed replay): first the extraction
        ``orders`` ``(buffer, type, lod)`` since the last frame drawn this way, then every
        visible object (of ``subset``) from the index buffer ``using`` names
        (``projection``, ``fbo`` as in :meth:`frame`)."""
        for buffer, type_index, lod in orders:
            self.drawer.set_indices(buffer, type_index,
                                      self.crowd.models[type_index].extract(lod))
        view_proj = (self.projection if projection is None else projection
                     ) @ viewpoint.view_matrix()
        visible = spheres_in_frustum(frustum_planes(view_proj), self.centres, self.radii)
        if subset is not None:
            visible &= subset
        self._draw(view_proj, using, np.flatnonzero(visible), fbo)
        self.gl.finish()

    def release(self) -> None:
        self.drawer.release()
