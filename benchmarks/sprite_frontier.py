"""Benchmark: LOD-sprite's error–time frontier against the adaptive renderer's on a store,
for each way of drawing spriteframes (the proxy geometry at scale 1, as the store's
defaults draw them; the keyframe's own depth with keyframes at scale 2; ...).

Every run is ``render`` in a process of its own, warmed up alike, taken in turns
(adaptive, each variant, adaptive, ...) so that drift on a shared machine falls on all:
adaptive at each ``--sse``, each variant at each ``--eps``.  Time is the whole path's
(``total_s``, ``ctx.finish()`` inside every frame); error is the RMSE of every
``--quality-stride``-th frame against the band-limited level 0, measured in the run's
untimed replay.  The frontier is the lower envelope of each technique's (time, error)
points chosen on one half of the judged frames, reported on the other half
(:func:`~lodsprite.experiments.base.split_sampled`); printed: every point, then each
variant's speedup over adaptive (adaptive's frontier time over the variant's) at
adaptive's own error at 1, 2 and 4 px, by the path's time, the median frame time and the
p99 (each its own frontier).

    python benchmarks/sprite_frontier.py --terrain STORE [--path flyover] [--frames 120]
        [--size 256] [--sse 0.5 1 2 4] [--eps 0.5 1 2] [--out DIR]
        [--reference-cache DIR]

Every run is judged against the same reference frames: they are drawn once and kept in
``--reference-cache`` (default ``OUT/references``; :mod:`lodsprite.reference_cache`).

Writes ``frontier.json`` (every run, the speedups) and ``frontier.png`` to ``--out``.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import tempfile
from pathlib import Path

import numpy as np

from lodsprite.experiments.base import split_sampled
from lodsprite.experiments.large.child import render_in_child
from lodsprite.reference_cache import ENV
from lodsprite.report.frontier import (
    frontier,
    frontier_speedup,
    plot_frontiers,
    speedup_lower_bound,
)

TIME_KEYS = ("total_s", "median_ms", "p99_ms")
VARIANTS = {
    "geometry k1": {"proxy": "geometry", "key_scale": 1.0},
    "depth k2": {"proxy": "depth", "key_scale": 2.0, "depth_stride": 8},
    "refined k2": {"proxy": "depth-refined", "key_scale": 2.0, "depth_stride": 8},
    "search k2": {"proxy": "search", "key_scale": 2.0, "depth_stride": 8},
    "depth k2 pair": {"proxy": "depth", "key_scale": 2.0, "depth_stride": 8, "pair": True},
    "depth k2 estimate": {"proxy": "depth", "key_scale": 2.0, "depth_stride": 8,
                          "metric": "depth"},
}


def judged(folder: Path) -> tuple[float, float]:
    """Mean RMSE of the judged frames, ``(reported, chosen)`` halves."""
    with open(folder / "frames.csv", newline="") as f:
        e = [float(r["rmse"]) for r in csv.DictReader(f) if r.get("rmse")]
    chosen, reported = split_sampled(e)
    return float(np.mean(reported)), float(np.mean(chosen))


def point(args, name: str, config: dict, out: Path) -> dict:
    w = args.size
    cfg = {"terrain": args.terrain, "path": args.path, "frames": args.frames,
           "size": [w, w], "ground_truth": True, "quality_stride": args.quality_stride,
           **config}
    folder = out / name.replace(" ", "_")
    s = render_in_child(cfg, folder)
    rmse, chosen = judged(folder)
    row = {"name": name, "total_s": s["total_s"], "median_ms": s["median_ms"],
           "p99_ms": s["p99_ms"], "rmse": rmse, "rmse_chosen": chosen,
           "keyframes": s.get("keyframes")}
    print(f"  {name:28s} total {row['total_s']:7.2f} s  median {row['median_ms']:7.2f} ms  "
          f"p99 {row['p99_ms']:7.1f} ms  RMSE {rmse:5.2f} (chosen half {chosen:5.2f})",
          flush=True)
    return row


def plot(rows: dict[str, list[dict]], file: Path, title: str) -> Path:
    """Each technique's (path time, reported RMSE) points and frontier, adaptive's errors
    at 1, 2 and 4 px marked."""
    levels = [r["rmse"] for r in rows.get("adaptive", []) if r["setting"] in (1.0, 2.0, 4.0)]
    return plot_frontiers({k: [(r["total_s"], r["rmse"]) for r in v] for k, v in rows.items()},
                          file, title, time_label="path time (s)", levels=levels)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--terrain", required=True)
    ap.add_argument("--path", default="flyover")
    ap.add_argument("--frames", type=int, default=120)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--sse", type=float, nargs="+", default=[0.5, 1.0, 2.0, 4.0])
    ap.add_argument("--eps", type=float, nargs="+", default=[0.5, 1.0, 2.0])
    ap.add_argument("--quality-stride", type=int, default=4)
    ap.add_argument("--variant", action="append", choices=sorted(VARIANTS))
    ap.add_argument("--out", type=Path)
    ap.add_argument("--reference-cache", type=Path)
    args = ap.parse_args()
    variants = args.variant or list(VARIANTS)
    out = args.out or Path(tempfile.mkdtemp(prefix="sprite-frontier-"))
    os.environ[ENV] = str(args.reference_cache or out / "references")  # the children's too
    rows: dict[str, list[dict]] = {"adaptive": [], **{v: [] for v in variants}}
    turns = max(len(args.sse), len(args.eps))
    for i in range(turns):
        if i < len(args.sse):
            sse = args.sse[i]
            rows["adaptive"].append({**point(args, f"adaptive sse{sse:g}",
                                             {"mode": "adaptive", "sse": sse}, out),
                                     "setting": sse})
        if i < len(args.eps):
            eps = args.eps[i]
            for v in variants:
                rows[v].append({**point(args, f"{v} eps{eps:g}",
                                        {"mode": "sprite", "epsilon": eps,
                                         **VARIANTS[v]}, out), "setting": eps})
    by_sse = {r["setting"]: r for r in rows["adaptive"]}
    print(f"\n{args.terrain}, {args.path}, {args.frames} frames at {args.size}²; speedup "
          "over adaptive at adaptive's error, by the path's time, the median frame and the "
          "p99 (frontiers chosen on one half of the judged frames, errors reported on the "
          "other; '>=': the variant's fastest run is below that error already)")
    result: dict = {"rows": rows, "speedups": {}}
    for key in TIME_KEYS:
        chosen = {k: frontier([(r[key], r["rmse_chosen"]) for r in v])
                  for k, v in rows.items()}
        for v in variants:
            for sse in (1.0, 2.0, 4.0):
                if sse not in by_sse:
                    continue
                err = by_sse[sse]["rmse_chosen"]
                s = frontier_speedup(chosen["adaptive"], chosen[v], err)
                bound = speedup_lower_bound(chosen["adaptive"], chosen[v], err)
                result["speedups"][f"{v} @ {sse:g} px by {key}"] = {
                    "error": err, "speedup": s, "at_least": bound}
                text = (f"{s:.2f}x" if s is not None else
                        f">= {bound:.2f}x" if bound is not None else "not reached")
                print(f"  {key:9s} {v:14s} at adaptive {sse:g} px (RMSE {err:.2f}): {text}")
    reported = {k: frontier([(r["total_s"], r["rmse"]) for r in v]) for k, v in rows.items()}
    result["frontiers_reported"] = reported
    (out / "frontier.json").write_text(json.dumps(result, indent=1, default=float))
    plot(rows, out / "frontier.png", f"{Path(args.terrain).name}, {args.path}, {args.size}²")
    print(f"\nwritten: {out / 'frontier.json'}, {out / 'frontier.png'}")


if __name__ == "__main__":
    main()
