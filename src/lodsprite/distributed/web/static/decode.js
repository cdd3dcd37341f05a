// The page's keyframe decoder, a module Web Worker: a keyframe's images are inflated
// (zlib), checked against their declared shapes and made into what WebGL uploads here,
// off the page's thread, so a frame never waits for a decode.  The colour, (H, W, 3)
// uint8 RGB rows bottom-up as the wire sends it (lodsprite.distributed.protocol's
// keyframe), becomes an ImageBitmap of the same rows in the same order (RGBA, alpha 255;
// no colour-space conversion, no premultiplication, no flip), which texImage2D uploads
// as it did the bytes: row 0 of the buffer is row 0 of the texture.  The depth, (H, W)
// float32, comes back as its Float32Array (ImageBitmaps hold 8-bit colour only).
//
// With `estimate` ({stride, keyScale}: the page's depth mesh and keyframe scale) it then
// builds the keyframe's error estimate on its own depth (depth_estimate.js), here, off
// the page's thread, and sends it apart, after the keyframe (which the page may draw
// meanwhile: a first build took about 100 ms in V8 here, most of it compiling): its state's typed arrays come
// back transferred.
//
// In: {id, header, color, depth, estimate} (the two image buffers as the wire gave them).
// Out: {id, bitmap, depth} (transferred), then with `estimate` {id, estimate} (or
// {id, estimateError}); or {id, error}.

import { mul } from './camera.js';
import { buildEstimate } from './depth_estimate.js';
import { image } from './wire.js';

export const BITMAP_OPTIONS = { imageOrientation: 'none', premultiplyAlpha: 'none', colorSpaceConversion: 'none' };

// (H, W, 3) RGB bytes as an (H, W) RGBA ImageData, rows in the same order.
export function rgbaImage(rgb, w, h) {
  const rgba = new Uint8ClampedArray(4 * w * h);
  for (let i = 0, j = 0; j < rgba.length; i += 3, j += 4) {
    rgba[j] = rgb[i]; rgba[j + 1] = rgb[i + 1]; rgba[j + 2] = rgb[i + 2]; rgba[j + 3] = 255;
  }
  return new ImageData(rgba, w, h);
}

if (typeof WorkerGlobalScope !== 'undefined' && self instanceof WorkerGlobalScope) {
  self.onmessage = async ({ data }) => {
    const { id, header, color, depth, estimate } = data;
    try {
      const [rgb, z] = await Promise.all([image(header.color, color), image(header.depth, depth)]);
      const [h, w, c] = header.color.shape;
      if (c !== 3) throw new Error(`keyframe colour of ${c} channels`);
      const [dh, dw] = header.depth.shape;
      const keep = estimate && dh === h && dw === w ? z.slice() : null;  // z goes with the keyframe
      const bitmap = await createImageBitmap(rgbaImage(rgb, w, h), BITMAP_OPTIONS);
      self.postMessage({ id, bitmap, depth: z }, [bitmap, z.buffer]);
      if (keep) {
        try {
          const est = buildEstimate(keep, w, h, header.viewpoint, header.fov, header.aspect, header.near,
            header.far, mul(header.proj, header.view), estimate.stride, estimate.keyScale, rgb);
          const moved = Object.values(est).filter((v) => ArrayBuffer.isView(v)).map((v) => v.buffer);
          self.postMessage({ id, estimate: est }, moved);
        } catch (e) {  // the keyframe itself is fine: the page keeps the coarse estimate
          self.postMessage({ id, estimateError: String(e.message || e) });
        }
      }
    } catch (e) {
      self.postMessage({ id, error: String(e.message || e) });
    }
  };
}
