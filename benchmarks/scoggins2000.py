"""Scoggins et al. (2000) targets: profile generation time for the LOD sphere family and the
jacksboro mountain (each target <= 2 min on 2 cores; paper 17 and 100 min), the
sphereflake's triangle reduction at the spiral's far end (target >= 10x), and profile vs
screen-space-error selection at equal triangles.

    python benchmarks/scoggins2000.py [--out DIR] [--workers N]

Runs the full reproduction once (default settings: 84 views, 512 px) and prints what it
measured; the report goes to DIR (default out/scoggins2000).
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from lodsprite.experiments.scoggins2000.report import write_outputs
from lodsprite.experiments.scoggins2000.run import ScogginsConfig, reproduce_scoggins2000


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("out/scoggins2000"))
    ap.add_argument("--workers", type=int, default=None)
    args = ap.parse_args()
    r = reproduce_scoggins2000(ScogginsConfig(workers=args.workers))
    report, _ = write_outputs(r, args.out)
    cores = len(os.sched_getaffinity(0))
    print(f"cores: {cores}, workers: {r['sphere']['workers']}, views: {r['sphere']['views']}, "
          f"profile image {r['sphere']['image_size']} px")
    print(f"profile sphere family ({len(r['sphere']['faces'])} LODs, "
          f"{r['sphere']['faces'][-1]:,} faces): {r['profile_s_sphere']:.1f} s "
          f"(target <= 120 s; paper 17 min)")
    print(f"profile mountain ({len(r['mountain']['faces'])} LODs, "
          f"{r['mountain']['faces'][-1]:,} faces): {r['profile_s_mountain']:.1f} s "
          f"(target <= 120 s; paper 100 min)")
    print(f"sphereflake full {r['snowflake_triangles_full']:,} triangles; far end "
          f"CSF {r['snowflake_triangles_far_csf']:,} ({r['snowflake_reduction_far_csf']:.0f}x), "
          f"no CSF {r['snowflake_triangles_far_nocsf']:,} "
          f"({r['snowflake_reduction_far_nocsf']:.0f}x) (target >= 10x)")
    for name, c in r["comparison"].items():
        print(f"{name}: triangles profile {c['triangles_profile']:,} / SSE {c['triangles_sse']:,}"
              f"; RMSE {c['rmse_profile']:.3f} / {c['rmse_sse']:.3f}; FLIP "
              f"{c['flip_profile']:.5f} / {c['flip_sse']:.5f}; SSIM {c['ssim_profile']:.5f} / "
              f"{c['ssim_sse']:.5f}")
    print(f"report: {report}")


if __name__ == "__main__":
    main()
