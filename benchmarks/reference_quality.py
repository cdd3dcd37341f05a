"""The band-limited reference: is it stable under resampling, and what does a frame cost?

Stability: along a held-out path over a store, the reference at ``N²`` against the
reference at ``(2N)²`` box-filtered to ``N²`` (in linear light, as the reference filters):
at one sample a pixel the two alias differently; band-limited they should agree.  Printed
per store and ``k`` (samples a pixel side): the median and the max over the frames of that
RMSE (grey levels).

Level 0 at one sample a pixel against the 4x4 reference (how far a renderer that aliases
as level 0 does is from it): printed as ``level0_1spp_vs_ref``.

Cost: one frame of ``--cost-size``² at ``k = 4`` over each store, the median of
``--repeats`` frames at different viewpoints of the path (the first drawn untimed: the
level-0 patch uploaded once for a whole level), seconds with ``ctx.finish()`` and the
filter included.

    python benchmarks/reference_quality.py STORE [STORE ...] [--path bank] [--frames 8]
        [--size 256] [--cost-size 512] [--repeats 3] [--json OUT]

Each STORE is a terrain store (``lodsprite tile fractal:4096 --out f4k.zarr``).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from lodsprite import metrics
from lodsprite.bandlimit import downsample
from lodsprite.gl.context import GLContext
from lodsprite.gl.reference import LevelZeroReference
from lodsprite.paths import get_path
from lodsprite.scene import load_scene
from lodsprite.terrain.store import TerrainStore


def stability(gl, store, path, frames: list[int], size: int) -> dict:
    """Per k: median and max RMSE of the N² reference against the 2N² one filtered down."""
    out = {}
    for k in (1, 4):
        small = LevelZeroReference(gl, store, (size, size), path.fov_y_deg, samples=k)
        large = LevelZeroReference(gl, store, (2 * size, 2 * size), path.fov_y_deg,
                                   samples=k)
        try:
            e = [metrics.rmse(small.image(path.viewpoints[i]),
                              downsample(large.image(path.viewpoints[i]), 2))
                 for i in frames]
        finally:
            small.release()
            large.release()
        out[f"k{k}"] = {"median": float(np.median(e)), "max": float(np.max(e))}
    one = LevelZeroReference(gl, store, (size, size), path.fov_y_deg, samples=1)
    ref = LevelZeroReference(gl, store, (size, size), path.fov_y_deg, samples=4)
    try:
        e = [metrics.rmse(one.image(path.viewpoints[i]), ref.image(path.viewpoints[i]))
             for i in frames]
    finally:
        one.release()
        ref.release()
    out["level0_1spp_vs_ref"] = {"median": float(np.median(e)), "max": float(np.max(e))}
    return out


def cost(gl, store, path, frames: list[int], size: int) -> dict:
    """Seconds for one frame at k = 4 (the first frame untimed), median and each."""
    ref = LevelZeroReference(gl, store, (size, size), path.fov_y_deg, samples=4)
    try:
        ref.image(path.viewpoints[frames[0]])
        gl.finish()
        times = []
        for i in frames[1:]:
            t0 = time.perf_counter()
            ref.image(path.viewpoints[i])
            gl.finish()
            times.append(time.perf_counter() - t0)
        how = ref.describe()
    finally:
        ref.release()
    return {"median_s": float(np.median(times)), "seconds": times, "how": how}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("stores", nargs="+", type=Path)
    ap.add_argument("--path", default="bank")
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--cost-size", type=int, default=512)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    results = {}
    with GLContext() as gl:
        for folder in args.stores:
            store = TerrainStore(folder)
            r, c = store.shape(0)
            path = get_path(args.path, load_scene(str(folder)).hf)  # follows its heights
            frames = [int(i) for i in np.linspace(0, len(path) - 1, args.frames)]
            st = stability(gl, store, path, frames, args.size)
            co = cost(gl, store, path, [int(i) for i in np.linspace(
                0, len(path) - 1, args.repeats + 1)], args.cost_size)
            results[f"{c}x{r}"] = {"stability": st, "cost": co}
            print(f"{folder} ({c}x{r} samples), path {args.path}, {len(frames)} frames:")
            for k in ("k1", "k4", "level0_1spp_vs_ref"):
                what = ("1 sample a pixel" if k == "k1" else "4x4 samples a pixel"
                        if k == "k4" else "level 0 at 1 spp vs the 4x4 reference")
                label = (f"{args.size}² vs {2 * args.size}² filtered, {what}"
                         if k != "level0_1spp_vs_ref" else f"{args.size}², {what}")
                print(f"  {label}: RMSE median {st[k]['median']:.2f}, max "
                      f"{st[k]['max']:.2f}")
            print(f"  cost of one {args.cost_size}² frame at k = 4: median "
                  f"{co['median_s']:.2f} s ({', '.join(f'{s:.2f}' for s in co['seconds'])});"
                  f" {co['how']}")
    if args.json:
        args.json.write_text(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
