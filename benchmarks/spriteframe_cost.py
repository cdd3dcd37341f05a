"""Benchmark: what a spriteframe costs on a store, by how it is drawn, beside an adaptive
frame on the same views.

Keyframes at frames ``--at - 2`` and ``--at`` of the path (so a pair has its older one),
then spriteframes at the ``--at`` .. ``--at + 7`` views in turn, each between two
``ctx.finish()``: median and p90 of ``--reps`` after 5 untimed; the adaptive renderer at
1 px on the same views (settled first), median of its frames.

    python benchmarks/spriteframe_cost.py --terrain STORE [--path flyover] [--size 512]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from lodsprite import techniques
from lodsprite.api import Renderer
from lodsprite.run import RenderConfig, prepare

CASES = {
    "proxy geometry, scale 1": {"proxy": "geometry", "key_scale": 1.0},
    "depth, every 4th texel, scale 1": {"proxy": "depth", "key_scale": 1.0,
                                        "depth_stride": 4},
    "depth, every 8th texel, scale 2": {"proxy": "depth", "key_scale": 2.0,
                                        "depth_stride": 8},
    "depth, every 4th texel, scale 2": {"proxy": "depth", "key_scale": 2.0,
                                        "depth_stride": 4},
    "depth, every 8th texel, scale 2, paired": {"proxy": "depth", "key_scale": 2.0,
                                                "depth_stride": 8, "pair": True},
    "depth, every 8th texel, scale 2, refined": {"proxy": "depth-refined",
                                                 "key_scale": 2.0, "depth_stride": 8},
    "depth searched per pixel, scale 2": {"proxy": "search", "key_scale": 2.0,
                                          "depth_stride": 8},
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--terrain", required=True, help="a terrain store")
    ap.add_argument("--path", default="flyover")
    ap.add_argument("--frames", type=int, default=120)
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--at", type=int, default=60)
    ap.add_argument("--reps", type=int, default=20)
    args = ap.parse_args()
    size = (args.size, args.size)
    scene, path = prepare(RenderConfig(terrain=args.terrain, path=args.path,
                                       frames=args.frames, mode="sprite", size=size))
    views = [path.viewpoints[args.at + i % 8] for i in range(args.reps + 5)]
    with Renderer(scene, size, path.fov_y_deg) as r:
        print(f"{args.terrain}, {args.path}, frames {args.at}..{args.at + 7} at "
              f"{args.size}²; {r.info.renderer}")
        for name, opts in CASES.items():
            t = techniques.create("sprite", r, **opts)
            s = t.sprite.sprite
            try:
                for k in (args.at - 2, args.at):
                    vp = path.viewpoints[k]
                    t.adaptive.fill(vp, s.key_projection(s.terrain.projection(vp)).matrix())
                    s.render_keyframe(vp, 0.0)
                ms = []
                for vp in views:
                    r.gl.finish()
                    t0 = time.perf_counter()
                    s.render_spriteframe(vp)
                    r.gl.finish()
                    ms.append((time.perf_counter() - t0) * 1e3)
            finally:
                t.release()
            ms = ms[5:]
            print(f"  {name:42s} median {np.median(ms):7.2f} ms  p90 "
                  f"{np.percentile(ms, 90):7.2f} ms", flush=True)
        a = techniques.create("adaptive", r, sse=1.0)
        try:
            a.warm_up(views[0])
            ms = [a.frame(vp).ms for vp in views][5:]
        finally:
            a.release()
        print(f"  {'adaptive at 1 px':42s} median {np.median(ms):7.2f} ms")


if __name__ == "__main__":
    main()
