"""Scale-out, measured: keyframes rendered and taken with one LOD server and with two.

Runs the swan2002 reproduction's ``same_all_cores`` (one server) and ``two_servers``
set-ups (client and servers as separate processes sharing every core) along the
swan2002 path, alternately, and prints per run the keyframes each server rendered, the
keyframes the client took, δt and the client's frame time; then the medians and the
ratio two servers ÷ one server of keyframes rendered.

With pace ``needed`` servers take turns (:mod:`lodsprite.distributed.pacing`): where one
server keeps up, a second should add few keyframes.  Drawing the path over more frames
slows the viewer down (``--frames 1800``: a keyframe is due about every 12 frames).

    python benchmarks/scale_out.py [--frames 1800] [--runs 2] [--out out/scale_out]
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import numpy as np

from lodsprite.experiments.swan2002.run import SwanConfig, run_setup

SETUPS = ("same_all_cores", "two_servers")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--terrain", default="jacksboro")
    ap.add_argument("--frames", type=int, default=1800)
    ap.add_argument("--runs", type=int, default=2)
    ap.add_argument("--out", type=Path, default=Path("out/scale_out"))
    args = ap.parse_args()
    cfg = SwanConfig(terrain=args.terrain, frames=args.frames)
    cpus = sorted(os.sched_getaffinity(0))
    rendered: dict[str, list[int]] = {s: [] for s in SETUPS}
    for run in range(args.runs):
        for name in SETUPS:
            out = args.out / f"{name}_{run}"
            res = run_setup(cfg, name, out, cpus)
            stats = json.loads((out / "server_stats.json").read_text())["stats"]
            per_server = [len(s.get("render_ms", [])) for s in stats]
            rendered[name].append(sum(per_server))
            print(f"run {run} {name:15s} rendered {per_server} taken {res['keyframes']:4d} "
                  f"δt {res['delta_t_ms_mean']:.1f} ms  client {res['client_ms_mean']:.2f} "
                  f"± {res['client_ms_std']:.2f} ms", flush=True)
    one, two = (float(np.median(rendered[s])) for s in SETUPS)
    print(f"median keyframes rendered: one server {one:.0f}, two servers {two:.0f}, "
          f"ratio {two / one:.2f} ({args.frames} frames, {len(cpus)} cores)")


if __name__ == "__main__":
    main()
