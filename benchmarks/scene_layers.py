"""What LOD-sprite's keyframes hold in a scene (issue 23, must-have 2): ``static`` (terrain
and static objects rendered into each keyframe, moving objects drawn every frame over
the spriteframe) against ``terrain`` (keyframes terrain only, every object every frame).

A small scene (a fractal terrain, a crowd of walkers and standing trees) flown along its
``[view]`` path with the ``scene`` technique in sprite mode, once per choice; each run's
time per frame (median, p99, mean per layer) and its RMSE against the full-detail scene
(full-resolution terrain, full meshes) in the untimed replay.  Prints one line per
choice.  Figures on a shared machine are noisy.

    python benchmarks/scene_layers.py [--frames 40] [--size 128] [--objects 200]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

SCENE = """[terrain]
source = "fractal:{grid}:3"
[[objects]]
mesh = "ogre"
height_m = 80.0
count = {objects}
seed = 1
walk_mps = {walk}
area = [-600.0, -600.0, 600.0, 600.0]
[[objects]]
mesh = "tree"
height_m = 150.0
count = {trees}
seed = 2
area = [-700.0, -700.0, 700.0, 700.0]
[view]
path = "flyover"
"""


def run(scene_file: Path, holds: str, frames: int, size: int, epsilon: float) -> dict:
    from lodsprite import techniques
    from lodsprite.api import Renderer
    from lodsprite.harness import run_path
    from lodsprite.layered.technique import reference
    from lodsprite.scene.world import load_scene_file

    world = load_scene_file(scene_file)
    cam = world.path(world.default_path, frames)
    with Renderer(world, (size, size), cam.fov_y_deg) as r:
        t = techniques.create("scene", r, world=world, terrain_mode="sprite",
                              keyframe_holds=holds, epsilon=epsilon)
        image, ref = reference(r, world, cam, t.frame_s)
        try:
            res = run_path(t, cam, ground_truth=True, reference=image)
        finally:
            t.release()
            ref.release()
    ms = np.array([f.ms for f in res.frames])
    return {"holds": holds, "median_ms": float(np.median(ms)),
            "p99_ms": float(np.percentile(ms, 99)),
            "ms_terrain": res.summary["mean_ms_terrain"],
            "ms_objects": res.summary["mean_ms_objects"],
            "keyframes": res.summary["keyframes"], "rmse": res.summary["rmse_mean"],
            "visible": float(np.mean([f.extra.get("visible", 0) for f in res.frames]))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--grid", type=int, default=256)
    ap.add_argument("--objects", type=int, default=200, help="walkers")
    ap.add_argument("--trees", type=int, default=100, help="standing trees")
    ap.add_argument("--walk", type=float, default=3.0, help="walkers' speed, m/s")
    ap.add_argument("--epsilon", type=float, default=2.0)
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        scene = Path(tmp) / "scene.toml"
        scene.write_text(SCENE.format(grid=a.grid, objects=a.objects, trees=a.trees,
                                      walk=a.walk))
        print(f"{'keyframes hold':<16} {'median':>7} {'p99':>7} {'terrain':>8} "
              f"{'objects':>8} {'keys':>5} {'rmse':>7} {'drawn':>6}   (ms; noisy)")
        for holds in ("static", "terrain"):
            s = run(scene, holds, a.frames, a.size, a.epsilon)
            print(f"{holds:<16} {s['median_ms']:7.2f} {s['p99_ms']:7.2f} "
                  f"{s['ms_terrain']:8.2f} {s['ms_objects']:8.2f} {s['keyframes']:5d} "
                  f"{s['rmse']:7.3f} {s['visible']:6.1f}")


if __name__ == "__main__":
    main()
