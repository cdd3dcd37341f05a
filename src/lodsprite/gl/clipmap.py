"""The imagery clipmap on the GPU (:mod:`lodsprite.terrain.clipmap` decides what it
holds): a texture array of the clip levels' windows, addressed toroidally, and a table of
the chunk each slot holds; :data:`~lodsprite.gl.shaders.CLIPMAP_FS` samples them per fragment.

``terrain_color(whole, uv)`` (GLSL): ``uv`` over the terrain's extent (0 at column 0 and
row 0, north; 1 at the last), ``whole`` the mipmapped texture of the whole imagery.  The
level of detail is the texels' screen size at level 0 (``log2`` of the larger of the
texel coordinates' screen derivatives); the finest clip level at or above it whose
window holds the four texels of the bilinear footprint (kept inside the level: no wrap
at its edges) is sampled, blended towards the next coarser one by the fraction of the
level of detail (no seam where levels meet), and over the whole texture by the
imagery's alpha (premultiplied: no dark fringe where coverage ends; where no source
covers the ground, the whole texture's colour).  No clip level holds the point: the
whole texture, mipmapped.
"""

from __future__ import annotations

import moderngl
import numpy as np

from lodsprite.gl.context import GLContext

UNIT_LEVELS, UNIT_TABLE = 8, 9  # texture units of the clip levels and their table



class ClipmapGL:
    """The GPU side of a :class:`~lodsprite.terrain.clipmap.Clipmap` (``core``; None: an
    empty one, what programs bind when the terrain has no clipmap).  ``extent``: the
    terrain's width and depth in metres (the eye's ground point to level-0 texels)."""

    def __init__(self, ctx: GLContext, core=None, extent: tuple[float, float] = (1.0, 1.0)
                 ) -> None:
        mgl = ctx.mgl
        self.core = core
        self.extent = (float(extent[0]), float(extent[1]))
        n = len(core) if core is not None else 0
        side = core.side if n else 1
        slots = core.slots if n else 1
        self.levels = mgl.texture_array((side, side, max(n, 1)), 4)
        self.levels.filter = (moderngl.LINEAR, moderngl.LINEAR)
        self.levels.repeat_x = self.levels.repeat_y = True  # toroidal windows
        self.table = mgl.texture_array((slots, slots, max(n, 1)), 1, dtype="i4")
        self.table.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.table.write(np.zeros((max(n, 1), slots, slots), np.int32).tobytes())
        self.uploaded = 0

    def update(self, eye) -> int:
        """Centre the windows on the ground under ``eye`` (world metres, the terrain
        centred on the origin), upload what arrived and send the next wishes (never
        waits); the chunks uploaded."""
        core = self.core
        if core is None or not len(core):
            return 0
        w, d = self.extent
        col0 = (float(eye[0]) / w + 0.5) * core.cols
        row0 = (0.5 - float(eye[1]) / d) * core.rows
        core.centre(row0, col0)
        arrived = core.pump()
        for li, sr, sc, block in arrived:
            h, wd = block.shape[:2]
            self.levels.write(np.ascontiguousarray(block).tobytes(),
                              viewport=(sc * core.chunk, sr * core.chunk, li, wd, h, 1))
        if arrived:
            self.table.write(core.tables().tobytes())
            self.uploaded += len(arrived)
        return len(arrived)

    def bind(self, prog: moderngl.Program) -> None:
        """Set ``prog``'s clipmap uniforms and bind its textures (units :data:`UNIT_LEVELS`
        and :data:`UNIT_TABLE`); a program without them is left alone."""
        if "u_clip_levels" not in prog:
            return
        core = self.core
        n = len(core) if core is not None else 0
        prog["u_clip_levels"].value = n
        for name, value in (("u_clip", UNIT_LEVELS), ("u_clip_table", UNIT_TABLE),
                            ("u_clip_texels", (float(core.cols), float(core.rows)) if n
                             else (1.0, 1.0)),
                            ("u_clip_chunk", core.chunk if n else 1),
                            ("u_clip_side", core.side if n else 1)):
            if name in prog:
                prog[name].value = value
        self.levels.use(UNIT_LEVELS)
        self.table.use(UNIT_TABLE)

    def release(self) -> None:
        self.levels.release()
        self.table.release()
        if self.core is not None:
            self.core.close()
