"""GL side of the time-critical lumigraph (Sloan, Cohen & Gortler 1997, §2.3).

* :class:`ColorMeshDrawer` draws a mesh with per-vertex colours under a fixed
  directional light through any view and projection: the node images of a capture, the
  ground truth, and the z-buffer of the approximate geometry (depth correction).
* :class:`LumigraphDrawer` reconstructs an image from node images resident in one
  texture array (the texture memory of §4): the draws of a covering of the st plane
  (:mod:`lodsprite.lumigraph.subsets`: each triangle once per node with data round it,
  textured from that node's uv image, alphas summing to one), blended additively.  The uv
  coordinate of a fragment is where the ray from the eye through it meets the uv plane,
  or, with depth correction (Gortler et al. 1996), where the ray from the node through
  the approximate geometry's surface point seen at that pixel meets it; both per
  fragment, in the shader.
* :class:`~lodsprite.gl.projective.ProjectiveDrawer` (:mod:`lodsprite.gl.projective`)
  reuses the last reconstructed image as a projective texture on the approximate geometry
  (§3.2).

All draws are one vertex buffer and one draw call; a frame uploads only the eye and its
matrices, plus the vertex buffer when the covering changes.  The slab and the draws are
the light field's data, passed in (gl/ imports no technique package).
"""

from __future__ import annotations

from typing import Protocol

import moderngl
import numpy as np

from lodsprite.gl.context import GLContext
from lodsprite.gl.terrain import mat_bytes


class Slab(Protocol):
    """What this module reads of a light slab (:class:`lodsprite.lumigraph.geometry.Slab`,
    named by no import: the lumigraph package draws through this one)."""

    frame: np.ndarray
    uv_size: float
    st_distance: float
    n_st: int
    n_uv: int

    @property
    def to_local(self) -> np.ndarray: ...
    def node_local(self) -> np.ndarray: ...


class Draws(Protocol):
    """What this module reads of a frame's triangle draws
    (:class:`lodsprite.lumigraph.subsets.Draws`)."""

    corners: np.ndarray
    node: np.ndarray
    alpha: np.ndarray

    @property
    def nodes(self) -> np.ndarray: ...

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


class ColorMeshDrawer:
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


def draw_vertices(slab: Slab, draws: Draws, slots: np.ndarray) -> np.ndarray:
    """The vertex data of ``draws`` (:mod:`lodsprite.lumigraph.subsets`), ``(D * 3, 8)
    float32``: st corner in the local frame (3), alpha (1), the texture-array layer of the
    draw's node (1, from ``slots (n_st * n_st,)``) and that node's position (3)."""
    d = len(draws)
    nodes = slab.node_local().reshape(-1, 3)
    pos = np.concatenate([draws.corners, np.full((d, 3, 1), slab.st_distance)], axis=2)
    layer = np.broadcast_to(slots[draws.node].astype(np.float64)[:, None, None], (d, 3, 1))
    node = np.broadcast_to(nodes[draws.node][:, None, :], (d, 3, 3))
    out = np.concatenate([pos, draws.alpha[..., None], layer, node], axis=2)
    return out.reshape(-1, 8).astype(np.float32)


class FloatTarget:
    """A ``width x height`` half-float RGBA colour texture (premultiplied alpha) with a
    depth buffer, bound as one framebuffer: where reconstructions accumulate."""

    def __init__(self, ctx: GLContext, width: int, height: int) -> None:
        mgl = ctx.mgl
        self.ctx = ctx
        self.size = (int(width), int(height))
        self.color = mgl.texture(self.size, 4, dtype="f2")
        self.color.repeat_x = self.color.repeat_y = False
        self.depth = mgl.depth_renderbuffer(self.size)
        self.fbo = mgl.framebuffer(color_attachments=[self.color], depth_attachment=self.depth)

    def read_rgba(self) -> np.ndarray:
        """``(h, w, 4) float32`` premultiplied, row 0 at the top."""
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
        if self.ctx.mgl.fbo is self.fbo:
            # moderngl re-binds the current framebuffer after creating others: never a dead one.
            self.ctx.default_fbo.use()
        for obj in (self.fbo, self.color, self.depth):
            obj.release()


class LumigraphDrawer(FloatTarget):
    """Reconstruction (§2.3) from node images resident in a texture array of ``capacity``
    layers of ``n_uv >> level`` pixels square (the texture memory of §4: nodes are
    uploaded into free layers and evicted by the caller) into a float target.

    :meth:`set_draws` takes any covering of §3.1 (:mod:`lodsprite.lumigraph.subsets`)
    whose nodes are resident; :meth:`render` draws it in one call."""

    BYTES_PER_TEXEL = 4  # RGB is stored as RGBA by GL drivers (and by the paper's Impact)

    def __init__(self, ctx: GLContext, slab: Slab, width: int, height: int,
                 capacity: int, level: int = 0) -> None:
        super().__init__(ctx, width, height)
        mgl = ctx.mgl
        self.slab, self.level = slab, int(level)
        self.n = max(1, slab.n_uv >> self.level)
        self.capacity = max(1, int(capacity))
        self.nodes = mgl.texture_array((self.n, self.n, self.capacity), 3, alignment=1)
        self.nodes.filter = (moderngl.LINEAR, moderngl.LINEAR)
        self.nodes.repeat_x = self.nodes.repeat_y = False
        self.slot_of: dict[int, int] = {}            # node i * n_st + j -> layer
        self._free = list(range(self.capacity - 1, -1, -1))
        self.program = mgl.program(vertex_shader=RECON_VS, fragment_shader=RECON_FS)
        self.vbo = mgl.buffer(reserve=max(32, 32 * 3 * 2 * slab.n_st ** 2 * 3))
        self.vao = mgl.vertex_array(self.program, [(self.vbo, "3f 1f 1f 3f", "in_pos",
                                                    "in_alpha", "in_layer", "in_node")])
        self.vertex_count = 0
        self.draws: Draws | None = None
        self.proxy_depth = mgl.depth_texture(self.size)
        self.proxy_depth.compare_func = ""
        self.proxy_fbo = mgl.framebuffer(depth_attachment=self.proxy_depth)
        self.query = mgl.query(samples=True)
        self.samples = 0                             # textured samples of the last render

    @property
    def free_layers(self) -> int:
        """Layers of texture memory not holding a node."""
        return len(self._free)

    @property
    def node_bytes(self) -> int:
        """Texture memory of one resident node."""
        return self.n * self.n * self.BYTES_PER_TEXEL

    @property
    def images(self) -> int:
        """Node images drawn per frame."""
        return 0 if self.draws is None else len(self.draws.nodes)

    def upload(self, node: int, image: np.ndarray) -> int:
        """Make node ``i * n_st + j`` resident (``image (m, m, 3) uint8``, row 0 at the top,
        ``m = n_uv >> level``); returns its layer.  Raises when texture memory is full."""
        if node in self.slot_of:
            return self.slot_of[node]
        if not self._free:
            raise RuntimeError("lumigraph texture memory is full: evict a node first")
        img = np.ascontiguousarray(image[::-1], dtype=np.uint8)  # GL rows
        if img.shape != (self.n, self.n, 3):
            raise ValueError(f"node image {img.shape}, expected {(self.n, self.n, 3)}")
        slot = self._free.pop()
        self.nodes.write(img, viewport=(0, 0, slot, self.n, self.n, 1))
        self.slot_of[node] = slot
        return slot

    def evict(self, node: int) -> None:
        """Free node ``node``'s layer (it must not be in the draws of the next render)."""
        slot = self.slot_of.pop(node, None)
        if slot is not None:
            self._free.append(slot)

    def set_draws(self, draws: Draws) -> None:
        """What the next renders draw; every node of ``draws`` must be resident."""
        slots = np.full(self.slab.n_st ** 2, -1, dtype=np.int64)
        for node, slot in self.slot_of.items():
            slots[node] = slot
        if len(draws) and (slots[draws.node] < 0).any():
            raise RuntimeError("a drawn lumigraph node is not resident")
        verts = draw_vertices(self.slab, draws, slots)
        if verts.nbytes > self.vbo.size:
            self.vbo.orphan(verts.nbytes)
        if len(verts):
            self.vbo.write(verts.tobytes())
        self.vertex_count, self.draws = len(verts), draws

    def render(self, view: np.ndarray, projection: np.ndarray,
               proxy: ColorMeshDrawer | None = None, white: bool = False,
               count_samples: bool = False) -> None:
        """Reconstruct the view ``projection @ view`` (world to clip); with ``proxy``, the
        approximate geometry's z-buffer corrects the uv coordinates for depth.  With
        ``count_samples``, :attr:`samples` becomes the number of textured samples drawn."""
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
            if count_samples:
                with self.query:
                    self.vao.render(moderngl.TRIANGLES, vertices=self.vertex_count)
                self.samples = int(self.query.samples)
            else:
                self.vao.render(moderngl.TRIANGLES, vertices=self.vertex_count)
        mgl.disable(moderngl.BLEND)

    def release(self) -> None:
        if self.ctx.mgl.fbo is self.proxy_fbo:
            self.ctx.default_fbo.use()
        for obj in (self.vao, self.vbo, self.program, self.nodes, self.proxy_fbo,
                    self.proxy_depth):
            obj.release()
        super().release()
