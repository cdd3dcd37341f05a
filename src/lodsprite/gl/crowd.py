"""GL side of the LODManager crowd (Gumbau et al.): one vertex buffer per object type,
index buffers for its LODs, and instanced drawing.

Every object type's vertices (position, normal, colour) are one vertex buffer; each LOD
is an index buffer over it, numbered by the manager (:mod:`lodsprite.manager.core`), with
a vertex array of its own.  Objects are drawn by index buffer: all objects drawing one
buffer are one instanced draw, their transforms ``(x, y, z, yaw)`` read by
``gl_InstanceID`` from a float texture uploaded once a frame (``u_base`` is the group's
first row), so a shared LOD costs one draw call however many objects share it.  The ground
is one quad.
"""

from __future__ import annotations

import moderngl
import numpy as np

from lodsprite.gl.context import GLContext
from lodsprite.gl.terrain import mat_bytes

CROWD_VS = """#version 330
uniform mat4 u_view_proj;
uniform sampler2D u_instances;  // RGBA32F: x, y, z, yaw per instance, 1024 a row
uniform int u_base;
in vec3 in_pos;
in vec3 in_normal;
in vec3 in_color;
out vec3 v_color;
out vec3 v_normal;
void main() {
    int k = u_base + gl_InstanceID;
    vec4 t = texelFetch(u_instances, ivec2(k % 1024, k / 1024), 0);
    float c = cos(t.w), s = sin(t.w);
    mat2 r = mat2(c, s, -s, c);
    vec3 p = vec3(r * in_pos.xy, in_pos.z) + t.xyz;
    v_normal = vec3(r * in_normal.xy, in_normal.z);
    v_color = in_color;
    gl_Position = u_view_proj * vec4(p, 1.0);
}
"""
CROWD_FS = """#version 330
uniform vec3 u_light;
in vec3 v_color;
in vec3 v_normal;
out vec4 f_color;
void main() {
    float lit = 0.35 + 0.65 * max(dot(normalize(v_normal), u_light), 0.0);
    f_color = vec4(v_color * lit, 1.0);
}
"""
GROUND_VS = """#version 330
uniform mat4 u_view_proj;
in vec2 in_xy;
out vec2 v_xy;
void main() { v_xy = in_xy; gl_Position = u_view_proj * vec4(in_xy, 0.0, 1.0); }
"""
GROUND_FS = """#version 330
in vec2 v_xy;
out vec4 f_color;
void main() {
    vec2 g = abs(fract(v_xy / 8.0) - 0.5);
    float line = step(0.47, max(g.x, g.y));
    f_color = vec4(mix(vec3(0.36, 0.42, 0.3), vec3(0.3, 0.35, 0.25), line), 1.0);
}
"""
LIGHT = np.array([0.3, -0.4, 0.87]) / np.linalg.norm([0.3, -0.4, 0.87])
SKY = (0.62, 0.74, 0.88)
ROW = 1024


class CrowdDrawer:
    """The crowd's GPU state: ``models`` (per type ``vertices``, ``normals``, ``colors``)
    and a ground square of half width ``extent`` metres."""

    def __init__(self, ctx: GLContext, models, extent: float) -> None:
        mgl = ctx.mgl
        self.ctx = ctx
        self.program = mgl.program(vertex_shader=CROWD_VS, fragment_shader=CROWD_FS)
        self.program["u_light"].value = tuple(LIGHT)
        self.vbos = []
        for m in models:
            data = np.concatenate([m.vertices, m.normals, m.colors], axis=1)
            self.vbos.append(mgl.buffer(np.ascontiguousarray(data, np.float32).tobytes()))
        self.buffers: dict[int, tuple] = {}   # id -> (ibo, vao, index count, type)
        self.instances = mgl.texture((ROW, 1), 4, dtype="f4")
        self.instances.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.ground_prog = mgl.program(vertex_shader=GROUND_VS, fragment_shader=GROUND_FS)
        e = float(extent) * 1.5
        quad = np.array([[-e, -e], [e, -e], [e, e], [-e, -e], [e, e], [-e, e]], np.float32)
        self.ground_vbo = mgl.buffer(quad.tobytes())
        self.ground = mgl.vertex_array(self.ground_prog, [(self.ground_vbo, "2f", "in_xy")])
        self.draw_calls = 0
        self.triangles = 0

    def set_indices(self, buffer: int, type_index: int, indices: np.ndarray) -> None:
        """Index buffer ``buffer`` of type ``type_index`` now holds ``indices (K,) uint32``
        (its vertex array is made once; a larger LOD grows the buffer in place)."""
        data = np.ascontiguousarray(indices, dtype=np.uint32)
        entry = self.buffers.get(buffer)
        if entry is None or entry[3] != type_index:
            if entry is not None:
                self._drop(buffer)
            ibo = self.ctx.mgl.buffer(data.tobytes() if data.nbytes else b"\0" * 4)
            vao = self.ctx.mgl.vertex_array(
                self.program, [(self.vbos[type_index], "3f 3f 3f", "in_pos", "in_normal",
                                "in_color")], index_buffer=ibo, index_element_size=4)
            self.buffers[buffer] = (ibo, vao, len(data), type_index)
            return
        ibo, vao = entry[0], entry[1]
        if data.nbytes > ibo.size:
            ibo.orphan(data.nbytes)
        if data.nbytes:
            ibo.write(data.tobytes())
        self.buffers[buffer] = (ibo, vao, len(data), type_index)

    def index_count(self, buffer: int) -> int:
        return self.buffers[buffer][2]

    def upload_instances(self, transforms: np.ndarray) -> None:
        """Per-instance ``(x, y, z, yaw)``, ``(K, 4) float32``, in drawing order."""
        k = len(transforms)
        rows = max(1, -(-k // ROW))
        if self.instances.height < rows:
            self.instances.release()
            self.instances = self.ctx.mgl.texture((ROW, rows), 4, dtype="f4")
            self.instances.filter = (moderngl.NEAREST, moderngl.NEAREST)
        if k:
            padded = np.zeros((rows * ROW, 4), np.float32)
            padded[:k] = transforms
            self.instances.write(padded.tobytes(), viewport=(0, 0, ROW, rows))

    def draw(self, view_proj: np.ndarray, fbo: moderngl.Framebuffer,
             groups: list[tuple[int, int, int]], ground: bool = True) -> None:
        """Clear ``fbo`` and draw the ground (``ground=False``: neither, drawing over what
        ``fbo`` holds, depth tested against its depth buffer: a scene's terrain), then each
        ``(buffer, first instance, instances)`` group as one instanced draw; counts
        :attr:`draw_calls` and :attr:`triangles`."""
        mgl = self.ctx.mgl
        fbo.use()
        mgl.enable(moderngl.DEPTH_TEST)
        mgl.disable(moderngl.CULL_FACE | moderngl.BLEND)
        vp = mat_bytes(view_proj)
        if ground:
            fbo.clear(*SKY, 1.0, depth=1.0)
            self.ground_prog["u_view_proj"].write(vp)
            self.ground.render(moderngl.TRIANGLES)
        p = self.program
        p["u_view_proj"].write(vp)
        p["u_instances"].value = 0
        self.instances.use(0)
        base = p["u_base"]
        calls = tris = 0
        for buffer, first, count in groups:
            _, vao, n, _ = self.buffers[buffer]
            if not n or not count:
                continue
            base.value = int(first)
            vao.render(moderngl.TRIANGLES, vertices=n, instances=int(count))
            calls += 1
            tris += n // 3 * int(count)
        self.draw_calls, self.triangles = calls + int(ground), tris
        mgl.disable(moderngl.DEPTH_TEST)

    def _drop(self, buffer: int) -> None:
        ibo, vao, _, _ = self.buffers.pop(buffer)
        vao.release()
        ibo.release()

    def release(self) -> None:
        for b in list(self.buffers):
            self._drop(b)
        for obj in (*self.vbos, self.instances, self.program, self.ground, self.ground_vbo,
                    self.ground_prog):
            obj.release()
