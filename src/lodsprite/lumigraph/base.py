"""What every lumigraph reconstruction method shares: the frame record, the context and
the base :class:`Method` over a pool of resident nodes (see :mod:`lodsprite.lumigraph.
methods` for the methods themselves and :mod:`lodsprite.lumigraph.timecritical` for the
critical-time one).

Its own module so that ``methods`` (which makes every method by name) and
``timecritical`` (a method too) both build on it without importing each other.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from lodsprite.camera import Viewpoint
from lodsprite.gl.lumigraph import ColorMeshDrawer, FloatTarget, LumigraphDrawer
from lodsprite.lumigraph.critical import st_point
from lodsprite.lumigraph.geometry import Slab
from lodsprite.lumigraph.loader import NodeLoader
from lodsprite.lumigraph.store import Lumigraph
from lodsprite.lumigraph.subsets import cover_draws, grid_cover, subset_cover
from lodsprite.record import Frame
from lodsprite.sprite.predictors import DecayLinearPredictor

FRAME_S = 1.0 / 30.0  # the nominal time between frames, for the motion predictor


#: A method frame's own columns (in :attr:`~lodsprite.record.Frame.extra`): of its ``ms``,
#: ``upload_ms`` making nodes resident (decoding included where the method decodes in the
#: frame) and ``raster_ms`` drawing; node ``images`` drawn, ``uploads`` and ``evictions``.
METHOD_COLUMNS = ("upload_ms", "raster_ms", "images", "uploads", "evictions")


def method_frame(ms: float, upload_ms: float, raster_ms: float, images: int, uploads: int,
                 evictions: int, kind: str = "frame") -> Frame:
    """A lumigraph method's frame record: ``ms`` in all, the rest its own columns
    (:data:`METHOD_COLUMNS`)."""
    return Frame(kind, ms, extra=dict(zip(METHOD_COLUMNS, (upload_ms, raster_ms, images,
                                                           uploads, evictions), strict=True)))


@dataclass
class Context:
    """What every method needs: the GL context, the lumigraph and its slab, the output
    size and the approximate geometry's renderer (None: no depth correction)."""

    gl: object
    lf: Lumigraph
    slab_index: int
    size: tuple[int, int]
    proxy: ColorMeshDrawer | None
    white: bool = False  # every texel white: the image is the alpha sum (tests)


class Method:
    """A reconstruction method over a pool of resident nodes (see module doc)."""

    name = "base"

    def __init__(self, ctx: Context, capacity: int, level: int = 0) -> None:
        self.ctx = ctx
        self.slab = ctx.lf.slabs[ctx.slab_index]
        self.n_nodes = self.slab.n_st ** 2
        w, h = ctx.size
        self.rec = LumigraphDrawer(ctx.gl, self.slab, w, h, capacity, level)
        self.loader = NodeLoader(ctx.lf, ctx.slab_index, level)
        self.predictor = DecayLinearPredictor()
        self.samples = 0
        self._set: tuple[int, ...] | None = None

    @property
    def output(self) -> FloatTarget:
        return self.rec

    def eye_st(self, viewpoint: Viewpoint) -> np.ndarray:
        return st_point(self.slab, viewpoint.o)

    def ensure(self, nodes: np.ndarray) -> tuple[np.ndarray, int, int]:
        """Make ``nodes`` resident, decoding in this frame what the loader does not hold;
        returns the validity of each (0 for a node without data), uploads, evictions."""
        keep = {int(n) for n in nodes}
        valid = np.ones(len(nodes))
        ups = evs = 0
        for k, n in enumerate(int(x) for x in nodes):
            if n in self.rec.slot_of:
                continue
            img = self.loader.load_now(n)
            if img is None:
                valid[k] = 0.0
                continue
            if not self.rec.free_layers:
                out = next(m for m in self.rec.slot_of if m not in keep)
                self.rec.evict(out)
                evs += 1
            self.rec.upload(n, img)
            ups += 1
        return valid, ups, evs

    def choose(self, index: int, viewpoint: Viewpoint) -> np.ndarray:
        """The nodes this frame needs."""
        raise NotImplementedError

    def draws(self, nodes: np.ndarray, valid: np.ndarray, viewpoint: Viewpoint):
        return cover_draws(subset_cover(self.slab, nodes, valid))

    def frame(self, index: int, viewpoint: Viewpoint, projection: np.ndarray,
              count_samples: bool = False, observe: bool = True) -> Frame:
        gl = self.ctx.gl
        t0 = time.perf_counter()
        if observe:  # (the projective method observes the real eye, not its prediction)
            self.predictor.observe(index * FRAME_S, viewpoint)
        nodes = self.choose(index, viewpoint)
        valid, ups, evs = self.ensure(nodes)
        key = tuple(int(n) for n in nodes) + tuple(valid)
        if key != self._set or self.dynamic:
            self.rec.set_draws(self.draws(nodes, valid, viewpoint))
            self._set = key
        gl.finish()
        t1 = time.perf_counter()
        raster_ms = self.draw(viewpoint, projection, count_samples)
        return method_frame((t1 - t0) * 1e3 + raster_ms, (t1 - t0) * 1e3, raster_ms,
                           self.rec.images, ups, evs)

    def draw(self, viewpoint: Viewpoint, projection: np.ndarray, count_samples: bool
             ) -> float:
        """Reconstruct the current draws (ms, GL work finished)."""
        t0 = time.perf_counter()
        self.rec.render(viewpoint.view_matrix(), projection, self.ctx.proxy,
                        white=self.ctx.white, count_samples=count_samples)
        self.ctx.gl.finish()
        self.samples = self.rec.samples
        return (time.perf_counter() - t0) * 1e3

    dynamic = False  # draws change with the viewpoint even for the same nodes

    def release(self) -> None:
        self.loader.close()
        self.rec.release()


def full_reconstruction(gl: object, slab: Slab, images: dict[tuple[int, int], np.ndarray],
                        width: int, height: int) -> LumigraphDrawer:
    """A renderer with every node of ``images`` (``(i, j)`` -> uv image) resident, drawn
    over the full grid (nodes missing from ``images`` are fictitious)."""
    rec = LumigraphDrawer(gl, slab, width, height, max(len(images), 1))
    n = slab.n_st
    valid = np.zeros((n, n))
    for (i, j), img in images.items():
        rec.upload(i * n + j, img)
        valid[i, j] = 1.0
    rec.set_draws(cover_draws(grid_cover(slab, valid)))
    return rec
