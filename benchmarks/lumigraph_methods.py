"""Lumigraph methods and the critical-time renderer against the issue's targets (issue 14).

In one run, on one lumigraph (captured here unless ``--lumigraph`` names one):

* capture time of the default lumigraph (32² nodes of 256², JPEG), target < 120 s;
* every method along the default arc (``--frames``, PSNR on every 5th frame): median,
  mean and p99 ms, images per frame, PSNR, and its median time as a ratio of ``full``'s;
* critical time at 4 MB of texture memory and 30 fps over ``--critical-frames`` (600):
  mean / target (target <= 1.05) and p99 / target (<= 1.25), and PSNR.

    python benchmarks/lumigraph_methods.py [--lumigraph DIR] [--frames 120]
                                           [--critical-frames 600]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from lodsprite.experiments.sloan1997.run import to_and_fro
from lodsprite.lumigraph.methods import METHODS
from lodsprite.lumigraph.paths import object_path
from lodsprite.lumigraph.run import capture_lumigraph, measure
from lodsprite.lumigraph.store import Lumigraph


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lumigraph", type=Path, default=None)
    ap.add_argument("--frames", type=int, default=120)
    ap.add_argument("--critical-frames", type=int, default=600)
    ap.add_argument("--size", type=int, default=512)
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        lf = a.lumigraph
        if lf is None:
            lf = Path(tmp) / "lf"
            s = capture_lumigraph("still-life", lf)
            print(f"capture: {s['nodes']} nodes of {s['uv']}² in {s['capture_s']:.1f} s "
                  f"(target < 120 s)")
        slab = Lumigraph(lf).slabs[0]
        size = (a.size, a.size)
        rows = {}
        for m in METHODS:
            _, rows[m] = measure(lf, m, object_path(slab, a.frames), size=size,
                                 ground_truth=True, quality_every=5)
        full = rows["full"]["median_ms"]
        print(f"\n{'method':<12} {'median':>8} {'mean':>8} {'p99':>8} {'images':>7} "
              f"{'PSNR':>7} {'vs full':>8}")
        for m, s in rows.items():
            print(f"{m:<12} {s['median_ms']:8.2f} {s['mean_ms']:8.2f} {s['p99_ms']:8.2f} "
                  f"{s['images_per_frame_mean']:7.1f} {s['psnr_mean']:7.2f} "
                  f"{s['median_ms'] / full:8.2f}")
        path = to_and_fro(object_path(slab, max(2, a.critical_frames // 2)),
                          a.critical_frames)
        _, c = measure(lf, "critical", path, size=size, ground_truth=True, quality_every=10,
                       target_fps=30.0, texture_mb=4.0)
        t = c["target_ms"]
        print(f"\ncritical, 4 MB, 30 fps, {c['frames']} frames: mean {c['mean_ms']:.2f} ms "
              f"({c['mean_ms'] / t:.3f} x target, <= 1.05), p99 {c['p99_ms']:.2f} ms "
              f"({c['p99_ms'] / t:.3f} x target, <= 1.25), {c['images_per_frame_mean']:.1f} "
              f"images a frame, PSNR {c['psnr_mean']:.2f} dB; GL {c['gl_renderer']}")


if __name__ == "__main__":
    main()
