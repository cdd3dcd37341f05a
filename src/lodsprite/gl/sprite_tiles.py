"""GL side of tiled keyframes (Qu, Wan, Qin & Kaufman 2000: part of the image re-rendered
every frame; Chen, Swan & Kaufman 1999 §3.3 for the spriteframe).

The keyframe image (frame plus guard band) is one render target split into an ``N x N``
grid of tiles; each tile is re-rendered on its own, from its own viewpoint, through the
full widened key projection at that viewpoint, scissored to its rectangle, with the
terrain culled by the tile's sub-frustum.  The coarse z-buffer is rendered per tile the
same way.  A tiled spriteframe picks, per fragment, the first tile whose key matrix maps
the fragment's world position into that tile's rectangle, and samples the colour and the
depths there as the whole-keyframe spriteframe does (rules ``fragment`` and ``coarse``;
``triangle`` is taken as ``fragment``: the tile is chosen per fragment); fragments no tile
saw are coloured as there (the terrain texture, or ``terrain_shade`` with the heights
shading).  No mipmaps.

It composes :class:`~lodsprite.gl.sprite.SpriteDrawer` (its key and coarse targets
index 0 hold the tiles, its terrain draws the tiles; the spriteframe and the coarse
z-buffers draw through its proxy geometry object, ``twin`` / ``draw``; a view-dependent
one is frozen at a tile update, :meth:`TiledSpriteDrawer.freeze`, and kept by the next
updates until stale (:mod:`lodsprite.sprite.proxy_hold`): the coarse z-buffers and the
spriteframes from then on draw it, so tiles of older updates are textured onto it).
"""

from __future__ import annotations

from collections.abc import Callable

import moderngl
import numpy as np

from lodsprite.camera import Projection, Viewpoint
from lodsprite.errors import InputError
from lodsprite.gl.shaders import (
    PROXY_VERTEX_COMMON,
    SPRITE_DERIVATIVES,
    SPRITE_FRAGMENT_COMMON,
    TERRAIN_SHADE,
)
from lodsprite.gl.sprite import SpriteDrawer
from lodsprite.gl.target import RenderTarget
from lodsprite.gl.terrain import SKY_RGB, draw_stats
from lodsprite.record import Frame

MAX_TILES = 16  # N x N tiles, N <= 4: one vec4 varying per tile

# Key clip coordinates are affine in the world position, so each tile's are computed per
# vertex and interpolated (perspective-correct, as the world position would be): the
# fragment shader tests every tile with a divide and four compares, in code unrolled per
# tile (a loop over uniform matrices, dynamically indexed, cost 7x the whole-keyframe
# spriteframe at 3 x 3 tiles on llvmpipe).
_TILED_VS = """
uniform mat4 u_mvp;
uniform mat4 u_key_mvp[N_TILES];
out vec2 g_uv;
out vec3 g_world;
out vec4 g_key[N_TILES];
void main() {
    vec3 p = terrain_position(g_uv);
    g_world = p;
    gl_Position = u_mvp * vec4(p, 1.0);
    for (int i = 0; i < N_TILES; ++i) g_key[i] = u_key_mvp[i] * vec4(p, 1.0);
}
"""

_TILED_FS_HEAD = """
uniform sampler2D u_color;
uniform sampler2D u_sprite;
uniform sampler2D u_key_depth;
uniform sampler2D u_key_coarse;
uniform vec4 u_rect[N_TILES];      // NDC x0, y0, x1, y1 of each tile (half-open)
uniform vec2 u_near_far[N_TILES];  // each tile's keyframe near, far (metres)
uniform int u_visibility;          // 1: full z-buffer, 2: coarse z-buffer
uniform float u_fragment_tol;
uniform float u_coarse_tol;
uniform int u_color_levels;
uniform vec4 u_fallback_tint;
uniform int u_shading;             // fallback colour: 0 the terrain texture, 1 terrain_shade
in vec2 g_uv;
in vec3 g_world;
in vec4 g_key[N_TILES];
out vec4 f_color;
float linear_depth(float window_z, vec2 nf) {
    return 2.0 * nf.x * nf.y / (nf.y + nf.x - (2.0 * window_z - 1.0) * (nf.y - nf.x));
}
"""
_TILED_FS_HOLDS = """
bool holds(vec4 c, vec4 r) {  // c.xy / c.w in [r.xy, r.zw), without the divide
    vec4 e = r * c.w;
    return c.w > 0.0 && c.x >= e.x && c.x < e.z && c.y >= e.y && c.y < e.w;
}
void main() {
    bool found = false;
    vec4 k = vec4(0.0, 0.0, 0.0, 1.0);
    vec2 nf = vec2(1.0);
"""

# One test per tile, last to first: the first tile whose key holds the fragment wins.
_TILED_FS_TILE = """    if (holds(g_key[{i}], u_rect[{i}])) {{
        found = true; k = g_key[{i}]; nf = u_near_far[{i}];
    }}
"""

_TILED_FS_TAIL = """
    bool sprite = false;
    if (found) {
        float z = k.z / k.w;
        if (abs(z) <= 1.0) {
            bool coarse = u_visibility == 2;
            float zb = coarse ? textureLod(u_key_coarse, key_uv, 0.0).r
                              : textureLod(u_key_depth, key_uv, 0.0).r;
            float tol = coarse ? u_coarse_tol : u_fragment_tol;
            sprite = linear_depth(z * 0.5 + 0.5, nf) <= linear_depth(zb, nf) * (1.0 + tol);
        }
    }
    vec3 rgb = sprite ? textureGrad(u_sprite, key_uv, key_dx, key_dy).rgb
                      : fallback_rgb(level, n);
    f_color = vec4(rgb, 1.0);
}
"""


def tiled_sprite_shaders(count: int) -> tuple[str, str]:
    """``(vertex, fragment)`` GLSL of the tiled spriteframe for ``count`` tiles; the vertex
    shader reads ``PROXY_VERTEX_COMMON`` (``terrain_position``)."""
    head = f"#version 330\n#define N_TILES {count}\n"
    tests = "".join(_TILED_FS_TILE.format(i=i) for i in reversed(range(count)))
    return (head + PROXY_VERTEX_COMMON + _TILED_VS,
            head + TERRAIN_SHADE + _TILED_FS_HEAD + SPRITE_FRAGMENT_COMMON + _TILED_FS_HOLDS
            + tests + SPRITE_DERIVATIVES + _TILED_FS_TAIL)


#: Draws a tile's full-resolution terrain: ``(viewpoint, projection, target, cull) ->
#: Frame`` (:func:`~lodsprite.gl.terrain.draw_stats`), ``cull`` the ``(4, 4)``
#: sub-frustum matrix the chunks are culled with.
TileDrawer = Callable[[Viewpoint, Projection, RenderTarget, np.ndarray], Frame]


def scissor_rect(rect: np.ndarray) -> tuple[int, int, int, int]:
    """``(x, y, w, h)`` of a pixel rectangle ``(x0, y0, x1, y1)``."""
    x0, y0, x1, y1 = (int(v) for v in rect)
    return x0, y0, x1 - x0, y1 - y0


class TiledSpriteDrawer:
    """Tiled keyframes and tiled spriteframes over a :class:`SpriteDrawer`.

    ``rects (T, 4) int``: the tiles' pixel rectangles ``(x0, y0, x1, y1)`` in the keyframe
    target (GL window coordinates), ``ndc (T, 4)``: the same in NDC (``T <=``
    :data:`MAX_TILES`; :func:`lodsprite.sprite.tiled.tile_rects` makes them).  Tile state
    (viewpoint, key projection, key view-projection) is set by :meth:`render_tile`.
    """

    def __init__(self, sprite: SpriteDrawer, rects: np.ndarray, ndc: np.ndarray) -> None:
        count = len(rects)
        if not 1 <= count <= MAX_TILES or len(ndc) != count:
            raise InputError(f"1 to {MAX_TILES} tiles, got {count}")
        self.sprite = sprite
        self.ctx = sprite.ctx
        # slot 0 of the keyframe pool: the tiled engine's one mosaic (no cache with tiles)
        self.target, self.coarse = sprite.slot_targets(0)
        self.rects = np.asarray(rects)
        self.ndc = np.asarray(ndc, np.float64)
        self.viewpoints: list[Viewpoint | None] = [None] * count
        self.projections: list[Projection | None] = [None] * count
        self.view_projs = np.tile(np.eye(4), (count, 1, 1))
        self.proxy_gl = None  # the proxy frozen for the latest tile update (None: sprite's)
        self.program = self._program()

    def _program(self):
        """The tiled spriteframe's program, reading the sprite drawer's proxy geometry."""
        sprite = self.sprite
        vs, fs = tiled_sprite_shaders(self.count)
        prog = self.ctx.mgl.program(vertex_shader=sprite.proxy.twin(vs), fragment_shader=fs)
        values = {"u_visibility": 2 if sprite.visibility == "coarse" else 1, "u_color": 0,
                  "u_sprite": 2, "u_key_depth": 3, "u_key_coarse": 4,
                  "u_fragment_tol": sprite.program["u_fragment_tol"].value,
                  "u_coarse_tol": sprite.program["u_coarse_tol"].value}
        for name, value in values.items():
            if name in prog:
                prog[name].value = value
        return prog

    def use_proxy(self) -> None:
        """Read the sprite drawer's proxy geometry again (after its ``set_proxy``)."""
        self.program.release()
        self.program = self._program()
        self.proxy_gl = None

    def freeze(self, viewpoint: Viewpoint, projection: Projection) -> None:
        """A tile update from ``viewpoint`` through the key ``projection``: a view-dependent
        proxy (one with ``for_keyframe``) is frozen for it; the update's coarse z-buffers
        and the spriteframes from then on draw that geometry.  Nothing for the uniform
        proxy."""
        freeze = getattr(self.sprite.proxy, "for_keyframe", None)
        if freeze is not None:
            self.proxy_gl = freeze(self.target, viewpoint, projection)

    @property
    def count(self) -> int:
        return len(self.rects)

    def default_drawer(self, viewpoint: Viewpoint, projection: Projection,
                       target: RenderTarget, cull: np.ndarray) -> Frame:
        """The full-resolution terrain with its chunks culled by ``cull``."""
        return self.sprite.terrain.render(viewpoint, None, projection, target, cull=cull)

    def render_tile(self, tile: int, viewpoint: Viewpoint, projection: Projection,
                    cull: np.ndarray, drawer: TileDrawer | None = None) -> Frame:
        """Re-render tile ``tile`` from ``viewpoint`` through the key ``projection`` (the
        widened one), scissored to its rectangle, the terrain culled by ``cull (4, 4)``
        (the tile's sub-frustum, :func:`lodsprite.sprite.tiled.sub_view_proj`); its coarse
        z-buffer too (``coarse`` rule).  Issues GL work only (no finish)."""
        box = scissor_rect(self.rects[tile])
        drawer = drawer or self.default_drawer
        try:
            self.target.fbo.scissor = box
            stats = drawer(viewpoint, projection, self.target, cull)
            if self.sprite.visibility == "coarse":
                self.coarse.fbo.scissor = box
                self.sprite.render_coarse_depth(viewpoint, projection, self.coarse,
                                                self.proxy_gl)
        finally:
            self.target.fbo.scissor = None
            self.coarse.fbo.scissor = None
        self.set_tile(tile, viewpoint, projection)
        return stats

    def set_tile(self, tile: int, viewpoint: Viewpoint, projection: Projection) -> None:
        """Tile ``tile`` now holds a render from ``viewpoint`` through the key
        ``projection`` (after :meth:`render_tile`, or a cached render copied in)."""
        self.viewpoints[tile], self.projections[tile] = viewpoint, projection
        self.view_projs[tile] = projection.matrix() @ viewpoint.view_matrix()

    def read_tile(self, tile: int) -> tuple[bytes, bytes, bytes]:
        """Tile ``tile``'s rectangle of the mosaic as ``(depth, colour, coarse)`` bytes:
        float32 window depth, RGBA8, and the coarse z-buffer's float32 depth (``coarse``
        rule; else empty), GL row order (bottom row first), what :meth:`upload_tile`
        writes back (a keyframe worker's answer)."""
        box = scissor_rect(self.rects[tile])
        fbo = self.target.fbo
        coarse = (self.coarse.fbo.read(viewport=box, components=1, attachment=-1, dtype="f4")
                  if self.sprite.visibility == "coarse" else b"")
        return (fbo.read(viewport=box, components=1, attachment=-1, dtype="f4"),
                fbo.read(viewport=box, components=4), coarse)

    def upload_tile(self, tile: int, viewpoint: Viewpoint, projection: Projection,
                    depth: bytes, color: bytes, coarse: bytes = b"") -> None:
        """Make a tile rendered elsewhere (a keyframe worker, :meth:`read_tile` there)
        tile ``tile``'s render: its full-resolution ``depth`` (float32) and ``color``
        (RGBA8) bytes of the tile's rectangle, GL row order, from ``viewpoint`` through
        the key ``projection``; its coarse z-buffer (``coarse`` rule) from ``coarse``
        (float32), drawn here when empty.  Raises :class:`~lodsprite.errors.InputError`
        for bytes of the wrong size."""
        box = scissor_rect(self.rects[tile])
        n = 4 * box[2] * box[3]
        if len(depth) != n or len(color) != n or len(coarse) not in (0, n):
            raise InputError(f"tile {tile} is {box[2]}x{box[3]}: got {len(depth)} depth, "
                             f"{len(color)} colour and {len(coarse)} coarse bytes")
        self.target.color.write(color, viewport=box, alignment=1)
        self.target.depth.write(depth, viewport=box, alignment=1)
        if self.sprite.visibility == "coarse" and coarse:
            self.coarse.depth.write(coarse, viewport=box, alignment=1)
        elif self.sprite.visibility == "coarse":
            try:
                self.coarse.fbo.scissor = box
                self.sprite.render_coarse_depth(viewpoint, projection, self.coarse,
                                                self.proxy_gl)
            finally:
                self.coarse.fbo.scissor = None
        self.set_tile(tile, viewpoint, projection)

    def keyframe_color(self) -> np.ndarray:
        """The tiled keyframe image without its guard band, ``(H, W, 3) uint8`` at the
        keyframe scale, row 0 at the top."""
        g = int(round(self.sprite.guard_px * self.sprite.key_scale))
        w, h = self.target.size
        img = self.target.read_color(copy=False)
        return (img[g:h - g, g:w - g] if g else img).copy()

    def render_spriteframe(self, viewpoint: Viewpoint,
                           projection: Projection | None = None) -> Frame:
        """The coarse level textured from the tiles into the sprite drawer's target."""
        if any(v is None for v in self.viewpoints):
            raise RuntimeError("render_spriteframe needs every tile rendered first")
        s = self.sprite
        projection = projection or s.terrain.projection(viewpoint)
        s.target.use(SKY_RGB)
        self.ctx.mgl.enable(moderngl.DEPTH_TEST)
        s.terrain.geometry.color_tex.use(0)
        self.target.color.use(2)
        self.target.depth.use(3)
        self.coarse.depth.use(4)
        prog = self.program
        _write_array(prog["u_key_mvp"], np.stack([m.T for m in self.view_projs]))
        _write_array(prog["u_rect"], self.ndc)
        _write_array(prog["u_near_far"], np.array([(p.near, p.far) for p in self.projections]))
        prog["u_color_levels"].value = s.terrain.geometry.color_tex_levels
        prog["u_fallback_tint"].value = s.fallback_tint
        for name, value in (("u_shading", int(s.terrain.shading == "heights")),
                            ("u_range", s.terrain.geometry.height_range)):
            if name in prog:  # fragments no tile saw: the terrain texture or terrain_shade
                prog[name].value = value
        tris = (self.proxy_gl or s.proxy).draw(prog, projection.matrix()
                                               @ viewpoint.view_matrix())
        return draw_stats(tris, 1, projection)

    def release(self) -> None:
        self.program.release()


class TileSlots:
    """A pool of GPU copies of tile renders (the tiled keyframe cache's storage,
    :class:`lodsprite.sprite.cache.TileCache`): slot ``(tile, k)`` holds a colour + depth target
    and a coarse-depth target of the tile's size, made when first stored into.  The
    mosaic (``mosaic``, ``coarse``: the tiled renderer's targets) holds the render each
    tile shows; :meth:`store` copies a tile's rectangle from it into a slot and
    :meth:`load` back, GPU-side through one pixel buffer (nothing is read to the host)."""

    def __init__(self, ctx, mosaic: RenderTarget, coarse: RenderTarget,
                 rects: np.ndarray) -> None:
        self.ctx, self.mosaic, self.coarse = ctx, mosaic, coarse
        self.rects = np.asarray(rects)
        self.slots: dict[tuple[int, int], tuple[RenderTarget, RenderTarget]] = {}
        w, h = (self.rects[:, 2:] - self.rects[:, :2]).max(axis=0)
        self._buffer = ctx.mgl.buffer(reserve=int(w * h * 4))

    @staticmethod
    def tile_bytes(rect: np.ndarray) -> int:
        """GPU bytes of one slot of the tile ``rect (x0, y0, x1, y1)``: RGBA8 colour, its
        depth and the coarse depth, 4 B/texel each."""
        x0, y0, x1, y1 = (int(v) for v in rect)
        return 12 * (x1 - x0) * (y1 - y0)

    def _slot(self, key: tuple[int, int]) -> tuple[RenderTarget, RenderTarget]:
        if key not in self.slots:
            _, _, w, h = scissor_rect(self.rects[key[0]])
            self.slots[key] = (RenderTarget(self.ctx, w, h),
                               RenderTarget(self.ctx, w, h, color=False))
        return self.slots[key]

    def _copy(self, src, src_box, dst_tex, dst_box, depth: bool) -> None:
        kw = {"attachment": -1, "components": 1, "dtype": "f4"} if depth else \
            {"components": 4}
        src.read_into(self._buffer, viewport=src_box, alignment=1, **kw)
        dst_tex.write(self._buffer, viewport=dst_box, alignment=1)

    def _pairs(self, key: tuple[int, int]):
        key_t, coarse_t = self._slot(key)
        box = scissor_rect(self.rects[key[0]])
        whole = (0, 0, box[2], box[3])
        return ((self.mosaic, key_t, box, whole), (self.coarse, coarse_t, box, whole))

    def store(self, key: tuple[int, int]) -> None:
        """Copy tile ``key[0]``'s rectangle of the mosaic into slot ``key``."""
        (m, k, box, whole), (c, kc, _, _) = self._pairs(key)
        self._copy(m.fbo, box, k.color, whole, False)
        self._copy(m.fbo, box, k.depth, whole, True)
        self._copy(c.fbo, box, kc.depth, whole, True)

    def load(self, key: tuple[int, int]) -> None:
        """Copy slot ``key`` back into tile ``key[0]``'s rectangle of the mosaic."""
        (m, k, box, whole), (c, kc, _, _) = self._pairs(key)
        self._copy(k.fbo, whole, m.color, box, False)
        self._copy(k.fbo, whole, m.depth, box, True)
        self._copy(kc.fbo, whole, c.depth, box, True)

    def release(self) -> None:
        for pair in self.slots.values():
            for t in pair:
                t.release()
        self.slots.clear()
        self._buffer.release()


def _write_array(uniform, values: np.ndarray) -> None:
    """Write ``values`` (one row per element) into a uniform array, zero-padded to its
    length."""
    flat = np.asarray(values, np.float32).reshape(len(values), -1)
    out = np.zeros((uniform.array_length, flat.shape[1]), np.float32)
    k = min(len(flat), len(out))  # the compiler may trim an array's unused tail
    out[:k] = flat[:k]
    uniform.write(out.tobytes())
