"""Spriteframes of the web page's WebGL2 drawer (``static/gl.js``) and of lodsprite's own
GL drawer (:class:`lodsprite.gl.sprite.SpriteDrawer`) from one keyframe, for the browser
tests: the keyframe is the server's (:class:`~lodsprite.distributed.render.
KeyframeService`), crossing to the page as the wire's keyframe message and decoded by the
page's own modules (``wire.js``, ``decode.js``), as the page decodes it."""

from __future__ import annotations

import base64

import numpy as np

from lodsprite.camera import Projection
from lodsprite.distributed.protocol import Keyframe, encode_keyframe
from lodsprite.distributed.web.wire import pack

# ``old``: the page's first drawer, for the tests' controls: the same module with the
# z-buffer sampled nearest (its first shader's lookup) and the scene's ribbon left out.
DRAW = """
const [doc, done] = arguments;
(async () => {
  const wire = await import('/static/wire.js');
  const dec = await import('/static/decode.js');
  let g = await import('/static/gl.js');
  if (doc.old) {
    const src = (await (await fetch('/static/gl.js')).text())
      .replace("'./camera.js'", `'${location.origin}/static/camera.js'`)
      .replace('bilinear_depth(ndc.xy * 0.5 + 0.5)',
               'textureLod(u_key_depth, ndc.xy * 0.5 + 0.5, 0.0).r');
    g = await import(URL.createObjectURL(new Blob([src], { type: 'text/javascript' })));
  }
  const bytes = (s) => Uint8Array.from(atob(s), (c) => c.charCodeAt(0)).buffer;
  const sc = wire.unpack(bytes(doc.scene));
  if (doc.old) { delete sc.header.ribbon; delete sc.header.ribbon_tris; }
  const [heights, texture] = await Promise.all([wire.image(sc.header.heights, sc.buffers[0]),
                                                wire.image(sc.header.texture, sc.buffers[1])]);
  const canvas = document.createElement('canvas');
  [canvas.width, canvas.height] = doc.size;
  const r = new g.SpriteDrawer(canvas);
  r.setScene(sc.header, heights, texture);
  r.fallbackTint = doc.tint;
  r.proxy = doc.proxy;
  r.pair = doc.pair;
  const out = [];
  for (const k of doc.keys) {
    const m = wire.unpack(bytes(k.msg));
    const [rgb, z] = await Promise.all([wire.image(m.header.color, m.buffers[0]),
                                        wire.image(m.header.depth, m.buffers[1])]);
    const [h, w] = m.header.color.shape;
    const bitmap = await createImageBitmap(dec.rgbaImage(rgb, w, h), dec.BITMAP_OPTIONS);
    r.useKeyframe(r.prepareKeyframe(m.header, bitmap, z));
    k.frames.forEach((vp, i) => { r.draw(vp, k.eyes[i]); out.push(r.pixels().rgba); });
  }
  done(out);
})().catch((e) => done(String(e.stack || e)));
"""


def page_spriteframes(browser, scene_parts: list, keys: list[tuple[Keyframe, list]],
                      size: tuple[int, int], old: bool = False,
                      tint: tuple = (1.0, 0.0, 1.0, 0.0), proxy: str = "coarse",
                      eyes: list[list] | None = None, pair: bool = False) -> list[np.ndarray]:
    """The page's spriteframes: for each ``(keyframe, [view_proj (4, 4)])`` of ``keys``
    the frames drawn from it, ``(H, W, 3) uint8`` rows bottom-up (readPixels), in order.
    ``browser`` is at a page of the server (its ``/static/`` modules); ``scene_parts``:
    the scene message (:func:`~lodsprite.distributed.web.scene.build_scene`); ``old``:
    the page's first drawer (module comment); ``tint``: the drawer's ``fallbackTint``;
    ``proxy``: its ``proxy`` (``coarse`` or ``depth``), ``eyes``: per keyframe the eye of
    each frame (for the depth mesh); ``pair``: the drawer's ``pair`` (the keyframe before
    drawn where the current one drew nothing)."""
    doc = {"scene": base64.b64encode(pack(scene_parts)).decode(), "size": list(size),
           "old": old, "tint": list(tint), "proxy": proxy, "pair": pair,
           "keys": [{"msg": base64.b64encode(pack(encode_keyframe(kf))).decode(),
                     "frames": [np.asarray(m, float).ravel().tolist() for m in frames],
                     "eyes": ([None] * len(frames) if eyes is None else
                              [np.asarray(e, float).tolist() for e in eyes[i]])}
                    for i, (kf, frames) in enumerate(keys)]}
    got = browser.execute_async_script(DRAW, doc)
    assert isinstance(got, list), got
    w, h = size
    return [np.frombuffer(base64.b64decode(s), np.uint8).reshape(h, w, 4)[..., :3] for s in got]


def offline_spriteframes(service, lod: int, keys: list[tuple[Keyframe, list]],
                         projection: Projection, depth_stride: int | None = None,
                         pair: bool = False) -> list[np.ndarray]:
    """lodsprite's own spriteframes of the same keyframes and viewpoints: the distributed
    client's drawer (:class:`~lodsprite.gl.sprite.SpriteDrawer`, coarse rule, border
    ribbons, no guard band; with ``depth_stride``, the fragment rule and the keyframe's
    own depth as the proxy) in ``service``'s context, each keyframe uploaded as the client
    uploads it; ``keys``: ``(keyframe, [viewpoint])``; ``pair``: the drawer's; rows
    bottom-up, as the page's."""
    from lodsprite.gl.sprite import SpriteDrawer

    rule = "coarse" if depth_stride is None else "fragment"
    drawer = (service.terrain_gl.drawer if hasattr(service, "terrain_gl")
              else service.keys.terrain)  # an adaptive service's working-grid drawer
    sprite = SpriteDrawer(drawer, lod, rule, border=True, guard_px=0,
                          depth_stride=depth_stride, pair=pair)
    out = []
    try:
        for kf, viewpoints in keys:
            sprite.upload_keyframe(kf.viewpoint, kf.projection, kf.color, kf.depth, kf.t0,
                                   kf.zbuffer)
            for vp in viewpoints:
                sprite.render_spriteframe(vp, projection)
                out.append(np.array(sprite.target.read_color())[::-1])
    finally:
        sprite.release()
    return out


def rmse(a: np.ndarray, b: np.ndarray) -> float:
    """Root mean square difference (grey levels 0..255, over every channel)."""
    return float(np.sqrt(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)))
