"""GL side of the time-critical lumigraph (Sloan, Cohen & Gortler 1997, §2.3).

* :class:`ColorMeshRenderer` draws a mesh with per-vertex colours under a fixed
  directional light through any view and projection: the node images of a capture, the
  ground truth, and the z-buffer of the approximate geometry (depth correction).
* :class:`LumigraphRenderer` reconstructs an image from node images kept in one texture
  array: every st-plane triangle is drawn once per corner node with data, textured from
  that node's uv image, with alpha 1 at that node and 0 at the other two corners, blended
  additively (the alphas sum to one).  The uv coordinate of a fragment is where the ray
  from the eye through it meets the uv plane, or, with depth correction (Gortler et al.
  1996), where the ray from the node through the approximate geometry's surface point
  seen at that pixel meets it; both per fragment, in the shader.

All triangles of all nodes are one vertex buffer and one draw: a frame uploads only the
eye and its matrices.
"""

from __future__ import annotations

import moderngl
import numpy as np

from lodsprite.gl.context import GLContext
from lodsprite.gl.terrain import mat_bytes
from lodsprite.lumigraph.geometry import Slab, grid_triangles

COLOR_MESH_VS = """#version 330
uniform mat4 u_mvp;
in vec3 in_pos;
in vec3 in_normal;
in vec3 in_color;
out vec3 v_color;
out vec3 v_normal;
void main() {
    v_color = in_color;
    v_normal = in_normal;
    gl_Position = u_mvp * vec4(in_pos, 1.0);
}
"""
COLOR_MESH_FS = """#version 330
uniform vec3 u_light;   // unit, towards the light (world)
in vec3 v_color;
in vec3 v_normal;
out vec4 f_color;
void main() {
    float lit = 0.35 + 0.65 * abs(dot(normalize(v_normal), u_light));
    f_color = vec4(v_color * lit, 1.0);
}
"""
LIGHT = np.array([0.4, 0.5, 0.77]) / np.linalg.norm([0.4, 0.5, 0.77])

RECON_VS = """#version 330
uniform mat4 u_mvp;          // local -> clip
in vec3 in_pos;              // st-plane corner, local frame
in float in_alpha;           // 1 at the node whose image this copy uses, 0 elsewhere
in float in_layer;           // that node's layer in the texture array
in vec3 in_node;             // that node's position, local frame
out float v_alpha;
out vec3 v_pos;
flat out float v_layer;
flat out vec3 v_node;
void main() {
    v_alpha = in_alpha;
    v_pos = in_pos;
    v_layer = in_layer;
    v_node = in_node;
    gl_Position = u_mvp * vec4(in_pos, 1.0);
}
"""
RECON_FS = """#version 330
uniform sampler2DArray u_nodes;
uniform sampler2D u_proxy_depth;  // window depth of the approximate geometry (1: none)
uniform mat4 u_inv_mvp;           // clip -> local
uniform vec3 u_eye;               // local frame
uniform vec2 u_viewport;
uniform float u_uv_size;
uniform int u_depth_correct;
uniform int u_white;              // 1: every texel white (the alpha-sum check)
in float v_alpha;
in vec3 v_pos;
flat in float v_layer;
flat in vec3 v_node;
out vec4 f_color;
vec2 uv_plane_hit(vec3 o, vec3 p) {
    vec3 d = p - o;
    return o.xy + (-o.z / d.z) * d.xy;
}
void main() {
    vec2 uv = uv_plane_hit(u_eye, v_pos);  // no correction: the eye ray on the uv plane
    if (u_depth_correct == 1) {
        float z = texture(u_proxy_depth, gl_FragCoord.xy / u_viewport).r;
        if (z < 1.0) {
            vec4 c = u_inv_mvp * vec4(vec3(gl_FragCoord.xy / u_viewport, z) * 2.0 - 1.0, 1.0);
            vec3 x = c.xyz / c.w;             // the proxy's surface seen at this pixel
            uv = uv_plane_hit(v_node, x);     // where the node saw it
        }
    }
    vec2 tc = uv / u_uv_size + 0.5;
    // A ray that crosses the uv plane outside its square was never captured: it carries
    // the capture's background (black), not the image's clamped edge.
    bool outside = any(lessThan(tc, vec2(0.0))) || any(greaterThan(tc, vec2(1.0)));
    vec3 rgb = u_white == 1 ? vec3(1.0)
             : (outside ? vec3(0.0) : texture(u_nodes, vec3(tc, v_layer)).rgb);
    f_color = vec4(rgb * v_alpha, v_alpha);
}
"""


class ColorMeshRenderer:
    """A mesh with per-vertex colours, lit by a fixed directional light."""

    def __init__(self, ctx: GLContext, vertices: np.ndarray, faces: np.ndarray,
                 colors: np.ndarray, normals: np.ndarray) -> None:
        mgl = ctx.mgl
        self.ctx = ctx
        data = np.concatenate([vertices, normals, colors], axis=1).astype(np.float32)
        self.vbo = mgl.buffer(np.ascontiguousarray(data).tobytes())
        self.ibo = mgl.buffer(np.ascontiguousarray(faces, dtype=np.int32).tobytes())
        self.program = mgl.program(vertex_shader=COLOR_MESH_VS, fragment_shader=COLOR_MESH_FS)
        self.program["u_light"].value = tuple(LIGHT)
        self.vao = mgl.vertex_array(self.program, [(self.vbo, "3f 3f 3f", "in_pos",
                                                    "in_normal", "in_color")],
                                    index_buffer=self.ibo, index_element_size=4)

    def render(self, view_proj: np.ndarray, fbo: moderngl.Framebuffer,
               clear: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> None:
        """Draw into ``fbo`` (cleared to ``clear``) through ``view_proj (4, 4)``."""
        fbo.use()
        fbo.clear(*clear, 1.0, depth=1.0)
        self.ctx.mgl.enable(moderngl.DEPTH_TEST)
        self.program["u_mvp"].write(mat_bytes(view_proj))
        self.vao.render(moderngl.TRIANGLES)

    def release(self) -> None:
        for obj in (self.vao, self.program, self.vbo, self.ibo):
            obj.release()


def reconstruction_vertices(slab: Slab, layers: np.ndarray) -> np.ndarray:
    """The vertex data of §2.3 for the nodes with data (``layers (n_st, n_st) int``,
    their texture-array layer, -1 for none): each st triangle once per corner with data,
    ``(k * 3, 8) float32``: position (3), alpha (1), layer (1), node position (3).

    The copy for corner ``a`` has alpha 1 at ``a`` and 0 at the other corners with data;
    a corner without data (a fictitious node, §3.1's ``draw_node_without_data``) gets
    ``1 / d`` from each of the triangle's ``d`` corners with data, so the alphas still sum
    to one wherever a triangle has a corner with data."""
    n = slab.n_st
    nodes = slab.node_local().reshape(-1, 3)
    lay = np.asarray(layers).reshape(-1)
    tris = grid_triangles(n)                                  # (T, 3)
    has = lay[tris] >= 0                                      # (T, 3)
    count = has.sum(axis=1)                                   # data corners per triangle
    corner = np.repeat(tris, 3, axis=0)                       # (3T, 3): one copy per corner
    which = np.tile(np.arange(3), len(tris))                  # the corner that copy serves
    node = corner[np.arange(len(corner)), which]              # (3T,)
    keep = lay[node] >= 0
    has_c = np.repeat(has, 3, axis=0)[keep]
    d = np.repeat(count, 3)[keep]
    corner, which, node = corner[keep], which[keep], node[keep]
    own = np.arange(3)[None, :] == which[:, None]
    alpha = np.where(own, 1.0, np.where(has_c, 0.0, 1.0 / d[:, None]))
    pos = nodes[corner]                                       # (K, 3, 3)
    out = np.concatenate([pos, alpha[..., None],
                          np.broadcast_to(lay[node][:, None, None], (len(node), 3, 1)),
                          np.broadcast_to(nodes[node][:, None, :], (len(node), 3, 3))],
                         axis=2)
    return out.reshape(-1, 8).astype(np.float32)


class LumigraphRenderer:
    """Reconstruction from node images (``images[i, j]`` ``(n_uv, n_uv, 3) uint8``, row 0
    at the top, or None for a node without data) into a ``width x height`` float target."""

    def __init__(self, ctx: GLContext, slab: Slab, images: dict[tuple[int, int], np.ndarray],
                 width: int, height: int) -> None:
        mgl = ctx.mgl
        self.ctx, self.slab = ctx, slab
        self.size = (int(width), int(height))
        layers = np.full((slab.n_st, slab.n_st), -1, dtype=np.int64)
        keys = sorted(images)
        for k, (i, j) in enumerate(keys):
            layers[i, j] = k
        self.layers = layers
        self.images = len(keys)  # node images drawn per frame (every one with data)
        n = slab.n_uv
        self.nodes = mgl.texture_array((n, n, max(len(keys), 1)), 3, alignment=1)
        for k, key in enumerate(keys):
            img = np.ascontiguousarray(images[key][::-1], dtype=np.uint8)  # GL rows
            self.nodes.write(img.tobytes(), viewport=(0, 0, k, n, n, 1))
        self.nodes.build_mipmaps()
        self.nodes.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
        self.nodes.repeat_x = self.nodes.repeat_y = False
        self.program = mgl.program(vertex_shader=RECON_VS, fragment_shader=RECON_FS)
        verts = reconstruction_vertices(slab, layers)
        self.vertex_count = len(verts)
        self.vbo = mgl.buffer(verts.tobytes() if len(verts) else b"\0" * 32)
        self.vao = mgl.vertex_array(self.program, [(self.vbo, "3f 1f 1f 3f", "in_pos",
                                                    "in_alpha", "in_layer", "in_node")])
        self.color = mgl.texture(self.size, 4, dtype="f2")
        self.fbo = mgl.framebuffer(color_attachments=[self.color])
        self.proxy_depth = mgl.depth_texture(self.size)
        self.proxy_depth.compare_func = ""
        self.proxy_fbo = mgl.framebuffer(depth_attachment=self.proxy_depth)

    def render(self, view: np.ndarray, projection: np.ndarray,
               proxy: ColorMeshRenderer | None = None, white: bool = False) -> None:
        """Reconstruct the view ``projection @ view`` (world to clip); with ``proxy``, the
        approximate geometry's z-buffer corrects the uv coordinates for depth."""
        mgl = self.ctx.mgl
        view_proj = projection @ view
        mvp = view_proj @ self.slab.frame                     # local -> clip
        if proxy is not None:
            proxy.render(view_proj, self.proxy_fbo)
        eye_world = np.linalg.inv(view)[:3, 3]
        eye_local = (self.slab.to_local @ np.append(eye_world, 1.0))[:3]
        self.fbo.use()
        self.fbo.clear(0.0, 0.0, 0.0, 0.0)
        mgl.disable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        mgl.enable(moderngl.BLEND)
        mgl.blend_func = moderngl.ONE, moderngl.ONE
        p = self.program
        p["u_mvp"].write(mat_bytes(mvp))
        p["u_inv_mvp"].write(mat_bytes(np.linalg.inv(mvp)))
        p["u_eye"].value = tuple(float(v) for v in eye_local)
        p["u_viewport"].value = (float(self.size[0]), float(self.size[1]))
        p["u_uv_size"].value = float(self.slab.uv_size)
        p["u_depth_correct"].value = int(proxy is not None)
        p["u_white"].value = int(white)
        p["u_nodes"].value, p["u_proxy_depth"].value = 0, 1
        self.nodes.use(0)
        self.proxy_depth.use(1)
        if self.vertex_count:
            self.vao.render(moderngl.TRIANGLES, vertices=self.vertex_count)
        mgl.disable(moderngl.BLEND)

    def read_rgba(self) -> np.ndarray:
        """The reconstruction, ``(h, w, 4) float32`` premultiplied, row 0 at the top."""
        w, h = self.size
        data = np.frombuffer(self.color.read(alignment=1), np.float16).reshape(h, w, 4)
        return data[::-1].astype(np.float32)

    def read_rgb8(self, background: tuple[float, float, float] = (0.0, 0.0, 0.0)
                  ) -> np.ndarray:
        """Composited over ``background`` (linear [0, 1]), ``(h, w, 3) uint8``."""
        rgba = self.read_rgba()
        rgb = rgba[..., :3] + (1.0 - np.clip(rgba[..., 3:], 0, 1)) * np.array(background)
        return np.clip(np.rint(rgb * 255.0), 0, 255).astype(np.uint8)

    def release(self) -> None:
        for obj in (self.vao, self.vbo, self.program, self.nodes, self.fbo, self.color,
                    self.proxy_fbo, self.proxy_depth):
            obj.release()
