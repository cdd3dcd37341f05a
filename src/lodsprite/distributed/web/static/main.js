// The lodsprite web page (Swan et al. 2002's LOD client in a browser): it loads the coarse
// level and the terrain texture from `lodsprite serve --web`, draws a spriteframe every
// display frame from the last keyframe (gl.js), asks the server for keyframes ahead of the
// viewer (predictor.js), flies with the keyboard, mouse and touch (camera.js) or plays a
// camera path the server computes, and shows a HUD (hud.js).
//
// Query string: token (required), terrain (a name as a ZeroMQ client gives it; default
// jacksboro), path (a built-in path: chen1999, swan2002, flyover..., played one viewpoint
// a frame, then held), frames (the path's viewpoints), size (WxH keyframe and canvas
// pixels; 512x512), grid (working grid), and the technique options the server declares
// at /options.json (lod: coarse quads a side, epsilon: pixels, visibility: the load's
// rule, coarse or fragment/triangle: the full z-buffer), each parsed and checked by its
// declaration: a bad one stops the page with the option's one-line error.  For tests and tools: window.lodsprite.ready (a Promise: scene loaded),
// .finished (a Promise: the path played and the held view's keyframe shown), .stats(),
// .pixels(), .viewpoint(), .pathIndex() (path viewpoints drawn so far: the one shown is
// pathIndex() - 1), .serverStats() (a Promise: the `stats` op's reply data),
// .decoded() (keyframes decoded by the decode worker).
//
// Keyframes are decoded by a Web Worker (decode.js: inflate, checks, an ImageBitmap of the
// colour) and uploaded when their decode resolves; a frame only adopts the newest one
// uploaded, so it never waits for a decode or an upload.

import { pack, unpack, image } from './wire.js';
import { SpriteDrawer } from './gl.js';
import { FlyControls, lookAt, norm, sub } from './camera.js';
import { ErrorMetric, Predictor } from './predictor.js';
import { Hud } from './hud.js';

const q = new URLSearchParams(location.search);
const int = (name, fallback) => (q.has(name) ? parseInt(q.get(name), 10) : fallback);
const [width, height] = (q.get('size') || '512x512').split('x').map((s) => parseInt(s, 10));
const opts = {
  token: q.get('token') || '', terrain: q.get('terrain') || 'jacksboro', path: q.get('path'),
  frames: int('frames', undefined), grid: int('grid', undefined),
};

// The query's technique options by their declarations (lodsprite.techniques.Option).
async function pageOptions() {
  const declared = await (await fetch('/options.json')).json();
  const out = {};
  for (const o of declared) {
    if (!q.has(o.name)) { out[o.name] = o.default; continue; }
    const text = q.get(o.name).trim();
    const number = o.type === 'int' || o.type === 'float';
    const v = number ? Number(text) : text;
    const bad = (number && (text === '' || !Number.isFinite(v)))
      || (o.type === 'int' && !Number.isInteger(v))
      || (o.choices.length > 0 && !o.choices.includes(v))
      || (o.min !== null && (o.above ? v <= o.min : v < o.min))
      || (o.max !== null && v > o.max);
    if (bad) throw new Error(`option ${o.name}: got '${text}', allowed: ${o.allowed}`);
    out[o.name] = v;
  }
  return out;
}
const RESTING_MS = 250;   // no input this long: the viewer rests (one exact keyframe)
const VIEWPOINT_MS = 33;  // viewpoint samples to the server at most this often
const KEEP = 2000;        // frame intervals and latencies kept for stats()

const canvas = document.getElementById('view');
canvas.width = width; canvas.height = height;
const hud = new Hud(document.getElementById('hud'));
const stats = { frames: 0, keyframes: 0, intervals: [], latencies: [], error_px: null };
// Input to pixels: a key press's event time to the display frame after the first frame
// drawn from a camera that includes it (the flying camera's; a path ignores keys).
const inputs = { pending: [], drawn: [], ms: [] };
addEventListener('keydown', (e) => {  // a press while a path plays moves nothing: not counted
  if (!e.repeat && !(path && pathIndex < path.length)) inputs.pending.push(e.timeStamp);
});
let state = 'connecting';
let seq = 0;
const waiting = new Map();  // control seq -> resolve
let sceneResolve;
const sceneArrived = new Promise((r) => { sceneResolve = r; });
let pendingKey = null;  // the newest keyframe uploaded, not yet drawn: {header, key}
let keyframesIn = 0, newestDecoded = 0, decoded = 0;
const keyframeHeaders = new Map();  // decode id -> header
const decoder = new Worker(new URL('./decode.js', import.meta.url), { type: 'module' });
decoder.onmessage = ({ data }) => {
  const header = keyframeHeaders.get(data.id);
  keyframeHeaders.delete(data.id);
  if (data.error) { state = `bad keyframe: ${data.error}`; return; }
  decoded += 1;
  if (!renderer || !header || data.id < newestDecoded) { data.bitmap.close(); return; }  // older than one uploaded
  newestDecoded = data.id;
  const key = renderer.prepareKeyframe(header, data.bitmap, data.depth);
  if (pendingKey) renderer.dropKeyframe(pendingKey.key);  // superseded before a frame drew it
  pendingKey = { header, key };
};
decoder.onerror = (e) => { state = `keyframe decoder: ${e.message}`; };

function percentile(values, p) {
  if (!values.length) return null;
  const s = [...values].sort((a, b) => a - b);
  return s[Math.min(s.length - 1, Math.floor(p * (s.length - 1) + 0.5))];
}
function keep(list, x) { list.push(x); if (list.length > KEEP) list.shift(); }

const ws = new WebSocket(`${location.protocol === 'https:' ? 'wss' : 'ws'}://${location.host}/ws?token=${encodeURIComponent(opts.token)}`);
ws.binaryType = 'arraybuffer';
const send = (header) => { seq += 1; ws.send(pack({ seq, ...header })); return seq; };
const call = (op, args = {}) => new Promise((resolve) => { waiting.set(send({ kind: 'control', op, args }), resolve); });

ws.onmessage = async (event) => {
  let msg;
  try { msg = unpack(event.data); } catch (e) { state = `bad message: ${e.message}`; return; }
  const { header, buffers } = msg;
  if (header.kind === 'reply') {
    const resolve = waiting.get(header.seq);
    if (resolve) { waiting.delete(header.seq); resolve(header); return; }
    if (!header.ok) { state = header.error; predictor?.failed(header.seq); }
  } else if (header.kind === 'scene') {
    const [heights, texture] = await Promise.all([image(header.heights, buffers[0]), image(header.texture, buffers[1])]);
    sceneResolve({ header, heights, texture });
  } else if (header.kind === 'keyframe') {
    keyframesIn += 1;
    keyframeHeaders.set(keyframesIn, header);
    decoder.postMessage({ id: keyframesIn, header, color: buffers[0], depth: buffers[1] }, [event.data]);
  }
};
ws.onclose = () => { state = 'disconnected'; };

let renderer, metric, predictor, controls, path = null, pathIndex = 0;
let keyEye = null, finishedResolve, lastFrame = null, lastSample = -Infinity;
const finished = new Promise((r) => { finishedResolve = r; });

async function start() {
  const opened = new Promise((resolve, reject) => { ws.onopen = resolve; ws.onerror = () => reject(new Error('no WebSocket')); });
  const page = await pageOptions();
  await opened;
  const args = {
    terrain: opts.terrain, size: [width, height], lod: page.lod, epsilon: page.epsilon, grid: opts.grid,
    visibility: page.visibility,
  };
  const reply = await call('load', args);
  if (!reply.ok) throw new Error(reply.error);
  const scene = await sceneArrived;
  const h = scene.header;
  renderer = new SpriteDrawer(canvas);
  renderer.setScene(h, scene.heights, scene.texture);
  metric = new ErrorMetric(h, scene.heights);
  predictor = new Predictor(h.epsilon, h.fov, width / height, h.near, h.far, height);
  predictor.failed = (s) => { if (predictor.inflight && predictor.inflight.seq === s) predictor.inflight = null; };
  const extent = h.coarse * h.spacing;
  const centre = [h.origin[0] + extent / 2, h.origin[1] + extent / 2, 0];
  controls = new FlyControls(canvas, lookAt([centre[0], centre[1] - 1.2 * extent, 0.6 * extent], centre), 0.25 * extent);
  if (opts.path) {
    const p = await call('path', { spec: opts.path, frames: opts.frames });
    if (!p.ok) throw new Error(p.error);
    path = p.data.viewpoints.map((r) => ({ x: r.slice(0, 3), y: r.slice(3, 6), z: r.slice(6, 9), o: r.slice(9, 12) }));
  }
  state = path ? `playing ${opts.path}` : 'flying';
  requestAnimationFrame(frame);
}

function adopt(now) {
  const { header, key } = pendingKey;
  pendingKey = null;
  renderer.useKeyframe(key);
  keyEye = header.viewpoint.o;
  stats.keyframes += 1;
  keep(stats.latencies, now - 1000 * header.t0);
  predictor.arrived(header.t0, now / 1000);
}

function frame(now) {
  const dt = lastFrame === null ? 0 : (now - lastFrame) / 1000;
  if (lastFrame !== null) keep(stats.intervals, now - lastFrame);
  lastFrame = now;
  for (const t of inputs.drawn) keep(inputs.ms, now - t);  // the drawn frame presented
  inputs.drawn = [];
  let vp, resting;
  if (path && pathIndex < path.length) {
    vp = path[pathIndex++];
    resting = pathIndex === path.length;
    if (resting) { controls.set(vp); state = 'path played: holding'; }
  } else {
    vp = controls.step(dt);
    resting = now - controls.moved > RESTING_MS;
    [inputs.drawn, inputs.pending] = [inputs.pending, []];  // this frame's camera has them
  }
  predictor.sample(now / 1000, vp);
  if (pendingKey) adopt(now);
  const want = predictor.want(metric, keyEye, now / 1000, resting);
  if (want) {
    const t = now / 1000;
    const s = send({ kind: 'request', t, viewpoint: want });
    predictor.sent(t, want); predictor.inflight.seq = s;
  } else if (now - lastSample > VIEWPOINT_MS) {
    lastSample = now;
    const shown = keyEye ? { eye: keyEye, slot: 0 } : undefined;  // as the ZeroMQ client
    send({ kind: 'viewpoint', t: now / 1000, viewpoint: vp, shown });
  }
  renderer.draw(predictor.viewProj(vp));
  stats.error_px = predictor.errorPx(metric, keyEye, vp);
  stats.frames += 1;
  if (path && pathIndex === path.length && keyEye && norm(sub(keyEye, vp.o)) <= 1e-6 * (1 + norm(vp.o))) {
    finishedResolve(stats.frames);
  }
  hud.update(now, api.stats, state);
  requestAnimationFrame(frame);
}

const api = {
  stats() {
    const lat = percentile(stats.latencies, 0.5);
    return {
      frames: stats.frames, keyframes: stats.keyframes,
      median_ms: percentile(stats.intervals, 0.5), p99_ms: percentile(stats.intervals, 0.99),
      error_px: Number.isFinite(stats.error_px) ? stats.error_px : null, latency_ms: lat,
      input_ms: percentile(inputs.ms, 0.5), input_ms_p99: percentile(inputs.ms, 0.99),
      inputs: inputs.ms.length,
    };
  },
  pixels: () => renderer.pixels(),
  viewpoint: () => controls && controls.vp,
  pathIndex: () => pathIndex,
  state: () => state,
  serverStats: () => call('stats').then((r) => r.data),
  decoded: () => decoded,
  finished,
};
api.ready = start().then(() => true, (e) => { state = `failed: ${e.message}`; hud.update(Infinity, api.stats, state); throw e; });
window.lodsprite = api;
