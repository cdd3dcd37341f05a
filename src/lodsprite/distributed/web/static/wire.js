// The web wire (lodsprite.distributed.web.wire): one WebSocket binary message is
// u32le n_parts, n_parts x u32le length, then the parts; part 0 is a msgpack header, the
// rest raw buffers.  A small msgpack encoder and decoder: only what the headers use
// (maps, arrays, strings, numbers, booleans, nil; the decoder also reads bin).

export const PROTOCOL_VERSION = 5;
const MAX_PARTS = 4;

// ---------------------------------------------------------------- msgpack encoder
class Writer {
  constructor() { this.buf = new Uint8Array(256); this.view = new DataView(this.buf.buffer); this.n = 0; }
  need(k) {
    if (this.n + k <= this.buf.length) return;
    const b = new Uint8Array(Math.max(2 * this.buf.length, this.n + k));
    b.set(this.buf); this.buf = b; this.view = new DataView(b.buffer);
  }
  u8(x) { this.need(1); this.buf[this.n++] = x; }
  u16(x) { this.need(2); this.view.setUint16(this.n, x); this.n += 2; }
  u32(x) { this.need(4); this.view.setUint32(this.n, x); this.n += 4; }
  f64(x) { this.need(8); this.view.setFloat64(this.n, x); this.n += 8; }
  bytes(b) { this.need(b.length); this.buf.set(b, this.n); this.n += b.length; }
}

function encodeValue(w, v) {
  if (v === null || v === undefined) w.u8(0xc0);
  else if (v === false) w.u8(0xc2);
  else if (v === true) w.u8(0xc3);
  else if (typeof v === 'number') encodeNumber(w, v);
  else if (typeof v === 'string') {
    const b = new TextEncoder().encode(v);
    if (b.length < 32) w.u8(0xa0 | b.length);
    else if (b.length < 256) { w.u8(0xd9); w.u8(b.length); }
    else if (b.length < 65536) { w.u8(0xda); w.u16(b.length); }
    else { w.u8(0xdb); w.u32(b.length); }
    w.bytes(b);
  } else if (Array.isArray(v)) {
    if (v.length < 16) w.u8(0x90 | v.length); else { w.u8(0xdd); w.u32(v.length); }
    for (const x of v) encodeValue(w, x);
  } else if (typeof v === 'object') {
    const keys = Object.keys(v).filter((k) => v[k] !== undefined);
    if (keys.length < 16) w.u8(0x80 | keys.length); else { w.u8(0xdf); w.u32(keys.length); }
    for (const k of keys) { encodeValue(w, k); encodeValue(w, v[k]); }
  } else throw new TypeError(`msgpack: cannot encode ${typeof v}`);
}

function encodeNumber(w, v) {
  if (Number.isInteger(v) && v >= 0 && v < 2 ** 32) {
    if (v < 128) w.u8(v);
    else if (v < 65536) { w.u8(0xcd); w.u16(v); }
    else { w.u8(0xce); w.u32(v); }
  } else if (Number.isInteger(v) && v < 0 && v >= -32) w.u8(v & 0xff);
  else { w.u8(0xcb); w.f64(v); }  // every other number as float64
}

export function msgpackEncode(v) {
  const w = new Writer();
  encodeValue(w, v);
  return w.buf.subarray(0, w.n);
}

// ---------------------------------------------------------------- msgpack decoder
export function msgpackDecode(bytes) {
  const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  let i = 0;
  const str = (n) => { const s = new TextDecoder().decode(bytes.subarray(i, i + n)); i += n; return s; };
  const bin = (n) => { const b = bytes.subarray(i, i + n); i += n; return b; };
  const arr = (n) => { const a = new Array(n); for (let k = 0; k < n; k++) a[k] = next(); return a; };
  const map = (n) => { const m = {}; for (let k = 0; k < n; k++) { const key = next(); m[key] = next(); } return m; };
  function next() {
    if (i >= bytes.length) throw new Error('msgpack: truncated');
    const b = bytes[i++];
    if (b < 0x80) return b;
    if (b < 0x90) return map(b & 0x0f);
    if (b < 0xa0) return arr(b & 0x0f);
    if (b < 0xc0) return str(b & 0x1f);
    if (b >= 0xe0) return b - 256;
    let v;
    switch (b) {
      case 0xc0: return null;
      case 0xc2: return false;
      case 0xc3: return true;
      case 0xc4: v = view.getUint8(i); i += 1; return bin(v);
      case 0xc5: v = view.getUint16(i); i += 2; return bin(v);
      case 0xc6: v = view.getUint32(i); i += 4; return bin(v);
      case 0xca: v = view.getFloat32(i); i += 4; return v;
      case 0xcb: v = view.getFloat64(i); i += 8; return v;
      case 0xcc: v = view.getUint8(i); i += 1; return v;
      case 0xcd: v = view.getUint16(i); i += 2; return v;
      case 0xce: v = view.getUint32(i); i += 4; return v;
      case 0xcf: v = Number(view.getBigUint64(i)); i += 8; return v;
      case 0xd0: v = view.getInt8(i); i += 1; return v;
      case 0xd1: v = view.getInt16(i); i += 2; return v;
      case 0xd2: v = view.getInt32(i); i += 4; return v;
      case 0xd3: v = Number(view.getBigInt64(i)); i += 8; return v;
      case 0xd9: v = view.getUint8(i); i += 1; return str(v);
      case 0xda: v = view.getUint16(i); i += 2; return str(v);
      case 0xdb: v = view.getUint32(i); i += 4; return str(v);
      case 0xdc: v = view.getUint16(i); i += 2; return arr(v);
      case 0xdd: v = view.getUint32(i); i += 4; return arr(v);
      case 0xde: v = view.getUint16(i); i += 2; return map(v);
      case 0xdf: v = view.getUint32(i); i += 4; return map(v);
      default: throw new Error(`msgpack: unsupported type byte 0x${b.toString(16)}`);
    }
  }
  return next();
}

// ---------------------------------------------------------------- framing
export function pack(header, ...buffers) {
  const parts = [msgpackEncode({ v: PROTOCOL_VERSION, ...header }), ...buffers];
  const head = 4 * (parts.length + 1);
  const total = parts.reduce((s, p) => s + p.byteLength, head);
  const out = new Uint8Array(total);
  const dv = new DataView(out.buffer);
  dv.setUint32(0, parts.length, true);
  let at = head;
  parts.forEach((p, k) => { dv.setUint32(4 * (k + 1), p.byteLength, true); out.set(p, at); at += p.byteLength; });
  return out;
}

// The header (an object, `kind` included) and the buffers (Uint8Array views) of a message.
export function unpack(data) {
  const bytes = new Uint8Array(data);
  const dv = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  const n = dv.getUint32(0, true);
  if (n < 1 || n > MAX_PARTS) throw new Error(`web message of ${n} parts`);
  let at = 4 * (n + 1);
  const parts = [];
  for (let k = 0; k < n; k++) {
    const len = dv.getUint32(4 * (k + 1), true);
    if (at + len > bytes.length) throw new Error('web message shorter than its parts');
    parts.push(bytes.subarray(at, at + len)); at += len;
  }
  return { header: msgpackDecode(parts[0]), buffers: parts.slice(1) };
}

// An image buffer as its typed array, inflating zlib (RFC 1950: "deflate") when declared.
export async function image(spec, bytes) {
  let data = bytes;
  if (spec.codec === 'zlib') {
    const stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream('deflate'));
    data = new Uint8Array(await new Response(stream).arrayBuffer());
  }
  const count = spec.shape.reduce((a, b) => a * b, 1);
  const copy = new Uint8Array(data);  // aligned, owned
  if (spec.dtype === 'float32') {
    if (copy.byteLength !== 4 * count) throw new Error('float32 image of the wrong size');
    return new Float32Array(copy.buffer);
  }
  if (copy.byteLength !== count) throw new Error('uint8 image of the wrong size');
  return copy;
}
