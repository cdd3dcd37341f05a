"""Benchmark: does a mipmapped sprite texture lower LOD-sprite's image error, and at what cost?

Two ways to sample the keyframe's colour in spriteframes (both through ``textureGrad``
with derivatives taken before the visibility branch): bilinear without mipmaps, and
trilinear with mipmaps built after every keyframe.  (Anisotropic filtering is not a
case: on llvmpipe a minified spriteframe took 2-3 s with it.)

* ``fly-away``: one keyframe, then spriteframes from eyes 1x to 3x as far from the same
  target (the sprite is shrunk up to 3x: minification), at three elevations (10
  degrees, the chen1999 path's, 35 and 70); RMSE against the full-resolution render of each view.
* ``chen1999``: the engine along the chen1999 path at ε = 1 px (timed pass: keyframe and
  spriteframe ms; untimed pass: RMSE on every 5th frame against full resolution).
* ``mipmap ms``: ``build_mipmaps`` of one keyframe's sprite texture alone, between two
  ``ctx.finish()``, median of 50.

    python benchmarks/sprite_mipmaps.py [--terrain SPEC] [--texture SPEC] [--frames N] [--size PX]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from lodsprite.camera import look_at
from lodsprite.gl.sprite import SpriteDrawer
from lodsprite.gl.terrain_gl import TerrainGL
from lodsprite.metrics import rmse
from lodsprite.run import RenderConfig, prepare
from lodsprite.sprite.engine import LodSpriteEngine
from lodsprite.sprite.policy import KEYFRAME

CASES = [("bilinear", False), ("trilinear", True)]
LOD = 16
SCALES = np.linspace(1.0, 3.0, 21)
BINS = ((1.0, 1.5), (1.5, 2.0), (2.0, 3.01))
ELEVATIONS = (10.0, 35.0, 70.0)


def fly_away(pr: TerrainGL, sprite: SpriteDrawer, elevation_deg: float) -> np.ndarray:
    """RMSE ``(len(SCALES),)`` of spriteframes from eyes SCALES times as far as the
    keyframe's from the terrain's centre."""
    hf = pr.geometry.hf
    target = np.array([0.0, 0.0, float(hf.height_at(0.0, 0.0))])
    e = np.radians(elevation_deg)
    base = 0.45 * hf.extent * np.array([0.0, -np.cos(e), np.sin(e)])
    sprite.render_keyframe(look_at(target + base, target), 0.0)
    errors = []
    for s in SCALES:
        vp = look_at(target + s * base, target)
        sprite.render_spriteframe(vp)
        frame = sprite.target.read_color()
        pr.drawer.render(vp)
        errors.append(rmse(frame, pr.drawer.target.read_color()))
    return np.array(errors)


def chen1999_run(pr: TerrainGL, path, sprite: SpriteDrawer) -> dict:
    vp0 = path.viewpoints[0]
    sprite.render_keyframe(vp0, 0.0)  # warm-up (shader compilation), untimed
    sprite.render_spriteframe(vp0)
    pr.ctx.finish()
    engine = LodSpriteEngine(sprite, 1.0)
    frames = [engine.frame(vp) for vp in path.viewpoints]
    engine = LodSpriteEngine(sprite, 1.0)
    errors = []
    for i, vp in enumerate(path.viewpoints):
        engine.frame(vp)
        if i % 5:
            continue
        image = engine.read_image()
        pr.drawer.render(vp)
        errors.append(rmse(image, pr.drawer.target.read_color()))
    keys = [f.ms for f in frames if f.type == KEYFRAME]
    sprites = [f.ms for f in frames if f.type != KEYFRAME]
    return {"keyframes": len(keys), "key_ms": float(np.mean(keys)),
            "sprite_ms": float(np.mean(sprites)), "total_s": sum(f.ms for f in frames) / 1e3,
            "rmse": float(np.mean(errors))}


def mipmap_ms(pr: TerrainGL, sprite: SpriteDrawer, vp, reps: int = 50) -> float:
    sprite.render_keyframe(vp, 0.0)
    tex = sprite.keyframe.color
    times = []
    for _ in range(reps):
        pr.ctx.finish()
        t0 = time.perf_counter()
        tex.build_mipmaps()
        pr.ctx.finish()
        times.append((time.perf_counter() - t0) * 1e3)
    return float(np.median(times))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--terrain", default="jacksboro")
    ap.add_argument("--frames", type=int, default=460)
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--texture", default="terrain")
    args = ap.parse_args()
    scene, path = prepare(RenderConfig(terrain=args.terrain, texture=args.texture,
                                       frames=args.frames, mode="sprite",
                                       size=(args.size, args.size)))
    rows = {}
    with TerrainGL(scene, (args.size, args.size)) as pr:
        info = pr.ctx.info
        for name, mipmaps in CASES:
            sprite = SpriteDrawer(pr.drawer, LOD, mipmaps=mipmaps)
            try:
                r = {f"fly{el}": fly_away(pr, sprite, el) for el in ELEVATIONS}
                r.update(chen1999_run(pr, path, sprite))
                r["mipmap_ms"] = mipmap_ms(pr, sprite, path.viewpoints[0]) if mipmaps else 0.0
            finally:
                sprite.release()
            rows[name] = r
            print(f"done {name}", flush=True)
    print(f"\n{args.terrain}, texture {args.texture}, {args.size}x{args.size} px, {LOD}² level, "
          f"{info.renderer}")
    print("\nfly-away: mean RMSE against full resolution by distance (x the keyframe's)")
    head = " ".join(f"{f'{e:g}° {a:g}-{min(b, 3):g}x':>11s}" for e in ELEVATIONS for a, b in BINS)
    print(f"{'sampling':18s} {head}")
    for name, r in rows.items():
        cells = []
        for el in ELEVATIONS:
            for a, b in BINS:
                sel = (SCALES >= a) & (SCALES < b)
                cells.append(f"{r[f'fly{el}'][sel].mean():11.2f}")
        print(f"{name:18s} {' '.join(cells)}")
    print(f"\nchen1999, ε = 1 px\n{'sampling':18s} {'keyframes':>9s} {'key ms':>7s} "
          f"{'sprite ms':>9s} {'total s':>7s} {'RMSE':>6s} {'mipmap ms':>9s}")
    for name, r in rows.items():
        print(f"{name:18s} {r['keyframes']:9d} {r['key_ms']:7.1f} {r['sprite_ms']:9.2f} "
              f"{r['total_s']:7.2f} {r['rmse']:6.2f} {r['mipmap_ms']:9.2f}")


if __name__ == "__main__":
    main()
