"""GL side of the adaptive terrain renderer (CDLOD-style, :mod:`lodsprite.terrain.quadtree`).

Every node is the same ``G x G`` grid mesh (squares split along their main diagonal),
drawn instanced: per instance, the node's world origin and sample spacing, its slot in the
height atlas, its parent's slot and quadrant, its morph range and its valid extent.  Node
heights live in one float atlas texture of ``(G + 1)²`` tiles (the GPU cache); the vertex
shader fetches a vertex's height from its node's tile and, within the morph range, blends
it towards the parent's triangulated surface (the mean of the parent samples at the floor
and ceiling of its position), so a node has become its parent's surface where the parent
takes over.  Colour: the terrain's texture, or ``terrain_shade`` (gl.shaders) with normals
per pixel from the node's tile.
"""

from __future__ import annotations

import math

import moderngl
import numpy as np

from lodsprite.camera import boxes_in_frustum, frustum_planes
from lodsprite.gl.context import GLContext
from lodsprite.gl.shaders import CLIPMAP_FS, HEIGHT_NORMAL, PROXY_VERTEX_COMMON, TERRAIN_SHADE
from lodsprite.gl.terrain import SKY_RGB, mat_bytes
from lodsprite.terrain.lod import grid_mesh

# The adaptive mesh's vertex position, shared by the adaptive renderer's own program and by
# LOD-sprite programs drawing the mesh as a sprite proxy (AdaptiveProxy.twin swaps it in for
# gl.shaders.PROXY_VERTEX_COMMON): per instance the node attributes, per vertex its grid
# position; ``terrain_position`` geomorphs towards the parent by the distance from u_eye.
ADAPTIVE_POSITION_COMMON = """
uniform sampler2D u_atlas;
uniform int u_per_row;
uniform int u_grid;
uniform vec3 u_eye;
uniform vec4 u_extent;  // world x of column 0, y of row 0, width, depth (texture mapping)
uniform float u_stride; // node samples between mesh vertices (1; a coarser proxy mesh: more)
in vec2 in_grid;        // grid vertex: column, row (0..G)
in vec4 in_node;        // world x, y of sample (0, 0); metres a sample east, south
in vec4 in_slots;       // own slot, parent slot (-1: none), quadrant row, column
in vec4 in_extra;       // morph start, end (metres); last valid row, column
in vec4 in_parent;      // the parent's last valid row, column
float fetch(float slot, vec2 rc) {
    int s = int(slot);
    ivec2 base = ivec2(s % u_per_row, s / u_per_row) * (u_grid + 1);
    return texelFetch(u_atlas, base + ivec2(int(rc.y), int(rc.x)), 0).r;
}
vec2 node_rc() {
    return min(vec2(in_grid.y, in_grid.x) * u_stride, in_extra.zw);
}
vec3 terrain_position(out vec2 uv) {
    vec2 rc = node_rc();
    vec2 xy = in_node.xy + vec2(rc.y * in_node.z, -rc.x * in_node.w);
    float h = fetch(in_slots.x, rc);
    if (in_slots.y >= 0.0) {
        // the parent's surface on its own mesh (every u_stride-th parent sample)
        vec2 p = (in_slots.zw * float(u_grid / 2) + rc * 0.5) / u_stride;
        vec2 p1 = min(ceil(p) * u_stride, in_parent.xy);   // never past the parent's samples
        float hc = 0.5 * (fetch(in_slots.y, min(floor(p) * u_stride, in_parent.xy))
                          + fetch(in_slots.y, p1));
        float d = distance(u_eye, vec3(xy, h));
        float m = clamp((d - in_extra.x) / max(in_extra.y - in_extra.x, 1e-6), 0.0, 1.0);
        h = mix(h, hc, m);
    }
    uv = vec2((xy.x - u_extent.x) / u_extent.z, (u_extent.y - xy.y) / u_extent.w);
    return vec3(xy, h);
}
"""
ADAPTIVE_VS = (
    "#version 330\n"
    + ADAPTIVE_POSITION_COMMON
    + """
uniform mat4 u_view_proj;
out vec3 v_normal;
out float v_height;
out vec2 v_uv;
flat out float v_slot;  // the node's atlas slot (heights shading: per-pixel normals)
out vec2 v_rc;          // fractional (row, column) in the node's tile
flat out vec4 v_tile;   // the tile's last valid row, column; metres a sample east, south
void main() {
    vec3 p = terrain_position(v_uv);
    vec2 rc = node_rc();
    vec2 e = vec2(min(rc.x + 1.0, in_extra.z), min(rc.y + 1.0, in_extra.w));
    vec2 w = vec2(max(rc.x - 1.0, 0.0), max(rc.y - 1.0, 0.0));
    float dzdx = (fetch(in_slots.x, vec2(rc.x, e.y)) - fetch(in_slots.x, vec2(rc.x, w.y)))
                 / max((e.y - w.y) * in_node.z, 1e-6);
    float dzdy = (fetch(in_slots.x, vec2(w.x, rc.y)) - fetch(in_slots.x, vec2(e.x, rc.y)))
                 / max((e.x - w.x) * in_node.w, 1e-6);
    v_normal = normalize(vec3(-dzdx, -dzdy, 1.0));
    v_height = p.z;
    v_slot = in_slots.x;
    v_rc = rc;
    v_tile = vec4(in_extra.zw, in_node.zw);
    gl_Position = u_view_proj * vec4(p, 1.0);
}
"""
)
# Coloured by the terrain's texture (as full resolution draws a scene's texture) ...
ADAPTIVE_TEXTURE_FS = "#version 330\n" + CLIPMAP_FS + """
uniform sampler2D u_color;
in vec2 v_uv;
out vec4 f_color;
void main() {
    f_color = vec4(terrain_color(u_color, v_uv), 1.0);
}
"""
# ... or by terrain_shade, normals per pixel from the node's tile (gl.shaders.HEIGHT_NORMAL).
ADAPTIVE_HEIGHTS_FS = (
    "#version 330\n"
    + TERRAIN_SHADE
    + HEIGHT_NORMAL
    + """
uniform sampler2D u_atlas;
uniform int u_per_row;
uniform int u_grid;
in float v_height;
flat in float v_slot;
in vec2 v_rc;
flat in vec4 v_tile;
out vec4 f_color;
void main() {
    int s = int(v_slot + 0.5);
    ivec2 base = ivec2(s % u_per_row, s / u_per_row) * (u_grid + 1);
    vec3 n = height_normal(u_atlas, base, ivec2(v_tile.y, v_tile.x), v_rc.yx, v_tile.zw);
    f_color = vec4(terrain_shade(v_height, n), 1.0);
}
"""
)
# the sun of terrain_shade (gl.shaders TERRAIN_LIGHT, unit, towards it), for numpy mirrors
LIGHT = np.array([-0.45, 0.45, 0.77]) / np.linalg.norm([-0.45, 0.45, 0.77])


class AdaptiveDrawer:
    """The GPU cache (a height atlas of ``capacity`` tiles) and the instanced node draw."""

    def __init__(self, ctx: GLContext, grid: int, capacity: int) -> None:
        mgl = ctx.mgl
        self.ctx, self.g = ctx, int(grid)
        side = self.g + 1
        limit = mgl.info["GL_MAX_TEXTURE_SIZE"] // side
        self.per_row = max(1, min(limit, math.ceil(math.sqrt(capacity))))
        rows = min(limit, max(1, math.ceil(capacity / self.per_row)))
        self.capacity = min(capacity, self.per_row * rows)
        self.atlas = mgl.texture((self.per_row * side, rows * side), 1, dtype="f4")
        self.atlas.filter = (moderngl.NEAREST, moderngl.NEAREST)
        # one program a colouring (a branch would shade both sides on llvmpipe)
        self.programs = {"texture": mgl.program(vertex_shader=ADAPTIVE_VS,
                                                fragment_shader=ADAPTIVE_TEXTURE_FS),
                         "heights": mgl.program(vertex_shader=ADAPTIVE_VS,
                                                fragment_shader=ADAPTIVE_HEIGHTS_FS)}
        uv, tris = grid_mesh(self.g)  # the terrain's own chunk mesh: the same diagonals
        self.vbo = mgl.buffer(uv.astype(np.float32).tobytes())
        self.ibo = mgl.buffer(tris.astype(np.uint32).tobytes())
        self.index_count = tris.size
        self.instances = mgl.buffer(reserve=64 * 256)
        self.vaos = {name: mgl.vertex_array(prog, [
            (self.vbo, "2f", "in_grid"),
            (self.instances, "4f 4f 4f 4f/i", "in_node", "in_slots", "in_extra",
             "in_parent")], index_buffer=self.ibo, index_element_size=4)
            for name, prog in self.programs.items()}
        self.triangles = 0
        self._readback: moderngl.Framebuffer | None = None
        from lodsprite.gl.clipmap import ClipmapGL

        self._no_clip = ClipmapGL(ctx)  # what the texture program binds without a clipmap

    def upload(self, slot: int, heights: np.ndarray) -> None:
        """Node samples ``(rows, cols) float32`` (at most ``(G+1)²``) into ``slot``."""
        side = self.g + 1
        x, y = (slot % self.per_row) * side, (slot // self.per_row) * side
        h = np.ascontiguousarray(heights, dtype=np.float32)
        self.atlas.write(h.tobytes(), viewport=(x, y, h.shape[1], h.shape[0]))

    def draw(self, fbo: moderngl.Framebuffer, view_proj: np.ndarray, eye: np.ndarray,
             instances: np.ndarray, height_range: tuple[float, float],
             extent: tuple[float, float, float, float] = (0.0, 0.0, 1.0, 1.0),
             color: moderngl.Texture | None = None, clip=None) -> None:
        """Clear ``fbo`` and draw ``instances (N, 16) float32`` nodes, coloured by
        ``color`` (a texture over ``extent``: x of the west edge, y of the north edge,
        width, depth) or by ``terrain_shade`` (height ramp over ``height_range``, normals
        per pixel from the node's tile); ``clip``: the imagery's clipmap
        (:class:`~lodsprite.gl.clipmap.ClipmapGL`) with ``color``."""
        mgl = self.ctx.mgl
        fbo.use()
        fbo.clear(*SKY_RGB, 1.0, depth=1.0)  # the sky every renderer clears to
        mgl.enable(moderngl.DEPTH_TEST)
        mgl.disable(moderngl.CULL_FACE | moderngl.BLEND)
        n = len(instances)
        if n:
            data = np.ascontiguousarray(instances, dtype=np.float32)
            if data.nbytes > self.instances.size:
                self.instances.orphan(data.nbytes * 2)
            self.instances.write(data.tobytes())
            shading = "heights" if color is None else "texture"
            p = self.programs[shading]
            p["u_view_proj"].write(mat_bytes(view_proj))
            p["u_eye"].value = tuple(float(v) for v in eye)
            p["u_per_row"].value = self.per_row
            p["u_grid"].value = self.g
            for name, value in (("u_range", tuple(float(v) for v in height_range)),
                                ("u_atlas", 0), ("u_extent", tuple(float(v) for v in extent)),
                                ("u_color", 1), ("u_stride", 1.0)):
                if name in p:
                    p[name].value = value
            self.atlas.use(0)
            if color is not None:
                color.use(1)
                (clip or self._no_clip).bind(p)  # always bound: no sampler on a wrong unit
            self.vaos[shading].render(moderngl.TRIANGLES, vertices=self.index_count, instances=n)
        self.triangles = n * self.index_count // 3
        mgl.disable(moderngl.DEPTH_TEST)

    def read_tile(self, slot: int, rows: int, cols: int) -> np.ndarray:
        """The samples ``(rows, cols) float32`` held in ``slot`` (a GPU read-back: for
        tiles the host cache no longer holds; untimed or once per keyframe)."""
        if self._readback is None:
            self._readback = self.ctx.mgl.framebuffer(color_attachments=[self.atlas])
        side = self.g + 1
        x, y = (slot % self.per_row) * side, (slot // self.per_row) * side
        data = self._readback.read(viewport=(x, y, cols, rows), components=1, dtype="f4")
        return np.frombuffer(data, np.float32).reshape(rows, cols).copy()

    def release(self) -> None:
        if self._readback is not None:
            self._readback.release()
        for obj in (*self.vaos.values(), self.instances, self.ibo, self.vbo,
                    *self.programs.values(), self.atlas, self._no_clip):
            obj.release()


ATLAS_UNIT = 5  # the texture unit a proxy binds the atlas to (sprite programs use 0-4)


class AdaptiveProxy:
    """A frozen selection of the adaptive mesh as LOD-sprite's proxy geometry (the object
    :class:`~lodsprite.gl.sprite.SpriteDrawer` draws spriteframes and the coarse z-buffer
    with): the node instances and the eye their morph factors are evaluated at (the
    keyframe's), drawn from ``drawer``'s atlas and grid mesh with any program whose vertex
    shader reads ``terrain_position`` (:meth:`twin`)."""

    def __init__(self, drawer: AdaptiveDrawer, extent: tuple[float, float, float, float],
                 stride: int = 1) -> None:
        if stride < 1 or drawer.g % (2 * stride):
            raise ValueError(f"a proxy stride must divide half the node grid, got {stride}")
        self.drawer = drawer
        self.extent = tuple(float(v) for v in extent)
        self.stride = int(stride)
        uv, tris = grid_mesh(drawer.g // self.stride)  # every stride-th node sample
        mgl = drawer.ctx.mgl
        self.vbo = mgl.buffer(uv.astype(np.float32).tobytes())
        self.ibo = mgl.buffer(tris.astype(np.uint32).tobytes())
        self.index_count = tris.size
        self.instances = mgl.buffer(reserve=64 * 64)
        self.count = 0
        self.eye = (0.0, 0.0, 0.0)
        self._all = np.zeros((0, 16), np.float32)
        self._boxes: tuple[np.ndarray, np.ndarray] | None = None
        self._written: bytes | None = None
        self._vaos: dict[int, moderngl.VertexArray] = {}

    @staticmethod
    def twin(vertex_shader: str) -> str:
        """``vertex_shader`` (reading ``PROXY_VERTEX_COMMON``) reading the adaptive mesh."""
        if PROXY_VERTEX_COMMON not in vertex_shader:
            raise ValueError("not a proxy vertex shader")
        return vertex_shader.replace(PROXY_VERTEX_COMMON, ADAPTIVE_POSITION_COMMON)

    def set(self, instances: np.ndarray, eye: np.ndarray,
            boxes: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        """Freeze ``instances (N, 16) float32`` (the layout of :meth:`AdaptiveDrawer.draw`)
        morphed by the distance from ``eye (3,)`` metres; ``boxes``: the nodes' bounds
        ``(lo (N, 3), hi (N, 3))`` metres, to draw only those in each view."""
        self._all = np.ascontiguousarray(instances, dtype=np.float32)
        self._boxes = boxes
        self._written: bytes | None = None
        self.count = len(self._all)
        self.eye = tuple(float(v) for v in eye)
        self._write(np.ones(self.count, bool))

    def _write(self, keep: np.ndarray) -> None:
        key = np.packbits(keep).tobytes()
        if key == self._written:
            return
        data = self._all[keep]
        if data.nbytes > self.instances.size:
            self.instances.orphan(data.nbytes * 2)
        if data.nbytes:
            self.instances.write(data.tobytes())
        self.count, self._written = len(data), key

    def draw(self, program: moderngl.Program, view_proj: np.ndarray) -> int:
        """Draw the frozen nodes with ``program`` (other uniforms set) through
        ``view_proj (4, 4)``; returns the triangles drawn."""
        r = self.drawer
        if program.glo not in self._vaos:
            self._vaos[program.glo] = r.ctx.mgl.vertex_array(program, [
                (self.vbo, "2f", "in_grid"),
                (self.instances, "4f 4f 4f 4f/i", "in_node", "in_slots", "in_extra",
                 "in_parent")], index_buffer=self.ibo, index_element_size=4)
        values = {"u_mvp": None, "u_atlas": ATLAS_UNIT, "u_per_row": r.per_row,
                  "u_grid": r.g, "u_eye": self.eye, "u_extent": self.extent,
                  "u_stride": float(self.stride)}
        for name, value in values.items():
            if name in program:
                if value is None:
                    program[name].write(mat_bytes(view_proj))
                else:
                    program[name].value = value
        if self._boxes is not None and len(self._all):
            self._write(boxes_in_frustum(frustum_planes(view_proj), *self._boxes))
        if not self.count:
            return 0
        r.atlas.use(ATLAS_UNIT)
        self._vaos[program.glo].render(moderngl.TRIANGLES, vertices=self.index_count,
                                       instances=self.count)
        return self.count * self.index_count // 3

    def release(self) -> None:
        for vao in self._vaos.values():
            vao.release()
        self._vaos.clear()
        for obj in (self.instances, self.ibo, self.vbo):
            obj.release()
