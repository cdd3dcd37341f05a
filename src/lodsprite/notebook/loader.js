// The lodsprite notebook widget's front end (anywidget): the web page's client (app.js)
// over the widget's messages.  The page's modules come as sources (lodsprite.notebook.bundle)
// and are linked here as blob: URLs in import order, so the widget runs the very modules
// the page runs.  Each view (a cell's output; a widget shown twice has two) is one client
// with its own id and its own session in the kernel.
//
// Messages (custom widget messages; the kernel validates each, lodsprite.notebook.messages):
//   to the kernel: {kind: 'wire', view} + one web message (wire.js), {kind: 'status', view,
//   stats, camera, state}, {kind: 'played', view, frames}, {kind: 'failed', view, error},
//   {kind: 'shot', view, id} + a PNG, {kind: 'closed', view};
//   from the kernel: {kind: 'wire', view} + one web message, {kind: 'play', spec, frames},
//   {kind: 'stop'}, {kind: 'reset'} (the figures start again), {kind: 'camera', viewpoint:
//   12 numbers}, {kind: 'shot', id}.

const MODULES = /*__MODULES__*/null;
const STATUS_MS = 250;  // stats and camera to the kernel at most this often

let linked = null;  // module name -> blob: URL, made once a page
function link() {
  if (linked) return linked;
  linked = {};
  for (const name of MODULES.order) {
    const text = MODULES.sources[name].replace(/(\bfrom\s+)(['"])\.\/([\w.-]+\.js)\2/g,
      (m, from, quote, dep) => `${from}${quote}${linked[dep]}${quote}`);
    linked[name] = URL.createObjectURL(new Blob([text], { type: 'text/javascript' }));
  }
  return linked;
}

const flat = (vp) => (vp ? [...vp.x, ...vp.y, ...vp.z, ...vp.o] : null);
const viewpoint = (r) => ({ x: r.slice(0, 3), y: r.slice(3, 6), z: r.slice(6, 9), o: r.slice(9, 12) });

// A buffer of a widget message (a DataView) as an ArrayBuffer of its own.
function owned(buffer) {
  const view = buffer instanceof DataView ? buffer : new DataView(buffer);
  return view.buffer.slice(view.byteOffset, view.byteOffset + view.byteLength);
}

async function render({ model, el }) {
  const urls = link();
  const { startApp } = await import(urls['app.js']);
  const view = Array.from(crypto.getRandomValues(new Uint8Array(8)), (b) => b.toString(16).padStart(2, '0')).join('');
  const options = { ...model.get('options') };
  const [width, height] = options.size;
  const box = document.createElement('div');
  box.className = 'lodsprite-widget';
  box.style.maxWidth = `${width}px`;
  const canvas = document.createElement('canvas');
  canvas.className = 'lodsprite-view';
  canvas.tabIndex = 0;  // keys fly the camera while the canvas has the focus
  canvas.style.aspectRatio = `${width} / ${height}`;
  const hud = document.createElement('div');
  hud.className = 'lodsprite-hud';
  box.append(canvas, hud);
  el.append(box);
  // Keys on the canvas are the camera's, not the notebook's (no cell is added or run).
  for (const type of ['keydown', 'keyup', 'keypress']) {
    canvas.addEventListener(type, (e) => { e.stopPropagation(); if (!(e.ctrlKey || e.metaKey)) e.preventDefault(); });
  }
  canvas.addEventListener('pointerdown', () => canvas.focus());

  let handler = null;
  const transport = {
    opened: Promise.resolve(),
    send: (bytes) => model.send({ kind: 'wire', view }, undefined, [bytes]),
    onmessage: (h) => { handler = h; },
    onclose: () => {},
  };
  const app = startApp({ canvas, hud, transport, options, decoderUrl: urls['decode.js'], keyTarget: canvas });
  box.lodsprite = app;  // the view's client API, for tools and tests
  const failed = (e) => model.send({ kind: 'failed', view, error: String(e && e.message || e).slice(0, 2000) });
  const status = () => model.send({ kind: 'status', view, stats: app.stats(), camera: flat(app.viewpoint()), state: app.state() });
  // The figures as the path ends go first: w.stats after `await w.played()` are the path's.
  const played = () => app.finished.then((frames) => { status(); model.send({ kind: 'played', view, frames }); });
  app.ready.then(() => { if (options.path) played(); }, failed);

  const onCustom = (msg, buffers) => {
    if (!msg || typeof msg !== 'object') return;
    if (msg.kind === 'wire') {
      if (msg.view === view && handler && buffers && buffers.length === 1) handler(owned(buffers[0]));
    } else if (msg.kind === 'play') {
      app.ready.then(() => app.play(msg.spec, msg.frames ?? undefined)).then(played, failed);
    } else if (msg.kind === 'reset') {
      app.resetStats();
    } else if (msg.kind === 'stop') {
      app.ready.then(() => app.stop(), () => {});
    } else if (msg.kind === 'camera' && Array.isArray(msg.viewpoint) && msg.viewpoint.length === 12) {
      app.ready.then(() => app.setViewpoint(viewpoint(msg.viewpoint)), () => {});
    } else if (msg.kind === 'shot') {
      app.ready.then(() => app.screenshot()).then((blob) => blob.arrayBuffer()).then(
        (png) => model.send({ kind: 'shot', view, id: msg.id }, undefined, [png]), failed);
    }
  };
  model.on('msg:custom', onCustom);
  const timer = setInterval(status, STATUS_MS);

  return () => {
    clearInterval(timer);
    model.off('msg:custom', onCustom);
    app.close();
    model.send({ kind: 'closed', view });
  };
}

export default { render };
