"""Benchmark: the battlefield's reused static layers on the keyframe's own depth.

``reproduce battlefield``'s scene (a 4k² store, 3000 walkers, 100 trees, two light fields)
and paths, its full-detail band-limited reference on the sampled frames, and three of its
runs per path on one renderer: the budget's ``scheduler`` at its target, and ``reuse``
(the scheduler at 3x that target with the terrain and trees in keyframes from the scene's
keyframe worker) once with spriteframes on the proxy geometry and once on the keyframe's
own depth (``--proxy depth``: walkers and light fields depth-tested against it).  Each run
gets the harness's untimed warm-up; quality comes from the untimed replay.  Printed per
run, pooled over the paths: median and p99 frame time, frame rate against the
scheduler's, RMSE, FLIP and flicker on the reported half of the sampled frames.

    python benchmarks/battlefield_reuse.py [--quick] [--out DIR]

Writes ``battlefield_reuse.json`` to ``--out``.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from lodsprite.api import Renderer
from lodsprite.experiments.battlefield.run import BattlefieldConfig, PathRuns, pooled
from lodsprite.experiments.battlefield.scene import write_scene
from lodsprite.scene.world import load_scene_file

RUNS = ("scheduler", "reuse geometry", "reuse depth")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="the tests' small scene")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    cfg = BattlefieldConfig.quick() if args.quick else BattlefieldConfig()
    out = args.out or Path(tempfile.mkdtemp(prefix="battlefield_reuse_"))
    out.mkdir(parents=True, exist_ok=True)
    scene_file, _ = write_scene(cfg, out)
    world = load_scene_file(scene_file)
    fov = world.path(cfg.paths[0], 2).fov_y_deg
    per_path: dict = {}
    with Renderer(world, (cfg.image, cfg.image), fov) as renderer:
        for spec in cfg.paths:
            p = PathRuns(renderer, world, world.path(spec, cfg.frames), cfg)
            reuse = {"schedule": "scheduler", "target_fps": cfg.reuse_fps,
                     "keyframes": "worker", "terrain_mode": cfg.reuse_mode}
            per_path[spec] = {
                "scheduler": p.run(schedule="scheduler", target_fps=cfg.target_fps),
                "reuse geometry": p.run(**reuse, proxy="geometry"),
                "reuse depth": p.run(**reuse, proxy="depth"),
            }
            print(f"{spec}: done", flush=True)
    table = {name: pooled(per_path, name) for name in RUNS}
    base = table["scheduler"]["median_ms"]
    print(f"{'run':16} {'median ms':>10} {'p99 ms':>8} {'fps x':>6} {'rmse':>7} "
          f"{'flip':>6} {'flicker':>8}")
    for name in RUNS:
        r = table[name]
        print(f"{name:16} {r['median_ms']:10.1f} {r['p99_ms']:8.1f} "
              f"{base / r['median_ms']:6.2f} {r['rmse']:7.2f} {r['flip']:6.3f} "
              f"{r['flicker']:8.2f}")
    (out / "battlefield_reuse.json").write_text(json.dumps(
        {"config": {k: (list(v) if isinstance(v, tuple) else v)
                    for k, v in cfg.__dict__.items()}, "pooled": table,
         "paths": {spec: {name: {k: v for k, v in run.items() if k != "columns"}
                          for name, run in runs.items()}
                   for spec, runs in per_path.items()}}, indent=1, default=str))
    print(f"wrote {out / 'battlefield_reuse.json'}")


if __name__ == "__main__":
    main()
