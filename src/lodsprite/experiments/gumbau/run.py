"""``lodsprite reproduce gumbau``: the LODManager's measurements (Gumbau et al., §5.3) on
this machine.

* Figure 6: fps and triangles per frame along the walkthrough, with and without the
  manager (baseline (a): every object extracts its own LOD), for the 3000-object scene and
  for 3000 objects plus 100 trees;
* Figure 5: one frame with the manager, the same without, and their per-pixel difference
  in red; ``image_diff_mean`` is the mean absolute difference (grey levels) over sampled
  frames;
* extractions and LOD CPU time per frame, draw calls;
* a run with a target frame rate, the feedback holding it;
* baseline (b), the engines' discrete LODs by screen size with hysteresis: fps, triangles
  and LOD switches per second.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from lodsprite.manager.run import CrowdConfig, run_crowd

Update = Callable[[str, int, int], None]


@dataclass(frozen=True)
class GumbauConfig:
    objects: int = 3000
    trees: int = 100
    frames: int = 600
    size: tuple[int, int] = (640, 480)
    slots: int = 16
    active: int = 300
    target_fps: float = 20.0
    sample_every: int = 50  # frames compared for image_diff_mean and kept for Figure 5

    @classmethod
    def quick(cls) -> GumbauConfig:
        return cls(objects=600, trees=8, frames=40, size=(320, 240), active=100,
                   sample_every=10)

    def crowd(self, **kw) -> CrowdConfig:
        base = CrowdConfig(objects=self.objects, trees=0, frames=self.frames,
                           size=self.size, slots=self.slots, active=self.active)
        return replace(base, **kw)


def reproduce_gumbau(cfg: GumbauConfig, update: Update | None = None) -> dict:
    """Run every measurement; returns the results (the report layer writes them)."""
    def step(name):
        return (lambda d, t: update(name, d, t)) if update else None

    keep = tuple(range(0, cfg.frames, cfg.sample_every))
    runs, images = {}, {}
    for scene, trees in (("crowd", 0), ("crowd_trees", cfg.trees)):
        for mode in ("manager", "independent"):
            name = f"{scene}_{mode}"
            rows, s, im = run_crowd(cfg.crowd(trees=trees, mode=mode), progress=step(name),
                                    keep_frames=keep if scene == "crowd" else ())
            runs[name] = {"summary": s, "frames": _columns(rows)}
            if scene == "crowd":
                images[mode] = im
    rows, s, _ = run_crowd(cfg.crowd(mode="manager", target_fps=cfg.target_fps),
                           progress=step(f"target {cfg.target_fps:g} fps"))
    runs["crowd_target"] = {"summary": s, "frames": _columns(rows)}
    rows, s, _ = run_crowd(cfg.crowd(mode="discrete"), progress=step("discrete LODs"))
    runs["crowd_discrete"] = {"summary": s, "frames": _columns(rows)}
    diffs = [float(np.abs(images["manager"][k].astype(np.float64)
                          - images["independent"][k].astype(np.float64)).mean())
             for k in keep]
    w, wo = runs["crowd_manager"]["summary"], runs["crowd_independent"]["summary"]
    t = runs["crowd_target"]["summary"]
    r = {"config": {k: (list(v) if isinstance(v, tuple) else v)
                    for k, v in cfg.__dict__.items()},
         "runs": runs,
         "extractions_with": w["extractions_total"],
         "extractions_without": wo["extractions_total"],
         "lod_cpu_ms_with": w["lod_cpu_ms_mean"], "lod_cpu_ms_without": wo["lod_cpu_ms_mean"],
         "fps_mean_with": w["fps_mean"], "fps_mean_without": wo["fps_mean"],
         "triangles_mean_with": w["triangles_mean"],
         "triangles_mean_without": wo["triangles_mean"],
         "draw_calls_mean_with": w["draw_calls_mean"],
         "draw_calls_mean_without": wo["draw_calls_mean"],
         "image_diff_mean": float(np.mean(diffs)), "image_diff_frames": list(keep),
         "image_diffs": diffs,
         "target_fps": cfg.target_fps, "frame_ms_median_at_target": t["median_ms"],
         "frame_ms_p99_at_target": t["p99_ms"],
         "gl_renderer": w["gl_renderer"]}
    shown = keep[len(keep) // 2]
    r["_figure5"] = (images["manager"][shown], images["independent"][shown], shown)
    return r


def _columns(rows: list[dict]) -> dict[str, list]:
    return {k: [row[k] for row in rows] for k in ("ms", "fps", "lod_ms", "extractions",
                                                  "draw_calls", "triangles", "exponent",
                                                  "switches")}
