"""The client's --max-error bound, swept: frame-time spread against the error shown.

Runs the ``separate_bounded`` set-up of ``lodsprite reproduce swan2002`` (client and
server as processes pinned to their own core, one llvmpipe thread each) once per bound,
each run measuring its frames' error untimed afterwards, and prints, per bound: the
client's frame time (σ, p99, mean, ms), the error shown (Eq. 2 in pixels: mean, p99,
max), the share of frames at or above ε, and the keyframes taken from the server and
rendered by the client itself.
``off`` is the paper's client.  The default bound (``DEFAULT_MAX_ERROR``) was chosen
from this table.

    python benchmarks/max_error_sweep.py [--quick] [--bounds 1 4 8 off] [--out out/max_error]
"""

from __future__ import annotations

import argparse
import os
from dataclasses import replace
from pathlib import Path

from lodsprite.experiments.swan2002.run import SwanConfig, run_setup


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="256², 150 frames")
    ap.add_argument("--bounds", nargs="+", default=["1", "4", "8", "off"])
    ap.add_argument("--out", type=Path, default=Path("out/max_error"))
    a = ap.parse_args()
    cpus = sorted(os.sched_getaffinity(0))
    base = SwanConfig.quick() if a.quick else SwanConfig()
    base = replace(base, quality_stride=base.frames)  # image quality on one frame alone
    runs = {}
    for b in a.bounds:
        bounded = b != "off"
        cfg = replace(base, max_error=float(b)) if bounded else base
        name = "separate_bounded" if bounded else "separate"
        res = run_setup(cfg, name, a.out / f"bound_{b}", cpus)
        if res is None:
            raise SystemExit("the separate set-ups need two cores")
        runs[b] = res
    print(f"{'bound px':>8} {'σ ms':>6} {'p99 ms':>7} {'mean ms':>7} {'err mean':>8} "
          f"{'err p99':>7} {'err max':>7} {'>= ε':>6} {'server kf':>9} {'own kf':>6}")
    for b, r in runs.items():
        im = r["image"]
        print(f"{b:>8} {r['client_ms_std']:6.2f} {r['client_ms_p99']:7.2f} "
              f"{r['client_ms_mean']:7.2f} {im['error_px_mean']:8.2f} "
              f"{im['error_px_p99']:7.2f} {im['error_px_max']:7.2f} "
              f"{100 * im['over_epsilon']:5.1f}% {r['keyframes']:9d} "
              f"{r.get('local_keyframes', 0):6d}")


if __name__ == "__main__":
    main()
