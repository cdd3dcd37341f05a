"""The one reference image of a terrain: level 0 band-limited, drawn by a code path of
its own (:mod:`lodsprite.gl.bandlimited`), independent of every renderer it judges.

Level 0 (of a :class:`~lodsprite.terrain.store.TerrainStore`, or an in-memory
:class:`~lodsprite.terrain.heightfield.HeightField` at its full grid) is drawn at ``k x
k`` samples a pixel (``samples``, 4 by default) and filtered down to the image size
(:func:`lodsprite.bandlimit.resolve`: a box over each pixel's samples by default, in
linear light).  Every quality figure is taken against it: ``render --ground-truth``,
the played runs' display-time error, the distributed replay
(:mod:`lodsprite.distributed.quality`), ``reproduce large``
(:mod:`lodsprite.experiments.large.reference`), ``reproduce timecritical``.

Level 0 is drawn whole when its longer side is at most ``max_side`` samples (4097: a
4096-quad grid); beyond that the part of it in view: the frustum's ground footprint
(:func:`lodsprite.camera.view_footprint`) widened by two samples (so that the per-pixel
normals of the heights shading see the same neighbours as the whole level's), read with
``TerrainStore.read``, and drawn at its place (world coordinates of the adaptive
renderer, :meth:`lodsprite.terrain.quadtree.Quadtree.world_xy`: level 0 centred on the
origin, x east, y north, metres).  A footprint of more than ``max_side`` samples a side
is drawn in patches (:func:`tile_ranges`: at most ``max_side`` samples a side sharing
their edge samples, so no crack opens between them) into the same sample image, one
depth buffer for all.  At a patch's inner edge the per-pixel normals are one-sided (its
height texture ends there), a line one sample wide.

Near and far planes are fitted as the adaptive renderer fits them (:meth:`Quadtree.box`,
:meth:`Quadtree.ground_below`), and the height ramp of the shading spans level 0's range,
so that the same viewpoint gives the same projection and colours in both.
"""

from __future__ import annotations

import hashlib
import math

import numpy as np

from lodsprite.bandlimit import check_filter, resolve
from lodsprite.camera import Projection, Viewpoint, fitted_projection, view_footprint
from lodsprite.errors import InputError
from lodsprite.gl.bandlimited import HeightPatch, SupersampledTerrain
from lodsprite.gl.context import GLContext
from lodsprite.terrain.heightfield import HeightField
from lodsprite.terrain.pyramid import MemoryPyramid
from lodsprite.terrain.quadtree import Quadtree

MAX_SIDE = 4097  # level-0 samples a side drawn at once (a 4096-quad grid)
MARGIN = 2       # samples around the footprint (central differences of its edge cells)
SAMPLES = 4      # samples a pixel side of the reference, by default
Window = tuple[int, int, int, int]  # level-0 samples r0, r1, c0, c1 (r1, c1 exclusive)


def tile_ranges(lo: int, hi: int, max_side: int) -> list[tuple[int, int]]:
    """Sample ranges ``[a, b)`` covering ``[lo, hi)`` with at most ``max_side`` samples
    each, as even as they can be, neighbours sharing one sample (the quads between them
    are drawn once, without a gap): ``(0, 9), 5`` gives ``(0, 5), (4, 9)``."""
    if max_side < 2:
        raise InputError(f"a reference tile needs at least 2 samples a side, not {max_side}")
    quads = max(hi - lo - 1, 1)
    count = -(-quads // (max_side - 1))
    edges = [lo + round(quads * k / count) for k in range(count + 1)]
    return [(a, b + 1) for a, b in zip(edges[:-1], edges[1:], strict=True)]


def tiles(win: Window, max_side: int) -> list[Window]:
    """The tiles of the level-0 window ``win``, each at most ``max_side`` samples a side
    (row-major; one tile when ``win`` fits)."""
    r0, r1, c0, c1 = win
    return [(a, b, c, d) for a, b in tile_ranges(r0, r1, max_side)
            for c, d in tile_ranges(c0, c1, max_side)]


class LevelZeroReference:
    """Band-limited reference frames of ``size = (w, h)`` pixels, vertical field of view
    ``fov_y_deg``, ``samples`` x ``samples`` a pixel filtered by ``filter`` in colour
    ``space`` (:mod:`lodsprite.bandlimit`), coloured by ``shading`` (``heights``:
    terrain_shade with per-pixel normals; ``texture``: ``texture (H, W, 3) uint8`` over
    level 0's extent, sampled at its base level, whole level only, unless ``imagery``
    gives each window's texture; ``auto``: heights for a store, the texture for an
    in-memory field given one).  ``store_or_field``: a
    :class:`~lodsprite.terrain.store.TerrainStore` (exaggerated as opened) or a
    :class:`HeightField` (centred on the origin).  ``imagery``: ``(r0, r1, c0, c1) -> (H,
    W, 3) uint8``, the texture over level 0's samples ``[r0, r1) x [c0, c1)`` (a store's
    imagery read at level 0's detail), what each patch, whole or a window, is coloured
    with (finer than one texture of the whole imagery, as the renderers' clipmap).
    GPU objects live until :meth:`release`.  Raises :class:`InputError` for texture
    shading of a level 0 beyond ``max_side`` without ``imagery``, or a sample count,
    filter or space not known."""

    def __init__(self, ctx: GLContext, store_or_field, size: tuple[int, int],
                 fov_y_deg: float = 45.0, shading: str = "heights",
                 texture: np.ndarray | None = None, max_side: int = MAX_SIDE,
                 samples: int = SAMPLES, filter: str = "box", space: str = "linear",
                 imagery=None) -> None:
        check_filter(samples, filter, space)
        if shading == "auto":  # as --shading auto: heights for a store, else the texture
            texture_ok = texture is not None and isinstance(store_or_field, HeightField)
            shading = "texture" if texture_ok else "heights"
        if shading not in ("heights", "texture"):
            raise InputError(f"the reference shades by auto, heights or texture, not "
                             f"{shading!r}")
        if shading == "texture" and texture is None and imagery is None:
            raise InputError("a texture-shaded reference needs the texture")
        self.imagery = imagery  # (r0, r1, c0, c1) -> the texture over that sample window
        self.ctx, self.size, self.fov = ctx, (int(size[0]), int(size[1])), float(fov_y_deg)
        # a patch is one height texture: never more samples a side than the GL allows
        self.shading, self.texture = shading, texture
        self.max_side = min(int(max_side), ctx.info.max_texture_size)
        self.samples, self.filter, self.space = int(samples), filter, space
        field = store_or_field if isinstance(store_or_field, HeightField) else None
        self.pyramid = MemoryPyramid.from_heightfield(field) if field is not None \
            else store_or_field
        self.tree = Quadtree(self.pyramid)
        self.rows, self.cols = self.tree.rows0, self.tree.cols0
        self.whole = max(self.rows, self.cols) <= self.max_side
        if shading == "texture" and not self.whole and imagery is None:
            raise InputError(f"level 0 is {self.cols}x{self.rows} samples, more than "
                             f"{self.max_side} a side: its reference is shaded from the "
                             "heights (--shading heights), a texture needs it whole")
        self.height_range = self.tree.height_range()
        self._field = field
        self._window: Window | None = None  # the window of the patch kept
        self._patch: HeightPatch | None = None  # kept while the view needs one patch
        self._drawer: SupersampledTerrain | None = None
        self._note = ""

    def projection(self, viewpoint: Viewpoint) -> Projection:
        """The adaptive renderer's projection at ``viewpoint``: near/far fitted to the
        terrain's box and the ground under the eye."""
        w, h = self.size
        return fitted_projection(viewpoint, self.fov, w / h, *self.tree.box(),
                                 self.tree.ground_below(np.asarray(viewpoint.o)))

    def window(self, viewpoint: Viewpoint, projection: Projection) -> Window | None:
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

    def _view_window(self, viewpoint: Viewpoint, projection: Projection) -> Window:
        """What to draw: level 0 whole, or the footprint's window (at least 2x2 samples:
        a corner of the terrain when nothing of it is in view, the sky)."""
        if self.whole:
            return (0, self.rows, 0, self.cols)
        win = self.window(viewpoint, projection)
        if win is None:
            return (0, 2, 0, 2)
        r0, r1, c0, c1 = win
        r0, c0 = min(r0, self.rows - 2), min(c0, self.cols - 2)
        return (r0, max(r1, r0 + 2), c0, max(c1, c0 + 2))

    def samples_image(self, viewpoint: Viewpoint, projection: Projection | None = None
                      ) -> np.ndarray:
        """The unfiltered sample image ``(k h, k w, 3) uint8`` (row 0 at the top)."""
        projection = projection or self.projection(viewpoint)
        win = self._view_window(viewpoint, projection)
        parts = tiles(win, self.max_side)
        view_proj = projection.matrix() @ viewpoint.view_matrix()
        if len(parts) == 1:
            patches = [self._patch_for(parts[0])]
        else:
            self._drop_patch()
            patches = []
            try:
                for part in parts:
                    patches.append(self._make(part))
            except BaseException:
                for p in patches:
                    p.release()
                raise
        try:
            samples = self._drawer_for().draw(patches, view_proj)
        finally:
            if len(parts) > 1:
                for p in patches:
                    p.release()
        self._note = self._describe_window(win, len(parts))
        return samples

    def image(self, viewpoint: Viewpoint, projection: Projection | None = None) -> np.ndarray:
        """The reference frame ``(h, w, 3) uint8`` (row 0 at the top) at ``viewpoint``
        through ``projection`` (default :meth:`projection`): level 0 whole, its window
        under the view, or that window in patches, at ``k x k`` samples a pixel, filtered."""
        return resolve(self.samples_image(viewpoint, projection), self.samples, self.filter,
                       self.space)

    def _make(self, win: Window) -> HeightPatch:
        """The GPU patch of level 0's window ``win`` at its place."""
        r0, r1, c0, c1 = win
        if self._field is not None:
            heights = self._field.heights[r0:r1, c0:c1]
        else:
            heights = self.pyramid.read(0, r0, r1, c0, c1)
        x, y = self.tree.world_xy(0, np.array([r0]), np.array([c0]))
        patch = HeightPatch(self.ctx, heights, (float(x[0]), float(y[0])),
                            (self.pyramid.dx, self.pyramid.dy))
        if self.shading == "texture" and self.imagery is not None:
            try:  # a store's imagery over this window, read here (level 0's detail)
                patch.set_color(self.ctx, self.imagery(r0, r1, c0, c1))
            except BaseException:
                patch.release()
                raise
        return patch

    def _patch_for(self, win: Window) -> HeightPatch:
        """The patch of a one-patch view, kept while the window stays (level 0 whole:
        always)."""
        if self._patch is None or self._window != win:
            self._drop_patch()
            self._patch, self._window = self._make(win), win
        return self._patch

    def _drawer_for(self) -> SupersampledTerrain:
        if self._drawer is None:
            self._drawer = SupersampledTerrain(
                self.ctx, self.size, self.samples, self.shading, self.height_range,
                self.texture, (self.cols - 1, self.rows - 1))
        return self._drawer

    def _describe_window(self, win: Window, count: int) -> str:
        r0, r1, c0, c1 = win
        if self.whole:
            return f"level 0 whole, {self.cols}x{self.rows} samples"
        how = f"in {count} tiles" if count > 1 else "in one piece"
        return (f"level-0 window rows {r0}:{r1}, columns {c0}:{c1} of {self.cols}x{self.rows} "
                f"samples (the view's footprint), drawn {how}")

    def identity(self) -> str:
        """Everything that decides this reference's frames besides the view, as text: the
        level 0 (a store's resolved path, header bytes and exaggeration; an in-memory
        field's SHA-256 and spacings) and the settings (size, field of view, samples,
        filter, colour space, shading, texture's SHA-256, patch side)."""
        if self._field is not None:
            src = (f"field {hashlib.sha256(np.ascontiguousarray(self._field.heights)).hexdigest()}"
                   f" {self.pyramid.dx!r} {self.pyramid.dy!r}")
        else:
            store = self.pyramid
            from lodsprite.terrain.remote import Url

            if isinstance(store.path, Url):  # a store at a URL: its header as read
                header = hashlib.sha256(repr(store.header).encode()).hexdigest()
                where = str(store.path)
            else:
                header = hashlib.sha256((store.path / "zarr.json").read_bytes()).hexdigest()
                where = str(store.path.resolve())
            src = f"store {where} {header} {store.exaggeration!r}"
        tex = ("none" if self.texture is None else
               hashlib.sha256(np.ascontiguousarray(self.texture)).hexdigest())
        if self.imagery is not None:
            tex = "the store's imagery by window"
        return (f"lodsprite level-0 reference 1; {src}; size {self.size}; fov {self.fov!r}; "
                f"samples {self.samples}; {self.filter}; {self.space}; {self.shading}; "
                f"texture {tex}; max side {self.max_side}")

    def describe(self) -> str:
        """How the reference is made, and for the last view what was drawn."""
        how = ("level 0 whole" if self.whole else
               f"level-0 windows cropped to the view's footprint, patches of at most "
               f"{self.max_side} samples a side")
        last = f"; last view: {self._note}" if self._note else ""
        return (f"level 0 band-limited: {self.samples}x{self.samples} samples a pixel, "
                f"{self.filter} filter in {self.space} colour, by its own drawing path; "
                f"{how}, of {self.cols}x{self.rows} samples; {self.shading} shading; "
                f"near/far fitted as the adaptive renderer's{last}")

    def _drop_patch(self) -> None:
        if self._patch is not None:
            self._patch.release()
        self._patch, self._window = None, None

    def release(self) -> None:
        """Free the GPU objects (the drawer's target and programs, the patch kept)."""
        self._drop_patch()
        if self._drawer is not None:
            self._drawer.release()
            self._drawer = None
