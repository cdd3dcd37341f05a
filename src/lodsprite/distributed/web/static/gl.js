// WebGL2 spriteframes (Chen, Swan & Kaufman 1999 §3.1, §3.3; Swan et al. 2002 §3.2): the
// coarse level of the terrain, textured from the last keyframe by projective texture
// mapping (bias * P_key * V_key, divide by w) where the keyframe saw the surface, and
// from the terrain texture where it did not.  Visibility as lodsprite.gl.sprite's
// per-fragment rules: a fragment takes the sprite when it lies in the keyframe's frustum
// and not behind the keyframe's z-buffer by more than a tolerance relative to its depth
// (the coarse level's z-buffer for the "coarse" rule, tolerance 0.002; the full z-buffer
// for "full", 0.03: lodsprite.gl.sprite's DEFAULT_COARSE_TOL and DEFAULT_FRAGMENT_TOL).
// The paper's per-triangle rule needs a geometry shader, which WebGL2 lacks: a "full"
// scene is drawn with the per-fragment rule.
//
// As lodsprite's own spriteframes (lodsprite.gl.sprite.SpriteDrawer), the keyframe's
// z-buffer is sampled bilinearly (window depth is affine across a triangle in screen
// space, so a bilinear sample is exact inside one), and the coarse level is drawn with
// its border ribbons (the scene message's `ribbon`: lodsprite.terrain.proxy), which the
// server's coarse z-buffer is drawn with too.  (The page's first version sampled the
// z-buffer nearest: where the keyframe saw a slope at a grazing angle a nearest sample
// is off by up to half a texel's depth slope, far beyond the 0.002 tolerance, so rows of
// fragments the keyframe saw fell back to the terrain texture: the streaks across slopes
// that a frame a few viewpoints from its keyframe showed.  Without the ribbons the
// terrain's far edge showed sky where the keyframe shows terrain.)

import { mul } from './camera.js';

export const SKY_RGB = [0.62, 0.74, 0.86];  // lodsprite.gl.terrain.SKY_RGB
export const KEY_SCALES = [1, 1.5, 2];       // lodsprite.distributed.messages.KEY_SCALES
export const MAX_IMAGE_SIDE = 4096;          // lodsprite.distributed.messages.MAX_IMAGE_SIDE
export const KEYFRAMES_PER_S = 4;            // the keyframe rate a link is budgeted for
const KEY_BYTES_PER_TEXEL = 7;               // RGB colour and float32 depth, raw

// Whether `host` (location.hostname) is loopback or a private network's address (RFC 1918,
// RFC 4193, link-local, localhost): the browser's downlink estimate leaves out such
// connections (Network Information API: "excluding connections made to a private
// address space"), so it says nothing of the link to this server.
export function isPrivateHost(host) {
  const h = String(host).toLowerCase().replace(/^\[|\]$/g, '');
  if (h === 'localhost' || h.endsWith('.localhost') || h === '::1') return true;
  const v4 = h.match(/^(\d+)\.(\d+)\.\d+\.\d+$/);
  if (v4) {
    const [a, b] = [Number(v4[1]), Number(v4[2])];
    return a === 127 || a === 10 || (a === 172 && b >= 16 && b <= 31) || (a === 192 && b === 168)
      || (a === 169 && b === 254);
  }
  return /^f[cd][0-9a-f]{2}:/.test(h) || /^fe[89ab][0-9a-f]:/.test(h);
}

// The keyframe scale a page asks for (keyframe texels a canvas pixel side) and why:
// `asked` ('auto' or one of KEY_SCALES), the canvas (w, h), the browser's largest texture
// side and the link's downlink estimate in Mbit/s (navigator.connection.downlink; null:
// none given); `privateHost`: the page's server is on loopback or a private network
// (isPrivateHost), where that estimate is not this link's and is not used.  Auto: the
// largest scale whose keyframes fit the texture limit and the image cap, and whose raw
// bytes at KEYFRAMES_PER_S fit the downlink when one is given for a public server.
export function chooseKeyScale(asked, w, h, maxTexture, downlinkMbit = null, privateHost = false) {
  if (asked !== 'auto') return { scale: Number(asked), why: 'asked' };
  const side = Math.min(maxTexture, MAX_IMAGE_SIDE);
  let scale = 1, why = 'texture limit';
  for (const k of KEY_SCALES) if (k * Math.max(w, h) <= side) scale = k;
  if (scale === KEY_SCALES[KEY_SCALES.length - 1]) why = 'largest';
  if (downlinkMbit && !privateHost) {
    const budget = downlinkMbit * 125000 / KEYFRAMES_PER_S;  // bytes a keyframe
    while (scale > 1 && scale * scale * w * h * KEY_BYTES_PER_TEXEL > budget) {
      scale = KEY_SCALES[KEY_SCALES.indexOf(scale) - 1];
      why = `downlink ${downlinkMbit} Mbit/s`;
    }
  }
  return { scale, why };
}
export const TOLERANCE = { coarse: 0.002, full: 0.03 };

const VS = `#version 300 es
layout(location = 0) in vec3 a_pos;
layout(location = 1) in vec2 a_uv;
uniform mat4 u_mvp;
uniform mat4 u_key_mvp;
out vec2 v_uv;
out vec4 v_key;
void main() {
  v_uv = a_uv;
  v_key = u_key_mvp * vec4(a_pos, 1.0);
  gl_Position = u_mvp * vec4(a_pos, 1.0);
}`;

const FS = `#version 300 es
precision highp float;
precision highp sampler2D;
uniform sampler2D u_color;      // terrain texture
uniform sampler2D u_sprite;     // keyframe colour
uniform sampler2D u_key_depth;  // keyframe z-buffer (window depth in [0, 1])
uniform int u_has_key;
uniform float u_tol;
uniform vec2 u_key_near_far;
uniform vec4 u_fallback_tint;   // mixed into fallback fragments by its alpha (0: none)
in vec2 v_uv;
in vec4 v_key;
out vec4 f_color;
float linear_depth(float z) {
  float n = u_key_near_far.x, f = u_key_near_far.y;
  return 2.0 * n * f / (f + n - (2.0 * z - 1.0) * (f - n));
}
// The keyframe z-buffer sampled bilinearly (as lodsprite.gl.sprite's LINEAR depth
// filter), from four texels: R32F textures filter only with OES_texture_float_linear.
float bilinear_depth(vec2 uv) {
  ivec2 size = textureSize(u_key_depth, 0), last = size - 1;
  vec2 p = uv * vec2(size) - 0.5;
  ivec2 i = ivec2(floor(p));
  vec2 f = p - floor(p);
  float z00 = texelFetch(u_key_depth, clamp(i, ivec2(0), last), 0).r;
  float z10 = texelFetch(u_key_depth, clamp(i + ivec2(1, 0), ivec2(0), last), 0).r;
  float z01 = texelFetch(u_key_depth, clamp(i + ivec2(0, 1), ivec2(0), last), 0).r;
  float z11 = texelFetch(u_key_depth, clamp(i + ivec2(1, 1), ivec2(0), last), 0).r;
  return mix(mix(z00, z10, f.x), mix(z01, z11, f.x), f.y);
}
void main() {
  vec2 key_uv = v_key.xy / v_key.w * 0.5 + 0.5;  // derivatives in uniform control flow
  vec2 key_dx = dFdx(key_uv), key_dy = dFdy(key_uv);
  vec3 fallback = texture(u_color, v_uv).rgb;
  bool seen = false;
  if (u_has_key == 1 && v_key.w > 0.0) {
    vec3 ndc = v_key.xyz / v_key.w;
    if (all(lessThanEqual(abs(ndc), vec3(1.0)))) {
      float zb = bilinear_depth(ndc.xy * 0.5 + 0.5);
      seen = linear_depth(ndc.z * 0.5 + 0.5) <= linear_depth(zb) * (1.0 + u_tol);
    }
  }
  vec3 rgb = seen ? textureGrad(u_sprite, key_uv, key_dx, key_dy).rgb
                  : mix(fallback, u_fallback_tint.rgb, u_fallback_tint.a);
  f_color = vec4(rgb, 1.0);
}`;

// The keyframe's own depth as the proxy (lodsprite.gl.depth_mesh, Jeschke & Wimmer 2002's
// textured depth meshes): a mesh over the keyframe image, a vertex every `stride` texels
// unprojected from the keyframe's full z-buffer, drawn over the coarse spriteframe.
// WebGL2 has no geometry shader: each triangle's three vertices carry all three of its
// texels, so that each vertex shader run sees the whole triangle and decides what the
// geometry shader decides there: a triangle of sky alone is left out; a rubber sheet (a
// triangle nearly along its keyframe ray: across a depth discontinuity, or from ground
// to sky) goes behind every other triangle (window depth [0.25, 0.5] against [0, 0.25]),
// and is left out once its pixel area grew more than STRETCH times, or, from ground to
// sky, once its ground end moved SKY_SHEET_PX pixels; a sky texel beside ground takes its
// farthest ground neighbour's depth.  A dropped triangle's three vertices meet at one
// point outside the view.  Where nothing of the mesh is drawn the coarse spriteframe
// under it shows.
export const DEPTH_STRIDE = 8;      // lodsprite.techniques.defaults: every 8th texel
export const CUT_DEG = 2.0;         // lodsprite.gl.depth_mesh.DEFAULT_CUT_DEG
export const STRETCH = 4.0;         // DEFAULT_STRETCH
export const SKY_SHEET_PX = 8.0;    // SKY_SHEET_PX

const MESH_VS = `#version 300 es
precision highp float;
precision highp sampler2D;
layout(location = 0) in vec4 a_t01;  // the triangle's texels 0 and 1 (column, row)
layout(location = 1) in vec3 a_t2c;  // its texel 2, and which corner this vertex is
uniform sampler2D u_corners;  // the keyframe's grid vertices (keyCorners), RGBA32F
uniform ivec2 u_key_size;   // the keyframe's size, texels
uniform mat3 u_key_axes;    // its eye axes as columns (eye -> world rotation)
uniform mat4 u_mvp_rel;     // the frame's view-projection x translate(keyframe eye)
uniform mat4 u_key_proj;
uniform int u_stride;
uniform float u_cut;        // sin of the rubber-sheet angle
uniform vec2 u_key_px;      // keyframe size, pixels
uniform vec2 u_frame_px;    // frame size, pixels
uniform float u_stretch;
uniform float u_moved;      // the eye's move from the keyframe's over its pixel angle (m)
uniform vec2 u_valid;       // window depth of its triangles: [x, x + y]
uniform float u_sheet;      // of its rubber sheets: [u_sheet, u_sheet + 0.25]
out vec4 v_key;
flat out int v_rubber;
struct Corner { vec3 rel; vec4 key; vec4 clip; float sky; };
Corner corner(vec2 t) {
  // the keyframe's grid vertex at texel t, unprojected once a keyframe (keyCorners):
  // its eye-space point (w 1) or, for sky, its ray's direction (w 0)
  ivec2 grid = textureSize(u_corners, 0);
  ivec2 p = clamp(ivec2(t), ivec2(0), u_key_size - 1);
  ivec2 g = ivec2(p.x == u_key_size.x - 1 ? grid.x - 1 : p.x / u_stride,
                  p.y == u_key_size.y - 1 ? grid.y - 1 : p.y / u_stride);
  vec4 e = texelFetch(u_corners, g, 0);
  vec4 eye = vec4(e.xyz, 1.0 - e.w);
  Corner c;
  c.sky = e.w;
  c.rel = u_key_axes * eye.xyz;
  c.key = u_key_proj * eye;
  c.clip = u_mvp_rel * vec4(c.rel, eye.w);
  if (c.sky > 0.5 || c.clip.z > c.clip.w) c.clip.z = c.clip.w * 0.999999;  // on the far plane
  return c;
}
float area2(vec4 a, vec4 b, vec4 c, vec2 size) {  // twice the pixel area (1e30: behind)
  if (a.w <= 0.0 || b.w <= 0.0 || c.w <= 0.0) return 1e30;
  vec2 p = a.xy / a.w * size, q = b.xy / b.w * size, r = c.xy / c.w * size;
  return abs((q.x - p.x) * (r.y - p.y) - (q.y - p.y) * (r.x - p.x));
}
void main() {
  Corner c0 = corner(a_t01.xy), c1 = corner(a_t01.zw), c2 = corner(a_t2c.xy);
  float sky = c0.sky + c1.sky + c2.sky;
  bool rubber = false, drop = sky > 2.5;
  if (!drop && sky > 0.5) {
    rubber = true;
    float d = 1e30;
    if (c0.sky < 0.5) d = min(d, length(c0.rel));
    if (c1.sky < 0.5) d = min(d, length(c1.rel));
    if (c2.sky < 0.5) d = min(d, length(c2.rel));
    drop = !(u_moved / d < ${SKY_SHEET_PX.toFixed(1)});
  } else if (!drop) {
    vec3 nrm = cross(c1.rel - c0.rel, c2.rel - c0.rel), ray = (c0.rel + c1.rel + c2.rel) / 3.0;
    rubber = abs(dot(nrm, ray)) < u_cut * length(nrm) * length(ray);
  }
  if (!drop && rubber) {
    float key = area2(c0.key, c1.key, c2.key, 0.5 * u_key_px);
    float now = area2(c0.clip, c1.clip, c2.clip, 0.5 * u_frame_px);
    drop = !(now <= u_stretch * max(key, 0.5));
  }
  int k = int(a_t2c.z + 0.5);
  v_key = k == 0 ? c0.key : (k == 1 ? c1.key : c2.key);
  v_rubber = rubber ? 1 : 0;
  if (drop) { gl_Position = vec4(2.0, 2.0, 0.0, 1.0); return; }  // one point: nothing drawn
  vec4 q = k == 0 ? c0.clip : (k == 1 ? c1.clip : c2.clip);
  // window depth (lodsprite.gl.depth_mesh): triangles in [u_valid.x, u_valid.x +
  // u_valid.y], sheets in [u_sheet, u_sheet + 0.25]; the newer keyframe of a pair takes
  // [0, 0.25] and [0.25, 0.5], the older [0.5, 0.75] and [0.75, 1]
  q.z = rubber ? 0.25 * q.z + (2.0 * u_sheet - 0.75) * q.w
               : u_valid.y * q.z + (2.0 * u_valid.x - 1.0 + u_valid.y) * q.w;
  gl_Position = q;
}`;

const MESH_FS = `#version 300 es
precision highp float;
uniform sampler2D u_sprite;
uniform vec4 u_fallback_tint;  // mixed into rubber sheets by its alpha (0: none)
in vec4 v_key;
flat in int v_rubber;
out vec4 f_color;
void main() {
  vec3 rgb = texture(u_sprite, v_key.xy / v_key.w * 0.5 + 0.5).rgb;
  if (v_rubber == 1) rgb = mix(rgb, u_fallback_tint.rgb, u_fallback_tint.a);
  f_color = vec4(rgb, 1.0);
}`;

// The keyframe's depth-mesh vertices in its eye space, once a keyframe (what the mesh's
// vertex shader reads, three texels a vertex instead of a depth search each frame): for
// the grid texels (every `stride`-th, the last row and column too) of the (dw, dh) window
// depth `depth` (rows bottom-up), its point (x, y, z, 0) or, for sky, its ray's direction
// (x, y, z, 1).  A sky texel beside ground (one of its 8 neighbours `stride` texels away
// is not sky) takes its farthest ground neighbour's depth; texel centres, the outer ring
// on the image's edges (as lodsprite.gl.depth_mesh).  {data Float32Array, nx, ny}.
export function keyCorners(depth, dw, dh, stride, near, far, tanX, tanY) {
  const axis = (n) => { const v = []; for (let i = 0; i < n; i += stride) v.push(i); if (v[v.length - 1] !== n - 1) v.push(n - 1); return v; };
  const xs = axis(dw), ys = axis(dh), nx = xs.length, ny = ys.length;
  const data = new Float32Array(nx * ny * 4);
  const at = (x, y) => depth[Math.min(Math.max(y, 0), dh - 1) * dw + Math.min(Math.max(x, 0), dw - 1)];
  for (let j = 0; j < ny; j++) for (let i = 0; i < nx; i++) {
    const px = xs[i], py = ys[j];
    let z = at(px, py);
    if (z >= 1) {  // sky beside ground: at the farthest ground neighbour's depth
      let g = 0;
      for (let b = -1; b <= 1; b++) for (let a = -1; a <= 1; a++) {
        const zn = at(px + a * stride, py + b * stride);
        if (zn < 1) g = Math.max(g, zn);
      }
      if (g > 0) z = g;
    }
    let ux = (px + 0.5) / dw, uy = (py + 0.5) / dh;
    if (px === 0) ux = 0; if (py === 0) uy = 0;
    if (px === dw - 1) ux = 1; if (py === dh - 1) uy = 1;
    const ray = [(ux * 2 - 1) * tanX, (uy * 2 - 1) * tanY, -1];
    const o = 4 * (j * nx + i);
    if (z >= 1) {
      const n = Math.hypot(...ray);
      data.set([ray[0] / n, ray[1] / n, ray[2] / n, 1], o);
    } else {
      const d = 2 * near * far / (far + near - (2 * z - 1) * (far - near));
      data.set([ray[0] * d, ray[1] * d, ray[2] * d, 0], o);
    }
  }
  return { data, nx, ny };
}

// The mesh over a (w, h) keyframe, as lodsprite.gl.depth_mesh.grid_vertices: a vertex every
// `stride` texels (the last row and column always), two triangles a cell; each triangle's
// vertices carry its three texels and their corner (7 floats a vertex).
export function depthMeshVertices(w, h, stride) {
  const axis = (n) => { const v = []; for (let i = 0; i < n; i += stride) v.push(i); if (v[v.length - 1] !== n - 1) v.push(n - 1); return v; };
  const xs = axis(w), ys = axis(h), nx = xs.length;
  const at = (k) => [xs[k % nx], ys[Math.floor(k / nx)]];
  const tris = [];
  for (let j = 0; j < ys.length - 1; j++) for (let i = 0; i < nx - 1; i++) {
    const a = j * nx + i;
    tris.push([a, a + 1, a + nx + 1], [a, a + nx + 1, a + nx]);
  }
  const out = new Float32Array(tris.length * 21);
  let o = 0;
  for (const t of tris) {
    const [p0, p1, p2] = t.map(at);
    for (let c = 0; c < 3; c++) { out.set([...p0, ...p1, ...p2, c], o); o += 7; }
  }
  return out;
}

function compile(gl, type, src) {
  const s = gl.createShader(type);
  gl.shaderSource(s, src); gl.compileShader(s);
  if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(s));
  return s;
}

// A linked program of vertex and fragment sources and the locations of its `uniforms`
// (names): {program, u}.  Throws with the compiler's or linker's log.
export function linkProgram(gl, vs, fs, uniforms) {
  const p = gl.createProgram();
  gl.attachShader(p, compile(gl, gl.VERTEX_SHADER, vs));
  gl.attachShader(p, compile(gl, gl.FRAGMENT_SHADER, fs));
  gl.linkProgram(p);
  if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(p));
  const u = {};
  for (const name of uniforms) u[name] = gl.getUniformLocation(p, name);
  return { program: p, u };
}

function texture(gl, unit, internal, format, type, w, h, data, filter, mipmaps = false) {
  const t = gl.createTexture();
  gl.activeTexture(gl.TEXTURE0 + unit);
  gl.bindTexture(gl.TEXTURE_2D, t);
  gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1);
  gl.texImage2D(gl.TEXTURE_2D, 0, internal, w, h, 0, format, type, data);
  if (mipmaps) gl.generateMipmap(gl.TEXTURE_2D);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, mipmaps ? gl.LINEAR_MIPMAP_LINEAR : filter);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, filter);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
  return t;
}

// The scene's border ribbon: {pos (V, 3) Float32Array metres, index (T, 3) Uint32Array},
// from its `ribbon` and `ribbon_tris` bytes (little-endian float32, uint32); empty when it
// has none.  Throws on bytes that are not whole vertices and triangles, a vertex that is
// not finite or a triangle naming a vertex it lacks (as distributed.web.scene.decode_ribbon).
export function ribbonMesh(scene) {
  const bytes = (b) => (b ? new Uint8Array(b) : new Uint8Array(0));  // a copy: aligned
  const v = bytes(scene.ribbon), t = bytes(scene.ribbon_tris);
  if (v.byteLength % 12 || t.byteLength % 12) throw new Error('scene: ribbon of partial vertices or triangles');
  const pos = new Float32Array(v.buffer), index = new Uint32Array(t.buffer);
  const little = new Uint8Array(new Uint16Array([1]).buffer)[0] === 1;
  if (!little) throw new Error('scene: a big-endian browser reads no ribbon');
  if (!pos.every(Number.isFinite)) throw new Error('scene: ribbon vertex not finite');
  const count = pos.length / 3;
  if (index.some((k) => k >= count)) throw new Error('scene: ribbon triangle names a missing vertex');
  return { pos, index };
}

// The coarse mesh ((n+1)^2 vertices: row i at y = origin_y + i * spacing_y, column j at
// x = origin_x + j * spacing, z from `heights`) and its texture coordinates (row 0 south);
// each square split along its north-west to south-east diagonal, as the server's coarse
// level (lodsprite.terrain.proxy.level_mesh), so the coarse z-buffer test agrees with it;
// then the border ribbon's vertices and triangles (ribbonMesh), texture coordinates from
// their x, y.
export function coarseMesh(scene, heights) {
  const n = scene.coarse, m = n + 1;
  const ribbon = ribbonMesh(scene), rv = ribbon.pos.length / 3;
  const pos = new Float32Array(3 * (m * m + rv)), uv = new Float32Array(2 * (m * m + rv));
  for (let i = 0; i < m; i++) for (let j = 0; j < m; j++) {
    const k = i * m + j;
    pos[3 * k] = scene.origin[0] + j * scene.spacing;
    pos[3 * k + 1] = scene.origin[1] + i * scene.spacing_y;
    pos[3 * k + 2] = heights[k];
    uv[2 * k] = j / n; uv[2 * k + 1] = i / n;
  }
  const extent = [n * scene.spacing, n * scene.spacing_y];
  pos.set(ribbon.pos, 3 * m * m);
  for (let k = 0; k < rv; k++) {
    const x = ribbon.pos[3 * k], y = ribbon.pos[3 * k + 1];
    uv[2 * (m * m + k)] = (x - scene.origin[0]) / extent[0];
    uv[2 * (m * m + k) + 1] = (y - scene.origin[1]) / extent[1];
  }
  const index = new Uint32Array(6 * n * n + ribbon.index.length);
  let at = 0;
  for (let i = 0; i < n; i++) for (let j = 0; j < n; j++) {
    const a = i * m + j, b = a + 1, c = a + m, d = c + 1;
    index.set([c, a, b, c, b, d], at); at += 6;  // split nw-se, as lodsprite.terrain.proxy
  }
  for (let k = 0; k < ribbon.index.length; k++) index[at + k] = m * m + ribbon.index[k];
  return { pos, uv, index };
}

export class SpriteDrawer {
  constructor(canvas) {
    const gl = canvas.getContext('webgl2', { antialias: false, preserveDrawingBuffer: true });
    if (!gl) throw new Error('this browser has no WebGL2');
    this.gl = gl;
    const { program, u } = linkProgram(gl, VS, FS, ['u_mvp', 'u_key_mvp', 'u_color', 'u_sprite', 'u_key_depth', 'u_has_key', 'u_tol', 'u_key_near_far', 'u_fallback_tint']);
    this.program = program;
    this.u = u;
    this.key = null;
    // 'coarse': the coarse level textured from the keyframe (the 1999 spriteframe);
    // 'depth': the keyframe's own depth as the proxy over it, for keyframes that carry
    // the full z-buffer (visibility fragment or triangle).
    this.proxy = 'coarse';
    this.stride = DEPTH_STRIDE;
    this.meshes = new Map();  // keyframe size -> {vao, count}
    // With the depth mesh, draw the keyframe shown before the current one too, where the
    // current one drew nothing (lodsprite's `pair`; the store default: off).
    this.pair = false;
    this.previous = null;
    // Mixed by its alpha into fragments that fell back to the terrain texture (as
    // lodsprite.gl.sprite.SpriteDrawer.fallback_tint); alpha 0 draws them as they are.
    this.fallbackTint = [1, 0, 1, 0];
  }

  meshProgram() {
    if (this.mesh) return this.mesh;
    const { program: p, u } = linkProgram(this.gl, MESH_VS, MESH_FS, ['u_corners', 'u_key_size', 'u_key_axes', 'u_mvp_rel', 'u_key_proj', 'u_stride', 'u_cut', 'u_key_px', 'u_frame_px', 'u_stretch', 'u_moved', 'u_sprite', 'u_fallback_tint', 'u_valid', 'u_sheet']);
    this.mesh = { program: p, u };
    return this.mesh;
  }

  meshFor(w, h) {
    const name = `${w}x${h}`;
    if (!this.meshes.has(name)) {
      const gl = this.gl, data = depthMeshVertices(w, h, this.stride);
      const vao = gl.createVertexArray();
      gl.bindVertexArray(vao);
      const b = gl.createBuffer();
      gl.bindBuffer(gl.ARRAY_BUFFER, b);
      gl.bufferData(gl.ARRAY_BUFFER, data, gl.STATIC_DRAW);
      gl.enableVertexAttribArray(0); gl.vertexAttribPointer(0, 4, gl.FLOAT, false, 28, 0);
      gl.enableVertexAttribArray(1); gl.vertexAttribPointer(1, 3, gl.FLOAT, false, 28, 16);
      gl.bindVertexArray(null);
      this.meshes.set(name, { vao, count: data.length / 7 });
    }
    return this.meshes.get(name);
  }

  // The keyframe `key`'s mesh over what is drawn, seen through `viewProj` (row-major);
  // `older`: the older keyframe of a pair (drawn where the newer drew nothing).
  drawMesh(key, viewProj, older = false) {
    const gl = this.gl, { program, u } = this.meshProgram();
    const h = key.header, [kh, kw] = h.depth.shape, corners = this.cornersOf(key);
    const o = h.viewpoint.o;
    const translate = [1, 0, 0, o[0], 0, 1, 0, o[1], 0, 0, 1, o[2], 0, 0, 0, 1];
    const moved = Math.hypot(...this.eye.map((v, i) => v - o[i]));
    gl.useProgram(program);
    gl.uniformMatrix4fv(u.u_mvp_rel, true, mul(viewProj, translate));
    gl.uniformMatrix4fv(u.u_key_proj, true, h.proj);
    gl.uniformMatrix3fv(u.u_key_axes, false, [...h.viewpoint.x, ...h.viewpoint.y, ...h.viewpoint.z]);
    gl.uniform2i(u.u_key_size, kw, kh);
    gl.uniform1i(u.u_stride, key.cornerStride);
    gl.uniform1f(u.u_cut, Math.sin(CUT_DEG * Math.PI / 180));
    gl.uniform2fv(u.u_key_px, [kw, kh]);
    gl.uniform2fv(u.u_frame_px, [gl.drawingBufferWidth, gl.drawingBufferHeight]);
    gl.uniform1f(u.u_stretch, STRETCH);
    gl.uniform1f(u.u_moved, moved / ((h.fov * Math.PI / 180) / kh));
    gl.uniform4fv(u.u_fallback_tint, this.fallbackTint);
    gl.uniform2fv(u.u_valid, older ? [0.5, 0.25] : [0.0, 0.25]);
    gl.uniform1f(u.u_sheet, older ? 0.75 : 0.25);
    gl.activeTexture(gl.TEXTURE1); gl.bindTexture(gl.TEXTURE_2D, key.sprite);
    gl.activeTexture(gl.TEXTURE3); gl.bindTexture(gl.TEXTURE_2D, corners);
    gl.uniform1i(u.u_sprite, 1); gl.uniform1i(u.u_corners, 3);
    const mesh = this.meshFor(kw, kh);
    gl.bindVertexArray(mesh.vao);
    gl.drawArrays(gl.TRIANGLES, 0, mesh.count);
    gl.bindVertexArray(null);
    return mesh.count / 3;
  }

  // The scene message (header, heights Float32Array, texture Uint8Array).
  setScene(scene, heights, tex) {
    const gl = this.gl;
    const mesh = coarseMesh(scene, heights);
    this.vao = gl.createVertexArray();
    gl.bindVertexArray(this.vao);
    const buffer = (target, data) => { const b = gl.createBuffer(); gl.bindBuffer(target, b); gl.bufferData(target, data, gl.STATIC_DRAW); };
    buffer(gl.ARRAY_BUFFER, mesh.pos);
    gl.enableVertexAttribArray(0); gl.vertexAttribPointer(0, 3, gl.FLOAT, false, 0, 0);
    buffer(gl.ARRAY_BUFFER, mesh.uv);
    gl.enableVertexAttribArray(1); gl.vertexAttribPointer(1, 2, gl.FLOAT, false, 0, 0);
    buffer(gl.ELEMENT_ARRAY_BUFFER, mesh.index);
    gl.bindVertexArray(null);
    this.count = mesh.index.length;
    const [th, tw] = scene.texture.shape;
    this.colorTex = texture(gl, 0, gl.RGB8, gl.RGB, gl.UNSIGNED_BYTE, tw, th, tex, gl.LINEAR, true);
    this.tol = TOLERANCE[scene.visibility] ?? TOLERANCE.full;
    this.triangles = this.count / 3;
  }

  // The keyframe's depth-mesh vertices (keyCorners) as an RGBA32F texture, made once.
  cornersOf(key) {
    if (!key.corners || key.cornerStride !== this.stride) {
      const h = key.header, [dh, dw] = h.depth.shape, ty = Math.tan(h.fov * Math.PI / 360);
      const c = keyCorners(key.depthData, dw, dh, this.stride, h.near, h.far, h.aspect * ty, ty);
      if (key.corners) this.gl.deleteTexture(key.corners);
      key.corners = texture(this.gl, 3, this.gl.RGBA32F, this.gl.RGBA, this.gl.FLOAT, c.nx, c.ny, c.data, this.gl.NEAREST);
      key.cornerStride = this.stride;
    }
    return key.corners;
  }

  // A keyframe's textures, uploaded now (when its decode resolves, not in a frame): header
  // (view, proj row-major; near, far), colour an ImageBitmap of its (H, W) RGBA rows
  // bottom-up (decode.js; closed here) and depth (H, W) float32 rows bottom-up, as WebGL's
  // textures want them.  Drawn once adopted (useKeyframe) or dropped (dropKeyframe).
  prepareKeyframe(header, bitmap, depth) {
    const gl = this.gl;
    const [dh, dw] = header.depth.shape;
    gl.pixelStorei(gl.UNPACK_FLIP_Y_WEBGL, false);  // the bitmap's rows as they came
    gl.pixelStorei(gl.UNPACK_PREMULTIPLY_ALPHA_WEBGL, false);
    gl.pixelStorei(gl.UNPACK_COLORSPACE_CONVERSION_WEBGL, gl.NONE);
    const key = {
      sprite: texture(gl, 1, gl.RGBA8, gl.RGBA, gl.UNSIGNED_BYTE, bitmap.width, bitmap.height, bitmap, gl.LINEAR),
      depth: texture(gl, 2, gl.R32F, gl.RED, gl.FLOAT, dw, dh, depth, gl.NEAREST),
      mvp: mul(header.proj, header.view),
      nearFar: [header.near, header.far],
      header,
      depthData: depth,  // for its mesh's vertices, made when first drawn (cornersOf)
      corners: null,
      cornerStride: 0,
    };
    bitmap.close();
    return key;
  }

  // Draw the prepared keyframe `key` from now on; the one it replaces kept as the older
  // of the pair when `this.pair` (the one before deleted), else deleted.
  useKeyframe(key) {
    if (this.previous) this.dropKeyframe(this.previous);
    this.previous = null;
    if (this.key) {
      if (this.pair) this.previous = this.key; else this.dropKeyframe(this.key);
    }
    this.key = key;
  }

  dropKeyframe(key) {
    this.gl.deleteTexture(key.sprite); this.gl.deleteTexture(key.depth);
    if (key.corners) this.gl.deleteTexture(key.corners);
  }

  // Draw a spriteframe at view-projection `viewProj` (row-major) into the canvas; `eye`
  // (world metres, the viewpoint's o) for the depth mesh's sky sheets (default: the
  // keyframe's own).
  draw(viewProj, eye = null) {
    const gl = this.gl, u = this.u;
    gl.viewport(0, 0, gl.drawingBufferWidth, gl.drawingBufferHeight);
    gl.clearColor(...SKY_RGB, 1);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    if (!this.vao) return 0;
    gl.enable(gl.DEPTH_TEST);
    gl.useProgram(this.program);
    gl.uniformMatrix4fv(u.u_mvp, true, viewProj);
    const key = this.key;
    gl.uniform1i(u.u_has_key, key ? 1 : 0);
    gl.uniformMatrix4fv(u.u_key_mvp, true, key ? key.mvp : viewProj);
    gl.uniform2fv(u.u_key_near_far, key ? key.nearFar : [1, 2]);
    gl.uniform1f(u.u_tol, this.tol);
    gl.uniform4fv(u.u_fallback_tint, this.fallbackTint);
    gl.activeTexture(gl.TEXTURE0); gl.bindTexture(gl.TEXTURE_2D, this.colorTex);
    gl.activeTexture(gl.TEXTURE1); gl.bindTexture(gl.TEXTURE_2D, key ? key.sprite : this.colorTex);
    gl.activeTexture(gl.TEXTURE2); gl.bindTexture(gl.TEXTURE_2D, key ? key.depth : null);
    gl.uniform1i(u.u_color, 0); gl.uniform1i(u.u_sprite, 1); gl.uniform1i(u.u_key_depth, 2);
    gl.bindVertexArray(this.vao);
    gl.drawElements(gl.TRIANGLES, this.count, gl.UNSIGNED_INT, 0);
    gl.bindVertexArray(null);
    this.meshDrawn = false;
    if (this.proxy !== 'depth' || !key || key.header.zbuffer !== 'full') return this.triangles;
    // the coarse spriteframe stays under the mesh, where the mesh draws nothing
    gl.clear(gl.DEPTH_BUFFER_BIT);
    this.meshDrawn = true;  // the depth buffer holds the mesh's (its own depth range)
    this.eye = eye || key.header.viewpoint.o;
    let tris = this.triangles + this.drawMesh(key, viewProj);
    const prev = this.previous;
    if (this.pair && prev && prev.header.zbuffer === 'full') tris += this.drawMesh(prev, viewProj, true);
    return tris;
  }

  // The canvas's pixels, RGBA rows bottom-up, base64 (for tests).
  pixels() {
    const gl = this.gl, w = gl.drawingBufferWidth, h = gl.drawingBufferHeight;
    const out = new Uint8Array(4 * w * h);
    gl.readPixels(0, 0, w, h, gl.RGBA, gl.UNSIGNED_BYTE, out);
    let s = '';
    for (let i = 0; i < out.length; i += 8192) s += String.fromCharCode(...out.subarray(i, i + 8192));
    return { width: w, height: h, rgba: btoa(s) };
  }
}
