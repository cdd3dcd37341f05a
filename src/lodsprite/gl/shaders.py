"""GLSL sources of lodsprite's programs (OpenGL 3.3 core).

The terrain is one shared grid mesh of ``C x C`` quads drawn once per visible
chunk (instanced); each vertex reads its height from an ``R32F`` height texture
with ``texelFetch``, so no level of detail needs its own vertex buffer.  A
level with step ``s`` (in full-resolution samples) reads every ``s``-th sample:
coarse vertices are exact full-resolution samples.  LOD-sprite draws a coarse level
as a *proxy mesh* instead (the level plus border ribbons, :mod:`lodsprite.terrain.proxy`)
whose vertices carry world positions: its programs read ``PROXY_VERTEX_COMMON``.
"""

# Shared by every terrain program: world position and texture coordinate of a grid vertex.
TERRAIN_VERTEX_COMMON = """
uniform sampler2D u_height;   // R32F, width = columns, height = rows (metres)
uniform int u_step;           // level step in full-resolution samples
uniform vec2 u_corner;        // world (x, y) of sample (row 0, col 0): (-width/2, +depth/2)
uniform vec2 u_spacing;       // (dx, dy) metres between columns / rows
uniform vec2 u_uv_scale;      // (1/(cols-1), 1/(rows-1))
in ivec2 in_local;            // (col, row) of the vertex inside the chunk mesh
in ivec2 in_origin;           // (col, row) of the chunk's first sample (per instance)

vec3 terrain_position(out vec2 uv) {
    ivec2 s = in_origin + in_local * u_step;
    float h = texelFetch(u_height, s, 0).r;
    uv = vec2(s) * u_uv_scale;
    return vec3(u_corner.x + float(s.x) * u_spacing.x, u_corner.y - float(s.y) * u_spacing.y, h);
}
"""

# Proxy meshes (lodsprite.terrain.proxy: a coarse level plus border ribbons) carry their own
# world positions and texture coordinates; a program's "proxy twin" swaps this in for
# TERRAIN_VERTEX_COMMON.
PROXY_VERTEX_COMMON = """
in vec3 in_pos;               // world metres
in vec2 in_uv;                // terrain texture coordinates

vec3 terrain_position(out vec2 uv) {
    uv = in_uv;
    return in_pos;
}
"""


def proxy_twin(vertex_shader: str) -> str:
    """The same vertex shader reading proxy-mesh vertices instead of grid vertices."""
    if TERRAIN_VERTEX_COMMON not in vertex_shader:
        raise ValueError("not a terrain vertex shader")
    return vertex_shader.replace(TERRAIN_VERTEX_COMMON, PROXY_VERTEX_COMMON)


TERRAIN_VS = (
    "#version 330\n"
    + TERRAIN_VERTEX_COMMON
    + """
uniform mat4 u_mvp;
out vec2 v_uv;
void main() {
    vec3 p = terrain_position(v_uv);
    gl_Position = u_mvp * vec4(p, 1.0);
}
"""
)

TERRAIN_FS = """#version 330
uniform sampler2D u_color;
in vec2 v_uv;
out vec4 f_color;
void main() {
    f_color = vec4(texture(u_color, v_uv).rgb, 1.0);
}
"""

# LOD-sprite spriteframe (Chen et al. 1999 §3.1, §3.3; Swan et al. 2002 Figures 2-3 and 5):
# the coarse level, textured from the keyframe by projective texture mapping
# (texture matrix = bias * P_key * V_key, divide by w), or from the terrain
# texture where the keyframe did not see the surface.
_LINEAR_DEPTH = """
uniform vec2 u_key_near_far;  // keyframe near, far (metres)
float linear_depth(float window_z) {
    float n = u_key_near_far.x, f = u_key_near_far.y;
    return 2.0 * n * f / (f + n - (2.0 * window_z - 1.0) * (f - n));
}
// 1 if world point with keyframe clip coordinates k is inside the keyframe frustum and not
// behind the keyframe z-buffer by more than tol (relative to its depth), else 0.
float seen_by_keyframe(vec4 k, sampler2D key_depth, float tol) {
    if (k.w <= 0.0) return 0.0;
    vec3 ndc = k.xyz / k.w;
    if (any(greaterThan(abs(ndc), vec3(1.0)))) return 0.0;
    float zb = textureLod(key_depth, ndc.xy * 0.5 + 0.5, 0.0).r;
    return linear_depth(ndc.z * 0.5 + 0.5) <= linear_depth(zb) * (1.0 + tol) ? 1.0 : 0.0;
}
"""

SPRITE_VS = (
    "#version 330\n"
    + PROXY_VERTEX_COMMON
    + _LINEAR_DEPTH
    + """
uniform mat4 u_mvp;
uniform mat4 u_key_mvp;
uniform sampler2D u_key_depth;
uniform float u_vertex_tol;
out vec2 vs_uv;
out vec4 vs_key;
out float vs_seen;
void main() {
    vec3 p = terrain_position(vs_uv);
    gl_Position = u_mvp * vec4(p, 1.0);
    vs_key = u_key_mvp * vec4(p, 1.0);
    vs_seen = seen_by_keyframe(vs_key, u_key_depth, u_vertex_tol);
}
"""
)

# Per-fragment rules need no per-vertex visibility and no geometry shader.
SPRITE_VS_FRAGMENT = (
    "#version 330\n"
    + PROXY_VERTEX_COMMON
    + """
uniform mat4 u_mvp;
uniform mat4 u_key_mvp;
out vec2 g_uv;
out vec4 g_key;
flat out int g_sprite;
void main() {
    vec3 p = terrain_position(g_uv);
    gl_Position = u_mvp * vec4(p, 1.0);
    g_key = u_key_mvp * vec4(p, 1.0);
    g_sprite = 0;
}
"""
)

# Per-triangle rule of the paper: a triangle takes the sprite only if all three vertices
# were seen by the keyframe.
SPRITE_GS = """#version 330
layout(triangles) in;
layout(triangle_strip, max_vertices = 3) out;
in vec2 vs_uv[];
in vec4 vs_key[];
in float vs_seen[];
out vec2 g_uv;
out vec4 g_key;
flat out int g_sprite;
void main() {
    int s = (vs_seen[0] > 0.5 && vs_seen[1] > 0.5 && vs_seen[2] > 0.5) ? 1 : 0;
    for (int i = 0; i < 3; ++i) {
        gl_Position = gl_in[i].gl_Position;
        g_uv = vs_uv[i];
        g_key = vs_key[i];
        g_sprite = s;
        EmitVertex();
    }
    EndPrimitive();
}
"""

SPRITE_FS = (
    "#version 330\n"
    + _LINEAR_DEPTH
    + """
uniform sampler2D u_color;      // terrain texture
uniform sampler2D u_sprite;     // keyframe colour
uniform sampler2D u_key_depth;  // keyframe z-buffer (full resolution)
uniform sampler2D u_key_coarse; // keyframe's z-buffer of the coarse level
uniform int u_visibility;       // 0: per triangle (paper), 1: per fragment, 2: coarse occlusion
uniform float u_fragment_tol;
uniform float u_coarse_tol;
uniform int u_color_levels;     // mipmap levels of u_color
uniform vec4 u_fallback_tint;   // mixed into fallback fragments by its alpha (0: none)
in vec2 g_uv;
in vec4 g_key;
flat in int g_sprite;
out vec4 f_color;
// The terrain texture where the keyframe did not see the surface, sampled nearest-mipmap-
// nearest with one texelFetch at a level chosen before the branch: software rasterisers
// shade both sides of a branch for every fragment, and a trilinear lookup cost 0.3 ms per
// 512x512 frame on llvmpipe for the few hundred fragments that use it.
vec3 terrain_fallback(vec2 uv, int level) {
    ivec2 size = textureSize(u_color, level);
    return texelFetch(u_color, clamp(ivec2(uv * vec2(size)), ivec2(0), size - 1), level).rgb;
}
void main() {
    // Every derivative is taken here, in uniform control flow: GLSL leaves dFdx/dFdy (and
    // the implicit ones of texture()) undefined inside a branch that the neighbouring
    // fragments of a 2x2 quad may not take.  The sprite is then sampled with textureGrad.
    vec2 key_uv = g_key.xy / g_key.w * 0.5 + 0.5;
    vec2 key_dx = dFdx(key_uv);
    vec2 key_dy = dFdy(key_uv);
    vec2 t = g_uv * vec2(textureSize(u_color, 0));
    vec2 t_dx = dFdx(t);
    vec2 t_dy = dFdy(t);
    float rho2 = max(dot(t_dx, t_dx), dot(t_dy, t_dy));
    int level = clamp(int(floor(0.5 * log2(max(rho2, 1.0)) + 0.5)), 0, u_color_levels - 1);
    bool sprite;
    if (u_visibility == 0) {
        sprite = g_sprite == 1;
    } else if (u_visibility == 1) {
        sprite = seen_by_keyframe(g_key, u_key_depth, u_fragment_tol) > 0.5;
    } else {
        sprite = seen_by_keyframe(g_key, u_key_coarse, u_coarse_tol) > 0.5;
    }
    vec3 rgb = sprite ? textureGrad(u_sprite, key_uv, key_dx, key_dy).rgb
                      : mix(terrain_fallback(g_uv, level), u_fallback_tint.rgb,
                            u_fallback_tint.a);
    f_color = vec4(rgb, 1.0);
}
"""
)

# Flat-shaded meshes under one directional light (Scoggins et al. 2000 §4.1: "directional
# lighting ... flat shading").  Many objects share one LOD mesh: each draw is instanced with a
# per-object model matrix and albedo.  The face normal comes from screen-space derivatives of
# the world position, so meshes need no per-face vertex copies; it always faces the viewer.
MESH_VS = """#version 330
uniform mat4 u_view_proj;
in vec3 in_pos;
in mat4 in_model;     // per instance: object -> world
in vec3 in_albedo;    // per instance: linear RGB in [0, 1]
out vec3 v_world;
out vec3 v_albedo;
void main() {
    vec4 w = in_model * vec4(in_pos, 1.0);
    v_world = w.xyz;
    v_albedo = in_albedo;
    gl_Position = u_view_proj * w;
}
"""

MESH_FS = """#version 330
uniform vec3 u_light;     // unit vector towards the light, world space
uniform float u_ambient;  // ambient fraction in [0, 1]
in vec3 v_world;
in vec3 v_albedo;
out vec4 f_color;
void main() {
    vec3 n = normalize(cross(dFdx(v_world), dFdy(v_world)));
    float lit = u_ambient + (1.0 - u_ambient) * max(dot(n, u_light), 0.0);
    f_color = vec4(v_albedo * lit, 1.0);
}
"""
