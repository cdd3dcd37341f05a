// Camera math as lodsprite.camera (row-major 4x4 matrices, OpenGL conventions: the camera
// looks along -z, NDC depth in [-1, 1]) and the fly controls: keyboard (WASD / arrows
// move and turn, Q/E or PageUp/PageDown climb), mouse drag to look, wheel to move along
// the view, one-finger drag to look and two-finger pinch to move on touch screens.

export const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
export const add = (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
export const scale = (a, s) => [a[0] * s, a[1] * s, a[2] * s];
export const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
export const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
export const norm = (a) => Math.hypot(a[0], a[1], a[2]);
export const unit = (a) => scale(a, 1 / (norm(a) || 1));

// A viewpoint {x, y, z, o}: camera axes and eye (metres), as the wire's WireViewpoint.
export function viewMatrix(vp) {
  const { x, y, z, o } = vp;
  return [x[0], x[1], x[2], -dot(x, o), y[0], y[1], y[2], -dot(y, o),
    z[0], z[1], z[2], -dot(z, o), 0, 0, 0, 1];
}

export function perspective(fovYDeg, aspect, near, far) {
  const f = 1 / Math.tan((fovYDeg * Math.PI) / 360);
  return [f / aspect, 0, 0, 0, 0, f, 0, 0,
    0, 0, (far + near) / (near - far), (2 * far * near) / (near - far), 0, 0, -1, 0];
}

export function mul(a, b) {  // row-major a @ b
  const m = new Array(16).fill(0);
  for (let r = 0; r < 4; r++) for (let c = 0; c < 4; c++) {
    let s = 0;
    for (let k = 0; k < 4; k++) s += a[4 * r + k] * b[4 * k + c];
    m[4 * r + c] = s;
  }
  return m;
}

export function clip(m, p) {  // row-major m @ (p, 1)
  return [0, 1, 2, 3].map((r) => m[4 * r] * p[0] + m[4 * r + 1] * p[1] + m[4 * r + 2] * p[2] + m[4 * r + 3]);
}

// Orthonormal axes from a view direction and an up hint (x = up x z, y = z x x).
export function lookAlong(eye, forward, up = [0, 0, 1]) {
  const z = unit(scale(forward, -1));
  let x = cross(up, z);
  if (norm(x) < 1e-9) x = cross([0, 1, 0], z);
  x = unit(x);
  return { x, y: cross(z, x), z, o: [...eye] };
}

export function lookAt(eye, target) { return lookAlong(eye, sub(target, eye)); }

// Fly controls over a viewpoint; `speed` in metres per second, the user's input marks the
// time of the last change (`moved`).  Keys are read on `keyTarget` (the window on the
// page; the canvas in a notebook, so that typing in a cell flies nothing); detach()
// removes every listener.
export class FlyControls {
  constructor(canvas, viewpoint, speed, keyTarget = window) {
    this.listening = new AbortController();
    const on = { signal: this.listening.signal };
    this.vp = viewpoint; this.speed = speed; this.keys = new Set(); this.moved = -Infinity;
    this.yawRate = 1.2;  // radians per second with the arrow keys
    const dirs = this._angles();
    this.yaw = dirs.yaw; this.pitch = dirs.pitch;
    keyTarget.addEventListener('keydown', (e) => { this.keys.add(e.key.toLowerCase()); }, on);
    keyTarget.addEventListener('keyup', (e) => { this.keys.delete(e.key.toLowerCase()); }, on);
    keyTarget.addEventListener('blur', () => { this.keys.clear(); }, on);
    let drag = null;
    canvas.addEventListener('pointerdown', (e) => { if (e.pointerType === 'mouse') drag = [e.clientX, e.clientY]; }, on);
    addEventListener('pointerup', () => { drag = null; }, on);
    addEventListener('pointermove', (e) => {
      if (!drag) return;
      this.turn((e.clientX - drag[0]) * -0.005, (e.clientY - drag[1]) * -0.005);
      drag = [e.clientX, e.clientY];
    }, on);
    canvas.addEventListener('wheel', (e) => { e.preventDefault(); this.forward(-e.deltaY * this.speed * 0.002); }, { passive: false, ...on });
    this._touches(canvas, on);
  }
  detach() { this.listening.abort(); this.keys.clear(); }
  _angles() {
    const f = scale(this.vp.z, -1);
    return { yaw: Math.atan2(f[1], f[0]), pitch: Math.asin(Math.max(-1, Math.min(1, f[2]))) };
  }
  _touches(canvas, on) {
    let last = null;
    const read = (e) => [...e.touches].map((t) => [t.clientX, t.clientY]);
    canvas.addEventListener('touchstart', (e) => { e.preventDefault(); last = read(e); }, { passive: false, ...on });
    canvas.addEventListener('touchmove', (e) => {
      e.preventDefault();
      const now = read(e);
      if (last && now.length === 1 && last.length === 1) {
        this.turn((now[0][0] - last[0][0]) * -0.005, (now[0][1] - last[0][1]) * -0.005);
      } else if (last && now.length === 2 && last.length === 2) {
        const d = (p) => Math.hypot(p[0][0] - p[1][0], p[0][1] - p[1][1]);
        this.forward((d(now) - d(last)) * this.speed * 0.004);
      }
      last = now;
    }, { passive: false, ...on });
    canvas.addEventListener('touchend', (e) => { last = read(e); }, on);
  }
  turn(dYaw, dPitch) {
    this.yaw += dYaw;
    this.pitch = Math.max(-1.5, Math.min(1.5, this.pitch + dPitch));
    const f = [Math.cos(this.pitch) * Math.cos(this.yaw), Math.cos(this.pitch) * Math.sin(this.yaw), Math.sin(this.pitch)];
    this.vp = lookAlong(this.vp.o, f);
    this.moved = performance.now();
  }
  forward(d) { this.vp = { ...this.vp, o: add(this.vp.o, scale(this.vp.z, -d)) }; this.moved = performance.now(); }
  // Apply the held keys over dt seconds; the (possibly new) viewpoint.
  step(dt) {
    const k = this.keys, s = this.speed * dt;
    const has = (...names) => names.some((n) => k.has(n));
    if (has('w')) this.forward(s);
    if (has('s')) this.forward(-s);
    if (has('arrowup')) this.turn(0, this.yawRate * dt);
    if (has('arrowdown')) this.turn(0, -this.yawRate * dt);
    if (has('arrowleft')) this.turn(this.yawRate * dt, 0);
    if (has('arrowright')) this.turn(-this.yawRate * dt, 0);
    const side = (has('d') ? 1 : 0) - (has('a') ? 1 : 0);
    const up = (has('e', 'pageup') ? 1 : 0) - (has('q', 'pagedown') ? 1 : 0);
    if (side || up) {
      this.vp = { ...this.vp, o: add(this.vp.o, add(scale(this.vp.x, side * s), [0, 0, up * s])) };
      this.moved = performance.now();
    }
    return this.vp;
  }
  set(vp) { this.vp = vp; const a = this._angles(); this.yaw = a.yaw; this.pitch = a.pitch; }
}
