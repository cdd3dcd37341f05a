"""GLSL sources of lodsprite's programs (OpenGL 3.3 core).

The terrain is one shared grid mesh of ``C x C`` quads drawn once per visible
chunk (instanced); each vertex reads its height from an ``R32F`` height texture
with ``texelFetch``, so no level of detail needs its own vertex buffer.  A
level with step ``s`` (in full-resolution samples) reads every ``s``-th sample:
coarse vertices are exact full-resolution samples.  LOD-sprite draws a coarse level
as a *proxy mesh* instead (the level plus border ribbons, :mod:`lodsprite.terrain.proxy`)
whose vertices carry world positions: its programs read ``PROXY_VERTEX_COMMON``.
"""

# terrain_color(whole, uv): the terrain's texture and, finer, the imagery's clip levels
# (:mod:`lodsprite.gl.clipmap`: units, uniforms and the level-of-detail choice).
CLIPMAP_FS = """
uniform sampler2DArray u_clip;         // clip levels' windows, RGBA8, toroidal
uniform isampler2DArray u_clip_table;  // per slot: the chunk held, cr * 65536 + cc + 1
uniform int u_clip_levels;             // clip levels (0: none), level li = imagery level li
uniform vec2 u_clip_texels;            // level 0's texels (cols, rows)
uniform int u_clip_chunk;              // texels a chunk side
uniform int u_clip_side;               // texels a window side
bool clip_has(int li, vec2 t) {
    ivec2 c = ivec2(floor(max(t, vec2(0.0)) / float(u_clip_chunk)));
    int n = u_clip_side / u_clip_chunk;
    int held = texelFetch(u_clip_table, ivec3(c.x % n, c.y % n, li), 0).r;
    return held == c.y * 65536 + c.x + 1;
}
vec2 clip_clamp(int li, vec2 t) {  // the footprint inside the level: no wrap at its edges
    vec2 size = ceil(u_clip_texels / float(1 << li));
    return clamp(t, vec2(0.5), size - vec2(0.5));
}
bool clip_covers(int li, vec2 t) {
    return clip_has(li, t + vec2(-0.5, -0.5)) && clip_has(li, t + vec2(0.5, -0.5))
        && clip_has(li, t + vec2(-0.5, 0.5)) && clip_has(li, t + vec2(0.5, 0.5));
}
vec4 clip_sample(int li, vec2 t) {  // premultiplied: colour times alpha
    return textureLod(u_clip, vec3(t / float(u_clip_side), float(li)), 0.0);
}
vec3 over_base(vec3 base, vec4 c) { return c.rgb + base * (1.0 - c.a); }
vec3 terrain_color(sampler2D whole, vec2 uv) {
    vec3 base = texture(whole, uv).rgb;
    if (u_clip_levels == 0) return base;
    vec2 t0 = uv * u_clip_texels;
    vec2 dx = dFdx(t0), dy = dFdy(t0);
    float lod = 0.5 * log2(max(max(dot(dx, dx), dot(dy, dy)), 1e-12));
    int first = max(0, int(floor(lod)));
    for (int li = first; li < u_clip_levels; li++) {
        vec2 t = clip_clamp(li, t0 / float(1 << li));
        if (!clip_covers(li, t)) continue;
        vec3 c = over_base(base, clip_sample(li, t));
        float f = li == first ? clamp(lod - float(li), 0.0, 1.0) : 0.0;
        if (f > 0.0) {
            vec2 t1 = clip_clamp(li + 1, t0 / float(2 << li));
            vec3 coarser = (li + 1 < u_clip_levels && clip_covers(li + 1, t1))
                ? over_base(base, clip_sample(li + 1, t1)) : base;
            return mix(c, coarser, f);
        }
        return c;
    }
    return base;
}
"""


#: The sky every terrain image is cleared to (linear 0..1 RGB, display-encoded as drawn).
SKY_RGB = (0.62, 0.74, 0.86)

# Shared by every terrain program: world position and texture coordinate of a grid vertex.
TERRAIN_VERTEX_COMMON = """
uniform sampler2D u_height;   // R32F, width = columns, height = rows (metres)
uniform int u_step;           // level step in full-resolution samples
uniform vec2 u_corner;        // world (x, y) of sample (row 0, col 0): (-width/2, +depth/2)
uniform vec2 u_spacing;       // (dx, dy) metres between columns / rows
uniform vec2 u_uv_scale;      // (1/(cols-1), 1/(rows-1))
uniform ivec2 u_last;         // (cols-1, rows-1): vertices past the edge collapse onto it
in ivec2 in_local;            // (col, row) of the vertex inside the chunk mesh
in ivec2 in_origin;           // (col, row) of the chunk's first sample (per instance)

vec3 terrain_position(out vec2 uv) {
    ivec2 s = min(in_origin + in_local * u_step, u_last);
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
out vec3 v_world;             // world metres (the heights shading reads the sample there)
void main() {
    vec3 p = terrain_position(v_uv);
    v_world = p;
    gl_Position = u_mvp * vec4(p, 1.0);
}
"""
)

TERRAIN_FS = "#version 330\n" + CLIPMAP_FS + """
uniform sampler2D u_color;
in vec2 v_uv;
out vec4 f_color;
void main() {
    f_color = vec4(terrain_color(u_color, v_uv), 1.0);  // the texture and its clipmap
}
"""

# One shading of the terrain from its heights, shared by full resolution, the adaptive
# renderer, LOD-sprite's fallback and the reference: a height ramp over ``u_range`` (lowest,
# highest height of level 0, metres) lit by one sun (TERRAIN_LIGHT) with 30 % ambient.
TERRAIN_SHADE = """
uniform vec2 u_range;         // lowest, highest height of level 0 (metres)
const vec3 TERRAIN_LIGHT = vec3(-0.450473, 0.450473, 0.770810);  // unit, towards the sun
vec3 terrain_shade(float height, vec3 normal) {
    float t = clamp((height - u_range.x) / max(u_range.y - u_range.x, 1e-3), 0.0, 1.0);
    vec3 low = vec3(0.32, 0.45, 0.25), mid = vec3(0.55, 0.48, 0.34), high = vec3(0.9);
    vec3 c = t < 0.6 ? mix(low, mid, t / 0.6) : mix(mid, high, (t - 0.6) / 0.4);
    float lit = 0.3 + 0.7 * max(dot(normalize(normal), TERRAIN_LIGHT), 0.0);
    return c * lit;
}
"""

# Per-pixel normals from a block of height samples in an R32F texture: texel ``base + (col,
# row)`` for ``(col, row)`` in ``[0, last]``; ``spacing`` = metres a column east, a row
# south.  The gradient at a fractional sample position ``p = (col, row)`` is the bilinear
# blend of the central differences at its four samples (one-sided at the block's edges):
# the central difference of the bilinear surface.
HEIGHT_NORMAL = """
float height_texel(sampler2D t, ivec2 base, ivec2 last, ivec2 s) {
    return texelFetch(t, base + clamp(s, ivec2(0), last), 0).r;
}
vec2 height_slope(sampler2D t, ivec2 base, ivec2 last, ivec2 s) {
    ivec2 e = min(s + ivec2(1, 0), last), w = max(s - ivec2(1, 0), ivec2(0));
    ivec2 n = max(s - ivec2(0, 1), ivec2(0)), so = min(s + ivec2(0, 1), last);
    return vec2((height_texel(t, base, last, e) - height_texel(t, base, last, w))
                / float(max(e.x - w.x, 1)),
                (height_texel(t, base, last, so) - height_texel(t, base, last, n))
                / float(max(so.y - n.y, 1)));
}
vec3 height_normal(sampler2D t, ivec2 base, ivec2 last, vec2 p, vec2 spacing) {
    vec2 q = clamp(p, vec2(0.0), vec2(last));
    ivec2 i = min(ivec2(floor(q)), max(last - ivec2(1), ivec2(0)));
    vec2 f = q - vec2(i);
    vec2 g = mix(mix(height_slope(t, base, last, i), height_slope(t, base, last, i + ivec2(1, 0)),
                     f.x),
                 mix(height_slope(t, base, last, i + ivec2(0, 1)),
                     height_slope(t, base, last, i + ivec2(1, 1)), f.x), f.y);
    // g: metres per column (east) and per row (south)
    return normalize(vec3(-g.x / spacing.x, g.y / spacing.y, 1.0));
}
"""

# Full resolution shaded from its own heights (``shading = heights``): the sample under the
# fragment from its world position (grid and proxy meshes alike).
TERRAIN_HEIGHTS_FS = (
    "#version 330\n"
    + TERRAIN_SHADE
    + HEIGHT_NORMAL
    + """
uniform sampler2D u_height;
uniform vec2 u_corner;
uniform vec2 u_spacing;
in vec3 v_world;
out vec4 f_color;
void main() {
    vec2 p = vec2((v_world.x - u_corner.x) / u_spacing.x, (u_corner.y - v_world.y) / u_spacing.y);
    ivec2 last = textureSize(u_height, 0) - ivec2(1);
    vec3 n = height_normal(u_height, ivec2(0), last, p, u_spacing);
    f_color = vec4(terrain_shade(v_world.z, n), 1.0);
}
"""
)

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
out vec3 vs_world;
void main() {
    vec3 p = terrain_position(vs_uv);
    vs_world = p;
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
out vec3 g_world;
flat out int g_sprite;
void main() {
    vec3 p = terrain_position(g_uv);
    g_world = p;
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
in vec3 vs_world[];
out vec2 g_uv;
out vec4 g_key;
out vec3 g_world;
flat out int g_sprite;
void main() {
    int s = (vs_seen[0] > 0.5 && vs_seen[1] > 0.5 && vs_seen[2] > 0.5) ? 1 : 0;
    for (int i = 0; i < 3; ++i) {
        gl_Position = gl_in[i].gl_Position;
        g_uv = vs_uv[i];
        g_key = vs_key[i];
        g_world = vs_world[i];
        g_sprite = s;
        EmitVertex();
    }
    EndPrimitive();
}
"""

# Shared by the spriteframe fragment shaders (whole keyframes: SPRITE_FS; tiles:
# gl.sprite_tiles); reads u_color, u_shading, u_fallback_tint, g_uv and g_world, declared
# before it, and terrain_shade (TERRAIN_SHADE).
SPRITE_FRAGMENT_COMMON = """
// The terrain texture where the keyframe did not see the surface, sampled nearest-mipmap-
// nearest with one texelFetch at a level chosen before the branch: software rasterisers
// shade both sides of a branch for every fragment, and a trilinear lookup cost 0.3 ms per
// 512x512 frame on llvmpipe for the few hundred fragments that use it.
vec3 terrain_fallback(vec2 uv, int level) {
    ivec2 size = textureSize(u_color, level);
    return texelFetch(u_color, clamp(ivec2(uv * vec2(size)), ivec2(0), size - 1), level).rgb;
}
// A fragment the keyframe did not see: the terrain texture or terrain_shade, tinted.
vec3 fallback_rgb(int level, vec3 n) {
    return mix(u_shading == 1 ? terrain_shade(g_world.z, n) : terrain_fallback(g_uv, level),
               u_fallback_tint.rgb, u_fallback_tint.a);
}
"""

# The first statements of a spriteframe's main(), on keyframe clip coordinates ``k``: every
# derivative is taken here, in uniform control flow (GLSL leaves dFdx/dFdy, and the
# implicit ones of texture(), undefined inside a branch that the neighbouring fragments of
# a 2x2 quad may not take): the sprite's coordinates and their derivatives (sampled with
# textureGrad), the terrain texture's level, and the proxy's own normal (screen
# derivatives of its world position, for heights shading).
SPRITE_DERIVATIVES = """
    vec2 key_uv = k.xy / k.w * 0.5 + 0.5;
    vec2 key_dx = dFdx(key_uv);
    vec2 key_dy = dFdy(key_uv);
    vec2 t = g_uv * vec2(textureSize(u_color, 0));
    vec2 t_dx = dFdx(t);
    vec2 t_dy = dFdy(t);
    float rho2 = max(dot(t_dx, t_dx), dot(t_dy, t_dy));
    int level = clamp(int(floor(0.5 * log2(max(rho2, 1.0)) + 0.5)), 0, u_color_levels - 1);
    vec3 n = cross(dFdx(g_world), dFdy(g_world));
    n = n.z < 0.0 ? -n : n;
"""

# Linear light to display encoding (IEC 61966-2-1), for sRGB textures sampled.
SRGB_ENCODE = """
vec3 srgb_encode(vec3 c) {
    return mix(c * 12.92, 1.055 * pow(c, vec3(1.0 / 2.4)) - 0.055, step(vec3(0.0031308), c));
}
"""

SPRITE_FS = (    "#version 330\n"
    + _LINEAR_DEPTH
    + TERRAIN_SHADE
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
uniform int u_shading;          // fallback colour: 0 the terrain texture, 1 terrain_shade
uniform int u_sprite_linear;    // 1: the sprite is an sRGB texture (sampled in linear light)
in vec2 g_uv;
in vec4 g_key;
in vec3 g_world;
flat in int g_sprite;
out vec4 f_color;
"""
    + SRGB_ENCODE
    + SPRITE_FRAGMENT_COMMON
    + """
void main() {
    vec4 k = g_key;
"""
    + SPRITE_DERIVATIVES
    + """
    bool sprite;
    if (u_visibility == 0) {
        sprite = g_sprite == 1;
    } else if (u_visibility == 1) {
        sprite = seen_by_keyframe(g_key, u_key_depth, u_fragment_tol) > 0.5;
    } else {
        sprite = seen_by_keyframe(g_key, u_key_coarse, u_coarse_tol) > 0.5;
    }
    vec3 key = textureGrad(u_sprite, key_uv, key_dx, key_dy).rgb;
    if (u_sprite_linear == 1) key = srgb_encode(key);
    vec3 rgb = sprite ? key : fallback_rgb(level, n);
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
