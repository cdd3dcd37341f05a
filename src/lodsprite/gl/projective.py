"""GL side of the time-critical lumigraph's image reuse (Sloan, Cohen & Gortler 1997,
§3.2): :class:`ProjectiveDrawer` keeps the last reconstructed image (a
:class:`~lodsprite.gl.lumigraph.FloatTarget`) and warps it to later views as a projective
texture on the approximate geometry, one draw call per frame."""

from __future__ import annotations

import moderngl
import numpy as np

from lodsprite.gl.context import GLContext
from lodsprite.gl.lumigraph import FloatTarget
from lodsprite.gl.terrain import mat_bytes

PROJ_VS = """#version 330
uniform mat4 u_mvp;       // world -> clip, this frame
uniform mat4 u_tex;       // world -> [0, 1]^3: the reused image's view, scaled (§3.2's M)
in vec3 in_pos;
out vec4 v_tc;
void main() {
    v_tc = u_tex * vec4(in_pos, 1.0);
    gl_Position = u_mvp * vec4(in_pos, 1.0);
}
"""
PROJ_FS = """#version 330
uniform sampler2D u_image;  // the reused reconstruction, premultiplied
in vec4 v_tc;
out vec4 f_color;
void main() {
    vec2 tc = v_tc.xy / v_tc.w;
    bool outside = v_tc.w <= 0.0 || any(lessThan(tc, vec2(0.0)))
                   || any(greaterThan(tc, vec2(1.0)));
    f_color = outside ? vec4(0.0) : texture(u_image, tc);
}
"""
TEXTURE_MATRIX = np.array([[0.5, 0, 0, 0.5], [0, 0.5, 0, 0.5], [0, 0, 0.5, 0.5],
                           [0, 0, 0, 1.0]])


class ProjectiveDrawer(FloatTarget):
    """§3.2: the last reconstructed image reused as a projective texture on the
    approximate geometry (``proxy``, vertices in world space) for the frames after it."""

    def __init__(self, ctx: GLContext, proxy_vertices: np.ndarray, proxy_faces: np.ndarray,
                 width: int, height: int) -> None:
        super().__init__(ctx, width, height)
        mgl = ctx.mgl
        self.image = mgl.texture(self.size, 4, dtype="f2")
        self.image.filter = (moderngl.LINEAR, moderngl.LINEAR)
        self.image.repeat_x = self.image.repeat_y = False
        self.vbo = mgl.buffer(np.ascontiguousarray(proxy_vertices, np.float32).tobytes())
        self.ibo = mgl.buffer(np.ascontiguousarray(proxy_faces, np.int32).tobytes())
        self.program = mgl.program(vertex_shader=PROJ_VS, fragment_shader=PROJ_FS)
        self.vao = mgl.vertex_array(self.program, [(self.vbo, "3f", "in_pos")],
                                    index_buffer=self.ibo, index_element_size=4)
        self.key_view_proj: np.ndarray | None = None
        self.query = mgl.query(samples=True)
        self.samples = 0

    def take(self, source: FloatTarget, view_proj: np.ndarray) -> None:
        """Keep ``source``'s image, reconstructed through ``view_proj``, as the texture
        (a framebuffer-to-texture copy, as the paper's glCopyTexImage)."""
        self.ctx.mgl.copy_framebuffer(self.image, source.fbo)
        self.key_view_proj = np.asarray(view_proj, dtype=np.float64)

    def render(self, view: np.ndarray, projection: np.ndarray,
               count_samples: bool = False) -> None:
        """Warp the kept image to the view ``projection @ view`` on the geometry."""
        if self.key_view_proj is None:
            raise RuntimeError("no reconstructed image to reuse yet: call take() first")
        mgl = self.ctx.mgl
        self.fbo.use()
        self.fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        mgl.enable(moderngl.DEPTH_TEST)
        mgl.disable(moderngl.BLEND | moderngl.CULL_FACE)
        self.program["u_mvp"].write(mat_bytes(projection @ view))
        self.program["u_tex"].write(mat_bytes(TEXTURE_MATRIX @ self.key_view_proj))
        self.program["u_image"].value = 0
        self.image.use(0)
        if count_samples:
            with self.query:
                self.vao.render(moderngl.TRIANGLES)
            self.samples = int(self.query.samples)
        else:
            self.vao.render(moderngl.TRIANGLES)
        mgl.disable(moderngl.DEPTH_TEST)

    def release(self) -> None:
        for obj in (self.vao, self.program, self.vbo, self.ibo, self.image):
            obj.release()
        super().release()
