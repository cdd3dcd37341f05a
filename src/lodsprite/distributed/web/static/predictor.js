// Keyframe requests ahead of the viewer (Swan et al. 2002 §3.3: the server renders
// keyframes at predicted viewpoints) and the spriteframe error (Chen, Swan & Kaufman 1999,
// §3.2, Eq. 1-2: theta at the current eye between a square's centre C and the point C'
// the keyframe maps its colour to; error = sqrt(mean theta^2) / beta pixels).
//
// The page holds only the coarse level, so C is estimated: each coarse square's centre
// at the mean of its corners, raised by the scene's `relief` (the RMS height of the
// full-resolution centres off the coarse surface, computed by the server).  C' is where
// the keyframe eye's ray through C meets the coarse mesh (the triangles the page draws,
// split north-west to south-east): first among the triangles of C's square and its eight
// neighbours, else among those of the squares the ray's ground track crosses inside the
// terrain; of the hits in front of the keyframe eye, the one nearest to C along the ray
// (as lodsprite.sprite.raycast).  C' depends only on the keyframe eye: it is cast once a
// keyframe (the last eye's is kept), and a frame measures theta for the centres in view.
// A ray meeting no triangle is a miss, counted as the worst hit (as
// lodsprite.sprite.metric does).  At the keyframe's own eye the error is 0, as in the
// paper; it grows with the parallax the coarse level cannot show.
//
// It also counts what the spriteframe cannot show from the keyframe: a square whose
// fragment F (the coarse surface under C, on its diagonal: gl.js draws its colour there)
// the keyframe did not see is drawn from the terrain texture (gl.js's fallback), which
// puts C's texel at F.  Not seen: hidden behind the keyframe's coarse level (the keyframe
// eye's ray to F meets it nearer than F by more than gl.js's tolerance: its coarse
// z-buffer rule; cast once a keyframe) or, when the keyframe's view-projection is given,
// outside its frustum.  When the current view shows that F (inside its frustum, and the
// same cast from the current eye, for those squares only), the square counts as a miss does, no better than the worst hit,
// and with the angle between C and F when that is larger.  At the keyframe's own eye
// nothing it did not see is in view: the error is 0 still.  (The first estimate counted
// parallax only.)
//
// The linear predictor: the eye and the axes extrapolated linearly from the last two
// samples (the axes re-orthonormalised).  A request goes out for the viewpoint the viewer
// will be at one measured keyframe latency ahead (at most 1 s), when the shown keyframe's
// error there reaches epsilon/2.  At most `jobs` requests are in flight (the server's
// renders in flight a session, its load reply's `jobs`: Swan et al.'s several servers
// for one client), a new one no sooner than latency / jobs after the last, so that their
// keyframes arrive spread over the latency rather than together; one in flight: never
// with a request in flight.  When the viewer rests, one more request at the resting
// viewpoint (with none in flight) makes the shown keyframe exact.
//
// lodsprite.distributed.web.estimate is this module in Python (the load benchmark's
// pages); the two are one algorithm.

import { add, clip, cross, dot, mul, norm, scale, sub, unit, viewMatrix, perspective } from './camera.js';

const MAX_CENTRES = 4096;  // square centres measured a frame (a finer coarse level: evenly)
const T_MIN = 1e-6;  // hits nearer the keyframe eye (in units of eye to C) are not in front
const EDGE_TOL = 1e-9;
// The page's visibility tolerance (gl.js TOLERANCE: lodsprite.gl.sprite's
// DEFAULT_COARSE_TOL and DEFAULT_FRAGMENT_TOL), relative to depth.
const TOLERANCE = { coarse: 0.002, full: 0.03 };

// Moller-Trumbore: t where the ray o + t d meets the triangle (p0, e1, e2), or NaN.
function hit(o, d, p0, e1, e2) {
  const pv = cross(d, e2), det = dot(e1, pv);
  if (!(Math.abs(det) > 1e-300)) return NaN;
  const inv = 1 / det, s = sub(o, p0), u = dot(s, pv) * inv;
  const q = cross(s, e1), v = dot(d, q) * inv, t = dot(e2, q) * inv;
  return u >= -EDGE_TOL && v >= -EDGE_TOL && u + v <= 1 + EDGE_TOL && t > T_MIN ? t : NaN;
}

export class ErrorMetric {
  constructor(scene, heights) {
    const n = scene.coarse, m = n + 1;
    this.n = n;
    this.origin = scene.origin;
    this.step = [scene.spacing, scene.spacing_y];
    this.relief = scene.relief || 0;
    this.tol = TOLERANCE[scene.visibility] ?? TOLERANCE.full;
    const vertex = (i, j) => [scene.origin[0] + j * scene.spacing, scene.origin[1] + i * scene.spacing_y, heights[i * m + j]];
    this.tris = [];  // square (i, j) at 2 (i n + j) and +1: [p0, e1, e2], split nw-se as gl.js
    this.zRange = [];  // square (i, j) at i n + j: [lowest, highest corner]
    for (let i = 0; i < n; i++) for (let j = 0; j < n; j++) {
      const a = vertex(i, j), b = vertex(i, j + 1), c = vertex(i + 1, j), d = vertex(i + 1, j + 1);
      this.tris.push([c, sub(a, c), sub(b, c)], [c, sub(b, c), sub(d, c)]);
      this.zRange.push([Math.min(a[2], b[2], c[2], d[2]), Math.max(a[2], b[2], c[2], d[2])]);
    }
    this.centres = [];  // [C, i, j, F]: F on the diagonal from (i+1, j) to (i, j+1)
    const stride = Math.ceil(n * n / MAX_CENTRES);  // evenly, row-major
    for (let k = 0; k < n * n; k += stride) {
      const i = Math.floor(k / n), j = k % n;
      const h = 0.25 * (heights[i * m + j] + heights[i * m + j + 1] + heights[(i + 1) * m + j] + heights[(i + 1) * m + j + 1]);
      const x = scene.origin[0] + (j + 0.5) * scene.spacing, y = scene.origin[1] + (i + 0.5) * scene.spacing_y;
      const f = 0.5 * (heights[(i + 1) * m + j] + heights[i * m + j + 1]);
      this.centres.push([[x, y, h + this.relief], i, j, [x, y, f]]);
    }
    this.last = null;  // {eye, cPrime (C' or null: a miss), hidden (F hidden from eye)}
  }

  // t nearest 1 (`first`: the smallest t) of the ray eye + t d against the triangles of
  // square (i, j), given the best so far; squares outside the grid have none.
  nearest(eye, d, i, j, best, first = false) {
    if (i < 0 || j < 0 || i >= this.n || j >= this.n) return best;
    for (let s = 0; s < 2; s++) {
      const [p0, e1, e2] = this.tris[2 * (i * this.n + j) + s];
      const t = hit(eye, d, p0, e1, e2);
      if (!Number.isNaN(t) && (Number.isNaN(best) || (first ? t < best : Math.abs(t - 1) < Math.abs(best - 1)))) best = t;
    }
    return best;
  }

  // The squares the ray's ground track crosses inside the terrain (t > 0): t nearest 1
  // (`first`: the smallest t).
  alongTrack(eye, d, first = false) {
    const n = this.n, lo = this.origin, hi = [lo[0] + n * this.step[0], lo[1] + n * this.step[1]];
    let a = 0, b = Infinity;
    const big = Math.max(Math.abs(d[0]), Math.abs(d[1]), Math.abs(d[2]));
    for (let k = 0; k < 2; k++) {
      if (Math.abs(d[k]) <= 1e-12 * big) {
        if (eye[k] < lo[k] || eye[k] > hi[k]) return NaN;
        continue;
      }
      const t0 = (lo[k] - eye[k]) / d[k], t1 = (hi[k] - eye[k]) / d[k];
      a = Math.max(a, Math.min(t0, t1)); b = Math.min(b, Math.max(t0, t1));
    }
    if (!(b > a) || !Number.isFinite(b)) return NaN;
    const ts = [a, b];
    for (let k = 0; k < 2; k++) {
      if (Math.abs(d[k]) <= 1e-12 * big) continue;
      for (let l = 0; l <= n; l++) {
        const t = (lo[k] + l * this.step[k] - eye[k]) / d[k];
        if (t > a && t < b) ts.push(t);
      }
    }
    ts.sort((x, y) => x - y);
    let best = NaN;
    for (let k = 0; k + 1 < ts.length; k++) {
      const t = 0.5 * (ts[k] + ts[k + 1]);
      const j = Math.min(n - 1, Math.max(0, Math.floor((eye[0] + t * d[0] - lo[0]) / this.step[0])));
      const i = Math.min(n - 1, Math.max(0, Math.floor((eye[1] + t * d[1] - lo[1]) / this.step[1])));
      // only a square whose height range the ray's stretch over it meets can be hit
      const [zlo, zhi] = this.zRange[i * n + j], tol = 1e-9 * (1 + Math.abs(zhi));
      const z0 = eye[2] + d[2] * ts[k], z1 = eye[2] + d[2] * ts[k + 1];
      if (Math.max(z0, z1) < zlo - tol || Math.min(z0, z1) > zhi + tol) continue;
      best = this.nearest(eye, d, i, j, best, first);
    }
    return best;
  }

  // Whether the coarse level hides centre k's F from `eye`: the ray meets it first nearer
  // than F by more than the tolerance, relative.
  hides(eye, k) {
    const t = this.alongTrack(eye, sub(this.centres[k][3], eye), true);
    return !Number.isNaN(t) && t * (1 + this.tol) < 1;
  }

  // C' of every centre for the keyframe eye `keyEye`, and whether its F is hidden from it
  // (the last eye's are kept): {eye, cPrime, hidden}.
  reproject(keyEye) {
    const last = this.last;
    if (last && last.eye[0] === keyEye[0] && last.eye[1] === keyEye[1] && last.eye[2] === keyEye[2]) return last;
    const hidden = this.centres.map((_, k) => this.hides(keyEye, k));
    const cPrime = this.centres.map(([c, i, j]) => {
      const d = sub(c, keyEye);
      let best = NaN;
      for (let di = -1; di <= 1; di++) for (let dj = -1; dj <= 1; dj++) best = this.nearest(keyEye, d, i + di, j + dj, best);
      if (Number.isNaN(best)) best = this.alongTrack(keyEye, d);
      return Number.isNaN(best) ? null : add(keyEye, scale(d, best));
    });
    this.last = { eye: [...keyEye], cPrime, hidden };
    return this.last;
  }

  // Error in pixels of the keyframe seen from `keyEye` shown at viewpoint `vp` through
  // view-projection `viewProj`, `beta` radians a pixel; `keyViewProj` (optional, row-major):
  // the keyframe's view-projection (its squares outside it count as not seen); Infinity
  // when no centre is in view or no centre in view is a hit.
  errorPx(keyEye, vp, viewProj, beta, keyViewProj = null) {
    const { cPrime, hidden } = this.reproject(keyEye);
    const angle = (p, q) => {
      const a = unit(sub(p, vp.o)), b = unit(sub(q, vp.o));
      return Math.atan2(norm(cross(a, b)), dot(a, b));
    };
    const outside = (m, p) => {
      const q = clip(m, p);
      return q[3] <= 0 || Math.abs(q[0]) > q[3] || Math.abs(q[1]) > q[3] || Math.abs(q[2]) > q[3];
    };
    let sum = 0, hits = 0, misses = 0, worst = 0;
    const shown = [];  // angles C to F of the squares drawn from the fallback, seen here
    for (let k = 0; k < this.centres.length; k++) {
      const [c, , , f] = this.centres[k];
      if (outside(viewProj, c)) continue;
      if (hidden[k] || (keyViewProj && outside(keyViewProj, f))) {  // the keyframe did not see F
        if (!outside(viewProj, f) && !this.hides(vp.o, k)) shown.push(angle(c, f));  // F drawn
        continue;
      }
      if (cPrime[k] === null) { misses++; continue; }  // the keyframe maps C nowhere
      const theta = angle(c, cPrime[k]);
      sum += theta * theta; hits++; worst = Math.max(worst, theta);
    }
    if (!hits) return Infinity;
    // a miss counts as the worst hit (lodsprite.sprite.metric.miss_floor), a square drawn
    // from the fallback as the worst hit or its own angle
    for (const u of shown) sum += Math.max(u, worst) ** 2;
    return Math.sqrt((sum + misses * worst * worst) / (hits + misses + shown.length)) / beta;
  }
}

const MAX_AHEAD_S = 1;  // look at most this far ahead (s): a line strays from a curve
const LOST_S = 5;  // a request unanswered this long (seconds) is given up
const SMOOTHING = 0.3;  // weight of a new latency in its exponential mean

function orthonormal(x, y) {  // axes from approximate x, y (Gram-Schmidt; z = x cross y)
  const ux = unit(x);
  const uy = unit(sub(y, scale(ux, dot(y, ux))));
  return { x: ux, y: uy, z: cross(ux, uy) };
}

export class Predictor {
  constructor(epsilon, fovDeg, aspect, near, far, heightPx, jobs = 1) {
    this.epsilon = epsilon;
    this.proj = perspective(fovDeg, aspect, near, far);
    this.beta = (fovDeg * Math.PI / 180) / heightPx;
    this.samples = [];   // [t seconds, viewpoint], the last two
    this.latency = 0.1;  // seconds, measured (an exponential mean of request -> keyframe)
    this.jobs = Number.isInteger(jobs) && jobs >= 1 && jobs <= 16 ? jobs : 1;  // in flight at most
    this.inflight = [];  // {t, vp, seq}: the requests unanswered, oldest first
    this.settled = false;
  }
  sample(t, vp) { this.samples.push([t, vp]); if (this.samples.length > 2) this.samples.shift(); }
  // The viewpoint extrapolated to time t (seconds).
  predict(t) {
    const s = this.samples;
    if (s.length < 2 || s[1][0] <= s[0][0]) return s[s.length - 1][1];
    const [[t0, a], [t1, b]] = s, f = (t - t1) / (t1 - t0);
    const lerp = (p, q) => add(q, scale(sub(q, p), f));
    return { ...orthonormal(lerp(a.x, b.x), lerp(a.y, b.y)), o: lerp(a.o, b.o) };
  }
  // Seconds ahead a request looks: the measured latency, at most MAX_AHEAD_S.
  lead() { return Math.min(this.latency, MAX_AHEAD_S); }
  viewProj(vp) { return mul(this.proj, viewMatrix(vp)); }
  // `keyViewProj` (optional): the shown keyframe's view-projection, mul(header.proj,
  // header.view) of its keyframe message (ErrorMetric.errorPx); `deficit`: what the
  // keyframe lacks (its header's deficit_px), added to the estimate as the window adds it.
  errorPx(metric, keyEye, vp, keyViewProj = null, deficit = 0) {
    return keyEye ? metric.errorPx(keyEye, vp, this.viewProj(vp), this.beta, keyViewProj) + deficit : Infinity;
  }
  // What to request now (a viewpoint) or null; `keyEye`: the shown keyframe's eye
  // (`keyViewProj`, `deficit`: as errorPx).  At rest a keyframe that lacks something is
  // asked for again (one request in flight at a time) until it lacks nothing.
  // `keyDir`: the shown keyframe's view axis (its viewpoint's z): at rest the view is the
  // keyframe's only where both eye and axis are (a still eye turned is another view).
  want(metric, keyEye, t, resting, keyViewProj = null, deficit = 0, keyDir = null) {
    this.inflight = this.inflight.filter((r) => t - r.t <= LOST_S);  // lost: given up
    // moving (even while a keyframe is in flight): the view at rest is asked for anew
    if (!resting) this.settled = false;
    const n = this.inflight.length;
    if (n >= this.jobs || (resting && n)) return null;
    const now = this.samples[this.samples.length - 1][1];
    if (resting) {
      const same = keyEye && norm(sub(keyEye, now.o)) === 0 && (!keyDir || norm(sub(keyDir, now.z)) === 0);
      if (deficit <= 0 && (this.settled || same)) return null;
      this.settled = true;
      return now;
    }
    if (n && t - this.inflight[n - 1].t < this.lead() / this.jobs) return null;  // staggered
    const ahead = this.predict(t + this.lead());
    return this.errorPx(metric, keyEye, ahead, keyViewProj, deficit) >= 0.5 * this.epsilon ? ahead : null;
  }
  // A request went out at t for vp; returns its entry (set its `seq` to match a failure).
  sent(t, vp) { const r = { t, vp, seq: null }; this.inflight.push(r); return r; }
  // The request whose message was `seq` failed: no longer in flight.
  failed(seq) { this.inflight = this.inflight.filter((r) => r.seq !== seq); }
  // The keyframe requested at t0 came after a newer one and is not shown: no longer in
  // flight, its latency not counted.
  dropped(t0) { this.inflight = this.inflight.filter((r) => r.t !== t0); }
  arrived(t0, now) {
    const i = this.inflight.findIndex((r) => r.t === t0);
    if (i >= 0) {
      this.latency += SMOOTHING * (Math.max(0, now - t0) - this.latency);
      this.inflight.splice(i, 1);
    }
  }
}
