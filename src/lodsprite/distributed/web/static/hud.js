// The heads-up display: frames per second, frame time, keyframes shown, the shown
// keyframe's error in pixels, the keyframe scale and why, the keyframe latency (request
// sent -> keyframe shown), and the point under the cursor in the dataset's coordinates
// with the vertical exaggeration (a line the page makes, `more()`).

export class Hud {
  constructor(el) { this.el = el; this.last = 0; }
  // Update at most four times a second from stats() (see main.js), called only then.
  update(now, stats, state, keyScaleWhy = null, more = null) {
    if (now - this.last < 250) return;
    this.last = now;
    const s = stats();
    const f = (x, d = 1) => (x === null || x === undefined || !Number.isFinite(x) ? '–' : x.toFixed(d));
    const fps = s.median_ms ? 1000 / s.median_ms : null;
    this.el.textContent = [
      `${f(fps, 0)} fps   frame ${f(s.median_ms)} ms (p99 ${f(s.p99_ms)})`,
      `keyframes ${s.keyframes} at ${f(s.key_scale)}x (${keyScaleWhy || '–'})   error ${f(s.error_px, 2)} px   latency ${f(s.latency_ms, 0)} ms`,
      state,
      ...(more ? [more()] : []),
    ].join('\n');
  }
}
