"""What a window draws besides the scene: the frame image, line overlays and the HUD.

* :class:`Presenter` draws a region of a colour texture over a viewport of the bound
  framebuffer (a keyframe's centre without its guard band, or a frame rendered at another
  size than the window's framebuffer).
* :class:`LineOverlay` draws world-space line segments (a keyframe's frustum) and the
  coarse level as a wireframe, over the frame.
* :class:`HudLayer` draws text from a glyph atlas on a translucent panel and a rolling
  frame-time graph as a line strip, in pixels from the top-left corner.

GPU objects are made once and reused every frame; only small uniforms and vertex data
change per frame.
"""

from __future__ import annotations

import moderngl
import numpy as np

from lodsprite.camera import Projection, Viewpoint
from lodsprite.gl.context import GLContext
from lodsprite.gl.terrain import TerrainGeometry, mat_bytes

_QUAD_VS = """#version 330
uniform vec4 u_uv;     // source region in texture coordinates: u0, v0, u1, v1
in vec2 in_corner;     // (0, 0) .. (1, 1): the whole viewport
out vec2 v_uv;
void main() {
    v_uv = mix(u_uv.xy, u_uv.zw, in_corner);
    gl_Position = vec4(in_corner * 2.0 - 1.0, 0.0, 1.0);
}
"""
_QUAD_FS = """#version 330
uniform sampler2D u_image;
in vec2 v_uv;
out vec4 f_color;
void main() { f_color = texture(u_image, v_uv); }
"""
_LINE_VS = """#version 330
uniform mat4 u_mvp;
in vec3 in_pos;
void main() { gl_Position = u_mvp * vec4(in_pos, 1.0); }
"""
_LINE_FS = """#version 330
uniform vec4 u_rgba;
out vec4 f_color;
void main() { f_color = u_rgba; }
"""
# Edges of the clip-space cube, as index pairs into its corners (x, y, z bits).
_CUBE_EDGES = np.array([[0, 1], [2, 3], [4, 5], [6, 7], [0, 2], [1, 3], [4, 6], [5, 7],
                        [0, 4], [1, 5], [2, 6], [3, 7]], dtype=np.intp)


def frustum_segments(viewpoint: Viewpoint, projection: Projection) -> np.ndarray:
    """The 12 edges of the view frustum of ``viewpoint`` through ``projection``, as
    ``(24, 3) float32`` world-space end points (metres), pairs in order."""
    inv = np.linalg.inv(projection.matrix() @ viewpoint.view_matrix())
    bits = np.arange(8)
    ndc = np.stack([(bits & 1) * 2 - 1, (bits >> 1 & 1) * 2 - 1, (bits >> 2 & 1) * 2 - 1,
                    np.ones(8)], axis=1).astype(np.float64)
    world = ndc @ inv.T
    corners = world[:, :3] / world[:, 3:]
    return corners[_CUBE_EDGES.ravel()].astype(np.float32)


class Presenter:
    """Draws a texture region over the whole viewport of the bound framebuffer."""

    def __init__(self, ctx: GLContext) -> None:
        mgl = ctx.mgl
        self.ctx = ctx
        self.program = mgl.program(vertex_shader=_QUAD_VS, fragment_shader=_QUAD_FS)
        corners = np.array([0, 0, 1, 0, 0, 1, 1, 1], dtype=np.float32)
        self.vbo = mgl.buffer(corners.tobytes())
        self.vao = mgl.vertex_array(self.program, [(self.vbo, "2f", "in_corner")])

    def draw(self, texture: moderngl.Texture,
             uv: tuple[float, float, float, float] = (0.0, 0.0, 1.0, 1.0)) -> None:
        """Draw ``texture``'s region ``uv = (u0, v0, u1, v1)`` (GL's bottom-up texture
        coordinates) stretched over the viewport, with no depth test and no blending."""
        self.ctx.mgl.disable(moderngl.DEPTH_TEST | moderngl.BLEND)
        texture.use(0)
        self.program["u_image"].value = 0
        self.program["u_uv"].value = uv
        self.vao.render(moderngl.TRIANGLE_STRIP)

    def release(self) -> None:
        for obj in (self.vao, self.vbo, self.program):
            obj.release()


class LineOverlay:
    """World-space lines over a frame: segments (a frustum) and a coarse level's wireframe."""

    def __init__(self, ctx: GLContext, max_segments: int = 64) -> None:
        mgl = ctx.mgl
        self.ctx = ctx
        self.program = mgl.program(vertex_shader=_LINE_VS, fragment_shader=_LINE_FS)
        self.max_segments = max_segments
        self.vbo = mgl.buffer(reserve=max_segments * 2 * 12)
        self.vao = mgl.vertex_array(self.program, [(self.vbo, "3f", "in_pos")])
        self._meshes: dict[tuple[int, int], moderngl.VertexArray] = {}

    def segments(self, points: np.ndarray, view_proj: np.ndarray,
                 rgba: tuple[float, float, float, float]) -> None:
        """Draw ``points (2k, 3)`` metres as ``k`` segments (at most ``max_segments``)."""
        pts = np.ascontiguousarray(points[: 2 * self.max_segments], dtype=np.float32)
        self.vbo.write(pts.tobytes())
        self._begin(view_proj, rgba)
        self.vao.render(moderngl.LINES, vertices=len(pts))

    def wireframe(self, geometry: TerrainGeometry, level_quads: int, view_proj: np.ndarray,
                  rgba: tuple[float, float, float, float]) -> None:
        """Draw the proxy mesh of level ``level_quads`` (border ribbons excluded) as lines."""
        key = (id(geometry), level_quads)
        if key not in self._meshes:
            vbo, ibo, _ = geometry.proxy(level_quads, False)
            self._meshes[key] = self.ctx.mgl.vertex_array(
                self.program, [(vbo, "3f 8x", "in_pos")], index_buffer=ibo,
                index_element_size=4)
        self._begin(view_proj, rgba)
        self.ctx.mgl.wireframe = True
        try:
            self._meshes[key].render(moderngl.TRIANGLES)
        finally:
            self.ctx.mgl.wireframe = False

    def forget_meshes(self) -> None:
        """Release the wireframe vertex arrays (their terrain geometry is going away)."""
        for vao in self._meshes.values():
            vao.release()
        self._meshes.clear()

    def _begin(self, view_proj: np.ndarray, rgba: tuple[float, float, float, float]) -> None:
        mgl = self.ctx.mgl
        mgl.disable(moderngl.DEPTH_TEST)
        mgl.enable(moderngl.BLEND)
        mgl.blend_func = moderngl.SRC_ALPHA, moderngl.ONE_MINUS_SRC_ALPHA
        self.program["u_mvp"].write(mat_bytes(view_proj))
        self.program["u_rgba"].value = rgba

    def release(self) -> None:
        for vao in self._meshes.values():
            vao.release()
        self._meshes.clear()
        for obj in (self.vao, self.vbo, self.program):
            obj.release()


_TEXT_VS = """#version 330
uniform vec2 u_viewport;   // pixels
in vec2 in_xy;             // pixels from the top-left
in vec2 in_uv;
out vec2 v_uv;
void main() {
    v_uv = in_uv;
    gl_Position = vec4(2.0 * in_xy.x / u_viewport.x - 1.0, 1.0 - 2.0 * in_xy.y / u_viewport.y,
                       0.0, 1.0);
}
"""
_TEXT_FS = """#version 330
uniform sampler2D u_atlas;  // glyph coverage
uniform vec4 u_rgba;
in vec2 v_uv;
out vec4 f_color;
void main() { f_color = vec4(u_rgba.rgb, u_rgba.a * texture(u_atlas, v_uv).r); }
"""
PANEL_RGBA = (0.04, 0.055, 0.08, 0.67)
TEXT_RGBA = (0.92, 0.94, 0.96, 1.0)
GRAPH_RGBA = (1.0, 0.85, 0.2, 1.0)


class HudLayer:
    """Text from a glyph atlas on a translucent panel, and a frame-time graph, drawn in
    window pixels (:mod:`lodsprite.viewer.hud` lays the text out)."""

    def __init__(self, ctx: GLContext, atlas_alpha: np.ndarray, max_chars: int = 2048,
                 graph_points: int = 240) -> None:
        mgl = ctx.mgl
        self.ctx = ctx
        h, w = atlas_alpha.shape
        # v runs down the atlas image (row 0 at the top): upload rows as they are.
        self.atlas = mgl.texture((w, h), 1, np.ascontiguousarray(atlas_alpha).tobytes(),
                                 alignment=1)
        self.atlas.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.text_program = mgl.program(vertex_shader=_TEXT_VS, fragment_shader=_TEXT_FS)
        self.max_chars = max_chars
        self.text_vbo = mgl.buffer(reserve=(max_chars + 1) * 6 * 16)
        self.text_vao = mgl.vertex_array(self.text_program,
                                         [(self.text_vbo, "2f 2f", "in_xy", "in_uv")])
        self._glyph_vertices = 0
        self.panel_height = 0.0
        self.graph_points = graph_points
        self.line_program = mgl.program(vertex_shader="""#version 330
in vec2 in_xy;
void main() { gl_Position = vec4(in_xy, 0.0, 1.0); }
""", fragment_shader=_LINE_FS)
        self.graph_vbo = mgl.buffer(reserve=graph_points * 8)
        self.graph_vao = mgl.vertex_array(self.line_program, [(self.graph_vbo, "2f", "in_xy")])

    def set_text(self, background: np.ndarray, glyphs: np.ndarray) -> None:
        """The panel's quads: ``background (6, 4)`` and ``glyphs (n*6, 4) float32``
        vertices ``x, y, u, v`` (pixels from the top-left; atlas coordinates), as
        :func:`lodsprite.viewer.hud.layout_text` makes them."""
        glyphs = glyphs[: self.max_chars * 6]
        data = np.ascontiguousarray(np.concatenate([background, glyphs]), dtype=np.float32)
        self.text_vbo.write(data.tobytes())
        self._glyph_vertices = len(glyphs)
        self.panel_height = float(background[:, 1].max())

    def draw(self, viewport: tuple[int, int], graph_ms: np.ndarray,
             graph_box: tuple[int, int, int, int], graph_max_ms: float) -> None:
        """Draw the panel and its text, and the graph of ``graph_ms`` (oldest first) in
        ``graph_box = (x, y, w, h)`` pixels from the top-left, scaled so that
        ``graph_max_ms`` reaches the top of the box.  ``viewport`` is ``(w, h)`` pixels."""
        mgl = self.ctx.mgl
        vw, vh = viewport
        mgl.disable(moderngl.DEPTH_TEST)
        mgl.enable(moderngl.BLEND)
        mgl.blend_func = moderngl.SRC_ALPHA, moderngl.ONE_MINUS_SRC_ALPHA
        if self._glyph_vertices:
            self.atlas.use(0)
            prog = self.text_program
            prog["u_atlas"].value = 0
            prog["u_viewport"].value = (float(vw), float(vh))
            prog["u_rgba"].value = PANEL_RGBA
            self.text_vao.render(moderngl.TRIANGLES, vertices=6)
            prog["u_rgba"].value = TEXT_RGBA
            self.text_vao.render(moderngl.TRIANGLES, vertices=self._glyph_vertices, first=6)
        ms = np.asarray(graph_ms, dtype=np.float32)[-self.graph_points:]
        if len(ms) >= 2:
            x, y, w, h = graph_box
            px = x + np.linspace(0.0, w, len(ms), dtype=np.float32)
            py = y + h - h * np.clip(ms / graph_max_ms, 0.0, 1.0)
            xy = np.stack([2.0 * px / vw - 1.0, 1.0 - 2.0 * py / vh], axis=1)
            self.graph_vbo.write(np.ascontiguousarray(xy, dtype=np.float32).tobytes())
            self.line_program["u_rgba"].value = GRAPH_RGBA
            self.graph_vao.render(moderngl.LINE_STRIP, vertices=len(ms))
        mgl.disable(moderngl.BLEND)

    def release(self) -> None:
        for obj in (self.text_vao, self.text_vbo, self.text_program, self.atlas,
                    self.graph_vao, self.graph_vbo, self.line_program):
            obj.release()
