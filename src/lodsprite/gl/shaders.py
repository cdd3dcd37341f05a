"""GLSL sources of lodsprite's programs (OpenGL 3.3 core).

The terrain is one shared grid mesh of ``C x C`` quads drawn once per visible
chunk (instanced); each vertex reads its height from an ``R32F`` height texture
with ``texelFetch``, so no level of detail needs its own vertex buffer.  A
level with step ``s`` (in full-resolution samples) reads every ``s``-th sample:
coarse vertices are exact full-resolution samples.
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
