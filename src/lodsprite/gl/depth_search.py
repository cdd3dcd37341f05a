"""The keyframe's own depth as the sprite proxy, searched per fragment: each pixel of the
spriteframe marches its own view ray through the keyframe's z-buffer and takes the
keyframe's colour where the ray first passes behind the surface the keyframe saw
(relief mapping on the keyframe's depth; screen-space ray marching, as post-rendering
3D warping's inverse: McMillan 1997's image warping by epipolar search, Policarpo et al.
2005 for the linear-then-binary search).  The alternative to
:class:`~lodsprite.gl.depth_mesh.DepthMesh`: no cells, so no parallax error inside them,
at the cost of a search per pixel.

Per fragment (everything relative to the keyframe's eye, so float32 stays precise far
away): the ray ``P(t) = e + t r`` (``e`` the frame's eye, ``r`` its direction at unit
depth ``t``) is cut to the depths both frusta hold, projected into the keyframe's image,
where a point's inverse keyframe depth ``1/w`` and its image position are both affine in
one parameter ``u``; the segment is clipped to the keyframe's image and marched in
``steps`` equal steps of ``u``, comparing the ray's keyframe depth ``w(u)`` with the
z-buffer's ``d(u) = 2nf / (f + n - (2z - 1)(f - n))`` (linear filtering: window depth is
affine across a triangle).  The first step past the surface is refined by ``REFINE``
bisections; the hit is kept only where the ray meets the surface there (``|w - d| <=
THICKNESS w``): a ray that passed behind an occluder, into what the keyframe never saw,
is a miss.  A miss (and sky, and a ray leaving the keyframe) is discarded, and the proxy
geometry's spriteframe drawn under it shows, as under the mesh.  The fragment's depth is
the hit's own, in the frame's window depth (the older keyframe of a pair in ``[0.5,
1]`` so that it shows only where the newer one drew nothing).
"""

from __future__ import annotations

import math

import moderngl
import numpy as np

from lodsprite.camera import Projection, Viewpoint
from lodsprite.errors import InputError
from lodsprite.gl.context import GLContext
from lodsprite.gl.shaders import SRGB_ENCODE

DEFAULT_STEPS = 64       # linear steps along the ray's image in the keyframe
REFINE = 6               # bisections of the step that crossed the surface
THICKNESS = 0.01         # a hit within 1 % of its depth from the surface

SEARCH_VS = """#version 330
void main() {  // one triangle over the whole frame
    vec2 p = vec2((gl_VertexID << 1) & 2, gl_VertexID & 2);
    gl_Position = vec4(p * 2.0 - 1.0, 0.0, 1.0);
}
"""

SEARCH_FS = """#version 330
#define REFINE """ + str(REFINE) + """
#define THICKNESS """ + f"{THICKNESS:.6f}" + """
""" + SRGB_ENCODE + """
uniform sampler2D u_key_depth;   // the keyframe's z-buffer (window depth)
uniform sampler2D u_sprite;      // its colour
uniform vec2 u_key_near_far;
uniform vec2 u_key_tan;          // tan of the keyframe's half-angles, x and y
uniform mat3 u_key_to_eye;       // world -> keyframe eye rotation
uniform vec3 u_eye;              // the frame's eye, relative to the keyframe's (metres)
uniform mat3 u_axes;             // the frame's eye -> world rotation
uniform vec2 u_tan;              // tan of the frame's half-angles
uniform vec2 u_near_far;         // the frame's near and far planes
uniform vec2 u_frame_px;
uniform int u_steps;
uniform vec2 u_valid;            // window depth range of this keyframe's hits
uniform int u_true;              // 1: true depth (what later layers test)
out vec4 f_color;

float key_dist(vec2 s) {  // the keyframe's eye distance at image point s in [-1, 1]^2
    float z = texture(u_key_depth, s * 0.5 + 0.5).r;
    if (z >= 1.0) return 1e30;
    float n = u_key_near_far.x, f = u_key_near_far.y;
    return 2.0 * n * f / (f + n - (2.0 * z - 1.0) * (f - n));
}

void main() {
    vec2 ndc = gl_FragCoord.xy / u_frame_px * 2.0 - 1.0;
    vec3 r = u_axes * vec3(ndc * u_tan, -1.0);          // world, per unit frame depth
    vec3 e0 = u_key_to_eye * u_eye, e1 = u_key_to_eye * r;  // keyframe eye space
    // t where both frusta hold the ray: the frame's near..far, keyframe depth in n..f
    float t0 = u_near_far.x, t1 = u_near_far.y;
    float kn = u_key_near_far.x, kf = u_key_near_far.y;
    float w0 = -e0.z, dw = -e1.z;                        // keyframe depth w(t) = w0 + t dw
    if (abs(dw) < 1e-12) {
        if (w0 < kn || w0 > kf) discard;
    } else {
        float ta = (kn - w0) / dw, tb = (kf - w0) / dw;
        t0 = max(t0, min(ta, tb));
        t1 = min(t1, max(ta, tb));
    }
    if (!(t1 > t0)) discard;
    vec3 a = e0 + t0 * e1, b = e0 + t1 * e1;
    float qa = 1.0 / -a.z, qb = 1.0 / -b.z;              // inverse keyframe depths
    vec2 sa = a.xy * qa / u_key_tan, sb = b.xy * qb / u_key_tan;  // image points
    // the part of the segment inside the keyframe's image: u in [ua, ub]
    float ua = 0.0, ub = 1.0;
    vec2 ds = sb - sa;
    for (int k = 0; k < 2; ++k) {
        if (abs(ds[k]) < 1e-12) {
            if (abs(sa[k]) > 1.0) discard;
        } else {
            float u1 = (-1.0 - sa[k]) / ds[k], u2 = (1.0 - sa[k]) / ds[k];
            ua = max(ua, min(u1, u2));
            ub = min(ub, max(u1, u2));
        }
    }
    if (!(ub > ua)) discard;
    float prev = ua;
    float hit = -1.0;
    for (int i = 1; i <= u_steps; ++i) {
        float u = mix(ua, ub, float(i) / float(u_steps));
        float w = 1.0 / mix(qa, qb, u);
        if (w >= key_dist(mix(sa, sb, u))) { hit = u; break; }
        prev = u;
    }
    if (hit < 0.0) discard;                               // sky, or no surface on the ray
    float lo = prev, hi = hit;
    for (int i = 0; i < REFINE; ++i) {
        float m = 0.5 * (lo + hi);
        if (1.0 / mix(qa, qb, m) >= key_dist(mix(sa, sb, m))) hi = m; else lo = m;
    }
    float w = 1.0 / mix(qa, qb, hi);
    vec2 s = mix(sa, sb, hi);
    if (abs(w - key_dist(s)) > THICKNESS * w) discard;  // behind an occluder: unseen
    // the frame depth t of the hit: the keyframe point back on the ray
    vec3 p = mix(a * qa, b * qb, hi) / mix(qa, qb, hi);
    float t = dot(p - e0, e1) / dot(e1, e1);
    float n = u_near_far.x, f = u_near_far.y;
    float z = 0.5 * ((f + n) / (f - n) - 2.0 * f * n / ((f - n) * t)) + 0.5;
    gl_FragDepth = u_true == 1 ? z : u_valid.x + u_valid.y * z;
    f_color = vec4(srgb_encode(texture(u_sprite, s * 0.5 + 0.5).rgb), 1.0);
}
"""


class DepthSearch:
    """Draws keyframes by a search per fragment along each pixel's ray through their own
    depth (module doc) into the bound framebuffer: ``steps`` linear steps; ``stride`` is
    only the keyframe texels between the depth estimate's samples
    (:mod:`lodsprite.sprite.depth_metric`), as a mesh's would be.  Draws what
    :class:`~lodsprite.gl.depth_mesh.DepthMesh` draws, with the same arguments."""

    kind = "search"  # the --proxy choice it draws

    def __init__(self, ctx: GLContext, stride: int, steps: int = DEFAULT_STEPS) -> None:
        if not (isinstance(steps, int | np.integer) and 8 <= int(steps) <= 1024):
            raise InputError(f"the depth search takes 8 to 1024 steps, not {steps!r}")
        self.ctx, self.stride, self.steps = ctx, int(stride), int(steps)
        self.program = ctx.mgl.program(vertex_shader=SEARCH_VS, fragment_shader=SEARCH_FS)
        self.program["u_key_depth"].value = 3
        self.program["u_sprite"].value = 2
        self.vao = ctx.mgl.vertex_array(self.program, [])

    def draw(self, key, viewpoint: Viewpoint, projection: Projection,
             tint: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0),
             older: bool = False, true_depth: bool = False,
             frame_px: tuple[int, int] = (1, 1), key_scale: float = 1.0) -> int:
        """Draw keyframe ``key`` (a :class:`~lodsprite.gl.sprite.GLKeyframe`) as seen from
        ``viewpoint`` through ``projection``; ``older``: the older keyframe of a pair,
        behind the newer one's hits; ``true_depth``: the hits' own window depth.  ``tint``
        and ``key_scale`` are the mesh's (no rubber sheets here).  Returns 1 (the
        frame's one triangle)."""
        prog = self.program
        kp, kv = key.projection, key.viewpoint
        ky = math.tan(math.radians(kp.fov_y_deg) / 2.0)
        fy = math.tan(math.radians(projection.fov_y_deg) / 2.0)
        prog["u_key_near_far"].value = (kp.near, kp.far)
        prog["u_key_tan"].value = (kp.aspect * ky, ky)
        # column-major mat3 uploads: world -> key eye has the key axes as rows
        prog["u_key_to_eye"].write(np.stack([kv.x, kv.y, kv.z], 1).astype("f4").tobytes())
        prog["u_eye"].value = tuple(float(c) for c in np.asarray(viewpoint.o) - kv.o)
        prog["u_axes"].write(np.stack([viewpoint.x, viewpoint.y, viewpoint.z])
                             .astype("f4").tobytes())
        prog["u_tan"].value = (projection.aspect * fy, fy)
        prog["u_near_far"].value = (projection.near, projection.far)
        prog["u_frame_px"].value = tuple(float(n) for n in frame_px)
        prog["u_steps"].value = self.steps
        prog["u_valid"].value = (0.5, 0.5) if older else (0.0, 0.5)
        prog["u_true"].value = int(true_depth)
        key.color.use(2)
        key.target.depth.use(3)
        self.ctx.mgl.enable(moderngl.DEPTH_TEST)
        self.ctx.mgl.disable(moderngl.CULL_FACE)
        self.vao.render(moderngl.TRIANGLES, vertices=3)
        return 1

    def release(self) -> None:
        self.vao.release()
        self.program.release()
