"""The reference image of a terrain: level 0's own samples at full resolution, a code path
independent of the adaptive renderer (issue 22, "an honest measure at scale").

Level 0 (of a :class:`~lodsprite.terrain.store.TerrainStore`, or an in-memory
:class:`~lodsprite.terrain.heightfield.HeightField`) is drawn by the full-resolution
:class:`~lodsprite.gl.terrain.TerrainRenderer`: whole when its longer side is at most
``max_side`` samples (4097), beyond that the part of it in view: the frustum's ground
footprint (:func:`lodsprite.camera.view_footprint`) widened by two samples (so that the
per-pixel normals of the heights shading see the same neighbours as the whole level's) and
read with ``TerrainStore.read`` as a window of at most ``max_side²`` samples, drawn at its
place (world coordinates of the adaptive renderer, :meth:`lodsprite.terrain.quadtree.
Quadtree.world_xy`: level 0 centred on the origin, x east, y north, metres).  A view whose
footprint needs more gets no image (:meth:`LevelZeroReference.image` returns None and
:meth:`~LevelZeroReference.describe` says why).

Near and far planes are fitted as the adaptive renderer fits them (:meth:`Quadtree.box`,
:meth:`Quadtree.ground_below`), and the height ramp of the shading spans level 0's range,
so that the same viewpoint gives the same projection and colours in both.
"""

from __future__ import annotations

import math

import numpy as np

from lodsprite.camera import Projection, Viewpoint, fitted_projection, view_footprint
from lodsprite.errors import InputError
from lodsprite.gl.context import GLContext
from lodsprite.gl.terrain import TerrainGeometry, TerrainRenderer
from lodsprite.terrain.heightfield import HeightField
from lodsprite.terrain.pyramid import MemoryPyramid
from lodsprite.terrain.quadtree import Quadtree

MAX_SIDE = 4097  # level-0 samples a side drawn at once (a 4096-quad grid)
MARGIN = 2       # samples around the footprint (central differences of its edge cells)


class LevelZeroReference:
    """Reference frames of ``size = (w, h)`` pixels, vertical field of view ``fov_y_deg``,
    coloured by ``shading`` (``heights``: terrain_shade with per-pixel normals; ``texture``:
    ``texture (H, W, 3) uint8`` over level 0's extent, whole level only; ``auto``: heights
    for a store, the texture for an in-memory field given one).  ``store_or_field``: a
    :class:`~lodsprite.terrain.store.TerrainStore` (exaggerated as opened) or a
    :class:`HeightField` (centred on the origin).  GPU objects live until :meth:`release`."""

    def __init__(self, ctx: GLContext, store_or_field, size: tuple[int, int],
                 fov_y_deg: float = 45.0, shading: str = "heights",
                 texture: np.ndarray | None = None, max_side: int = MAX_SIDE) -> None:
        if shading == "auto":  # as --shading auto: heights for a store, else the texture
            texture_ok = texture is not None and isinstance(store_or_field, HeightField)
            shading = "texture" if texture_ok else "heights"
        if shading not in ("heights", "texture"):
            raise InputError(f"the reference shades by auto, heights or texture, not "
                             f"{shading!r}")
        if shading == "texture" and texture is None:
            raise InputError("a texture-shaded reference needs the texture")
        self.ctx, self.size, self.fov = ctx, (int(size[0]), int(size[1])), float(fov_y_deg)
        self.shading, self.texture, self.max_side = shading, texture, int(max_side)
        field = store_or_field if isinstance(store_or_field, HeightField) else None
        self.pyramid = MemoryPyramid.from_heightfield(field) if field is not None \
            else store_or_field
        self.tree = Quadtree(self.pyramid)
        self.rows, self.cols = self.tree.rows0, self.tree.cols0
        self.whole = max(self.rows, self.cols) <= self.max_side
        self.height_range = self.tree.height_range()
        self._field = field
        self._window: tuple[int, int, int, int] | None = None  # r0, r1, c0, c1 (exclusive)
        self._drawer: tuple[TerrainGeometry, TerrainRenderer] | None = None
        self._note = ""

    def projection(self, viewpoint: Viewpoint) -> Projection:
        """The adaptive renderer's projection at ``viewpoint``: near/far fitted to the
        terrain's box and the ground under the eye."""
        w, h = self.size
        return fitted_projection(viewpoint, self.fov, w / h, *self.tree.box(),
                                 self.tree.ground_below(np.asarray(viewpoint.o)))

    def window(self, viewpoint: Viewpoint, projection: Projection) -> tuple[int, ...] | None:
        """Level 0's sample window ``(r0, r1, c0, c1)`` (``r1``, ``c1`` exclusive) under the
        view's footprint, widened by :data:`MARGIN`; None when nothing is in view."""
        lo, hi = self.tree.box()
        lo[2] = min(lo[2], self.height_range[0])
        hi[2] = max(hi[2], self.height_range[1])
        fp = view_footprint(projection.matrix() @ viewpoint.view_matrix(), lo, hi)
        if fp is None:
            return None
        (x0, y0), (x1, y1) = fp
        dx, dy = self.pyramid.dx, self.pyramid.dy
        c0 = x0 / dx + (self.cols - 1) / 2.0
        c1 = x1 / dx + (self.cols - 1) / 2.0
        r0 = (self.rows - 1) / 2.0 - y1 / dy
        r1 = (self.rows - 1) / 2.0 - y0 / dy
        return (max(0, math.floor(r0) - MARGIN), min(self.rows, math.ceil(r1) + MARGIN + 1),
                max(0, math.floor(c0) - MARGIN), min(self.cols, math.ceil(c1) + MARGIN + 1))

    def image(self, viewpoint: Viewpoint, projection: Projection | None = None
              ) -> np.ndarray | None:
        """The reference frame ``(h, w, 3) uint8`` at ``viewpoint`` (through ``projection``,
        default :meth:`projection`), or None when level 0 in view exceeds ``max_side²``."""
        projection = projection or self.projection(viewpoint)
        if self.whole:
            win = (0, self.rows, 0, self.cols)
        else:
            win = self.window(viewpoint, projection)
            if win is None:
                win = (0, 2, 0, 2)  # nothing of the terrain in view: the sky
            if max(win[1] - win[0], win[3] - win[2]) > self.max_side:
                self._note = (f"the view's footprint needs {win[3] - win[2]}x{win[1] - win[0]} "
                              f"level-0 samples, more than {self.max_side} a side: no image")
                return None
        if self.shading == "texture" and not self.whole:
            self._note = "texture shading needs level 0 whole: no image"
            return None
        _, renderer = self._drawer_for(win)
        renderer.render(viewpoint, None, projection)
        self.ctx.finish()
        return renderer.target.read_color()

    def _drawer_for(self, win: tuple[int, int, int, int]) -> tuple[TerrainGeometry,
                                                                    TerrainRenderer]:
        """Geometry and renderer of level 0's window ``win`` (made again when it moves)."""
        if self._drawer is not None and self._window == win:
            return self._drawer
        self._release_drawer()
        r0, r1, c0, c1 = win
        if self._field is not None:
            heights = self._field.heights[r0:r1, c0:c1]
        else:
            heights = self.pyramid.read(0, r0, r1, c0, c1)
        hf = HeightField(heights, self.pyramid.dx, self.pyramid.dy, "level 0")
        x, y = self.tree.world_xy(0, np.array([r0]), np.array([c0]))
        corner = None if self.whole else (float(x[0]), float(y[0]))
        geometry = TerrainGeometry(self.ctx, hf, self.texture, corner=corner,
                                   height_range=self.height_range)
        renderer = TerrainRenderer(self.ctx, geometry, *self.size, self.fov)
        renderer.shading = self.shading
        self._drawer, self._window = (geometry, renderer), win
        self._note = (f"level 0 whole, {self.cols}x{self.rows} samples" if self.whole else
                      f"level-0 window rows {r0}:{r1}, columns {c0}:{c1} of "
                      f"{self.cols}x{self.rows} samples (the view's footprint)")
        return self._drawer

    def describe(self) -> str:
        """How the reference is made, and for the last view what was drawn (or why not)."""
        how = ("level 0 whole" if self.whole else
               f"level-0 windows cropped to the view's footprint (at most {self.max_side} "
               "samples a side)")
        last = f"; last view: {self._note}" if self._note else ""
        return (f"full resolution, {how}, of {self.cols}x{self.rows} samples; "
                f"{self.shading} shading; near/far fitted as the adaptive renderer's{last}")

    def _release_drawer(self) -> None:
        if self._drawer is not None:
            geometry, renderer = self._drawer
            renderer.release()
            geometry.release()
        self._drawer, self._window = None, None

    def release(self) -> None:
        self._release_drawer()
