"""Depth compositing of an image-based object into a frame: its reconstruction projected
onto its proxy geometry, drawn into the frame's own depth buffer.

A light-field object (Sloan, Cohen & Gortler 1997) is reconstructed into a small target
of its own through the frame's view and a projection cropped to the object's screen
rectangle ``rect``, so that the reconstruction's texel at ``(p - rect.xy) / rect.wh`` is
the object seen through the frame's window position ``p``.
:class:`ProxyCompositor` then draws the object's approximate geometry (the proxy mesh the
reconstruction's depth correction uses), placed in the world by a model matrix, into the
frame with the depth test on and depth writes on: each proxy fragment that is in front of
what the frame holds takes the reconstruction's colour at its own window position (the
reconstruction projected onto the proxy from the eye; premultiplied alpha undone), so the
object hides what is behind it and is hidden by what is in front, in the one depth
buffer.  Where the reconstruction has no coverage (alpha ~ 0: rays outside the slab) the
proxy's own shaded colour stands in.
"""

from __future__ import annotations

import moderngl
import numpy as np

from lodsprite.gl.context import GLContext
from lodsprite.gl.lumigraph import COLOR_MESH_VS, LIGHT
from lodsprite.gl.terrain import mat_bytes

# The proxy's vertices as the lumigraph's colour meshes pass them (position, normal, colour).
PROXY_VS = COLOR_MESH_VS
PROXY_FS = """#version 330
uniform sampler2D u_image;   // the reconstruction, premultiplied RGBA
uniform vec2 u_viewport;
uniform vec4 u_rect;         // the window region it covers: x0, y0, width, height in 0..1
uniform vec3 u_light;
in vec3 v_color;
in vec3 v_normal;
out vec4 f_color;
void main() {
    vec4 c = texture(u_image, (gl_FragCoord.xy / u_viewport - u_rect.xy) / u_rect.zw);
    vec3 own = v_color * (0.35 + 0.65 * abs(dot(normalize(v_normal), u_light)));
    f_color = vec4(c.a > 0.02 ? c.rgb / c.a : own, 1.0);
}
"""


class ProxyCompositor:
    """A proxy mesh (``vertices (n, 3)``, ``faces (m, 3)``, ``colors``, ``normals``, in the
    object's own frame) drawn into a frame with a reconstruction projected onto it."""

    def __init__(self, ctx: GLContext, vertices: np.ndarray, faces: np.ndarray,
                 colors: np.ndarray, normals: np.ndarray) -> None:
        mgl = ctx.mgl
        self.ctx = ctx
        data = np.concatenate([vertices, normals, colors], axis=1).astype(np.float32)
        self.vbo = mgl.buffer(np.ascontiguousarray(data).tobytes())
        self.ibo = mgl.buffer(np.ascontiguousarray(faces, dtype=np.int32).tobytes())
        self.program = mgl.program(vertex_shader=PROXY_VS, fragment_shader=PROXY_FS)
        self.program["u_light"].value = tuple(LIGHT)
        self.vao = mgl.vertex_array(self.program, [(self.vbo, "3f 3f 3f", "in_pos",
                                                    "in_normal", "in_color")],
                                    index_buffer=self.ibo, index_element_size=4)
        self.triangles = len(faces)

    def draw(self, mvp: np.ndarray, image: moderngl.Texture, fbo: moderngl.Framebuffer,
             rect: tuple[float, float, float, float] = (0.0, 0.0, 1.0, 1.0)) -> int:
        """Draw over ``fbo`` (no clear; depth tested and written) through ``mvp (4, 4)``
        (object -> the frame's clip space), coloured from ``image``, which covers the
        window region ``rect`` (``x0, y0, width, height``, fractions of ``fbo``'s
        viewport, GL's bottom-up rows); returns the triangles drawn."""
        mgl = self.ctx.mgl
        fbo.use()
        mgl.enable(moderngl.DEPTH_TEST)
        mgl.disable(moderngl.CULL_FACE | moderngl.BLEND)
        image.use(0)
        self.program["u_image"].value = 0
        self.program["u_viewport"].value = (float(fbo.viewport[2]), float(fbo.viewport[3]))
        self.program["u_rect"].value = tuple(float(v) for v in rect)
        self.program["u_mvp"].write(mat_bytes(mvp))
        self.vao.render(moderngl.TRIANGLES)
        mgl.disable(moderngl.DEPTH_TEST)
        return self.triangles

    def release(self) -> None:
        for obj in (self.vao, self.program, self.vbo, self.ibo):
            obj.release()
