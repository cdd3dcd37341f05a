// The spriteframe error on the keyframe's own depth (lodsprite.sprite.depth_metric's
// DepthEstimate, ported: one algorithm, cross-checked to 1e-9 in test_browser.py): Chen,
// Swan & Kaufman 1999's Eq. 1-2 with the depth mesh the page draws (gl.js, a vertex every
// `stride` texels) as the proxy, in closed form, plus the keyframe image's resampling and
// the view's uncovered area.  What the keyframe saw (terrain, a scene's standing objects)
// is measured: a scene's standing objects parallax as the terrain does.
//
// Built once a keyframe from its depth and colour (buildEstimate, in the decode worker:
// off the page's thread), sent to the page as plain typed arrays (its `state`), and
// measured a frame (DepthEstimate.errorPx).  Depth and colour rows bottom-up, as the wire
// sends them.  Every step is the Python one's, in the same order, in float64.

import { cross } from './camera.js';

export const MAX_SAMPLES = 4096;
export const MAX_RESAMPLED = 1024;
export const MAX_COVER = 8192;
export const COVER_GRID = 16;
export const UNCOVERED_PX = 2.0;
export const CONTRAST_FLOOR = 0.1;
export const MAX_RESAMPLING_PX = 64.0;
const CELL_SAMPLES = [[0.5, 0.5], [0.5, 0.0], [0.0, 0.5]];

export function gridAxis(n, stride) {
  const v = [];
  for (let i = 0; i < n; i += stride) v.push(i);
  if (v[v.length - 1] !== n - 1) v.push(n - 1);
  return v;
}

export function inverseDepth(z, near, far) {
  if (z >= 1.0) return 0.0;
  const d = 2.0 * near * far / (far + near - (2.0 * z - 1.0) * (far - near));
  return 1.0 / Math.max(d, 1e-30);
}

// At most `most` indices of 0..n-1, evenly spread (numpy's linspace, truncated, unique).
export function even(n, most) {
  const out = [];
  if (n <= most) { for (let i = 0; i < n; i++) out.push(i); return out; }
  const step = (n - 1) / (most - 1);
  let last = -1;
  for (let i = 0; i < most; i++) {
    const k = i === most - 1 ? n - 1 : Math.trunc(i * step);
    if (k !== last) { out.push(k); last = k; }
  }
  return out;
}

const roundHalfEven = (x) => {  // Python's round
  const r = Math.round(x);
  return Math.abs(x % 1) === 0.5 && r % 2 !== 0 ? r - 1 : r;
};

// The keyframe's rays through texel (px, py) (GL rows), scaled to unit eye depth.
function keyRay(px, py, w, h, key, tx, ty) {
  const nx = ((px + 0.5) / w * 2.0 - 1.0) * tx, ny = ((py + 0.5) / h * 2.0 - 1.0) * ty;
  return [0, 1, 2].map((i) => nx * key.x[i] + ny * key.y[i] - key.z[i]);
}

function tangentBasis(n0) {  // (t1, t2) of the plane with normal n0 (need not be unit)
  const len = Math.sqrt(n0[0] * n0[0] + n0[1] * n0[1] + n0[2] * n0[2]);
  const n = len > 0 ? [n0[0] / len, n0[1] / len, n0[2] / len] : [0, 0, 1];
  let k = 0;  // the world axis least aligned with n (the first of equals)
  for (let i = 1; i < 3; i++) if (Math.abs(n[i]) < Math.abs(n[k])) k = i;
  const axis = [0, 0, 0]; axis[k] = 1;
  let t1 = cross(n, axis);
  const l1 = Math.sqrt(t1[0] * t1[0] + t1[1] * t1[1] + t1[2] * t1[2]);
  t1 = [t1[0] / l1, t1[1] / l1, t1[2] / l1];
  return [t1, cross(n, t1)];
}

// d(pixel x, y)/d(u, v) of the plane point p + u t1 + v t2 through row-major m on a
// (w, h) image: [a00, a01, a10, a11] and the point's clip w.
function pixelDerivatives(p, t1, t2, m, w, h) {
  const c = [0, 1, 2, 3].map((r) => m[4 * r] * p[0] + m[4 * r + 1] * p[1] + m[4 * r + 2] * p[2] + m[4 * r + 3]);
  const cw = c[3], safe = cw !== 0 ? cw : 1.0;
  const ndc = [c[0] / safe, c[1] / safe], half = [0.5 * w, 0.5 * h];
  const out = [0, 0, 0, 0];
  [t1, t2].forEach((t, j) => {
    const dc = [0, 1, 2, 3].map((r) => m[4 * r] * t[0] + m[4 * r + 1] * t[1] + m[4 * r + 2] * t[2]);
    for (let i = 0; i < 2; i++) out[2 * i + j] = half[i] * (dc[i] - ndc[i] * dc[3]) / safe;
  });
  return [out, cw];
}

function resamplingFromSingular(s1, s2) {
  let blur = s2 > 0 ? 1.0 / s2 - 1.0 : Infinity;
  let alias = s1 > 0 ? 1.0 - 1.0 / s1 : 0.0;
  if (Number.isNaN(blur)) blur = MAX_RESAMPLING_PX;
  if (Number.isNaN(alias)) alias = 1.0;
  blur = Math.min(Math.max(blur, 0.0), MAX_RESAMPLING_PX);
  alias = Math.min(Math.max(alias, 0.0), 1.0);
  return Math.min(Math.hypot(blur, alias), MAX_RESAMPLING_PX);
}

// One keyframe's samples from its window depth (dh, dw) float32 rows bottom-up, its
// viewpoint {x, y, z, o}, its projection's fov (degrees), aspect, near and far and its
// projection @ view `keyVP` (row-major: the header's proj times its view), a mesh of
// `stride` texels and a keyframe `keyScale` texels a display pixel; with `rgb` (its
// colour, (dh, dw, 3) bytes rows bottom-up) weighed by contrast.  Returns its state.
export function buildEstimate(depth, dw, dh, key, fov, aspect, near, far, keyVP, stride, keyScale, rgb = null) {
  const w = dw, h = dh;
  const ty = Math.tan(fov * (Math.PI / 180) / 2.0), tx = ty * aspect;
  const keyPx = [Math.max(1, roundHalfEven(w / keyScale)), Math.max(1, roundHalfEven(h / keyScale))];
  const xs = gridAxis(w, stride), ys = gridAxis(h, stride), nx = xs.length, ny = ys.length;
  // the vertices' inverse depth, sky beside ground at its farthest ground neighbour's
  const zv = new Float64Array(nx * ny);
  for (let j = 0; j < ny; j++) for (let i = 0; i < nx; i++) zv[j * nx + i] = depth[ys[j] * w + xs[i]];
  const inv = new Float64Array(nx * ny);
  for (let j = 0; j < ny; j++) for (let i = 0; i < nx; i++) {
    let z = zv[j * nx + i];
    if (z >= 1.0) {
      let g = 0;
      for (let b = -1; b <= 1; b++) for (let a = -1; a <= 1; a++) {
        const jj = j + b, ii = i + a;
        if (jj < 0 || jj >= ny || ii < 0 || ii >= nx) continue;
        const zn = zv[jj * nx + ii];
        if (zn < 1.0 && zn > g) g = zn;
      }
      if (g > 0) z = g;
    }
    inv[j * nx + i] = inverseDepth(z, near, far);
  }
  // samples: each cell's, evenly thinned
  const cells = (nx - 1) * (ny - 1);
  const keep = even(3 * cells, MAX_SAMPLES), n = keep.length;
  const s = {
    n, eye: key.o.slice(), keyScale, keyPx, keyViewProj: null,
    rays: new Float64Array(3 * n), invTrue: new Float64Array(n), invMesh: new Float64Array(n),
    texel: new Float64Array(2 * n), ground: new Uint8Array(n), points: new Float64Array(3 * n),
    t1: new Float64Array(3 * n), t2: new Float64Array(3 * n), b: new Float64Array(4 * n),
    kw: new Float64Array(n), samplesH: new Float64Array(4 * n), weights: new Float64Array(n).fill(1),
    coverH: null, coverSpacingPx: 0,
  };
  const cellsAt = new Int32Array(2 * n);
  const verts = new Array(nx * ny);  // each grid vertex's world point, once
  for (let j = 0; j < ny; j++) for (let i = 0; i < nx; i++) {
    const r = keyRay(xs[i], ys[j], w, h, key, tx, ty), d = Math.max(inv[j * nx + i], 1e-30);
    verts[j * nx + i] = [key.o[0] + r[0] / d, key.o[1] + r[1] / d, key.o[2] + r[2] / d];
  }
  const vertex = (ry, rx) => verts[ry * nx + rx];
  for (let q = 0; q < n; q++) {
    const flat = keep[q], which = Math.floor(flat / cells), cell = flat % cells;
    const [fu, fv] = CELL_SAMPLES[which];
    const iy = Math.floor(cell / (nx - 1)), ix = cell % (nx - 1);
    const x0 = xs[ix], x1 = xs[ix + 1], y0 = ys[iy], y1 = ys[iy + 1];
    const px = x0 + Math.floor(fu * (x1 - x0)), py = y0 + Math.floor(fv * (y1 - y0));
    const u = (px - x0) / (x1 - x0), v = (py - y0) / (y1 - y0);
    const i00 = inv[iy * nx + ix], i10 = inv[iy * nx + ix + 1], i11 = inv[(iy + 1) * nx + ix + 1], i01 = inv[(iy + 1) * nx + ix];
    const lower = u >= v;
    s.invMesh[q] = lower ? (1 - u) * i00 + (u - v) * i10 + v * i11 : (1 - v) * i00 + u * i11 + (v - u) * i01;
    const it = inverseDepth(depth[py * w + px], near, far);
    s.invTrue[q] = it;
    const r = keyRay(px, py, w, h, key, tx, ty);
    s.rays.set(r, 3 * q);
    s.texel[2 * q] = px + 0.5; s.texel[2 * q + 1] = py + 0.5;
    const p00 = vertex(iy, ix), p10 = vertex(iy, ix + 1), p11 = vertex(iy + 1, ix + 1), p01 = vertex(iy + 1, ix);
    const e = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    const normal = lower ? cross(e(p10, p00), e(p11, p00)) : cross(e(p11, p00), e(p01, p00));
    s.ground[q] = it > 0 && (lower ? i00 > 0 && i10 > 0 && i11 > 0 : i00 > 0 && i11 > 0 && i01 > 0) ? 1 : 0;
    const d = Math.max(it, 1e-30);
    const point = [key.o[0] + r[0] / d, key.o[1] + r[1] / d, key.o[2] + r[2] / d];
    s.points.set(point, 3 * q);
    const [t1, t2] = tangentBasis(normal);
    s.t1.set(t1, 3 * q); s.t2.set(t2, 3 * q);
    s.samplesH.set([r[0] + key.o[0] * it, r[1] + key.o[1] * it, r[2] + key.o[2] * it, it], 4 * q);
    cellsAt[2 * q] = px; cellsAt[2 * q + 1] = py;
  }
  s.cellR = Math.max(1, Math.floor(stride / 2));
  s.keyViewProj = Float64Array.from(keyVP);
  for (let q = 0; q < n; q++) {
    const [bq, kw] = pixelDerivatives(s.points.subarray(3 * q, 3 * q + 3), s.t1.subarray(3 * q, 3 * q + 3),
      s.t2.subarray(3 * q, 3 * q + 3), s.keyViewProj, keyPx[0], keyPx[1]);
    s.b.set(bq, 4 * q); s.kw[q] = kw;
  }
  // coverage: the mesh's vertices, every step-th a side, sky directions included
  const step = Math.max(1, Math.ceil(Math.sqrt(nx * ny / MAX_COVER)));
  const cover = [];
  for (let j = 0; j < ny; j += step) for (let i = 0; i < nx; i += step) {
    const r = keyRay(xs[i], ys[j], w, h, key, tx, ty), ci = inv[j * nx + i];
    cover.push(r[0] + key.o[0] * ci, r[1] + key.o[1] * ci, r[2] + key.o[2] * ci, ci);
  }
  s.coverH = Float64Array.from(cover);
  s.coverSpacingPx = stride * step / keyScale;
  if (rgb) weighBy(s, rgb, w, h, cellsAt);
  return s;
}

// Each sample's share of the means: the keyframe's mean squared luminance gradient over
// a box about it, at the display's resolution, plus a floor (DepthEstimate.weigh_by).
function weighBy(s, rgb, w, h, cellsAt) {
  const step = Math.max(1, roundHalfEven(s.keyScale));
  const lw = Math.ceil(w / step), lh = Math.ceil(h / step);
  const lum = new Float64Array(lw * lh);
  for (let j = 0; j < lh; j++) for (let i = 0; i < lw; i++) {
    const k = 3 * ((j * step) * w + i * step);
    lum[j * lw + i] = 0.2126 * rgb[k] + 0.7152 * rgb[k + 1] + 0.0722 * rgb[k + 2];
  }
  const g2 = new Float64Array(lw * lh);
  for (let j = 0; j < lh; j++) for (let i = 0; i < lw - 1; i++) {
    const d = lum[j * lw + i + 1] - lum[j * lw + i]; g2[j * lw + i] += d * d;
  }
  for (let j = 0; j < lh - 1; j++) for (let i = 0; i < lw; i++) {
    const d = lum[(j + 1) * lw + i] - lum[j * lw + i]; g2[j * lw + i] += d * d;
  }
  const tw = lw + 1, table = new Float64Array(tw * (lh + 1));  // cumsum down, then across
  for (let j = 0; j < lh; j++) for (let i = 0; i < lw; i++) table[(j + 1) * tw + i + 1] = table[j * tw + i + 1] + g2[j * lw + i];
  for (let j = 1; j <= lh; j++) for (let i = 2; i <= lw; i++) table[j * tw + i] += table[j * tw + i - 1];
  const r = Math.max(1, Math.floor(s.cellR / step)), box = new Float64Array(s.n);
  const clamp = (v, hi) => Math.min(Math.max(v, 0), hi);
  let sum = 0;
  for (let q = 0; q < s.n; q++) {
    const px = Math.floor(cellsAt[2 * q] / step), py = Math.floor(cellsAt[2 * q + 1] / step);
    const x0 = clamp(px - r, lw), x1 = clamp(px + r + 1, lw), y0 = clamp(py - r, lh), y1 = clamp(py + r + 1, lh);
    box[q] = (table[y1 * tw + x1] - table[y0 * tw + x1] - table[y1 * tw + x0] + table[y0 * tw + x0]) / ((x1 - x0) * (y1 - y0));
    sum += box[q];
  }
  const mean = sum / s.n;
  if (!(mean > 0)) return;
  let total = 0;
  for (let q = 0; q < s.n; q++) { box[q] += CONTRAST_FLOOR * mean; total += box[q]; }
  const wm = total / s.n;
  for (let q = 0; q < s.n; q++) s.weights[q] = box[q] / wm;
}

// Whether the homogeneous point A[i..i+4] through row-major m is inside the frustum's
// sides (clip w > 0, |x|, |y| <= w); its clip x, y, w left in out.
const CLIP = new Float64Array(3);
function inView(m, A, i, out) {
  const x = A[i], y = A[i + 1], z = A[i + 2], v = A[i + 3];
  const c3 = m[12] * x + m[13] * y + m[14] * z + m[15] * v;
  if (!(c3 > 0)) return false;
  const c0 = m[0] * x + m[1] * y + m[2] * z + m[3] * v;
  if (!(Math.abs(c0) <= c3)) return false;
  const c1 = m[4] * x + m[5] * y + m[6] * z + m[7] * v;
  if (!(Math.abs(c1) <= c3)) return false;
  out[0] = c0; out[1] = c1; out[2] = c3;
  return true;
}

export class DepthEstimate {
  constructor(state) { Object.assign(this, state); }

  // The estimate (pixels) at a current eye through viewProj (row-major) on a (w, h)
  // image with pixel angle beta (radians); Infinity when no sample is in view.  No
  // allocation per sample: it runs twice a display frame.
  errorPx(eye, viewProj, beta, w, h) {
    const m = viewProj, S = this.samplesH, R = this.rays, W = this.weights;
    const o0 = this.eye[0] - eye[0], o1 = this.eye[1] - eye[1], o2 = this.eye[2] - eye[2];
    let total = 0, theta2 = 0, any = false;
    const g = this._ground || (this._ground = new Int32Array(this.n));
    let ng = 0;
    for (let q = 0; q < this.n; q++) {
      if (!inView(m, S, 4 * q, CLIP)) continue;
      any = true;
      const it = this.invTrue[q];
      let th = 0;
      if (it !== 0) {
        const im = this.invMesh[q], r0 = R[3 * q], r1 = R[3 * q + 1], r2 = R[3 * q + 2];
        const a0 = r0 + o0 * it, a1 = r1 + o1 * it, a2 = r2 + o2 * it;
        const b0 = r0 + o0 * im, b1 = r1 + o1 * im, b2 = r2 + o2 * im;
        const x0 = a1 * b2 - a2 * b1, x1 = a2 * b0 - a0 * b2, x2 = a0 * b1 - a1 * b0;
        th = Math.atan2(Math.sqrt(x0 * x0 + x1 * x1 + x2 * x2), a0 * b0 + a1 * b1 + a2 * b2);
      }
      total += W[q]; theta2 += W[q] * th * th;
      if (this.ground[q]) g[ng++] = q;
    }
    if (!any) return Infinity;
    let res2 = 0;
    if (ng) {
      let ws = 0, wr = 0, wg = 0;
      for (const i of even(ng, MAX_RESAMPLED)) {
        const q = g[i];
        ws += W[q]; wr += W[q] * this.resampling2(q, m, w, h);
      }
      for (let i = 0; i < ng; i++) wg += W[g[i]];
      res2 = wr / ws * wg / total;
    }
    const mean2 = theta2 / total + beta * beta * res2;
    const u = this.uncovered(m, w, h);
    return Math.sqrt((1.0 - u) * mean2 + u * (beta * UNCOVERED_PX) ** 2) / beta;
  }

  // e_res^2 + e_phase^2 (px^2) of ground sample q.
  resampling2(q, m, w, h) {
    const P = this.points, T1 = this.t1, T2 = this.t2;
    const px = P[3 * q], py = P[3 * q + 1], pz = P[3 * q + 2];
    const c0 = m[0] * px + m[1] * py + m[2] * pz + m[3], c1 = m[4] * px + m[5] * py + m[6] * pz + m[7];
    const cw = m[12] * px + m[13] * py + m[14] * pz + m[15], safe = cw !== 0 ? cw : 1.0;
    const n0 = c0 / safe, n1 = c1 / safe, hw = 0.5 * w, hh = 0.5 * h;
    const d = (t, r) => m[4 * r] * t[0] + m[4 * r + 1] * t[1] + m[4 * r + 2] * t[2];
    const t1 = T1.subarray(3 * q, 3 * q + 3), t2 = T2.subarray(3 * q, 3 * q + 3);
    const a00 = hw * (d(t1, 0) - n0 * d(t1, 3)) / safe, a01 = hw * (d(t2, 0) - n0 * d(t2, 3)) / safe;
    const a10 = hh * (d(t1, 1) - n1 * d(t1, 3)) / safe, a11 = hh * (d(t2, 1) - n1 * d(t2, 3)) / safe;
    const B = this.b, kw = this.kw[q];
    const b00 = B[4 * q], b01 = B[4 * q + 1], b10 = B[4 * q + 2], b11 = B[4 * q + 3];
    let det = a00 * a11 - a01 * a10;
    const scale = a00 * a00 + a01 * a01 + a10 * a10 + a11 * a11;
    const ok = cw > 0 && kw > 0 && Math.abs(det) > 1e-12 * Math.max(scale, 1e-300);
    if (!ok) det = 1.0;
    const i00 = a11 / det, i01 = -a01 / det, i10 = -a10 / det, i11 = a00 / det;
    let j00 = b00 * i00 + b01 * i10, j01 = b00 * i01 + b01 * i11;
    let j10 = b10 * i00 + b11 * i10, j11 = b10 * i01 + b11 * i11;
    let eRes = 0.0;
    if (ok) {
      const p = Math.hypot(j00 + j11, j10 - j01), r = Math.hypot(j00 - j11, j10 + j01);
      eRes = resamplingFromSingular(0.5 * (p + r), 0.5 * Math.abs(p - r));
    } else {
      j00 = j01 = j10 = j11 = 0;
    }
    // the sub-texel phase of the current pixel centre nearest the sample
    const S = this.samplesH, x = S[4 * q], y = S[4 * q + 1], z = S[4 * q + 2], v = S[4 * q + 3];
    const s0 = m[0] * x + m[1] * y + m[2] * z + m[3] * v, s1 = m[4] * x + m[5] * y + m[6] * z + m[7] * v;
    const s3 = m[12] * x + m[13] * y + m[14] * z + m[15] * v;
    const p0 = (s0 / s3 + 1.0) * 0.5 * w, p1 = (s1 / s3 + 1.0) * 0.5 * h;
    const d0 = Math.floor(p0) + 0.5 - p0, d1 = Math.floor(p1) + 0.5 - p1, k = this.keyScale;
    const f = (t) => t - 0.5 - Math.floor(t - 0.5);
    const f0 = f(this.texel[2 * q] + k * (j00 * d0 + j01 * d1));
    const f1 = f(this.texel[2 * q + 1] + k * (j10 * d0 + j11 * d1));
    const phase2 = Math.abs(f0 * (1.0 - f0) / k ** 2 - 1.0 / 12.0) + Math.abs(f1 * (1.0 - f1) / k ** 2 - 1.0 / 12.0);
    return eRes ** 2 + phase2;
  }

  // The share of the current image's cells no keyframe vertex lands in.
  uncovered(m, w, h) {
    const grid = Math.trunc(Math.min(Math.max(Math.floor(Math.min(w, h) / (2.0 * this.coverSpacingPx)), 4), COVER_GRID));
    const hit = new Uint8Array(grid * grid), C = this.coverH;
    let any = false;
    for (let i = 0; i < C.length; i += 4) {
      if (!inView(m, C, i, CLIP)) continue;
      any = true;
      const [c0, c1, c3] = CLIP;
      const cx = Math.min(Math.max(Math.trunc((c0 / c3 + 1.0) * 0.5 * grid), 0), grid - 1);
      const cy = Math.min(Math.max(Math.trunc((c1 / c3 + 1.0) * 0.5 * grid), 0), grid - 1);
      hit[cy * grid + cx] = 1;
    }
    if (!any) return 1.0;
    let n = 0;
    for (let i = 0; i < hit.length; i++) n += hit[i];
    return 1.0 - n / hit.length;
  }
}
