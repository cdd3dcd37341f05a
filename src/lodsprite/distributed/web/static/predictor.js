// Keyframe requests ahead of the viewer (Swan et al. 2002 §3.3: the server renders
// keyframes at predicted viewpoints) and the spriteframe error (Chen, Swan & Kaufman 1999,
// §3.2, Eq. 1-2: theta at the current eye between a square's centre C and the point C'
// the keyframe maps its colour to; error = sqrt(mean theta^2) / beta pixels).
//
// The page holds only the coarse level, so C is estimated: each coarse square's centre
// at the mean of its corners, raised by the scene's `relief` (the RMS height of the
// full-resolution centres off the coarse surface, computed by the server), and C' is
// where the keyframe eye's ray through C meets the horizontal plane through the square's
// centre (in front of the keyframe eye; otherwise a miss, counted as the worst hit, as
// lodsprite.sprite.metric does).  At the keyframe's own eye the error is 0, as in the
// paper; it grows with the parallax the coarse level cannot show.
//
// The linear predictor: the eye and the axes extrapolated linearly from the last two
// samples (the axes re-orthonormalised).  A request goes out for the viewpoint the viewer
// will be at one measured keyframe latency ahead (at most 1 s), when the shown keyframe's
// error there reaches epsilon/2, and never with a request in flight; when the viewer rests, one more
// request at the resting viewpoint makes the shown keyframe exact.

import { add, clip, cross, dot, mul, norm, scale, sub, unit, viewMatrix, perspective } from './camera.js';

const MAX_CENTRES = 4096;  // square centres measured a frame (a finer coarse level: evenly)

export class ErrorMetric {
  constructor(scene, heights) {
    const n = scene.coarse, m = n + 1;
    this.centres = [];
    for (let i = 0; i < n; i++) for (let j = 0; j < n; j++) {
      const h = 0.25 * (heights[i * m + j] + heights[i * m + j + 1] + heights[(i + 1) * m + j] + heights[(i + 1) * m + j + 1]);
      this.centres.push([scene.origin[0] + (j + 0.5) * scene.spacing, scene.origin[1] + (i + 0.5) * scene.spacing_y, h]);
    }
    this.relief = scene.relief || 0;
    const stride = Math.ceil(this.centres.length / MAX_CENTRES);  // evenly, row-major
    if (stride > 1) this.centres = this.centres.filter((_, k) => k % stride === 0);
  }

  // Error in pixels of the keyframe seen from `keyEye` shown at viewpoint `vp` through
  // view-projection `viewProj`, `beta` radians a pixel; Infinity when no centre is in view.
  errorPx(keyEye, vp, viewProj, beta) {
    let sum = 0, hits = 0, misses = 0, worst = 0;
    for (const base of this.centres) {
      const c = [base[0], base[1], base[2] + this.relief];
      const k = clip(viewProj, c);
      if (k[3] <= 0 || Math.abs(k[0]) > k[3] || Math.abs(k[1]) > k[3] || Math.abs(k[2]) > k[3]) continue;
      const ray = sub(c, keyEye);
      const s = Math.abs(ray[2]) > 1e-9 * norm(ray) ? (base[2] - keyEye[2]) / ray[2] : (this.relief ? -1 : 1);
      if (!(s > 0)) { misses++; continue; }  // C' behind the keyframe eye: never seen
      const a = unit(sub(c, vp.o)), b = unit(sub(add(keyEye, scale(ray, s)), vp.o));
      const theta = Math.atan2(norm(cross(a, b)), dot(a, b));
      sum += theta * theta; hits++; worst = Math.max(worst, theta);
    }
    // a miss counts as the worst hit (lodsprite.sprite.metric.miss_floor); none: due
    return hits ? Math.sqrt((sum + misses * worst * worst) / (hits + misses)) / beta : Infinity;
  }
}

const MAX_AHEAD_S = 1;  // look at most this far ahead (s): a line strays from a curve
const LOST_S = 5;  // a request unanswered this long (seconds) is given up

function orthonormal(x, y) {  // axes from approximate x, y (Gram-Schmidt; z = x cross y)
  const ux = unit(x);
  const uy = unit(sub(y, scale(ux, dot(y, ux))));
  return { x: ux, y: uy, z: cross(ux, uy) };
}

export class Predictor {
  constructor(epsilon, fovDeg, aspect, near, far, heightPx) {
    this.epsilon = epsilon;
    this.proj = perspective(fovDeg, aspect, near, far);
    this.beta = (fovDeg * Math.PI / 180) / heightPx;
    this.samples = [];   // [t seconds, viewpoint], the last two
    this.latency = 0.1;  // seconds, measured (an exponential mean of request -> keyframe)
    this.inflight = null;
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
  viewProj(vp) { return mul(this.proj, viewMatrix(vp)); }
  errorPx(metric, keyEye, vp) { return keyEye ? metric.errorPx(keyEye, vp, this.viewProj(vp), this.beta) : Infinity; }
  // What to request now (a viewpoint) or null; `keyEye`: the shown keyframe's eye.
  want(metric, keyEye, t, resting) {
    if (this.inflight && t - this.inflight.t > LOST_S) this.inflight = null;  // lost
    if (this.inflight) return null;
    const now = this.samples[this.samples.length - 1][1];
    if (resting) {
      if (this.settled || (keyEye && norm(sub(keyEye, now.o)) === 0)) return null;
      this.settled = true;
      return now;
    }
    this.settled = false;
    const ahead = this.predict(t + Math.min(this.latency, MAX_AHEAD_S));
    return this.errorPx(metric, keyEye, ahead) >= 0.5 * this.epsilon ? ahead : null;
  }
  sent(t, vp) { this.inflight = { t, vp }; }
  arrived(t0, now) {
    if (this.inflight && this.inflight.t === t0) {
      this.latency = 0.7 * this.latency + 0.3 * Math.max(0, now - t0);
      this.inflight = null;
    }
  }
}
