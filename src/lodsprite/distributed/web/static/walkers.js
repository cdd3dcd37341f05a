// A scene's walkers drawn by the page each frame (lodsprite.distributed.web.walkers): the
// closed-form walk (lodsprite.scene.walk.walk: straight lines at constant speed, reflected
// at the walking rectangle's edges by the triangle wave) on the ground (HeightField.
// height_at: bilinear, clamped), each walker's LOD by its distance (Gumbau et al. §4.2:
// 1 - (d - near) / (far - near), clamped; the coarsest shipped level whose share of the
// triangles is at or above it; under a frame budget of triangles, TRIANGLE_BUDGET), each
// (type, level) one instanced draw, shaded as lodsprite.gl.crowd, depth
// tested against what the spriteframe drew (the keyframe's own surface).  Walkers outside
// the view frustum (by a bounding sphere about the type's base) are not drawn.  walk() and
// groundAt() are cross-checked with the Python ones (relative 1e-9).

import { linkProgram } from './gl.js';

const LIGHT = (() => { const l = [0.3, -0.4, 0.87], n = Math.hypot(...l); return l.map((x) => x / n); })();

// The depth mesh's window depth of a keyframe's surfaces (gl.js MESH_VS, the newer
// keyframe's triangles: [0, 0.25]), for walkers drawn over the mesh (u_remap 1).
const REMAP = 'if (u_remap == 1) q.z = 0.25 * q.z - 0.75 * q.w;';

const VS = `#version 300 es
layout(location = 0) in vec3 a_pos;
layout(location = 1) in vec3 a_normal;
layout(location = 2) in vec3 a_color;
layout(location = 3) in vec4 a_inst;  // x, y, z, yaw
uniform mat4 u_view_proj;
uniform int u_remap;
out vec3 v_color;
out vec3 v_normal;
void main() {
  float c = cos(a_inst.w), s = sin(a_inst.w);
  mat2 r = mat2(c, s, -s, c);
  vec3 p = vec3(r * a_pos.xy, a_pos.z) + a_inst.xyz;
  v_normal = vec3(r * a_normal.xy, a_normal.z);
  v_color = a_color;
  vec4 q = u_view_proj * vec4(p, 1.0);
  ${REMAP}
  gl_Position = q;
}`;

const FS = `#version 300 es
precision highp float;
uniform vec3 u_light;
in vec3 v_color;
in vec3 v_normal;
out vec4 f_color;
void main() {
  float lit = 0.35 + 0.65 * max(dot(normalize(v_normal), u_light), 0.0);
  f_color = vec4(v_color * lit, 1.0);
}`;

// A walker smaller than POINT_PX pixels tall is drawn as one point of its type's lit
// colour, the side of the square of its silhouette's area (a 200-triangle mesh on a pixel
// or two is mostly vertex work for nothing).
export const POINT_PX = 2.0;

const POINT_VS = `#version 300 es
layout(location = 0) in vec3 a_pos;    // its middle (x, y, ground + height / 2)
layout(location = 1) in vec4 a_col;    // lit colour, side in metres
uniform mat4 u_view_proj;
uniform float u_focal;  // pixels a metre at unit depth
uniform int u_remap;
out vec3 v_color;
void main() {
  vec4 q = u_view_proj * vec4(a_pos, 1.0);
  gl_PointSize = max(1.0, a_col.w * u_focal / max(q.w, 1e-6));
  ${REMAP}
  v_color = a_col.rgb;
  gl_Position = q;
}`;

const POINT_FS = `#version 300 es
precision highp float;
in vec3 v_color;
out vec4 f_color;
void main() { f_color = vec4(v_color, 1.0); }`;

// An aligned typed array over a copy of little-endian bytes (msgpack bin: a Uint8Array).
function typed(Type, bytes) { return new Type(new Uint8Array(bytes).buffer); }

// The walkers' arrays of a scene header's `walkers` entry.
export function walkerData(w) {
  return {
    count: w.count, near: w.near, far: w.far,
    xy0: typed(Float64Array, w.xy0), heading: typed(Float64Array, w.heading),
    speed: typed(Float64Array, w.speed), box: typed(Float64Array, w.box),
    type: typed(Uint16Array, w.type),
    ground: typed(Float32Array, w.ground), rows: w.ground_shape[0], cols: w.ground_shape[1],
    dx: w.ground_dx, dy: w.ground_dy,
    types: w.types.map((t) => {
      const vertices = typed(Float32Array, t.vertices);
      let r2 = 0, top = 0, side = 0;  // bounding radius about the base, height, half width
      const colour = [0, 0, 0];  // its lit colour, averaged over its vertices
      const n = vertices.length / 9;
      for (let i = 0; i < vertices.length; i += 9) {
        const [x, y, z] = [vertices[i], vertices[i + 1], vertices[i + 2]];
        r2 = Math.max(r2, x * x + y * y + z * z);
        top = Math.max(top, z); side = Math.max(side, Math.abs(x), Math.abs(y));
        const lit = 0.35 + 0.65 * Math.max(vertices[i + 3] * LIGHT[0] + vertices[i + 4] * LIGHT[1] + vertices[i + 5] * LIGHT[2], 0);
        for (let c = 0; c < 3; c++) colour[c] += (vertices[i + 6 + c] * lit) / n;
      }
      return {
        name: t.name, vertices, radius: Math.sqrt(r2), height: top, colour,
        pointScale: Math.sqrt(Math.min(1, (2 * side) / Math.max(top, 1e-9))),  // area-true side
        levels: t.levels.map((l) => ({ fraction: l.fraction, indices: typed(Uint32Array, l.indices) })),
      };
    }),
  };
}

// The six planes (a, b, c, d; inside: a x + b y + c z + d >= 0, normalised) of a row-major
// view-projection's frustum (Gribb & Hartmann).
export function frustumPlanes(m) {
  const row = (i) => m.slice(4 * i, 4 * i + 4);
  const [r0, r1, r2, r3] = [row(0), row(1), row(2), row(3)];
  return [[r3, r0, 1], [r3, r0, -1], [r3, r1, 1], [r3, r1, -1], [r3, r2, 1], [r3, r2, -1]].map(([a, b, k]) => {
    const p = a.map((v, i) => v + k * b[i]);
    const n = Math.hypot(p[0], p[1], p[2]);
    return p.map((v) => v / n);
  });
}

// Positions and headings of every walker at time t seconds (lodsprite.scene.walk.walk):
// out.xy (2K) and out.yaw (K), Float64Arrays.
export function walk(d, t, out = { xy: new Float64Array(2 * d.count), yaw: new Float64Array(d.count) }) {
  const axis = (k, a, dir) => {  // the folded coordinate on axis a; its sign of dir
    const lo = d.box[4 * k + a], hi = d.box[4 * k + 2 + a];
    const span = Math.max(hi - lo, 1e-12), period = 2 * span;
    let u = (d.xy0[2 * k + a] - lo) + dir * (d.speed[k] * t);
    u -= period * Math.floor(u / period);  // numpy's mod: the divisor's sign
    const back = u > span;
    out.xy[2 * k + a] = lo + (back ? period - u : u);
    return back ? -dir : dir;
  };
  for (let k = 0; k < d.count; k++) {
    const h = d.heading[k];
    const tx = axis(k, 0, Math.cos(h)), ty = axis(k, 1, Math.sin(h));
    out.yaw[k] = Math.atan2(ty, tx);
  }
  return out;
}

// Ground height (metres) at world (x, y): HeightField.height_at over the shipped heights
// (row 0 north, centred on the origin), bilinear, clamped at the edges.
export function groundAt(d, x, y) {
  const rows = d.rows, cols = d.cols;
  const width = (cols - 1) * d.dx, depth = (rows - 1) * d.dy;
  const r = Math.min(Math.max((depth / 2 - y) / d.dy, 0), rows - 1);
  const c = Math.min(Math.max((x + width / 2) / d.dx, 0), cols - 1);
  const r0 = Math.min(Math.floor(r), rows - 2), c0 = Math.min(Math.floor(c), cols - 2);
  const fr = r - r0, fc = c - c0, g = d.ground, i = r0 * cols + c0;
  const top = g[i] * (1 - fc) + g[i + 1] * fc;
  const bot = g[i + cols] * (1 - fc) + g[i + cols + 1] * fc;
  return top * (1 - fr) + bot * fr;
}

// The shipped level (index) a walker at distance `dist` draws: the coarsest whose fraction
// is at or above the desired LOD (levels finest first), that LOD scaled by `scale` (the
// frame's budget, below; 1: the rule as it is).
export function levelFor(levels, near, far, dist, scale = 1) {
  const want = scale * Math.min(Math.max(1 - (dist - near) / (far - near), 0), 1);
  let pick = 0;
  for (let i = 0; i < levels.length; i++) if (levels[i].fraction >= want) pick = i;
  return pick;
}

// Most triangles the walkers of one frame draw (Gumbau et al.'s frame budget, as their
// LOD manager holds one): past it, every walker's desired LOD is scaled by the one factor
// that brings the frame under it (bisection), so the nearest stay the finest.  A crowd
// seen from among it asks millions at the rule's own levels, which a software rasteriser
// draws at a few frames a second.
export const TRIANGLE_BUDGET = 300000;

// The LOD scale in [0, 1] of the frame whose visible walkers are `n` entries of `types`
// and `dists` (their type indices and distances): 1 when the rule's levels fit `budget`;
// 0 (every walker at its coarsest level, the frame over the budget) when even those do not.
export function budgetScale(d, types, dists, n, budget = TRIANGLE_BUDGET) {
  const cost = (scale) => {
    let tris = 0;
    for (let i = 0; i < n; i++) {
      const tp = d.types[types[i]];
      tris += tp.levels[levelFor(tp.levels, d.near, d.far, dists[i], scale)].indices.length / 3;
    }
    return tris;
  };
  if (cost(1) <= budget) return 1;
  let lo = 0, hi = 1;  // cost(hi) does not fit; cost(lo) fits unless lo is still 0
  for (let it = 0; it < 12; it++) {
    const mid = 0.5 * (lo + hi);
    if (cost(mid) <= budget) lo = mid; else hi = mid;
  }
  return lo;
}

export class WalkerDrawer {
  constructor(gl, data) {
    this.gl = gl; this.d = data;
    const { program, u } = linkProgram(gl, VS, FS, ['u_view_proj', 'u_light', 'u_remap']);
    this.program = program;
    this.u = { viewProj: u.u_view_proj, light: u.u_light, remap: u.u_remap };
    this.out = { xy: new Float64Array(2 * data.count), yaw: new Float64Array(data.count) };
    this.buckets = [];  // per type, per level: {vao, count (indices), inst buffer, data, n}
    for (const t of data.types) {
      const vbo = gl.createBuffer();
      gl.bindBuffer(gl.ARRAY_BUFFER, vbo);
      gl.bufferData(gl.ARRAY_BUFFER, t.vertices, gl.STATIC_DRAW);
      const perType = [];
      for (const level of t.levels) {
        const vao = gl.createVertexArray();
        gl.bindVertexArray(vao);
        gl.bindBuffer(gl.ARRAY_BUFFER, vbo);
        for (let a = 0; a < 3; a++) {
          gl.enableVertexAttribArray(a);
          gl.vertexAttribPointer(a, 3, gl.FLOAT, false, 36, 12 * a);
        }
        const inst = gl.createBuffer();
        gl.bindBuffer(gl.ARRAY_BUFFER, inst);
        gl.bufferData(gl.ARRAY_BUFFER, 16 * data.count, gl.DYNAMIC_DRAW);
        gl.enableVertexAttribArray(3);
        gl.vertexAttribPointer(3, 4, gl.FLOAT, false, 0, 0);
        gl.vertexAttribDivisor(3, 1);
        const ibo = gl.createBuffer();
        gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, ibo);
        gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, level.indices, gl.STATIC_DRAW);
        gl.bindVertexArray(null);
        perType.push({ vao, count: level.indices.length, inst, data: new Float32Array(4 * data.count), n: 0 });
      }
      this.buckets.push(perType);
    }
    const pts = linkProgram(gl, POINT_VS, POINT_FS, ['u_view_proj', 'u_focal', 'u_remap']);
    this.points = { program: pts.program, u: pts.u, vao: gl.createVertexArray(), buffer: gl.createBuffer(), data: new Float32Array(7 * data.count), n: 0 };
    gl.bindVertexArray(this.points.vao);
    gl.bindBuffer(gl.ARRAY_BUFFER, this.points.buffer);
    gl.bufferData(gl.ARRAY_BUFFER, this.points.data.byteLength, gl.DYNAMIC_DRAW);
    gl.enableVertexAttribArray(0); gl.vertexAttribPointer(0, 3, gl.FLOAT, false, 28, 0);
    gl.enableVertexAttribArray(1); gl.vertexAttribPointer(1, 4, gl.FLOAT, false, 28, 12);
    gl.bindVertexArray(null);
    this.triangles = 0;
  }

  // Draw every walker at time t seconds from eye (world metres) with viewProj (row-major),
  // over what the canvas holds (its depth buffer tested; `meshDepth`: the spriteframe drew
  // the keyframe's depth mesh, whose depth range the walkers then share); `focal`: pixels
  // a metre at unit depth (the canvas height over 2 tan(fov / 2)).  Returns the triangles
  // drawn (points: this.pointsDrawn).
  draw(viewProj, eye, t, meshDepth = false, focal = 500) {
    const gl = this.gl, d = this.d, { xy, yaw } = walk(d, t, this.out);
    for (const perType of this.buckets) for (const b of perType) b.n = 0;
    this.points.n = 0;
    const planes = frustumPlanes(viewProj);
    const seen = this.seen || (this.seen = { k: new Int32Array(d.count), dist: new Float64Array(d.count),
      type: new Int32Array(d.count), z: new Float64Array(d.count) });
    let n = 0;
    for (let k = 0; k < d.count; k++) {
      const x = xy[2 * k], y = xy[2 * k + 1], z = groundAt(d, x, y);
      const type = d.type[k], r = d.types[type].radius;
      // outside the view (its bounding sphere about its base, radius its farthest vertex)
      let outside = false;
      for (let i = 0; i < 6 && !outside; i++) {
        const p = planes[i];
        outside = p[0] * x + p[1] * y + p[2] * z + p[3] < -r;
      }
      if (outside) continue;
      const dist = Math.hypot(x - eye[0], y - eye[1], z - eye[2]);
      const tp = d.types[type];
      if (tp.height * focal < POINT_PX * dist) {  // under POINT_PX tall: a point
        const P = this.points, o = 7 * P.n;
        P.data[o] = x; P.data[o + 1] = y; P.data[o + 2] = z + 0.5 * tp.height;
        P.data[o + 3] = tp.colour[0]; P.data[o + 4] = tp.colour[1]; P.data[o + 5] = tp.colour[2];
        P.data[o + 6] = tp.height * tp.pointScale;
        P.n += 1;
        continue;
      }
      seen.k[n] = k; seen.dist[n] = dist; seen.type[n] = type; seen.z[n] = z; n += 1;
    }
    this.scale = budgetScale(d, seen.type, seen.dist, n);
    for (let i = 0; i < n; i++) {
      const k = seen.k[i], tp = d.types[seen.type[i]];
      const b = this.buckets[seen.type[i]][levelFor(tp.levels, d.near, d.far, seen.dist[i], this.scale)];
      const o = 4 * b.n;
      b.data[o] = xy[2 * k]; b.data[o + 1] = xy[2 * k + 1]; b.data[o + 2] = seen.z[i]; b.data[o + 3] = yaw[k];
      b.n += 1;
    }
    gl.enable(gl.DEPTH_TEST);
    gl.useProgram(this.program);
    gl.uniformMatrix4fv(this.u.viewProj, true, viewProj);
    gl.uniform3fv(this.u.light, LIGHT);
    gl.uniform1i(this.u.remap, meshDepth ? 1 : 0);
    let tris = 0;
    for (const perType of this.buckets) {
      for (const b of perType) {
        if (!b.n) continue;
        gl.bindBuffer(gl.ARRAY_BUFFER, b.inst);
        gl.bufferSubData(gl.ARRAY_BUFFER, 0, b.data, 0, 4 * b.n);
        gl.bindVertexArray(b.vao);
        gl.drawElementsInstanced(gl.TRIANGLES, b.count, gl.UNSIGNED_INT, 0, b.n);
        tris += (b.count / 3) * b.n;
      }
    }
    const P = this.points;
    if (P.n) {
      gl.useProgram(P.program);
      gl.uniformMatrix4fv(P.u.u_view_proj, true, viewProj);
      gl.uniform1f(P.u.u_focal, focal);
      gl.uniform1i(P.u.u_remap, meshDepth ? 1 : 0);
      gl.bindBuffer(gl.ARRAY_BUFFER, P.buffer);
      gl.bufferSubData(gl.ARRAY_BUFFER, 0, P.data, 0, 7 * P.n);
      gl.bindVertexArray(P.vao);
      gl.drawArrays(gl.POINTS, 0, P.n);
    }
    gl.bindVertexArray(null);
    this.triangles = tris;
    this.pointsDrawn = P.n;
    return tris;
  }
}
