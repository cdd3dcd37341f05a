"""LODManager against its baselines along one walkthrough (issue 15).

In one run, on the 3000-ogre crowd (``--objects``, ``--trees``), ``--frames`` frames:

* the manager, baseline (a) (no sharing: every object extracts its own LOD) and
  baseline (b) (discrete LODs by screen size with hysteresis): mean fps, median and p99
  ms, extractions, LOD CPU ms a frame, draw calls, triangles, LOD switches per second;
* the ratios the issue sets targets for: extractions (a) / manager (>= 10), fps
  manager / (a) (>= 1.5), and the mean absolute image difference between the manager's
  frames and (a)'s on every 50th frame (<= 2 grey levels);
* the manager with ``--target-fps``: median and p99 frame time against the target.

    python benchmarks/lodmanager.py [--objects 3000] [--trees 0] [--frames 600]
                                    [--target-fps 20]
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

from lodsprite.manager.run import CrowdConfig, run_crowd


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--objects", type=int, default=3000)
    ap.add_argument("--trees", type=int, default=0)
    ap.add_argument("--frames", type=int, default=600)
    ap.add_argument("--target-fps", type=float, default=20.0)
    a = ap.parse_args()
    keep = tuple(range(0, a.frames, 50))
    base = CrowdConfig(objects=a.objects, trees=a.trees, frames=a.frames)
    out, images = {}, {}
    for mode in ("manager", "independent", "discrete"):
        _, out[mode], images[mode] = run_crowd(replace(base, mode=mode), keep_frames=keep)
    print(f"{'mode':<12} {'fps':>7} {'median':>8} {'p99':>8} {'extract':>8} {'LOD ms':>7} "
          f"{'draws':>6} {'triangles':>10} {'switch/s':>9}")
    for mode, s in out.items():
        print(f"{mode:<12} {s['fps_mean']:7.2f} {s['median_ms']:8.1f} "
              f"{s['p99_ms']:8.1f} {s['extractions_total']:8d} "
              f"{s['lod_cpu_ms_mean']:7.2f} {s['draw_calls_mean']:6.0f} "
              f"{s['triangles_mean']:10,.0f} {s['switches_per_s']:9.0f}")
    m, i = out["manager"], out["independent"]
    diff = np.mean([np.abs(images["manager"][k].astype(float)
                           - images["independent"][k].astype(float)).mean() for k in keep])
    ratio = i["extractions_total"] / max(1, m["extractions_total"])
    print(f"\nextractions (a) / manager: {ratio:.0f} (>= 10); fps manager / (a): "
          f"{m['fps_mean'] / i['fps_mean']:.2f} (>= 1.5); "
          f"image difference {diff:.3f} grey levels (<= 2)")
    _, t, _ = run_crowd(replace(base, mode="manager", target_fps=a.target_fps))
    target_ms = 1e3 / a.target_fps
    print(f"target {a.target_fps:g} fps ({target_ms:.1f} ms): median {t['median_ms']:.1f}"
          f" ms ({t['median_ms'] / target_ms:.3f} x, within 10 %), p99 "
          f"{t['p99_ms']:.1f} ms ({t['p99_ms'] / target_ms:.2f} x, <= 1.5); "
          f"GL {t['gl_renderer']}")


if __name__ == "__main__":
    main()
