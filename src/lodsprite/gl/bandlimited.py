"""The reference's own drawing path: level-0 height patches drawn at ``k x k`` samples a
pixel, independent of every renderer it judges.

It shares with the renderers only the definition of colour (:mod:`lodsprite.gl.shaders`:
the height ramp and sun of ``TERRAIN_SHADE``, the per-pixel normals of
``HEIGHT_NORMAL``, the sky ``SKY_RGB``; a colour texture sampled at its base level,
bilinear).  Its mesh is its own: no vertex or index buffer, each quad row of a patch is
one triangle strip whose vertices come from ``gl_VertexID`` (``2j``: sample ``(col + j,
row + 1)``, ``2j + 1``: ``(col + j, row)``, so that each quad is split along its
north-west to south-east diagonal: the surface level 0's samples define, triangulated as
everywhere in the project) and a per-instance start sample, culled by
blocks of :data:`BLOCK` quads against the frustum; heights from an ``R32F`` texture by
``texelFetch``.  A bug in the renderers' chunk meshes, instancing or uniforms cannot
reach it.

The sample image, ``(k w) x (k h)`` pixels, is drawn in image tiles of at most
:data:`TILE` pixels a side (an off-centre projection per tile: the GL's viewport and
texture limits, and memory), each with every patch, and returned whole for
:func:`lodsprite.bandlimit.resolve` to filter.
"""

from __future__ import annotations

from collections.abc import Sequence

import moderngl
import numpy as np

from lodsprite.camera import boxes_in_frustum, frustum_planes
from lodsprite.errors import InputError
from lodsprite.gl.context import GLContext
from lodsprite.gl.shaders import HEIGHT_NORMAL, SKY_RGB, TERRAIN_SHADE

BLOCK = 128   # quads a side of a culling block (and the width of its strips)
TILE = 4096   # sample-image pixels a side drawn at once (at most; the GL's limit below)

_VS = """#version 330
uniform sampler2D u_height;   // the patch's heights, R32F (cols x rows), metres
uniform ivec2 u_last;         // (cols - 1, rows - 1)
uniform vec2 u_corner;        // world (x, y) metres of the patch's sample (0, 0)
uniform vec2 u_spacing;       // metres a column east, a row south
uniform mat4 u_mvp;
in ivec2 in_strip;            // per instance: (col, row) of the strip's first sample
out vec3 v_world;
void main() {
    ivec2 s = min(in_strip + ivec2(gl_VertexID >> 1, 1 - (gl_VertexID & 1)), u_last);
    float h = texelFetch(u_height, s, 0).r;
    v_world = vec3(u_corner.x + float(s.x) * u_spacing.x,
                   u_corner.y - float(s.y) * u_spacing.y, h);
    gl_Position = u_mvp * vec4(v_world, 1.0);
}
"""

_HEIGHTS_FS = ("#version 330\n" + TERRAIN_SHADE + HEIGHT_NORMAL + """
uniform sampler2D u_height;
uniform vec2 u_corner;
uniform vec2 u_spacing;
in vec3 v_world;
out vec4 f_color;
void main() {
    vec2 p = vec2((v_world.x - u_corner.x) / u_spacing.x, (u_corner.y - v_world.y) / u_spacing.y);
    ivec2 last = textureSize(u_height, 0) - ivec2(1);
    f_color = vec4(terrain_shade(v_world.z, height_normal(u_height, ivec2(0), last, p,
                                                          u_spacing)), 1.0);
}
""")

_TEXTURE_FS = """#version 330
uniform sampler2D u_color;    // over level 0's extent: u = 0 at column 0, 1 at the last
uniform vec2 u_corner;
uniform vec2 u_spacing;
uniform vec2 u_quads;         // level 0's (cols - 1, rows - 1)
in vec3 v_world;
out vec4 f_color;
void main() {
    vec2 p = vec2((v_world.x - u_corner.x) / u_spacing.x, (u_corner.y - v_world.y) / u_spacing.y);
    f_color = vec4(textureLod(u_color, p / u_quads, 0.0).rgb, 1.0);
}
"""


class HeightPatch:
    """A block of level-0 heights ``(rows, cols) float32`` on the GPU, sample ``(0, 0)`` at
    world ``corner = (x, y)`` metres, ``spacing = (dx, dy)`` metres a column east and a
    row south; its culling blocks' boxes and strips.  Release after use."""

    def __init__(self, ctx: GLContext, heights: np.ndarray, corner: tuple[float, float],
                 spacing: tuple[float, float]) -> None:
        h = np.ascontiguousarray(heights, dtype=np.float32)
        rows, cols = h.shape
        if rows < 2 or cols < 2:
            raise InputError(f"a height patch needs 2x2 samples at least, not {cols}x{rows}")
        if max(rows, cols) > ctx.info.max_texture_size:
            raise InputError(f"a {cols}x{rows} height patch exceeds the GL's texture size "
                             f"{ctx.info.max_texture_size}")
        self.rows, self.cols = rows, cols
        self.corner = (float(corner[0]), float(corner[1]))
        self.spacing = (float(spacing[0]), float(spacing[1]))
        self.tex = ctx.mgl.texture((cols, rows), 1, h.tobytes(), dtype="f4")
        self.tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.color = None  # the patch's own colour texture over its samples (set_color)
        r0 = np.arange(0, rows - 1, BLOCK)
        c0 = np.arange(0, cols - 1, BLOCK)
        self.mins, self.maxs = self._boxes(h, r0, c0)
        # strips of each block: (col, row) of its first sample, one per quad row
        self.strips = [np.stack([np.full(min(BLOCK, rows - 1 - r), c, np.int32),
                                 np.arange(r, min(r + BLOCK, rows - 1), dtype=np.int32)],
                                axis=1) for r in r0 for c in c0]

    def _boxes(self, h: np.ndarray, r0: np.ndarray, c0: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
        """World boxes ``(B, 3)`` of the blocks, row-major, edge samples included."""
        rows, cols = h.shape
        r_end, c_end = np.minimum(r0 + BLOCK, rows - 1), np.minimum(c0 + BLOCK, cols - 1)

        def reduce(op):
            a = op(op.reduceat(h, r0, axis=0), h[r_end])
            return op(op.reduceat(a, c0, axis=1), a[:, c_end])

        lo, hi = reduce(np.minimum), reduce(np.maximum)
        x0 = self.corner[0] + c0 * self.spacing[0]
        x1 = self.corner[0] + c_end * self.spacing[0]
        y1 = self.corner[1] - r0 * self.spacing[1]
        y0 = self.corner[1] - r_end * self.spacing[1]
        xx0, yy0 = np.meshgrid(x0, y0)
        xx1, yy1 = np.meshgrid(x1, y1)
        mins = np.stack([xx0.ravel(), yy0.ravel(), lo.ravel()], axis=1)
        maxs = np.stack([xx1.ravel(), yy1.ravel(), hi.ravel()], axis=1)
        return mins, maxs

    def set_color(self, ctx: GLContext, rgb: np.ndarray) -> None:
        """Colour this patch with its own texture ``(H, W, 3) uint8`` spanning exactly its
        samples (``u = 0`` at its first column, ``1`` at its last; row 0 north)."""
        t = np.ascontiguousarray(rgb, dtype=np.uint8)
        if t.ndim != 3 or t.shape[2] != 3 or max(t.shape[:2]) > ctx.info.max_texture_size:
            raise InputError(f"a patch texture must be (H, W, 3) uint8 within the GL's "
                             f"texture size, not {t.shape}")
        self.color = ctx.mgl.texture((t.shape[1], t.shape[0]), 3, t.tobytes(), alignment=1)
        self.color.filter = (moderngl.LINEAR, moderngl.LINEAR)
        self.color.repeat_x = self.color.repeat_y = False

    def visible_strips(self, view_proj: np.ndarray) -> np.ndarray:
        """``(N, 2) int32`` strips of the blocks in the frustum of ``view_proj``."""
        mask = boxes_in_frustum(frustum_planes(view_proj), self.mins, self.maxs)
        chosen = [s for s, keep in zip(self.strips, mask, strict=True) if keep]
        return np.concatenate(chosen) if chosen else np.zeros((0, 2), np.int32)

    def release(self) -> None:
        self.tex.release()
        if self.color is not None:
            self.color.release()


def tile_matrix(full: tuple[int, int], tile: tuple[int, int, int, int]) -> np.ndarray:
    """``(4, 4)`` clip-space transform that maps the image tile ``(x0, y0, w, h)`` (pixels
    of a ``full = (W, H)`` image, GL's bottom-up rows) onto the whole viewport."""
    (fw, fh), (x0, y0, tw, th) = full, tile
    m = np.eye(4)
    m[0, 0], m[0, 3] = fw / tw, (fw - 2 * x0) / tw - 1.0
    m[1, 1], m[1, 3] = fh / th, (fh - 2 * y0) / th - 1.0
    return m


def image_tiles(w: int, h: int, side: int) -> list[tuple[int, int, int, int]]:
    """Tiles ``(x0, y0, w, h)`` of at most ``side`` pixels a side covering ``w x h``."""
    return [(x, y, min(side, w - x), min(side, h - y))
            for y in range(0, h, side) for x in range(0, w, side)]


def _mat(m: np.ndarray) -> bytes:
    return np.asarray(m, dtype=np.float32).T.tobytes()


class SupersampledTerrain:
    """Draws :class:`HeightPatch` es at ``samples x samples`` a pixel of ``size = (w, h)``
    (module doc), coloured by ``shading``: ``heights`` (``TERRAIN_SHADE`` over the ramp
    ``height_range`` with per-pixel normals) or ``texture`` (``texture (H, W, 3) uint8``
    over level 0, whose sample ``(0, 0)`` is at ``corner`` and which has ``quads = (cols -
    1, rows - 1)``; a patch with its own colour, :meth:`HeightPatch.set_color`, is drawn
    with that instead).  GPU objects live until :meth:`release`."""

    def __init__(self, ctx: GLContext, size: tuple[int, int], samples: int,
                 shading: str, height_range: tuple[float, float],
                 texture: np.ndarray | None = None,
                 quads: tuple[int, int] | None = None) -> None:
        if shading == "texture" and quads is None:
            raise InputError("a texture-shaded reference needs level 0's size")
        mgl = ctx.mgl
        self.ctx, self.samples = ctx, int(samples)
        self.full = (int(size[0]) * self.samples, int(size[1]) * self.samples)
        limit = min(TILE, ctx.info.max_texture_size,
                    *mgl.info["GL_MAX_VIEWPORT_DIMS"])
        self.tiles = image_tiles(*self.full, limit)
        tw = max(t[2] for t in self.tiles)
        th = max(t[3] for t in self.tiles)
        self.color = mgl.texture((tw, th), 4)
        self.depth = mgl.depth_texture((tw, th))
        self.fbo = mgl.framebuffer(color_attachments=[self.color], depth_attachment=self.depth)
        fs = _HEIGHTS_FS if shading == "heights" else _TEXTURE_FS
        self.program = mgl.program(vertex_shader=_VS, fragment_shader=fs)
        self.texture = None
        self.quads = None if quads is None else tuple(float(q) for q in quads)
        if shading == "texture" and texture is not None:  # else each patch brings its own
            t = np.ascontiguousarray(texture, dtype=np.uint8)
            self.texture = mgl.texture((t.shape[1], t.shape[0]), 3, t.tobytes(), alignment=1)
            self.texture.filter = (moderngl.LINEAR, moderngl.LINEAR)
            self.texture.repeat_x = self.texture.repeat_y = False
            self.program["u_color"].value = 1
        elif shading == "texture":
            self.program["u_color"].value = 1
        else:
            self.program["u_range"].value = tuple(float(v) for v in height_range)
        self.program["u_height"].value = 0
        self.instances = None
        self.vao = None

    def _instances(self, count: int) -> moderngl.Buffer:
        if self.instances is None or self.instances.size < count * 8:
            for obj in (self.vao, self.instances):
                if obj is not None:
                    obj.release()
            self.instances = self.ctx.mgl.buffer(reserve=max(count, 1024) * 8)
            self.vao = self.ctx.mgl.vertex_array(
                self.program, [(self.instances, "2i/i", "in_strip")])
        return self.instances

    def _draw_patch(self, patch: HeightPatch, mvp: np.ndarray) -> int:
        strips = patch.visible_strips(mvp)
        if not len(strips):
            return 0
        self._instances(len(strips)).write(np.ascontiguousarray(strips).tobytes())
        prog = self.program
        prog["u_mvp"].write(_mat(mvp))
        prog["u_last"].value = (patch.cols - 1, patch.rows - 1)
        prog["u_spacing"].value = patch.spacing
        prog["u_corner"].value = patch.corner
        patch.tex.use(0)
        if patch.color is not None:  # its own texture, over its samples
            patch.color.use(1)
            prog["u_quads"].value = (patch.cols - 1.0, patch.rows - 1.0)
        elif self.texture is not None:  # the one texture: the patch is level 0 whole
            self.texture.use(1)
            prog["u_quads"].value = self.quads
        self.vao.render(moderngl.TRIANGLE_STRIP, vertices=2 * (BLOCK + 1),
                        instances=len(strips))
        return len(strips)

    def draw(self, patches: Sequence[HeightPatch], view_proj: np.ndarray) -> np.ndarray:
        """The sample image ``(k h, k w, 3) uint8`` (row 0 at the top) of ``patches``
        through ``view_proj (4, 4)`` (world to clip), the sky behind."""
        mgl = self.ctx.mgl
        fw, fh = self.full
        out = np.empty((fh, fw, 3), np.uint8)
        mgl.enable(moderngl.DEPTH_TEST)
        mgl.disable(moderngl.CULL_FACE | moderngl.BLEND)
        for tile in self.tiles:
            x0, y0, tw, th = tile
            self.fbo.use()
            self.fbo.viewport = (0, 0, tw, th)
            self.fbo.clear(*SKY_RGB, 1.0, depth=1.0)
            mvp = tile_matrix(self.full, tile) @ view_proj
            for patch in patches:
                self._draw_patch(patch, mvp)
            data = self.fbo.read(viewport=(0, 0, tw, th), components=3, alignment=1)
            out[y0:y0 + th, x0:x0 + tw] = np.frombuffer(data, np.uint8).reshape(th, tw, 3)
        self.ctx.finish()
        return out[::-1]

    def release(self) -> None:
        if self.ctx.mgl.fbo is self.fbo:  # moderngl re-binds the current one: never a dead one
            self.ctx.default_fbo.use()
        for obj in (self.vao, self.instances, self.program, self.texture, self.fbo,
                    self.color, self.depth):
            if obj is not None:
                obj.release()
        self.vao = self.instances = self.texture = None
