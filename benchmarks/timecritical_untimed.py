"""Benchmark: the adaptive renderer given all the time it needs, on ``reproduce
timecritical``'s path, as that experiment's bar for a technique played in time.

The same terrain, path (its first ``--seconds`` at its own speed) and size as
:class:`~lodsprite.experiments.timecritical.run.TimeCriticalConfig`, each frame drawn
untimed and judged at its own viewpoint against the same band-limited reference (4 x 4
samples a pixel), at each ``--sse``.  Printed: the mean and median RMSE over the frames and
the median frame time.

    python benchmarks/timecritical_untimed.py [--terrain jacksboro] [--path bank]
        [--size 256] [--seconds 5] [--sse 1 0.5]
"""

from __future__ import annotations

import argparse

import numpy as np

from lodsprite import techniques
from lodsprite.api import Renderer
from lodsprite.harness import level_zero_reference, run_path
from lodsprite.paths import CameraPath
from lodsprite.paths.core import NOMINAL_FPS
from lodsprite.runconfig import RenderConfig, field_of_view, prepare


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--terrain", default="jacksboro")
    ap.add_argument("--path", default="bank")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--sse", type=float, nargs="+", default=[1.0, 0.5])
    args = ap.parse_args()
    size = (args.size, args.size)
    cfg = RenderConfig(terrain=args.terrain, path=args.path, mode="adaptive", size=size,
                       ground_truth=True).resolved()
    scene, path = prepare(cfg)[:2]
    n = max(2, min(len(path), int(args.seconds * NOMINAL_FPS) + 1))
    path = CameraPath(path.name, path.viewpoints[:n], path.fov_y_deg)
    fov = field_of_view(cfg, path)
    with Renderer(scene, size, fov) as r:
        ref = level_zero_reference(r.gl, scene, r.size, fov, "auto", 4)
        try:
            for sse in args.sse:
                t = techniques.create("adaptive", r, sse=sse)
                try:
                    res = run_path(t, path, ground_truth=True, reference=ref.image)
                finally:
                    t.release()
                e = [row["rmse"] for row in res.rows if "rmse" in row]
                print(f"adaptive {sse:g} px untimed, {len(e)} frames: RMSE mean "
                      f"{np.mean(e):.3f}, median {np.median(e):.3f}; median frame "
                      f"{res.summary['median_ms']:.1f} ms")
        finally:
            ref.release()


if __name__ == "__main__":
    main()
