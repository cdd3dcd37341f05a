// The lodsprite web page: the client of app.js over a WebSocket to `lodsprite serve --web`.
//
// Query string: token (required), scene (a name the server serves: a terrain, a store,
// fractal:N...; terrain= is the same, kept for older links; default jacksboro), path (a
// built-in path: chen1999, swan2002, flyover..., played one viewpoint a frame, then held),
// frames (the path's viewpoints), size (WxH keyframe and canvas pixels; 512x512), keyscale
// (keyframe texels a canvas pixel side: auto, 1, 1.5 or 2; gl.js chooseKeyScale), grid
// (working grid), and the technique options the server declares at /options.json (lod:
// coarse quads a side, epsilon: pixels, visibility: the load's rule, coarse or
// fragment/triangle: the full z-buffer, proxy: depth, the keyframe's own depth, or
// geometry, the coarse mesh alone), each parsed and checked by its declaration: a bad
// one stops the page with the option's one-line error, and so does a parameter that is
// none of these (a misspelt option is not ignored).  For tests and tools:
// window.lodsprite, the client's API (app.js).

import { startApp } from './app.js';

const q = new URLSearchParams(location.search);
const int = (name, fallback) => (q.has(name) ? parseInt(q.get(name), 10) : fallback);

// The page's own query parameters (the options the server declares come beside them).
const PAGE_KEYS = ['token', 'scene', 'terrain', 'path', 'frames', 'size', 'grid', 'keyscale'];

// The query's technique options by their declarations (lodsprite.techniques.Option); a
// parameter neither the page's nor a declared option's is an error.
async function pageOptions() {
  const declared = await (await fetch('/options.json')).json();
  const known = new Set([...PAGE_KEYS, ...declared.map((o) => o.name)]);
  for (const key of q.keys()) {
    if (!known.has(key)) throw new Error(`unknown query parameter '${key}': use ${[...known].join(', ')}`);
  }
  if (q.has('keyscale') && !['auto', '1', '1.5', '2'].includes(q.get('keyscale'))) {
    throw new Error(`keyscale '${q.get('keyscale')}': auto, 1, 1.5 or 2`);
  }
  if (q.has('scene') && q.has('terrain') && q.get('scene') !== q.get('terrain')) {
    throw new Error("give scene or terrain (the same parameter), not both");
  }
  const out = {};
  for (const o of declared) {
    if (!q.has(o.name)) { out[o.name] = o.default; continue; }
    const text = q.get(o.name).trim();
    const number = o.type === 'int' || o.type === 'float';
    const flag = o.type === 'bool';
    const v = number ? Number(text) : (flag ? text === 'true' || text === '1' : text);
    const bad = (number && (text === '' || !Number.isFinite(v)))
      || (flag && !['true', 'false', '1', '0'].includes(text))
      || (o.type === 'int' && !Number.isInteger(v))
      || (o.choices.length > 0 && !o.choices.includes(v))
      || (o.min !== null && (o.above ? v <= o.min : v < o.min))
      || (o.max !== null && v > o.max);
    if (bad) throw new Error(`option ${o.name}: got '${text}', allowed: ${o.allowed}`);
    out[o.name] = v;
  }
  return out;
}

// A WebSocket as app.js's transport.
function socketTransport(url) {
  const ws = new WebSocket(url);
  ws.binaryType = 'arraybuffer';
  const opened = new Promise((resolve, reject) => { ws.onopen = resolve; ws.onerror = () => reject(new Error('no WebSocket')); });
  return {
    opened,
    send: (bytes) => ws.send(bytes),
    onmessage: (handler) => { ws.onmessage = (event) => handler(event.data); },
    onclose: (handler) => { ws.onclose = handler; },
  };
}

const token = q.get('token') || '';
const transport = socketTransport(`${location.protocol === 'https:' ? 'wss' : 'ws'}://${location.host}/ws?token=${encodeURIComponent(token)}`);
const canvas = document.getElementById('view');
const hud = document.getElementById('hud');
const [width, height] = (q.get('size') || '512x512').split('x').map((s) => parseInt(s, 10));
const base = {
  terrain: q.get('scene') || q.get('terrain') || 'jacksboro', path: q.get('path'), frames: int('frames', undefined),
  grid: int('grid', undefined), size: [width, height], keyscale: q.get('keyscale') || 'auto',
};


const app = startApp({
  canvas, hud, transport, options: base, moreOptions: pageOptions(),
  decoderUrl: new URL('./decode.js', import.meta.url),
});
window.lodsprite = app;
