// The lodsprite client (Swan et al. 2002's LOD client in a browser), whatever carries its
// messages: it loads the coarse level and the terrain texture from the server, draws a
// spriteframe every display frame from the last keyframe (gl.js), asks for keyframes
// ahead of the viewer (predictor.js), flies with the keyboard, mouse and touch
// (camera.js) or plays a camera path the server computes, and shows a HUD (hud.js).
// The web page (main.js) carries its messages over a WebSocket, the notebook widget
// (lodsprite.widget) over the widget's own messages; both are this module.
//
// startApp({canvas, hud, transport, options, decoderUrl, keyTarget}) -> the client's API:
//   transport: {opened: Promise, send(Uint8Array), onmessage(handler(ArrayBuffer)),
//               onclose(handler())}: one web message (wire.js) each way a call;
//   options: {terrain, size: [w, h], lod, epsilon, visibility, proxy, pair, grid, path, frames,
//   keyscale ('auto' or 1, 1.5, 2: gl.js chooseKeyScale)}, and
//   moreOptions (a Promise of more, merged before the load; a rejection fails `ready`);
//   decoderUrl: decode.js's URL (a module Web Worker); keyTarget: the element whose key
//   presses fly the camera (default: the window).
// The API (for tests, tools and the widget): ready (a Promise: scene loaded), finished()
// (a Promise: the path played and the held view's keyframe shown), stats(), pixels(),
// viewpoint(), keyViewpoint() (the shown keyframe's, null before the first), pathIndex() (path viewpoints drawn so far: the one shown is pathIndex() - 1),
// keyScale() ({scale, why}: the keyframe scale asked for and why; stats() has its number:
// stats() holds numbers only, what the widget's status message carries),
// setWalkTime(t) (a scene's walkers held at t seconds; null: their clock, seconds since the
// first frame), capture(indices) (keep the canvas's pixels, viewpoint and walkers' time as the frames of those path
// indices are drawn: a readback in the frame, for untimed judged passes only), captured()
// (those kept, {index, vp, t, width, height, rgba}, then forgotten),
// serverStats() (a Promise: the `stats` op's reply data), decoded() (keyframes decoded by
// the decode worker), play(spec, frames) (a Promise: the path's viewpoints arrived and
// play), stop() (hold the view shown), setViewpoint(vp), screenshot() (a Promise: a PNG
// Blob of the canvas), close().
//
// Keyframes are decoded by a Web Worker (decode.js: inflate, checks, an ImageBitmap of the
// colour) and uploaded when their decode resolves; a frame only adopts the newest one
// uploaded, so it never waits for a decode or an upload.

import { pack, unpack, image } from './wire.js';
import { SpriteDrawer, chooseKeyScale, isPrivateHost } from './gl.js';
import { FlyControls, lookAt, mul, norm, sub } from './camera.js';
import { ErrorMetric, Predictor } from './predictor.js';
import { DepthEstimate } from './depth_estimate.js';
import { cursorPoint } from './cursor.js';
import { Hud } from './hud.js';
import { WalkerDrawer, walkerData } from './walkers.js';

const RESTING_MS = 250;   // no input this long: the viewer rests (one exact keyframe)
const VIEWPOINT_MS = 33;  // viewpoint samples to the server at most this often
const KEEP = 2000;        // frame intervals and latencies kept for stats()

export function percentile(values, p) {
  if (!values.length) return null;
  const s = [...values].sort((a, b) => a - b);
  return s[Math.min(s.length - 1, Math.floor(p * (s.length - 1) + 0.5))];
}
function keep(list, x) { list.push(x); if (list.length > KEEP) list.shift(); }

// Viewpoint rows of a `path` reply (12 numbers: axes x, y, z, then the eye o).
export function viewpoints(rows) {
  return rows.map((r) => ({ x: r.slice(0, 3), y: r.slice(3, 6), z: r.slice(6, 9), o: r.slice(9, 12) }));
}

export function startApp({ canvas, hud: hudEl = null, transport, options, moreOptions = null, decoderUrl, keyTarget = window }) {
  const [width, height] = options.size;
  canvas.width = width; canvas.height = height;
  const hud = hudEl ? new Hud(hudEl) : null;
  const stats = { frames: 0, keyframes: 0, intervals: [], latencies: [], error_px: null, errorSum: 0, errorFrames: 0 };
  let loadAt = null, firstKeyMs = null, keyScale = { scale: 1, why: null };  // the load sent; the first keyframe drawn, ms after it
  const firstMs = { scene: null, request: null, arrived: null };  // the way to it: ms after the load
  // Input to pixels: a key press's event time to the display frame after the first frame
  // drawn from a camera that includes it (the flying camera's; a path ignores keys).
  const inputs = { pending: [], drawn: [], ms: [] };
  const playing = () => path && pathIndex < path.length;
  const onKey = (e) => { if (!e.repeat && !playing()) inputs.pending.push(e.timeStamp); };
  keyTarget.addEventListener('keydown', onKey);
  let state = 'connecting', seq = 0, closed = false;
  const waiting = new Map();  // control seq -> resolve
  let sceneResolve;
  const sceneArrived = new Promise((r) => { sceneResolve = r; });
  let pendingKey = null;  // the newest keyframe uploaded, not yet drawn: {header, key}
  let keyframesIn = 0, newestDecoded = 0, newestT0 = -Infinity, decoded = 0, shownKeyId = 0;
  const keyframeHeaders = new Map();  // decode id -> header
  const decoder = new Worker(decoderUrl, { type: 'module' });
  decoder.onmessage = ({ data }) => {
    if (data.estimateError) {  // the keyframe stands; its error stays the coarse level's
      console.warn(`keyframe estimate: ${data.estimateError}`);
      return;
    }
    if (data.estimate) {  // a keyframe's estimate, after it: its own, pending or shown, else dropped
      if (pendingKey && pendingKey.id === data.id) pendingKey.estimate = data.estimate;
      else if (shownKeyId === data.id) metric = depthMetric(new DepthEstimate(data.estimate));
      return;
    }
    const header = keyframeHeaders.get(data.id);
    keyframeHeaders.delete(data.id);
    if (data.error) { state = `bad keyframe: ${data.error}`; return; }
    decoded += 1;
    // older than one uploaded: by arrival, or (requests in flight together, renderers of
    // different speeds) by the time it was asked for
    if (closed || !renderer || !header || data.id < newestDecoded || header.t0 < newestT0) {
      if (header) predictor?.dropped(header.t0);
      data.bitmap.close();
      return;
    }
    newestDecoded = data.id; newestT0 = header.t0;
    const key = renderer.prepareKeyframe(header, data.bitmap, data.depth);
    if (pendingKey) {  // superseded before a frame drew it: not shown, no longer in flight
      renderer.dropKeyframe(pendingKey.key);
      predictor?.dropped(pendingKey.header.t0);
    }
    pendingKey = { header, key, id: data.id, estimate: null };
  };
  decoder.onerror = (e) => { state = `keyframe decoder: ${e.message}`; };

  const send = (header) => { seq += 1; transport.send(pack({ seq, ...header })); return seq; };
  const call = (op, args = {}) => new Promise((resolve) => { waiting.set(send({ kind: 'control', op, args }), resolve); });

  transport.onmessage(async (data) => {
    let msg;
    try { msg = unpack(data); } catch (e) { state = `bad message: ${e.message}`; return; }
    const { header, buffers } = msg;
    if (header.kind === 'reply') {
      const resolve = waiting.get(header.seq);
      if (resolve) { waiting.delete(header.seq); resolve(header); return; }
      if (!header.ok) { state = header.error; predictor?.failed(header.seq); }
    } else if (header.kind === 'scene') {
      try {
        const [heights, texture] = await Promise.all([image(header.heights, buffers[0]), image(header.texture, buffers[1])]);
        sceneResolve({ header, heights, texture });
      } catch (e) { state = `bad scene: ${e.message}`; }
    } else if (header.kind === 'keyframe') {
      keyframesIn += 1;
      if (firstMs.arrived === null && loadAt !== null) firstMs.arrived = performance.now() - loadAt;
      keyframeHeaders.set(keyframesIn, header);
      const estimate = renderer && renderer.proxy === 'depth' && header.zbuffer === 'full'
        ? { stride: renderer.stride, keyScale: keyScale.scale } : null;
      decoder.postMessage({ id: keyframesIn, header, color: buffers[0], depth: buffers[1], estimate }, [data]);
    }
  });
  transport.onclose(() => { state = 'disconnected'; });

  let renderer, metric, coarseMetric, predictor, controls, path = null, pathIndex = 0, pathName = null;
  // A keyframe's DepthEstimate as the predictor's metric (its errorPx's arguments).
  const depthMetric = (est) => ({ errorPx: (keyEye, vp, viewProj, beta) => est.errorPx(vp.o, viewProj, beta, width, height) });
  let walkers = null, walkStart = null, walkFixed = null, focal = 1;  // a scene's walkers, their clock (s)
  let sceneHeader = null, cursorPx = null;  // the scene message's header; the cursor on the canvas
  const cursorEvents = new AbortController();  // removed by close()
  canvas.addEventListener('pointermove', (e) => {  // CSS pixels -> the image's pixel (whose
    const r = canvas.getBoundingClientRect();        // centre is +0.5), the image fitted
    const s = Math.min(r.width / width, r.height / height) || 1;  // inside (object-fit: contain)
    cursorPx = [(e.clientX - r.left - 0.5 * (r.width - width * s)) / s - 0.5,
                (e.clientY - r.top - 0.5 * (r.height - height * s)) / s - 0.5];
  }, { signal: cursorEvents.signal });
  canvas.addEventListener('pointerleave', () => { cursorPx = null; }, { signal: cursorEvents.signal });
  // The point under canvas pixel (px, py) from the shown view ({world, e, n, h, crs}: the
  // dataset's coordinates, cursor.js), or null.
  const cursorAt = (px, py) => {
    const vp = shownVp || (controls && controls.vp);
    if (!sceneHeader || !coarseMetric || !vp) return null;
    return cursorPoint(coarseMetric, vp, px, py, width, height, sceneHeader.fov, sceneHeader.georef ?? null, sceneHeader.exaggeration ?? 1);
  };
  // the imagery's licence and attribution, on the HUD whenever the terrain drapes some
  const credit = () => (sceneHeader && sceneHeader.attribution ? `\nimagery ${sceneHeader.attribution}` : '');
  const cursorLine = () => cursorText() + credit();
  const cursorText = () => {
    const ex = sceneHeader ? `exaggeration ${(sceneHeader.exaggeration ?? 1).toFixed(2)}x` : '';
    const c = cursorPx && cursorAt(cursorPx[0], cursorPx[1]);
    if (!c) return ex;
    // decimals to about 0.1 m: 1 for metres or feet, 6 for degrees (any geographic CRS)
    const mpu = sceneHeader.georef ? sceneHeader.georef.metres_per_unit[0] : 1;
    const d = Math.min(9, Math.max(1, Math.ceil(Math.log10(mpu)) + 1));
    const at = c.crs ? `E ${c.e.toFixed(d)} N ${c.n.toFixed(d)} (${c.crs})` : `x ${c.world[0].toFixed(1)} y ${c.world[1].toFixed(1)} m`;
    return `cursor ${at} height ${c.h.toFixed(1)} m   ${ex}`;
  };
  let captures = null, captureSet = null;
  let shownVp = null, keyVp = null, keyEye = null, keyDir = null, keyViewProj = null, keyDeficit = 0, finishedResolve = () => {}, finished = null, lastFrame = null, lastSample = -Infinity;
  const newFinished = () => { finished = new Promise((r) => { finishedResolve = r; }); };
  newFinished();

  async function load() {
    if (moreOptions) Object.assign(options, await moreOptions);
    await transport.opened;
    // the keyframe's own depth as the proxy needs the full z-buffer: the coarse rule's
    // coarse one becomes the fragment rule's (the coarse spriteframe under the mesh)
    const depth = (options.proxy ?? 'depth') === 'depth';
    renderer = new SpriteDrawer(canvas);  // the GL context: its texture limit
    const gl = renderer.gl;
    keyScale = chooseKeyScale(options.keyscale ?? 'auto', width, height,
      gl.getParameter(gl.MAX_TEXTURE_SIZE), globalThis.navigator?.connection?.downlink ?? null,
      isPrivateHost(globalThis.location?.hostname ?? ''));
    const args = {
      terrain: options.terrain, size: [width, height], lod: options.lod, epsilon: options.epsilon,
      grid: options.grid, key_scale: keyScale.scale,
      visibility: depth && options.visibility === 'coarse' ? 'fragment' : options.visibility,
    };
    loadAt = performance.now();
    const reply = await call('load', args);
    if (!reply.ok) throw new Error(reply.error);
    const scene = await sceneArrived;
    firstMs.scene = performance.now() - loadAt;
    const h = scene.header;
    sceneHeader = h;
    renderer.proxy = depth ? 'depth' : 'coarse';
    renderer.pair = depth && options.pair === true;
    renderer.setScene(h, scene.heights, scene.texture);
    if (h.walkers) walkers = new WalkerDrawer(renderer.gl, walkerData(h.walkers));
    focal = height / (2 * Math.tan(h.fov * Math.PI / 360));  // pixels a metre at unit depth
    metric = coarseMetric = new ErrorMetric(h, scene.heights);
    const jobs = reply.data?.jobs;  // the server's renders in flight for this page: 1-16
    predictor = new Predictor(h.epsilon, h.fov, width / height, h.near, h.far, height,
      Number.isInteger(jobs) && jobs >= 1 && jobs <= 16 ? jobs : 1);
    const extent = h.coarse * h.spacing;
    const centre = [h.origin[0] + extent / 2, h.origin[1] + extent / 2, 0];
    controls = new FlyControls(canvas, lookAt([centre[0], centre[1] - 1.2 * extent, 0.6 * extent], centre), 0.25 * extent, keyTarget);
    if (options.path) await play(options.path, options.frames);
    else state = 'flying';
    requestAnimationFrame(frame);
  }

  async function play(spec, frames) {
    const p = await call('path', { spec, frames });
    if (!p.ok) throw new Error(p.error);
    path = viewpoints(p.data.viewpoints);
    pathIndex = 0; pathName = spec;
    newFinished();
    state = `playing ${spec}`;
  }

  function hold(vp) {  // fly from vp on: a path stops where it is
    path = null;
    controls.set(vp);
    controls.moved = performance.now();
    state = 'flying';
  }

  function adopt(now) {
    const { header, key, id, estimate } = pendingKey;
    pendingKey = null;
    renderer.useKeyframe(key);
    shownKeyId = id;
    // the error on this keyframe's own depth (what the depth mesh shows) once the decode
    // worker has built it, the coarse level's until then
    metric = estimate ? depthMetric(new DepthEstimate(estimate)) : coarseMetric;
    keyEye = header.viewpoint.o; keyVp = header.viewpoint;
    keyDir = header.viewpoint.z;
    keyViewProj = mul(header.proj, header.view);  // the estimate's keyframe frustum
    keyDeficit = header.deficit_px || 0;  // what it lacks while the renderer's tiles stream
    stats.keyframes += 1;
    if (firstKeyMs === null && loadAt !== null) firstKeyMs = now - loadAt;
    keep(stats.latencies, now - 1000 * header.t0);
    predictor.arrived(header.t0, now / 1000);
  }

  function frame(now) {
    if (closed) return;
    const dt = lastFrame === null ? 0 : (now - lastFrame) / 1000;
    if (lastFrame !== null) keep(stats.intervals, now - lastFrame);
    lastFrame = now;
    for (const t of inputs.drawn) keep(inputs.ms, now - t);  // the drawn frame presented
    inputs.drawn = [];
    let vp, resting, index = -1;
    if (playing()) {
      index = pathIndex;
      vp = path[pathIndex++];
      resting = pathIndex === path.length;
      if (resting) { controls.set(vp); state = `${pathName} played: holding`; }
    } else {
      vp = controls.step(dt);
      resting = now - controls.moved > RESTING_MS;
      [inputs.drawn, inputs.pending] = [inputs.pending, []];  // this frame's camera has them
    }
    shownVp = vp;
    predictor.sample(now / 1000, vp);
    if (pendingKey) adopt(now);
    const want = predictor.want(metric, keyEye, now / 1000, resting, keyViewProj, keyDeficit, keyDir);
    if (want) {
      const t = now / 1000;
      const s = send({ kind: 'request', t, viewpoint: want });
      if (firstMs.request === null && loadAt !== null) firstMs.request = now - loadAt;
      predictor.sent(t, want).seq = s;
    } else if (now - lastSample > VIEWPOINT_MS) {
      lastSample = now;
      const shown = keyEye ? { eye: keyEye, slot: 0 } : undefined;  // as the ZeroMQ client
      send({ kind: 'viewpoint', t: now / 1000, viewpoint: vp, shown });
    }
    const viewProj = predictor.viewProj(vp);
    renderer.draw(viewProj, vp.o);
    if (walkStart === null) walkStart = now;
    const walkT = walkFixed ?? (now - walkStart) / 1000;
    if (walkers) walkers.draw(viewProj, vp.o, walkT, renderer.meshDrawn, focal);
    if (captureSet && captureSet.has(index)) captures.push({ index, vp, t: walkT, ...renderer.pixels() });
    stats.error_px = predictor.errorPx(metric, keyEye, vp, keyViewProj, keyDeficit);
    if (Number.isFinite(stats.error_px)) { stats.errorSum += stats.error_px; stats.errorFrames += 1; }
    stats.frames += 1;
    if (path && pathIndex === path.length && keyEye && norm(sub(keyEye, vp.o)) <= 1e-6 * (1 + norm(vp.o))) {
      finishedResolve(stats.frames);
    }
    if (hud) hud.update(now, api.stats, state, keyScale.why, cursorLine);
    requestAnimationFrame(frame);
  }

  const api = {
    stats() {
      return {
        frames: stats.frames, keyframes: stats.keyframes,
        median_ms: percentile(stats.intervals, 0.5), p99_ms: percentile(stats.intervals, 0.99),
        error_px: Number.isFinite(stats.error_px) ? stats.error_px : null,
        error_px_mean: stats.errorFrames ? stats.errorSum / stats.errorFrames : null,
        latency_ms: percentile(stats.latencies, 0.5), first_keyframe_ms: firstKeyMs,
        // the way to the first keyframe: the scene message in, the first request out, the
        // first keyframe message in (then decoded and drawn: first_keyframe_ms)
        first_scene_ms: firstMs.scene, first_request_ms: firstMs.request,
        first_arrived_ms: firstMs.arrived,
        key_scale: keyScale.scale,
        input_ms: percentile(inputs.ms, 0.5), input_ms_p99: percentile(inputs.ms, 0.99),
        inputs: inputs.ms.length,
        walkers: walkers ? walkers.d.count : 0, walker_triangles: walkers ? walkers.triangles : 0,
        walker_points: walkers ? walkers.pointsDrawn : 0,
      };
    },
    resetStats() {
      Object.assign(stats, { frames: 0, keyframes: 0, intervals: [], latencies: [], errorSum: 0, errorFrames: 0 });
      inputs.ms = []; lastFrame = null;
    },
    pixels: () => renderer.pixels(),
    capture(indices) { captureSet = new Set(indices); captures = []; },
    captured() { const out = captures || []; captures = null; captureSet = null; return out; },
    viewpoint: () => controls && controls.vp,
    keyViewpoint: () => keyVp,
    cursorAt,  // (px, py) canvas pixels -> {world, e, n, h, crs} or null (cursor.js)
    attribution: () => (sceneHeader && sceneHeader.attribution) || '',  // the imagery's credit
    pathIndex: () => pathIndex,
    keyScale: () => ({ ...keyScale }),  // {scale, why}: the keyframe scale asked for, and why
    setWalkTime(t) { walkFixed = t; },  // walkers held at t seconds (null: their own clock)
    state: () => state,
    serverStats: () => call('stats').then((r) => r.data),
    decoded: () => decoded,
    get finished() { return finished; },
    play,
    stop() { if (controls) hold(shownVp || controls.vp); },
    setViewpoint(vp) { if (controls) hold(vp); },
    screenshot: () => new Promise((resolve) => canvas.toBlob(resolve, 'image/png')),
    close() {
      closed = true;
      keyTarget.removeEventListener('keydown', onKey);
      cursorEvents.abort();
      if (controls) controls.detach();
      decoder.terminate();
      const gl = canvas.getContext('webgl2');  // the context the drawer made: lost, freed
      gl?.getExtension('WEBGL_lose_context')?.loseContext();
    },
  };
  api.ready = load().then(() => true, (e) => { state = `failed: ${e.message}`; if (hud) hud.update(Infinity, api.stats, state); throw e; });
  return api;
}
