"""The keyframe's own depth as the sprite proxy: a mesh over the keyframe image whose
vertices are unprojected from the keyframe's z-buffer (textured depth meshes, Jeschke &
Wimmer 2002; post-rendering 3D warping, Mark, McMillan & Bishop 1997).

One vertex every ``stride`` keyframe texels (at texel centres, the last row and column
always included), two triangles a cell.  The vertex shader reads the texel's window depth
(``texelFetch``: the nearest sample, never a blend of sky and ground), turns it into the
eye distance ``d = 2nf / (f + n - (2z - 1)(f - n))`` and the eye-space point
``d (x tan(fx/2), y tan(fy/2), -1)`` of the keyframe's symmetric frustum, all relative to
the keyframe's eye (float32 stays precise far away); a texel that saw sky (``z = 1``)
becomes a point at infinity in its direction (``w = 0``), drawn on the far plane.  Each
spriteframe fragment takes the keyframe's colour where its world point projects into
the keyframe (projective texturing, exact at the keyframe's own view for any mesh): so the
keyframe's silhouettes are kept to the texel and parallax errs only inside cells.

A triangle across a depth discontinuity (or between sky and ground) is a *rubber sheet*:
its normal is nearly perpendicular to the keyframe's ray through it (``|cos| < cut``).
Rubber sheets are drawn behind every other triangle of their keyframe, whatever their
depth (the geometry shader remaps clip z to window depth [0, 0.25] for the triangles and
[0.25, 0.5] for the sheets; the older keyframe of a pair [0.5, 0.75] and [0.75, 1], so
that it shows only where the newer one drew nothing), so they fill only what no triangle
covers: at the keyframe's view they are exactly the keyframe's pixels; in motion they fill
small disocclusions with a stretch of their edges' colours. A sheet whose pixel area has
grown more than ``stretch`` times since the keyframe's view is left out: there the proxy
geometry's spriteframe, drawn under the mesh, shows (the terrain's own texture or shading
where the keyframe did not see it).

A sky vertex beside ground (one of its eight neighbours at ``stride`` texels sees ground)
takes its farthest ground neighbour's depth: the cells along a silhouette then move with
the ground they hold, carrying their sky texels with it, instead of becoming sheets from
the ground to infinity (which, dropped once they swept too far, took thin peaks and the
silhouette's last texels with them: a 6-frame-late keyframe over a ridge line measured
RMSE 11.3 against 7.6 with the dilation).  Sky is not drawn: a triangle of sky alone is
the cleared colour, or, where the proxy's spriteframe under the mesh reaches, the
keyframe's colour on it; drawn at infinity it would hide ground the keyframe never saw (a
terrain's outline, seen turning).  A sheet between ground and sky that remains (at the
keyframe's last row or column, where the neighbours are nearer than ``stride``) is drawn
only while its ground end has moved less than ``SKY_SHEET_PX`` pixels: its far end does
not move with the eye, so it sweeps over the terrain as the eye moves.

Refined (:meth:`DepthMesh.refine`): the geometry shader splits a triangle whose texels
leave its plane (inverse depth is affine in the image on a plane) into ``REFINE_SPLIT``
squared triangles, each vertex from its own texel and each a rubber sheet or not on its
own: finer where depth is not planar, the fixed stride elsewhere.
"""

from __future__ import annotations

import math

import moderngl
import numpy as np

from lodsprite.camera import Projection, Viewpoint
from lodsprite.errors import InputError
from lodsprite.gl.context import GLContext
from lodsprite.gl.shaders import SRGB_ENCODE
from lodsprite.gl.terrain import mat_bytes

DEFAULT_STRIDE = 2       # keyframe texels between vertices
DEFAULT_CUT_DEG = 2.0    # a triangle this close to its keyframe ray (degrees) is a sheet
DEFAULT_STRETCH = 4.0    # a rubber sheet grown more than this (pixel area) is left out
SKY_SHEET_PX = 8.0       # a sheet from ground to sky: kept while its ground moved less (px)
REFINE_SPLIT = 4         # a triangle that is not planar is drawn as 4 x 4 triangles
REFINE_PLANAR = 0.01     # :meth:`DepthMesh.refine`'s relative inverse-depth deviation
DEFAULT_PLANAR = 0.0     # no refinement unless asked for

DEPTH_MESH_VS = """#version 330
uniform sampler2D u_key_depth;   // the keyframe's z-buffer (window depth)
uniform vec2 u_key_near_far;     // its near and far planes (metres)
uniform vec2 u_key_tan;          // tan of its half-angles, x and y
uniform mat3 u_key_axes;         // its eye axes x, y, z as columns (eye -> world rotation)
uniform mat4 u_mvp_rel;          // the frame's projection x view x translate(key eye)
uniform mat4 u_key_proj;         // the keyframe's projection
uniform int u_stride;            // texels between vertices
in ivec2 in_px;                  // the vertex's keyframe texel
out vec2 v_px;                   // the texel (for the geometry shader's refinement)
out vec3 v_rel;                  // world offset from the keyframe's eye (w 0: direction)
out vec4 v_key;                  // keyframe clip coordinates
out float v_sky;
void main() {
    ivec2 size = textureSize(u_key_depth, 0);
    ivec2 p = clamp(in_px, ivec2(0), size - 1);
    v_px = vec2(p);
    float z = texelFetch(u_key_depth, p, 0).r;
    if (z >= 1.0) {  // sky beside ground: at the farthest ground neighbour's depth
        float g = 0.0;
        for (int j = -1; j <= 1; ++j)
            for (int i = -1; i <= 1; ++i) {
                float zn = texelFetch(u_key_depth,
                                      clamp(p + ivec2(i, j) * u_stride, ivec2(0), size - 1),
                                      0).r;
                if (zn < 1.0) g = max(g, zn);
            }
        if (g > 0.0) z = g;
    }
    vec2 ndc = (vec2(p) + 0.5) / vec2(size) * 2.0 - 1.0;
    vec3 ray = vec3(ndc * u_key_tan, -1.0);   // eye space, at unit distance
    float n = u_key_near_far.x, f = u_key_near_far.y;
    vec4 eye;
    if (z >= 1.0) {
        eye = vec4(normalize(ray), 0.0);
        v_sky = 1.0;
    } else {
        float d = 2.0 * n * f / (f + n - (2.0 * z - 1.0) * (f - n));
        eye = vec4(ray * d, 1.0);
        v_sky = 0.0;
    }
    v_rel = u_key_axes * eye.xyz;
    v_key = u_key_proj * eye;
    vec4 c = u_mvp_rel * vec4(v_rel, eye.w);
    // beyond the frame's far plane (sky, or ground its fit left out): on it, not clipped
    if (z >= 1.0 || c.z > c.w) c.z = c.w * 0.999999;
    gl_Position = c;
}
"""

DEPTH_MESH_GS = """#version 330
#define SKY_SHEET_PX """ + f"{SKY_SHEET_PX:.1f}" + """
#define SUB """ + str(REFINE_SPLIT) + """
#define REFINE @REFINE@
layout(triangles) in;
layout(triangle_strip, max_vertices = @MAX_VERTICES@) out;
uniform sampler2D u_key_depth;
uniform vec2 u_key_near_far;
uniform vec2 u_key_tan;
uniform mat3 u_key_axes;
uniform mat4 u_mvp_rel;
uniform mat4 u_key_proj;
uniform float u_planar;   // 0: no refinement; else the relative deviation of a texel's
                          // inverse depth from its triangle's plane that splits it
uniform float u_cut;      // |cos(normal, ray)| below which a triangle is a rubber sheet
uniform float u_sheet;    // window depth where this keyframe's rubber sheets start
uniform vec2 u_valid;     // window depth where its other triangles start, and their span
                          // (sheets span 0.25)
uniform int u_true;       // 1: true depth, no rubber sheets (what later layers test)
uniform vec2 u_key_px;    // keyframe size, display pixels (texels / scale)
uniform vec2 u_frame_px;  // frame size, pixels
uniform float u_stretch;  // a rubber sheet grown more than this (area) is left out
uniform float u_moved;    // the eye's move from the keyframe's over the pixel angle (m)
// twice the pixel area of a triangle given in clip coordinates (1e30: a vertex behind
// the eye, the triangle stretched without bound)
float area2(vec4 a, vec4 b, vec4 c, vec2 size) {
    if (a.w <= 0.0 || b.w <= 0.0 || c.w <= 0.0) return 1e30;
    vec2 p = a.xy / a.w * size, q = b.xy / b.w * size, r = c.xy / c.w * size;
    return abs((q.x - p.x) * (r.y - p.y) - (q.y - p.y) * (r.x - p.x));
}
in vec2 v_px[];
in vec3 v_rel[];
in vec4 v_key[];
in float v_sky[];
out vec4 g_key;
flat out int g_rubber;

float inv_depth(vec2 px) {  // 1 / eye depth of the keyframe texel nearest px (0: sky)
    ivec2 size = textureSize(u_key_depth, 0);
    float z = texelFetch(u_key_depth, clamp(ivec2(px + 0.5), ivec2(0), size - 1), 0).r;
    if (z >= 1.0) return 0.0;
    float n = u_key_near_far.x, f = u_key_near_far.y;
    return (f + n - (2.0 * z - 1.0) * (f - n)) / (2.0 * n * f);
}

bool is_rubber(vec3 a, vec3 b, vec3 c) {
    vec3 nrm = cross(b - a, c - a);
    vec3 ray = (a + b + c) / 3.0;
    return abs(dot(nrm, ray)) < u_cut * length(nrm) * length(ray);
}

void emit(vec4 k0, vec4 k1, vec4 k2, vec4 c0, vec4 c1, vec4 c2, bool rubber) {
    if (u_true == 1 && rubber) return;
    if (rubber) {  // a sheet stretched over what the keyframe never saw: the fallback's
        float key = area2(k0, k1, k2, 0.5 * u_key_px);
        float now = area2(c0, c1, c2, 0.5 * u_frame_px);
        if (!(now <= u_stretch * max(key, 0.5))) return;
    }
    vec4 ks[3] = vec4[3](k0, k1, k2);
    vec4 cs[3] = vec4[3](c0, c1, c2);
    for (int i = 0; i < 3; ++i) {
        vec4 p = cs[i];
        if (u_true == 0)  // window depth: triangles in [u_valid.x, u_valid.x +
                          // u_valid.y], rubber sheets in [u_sheet, u_sheet + 0.25]
            p.z = rubber ? 0.25 * p.z + (2.0 * u_sheet - 0.75) * p.w
                         : u_valid.y * p.z + (2.0 * u_valid.x - 1.0 + u_valid.y) * p.w;
        gl_Position = p;
        g_key = ks[i];
        g_rubber = rubber ? 1 : 0;
        EmitVertex();
    }
    EndPrimitive();
}

#if REFINE
// A triangle whose texels leave its plane (its corners' inverse depth, affine in the
// image on a plane) by more than u_planar is drawn as SUB x SUB triangles, each vertex
// from its own texel: finer where depth is not planar.  Not where any of those texels
// saw sky.  Returns whether it was.
bool refined() {
    const int N = (SUB + 1) * (SUB + 1);
    float inv[N];
    float i0 = inv_depth(v_px[0]), i1 = inv_depth(v_px[1]), i2 = inv_depth(v_px[2]);
    if (i0 <= 0.0 || i1 <= 0.0 || i2 <= 0.0) return false;
    bool flat_ = true;
    for (int i = 0; i <= SUB; ++i)
        for (int j = 0; i + j <= SUB; ++j) {
            float a = float(i) / float(SUB), b = float(j) / float(SUB);
            vec2 px = v_px[0] + a * (v_px[1] - v_px[0]) + b * (v_px[2] - v_px[0]);
            float v = inv_depth(px);
            if (v <= 0.0) return false;
            float plane = (1.0 - a - b) * i0 + a * i1 + b * i2;
            if (abs(v - plane) > u_planar * plane) flat_ = false;
            inv[i * (SUB + 1) + j] = v;
        }
    if (flat_) return false;
    vec3 rel[N];
    vec4 key[N];
    vec4 clip[N];
    ivec2 size = textureSize(u_key_depth, 0);
    for (int i = 0; i <= SUB; ++i)
        for (int j = 0; i + j <= SUB; ++j) {
            int k = i * (SUB + 1) + j;
            float a = float(i) / float(SUB), b = float(j) / float(SUB);
            vec2 px = floor(v_px[0] + a * (v_px[1] - v_px[0]) + b * (v_px[2] - v_px[0])
                            + 0.5);
            vec2 ndc = (px + 0.5) / vec2(size) * 2.0 - 1.0;
            vec3 eye = vec3(ndc * u_key_tan, -1.0) / inv[k];
            rel[k] = u_key_axes * eye;
            key[k] = u_key_proj * vec4(eye, 1.0);
            vec4 c = u_mvp_rel * vec4(rel[k], 1.0);
            if (c.z > c.w) c.z = c.w * 0.999999;
            clip[k] = c;
        }
    for (int i = 0; i < SUB; ++i)
        for (int j = 0; i + j < SUB; ++j) {
            int a = i * (SUB + 1) + j, b = (i + 1) * (SUB + 1) + j, c = a + 1;
            emit(key[a], key[b], key[c], clip[a], clip[b], clip[c],
                 is_rubber(rel[a], rel[b], rel[c]));
            if (i + j < SUB - 1) {
                int d = b + 1;
                emit(key[b], key[d], key[c], clip[b], clip[d], clip[c],
                     is_rubber(rel[b], rel[d], rel[c]));
            }
        }
    return true;
}
#endif

void main() {
    float sky = v_sky[0] + v_sky[1] + v_sky[2];
    bool rubber;
    if (sky > 2.5) {
        rubber = false;
    } else if (sky > 0.5) {
        rubber = true;
    } else {
#if REFINE
        if (refined()) return;
#endif
        rubber = is_rubber(v_rel[0], v_rel[1], v_rel[2]);
    }
    if (u_true == 1 && rubber) return;
    if (sky > 0.5 && sky < 2.5) {  // ground to sky: its ground end's parallax, pixels
        float d = 1e30;
        for (int i = 0; i < 3; ++i) if (v_sky[i] < 0.5) d = min(d, length(v_rel[i]));
        if (!(u_moved / d < SKY_SHEET_PX)) return;
    }
    // sky alone: the cleared colour, or where the proxy under the mesh reaches, the
    // keyframe's colour on it; drawn, it would hide ground the keyframe never saw
    if (sky > 2.5) return;
    emit(v_key[0], v_key[1], v_key[2], gl_in[0].gl_Position, gl_in[1].gl_Position,
         gl_in[2].gl_Position, rubber);
}
"""

DEPTH_MESH_FS = """#version 330
""" + SRGB_ENCODE + """
uniform sampler2D u_sprite;      // the keyframe's colour
uniform vec4 u_fallback_tint;    // mixed into rubber sheets by its alpha (0: none)
in vec4 g_key;
flat in int g_rubber;
out vec4 f_color;
void main() {
    // an sRGB texture: filtered in linear light, encoded again
    vec3 rgb = srgb_encode(texture(u_sprite, g_key.xy / g_key.w * 0.5 + 0.5).rgb);
    if (g_rubber == 1) rgb = mix(rgb, u_fallback_tint.rgb, u_fallback_tint.a);
    f_color = vec4(rgb, 1.0);
}
"""


def grid_vertices(width: int, height: int, stride: int) -> tuple[np.ndarray, np.ndarray]:
    """The mesh over a ``width x height`` keyframe: vertices ``(N, 2) int32`` (texel
    column, row; every ``stride``-th, the last always) and triangles ``(M, 3) int32``."""
    xs = np.unique(np.r_[np.arange(0, width, stride), width - 1]).astype(np.int32)
    ys = np.unique(np.r_[np.arange(0, height, stride), height - 1]).astype(np.int32)
    gx, gy = np.meshgrid(xs, ys)
    verts = np.stack([gx.ravel(), gy.ravel()], axis=1).astype(np.int32)
    nx = len(xs)
    i = (np.arange(len(ys) - 1)[:, None] * nx + np.arange(nx - 1)[None, :]).ravel()
    tris = np.concatenate([np.stack([i, i + 1, i + nx + 1], 1),
                           np.stack([i, i + nx + 1, i + nx], 1)]).astype(np.int32)
    return verts, tris


def rel_matrix(view_proj: np.ndarray, eye: np.ndarray) -> np.ndarray:
    """``view_proj @ translate(eye)``: the matrix of points given relative to ``eye``."""
    t = np.eye(4)
    t[:3, 3] = eye
    return view_proj @ t


class DepthMesh:
    """Draws keyframes as meshes from their own depth (module doc) into the bound
    framebuffer: ``stride`` keyframe texels between vertices, ``cut_deg`` the rubber-sheet
    angle.  GPU objects (one mesh a keyframe size) live until :meth:`release`."""


    def __init__(self, ctx: GLContext, stride: int = DEFAULT_STRIDE,
                 cut_deg: float = DEFAULT_CUT_DEG, stretch: float = DEFAULT_STRETCH,
                 planar: float = DEFAULT_PLANAR) -> None:
        if not (isinstance(stride, int | np.integer) and 1 <= int(stride) <= 16):
            raise InputError(f"the depth mesh's stride is 1 to 16 keyframe texels, not "
                             f"{stride!r}")
        if not 0.0 <= float(cut_deg) < 90.0:
            raise InputError(f"the rubber-sheet angle is in [0, 90) degrees, not {cut_deg!r}")
        if not 0.0 <= float(planar) < 1.0:
            raise InputError(f"the planarity tolerance is in [0, 1), not {planar!r}")
        self.ctx, self.stride, self.cut_deg = ctx, int(stride), float(cut_deg)
        self.stretch = float(stretch)
        self.planar = float(planar)  # 0: no refinement
        self.program = self._program()
        self._meshes: dict[tuple[int, int], tuple] = {}  # key size -> (vao, bufs, tris)

    @property
    def kind(self) -> str:
        """The ``--proxy`` choice this mesh draws."""
        return "depth-refined" if self.planar else "depth"

    def _program(self) -> moderngl.Program:
        """The mesh's program; its geometry shader emits 3 vertices a triangle, or (when
        refined) up to ``3 REFINE_SPLIT²``, which costs the plain mesh's draws time on
        llvmpipe even where nothing is split: two programs, not one."""
        refine = self.planar > 0
        gs = (DEPTH_MESH_GS.replace("@REFINE@", str(int(refine)))
              .replace("@MAX_VERTICES@", str(3 * REFINE_SPLIT ** 2 if refine else 3)))
        prog = self.ctx.mgl.program(vertex_shader=DEPTH_MESH_VS, geometry_shader=gs,
                                    fragment_shader=DEPTH_MESH_FS)
        prog["u_key_depth"].value = 3
        prog["u_sprite"].value = 2
        prog["u_cut"].value = math.sin(math.radians(self.cut_deg))
        return prog

    def refine(self, planar: float = REFINE_PLANAR) -> None:
        """Split each triangle whose texels leave its plane by more than ``planar`` (their
        inverse depth, relative) into 4 x 4 triangles, each vertex from its own texel."""
        if not 0.0 < float(planar) < 1.0:
            raise InputError(f"the planarity tolerance is in (0, 1), not {planar!r}")
        self.planar = float(planar)
        self._release_meshes()  # their vertex arrays belong to the program replaced
        self.program.release()
        self.program = self._program()

    def _mesh(self, size: tuple[int, int]) -> tuple:
        if size not in self._meshes:
            verts, tris = grid_vertices(size[0], size[1], self.stride)
            vbo = self.ctx.mgl.buffer(verts.tobytes())
            ibo = self.ctx.mgl.buffer(tris.tobytes())
            vao = self.ctx.mgl.vertex_array(self.program, [(vbo, "2i", "in_px")], ibo)
            self._meshes[size] = (vao, vbo, ibo, len(tris))
        return self._meshes[size]

    def draw(self, key, viewpoint: Viewpoint, projection: Projection,
             tint: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0),
             older: bool = False, true_depth: bool = False,
             frame_px: tuple[int, int] = (1, 1), key_scale: float = 1.0) -> int:
        """Draw keyframe ``key`` (a :class:`~lodsprite.gl.sprite.GLKeyframe`: colour,
        depth, view, projection) as seen from ``viewpoint`` through ``projection`` into
        the bound framebuffer, depth-tested; returns the triangles drawn.  ``older``: the
        older keyframe of a pair, whose rubber sheets go behind the newer one's;
        ``true_depth``: the surfaces' own window depth, rubber sheets left out (the depth
        a scene's later layers are tested against; draw it with colour writes off).
        ``frame_px``: the frame's size (pixels), ``key_scale``: the keyframe's texels a
        display pixel side: a rubber sheet whose pixel area grew more than ``stretch``
        times from the keyframe's view is left out (the fallback under the mesh shows)."""
        prog = self.program
        kp = key.projection
        ty = math.tan(math.radians(kp.fov_y_deg) / 2.0)
        vp = key.viewpoint
        prog["u_key_near_far"].value = (kp.near, kp.far)
        prog["u_key_tan"].value = (kp.aspect * ty, ty)
        prog["u_key_axes"].write(np.stack([vp.x, vp.y, vp.z], axis=1)
                                 .astype("f4").T.tobytes())
        mvp = projection.matrix() @ viewpoint.view_matrix()
        prog["u_mvp_rel"].write(mat_bytes(rel_matrix(mvp, vp.o)))
        prog["u_key_proj"].write(mat_bytes(kp.matrix()))
        prog["u_fallback_tint"].value = tint
        prog["u_sheet"].value = 0.75 if older else 0.25
        prog["u_valid"].value = (0.5, 0.25) if older else (0.0, 0.25)
        prog["u_true"].value = int(true_depth)
        prog["u_stride"].value = self.stride
        prog["u_stretch"].value = self.stretch
        if self.planar:
            prog["u_planar"].value = self.planar
        # a sheet from the ground to a point at infinity sweeps over the terrain as the eye
        # moves (its far end has no parallax): kept while its ground end has moved less
        # than SKY_SHEET_PX pixels
        moved = float(np.linalg.norm(np.asarray(viewpoint.o) - vp.o))
        prog["u_moved"].value = moved / kp.pixel_angle_rad(
            int(round(key.target.size[1] / key_scale)))
        prog["u_key_px"].value = tuple(n / key_scale for n in key.target.size)
        prog["u_frame_px"].value = tuple(float(n) for n in frame_px)
        key.color.use(2)
        key.target.depth.use(3)
        vao, _, _, tris = self._mesh(key.target.size)
        self.ctx.mgl.enable(moderngl.DEPTH_TEST)
        self.ctx.mgl.disable(moderngl.CULL_FACE)
        vao.render(moderngl.TRIANGLES)
        return tris

    def _release_meshes(self) -> None:
        for vao, vbo, ibo, _ in self._meshes.values():
            vao.release()
            vbo.release()
            ibo.release()
        self._meshes.clear()

    def release(self) -> None:
        self._release_meshes()
        self.program.release()
