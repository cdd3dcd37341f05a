"""Benchmark: median milliseconds per frame along the chen1999 path.

Full resolution at 512² (Jacksboro), the 16² level, and full resolution of 2048² and
4096² fractal terrains, each rendered offscreen at 512×512 pixels with ctx.finish()
before the clock stops.  Large fields use fewer frames over the same geometric path
(--frames-large, default 115) to keep the run short; the frame count is printed.

    python benchmarks/render_times.py [--out DIR] [--frames-large N]
"""

from __future__ import annotations

import argparse
from pathlib import Path

from lodsprite.run import RenderConfig, render_path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("out/bench-render"))
    ap.add_argument("--frames-large", type=int, default=115)
    args = ap.parse_args()
    cases = [
        ("full 512² jacksboro", RenderConfig(terrain="jacksboro", mode="full")),
        ("coarse 16² jacksboro", RenderConfig(terrain="jacksboro", mode="lod", lod=16)),
        ("full 2048² fractal", RenderConfig(terrain="fractal:2048:1", mode="full",
                                            frames=args.frames_large)),
        ("full 4096² fractal", RenderConfig(terrain="fractal:4096:1", mode="full",
                                            frames=args.frames_large)),
    ]
    print(f"{'case':24s} {'frames':>6s} {'median ms':>10s} {'mean ms':>9s} {'p95 ms':>8s}")
    for i, (name, cfg) in enumerate(cases):
        s = render_path(cfg, args.out / f"case{i}")
        print(f"{name:24s} {s['frames']:6d} {s['median_ms']:10.2f} {s['mean_ms']:9.2f} "
              f"{s['p95_ms']:8.2f}", flush=True)
    print(f"GL renderer: {s['gl_renderer']}")


if __name__ == "__main__":
    main()
