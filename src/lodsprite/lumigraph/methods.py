"""The reconstruction methods of Sloan, Cohen & Gortler (1997), frame by frame.

Each method turns a viewpoint into a reconstruction in its float target and reports what
the frame cost (GL work finished before each clock stops):

* ``full`` - every node (§2.3).
* ``subsample`` - level ``level`` of the 4D mipmap: every ``2**level``-th st node, uv
  images decoded at ``1/2**level`` (§3.1).
* ``fixed`` - the 9 nodes round the eye's st point, plus fictitious corners (Figure 3);
  the block moves when the eye's nearest node leaves its centre.
* ``arbitrary`` - the ``nodes`` nearest the eye's st point, any subset, triangulated.
* ``line`` - the row or column of nodes along the predicted motion, drawn as strips.
* ``projective`` - §3.2: every ``reuse`` frames a reconstruction (``arbitrary``) at the
  viewpoint predicted for the end of the cycle, warped on the approximate geometry in
  between.
* ``progressive`` - §3.3: the ``arbitrary`` set, nodes blended in and out over ``fade``
  frames through their validity.
* ``critical`` - §4: benefit/cost selection under a time and a texture-memory budget,
  nodes fetched and decoded in the loader's process (:class:`CriticalMethod`).

Except for ``critical``, a method that needs a node not yet decoded decodes it in the
frame (its "texture load" in Table 1 terms).
"""

from __future__ import annotations

import time

import numpy as np

from lodsprite.camera import Viewpoint
from lodsprite.errors import InputError
from lodsprite.gl.lumigraph import FloatTarget
from lodsprite.gl.projective import ProjectiveDrawer
from lodsprite.lumigraph.base import FRAME_S, Context, Method, method_frame
from lodsprite.lumigraph.critical import st_point
from lodsprite.lumigraph.geometry import facing_slab
from lodsprite.lumigraph.subsets import (
    cover_draws,
    grid_cover,
    line_draws,
    nearest_block,
    nearest_nodes,
    subsample_nodes,
    subset_cover,
)
from lodsprite.record import Frame

__all__ = ["FRAME_S", "METHODS", "Context", "Method", "MultiSlabMethod",
           "make_method"]

METHODS = ("full", "subsample", "fixed", "arbitrary", "line", "projective", "progressive",
           "critical")


class FullMethod(Method):
    name = "full"

    def __init__(self, ctx: Context) -> None:
        n = ctx.lf.slabs[ctx.slab_index].n_st
        super().__init__(ctx, n * n)
        self.all = np.arange(n * n)

    def choose(self, index, viewpoint):
        return self.all

    def draws(self, nodes, valid, viewpoint):
        return cover_draws(grid_cover(self.slab, valid))


class SubsampleMethod(Method):
    name = "subsample"

    def __init__(self, ctx: Context, level: int = 1) -> None:
        n = ctx.lf.slabs[ctx.slab_index].n_st
        if not 0 <= level <= 4 or (n - 1) >> level < 1:
            raise InputError(f"subsample level must be 0..4 and leave 2 nodes a side, "
                             f"got {level}")
        self.nodes = subsample_nodes(n, level)
        super().__init__(ctx, len(self.nodes), level)

    def choose(self, index, viewpoint):
        return self.nodes

    def draws(self, nodes, valid, viewpoint):
        return cover_draws(subset_cover(self.slab, nodes, valid, ring=False))


class FixedMethod(Method):
    name = "fixed"

    def __init__(self, ctx: Context) -> None:
        super().__init__(ctx, 9)
        self.block: np.ndarray | None = None

    def choose(self, index, viewpoint):
        centre = nearest_nodes(self.slab, self.eye_st(viewpoint), 1)[0]
        if self.block is None or centre not in self.block[[4]]:
            # moves only once the eye's nearest node is no longer the block's centre
            self.block = nearest_block(self.slab, self.eye_st(viewpoint), 3)
        return self.block


class ArbitraryMethod(Method):
    name = "arbitrary"

    def __init__(self, ctx: Context, nodes: int = 16) -> None:
        if not 1 <= nodes <= ctx.lf.slabs[ctx.slab_index].n_st ** 2:
            raise InputError(f"--nodes must be 1..{ctx.lf.slabs[ctx.slab_index].n_st ** 2}, "
                             f"got {nodes}")
        super().__init__(ctx, nodes)
        self.count = nodes

    def choose(self, index, viewpoint):
        return np.sort(nearest_nodes(self.slab, self.eye_st(viewpoint), self.count))


class LineMethod(Method):
    name = "line"

    def __init__(self, ctx: Context) -> None:
        super().__init__(ctx, ctx.lf.slabs[ctx.slab_index].n_st)
        self.direction = np.array([1.0, 0.0])

    def choose(self, index, viewpoint):
        st = self.eye_st(viewpoint)
        ahead = st_point(self.slab, self.predictor.predict(0.5).o) - st
        if np.linalg.norm(ahead) > 1e-9:
            self.direction = ahead
        self._draws = line_draws(self.slab, st, self.direction)
        return self._draws.nodes

    def draws(self, nodes, valid, viewpoint):
        return self._draws


class ProgressiveMethod(Method):
    name = "progressive"
    dynamic = True  # validities change every frame while nodes fade

    def __init__(self, ctx: Context, nodes: int = 16, fade: int = 8) -> None:
        super().__init__(ctx, 2 * nodes)
        self.count, self.step = nodes, 1.0 / max(1, fade)
        self.validity: dict[int, float] = {}

    def choose(self, index, viewpoint):
        target = set(int(n) for n in nearest_nodes(self.slab, self.eye_st(viewpoint),
                                                    self.count))
        for n in target | set(self.validity):
            v = self.validity.get(n, 0.0) + (self.step if n in target else -self.step)
            self.validity[n] = min(1.0, v)
            if self.validity[n] <= 0.0:
                del self.validity[n]
                self.rec.evict(n)
        # texture memory holds 2 x nodes: past that, the faintest fading nodes go at once
        fading = sorted((v, n) for n, v in self.validity.items() if n not in target)
        while len(self.validity) > self.rec.capacity and fading:
            _, n = fading.pop(0)
            del self.validity[n]
            self.rec.evict(n)
        return np.array(sorted(self.validity), dtype=np.int64)

    def draws(self, nodes, valid, viewpoint):
        v = np.array([self.validity[int(n)] for n in nodes]) * valid
        return cover_draws(subset_cover(self.slab, nodes, v))

    @property
    def partial(self) -> float:
        """The fraction of drawn nodes with partial validity (Table 1's x)."""
        v = np.array(list(self.validity.values()))
        return float(np.mean(v < 1.0)) if len(v) else 0.0


class ProjectiveMethod(ArbitraryMethod):
    name = "projective"

    def __init__(self, ctx: Context, nodes: int = 16, reuse: int = 6) -> None:
        super().__init__(ctx, nodes)
        if ctx.proxy is None:
            raise InputError("the projective method needs the approximate geometry "
                             "(depth correction on)")
        mesh = ctx.lf.proxy()
        self.proj = ProjectiveDrawer(ctx.gl, mesh.vertices, mesh.faces, *ctx.size)
        self.reuse = max(1, int(reuse))

    @property
    def output(self) -> FloatTarget:
        return self.proj

    def frame(self, index, viewpoint, projection, count_samples=False):
        self.predictor.observe(index * FRAME_S, viewpoint)
        if index % self.reuse == 0 or self.proj.key_view_proj is None:
            # a new image, from where the eye is predicted to be half a cycle on
            ahead = self.predictor.predict(self.reuse * FRAME_S / 2) if index else viewpoint
            key = Viewpoint(viewpoint.x, viewpoint.y, viewpoint.z, ahead.o)
            t0 = time.perf_counter()
            f = super().frame(index, key, projection, observe=False)
            self.proj.take(self.rec, projection @ key.view_matrix())
            self.ctx.gl.finish()
            extra = (time.perf_counter() - t0) * 1e3 - f.ms
        else:
            f, extra = method_frame(0.0, 0.0, 0.0, 0, 0, 0, "reuse"), 0.0
        t1 = time.perf_counter()
        self.proj.render(viewpoint.view_matrix(), projection, count_samples)
        self.ctx.gl.finish()
        warp = (time.perf_counter() - t1) * 1e3
        self.samples = self.proj.samples
        kind = "reuse" if f.kind == "reuse" else "keyframe"
        x = f.extra
        return method_frame(f.ms + extra + warp, x["upload_ms"], x["raster_ms"] + extra + warp,
                            x["images"], x["uploads"], x["evictions"], kind)

    def release(self) -> None:
        self.proj.release()
        super().release()


class MultiSlabMethod:
    """A method over a lumigraph of several slabs: each frame uses the slab facing the eye
    (:func:`~lodsprite.lumigraph.geometry.facing_slab`), through its own instance of the
    method, made when the eye first comes round to it; the previous slab's instance is
    released on a switch, so texture memory holds one slab at a time."""

    def __init__(self, ctx: Context, name: str, options: dict) -> None:
        self.ctx, self.name, self.options = ctx, name, options
        self.current: Method | None = None
        self.slab_index = -1
        self.switches = 0

    def _for(self, viewpoint: Viewpoint, projection: np.ndarray) -> Method:
        k = facing_slab(self.ctx.lf.slabs, viewpoint.o)
        if k != self.slab_index:
            if self.current is not None:
                self.current.release()
                self.switches += 1
            ctx = Context(self.ctx.gl, self.ctx.lf, k, self.ctx.size, self.ctx.proxy,
                          self.ctx.white)
            self.current = make_method(self.name, ctx, **self.options)
            self.slab_index = k
            if hasattr(self.current, "warm_up"):
                self.current.warm_up(viewpoint, projection)
        return self.current

    def warm_up(self, viewpoint: Viewpoint, projection: np.ndarray) -> None:
        self._for(viewpoint, projection)

    def frame(self, index: int, viewpoint: Viewpoint, projection: np.ndarray,
              count_samples: bool = False) -> Frame:
        """A frame on the facing slab; a switch (the new slab's method made, and warmed
        up for ``critical``) is timed as part of the frame."""
        from dataclasses import replace as _replace

        t0 = time.perf_counter()
        before = self.slab_index
        method = self._for(viewpoint, projection)
        switch_ms = (time.perf_counter() - t0) * 1e3
        f = method.frame(index, viewpoint, projection, count_samples)
        if self.slab_index != before and before >= 0:
            f = _replace(f, ms=f.ms + switch_ms, kind="switch")
        return f

    @property
    def target_ms(self) -> float:
        return self.current.target_ms

    @target_ms.setter
    def target_ms(self, value: float) -> None:  # kept for the next slab's method too
        self.current.target_ms = value
        self.options["target_fps"] = 1e3 / value

    def __getattr__(self, name: str):
        current = self.__dict__.get("current")
        if current is None:
            raise AttributeError(name)
        return getattr(current, name)

    def release(self) -> None:
        if self.current is not None:
            self.current.release()
            self.current = None


def make_method(name: str, ctx: Context, nodes: int = 16, level: int = 1, reuse: int = 6,
                fade: int = 8, target_fps: float = 30.0, texture_mb: float = 4.0,
                **critical) -> Method:
    """The method ``name`` of :data:`METHODS` with its options."""
    if name == "full":
        return FullMethod(ctx)
    if name == "subsample":
        return SubsampleMethod(ctx, level)
    if name == "fixed":
        return FixedMethod(ctx)
    if name == "arbitrary":
        return ArbitraryMethod(ctx, nodes)
    if name == "line":
        return LineMethod(ctx)
    if name == "projective":
        return ProjectiveMethod(ctx, nodes, reuse)
    if name == "progressive":
        return ProgressiveMethod(ctx, nodes, fade)
    if name == "critical":
        from lodsprite.lumigraph.timecritical import CriticalMethod

        return CriticalMethod(ctx, target_fps, texture_mb, **critical)
    raise InputError(f"unknown lumigraph method {name!r}: use one of {', '.join(METHODS)}")
