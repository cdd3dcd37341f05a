"""The adaptive terrain renderer, frame by frame: quadtree selection by screen-space
error (:mod:`lodsprite.terrain.quadtree`), tiles streamed through the host and GPU caches
(:mod:`lodsprite.terrain.streaming`), geomorphed instanced drawing
(:mod:`lodsprite.gl.adaptive`).

A frame selects with what is resident, asks the loader for what it lacks (most urgent
first), uploads what has arrived (at most ``upload_budget`` tiles), and draws; it never
waits for I/O.  The roots are read before the first frame.  Near and far planes are fitted
to the terrain's bounds as the full-resolution renderer fits them.

It drives GL, so it lives here, above both terrain/ (the selection and the caches, which
know no GL) and gl/ (the draw, which knows no technique).
"""

from __future__ import annotations

import time

import numpy as np

from lodsprite.camera import Viewpoint, fitted_projection, frustum_planes
from lodsprite.errors import InputError
from lodsprite.record import Frame
from lodsprite.terrain.quadtree import (
    DEFAULT_GRID,
    MORPH_SPAN,
    Node,
    Quadtree,
    ranges,
    selection_counts,
)
from lodsprite.terrain.streaming import SlotCache, tile_loader

#: An adaptive frame's own columns (in :attr:`~lodsprite.record.Frame.extra`): quadtree
#: ``nodes`` drawn, tiles ``uploaded`` this frame, ``resident`` on the GPU, ``loaded`` and
#: ``evicted`` so far, ``bad`` tiles.
ADAPTIVE_COLUMNS = ("nodes", "uploaded", "resident", "loaded", "evicted", "bad")


class AdaptiveTerrain:
    """A pyramid (store or :class:`~lodsprite.terrain.pyramid.MemoryPyramid`) drawn into
    ``target`` at ``sse_px`` pixels of screen-space error."""

    def __init__(self, gl, pyramid, target, fov_y_deg: float, sse_px: float = 1.0,
                 grid: int = DEFAULT_GRID, gpu_mb: float = 256.0, host_mb: float = 512.0,
                 upload_budget: int = 16, color=None, clip=None) -> None:
        from lodsprite.gl.adaptive import AdaptiveDrawer

        if not sse_px > 0:
            raise InputError(f"--sse must be > 0 pixels, got {sse_px}")
        if not gpu_mb > 0:
            raise InputError(f"the GPU cache budget must be > 0 MB, got {gpu_mb}")
        self.gl, self.target, self.fov = gl, target, float(fov_y_deg)
        self.tree = Quadtree(pyramid, grid)
        self.sse = float(sse_px)
        self.r = ranges(pyramid.level_errors, sse_px, target.size[1], fov_y_deg,
                        self.tree.node_diagonals())
        self.loader = tile_loader(self.tree, host_mb)
        tile_bytes = (grid + 1) ** 2 * 4
        self.drawer = AdaptiveDrawer(gl, grid, max(1, int(gpu_mb * 2 ** 20 // tile_bytes)))
        self.slots = SlotCache(self.drawer.capacity)
        self.upload_budget = int(upload_budget)
        self.bounds = self.tree.box()
        # the height ramp of terrain_shade: level 0's range, as full resolution's
        self.height_range = self.tree.height_range()
        x = np.array([self.bounds[0][0], self.bounds[1][0]])
        y = np.array([self.bounds[0][1], self.bounds[1][1]])
        self.color = color  # the terrain's colour texture (a moderngl texture) or None
        self.clip = clip  # with it, the imagery's clipmap (gl.clipmap.ClipmapGL) or None
        self.extent = (float(x.min()), float(y.max()), float(x.max() - x.min()),
                       float(y.max() - y.min()))
        self._wanted: list[Node] = []
        self.last_draw: list[Node] = []        # the last frame's selection (for replays)
        self.last_morphed: frozenset = frozenset()
        self._last_eye: np.ndarray | None = None  # the eye the last selection was made at
        self._keep: set = set()
        self.pinned: set = set()  # nodes whose slots stay (a sprite proxy's frozen nodes)
        # a tile update's requests and nodes kept so far (None: each selection its own)
        self.gathering: tuple[list, set] | None = None
        self._ranges_key: tuple[float, ...] | None = None  # triangles_at's ranges, per
        self._ranges = np.zeros((0, self.tree.levels))       # tolerance, for these
        roots = self.roots = self.tree.roots()
        if len(roots) > self.slots.capacity:
            raise InputError("the GPU cache cannot hold the coarsest level: raise its budget")
        for n in roots:
            data = self.loader.read_now(n)
            if data is None:
                raise InputError(f"the coarsest level of {getattr(pyramid, 'path', 'the')} "
                                 "store is unreadable")
            self._upload(n, data, set())

    def set_sse(self, sse_px: float) -> None:
        """A new screen-space error tolerance (pixels): the LOD ranges recomputed."""
        from lodsprite.errors import InputError

        if not sse_px > 0:
            raise InputError(f"--sse must be > 0 pixels, got {sse_px}")
        self.sse = float(sse_px)
        self.r = ranges(self.tree.errors, self.sse, self.target.size[1], self.fov,
                        self.tree.node_diagonals())

    def triangles_at(self, viewpoint: Viewpoint, tolerances: tuple[float, ...]) -> np.ndarray:
        """The triangles a frame from ``viewpoint`` would draw at each tolerance (pixels)
        once its tiles are resident, ``(len(tolerances),) float64``, from one traversal
        (:func:`~lodsprite.terrain.quadtree.selection_counts`): the scene budget's
        prediction of the terrain's work at every setting."""
        key = tuple(float(t) for t in tolerances)
        if self._ranges_key != key:
            diag = self.tree.node_diagonals()
            self._ranges = np.array([ranges(self.tree.errors, t, self.target.size[1],
                                            self.fov, diag) for t in key])
            self._ranges_key = key
        view_proj = self.projection(viewpoint) @ viewpoint.view_matrix()
        nodes = selection_counts(self.tree, np.asarray(viewpoint.o, np.float64),
                                 frustum_planes(view_proj), self._ranges)
        return nodes * 2.0 * self.tree.g ** 2

    def projection(self, viewpoint: Viewpoint) -> np.ndarray:
        w, h = self.target.size
        ground = self.ground_below(viewpoint.o)
        return fitted_projection(viewpoint, self.fov, w / h, *self.bounds, ground).matrix()

    def ground_below(self, eye) -> float:
        """A height at or above the ground under ``eye`` (:meth:`Quadtree.ground_below`)."""
        return self.tree.ground_below(eye)

    def _upload(self, node: Node, data: np.ndarray, keep: set) -> bool:
        slot = self.slots.assign(node, keep)
        if slot is None:
            return False
        self.drawer.upload(slot, data)
        return True

    def render_into(self, viewpoint: Viewpoint, projection, target, cull=None):
        """Draw into ``target`` through ``projection`` (a :class:`~lodsprite.camera.
        Projection`; the LOD-sprite keyframe hook); returns what it drew
        (:func:`~lodsprite.gl.terrain.draw_stats`).  Selection uses the target's height
        for screen error.  ``cull``:
        a ``(4, 4)`` matrix whose frustum the quadtree is culled by instead of the view's
        (a keyframe tile's sub-frustum; draw it with ``target.fbo.scissor`` set to the
        tile)."""
        from lodsprite.gl.terrain import draw_stats

        f = self.frame(viewpoint, projection.matrix(), target, finish=False, cull=cull)
        return draw_stats(f.triangles, f.extra["nodes"], projection)

    def frame(self, viewpoint: Viewpoint, projection: np.ndarray | None = None,
              target=None, finish: bool = True, cull=None) -> Frame:
        """Select, stream and draw one frame (into ``target``, default the renderer's own,
        through ``projection``, default fitted to the terrain; the selection culled by
        the frustum of ``cull (4, 4)`` when given)."""
        t0 = time.perf_counter()
        target = target if target is not None else self.target
        proj = self.projection(viewpoint) if projection is None else projection
        view_proj = proj @ viewpoint.view_matrix()
        eye = np.asarray(viewpoint.o, dtype=np.float64)
        draw, uploaded = self._stream(eye, view_proj if cull is None else cull)
        self.last_draw, self._last_eye = draw, eye
        if self.clip is not None and self.color is not None:
            self.clip.update(eye)  # never waits: uploads what arrived
        self.drawer.draw(target.fbo, view_proj, eye, self._instances(draw),
                           self.height_range, self.extent, self.color, self.clip)
        if finish:
            self.gl.finish()
        return Frame("adaptive", (time.perf_counter() - t0) * 1e3, self.drawer.triangles,
                     extra=dict(zip(ADAPTIVE_COLUMNS, (
                         len(draw), uploaded, len(self.slots.slots), self.loader.loaded,
                         self.slots.evicted, len(self.loader.bad)), strict=True)))

    def deficit_px(self) -> float:
        """What the last frame drawn lacks (pixels): the largest screen-space error, at
        the eye it was selected at, of the nodes it drew coarser than its tolerance asks
        because their finer nodes were not resident (the selection wanted to split them:
        ``d < R_k``) and whose error exceeds the tolerance; 0 when none does.  Nodes with
        a child that cannot be read (the loader's ``bad``) are left out: no refresh can
        draw them finer.  A frame drawn after every tile it wants has arrived lacks 0."""
        eye = self._last_eye
        nodes = [n for n in self.last_draw if n.k > 0]
        if eye is None or not nodes:
            return 0.0
        box = [self.tree.bounds(n) for n in nodes]
        lo, hi = np.array([b[0] for b in box]), np.array([b[1] for b in box])
        d = np.linalg.norm(np.clip(eye, lo, hi) - eye, axis=1)
        k = np.array([n.k for n in nodes])
        bad = self.loader.bad
        split = (d < self.r[k]) & np.array([not any(c in bad for c in self.tree.kids(n))
                                            for n in nodes])
        h = self.target.size[1]
        err = self.tree.errors[k] * h / (2.0 * np.maximum(d, 1e-9)
                                         * np.tan(np.radians(self.fov) / 2))
        over = err[split & (err > self.sse)]
        return float(over.max()) if over.size else 0.0

    def _stream(self, eye: np.ndarray, view_proj: np.ndarray) -> tuple[list[Node], int]:
        """Select the nodes to draw, ask the loader for what is missing and upload what
        has arrived (at most ``upload_budget``); returns the nodes and the uploads."""
        draw, want = self.tree.select(eye, frustum_planes(view_proj), self.r,
                                      self.slots.__contains__)
        # a root evicted (off-screen, LRU) comes back first: its region would be a hole
        want += [(float("inf"), n) for n in self.roots if n not in self.slots]
        keep = set(self.roots) | self.pinned
        for n in draw:
            while n.k <= self.tree.top and n not in keep:
                keep.add(n)
                n = n.parent()
        if self.gathering is not None:  # a tile update: every tile's wants, not the last's
            self.gathering[0].extend(want)
            self.gathering[1].update(keep)
            want, keep = self.gathering
        self.loader.want(want)
        self._wanted, self._keep = [n for _, n in sorted(want, key=lambda u: -u[0])], keep
        return draw, self._upload_arrived()

    def _upload_arrived(self) -> int:
        """Upload what has arrived of the last selection's wish list, most urgent first
        (at most ``upload_budget``)."""
        uploaded = 0
        for n in self._wanted:
            if uploaded >= self.upload_budget:
                break
            data = self.loader.take(n)
            if data is not None and n not in self.slots and self._upload(n, data, self._keep):
                uploaded += 1
        if uploaded:  # what is resident is not looked for again (prefetch, every frame)
            self._wanted = [n for n in self._wanted if n not in self.slots]
        return uploaded

    def prefetch(self) -> int:
        """Between frames drawn by this renderer (LOD-sprite's spriteframes): go on
        streaming the last selection's tiles and upload what has arrived, so the next
        keyframe finds them resident; returns the tiles uploaded."""
        pump = getattr(self.loader, "pump", None)
        if pump is not None:
            pump()
        return self._upload_arrived()

    def fill(self, viewpoint: Viewpoint, projection: np.ndarray | None = None,
             max_rounds: int = 100000) -> int:
        """Stream the tiles ``viewpoint`` wants through ``projection (4, 4)`` (default
        :meth:`projection`) until none is left to load, uploading them all (untimed use
        only: this waits; warm-ups and references); returns the tiles uploaded."""
        proj = self.projection(viewpoint) if projection is None else projection
        view_proj = proj @ viewpoint.view_matrix()
        eye = np.asarray(viewpoint.o, dtype=np.float64)
        total = 0
        for _ in range(max_rounds):
            _, uploaded = self._stream(eye, view_proj)
            total += uploaded
            if uploaded == 0 and self.loader.idle():
                late = self._stream(eye, view_proj)[1]  # what arrived meanwhile
                total += late
                if late == 0:
                    break
            elif uploaded == 0:
                time.sleep(0.002)
        return total

    def settle(self, viewpoint: Viewpoint, max_rounds: int = 100000) -> Frame:
        """Stream ``viewpoint``'s tiles until none it wants is left to load (:meth:`fill`),
        then draw it (a converged image, untimed use only); returns that frame."""
        self.fill(viewpoint, None, max_rounds)
        return self.frame(viewpoint)

    def redraw(self, viewpoint: Viewpoint, draw: tuple[Node, ...], morphed: frozenset,
               projection=None, target=None) -> None:
        """Draw a recorded selection again (an untimed replay): the nodes ``draw`` (a
        frame's :attr:`last_draw`), geomorphed towards their parents for the nodes in
        ``morphed`` (its :attr:`last_morphed`); tiles not resident are read now.  Into
        ``target`` through ``projection`` (a :class:`~lodsprite.camera.Projection`) when
        given, as :meth:`render_into` draws."""
        self.make_resident(list(draw) + [n.parent() for n in morphed])
        proj = self.projection(viewpoint) if projection is None else projection.matrix()
        view_proj = proj @ viewpoint.view_matrix()
        eye = np.asarray(viewpoint.o, dtype=np.float64)
        target = self.target if target is None else target
        if self.clip is not None and self.color is not None:
            self.clip.update(eye)
        self.drawer.draw(target.fbo, view_proj, eye, self._instances(list(draw), morphed),
                           self.height_range, self.extent, self.color, self.clip)
        self.gl.finish()

    def make_resident(self, need: list[Node]) -> None:
        """Read the nodes of ``need`` not resident now and upload them, keeping ``need``,
        the roots and :attr:`pinned` (untimed replays only: this reads storage)."""
        keep = set(need) | set(self.roots) | self.pinned
        for n in need:
            if n not in self.slots:
                data = self.loader.read_now(n)
                if data is not None:
                    self._upload(n, data, keep)

    def _instances(self, draw: list[Node], morphed: frozenset | None = None) -> np.ndarray:
        """Per node: world origin, spacing, slots, quadrant, morph range, valid extent, and
        the parent's valid extent (a node morphs towards its parent when that is resident,
        or, in a replay, when it is in ``morphed``); :attr:`last_morphed` keeps which did."""
        out, used = self.instances(draw, morphed, self.r)
        self.last_morphed = used
        return out

    def instances(self, draw: list[Node], morphed: frozenset | None,
                  r: np.ndarray) -> tuple[np.ndarray, frozenset]:
        """``(instances (N, 16) float32, the nodes that morph)`` for ``draw`` with the
        morph ranges of the range table ``r`` (metres per level): :meth:`_instances`."""
        out = np.zeros((len(draw), 16), np.float32)
        g = self.tree.g
        used = set()
        for m, n in enumerate(draw):
            self.slots.touch(n)
            r0, r1, c0, c1 = self.tree.samples(n)
            x, y = self.tree.world_xy(n.k, np.array([r0]), np.array([c0]))
            s = 1 << n.k
            parent = n.parent()
            if n.k < self.tree.top and parent in self.slots and (morphed is None
                                                                  or n in morphed):
                used.add(n)
                ps, qr, qc = self.slots.slot(parent), n.i % 2, n.j % 2
                end = r[n.k + 1]
                start = end - MORPH_SPAN * (r[n.k + 1] - r[n.k])
                pr0, pr1, pc0, pc1 = self.tree.samples(parent)
                prow, pcol = pr1 - pr0 - 1, pc1 - pc0 - 1
            else:
                ps, qr, qc, start, end, prow, pcol = -1, 0, 0, 0.0, 1.0, 0, 0
            out[m] = (x[0], y[0], s * self.tree.p.dx, s * self.tree.p.dy,
                      self.slots.slot(n), ps, qr, qc, start, end,
                      min(g, r1 - r0 - 1), min(g, c1 - c0 - 1), prow, pcol, 0.0, 0.0)
        return out, frozenset(used)

    def node_heights(self, n: Node) -> np.ndarray:
        """A resident node's samples ``(rows, cols) float32``: from the host cache, else
        read back from its GPU slot (never from storage)."""
        data = self.loader.cache.get(n)
        if data is None:
            r0, r1, c0, c1 = self.tree.samples(n)
            data = self.drawer.read_tile(self.slots.slot(n), r1 - r0, c1 - c0)
        return data

    def release(self) -> None:
        self.loader.close()
        self.drawer.release()
