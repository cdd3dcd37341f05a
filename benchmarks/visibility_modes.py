"""Benchmark: the three spriteframe visibility rules side by side, and the default rule
without each of its additions (keyframes ahead of the viewer, border ribbons, guard band).

Each case runs LOD-sprite along chen1999 on Jacksboro 512² at 512×512 px, ε = 1 px: a
timed pass, then an untimed pass measuring every 5th frame against full resolution.

    python benchmarks/visibility_modes.py [--terrain SPEC] [--frames N]
"""

from __future__ import annotations

import argparse

import numpy as np

from lodsprite.gl.sprite import SpriteDrawer
from lodsprite.gl.terrain_gl import TerrainGL
from lodsprite.metrics import rmse
from lodsprite.run import RenderConfig, prepare
from lodsprite.sprite.engine import LodSpriteEngine
from lodsprite.sprite.policy import KEYFRAME

CASES = [  # visibility, keyframes ahead, border ribbons, guard band (px)
    ("triangle", True, True, 32), ("fragment", True, True, 32), ("coarse", True, True, 32),
    ("coarse", False, True, 32), ("coarse", True, False, 32), ("coarse", True, True, 0),
    ("coarse", False, False, 0),
]


def run(pr: TerrainGL, path, visibility: str, predict: bool, border: bool,
        guard: int) -> dict:
    sprite = SpriteDrawer(pr.drawer, 16, visibility, border=border, guard_px=guard)
    try:
        vp0 = path.viewpoints[0]
        sprite.render_keyframe(vp0, 0.0)
        sprite.render_spriteframe(vp0)
        pr.ctx.finish()
        engine = LodSpriteEngine(sprite, 1.0, predict=predict)
        frames = [engine.frame(vp) for vp in path.viewpoints]
        engine = LodSpriteEngine(sprite, 1.0, predict=predict)
        err_sprite, err_lod = [], []
        for i, vp in enumerate(path.viewpoints):
            engine.frame(vp)
            if i % 5:
                continue
            image = engine.read_image()
            pr.drawer.render(vp)
            truth = pr.drawer.target.read_color()
            pr.drawer.render(vp, 16)
            err_sprite.append(rmse(image, truth))
            err_lod.append(rmse(pr.drawer.target.read_color(), truth))
    finally:
        sprite.release()
    sprites = [f.ms for f in frames if f.type != KEYFRAME]
    return {"keyframes": sum(f.type == KEYFRAME for f in frames),
            "sprite_ms": float(np.mean(sprites)), "total_s": sum(f.ms for f in frames) / 1e3,
            "rmse_sprite": float(np.mean(err_sprite)), "rmse_lod": float(np.mean(err_lod))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--terrain", default="jacksboro")
    ap.add_argument("--frames", type=int, default=460)
    args = ap.parse_args()
    scene, path = prepare(RenderConfig(terrain=args.terrain, frames=args.frames, mode="sprite"))
    print(f"{'visibility':10s} {'ahead':>5s} {'border':>6s} {'guard':>5s} {'keyframes':>9s} "
          f"{'sprite ms':>9s} {'total s':>8s} {'RMSE sprite':>11s} {'RMSE 16²':>9s} "
          f"{'ratio':>6s}")
    with TerrainGL(scene, (512, 512)) as pr:
        for visibility, predict, border, guard in CASES:
            r = run(pr, path, visibility, predict, border, guard)
            print(f"{visibility:10s} {predict!s:>5s} {border!s:>6s} {guard:5d} "
                  f"{r['keyframes']:9d} {r['sprite_ms']:9.2f} {r['total_s']:8.2f} "
                  f"{r['rmse_sprite']:11.2f} {r['rmse_lod']:9.2f} "
                  f"{r['rmse_sprite'] / r['rmse_lod']:6.3f}", flush=True)


if __name__ == "__main__":
    main()
