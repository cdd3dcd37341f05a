"""Terrain drawer: full-resolution and uniform coarse levels, offscreen, with chunk culling.

GPU objects (height texture, colour texture, one grid mesh per chunk size, the
instance buffer and the programs) are created once and reused for every frame;
a frame only uploads the origins of the chunks that survive frustum culling.
"""

from __future__ import annotations

import moderngl
import numpy as np

from lodsprite.camera import (
    Projection,
    Viewpoint,
    boxes_in_frustum,
    fitted_projection,
    frustum_planes,
)
from lodsprite.errors import InputError
from lodsprite.gl.context import GLContext, gl_draw_elements_instanced
from lodsprite.gl.shaders import (  # SKY_RGB: re-exported, the sky every renderer clears to
    SKY_RGB,
    TERRAIN_FS,
    TERRAIN_HEIGHTS_FS,
    TERRAIN_VS,
    proxy_twin,
)
from lodsprite.gl.target import RenderTarget
from lodsprite.record import Frame
from lodsprite.terrain.heightfield import HeightField
from lodsprite.terrain.lod import (
    DEFAULT_CHUNK,
    ChunkLayout,
    chunk_layout,
    grid_layout,
    grid_mesh,
    is_working_grid,
)
from lodsprite.terrain.proxy import proxy_mesh

# auto: a store's imagery, else heights on a store, else the texture; imagery: a store's
# imagery, which is the scene's texture (drawn as texture)
SHADINGS = ("auto", "texture", "heights", "imagery")
GL_UNSIGNED_INT = 0x1405


def draw_stats(triangles: int, chunks: int, projection: Projection) -> Frame:
    """What one draw did, as the one frame record: ``kind`` ``draw``, ``ms`` 0 (a draw is
    not timed; the frame it is part of is), ``triangles`` submitted, and in ``extra`` the
    ``chunks`` drawn and the ``projection`` used."""
    return Frame("draw", 0.0, triangles, extra={"chunks": chunks, "projection": projection})


class TerrainGeometry:
    """GPU-resident terrain: height texture, colour texture and shared chunk meshes.

    ``texture_rgb`` None: a plain grey texture (for drawings shaded from the heights).
    ``corner``: world ``(x, y)`` metres of sample ``(0, 0)`` (default: ``hf`` centred on the
    origin); a window of a larger field drawn at its place, full resolution only.
    ``height_range``: the heights shading's ramp (default ``hf``'s lowest and highest)."""

    def __init__(self, ctx: GLContext, hf: HeightField, texture_rgb: np.ndarray | None,
                 chunk_quads: int = DEFAULT_CHUNK, corner: tuple[float, float] | None = None,
                 height_range: tuple[float, float] | None = None) -> None:
        max_tex = ctx.info.max_texture_size
        if max(hf.rows, hf.cols) > max_tex:
            raise InputError(f"height field {hf.cols}x{hf.rows} exceeds this GL driver's "
                             f"maximum texture size {max_tex}")
        mgl = ctx.mgl
        self.ctx = ctx
        self.hf = hf
        # The full-resolution model LOD-sprite's proxy, ribbons and error metric are taken
        # from: ``hf`` itself, or a terrain store's level 0 (:meth:`set_full`).
        self.full: HeightField = hf
        self.chunk_quads = chunk_quads
        self.corner = (-hf.width / 2, hf.depth / 2) if corner is None else tuple(corner)
        self.offset = corner is not None
        lo, hi = hf.bounds()
        self.height_range = (float(lo[2]), float(hi[2])) if height_range is None else \
            tuple(float(v) for v in height_range)
        self.height_tex = mgl.texture((hf.cols, hf.rows), 1, hf.heights.tobytes(), dtype="f4")
        self.height_tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.height_tex.repeat_x = self.height_tex.repeat_y = False
        self.color_tex = None
        self.set_texture(np.full((2, 2, 3), 160, np.uint8) if texture_rgb is None
                         else texture_rgb)
        from lodsprite.gl.clipmap import ClipmapGL

        self.clip = ClipmapGL(ctx)  # imagery finer than the texture: none until use_clipmap
        self._meshes: dict[int, tuple[moderngl.Buffer, moderngl.Buffer, int]] = {}
        self._layouts: dict[int, ChunkLayout] = {}
        self._proxies: dict[tuple[int, bool], tuple[moderngl.Buffer, moderngl.Buffer, int]] = {}
        self.generation = 0  # counts set_full calls (proxy vertex arrays are cached by it)
        c = max(1, min(chunk_quads, hf.rows - 1, hf.cols - 1))
        max_chunks = -(-(hf.rows - 1) // c) * -(-(hf.cols - 1) // c)
        self.instances = mgl.buffer(reserve=max_chunks * 8)

    def set_texture(self, texture_rgb: np.ndarray) -> None:
        """Replace the terrain's colour texture, an ``(H, W, 3) uint8`` image (mipmapped)."""
        if texture_rgb.ndim != 3 or texture_rgb.shape[2] != 3 or texture_rgb.dtype != np.uint8:
            raise InputError("terrain texture must be an (H, W, 3) uint8 array")
        th, tw = texture_rgb.shape[:2]
        max_tex = self.ctx.info.max_texture_size
        if max(th, tw) > max_tex:
            raise InputError(f"texture {tw}x{th} exceeds the maximum texture size {max_tex}")
        if self.color_tex is not None:
            self.color_tex.release()
        tex = self.ctx.mgl.texture((tw, th), 3, np.ascontiguousarray(texture_rgb).tobytes(),
                                   alignment=1)
        tex.repeat_x = tex.repeat_y = False
        tex.build_mipmaps()
        tex.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
        self.color_tex = tex
        self.color_tex_levels = 1 + int(np.log2(max(tw, th)))

    def use_clipmap(self, core) -> None:
        """Drape imagery finer than the colour texture through ``core`` (a
        :class:`~lodsprite.terrain.clipmap.Clipmap` over this terrain's extent; released
        with the geometry)."""
        from lodsprite.gl.clipmap import ClipmapGL

        self.clip.release()
        self.clip = ClipmapGL(self.ctx, core, (self.hf.width, self.hf.depth))

    def layout(self, level_quads: int) -> ChunkLayout:
        if level_quads not in self._layouts:
            if is_working_grid(self.hf) and not self.offset:
                self._layouts[level_quads] = chunk_layout(self.hf, level_quads,
                                                          self.chunk_quads)
            elif level_quads == self.hf.quads:
                self._layouts[level_quads] = grid_layout(self.hf, self.chunk_quads,
                                                         self.corner)
            else:
                raise InputError(f"a {self.hf.cols}x{self.hf.rows} field (level 0 of a "
                                 "store, or a window of it) is drawn at full resolution only")
        return self._layouts[level_quads]

    def mesh(self, chunk_quads: int) -> tuple[moderngl.Buffer, moderngl.Buffer, int]:
        """(vertex buffer, index buffer, index count) of the shared ``C x C`` grid."""
        if chunk_quads not in self._meshes:
            verts, tris = grid_mesh(chunk_quads)
            mgl = self.ctx.mgl
            self._meshes[chunk_quads] = (mgl.buffer(verts.tobytes()), mgl.buffer(tris.tobytes()),
                                         tris.size)
        return self._meshes[chunk_quads]

    def set_full(self, full: HeightField) -> None:
        """Take LOD-sprite's proxy and ribbons from ``full`` (same extent as ``hf``, e.g. a
        :class:`~lodsprite.terrain.storefield.StoreField`); proxies built from the previous
        field are dropped (a viewer switching to a technique that reads the store)."""
        if abs(full.width - self.hf.width) > 1e-6 * self.hf.width or \
                abs(full.depth - self.hf.depth) > 1e-6 * self.hf.depth:
            raise InputError(f"the full-resolution field spans {full.width:.1f} x "
                             f"{full.depth:.1f} m, the terrain {self.hf.width:.1f} x "
                             f"{self.hf.depth:.1f} m")
        for vbo, ibo, _ in self._proxies.values():
            vbo.release()
            ibo.release()
        self._proxies.clear()
        self.generation += 1  # vertex arrays of the dropped proxies are not used again
        self.full = full

    def proxy(self, level_quads: int, border: bool) -> tuple[moderngl.Buffer, moderngl.Buffer,
                                                              int]:
        """(vertex buffer ``3f 2f``: position and uv, index buffer, index count) of level
        ``level_quads`` as one mesh, with its border ribbon if ``border``
        (:mod:`lodsprite.terrain.proxy`)."""
        key = (level_quads, border)
        if key not in self._proxies:
            mesh = proxy_mesh(self.full, level_quads, border)
            verts = np.concatenate([mesh.positions, mesh.uv], axis=1).astype(np.float32)
            mgl = self.ctx.mgl
            self._proxies[key] = (mgl.buffer(verts.tobytes()), mgl.buffer(mesh.tris.tobytes()),
                                  mesh.tris.size)
        return self._proxies[key]

    def set_uniforms(self, prog: moderngl.Program, step: int) -> None:
        hf = self.hf
        for name, value in (("u_step", step), ("u_corner", self.corner),
                            ("u_spacing", (hf.dx, hf.dy)),
                            ("u_uv_scale", (1.0 / (hf.cols - 1), 1.0 / (hf.rows - 1))),
                            ("u_last", (hf.cols - 1, hf.rows - 1))):
            if name in prog:  # a heights program has no texture coordinates
                prog[name].value = value

    def set_shading(self, prog: moderngl.Program) -> None:
        """The uniforms of the heights shading (``TERRAIN_HEIGHTS_FS``) that a proxy
        program's vertex shader does not set: ramp, corner, spacing, height texture 1."""
        for name, value in (("u_range", self.height_range), ("u_corner", self.corner),
                            ("u_spacing", (self.hf.dx, self.hf.dy)), ("u_height", 1)):
            if name in prog:
                prog[name].value = value

    def visible_chunks(self, layout: ChunkLayout, view_proj: np.ndarray) -> int:
        """Cull ``layout``'s chunks against the frustum; upload survivors' origins; return count."""
        mask = boxes_in_frustum(frustum_planes(view_proj), layout.mins, layout.maxs)
        visible = layout.origins[mask]
        if len(visible):
            self.instances.write(np.ascontiguousarray(visible).tobytes())
        return len(visible)

    def release(self) -> None:
        for vbo, ibo, _ in [*self._meshes.values(), *self._proxies.values()]:
            vbo.release()
            ibo.release()
        self._meshes.clear()
        self._proxies.clear()
        for obj in (self.height_tex, self.color_tex, self.instances, self.clip):
            obj.release()


def mat_bytes(m: np.ndarray) -> bytes:
    """A row-major ``(4, 4)`` matrix as the column-major float32 bytes GLSL expects."""
    return np.asarray(m, dtype=np.float32).T.tobytes()


class TerrainDrawer:
    """Renders a terrain at full resolution or at any uniform level into a render target.

    ``render`` issues the GL work and returns at once; call ``ctx.finish()``
    before stopping a clock, and ``target.read_color()`` / ``read_depth()`` for
    the pixels.
    """

    def __init__(self, ctx: GLContext, geometry: TerrainGeometry, width: int = 512,
                 height: int = 512, fov_y_deg: float = 45.0,
                 target: RenderTarget | None = None) -> None:
        self.ctx = ctx
        self.geometry = geometry
        self.fov_y_deg = fov_y_deg
        # Where frames go: a target of its own, or a given one (an application's window).
        self.target = target if target is not None else RenderTarget(ctx, width, height)
        self.program = ctx.mgl.program(vertex_shader=TERRAIN_VS, fragment_shader=TERRAIN_FS)
        self.proxy_program = ctx.mgl.program(vertex_shader=proxy_twin(TERRAIN_VS),
                                             fragment_shader=TERRAIN_FS)
        self._vaos: dict[int, moderngl.VertexArray] = {}
        self._proxy_vaos: dict[tuple[int, bool], moderngl.VertexArray] = {}
        # "texture": the terrain's colour texture; "heights": terrain_shade with per-pixel
        # normals from the height texture (gl.shaders.TERRAIN_HEIGHTS_FS), made when used
        self.shading = "texture"
        self._heights: tuple | None = None
        # Issue the chunk draws through ctypes, without the GIL (for worker threads: on
        # llvmpipe a large draw call shades its vertices on the calling thread, 30-40 ms
        # at full resolution, and moderngl holds the GIL meanwhile).
        self.unlocked_draws = False

    def vao(self, program: moderngl.Program, chunk_quads: int,
            cache: dict[int, moderngl.VertexArray]) -> moderngl.VertexArray:
        if chunk_quads not in cache:
            vbo, ibo, _ = self.geometry.mesh(chunk_quads)
            cache[chunk_quads] = self.ctx.mgl.vertex_array(
                program,
                [(vbo, "2i", "in_local"), (self.geometry.instances, "2i/i", "in_origin")],
                index_buffer=ibo, index_element_size=4)
        return cache[chunk_quads]

    def draw_proxy(self, program: moderngl.Program,
                   cache: dict[tuple, moderngl.VertexArray], view_proj: np.ndarray,
                   level_quads: int, border: bool) -> int:
        """Draw the proxy mesh of level ``level_quads`` (:meth:`TerrainGeometry.proxy`) whole,
        with ``program`` (reading ``PROXY_VERTEX_COMMON``, other uniforms set); returns
        the triangles drawn."""
        key = (level_quads, border, self.geometry.generation)
        vbo, ibo, count = self.geometry.proxy(level_quads, border)
        if key not in cache:
            layout = ((vbo, "3f 2f", "in_pos", "in_uv") if "in_uv" in program
                      else (vbo, "3f 2x4", "in_pos"))  # a heights program reads no uv
            cache[key] = self.ctx.mgl.vertex_array(program, [layout], index_buffer=ibo,
                                                   index_element_size=4)
        program["u_mvp"].write(mat_bytes(view_proj))
        cache[key].render(moderngl.TRIANGLES)
        return count // 3

    def projection(self, viewpoint: Viewpoint) -> Projection:
        """Projection with near/far fitted to the terrain's box and the eye's ground clearance."""
        hf = self.geometry.hf
        return fitted_projection(viewpoint, self.fov_y_deg, self.target.width / self.target.height,
                                 *hf.bounds(), float(hf.height_at(viewpoint.o[0], viewpoint.o[1])))

    def draw(self, program: moderngl.Program, cache: dict[int, moderngl.VertexArray],
             viewpoint: Viewpoint, projection: Projection, level_quads: int,
             cull: np.ndarray | None = None) -> Frame:
        """Draw one level with ``program`` (uniforms other than geometry's already set);
        chunks are culled by the frustum of ``cull (4, 4)`` when given (a tile's
        sub-frustum), else by the view's."""
        layout = self.geometry.layout(level_quads)
        view_proj = projection.matrix() @ viewpoint.view_matrix()
        chunks = self.geometry.visible_chunks(layout, view_proj if cull is None else cull)
        self.geometry.set_uniforms(program, layout.step)
        program["u_mvp"].write(mat_bytes(view_proj))
        if chunks:
            vao = self.vao(program, layout.chunk_quads, cache)
            draw = gl_draw_elements_instanced() if self.unlocked_draws else None
            if draw is None:
                vao.render(moderngl.TRIANGLES, instances=chunks)
            else:  # bind program and vertex array through moderngl, then draw
                vao.render(moderngl.TRIANGLES, vertices=0, instances=chunks)
                draw(moderngl.TRIANGLES, self.geometry.mesh(layout.chunk_quads)[2],
                     GL_UNSIGNED_INT, None, chunks)
        return draw_stats(chunks * layout.triangles_per_chunk, chunks, projection)

    def programs(self, proxy: bool) -> tuple[moderngl.Program, dict]:
        """The program (grid or proxy mesh) of :attr:`shading` and its vertex arrays,
        uniforms of the colour set."""
        if self.shading == "heights":
            if self._heights is None:
                mgl = self.ctx.mgl
                self._heights = (
                    mgl.program(vertex_shader=TERRAIN_VS, fragment_shader=TERRAIN_HEIGHTS_FS),
                    mgl.program(vertex_shader=proxy_twin(TERRAIN_VS),
                                fragment_shader=TERRAIN_HEIGHTS_FS), {}, {})
            prog, cache = self._heights[1 if proxy else 0], self._heights[3 if proxy else 2]
            self.geometry.set_shading(prog)
            return prog, cache
        prog = self.proxy_program if proxy else self.program
        prog["u_color"].value = 0
        self.geometry.clip.bind(prog)
        return prog, self._proxy_vaos if proxy else self._vaos

    def _begin(self, target: RenderTarget | None, clear: bool = True) -> None:
        target = target or self.target
        if clear:
            target.use(SKY_RGB)
        else:  # drawn over what is there, depth test against its depth
            target.fbo.use()
        self.ctx.mgl.enable(moderngl.DEPTH_TEST)
        self.geometry.color_tex.use(0)
        self.geometry.height_tex.use(1)

    def render(self, viewpoint: Viewpoint, level_quads: int | None = None,
               projection: Projection | None = None,
               target: RenderTarget | None = None,
               cull: np.ndarray | None = None, clear: bool = True) -> Frame:
        """Render the terrain coloured by :attr:`shading` into ``target`` (default: this
        renderer's own); ``level_quads`` None means full resolution; ``cull``: as
        :meth:`draw`; ``clear`` False draws over the target's colour and depth (the tiles
        of one image, :mod:`lodsprite.gl.reference`)."""
        level = self.geometry.hf.quads if level_quads is None else level_quads
        projection = projection or self.projection(viewpoint)
        if self.shading == "texture":  # the imagery's clip levels follow the eye
            self.geometry.clip.update(viewpoint.o)
        self._begin(target, clear)
        prog, cache = self.programs(proxy=False)
        prog["u_height"].value = 1
        return self.draw(prog, cache, viewpoint, projection, level, cull)

    def render_proxy(self, viewpoint: Viewpoint, level_quads: int, border: bool = True,
                     projection: Projection | None = None,
                     target: RenderTarget | None = None) -> Frame:
        """Render the proxy mesh of a coarse level (with its border ribbon if ``border``)
        coloured by :attr:`shading`, like :meth:`render`."""
        projection = projection or self.projection(viewpoint)
        self._begin(target)
        prog, cache = self.programs(proxy=True)
        tris = self.draw_proxy(prog, cache,
                               projection.matrix() @ viewpoint.view_matrix(), level_quads, border)
        return draw_stats(tris, 1, projection)

    def set_geometry(self, geometry: TerrainGeometry) -> None:
        """Draw ``geometry`` from now on (the vertex arrays of the last one released; the
        geometry is the caller's to release)."""
        self._release_vaos()
        self.geometry = geometry

    def _release_vaos(self) -> None:
        heights = self._heights or (None, None, {}, {})
        for cache in (self._vaos, self._proxy_vaos, heights[2], heights[3]):
            for vao in cache.values():
                vao.release()
            cache.clear()

    def release(self) -> None:
        heights = self._heights or (None, None, {}, {})
        self._release_vaos()
        for prog in (self.program, self.proxy_program, *heights[:2]):
            if prog is not None:
                prog.release()
        self._heights = None
        self.target.release()
